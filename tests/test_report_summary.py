"""A sweep's per-cell statistics (flatcli/report/summary.py)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from flatcli.report.summary import summarize_trials


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
