"""Model predictive control that respects the actuators: an inner feedback law plus a
correction chosen at sample instants by a QP over the next H samples.

Between samples the controller is an inner law (the flat outputs' linearising feedback of
``control``, or the as-built robot's time-varying LQR of ``lqr``) with a correction dv held
over the sample, added where the law's input enters (the flat law's v = y'': dv is added to
the plan's y''; the as-built law's joint rates w: dv is added to them). With the
controller's model, the error s of the state from the plan then obeys, to first order about
the plan, a linear system that the design discretises exactly over each sample
[t_k, t_k+1) (zero-order hold on dv):

    s_k+1 = A_k s_k + B_k dv_k,

(the flat law: s = (e_j, e_j') per flat output, e'' = -kp e - kv e' + dv, the same A, B at
every sample; the as-built law: s = the angles' errors, e' = (A(t) - B(t) L(t)) e + B(t) dv).
At each sample k (every ``every`` output steps) the controller measures s_k and solves

    minimise   sum_i  s_i' W s_i + r |dv_i|^2      (i over the samples left in the horizon)
    subject to lo_q <= quantity_q <= hi_q            for each constrained quantity, sample i
               s = 0 at T                            where T is within the horizon

a QP in the corrections (``qp``). A constrained quantity (a joint rate, the singularity
margin; on the dynamic plant under a torque limit the servo's joint torques, just after each
sample's jump of the correction and at the sample interval's end: ``servo_torques``,
``_jump_design``) is a function of the state and the input, linearised about the plan at
each sample: quantity = value + slope_s . s_i + slope_v . dv_i (``Design``). Its bounds are
soft: one slack s >= 0 widens each, at a cost ``SLACK_QUADRATIC`` s^2 / 2 + ``SLACK_LINEAR``
s, so a state from which the limits cannot all be kept still gets the correction that
violates them least, and the sample is counted (``qp_infeasible``); the terminal equalities
are hard, and imposed only while the corrections left can meet them (N r >= S with r samples
to go: two samples for the flat law's S = 2 N errors, three for the as-built law's S = 2 N +
1 with a servo); in the samples after that the corrections the last solved QP planned for
them are held (with S equalities on fewer than S unknowns the QP has no solution: the
as-built dynamic MPC's second-to-last sample counted as ``qp_infeasible`` before).

What it guarantees and what it does not: the limits hold at the predicted samples for the
controller's model and the linearisation about the plan, not between samples, not for a
plant that differs from the model, and not to the linearisation's error far from the plan
(tests/test_mpc.py measures it); recursive feasibility is not guaranteed (the slack takes
what cannot be met). The torques are the servo's quasi-steady model (``servo_torques``: it
leaves out terms of order 1/b, up to 0.023 N m of 0.5 at b = 100 rad/s, measured in
tests/test_compose.py), and the torque at a trial's start (t = 0), where the servo's rates
start away from the commanded ones, is not in the model (1.1 N m on a trial 5 mrad off).

``design`` tabulates everything a sample needs (numpy, once per plan: ``flat_design``);
``sample_step`` (compiled into the closed loop, allocating nothing) builds and solves one
QP.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.controllers import qp
from flatcli.core.controllers.control import Gains
from flatcli.core.controllers.parts import SampledPart
from flatcli.core.controllers.settings import MpcSettings as MpcSettings
from flatcli.core.errors import FlatcliError

Array = NDArray[np.float64]

#: The slack's penalty: s^2 / 2 times this plus s times ``SLACK_LINEAR``.
SLACK_QUADRATIC = 1e4
SLACK_LINEAR = 1e6
#: A sample whose slack exceeds this [the quantities' units] counts as infeasible.
SLACK_TOLERANCE = 1e-9
#: Active-set iterations per QP at most, per variable and constraint.
ITERATIONS_PER_ROW = 3


#: The inner flat law's default gains: a double pole at -1 rad/s for every output, slow
#: enough that correcting a few milliradians asks little of the joints (the paper's
#: gains, with poles at -10 rad/s and beyond, ask rates far beyond a 4 rad/s limit).
INNER_KP = 1.0
INNER_KV = 2.0
#: On the dynamic plant: a double pole at -4 rad/s. The design's servo offset is the lag
#: along the MPC's own path from the plan's start with no error (``tracked_offsets``; until
#: 2026-12-05 along the inner law's path, dv = 0); the lag of a trial's own corrections away
#: from it the design does not model, and (measured with the offsets along dv = 0) with
#: the poles at -1 rad/s they leave up to 2.6 mrad at T (paper's cubic, 100 rad/s servo,
#: 2 mrad initial errors: 79/100 reached; at -4 rad/s 100/100, 2026-12-05).
DYNAMIC_INNER_KP = 16.0
DYNAMIC_INNER_KV = 8.0
#: On the dynamic plant, tracking a plan re-planned within the torque limit with no rate
#: limit (``Scenario.torque_replanned``): a double pole at -2 rad/s. The torque the inner
#: law asks to correct a trial's own errors grows with its gains, which the design did not
#: bound then (no torque rows until later on 2026-12-06: ``TORQUE_ROWS``): the cubic's
#: re-plan, 2 mrad errors, 100 trials a cell (seed 2003; docs/physics.md, "Within the
#: torque limit"), measured without the rows: at 1 N m 90 reached with the poles at
#: -4 rad/s, 100 at -2; at 0.5 N m 45 and 98; from 3 to 30 N m 100 and 100. On the cubic
#: (no limit) 100 and 99, so not there; with a rate limit the faster poles keep more
#: (4, 6, 10 rad/s: 99, 98, 54 at -4; 75, 28, 23 at -2).
TORQUE_INNER_KP = 4.0
TORQUE_INNER_KV = 4.0


class Design(NamedTuple):
    """What every sample of one plan's MPC reads (``design``); S error states, N
    corrections, H samples ahead, K samples in [0, T], Q constrained quantities, n = N H + 1
    variables (the corrections dv_0..dv_H-1, N each, then the slack).

    A : (K, S, S), B : (K, S, N) the error's transition over sample k
    weights : (S,) W's diagonal; weight_input : r
    factors : (K, n, n) ``qp.factor`` of the cost's Hessian at sample k
    gradients : (K, n, S) the cost's gradient per unit initial error at sample k
    value : (K + 1, Q) the quantities along the plan at the samples
    slope_s : (K + 1, Q, S), slope_v : (K + 1, Q, N) their slopes along s and dv
    lo, hi : (K + 1, Q) their bounds (-inf, inf: none)
    endpoint : (Q,) 1.0 for a quantity also bounded at the end of each sample interval (it
        depends on dv, so it jumps at the next sample), 0.0 for one continuous in time
    offset : the error states after the S' that s(T) = 0 is about (weight 0, no terminal
        condition): 1 if the last is the constant 1 that carries a known per-sample offset
        c_k (A[k, :, -1]; ``servo_offsets``), 1 + N with the correction held before
        (``held``), else 0
    warm_start : 1: each QP starts from a guessed active set (``sample_step``), 0: from
        the unconstrained minimiser (the same answer, to rounding: the QP is strictly
        convex)
    held : N if the N error states before the constant hold the correction held over the
        last sample (dv_k-1: the torque rows on the jumps, ``_jump_design``), which each
        sample fills from ``Scratch.held``; else 0
    """

    A: Array
    B: Array
    weights: Array
    weight_input: float
    factors: Array
    gradients: Array
    value: Array
    slope_s: Array
    slope_v: Array
    lo: Array
    hi: Array
    endpoint: Array
    horizon: int
    samples: int
    every: int
    offset: int = 0
    warm_start: int = 1
    held: int = 0


def discretise(kp: float, kv: float, ts: float) -> tuple[Array, Array]:
    """The exact transition (2, 2) and input response (2,) over ts [s] of e'' = -kp e - kv e'
    + dv with dv held (zero-order hold): the matrix exponential of the augmented system."""
    import scipy.linalg  # here: a sweep of another controller loads no scipy.linalg

    a = np.array([[0.0, 1.0, 0.0], [-kp, -kv, 1.0], [0.0, 0.0, 0.0]])
    m = scipy.linalg.expm(a * ts)
    return np.ascontiguousarray(m[:2, :2]), np.ascontiguousarray(m[:2, 2])


def condensed_cost(A: Array, B: Array, weights: Array, weight_input: float, start: int,
                   horizon: int) -> tuple[Array, Array]:
    """The Hessian (n, n) and the gradient per unit initial error (n, S) at sample ``start``
    of the cost over the samples left in the horizon (the corrections after T cost r alone,
    so they are 0), with the slack's quadratic penalty last."""
    samples, size, inputs = B.shape
    costed = min(horizon, samples - start)
    n = inputs * horizon + 1
    hessian = np.zeros((n, n))
    gradient = np.zeros((n, size))
    W = np.diag(weights)
    # the error at sample i: Phi_i s0 + sum_k<i Gamma_ik dv_k, built sample by sample
    phi = np.eye(size)
    gamma = np.zeros((size, n - 1))
    for i in range(costed):
        k = start + i
        gamma = A[k] @ gamma
        gamma[:, i * inputs: (i + 1) * inputs] = B[k]
        phi = A[k] @ phi
        hessian[:-1, :-1] += gamma.T @ W @ gamma
        gradient[:-1] += gamma.T @ W @ phi
    hessian[np.arange(n - 1), np.arange(n - 1)] += weight_input
    hessian[n - 1, n - 1] = SLACK_QUADRATIC
    return hessian, gradient


def design(A: Array, B: Array, weights: Array, weight_input: float, value: Array,
           slope_s: Array, slope_v: Array, lo: Array, hi: Array, endpoint: Array,
           horizon: int, every: int, offset: int = 0) -> Design:
    """A ``Design`` from its tables (see there): the cost's factors are computed here."""
    samples = A.shape[0]
    factors = []
    gradients = []
    for k in range(samples):
        hessian, gradient = condensed_cost(A, B, weights, weight_input, k, horizon)
        factors.append(qp.factor(hessian))
        gradients.append(gradient)
    def c(a: Any) -> Array:
        return np.ascontiguousarray(a, dtype=float)

    return Design(c(A), c(B), c(weights), float(weight_input), c(np.stack(factors)),
                  c(np.stack(gradients)), c(value), c(slope_s), c(slope_v), c(lo), c(hi),
                  c(endpoint), int(horizon), int(samples), int(every), int(offset))


class TorqueRows(NamedTuple):
    """The dynamic plant's joint torques as quantities of ``flat_design`` (``servo_torques``):
    value (K + 1, N) [N m] along the plan at the samples, slope_s (K + 1, N, 2 N) along the
    flat law's errors (e_j, e_j') [N m / rad, N m / (rad/s)], slope_v (K + 1, N, N) along
    the correction [N m / (rad/s^2)], each bounded within +- limit [N m] (widened to the
    plan's own value where that is beyond); jump (K + 1, N, N) [N m / (rad/s^2)] or None:
    the torques' jump per unit change of the correction at a sample, b Mhat[:, N] (dr_N/dv)
    (with it the rows bound the torque just after each sample's jump and at the sample
    interval's end: ``flat_design``)."""

    value: Array
    slope_s: Array
    slope_v: Array
    limit: float
    jump: Array | None = None


#: ``servo_torques``: the finite-difference step along each flag component [rad, rad/s,
#: rad/s^2, rad/s^3] (central differences; the torque is smooth in the flag: truncation
#: ~ step^2, rounding ~ 1e-16 / step relative).
TORQUE_STEP = 1e-5


def servo_torques(plan: Any, settings: MpcSettings, ts: float, samples: int, limit: float,
                  bandwidth: float, jumps: bool = True) -> TorqueRows:
    """The joint torques tau (N,) [N m] the dynamic plant's rate servo of bandwidth
    ``bandwidth`` b [rad/s] applies between its jumps, linearised about the flat plan at the
    K + 1 sample instants t_k = k ts [s] in the flat law's errors s = (e_j, e_j') and the
    correction dv held over the sample; with ``jumps`` also their jump at a sample.

    The servo tau = Mhat b (r - w) + chat makes the joint rates w follow the commanded r as
    w' = b (r - w): once a jump has decayed (rate ~b), w' ~ r' and w ~ r, and tau ~ Mhat(q)
    r' + chat(q, r), the robot's inverse dynamics (``dynamics.inverse_dynamics``, the base
    unactuated: its row ~0) along the commanded motion. That motion is the flat map's
    (``FlatModel.motion``: q'' by complex step along the flag's derivative) of the applied
    flag: about the plan's y_d, with the inner law e'' = -kp e - kv e' + dv (dv held:
    dv' = 0),

        y = y_d + e,  y' = y_d' + e',  y'' = y_d'' + dv - kp e - kv e',
        y''' = y_d''' + kp kv e + (kv^2 - kp) e' - kv dv,

    so tau(s, dv) is smooth, and its slopes along (s, dv) are those along the flag
    (central differences of ``TORQUE_STEP``) times these. What it leaves out is of order
    1/b: on the paper's maneuver re-planned within 0.5 N m, 2.7 mrad off, the torque the
    plant applies at the intervals' ends misses it by up to 0.023 N m at b = 100 rad/s and
    0.003 N m at 1000 (tests/test_compose.py; a first-order lag correction, w' ~ r' -
    r''/b, changed it by 1e-3 N m, 2026-12-06). The jump: the last joint's command r_N is
    the flat map's th_N' of (y, y', y''), so it jumps by (dr_N/dv) (dv_k - dv_k-1)
    (``FlatModel.flag_jacobian``; the inner joints' commands are the law's integrators:
    continuous), and the torques by b Mhat(q)[:, N] times that (``dynamics.joint_space``).
    The robot's dynamics are the plan's robot's (the servo's model of the nominal robot)."""
    from flatcli.core.robots.dynamics import (
        bias_forces,
        inverse_dynamics,
        joint_space,
        make_chain,
        mass_matrix,
    )

    n = plan.n_joints
    robot = plan.robot
    chain = make_chain(robot.mass, robot.inertia, robot.length, robot.com)
    model = plan.model
    kp, kv = _inner_gains_of(n, settings)
    times = np.arange(samples + 1) * ts
    flag = np.concatenate([plan.trajectory.derivative(times, order) for order in range(4)],
                          axis=-1)  # (K + 1, 4 N): y, y', y'', y'''

    class Flags:
        """A flag (m, 4 N) as the trajectory ``FlatModel.motion`` reads: y^(order)."""

        def __init__(self, flags: Array) -> None:
            self.flags = flags

        def derivative(self, t: Array, order: int) -> Array:
            return np.ascontiguousarray(self.flags[:, order * n: (order + 1) * n])

    def torque(flags: Array) -> Array:
        q, q_dot, q_ddot = model.motion(Flags(flags), times)
        return inverse_dynamics(chain, q, q_dot, q_ddot)[:, 1:]

    value = torque(flag)
    along = np.zeros((samples + 1, n, 4 * n))  # d tau / d flag
    for c in range(4 * n):
        step = np.zeros(4 * n)
        step[c] = TORQUE_STEP
        along[:, :, c] = (torque(flag + step) - torque(flag - step)) / (2 * TORQUE_STEP)
    d0, d1, d2, d3 = (along[..., m * n: (m + 1) * n] for m in range(4))
    slope_s = np.zeros((samples + 1, n, 2 * n))
    slope_s[..., 0::2] = d0 - kp * d2 + kp * kv * d3
    slope_s[..., 1::2] = d1 - kv * d2 + (kv * kv - kp) * d3
    slope_v = d2 - kv * d3
    if not jumps:
        return TorqueRows(value, slope_s, slope_v, float(limit))
    _, slopes = model.flag_jacobian(np.ascontiguousarray(flag[:, :3 * n].T))
    rate = slopes[2 * n, 2 * n:, :].T  # (K + 1, N): d th_N' / d y''
    q, q_dot, _ = model.motion(Flags(flag), times)
    masses = mass_matrix(chain, q)
    forces = bias_forces(chain, q, q_dot)
    hat, chat = np.zeros((n, n)), np.zeros(n)
    jump = np.zeros((samples + 1, n, n))
    for k in range(samples + 1):
        joint_space(masses[k], forces[k], hat, chat)
        jump[k] = bandwidth * np.outer(hat[:, n - 1], rate[k])
    return TorqueRows(value, slope_s, slope_v, float(limit), jump)


def flat_design(model: Any, trajectory: Any, duration: float, dt: float, rate_limit: float,
                settings: MpcSettings, offsets: Any = None,
                torques: TorqueRows | None = None) -> Design:
    """The MPC about a flat plan (module docstring): per flat output j the errors
    (e_j, e_j') under the inner law e'' = -kp e - kv e' + dv; the quantities are the joint
    rates th1'..thN' [rad/s] (bounded by the rate limit) and the signed margin [rad/s] (kept
    at min(margin, |margin along the plan| / 2) on the plan's side), linearised by complex
    step through the flat model's map from the flag (``FlatModel.flag_jacobian``): the
    applied flag is the plan's plus (e, e', -kp e - kv e' + dv).

    Parameters
    ----------
    model : the flat model the controller believes (``flatmodel.FlatModel``), N joints
    trajectory : the plan's flat outputs (``basis.FlatTrajectory``)
    duration : T [s]; dt : the output step [s]
    rate_limit : the joint-rate limit [rad/s] (inf: none)
    offsets : (K, 2 N) or None: a known offset c_k of the errors over each sample
        (s_k+1 = A s_k + B dv_k + c_k; ``servo_offsets``), carried by a constant error state
        1 appended last (weight 0, no terminal condition, no slope of any quantity)
    torques : the dynamic plant's joint torques as N more quantities after the margin
        (``servo_torques``), or None: none
    """
    n = model.n_joints
    every = settings.every(dt, duration)
    samples = round(duration / dt) // every
    ts = every * dt
    kp, kv = _inner_gains_of(n, settings)
    if kp.shape != (n,) or kv.shape != (n,):
        raise FlatcliError(f"track.mpc_kp, track.mpc_kv: expected {n} gains each, one per "
                           "flat output")
    size = 2 * n
    a = np.zeros((size, size))
    b = np.zeros((size, n))
    for j in range(n):
        aj, bj = discretise(float(kp[j]), float(kv[j]), ts)
        a[2 * j: 2 * j + 2, 2 * j: 2 * j + 2] = aj
        b[2 * j: 2 * j + 2, j] = bj
    A = np.broadcast_to(a, (samples, size, size))
    B = np.broadcast_to(b, (samples, size, n))
    times = np.arange(samples + 1) * ts
    flag = trajectory.flags(times).T  # (3 N, K + 1)
    values, slopes = model.flag_jacobian(flag)  # (2 N + 2, ...), (2 N + 2, 3 N, K + 1)
    rows = list(range(n + 1, 2 * n + 2))  # th1'..thN', then the margin
    value = values[rows].T.copy()  # (K + 1, Q)
    d = np.transpose(slopes[rows], (2, 0, 1))  # (K + 1, Q, 3 N) along y, y', y''
    dy, dy_dot, dy_ddot = d[..., :n], d[..., n: 2 * n], d[..., 2 * n:]
    slope_s = np.zeros((samples + 1, n + 1, size))
    slope_s[..., 0::2] = dy - kp * dy_ddot
    slope_s[..., 1::2] = dy_dot - kv * dy_ddot
    slope_v = dy_ddot.copy()
    limit = rate_limit * (1.0 - settings.backoff) if math.isfinite(rate_limit) else math.inf
    lo = np.full((samples + 1, n + 1), -np.inf)
    hi = np.full((samples + 1, n + 1), np.inf)
    if math.isfinite(limit):
        lo[:, :n], hi[:, :n] = -limit, limit
    sigma = value[:, n]
    if settings.margin > 0:
        kept = np.minimum(settings.margin, 0.5 * np.abs(sigma))
        positive = sigma > 0
        lo[:, n] = np.where(positive, kept, -np.inf)
        hi[:, n] = np.where(positive, np.inf, -kept)
        lo[0, n], hi[0, n] = -np.inf, np.inf  # the measured state: nothing to choose
    if torques is not None:
        value = np.concatenate([value, torques.value], axis=1)
        slope_s = np.concatenate([slope_s, torques.slope_s], axis=1)
        slope_v = np.concatenate([slope_v, torques.slope_v], axis=1)
        lo = np.concatenate([lo, np.minimum(-torques.limit, torques.value)], axis=1)
        hi = np.concatenate([hi, np.maximum(torques.limit, torques.value)], axis=1)
    endpoint = (np.abs(slope_v).max(axis=(0, 2)) > 0.0).astype(float)
    weights = np.full(size, settings.weight_state)
    if offsets is None:
        return design(A, B, weights, settings.weight_input, value, slope_s, slope_v, lo, hi,
                      endpoint, settings.horizon, every)
    if torques is not None and torques.jump is not None:
        return _jump_design(A, B, np.asarray(offsets), weights, settings, value, slope_s,
                            slope_v, lo, hi, endpoint, every, torques.jump)
    A = np.concatenate([np.concatenate([A, np.asarray(offsets)[:, :, None]], axis=2),
                        np.zeros((samples, 1, size + 1))], axis=1)
    A[:, size, size] = 1.0
    B = np.concatenate([B, np.zeros((samples, 1, n))], axis=1)
    slope_s = np.concatenate([slope_s, np.zeros((samples + 1, slope_s.shape[1], 1))], axis=2)
    return design(A, B, np.append(weights, 0.0), settings.weight_input, value, slope_s,
                  slope_v, lo, hi, endpoint, settings.horizon, every, 1)


def _jump_design(A: Array, B: Array, offsets: Array, weights: Array, settings: MpcSettings,
                 value: Array, slope_s: Array, slope_v: Array, lo: Array, hi: Array,
                 endpoint: Array, every: int, jump: Array) -> Design:
    """``flat_design``'s design with the torque rows on the jumps: the error states (the
    2 N errors, then the correction held over the last sample dv_k-1 (N), then the
    constant 1 of the offsets; ``Design.held``), and the last N quantities (the torques)
    taken just after the jump at the interval's start and at its end,

        tau(t_k+) = tau(s_k, dv_k-1) + J_k (dv_k - dv_k-1),   tau(t_k+1-) = tau(s_k+1, dv_k)

    (tau(s, dv) the quasi-steady torque of ``servo_torques``, J its ``jump``): one
    quantity, value + slope_s . (s, dv_k-1) + J . dv_k, whose end-of-interval row (the held
    state then dv_k) is the quasi-steady torque."""
    samples, size, n = B.shape
    states = size + n + 1
    a = np.zeros((samples, states, states))
    a[:, :size, :size] = A
    a[:, :size, -1] = offsets
    a[:, -1, -1] = 1.0
    b = np.zeros((samples, states, n))
    b[:, :size] = B
    for j in range(n):
        b[:, size + j, j] = 1.0
    along_s = np.zeros((samples + 1, value.shape[1], states))
    along_s[:, :, :size] = slope_s
    along_v = slope_v.copy()
    along_s[:, -n:, size: size + n] = slope_v[:, -n:] - jump
    along_v[:, -n:] = jump
    return design(a, b, np.concatenate([weights, np.zeros(n + 1)]), settings.weight_input,
                  value, along_s, along_v, lo, hi, endpoint, settings.horizon, every,
                  n + 1)._replace(held=n)


def servo_offsets(plan: Any, dt: float, settings: MpcSettings, bandwidth: float) -> Array:
    """The offsets c_k (K, 2 N) of the flat law's measured errors over each sample that the
    dynamic plant's servo lag makes along the plan, for ``flat_design``: the inner law
    (``inner_gains``, dv = 0) from the plan's start with no error, on the robot whose joint
    rates w follow the commanded ones r as the servo does when its model is right and no
    torque is clipped, w' = bandwidth (r - w) (w(0) = r(0)), the base turning as momentum
    conservation makes it (H = 0); the law measures y' from its own commanded rates (as the
    dynamic loop's does), so its errors differ from zero by the lag alone (``lagged_run``).
    c_k = s_k+1 - A s_k with the measured errors s_k at the samples."""
    every = settings.every(dt, plan.duration)
    samples = round(plan.duration / dt) // every
    s, _ = lagged_run(plan, every * dt, samples, settings, bandwidth, math.inf, None)
    a = _inner_transition(plan.n_joints, settings, every * dt)
    return np.asarray(s[1:] - s[:-1] @ a.T)


def _inner_gains_of(n: int, settings: MpcSettings) -> tuple[Array, Array]:
    """The inner law's kp, kv (N,) of ``settings`` (``INNER_KP``, ``INNER_KV`` unless set)."""
    kp = np.full(n, INNER_KP) if settings.kp is None else np.asarray(settings.kp, dtype=float)
    kv = np.full(n, INNER_KV) if settings.kv is None else np.asarray(settings.kv, dtype=float)
    return kp, kv


def _inner_transition(n: int, settings: MpcSettings, ts: float) -> Array:
    """(2 N, 2 N): the inner law's errors (e_j, e_j') over one sample of ``ts`` [s]."""
    kp, kv = _inner_gains_of(n, settings)
    a = np.zeros((2 * n, 2 * n))
    for j in range(n):
        a[2 * j: 2 * j + 2, 2 * j: 2 * j + 2] = discretise(float(kp[j]), float(kv[j]), ts)[0]
    return a


#: ``tracked_offsets``: at most this many passes along the MPC's own path, stopping once the
#: largest model miss of a pass is below ``OFFSET_TOLERANCE`` [rad, rad/s]. On the paper's
#: maneuver at 4 rad/s (the least-peak-rate re-plan, b = 100 rad/s), passes made on the
#: compiled loop's trial with no error: misses 7.9e-5, 5.0e-5, 6.9e-6, 2.6e-6, 3.2e-7, and 0,
#: 0, 68, 100, 100 of 100 trials reached after 0-4 passes (2026-12-05).
OFFSET_PASSES = 3
OFFSET_TOLERANCE = 1e-7


def tracked_offsets(plan: Any, dt: float, settings: MpcSettings, bandwidth: float,
                    rate_limit: float, torques: TorqueRows | None = None) -> Array:
    """The servo's offsets c_k (K, 4) on the path the MPC itself takes, for ``flat_design``:
    ``servo_offsets`` (the lag along the inner law's path with dv = 0), then passes of the
    MPC's own closed loop from the plan's start with no error (``lagged_path``: its
    corrections from ``sample_step`` on the design with the offsets so far, the joint
    rates lagging their commands clipped at ``rate_limit`` [rad/s]), each adding to c_k
    the miss s_k+1 - (A s_k + B dv_k + c_k) of the model along that path (at most
    ``OFFSET_PASSES``). On a plan whose ends lie near the singular set the path with dv = 0
    leaves the plan far (the paper's maneuver re-planned within 4 rad/s: 0.60 rad in th2)
    and the corrections' own lag moves the flat outputs at T by 1.1e-4, which the angles
    there multiply by 1,005 (docs/physics.md, "On the dynamic plant")."""
    offsets = servo_offsets(plan, dt, settings, bandwidth)
    for _ in range(OFFSET_PASSES):
        d = flat_design(plan.model, plan.trajectory, plan.duration, dt, rate_limit, settings,
                        offsets, torques)
        s, dv = lagged_path(plan, d, dt, settings, bandwidth, rate_limit)
        size = s.shape[1]
        a, b = d.A[:, :size, :size], d.B[:, :size, :]
        miss = (s[1:] - np.einsum("kij,kj->ki", a, s[:-1]) - np.einsum("kij,kj->ki", b, dv)
                - offsets)
        offsets = offsets + miss
        if np.abs(miss).max() < OFFSET_TOLERANCE:
            break
    return offsets


def lagged_path(plan: Any, d: Design, dt: float, settings: MpcSettings, bandwidth: float,
                rate_limit: float) -> tuple[Array, Array]:
    """The MPC (design ``d``, with a servo offset) from the plan's start with no error on the
    lagged robot (``lagged_run``) with its joint-rate commands clipped at ``rate_limit``
    [rad/s], each sample's correction from ``sample_step``. Returns the errors measured at
    the samples (K + 1, 2 N) (e_j, e_j' per flat output; y' from the commanded rates, as the
    loop measures) and the corrections held (K, N) [rad/s^2]."""
    s = scratch(d)
    reset(s)
    size = 2 * plan.n_joints

    def step(k: int, errors: Array) -> Array:
        s.s0[:size] = errors
        sample_step(d, s, k)
        return np.asarray(s.held, dtype=float).copy()

    return lagged_run(plan, d.every * dt, d.samples, settings, bandwidth, rate_limit, step)


def _flag_evaluator(trajectory: Any) -> Any:
    """The plan's flag y, y', y'' (3 N,) at one time t [s], from its piecewise polynomials
    (``FlatTrajectory.piecewise``): what ``trajectory.flags`` gives (to 1.2e-13 on a
    B-spline re-plan of flags up to 2, its rounding; 4e-16 on a polynomial), 8 us a call
    where ``flags`` takes 156 (a basis matrix a call): ``lagged_run``'s DOP853 asks it at
    every evaluation, ~20,000 a design on the dynamic plant (2026-12-06: 6.8 of the
    design's 10 s went there)."""
    breaks, local = trajectory.piecewise()  # (m + 1,), (m, degree + 1, N)
    width = np.diff(breaks)
    degree = local.shape[1] - 1
    power = np.arange(degree + 1, dtype=float)
    first = local[:, 1:, :] * power[1:, None]  # d/ds: s^0 .. s^(degree - 1)
    second = local[:, 2:, :] * (power[2:] * (power[2:] - 1.0))[:, None]
    last = len(width) - 1

    def flag_at(t: float) -> Array:
        i = min(max(int(np.searchsorted(breaks, t, side="right")) - 1, 0), last)
        w = width[i]
        s = np.asarray(((t - breaks[i]) / w) ** power)
        return np.concatenate([s @ local[i], (s[:degree] @ first[i]) / w,
                               (s[:degree - 1] @ second[i]) / (w * w)])

    return flag_at


def lagged_run(plan: Any, ts: float, samples: int, settings: MpcSettings, bandwidth: float,
               rate_limit: float, step: Any) -> tuple[Array, Array]:
    """The inner flat law (``settings``' gains) from the plan's start with no error, N joints,
    on the robot whose joint rates w follow the commands r clipped at ``rate_limit``
    [rad/s] as a first-order servo, w' = bandwidth (sat(r) - w) (what the dynamic plant does
    when the servo's model is right and no torque is clipped), w(0) = r(0); the law's
    integrators u_j held while their command is clipped and pushed further (the dynamic
    plant's rule, ``control.unwound``); the base from H = 0 with the robot's momentum
    weights (``chain.momentum_weights``: h_0 th0' = -sum_j h_j w_j); dv_k = step(k, s_k)
    added to the law's y'' over sample k (``step`` None: dv = 0). State (th0..thN,
    u_1..u_N-1, w_1..w_N), DOP853 at rtol ``DISCRETE_RTOL`` over each sample of ``ts`` [s].
    Returns the errors measured at the samples (K + 1, 2 N) (e_j = y_j - y_jd, then e_j';
    y' from the commanded u, as the loop measures) and the corrections held (K, N)."""
    from scipy.integrate import solve_ivp

    from flatcli.core.models.chainflat import inputs
    from flatcli.core.models.flatmodel import ChainModel
    from flatcli.core.robots.chain import momentum_weights

    n = plan.n_joints
    model = ChainModel.of(plan.robot)
    kp, kv = _inner_gains_of(n, settings)
    K, inertia = np.array(model.K), np.array(model.inertia)
    limit = rate_limit if math.isfinite(rate_limit) else math.inf
    nb = n + 1
    weights = np.zeros(nb)

    flag_at = _flag_evaluator(plan.trajectory)

    def measured(x: Array, t: float) -> tuple[Array, Array]:
        y, y_dot, _ = model.outputs(x[None, :nb], x[None, nb: nb + n - 1])
        flag = flag_at(t)  # y, y', y'' (3 N,)
        s = np.empty(2 * n)
        s[0::2] = y[0] - flag[:n]
        s[1::2] = y_dot[0] - flag[n: 2 * n]
        return s, flag

    def rhs(t: float, x: Array, dv: Array) -> Array:
        s, flag = measured(x, t)
        v = flag[2 * n:] + dv - kp * s[0::2] - kv * s[1::2]
        theta, u, w = x[:nb], x[nb: nb + n - 1], x[nb + n - 1:]
        u_dot = np.zeros(n - 1)
        r_last = float(inputs(K, inertia, theta, u, v, u_dot))
        out = np.empty_like(x)
        for j in range(n - 1):
            if (u[j] >= limit and u_dot[j] > 0.0) or (u[j] <= -limit and u_dot[j] < 0.0):
                u_dot[j] = 0.0
        r = np.clip(np.append(u, r_last), -limit, limit)
        momentum_weights(K, inertia, theta, weights)
        out[0] = -float(weights[1:] @ w) / weights[0]
        out[1:nb] = w
        out[nb: nb + n - 1] = u_dot
        out[nb + n - 1:] = bandwidth * (r - w)
        return out

    start = plan.sample(np.array([0.0]))
    rates = start.theta_dot[0][1:]  # th1'..thN' of the plan at t = 0
    x = np.concatenate([start.theta[0], rates[:n - 1], rates])
    errors = np.zeros((samples + 1, 2 * n))
    held = np.zeros((samples, n))
    for k in range(samples):
        errors[k] = measured(x, k * ts)[0]
        if step is not None:
            held[k] = step(k, errors[k])
        sol = solve_ivp(rhs, (k * ts, (k + 1) * ts), x, method="DOP853", rtol=DISCRETE_RTOL,
                        atol=DISCRETE_ATOL, args=(held[k].copy(),))
        if not sol.success:
            raise FlatcliError(f"track.mpc_sample: the servo's lag could not be integrated "
                               f"over sample {k} ({sol.message})")
        x = sol.y[:, -1]
    errors[-1] = measured(x, samples * ts)[0]
    return errors, held


def rows(d: Design) -> int:
    """The QP's constraints at most: S terminal equalities, per sample a two-sided row of
    each quantity (and of each endpoint one at its interval's end), and the slack's own."""
    size = int(d.A.shape[1]) - d.offset
    quantities = int(d.value.shape[1])
    return size + d.horizon * (quantities + int(d.endpoint.sum())) + 1


class Scratch(NamedTuple):
    """One trial's MPC state and buffers (``scratch``): the correction held dv (N,), the last
    solution (n,), the sample it was solved at plus one (valid[0]; 0: none), the QP's rows
    C (m, n), their bounds lo, hi (m,), widths (m,) and softness (m,) (``qp.solve``), its
    gradient (n,) and solution (n,), the measured errors s0 (S,), a row (n,) and a row of
    state slopes (S,) being propagated, the QP's buffers, and counters: QP iterations,
    infeasible samples, largest slack, the bounds the last QP was started from; for the
    warm start (``sample_step``): each row's key (m,) (its quantity, sample and end, -1 for
    none), the bounds guessed active (m,), and per key the bound active in the last QP
    solved (0 none, 1 lower, 2 upper); the predicted state's response to the corrections
    gamma (2, S, n - 1) and to s0 free (2, S) at horizon samples i and i + 1
    (``_forward``)."""

    held: Array
    last: Array
    valid: Array
    C: Array
    lo: Array
    hi: Array
    width: NDArray[np.int64]
    soft: Array
    g: Array
    x: Array
    s0: Array
    row: Array
    slope: Array
    spare: Array
    work: qp.Work
    counters: Array
    keys: NDArray[np.int64]
    guess: NDArray[np.int64]
    marks: NDArray[np.int64]
    gamma: Array
    free: Array


def scratch(d: Design) -> Scratch:
    """Fresh buffers for one trial's samples."""
    inputs = d.B.shape[2]
    size = d.factors.shape[1]
    states = d.A.shape[1]
    m = rows(d)
    return Scratch(np.zeros(inputs), np.zeros(size), np.zeros(1), np.zeros((m, size)),
                   np.zeros(m), np.zeros(m), np.zeros(m, dtype=np.int64), np.zeros(m),
                   np.zeros(size), np.zeros(size), np.zeros(states), np.zeros(size),
                   np.zeros(states), np.zeros(states), qp.work(size, m), np.zeros(4),
                   np.full(m, -1, dtype=np.int64), np.zeros(m, dtype=np.int64),
                   np.zeros(_keys(d), dtype=np.int64), np.zeros((2, states, size - 1)),
                   np.zeros((2, states)))


def _keys(d: Design) -> int:
    """How many row keys there are: (K + 2) samples, Q quantities, 2 ends (``_key``)."""
    return (d.samples + 2) * int(d.value.shape[1]) * 2


@jitable
def _key(d: Design, at: int, q: int, end: int) -> int:
    """The key of quantity q's row at sample ``at`` (at the start of its interval, end 0, or
    at its end, 1: the same for a quantity continuous in time, whose value there is the
    next interval's start): the same constraint has the same key at every sample that
    builds it."""
    return int((at * d.value.shape[1] + q) * 2 + (end if d.endpoint[q] != 0.0 else 0))


#: Where ``Scratch.counters`` keeps what a trial reports, and the bounds the last QP was
#: started from (``QP_GUESSED``, not reported).
QP_ITERATIONS, QP_INFEASIBLE, QP_SLACK, QP_GUESSED = 0, 1, 2, 3


@jitable
def reset(s: Scratch) -> None:
    """A trial starts: no correction held, no solution, counters at 0."""
    s.held[:] = 0.0
    s.valid[0] = 0.0
    s.counters[:] = 0.0
    s.marks[:] = 0


@jitable
def _row(d: Design, s: Scratch, k: int, i: int, at: int, q: int, direct: int) -> float:
    """Into s.row: the coefficients on the corrections of quantity q's deviation from the
    plan's at sample ``at`` given the state at horizon sample i (q < 0: the unit state
    component -q - 1), plus its slope along dv_direct (direct < 0: none); returns the
    deviation's value from s0 alone. The state's slope row is carried back through the
    transitions (slope . A_k+i-1 ... A_k+j+1 B_k+j for dv_j)."""
    inputs = d.B.shape[2]
    states = d.A.shape[1]
    slope, spare = s.slope, s.spare
    for c in range(states):
        slope[c] = (1.0 if c == -q - 1 else 0.0) if q < 0 else d.slope_s[at, q, c]
    s.row[:] = 0.0
    for j in range(i - 1, -1, -1):
        kk = k + j
        for v in range(inputs):
            acc = 0.0
            for c in range(states):
                acc += slope[c] * d.B[kk, c, v]
            s.row[j * inputs + v] = acc
        for c in range(states):
            acc = 0.0
            for r in range(states):
                acc += slope[r] * d.A[kk, r, c]
            spare[c] = acc
        for c in range(states):
            slope[c] = spare[c]
    if direct >= 0 and q >= 0:
        for v in range(inputs):
            s.row[direct * inputs + v] += d.slope_v[at, q, v]
    value = 0.0
    for c in range(states):
        value += slope[c] * s.s0[c]
    return value


@jitable
def _forward(d: Design, s: Scratch, k: int, i: int, now: int) -> None:
    """The predicted state at horizon sample i + 1 from that at i (s.gamma[now],
    s.free[now] into s.gamma[1 - now], s.free[1 - now]): gamma_i+1 = A_k+i gamma_i with
    B_k+i as the columns of dv_i, free_i+1 = A_k+i free_i (s_i = free_i + gamma_i dv)."""
    inputs = d.B.shape[2]
    states = d.A.shape[1]
    kk = k + i
    a = d.A[kk]
    g0, g1 = s.gamma[now], s.gamma[1 - now]
    f0, f1 = s.free[now], s.free[1 - now]
    width = i * inputs
    for r in range(states):
        acc = 0.0
        for c in range(states):
            acc += a[r, c] * f0[c]
        f1[r] = acc
        for v in range(width):
            g1[r, v] = 0.0
        for c in range(states):
            arc = a[r, c]
            for v in range(width):
                g1[r, v] += arc * g0[c, v]
        for v in range(inputs):
            g1[r, width + v] = d.B[kk, r, v]


@jitable
def _forward_row(d: Design, s: Scratch, now: int, j: int, at: int, q: int,
                 direct: int) -> float:
    """``_row`` from the predicted state at horizon sample j (s.gamma[now], s.free[now]):
    into s.row[:(direct + 1) N] quantity q's coefficients on the corrections at sample
    ``at``, its slope along dv_direct added; returns its deviation from s0 alone."""
    inputs = d.B.shape[2]
    states = d.A.shape[1]
    g, f = s.gamma[now], s.free[now]
    width = j * inputs
    for v in range(width):
        s.row[v] = 0.0
    for v in range(width, (direct + 1) * inputs):
        s.row[v] = 0.0
    value = 0.0
    for c in range(states):
        slope = d.slope_s[at, q, c]
        value += slope * f[c]
        for v in range(width):
            s.row[v] += slope * g[c, v]
    for v in range(inputs):
        s.row[direct * inputs + v] += d.slope_v[at, q, v]
    return value


@jitable
def _append(s: Scratch, count: int, width: int, lo: float, hi: float, slack: bool,
            key: int = -1) -> int:
    """Row ``count`` of the QP: lo <= s.row[:width] x (+- the slack) <= hi, its key
    ``key`` (-1: none); returns count + 1."""
    for c in range(width):
        s.C[count, c] = s.row[c]
    s.lo[count] = lo
    s.hi[count] = hi
    s.width[count] = width
    s.soft[count] = 1.0 if slack else 0.0
    s.keys[count] = key
    return count + 1


#: The first sample's guess (``sample_step``): a bound the plan's own value lies within
#: this fraction of [-]. At 0: the bounds the plan itself meets or breaks. Measured on the
#: paper's maneuver at 4 rad/s (the re-plan's th2' at 3.72-3.75 rad/s for long stretches,
#: kept at 3.88), 8 trials of 2 mrad: at 5 % the first QP took 198 iterations (the rows
#: guessed at both ends of those stretches dropped again) against 12 with no guess; at 2 %
#: and less nothing is guessed there (2026-12-05).
GUESS_WITHIN = 0.0


@jitable
def sample_step(d: Design, s: Scratch, k: int) -> None:
    """The correction for sample k (0..K - 1) into s.held, from the errors s.s0 measured
    there (module docstring)."""
    inputs = d.B.shape[2]
    states = d.A.shape[1]
    quantities = d.value.shape[1]
    size = s.row.shape[0]
    terminal = states - d.offset  # the errors s(T) = 0 is about (not the constant 1)
    if d.offset != 0:
        s.s0[states - 1] = 1.0
    for v in range(d.held):  # the correction held over the last sample (``_jump_design``)
        s.s0[terminal + v] = s.held[v]
    remaining = d.samples - k
    if remaining * inputs < terminal:  # too few samples left to meet s(T) = 0: hold the plan
        ahead = k - int(s.valid[0]) + 1  # samples since the last QP solved (valid: its k + 1)
        for v in range(inputs):
            at = ahead * inputs + v
            s.held[v] = s.last[at] if s.valid[0] != 0.0 and at < size - 1 else 0.0
        return
    costed = min(d.horizon, remaining)
    gradient = d.gradients[k]
    for c in range(size):
        acc = 0.0
        for q in range(states):
            acc += gradient[c, q] * s.s0[q]
        s.g[c] = acc
    s.g[size - 1] += SLACK_LINEAR
    count = 0
    if remaining <= d.horizon:  # the goal: s(T) = 0
        for c in range(terminal):
            value = _row(d, s, k, remaining, k + remaining, -c - 1, -1)
            count = _append(s, count, remaining * inputs, -value, -value, False)
    meq = count
    previous = k > 0 and s.valid[0] == k  # sample k - 1's QP solved: guess its active set
    guessed = 0
    now = 0  # s.gamma[now], s.free[now]: the state at horizon sample i
    for c in range(states):
        s.free[now, c] = s.s0[c]
    for i in range(costed):
        _forward(d, s, k, i, now)
        for q in range(quantities):
            for end in range(2):  # at the interval's start; an endpoint also at its end
                if end == 1 and d.endpoint[q] == 0.0 and i < costed - 1:
                    continue  # a continuous quantity: the next sample's start row
                at = k + i + end
                lo = d.lo[at, q]
                hi = d.hi[at, q]
                if math.isinf(lo) and math.isinf(hi):
                    continue
                deviation = _forward_row(d, s, now if end == 0 else 1 - now, i + end, at,
                                         q, i)
                value = d.value[at, q] + deviation
                width = (i + 1) * inputs
                if end == 0 and d.endpoint[q] == 0.0:
                    width = i * inputs  # no dv of its own sample: a state's function
                    if i == 0:
                        continue  # the measured state: nothing to choose
                key = _key(d, at, q, end)
                if d.warm_start != 0:
                    side = -1
                    if previous:  # the bound active for this row at the last sample
                        side = s.marks[key] - 1
                    elif not math.isinf(hi) and d.value[at, q] >= hi - GUESS_WITHIN * abs(hi):
                        side = 1  # the plan's own value near a bound
                    elif not math.isinf(lo) and d.value[at, q] <= lo + GUESS_WITHIN * abs(lo):
                        side = 0
                    if side >= 0:
                        s.guess[guessed] = 2 * count + side
                        guessed += 1
                count = _append(s, count, width, lo - value, hi - value, True, key)
        now = 1 - now
    if d.warm_start != 0:  # the slack at 0
        s.guess[guessed] = 2 * count
        guessed += 1
    count = _append(s, count, 0, 0.0, math.inf, True)  # the slack itself: s >= 0
    status, iterations, active = qp.solve_warm(d.factors[k], s.g, s.C, s.lo, s.hi, s.width,
                                               s.soft, meq, count, s.x, s.work,
                                               ITERATIONS_PER_ROW * (size + count),
                                               s.guess, guessed)
    s.counters[QP_ITERATIONS] += iterations
    s.counters[QP_GUESSED] = guessed
    if status != qp.OPTIMAL:  # no correction: the inner law alone
        s.counters[QP_INFEASIBLE] += 1.0
        s.held[:] = 0.0
        s.valid[0] = 0.0
        return
    s.marks[:] = 0  # what the next sample guesses
    for j in range(active):
        row = s.work.active[j] // 2
        if row >= meq and s.keys[row] >= 0:
            s.marks[s.keys[row]] = s.work.active[j] % 2 + 1
    slack = s.x[size - 1]
    if slack > SLACK_TOLERANCE:
        s.counters[QP_INFEASIBLE] += 1.0
    s.counters[QP_SLACK] = max(s.counters[QP_SLACK], slack)
    for v in range(inputs):
        s.held[v] = s.x[v]
    for c in range(size):
        s.last[c] = s.x[c]
    s.valid[0] = k + 1.0


@jitable
def period(d: Design) -> int:
    """Output steps between samples."""
    return d.every


@jitable
def extras(s: Scratch, row: Array) -> None:
    """The trial's ``COLUMNS`` into row (3,): QP iterations, infeasible samples (counts),
    the largest slack [the quantities' units]."""
    row[0] = s.counters[QP_ITERATIONS]
    row[1] = s.counters[QP_INFEASIBLE]
    row[2] = s.counters[QP_SLACK]


#: The per-trial columns the MPC reports (``extras``).
COLUMNS = ("qp_iterations", "qp_infeasible", "qp_slack_max")

#: ``design_for``'s designs by what they are made of (``_design_key``), most recent last:
#: a sweep's cells that differ only in what the design does not read (a torque limit on the
#: kinematic plant, a trial count, ...) share one design instead of each making it (2-5 s
#: on the dynamic plant, 4-14 s before ``_flag_evaluator``; there a torque limit is read
#: since the torque rows: each limit its own design).
_DESIGNS: dict[bytes, Design] = {}
DESIGNS_KEPT = 8


def _design_key(scenario: Any, settings: MpcSettings) -> bytes | None:
    """What a design is made of, as bytes (None: not picklable, no reuse): the plan's robot,
    trajectory, duration and model (the coefficients the controller believes), the output
    step, the rate limit, the settings (inner gains included), the plant, its servo's
    bandwidth, the law and its weights, the torque limit the rows keep (``_torque_kept``)
    and ``TORQUE_ROWS``."""
    import hashlib
    import pickle

    plan = scenario.plan
    try:
        blob = pickle.dumps((type(plan).__name__, plan.robot, plan.trajectory, plan.duration,
                             plan.model, getattr(plan, "coefficients", None),
                             scenario.dt, scenario.rate_limit, settings, scenario.plant,
                             scenario.servo_bandwidth, scenario.law, scenario.lqr,
                             _torque_kept(scenario), TORQUE_ROWS))
    except Exception:  # an object that cannot be pickled: no reuse
        return None
    return hashlib.sha256(blob).digest()


def design_for(scenario: Any) -> Design:
    """The MPC's design for a ``loop.simulate.Scenario`` (its settings for "mpc"): about the
    flat plan (``flat_design``), or about an exact plan with the as-built law
    (``asbuilt_design``, the dynamic plant's servo bandwidth a state); the same design
    again where it is made of the same things (``_design_key``)."""
    settings = _settings(scenario)
    key = _design_key(scenario, settings)
    if key is not None and key in _DESIGNS:
        found = _DESIGNS.pop(key)
        _DESIGNS[key] = found
        return found
    made = _design_for(scenario, settings)
    if key is not None:
        _DESIGNS[key] = made
        while len(_DESIGNS) > DESIGNS_KEPT:
            del _DESIGNS[next(iter(_DESIGNS))]
    return made


def _design_for(scenario: Any, settings: MpcSettings) -> Design:
    """``design_for`` without reuse."""
    if scenario.law == "asbuilt":
        servo = scenario.servo_bandwidth if scenario.plant == "dynamic" else None
        return asbuilt_design(scenario.plan, scenario.lqr, scenario.dt, scenario.rate_limit,
                              settings, servo)
    plan = scenario.plan
    offsets = None
    torques = None
    kept = _torque_kept(scenario)
    if math.isfinite(kept):
        every = settings.every(scenario.dt, plan.duration)
        torques = servo_torques(plan, settings, every * scenario.dt,
                                round(plan.duration / scenario.dt) // every, kept,
                                scenario.servo_bandwidth, TORQUE_ROWS == "jump")
    if scenario.plant == "dynamic":
        offsets = _offsets_for(scenario, settings)
    return flat_design(plan.model, plan.trajectory, plan.duration, scenario.dt,
                       scenario.rate_limit, settings, offsets, torques)


#: ``_offsets_for``'s servo offsets by what they are made of (``_design_key`` of the scenario
#: without a torque limit), most recent last: a torque-limit grid shares them.
_OFFSETS: dict[bytes, Array] = {}


def _offsets_for(scenario: Any, settings: MpcSettings) -> Array:
    """The servo's offsets of a flat design on the dynamic plant (``tracked_offsets``),
    made without the torque rows and shared by every torque limit (the lag of the MPC's
    own path from the plan's start with no error, which the rows do not bind at the
    limits measured: docs/physics.md, "The torque rows"): each limit's design then takes
    0.05 s instead of 3-10 s (2026-12-06)."""
    free = replace(scenario, torque_kept=math.inf) if math.isfinite(
        getattr(scenario, "torque_kept", math.inf)) else scenario
    key = _design_key(free, settings)
    if key is not None and key in _OFFSETS:
        return _OFFSETS[key]
    offsets = tracked_offsets(scenario.plan, scenario.dt, settings, scenario.servo_bandwidth,
                              scenario.rate_limit)
    if key is not None:
        _OFFSETS[key] = offsets
        while len(_OFFSETS) > DESIGNS_KEPT:
            del _OFFSETS[next(iter(_OFFSETS))]
    return offsets


#: The flat MPC on the dynamic plant bounds its servo's torques (``servo_torques``) where
#: the MPC keeps a finite torque limit (``Scenario.torque_kept``): "jump" just after each
#: sample's jump and at each interval's end (``_jump_design``), "sustained" the quasi-steady
#: torque at each interval's start and end, "none": no torque rows (the design before
#: 2026-12-06; for measurement).
TORQUE_ROWS = "jump"


def _torque_kept(scenario: Any) -> float:
    """The torque limit the flat MPC's rows keep [N m] (``Scenario.torque_kept``): inf off
    the dynamic plant, for the as-built law, or with ``TORQUE_ROWS`` off."""
    kept = float(getattr(scenario, "torque_kept", math.inf))
    if TORQUE_ROWS == "none" or scenario.plant != "dynamic" or scenario.law == "asbuilt":
        return math.inf
    return kept


def inner_gains(scenario: Any) -> Gains:
    """The inner flat law's gains: ``track.mpc_kp``, ``track.mpc_kv`` (``INNER_KP``,
    ``INNER_KV`` unless set)."""
    n = scenario.n_joints
    settings = _settings(scenario)
    kp = settings.kp if settings.kp is not None else (INNER_KP,) * n
    kv = settings.kv if settings.kv is not None else (INNER_KV,) * n
    return Gains(tuple(kp), tuple(kv))


def _settings(scenario: Any) -> MpcSettings:
    """The scenario's MPC settings; the flat law's on the dynamic plant with its inner
    gains ``DYNAMIC_INNER_KP``, ``DYNAMIC_INNER_KV`` (``TORQUE_INNER_KP``,
    ``TORQUE_INNER_KV`` on a plan re-planned within the torque limit, no rate limit) unless
    ``track.mpc_kp``, ``mpc_kv`` are set."""
    import dataclasses

    settings: MpcSettings = scenario.settings_for("mpc")
    if scenario.law == "asbuilt" or scenario.plant != "dynamic":
        return settings
    n = scenario.n_joints
    kp0, kv0 = ((TORQUE_INNER_KP, TORQUE_INNER_KV) if scenario.torque_replanned
                else (DYNAMIC_INNER_KP, DYNAMIC_INNER_KV))
    kp = settings.kp if settings.kp is not None else (kp0,) * n
    kv = settings.kv if settings.kv is not None else (kv0,) * n
    return dataclasses.replace(settings, kp=tuple(kp), kv=tuple(kv))


#: The MPC's parts for the loop factory (``loop.compose``).
PART = SampledPart("mpc", scratch, reset, period, sample_step, extras, COLUMNS, COLUMNS[:2],
                   design_for, inner_gains)


def asbuilt_design(plan: Any, weights: Any, dt: float, rate_limit: float,
                   settings: MpcSettings, servo: float | None = None) -> Design:
    """The MPC about a plan of a robot as built (module docstring): the inner law is the
    as-built LQR w = w_r - L(t) e (``lqr``: its weights ``weights``, designed on the plan's
    robot; the dynamic plant's servo lag of bandwidth ``servo`` [rad/s] a state too) and
    dv is added to the joint rates it commands; the errors e (the angles th0..thN, then the
    joint rates with a servo: the order of ``lqr.linearisation``) obey, to first order,
    e' = (A(t) - B(t) L(t)) e + B(t) dv, discretised over each sample by integrating the
    transition and the response to a held dv (DOP853 at rtol ``DISCRETE_RTOL``). The
    quantities are the commanded joint rates w_r - L e + dv (with a servo, plus the plan's
    joint accelerations over its bandwidth: the lead the law adds), bounded by the rate
    limit; there is no singular set, so no margin.

    Raises FlatcliError naming the key if the sample time does not fit (``MpcSettings``).
    """
    from scipy.integrate import solve_ivp

    from flatcli.core.controllers.lqr import TrackedLayout, linearisation, tracked
    from flatcli.core.plan.exact import constraint_of

    duration = plan.duration
    every = settings.every(dt, duration)
    samples = round(duration / dt) // every
    ts = every * dt
    n = plan.n_joints
    curves = tracked(plan, weights, servo)
    layout = TrackedLayout(n, 2 * n + 1 if servo is not None else n + 1)
    size = layout.width
    constraint = constraint_of(plan.robot)

    def closed_loop(t: float) -> tuple[Array, Array]:
        channels = curves.derivative(np.array([t]), 0)[0]
        rates = curves.derivative(np.array([t]), 1)[0]
        a, b = linearisation(constraint, channels[None, :n], rates[None, :n], servo)
        gains = channels[n + 1:].reshape(n, size)
        return a[0] - b[0] @ gains, b[0]

    def rhs(t: float, z: Array) -> Array:
        acl, b = closed_loop(t)
        phi = z[: size * size].reshape(size, size)
        gamma = z[size * size:].reshape(size, n)
        return np.concatenate([(acl @ phi).ravel(), (acl @ gamma + b).ravel()])

    A = np.zeros((samples, size, size))
    B = np.zeros((samples, size, n))
    start = np.concatenate([np.eye(size).ravel(), np.zeros(size * n)])
    for k in range(samples):
        sol = solve_ivp(rhs, (k * ts, (k + 1) * ts), start, method="DOP853",
                        rtol=DISCRETE_RTOL, atol=DISCRETE_ATOL)
        if not sol.success:
            raise FlatcliError(f"track.mpc_sample: the as-built law's error could not be "
                               f"discretised over sample {k} ({sol.message})")
        end = sol.y[:, -1]
        A[k] = end[: size * size].reshape(size, size)
        B[k] = end[size * size:].reshape(size, n)
    times = np.arange(samples + 1) * ts
    channels = curves.derivative(times, 0)
    value = curves.derivative(times, 1)[:, :n].copy()  # w_r: the joints' planned rates
    if servo is not None:
        value += curves.derivative(times, 2)[:, :n] / servo
    slope_s = -channels[:, n + 1:].reshape(samples + 1, n, size)
    slope_v = np.broadcast_to(np.eye(n), (samples + 1, n, n)).copy()
    limit = rate_limit * (1.0 - settings.backoff) if math.isfinite(rate_limit) else math.inf
    lo = np.full((samples + 1, n), -limit)
    hi = np.full((samples + 1, n), limit)
    endpoint = np.ones(n)
    return design(A, B, np.full(size, settings.weight_state), settings.weight_input, value,
                  slope_s, slope_v, lo, hi, endpoint, settings.horizon, every)


#: Tolerances of the as-built design's discretisation over each sample.
DISCRETE_RTOL = 1e-10
DISCRETE_ATOL = 1e-12
