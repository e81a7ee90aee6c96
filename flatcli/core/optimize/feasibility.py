"""Necessary conditions checked before optimising, each refused in one line naming its key.

The signed margin is sigma sin(y1) y1' = -sigma d(cos y1)/dt, so its integral over [0, T] is
sigma (cos th1(0) - cos th1(T)): the margin can stay >= m only if that is >= m T, and th1 must
move monotonically within one interval (k pi, (k + 1) pi). Along such a th1 path, momentum
conservation fixes the integral of h(y1) th2 dy1 (``flatness``: y2' = (g - h th2) y1'), so
th2 must reach a value ``required_fold`` fixes (2.67 rad on the paper's maneuver), which
bounds the th2 angle limit and, with th2's travel there and back, the rate limit. End
configurations outside their angle limits, fixed end rates outside the rate limit or inside
the margin, and th1 travel faster than the rate limit allows are refused likewise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.flatness import chart
from flatcli.core.model import Coefficients, FlatcliError
from flatcli.core.optimize.affine import end_flat
from flatcli.core.optimize.limits import PlanLimits
from flatcli.core.optimize.quantities import ANGLES, NAMES

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Ends:
    """What the up-front checks settle about a maneuver's ends.

    Attributes
    ----------
    sigma : sign of the margin sin(th1) th1' along any admissible plan (+1 or -1)
    start_rate, goal_rate : th1'(0), th1'(T) [rad/s]: the fixed end rates, or the starting
        guesses, pointed the way th1 moves and clipped into the range the limits allow
    """

    sigma: float
    start_rate: float
    goal_rate: float


def check_ends(
    k: Coefficients,
    start: Array,
    goal: Array,
    start_rate: float,
    goal_rate: float,
    duration: float,
    limits: PlanLimits,
    free_rates: bool,
    clearance: float,
) -> Ends:
    """Up-front feasibility checks of a maneuver under limits.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    start, goal : (3,) end configurations [rad]
    start_rate, goal_rate : th1'(0), th1'(T) [rad/s] (guesses, or fixed values)
    duration : T [s]
    limits : the user's limits
    free_rates : whether the end rates are decision variables
    clearance : a free end-rate guess below the margin's minimum is raised to (1 + this)
        times it (``Tuning.end_rate_clearance``)

    Returns
    -------
    Ends

    Raises
    ------
    FlatcliError, one line naming the spec key, for any request no plan can meet (see the
    module docstring)
    """
    for key, theta in (("start", start), ("goal", goal)):
        for i in ANGLES:
            if abs(theta[i]) > limits.angle_limit[i]:
                raise FlatcliError(
                    f"plan.optimize.angle_limit[{i}] = {limits.angle_limit[i]:g} rad cannot be "
                    f"met: the {key} configuration has |{NAMES[i]}| = {abs(theta[i]):g} rad"
                )
    th1_0, th1_T = float(start[1]), float(goal[1])
    m = limits.min_margin
    # sin th1 must keep its sign: th1 stays inside one interval (k pi, (k + 1) pi)
    if math.floor(th1_0 / math.pi) != math.floor(th1_T / math.pi):
        raise FlatcliError(
            f"plan.goal[1] = {th1_T:g} rad: th1 would have to cross a multiple of pi from "
            f"plan.start[1] = {th1_0:g} rad, where the flat map is singular (sin th1 = 0)"
        )
    travel = th1_T - th1_0
    if travel == 0:
        raise FlatcliError(
            "plan.goal[1] equals plan.start[1]: th1 would have to stop and turn back, crossing "
            "the singular set th1' = 0; a flat plan needs th1 to move monotonically"
        )
    direction = math.copysign(1.0, travel)
    if free_rates:
        # the sign of th1' is forced by the direction of travel
        start_rate = direction * abs(start_rate)
        goal_rate = direction * abs(goal_rate)
    elif math.copysign(1.0, start_rate) != direction or math.copysign(1.0, goal_rate) != direction:
        raise FlatcliError(
            f"plan.optimize.min_margin = {m:g} rad/s cannot be met: th1 moves from "
            f"{th1_0:g} to {th1_T:g} rad but the fixed end rates plan.start_rate = "
            f"{start_rate:g} and plan.goal_rate = {goal_rate:g} rad/s do not both point that "
            "way, so th1' must cross 0"
        )
    sigma = math.copysign(1.0, math.sin(th1_0) * start_rate)
    available = sigma * (math.cos(th1_0) - math.cos(th1_T))
    if available < m * duration:
        raise FlatcliError(
            f"plan.optimize.min_margin = {m:g} rad/s cannot be met: the margin "
            f"|sin th1 th1'| = |d(cos th1)/dt| averages |cos th1(0) - cos th1(T)| / T = "
            f"{available / duration:.4g} rad/s over this maneuver"
        )
    R = limits.rate_limit
    if abs(travel) > R * duration:
        raise FlatcliError(
            f"plan.optimize.rate_limit = {R:g} rad/s cannot be met: th1 must move "
            f"{abs(travel):g} rad in {duration:g} s, {abs(travel) / duration:.4g} rad/s on average"
        )
    rates = []
    for key, th1, rate in (("start", th1_0, start_rate), ("goal", th1_T, goal_rate)):
        low = m / abs(math.sin(th1))
        if free_rates:
            if low > R:
                raise FlatcliError(
                    f"plan.optimize.min_margin = {m:g} rad/s cannot be met within "
                    f"plan.optimize.rate_limit = {R:g} rad/s at the {key}: |sin th1| = "
                    f"{abs(math.sin(th1)):.4g} needs |th1'| >= {low:.4g} rad/s there"
                )
            rate = math.copysign(min(max(abs(rate), low * (1 + clearance)), R), rate)
        else:
            if abs(rate) > R:
                raise FlatcliError(
                    f"plan.optimize.rate_limit = {R:g} rad/s cannot be met: plan.{key}_rate = "
                    f"{rate:g} rad/s is fixed (free_rates = false)"
                )
            if abs(math.sin(th1) * rate) < m:
                raise FlatcliError(
                    f"plan.optimize.min_margin = {m:g} rad/s cannot be met: the fixed "
                    f"plan.{key}_rate = {rate:g} rad/s gives a margin of "
                    f"{abs(math.sin(th1) * rate):.4g} rad/s at the {key} (free_rates = false)"
                )
        rates.append(rate)
    check_fold(k, start, goal, duration, limits)
    return Ends(sigma, rates[0], rates[1])


def required_fold(k: Coefficients, start: ArrayLike, goal: ArrayLike, nodes: int = 32) -> float:
    """A value th2 must reach somewhere on any flat plan from ``start`` to ``goal`` [rad].

    With th1 moving monotonically (as a positive margin forces) the flat output obeys
    y2' = (g - h th2) th1' (``flatness``), so, integrating over th1 instead of time,

        integral of h th2 dth1 = integral of g dth1 - (y2(T) - y2(0)) =: D.

    h has one sign between th1(0) and th1(T), so th2 cannot stay strictly on the near side
    of v = D / (integral of h dth1) throughout: th2 >= v somewhere if v > 0, th2 <= v
    somewhere if v < 0. Only the end configurations enter, so this is a necessary condition
    for any flat plan of the maneuver, whatever the basis or the end rates; the bound is
    approached only by th2 staying at v the whole time, so real plans fold further.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    start, goal : (3,) th0, th1, th2 [rad]; th1 must differ and sin th1 keep its sign
    nodes : Gauss-Legendre nodes for the two integrals over th1 (smooth integrands)

    Returns
    -------
    v : float [rad]; 0 when th1 does not move
    """
    start = np.asarray(start, dtype=float)
    goal = np.asarray(goal, dtype=float)
    lo, hi = float(start[1]), float(goal[1])
    if lo == hi:
        return 0.0
    x, w = np.polynomial.legendre.leggauss(nodes)
    th1 = 0.5 * (hi - lo) * (x + 1.0) + lo
    weights = 0.5 * (hi - lo) * w
    _, g, h = chart(k, np.cos(th1), np.sin(th1))
    rise = end_flat(k, goal)[1] - end_flat(k, start)[1]
    return (float(weights @ g) - rise) / float(weights @ h)


def check_fold(
    k: Coefficients, start: Array, goal: Array, duration: float, limits: PlanLimits
) -> None:
    """th2 must reach ``required_fold``: against the th2 angle limit and the rate limit.

    Raises
    ------
    FlatcliError naming ``plan.optimize.angle_limit[2]`` or ``plan.optimize.rate_limit``
    """
    v = required_fold(k, start, goal)
    lim = limits.angle_limit[2]
    if abs(v) > lim:
        raise FlatcliError(
            f"plan.optimize.angle_limit[2] = {lim:g} rad cannot be met: momentum conservation "
            f"forces th2 to reach {v:.4g} rad somewhere on any plan of this maneuver"
        )
    side = math.copysign(1.0, v)
    travel = max(0.0, side * (v - start[2])) + max(0.0, side * (v - goal[2]))
    R = limits.rate_limit
    if travel > R * duration:
        raise FlatcliError(
            f"plan.optimize.rate_limit = {R:g} rad/s cannot be met: momentum conservation "
            f"forces th2 from {start[2]:g} to {v:.4g} and on to {goal[2]:g} rad, "
            f"{travel / duration:.4g} rad/s on average"
        )


def end_rate_bounds(
    theta: Array, limits: PlanLimits, rate: float
) -> tuple[float | None, float | None]:
    """Bounds on a free end rate th1' [rad/s]: on the side of ``rate``, above the margin's
    minimum min_margin / |sin th1| and within the rate limit (None: unbounded)."""
    low = limits.min_margin / abs(math.sin(theta[1]))
    high = None if math.isinf(limits.rate_limit) else limits.rate_limit
    if rate > 0:
        return low, high
    return (None if high is None else -high), -low


__all__ = ["Ends", "check_ends", "check_fold", "end_rate_bounds", "required_fold"]
