"""The paper's robot (N = 2) in closed loop: its compiled batch kernels.

``_kinematic_kernel`` and ``_dynamic_kernel`` integrate every trial of a batch, one at a
time, by the compiled integrators of ``integrate`` (RK4 or the adaptive Dormand-Prince) on
the kinematic or the dynamic plant (``plant``), observe each output sample
(``metrics.observe_sample``) and conclude each trial (``metrics.conclude_trial``); the other
kernels evaluate the same right-hand sides and observers one call at a time, for the scipy
reference (``reference``). ``chainloop`` and ``chaindynamic`` are the same for N-link chains;
``simulate`` dispatches to all of them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable, kernel
from flatcli.core.control import Gains
from flatcli.core.integrate import WORK_ROWS, make_trial_integrators, plan_flag
from flatcli.core.metrics import (
    ACCUMULATOR_SIZE,
    conclude_trial,
    finish_metrics,
    observe_sample,
    observe_torque,
    plan_momentum_residual,
    reset_accumulator,
)
from flatcli.core.model import Coefficients, Links
from flatcli.core.plant import (
    AUX_C1,
    AUX_R2,
    AUX_S1,
    AUX_SATURATED,
    AUX_TAU1,
    AUX_TAU2,
    DYNAMIC_AUX,
    DYNAMIC_STATE,
    KINEMATIC_AUX,
    KINEMATIC_STATE,
    DynamicLoop,
    Loop,
    dynamic_initial,
    dynamic_loop,
    dynamic_momentum,
    dynamic_rhs,
    kinematic_momentum,
    kinematic_rhs,
)

Array = NDArray[np.float64]

#: The kernels' integrator codes: RK4, the adaptive Dormand-Prince (the chain kernels also
#: read 0 as RK4).
_METHOD_RK4 = 0
_METHOD_ADAPTIVE = 1


def _plain(k: Coefficients) -> Coefficients:
    return Coefficients(*(float(v) for v in k))


@jitable
def _observe_kinematic(loop: Loop, obs: Any, acc: Array, j: int, x: Array, f: Array) -> None:
    """Metrics of the kinematic plant at output sample j: H from the full link kinematics at
    the state with the joint rates the plant applies there (f)."""
    theta_ref, ref, threshold = obs
    observe_sample(acc, j, x[0], x[1], x[2], x[3], f[5], f[6], f[1], f[2],
                   kinematic_momentum(loop, x, f), theta_ref, ref, loop.kc, loop.h0, threshold)


_rk4_kinematic, _adaptive_kinematic = make_trial_integrators(kinematic_rhs, _observe_kinematic)


@jitable
def _observe_dynamic(loop: DynamicLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
                     ) -> None:
    """Metrics of the dynamic plant at output sample j: H from the full link kinematics at
    the state (its own rates), the joint rates and torques it applies."""
    theta_ref, ref, threshold = obs
    observe_sample(acc, j, x[0], x[1], x[2], x[6], f[AUX_C1], f[AUX_S1], x[4], x[5],
                   dynamic_momentum(loop, x, f), theta_ref, ref, loop.kc, loop.h0, threshold)
    observe_torque(acc, f[AUX_TAU1], f[AUX_TAU2], f[AUX_SATURATED])


@jitable
def _record_dynamic(trace: Array, j: int, nx: int, x: Array, f: Array) -> None:
    """Trace row j of the dynamic plant (``DYNAMIC_TRACE_COLUMNS``)."""
    for i in range(nx):
        trace[j, i] = x[i]
    trace[j, nx] = f[AUX_TAU1]
    trace[j, nx + 1] = f[AUX_TAU2]
    trace[j, nx + 2] = f[AUX_R2]


_rk4_dynamic, _adaptive_dynamic = make_trial_integrators(dynamic_rhs, _observe_dynamic,
                                                         _record_dynamic)


# fmt: off
@jitable
def _links_row(a: Array, i: int) -> Links:
    return Links(a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5],
                 a[i, 6], a[i, 7], a[i, 8], a[i, 9], a[i, 10], a[i, 11])


@jitable
def _coefficients_row(a: Array, i: int) -> Coefficients:
    return Coefficients(a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5],
                        a[i, 6], a[i, 7], a[i, 8], a[i, 9], a[i, 10])
# fmt: on


@jitable
def _is_flat(k: Coefficients) -> bool:
    """Whether a plant's constraint has no d2-terms (d2 = 0)."""
    return (k.a2 == 0.0 and k.a3 == 0.0 and k.b2 == 0.0 and k.b3 == 0.0 and k.c2 == 0.0
            and k.c3 == 0.0)


@kernel
def _kinematic_kernel(
    method: int,
    kc: Coefficients,
    gains: Gains,
    links: Array,
    plant_k: Array,
    h0: Array,
    rate_limit: float,
    initial: Array,
    ref: Array,
    theta_ref: Array,
    breaks: Array,
    local: Array,
    plan_theta: Array,
    plan_theta_dot: Array,
    dt: float,
    bound: float,
    threshold: float,
    rtol: float,
    atol: float,
    max_steps: int,
    tables: Array,
    gen: Any,
    std: float,
    record: bool,
    metrics: Array,
    status: NDArray[np.int64],
    event: NDArray[np.int64],
    event_time: Array,
    trace: Array,
) -> None:
    """Integrate every trial of a batch, one at a time; write metrics, status, events and
    (maybe) traces.

    Shapes: ref (2n+1, 6); theta_ref (n+1, 3); breaks (m+1,), local (m, d+1, 2);
    plan_theta, plan_theta_dot (p, 3); links (N, 12); plant_k (N, 11); h0 (N,);
    initial (N, 4); tables (N, n, 3) or (N, 0, 3); metrics (N, N_METRICS);
    status, event, event_time (N,); trace (N, n+1, 7) if record.
    """
    n = theta_ref.shape[0] - 1
    nx = KINEMATIC_STATE
    work = np.empty((WORK_ROWS, nx + KINEMATIC_AUX))
    acc = np.empty(ACCUMULATOR_SIZE)
    noise = np.zeros(3)
    flag = np.empty(6)
    scratch = np.empty((0, nx + 3))
    obs = (theta_ref, ref, threshold)
    for i in range(links.shape[0]):
        p = _links_row(links, i)
        kq = _coefficients_row(plant_k, i)
        loop = Loop(kc, gains, kq, p, p.m0 + p.m1 + p.m2, h0[i], rate_limit, _is_flat(kq))
        reset_accumulator(acc)
        tr = trace[i] if record else scratch
        x0 = initial[i]
        if method == _METHOD_RK4:
            last, ev, t_ev = _rk4_kinematic(loop, obs, x0, ref, dt, n, bound, tables[i], gen,
                                            std, record, tr, acc, work, noise)
            estimate, steps, evaluations = math.nan, last, 4 * last + 1
        else:
            last, ev, t_ev, estimate, steps, evaluations = _adaptive_kinematic(
                loop, obs, x0, breaks, local, dt, n, bound, rtol, atol, max_steps, 3,
                tables[i], gen, std, record, tr, acc, work, noise, flag, ref)
        _conclude(i, p, h0[i], plan_theta, plan_theta_dot, acc, last, n, ev, t_ev, estimate,
                  steps, evaluations, dt, record, tr, metrics, status, event, event_time)


@jitable
def _conclude(
    i: int, p: Links, h0: float, plan_theta: Array, plan_theta_dot: Array, acc: Array,
    last: int, n: int, ev: int, t_ev: float, estimate: float, steps: int, evaluations: int,
    dt: float, record: bool, tr: Array, metrics: Array, status: NDArray[np.int64],
    event: NDArray[np.int64], event_time: Array,
) -> None:
    """Trial i's metrics, status, event and event time from its run; its trace blanked
    after the last valid sample."""
    conclude_trial(i, plan_momentum_residual(plan_theta, plan_theta_dot, p, h0), acc, last, n,
                   ev, t_ev, estimate, steps, evaluations, dt, record, tr, metrics, status,
                   event, event_time)


@kernel
def _dynamic_kernel(
    method: int,
    kc: Coefficients,
    gains: Gains,
    robot: Links,
    servo_is_plant: bool,
    links: Array,
    h0: Array,
    servo: Array,
    rate_limit: float,
    initial: Array,
    ref: Array,
    theta_ref: Array,
    breaks: Array,
    local: Array,
    plan_theta: Array,
    plan_theta_dot: Array,
    dt: float,
    bound: float,
    threshold: float,
    rtol: float,
    atol: float,
    max_steps: int,
    tables: Array,
    gen: Any,
    std: float,
    record: bool,
    metrics: Array,
    status: NDArray[np.int64],
    event: NDArray[np.int64],
    event_time: Array,
    trace: Array,
) -> None:
    """``_kinematic_kernel`` for the dynamic plant: ``robot`` is the nominal robot (the
    servo's model unless ``servo_is_plant``), servo (N, 2) each trial's bandwidth [rad/s] and
    torque limit [N m], initial (N, 4) th(0) and u1(0) (``plant.dynamic_initial`` completes
    the state); trace (N, n+1, 10) if record (``DYNAMIC_TRACE_COLUMNS``)."""
    n = theta_ref.shape[0] - 1
    nx = DYNAMIC_STATE
    work = np.empty((WORK_ROWS, nx + DYNAMIC_AUX))
    acc = np.empty(ACCUMULATOR_SIZE)
    noise = np.zeros(3)
    flag = np.empty(6)
    scratch = np.empty((0, nx + 3))
    x0 = np.empty(nx)
    obs = (theta_ref, ref, threshold)
    for i in range(links.shape[0]):
        p = _links_row(links, i)
        loop = dynamic_loop(kc, gains, p, robot, servo_is_plant, h0[i], rate_limit,
                            servo[i, 0], servo[i, 1])
        dynamic_initial(loop, initial[i], ref[0], x0)
        reset_accumulator(acc)
        tr = trace[i] if record else scratch
        if method == _METHOD_RK4:
            last, ev, t_ev = _rk4_dynamic(loop, obs, x0, ref, dt, n, bound, tables[i], gen,
                                          std, record, tr, acc, work, noise)
            estimate, steps, evaluations = math.nan, last, 4 * last + 1
        else:
            last, ev, t_ev, estimate, steps, evaluations = _adaptive_dynamic(
                loop, obs, x0, breaks, local, dt, n, bound, rtol, atol, max_steps, 3,
                tables[i], gen, std, record, tr, acc, work, noise, flag, ref)
        _conclude(i, p, h0[i], plan_theta, plan_theta_dot, acc, last, n, ev, t_ev, estimate,
                  steps, evaluations, dt, record, tr, metrics, status, event, event_time)


@kernel
def _dynamic_rhs_kernel(loop: DynamicLoop, x: Array, ref: Array, noise: Array) -> Array:
    out = np.empty(DYNAMIC_STATE + DYNAMIC_AUX)
    dynamic_rhs(loop, x, ref, noise, out)
    return out


@kernel
def _dynamic_rhs_at(
    loop: DynamicLoop, breaks: Array, local: Array, t: float, x: Array, noise: Array
) -> Array:
    """The dynamic plant's state derivative (7,) at time t (for solve_ivp)."""
    ref = np.empty(6)
    plan_flag(breaks, local, t, ref)
    out = np.empty(DYNAMIC_STATE + DYNAMIC_AUX)
    dynamic_rhs(loop, x, ref, noise, out)
    return out[:DYNAMIC_STATE]


@kernel
def _dynamic_start(loop: DynamicLoop, initial: Array, ref: Array) -> Array:
    """The dynamic plant's state at t = 0 (``plant.dynamic_initial``)."""
    x0 = np.empty(DYNAMIC_STATE)
    dynamic_initial(loop, initial, ref, x0)
    return x0


@kernel
def _make_dynamic_loop(kc: Coefficients, gains: Gains, links: Links, robot: Links,
                       servo_is_plant: bool, h0: float, rate_limit: float, bandwidth: float,
                       torque_limit: float) -> DynamicLoop:
    return dynamic_loop(kc, gains, links, robot, servo_is_plant, h0, rate_limit, bandwidth,
                        torque_limit)


@kernel
def _observe_dynamic_trace_kernel(
    loop: DynamicLoop, theta_ref: Array, ref: Array, threshold: float, states: Array,
    rates: Array, last: int, complete: bool, dt: float, plan_theta: Array,
    plan_theta_dot: Array, out: Array,
) -> int:
    """``_observe_trace_kernel`` for the dynamic plant: states (n+1, 7), right-hand sides
    (n+1, 7 + DYNAMIC_AUX)."""
    acc = np.empty(ACCUMULATOR_SIZE)
    reset_accumulator(acc)
    obs = (theta_ref, ref, threshold)
    for j in range(last + 1):
        _observe_dynamic(loop, obs, acc, j, states[j], rates[j])
    residual = plan_momentum_residual(plan_theta, plan_theta_dot, loop.links, loop.h0)
    return finish_metrics(out, acc, complete, dt, residual, math.nan, 0, 0)


@kernel
def _kinematic_rhs_kernel(loop: Loop, x: Array, ref: Array, noise: Array) -> Array:
    out = np.empty(KINEMATIC_STATE + KINEMATIC_AUX)
    kinematic_rhs(loop, x, ref, noise, out)
    return out


@kernel
def _kinematic_rhs_at(
    loop: Loop, breaks: Array, local: Array, t: float, x: Array, noise: Array
) -> Array:
    """The state's derivative (4,) at time t, the plan evaluated there (for solve_ivp)."""
    ref = np.empty(6)
    plan_flag(breaks, local, t, ref)
    out = np.empty(KINEMATIC_STATE + KINEMATIC_AUX)
    kinematic_rhs(loop, x, ref, noise, out)
    return out[:KINEMATIC_STATE]


@kernel
def _observe_trace_kernel(
    loop: Loop, theta_ref: Array, ref: Array, threshold: float, states: Array, rates: Array,
    last: int, complete: bool, dt: float, plan_theta: Array, plan_theta_dot: Array,
    out: Array,
) -> int:
    """Metrics of a trace computed elsewhere (the reference integrator): states (n+1, 4) and
    right-hand sides (n+1, 4 + KINEMATIC_AUX), samples 0..last."""
    acc = np.empty(ACCUMULATOR_SIZE)
    reset_accumulator(acc)
    obs = (theta_ref, ref, threshold)
    for j in range(last + 1):
        _observe_kinematic(loop, obs, acc, j, states[j], rates[j])
    residual = plan_momentum_residual(plan_theta, plan_theta_dot, loop.links, loop.h0)
    return finish_metrics(out, acc, complete, dt, residual, math.nan, 0, 0)

