"""The flat-output MPC's design and per-sample QP (flatcli/core/mpc.py).

Referees: the error dynamics integrated by scipy's DOP853 at tight tolerances (the exact
discretisation and the terminal condition); the cost evaluated by stepping the discrete
recursion one sample at a time (the condensed Hessian and gradient); the joint rates and
margin predicted by an independent numpy evaluation of the linearisation and by the flat
model's own nonlinear map (the constraints)."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core.controllers import mpc
from flatcli.core.errors import FlatcliError

Array = NDArray[np.float64]

TIGHT = {"method": "DOP853", "rtol": 1e-12, "atol": 1e-14}


@pytest.mark.parametrize(("kp", "kv", "ts"), [(1.0, 2.0, 0.1), (100.0, 10.0, 0.01),
                                              (0.0, 0.0, 0.05), (13.0, 110.0, 0.02)])
def test_the_discretisation_is_the_ode_integrated_over_a_sample(kp: float, kv: float,
                                                                ts: float) -> None:
    a, b = mpc.discretise(kp, kv, ts)

    def ode(dv: float) -> object:
        return lambda t, s: [s[1], -kp * s[0] - kv * s[1] + dv]

    for column, s0 in enumerate(([1.0, 0.0], [0.0, 1.0])):
        end = solve_ivp(ode(0.0), (0.0, ts), s0, **TIGHT).y[:, -1]
        np.testing.assert_allclose(a[:, column], end, atol=1e-12)
    forced = solve_ivp(ode(1.0), (0.0, ts), [0.0, 0.0], **TIGHT).y[:, -1]
    np.testing.assert_allclose(b, forced, atol=1e-12)


def _stepped_cost(A: Array, B: Array, weights: Array, r: float, x: Array, s0: Array,
                  start: int, costed: int) -> float:
    """The MPC's cost by stepping the error one sample at a time."""
    inputs = B.shape[2]
    total = r * float(x @ x)
    s = s0.copy()
    for i in range(costed):
        s = A[start + i] @ s + B[start + i] @ x[i * inputs: (i + 1) * inputs]
        total += float(s @ (weights * s))
    return total


def test_the_condensed_cost_is_the_stepped_one() -> None:
    """On a time-varying system (random A_k, B_k), from several samples (the horizon
    reaching T or not)."""
    rng = np.random.default_rng(3)
    samples, size, inputs, horizon = 9, 3, 2, 5
    A = rng.standard_normal((samples, size, size)) * 0.5
    B = rng.standard_normal((samples, size, inputs))
    weights = np.array([3.0, 0.5, 2.0])
    for start in (0, 4, 7):
        costed = min(horizon, samples - start)
        hessian, gradient = mpc.condensed_cost(A, B, weights, 0.2, start, horizon)
        for _ in range(5):
            x = rng.standard_normal(inputs * horizon + 1)
            x[-1] = 0.0  # the slack
            x[inputs * costed: -1] = 0.0  # corrections after T
            s0 = rng.standard_normal(size)
            base = _stepped_cost(A, B, weights, 0.2, np.zeros_like(x[:-1]), s0, start, costed)
            quadratic = 0.5 * x @ hessian @ x + (gradient @ s0) @ x
            stepped = _stepped_cost(A, B, weights, 0.2, x[:-1], s0, start, costed)
            # the cost is quadratic: twice the QP's objective plus its value at x = 0
            assert stepped == pytest.approx(2.0 * quadratic + base, rel=1e-10, abs=1e-12)


def test_settings_are_checked_naming_the_key() -> None:
    with pytest.raises(FlatcliError, match=r"track\.mpc_horizon"):
        mpc.MpcSettings(horizon=1)
    with pytest.raises(FlatcliError, match=r"track\.mpc_weight_input"):
        mpc.MpcSettings(weight_input=0.0)
    with pytest.raises(FlatcliError, match=r"track\.mpc_sample"):
        mpc.MpcSettings(sample=0.0)
    with pytest.raises(FlatcliError, match=r"track\.mpc_sample"):
        mpc.MpcSettings(sample=0.3).every(0.001, 2.0)


@pytest.fixture(scope="module")
def paper_plan():  # type: ignore[no-untyped-def]
    import flatcli

    return flatcli.plan().plan


@numba.njit(cache=False)
def _step(d, s, k):  # type: ignore[no-untyped-def]
    mpc.sample_step(d, s, k)


def _design(plan, rate_limit: float, settings: mpc.MpcSettings) -> mpc.Design:  # type: ignore[no-untyped-def]
    return mpc.flat_design(plan.model, plan.trajectory, plan.duration, 0.001, rate_limit,
                           settings)


def _solve(d: mpc.Design, k: int, s0: Array) -> mpc.Scratch:
    s = mpc.scratch(d)
    mpc.reset(s)
    s.s0[:] = s0
    _step(d, s, k)
    return s


def test_without_limits_and_the_goal_beyond_the_horizon_there_is_no_correction(
        paper_plan) -> None:  # type: ignore[no-untyped-def]
    d = _design(paper_plan, math.inf, mpc.MpcSettings(sample=0.05, horizon=10, margin=0.0))
    s = _solve(d, 0, np.array([1e-3, -2e-3, 3e-3, 1e-3]))
    assert np.all(s.held == 0.0)
    assert s.counters[mpc.QP_INFEASIBLE] == 0.0


def _errors_at_the_goal(d: mpc.Design, settings: mpc.MpcSettings, k: int, s0: Array,
                        x: Array) -> Array:
    """e_j(T), e_j'(T) from s0 under the corrections x held sample by sample: the
    continuous error dynamics of the inner law integrated by DOP853 (independent of the
    design's tables)."""
    kp, kv = mpc.INNER_KP, mpc.INNER_KV
    out = np.zeros(4)
    for j in range(2):
        s = s0[2 * j: 2 * j + 2].copy()
        for i in range(d.samples - k):
            dv = x[i * 2 + j]
            s = solve_ivp(lambda t, z, dv=dv: [z[1], -kp * z[0] - kv * z[1] + dv],
                          (0.0, settings.sample), s, **TIGHT).y[:, -1]
        out[2 * j: 2 * j + 2] = s
    return out


def test_the_goal_within_the_horizon_is_reached_by_the_predicted_errors(
        paper_plan) -> None:  # type: ignore[no-untyped-def]
    settings = mpc.MpcSettings(sample=0.1, horizon=8, margin=0.0)
    d = _design(paper_plan, math.inf, settings)
    s0 = np.array([2e-3, -1e-3, -3e-3, 4e-3])
    k = d.samples - 6  # six samples to go
    s = _solve(d, k, s0)
    assert s.counters[mpc.QP_INFEASIBLE] == 0.0
    assert np.abs(s.x[:-1]).max() > 0.0
    np.testing.assert_allclose(_errors_at_the_goal(d, settings, k, s0, s.x), 0.0, atol=1e-10)


def _predicted_flags(d: mpc.Design, plan, k: int, s0: Array, x: Array, ts: float  # type: ignore[no-untyped-def]
                     ) -> Array:
    """The applied flag (y, y', y'') at the start of each horizon sample i: the plan's plus
    the predicted errors, stepping the discrete recursion (numpy), y'' with the inner law's
    terms and the correction."""
    kp, kv = mpc.INNER_KP, mpc.INNER_KV
    flags = []
    s = s0.reshape(2, 2).copy()
    for i in range(min(d.horizon, d.samples - k)):
        ref = plan.flags(np.array([(k + i) * ts]))[0]
        dv = x[i * 2: (i + 1) * 2]
        flag = ref.copy()
        flag[:2] += s[:, 0]
        flag[2:4] += s[:, 1]
        flag[4:] += -kp * s[:, 0] - kv * s[:, 1] + dv
        flags.append(flag)
        s = (d.A[k + i] @ s.ravel() + d.B[k + i] @ dv).reshape(2, 2)
    return np.array(flags)


def test_the_rate_limit_holds_at_the_predicted_samples(paper_plan) -> None:  # type: ignore[no-untyped-def]
    """A limit the plan keeps over the horizon (its joint rates stay below 1.7 rad/s from
    t = 0.8 s to 1 s) and an initial error that would break it: the correction keeps every
    predicted joint rate within it, evaluated by the linearisation (exactly, to rounding)
    and by the model's nonlinear flag map (to the linearisation's error: 8 % of the limit
    for these rates 6-8 rad/s away from the plan's, which the docs state)."""
    limit = 10.0
    settings = mpc.MpcSettings(sample=0.02, horizon=10, margin=0.0)
    d = _design(paper_plan, limit, settings)
    kept = limit * (1.0 - settings.backoff)
    k = 40
    assert np.abs(d.value[k: k + 11, :2]).max() < 1.7
    s0 = np.array([0.0, 0.0, 0.0, 0.1])  # a y2' error that pushes th2' beyond the limit
    free = _solve(_design(paper_plan, math.inf, settings), k, s0)
    flags = _predicted_flags(d, paper_plan, k, s0, free.x, settings.sample)
    free_rates = paper_plan.model.flag_values(flags.T)[3:5]
    assert np.abs(free_rates).max() > kept  # without the limit it is broken
    s = _solve(d, k, s0)
    assert s.counters[mpc.QP_INFEASIBLE] == 0.0  # feasible: no slack
    flags = _predicted_flags(d, paper_plan, k, s0, s.x, settings.sample)
    # the linearisation, evaluated independently: rate = rate_ref + slopes @ (flag - ref)
    _, jacobian = paper_plan.model.flag_jacobian(paper_plan.flags(
        (k + np.arange(len(flags))) * settings.sample).T)
    for i, flag in enumerate(flags):
        ref = paper_plan.flags(np.array([(k + i) * settings.sample]))[0]
        linear = d.value[k + i, :2] + jacobian[3:5, :, i] @ (flag - ref)
        assert np.all(np.abs(linear) <= kept + 1e-9)
    nonlinear = paper_plan.model.flag_values(flags.T)[3:5]
    assert np.abs(nonlinear).max() <= limit * 1.08


def test_an_unreachable_limit_is_met_by_the_slack_and_counted(paper_plan) -> None:  # type: ignore[no-untyped-def]
    """The goal within the horizon fixes th1'(T) = 0.5 rad/s (the plan's end rate, a hard
    terminal condition) above a limit of 0.2 rad/s: the slack takes the excess (at least
    0.5 - 0.2 (1 - backoff) rad/s) and the sample counts as infeasible."""
    settings = mpc.MpcSettings(sample=0.02, horizon=10, margin=0.0)
    d = _design(paper_plan, 0.2, settings)
    k = d.samples - 5
    assert d.value[d.samples, 0] == pytest.approx(0.5, abs=1e-9)
    s = _solve(d, k, np.zeros(4))
    assert s.counters[mpc.QP_INFEASIBLE] == 1.0
    assert s.counters[mpc.QP_SLACK] >= 0.5 - 0.2 * (1 - settings.backoff) - 1e-9


def test_a_limit_the_correction_can_reach_within_a_sample_needs_no_slack(paper_plan) -> None:  # type: ignore[no-untyped-def]
    """th1' = 0.6 rad/s at t = 1 s above a limit of 0.5: a state that no correction changes
    at once, but within one sample it does (u1' = v1): no slack."""
    settings = mpc.MpcSettings(sample=0.02, horizon=5, margin=0.0)
    d = _design(paper_plan, 0.5, settings)
    k = 50
    assert d.value[k, 0] == pytest.approx(0.6, abs=1e-9)
    s = _solve(d, k, np.zeros(4))
    assert s.counters[mpc.QP_INFEASIBLE] == 0.0
    assert s.held[0] < 0.0  # th1' is slowed down


def test_the_as_built_discretisation_is_the_nonlinear_loop_to_second_order() -> None:
    """The as-built design's A_k, B_k against the robot as built in closed loop with its
    LQR and a held correction: th' = (th0'(q, w), w), w = w_r - L (th - th_r) + dv, the base
    rate from the link geometry (tests/asbuilt_support.py, nothing of flatcli's chain),
    integrated by DOP853: the prediction's error falls as the square of the error's size
    (a first-order model), and is small."""
    from asbuilt_support import AS_BUILT, base_rate

    import flatcli
    from flatcli.core.controllers.lqr import LqrWeights, tracked

    plan = flatcli.plan(overrides={"robot.com": list(AS_BUILT.com)}).plan
    assert plan.model.kind == "exact"
    settings = mpc.MpcSettings(sample=0.1, horizon=5)
    d = mpc.asbuilt_design(plan, LqrWeights(), 0.001, math.inf, settings)
    curves = tracked(plan, LqrWeights(), None)
    n = 2

    def reference(t: float) -> tuple[Array, Array, Array]:
        c = curves.derivative(np.array([t]), 0)[0]
        r = curves.derivative(np.array([t]), 1)[0]
        theta = np.r_[c[n], c[:n]]
        return theta, r[:n], c[n + 1:].reshape(n, n + 1)

    def loop(t: float, theta: Array, dv: Array) -> Array:
        ref, w_ref, gains = reference(t)
        w = w_ref - gains @ (theta - ref) + dv
        return np.r_[base_rate(AS_BUILT, theta[1:], w), w]

    k = 7
    t0, t1 = k * 0.1, (k + 1) * 0.1
    rng = np.random.default_rng(5)
    direction_e = rng.standard_normal(n + 1)
    direction_v = rng.standard_normal(n)
    misses = []
    for size in (1e-3, 5e-4):
        e0, dv = size * direction_e, size * direction_v
        start = reference(t0)[0] + e0
        end = solve_ivp(lambda t, th, dv=dv: loop(t, th, dv), (t0, t1), start,
                        **TIGHT).y[:, -1]
        e1 = end - reference(t1)[0]
        misses.append(np.abs(e1 - (d.A[k] @ e0 + d.B[k] @ dv)).max())
    assert misses[0] < 1e-2 * 1e-3  # small against the error itself
    assert 3.0 < misses[0] / misses[1] < 5.0  # second order: halving the size quarters it


def test_the_as_built_dynamic_mpc_solves_every_sample() -> None:
    """The as-built law with a servo has S = 2 N + 1 = 5 error states and N = 2 corrections
    a sample: two samples before T the terminal condition s(T) = 0 would be 5 equalities on
    4 unknowns, a QP with no solution once the measured error is off the last prediction
    (counted as ``qp_infeasible`` with no slack before). Stepping the design's own
    recursion s_k+1 = A_k s_k + B_k dv_k (numpy, here) plus a disturbance of 1e-6 (what the
    nonlinear plant adds to the linear prediction) through every sample: no sample is
    counted infeasible; without disturbances the error at T is 0 (to the QP's tolerance),
    and with them the last two samples hold what the QP three samples before T planned."""
    from asbuilt_support import AS_BUILT

    import flatcli
    from flatcli.core.controllers.lqr import LqrWeights

    plan = flatcli.plan(overrides={"robot.com": list(AS_BUILT.com)}).plan
    settings = mpc.MpcSettings(sample=0.1, horizon=20)
    d = mpc.asbuilt_design(plan, LqrWeights(), 0.001, math.inf, settings, servo=50.0)
    states, inputs = d.A.shape[1], d.B.shape[2]
    assert (states, inputs) == (5, 2)
    for disturbance in (0.0, 1e-6):
        rng = np.random.default_rng(3)
        s = mpc.scratch(d)
        mpc.reset(s)
        error = np.array([1e-3, -2e-3, 1.5e-3, 0.0, 0.0])
        held = []
        planned = np.zeros(0)
        for k in range(d.samples):
            s.s0[:] = error
            _step(d, s, k)
            held.append(s.held.copy())
            if k == d.samples - 3:  # the last sample whose QP can meet s(T) = 0
                planned = s.x.copy()
            error = (d.A[k] @ error + d.B[k] @ s.held
                     + disturbance * rng.standard_normal(states))
        assert s.counters[mpc.QP_INFEASIBLE] == 0.0
        np.testing.assert_array_equal(held[-2], planned[inputs: 2 * inputs])
        np.testing.assert_array_equal(held[-1], planned[2 * inputs: 3 * inputs])
        if disturbance == 0.0:
            np.testing.assert_allclose(error, 0.0, atol=1e-9 * 2e-3)


def test_the_warm_start_changes_no_correction(replan) -> None:  # type: ignore[no-untyped-def]
    """Every sample of the maneuver re-planned for 4 rad/s (``replan``: the rate rows bind),
    the error stepped through the design's own recursion plus a disturbance of 1e-5 (so the
    active set moves): the corrections with the warm start (each QP from the last
    sample's active set) are the cold ones (from the unconstrained minimiser, the
    referee: its QP is checked against quadprog in tests/test_qp.py) to 1e-9 of their
    size; the warm QPs were started from guessed bounds after the first sample."""
    settings = mpc.MpcSettings(sample=0.1, horizon=8)
    d = _design(replan, 4.0, settings)
    runs = []
    for warm in (1, 0):
        design = d._replace(warm_start=warm)
        rng = np.random.default_rng(7)
        s = mpc.scratch(design)
        mpc.reset(s)
        error = np.array([2e-3, -1e-3, -1.5e-3, 2e-3])
        held, guessed = [], []
        for k in range(design.samples):
            s.s0[:] = error
            _step(design, s, k)
            held.append(s.held.copy())
            guessed.append(s.counters[mpc.QP_GUESSED])
            error = (design.A[k] @ error + design.B[k] @ s.held
                     + 1e-5 * rng.standard_normal(4))
        runs.append((np.array(held), np.array(guessed), s.counters[mpc.QP_INFEASIBLE]))
    (warm_held, warm_guessed, warm_slacked), (cold_held, cold_guessed, cold_slacked) = runs
    assert warm_slacked == cold_slacked  # samples that needed the slack: the same
    assert np.abs(cold_held).max() > 1e-2  # the corrections act
    np.testing.assert_allclose(warm_held, cold_held, atol=1e-9 * np.abs(cold_held).max(),
                               rtol=0)
    assert np.all(cold_guessed == 0) and warm_guessed[1:].max() > 1  # beyond the slack


def test_a_design_is_made_once_for_what_it_is_made_of() -> None:
    """``design_for`` gives the same design again for a scenario made of the same things (a
    sweep's cells that differ in a torque limit the same re-plan keeps), and a new one when
    the plan's model, the output step or the settings differ; a reused design equals one
    made afresh (``_design_for``, no reuse) array by array."""
    from flatcli.api import load_spec
    from flatcli.core.loop.simulate import Scenario
    from flatcli.experiment import scenario_from, tracked_plan

    mpc._DESIGNS.clear()

    def scenario_of(*sets: str) -> Scenario:
        spec = load_spec(None, ("track.controller=\"mpc\"", *sets))
        plan, replanned = tracked_plan(spec)
        return scenario_from(spec, plan, replanned)

    a = scenario_of("track.rate_limit=4.0", "track.dt=0.002")
    b = scenario_of("track.rate_limit=4.0", "track.dt=0.002", "plant.torque_limit=5.0")
    first = mpc.design_for(a)
    assert mpc.design_for(b) is first  # the kinematic plant reads no torque limit
    fresh = mpc._design_for(a, mpc._settings(a))
    for name, value in first._asdict().items():
        np.testing.assert_array_equal(np.asarray(value), np.asarray(getattr(fresh, name)))
    for other in (scenario_of("track.rate_limit=4.0", "track.dt=0.004"),
                  scenario_of("track.rate_limit=4.0", "track.dt=0.002",
                              "track.mpc_horizon=10"),
                  scenario_of("track.rate_limit=4.0", "track.dt=0.002",
                              "robot.model=\"paper\"")):
        assert mpc.design_for(other) is not first


def test_the_servo_offsets_are_shared_by_torque_limits_and_are_those_with_the_rows() -> None:
    """On the dynamic plant each torque limit has its own design (its torque rows), but the
    servo's offsets (``tracked_offsets``, 3-10 s) are made once, without the rows, for every
    limit (``_offsets_for``). Referee: ``tracked_offsets`` made with the rows of 0.5 N m
    (``servo_torques``), where the QP's torque rows are closest to binding on the path with
    no error: the same offsets."""
    import math

    from flatcli.api import load_spec
    from flatcli.core.loop.simulate import Scenario
    from flatcli.experiment import scenario_from, tracked_plan

    mpc._DESIGNS.clear()
    mpc._OFFSETS.clear()

    def scenario_of(limit: float) -> Scenario:
        spec = load_spec(None, ("track.controller=\"mpc\"", "plant.model=\"dynamic\"",
                                f"plant.torque_limit={limit}"))
        plan, replanned = tracked_plan(spec)
        assert replanned
        return scenario_from(spec, plan, replanned)

    low, high = scenario_of(0.5), scenario_of(1.0)
    assert mpc.design_for(low) is not mpc.design_for(high)  # each limit its own rows
    assert len(mpc._OFFSETS) == 1  # one lag model for both
    shared = next(iter(mpc._OFFSETS.values()))
    settings = mpc._settings(low)
    every = settings.every(low.dt, low.plan.duration)
    torques = mpc.servo_torques(low.plan, settings, every * low.dt,
                                round(low.plan.duration / low.dt) // every,
                                low.torque_kept, low.servo_bandwidth)
    assert math.isfinite(low.torque_kept)
    with_rows = mpc.tracked_offsets(low.plan, low.dt, settings, low.servo_bandwidth,
                                    low.rate_limit, torques)
    np.testing.assert_allclose(shared, with_rows, rtol=0, atol=1e-12)


def test_the_lag_runs_flag_is_the_plans_own_on_both_bases() -> None:
    """``mpc._flag_evaluator`` (piecewise polynomials, what ``lagged_run`` asks at every
    evaluation) against the plan's basis itself (``FlatTrajectory.flags``: scipy's B-spline
    or the scaled monomials), at 400 random times and at the breakpoints, on a B-spline
    curve of 12 coefficients and a polynomial one."""
    from flatcli.core.curves.basis import BSplineBasis, FlatTrajectory, PolynomialBasis

    rng = np.random.default_rng(41)
    for basis in (BSplineBasis(12, 2.0), PolynomialBasis(7, 2.0)):
        trajectory = FlatTrajectory(basis, rng.normal(size=(2, basis.size)))
        flag_at = mpc._flag_evaluator(trajectory)
        times = np.concatenate([rng.uniform(0.0, 2.0, 400), basis.breakpoints])
        want = trajectory.flags(times)
        got = np.array([flag_at(float(t)) for t in times])
        scale = np.max(np.abs(want), axis=0)
        assert np.max(np.abs(got - want) / scale) < 1e-12
