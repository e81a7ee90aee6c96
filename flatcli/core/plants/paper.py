"""The paper's robot (N = 2) as plants, in closed form (``plants.part.PlantPart``;
``loop.base`` composes them with ``controllers.paper``): the kinematic and the dynamic plant
of ``kinematic`` and ``dynamic`` written out for three bodies, the paper model's speed.

Each obeys the true physics (the derived constraint for its own parameters, any d2, its own
angular momentum H0) under the joint-rate commands r = (r1, r2) and knows nothing of the
controller. The kinematic plant (``KINEMATIC``), state (th0, th1, th2):

    th1' = sat(r1),  th2' = sat(r2),  th0' = (B th1' + C th2' + M H0) / A

with sat the clip to +-rate_limit (infinite by default). The dynamic plant (``DYNAMIC``), the
robot with inertia (``dynamics.three_body``, the plant's own parameters) driven by joint
torques from a rate servo on each joint, state (th0, th1, th2, th0', th1', th2'):

    M(q) q'' + C(q, q') q' = (0, tau1, tau2),
    a_k = bandwidth (sat(r_k) - th_k')               (k = 1, 2: what the servo asks)
    tau = clip(Mhat_s a + chat_s, +-torque_limit)    (computed torque, each joint clipped)

with Mhat_s, chat_s the free-floating joint-space inertia and bias
(``dynamics.three_body_joint_space``) of the *servo's model* (the nominal ``[robot]``, or the
plant itself with ``plant.servo_model = "plant"``) at the true joint angles and rates. Where
the servo's model is the plant's and no torque is clipped, each joint rate follows its
command exactly as a first-order lag, th_k'' = bandwidth (sat(r_k) - th_k'); the base turns
as momentum conservation makes it. A torque limit of 0 applies no torque at all.

A plant whose centre of mass of link 2 lies across it turns th2 by its ``offset`` alpha
[rad] (its coefficients and links are those of its equivalent placement,
``model.RobotParams.placement``). Each writes the plant's cos th1, sin th1 first among its aux
values (the paper's law reads them where it observes, ``controllers.paper.observed``):
kinematic (c1, s1, c12), dynamic (c1, s1, c12, s12, tau1, tau2, r1, r2, clipped); c12 =
cos(th1 + th2 + alpha), s12 likewise, r1 the command as given, r2 clipped.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import inlined, jitable
from flatcli.core.plants.part import PlantPart
from flatcli.core.robots.chain import barycentric_matrices
from flatcli.core.robots.dynamics import ThreeBody, three_body_joint_space, three_body_terms
from flatcli.core.robots.params import (
    Coefficients,
    Links,
    base_rate_at,
    constraint_coefficients,
    momentum,
    momentum_at,
)

Array = NDArray[np.float64]

#: Where the dynamic plant writes its aux values, from ``at``.
C1, S1, C12, S12, TAU1, TAU2, R1, R2, CLIPPED = range(9)


def plant_arrays(params: Array, plant: str) -> Array:
    """Per trial, what the closed form needs of the plant: its constraint coefficients (the
    kinematic plant, (T, 11)) or its barycentric matrix (the dynamic plant, (T, 3, 3))."""
    if plant == "kinematic":
        k = constraint_coefficients(Links(*np.asarray(params, dtype=float).T), "derived")
        return np.ascontiguousarray(np.stack(np.broadcast_arrays(*k), axis=-1))
    return barycentric_matrices(params)


@jitable
def links_row(a: Array, i: int) -> Links:
    return Links(a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5],
                 a[i, 6], a[i, 7], a[i, 8], a[i, 9], a[i, 10], a[i, 11])


@jitable
def is_flat_plant(k: Coefficients) -> bool:
    """Whether a plant's constraint has no d2-terms (d2 = 0): then its terms in cos th2 and
    cos(th1 + th2) vanish and the kinematic plant skips them (the same numbers to the bit:
    they are multiplied by zero)."""
    return (k.a2 == 0.0 and k.a3 == 0.0 and k.b2 == 0.0 and k.b3 == 0.0 and k.c2 == 0.0
            and k.c3 == 0.0)


class KinematicPaper(NamedTuple):
    """One trial's kinematic plant: its constraint coefficients, links, total mass M [kg],
    H0 [kg m^2/s], the rate limit [rad/s], whether d2 = 0, its offset [rad], the commands'
    row r (2,)."""

    kq: Coefficients
    links: Links
    total_mass: float
    h0: float
    rate_limit: float
    flat_plant: bool
    offset: float
    r: Array


class DynamicPaper(NamedTuple):
    """One trial's dynamic plant: its links, its three-body chain and the servo's model of
    it (``same``: the same chain, its terms computed once), H0 [kg m^2/s], the rate limit
    [rad/s], the servo's bandwidth [rad/s] and torque limit [N m] (inf: none), its offset
    [rad], the commands' row r (2,)."""

    links: Links
    plant: ThreeBody
    servo: ThreeBody
    same: bool
    h0: float
    rate_limit: float
    bandwidth: float
    torque_limit: float
    offset: float
    r: Array


def scratch(n: int) -> Array:
    return np.zeros(2)


@jitable
def make_kinematic(trials: Any, i: int, rate_limit: float, servo: Any, r: Array
                   ) -> KinematicPaper:
    """Trial i's plant (``PlantPart.make``; no servo)."""
    p = links_row(trials.params, i)
    a = trials.plant
    kq = Coefficients(a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5], a[i, 6], a[i, 7],
                      a[i, 8], a[i, 9], a[i, 10])
    return KinematicPaper(kq, p, p.m0 + p.m1 + p.m2, trials.h0[i], rate_limit,
                          is_flat_plant(kq), trials.offset[i], r)


@jitable
def make_dynamic(trials: Any, i: int, rate_limit: float, servo: Any, r: Array
                 ) -> DynamicPaper:
    """Trial i's plant; ``servo`` the nominal robot's chain and whether the servo knows the
    plant instead (``controllers.paper.servo``)."""
    p = links_row(trials.params, i)
    K = trials.plant[i]
    plant = ThreeBody(K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2], K[2, 2], p.i0, p.i1, p.i2)
    robot, is_plant = servo
    model = plant if is_plant else robot
    return DynamicPaper(p, plant, model, is_plant or plant == model, trials.h0[i],
                        rate_limit, trials.servo[i, 0], trials.servo[i, 1], trials.offset[i], r)


@jitable
def kinematic_state(n: int) -> int:
    """th0, th1, th2."""
    return 3


@jitable
def dynamic_state(n: int) -> int:
    """th0, th1, th2, th0', th1', th2'."""
    return 6


@jitable
def kinematic_io(plant: KinematicPaper, x: Array) -> tuple[Array, Array]:
    """Its commands' row; no joint rates in its state."""
    return plant.r, x[3:3]


@jitable
def dynamic_io(plant: DynamicPaper, x: Array) -> tuple[Array, Array]:
    """Its commands' row, the rates in its state."""
    return plant.r, x[3:6]


@inlined
def kinematic_rates(plant: KinematicPaper, x: Array, cs: float, sn: float, given: bool,
                    out: Array, at: int, torques: bool) -> None:
    """th0', th1', th2' into out[:3]; c1, s1, c12 (0 for a flat plant) into out[at:]. cs, sn
    cos th1, sin th1 where ``given``."""
    if given:
        c1, s1 = cs, sn
    else:
        c1, s1 = np.cos(x[1]), np.sin(x[1])
    limit = plant.rate_limit
    w1 = min(max(plant.r[0], -limit), limit)
    w2 = min(max(plant.r[1], -limit), limit)
    if plant.flat_plant:
        c2 = c12 = 0.0
    else:
        c2, c12 = np.cos(x[2] + plant.offset), np.cos(x[1] + x[2] + plant.offset)
    out[0] = base_rate_at(plant.kq, plant.total_mass, plant.h0, c1, c2, c12, w1, w2)
    out[1], out[2] = w1, w2
    out[at], out[at + 1], out[at + 2] = c1, s1, c12


@jitable
def servo_torques(plant: DynamicPaper, hat11: float, hat12: float, hat22: float,
                  chat1: float, chat2: float, r1: float, r2: float, th1_dot: float,
                  th2_dot: float) -> tuple[float, float, float]:
    """The servo's joint torques tau1, tau2 [N m], clipped to the torque limit, and 1.0 if
    one was clipped, else 0.0; hat11, hat12, hat22 [kg m^2], chat1, chat2 [N m] the servo
    model's joint-space inertia and bias at the state, r1, r2 the clipped commands and
    th1_dot, th2_dot the joint rates [rad/s]."""
    a1 = plant.bandwidth * (r1 - th1_dot)
    a2 = plant.bandwidth * (r2 - th2_dot)
    demand1 = hat11 * a1 + hat12 * a2 + chat1
    demand2 = hat12 * a1 + hat22 * a2 + chat2
    limit = plant.torque_limit
    saturated = 1.0 if (abs(demand1) > limit or abs(demand2) > limit) else 0.0
    return (min(max(demand1, -limit), limit), min(max(demand2, -limit), limit), saturated)


@inlined
def dynamic_rates(plant: DynamicPaper, x: Array, cs: float, sn: float, given: bool,
                  out: Array, at: int, torques: bool) -> None:
    """th0'..th2'', written into out[:6], its aux values (module docstring) into out[at:]."""
    if given:
        c1, s1 = cs, sn
    else:
        c1, s1 = np.cos(x[1]), np.sin(x[1])
    limit = plant.rate_limit
    u1 = plant.r[0]
    r1 = min(max(u1, -limit), limit)
    r2 = min(max(plant.r[1], -limit), limit)
    c2 = np.cos(x[2] + plant.offset)
    s2 = np.sin(x[2] + plant.offset)
    m00, m01, m02, m11, m12, m22, h0, h1, h2 = three_body_terms(plant.plant, c1, s1, c2, s2,
                                                                x[3], x[4], x[5])
    a11, a12, a22, b1, b2 = three_body_joint_space(m00, m01, m02, m11, m12, m22, h0, h1, h2)
    if plant.same:
        tau1, tau2, saturated = servo_torques(plant, a11, a12, a22, b1, b2, r1, r2, x[4], x[5])
    else:
        s00, s01, s02, s11, s12, s22, g0, g1, g2 = three_body_terms(plant.servo, c1, s1, c2,
                                                                    s2, x[3], x[4], x[5])
        e11, e12, e22, f1, f2 = three_body_joint_space(s00, s01, s02, s11, s12, s22, g0, g1, g2)
        tau1, tau2, saturated = servo_torques(plant, e11, e12, e22, f1, f2, r1, r2, x[4], x[5])
    # the plant: Mhat qj'' = tau - chat, then the base from its own row
    rhs1 = tau1 - b1
    rhs2 = tau2 - b2
    inv_det = 1.0 / (a11 * a22 - a12 * a12)
    q1_ddot = (a22 * rhs1 - a12 * rhs2) * inv_det
    q2_ddot = (a11 * rhs2 - a12 * rhs1) * inv_det
    out[0], out[1], out[2] = x[3], x[4], x[5]
    out[3], out[4], out[5] = -(m01 * q1_ddot + m02 * q2_ddot + h0) / m00, q1_ddot, q2_ddot
    out[at + C1], out[at + S1] = c1, s1
    out[at + C12], out[at + S12] = c1 * c2 - s1 * s2, s1 * c2 + c1 * s2
    out[at + TAU1], out[at + TAU2], out[at + CLIPPED] = tau1, tau2, saturated
    out[at + R1], out[at + R2] = u1, r2


@jitable
def kinematic_start(plant: KinematicPaper, initial: Array, r: Array, x0: Array) -> None:
    """th(0)."""
    x0[0], x0[1], x0[2] = initial[0], initial[1], initial[2]


@jitable
def dynamic_start(plant: DynamicPaper, initial: Array, r: Array, x0: Array) -> None:
    """th(0); th1'(0), th2'(0) = r (the clipped commands at t = 0: the servo in equilibrium);
    th0'(0) such that H = (M q')_0 = H0 of the plant."""
    m00, m01, m02, _, _, _, _, _, _ = three_body_terms(
        plant.plant, np.cos(initial[1]), np.sin(initial[1]), np.cos(initial[2] + plant.offset),
        np.sin(initial[2] + plant.offset), 0.0, 0.0, 0.0)
    x0[0], x0[1], x0[2] = initial[0], initial[1], initial[2]
    x0[3] = (plant.h0 - m01 * r[0] - m02 * r[1]) / m00
    x0[4], x0[5] = r[0], r[1]


@jitable
def kinematic_observed(plant: KinematicPaper, x: Array, f: Array, at: int, cs: Any, sn: Any,
                       given: bool) -> tuple[float, float, float, bool, float, float]:
    """H from the full link kinematics with the applied rates f[:3], the larger joint rate,
    whether one is at the limit (clipped); no torques (nan)."""
    s12 = 0.0 if plant.flat_plant else np.sin(x[1] + x[2] + plant.offset)  # d2 = 0: times 0
    h = momentum_at(plant.links, f[at], f[at + 1], f[at + 2], s12, f[0], f[1], f[2])
    limit = plant.rate_limit
    return (float(h), plant.h0, max(abs(f[1]), abs(f[2])),
            abs(f[1]) >= limit or abs(f[2]) >= limit, math.nan, math.nan)


@jitable
def dynamic_observed(plant: DynamicPaper, x: Array, f: Array, at: int, cs: Any, sn: Any,
                     given: bool) -> tuple[float, float, float, bool, float, float]:
    """H from the full link kinematics at the state (its own rates), the larger joint rate,
    whether a servo's set point is at or beyond the limit, the larger torque, whether one
    was clipped."""
    h = momentum_at(plant.links, f[at + C1], f[at + S1], f[at + C12], f[at + S12], x[3], x[4],
                    x[5])
    limit = plant.rate_limit
    return (float(h), plant.h0, max(abs(x[4]), abs(x[5])),
            abs(f[at + R1]) >= limit or abs(f[at + R2]) >= limit,
            max(abs(f[at + TAU1]), abs(f[at + TAU2])), f[at + CLIPPED])


@jitable
def kinematic_record(plant: KinematicPaper, trace: Array, j: int, col: int, x: Array,
                     f: Array, at: int, commands: bool) -> None:
    """th0', th1', th2' (the law has a state: no commands)."""
    trace[j, col], trace[j, col + 1], trace[j, col + 2] = f[0], f[1], f[2]


@jitable
def dynamic_record(plant: DynamicPaper, trace: Array, j: int, col: int, x: Array, f: Array,
                   at: int, commands: bool) -> None:
    """tau1, tau2 [N m], r2 [rad/s] (``simulate.DYNAMIC_TRACE_COLUMNS``)."""
    trace[j, col], trace[j, col + 1] = f[at + TAU1], f[at + TAU2]
    trace[j, col + 2] = f[at + R2]


@jitable
def residual(plant: Any, trials: Any, i: int, plan_theta: Array, plan_theta_dot: Array
             ) -> float:
    """The plan's max |H - H0| on the plant (link 2 turned by its offset) [kg m^2/s]."""
    offset = trials.offset[i]
    links = links_row(trials.params, i)
    worst = 0.0
    for j in range(plan_theta.shape[0]):
        th2 = plan_theta[j, 2] if offset == 0.0 else plan_theta[j, 2] + offset
        h = momentum(links, plan_theta[j, 0], plan_theta[j, 1], th2, plan_theta_dot[j, 0],
                     plan_theta_dot[j, 1], plan_theta_dot[j, 2])
        worst = max(worst, abs(h - trials.h0[i]))
    return worst


@jitable
def kinematic_bounded(plant: KinematicPaper) -> bool:
    """The joint rates are clipped to a finite rate limit."""
    return not math.isinf(plant.rate_limit)


@jitable
def dynamic_bounded(plant: DynamicPaper) -> bool:
    """Its servos' commands clipped to a finite rate limit, or their torques to a finite
    torque limit (0 included: no torque at all)."""
    return not (math.isinf(plant.rate_limit) and math.isinf(plant.torque_limit))


KINEMATIC = PlantPart("kinematic", scratch, make_kinematic, kinematic_state, lambda n: 3,
                      lambda n: 3, kinematic_io, kinematic_rates, kinematic_start,
                      kinematic_observed, kinematic_record, residual, kinematic_bounded,
                      rate_states=False, torques=False)
DYNAMIC = PlantPart("dynamic", scratch, make_dynamic, dynamic_state, lambda n: 9, lambda n: 3,
                    dynamic_io, dynamic_rates, dynamic_start, dynamic_observed, dynamic_record,
                    residual, dynamic_bounded, rate_states=True, torques=True)
