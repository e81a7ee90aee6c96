"""Planning without flatness: an SLSQP shooting NLP over piecewise-constant joint rates."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import Bounds, minimize

from benchmarks.baselines.problem import PAPER_MANEUVER, Maneuver
from flatcli.core.robots.params import (
    base_rate,
    momentum,
)

Array = NDArray[np.float64]

@dataclass(frozen=True)
class ShootingPlan:
    """Result of the shooting NLP.

    Attributes
    ----------
    success, message : from SLSQP
    rates : (K, 2) th1', th2' on each interval [rad/s]
    knots : (K + 1,) interval ends [s]
    theta : (K + 1, 3) angles at the knots from the plan's own integration [rad]
    objective : input energy, integral of th1'^2 + th2'^2 (exact for these rates) [rad^2/s]
    terminal_error : max |th(T) - goal| by the plan's own integration [rad]
    integration_error : |th0(T)| difference to the same rates integrated 16x finer [rad]
        (what the robot flying these rates would actually miss the goal by, to leading order)
    violation : max excess over the imposed limits (0: none)
    max_abs_momentum : max |H| from the full kinematics with the rates used (th0' from the
        constraint) at every integration point [kg m^2/s]
    iterations : SLSQP iterations; evaluations : objective evaluations
    seconds : wall time of the solve [s]
    """

    success: bool
    message: str
    rates: Array
    knots: Array
    theta: Array
    objective: float
    terminal_error: float
    integration_error: float
    violation: float
    max_abs_momentum: float
    iterations: int
    evaluations: int
    seconds: float


class _Shooting:
    """th(t) for piecewise-constant joint rates, th0' from the reduced constraint.

    The joint angles are piecewise linear, exactly; th0 is integrated by RK4 on ``substeps``
    steps per interval. Since th0' does not depend on th0 and the joint rates are constant
    on a step, RK4's stages fall at the step's start, middle (twice) and end, so each RK4
    step is Simpson's rule; written that way, every step of every interval is evaluated in
    one vectorised call.
    """

    def __init__(self, maneuver: Maneuver, intervals: int, substeps: int) -> None:
        self.k = maneuver.coefficients
        self.total_mass = maneuver.robot.total_mass
        self.start = np.asarray(maneuver.start, dtype=float)
        self.intervals = intervals
        self.substeps = substeps
        self.h = maneuver.duration / intervals
        self.hs = self.h / substeps
        self.offsets = np.array([0.0, 0.5, 1.0]) * self.hs
        self.simpson = np.array([1.0, 4.0, 1.0]) * (self.hs / 6.0)

    def points(self, rates: Any) -> tuple[Any, Any, Any, Any]:
        """th1, th2 and the rates at every RK4 stage point: (..., K * S, 3) each."""
        per_step = np.repeat(rates, self.substeps, axis=-2)  # (..., Q, 2)
        begin = self.start[1:] + self.hs * (np.cumsum(per_step, axis=-2) - per_step)
        pts = begin[..., :, None, :] + self.offsets[:, None] * per_step[..., :, None, :]
        r = np.broadcast_to(per_step[..., :, None, :], pts.shape)
        return pts[..., 0], pts[..., 1], r[..., 0], r[..., 1]

    def base_rates(self, rates: Any) -> Any:
        """th0' at every stage point, (..., K * S, 3)."""
        th1, th2, r1, r2 = self.points(rates)
        return base_rate(self.k, self.total_mass, 0.0, th1, th2, r1, r2)

    def final_base(self, rates: Any) -> Any:
        """th0(T), (...)."""
        return self.start[0] + np.sum(self.base_rates(rates) @ self.simpson, axis=-1)

    def final_base_gradient(self, rates: Array) -> Array:
        """d th0(T) / d rates, flattened (2K,), exact to rounding.

        The partial derivatives of th0' in th1, th2, th1', th2' at every stage point come
        from a complex step; the chain rule through th_j(t) = th_j(0) + integral of th_j'
        is a reversed cumulative sum, so the whole gradient costs four evaluations.
        """
        step = 1e-30
        args = self.points(rates)
        partial = []
        for a in range(4):
            z = list(args)
            z[a] = z[a] + 1j * step
            partial.append(base_rate(self.k, self.total_mass, 0.0, *z).imag / step)
        grad = np.empty((self.intervals, 2))
        for c in range(2):
            d_angle, d_rate = partial[c], partial[2 + c]  # (Q, 3)
            weight = d_angle @ self.simpson  # (Q,) th0(T) per unit change of th_c on step q
            later = np.cumsum(weight[::-1])[::-1] - weight  # steps after q
            per_step = (
                self.hs * later + d_angle @ (self.simpson * self.offsets) + d_rate @ self.simpson
            )
            grad[:, c] = per_step.reshape(self.intervals, self.substeps).sum(axis=1)
        return grad.ravel()

    def knots_theta(self, rates: Array) -> Array:
        """(K + 1, 3) angles at the interval ends."""
        f = self.base_rates(rates) @ self.simpson  # (Q,)
        th0 = self.start[0] + np.concatenate([[0.0], np.cumsum(f)])[:: self.substeps]
        joints = self.start[1:] + np.concatenate([np.zeros((1, 2)), np.cumsum(rates, 0) * self.h])
        return np.column_stack([th0, joints])


def shooting_plan(
    maneuver: Maneuver = PAPER_MANEUVER,
    intervals: int = 40,
    substeps: int = 4,
    angle_limit: float | None = None,
    rate_limit: float | None = None,
    maxiter: int = 500,
    ftol: float = 1e-10,
    exact_gradients: bool = True,
) -> ShootingPlan:
    """Least input energy from start to goal without flatness: a shooting NLP with SLSQP.

    Decision: piecewise-constant joint rates (th1', th2') on K equal intervals. th0 follows
    from the reduced constraint of the planning model (``base_rate`` with H = 0), integrated
    by RK4 on ``substeps`` steps per interval. Minimise the input energy h sum(th1'^2 +
    th2'^2) subject to reaching the goal angles at T (th1, th2 linear, th0 nonlinear with an
    exact complex-step gradient), |th2| <= angle_limit at the knots (exact: th2 is piecewise
    linear) and |rates| <= rate_limit (bounds). The end rates are free. Start: constant rates
    along the straight line in joint space.

    Parameters
    ----------
    maneuver : Maneuver (start, goal, T, robot and model; its end rates are not used)
    intervals : K
    substeps : RK4 steps per interval
    angle_limit : bound on |th2| [rad] or None
    rate_limit : bound on |th1'|, |th2'| [rad/s] or None
    maxiter, ftol : SLSQP options
    exact_gradients : give SLSQP the exact gradients (default); False lets it take forward
        differences, as a quick script would (2K + 1 integrations per iteration)

    Returns
    -------
    ShootingPlan
    """
    model = _Shooting(maneuver, intervals, substeps)
    K, h = intervals, model.h
    goal = np.asarray(maneuver.goal, dtype=float)
    joint_rows = np.zeros((2, 2 * K))
    joint_rows[0, 0::2] = h
    joint_rows[1, 1::2] = h
    joint_target = goal[1:] - model.start[1:]

    def shape(z: Array) -> Array:
        return z.reshape(K, 2)

    def energy(z: Array) -> float:
        return float(h * (z @ z))

    def energy_grad(z: Array) -> Array:
        return 2.0 * h * z

    def equality(z: Array) -> Array:
        return np.concatenate(
            [[float(model.final_base(shape(z))) - goal[0]], joint_rows @ z - joint_target]
        )

    def equality_jac(z: Array) -> Array:
        return np.vstack([model.final_base_gradient(shape(z)), joint_rows])

    constraints: list[dict[str, Any]] = [{"type": "eq", "fun": equality}]
    if exact_gradients:
        constraints[0]["jac"] = equality_jac
    if angle_limit is not None:
        # th2 at knots 1..K: start + h * cumulative sum of th2'
        cum = np.tril(np.ones((K, K))) * h
        rows = np.zeros((K, 2 * K))
        rows[:, 1::2] = cum
        A = np.vstack([-rows, rows])
        b = np.concatenate(
            [np.full(K, angle_limit + model.start[2]), np.full(K, angle_limit - model.start[2])]
        )

        constraints.append({"type": "ineq", "fun": lambda z: b - A @ z, "jac": lambda z: -A})
    bounds = None if rate_limit is None else Bounds(-rate_limit, rate_limit)
    z0 = np.tile((goal[1:] - model.start[1:]) / maneuver.duration, K)

    start = time.perf_counter()
    res = minimize(
        energy,
        z0,
        jac=energy_grad if exact_gradients else None,
        method="SLSQP",
        bounds=bounds,
        constraints=constraints,
        options={"maxiter": maxiter, "ftol": ftol},
    )
    seconds = time.perf_counter() - start

    rates = shape(res.x)
    theta = model.knots_theta(rates)
    fine = _Shooting(maneuver, intervals, substeps * 16)
    th1, th2, r1, r2 = model.points(rates)
    H = momentum(maneuver.robot.links, 0.0, th1, th2, model.base_rates(rates), r1, r2)
    excess = [0.0]
    if angle_limit is not None:
        excess.append(float(np.max(np.abs(theta[:, 2]))) - angle_limit)
    if rate_limit is not None:
        excess.append(float(np.max(np.abs(rates))) - rate_limit)
    return ShootingPlan(
        success=bool(res.success),
        message=str(res.message),
        rates=rates,
        knots=np.linspace(0.0, maneuver.duration, K + 1),
        theta=theta,
        objective=energy(res.x),
        terminal_error=float(np.max(np.abs(theta[-1] - goal))),
        integration_error=float(abs(fine.final_base(rates) - theta[-1, 0])),
        violation=max(excess),
        max_abs_momentum=float(np.max(np.abs(H))),
        iterations=int(res.nit),
        evaluations=int(res.nfev),
        seconds=seconds,
    )
