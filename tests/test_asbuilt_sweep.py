"""Both pipelines in one sweep (issue 22, item 3): ``plan.method`` and ``track.controller`` as
grid keys, and the as-built trials' columns meaning what every trial's mean.

Referees: the plan's goal (the spec's, written here) for the final errors; scipy's DOP853 at
rtol 1e-10 (``sweep.verify``, every trial of each cell re-run) for the as-built trials'
integration; the definition of the metrics (docs/outputs.md) for the columns of a law without
a singular set; the trial's own row for ``--rerun``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from small_sweep import sweep, write_spec

import flatcli

SPEC = """
name = "pipelines"
[robot]
com = [0.1, 0.1, 0.003]        # the counterweight as built: 3 mm along link 2
[plant]
com = [0.1, 0.1, 0.003]
[track]
initial = [1.8, 1.0, 0.0]      # the plan's start; errors drawn below
initial_rate = 0.1
dt = 0.002
[sweep]
trials = 4
seed = 22
verify = 4
[sweep.perturb]
initial = { dist = "normal", std = 0.01 }
[[sweep.grid.pipeline]]         # the paper's: it believes d2 = 0 (gains swapped)
label = "ideal"
"robot.com" = [0.1, 0.1, 0.0]
"plan.method" = "flat"
"track.controller" = "flat"
"track.kp" = [100, 110]
"track.kv" = [10, 13]
[[sweep.grid.pipeline]]         # the robot as built
label = "asbuilt"
"plan.method" = "exact"
"track.controller" = "asbuilt"
"""
#: The issue's goal for the as-built pipeline [rad]; the ideal-model pipeline misses the
#: plan's goal by the plan's own miss at d2 = 3 mm (about 0.08 rad), far above it.
GOAL_ERROR = 1e-4
IDEAL_MISS = 1e-2
#: The compiled adaptive loop (track.rtol 5e-8) against DOP853 at rtol 1e-10, along the run.
REFERENCE_TOL = 1e-6


def test_both_pipelines_in_one_sweep_and_the_as_built_columns(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, SPEC)
    out = tmp_path / "s"
    code, text = sweep(str(spec), "--out", str(out), "-q")
    assert code == 0, text
    trials = pd.read_parquet(out / "trials.parquet")
    ideal = trials[trials["pipeline"] == "ideal"]
    asbuilt = trials[trials["pipeline"] == "asbuilt"]
    assert len(ideal) == len(asbuilt) == 4
    assert list(asbuilt["plan.method"].unique()) == ["exact"]
    assert list(asbuilt["track.controller"].unique()) == ["asbuilt"]
    # the goal, from the spec's own plan.goal
    assert (asbuilt["err_theta_final"] <= GOAL_ERROR).all()
    assert (ideal["err_theta_final"] >= IDEAL_MISS).all()
    # a law without a singular set: no crossing, no hit, no margin; twin-estimated, verified
    assert (asbuilt["status"] == "ok").all() and asbuilt["verified"].all()
    assert (asbuilt["crossings"] == 0).all() and (asbuilt["singular_hits"] == 0).all()
    assert asbuilt["first_crossing_time"].isna().all() and asbuilt["min_margin"].isna().all()
    assert asbuilt["err_estimate"].notna().all()
    # DOP853 re-ran every trial: the same status, the same path
    assert (asbuilt["reference_status"] == asbuilt["status"]).all()
    assert (asbuilt["reference_difference"] <= REFERENCE_TOL).all()
    # a trial re-run alone is its row
    trial = str(asbuilt["trial"].iloc[1])
    code, text = sweep(str(spec), "--out", str(out), "--rerun", trial)
    assert code == 0, text
    assert "NO" not in text and "identical" in text


def test_without_an_error_estimate_an_as_built_trial_has_none() -> None:
    result = flatcli.track(overrides={"robot.com": [0.1, 0.1, 0.003],
                                      "track.controller": "asbuilt", "track.dt": 0.002,
                                      "track.error_estimate": "none"}, quiet=True)
    assert result.metrics["err_estimate"] is None
    assert result.metrics["crossings"] == 0 and result.metrics["min_margin"] is None
    assert result.metrics["status"] == "ok" and result.metrics["verified"] is True
