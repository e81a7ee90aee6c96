"""A search's design space (flatcli/designsearch/design.py): design vectors to robots and
candidate specs, as-built offsets kept, constraints.

Referees: the counterweighted link from the balance condition written out here (m_c = m |r| /
|p|, inertia about the joint I + m |r|^2 + m_c |p|^2); the spec's own [plant] values; the
flatness verdict of ``design_verdict`` (w ^ dw from the link kinematics at 64 sampled
configurations), which the constraint computes another way (``flatness_check``)."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
from small_search import SPEC

from flatcli.core.robots.design import design_verdict
from flatcli.designsearch.design import Design
from flatcli.spec import resolve


def design_of(text: str = SPEC, **search: object) -> Design:
    tree = tomllib.loads(text)
    tree["search"].update(search)
    return Design.of(resolve(tree))


def test_the_specs_own_design_is_the_papers_robot() -> None:
    """The bare 0.5 kg link with 0.5 kg at 0.1 m behind joint 2 is the paper's link 2."""
    design = design_of()
    own = design.own_robot
    assert own.mass == pytest.approx((1.0, 1.0, 1.0))
    assert own.inertia == pytest.approx((0.0533,) * 3, rel=1e-12)
    assert own.com == (0.1, 0.1, 0.0) and own.com_across == 0.0
    assert design.baseline_inside


@pytest.mark.parametrize("x", [(0.8, 0.15, 0.07), (1.25, 0.25, 0.13), (1.0, 0.2, 0.1)])
def test_a_design_vector_is_its_robot(x: tuple[float, float, float]) -> None:
    design = design_of()
    robot = design.robot(np.array(x))
    m1, l1, distance = x
    m, d, inertia = 0.5, 0.1, 0.0433  # the bare link 2
    weight = m * d / distance  # the balance: m_c |p| = m |r|
    assert robot.mass == pytest.approx((1.0, m1, m + weight), rel=1e-12)
    assert robot.length == pytest.approx((0.2, l1, 0.2))
    assert robot.com == pytest.approx((0.1, 0.1, 0.0), abs=1e-15)
    assert robot.inertia[2] == pytest.approx(inertia + m * d**2 + weight * distance**2,
                                             rel=1e-12)
    assert design.counterweight_of(np.array(x)) == pytest.approx(
        {"mass": weight, "x": -distance, "y": 0.0})


def test_the_plant_keeps_its_as_built_offset() -> None:
    """[plant] com = [0.1, 0.1, 0.001]: 1 mm off the own design's joint, in every candidate;
    keys the spec leaves unset are the candidate's robot's."""
    design = design_of()
    candidate = design.candidate(np.array([0.8, 0.15, 0.12]))
    assert candidate.feasible and candidate.spec is not None
    spec = candidate.spec
    assert spec.robot.com == pytest.approx((0.1, 0.1, 0.0))
    assert spec.plant.com == pytest.approx((0.1, 0.1, 0.001))
    assert spec.plant.mass is None and spec.robot.mass[1] == pytest.approx(0.8)
    assert not spec.search.vary and not spec.search.counterweight
    # link 1 built 50 g heavier than designed: 50 g heavier in every candidate
    text = SPEC.replace("com = [0.1, 0.1, 0.001]", "com = [0.1, 0.1, 0.001]\n"
                        "mass = [1.0, 1.05, 1.0]")
    shifted = design_of(text).candidate(np.array([0.8, 0.15, 0.12])).spec
    assert shifted is not None
    link2 = 0.5 + 0.5 * 0.1 / 0.12  # the candidate's counterweighted link 2
    assert shifted.plant.mass == pytest.approx((1.0, 0.85, link2), rel=1e-12)
    own = design_of(text).candidate(design_of(text).baseline).spec
    assert own is not None and own.plant.mass == (1.0, 1.05, 1.0)  # exactly as written


def test_a_plant_design_leaves_the_controllers_robot_alone() -> None:
    text = SPEC.replace("[robot]\nmass = [1.0, 1.0, 0.5]\ninertia = [0.0533, 0.0533, 0.0433]"
                        "\ncom = [0.1, 0.1, 0.1]\n[plant]\ncom = [0.1, 0.1, 0.001]",
                        "[plant]\nmass = [1.0, 1.0, 0.5]\ninertia = [0.0533, 0.0533, 0.0433]"
                        "\ncom = [0.1, 0.1, 0.1]")
    text = text.replace('"robot.mass[1]"', '"plant.mass[1]"').replace(
        '"robot.length[1]"', '"plant.length[1]"')
    design = design_of(text, apply="plant")
    spec = design.candidate(np.array([0.9, 0.2, 0.1])).spec
    assert spec is not None
    assert spec.robot.mass == (1.0, 1.0, 1.0) and spec.robot.com == (0.1, 0.1, 0.0)
    assert spec.plant.mass == pytest.approx((1.0, 0.9, 1.0))
    assert spec.plant.inertia == pytest.approx((0.0533,) * 3, rel=1e-12)


def test_the_total_mass_constraint() -> None:
    design = design_of(max_mass=3.1)
    light = design.candidate(np.array([0.8, 0.2, 0.1]))  # 1 + 0.8 + 1 = 2.8 kg
    heavy = design.candidate(np.array([1.3, 0.2, 0.07]))  # 1 + 1.3 + 0.5 + 0.714 = 3.514 kg
    assert light.feasible and light.violations[0] == 0.0
    assert not heavy.feasible and heavy.spec is None
    assert heavy.violations[0] == pytest.approx(1.0 + 1.3 + 0.5 + 0.05 / 0.07 - 3.1)
    assert heavy.reason.startswith("total mass 3.51429 kg > search.max_mass 3.1 kg")


def test_the_verdict_constraint_agrees_with_the_link_kinematics() -> None:
    """The constraint's verdict (closed-form conditions and the couplings K_ab) is
    design_verdict's, which samples w ^ dw from the full link kinematics."""
    text = SPEC.split("[search.counterweight]")[0].replace(
        '"counterweight.distance" = [0.07, 0.13]', '"robot.com[2]" = [-0.01, 0.01]')
    text = text.replace("com = [0.1, 0.1, 0.1]", "com = [0.1, 0.1, 0.0]").replace(
        "inertia = [0.0533, 0.0533, 0.0433]", "inertia = [0.0533, 0.0533, 0.0533]")
    design = design_of(text, verdict="closed_form")
    rng = np.random.default_rng(3)
    for x in [np.array([1.0, 0.2, 0.0]), *(np.array([rng.uniform(0.7, 1.3),
                                                     rng.uniform(0.14, 0.26),
                                                     rng.uniform(-0.01, 0.01)])
                                          for _ in range(4))]:
        candidate = design.candidate(x)
        assert candidate.robot is not None
        assert candidate.verdict == design_verdict(candidate.robot).verdict
        assert candidate.feasible == (x[2] == 0.0)
        if not candidate.feasible:
            assert candidate.violations[1] == 1.0
            assert "verdict flat, search.verdict asks for closed_form" in candidate.reason
