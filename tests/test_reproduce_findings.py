"""Tests of flatcli.findings: the report's sentences carry the numbers of the runs they
describe (read back here from the runs themselves), and the study's failures by cell."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatcli.core.loop.metrics import Metric
from flatcli.experiment import run_track
from flatcli.report import fmt
from flatcli.reproduce.findings import GAIN_READINGS, gains_verdict, study_findings
from flatcli.spec import resolve


def test_gains_verdict_quotes_the_runs() -> None:
    base = resolve({})
    printed, swapped = (run_track(base.with_overrides(g)) for g in GAIN_READINGS.values())
    text = gains_verdict(printed, swapped)
    for run in (printed, swapped):
        assert fmt(float(run.outcome.metrics[0, Metric.ERR_THETA_MAX]), 3) in text
    theta2 = swapped.columns["theta2"]
    assert f"{np.nanmax(theta2):+.2f}" in text and f"{np.nanmin(theta2):+.2f}" in text
    # the paper's example: th2 swings by several rad although y converges (issue review:
    # +4 to -3.7 rad; err_theta_max 7.9 rad with the swapped gains)
    assert np.nanmax(theta2) > 3.0 and np.nanmin(theta2) < -3.0


def test_study_findings_name_the_cells_that_failed(tmp_path: Path) -> None:
    trials = pd.DataFrame({
        "cell": [0, 0, 1, 1, 1],
        "gains": ["printed", "printed", "swapped", "swapped", "swapped"],
        "status": ["ok", "ok", "ok", "diverged", "unresolved"],
        "steps": [300, 320, 150, 20, 1000],
        "momentum_drift": [1e-17, 2e-17, 3e-17, np.nan, np.nan],
        "err_estimate": [1e-5, 2e-5, 3e-5, np.nan, np.nan],
        "outcome": ["missed", "missed", "reached", "lost", "lost"],
        "err_theta_final": [0.5, 0.4, 1e-4, np.nan, np.nan],
    })
    path = tmp_path / "trials.parquet"
    trials.to_parquet(path)
    summary = pd.DataFrame({
        "cell": [0, 1], "gains": ["printed", "swapped"], "trials": [2, 3],
        "diverged": [0, 1], "unresolved": [0, 1], "singular_fraction": [0.0, 0.0],
        "err_y_final_median": [1e-2, 1e-6], "reached_fraction": [0.0, 1 / 3],
        "err_theta_final_median_all": [0.45, np.inf],
    })
    lines = study_findings(summary, path)
    swapped = next(line for line in lines if line.startswith("- gains swapped"))
    assert "1 of 3 trials resolved" in swapped
    assert "1 diverged and 1 unresolved, in cell 1" in swapped
    # by outcome, over all the trials (scipy's Wilson interval: binomtest(1, 3))
    assert swapped.startswith("- gains swapped: 1 of 3 trials reached (33.3 %, 95 % "
                              "interval 6.15-79.2 %); 0 collided, 0 missed, 2 lost")
    assert "ALL its trials" in swapped and "to inf rad" in swapped
    printed = next(line for line in lines if line.startswith("- gains printed"))
    assert "2 of 2 trials resolved" in printed and "in cell" not in printed
    assert "0 of 2 trials reached" in printed and "2 missed" in printed
