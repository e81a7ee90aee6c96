"""Tables of plan and track runs (flatcli/outputs.py), built once for every command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from flatcli.core.robots.dynamics import make_chain
from flatcli.experiment import plan_from, run_track
from flatcli.outputs import plan_frame, track_frame, write_track
from flatcli.spec import resolve
from flatcli.storage import column_units, write_parquet
from tests.referees import base_row_momentum

#: The columns the README's *Output files* lists for plan.parquet and track.parquet.
PLAN_COLUMNS = ["t", "theta0", "theta1", "theta2", "theta0_dot", "theta1_dot", "theta2_dot",
                "u1_dot", "u2", "y1", "y2", "y1_dot", "y2_dot", "y1_ddot", "y2_ddot", "margin",
                "momentum"]
TRACK_COLUMNS = ["t", "theta0", "theta1", "theta2", "theta0_dot", "theta1_dot", "theta2_dot",
                 "theta0_ref", "theta1_ref", "theta2_ref", "u1", "u2", "y1", "y2", "y1_ref",
                 "y2_ref", "margin", "momentum", "tau1", "tau2", "ee_x", "ee_y", "base_x",
                 "base_y"]


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


def _float_columns(path: Path) -> list[str]:
    return [f.name for f in pq.read_schema(path) if pa.types.is_floating(f.type)]


def test_plan_and_track_tables_carry_a_unit_on_every_column(tmp_path: Path) -> None:
    plan = plan_from(resolve({}))
    write_parquet(tmp_path / "plan.parquet", plan_frame(plan.sample(plan.grid(11))), {})
    run = run_track(resolve({"track": {"dt": 0.01}}))
    write_track(tmp_path, run, {"command": "test"})
    for name, columns in (("plan.parquet", PLAN_COLUMNS), ("track.parquet", TRACK_COLUMNS)):
        units = column_units(tmp_path / name)
        assert _float_columns(tmp_path / name) == columns  # every column is a number
        assert set(units) == set(columns), name
    units = column_units(tmp_path / "track.parquet")
    assert units["t"] == "s" and units["theta1"] == "rad" and units["u1"] == "rad/s"
    assert column_units(tmp_path / "plan.parquet")["u1_dot"] == "rad/s^2"
    assert units["momentum"] == "kg m^2/s"


def test_a_trial_that_stopped_early_writes_null_not_nan(tmp_path: Path) -> None:
    # u1(0) of the wrong sign: the loop must cross u1 = 0, the singular set, and stops there
    run = run_track(resolve({"track": {"dt": 0.01, "initial_rate": -0.05}}))
    assert run.metrics["status"] == "diverged"
    write_track(tmp_path, run, {"command": "test"})
    text = (tmp_path / "metrics.json").read_text()
    metrics = json.loads(text)
    assert metrics["err_theta_final"] is None and metrics["err_y_final"] is None
    assert metrics["peak_torque"] is None  # the kinematic plant has no torques
    assert 0 < metrics["event_time"] < 2.0
    assert '"nan"' not in text and '"inf"' not in text
    table = pq.read_table(tmp_path / "track.parquet")
    after = pc.greater(table.column("t"), metrics["event_time"] + 0.01)
    assert pc.any(after).as_py()  # rows after the stop exist, with no state
    for name in _float_columns(tmp_path / "track.parquet"):
        assert not pc.any(pc.is_nan(table.column(name))).as_py(), name
    assert pc.filter(table.column("theta1"), after).null_count == pc.sum(after).as_py()


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


#: A robot of three joints (base + 3 links, d3 = 0) and a maneuver for it.
THREE_JOINTS = {
    "robot": {"mass": [2.0, 1.0, 1.0, 0.6], "inertia": [0.08, 0.03, 0.03, 0.2],
              "length": [0.3, 0.25, 0.25, 0.25], "com": [0.12, 0.1, 0.1, 0.0]},
    "plan": {"start": [0.0, 1.0, 0.3, 0.0], "goal": [0.4, 2.0, 0.6, 0.0], "start_rate": 0.3,
             "goal_rate": 0.5},
    "track": {"initial": [0.05, 0.95, 0.32, 0.02], "kp": [100.0] * 3, "kv": [20.0] * 3,
              "dt": 0.01},
}


def test_a_robot_of_three_joints_has_a_column_per_link_and_output(tmp_path: Path) -> None:
    spec = resolve(THREE_JOINTS)
    plan = plan_from(spec)
    samples = plan.sample(plan.grid(11))
    frame = plan_frame(samples)
    assert list(frame.columns) == [
        "t", "theta0", "theta1", "theta2", "theta3", "theta0_dot", "theta1_dot", "theta2_dot",
        "theta3_dot", "u1_dot", "u2_dot", "u3", "y1", "y2", "y3", "y1_dot", "y2_dot", "y3_dot",
        "y1_ddot", "y2_ddot", "y3_ddot", "margin", "momentum"]
    assert frame["u3"].tolist() == frame["theta3_dot"].tolist()  # the last joint's input
    run = run_track(spec)
    assert run.metrics["status"] == "ok"
    write_track(tmp_path, run, {"command": "test"})
    track = pd.read_parquet(tmp_path / "track.parquet")
    assert list(track.columns) == [
        "t", "theta0", "theta1", "theta2", "theta3", "theta0_dot", "theta1_dot", "theta2_dot",
        "theta3_dot", "theta0_ref", "theta1_ref", "theta2_ref", "theta3_ref", "u1", "u2", "u3",
        "y1", "y2", "y3", "y1_ref", "y2_ref", "y3_ref", "margin", "momentum", "tau1", "tau2",
        "tau3", "ee_x", "ee_y", "base_x", "base_y"]
    units = column_units(tmp_path / "track.parquet")
    assert set(units) == set(track.columns)
    assert units["theta3"] == "rad" and units["u2"] == "rad/s" and units["tau3"] == "N m"
    # H of the plant by another route: the mass matrix of the Lagrangian dynamics,
    # H = (M(q) q')_0 (flatcli/core/robots/dynamics.py), not the link kinematics the table used
    chain = make_chain(*(THREE_JOINTS["robot"][k] for k in ("mass", "inertia", "length", "com")))
    theta = track[[f"theta{i}" for i in range(4)]].to_numpy()
    rates = track[[f"theta{i}_dot" for i in range(4)]].to_numpy()
    np.testing.assert_allclose(track["momentum"], base_row_momentum(chain, theta, rates),
                               rtol=0, atol=1e-12)
    # y = (th1, th2, th0 + I3 th3 / h0(q)) of the true state: the first two are the angles,
    # and the flat outputs converge to the plan's (err_y_final)
    assert track["y1"].tolist() == track["theta1"].tolist()
    assert track["y2"].tolist() == track["theta2"].tolist()
    last = track.iloc[-1]
    error = np.sqrt(sum((last[f"y{j}"] - last[f"y{j}_ref"]) ** 2 for j in (1, 2, 3)))
    assert error == pytest.approx(run.metrics["err_y_final"], rel=1e-9)
    assert error < 1e-6


def test_a_plan_table_of_many_joints_is_built_without_warnings() -> None:
    # 40 joints: 245 columns; inserted one by one, pandas warned about fragmentation 100s of
    # times (printed by `flatcli plan -q`)
    import warnings

    from flatcli.core.plan.planning import PlanSamples

    n, points = 40, 5
    rng = np.random.default_rng(1)
    samples = PlanSamples(
        t=np.linspace(0, 1, points), theta=rng.random((points, n + 1)),
        theta_dot=rng.random((points, n + 1)), u_dot=rng.random((points, n - 1)),
        y=rng.random((points, n)), y_dot=rng.random((points, n)),
        y_ddot=rng.random((points, n)), margin=rng.random(points), momentum=rng.random(points))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frame = plan_frame(samples)
    assert frame.shape == (points, 6 * n + 5)
    assert list(frame.columns[:3]) == ["t", "theta0", "theta1"]
    np.testing.assert_array_equal(frame[f"y{n}_ddot"], samples.y_ddot[:, n - 1])
    np.testing.assert_array_equal(frame[f"u{n}"], samples.theta_dot[:, n])
    np.testing.assert_array_equal(frame["u1_dot"], samples.u_dot[:, 0])
