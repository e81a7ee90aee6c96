"""The as-built controller in closed loop: the kernels' functions for both plants, any N.

The controller (``lqr``) reads from the tracked flag (``lqr.TrackedLayout``) the plan's angles
th_r, the joints' rates w_r and accelerations a_r, and the gains L, and commands the joint
rates

    w = w_r - L (th_measured - th_r),      r = sat(w)  (kinematic plant),
                                           r = sat(w + a_r / bandwidth)  (dynamic plant),

the dynamic plant's command leading its servo's first-order lag by the plan's acceleration
(so that a servo whose model is right follows the plan exactly when the state is on it).
There is no integrator in the law, so nothing winds up against a rate or torque limit.

The plants are those of ``chainloop`` and ``chaindynamic`` (the same functions of ``chain``
and ``dynamics``), any d_N, with the plant's centre of mass across its last link as the turn
of that link's trigonometry (``chain.turn_last``; the plant's parameters are those of its
equivalent placement, ``model.RobotParams.placement``):

* kinematic, x = (th0 .. th_N): th_j' = r_j, th0' = (H0 - sum_j h_j r_j) / h_0;
* dynamic, x = (th, th'): M q'' + C q' = (0, tau), tau from the rate servo of
  ``chaindynamic.servo_demand`` (its model the plant's, or the controller's robot turned by
  the robot's own offset).

Each right-hand side writes the state's derivative, then 1.0 where the integrators look for
the controller's signed margin (the law has no singular set: the margin never changes sign,
so no trial meets a crossing, ``crossings`` is 0), then the plant's aux values (the dynamic
plant's torques, saturation flag and every rate command). The metrics
(``metrics.observe_errors``) observe an infinite margin: no singular hits, ``min_margin``
null (no status ``singular``); err_y is the error of the joint angles th_1..th_N (the
"outputs" of an exact plan).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.loop.chaindynamic import (
    _C,
    _C_S,
    _CHAT_S,
    _M,
    _M_S,
    _MHAT,
    _MHAT_S,
    _Q_DDOT,
    _R,
    _RHS,
    _TAU,
    ChainDynamicLoop,
    make_scratch,
    same_chain,
    servo_demand,
)
from flatcli.core.loop.metrics import observe_clipped, observe_errors, observe_torque
from flatcli.core.models.chainflat import Scratch, scratch
from flatcli.core.robots.chain import (
    chain_momentum_given,
    link_trig,
    momentum_weights_given,
    turn_last,
)
from flatcli.core.robots.dynamics import (
    Chain,
    absolute_motion,
    chain_terms,
    free_floating_accelerations,
    joint_accelerations,
    joint_space,
)

Array = NDArray[np.float64]

#: The threshold the metrics compare the margin with: none (below any margin), and the
#: margin they observe: the law has no singular set.
NO_THRESHOLD = -1.0
NO_MARGIN = math.inf
#: Rows of ``AsbuiltScratch.rows`` (each N + 1 long): measured angles, rate commands,
#: h, the plant's cos, sin.
_MEAS, _CMD, _H, _CS, _SN = range(5)
ROWS = 5


class AsbuiltShared(NamedTuple):
    """What every trial shares: the controller's robot (its equivalent placement's K and
    inertias, for the dynamic plant's servo model), cos and sin of its offset, the joint-rate
    limit [rad/s], whether the servo knows the plant, and (the dynamic plant) the lead
    1 / b_s [s] of the servo the law was designed for and whether the gains act on the joint
    rates too."""

    Kc: Array
    Ic: Array
    cos_c: float
    sin_c: float
    rate_limit: float
    servo_is_plant: bool
    lead: float = 0.0
    lagged: bool = False


class AsbuiltScratch(NamedTuple):
    """A loop's buffers: rows (ROWS, N + 1), the servo model's trig (TRIG_ROWS, N + 1),
    the dynamic plant's (``chaindynamic.make_scratch``) and a flat-map scratch its record
    carries (unused)."""

    rows: Array
    servo_trig: Array
    dynamic_rows: Array
    trig: Array
    matrices: Array
    maps: Scratch


def asbuilt_scratch(n: int) -> AsbuiltScratch:
    nb = n + 1
    return AsbuiltScratch(np.zeros((ROWS, nb)), np.zeros((3, nb)), *make_scratch(n),
                          scratch(n))


class AsbuiltLoop(NamedTuple):
    """One trial: the plant's K, inertias, parameters (4 (N + 1),) of its equivalent
    placement and cos, sin of its offset; H0 [kg m^2/s]; the shared record; the buffers; the
    dynamic plant's record (``chaindynamic.ChainDynamicLoop``: its servo and matrices)."""

    Kq: Array
    Iq: Array
    params: Array
    cos_p: float
    sin_p: float
    h0: float
    shared: AsbuiltShared
    rows: Array
    servo_trig: Array
    dyn: ChainDynamicLoop


@jitable
def asbuilt_loop(shared: AsbuiltShared, Kq: Array, params: Array, offset: float, h0: float,
                 bandwidth: float, torque_limit: float, work: AsbuiltScratch) -> AsbuiltLoop:
    """Trial's loop record (``offset``: its plant's turn of the last link [rad])."""
    nb = shared.Ic.shape[0]
    Iq = params[nb: 2 * nb]
    cos_p, sin_p = np.cos(offset), np.sin(offset)
    plant = Chain(Kq, Iq)
    servo = plant if shared.servo_is_plant else Chain(shared.Kc, shared.Ic)
    same = shared.servo_is_plant or (same_chain(plant, servo) and cos_p == shared.cos_c
                                     and sin_p == shared.sin_c)
    # the flat law's fields of the record (its gains, its maps) are not used here, nor its
    # turn (``_servo_terms`` turns the plant's and the servo model's trigonometry itself)
    dyn = ChainDynamicLoop(shared.Kc, shared.Ic, shared.Ic, shared.Ic, plant, servo, same,
                           params, h0, shared.rate_limit, bandwidth, torque_limit,
                           work.dynamic_rows, work.trig, work.matrices, work.maps, 1.0, 0.0)
    return AsbuiltLoop(Kq, Iq, params, cos_p, sin_p, h0, shared, work.rows, work.servo_trig,
                       dyn)


@jitable
def commands(loop: AsbuiltLoop, x: Array, ref: Array, noise: Array) -> None:
    """The rate commands r_j (N,) into rows[_CMD, :N]: the law at the measured angles
    x[:N + 1] + noise (and, lagged, the joints' rates x[N + 2:]), plus the lead times the
    plan's joint accelerations, clipped to the rate limit (``lqr.TrackedLayout``)."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    shared = loop.shared
    width = 2 * n + 1 if shared.lagged else nb
    c = nb + n * width
    meas = loop.rows[_MEAS]
    for a in range(nb):
        meas[a] = x[a] + noise[a]
    limit = shared.rate_limit
    cmd = loop.rows[_CMD]
    for j in range(1, nb):
        w = ref[c + j - 1] + shared.lead * ref[2 * c + j - 1]
        base = nb + (j - 1) * width
        w -= ref[base] * (meas[0] - ref[n])
        for a in range(1, nb):
            w -= ref[base + a] * (meas[a] - ref[a - 1])
        if shared.lagged:
            for k in range(1, nb):
                w -= ref[base + n + k] * (x[nb + k] - ref[c + k - 1])
        cmd[j - 1] = min(max(w, -limit), limit)


@jitable
def plant_trig(loop: AsbuiltLoop, theta: Array) -> None:
    """The plant's trigonometry at theta[:N + 1] into rows[_CS], rows[_SN] (turned; an
    integrator's state rows are longer than the state)."""
    cs, sn = loop.rows[_CS], loop.rows[_SN]
    link_trig(theta[: cs.shape[0]], cs, sn)
    turn_last(cs, sn, loop.cos_p, loop.sin_p)


@jitable
def kinematic_rhs(loop: AsbuiltLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the kinematic plant under the as-built law.

    Parameters
    ----------
    x : (N + 1,) th0..th_N [rad]; ref : the tracked flag (``lqr.TrackedLayout``)
    noise : (N + 1,) sensor noise on the measured angles [rad]
    out : (>= N + 2,) written: th0'..th_N' [rad/s] (the applied rates), then 1.0
    """
    nb = loop.Iq.shape[0]
    commands(loop, x, ref, noise)
    plant_trig(loop, x[:nb])
    h = loop.rows[_H]
    momentum_weights_given(loop.Kq, loop.Iq, loop.rows[_CS], loop.rows[_SN], h)
    cmd = loop.rows[_CMD]
    base = loop.h0
    for j in range(1, nb):
        out[j] = cmd[j - 1]
        base -= h[j] * cmd[j - 1]
    out[0] = base / h[0]
    out[nb] = 1.0


@jitable
def squared_errors(obs: Any, j: int, x: Array, nb: int) -> tuple[float, float]:
    """At output sample j, the squared norms of the angles' error from the plan (th0..thN)
    and of the joint angles' error from the plan's y (th1..thN, the as-built law's
    outputs); ``obs`` = (theta_ref, ref, threshold) as the kernels pass it (the singular
    threshold does not apply: module docstring)."""
    theta_ref, ref, _ = obs
    et2 = 0.0
    ey2 = 0.0
    for i in range(nb):
        d = x[i] - theta_ref[j, i]
        et2 += d * d
        if i > 0:
            e = x[i] - ref[2 * j, i - 1]
            ey2 += e * e
    return et2, ey2


@jitable
def observe_kinematic(loop: AsbuiltLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
                      ) -> None:
    """Metrics of the kinematic plant at output sample j (module docstring)."""
    nb = loop.Iq.shape[0]
    et2, ey2 = squared_errors(obs, j, x, nb)
    plant_trig(loop, x[:nb])
    peak = 0.0
    for i in range(1, nb):
        peak = max(peak, abs(f[i]))
    h = chain_momentum_given(loop.params, loop.rows[_CS], loop.rows[_SN], f[:nb])
    observe_errors(acc, j, et2, ey2, NO_MARGIN, h, loop.h0, peak, NO_THRESHOLD)
    # the joints turn at the clipped commands: at the limit exactly where one was clipped
    observe_clipped(acc, j, peak >= loop.shared.rate_limit)


@jitable
def record_kinematic(loop: Any, trace: Array, j: int, nx: int, x: Array, f: Array
                     ) -> None:
    """Trace row j (``simulate.chain_trace_columns``): th, the rate commands of joints
    1..N-1 (in the columns of the flat loop's u_j), then th0'..th_N'."""
    n = nx - 1
    for i in range(nx):
        trace[j, i] = x[i]
    for i in range(1, n):
        trace[j, nx + i - 1] = f[i]
    for i in range(nx):
        trace[j, nx + n - 1 + i] = f[i]


@jitable
def kinematic_initial(loop: AsbuiltLoop, initial: Array, ref: Array, x0: Array) -> None:
    """th(0) into x0 (N + 1,) (the kinematic plant has no rate state: u(0) does not enter)."""
    for k in range(x0.shape[0]):
        x0[k] = initial[k]


@jitable
def _servo_terms(loop: AsbuiltLoop, theta: Array, rates: Array) -> None:
    """The plant's M, C q' (and the servo model's Mhat, chat) at (theta, rates) into the
    dynamic record's buffers."""
    dyn = loop.dyn
    trig = dyn.trig
    absolute_motion(theta, rates, trig)
    turn_last(trig[0], trig[1], loop.cos_p, loop.sin_p)
    M, c = dyn.matrices[_M], dyn.buffers[_C]
    chain_terms(dyn.plant, trig, M, c)
    if dyn.same_model:
        joint_space(M, c, dyn.matrices[_MHAT_S], dyn.buffers[_CHAT_S])
        return
    servo = loop.servo_trig
    absolute_motion(theta, rates, servo)
    turn_last(servo[0], servo[1], loop.shared.cos_c, loop.shared.sin_c)
    chain_terms(dyn.servo, servo, dyn.matrices[_M_S], dyn.buffers[_C_S])
    joint_space(dyn.matrices[_M_S], dyn.buffers[_C_S], dyn.matrices[_MHAT_S],
                dyn.buffers[_CHAT_S])


@jitable
def dynamic_rhs(loop: AsbuiltLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the dynamic plant under the as-built law and the rate servos.

    Parameters
    ----------
    x : (2 N + 2,) th [rad], th' [rad/s]; ref : the tracked flag; noise : (N + 1,) [rad]
    out : (>= 2 N + 2 + ``dynamic_aux(N)``,) written: th' [rad/s], th'' [rad/s^2]; 1.0;
        tau_1..tau_N [N m], 1.0 if a torque was clipped (else 0.0), r_1..r_N [rad/s]
    """
    nb = loop.Iq.shape[0]
    n = nb - 1
    nx = 2 * nb
    dyn = loop.dyn
    theta, rates = x[:nb], x[nb:nx]
    commands(loop, x, ref, noise)
    cmd = loop.rows[_CMD]
    r = dyn.buffers[_R]
    for j in range(n):
        r[j] = cmd[j]
    _servo_terms(loop, theta, rates)
    saturated = servo_demand(dyn, rates[1:])
    M, c = dyn.matrices[_M], dyn.buffers[_C]
    tau = dyn.buffers[_TAU, :n]
    q_ddot = dyn.buffers[_Q_DDOT]
    if dyn.same_model:
        hat, chat, scratch_hat, rhs = (dyn.matrices[_MHAT_S], dyn.buffers[_CHAT_S],
                                       dyn.matrices[_MHAT], dyn.buffers[_RHS])
        for j in range(n):
            rhs[j] = chat[j]
            for k in range(n):
                scratch_hat[j, k] = hat[j, k]
        joint_accelerations(M, c, tau, scratch_hat, rhs, q_ddot)
    else:
        free_floating_accelerations(M, c, tau, dyn.matrices[_MHAT], dyn.buffers[_RHS], q_ddot)
    for i in range(nb):
        out[i] = rates[i]
        out[nb + i] = q_ddot[i]
    out[nx] = 1.0
    for j in range(n):
        out[nx + 1 + j] = tau[j]
    out[nx + 1 + n] = saturated
    for j in range(n):
        out[nx + 2 + n + j] = r[j]


def dynamic_aux(n: int) -> int:
    """Values ``dynamic_rhs`` writes after the state's derivative: 1.0, tau (N), the
    saturation flag, r (N)."""
    return 2 * n + 2


@jitable
def dynamic_initial(loop: AsbuiltLoop, initial: Array, ref: Array, x0: Array) -> None:
    """The dynamic plant's state at t = 0 into x0 (2 N + 2,): th(0) and the rates th_j'(0)
    = u_j(0) of joints j < N from ``initial`` (2 N,), joint N at the plan's rate, th0' such
    that H = (M q')_0 = H0 (the law acts on the rate errors from there)."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    width = 2 * n + 1 if loop.shared.lagged else nb
    c = nb + n * width
    for a in range(nb):
        x0[a] = initial[a]
    x0[nb] = 0.0
    for j in range(1, n):
        x0[nb + j] = initial[nb + j - 1]
    x0[nb + n] = ref[c + n - 1]
    _servo_terms(loop, x0[:nb], x0[nb:])
    M = loop.dyn.matrices[_M]
    acc = loop.h0
    for k in range(1, nb):
        acc -= M[0, k] * x0[nb + k]
    x0[nb] = acc / M[0, 0]


@jitable
def observe_dynamic(loop: AsbuiltLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
                    ) -> None:
    """Metrics of the dynamic plant at output sample j: errors, the margin of its motion,
    H from the full kinematics with its own rates, peak joint rate and torque, saturation."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    nx = 2 * nb
    et2, ey2 = squared_errors(obs, j, x, nb)
    plant_trig(loop, x[:nb])
    rates = x[nb:nx]
    peak = 0.0
    torque = 0.0
    for i in range(n):
        peak = max(peak, abs(rates[i + 1]))
        torque = max(torque, abs(f[nx + 1 + i]))
    h = chain_momentum_given(loop.params, loop.rows[_CS], loop.rows[_SN], rates)
    observe_errors(acc, j, et2, ey2, NO_MARGIN, h, loop.h0, peak, NO_THRESHOLD)
    observe_torque(acc, torque, 0.0, f[nx + 1 + n])
    # the servos' set points r_1..r_N (clipped commands): at the limit where one was clipped
    limit = loop.shared.rate_limit
    clipped = False
    for i in range(n):
        clipped = clipped or abs(f[nx + 2 + n + i]) >= limit
    observe_clipped(acc, j, clipped)


@jitable
def record_dynamic(loop: Any, trace: Array, j: int, nx: int, x: Array, f: Array
                   ) -> None:
    """Trace row j (``simulate.chain_dynamic_trace_columns``): the state, the rate commands
    r_1..r_N-1 (the flat loop's u_j columns), tau_1..tau_N, r_N."""
    n = (nx - 2) // 2
    for i in range(nx):
        trace[j, i] = x[i]
    for i in range(n - 1):
        trace[j, nx + i] = f[nx + 2 + n + i]
    for i in range(n):
        trace[j, nx + n - 1 + i] = f[nx + 1 + i]
    trace[j, nx + 2 * n - 1] = f[nx + 1 + 2 * n]


@jitable
def plan_residual(loop: AsbuiltLoop, plan_theta: Array, plan_theta_dot: Array) -> float:
    """max_j |H - H0| of the plan's own samples with the plant's parameters [kg m^2/s]."""
    residual = 0.0
    for j in range(plan_theta.shape[0]):
        plant_trig(loop, plan_theta[j])
        h = chain_momentum_given(loop.params, loop.rows[_CS], loop.rows[_SN],
                                 plan_theta_dot[j])
        residual = max(residual, abs(h - loop.h0))
    return residual


__all__ = ["AsbuiltLoop", "AsbuiltScratch", "AsbuiltShared", "asbuilt_loop",
           "asbuilt_scratch", "dynamic_aux", "dynamic_initial", "dynamic_rhs",
           "kinematic_initial", "kinematic_rhs", "observe_dynamic",
           "observe_kinematic", "plan_residual", "record_dynamic", "record_kinematic"]


@jitable
def additive(loop: AsbuiltLoop, ref: Array, dv: Array, out: Array) -> None:
    """The as-built law's additive input: ``out`` = the tracked flag ``ref`` with dv (N,)
    [rad/s] added to the joint-rate commands w (``commands``): on the plan's joint rates w_r
    (the kinematic plant's law), or, where w_r enters the rate errors too (the dynamic
    plant's, ``AsbuiltShared.lagged``), on the lead's channel a_r as dv / lead (for a law that
    wraps it, ``loop.compose``)."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    shared = loop.shared
    width = 2 * n + 1 if shared.lagged else nb
    c = nb + n * width
    for k in range(3 * c):
        out[k] = ref[k]
    for j in range(1, nb):
        if shared.lagged:
            out[2 * c + j - 1] += dv[j - 1] / shared.lead
        else:
            out[c + j - 1] += dv[j - 1]


@jitable
def measure(loop: AsbuiltLoop, x: Array, noise: Array, ref: Array, s0: Array) -> None:
    """What the as-built law measures at state x with noise (N + 1,): the errors its gains
    act on, from the tracked flag ``ref``, into ``s0``: the measured angles' th0 - th0_r,
    th_j - th_jr (j = 1..N), and where the law acts on the joint rates (the dynamic plant)
    th_j' - w_jr (the order of ``lqr.linearisation``; for ``loop.compose``)."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    shared = loop.shared
    width = 2 * n + 1 if shared.lagged else nb
    c = nb + n * width
    s0[0] = x[0] + noise[0] - ref[n]
    for a in range(1, nb):
        s0[a] = x[a] + noise[a] - ref[a - 1]
    if shared.lagged:
        for k in range(1, nb):
            s0[n + k] = x[nb + k] - ref[c + k - 1]
