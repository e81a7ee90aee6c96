"""Tables of plan and track runs (flatcli/outputs.py), built once for every command."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from flatcli.experiment import plan_from, run_track
from flatcli.outputs import plan_frame, track_frame, write_track
from flatcli.spec import resolve

#: The columns the README's *Output files* lists for plan.parquet and track.parquet.
PLAN_COLUMNS = ["t", "theta0", "theta1", "theta2", "theta0_dot", "theta1_dot", "theta2_dot",
                "u1_dot", "u2", "y1", "y2", "y1_dot", "y2_dot", "y1_ddot", "y2_ddot", "margin",
                "momentum"]
TRACK_COLUMNS = ["t", "theta0", "theta1", "theta2", "theta0_dot", "theta1_dot", "theta2_dot",
                 "theta0_ref", "theta1_ref", "theta2_ref", "u1", "u2", "y1", "y2", "y1_ref",
                 "y2_ref", "margin", "momentum", "tau1", "tau2"]


def test_plan_frame_columns_and_values() -> None:
    plan = plan_from(resolve({}))
    samples = plan.sample(plan.grid(11))
    frame = plan_frame(samples)
    assert list(frame.columns) == PLAN_COLUMNS
    assert frame["theta2_dot"].tolist() == samples.theta_dot[:, 2].tolist()
    assert frame["y2_ddot"].tolist() == samples.y_ddot[:, 1].tolist()


def test_track_files(tmp_path: Path) -> None:
    run = run_track(resolve({"track": {"dt": 0.01}}))
    assert list(track_frame(run).columns) == TRACK_COLUMNS
    names = write_track(tmp_path, run, {"command": "test"})
    assert names == ["track.parquet", "metrics.json"]
    assert not (tmp_path / "track.png").exists()
    assert len(pd.read_parquet(tmp_path / "track.parquet")) == 201
    assert frame_is_kinematic(pd.read_parquet(tmp_path / "track.parquet"))


def frame_is_kinematic(frame: pd.DataFrame) -> bool:
    """The kinematic plant: no torques, and joint 2 turns at its command."""
    return bool(frame["tau1"].isna().all() and frame["tau2"].isna().all()
                and (frame["u2"] == frame["theta2_dot"]).all())


def test_dynamic_track_table(tmp_path: Path) -> None:
    """The dynamic plant's rates, torques and command, named as for the kinematic plant."""
    run = run_track(resolve({"track": {"dt": 0.01}, "plant": {"model": "dynamic"}}))
    frame = track_frame(run)
    assert list(frame.columns) == TRACK_COLUMNS
    trace = run.outcome.trace
    assert trace is not None
    named = dict(zip(run.outcome.columns, trace[0].T, strict=True))
    for name in ("theta1_dot", "theta2_dot", "u1", "u2", "tau1", "tau2"):
        assert frame[name].tolist() == named[name].tolist()
    assert not frame_is_kinematic(frame)
    assert run.metrics["peak_torque"] == max(frame["tau1"].abs().max(),
                                             frame["tau2"].abs().max())
