"""The dynamic plant of an N-link chain: the free-floating robot with inertia (``dynamics``:
N + 1 bodies, the plant's own masses, inertias, lengths and d_i, any d_N) driven by joint
torques from a rate servo on every joint. It takes joint-rate commands r (N,) and knows
nothing of the controller that made them:

    M(q) q'' + C(q, q') q' = (0, tau_1 .. tau_N),
    r_j = sat(r_j)                                   (clipped to +-rate_limit)
    a = bandwidth (r - (th_1' .. th_N'))             (what the servo asks)
    tau = clip(Mhat_s a + chat_s, +-torque_limit)    (each joint clipped)

with Mhat_s, chat_s the free-floating joint-space inertia and bias (``dynamics.joint_space``)
of the *servo's model* (the plant itself, or a nominal chain with its own turn of the last
link) at the true joint angles and rates. Where the servo's model is the plant's and no
torque is clipped, each joint rate follows its command as the first-order lag
th_j'' = bandwidth (r_j - th_j'); the base turns as momentum conservation makes it.

Its state is (th0..th_N, th0'..th_N'); it writes tau_1..tau_N [N m], 1.0 if a torque was
clipped (else 0.0) and the clipped commands r_1..r_N [rad/s] as aux values; its trace columns
are tau_1..tau_N and r_N (``PLANT``).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import inlined, jitable
from flatcli.core.plants.part import PlantPart, plant_trig
from flatcli.core.robots.chain import chain_momentum_given, plan_residual, turn_last
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

#: Rows of ``ServoPlant.rows`` (each N + 1 long): r, the plant's C q', the servo model's C q'
#: and chat_s, the servo's a, its demand, the torques, a solve's right-hand side, q''.
R, _C, _C_S, _CHAT_S, _A, _DEMAND, _TAU, _RHS, _Q_DDOT = range(9)
ROWS = 9
#: Matrices of ``ServoPlant.matrices`` (N + 1, N + 1): M, the servo's M, Mhat, the servo's.
M, _M_S, _MHAT, _MHAT_S = range(4)
MATRICES = 4


def aux(n: int) -> int:
    """Values ``servo_rates`` writes after the controller's: tau (N), the clip flag, r (N)."""
    return 2 * n + 1


class ServoPlant(NamedTuple):
    """One trial's dynamic plant (floats and arrays, for the kernels).

    plant : its chain (``dynamics.Chain``); servo : the servo's model of it
    same_model : servo and plant are the same chain, turned alike (its terms computed once)
    h0 : its angular momentum [kg m^2/s]; rate_limit : joint-rate limit [rad/s]
    bandwidth : servo bandwidth [rad/s]; torque_limit : joint-torque limit [N m] (inf: none)
    rows (ROWS, N + 1), trig, servo_trig (TRIG_ROWS, N + 1), matrices (MATRICES, N + 1,
        N + 1): scratch
    cos_p, sin_p : the turn of its last link that a centre of mass across it adds
        (``model.RobotParams.placement``; 1 and 0: none); cos_s, sin_s : the servo model's
    lag_shortcut : where the servo's model is the plant's and no torque is clipped, q_j'' = a
        without a solve (the flat law's loops; the as-built law's solve, to keep its numbers)
    """

    plant: Chain
    servo: Chain
    same_model: bool
    h0: float
    rate_limit: float
    bandwidth: float
    torque_limit: float
    rows: Array
    trig: Array
    servo_trig: Array
    matrices: Array
    cos_p: float
    sin_p: float
    cos_s: float
    sin_s: float
    lag_shortcut: bool


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
def trig_given(sp: ServoPlant, cs: Array, sn: Array, rates: Array) -> None:
    """The plant's trigonometry from cos, sin (N + 1,) of its links' angles relative to the
    base computed elsewhere (``chain.link_trig``, the same sums as ``absolute_motion``) and
    its rates (N + 1,) into ``sp.trig`` (before its last link's turn)."""
    trig = sp.trig
    rate = 0.0
    for a in range(cs.shape[0]):
        trig[0, a] = cs[a]
        trig[1, a] = sn[a]
        rate += rates[a]
        trig[2, a] = rate


@jitable
def servo_accelerations(sp: ServoPlant, rates: Array) -> None:
    """a = bandwidth (r - rates) into rows[_A] (N,) [rad/s^2]; rates (N,) [rad/s]."""
    r, a = sp.rows[R], sp.rows[_A]
    for j in range(rates.shape[0]):
        a[j] = sp.bandwidth * (r[j] - rates[j])


@jitable
def servo_demand(sp: ServoPlant, rates: Array) -> float:
    """The servo's torques Mhat_s a + chat_s (matrices[_MHAT_S], rows[_CHAT_S]) clipped to
    the torque limit into rows[_TAU] (N,) [N m], unclipped into rows[_DEMAND]; rates (N,)
    [rad/s]. Returns 1.0 if a torque was clipped, else 0.0."""
    n = rates.shape[0]
    rows = sp.rows
    a, tau, chat, demand = rows[_A], rows[_TAU], rows[_CHAT_S], rows[_DEMAND]
    hat = sp.matrices[_MHAT_S]
    servo_accelerations(sp, rates)
    limit = sp.torque_limit
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
def clip_commands(sp: ServoPlant, n: int) -> None:
    """The rate commands rows[R, :n] clipped to the rate limit, in place."""
    r = sp.rows[R]
    limit = sp.rate_limit
    for j in range(n):
        r[j] = min(max(r[j], -limit), limit)


@jitable
def servo_rates(sp: ServoPlant, theta: Array, rates: Array, out: Array, at: int,
                torques: bool, given: bool) -> None:
    """The dynamic plant's rates under the rate commands in rows[R, :N] (clipped here).

    theta, rates (N + 1,): its angles [rad] and rates [rad/s]; ``given``: its trigonometry is
    in ``sp.trig`` already (``trig_given``), else computed here. Writes th' [rad/s] into
    out[:N + 1], th'' [rad/s^2] into out[N + 1: 2 N + 2], and at out[at:] tau_1..tau_N
    [N m], 1.0 if a torque was clipped (else 0.0), r_1..r_N [rad/s]. Without ``torques`` (an
    integrator's stage, whose torques nobody observes) where the servo's model is the plant,
    there is no torque limit and ``lag_shortcut``, the torques do not enter the rates (each
    joint rate is the lag) and are written as nan (the same rates, bit for bit).
    """
    nb = theta.shape[0]
    n = nb - 1
    rows, mats = sp.rows, sp.matrices
    clip_commands(sp, n)
    if not given:
        absolute_motion(theta, rates, sp.trig)
    turn_last(sp.trig[0], sp.trig[1], sp.cos_p, sp.sin_p)
    Mq, c = mats[M], rows[_C]
    chain_terms(sp.plant, sp.trig, Mq, c)
    lag_only = (not torques and sp.lag_shortcut and sp.same_model
                and sp.torque_limit == np.inf)
    if lag_only:  # what ``servo_demand`` asks, without its torques: never clipped
        servo_accelerations(sp, rates[1:])
        saturated = 0.0
    else:
        if sp.same_model:
            joint_space(Mq, c, mats[_MHAT_S], rows[_CHAT_S])
        else:
            strig = sp.trig
            if sp.cos_s != sp.cos_p or sp.sin_s != sp.sin_p:
                strig = sp.servo_trig
                absolute_motion(theta, rates, strig)
                turn_last(strig[0], strig[1], sp.cos_s, sp.sin_s)
            chain_terms(sp.servo, strig, mats[_M_S], rows[_C_S])
            joint_space(mats[_M_S], rows[_C_S], mats[_MHAT_S], rows[_CHAT_S])
        saturated = servo_demand(sp, rates[1:])
    tau = rows[_TAU, :n]
    q_ddot = rows[_Q_DDOT]
    if sp.lag_shortcut and sp.same_model and saturated == 0.0:
        # the servo's model is the plant and no torque is clipped: Mhat q_j'' = tau - chat =
        # Mhat a, so q_j'' = a (the first-order lag) without a solve; the base from row 0
        a = rows[_A]
        acc = c[0]
        for j in range(n):
            q_ddot[1 + j] = a[j]
            acc += Mq[0, 1 + j] * a[j]
        q_ddot[0] = -acc / Mq[0, 0]
    elif sp.same_model:  # the plant's Mhat and chat are the servo's: a copy for the solve
        hat, chat, scratch_hat, rhs = mats[_MHAT_S], rows[_CHAT_S], mats[_MHAT], rows[_RHS]
        for j in range(n):
            rhs[j] = chat[j]
            for k in range(n):
                scratch_hat[j, k] = hat[j, k]
        joint_accelerations(Mq, c, tau, scratch_hat, rhs, q_ddot)
    else:
        free_floating_accelerations(Mq, c, tau, mats[_MHAT], rows[_RHS], q_ddot)
    r = rows[R]
    for i in range(nb):
        out[i] = rates[i]
        out[nb + i] = q_ddot[i]
    for j in range(n):
        out[at + j] = math.nan if lag_only else tau[j]
        out[at + n + 1 + j] = r[j]
    out[at + n] = math.nan if lag_only else saturated


@jitable
def initial_base_rate(sp: ServoPlant, x0: Array) -> None:
    """th0'(0) into x0[N + 1] such that H = (M q')_0 = H0 of the plant, given th(0) in
    x0[:N + 1] and the joint rates in x0[N + 2: 2 N + 2]."""
    nb = sp.plant.inertia.shape[0]
    x0[nb] = 0.0
    absolute_motion(x0[:nb], x0[nb: 2 * nb], sp.trig)
    turn_last(sp.trig[0], sp.trig[1], sp.cos_p, sp.sin_p)
    Mq = sp.matrices[M]
    chain_terms(sp.plant, sp.trig, Mq, sp.rows[_C])
    acc = sp.h0
    for k in range(1, nb):
        acc -= Mq[0, k] * x0[nb + k]
    x0[nb] = acc / Mq[0, 0]


class DynamicPlant(NamedTuple):
    """One trial's dynamic plant: its servo plant (``ServoPlant``), its (4 (N + 1),)
    parameters (H from the full kinematics), rows (2, N + 1): its cos and sin for H."""

    servo: ServoPlant
    params: Array
    rows: Array


def scratch(n: int) -> tuple[Array, Array, Array, Array, Array]:
    """A dynamic plant's buffers for N joints: its servo plant's rows, trig, servo_trig,
    matrices (``ServoPlant``), then its rows for H."""
    nb = n + 1
    return (np.zeros((ROWS, nb)), np.zeros((TRIG_ROWS, nb)), np.zeros((TRIG_ROWS, nb)),
            np.zeros((MATRICES, nb, nb)), np.zeros((2, nb)))


@jitable
def make(trials: Any, i: int, rate_limit: float, servo: Any, scratch: Any) -> DynamicPlant:
    """Trial i's plant (``PlantPart.make``): its K, inertias, last link turned by its offset;
    ``servo`` = (K, inertia, cos, sin of its turn, is_plant, lag_shortcut): the servo's model
    the plant itself (is_plant) or that chain."""
    Ks, Is, cos_s, sin_s, servo_is_plant, lag_shortcut = servo
    p = trials.params[i]
    Kq = trials.plant[i]
    nb = Kq.shape[0]
    plant = Chain(Kq, p[nb: 2 * nb])
    model = plant if servo_is_plant else Chain(Ks, Is)
    cos_p, sin_p = np.cos(trials.offset[i]), np.sin(trials.offset[i])
    same = servo_is_plant or (same_chain(plant, model) and cos_p == cos_s and sin_p == sin_s)
    sp = ServoPlant(plant, model, same, trials.h0[i], rate_limit, trials.servo[i, 0],
                    trials.servo[i, 1], scratch[0], scratch[1], scratch[2], scratch[3], cos_p,
                    sin_p, cos_s, sin_s, lag_shortcut)
    return DynamicPlant(sp, p, scratch[4])


@jitable
def state(n: int) -> int:
    """th0..th_N, th0'..th_N'."""
    return 2 * n + 2


def columns(n: int) -> int:
    """tau_1..tau_N, r_N in a trace row."""
    return n + 1


@jitable
def io(plant: DynamicPlant, x: Array) -> tuple[Array, Array]:
    """Its commands' row; th0'..th_N'."""
    nb = plant.rows.shape[1]
    return plant.servo.rows[R], x[nb: 2 * nb]


@inlined
def rates(plant: DynamicPlant, x: Array, cs: Array, sn: Array, given: bool, out: Array,
          at: int, torques: bool) -> None:
    """th', th'' into out[:2 N + 2], its aux values at out[at:] (``servo_rates``)."""
    sp = plant.servo
    nb = plant.rows.shape[1]
    theta, q_dot = x[:nb], x[nb: 2 * nb]
    if given:  # the controller's trigonometry is the plant's (the same sums)
        trig_given(sp, cs, sn, q_dot)
    servo_rates(sp, theta, q_dot, out, at, torques, given)


@jitable
def start(plant: DynamicPlant, initial: Array, r: Array, x0: Array) -> None:
    """th(0), th_j'(0) = r_j (the servo in equilibrium), th0'(0) such that H = (M q')_0 = H0
    (``initial_base_rate``)."""
    nb = plant.rows.shape[1]
    for a in range(nb):
        x0[a] = initial[a]
    for j in range(nb - 1):
        x0[nb + 1 + j] = r[j]
    initial_base_rate(plant.servo, x0)


@jitable
def observed(plant: DynamicPlant, x: Array, f: Array, at: int, cs: Array, sn: Array,
             given: bool) -> tuple[float, float, float, bool, float, float]:
    """H with its own rates, the largest joint rate and torque; clipped where a servo's set
    point (a clipped command r_j) is at the limit."""
    sp = plant.servo
    nb = plant.rows.shape[1]
    n = nb - 1
    peak = 0.0
    torque = 0.0
    for i in range(n):
        peak = max(peak, abs(x[nb + 1 + i]))
        torque = max(torque, abs(f[at + i]))
    pcs, psn = plant_trig(x[:nb], cs, sn, given, plant.rows[0], plant.rows[1], sp.cos_p,
                          sp.sin_p)
    h = chain_momentum_given(plant.params, pcs, psn, x[nb: 2 * nb])
    clipped = False
    for i in range(n):
        clipped = clipped or abs(f[at + n + 1 + i]) >= sp.rate_limit
    return h, sp.h0, peak, clipped, torque, f[at + n]


@jitable
def record(plant: DynamicPlant, trace: Array, j: int, col: int, x: Array, f: Array,
           at: int, commands: bool) -> None:
    """[r_1..r_N-1,] tau_1..tau_N, r_N."""
    n = plant.rows.shape[1] - 1
    if commands:
        for i in range(n - 1):
            trace[j, col + i] = f[at + n + 1 + i]
        col += n - 1
    for i in range(n):
        trace[j, col + i] = f[at + i]
    trace[j, col + n] = f[at + 2 * n]


@jitable
def residual(plant: DynamicPlant, trials: Any, i: int, plan_theta: Array,
             plan_theta_dot: Array) -> float:
    sp = plant.servo
    return plan_residual(plan_theta, plan_theta_dot, plant.params, sp.h0, plant.rows[0],
                         plant.rows[1], sp.cos_p, sp.sin_p)


@jitable
def bounded(plant: DynamicPlant) -> bool:
    """Its servos' commands clipped to a finite rate limit, or their torques to a finite
    torque limit (0 included: no torque at all)."""
    sp = plant.servo
    return not (math.isinf(sp.rate_limit) and math.isinf(sp.torque_limit))


PLANT = PlantPart("dynamic", scratch, make, state, aux, columns, io, rates, start,
                  observed, record, residual, bounded, rate_states=True, torques=True)
