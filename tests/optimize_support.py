"""Shared helpers of the tests of ``flatcli.core.optimize`` (tests/test_optimize_*.py).

``optimize_paper`` runs ``optimize_plan`` on the paper's maneuver (Franch et al. 2003,
Sec. VI: th(0) = (1.8, 1, 0), th(2) = (1.2, 2, 0), T = 2 s, the paper's robot), memoised for
the whole test session (results are immutable); ``check_plan`` checks an optimised plan
against its limits, the full kinematics and its ends on a grid the optimiser never saw.

``optimize_chain`` does the same for the example chain of N >= 3 joints of
``tests/test_chainplan.py`` (start (0, 1, 0.3.., 0), goal (0.4, 2, 0.6.., 0), T = 2 s);
``check_chain_plan`` checks its plans against the full link kinematics
(``chain.chain_momentum``) on a dense grid: H = 0, rates that are the angles' derivatives,
the ends, every limit, and the margin -(dh_0/dt) / (2 K_10) with h_0 read off the momentum
(the coefficient of th0') and K_10 from its defining sum (``chain``'s docstring).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.integrate import simpson
from test_chainplan import example_chain

from flatcli.core.optimize import TUNING, OptimizeResult, PlanLimits, optimize_plan
from flatcli.core.plan.planning import Plan, PlanSamples
from flatcli.core.robots.chain import chain_momentum
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams, momentum

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


def fine(plan: Plan) -> PlanSamples:
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
    assert peak_rate(s) <= min(limits.rate_of(1), limits.rate_of(2))
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


# --- chains of N >= 3 joints ---------------------------------------------------------------

#: Dense grid for the chain checks (the optimiser's check grid has at most 2001 times).
CHAIN_FINE = 4001
#: |H| of a chain's plan from the full link kinematics [kg m^2/s]: rounding of terms of order
#: 1 through the inverse flat map.
CHAIN_MOMENTUM_BOUND = 1e-11
#: Rates against second-order differences of the sampled angles (step T / 4000): truncation
#: ~h^2 / 6 x the third derivative, which is large for th0 and th_N (their rates contain
#: y''); observed 2.6e-4 of the largest rate.
FD_RATE_TOL = 1e-3
#: The ends, through the inverse map (rounding amplified where the margin is small).
CHAIN_BOUNDARY_TOL = 1e-9

_CHAIN_CACHE: dict[str, OptimizeResult] = {}


def chain_ends(n: int) -> tuple[Array, Array]:
    """The example maneuver of ``tests/test_chainplan.py`` for n joints (N + 1,) [rad]."""
    start = np.r_[0.0, 1.0, np.full(n - 1, 0.3)]
    goal = np.r_[0.4, 2.0, np.full(n - 1, 0.6)]
    start[-1] = goal[-1] = 0.0
    return start, goal


def optimize_chain(n: int, **kwargs: Any) -> OptimizeResult:
    """``optimize_plan`` on the example chain of n joints, memoised per arguments."""
    key = repr((n, sorted(kwargs.items())))
    if key not in _CHAIN_CACHE:
        start, goal = chain_ends(n)
        _CHAIN_CACHE[key] = optimize_plan(example_chain(n), start, goal, DURATION, **kwargs)
    return _CHAIN_CACHE[key]


def k10(robot: RobotParams) -> float:
    """K_10 = sum_i m_i L_i1 L_i0 - (sum_i m_i L_i1)(sum_i m_i L_i0) / M, L_ia = l_a (a < i),
    d_a (a = i), 0 (a > i) (``chain``'s docstring) [kg m^2]."""
    m = np.asarray(robot.mass, dtype=float)
    length, com = np.asarray(robot.length, dtype=float), np.asarray(robot.com, dtype=float)
    idx = np.arange(m.size)
    lever = [np.where(idx > a, length[a], np.where(idx == a, com[a], 0.0)) for a in (0, 1)]
    return float(m @ (lever[1] * lever[0]) - (m @ lever[1]) * (m @ lever[0]) / m.sum())


def _momentum(robot: RobotParams, theta: Array, theta_dot: Array) -> Array:
    mass, inertia, length, com = (np.asarray(v, dtype=float) for v in
                                  (robot.mass, robot.inertia, robot.length, robot.com))
    return np.asarray(chain_momentum(mass, inertia, length, com, theta, theta_dot))


def base_inertia_h0(robot: RobotParams, theta: Array) -> Array:
    """h_0 at each row of theta (n, N + 1): H of the full link kinematics at th0' = 1 and
    the joints still [kg m^2]."""
    e0 = np.zeros_like(theta)
    e0[:, 0] = 1.0
    return _momentum(robot, theta, e0)


def chain_margin(robot: RobotParams, t: Array, theta: Array) -> Array:
    """-(dh_0/dt) / (2 K_10) along sampled angles, dh_0/dt by second-order differences of
    h_0 (``np.gradient``) [rad/s]."""
    h0 = base_inertia_h0(robot, theta)
    return np.asarray(-np.gradient(h0, t, edge_order=2) / (2.0 * k10(robot)))


def check_chain_plan(result: OptimizeResult, n: int, limits: PlanLimits | None = None
                     ) -> PlanSamples:
    """A chain's optimised plan on ``CHAIN_FINE`` times: the full link kinematics, the ends
    and end rates, every limit, one sign of the margin; returns the samples."""
    limits = PlanLimits() if limits is None else limits
    plan = result.plan
    assert isinstance(plan, Plan) and plan.n_joints == n
    robot, (start, goal) = plan.robot, chain_ends(n)
    t = plan.grid(CHAIN_FINE)
    s = plan.sample(t)
    assert np.all(np.isfinite(s.theta)) and np.all(np.isfinite(s.theta_dot))
    assert np.max(np.abs(_momentum(robot, s.theta, s.theta_dot))) < CHAIN_MOMENTUM_BOUND
    fd = np.gradient(s.theta, t, axis=0, edge_order=2)
    scale = float(np.max(np.abs(s.theta_dot)))
    np.testing.assert_allclose(fd, s.theta_dot, rtol=0, atol=FD_RATE_TOL * scale)
    np.testing.assert_allclose(s.theta[0], start, rtol=0, atol=CHAIN_BOUNDARY_TOL)
    np.testing.assert_allclose(s.theta[-1], goal, rtol=0, atol=CHAIN_BOUNDARY_TOL)
    np.testing.assert_allclose(s.theta_dot[0, 1:n], result.start_rates, rtol=0, atol=EXACT_TOL)
    np.testing.assert_allclose(s.theta_dot[-1, 1:n], result.goal_rates, rtol=0, atol=EXACT_TOL)
    assert (result.start_rate, result.goal_rate) == (result.start_rates[0], result.goal_rates[0])
    for i, bound in enumerate(limits.for_joints(n).angle_limit):
        assert np.max(np.abs(s.theta[:, i])) <= bound
    for j in range(1, n + 1):
        assert np.max(np.abs(s.theta_dot[:, j])) <= limits.rate_of(j)
    margin = chain_margin(robot, t, s.theta)
    sign = np.sign(margin[CHAIN_FINE // 2])
    # one sign throughout, >= min_margin up to the differences' error
    assert np.min(sign * margin) >= limits.min_margin * (1 - 1e-3)
    assert result.max_violation == 0.0
    return s


def chain_energy(s: PlanSamples) -> float:
    """Integral of the sum of squared joint rates th1'..thN' by Simpson's rule on the samples
    [rad^2/s]."""
    return float(simpson(np.sum(s.theta_dot[:, 1:] ** 2, axis=1), x=s.t))
