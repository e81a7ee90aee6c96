"""Tables and figures."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from flatcli.core.model import PAPER_ROBOT
from flatcli.core.planning import plan_point_to_point
from flatcli.report import fmt, plan_summary, plot_plan, summarize_trials, table


def test_fmt_is_compact_and_marks_missing_values() -> None:
    assert fmt(0.5) == "0.5"
    assert fmt(1.23456789e-7) == "1.23e-07"
    assert fmt(math.nan) == "-"
    assert fmt(math.inf) == "inf"
    assert fmt(3) == "3"
    assert fmt(True) == "true"
    assert fmt("x") == "x"


def test_table_aligns_numbers_right_and_text_left() -> None:
    text = table(["name", "value"], [["a", 1.5], ["long name", 100.0]])
    lines = text.splitlines()
    assert lines[0] == "| name      | value |"
    assert lines[1] == "|-----------|------:|"
    assert lines[3] == "| long name |   100 |"
    assert len({len(line) for line in lines}) == 1


def test_plan_summary_and_figure(tmp_path: Path) -> None:
    plan = plan_point_to_point(PAPER_ROBOT, np.array([1.8, 1, 0]), np.array([1.2, 2, 0]), 0.1,
                               0.5, 2.0)
    samples = plan.sample(plan.grid(201))
    summary = plan_summary(plan, samples)
    # th2 reaches 3.93 rad; initial rates (-13.25, 0.1, 48.8) rad/s: the cubic of Sec. VI
    # with the correct b1 (tests/test_planning.py::test_derived_plan_matches_physics_note)
    assert round(summary["max_abs_theta2"], 2) == 3.93
    assert round(summary["peak_rate2"], 1) == 48.8
    # the paper's cubic costs an input energy of about 101 (tests/test_optimize.py,
    # CUBIC_ENERGY = 101.19)
    assert 100 < summary["input_energy"] < 102
    plot_plan(samples, tmp_path / "p.png", "t")
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


def test_summary_counts_and_statistics_on_a_handmade_frame() -> None:
    frame = pd.DataFrame({
        "cell": [0, 0, 0, 0, 1],
        "status": ["ok", "singular", "diverged", "error", "ok"],
        "singular_hits": [0, 3, 1, -1, 0],
        **{m: [1.0, 3.0, 100.0, np.nan, 2.0] for m in (
            "err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final", "min_margin",
            "momentum_drift", "plan_momentum_residual")},
    })
    summary = summarize_trials(frame, {0: {"g": "a"}, 1: {"g": "b"}})
    row = summary.iloc[0]
    assert (row["ok"], row["singular"], row["diverged"], row["error"]) == (1, 1, 1, 1)
    assert row["err_y_rms_median"] == 2.0  # ok and singular only: median(1, 3)
    assert row["err_y_rms_max"] == 3.0
    assert row["singular_fraction"] == 2 / 3  # of the three simulated trials
    assert row["min_margin_median"] == 3.0  # median(1, 3, 100)
    assert summary.iloc[1]["g"] == "b"
