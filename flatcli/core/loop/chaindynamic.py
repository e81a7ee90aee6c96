"""The dynamic plant of an N-link chain in closed loop (N >= 2 joints).

The robot with inertia (``dynamics``: the free-floating chain of N + 1 bodies, the plant's own
masses, inertias, lengths and d_i, any d_N) driven by joint torques from a rate servo on every
joint, under the chain's linearising feedback (``chainloop``, ``chainflat``). For N = 2 it is
the paper's robot, whose own compiled plant (``paperloop.dynamic_rhs``, written out for three
bodies) stays what ``simulate`` runs for a ``FlatPlan``; the tests check that both agree.

The state is x = (th0 .. th_N, th0' .. th_N', u_1 .. u_N-1), 3 N + 1 numbers:

    M(q) q'' + C(q, q') q' = (0, tau_1 .. tau_N),   u_j' = the controller's command (j < N),
    r_j = sat(u_j) (j < N),  r_N = sat(the controller's th_N')   (the joint-rate commands)
    a = bandwidth (r - (th_1' .. th_N'))                          (what the servo asks)
    tau = clip(Mhat_s a + chat_s, +-torque_limit)                 (each joint clipped)

with the controller's commands (u_j', th_N') from the feedback at the measured angles
th + noise (``chainflat.outputs``, ``chainflat.inputs``; v_j = y_jd'' + kv_j (y_jd' - y_j')
+ kp_j (y_jd - y_j)), sat the rate limit, u_j' set to 0 while u_j is at or beyond the limit
and the command pushes it further out (conditional integration, as ``chainloop.chain_rhs``),
and Mhat_s, chat_s the free-floating joint-space inertia and bias (``dynamics.joint_space``)
of the *servo's model* (the nominal robot, or the plant itself) at the true joint angles and
rates. Where the servo's model is the plant's and no torque is clipped, each joint rate
follows its command as the first-order lag th_j'' = bandwidth (r_j - th_j'). The plant's
accelerations are ``dynamics.free_floating_accelerations``.

``chain_dynamic_rhs`` writes the state's derivative into out[:3N+1], the controller's signed
margin sigma = -D / (2 K_10) into out[3N+1] (as ``chainloop.chain_rhs``: the integrators stop
where it changes sign), then the torques tau_1 .. tau_N [N m], 1.0 if a torque was clipped
(else 0.0) and the rate command r_N [rad/s]; so the integrators of ``integrate`` run it and
``chain_dynamic_kernel`` runs a batch of trials.

Initial state (``chain_dynamic_initial``): th(0) and u(0) given; th_j'(0) = r_j(0), the rate
commands of the controller at t = 0 at the true angles (the servo starts in equilibrium);
th0'(0) such that H = (M q')_0 = H0 of the plant.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.controllers.control import law
from flatcli.core.loop.chainloop import flat_chain_errors
from flatcli.core.loop.metrics import (
    observe_clipped,
    observe_errors,
    observe_torque,
)
from flatcli.core.models.chainflat import (
    Scratch,
    first_terms_at,
    inputs_given,
    outputs_given,
    terms_into,
)
from flatcli.core.robots.chain import chain_momentum_given, turn_last
from flatcli.core.robots.dynamics import (
    TRIG_ROWS,
    Chain,
    absolute_motion,
    chain_terms,
    free_floating_accelerations,
    joint_accelerations,
    joint_space,
)

Array = NDArray[np.float64]


#: Rows of ``ChainDynamicLoop.buffers`` (each N + 1 long): measured angles, y, y', v, u',
#: rate commands r, the plant's C q', the servo model's C q', the servo model's chat_s, the
#: servo's wanted accelerations a, its demand, the torques, a solve's right-hand side, q''.
(_MEASURED, _Y, _Y_DOT, _V, _U_DOT, _R, _C, _C_S, _CHAT_S, _A, _DEMAND, _TAU, _RHS,
 _Q_DDOT, _PLANT_CS, _PLANT_SN) = range(16)
BUFFER_ROWS = 16
#: Matrices of ``ChainDynamicLoop.matrices`` (each (N + 1, N + 1)): the plant's M, the
#: servo's M, the plant's Mhat (scratch of the solve), the servo's Mhat.
_M, _M_S, _MHAT, _MHAT_S = range(4)
MATRICES = 4


def chain_dynamic_state(n: int) -> int:
    """State size of the N-link dynamic plant: th (N + 1), th' (N + 1), u (N - 1)."""
    return 3 * n + 1


def chain_dynamic_aux(n: int) -> int:
    """Values ``chain_dynamic_rhs`` writes after the state's derivative: sigma, tau_1 ..
    tau_N, the saturation flag, r_N."""
    return n + 3


class ChainDynamicLoop(NamedTuple):
    """What one trial's closed loop with the N-link dynamic plant needs (for the kernels).

    Kc, Ic : the controller's K (N + 1, N + 1) [kg m^2] and inertias (N + 1,) [kg m^2]
    kp, kv : gains (N,) [1/s^2, 1/s]
    plant : the plant's ``dynamics.Chain``; servo : the servo's model of it
    same_model : servo and plant are the same chain (its terms are computed once)
    params : the plant's (4 (N + 1),) mass, inertia, length, com (H from the full kinematics)
    h0 : the plant's angular momentum [kg m^2/s]; rate_limit : joint-rate limit [rad/s]
    bandwidth : servo bandwidth [rad/s]; torque_limit : joint-torque limit [N m] (inf: none)
    buffers : (BUFFER_ROWS, N + 1), trig : (TRIG_ROWS, N + 1), matrices : (MATRICES, N + 1,
        N + 1) scratch of the right-hand side; work : the flat maps' (``chainflat.Scratch``)
    cos_p, sin_p : the turn of the plant's last link that a centre of mass across it adds
        (``model.RobotParams.placement``; 1 and 0: none). The servo's model takes it too: the
        nominal robot (d_N = 0, which th_N does not enter) or the plant
    """

    Kc: Array
    Ic: Array
    kp: Array
    kv: Array
    plant: Chain
    servo: Chain
    same_model: bool
    params: Array
    h0: float
    rate_limit: float
    bandwidth: float
    torque_limit: float
    buffers: Array
    trig: Array
    matrices: Array
    work: Scratch
    cos_p: float = 1.0
    sin_p: float = 0.0


@jitable
def same_chain(a: Chain, b: Chain) -> bool:
    """Whether two chains hold the same numbers."""
    n = a.inertia.shape[0]
    for i in range(n):
        if a.inertia[i] != b.inertia[i]:
            return False
        for k in range(n):
            if a.coupling[i, k] != b.coupling[i, k]:
                return False
    return True


@jitable
def chain_dynamic_loop(
    Kc: Array, Ic: Array, kp: Array, kv: Array, Kq: Array, Iq: Array, servo_is_plant: bool,
    params: Array, h0: float, rate_limit: float, bandwidth: float, torque_limit: float,
    buffers: Array, trig: Array, matrices: Array, work: Scratch, offset: float = 0.0,
) -> ChainDynamicLoop:
    """A ``ChainDynamicLoop`` for a plant (its K ``Kq`` and inertias ``Iq``, its last link
    turned by ``offset`` [rad]) and a servo model: the plant (``servo_is_plant``) or the
    controller's nominal chain (Kc, Ic)."""
    plant = Chain(Kq, Iq)
    servo = plant if servo_is_plant else Chain(Kc, Ic)
    same = servo_is_plant or same_chain(plant, servo)
    return ChainDynamicLoop(Kc, Ic, kp, kv, plant, servo, same, params, h0, rate_limit,
                            bandwidth, torque_limit, buffers, trig, matrices, work,
                            np.cos(offset), np.sin(offset))


@jitable
def _commands(loop: ChainDynamicLoop, measured: Array, u: Array, ref: Array) -> float:
    """The feedback at the measured angles (N + 1,) and u (N - 1,): the rate commands r (N,)
    (sat(u_j), then sat(th_N')) into buffers[_R] and the commands u' (N - 1,) into
    buffers[_U_DOT]; returns sigma [rad/s]. ``ref`` (3 N,): the plan's y, y', y''."""
    n = loop.Ic.shape[0] - 1
    buf = loop.buffers
    y, y_dot, v, r = buf[_Y, :n], buf[_Y_DOT, :n], buf[_V, :n], buf[_R, :n]
    work = loop.work
    h0 = terms_into(loop.Kc, loop.Ic, measured, work)  # once for both maps
    h_c, grad, hess, slopes = work.h, work.grad, work.hess, work.slopes
    sigma = outputs_given(loop.Kc, loop.Ic, h0, h_c, grad, measured, u, y, y_dot)
    for j in range(n):
        v[j] = law(ref, j, n, loop.kp[j], loop.kv[j], y[j], y_dot[j])
    command = inputs_given(loop.Ic, h0, h_c, grad, hess, slopes, measured, u, v,
                           buf[_U_DOT, : n - 1])
    limit = loop.rate_limit
    for j in range(n - 1):
        r[j] = min(max(u[j], -limit), limit)
    r[n - 1] = min(max(command, -limit), limit)
    return sigma


@jitable
def servo_accelerations(loop: ChainDynamicLoop, rates: Array) -> None:
    """What the servo asks of the joints, a = bandwidth (r - rates), into buffers[_A] (N,)
    [rad/s^2], from the rate commands buffers[_R] and the joint rates ``rates`` (N,)
    [rad/s]."""
    n = loop.Ic.shape[0] - 1
    buf = loop.buffers
    r, a = buf[_R], buf[_A]
    for j in range(n):
        a[j] = loop.bandwidth * (r[j] - rates[j])


@jitable
def servo_demand(loop: ChainDynamicLoop, rates: Array) -> float:
    """The servo's torques into buffers[_TAU] (N,) [N m], clipped to the torque limit, from
    the rate commands buffers[_R] and the joint rates ``rates`` (N,) [rad/s], with the
    servo model's Mhat_s, chat_s in matrices[_MHAT_S], buffers[_CHAT_S]; its unclipped
    demand into buffers[_DEMAND]. Returns 1.0 if a torque was clipped, else 0.0."""
    n = loop.Ic.shape[0] - 1
    buf = loop.buffers
    a, tau, chat = buf[_A], buf[_TAU], buf[_CHAT_S]
    demand = buf[_DEMAND]
    hat = loop.matrices[_MHAT_S]
    servo_accelerations(loop, rates)
    limit = loop.torque_limit
    saturated = 0.0
    for j in range(n):
        acc = chat[j]
        for k in range(n):
            acc += hat[j, k] * a[k]
        demand[j] = acc
        if abs(acc) > limit:
            saturated = 1.0
        tau[j] = min(max(acc, -limit), limit)
    return saturated


@jitable
def chain_dynamic_rhs(loop: ChainDynamicLoop, x: Array, ref: Array, noise: Array, out: Array
                      ) -> None:
    """Rates of the N-link dynamic plant's state under the feedback and the servos.

    Parameters
    ----------
    loop : ChainDynamicLoop
    x : (3 N + 1,) th0..th_N [rad], th0'..th_N' [rad/s], u_1..u_N-1 [rad/s]
    ref : (3 N,) plan y, y', y'' at this instant
    noise : (N + 1,) sensor noise on the measured angles [rad]
    out : (>= 3 N + 1 + ``chain_dynamic_aux(N)``,) written: th' [rad/s], th'' [rad/s^2],
        u' [rad/s^2]; then the controller's signed margin sigma [rad/s], tau_1..tau_N
        [N m], 1.0 if a torque was clipped (else 0.0), the rate command r_N [rad/s]
    """
    _chain_dynamic_rates(loop, x, ref, noise, out, True)


@jitable
def chain_dynamic_stage(loop: ChainDynamicLoop, x: Array, ref: Array, noise: Array,
                        out: Array) -> None:
    """``chain_dynamic_rhs`` for an integrator's stage, whose torques nobody observes: the
    same state's derivative and sigma, bit for bit, and the same r_N; but where the servo's
    model is the plant and there is no torque limit, the torques do not enter the
    derivative (each joint rate is the lag th_j'' = bandwidth (r_j - th_j')), so they are not
    computed (the servo's Mhat_s and chat_s neither) and tau_1..tau_N and the saturation
    flag are written as nan."""
    _chain_dynamic_rates(loop, x, ref, noise, out, False)


@jitable
def _chain_dynamic_rates(loop: ChainDynamicLoop, x: Array, ref: Array, noise: Array,
                         out: Array, torques: bool) -> None:
    """``chain_dynamic_rhs`` (``torques``) or ``chain_dynamic_stage``."""
    n = loop.Ic.shape[0] - 1
    nb = n + 1
    nx = 3 * n + 1
    buf = loop.buffers
    mats = loop.matrices
    theta, rates, u = x[:nb], x[nb: 2 * nb], x[2 * nb: nx]
    measured = buf[_MEASURED]
    noisy = False
    for i in range(nb):
        measured[i] = theta[i] + noise[i]
        noisy = noisy or noise[i] != 0.0
    sigma = _commands(loop, measured, u, ref)
    if noisy:
        absolute_motion(theta, rates, loop.trig)
    else:  # the controller's trigonometry is the plant's (``chain.link_trig``, the same sums)
        trig, work = loop.trig, loop.work
        rate = 0.0
        for a in range(nb):
            trig[0, a] = work.cs[a]
            trig[1, a] = work.sn[a]
            rate += rates[a]
            trig[2, a] = rate
    turn_last(loop.trig[0], loop.trig[1], loop.cos_p, loop.sin_p)
    M, c = mats[_M], buf[_C]
    chain_terms(loop.plant, loop.trig, M, c)
    lag_only = not torques and loop.same_model and loop.torque_limit == np.inf
    if lag_only:  # what ``servo_demand`` asks, without its torques: never clipped
        servo_accelerations(loop, rates[1:])
        saturated = 0.0
    else:
        if loop.same_model:
            joint_space(M, c, mats[_MHAT_S], buf[_CHAT_S])
        else:
            chain_terms(loop.servo, loop.trig, mats[_M_S], buf[_C_S])
            joint_space(mats[_M_S], buf[_C_S], mats[_MHAT_S], buf[_CHAT_S])
        saturated = servo_demand(loop, rates[1:])
    tau = buf[_TAU, :n]
    q_ddot = buf[_Q_DDOT]
    if loop.same_model and saturated == 0.0:
        # the servo's model is the plant and no torque is clipped: Mhat q_j'' = tau - chat =
        # Mhat a, so q_j'' = a (the first-order lag) without a solve; the base from row 0
        a = buf[_A]
        acc = c[0]
        for j in range(n):
            q_ddot[1 + j] = a[j]
            acc += M[0, 1 + j] * a[j]
        q_ddot[0] = -acc / M[0, 0]
    elif loop.same_model:  # the plant's Mhat and chat are the servo's: a copy for the solve
        hat, chat, scratch_hat, rhs = mats[_MHAT_S], buf[_CHAT_S], mats[_MHAT], buf[_RHS]
        for j in range(n):
            rhs[j] = chat[j]
            for k in range(n):
                scratch_hat[j, k] = hat[j, k]
        joint_accelerations(M, c, tau, scratch_hat, rhs, q_ddot)
    else:
        free_floating_accelerations(M, c, tau, mats[_MHAT], buf[_RHS], q_ddot)
    limit = loop.rate_limit
    u_dot = buf[_U_DOT]
    for i in range(nb):
        out[i] = rates[i]
        out[nb + i] = q_ddot[i]
    for j in range(n - 1):
        step = u_dot[j]
        if (u[j] >= limit and step > 0.0) or (u[j] <= -limit and step < 0.0):
            step = 0.0  # conditional integration: no wind-up while the command is clipped
        out[2 * nb + j] = step
    out[nx] = sigma
    for j in range(n):
        out[nx + 1 + j] = math.nan if lag_only else tau[j]
    out[nx + 1 + n] = math.nan if lag_only else saturated
    out[nx + 2 + n] = buf[_R, n - 1]


@jitable
def chain_dynamic_initial(loop: ChainDynamicLoop, initial: Array, ref: Array, x0: Array
                          ) -> None:
    """The state at t = 0 into ``x0`` (3 N + 1,) from ``initial`` (2 N,) th(0) [rad] and
    u(0) [rad/s]: th_j'(0) = r_j, the controller's rate commands at t = 0 at the true
    angles (the servo in equilibrium), th0'(0) such that H = (M q')_0 = H0 of the plant.
    ``ref`` (3 N,) is the plan's flag at t = 0."""
    n = loop.Ic.shape[0] - 1
    nb = n + 1
    theta = initial[:nb]
    u = initial[nb: 2 * n]
    _commands(loop, theta, u, ref)
    r = loop.buffers[_R]
    x0[nb] = 0.0
    for i in range(nb):
        x0[i] = theta[i]
    for j in range(n):
        x0[nb + 1 + j] = r[j]
    for j in range(n - 1):
        x0[2 * nb + j] = u[j]
    M = loop.matrices[_M]
    absolute_motion(x0[:nb], x0[nb: 2 * nb], loop.trig)
    turn_last(loop.trig[0], loop.trig[1], loop.cos_p, loop.sin_p)
    chain_terms(loop.plant, loop.trig, M, loop.buffers[_C])
    acc = loop.h0
    for k in range(1, nb):
        acc -= M[0, k] * x0[nb + k]
    x0[nb] = acc / M[0, 0]


@jitable
def chain_dynamic_momentum(loop: ChainDynamicLoop, x: Array) -> float:
    """H of the plant from its full link kinematics (``chain.chain_momentum_given``) at state
    x with its own rates [kg m^2/s], given the trigonometry of its angles in
    ``loop.work`` (``chain.link_trig``)."""
    nb = loop.Ic.shape[0]
    cs, sn = loop.work.cs, loop.work.sn
    if loop.sin_p != 0.0 or loop.cos_p != 1.0:  # the plant's last link turned: a copy
        cs, sn = loop.buffers[_PLANT_CS], loop.buffers[_PLANT_SN]
        for a in range(nb):
            cs[a] = loop.work.cs[a]
            sn[a] = loop.work.sn[a]
        turn_last(cs, sn, loop.cos_p, loop.sin_p)
    return float(chain_momentum_given(loop.params, cs, sn, x[nb: 2 * nb]))


@jitable
def observe_chain_dynamic(loop: ChainDynamicLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
             ) -> None:
    """Metrics at output sample j (see ``metrics``): angle and flat-output errors (the
    controller's flat map at the true state), the margin |sigma| there, H from the full
    kinematics with the plant's own rates, the largest joint rate and torque, saturation."""
    theta_ref, ref, threshold = obs
    n = loop.Ic.shape[0] - 1
    nb = n + 1
    nx = 3 * n + 1
    buf = loop.buffers
    y, y_dot = buf[_Y, :n], buf[_Y_DOT, :n]
    et2 = 0.0
    for i in range(nb):
        d = x[i] - theta_ref[j, i]
        et2 += d * d
    work = loop.work
    h0 = first_terms_at(loop.Kc, loop.Ic, x[:nb], work)  # its trigonometry serves H too
    sigma = outputs_given(loop.Kc, loop.Ic, h0, work.h, work.grad, x[:nb], x[2 * nb: nx], y,
                          y_dot)
    ey2 = 0.0
    for i in range(n):
        e = y[i] - ref[2 * j, i]
        ey2 += e * e
    peak = 0.0
    torque = 0.0
    for i in range(n):
        peak = max(peak, abs(x[nb + 1 + i]))
        torque = max(torque, abs(f[nx + 1 + i]))
    observe_errors(acc, j, et2, ey2, abs(sigma), chain_dynamic_momentum(loop, x), loop.h0,
                   peak, threshold)
    observe_torque(acc, torque, 0.0, f[nx + 1 + n])
    # the servos' set points: sat(u_j) (j < N) and r_N, clipped where at or beyond the limit
    limit = loop.rate_limit
    clipped = abs(f[nx + 2 + n]) >= limit
    for i in range(n - 1):
        clipped = clipped or abs(x[2 * nb + i]) >= limit
    observe_clipped(acc, j, clipped)


@jitable
def record_chain_dynamic(loop: Any, trace: Array, j: int, nx: int, x: Array, f: Array
                         ) -> None:
    """Trace row j: the state, the torques tau_1..tau_N, the rate command r_N
    (``simulate.chain_dynamic_trace_columns``)."""
    n = (nx - 1) // 3
    for i in range(nx):
        trace[j, i] = x[i]
    for i in range(n):
        trace[j, nx + i] = f[nx + 1 + i]
    trace[j, nx + n] = f[nx + 2 + n]


def make_scratch(n: int) -> tuple[Array, Array, Array]:
    """Scratch arrays of a ``ChainDynamicLoop`` of N joints: buffers, trig, matrices."""
    nb = n + 1
    return (np.zeros((BUFFER_ROWS, nb)), np.zeros((TRIG_ROWS, nb)),
            np.zeros((MATRICES, nb, nb)))


@jitable
def measure_chain_dynamic(loop: ChainDynamicLoop, x: Array, noise: Array, ref: Array,
                          s0: Array) -> None:
    """What the flat law measures at the dynamic chain's state x (3 N + 1,) with noise
    (N + 1,): its flat outputs' errors from the plan's flag ``ref`` (3 N,) into ``s0``
    (2 N,), for a law that wraps it (``loop.compose``)."""
    n = loop.Ic.shape[0] - 1
    nb = n + 1
    buf = loop.buffers
    measured = buf[_MEASURED]
    for i in range(nb):
        measured[i] = x[i] + noise[i]
    flat_chain_errors(loop.Kc, loop.Ic, loop.work, measured, x[2 * nb: 3 * n + 1],
                      buf[_Y, :n], buf[_Y_DOT, :n], ref, s0)
