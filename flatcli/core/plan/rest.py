"""Rest-to-rest maneuvers: plans that start and stop with every rate zero.

Rest lies on the singular set: the inverse map recovers th_N from the ratio of y_N' to the
inner joints' rates (N = 2: th2 = (g(y1) - y2'/y1') / h(y1), ``flatness``; any N:
y_N' = sigma(q, th_N) . u, affine in th_N, ``chainflat``), which is 0/0 at rest. The ratio
has a finite limit, and th_N the wanted one, when the flat outputs vanish to the same order
with the slope of the end configuration (derivation in docs/tasks.md):

    y_j'(end) = 0,  y_N'(end) = 0,
    y_N''(end) = sigma_end . q''(end),      y_N'''(end) = sigma_end . q'''(end),

with sigma_end the end map's slope at the end configuration (``FlatModel.end_map``: y' =
slope u). The first pair makes every rate vanish; the second gives th_N(t) = th_N(end) +
O(t^2), hence th_N'(end) = 0 and (through the momentum constraint) th0'(end) = 0. It needs
q''(end) off the level set of h_0 (D ~ grad h_0 . q'' t != 0): the margin grows from zero
linearly, and the plan leaves the singular set at once.

flatcli's rest plan (``plan_rest_to_rest``): each inner joint a smooth-step cubic
q_j(s) = q_j(0) + (q_j(T) - q_j(0)) (3 s^2 - 2 s^3), s = t / T (zero rates at the ends;
q''(0) = 6 dq / T^2, q'''(0) = -12 dq / T^3, q''(T) = -6 dq / T^2, q'''(T) = -12 dq / T^3),
and y_N the degree-7 polynomial meeting its eight conditions (Hermite). For N = 2 the signed
margin is sin(y1) y1' with y1' = 6 dth1 s (1 - s) / T: of one sign inside exactly when th1
moves (dth1 != 0) and no multiple of pi lies between its ends.

At the ends themselves the closed forms are 0/0: ``RestPlan`` evaluates the limits there
(the end configuration, zero rates, u' = q''), and the angles' accelerations by Richardson
extrapolation from inside. Near them the rates lose about eps / t of absolute accuracy
(terms of size 1/t cancel): 1e-8 rad/s at t = 1e-8 s.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.curves.basis import FlatTrajectory, PolynomialBasis
from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import ChainModel, FlatModel, flat_model
from flatcli.core.names import Model
from flatcli.core.plan.planning import Plan, PlanSamples
from flatcli.core.robots.chain import base_inertia_slopes
from flatcli.core.robots.params import RobotParams, require_flat

Array = NDArray[np.float64]

#: Degree of y_N in a rest plan (eight end conditions).
REST_DEGREE = 7
#: Points of the scan for sign changes of a chain's reduced margin (N >= 3).
REST_SCAN = 4096
#: Relative step of the Richardson extrapolation of accelerations to the ends.
END_STEP = 1e-4


@functools.lru_cache(maxsize=8)
def _hermite_operators(far_node: float) -> tuple[Array, Array]:
    """For ``_hermite7``: the rows d^k/dx^k x^j at x = ``far_node``, k = 0..3, j = 0..7 (4, 8),
    split into the known part (j < 4) and the inverse of the unknown one (j >= 4) (read-only)."""
    terms = np.array([[math.prod(range(j - k + 1, j + 1)) * far_node ** (j - k) if j >= k
                       else 0.0 for j in range(8)] for k in range(4)])
    known, inverse = terms[:, :4].copy(), np.linalg.inv(terms[:, 4:])
    for arr in (known, inverse):
        arr.setflags(write=False)
    return known, inverse


def _hermite7(near: tuple[float, float, float, float], far: tuple[float, float, float, float],
              far_node: float) -> Array:
    """(8,) coefficients of x^0..x^7 of the polynomial whose value and first three
    x-derivatives are ``near`` at x = 0 (taken exactly: c_k = near_k / k!) and ``far`` at
    x = ``far_node`` (the other four coefficients solved for)."""
    c = np.zeros(8)
    c[:4] = np.asarray(near, dtype=float) / np.array([1.0, 1.0, 2.0, 6.0])
    known, inverse = _hermite_operators(float(far_node))
    c[4:] = inverse @ (np.asarray(far, dtype=float) - known @ c[:4])
    return c


def rest_coefficients(model: FlatModel, start: Array, goal: Array, about_goal: bool = False,
                      skew: float = 0.0) -> Array:
    """(N, 8) coefficients in s = t / T of the rest plan's flat outputs (module docstring);
    independent of T. ``about_goal``: in x = s - 1 instead. Each representation takes the
    conditions of its own end exactly (y' = 0 there is an exact zero coefficient), so that
    near either end y_N' / y_j' is not off by the rounding of the coefficients' sums
    (eps |c| / (1 - s) near s = 1 in the monomials of s). ``skew`` beta in (-1, 1) shifts
    the inner joints' motion: q_j = q_j(0) + dq_j (3 s^2 - 2 s^3 - 3 beta s^2 (1 - s)^2),
    whose rate 6 dq_j s (1 - s) (1 + beta (2 s - 1)) keeps its sign."""
    n = model.n_joints
    y0, slope0 = model.end_map(start)
    yT, slopeT = model.end_map(goal)
    dq = np.asarray(goal[1:n] - start[1:n], dtype=float)  # (N - 1,)
    out = np.zeros((n, REST_DEGREE + 1))
    b = float(skew)
    for j in range(n - 1):  # the smooth step, in s or in x = s - 1 (s^2 (1-s)^2 = x^2 (1+x)^2)
        d = dq[j]
        if about_goal:
            out[j, :5] = (goal[1 + j], 0.0, -3.0 * d * (1 + b), -2.0 * d * (1 + 3 * b), -3 * b * d)
        else:
            out[j, :5] = (start[1 + j], 0.0, 3.0 * d * (1 - b), -2.0 * d * (1 - 3 * b), -3 * b * d)
    s0 = float(slope0[n - 1] @ dq)
    sT = float(slopeT[n - 1] @ dq)
    at_start = (float(y0[n - 1]), 0.0, 6.0 * (1 - b) * s0, (-12.0 + 36.0 * b) * s0)
    at_goal = (float(yT[n - 1]), 0.0, -6.0 * (1 + b) * sT, (-12.0 - 36.0 * b) * sT)
    out[n - 1] = (_hermite7(at_goal, at_start, -1.0) if about_goal
                  else _hermite7(at_start, at_goal, 1.0))
    return out


def reduced_margin(model: FlatModel, robot: RobotParams, start: Array, goal: Array,
                   s: Array, skew: float = 0.0) -> Array:
    """(n,) the signed margin of the rest plan divided by 6 s (1 - s) (1 + beta (2 s - 1)) / T
    at s (n,) in [0, 1] [rad]: its sign is the margin's inside (0, T), and it is finite at the
    ends."""
    n = model.n_joints
    dq = np.asarray(goal[1:n] - start[1:n], dtype=float)
    step = 3.0 * s**2 - 2.0 * s**3 - 3.0 * skew * s**2 * (1.0 - s) ** 2
    q = start[1:n][None, :] + np.outer(step, dq)
    if n == 2 and not isinstance(model, ChainModel):
        return np.asarray(np.sin(q[:, 0]) * dq[0], dtype=float)
    chain = model if isinstance(model, ChainModel) else ChainModel.of(robot)
    out = np.empty(len(s))
    grad = np.empty(n)
    hess = np.empty((n, n))
    theta = np.zeros(n + 1)
    for i in range(len(s)):
        theta[1:n] = q[i]
        base_inertia_slopes(chain.K, chain.inertia, theta, grad, hess)
        out[i] = -float(grad[: n - 1] @ dq) / (2.0 * float(chain.K[1, 0]))
    return out


def check_rest_margin(model: FlatModel, robot: RobotParams, start: Array, goal: Array,
                      skew: float = 0.0) -> None:
    """FlatcliError naming task.rest unless the rest plan's margin keeps one sign strictly
    inside (0, T) and is non-zero to first order at the ends."""
    n = model.n_joints
    if np.all(goal[1:n] == start[1:n]):
        raise FlatcliError("task.rest: the inner joints th1..th_N-1 do not move between the start "
                           "and the goal; a rest-to-rest flat plan needs them to (the margin "
                           "grows from rest only through their motion): change the target or "
                           "plan.start")
    if n == 2 and not isinstance(model, ChainModel):
        lo, hi = sorted((float(start[1]), float(goal[1])))
        k = math.floor(lo / math.pi) + 1
        if k * math.pi <= hi or abs(math.sin(lo)) < 1e-9 or abs(math.sin(hi)) < 1e-9:
            raise FlatcliError(f"task.rest: th1 moves from {start[1]:g} to {goal[1]:g} rad, "
                               f"through th1 = {k * math.pi:g} rad where sin th1 = 0: the plan "
                               "would cross the singular set")
        return
    s = np.linspace(0.0, 1.0, REST_SCAN)
    m = reduced_margin(model, robot, start, goal, s, skew)
    if not (np.all(m > 0) or np.all(m < 0)):
        where = float(s[int(np.argmax(np.sign(m) != np.sign(m[0])))]) if m[0] != 0 else 0.0
        raise FlatcliError(f"task.rest: the rest plan's margin changes sign near t/T = "
                           f"{where:.3g} (dh_0/dt = 0 along the straight joint path): no "
                           "rest-to-rest plan of this shape; change the target or plan.start")


@dataclass(frozen=True)
class RestPlan(Plan):
    """A rest-to-rest ``Plan``: the same flat curves and maps, with the limits at the ends
    (module docstring). ``start``, ``goal`` (N + 1,) are the end configurations [rad]."""

    start: Array = None  # type: ignore[assignment]
    goal: Array = None  # type: ignore[assignment]
    tail: Array = None  # type: ignore[assignment]  # (N, 8) the same curves in s - 1
    skew: float = 0.0

    def derivative(self, t: Array, order: int) -> Array:
        """(n, N) d^order y / dt^order at t (n,): from the coefficients in s on the first
        half, in s - 1 on the second (``rest_coefficients``)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = self.trajectory.derivative(t, order)
        late = t > 0.5 * self.duration
        if late.any():
            x = t[late] / self.duration - 1.0
            c = self.tail
            for _ in range(order):
                c = c[:, 1:] * np.arange(1, c.shape[1])
            values = np.stack([np.polynomial.polynomial.polyval(x, row) for row in c], axis=-1)
            out[late] = values / self.duration**order
        return out

    def flags(self, t: Array) -> Array:
        return np.ascontiguousarray(np.concatenate(
            [self.derivative(np.asarray(t, dtype=float), k) for k in range(3)], axis=-1))

    @classmethod
    def flags_of(cls, plans: Sequence[Plan], t: Array) -> Array:
        """``Plan.flags_of`` with each plan's tail on the second half (``derivative``)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        flags = super().flags_of(plans, t)
        duration = plans[0].duration
        late = t > 0.5 * duration
        if late.any():
            x = t[late] / duration - 1.0
            tails = [p.tail for p in plans if isinstance(p, RestPlan)]
            if len(tails) != len(plans):
                raise TypeError("RestPlan.flags_of: rest plans only")
            c = np.swapaxes(np.stack(tails), -1, -2)  # (P, 8, N)
            n = c.shape[-1]
            powers = np.vander(x, c.shape[-2], increasing=True)
            for k in range(3):
                flags[:, late, k * n:(k + 1) * n] = (powers[:, :c.shape[-2]] @ c) / duration**k
                c = c[:, 1:] * np.arange(1, c.shape[-2])[:, None]
        return flags

    @classmethod
    def states_of(cls, plans: Sequence[Plan], t: Array) -> tuple[Array, Array, Array]:
        """``Plan.states_of`` with the limits at the ends (``sample``)."""
        duration = plans[0].duration
        inner = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, duration)
        with np.errstate(divide="ignore", invalid="ignore"):
            theta, theta_dot, margin = super().states_of(plans, inner)
        for rows, field in ((np.flatnonzero(inner <= 0.0), "start"),
                            (np.flatnonzero(inner >= duration), "goal")):
            if rows.size:
                theta[:, rows] = np.stack([getattr(p, field) for p in plans])[:, None, :]
                theta_dot[:, rows] = 0.0
                margin[:, rows] = 0.0
        return theta, theta_dot, margin

    def _end_rows(self, t: Array) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        t = np.asarray(t, dtype=float)
        return np.flatnonzero(t <= 0.0), np.flatnonzero(t >= self.duration)

    def _end_accelerations(self) -> tuple[Array, Array]:
        """u' = q'' at t = 0 and T, (N - 1,) [rad/s^2]."""
        n = self.n_joints
        dq = self.goal[1:n] - self.start[1:n]
        a = 6.0 * dq / self.duration**2
        return a * (1.0 - self.skew), -a * (1.0 + self.skew)

    def sample(self, t: Array) -> PlanSamples:
        t = np.asarray(t, dtype=float)
        inner = np.clip(t, 0.0, self.duration)
        with np.errstate(divide="ignore", invalid="ignore"):
            samples = super().sample(inner)
        first, last = self._end_rows(inner)
        if not (first.size or last.size):
            return samples
        theta = samples.theta.copy()
        theta_dot = samples.theta_dot.copy()
        u_dot = samples.u_dot.copy()
        margin = samples.margin.copy()
        momentum = samples.momentum.copy()
        acc0, accT = self._end_accelerations()
        for rows, config, acc in ((first, self.start, acc0), (last, self.goal, accT)):
            theta[rows] = config
            theta_dot[rows] = 0.0
            u_dot[rows] = acc
            margin[rows] = 0.0
            momentum[rows] = 0.0
        return replace(samples, theta=theta, theta_dot=theta_dot, u_dot=u_dot, margin=margin,
                       momentum=momentum)

    def evaluate(self, t: Array) -> tuple[Array, Array]:
        n = self.n_joints
        s = self.sample(t)
        state = np.concatenate([s.theta, s.theta_dot[..., 1:n]], axis=-1)
        return state, np.concatenate([s.u_dot, s.theta_dot[..., n:]], axis=-1)

    def motion(self, t: Array) -> tuple[Array, Array, Array]:
        t = np.asarray(t, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            q, q_dot, q_ddot = self.model.motion(self, np.clip(t, 0.0, self.duration))  # type: ignore[arg-type]  # derivative() is all it asks
        first, last = self._end_rows(t)
        h = END_STEP * self.duration
        for rows, config, inside in ((first, self.start, (h, 2 * h)),
                                     (last, self.goal, (self.duration - h,
                                                        self.duration - 2 * h))):
            if rows.size:
                near = self.model.motion(self, np.array(inside))[2]  # type: ignore[arg-type]
                q[rows] = config
                q_dot[rows] = 0.0
                q_ddot[rows] = 2.0 * near[0] - near[1]  # linear extrapolation, O(h^2)
        return q, q_dot, q_ddot

    def margin_zeros(self) -> Array:
        """Times strictly inside (0, T) where the margin is zero [s] (the ends are rest)."""
        s = np.linspace(0.0, 1.0, REST_SCAN)
        m = reduced_margin(self.model, self.robot, self.start, self.goal, s, self.skew)
        change = np.flatnonzero(np.sign(m[1:]) != np.sign(m[:-1]))
        return np.asarray(s[change] * self.duration, dtype=float)


def plan_rest_to_rest(robot: RobotParams, start: ArrayLike, goal: ArrayLike, duration: float,
                      model: Model | FlatModel = "derived", skew: float = 0.0) -> RestPlan:
    """The rest-to-rest plan from ``start`` to ``goal`` (N + 1,) [rad] in ``duration`` [s]
    (module docstring); ``skew`` in (-1, 1) shifts the inner joints' motion earlier (< 0) or
    later (``rest_coefficients``).

    Raises
    ------
    FlatcliError naming the key: a design whose outputs do not apply, a maneuver whose
    inner joints do not move, or whose margin changes sign inside (0, T).
    """
    require_flat(robot)
    if not (duration > 0 and math.isfinite(duration)):
        raise FlatcliError(f"plan.duration: must be a finite number > 0 s, got {duration}")
    flat = model if isinstance(model, FlatModel) else flat_model(robot, model)
    a = np.asarray(start, dtype=float)
    b = np.asarray(goal, dtype=float)
    if not -1.0 < skew < 1.0:
        raise FlatcliError(f"rest plan: skew must lie in (-1, 1), got {skew}")
    check_rest_margin(flat, robot, a, b, skew)
    basis = PolynomialBasis(REST_DEGREE, float(duration))
    coefficients = rest_coefficients(flat, a, b, skew=skew)
    tail = rest_coefficients(flat, a, b, about_goal=True, skew=skew)
    for arr in (a, b, tail):
        arr.setflags(write=False)
    return RestPlan(robot, flat, FlatTrajectory(basis, coefficients), float(duration), a, b,
                    tail, float(skew))


__all__ = [
    "REST_DEGREE",
    "RestPlan",
    "check_rest_margin",
    "plan_rest_to_rest",
    "reduced_margin",
    "rest_coefficients",
]
