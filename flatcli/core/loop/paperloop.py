"""The paper's robot (N = 2) in closed loop, in closed form: the right-hand sides of its
kinematic and dynamic plants under the controller (``simulate`` runs them for a flat plan of
three links; ``controllers.flat`` on ``plants``, composed by ``base``, are the same loops for
any N).

The controller (``control.feedback``) believes the nominal model; the plant always obeys the
true physics (the derived constraint for its own parameters, d2 of any value, and its own
angular momentum H0). The kinematic plant's state is x = (th0, th1, th2, u1):

    th1' = sat(u1),  th2' = sat(u2),  th0' = (B th1' + C th2' + M H0) / A,  u1' = v1

where (u1', u2) come from the controller at the measured angles th + noise, and sat clips a
joint rate to +-rate_limit (an actuator limit; infinite by default). While th1' is clipped
the controller's integrator does not wind up: u1' is set to 0 whenever u1 is at or beyond
the limit and v1 would push it further out (conditional integration, ``control.unwound``), so
u1 never runs away from the rate the joint actually turns at.

The dynamic plant (``plant.model = "dynamic"``) is the robot with inertia: free-floating
multibody dynamics (``dynamics``, the plant's own parameters, any d2) driven by joint torques
from a rate servo on each joint. Its state is x = (th0, th1, th2, th0', th1', th2', u1):

    M(q) q'' + C(q, q') q' = (0, tau1, tau2),   u1' = v1,
    r1 = sat(u1), r2 = sat(u2)                        (the joint-rate commands)
    a_k = bandwidth (r_k - th_k')                     (k = 1, 2: what the servo asks)
    tau = clip(Mhat_s a + chat_s, +-torque_limit)     (computed torque, each joint clipped)

with (u1', u2) from the controller at the measured angles as above, sat the rate limit, and
Mhat_s, chat_s the free-floating joint-space inertia and bias (``dynamics.joint_space``) of the
*servo's model* (the nominal ``[robot]``, or the plant itself with ``plant.servo_model =
"plant"``) at the true joint angles and rates (the joints' own encoders: the sensor noise
corrupts the controller's measurement only). Where the servo's model is the plant's and no
torque is clipped, each joint rate follows its command exactly as a first-order lag,
th_k'' = bandwidth (r_k - th_k'); the base turns as momentum conservation makes it. A
torque limit of 0 applies no torque at all: the robot drifts freely. u1 does not wind up
against the rate limit (as above); the servo's torque limit is not fed back to it.

Every right-hand side here has the same signature and writes the state's derivative into
``out[:nx]`` and the controller's signed margin into ``out[nx]``, so that one integrator
(``integrate``) serves every plant.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import Real, jitable
from flatcli.core.controllers.control import PaperGains, feedback, feedback_at, unwound
from flatcli.core.controllers.rest import faded_paper
from flatcli.core.loop.metrics import observe_clipped, observe_sample, observe_torque
from flatcli.core.models.flatness import chart, outputs_at
from flatcli.core.robots.dynamics import (
    ThreeBody,
    three_body,
    three_body_joint_space,
    three_body_terms,
)
from flatcli.core.robots.params import Coefficients, Links, base_rate_at, momentum_at

Array = NDArray[np.float64]

#: State size of the kinematic plant: th0, th1, th2 [rad], u1 [rad/s].
KINEMATIC_STATE = 4
#: Values ``kinematic_rhs`` writes after the state's derivative: the margin, then the plant's
#: cos th1, sin th1 and cos(th1 + th2) (shared with the metrics).
KINEMATIC_AUX = 4


#: State size of the dynamic plant: th0, th1, th2 [rad], th0', th1', th2' [rad/s], u1 [rad/s].
DYNAMIC_STATE = 7
#: Values ``dynamic_rhs`` writes after the state's derivative: the margin, tau1, tau2 [N m],
#: the rate command r2 [rad/s], whether a torque was clipped (1.0) or not (0.0), and the
#: plant's cos th1, sin th1, cos(th1 + th2), sin(th1 + th2).
DYNAMIC_AUX = 9
#: Where ``dynamic_rhs`` writes them in its output (after the 7 rates and the margin).
AUX_TAU1, AUX_TAU2, AUX_R2, AUX_SATURATED, AUX_C1, AUX_S1, AUX_C12, AUX_S12 = range(8, 16)


class Loop(NamedTuple):
    """What one trial's closed loop needs (floats and tuples of floats, for the kernels).

    kc : the controller's coefficients (d2 = 0); gains : PaperGains
    kq : the plant's constraint coefficients (derived model, its own d2)
    links : the plant's link parameters; total_mass : the plant's M [kg]
    h0 : the plant's angular momentum [kg m^2/s]; rate_limit : joint-rate limit [rad/s]
    flat_plant : the plant has d2 = 0, so its terms in cos th2 and cos(th1 + th2) vanish and
        are skipped (the same numbers to the bit: those terms are multiplied by zero)
    offset : the turn alpha [rad] of link 2 that a centre of mass across it adds (its
        coefficients and links are those of its equivalent placement,
        ``model.RobotParams.placement``): th2 + alpha enters its physics
    """

    kc: Coefficients
    gains: PaperGains
    kq: Coefficients
    links: Links
    total_mass: float
    h0: float
    rate_limit: float
    flat_plant: bool
    offset: float = 0.0


@jitable
def kinematic_rhs(loop: Loop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the kinematic plant's state under the feedback.

    Parameters
    ----------
    loop : Loop
    x : (4,) th0, th1, th2 [rad], u1 [rad/s]
    ref : (6,) plan y1, y2, y1', y2', y1'', y2'' at this instant (a rest plan's flag: its
        channels, the feedback faded at the ends, ``controllers.rest``)
    noise : (3,) sensor noise on the three measured angles [rad]
    out : (>= 4 + KINEMATIC_AUX,) written: th0', th1', th2' [rad/s] (the applied joint rates),
        u1' [rad/s^2]; then the controller's signed margin sin(measured th1) * u1 [rad/s]
        (the feedback divides by it: where it changes sign the trial crosses the singular
        set), and the plant's cos th1, sin th1, cos(th1 + th2) (0 for a flat plant)
    """
    x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
    c1 = np.cos(x1)
    s1 = np.sin(x1)
    if noise[1] == 0.0:  # the controller measures th1 exactly: share its trigonometry
        cm1, sm1 = c1, s1
    else:
        cm1, sm1 = np.cos(x1 + noise[1]), np.sin(x1 + noise[1])
    u1_dot, u2 = feedback_at(loop.kc, loop.gains, x0 + noise[0], x1 + noise[1], x2 + noise[2],
                             x3, cm1, sm1, ref)
    margin = sm1 * x3
    if ref.shape[0] > 6:  # a rest plan's flag: the feedback faded (``rest``)
        u1_dot, u2, margin = faded_paper(ref, u1_dot, u2, margin)
    kinematic_plant(loop, x, c1, s1, x3, u2, out)
    out[3] = unwound(x3, u1_dot, loop.rate_limit)
    out[4] = margin


@jitable
def kinematic_plant(loop: Loop, x: Array, c1: float, s1: float, r1: float, r2: Real,
                    out: Array) -> None:
    """The kinematic plant of the paper's robot (closed form) under the joint-rate commands
    r1, r2 [rad/s]: th0', th1', th2' (sat(r1), sat(r2), the base from its momentum) into
    out[:3] and its cos th1, sin th1, cos(th1 + th2) (0 for a flat plant) into out[5:8];
    c1, s1 the cos and sin of its th1 (shared with a law that measures th1 exactly)."""
    limit = loop.rate_limit
    w1 = min(max(r1, -limit), limit)
    w2 = min(max(r2, -limit), limit)
    if loop.flat_plant:
        c2 = c12 = 0.0
    else:
        c2, c12 = np.cos(x[2] + loop.offset), np.cos(x[1] + x[2] + loop.offset)
    out[0] = base_rate_at(loop.kq, loop.total_mass, loop.h0, c1, c2, c12, w1, w2)
    out[1], out[2] = w1, w2
    out[5], out[6], out[7] = c1, s1, c12


class CommandLoop(NamedTuple):
    """The kinematic plant's ``Loop`` and the law's commands (2,) u1' [rad/s^2], u2 [rad/s],
    given by a controller written in Python before each evaluation (``loop.reference``)."""

    loop: Loop
    command: Array


@jitable
def command_rhs(loop: CommandLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """``kinematic_rhs`` with the law's commands given (``CommandLoop``); the margin is the
    flat law's, sin(measured th1) u1 [rad/s]."""
    c1, s1 = np.cos(x[1]), np.sin(x[1])
    kinematic_plant(loop.loop, x, c1, s1, x[3], loop.command[1], out)
    out[3] = unwound(x[3], loop.command[0], loop.loop.rate_limit)
    out[4] = np.sin(x[1] + noise[1]) * x[3]


@jitable
def observe_command(loop: CommandLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
                    ) -> None:
    """``observe_kinematic`` of a ``CommandLoop``."""
    observe_kinematic(loop.loop, obs, acc, j, x, f)


@jitable
def kinematic_momentum(loop: Loop, x: Array, f: Array) -> float:
    """H of the plant from its full link kinematics at state x with the rates f it applies
    (``model.momentum``; f as written by ``kinematic_rhs``) [kg m^2/s]."""
    # d2 = 0: s12 is multiplied by 0
    s12 = 0.0 if loop.flat_plant else np.sin(x[1] + x[2] + loop.offset)
    return float(momentum_at(loop.links, f[5], f[6], f[7], s12, f[0], f[1], f[2]))


class DynamicLoop(NamedTuple):
    """What one trial's closed loop with the dynamic plant needs (floats, for the kernels).

    kc : the controller's coefficients; gains : PaperGains
    links : the plant's link parameters (for H from the full kinematics)
    plant : the plant's chain (``dynamics.three_body``); servo : the servo's model of it
    same_model : servo and plant are the same chain (its terms are computed once)
    h0 : the plant's angular momentum [kg m^2/s]; rate_limit : joint-rate limit [rad/s]
    bandwidth : servo bandwidth [rad/s]; torque_limit : joint-torque limit [N m] (inf: none)
    offset : the plant's turn of link 2 [rad] (``Loop``); the servo's model, the nominal
        robot (d2 = 0, which th2 does not enter) or the plant, takes it too
    """

    kc: Coefficients
    gains: PaperGains
    links: Links
    plant: ThreeBody
    servo: ThreeBody
    same_model: bool
    h0: float
    rate_limit: float
    bandwidth: float
    torque_limit: float
    offset: float = 0.0


@jitable
def dynamic_loop(kc: Coefficients, gains: PaperGains, links: Links, servo_links: Links,
                 servo_is_plant: bool, h0: float, rate_limit: float, bandwidth: float,
                 torque_limit: float) -> DynamicLoop:
    """A ``DynamicLoop`` for a plant and a servo model (``servo_is_plant``: the servo knows
    the plant; else ``servo_links``, the nominal robot)."""
    plant = three_body(links)
    servo = plant if servo_is_plant else three_body(servo_links)
    same = servo_is_plant or plant == servo
    return DynamicLoop(kc, gains, links, plant, servo, same, h0, rate_limit, bandwidth,
                       torque_limit)


@jitable
def servo_torques(
    loop: DynamicLoop, hat11: float, hat12: float, hat22: float, chat1: float, chat2: float,
    r1: float, r2: float, th1_dot: float, th2_dot: float,
) -> tuple[float, float, float]:
    """The servo's joint torques tau1, tau2 [N m], clipped to the torque limit, and 1.0 if
    one was clipped (the servo asked for more), else 0.0.

    hat11, hat12, hat22 [kg m^2], chat1, chat2 [N m]: the servo model's free-floating
    joint-space inertia and bias at the state (``dynamics.three_body_joint_space``); r1, r2
    the rate commands and th1_dot, th2_dot the joint rates [rad/s].
    """
    a1 = loop.bandwidth * (r1 - th1_dot)
    a2 = loop.bandwidth * (r2 - th2_dot)
    demand1 = hat11 * a1 + hat12 * a2 + chat1
    demand2 = hat12 * a1 + hat22 * a2 + chat2
    limit = loop.torque_limit
    saturated = 1.0 if (abs(demand1) > limit or abs(demand2) > limit) else 0.0
    return (min(max(demand1, -limit), limit), min(max(demand2, -limit), limit), saturated)


@jitable
def dynamic_rhs(loop: DynamicLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the dynamic plant's state under the feedback and the servos.

    Parameters
    ----------
    loop : DynamicLoop
    x : (7,) th0, th1, th2 [rad], th0', th1', th2' [rad/s], u1 [rad/s]
    ref : (6,) plan y1, y2, y1', y2', y1'', y2'' at this instant
    noise : (3,) sensor noise on the three measured angles [rad]
    out : (>= 7 + DYNAMIC_AUX,) written: th0', th1', th2' [rad/s], th0'', th1'', th2''
        [rad/s^2], u1' [rad/s^2]; then the controller's signed margin sin(measured th1) * u1
        [rad/s], tau1, tau2 [N m], the rate command r2 [rad/s], 1.0 if a torque was clipped
        (else 0.0), and the plant's cos th1, sin th1, cos(th1 + th2), sin(th1 + th2)
    """
    x1 = x[1]
    c1 = np.cos(x1)
    s1 = np.sin(x1)
    if noise[1] == 0.0:  # the controller measures th1 exactly: share its trigonometry
        cm1, sm1 = c1, s1
    else:
        cm1, sm1 = np.cos(x1 + noise[1]), np.sin(x1 + noise[1])
    u1 = x[6]
    u1_dot, u2 = feedback_at(loop.kc, loop.gains, x[0] + noise[0], x1 + noise[1],
                             x[2] + noise[2], u1, cm1, sm1, ref)
    limit = loop.rate_limit
    r1 = min(max(u1, -limit), limit)
    r2 = min(max(float(u2), -limit), limit)
    c2 = np.cos(x[2] + loop.offset)
    s2 = np.sin(x[2] + loop.offset)
    m00, m01, m02, m11, m12, m22, h0, h1, h2 = three_body_terms(loop.plant, c1, s1, c2, s2,
                                                                x[3], x[4], x[5])
    a11, a12, a22, b1, b2 = three_body_joint_space(m00, m01, m02, m11, m12, m22, h0, h1, h2)
    if loop.same_model:
        tau1, tau2, saturated = servo_torques(loop, a11, a12, a22, b1, b2, r1, r2, x[4], x[5])
    else:
        s00, s01, s02, s11, s12, s22, g0, g1, g2 = three_body_terms(loop.servo, c1, s1, c2, s2,
                                                                    x[3], x[4], x[5])
        e11, e12, e22, f1, f2 = three_body_joint_space(s00, s01, s02, s11, s12, s22, g0, g1, g2)
        tau1, tau2, saturated = servo_torques(loop, e11, e12, e22, f1, f2, r1, r2, x[4], x[5])
    # the plant: Mhat qj'' = tau - chat, then the base from its own row
    rhs1 = tau1 - b1
    rhs2 = tau2 - b2
    inv_det = 1.0 / (a11 * a22 - a12 * a12)
    q1_ddot = (a22 * rhs1 - a12 * rhs2) * inv_det
    q2_ddot = (a11 * rhs2 - a12 * rhs1) * inv_det
    q0_ddot = -(m01 * q1_ddot + m02 * q2_ddot + h0) / m00
    out[0], out[1], out[2] = x[3], x[4], x[5]
    out[3], out[4], out[5] = q0_ddot, q1_ddot, q2_ddot
    out[6] = unwound(u1, u1_dot, limit)
    out[7] = sm1 * u1
    out[AUX_TAU1], out[AUX_TAU2] = tau1, tau2
    out[AUX_R2], out[AUX_SATURATED] = r2, saturated
    out[AUX_C1], out[AUX_S1] = c1, s1
    out[AUX_C12], out[AUX_S12] = c1 * c2 - s1 * s2, s1 * c2 + c1 * s2


@jitable
def dynamic_momentum(loop: DynamicLoop, x: Array, f: Array) -> float:
    """H of the plant from its full link kinematics (``model.momentum``) at state x with its
    own rates; f as written by ``dynamic_rhs`` [kg m^2/s]."""
    return float(momentum_at(loop.links, f[AUX_C1], f[AUX_S1], f[AUX_C12], f[AUX_S12], x[3],
                             x[4], x[5]))


@jitable
def dynamic_initial(loop: DynamicLoop, initial: Array, ref: Array, x0: Array) -> None:
    """The dynamic plant's state at t = 0 into ``x0`` (7,).

    th(0) and u1(0) from ``initial`` (4,); th1'(0) = r1 = sat(u1(0)) and th2'(0) = r2 =
    sat(u2(0)), the rate commands of the controller at t = 0 at the true angles (the servo
    starts in equilibrium); th0'(0) such that H = (M q')_0 = H0 of the plant.
    ``ref`` (6,) is the plan's flag at t = 0.
    """
    limit = loop.rate_limit
    u1 = initial[3]
    _, u2 = feedback(loop.kc, loop.gains, initial[0], initial[1], initial[2], u1, ref)
    r1 = min(max(u1, -limit), limit)
    r2 = min(max(u2, -limit), limit)
    m00, m01, m02, _, _, _, _, _, _ = three_body_terms(
        loop.plant, np.cos(initial[1]), np.sin(initial[1]), np.cos(initial[2] + loop.offset),
        np.sin(initial[2] + loop.offset), 0.0, 0.0, 0.0)
    x0[0], x0[1], x0[2] = initial[0], initial[1], initial[2]
    x0[3] = (loop.h0 - m01 * r1 - m02 * r2) / m00
    x0[4], x0[5], x0[6] = r1, r2, u1


@jitable
def is_flat_plant(k: Coefficients) -> bool:
    """Whether a plant's constraint has no d2-terms (d2 = 0): then its terms in cos th2 and
    cos(th1 + th2) vanish and the kinematic plant skips them (the same numbers to the bit)."""
    return (k.a2 == 0.0 and k.a3 == 0.0 and k.b2 == 0.0 and k.b3 == 0.0 and k.c2 == 0.0
            and k.c3 == 0.0)


@jitable
def observe_kinematic(loop: Loop, obs: Any, acc: Array, j: int, x: Array, f: Array) -> None:
    """Metrics of the kinematic plant at output sample j: H from the full link kinematics at
    the state with the joint rates the plant applies there (f)."""
    theta_ref, ref, threshold = obs
    observe_sample(acc, j, x[0], x[1], x[2], x[3], f[5], f[6], f[1], f[2],
                   kinematic_momentum(loop, x, f), theta_ref, ref, loop.kc, loop.h0, threshold)
    # the joints turn at sat(u1), sat(u2): at the limit exactly where a command was clipped
    observe_clipped(acc, j, abs(f[1]) >= loop.rate_limit or abs(f[2]) >= loop.rate_limit)


@jitable
def observe_dynamic(loop: DynamicLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
                    ) -> None:
    """Metrics of the dynamic plant at output sample j: H from the full link kinematics at
    the state (its own rates), the joint rates and torques it applies."""
    theta_ref, ref, threshold = obs
    observe_sample(acc, j, x[0], x[1], x[2], x[6], f[AUX_C1], f[AUX_S1], x[4], x[5],
                   dynamic_momentum(loop, x, f), theta_ref, ref, loop.kc, loop.h0, threshold)
    observe_torque(acc, f[AUX_TAU1], f[AUX_TAU2], f[AUX_SATURATED])
    # the servos' set points sat(u1) and r2 = sat(u2): clipped where at or beyond the limit
    observe_clipped(acc, j, abs(x[6]) >= loop.rate_limit or abs(f[AUX_R2]) >= loop.rate_limit)


@jitable
def record_dynamic(loop: Any, trace: Array, j: int, nx: int, x: Array, f: Array
                   ) -> None:
    """Trace row j of the dynamic plant (``simulate.DYNAMIC_TRACE_COLUMNS``): the state, the
    torques tau1, tau2 and the rate command r2."""
    for i in range(nx):
        trace[j, i] = x[i]
    trace[j, nx] = f[AUX_TAU1]
    trace[j, nx + 1] = f[AUX_TAU2]
    trace[j, nx + 2] = f[AUX_R2]


@jitable
def _measure(kc: Coefficients, th0: float, th1: float, th2: float, u1: float, ref: Array,
             s0: Array) -> None:
    """The flat outputs' errors (``control.flat_errors``) at measured angles and u1."""
    inv_A, g, h = chart(kc, np.cos(th1), np.sin(th1))
    y1, y2, y1_dot, y2_dot = outputs_at(kc, inv_A, g, h, th0, th1, th2, u1)
    s0[0] = y1 - ref[0]
    s0[1] = y1_dot - ref[2]
    s0[2] = y2 - ref[1]
    s0[3] = y2_dot - ref[3]


@jitable
def measure_kinematic(loop: Loop, x: Array, noise: Array, ref: Array, s0: Array) -> None:
    """What the flat law measures at the kinematic plant's state x (4,) with noise (3,): its
    flat outputs' errors from the plan's flag ``ref`` (6,) into ``s0`` (4,) (e1, e1', e2,
    e2'; ``control.flat_errors``), for a law that wraps it (``loop.compose``)."""
    _measure(loop.kc, x[0] + noise[0], x[1] + noise[1], x[2] + noise[2], x[3], ref, s0)


@jitable
def measure_dynamic(loop: DynamicLoop, x: Array, noise: Array, ref: Array, s0: Array
                    ) -> None:
    """``measure_kinematic`` at the dynamic plant's state x (7,) (u1 = x[6])."""
    _measure(loop.kc, x[0] + noise[0], x[1] + noise[1], x[2] + noise[2], x[6], ref, s0)
