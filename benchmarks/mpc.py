"""make bench: what the MPC (``track.controller = "mpc"``, issue 40) costs.

* an MPC trial against a paper-feedback trial of the same sweep: the paper's maneuver (gains
  swapped), the same 200 trials (th(0) off by up to 2 mrad), ``simulate`` on the default
  adaptive integrator in this process (one thread), the two controllers timed alternately
  (A B A B ...) and the ratio taken pair by pair (its median): with no rate limit, and at
  4 rad/s (the paper's feedback on the cubic, the MPC on its re-plan, ``replanned``);
* one MPC step (``controllers.mpc.sample_step``: the QP built and solved) at horizon 20,
  compiled, called in a compiled loop from the errors measured at the samples of recorded
  trials: the first sample of the maneuver (all 20 samples ahead and the terminal
  condition), and the mean over the maneuver's samples (each trial's samples in turn, as
  the loop calls them), with the warm start (the default) and without;
* on the dynamic plant at a 10 N m torque limit (b = 100 rad/s): the cubic tracked as it is
  against the MPC's re-plan within the torque limit (the plan of largest margin): the torque
  each asks, the re-plan's and the designs' seconds, seconds per trial and reached;
* at 0.5 N m the MPC with its torque rows against without them: reached, seconds per trial
  and per step, the designs' seconds.

The issue's goals: an MPC trial at most 20x a paper-feedback trial in the same sweep; one
step at horizon 20 at most 50 us on one core.
"""

from __future__ import annotations

import time
from typing import Any

import numba
import numpy as np

from flatcli.core.controllers import mpc

SECTION = "The MPC (issue 40): a trial against the paper's feedback, and one step"
HEADERS = {SECTION: ["what", "time", "ratio", "goal", "note"]}
SWAPPED = {"track.kp": [100, 110], "track.kv": [10, 13], "track.initial": [1.8, 1.0, 0.0]}
#: The goals of issue 40.
TRIAL_RATIO_GOAL = 20.0
STEP_GOAL_SECONDS = 50e-6


def _scenario(controller: str, rate_limit: float) -> tuple[Any, Any]:
    """The scenario and spec of the paper's maneuver with ``controller`` at ``rate_limit``
    (the MPC's re-plan when the cubic exceeds it, as a sweep makes it)."""
    from flatcli.api import load_spec
    from flatcli.experiment import scenario_from, tracked_plan

    spec = load_spec(None, {**SWAPPED, "track.controller": controller,
                            "track.rate_limit": rate_limit})
    plan, _ = tracked_plan(spec)
    return scenario_from(spec, plan).prepared(), spec


def _trials(spec: Any, plan: Any, count: int) -> Any:
    from benchmarks.outcomes import _perturbed

    return _perturbed(spec, plan, count)


def trial_ratio(bench: Any, rate_limit: float, count: int, pairs: int) -> dict[str, float]:
    """Seconds per trial of each controller on the same ``count`` trials, timed in ``pairs``
    alternating pairs; the median ratio."""
    from flatcli.core.loop.simulate import simulate

    timed: dict[str, list[float]] = {"flat": [], "mpc": []}
    cases = {name: _scenario(name, rate_limit) for name in timed}
    trials = {name: _trials(spec, scenario.plan, count)
              for name, (scenario, spec) in cases.items()}
    for name, (scenario, _) in cases.items():  # compiled and warm
        simulate(scenario, trials[name].subset(slice(0, 2)))
    for _ in range(pairs):
        for name, (scenario, _) in cases.items():
            started = time.perf_counter()
            simulate(scenario, trials[name])
            timed[name].append((time.perf_counter() - started) / count)
    ratios = np.array(timed["mpc"]) / np.array(timed["flat"])
    ratio = float(np.median(ratios))
    flat, per_mpc = float(np.median(timed["flat"])), float(np.median(timed["mpc"]))
    limit = "no rate limit" if not np.isfinite(rate_limit) else f"rate limit {rate_limit:g} rad/s"
    bench.row(SECTION, f"an MPC trial / a paper-feedback trial, {limit} ({count} trials, "
              f"{pairs} alternating pairs)", f"{per_mpc * 1e3:.2f} ms",
              f"{ratio:.1f}x", f"<= {TRIAL_RATIO_GOAL:g}x: "
              + ("met" if ratio <= TRIAL_RATIO_GOAL else
                 f"missed by {ratio / TRIAL_RATIO_GOAL:.2f}x"),
              f"paper's feedback {flat * 1e3:.2f} ms a trial; pair ratios "
              f"{ratios.min():.1f}-{ratios.max():.1f}x")
    return {"flat_seconds": flat, "mpc_seconds": per_mpc, "ratio": ratio}


@numba.njit(cache=False)
def _steps(d: Any, s: Any, errors: Any, first: bool, repeats: int) -> float:
    """Calls ``sample_step`` along each trial's samples in turn (errors (trials, K, S): the
    errors measured at its samples), as a trial does (reset at its start, the last QP's
    active set guessed at the next sample); with ``first`` only at sample 0 of each trial,
    ``repeats`` times; returns a checksum (so the work is not dropped)."""
    total = 0.0
    samples = 1 if first else errors.shape[1]
    for _ in range(repeats):
        for i in range(errors.shape[0]):
            mpc.reset(s)
            for k in range(samples):
                for c in range(errors.shape[2]):
                    s.s0[c] = errors[i, k, c]
                mpc.sample_step(d, s, k)
                total += s.held[0]
    return total


def measured_errors(scenario: Any, spec: Any, count: int) -> Any:
    """The errors (count, K, S) the MPC measures at its samples in ``count`` trials of the
    scenario (th(0) off by up to 2 mrad): the flat outputs' errors from the plan (e_j,
    e_j'), computed from each recorded trial's state at the sample instants (the flat
    model's outputs, ``ChainModel``)."""
    from flatcli.core.loop.simulate import simulate
    from flatcli.core.models.flatmodel import ChainModel

    plan = scenario.plan
    d = scenario.sampled_design
    out = simulate(scenario, _trials(spec, plan, count), "adaptive", record=True)
    assert out.trace is not None
    model = ChainModel.of(plan.robot)
    n = plan.n_joints
    times = np.arange(d.samples) * d.every * scenario.dt
    flags = plan.trajectory.flags(times)  # (K, 3 N)
    errors = np.zeros((count, d.samples, d.A.shape[1]))
    for i in range(count):
        rows = out.trace[i, : d.samples * d.every: d.every]
        y, y_dot, _ = model.outputs(rows[:, : n + 1], rows[:, n + 1: 2 * n])
        errors[i, :, 0: 2 * n: 2] = y - flags[:, :n]
        errors[i, :, 1: 2 * n: 2] = y_dot - flags[:, n: 2 * n]
    return errors


def step_time(bench: Any, repeats: int, rate_limit: float) -> dict[str, float]:
    """Seconds per MPC step at horizon 20 on the paper's maneuver (at 4 rad/s the MPC's
    re-plan, every joint rate and the margin as constraints; with no limit the cubic and
    the margin alone), from the errors measured at the samples of 8 trials (th(0) off by
    up to 2 mrad): with the warm start (the design's default) and without it (each QP from
    the unconstrained minimiser), alternately, the same errors."""
    scenario, spec = _scenario("mpc", rate_limit)
    d = scenario.sampled_design
    assert d.horizon == 20
    errors = measured_errors(scenario, spec, 8)
    s = mpc.scratch(d)
    out: dict[str, float] = {}
    limit = "no rate limit" if not np.isfinite(rate_limit) else f"rate limit {rate_limit:g} rad/s"
    for first, label in ((True, "the first sample (20 ahead, the terminal condition)"),
                         (False, f"mean over the maneuver's {d.samples} samples")):
        steps = errors.shape[0] * (1 if first else d.samples)
        best = {1: np.inf, 0: np.inf}
        iterations = {}
        for warm in (1, 0):  # compiled; the iterations of one pass
            design = d._replace(warm_start=warm)
            _steps(design, s, errors, first, 1)
            iterations[warm] = 0.0
            for i in range(errors.shape[0]):
                _steps(design, s, errors[i: i + 1], first, 1)
                iterations[warm] += s.counters[mpc.QP_ITERATIONS] / steps
        for _ in range(5):
            for warm in (1, 0):
                design = d._replace(warm_start=warm)
                started = time.perf_counter()
                _steps(design, s, errors, first, repeats)
                best[warm] = min(best[warm], (time.perf_counter() - started) / (repeats * steps))
        for warm in (1, 0):
            how = "warm start" if warm else "cold (no warm start)"
            bench.row(SECTION, f"one MPC step at horizon 20, {limit}, {how}: {label}",
                      f"{best[warm] * 1e6:.1f} us",
                      "", f"<= {STEP_GOAL_SECONDS * 1e6:g} us: "
                      + ("met" if best[warm] <= STEP_GOAL_SECONDS else
                         f"missed by {best[warm] / STEP_GOAL_SECONDS:.2f}x"),
                      f"{mpc.rows(d)} rows at most, {d.factors.shape[1]} variables; "
                      f"{iterations[warm]:.1f} QP iterations a step; best of 5")
            key = ("first" if first else "mean") + ("" if warm else "_cold")
            out[key] = float(best[warm])
            out[key + "_iterations"] = float(iterations[warm])
    rng = np.random.default_rng(40)  # the inputs of this bench before 2026-12-05 evening
    harsh = rng.normal(0.0, 2e-3, (64, 1, d.A.shape[1]))
    harsh_iterations = 0.0
    for i in range(harsh.shape[0]):
        _steps(d, s, harsh[i: i + 1], True, 1)
        harsh_iterations += s.counters[mpc.QP_ITERATIONS] / harsh.shape[0]
    best_harsh = np.inf
    for _ in range(5):
        started = time.perf_counter()
        _steps(d, s, harsh, True, repeats)
        best_harsh = min(best_harsh, (time.perf_counter() - started) / (repeats * 64))
    bench.row(SECTION, f"one MPC step at horizon 20, {limit}: the first sample from random "
              "errors (2 mrad and 2 mrad/s in every state, 64 draws)",
              f"{best_harsh * 1e6:.1f} us", "", f"<= {STEP_GOAL_SECONDS * 1e6:g} us: "
              + ("met" if best_harsh <= STEP_GOAL_SECONDS else
                 f"missed by {best_harsh / STEP_GOAL_SECONDS:.2f}x"),
              f"the errors this bench drew before measuring trials' own; "
              f"{harsh_iterations:.1f} QP iterations a step; best of 5")
    out["first_random"] = float(best_harsh)
    out["first_random_iterations"] = float(harsh_iterations)
    return out


#: The torque limit of the re-plan's bench [N m] (below the cubic's 32.6 N m peak) and the
#: dynamic plant's servo (docs/physics.md's torque table: b = 100 rad/s, its model right).
TORQUE_LIMIT = 10.0
DYNAMIC = {"plant.model": "dynamic", "plant.servo_bandwidth": 100.0,
           "track.initial": [1.8, 1.0, 0.0]}


def _best_of(scenario: Any, trials: Any, repeats: int) -> tuple[float, Any]:
    """The best of ``repeats`` timed runs of ``trials`` [s] (after a warm, compiled run of
    two), and the last run's Outcome."""
    from flatcli.core.loop.simulate import simulate

    simulate(scenario, trials.subset(slice(0, 2)))  # compiled, warm
    best = np.inf
    for _ in range(repeats):
        started = time.perf_counter()
        result = simulate(scenario, trials)
        best = min(best, time.perf_counter() - started)
    return best, result


def _reached(result: Any, goal: Any) -> int:
    """Trials that ended ok with every angle within 1e-3 rad of ``goal`` (N + 1,)."""
    from flatcli.core.loop.metrics import Status

    assert result.final is not None
    miss = np.abs(result.final - goal).max(axis=1)
    return int(np.sum((result.status == Status.OK) & (miss <= 1e-3)))


def torque_replan(bench: Any, count: int, repeats: int) -> dict[str, float]:
    """The MPC on the dynamic plant at ``TORQUE_LIMIT``: the spec's cubic tracked as it is (as
    before the torque re-plan) against the re-plan of largest margin
    (``experiment.mpc_reference``), both on the same trials at the limit: what
    each plan asks (``peak_joint_torque``), the re-plan's and each design's seconds
    (``mpc_reference``; ``mpc.design_for`` with the servo offsets on the MPC's own path),
    seconds per trial (``simulate``, the same ``count`` trials, th(0) off by up to 2 mrad,
    best of ``repeats``), reached (within 1e-3 rad at T) and the median peak torque
    applied."""
    from flatcli.api import load_spec
    from flatcli.core.controllers.mpc import design_for
    from flatcli.core.loop.metrics import Metric
    from flatcli.experiment import (
        mpc_reference,
        peak_joint_torque,
        plan_from,
        scenario_from,
    )

    spec = load_spec(None, {"track.controller": "mpc", **DYNAMIC,
                            "plant.torque_limit": TORQUE_LIMIT})
    cubic = plan_from(spec)
    seconds = []
    for _ in range(repeats):
        started = time.perf_counter()
        replan, replanned = mpc_reference(spec, cubic)
        seconds.append(time.perf_counter() - started)
    assert replanned
    out: dict[str, float] = {"replan_seconds": float(min(seconds))}
    rows = []
    for name, plan in (("cubic", cubic), ("replan", replan)):
        scenario = scenario_from(spec, plan)
        started = time.perf_counter()
        design_for(scenario)
        out[f"{name}_design_seconds"] = time.perf_counter() - started
        scenario = scenario.prepared()
        trials = _trials(spec, plan, count)
        best, result = _best_of(scenario, trials, repeats)
        goal = plan.sample(np.array([plan.duration])).theta[0]
        reached = _reached(result, goal)
        peak = float(np.median(result.metrics[:, Metric.PEAK_TORQUE]))
        need = peak_joint_torque(spec, plan)[1]
        out.update({f"{name}_trial_seconds": best / count, f"{name}_reached": reached,
                    f"{name}_need": need, f"{name}_peak_torque": peak})
        rows.append((name, need, peak, reached, best / count))
    for name, need, peak, reached, per in rows:
        what = ("the cubic (not re-planned)" if name == "cubic" else
                "the re-plan of largest margin")
        design = out[f"{name}_design_seconds"]
        bench.row(SECTION, f"the MPC at {TORQUE_LIMIT:g} N m on the dynamic plant: {what} "
                  f"({count} trials)", f"{per * 1e3:.2f} ms a trial",
                  f"{per / out['cubic_trial_seconds']:.2f}x", f"reached {reached}/{count}",
                  f"plan asks {need:.3g} N m, trials apply {peak:.3g} N m (median peak); "
                  f"design {design:.1f} s"
                  + (f", re-plan {out['replan_seconds']:.2f} s" if name == "replan" else ""))
    return out


#: The torque rows' bench: a limit where they bind (docs/physics.md, "Within the torque
#: limit": the re-plan asks 0.325 N m).
ROWS_LIMIT = 0.5


def torque_rows(bench: Any, count: int, repeats: int) -> dict[str, float]:
    """The MPC on the dynamic plant at ``ROWS_LIMIT`` (the re-plan of largest margin) with
    its torque rows (``mpc.servo_torques``: the design a sweep makes) and without
    (``Scenario.torque_kept`` inf, the design before them), the same ``count`` trials (th(0)
    off by up to 2 mrad): each design's seconds, seconds per trial (best of ``repeats``),
    reached (within 1e-3 rad at T), and one MPC step (``sample_step``, warm start) as the
    trials call it, the mean over the maneuver's samples of 8 of them."""
    import dataclasses

    from flatcli.api import load_spec
    from flatcli.experiment import scenario_from, tracked_plan

    spec = load_spec(None, {"track.controller": "mpc", **DYNAMIC,
                            "plant.torque_limit": ROWS_LIMIT})
    plan, replanned = tracked_plan(spec)
    base = scenario_from(spec, plan, replanned)
    trials = _trials(spec, plan, count)
    goal = plan.sample(np.array([plan.duration])).theta[0]
    out: dict[str, float] = {}
    for name, kept in (("rows", base.torque_kept), ("none", float("inf"))):
        scenario = dataclasses.replace(base, torque_kept=kept)
        mpc._DESIGNS.clear()
        mpc._OFFSETS.clear()  # each design makes its servo offsets too
        started = time.perf_counter()
        d = mpc.design_for(scenario)
        design = time.perf_counter() - started
        scenario = scenario.prepared()
        best, result = _best_of(scenario, trials, repeats)
        reached = _reached(result, goal)
        errors = measured_errors(scenario, spec, 8)
        s = mpc.scratch(d)
        _steps(d, s, errors, False, 1)
        step = np.inf
        for _ in range(5):
            started = time.perf_counter()
            _steps(d, s, errors, False, 20)
            step = min(step, (time.perf_counter() - started) / (20 * 8 * d.samples))
        out.update({f"{name}_design_seconds": design, f"{name}_trial_seconds": best / count,
                    f"{name}_reached": reached, f"{name}_step_seconds": step})
        what = "with the torque rows" if name == "rows" else "without torque rows"
        bench.row(SECTION, f"the MPC at {ROWS_LIMIT:g} N m on the dynamic plant {what} "
                  f"({count} trials)", f"{best / count * 1e3:.2f} ms a trial",
                  f"{best / count / out['rows_trial_seconds']:.2f}x",
                  f"reached {reached}/{count}",
                  f"one step {step * 1e6:.1f} us ({mpc.rows(d)} rows at most); design "
                  f"{design:.1f} s")
    return out


def run_all(bench: Any) -> None:
    quick = bench.quick
    count, pairs = (50, 3) if quick else (200, 7)
    bench.raw["mpc"] = {
        "unlimited": trial_ratio(bench, float("inf"), count, pairs),
        "limit_4": trial_ratio(bench, 4.0, count, pairs),
        "step_limit_4": step_time(bench, 20 if quick else 200, 4.0),
        "step_unlimited": step_time(bench, 20 if quick else 200, float("inf")),
        "torque_replan": torque_replan(bench, 20 if quick else 100, 1 if quick else 3),
        "torque_rows": torque_rows(bench, 20 if quick else 100, 1 if quick else 3),
    }
