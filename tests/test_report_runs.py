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
