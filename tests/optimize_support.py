"""Shared helpers of the tests of ``flatcli.core.optimize`` (tests/test_optimize_*.py).

``optimize_paper`` runs ``optimize_plan`` on the paper's maneuver (Franch et al. 2003,
Sec. VI: th(0) = (1.8, 1, 0), th(2) = (1.2, 2, 0), T = 2 s, the paper's robot), memoised for
the whole test session (results are immutable); ``check_plan`` checks an optimised plan
against its limits, the full kinematics and its ends on a grid the optimiser never saw.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from flatcli.core.model import PAPER_ROBOT, momentum
from flatcli.core.optimize import TUNING, OptimizeResult, PlanLimits, optimize_plan
from flatcli.core.planning import FlatPlan, PlanSamples

Array = NDArray[np.float64]

#: The paper's maneuver (Sec. VI).
START = (1.8, 1.0, 0.0)
GOAL = (1.2, 2.0, 0.0)
DURATION = 2.0
#: Fine grid for every check along a plan: twice as dense as the optimiser's check grid
#: (201 constraint samples, ``TUNING.check_refinement`` = 10), so half its points were never
#: seen by the optimiser.
FINE = 2 * TUNING.check_refinement * 200 + 1
#: |H| from the full kinematics (``model.momentum``) along an optimised plan [kg m^2/s]:
#: rounding of terms of order 1 (observed ~2e-16 on every plan of these tests).
MOMENTUM_BOUND = 1e-12
#: Identities that hold to rounding.
EXACT_TOL = 1e-12
#: End angles come back through the inverse map, which divides by h y1' ~ 1e-3 at the ends
#: of an optimised plan (its end rates sit on the margin): rounding is amplified ~1e3-fold.
BOUNDARY_TOL = 1e-9

_CACHE: dict[str, OptimizeResult] = {}


def optimize_paper(**kwargs: Any) -> OptimizeResult:
    """``optimize_plan`` on the paper's maneuver (derived model), memoised per arguments."""
    key = repr(sorted(kwargs.items()))
    if key not in _CACHE:
        goal = kwargs.pop("goal", GOAL)
        _CACHE[key] = optimize_plan(PAPER_ROBOT, START, goal, DURATION, **kwargs)
    return _CACHE[key]


def fine(plan: FlatPlan) -> PlanSamples:
    """The plan sampled on the ``FINE`` grid."""
    return plan.sample(plan.grid(FINE))


def peak_rate(s: PlanSamples) -> float:
    """Largest |th1'|, |th2'| of the samples [rad/s]."""
    return float(np.max(np.abs(s.theta_dot[:, 1:])))


def signed_margin(s: PlanSamples) -> Array:
    """sin(th1) th1' at each sample [rad/s] (positive along the paper's maneuver)."""
    return np.asarray(np.sin(s.theta[:, 1]) * s.theta_dot[:, 1])


def check_plan(
    result: OptimizeResult, limits: PlanLimits, goal: tuple[float, ...] = GOAL
) -> PlanSamples:
    """Every limit at every fine-grid sample, exact ends, |H|, and a sane result record."""
    s = fine(result.plan)
    assert np.all(np.isfinite(s.theta)) and np.all(np.isfinite(s.theta_dot))
    for i in range(3):
        assert np.max(np.abs(s.theta[:, i])) <= limits.angle_limit[i]
    assert peak_rate(s) <= limits.rate_limit
    assert np.min(signed_margin(s)) >= limits.min_margin
    H = momentum(PAPER_ROBOT.links, *s.theta.T, *s.theta_dot.T)
    assert np.max(np.abs(H)) < MOMENTUM_BOUND
    np.testing.assert_allclose(s.theta[0], START, rtol=0, atol=BOUNDARY_TOL)
    np.testing.assert_allclose(s.theta[-1], goal, rtol=0, atol=BOUNDARY_TOL)
    assert s.theta_dot[0, 1] == pytest.approx(result.start_rate, abs=EXACT_TOL)
    assert s.theta_dot[-1, 1] == pytest.approx(result.goal_rate, abs=EXACT_TOL)
    assert result.max_violation == 0.0
    assert result.success, result.message
    assert result.iterations > 0 and result.evaluations > 0
    return s
