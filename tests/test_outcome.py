"""Outcomes (flatcli/core/outcome.py): reached, collided, missed, lost; the closed-loop
clearance; the final angles the kernels return.

Referees, none of them the code under test:

* the tolerance rule recomputed from a trial's own columns (``status``, ``err_theta{i}_final``,
  ``ee_error_final``) and from the final angles of a re-integration by scipy's DOP853
  (rtol 1e-10): of ``referees.ClippedLoop`` on the paper's kinematic plant (its laws are
  sympy's, from the full link kinematics; nothing of flatcli's kernels), of flatcli's compiled
  right-hand side (``closed_loop_rhs``) on the other plants, so the integration is scipy's;
  the end effector from the complex-plane link geometry (``task_referees``);
* the clearance from the complex-plane link geometry (``task_referees.link_clearance``) on a
  grid 100x finer than the output, of a DOP853 re-integration's dense output.

Both sides of every rule: reached and missed with and without rate limits, fixed (rk4) and
controlled step (adaptive), kinematic and dynamic plant, the paper's robot, an N = 3 chain
and a robot as built; collided and clear.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import task_referees as ref
from numpy.typing import NDArray
from referees import ClippedLoop
from scipy.integrate import solve_ivp

import flatcli
from flatcli.core.loop.outcome import Geometry, Goal, joint_points, judge, motion_clearance
from flatcli.core.loop.simulate import closed_loop_rhs, closed_loop_start, simulate
from flatcli.experiment import nominal_trials

Array = NDArray[np.float64]

#: The paper's maneuver with the gains swapped (the reading that tracks) from 2 mrad off.
SWAPPED = {"track.kp": [100, 110], "track.kv": [10, 13], "track.initial": [1.802, 1.002, 0.002]}
#: The referee's tolerances, and how far its final angles may be from flatcli's [rad] (the
#: adaptive integrator's default tolerances leave ~1e-6 rad; rk4 at dt = 1 ms about 1e-5).
REFEREE = {"rtol": 1e-10, "atol": 1e-12}
AGREE = 1e-4
#: A trial is judged by both only where its error is this far from the tolerance [rad].
MARGIN = 1e-4
#: The as-built robot: the counterweight 3 mm along link 2 (docs/asbuilt.md), tracked by the
#: as-built law from Fig. 4's neighbourhood.
AS_BUILT = {"robot.com": [0.1, 0.1, 0.003], "track.controller": "asbuilt",
            "track.initial": [1.82, 0.99, 0.01]}


def rule(metrics: dict[str, Any], joints: int, tolerance: float,
         target_tolerance: float | None = None) -> str:
    """The outcome recomputed from a track run's own columns (no obstacles): docs/outputs.md,
    *Outcomes*."""
    if metrics["status"] not in ("ok", "singular"):
        return "lost"
    errors = [metrics[f"err_theta{i}_final"] for i in range(joints + 1)]
    near = all(abs(e) <= tolerance for e in errors)
    if target_tolerance is not None:
        near = near and metrics["ee_error_final"] <= target_tolerance
    return "reached" if near else "missed"


CASES = {
    # name: (spec, overrides, the outcome the case is chosen for)
    "paper kinematic": (None, SWAPPED, "reached"),
    "paper kinematic, 4 rad/s": (None, {**SWAPPED, "track.rate_limit": 4.0}, "missed"),
    "paper kinematic rk4": (None, {**SWAPPED, "track.integrator": "rk4"}, "reached"),
    "paper kinematic rk4, 4 rad/s": (None, {**SWAPPED, "track.integrator": "rk4",
                                            "track.rate_limit": 4.0}, "missed"),
    "paper dynamic, servo 1000 rad/s": (None, {**SWAPPED, "plant.model": "dynamic",
                                               "plant.servo_bandwidth": 1000.0,
                                               "plant.servo_model": "plant"}, "reached"),
    "paper dynamic, servo 100 rad/s": (None, {**SWAPPED, "plant.model": "dynamic"}, "missed"),
    "chain4 kinematic": ({"robot": "chain4"}, {}, "reached"),
    "chain4 kinematic, 0.5 rad/s": ({"robot": "chain4"}, {"track.rate_limit": 0.5}, "missed"),
    "as built": (None, AS_BUILT, "reached"),
    "as built, 1 rad/s": (None, {**AS_BUILT, "track.rate_limit": 1.0}, "missed"),
}


def redo(run: Any) -> Array:
    """The run's final angles (N + 1,) by scipy's DOP853 (``REFEREE``): on the paper's
    kinematic plant of ``referees.ClippedLoop`` (sympy's laws), else on flatcli's compiled
    right-hand side."""
    spec, plan, scenario = run.spec, run.plan, run.scenario
    trials = nominal_trials(spec, plan)
    angles = spec.joints + 1
    if spec.joints == 2 and spec.plant.model == "kinematic" and spec.track.controller == "flat":
        loop = ClippedLoop(plan.robot, plan, tuple(spec.track.kp), tuple(spec.track.kv),
                           spec.plant.momentum, spec.track.rate_limit)
        rhs = loop.rhs
    else:
        compiled = closed_loop_rhs(scenario, trials)

        def rhs(t: float, x: Array) -> Array:
            return compiled(t, x)

    start = closed_loop_start(scenario, trials)
    with np.errstate(all="ignore"):
        sol = solve_ivp(rhs, (0.0, plan.duration), start, method="DOP853", **REFEREE)
    assert sol.status == 0, sol.message
    return np.asarray(sol.y[:angles, -1], dtype=float)


@pytest.mark.parametrize("name", list(CASES))
def test_outcome_is_the_tolerance_rule_of_its_own_columns_and_of_an_independent_dop853(
        name: str) -> None:
    spec, overrides, expected = CASES[name]
    result = flatcli.track(spec, overrides=overrides, quiet=True)
    m = result.metrics
    s = result.spec
    tolerance = s.track.goal_tolerance
    assert m["outcome"] == expected, m["outcome_reason"]
    assert rule(m, s.joints, tolerance) == expected  # referee 1: the trial's own columns
    goal = result.run.plan.sample(np.array([s.plan.duration])).theta[-1]
    final = redo(result.run)  # referee 2: scipy's DOP853
    ours = np.array([m[f"err_theta{i}_final"] for i in range(s.joints + 1)])
    np.testing.assert_allclose(ours, final - goal, atol=AGREE, err_msg=name)
    off = np.abs(final - goal)
    assert np.all(np.abs(off - tolerance) > MARGIN), "a case too near the tolerance to judge"
    assert ("reached" if np.all(off <= tolerance) else "missed") == expected
    # the reason names what missed, by how much
    if expected == "missed":
        worst = int(np.argmax(off))
        assert f"th{worst} off by" in m["outcome_reason"]


def test_the_batch_returns_each_trials_final_angles_as_its_trace_ends() -> None:
    """``kernels.make_batch``'s final angles are the last trace row of a trial that reached
    T and nan for one that stopped, and the same whether trials run together or alone (both
    integrators)."""
    base = flatcli.track(overrides=SWAPPED, quiet=True).run
    scenario = base.scenario
    initial = np.array([[1.802, 1.002, 0.002, 0.1], [1.8, 1.0, 0.0, -0.1],  # stops there
                        [1.79, 1.01, -0.01, 0.1]])
    from conftest import make_trials

    trials = make_trials(initial)
    for integrator in ("adaptive", "rk4"):
        together = simulate(scenario, trials, integrator, record=True)
        assert together.final is not None and together.trace is not None
        for i in range(3):
            alone = simulate(scenario, trials.subset(slice(i, i + 1)), integrator)
            assert alone.final is not None
            np.testing.assert_array_equal(alone.final[0], together.final[i])
        stopped = together.status != 0
        assert stopped[1] and not stopped[0] and not stopped[2]
        assert np.isnan(together.final[1]).all()
        np.testing.assert_array_equal(together.final[[0, 2]], together.trace[[0, 2], -1, :3])


def test_a_summary_counts_outcomes_as_the_parquet_rows_do(tmp_path: Any) -> None:
    """The rate-limited study of the issue (the paper's maneuver, swapped gains, 2 mrad
    initial errors, 4 rad/s) beside the unlimited one, adaptive and rk4: every trial whose
    final error exceeds the tolerance is not reached, and each cell's reached fraction, its
    Wilson interval (scipy's binomtest) and its median over all trials are what counting the
    rows of trials.parquet gives."""
    import pandas as pd
    from scipy.stats import binomtest

    spec = {"name": "outcomes",
            "track": {"initial": [1.8, 1.0, 0.0], "kp": [100, 110], "kv": [10, 13]},
            "sweep": {"trials": 12, "seed": 5,
                      "perturb": {"initial": {"dist": "normal", "std": 0.002}},
                      "grid": {"track.rate_limit": [4.0, math.inf],
                               "track.integrator": ["adaptive", "rk4"]}}}
    flatcli.sweep(spec, tmp_path / "sweep", workers=1, quiet=True)
    trials = pd.read_parquet(tmp_path / "sweep" / "trials.parquet")
    summary = pd.read_parquet(tmp_path / "sweep" / "summary.parquet")
    errors = trials[[f"err_theta{i}_final" for i in range(3)]].abs().to_numpy()
    tolerance = 1e-3
    beyond = ~(errors <= tolerance).all(axis=1)
    resolved = trials["status"].isin(["ok", "singular"]).to_numpy()
    recomputed = np.where(~resolved, "lost", np.where(beyond, "missed", "reached"))
    np.testing.assert_array_equal(trials["outcome"].to_numpy(), recomputed)
    assert not (trials["outcome"].to_numpy()[trials["err_theta_final"].to_numpy() > tolerance]
                == "reached").any()
    limited = trials["track.rate_limit"].to_numpy() == 4.0
    assert (trials["outcome"][limited] == "missed").all()  # both sides: 4 rad/s misses,
    assert (trials["outcome"][~limited] == "reached").mean() > 0.9  # unlimited reaches
    assert list(summary.columns[summary.columns.get_loc("trials") + 1:][:4]) == [
        "reached", "collided", "missed", "lost"]
    for _, row in summary.iterrows():
        rows = trials[trials["cell"] == row["cell"]]
        k, n = int((rows["outcome"] == "reached").sum()), len(rows)
        assert row["reached"] == k and row["reached_fraction"] == k / n
        ci = binomtest(k, n).proportion_ci(method="wilson")
        assert row["reached_fraction_low"] == pytest.approx(ci.low, abs=1e-12)
        assert row["reached_fraction_high"] == pytest.approx(ci.high, abs=1e-12)
        finals = rows["err_theta_final"].to_numpy(dtype=float, na_value=np.nan)
        assert row["err_theta_final_median_all"] == np.median(np.where(np.isnan(finals),
                                                                       np.inf, finals))


def fine_motion(run: Any, factor: int = 100) -> tuple[Array, Array]:
    """A track run re-integrated by scipy's DOP853 (``REFEREE``) on flatcli's compiled right-
    hand side, its dense output sampled ``factor`` times finer than the output grid: times
    (m,) [s] and angles (m, N + 1) [rad] (up to a stop)."""
    spec, plan, scenario = run.spec, run.plan, run.scenario
    trials = nominal_trials(spec, plan)
    compiled = closed_loop_rhs(scenario, trials)
    start = closed_loop_start(scenario, trials)
    t = np.linspace(0.0, plan.duration, factor * scenario.n_steps + 1)
    with np.errstate(all="ignore"):
        sol = solve_ivp(lambda s, x: compiled(s, x), (0.0, plan.duration), start,
                        method="DOP853", t_eval=t, **REFEREE)
    return sol.t, sol.y[: spec.joints + 1].T


#: A task of the paper's robot without rest, tracked on the compiled kernels: the capture
#: point of flatcli/data/capture.toml, its three discs, end rates of the plan's choosing.
CAPTURE = {"plan.start": [1.8, 1.0, 0.0], "task.end_effector": [-0.25, 0.05],
           "task.base_attitude": 1.0,
           "task.obstacles": [[0.2, 0.2, 0.05], [-0.25, -0.25, 0.04], [0.0, 0.3, 0.03]],
           "task.clearance": 0.01, "track.initial": [1.8, 1.0, 0.0], "track.kp": [100, 110],
           "track.kv": [10, 13], "track.dt": 0.01}


@pytest.mark.parametrize(("push", "collides"), [
    ({}, False),
    ({"plant.momentum": 0.03}, True),  # a momentum the controller does not know: pushed in
    ({"plant.model": "dynamic", "plant.momentum": 0.03}, True),
    ({"plant.model": "dynamic"}, False),
])
def test_collided_is_the_complex_plane_clearance_sampled_100x_finer(
        push: dict[str, Any], collides: bool) -> None:
    result = flatcli.track(overrides={**CAPTURE, **push}, quiet=True)
    m = result.metrics
    robot = result.run.plan.robot
    obstacles = np.asarray(CAPTURE["task.obstacles"], dtype=float)
    _, theta = fine_motion(result.run)
    fine = ref.link_clearance(robot, theta, obstacles)  # the referee, 100x finer
    assert (m["outcome"] == "collided") == collides, m["outcome_reason"]
    assert (float(np.min(fine)) < 0) == collides
    # the bound is a lower bound of the finer grid's minimum (within the two integrations'
    # difference), the samples' minimum one of its values
    assert m["clearance_bound"] <= float(np.min(fine)) + 1e-6
    assert m["min_clearance"] >= float(np.min(fine)) - 1e-6
    if not collides:
        assert m["outcome"] in ("reached", "missed") and m["clearance_bound"] > 0


def test_the_rest_loops_capture_pushed_into_a_disc_collides() -> None:
    """make_reproduce's capture maneuver (rest to rest, the flat law faded at the ends,
    controllers/rest.py) from the plan's start is clear; started 0.1 rad off in th0 it swings
    link 2 into a disc: collided, as the referee finds on a grid 100x finer (the rest law
    integrated by DOP853, tests/rest_referee.py, at dt / 100)."""
    from rest_referee import track_rest

    from flatcli.core.controllers.control import Gains

    for initial, collides in (([1.8, 1.0, 0.0], False), ([1.9, 1.0, 0.0], True)):
        result = flatcli.track("flatcli/data/capture.toml",
                               overrides={"track.initial": initial}, quiet=True)
        s, m = result.spec, result.metrics
        plan = result.run.plan
        fine_t = np.linspace(0.0, plan.duration, 100 * result.run.scenario.n_steps + 1)
        trace = track_rest(plan, Gains(s.track.kp, s.track.kv), plan.robot,
                           np.asarray(initial), fine_t, s.task.fade)
        fine = ref.link_clearance(plan.robot, trace.theta, np.asarray(s.task.obstacles))
        assert (m["outcome"] == "collided") == collides, m["outcome_reason"]
        assert (float(np.min(fine)) < 0) == collides
        assert m["clearance_bound"] <= float(np.min(fine)) + 1e-9
        if collides:
            assert "inside obstacle" in m["outcome_reason"]


def test_the_motion_clearance_of_a_chain_and_of_a_robot_as_built() -> None:
    """N = 3 (chain4) and a last link's centre of mass across it: the joints agree with the
    complex-plane geometry, and the closed-loop bound is below the referee's clearance on a
    grid 100x finer, for a disc the motion passes through and one it clears."""
    run = flatcli.track({"robot": "chain4"}, overrides={"track.dt": 0.01}, quiet=True).run
    robot = run.plan.robot
    _, theta = fine_motion(run)
    ee = ref.end_effector(robot, theta)
    middle = ee[len(ee) // 2]
    inside = [middle.real, middle.imag, 0.01]  # on the end effector's path: entered
    far = [1.0, 1.0, 0.05]
    trace = run.outcome.trace[0]
    columns = run.outcome.columns
    angles = [columns.index(f"theta{i}") for i in range(4)]
    rates = [columns.index(f"theta{i}_dot") for i in range(4)]
    geometry = Geometry.of(robot.as_array()[None, :])
    for disc, entered in ((inside, True), (far, False)):
        found = motion_clearance(geometry, [disc], trace[None, :, angles], trace[None, :, rates],
                                 run.scenario.dt)
        fine = ref.link_clearance(robot, theta, np.array([disc]))
        assert (float(np.min(fine)) < 0) == entered
        assert found.bound[0] <= float(np.min(fine)) + 1e-6
        assert (found.bound[0] < 0) == entered
    across = flatcli.experiment.plant_from(flatcli.load_spec(
        overrides={"plant.com_across": 0.004, "plant.com": [0.1, 0.1, 0.002]}))
    q = np.random.default_rng(3).uniform(-3, 3, (7, 3))
    points = joint_points(Geometry.of(across.as_array()[None, :], [across.com_across]),
                          q[None])[0]
    z = ref.joints(across, q)
    np.testing.assert_allclose(points[..., 0] + 1j * points[..., 1], z, atol=1e-15)


def test_judge_both_sides_of_each_outcome_by_hand() -> None:
    """The rule on made-up trials (docs/outputs.md): within tolerance or not, a target met or
    not, a sample inside a disc, a bound below zero for a resolved and a lost trial."""
    from flatcli.core.loop.outcome import MotionClearance

    goal = Goal(np.zeros(3), 1e-3)
    final = np.array([[5e-4, -9e-4, 0.0], [0.0, 2e-3, 0.0], [np.nan] * 3, [0.0] * 3,
                      [0.0] * 3, [np.nan] * 3, [np.nan] * 3])
    status = ["ok", "singular", "diverged", "ok", "ok", "diverged", "error"]
    nan, zero = np.full(7, np.nan), np.zeros(7, dtype=np.int64)
    sampled = np.array([1.0, 1.0, 1.0, -0.002, 0.001, 0.5, np.nan])
    bound = np.array([0.5, 0.5, -0.3, -0.01, -0.001, -0.2, np.nan])
    clearance = MotionClearance(sampled, np.full(7, 0.5), zero, zero, bound,
                                np.zeros((7, 2)), zero, zero)
    del nan
    judged = judge(status, [""] * 7, final, goal, None, clearance)
    assert judged.outcome == ["reached", "missed", "lost", "collided", "collided", "lost",
                              "lost"]
    assert "th1 off by 0.002 rad" in judged.reason[1]
    assert "inside obstacle" in judged.reason[3] and "not shown clear" in judged.reason[4]
    with_target = Goal(np.zeros(3), 1e-3, np.array([0.3, 0.0]), 1e-3)
    robot = flatcli.experiment.robot_from(flatcli.load_spec())
    geometry = Geometry.of(np.tile(robot.as_array(), (2, 1)))
    near = ref.end_effector(robot, np.zeros(3))
    judged = judge(["ok", "ok"], ["", ""], np.zeros((2, 3)),
                   Goal(np.zeros(3), 1e-3, np.array([[near.real, near.imag],
                                                     [near.real + 0.01, near.imag]]), 1e-3),
                   geometry)
    assert judged.outcome == ["reached", "missed"]
    assert judged.target_error[1] == pytest.approx(0.01, abs=1e-12)
    assert with_target.target is not None


def test_peaks_and_clipped_time_of_every_loop_are_its_traces() -> None:
    """peak_rate, peak_torque and clipped_time of the paper's, a chain's and the as-built
    loops, kinematic and dynamic, and of the rest law, recomputed from track.parquet: the
    largest abs(th_j') and abs(tau_j), and the trapezoidal integral (numpy's) of "a rate
    command at or beyond track.rate_limit", with a limit (> 0) and without (0)."""
    setups = {"paper": (None, SWAPPED), "chain4": ({"robot": "chain4"}, {}),
              "as built": (None, AS_BUILT),
              "rest": ("flatcli/data/capture.toml", {"track.initial": [1.82, 0.99, 0.01]})}
    for name, (spec, overrides) in setups.items():
        for model in ("kinematic", "dynamic"):
            if name == "rest" and model == "dynamic":
                with pytest.raises(flatcli.FlatcliError, match=r"plant\.model"):
                    flatcli.track(spec, overrides={**overrides, "plant.model": model})
                continue
            for limit in (math.inf, 0.5):
                result = flatcli.track(spec, overrides={**overrides, "plant.model": model,
                                                        "track.rate_limit": limit}, quiet=True)
                m, frame, s = result.metrics, result.frame, result.spec
                n = s.joints
                rates = np.abs(frame[[f"theta{j}_dot" for j in range(1, n + 1)]].to_numpy())
                valid = np.isfinite(rates).all(axis=1)
                assert m["peak_rate"] == pytest.approx(rates[valid].max(), rel=1e-12)
                torques = frame[[f"tau{j}" for j in range(1, n + 1)]].to_numpy()
                if model == "dynamic":
                    assert m["peak_torque"] == pytest.approx(np.abs(torques[valid]).max(),
                                                             rel=1e-12)
                    commands = np.abs(frame[[f"u{j}" for j in range(1, n + 1)]].to_numpy())
                else:
                    assert m["peak_torque"] is None
                    commands = rates
                clipped = (commands[valid] >= limit).any(axis=1).astype(float)
                assert m["clipped_time"] == pytest.approx(
                    float(np.trapezoid(clipped, dx=s.track.dt)), abs=1e-12), (name, model)
                assert (m["clipped_time"] > 0) == math.isfinite(limit), (name, model, limit)


def test_an_exact_plans_y_columns_are_its_joint_paths_and_their_derivatives() -> None:
    """plan.parquet of an exact plan (plan.method = "exact", d2 = 3 mm): y_j = th_j, and its
    derivative columns match central finite differences of the plan's own theta columns."""
    p = flatcli.plan(overrides={"robot.com": [0.1, 0.1, 0.003], "plan.method": "exact",
                                "plan.samples": 2001})
    f = p.frame
    t = f["t"].to_numpy()
    h = t[1] - t[0]
    for j in (1, 2):
        th = f[f"theta{j}"].to_numpy()
        np.testing.assert_array_equal(f[f"y{j}"].to_numpy(), th)
        rate = np.gradient(th, h, edge_order=2)
        np.testing.assert_allclose(f[f"y{j}_dot"].to_numpy()[1:-1], rate[1:-1], atol=1e-5)
        np.testing.assert_allclose(f[f"theta{j}_dot"].to_numpy(), f[f"y{j}_dot"].to_numpy(),
                                   atol=1e-12)
        accel = np.gradient(f[f"theta{j}_dot"].to_numpy(), h, edge_order=2)
        np.testing.assert_allclose(f[f"y{j}_ddot"].to_numpy()[1:-1], accel[1:-1], atol=1e-3)
    # at t = 0 of the example y1' is th1'(0) = 0.1, not th0(0) = 1.8
    assert f["y1_dot"].iloc[0] == pytest.approx(0.1, abs=1e-9)
    assert "th1 [rad]" in p.text()  # the boundary table names the joint paths


def test_a_task_plan_keeps_its_joints_below_the_rate_warning_when_a_candidate_does() -> None:
    """A task without rest and without obstacles: the first candidate's th2' reaches
    187 rad/s; with plan.rate_warning = 50 rad/s the planner picks end rates that stay below
    (on the plan's own grid), and says nothing; without a warning it keeps the first, and
    with a warning below every candidate's peak it keeps the slowest and warns."""
    from flatcli.core.plan.planning import fastest_joint

    task = {k: v for k, v in CAPTURE.items() if k != "task.obstacles"}
    free = flatcli.plan(overrides={**task, "plan.rate_warning": math.inf})
    assert fastest_joint(free.samples)[1] > 150 and free.warnings == []
    kept = flatcli.plan(overrides=task)
    assert fastest_joint(kept.samples)[1] <= 50 and kept.warnings == []
    assert kept.metrics["task_candidates"] > 1
    strict = flatcli.plan(overrides={**task, "plan.rate_warning": 1.0})
    joint, peak, when = fastest_joint(strict.samples)
    assert peak > 1.0 and len(strict.warnings) == 1
    assert f"th{joint}'" in strict.warnings[0] and f"{peak:.4g} rad/s" in strict.warnings[0]
    assert f"t = {when:.4g} s" in strict.warnings[0]


def test_cli_prints_the_rate_warning_and_runs_lists_the_outcome(tmp_path: Any) -> None:
    from click.testing import CliRunner

    from flatcli.cli import main

    runner = CliRunner()
    out = runner.invoke(main, ["track", "--out", str(tmp_path / "fast"), "--set",
                               "plan.rate_warning=1", "--set", "track.kp=[100,110]", "--set",
                               "track.kv=[10,13]", "--set", "track.rate_limit=4"])
    assert out.exit_code == 0, out.output
    assert "warning: the plan's th2' reaches" in out.output
    assert "missed" in out.output
    listed = runner.invoke(main, ["runs", str(tmp_path), "--filter", "outcome=missed"])
    assert listed.exit_code == 0 and "fast" in listed.output and "missed" in listed.output
    none = runner.invoke(main, ["runs", str(tmp_path), "--filter", "outcome=reached"])
    assert "fast" not in none.output
    quiet = runner.invoke(main, ["track", "--out", str(tmp_path / "slow"), "--set",
                                 "track.kp=[100,110]", "--set", "track.kv=[10,13]"])
    assert quiet.exit_code == 0 and "warning" not in quiet.output
