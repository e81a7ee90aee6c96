"""Terminal summaries of plans and runs (flatcli/report/runs.py)."""

from __future__ import annotations

import numpy as np

from flatcli.core.model import PAPER_ROBOT
from flatcli.core.planning import plan_point_to_point
from flatcli.report.runs import plan_summary


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
