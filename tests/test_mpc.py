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

from flatcli.core import mpc
from flatcli.core.model import FlatcliError

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


def _stepped_cost(phi: Array, gamma: Array, weights: tuple[float, float, float], x: Array,
                  s0: Array, costed: int) -> float:
    """The MPC's cost by stepping each output's error one sample at a time."""
    n_out = phi.shape[0]
    a_step = phi[:, 1]
    b_step = gamma[:, 0]
    qp_, qv, r = weights
    total = r * float(x @ x)
    for j in range(n_out):
        s = s0[2 * j: 2 * j + 2].copy()
        for i in range(costed):
            s = a_step[j] @ s + b_step[j] * x[i * n_out + j]
            total += qp_ * s[0] ** 2 + qv * s[1] ** 2
    return total


def test_the_condensed_cost_is_the_stepped_one() -> None:
    kp, kv = np.array([4.0, 9.0]), np.array([4.0, 6.0])
    settings = mpc.MpcSettings(horizon=6, weight_position=3.0, weight_rate=0.5,
                               weight_input=0.2)
    phi, gamma = mpc.predictions(kp, kv, 0.05, 6)
    rng = np.random.default_rng(3)
    for costed in (1, 4, 6):
        hessian, gradient = mpc.condensed_cost(phi, gamma, settings, costed)
        for _ in range(5):
            x = rng.standard_normal(13)
            x[-1] = 0.0  # the slack
            s0 = rng.standard_normal(4)
            base = _stepped_cost(phi, gamma, (3.0, 0.5, 0.2), np.zeros(12), s0, costed)
            quadratic = 0.5 * x @ hessian @ x + (gradient @ s0) @ x
            stepped = _stepped_cost(phi, gamma, (3.0, 0.5, 0.2), x[:12], s0, costed)
            # the cost is quadratic: twice the QP's objective plus its value at x = 0
            assert stepped == pytest.approx(2.0 * quadratic + base, rel=1e-10, abs=1e-12)


def test_settings_are_checked_naming_the_key() -> None:
    with pytest.raises(FlatcliError, match=r"track\.mpc_horizon"):
        mpc.MpcSettings(horizon=1)
    with pytest.raises(FlatcliError, match=r"track\.mpc_weight_input"):
        mpc.MpcSettings(weight_input=0.0)
    with pytest.raises(FlatcliError, match=r"track\.mpc_every"):
        mpc.MpcSettings(every=0)


@pytest.fixture(scope="module")
def paper_plan():  # type: ignore[no-untyped-def]
    import flatcli

    return flatcli.plan().plan


@numba.njit(cache=False)
def _step(d, s, k, a, b, direct):  # type: ignore[no-untyped-def]
    mpc.sample_step(d, s, k, a, b, direct)


def _design(plan, rate_limit: float, settings: mpc.MpcSettings) -> mpc.Design:  # type: ignore[no-untyped-def]
    return mpc.design(plan.model, plan.trajectory, plan.duration, 0.001,
                      np.array([1.0, 1.0]), np.array([2.0, 2.0]), rate_limit, settings)


def _solve(d: mpc.Design, k: int, s0: Array) -> mpc.Scratch:
    s = mpc.scratch(d)
    mpc.reset(s)
    s.s0[:] = s0
    _step(d, s, k, np.zeros(2), np.zeros(2), np.zeros(2))
    return s


def test_without_limits_and_the_goal_beyond_the_horizon_there_is_no_correction(
        paper_plan) -> None:  # type: ignore[no-untyped-def]
    d = _design(paper_plan, math.inf, mpc.MpcSettings(every=50, horizon=10, margin=0.0))
    s = _solve(d, 0, np.array([1e-3, -2e-3, 3e-3, 1e-3]))
    assert np.all(s.held == 0.0)
    assert s.counters[1] == 0.0


def _errors_at_the_goal(d: mpc.Design, k: int, s0: Array, x: Array) -> Array:
    """e_j(T), e_j'(T) from s0 under the corrections x held sample by sample: the
    continuous error dynamics integrated by DOP853 (independent of the design's tables)."""
    n_out = d.kp.shape[0]
    ts = d.every * 0.001
    out = np.zeros(2 * n_out)
    for j in range(n_out):
        s = s0[2 * j: 2 * j + 2].copy()
        for i in range(d.samples - k):
            dv = x[i * n_out + j]
            kp, kv = d.kp[j], d.kv[j]
            s = solve_ivp(lambda t, z, dv=dv, kp=kp, kv=kv: [z[1], -kp * z[0] - kv * z[1] + dv],
                          (0.0, ts), s, **TIGHT).y[:, -1]
        out[2 * j: 2 * j + 2] = s
    return out


def test_the_goal_within_the_horizon_is_reached_by_the_predicted_errors(
        paper_plan) -> None:  # type: ignore[no-untyped-def]
    settings = mpc.MpcSettings(every=100, horizon=8, margin=0.0)
    d = _design(paper_plan, math.inf, settings)
    s0 = np.array([2e-3, -1e-3, -3e-3, 4e-3])
    k = d.samples - 6  # six samples to go
    s = _solve(d, k, s0)
    assert s.counters[1] == 0.0
    np.testing.assert_allclose(_errors_at_the_goal(d, k, s0, s.x), 0.0, atol=1e-10)
    # the least-norm correction that does so: none is smaller (a random perturbation within
    # the equalities' null space only grows it)
    assert np.linalg.norm(s.x[:-1]) > 0.0


def _predicted_flags(d: mpc.Design, plan, k: int, s0: Array, x: Array) -> Array:  # type: ignore[no-untyped-def]
    """The applied flag (y, y', y'') at the start of each horizon sample i: the plan's plus
    the predicted errors, stepping the discrete recursion (numpy), y'' with the PD terms and
    the correction."""
    n_out = d.kp.shape[0]
    horizon = d.gamma.shape[1]
    ts = d.every * 0.001
    flags = []
    s = s0.reshape(n_out, 2).copy()
    for i in range(min(horizon, d.samples - k)):
        ref = plan.flags(np.array([(k + i) * ts]))[0]
        dv = x[i * n_out: (i + 1) * n_out]
        flag = ref.copy()
        flag[:n_out] += s[:, 0]
        flag[n_out: 2 * n_out] += s[:, 1]
        flag[2 * n_out:] += -d.kp * s[:, 0] - d.kv * s[:, 1] + dv
        flags.append(flag)
        s = np.array([d.phi[j, 1] @ s[j] + d.gamma[j, 0] * dv[j] for j in range(n_out)])
    return np.array(flags)


def test_the_rate_limit_holds_at_the_predicted_samples(paper_plan) -> None:  # type: ignore[no-untyped-def]
    """A limit the plan keeps over the horizon (its joint rates stay below 1.7 rad/s from
    t = 0.8 s to 1 s) and an initial error that would break it: the correction keeps every
    predicted joint rate within it, evaluated by the linearisation (exactly, to rounding)
    and by the model's nonlinear flag map (to the linearisation's error: 7 % of the limit
    for these rates 6-8 rad/s away from the plan's, which the docs state)."""
    limit = 10.0
    settings = mpc.MpcSettings(every=20, horizon=10, margin=0.0)
    d = _design(paper_plan, limit, settings)
    kept = limit * (1.0 - settings.backoff)
    k = 40
    assert np.abs(d.rates[k: k + 11]).max() < 1.7
    s0 = np.array([0.0, 0.0, 0.0, 0.1])  # a y2' error that pushes th2' beyond the limit
    free = _solve(mpc.design(paper_plan.model, paper_plan.trajectory, paper_plan.duration,
                             0.001, d.kp, d.kv, math.inf, settings), k, s0)
    flags = _predicted_flags(d, paper_plan, k, s0, free.x)
    free_rates = paper_plan.model.flag_values(flags.T)[3:5]
    assert np.abs(free_rates).max() > kept  # without the limit it is broken
    s = _solve(d, k, s0)
    assert s.counters[1] == 0.0  # feasible: no slack
    flags = _predicted_flags(d, paper_plan, k, s0, s.x)
    # the linearisation, evaluated independently: rate = rate_ref + slopes @ (flag - ref)
    for i, flag in enumerate(flags):
        ref = paper_plan.flags(np.array([(k + i) * d.every * 0.001]))[0]
        linear = d.rates[k + i] + d.rate_slopes[k + i] @ (flag - ref)
        assert np.all(np.abs(linear) <= kept + 1e-9)
    nonlinear = paper_plan.model.flag_values(flags.T)[3:5]
    assert np.abs(nonlinear).max() <= limit * 1.08


def test_an_unreachable_limit_is_met_by_the_slack_and_counted(paper_plan) -> None:  # type: ignore[no-untyped-def]
    """A limit below the plan's th1' at the sample (0.6 rad/s at t = 1 s): th1' = u1 is a
    state no correction changes at once, so the slack takes the excess (at least 0.6 - 0.5
    (1 - backoff) rad/s) and the sample counts as infeasible. th2', which the correction
    commands directly, is brought within the limit though the plan's is 1.67 rad/s."""
    settings = mpc.MpcSettings(every=20, horizon=5, margin=0.0)
    d = _design(paper_plan, 0.5, settings)
    k = 50
    assert d.rates[k, 0] == pytest.approx(0.6, abs=1e-9)
    assert abs(d.rates[k, 1]) > 1.6
    s = _solve(d, k, np.zeros(4))
    assert s.counters[1] == 1.0
    assert s.counters[2] >= 0.6 - 0.5 * (1 - settings.backoff) - 1e-9
