"""Necessary conditions checked before optimising, each refused in one line naming its key.

The paper's robot (N = 2). The signed margin is sigma sin(y1) y1' = -sigma d(cos y1)/dt, so
its integral over [0, T] is sigma (cos th1(0) - cos th1(T)): the margin can stay >= m only if
that is >= m T, and th1 must move monotonically within one interval (k pi, (k + 1) pi). Along
such a th1 path, momentum conservation fixes the integral of h(y1) th2 dy1 (``flatness``:
y2' = (g - h th2) y1'), so th2 must reach a value ``required_fold`` fixes (2.67 rad on the
paper's maneuver), which bounds the th2 angle limit and, with th2's travel there and back,
the rate limit. End configurations outside their angle limits, fixed end rates outside the
rate limit or inside the margin, and th1 travel faster than the rate limit allows are refused
likewise.

A chain of N >= 3 joints. The margin is sigma_t = -(dh_0/dt) / (2 K_10) (``chainflat``), so
its integral over [0, T] is (h_0(q(0)) - h_0(q(T))) / (2 K_10), fixed by the end
configurations: the margin can keep one sign only if h_0 differs at the ends, and can stay
>= m only if that integral is >= m T in size; its sign is the margin's sign sigma. At each end
sigma_t = -grad h_0 . u / (2 K_10) is linear in the joint rates u there, so within the rate
limits it reaches at most sum_j R_j |dh_0/dth_j| / (2 |K_10|); fixed end rates must give a
margin >= m of sign sigma and lie within the rate limits; each joint must be able to travel
from its start to its goal angle within its rate limit. What does not carry over is the fold:
the analogue of ``required_fold`` (the integral of th_N d(1/h_0), which momentum conservation
fixes) contains the line integral of sum_j (h_j / h_0) dq_j over the path of
q = (th_1..th_N-1), which for N >= 3 depends on the path, not only on its ends, so no fold
bound on th_N is checked up front; an angle or rate limit that forbids every fold is found by
the solver (phase 1 names the least violation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import ChainModel, PaperModel
from flatcli.core.models.flatness import chart
from flatcli.core.optimize.limits import PlanLimits
from flatcli.core.optimize.quantities import ANGLES, NAMES, Flat, layout

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Ends:
    """What the up-front checks settle about a maneuver's ends.

    Attributes
    ----------
    sigma : sign of the margin (sin(th1) th1', or -(dh_0/dt) / (2 K_10) for a chain) along
        any admissible plan (+1 or -1)
    start_rate, goal_rate : the end rates th1'(0), th1'(T) [rad/s], or for a chain the
        tuples (N - 1,) th_1'..th_N-1' at 0 and T: the fixed end rates, or the starting
        guesses, pointed the way the margin's sign needs and clipped into the range the
        limits allow
    """

    sigma: float
    start_rate: float | tuple[float, ...]
    goal_rate: float | tuple[float, ...]


def check_ends(
    k: Flat,
    start: Array,
    goal: Array,
    start_rate: float | Array,
    goal_rate: float | Array,
    duration: float,
    limits: PlanLimits,
    free_rates: bool,
    clearance: float,
) -> Ends:
    """Up-front feasibility checks of a maneuver under limits.

    Parameters
    ----------
    k : Coefficients (d2 = 0), or ChainModel (d_N = 0) for a chain
    start, goal : (N + 1,) end configurations [rad]
    start_rate, goal_rate : th1'(0), th1'(T) [rad/s], or for a chain th_1'..th_N-1' at the
        ends, (N - 1,) or one number for all (guesses, or fixed values)
    duration : T [s]
    limits : the user's limits, for N joints (``PlanLimits.for_joints``)
    free_rates : whether the end rates are decision variables
    clearance : a free end-rate guess whose margin is below min_margin is moved until it is
        (1 + this) min_margin (``Tuning.end_rate_clearance``)

    Returns
    -------
    Ends

    Raises
    ------
    FlatcliError, one line naming the spec key, for any request no plan can meet (see the
    module docstring)
    """
    check: Any = _END_CHECKS[k.kind]
    return cast(Ends, check(k, start, goal, start_rate, goal_rate, duration, limits,
                            free_rates, clearance))


def _check_paper_ends(
    k: PaperModel,
    start: Array,
    goal: Array,
    start_rate: float | Array,
    goal_rate: float | Array,
    duration: float,
    limits: PlanLimits,
    free_rates: bool,
    clearance: float,
) -> Ends:
    """``check_ends`` for the paper's robot (see the module docstring)."""
    start_rate, goal_rate = float(start_rate), float(goal_rate)
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
    R = limits.rate_of(1)
    if abs(travel) > R * duration:
        raise FlatcliError(
            f"plan.optimize.{limits.rate_key(1)} = {R:g} rad/s cannot be met: th1 must move "
            f"{abs(travel):g} rad in {duration:g} s, {abs(travel) / duration:.4g} rad/s on average"
        )
    rates = []
    for key, th1, rate in (("start", th1_0, start_rate), ("goal", th1_T, goal_rate)):
        low = m / abs(math.sin(th1))
        if free_rates:
            if low > R:
                raise FlatcliError(
                    f"plan.optimize.min_margin = {m:g} rad/s cannot be met within "
                    f"plan.optimize.{limits.rate_key(1)} = {R:g} rad/s at the {key}: |sin th1| = "
                    f"{abs(math.sin(th1)):.4g} needs |th1'| >= {low:.4g} rad/s there"
                )
            rate = math.copysign(min(max(abs(rate), low * (1 + clearance)), R), rate)
        else:
            if abs(rate) > R:
                raise FlatcliError(
                    f"plan.optimize.{limits.rate_key(1)} = {R:g} rad/s cannot be met: "
                    f"plan.{key}_rate = "
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


def required_fold(k: PaperModel, start: ArrayLike, goal: ArrayLike, nodes: int = 32) -> float:
    """A value th2 must reach somewhere on any flat plan of the paper's robot (N = 2) from
    ``start`` to ``goal`` [rad] (for a chain of N >= 3 joints no such bound follows from the
    ends alone: see the module docstring).

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
    k : the paper's closed-form model (d2 = 0)
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
    _, g, h = chart(k.coefficients, np.cos(th1), np.sin(th1))
    rise = float(k.end_map(goal)[0][1]) - float(k.end_map(start)[0][1])
    return (float(weights @ g) - rise) / float(weights @ h)


def check_fold(
    k: PaperModel, start: Array, goal: Array, duration: float, limits: PlanLimits
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
    R = limits.rate_of(2)
    if travel > R * duration:
        raise FlatcliError(
            f"plan.optimize.{limits.rate_key(2)} = {R:g} rad/s cannot be met: momentum "
            f"conservation forces th2 from {start[2]:g} to {v:.4g} and on to {goal[2]:g} rad, "
            f"{travel / duration:.4g} rad/s on average"
        )


def end_rate_bounds(
    theta: Array, limits: PlanLimits, rate: float
) -> tuple[float | None, float | None]:
    """Bounds on a free end rate th1' of the paper's robot [rad/s]: on the side of ``rate``,
    above the margin's minimum min_margin / |sin th1| and within the rate limit (None:
    unbounded)."""
    low = limits.min_margin / abs(math.sin(theta[1]))
    R = limits.rate_of(1)
    high = None if math.isinf(R) else R
    if rate > 0:
        return low, high
    return (None if high is None else -high), -low


def chain_rate_bounds(limits: PlanLimits) -> list[tuple[float | None, float | None]]:
    """Bounds on the free end rates th_1'..th_N-1' of a chain at one end [rad/s]: within
    each joint's rate limit (None: unbounded). The margin there is a constraint row."""
    bounds: list[tuple[float | None, float | None]] = []
    for joint in range(1, limits.n_joints):
        R = limits.rate_of(joint)
        bounds.append((None, None) if math.isinf(R) else (-R, R))
    return bounds


def base_inertia(model: ChainModel, theta: Array) -> tuple[float, Array]:
    """h_0 [kg m^2] at a configuration (N + 1,), and its gradient in th_1..th_N-1
    (N - 1,) [kg m^2] (``ChainModel.base_inertia``)."""
    return model.base_inertia(theta)


def margin_mean(k: Flat, start: Array, goal: Array, duration: float) -> float:
    """The margin's mean over [0, T] on any plan between the two configurations, unsigned
    [rad/s]: (cos th1(0) - cos th1(T)) / T for the paper's robot, (h_0(q(0)) - h_0(q(T))) /
    (2 K_10 T) for a chain (times sigma, the margin's sign, it is the mean of the signed
    margin: the largest least margin any plan can have; ``FlatModel.margin_mean``)."""
    return float(k.margin_mean(start, goal, duration))


def _check_chain_ends(
    model: ChainModel,
    start: Array,
    goal: Array,
    start_rate: float | Array,
    goal_rate: float | Array,
    duration: float,
    limits: PlanLimits,
    free_rates: bool,
    clearance: float,
) -> Ends:
    """``check_ends`` for a chain of N joints (see the module docstring)."""
    n = model.n_joints
    names = layout(n).names
    for key, theta in (("start", start), ("goal", goal)):
        for i in range(n + 1):
            if abs(theta[i]) > limits.angle_limit[i]:
                raise FlatcliError(
                    f"plan.optimize.angle_limit[{i}] = {limits.angle_limit[i]:g} rad cannot be "
                    f"met: the {key} configuration has |{names[i]}| = {abs(theta[i]):g} rad"
                )
    m = limits.min_margin
    mean = margin_mean(model, start, goal, duration)
    if mean == 0.0:
        raise FlatcliError(
            "plan.goal: the base's locked inertia h_0 is the same at plan.start and plan.goal, "
            "so the margin -(dh_0/dt) / (2 K_10), whose integral over the maneuver is "
            "(h_0(0) - h_0(T)) / (2 K_10), would have to change sign: the plan would cross "
            "the singular set"
        )
    sigma = math.copysign(1.0, mean)
    if abs(mean) < m:
        raise FlatcliError(
            f"plan.optimize.min_margin = {m:g} rad/s cannot be met: the margin "
            f"-(dh_0/dt) / (2 K_10) averages (h_0(0) - h_0(T)) / (2 K_10 T) = {abs(mean):.4g} "
            "rad/s over this maneuver"
        )
    for joint in range(1, n + 1):
        R = limits.rate_of(joint)
        travel = abs(float(goal[joint]) - float(start[joint]))
        if travel > R * duration:
            raise FlatcliError(
                f"plan.optimize.{limits.rate_key(joint)} = {R:g} rad/s cannot be met: "
                f"th{joint} must move {travel:g} rad in {duration:g} s, "
                f"{travel / duration:.4g} rad/s on average"
            )
    bound = np.array([limits.rate_of(j) for j in range(1, n)])  # th_1'..th_N-1'
    rates = []
    for key, theta, given in (("start", start, start_rate), ("goal", goal, goal_rate)):
        u = np.broadcast_to(np.asarray(given, dtype=float), (n - 1,)).copy()
        # the margin at this end is slope @ u [rad/s]
        slope = -base_inertia(model, theta)[1] / (2.0 * float(model.K[1, 0]))
        if free_rates:
            reach = float(np.abs(slope) @ bound)
            if reach < m:
                raise FlatcliError(
                    f"plan.optimize.min_margin = {m:g} rad/s cannot be met within "
                    f"plan.optimize.rate_limit at the {key}: the joint rates allowed there give "
                    f"a margin of at most {reach:.4g} rad/s"
                )
            u = _pointed(u, slope, sigma, m * (1 + clearance), bound)
        else:
            for j in range(n - 1):
                if abs(u[j]) > bound[j]:
                    raise FlatcliError(
                        f"plan.optimize.{limits.rate_key(j + 1)} = {bound[j]:g} rad/s cannot be "
                        f"met: plan.{key}_rate has th{j + 1}' = {u[j]:g} rad/s, fixed "
                        "(free_rates = false)"
                    )
            margin = float(slope @ u)
            if sigma * margin < m:
                raise FlatcliError(
                    f"plan.optimize.min_margin = {m:g} rad/s cannot be met: the fixed "
                    f"plan.{key}_rate gives a margin of {sigma * margin:.4g} rad/s at the {key} "
                    f"(free_rates = false; h_0 must move from {base_inertia(model, start)[0]:.4g} "
                    f"to {base_inertia(model, goal)[0]:.4g} kg m^2, which fixes the margin's sign)"
                )
        rates.append(tuple(float(v) for v in u))
    return Ends(sigma, rates[0], rates[1])


#: The up-front checks of each kind of model (``FlatModel.kind``).
_END_CHECKS = {"paper": _check_paper_ends, "chain": _check_chain_ends}


def _pointed(u: Array, slope: Array, sigma: float, low: float, R: Array) -> Array:
    """End rates of a chain moved so that the margin slope @ u there is sigma-signed and at
    least ``low``, within the rate limits R (as far as they allow): reversed if the margin
    has the wrong sign, then shifted along the margin's gradient, least change first, joints
    that reach their limit held there."""
    if sigma * float(slope @ u) < 0:
        u = -u
    free = np.ones(u.size, dtype=bool)
    for _ in range(u.size):
        deficit = low - sigma * float(slope @ u)
        direction = np.where(free, slope, 0.0)
        size = float(direction @ direction)
        if deficit <= 0 or size == 0.0:
            break
        u = np.clip(u + sigma * deficit * direction / size, -R, R)
        free &= np.abs(u) < R
    return u


__all__ = [
    "Ends",
    "base_inertia",
    "chain_rate_bounds",
    "check_ends",
    "check_fold",
    "end_rate_bounds",
    "margin_mean",
    "required_fold",
]
