"""The as-built law, as a part any chain plant runs (``parts.LawPart``; ``loop.base``
composes it with a plant), any N.

The controller (``lqr``) reads from the tracked flag (``lqr.TrackedLayout``) the plan's angles
th_r, the joints' rates w_r and accelerations a_r, and the gains L, and commands the joint
rates

    w = w_r - L (th_measured - th_r),      r = sat(w)  (kinematic plant),
                                           r = sat(w + a_r / bandwidth)  (dynamic plant),

the dynamic plant's command leading its servo's first-order lag by the plan's acceleration
(so that a servo whose model is right follows the plan exactly when the state is on it;
``AsbuiltShared.lagged``: the gains act on the joint rates' errors too). There is no
integrator in the law (no states), so nothing winds up against a rate or torque limit. On a
dynamic plant it starts with th_j'(0) = u_j(0) (j < N) and joint N at the plan's rate.

The law has no singular set: its margin is 1.0 and never changes sign (no trial meets a
crossing, ``crossings`` is 0); the metrics observe an infinite margin (no singular hits,
``min_margin`` null, no status ``singular``); err_y is the error of the joint angles
th_1..th_N (the "outputs" of an exact plan).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.controllers.control import Gains
from flatcli.core.controllers.parts import LawPart
from flatcli.core.plan.exact import constraint_of
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: The threshold the metrics compare the margin with: none (below any margin), and the
#: margin they observe: the law has no singular set.
NO_THRESHOLD = -1.0
NO_MARGIN = math.inf


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


class AsbuiltLaw(NamedTuple):
    """One trial's law: the shared record (it needs no buffers)."""

    shared: AsbuiltShared


def asbuilt_shared(model: Any, gains: Gains, rate_limit: float, servo_is_plant: bool,
                   robot: RobotParams) -> AsbuiltShared:
    """What every trial shares: the controller's robot (``exact.Constraint`` of ``robot``,
    writable copies), the rate limit, the servo's model (``gains`` and ``model`` are the
    flat law's: the as-built law's gains are in the tracked flag)."""
    constraint = constraint_of(robot)
    return AsbuiltShared(np.array(constraint.K, dtype=float),
                         np.array(constraint.inertia, dtype=float),
                         float(np.cos(constraint.offset)), float(np.sin(constraint.offset)),
                         float(rate_limit), servo_is_plant)


def scratch(n: int) -> Array:
    return np.zeros(1)


@jitable
def make(shared: AsbuiltShared, unused: Array) -> AsbuiltLaw:
    return AsbuiltLaw(shared)


@jitable
def joints(law: AsbuiltLaw) -> int:
    return law.shared.Ic.shape[0] - 1  # type: ignore[no-any-return]


@jitable
def states(n: int) -> int:
    """None."""
    return 0


@jitable
def servo(shared: AsbuiltShared, offset: float) -> Any:
    """The servo's model: the plant, or the controller's robot turned by the robot's own
    offset; its accelerations solved for even where it is the plant's (the as-built loop's
    numbers as they were)."""
    return shared.Kc, shared.Ic, shared.cos_c, shared.sin_c, shared.servo_is_plant, False


@jitable
def _layout(shared: AsbuiltShared, n: int) -> tuple[int, int]:
    """The gains' row width and the start of the plan's joint rates in the tracked flag."""
    width = 2 * n + 1 if shared.lagged else n + 1
    return width, n + 1 + n * width


@jitable
def command(law: AsbuiltLaw, meas: Array, rates: Array, z: Array, ref: Array, r: Array,
            z_dot: Array) -> float:
    """The rate commands r_j (N,): the law at the measured angles (and, lagged, the joints'
    rates), plus the lead times the plan's joint accelerations; the margin 1.0."""
    shared = law.shared
    nb = shared.Ic.shape[0]
    n = nb - 1
    width, c = _layout(shared, n)
    for j in range(1, nb):
        w = ref[c + j - 1] + shared.lead * ref[2 * c + j - 1]
        base = nb + (j - 1) * width
        w -= ref[base] * (meas[0] - ref[n])
        for a in range(1, nb):
            w -= ref[base + a] * (meas[a] - ref[a - 1])
        if shared.lagged:
            for k in range(1, nb):
                w -= ref[base + n + k] * (rates[k] - ref[c + k - 1])
        r[j - 1] = w
    return 1.0


@jitable
def start(law: AsbuiltLaw, initial: Array, z0: Array) -> None:
    """No states."""


@jitable
def start_rates(law: AsbuiltLaw, initial: Array, ref: Array, r: Array) -> None:
    """u_j(0) of joints j < N from ``initial``, joint N at the plan's rate (the law acts on
    the rate errors from there)."""
    nb = law.shared.Ic.shape[0]
    n = nb - 1
    _, c = _layout(law.shared, n)
    for j in range(1, n):
        r[j - 1] = initial[nb + j - 1]
    r[n - 1] = ref[c + n - 1]


@jitable
def trig(law: AsbuiltLaw) -> tuple[Array, Array]:
    """None of its own (``shares_trig`` is false)."""
    return law.shared.Ic, law.shared.Ic


@jitable
def observed(law: AsbuiltLaw, obs: Any, j: int, theta: Array, z: Array, f: Array,
             at: int) -> tuple[float, float, float]:
    """The joint angles' squared error from the plan's y (th1..thN, the law's outputs); no
    margin, no threshold."""
    ref = obs[1]
    ey2 = 0.0
    for i in range(1, law.shared.Ic.shape[0]):
        e = theta[i] - ref[2 * j, i - 1]
        ey2 += e * e
    return ey2, NO_MARGIN, NO_THRESHOLD


@jitable
def additive(law: AsbuiltLaw, ref: Array, dv: Array, out: Array) -> None:
    """``out`` = the tracked flag ``ref`` with dv (N,) [rad/s] added to the joint-rate
    commands w: on the plan's joint rates w_r, or, where w_r enters the rate errors too
    (``AsbuiltShared.lagged``), on the lead's channel a_r as dv / lead."""
    shared = law.shared
    nb = shared.Ic.shape[0]
    _, c = _layout(shared, nb - 1)
    for k in range(3 * c):
        out[k] = ref[k]
    for j in range(1, nb):
        if shared.lagged:
            out[2 * c + j - 1] += dv[j - 1] / shared.lead
        else:
            out[c + j - 1] += dv[j - 1]


@jitable
def measure(law: AsbuiltLaw, measured: Array, rates: Array, z: Array, ref: Array, s0: Array
            ) -> None:
    """The errors its gains act on, from the tracked flag ``ref``, into ``s0``: the measured
    angles' th0 - th0_r, th_j - th_jr (j = 1..N), and where it acts on the joint rates
    th_j' - w_jr (the order of ``lqr.linearisation``)."""
    shared = law.shared
    nb = shared.Ic.shape[0]
    n = nb - 1
    _, c = _layout(shared, n)
    s0[0] = measured[0] - ref[n]
    for a in range(1, nb):
        s0[a] = measured[a] - ref[a - 1]
    if shared.lagged:
        for k in range(1, nb):
            s0[n + k] = rates[k] - ref[c + k - 1]


LAW = LawPart("asbuilt", asbuilt_shared, scratch, make, joints, states, servo, command, start,
              start_rates, trig, observed, additive, measure, shares_trig=False, bounded=True)
