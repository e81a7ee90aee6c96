"""Tests of the counterweight designer (flatcli.core.robots.counterweight, flatcli.designer and
``flatcli design --counterweight``).

Referees: the centre of mass and the inertia about the joint from their definitions
((m r + m_c p) / (m + m_c), parallel axes); a brute-force search over the allowed segment;
the Python API planning the resulting design (its input energy) and judging it
(``design_verdict``).
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import example, given, settings
from hypothesis import strategies as st

import flatcli
from flatcli.cli import main
from flatcli.core.errors import FlatcliError
from flatcli.core.robots.counterweight import POSITION_RTOL, apply, attach, design_counterweight
from flatcli.core.robots.design import design_verdict
from flatcli.core.robots.params import RobotParams

#: Balancing to rounding.
ROUNDING = 1e-12


def _balance(m: float, r: np.ndarray, mc: float, p: np.ndarray) -> np.ndarray:
    return (m * r + mc * p) / (m + mc)


@pytest.mark.parametrize("segment", [[[-0.1, 0.0], [-0.02, 0.0]],   # along the axis, behind
                                     [[-0.2, -0.05], [0.0, -0.05]],  # across it, crossing
                                     [[-0.05, 0.1], [-0.05, -0.1]]])
def test_least_mass_and_least_inertia_balance_the_link(segment: list[list[float]]) -> None:
    """Referee: the centre of mass (definition) is on the joint; brute force over 2001
    points of the segment: no balancing point needs less mass or adds less inertia."""
    m, inertia, d, e = 0.5, 0.01, 0.05, 0.02 if segment[0][1] != 0 else 0.0
    light, compact = design_counterweight(m, inertia, d, e, segment)
    r = np.array([d, e])
    band = POSITION_RTOL * max(np.abs(segment).max(), np.hypot(d, e))
    for cw in (light, compact):
        p = np.array([cw.x, cw.y])
        centre = _balance(m, r, cw.mass, p)  # within the band's share of the joint
        assert np.hypot(*centre) == pytest.approx(cw.residual, abs=ROUNDING)
        assert cw.residual <= band * cw.mass / (m + cw.mass) * (1 + 1e-9)
        want = inertia + m * (r @ r) + cw.mass * (p @ p)
        assert cw.link_inertia == pytest.approx(want, rel=1e-12)
        assert cw.link_mass == pytest.approx(m + cw.mass)
    a, b = np.asarray(segment)
    points = a + np.linspace(0, 1, 2001)[:, None] * (b - a)
    unit = -r / np.linalg.norm(r)
    along = points @ unit
    off = np.abs(points @ np.array([-unit[1], unit[0]]))
    ok = (off <= 1e-3 * np.abs(points).max()) & (along > 0)
    masses = m * np.linalg.norm(r) / along[ok]
    added = masses * along[ok] ** 2
    assert light.mass <= masses.min() * (1 + 1e-2)
    assert compact.mass * compact.distance**2 <= added.min() * (1 + 1e-2)


def test_a_segment_off_the_ray_is_refused() -> None:
    with pytest.raises(FlatcliError, match=r"^--positions: no allowed position lies on the ray"):
        design_counterweight(0.5, 0.01, 0.05, 0.0, [[0.1, 0.0], [0.2, 0.0]])
    with pytest.raises(FlatcliError, match=r"needs no counterweight"):
        design_counterweight(0.5, 0.01, 0.0, 0.0, [[-0.1, 0.0], [-0.2, 0.0]])


def test_cli_reports_each_design_its_verdict_and_plan_energy() -> None:
    """Referee: the API planning each resulting robot, and design_verdict of it."""
    sets = ["--set", "robot.com=[0.1,0.1,0.05]", "--set", "robot.mass=[1,1,0.5]"]
    result = CliRunner().invoke(main, ["design", "--counterweight", "--positions", "-0.1",
                                       "0", "-0.02", "0", *sets])
    assert result.exit_code == 0, result.output
    bare = RobotParams(mass=(1, 1, 0.5), com=(0.1, 0.1, 0.05))
    for label, cw in zip(("least mass", "least inertia"),
                         design_counterweight(0.5, 0.0533, 0.05, 0.0, [[-0.1, 0], [-0.02, 0]]),
                         strict=True):
        robot = apply(bare, cw)
        assert design_verdict(robot).verdict == "closed_form"
        energy = flatcli.plan(overrides={"robot.mass": list(robot.mass),
                                         "robot.inertia": list(robot.inertia),
                                         "robot.com": list(robot.com)}).metrics["input_energy"]
        row = next(line for line in result.output.splitlines() if line.startswith(f"| {label}"))
        assert "closed_form" in row and f"{energy:.6g}" in row


@pytest.mark.parametrize(("weight", "x", "y", "own"), [(0.5, -0.1, 0.0, 0.0),
                                                       (0.3, -0.05, 0.02, 1e-4),
                                                       (0.0, 0.3, 0.3, 0.0),
                                                       (2.0, 0.15, -0.04, 3e-3)])
def test_a_counterweight_attached_anywhere(weight: float, x: float, y: float,
                                           own: float) -> None:
    """Referee: the centre of mass by its definition, and the inertia about the centre by
    the other route: about the joint (each body's parallel axis to the origin), then back to
    the centre (I_c = I_O - M |c|^2)."""
    bare = RobotParams((1.0, 1.0, 0.6), (0.05, 0.05, 0.02), (0.2, 0.2, 0.2),
                       (0.1, 0.1, 0.07), 0.01)
    got = attach(bare, weight, x, y, own)
    r, p = np.array([0.07, 0.01]), np.array([x, y])
    total = 0.6 + weight
    centre = (0.6 * r + weight * p) / total
    about_joint = 0.02 + 0.6 * (r @ r) + own + weight * (p @ p)
    assert got.mass[2] == pytest.approx(total, rel=ROUNDING)
    assert (got.com[2], got.com_across) == pytest.approx(tuple(centre), abs=ROUNDING)
    assert got.inertia[2] == pytest.approx(about_joint - total * (centre @ centre),
                                           rel=1e-12)
    assert got.mass[:2] == bare.mass[:2] and got.com[:2] == bare.com[:2]


def test_attached_at_the_designers_place_it_is_the_designers_link() -> None:
    bare = RobotParams((1.0, 1.0, 0.5), (0.0533, 0.0533, 0.0433), (0.2, 0.2, 0.2),
                       (0.1, 0.1, 0.1))
    _, weight = design_counterweight(0.5, 0.0433, 0.1, 0.0, [[-0.1, 0.0], [-0.1, 0.0]])
    designed = apply(bare, weight)
    placed = attach(bare, weight.mass, weight.x, weight.y)
    assert placed.mass == designed.mass
    assert placed.inertia == pytest.approx(designed.inertia, rel=1e-12)
    assert placed.com == pytest.approx(designed.com, abs=ROUNDING)
    # and both are the paper's link 2: 1 kg, 0.0533 kg m^2 on joint 2
    assert designed.mass[2] == pytest.approx(1.0) and designed.inertia[2] == pytest.approx(0.0533)


def test_an_attached_counterweight_refuses_negative_or_infinite_values() -> None:
    bare = RobotParams()
    with pytest.raises(FlatcliError, match=r"^counterweight: mass and own inertia must be >= 0"):
        attach(bare, -0.1, 0.1, 0.0)
    with pytest.raises(FlatcliError, match=r"every value finite"):
        attach(bare, 0.1, float("inf"), 0.0)


@settings(deadline=None, max_examples=300)
@given(angle=st.floats(-3.1, 3.1), reach=st.floats(0.005, 0.2), near=st.floats(0.01, 0.3),
       extent=st.floats(0.0, 0.3), offset_a=st.floats(-0.5, 0.5), offset_b=st.floats(-0.5, 0.5),
       swap=st.booleans())
def test_a_segment_off_the_ray_by_less_than_the_band_gives_the_same_answers(
        angle: float, reach: float, near: float, extent: float, offset_a: float,
        offset_b: float, swap: bool) -> None:
    """The ideal segment along the ray opposite the link's centre, then the same segment
    with each end moved across the ray by up to half the stated band (POSITION_RTOL of the
    link's scale; 1e-7 m off a 0.1 m ray is such a move): the same counterweights, to
    rounding (their mass depends on the distance along the ray only), each off the ray by
    at most that move. Referee: m_c = m |r| / t at the segment's farthest and nearest
    distance t along the ray (the module's closed form, from the balance m_c p = -m r)."""
    m = 0.5
    r = reach * np.array([np.cos(angle), np.sin(angle)])
    unit, normal = -r / reach, np.array([np.sin(angle), -np.cos(angle)])
    ends = [near * unit, (near + extent) * unit]
    band = POSITION_RTOL * max(float(np.abs(np.array(ends)).max()), reach)
    moved = [ends[0] + offset_a * band * normal, ends[1] + offset_b * band * normal]
    segment = [moved[1], moved[0]] if swap else moved
    light, compact = design_counterweight(m, 0.01, float(r[0]), float(r[1]), segment)
    assert light.mass == pytest.approx(m * reach / (near + extent), rel=1e-9)
    assert compact.mass == pytest.approx(m * reach / near, rel=1e-9)
    for cw in (light, compact):
        assert cw.residual <= 0.5 * band * cw.mass / (m + cw.mass) * (1 + 1e-6) + 1e-15


@settings(deadline=None, max_examples=300)
@given(tilt=st.floats(-20.0, 20.0), shift=st.floats(-3.0, 3.0), nudge=st.floats(-1.0, 1.0))
@example(tilt=0.0, shift=1.0, nudge=1.0)  # the whole segment on the band's edge
def test_the_answers_change_continuously_with_the_segment(tilt: float, shift: float,
                                                          nudge: float) -> None:
    """A segment crossing or running beside the ray at any small angle (up to 20 bands of
    tilt over its length, shifted up to 3 bands): moving one end by 1e-12 m (a rounding)
    changes each counterweight by at most 1e-6 of its mass, or the segment is refused both
    times; a refusal only where the segment misses the band."""
    m = 0.5
    band = POSITION_RTOL * 0.1
    a = np.array([-0.1, (shift + tilt) * band])
    b = np.array([-0.02, shift * band])

    def answer(p: np.ndarray) -> tuple[float, float] | None:
        try:
            light, compact = design_counterweight(m, 0.01, 0.05, 0.0, [p, b])
        except FlatcliError:
            return None
        return light.mass, compact.mass

    first, second = answer(a), answer(a + np.array([0.0, nudge * 1e-12]))
    misses = min(abs(a[1]), abs(b[1])) > band and a[1] * b[1] > 0
    assert (first is None) == misses
    on_edge = abs(abs(a[1]) - band) <= 1e-9  # the stated tolerance's own edge: a rounding of
    if on_edge:  # an end lying on it may take that end in or out (tilt 0, shift 1: the whole
        return  # segment on the edge, 0.25 kg with its far end in, 1.25 kg with it out)
    if first is not None and second is not None:
        assert second[0] == pytest.approx(first[0], rel=1e-6)
        assert second[1] == pytest.approx(first[1], rel=1e-6)
    else:  # one refusal: only exactly at the band's edge
        assert first == second
