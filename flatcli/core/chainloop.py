"""The closed loop of an N-link chain (N >= 3; the paper's robot keeps ``plant``).

The prolonged state is x = (th0 .. th_N, u_1 .. u_N-1), 2 N numbers. The controller measures
the angles (+ noise), computes the flat outputs with its model (``chainflat.outputs``), asks
for v_j = y_jd'' + kv_j (y_jd' - y_j') + kp_j (y_jd - y_j), j = 1..N, and commands the inputs
that make y'' = v (``chainflat.inputs``): u_j' and th_N'. The kinematic plant applies the
joint rates th_j' = sat(u_j) (j < N) and th_N' = sat(command), clipped to +-rate_limit (with
the same conditional integration of u_j as ``plant``), and th0' from its own momentum
H0 = sum_j h_j th_j' with its own K (any d_N: an imperfect counterweight included).

``chain_rhs`` writes the state's derivative into out[:2N] and the controller's signed margin
sigma into out[2N], like ``plant.kinematic_rhs``, so the same compiled integrators
(``integrate``) run it; ``chain_kernel`` runs a batch of trials.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable, kernel
from flatcli.core.chain import (
    barycentric_matrix,
    chain_momentum_at,
    link_trig,
    momentum_weights_given,
)
from flatcli.core.chainflat import (
    Scratch,
    first_terms_into,
    inputs_given,
    outputs_given,
    scratch_like,
    terms_into,
)
from flatcli.core.integrate import WORK_ROWS, make_trial_integrators
from flatcli.core.metrics import (
    ACCUMULATOR_SIZE,
    conclude_trial,
    observe_errors,
    reset_accumulator,
)

Array = NDArray[np.float64]



class ChainLoop(NamedTuple):
    """What one trial's closed loop needs (arrays and floats, for the kernels).

    Kc, Ic : the controller's K (N + 1, N + 1) and inertias (N + 1,)
    kp, kv : gains (N,) [1/s^2, 1/s]
    Kq, Iq : the plant's K and inertias; params : the plant's (4 (N + 1),) mass, inertia,
        length, com side by side (for H from the full kinematics)
    h0 : the plant's angular momentum [kg m^2/s]; rate_limit : joint-rate limit [rad/s]
    buffers : (6, N + 1) scratch rows for the right-hand side
    work : the flat maps' scratch (``chainflat.Scratch``)
    """

    Kc: Array
    Ic: Array
    kp: Array
    kv: Array
    Kq: Array
    Iq: Array
    params: Array
    h0: float
    rate_limit: float
    buffers: Array
    work: Scratch


@jitable
def chain_rhs(loop: ChainLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the chain's prolonged state under the feedback.

    Parameters
    ----------
    loop : ChainLoop
    x : (2 N,) th0..th_N [rad], u_1..u_N-1 [rad/s]
    ref : (3 N,) plan y, y', y'' at this instant
    noise : (N + 1,) sensor noise on the measured angles [rad]
    out : (>= 2 N + 1,) written: th0'..th_N' [rad/s] (the applied rates), u' [rad/s^2], then
        the controller's signed margin sigma [rad/s]
    """
    n = loop.Ic.shape[0] - 1
    buf = loop.buffers
    measured, y, y_dot, v, h = buf[0], buf[1, :n], buf[2, :n], buf[3, :n], buf[4]
    u_dot = buf[5, : n - 1]
    for i in range(n + 1):
        measured[i] = x[i] + noise[i]
    u = x[n + 1: 2 * n]
    work = loop.work
    h0 = terms_into(loop.Kc, loop.Ic, measured, work)  # once for both maps
    h_c, grad, hess, slopes = work.h, work.grad, work.hess, work.slopes
    sigma = outputs_given(loop.Kc, loop.Ic, h0, h_c, grad, measured, u, y, y_dot)
    for j in range(n):
        v[j] = (ref[2 * n + j] + loop.kv[j] * (ref[n + j] - y_dot[j])
                + loop.kp[j] * (ref[j] - y[j]))
    command = inputs_given(loop.Ic, h0, h_c, grad, hess, slopes, measured, u, v, u_dot)
    limit = loop.rate_limit
    link_trig(x[: n + 1], work.cs, work.sn)  # the plant's own angles
    momentum_weights_given(loop.Kq, loop.Iq, work.cs, work.sn, h)
    base = loop.h0
    for j in range(1, n):
        rate = min(max(x[n + j], -limit), limit)
        out[j] = rate
        base -= h[j] * rate
        step = u_dot[j - 1]
        if (x[n + j] >= limit and step > 0.0) or (x[n + j] <= -limit and step < 0.0):
            step = 0.0  # conditional integration: no wind-up while th_j' is clipped
        out[n + j] = step
    last = min(max(command, -limit), limit)
    out[n] = last
    base -= h[n] * last
    out[0] = base / h[0]
    out[2 * n] = sigma


@jitable
def _observe_chain(loop: ChainLoop, obs: Any, acc: Array, j: int, x: Array, f: Array) -> None:
    """Metrics of the chain at output sample j (see ``metrics``): angle and flat-output
    errors, the margin |sigma| at the true state, H from the full kinematics at the state
    with the applied rates, the largest applied joint rate."""
    theta_ref, ref, threshold = obs
    n = loop.Ic.shape[0] - 1
    buf = loop.buffers
    y, y_dot = buf[1, :n], buf[2, :n]
    et2 = 0.0
    for i in range(n + 1):
        d = x[i] - theta_ref[j, i]
        et2 += d * d
    work = loop.work
    theta = x[: n + 1]
    h0 = first_terms_into(loop.Kc, loop.Ic, theta, work)
    sigma = outputs_given(loop.Kc, loop.Ic, h0, work.h, work.grad, theta, x[n + 1: 2 * n], y,
                          y_dot)
    ey2 = 0.0
    for i in range(n):
        e = y[i] - ref[2 * j, i]
        ey2 += e * e
    peak = 0.0
    for i in range(1, n + 1):
        peak = max(peak, abs(f[i]))
    h = chain_momentum_at(loop.params, x[: n + 1], f[: n + 1])
    observe_errors(acc, j, et2, ey2, abs(sigma), h, loop.h0, peak, threshold)


_rk4_chain, _adaptive_chain = make_trial_integrators(chain_rhs, _observe_chain)


@jitable
def plan_residual(plan_theta: Array, plan_theta_dot: Array, params: Array, h0: float) -> float:
    """max_j |H - H0| of the plan's own samples with the plant's parameters [kg m^2/s]."""
    residual = 0.0
    for j in range(plan_theta.shape[0]):
        residual = max(residual, abs(chain_momentum_at(params, plan_theta[j],
                                                       plan_theta_dot[j]) - h0))
    return residual


@kernel
def chain_kernel(
    method: int, Kc: Array, Ic: Array, kp: Array, kv: Array, Kq: Array, params: Array,
    h0: Array, rate_limit: float, initial: Array, ref: Array, theta_ref: Array, breaks: Array,
    local: Array, plan_theta: Array, plan_theta_dot: Array, dt: float, bound: float,
    threshold: float, rtol: float, atol: float, max_steps: int, tables: Array, gen: Any,
    std: float, record: bool, metrics: Array, status: NDArray[np.int64],
    event: NDArray[np.int64], event_time: Array, trace: Array,
) -> None:
    """Integrate every trial of a batch of an N-link chain, one at a time.

    Shapes: ref (2n+1, 3N); theta_ref (n+1, N+1); Kq (T, N+1, N+1); params (T, 4(N+1));
    h0 (T,); initial (T, 2N); tables (T, n, N+1) or (T, 0, N+1); metrics (T, N_METRICS);
    trace (T, n+1, 3N+1) if record (the state, then the applied rates th0'..th_N').
    """
    n_out = theta_ref.shape[0] - 1
    nb = Ic.shape[0]
    nx = 2 * (nb - 1)
    work = np.empty((WORK_ROWS, nx + 1))
    acc = np.empty(ACCUMULATOR_SIZE)
    noise = np.zeros(nb)
    flag = np.empty(ref.shape[1])
    scratch = np.empty((0, nx + nb))
    obs = (theta_ref, ref, threshold)
    buffers = np.zeros((6, nb))
    maps = scratch_like(Ic)
    for i in range(params.shape[0]):
        p = params[i]
        loop = ChainLoop(Kc, Ic, kp, kv, Kq[i], p[nb: 2 * nb], p, h0[i], rate_limit, buffers,
                         maps)
        reset_accumulator(acc)
        tr = trace[i] if record else scratch
        if method == 0:
            last, ev, t_ev = _rk4_chain(loop, obs, initial[i], ref, dt, n_out, bound,
                                        tables[i], gen, std, record, tr, acc, work, noise)
            estimate, steps, evaluations = math.nan, last, 4 * last + 1
        else:
            last, ev, t_ev, estimate, steps, evaluations = _adaptive_chain(
                loop, obs, initial[i], breaks, local, dt, n_out, bound, rtol, atol, max_steps,
                nb, tables[i], gen, std, record, tr, acc, work, noise, flag, ref)
        conclude_trial(i, plan_residual(plan_theta, plan_theta_dot, p, h0[i]), acc, last,
                       n_out, ev, t_ev, estimate, steps, evaluations, dt, record, tr, metrics,
                       status, event, event_time)


def run_chain_kernel(
    scenario: Any, trials: Any, method: int, record: bool, metrics: Array,
    status: NDArray[np.int64], event: NDArray[np.int64], event_time: Array, trace: Array,
    rows: slice, tables: Array, gen: np.random.Generator, std: float,
) -> None:
    """``chain_kernel`` on trials ``rows`` of a scenario whose plan is a ``ChainPlan``."""
    plan = scenario.plan
    gains = scenario.gains
    n = plan.n_joints
    params = np.ascontiguousarray(trials.links[rows], dtype=float)
    Kq = np.stack([chain_matrix(p, n) for p in params]) if len(params) else np.empty(
        (0, n + 1, n + 1))
    plan_theta, plan_theta_dot = scenario.plan_on_own_grid
    breaks, local = scenario.pieces
    chain_kernel(
        method, plan.model.K, plan.model.inertia, np.asarray(gains.kp, dtype=float),
        np.asarray(gains.kv, dtype=float), np.ascontiguousarray(Kq), params,
        np.ascontiguousarray(trials.momentum[rows], dtype=float), float(scenario.rate_limit),
        np.ascontiguousarray(trials.initial[rows], dtype=float), scenario.reference,
        scenario.theta_reference, breaks, local, plan_theta, plan_theta_dot,
        float(scenario.dt), float(scenario.divergence_bound), float(scenario.singular_threshold),
        float(scenario.rtol), float(scenario.atol), int(scenario.max_steps), tables, gen, std,
        record, metrics[rows], status[rows], event[rows], event_time[rows],
        trace[rows] if record else trace,
    )


def chain_matrix(params: Array, n: int) -> Array:
    """K of a chain from its (4 (N + 1),) parameters (mass, inertia, length, com)."""
    nb = n + 1
    return np.ascontiguousarray(barycentric_matrix(params[:nb], params[2 * nb: 3 * nb],
                                                   params[3 * nb: 4 * nb]))


class ChainGains(NamedTuple):
    """Feedback gains of an N-link chain: kp (N,) [1/s^2] and kv (N,) [1/s], one per flat
    output y_1..y_N."""

    kp: tuple[float, ...]
    kv: tuple[float, ...]
