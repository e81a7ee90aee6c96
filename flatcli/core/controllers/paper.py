"""The flat law on the paper's robot (N = 2) in closed form, as a part the paper's plants run
(``parts.LawPart``; ``loop.base`` composes it with ``plants.paper``): the N-link flat law
(``flat``) with the paper's model, 3-5x faster per right-hand side.

At the measured angles th + noise and its integrator u1 (its one state) it asks for the
inputs of the linearising feedback (``control.feedback_at``): u1' and u2, the commanded rates
r = (u1, u2) (the plant clips them to +-rate_limit), u1' set to 0 while u1 is at or beyond
the limit and u1' pushes it further out (``control.unwound``: no wind-up). Its signed margin
sin(measured th1) u1 [rad/s] changes sign where the feedback divides by zero. On a rest
plan's flag it blends its commands with the plan's (``rest.faded_paper``). ``COMMAND`` is the
same part with u1' and u2 given by a controller written in Python before each evaluation
(``controllers.python``; ``loop.reference`` writes them into the law's scratch).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import inlined, jitable
from flatcli.core.controllers.control import (
    Gains,
    PaperGains,
    add_to_accelerations,
    feedback,
    feedback_at,
    unwound,
)
from flatcli.core.controllers.parts import LawPart
from flatcli.core.controllers.rest import faded_paper, observed_margin
from flatcli.core.models.flatness import chart, outputs_at
from flatcli.core.robots.chain import barycentric_matrix
from flatcli.core.robots.dynamics import ThreeBody
from flatcli.core.robots.params import Coefficients, Links, RobotParams

Array = NDArray[np.float64]


class PaperShared(NamedTuple):
    """What every trial shares: the controller's coefficients (d2 = 0), gains, the joint-rate
    limit [rad/s], the nominal robot's three-body chain (a dynamic plant's servo model unless
    ``servo_is_plant``)."""

    kc: Coefficients
    gains: PaperGains
    rate_limit: float
    robot: ThreeBody
    servo_is_plant: bool


class PaperLaw(NamedTuple):
    """One trial's law: the shared record's coefficients, gains and rate limit; ``held``
    (2,): cos and sin of the measured th1 it last evaluated (``trig``), or, for ``COMMAND``,
    the commands u1' [rad/s^2], u2 [rad/s] given it."""

    kc: Coefficients
    gains: PaperGains
    rate_limit: float
    held: Array


def paper_shared(model: Any, gains: Gains, rate_limit: float, servo_is_plant: bool,
                 robot: RobotParams) -> PaperShared:
    """``LawPart.shared``. K of the one robot comes from ``barycentric_matrix`` run as Python
    (the same IEEE operations in the same order as the compiled ``barycentric_matrices``, to
    the bit): the compiled batch form would load a kernel with numba's runtime into every
    sweep, 30-50 ms of its start-up, for a 3 x 3 matrix."""
    p = robot.as_array()
    nb = p.shape[0] // 4
    K = barycentric_matrix(p[:nb], p[2 * nb: 3 * nb], p[3 * nb:])
    links = Links(*(float(v) for v in robot.links))
    return PaperShared(Coefficients(*(float(v) for v in model.coefficients)), gains.paper(),
                       float(rate_limit), ThreeBody(K[0, 0], K[0, 1], K[0, 2], K[1, 1],
                                                    K[1, 2], K[2, 2], links.i0, links.i1,
                                                    links.i2), servo_is_plant)


def scratch(n: int) -> Array:
    return np.zeros(2)


@jitable
def make(shared: PaperShared, held: Array) -> PaperLaw:
    return PaperLaw(shared.kc, shared.gains, shared.rate_limit, held)


@jitable
def joints(law: PaperLaw) -> int:
    return 2


@jitable
def states(n: int) -> int:
    """u1."""
    return 1


@jitable
def servo(shared: PaperShared, offset: float) -> tuple[ThreeBody, bool]:
    """The nominal robot (d2 = 0: th2, and so the plant's offset, does not enter it) and
    whether the servo knows the plant instead (``plants.paper.make_dynamic``)."""
    return shared.robot, shared.servo_is_plant


@inlined
def command(law: PaperLaw, measured: Array, rates: Array, z: Array, ref: Array, r: Array,
            z_dot: Array) -> float:
    """``LawPart.command``: r = (u1, u2) [rad/s], u1' into z_dot; returns the margin."""
    cm1, sm1 = np.cos(measured[1]), np.sin(measured[1])
    u1 = z[0]
    u1_dot, u2 = feedback_at(law.kc, law.gains, measured[0], measured[1], measured[2], u1,
                             cm1, sm1, ref)
    margin = sm1 * u1
    if ref.shape[0] > 6:  # a rest plan's flag: the feedback faded (``rest``)
        u1_dot, u2, margin = faded_paper(ref, u1_dot, u2, margin)
    law.held[0], law.held[1] = cm1, sm1  # stores after the loads: they may alias
    z_dot[0] = unwound(u1, u1_dot, law.rate_limit)
    r[0], r[1] = u1, u2  # last: the plant reads them next
    return margin  # type: ignore[no-any-return]


@jitable
def given_command(law: PaperLaw, measured: Array, rates: Array, z: Array, ref: Array,
                  r: Array, z_dot: Array) -> float:
    """``command`` with u1', u2 given (``COMMAND``)."""
    r[0], r[1] = z[0], law.held[1]
    z_dot[0] = unwound(z[0], law.held[0], law.rate_limit)
    return np.sin(measured[1]) * z[0]  # type: ignore[no-any-return]


@jitable
def start(law: PaperLaw, initial: Array, z0: Array) -> None:
    """u1(0)."""
    z0[0] = initial[3]


@jitable
def start_rates(law: PaperLaw, initial: Array, ref: Array, r: Array) -> None:
    """The commands at t = 0 at the true angles, clipped to the rate limit."""
    limit = law.rate_limit
    _, u2 = feedback(law.kc, law.gains, initial[0], initial[1], initial[2], initial[3], ref)
    r[0] = min(max(initial[3], -limit), limit)
    r[1] = min(max(u2, -limit), limit)


@jitable
def trig(law: PaperLaw) -> tuple[float, float]:
    """cos, sin of the measured th1 (the true one's without noise)."""
    return law.held[0], law.held[1]


@jitable
def observed(law: PaperLaw, obs: Any, j: int, theta: Array, z: Array, f: Array, at: int
             ) -> tuple[float, float, float]:
    """The flat outputs' squared error (the controller's y2 = th0 - c0 th2 / A, eq. 35, at
    the true state), the margin |sin th1 u1|; cos th1, sin th1 of the plant from its aux
    values f[at], f[at + 1] (``plants.paper``)."""
    _, ref, threshold = obs
    c1, s1 = f[at], f[at + 1]
    inv_A, _, _ = chart(law.kc, c1, s1)
    e1 = theta[1] - ref[2 * j, 0]
    e2 = theta[0] - law.kc.c0 * theta[2] * inv_A - ref[2 * j, 1]
    return e1 * e1 + e2 * e2, observed_margin(ref, j, 2, abs(s1 * z[0])), threshold


@jitable
def additive(law: PaperLaw, ref: Array, dv: Array, out: Array) -> None:
    """dv added to the plan's y'' (``control.add_to_accelerations``)."""
    add_to_accelerations(ref, dv, out)


@jitable
def measure(law: PaperLaw, measured: Array, rates: Array, z: Array, ref: Array, s0: Array
            ) -> None:
    """The flat outputs' errors (``control.flat_errors``) at the measured angles and u1."""
    kc = law.kc
    inv_A, g, h = chart(kc, np.cos(measured[1]), np.sin(measured[1]))
    y1, y2, y1_dot, y2_dot = outputs_at(kc, inv_A, g, h, measured[0], measured[1],
                                        measured[2], z[0])
    s0[0] = y1 - ref[0]
    s0[1] = y1_dot - ref[2]
    s0[2] = y2 - ref[1]
    s0[3] = y2_dot - ref[3]


LAW = LawPart("flat", paper_shared, scratch, make, joints, states, servo, command, start,
              start_rates, trig, observed, additive, measure, shares_trig=True, bounded=False)
COMMAND = LawPart("command", paper_shared, scratch, make, joints, states, servo,
                  given_command, start, start_rates, trig, observed, additive, measure,
                  shares_trig=False, bounded=False)
