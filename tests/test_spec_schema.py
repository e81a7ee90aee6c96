"""The schema (flatcli/spec/schema.py): records, their keys, enumerations from the core."""

from __future__ import annotations

import math
import re
from dataclasses import fields

import numpy as np
import pytest

from flatcli.core.names import INTEGRATORS, MODELS
from flatcli.core.optimize import OBJECTIVES
from flatcli.spec import (
    GAINS,
    LINKS,
    SCHEMA,
    SECTIONS,
    Spec,
    SpecError,
    all_keys,
    find_key,
    lookup,
    resolve,
)


def test_sections_are_the_toml_tables() -> None:
    assert list(SECTIONS) == ["", "robot", "plan", "plan.optimize", "task", "track", "plant",
                              "sweep", "figures", "summary", "search"]
    assert list(SCHEMA) == list(SECTIONS)


def test_figures_enter_no_digest_and_are_bounded() -> None:
    plain = resolve({})
    pdf = resolve({"figures": {"format": "pdf", "dpi": 300}})
    assert pdf.figures.format == "pdf" and pdf.figures.dpi == 300
    assert pdf.digest() == plain.digest()  # how results are drawn is not the experiment
    assert pdf.tree["figures"] == {"format": "pdf", "dpi": 300}  # but the record keeps it
    assert "figures" not in pdf.experiment_tree()
    assert resolve({"track": {"dt": 2e-3}}).digest() != plain.digest()
    with pytest.raises(SpecError, match=r"figures.dpi: must be at most 1200 dots/in, got 5000"):
        resolve({"figures": {"dpi": 5000}})
    with pytest.raises(SpecError, match=r"figures.format: expected one of \['png', 'pdf', "
                                        r"'svg'\], got 'jpg'"):
        resolve({"figures": {"format": "jpg"}})
    assert lookup("figures.dpi").bounds_text() == "50 to 1200"
    with pytest.raises(SpecError, match=r"cannot grid over 'figures\.format'"):
        resolve({"sweep": {"grid": {"figures.format": ["png", "pdf"]}}})


def test_the_summary_section_is_presentation_too() -> None:
    """summary.reach_tolerance judges a sweep's trials; it computes nothing, so it enters no
    digest (a sweep resumes whatever it says) and cannot be gridded."""
    plain = resolve({})
    judged = resolve({"summary": {"reach_tolerance": 0.01}})
    assert judged.summary.reach_tolerance == 0.01 and plain.summary.reach_tolerance == 1e-3
    assert judged.digest() == plain.digest()
    assert "summary" not in judged.experiment_tree()
    with pytest.raises(SpecError, match=r"summary.reach_tolerance: must be > 0"):
        resolve({"summary": {"reach_tolerance": 0.0}})
    with pytest.raises(SpecError, match=r"cannot grid over 'summary\.reach_tolerance'"):
        resolve({"sweep": {"grid": {"summary.reach_tolerance": [1e-3, 1e-2]}}})


def test_every_key_has_a_default_value_in_the_built_spec() -> None:
    values = resolve({}).values()
    assert sorted(values) == sorted(all_keys())
    for dotted in all_keys():
        key = lookup(dotted)
        expected = {} if key.kind == "table" else key.default
        assert values[dotted] == expected, dotted


def test_choices_come_from_the_core() -> None:
    assert lookup("robot.model").choices == MODELS
    assert lookup("plan.optimize.objective").choices == OBJECTIVES
    assert lookup("track.integrator").choices == INTEGRATORS


def test_per_link_vectors_follow_the_robot() -> None:
    for dotted in ("robot.mass", "robot.com", "plan.start", "track.initial", "plant.com",
                   "plan.optimize.angle_limit"):
        key = lookup(dotted)
        assert key.size == "links" and len(key.default or (0.0,) * LINKS) == LINKS
    assert lookup("track.kp").size == lookup("track.kv").size == "joints"
    assert len(lookup("track.kp").default) == GAINS
    for dotted in ("plan.start_rate", "plan.goal_rate", "track.initial_rate"):
        assert lookup(dotted).size == "inner" and lookup(dotted).kind == "numbers"


FOUR_LINKS = {
    "robot": {"mass": [2.0, 1.0, 1.0, 0.6], "inertia": [0.08, 0.03, 0.03, 0.2],
              "length": [0.3, 0.25, 0.25, 0.25], "com": [0.12, 0.1, 0.1, 0.0]},
    "plan": {"start": [0, 1, 0.3, 0], "goal": [0.4, 2, 0.6, 0]},
    "track": {"initial": [0, 1, 0.3, 0], "kp": [1, 2, 3], "kv": [4, 5, 6]},
}


def test_a_robot_of_three_joints_sizes_every_per_link_key() -> None:
    spec = resolve(FOUR_LINKS)
    assert spec.joints == 3
    assert spec.plan.optimize.angle_limit == (math.inf,) * 4  # a uniform default follows N
    assert spec.plan.start_rate == 0.1  # one number: every joint 1..N-1
    spec = resolve(FOUR_LINKS, {"plan.start_rate": [0.2, 0.3], "track.initial_rate": 0.1})
    assert spec.plan.start_rate == (0.2, 0.3) and spec.track.initial_rate == 0.1
    # a scalar stays a float (not a 1-list): the JSON, hence the digest, of every existing
    # spec is what it was, so their sweep directories still resume
    assert '"start_rate":0.1}' in resolve({}).to_json()


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"plan.start": [0, 1, 0]}, "plan.start: expected 4 numbers (one per link 0..N) for "
                                    "a robot of 3 joints (robot.mass has 4 links), got 3"),
        ({"track.kp": [1, 2]}, "track.kp: expected 3 numbers (one per joint 1..N)"),
        ({"plan.goal_rate": [0.1, 0.2, 0.3]},
         "plan.goal_rate: expected 2 numbers (one per joint 1..N-1)"),
        ({"robot.com": [0.1, 0.1, 0.0]}, "robot.com: expected 4 numbers"),
        ({"plant.inertia": [1, 1, 1, 1, 1]}, "plant.inertia: expected 4 numbers"),
        ({"plan.optimize.angle_limit": [1, 1, 1]}, "plan.optimize.angle_limit: expected 4"),
        ({"track.initial_rate": []}, "track.initial_rate: expected a number or a list of "
                                     "N - 1 numbers"),
    ],
)
def test_a_key_of_the_wrong_length_is_refused_naming_it(overrides: dict[str, object],
                                                        message: str) -> None:
    with pytest.raises(SpecError, match="^" + re.escape(message)):
        resolve(FOUR_LINKS, overrides)


def test_a_default_of_the_papers_robot_must_be_set_for_another() -> None:
    user = {"robot": FOUR_LINKS["robot"]}
    with pytest.raises(SpecError, match=r"^plan.start: expected 4 numbers .* got 3 \(the "
                                        r"default is the paper's robot's: set it\)$"):
        resolve(user)


def test_a_robot_of_other_n_tracks_with_only_its_robot_and_plan() -> None:
    """Sized defaults: the plant starts on the plan and every flat output gets kp = p^2,
    kv = 2 p, the closed form of a double pole at -p of y'' = -kv y' - kp y (p = 5 rad/s);
    the paper's robot keeps Fig. 4's start and the gains as printed."""
    user = {"robot": FOUR_LINKS["robot"], "plan": FOUR_LINKS["plan"]}
    spec = resolve(user)
    assert spec.track.initial == tuple(float(v) for v in FOUR_LINKS["plan"]["start"])
    poles = np.roots([1.0, spec.track.kv[0], spec.track.kp[0]])
    assert np.allclose(poles, [-5.0, -5.0], atol=1e-6)
    assert spec.track.kp == (25.0,) * 3 and spec.track.kv == (10.0,) * 3
    set_gains = resolve(user, {"track.kp": [1, 2, 3]})
    assert set_gains.track.kp == (1.0, 2.0, 3.0) and set_gains.track.kv == (10.0,) * 3
    paper = resolve({})
    assert paper.track.initial == (1.96, 0.8, -0.1)  # Fig. 4 of the paper
    assert paper.track.kp == (10.0, 13.0) and paper.track.kv == (100.0, 110.0)


def test_tree_mirrors_the_records_and_values_the_keys() -> None:
    spec = resolve({"track": {"dt": 0.002}})
    assert spec.tree["track"]["dt"] == spec.track.dt == 0.002
    assert spec.tree["plan"]["optimize"]["max_iter"] == spec.plan.optimize.max_iter
    assert spec.values()["plan.optimize.max_iter"] == 300
    assert [f.name for f in fields(Spec)] == list(spec.tree)


def test_unknown_keys_get_a_suggestion() -> None:
    expected = r"unknown key 'plan.optimise.objective' \(did you mean 'plan.optimize.objective'"
    with pytest.raises(SpecError, match=expected):
        lookup("plan.optimise.objective")


def test_find_key_is_lookup_without_the_error() -> None:
    """``find_key`` returns lookup's Key for every key of the schema and None where lookup
    raises (a column name, a section, a near miss)."""
    for dotted in all_keys():
        assert find_key(dotted) is lookup(dotted)
    for name in ("final_error", "track", "track.kpp", "sweep.perturb.mass.std", ""):
        assert find_key(name) is None
        with pytest.raises(SpecError):
            lookup(name)
