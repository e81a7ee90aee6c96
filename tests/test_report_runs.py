"""Terminal summaries of plans and runs (flatcli/report/runs.py)."""

from __future__ import annotations

import numpy as np

from flatcli.core.plan.planning import plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT
from flatcli.report.runs import optimization_text, plan_summary


def test_plan_summary_of_the_papers_cubic() -> None:
    plan = plan_point_to_point(PAPER_ROBOT, np.array([1.8, 1, 0]), np.array([1.2, 2, 0]), 0.1,
                               0.5, 2.0)
    samples = plan.sample(plan.grid(201))
    summary = plan_summary(plan, samples)
    # th2 reaches 3.93 rad; initial rates (-13.25, 0.1, 48.8) rad/s: the cubic of Sec. VI
    # with the correct b1 (tests/test_planning.py::test_derived_plan_matches_physics_note)
    assert round(summary["max_abs_theta2"], 2) == 3.93
    assert round(summary["peak_rate2"], 1) == 48.8
    # the paper's cubic costs an input energy of about 101 (tests/test_optimize_api.py,
    # CUBIC_ENERGY = 101.19)
    assert 100 < summary["input_energy"] < 102


def test_the_optimisers_chosen_end_rates_are_shown_for_every_inner_joint() -> None:
    """The paper's robot: th1' at both ends; a chain: every inner joint's (the values are
    the summary's own, so only the layout is tested here)."""
    base = {"objective": "energy", "value": 1.0, "initial_value": 2.0, "success": True,
            "message": "", "iterations": 1, "evaluations": 2, "max_violation": 0.0,
            "active": [], "start_rate": 0.1, "goal_rate": 0.5}
    paper = optimization_text({**base, "start_rates": [0.1], "goal_rates": [0.5]})
    assert "th1'(0), th1'(T) chosen [rad/s]" in paper and "0.1, 0.5" in paper
    chain = optimization_text({**base, "start_rates": [0.1, -0.2], "goal_rates": [0.5, 0.3]})
    assert "th1'..th2' at 0 and T chosen [rad/s]" in chain and "(0.1, -0.2), (0.5, 0.3)" in chain


def test_plan_text_names_its_curves_in_words_not_class_names() -> None:
    """The header says what the curves are (the basis's degree and coefficients, an exact
    plan's pieces), never a Python class name."""
    from flatcli.core.curves.basis import BSplineBasis
    from flatcli.core.plan.exact import plan_exact
    from flatcli.core.plan.rest import plan_rest_to_rest
    from flatcli.report.runs import plan_text

    start, goal = np.array([1.8, 1, 0]), np.array([1.2, 2, 0])
    cubic = plan_point_to_point(PAPER_ROBOT, start, goal, 0.1, 0.5, 2.0)
    spline = plan_point_to_point(PAPER_ROBOT, start, goal, 0.1, 0.5, 2.0,
                                 basis=BSplineBasis(12, 2.0, 5))
    rest = plan_rest_to_rest(PAPER_ROBOT, start, goal, 2.0)
    built = PAPER_ROBOT.__class__(com=(0.1, 0.1, 0.003))
    exact = plan_exact(built, start, goal, 0.1, 0.5, 2.0)
    expected = [(cubic, "flat outputs as cubic polynomials (4 coefficients each)"),
                (spline, "flat outputs as quintic B-splines (12 coefficients each)"),
                (rest, "rest to rest, flat outputs as degree-7 polynomials (8 coefficients"),
                (exact, "exact plan (no flat outputs): joint paths and th0 as piecewise")]
    for plan, words in expected:
        text = plan_text("x", plan, plan.sample(plan.grid(11)))
        head = text.splitlines()[0]
        assert words in head, head
        assert "Basis" not in text and "size" not in head
    exact_text = plan_text("x", exact, exact.sample(exact.grid(11)))
    assert "th1' [rad/s]" in exact_text and "y1' [rad/s]" not in exact_text


def test_track_metrics_are_printed_with_their_units() -> None:
    """Every metric with a physical unit shows it (the one table of units, flatcli/units.py:
    its own test checks it against docs/outputs.md); counts and flags show none."""
    from flatcli.report.runs import metrics_text

    text = metrics_text("x", {"status": "ok", "err_theta_rms": 0.1, "min_margin": 0.2,
                              "momentum_drift": 1e-15, "first_hit_time": float("nan"),
                              "peak_torque": 2.0, "singular_hits": 0, "verified": True,
                              "ee_error_final": 1e-3})
    rows = {line.split("|")[1].strip(): line.split("|")[3].strip()
            for line in text.splitlines()[3:]}
    assert rows == {"err_theta_rms": "rad", "min_margin": "rad/s", "momentum_drift": "kg m^2/s",
                    "first_hit_time": "s", "peak_torque": "N m", "singular_hits": "",
                    "verified": "", "ee_error_final": "m"}


def test_a_tracks_first_line_says_its_outcome_before_its_status() -> None:
    """A trial integrated to T (status ok) that ended off its goal reads "missed" first, with
    the reason, so "ok" is never the headline of a robot that did not do its job; without an
    outcome (a plan's text) the line is the status alone."""
    from flatcli.report.runs import metrics_text

    missed = {"status": "ok", "outcome": "missed",
              "outcome_reason": "at T th2 off by 0.0119 rad (track.goal_tolerance 0.001 rad)"}
    assert metrics_text("x", missed).splitlines()[0] == (
        "track 'x': missed (at T th2 off by 0.0119 rad (track.goal_tolerance 0.001 rad)); "
        "status ok")
    lost = {"status": "diverged", "reason": "beyond the bound at 0.5 s", "outcome": "lost"}
    assert metrics_text("x", lost).splitlines()[0] == (
        "track 'x': lost; status diverged (beyond the bound at 0.5 s)")
    assert metrics_text("x", {"status": "ok"}).splitlines()[0] == "track 'x': status ok"
