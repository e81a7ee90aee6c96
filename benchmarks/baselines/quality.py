"""How good a plan is, measured the same way for every planner: energy, peaks, limits, H."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.curves.basis import composite_gauss_legendre
from flatcli.core.models.flatmodel import state_and_rates
from flatcli.core.plan.planning import ENERGY_ORDER, ENERGY_PIECES, Plan
from flatcli.core.robots.params import (
    Coefficients,
    RobotParams,
    momentum,
)

Array = NDArray[np.float64]

@dataclass(frozen=True)
class PlanQuality:
    """What a plan costs and how well it keeps the limits, judged on a dense grid.

    Attributes
    ----------
    energy : integral of th1'^2 + th2'^2 over [0, T] [rad^2/s]
    max_abs_theta : (3,) max |th_i| [rad]
    max_abs_rate : (3,) max |th_i'| [rad/s]
    min_margin : min |sin th1 * th1'| [rad/s]
    max_abs_momentum : max |H| from the full kinematics [kg m^2/s]
    violation : max amount by which any imposed limit is exceeded (0: none) [rad or rad/s]
    """

    energy: float
    max_abs_theta: Array
    max_abs_rate: Array
    min_margin: float
    max_abs_momentum: float
    violation: float


def limits_violation(
    theta: Array,
    rates: Array,
    margin: Array,
    angle_limit: float | None,
    rate_limit: float | None,
    min_margin: float | None,
) -> float:
    """Largest excess over |th2| <= angle_limit, |th1'|, |th2'| <= rate_limit, margin."""
    excess = [0.0]
    if angle_limit is not None:
        excess.append(float(np.max(np.abs(theta[:, 2]))) - angle_limit)
    if rate_limit is not None:
        excess.append(float(np.max(np.abs(rates[:, 1:3]))) - rate_limit)
    if min_margin is not None:
        excess.append(min_margin - float(np.min(margin)))
    return max(excess)


def flat_plan_quality(
    k: Coefficients,
    robot: RobotParams,
    flags: Callable[[Array], tuple[Array, Array, Array]],
    duration: float,
    angle_limit: float | None = None,
    rate_limit: float | None = None,
    min_margin: float | None = None,
    samples: int = 2001,
) -> PlanQuality:
    """Judge a flat plan given by its flags y, y', y'' as functions of time.

    Rates are the exact derivative of the inverse flat map (complex step, as flatcli's
    planner does), so H measures the plan itself, not an integration.
    """
    t = np.linspace(0.0, duration, samples)
    y, y_dot, y_ddot = flags(t)
    state, state_dot = state_and_rates(k, y, y_dot, y_ddot)
    theta, rates = state[:, :3], state_dot[:, :3]
    margin = np.abs(np.sin(theta[:, 1]) * rates[:, 1])
    H = momentum(robot.links, *theta.T, *rates.T)
    tq, wq = composite_gauss_legendre(duration, ENERGY_PIECES, ENERGY_ORDER)
    _, rq = state_and_rates(k, *flags(tq))
    return PlanQuality(
        energy=float(wq @ (rq[:, 1] ** 2 + rq[:, 2] ** 2)),
        max_abs_theta=np.max(np.abs(theta), axis=0),
        max_abs_rate=np.max(np.abs(rates), axis=0),
        min_margin=float(np.min(margin)),
        max_abs_momentum=float(np.max(np.abs(H))),
        violation=limits_violation(theta, rates, margin, angle_limit, rate_limit, min_margin),
    )


def plan_quality(
    plan: Plan,
    angle_limit: float | None = None,
    rate_limit: float | None = None,
    min_margin: float | None = None,
) -> PlanQuality:
    """``flat_plan_quality`` of a flatcli plan (the same referee as for python-control's)."""

    def flags(t: Array) -> tuple[Array, Array, Array]:
        curve = plan.trajectory
        return curve.derivative(t, 0), curve.derivative(t, 1), curve.derivative(t, 2)

    return flat_plan_quality(
        plan.coefficients, plan.robot, flags, plan.duration, angle_limit, rate_limit, min_margin
    )
