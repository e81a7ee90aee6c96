"""Tests of flatcli.core.optimize.problem: the programme, its exact gradients, ``Request``.

References: ``Plan.input_energy`` (the plan's energy computed by planning) and central
finite differences of the problem's own values.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from optimize_support import DURATION, GOAL, START

from flatcli.core.models.flatmodel import flat_model
from flatcli.core.optimize import TUNING, PlanLimits, default_basis
from flatcli.core.optimize.affine import affine_map
from flatcli.core.optimize.feasibility import Ends
from flatcli.core.optimize.limits import limit_rows
from flatcli.core.optimize.problem import Problem, Request
from flatcli.core.optimize.quantities import MARGIN, RATES
from flatcli.core.plan.planning import FlatTrajectory, Plan
from flatcli.core.robots.params import PAPER_ROBOT

#: Identities that hold to rounding.
EXACT_TOL = 1e-12
#: Central differences at step 1e-6 (relative to max(1, |x_j|)): truncation ~1e-12 x third
#: derivative, rounding ~1e-16 / 1e-6 x value; observed < 1e-7 relative.
FD_STEP = 1e-6
FD_RTOL = 1e-6

K = flat_model(PAPER_ROBOT)  # the paper's closed form


def request(samples: int = 21) -> Request:
    """The paper's maneuver with guesses th1'(0) = 0.2, th1'(T) = 0.4 rad/s."""
    times = np.linspace(0.0, DURATION, samples)
    return Request(
        K, default_basis(DURATION), np.array(START), np.array(GOAL), Ends(1.0, 0.2, 0.4),
        DURATION, True, times, np.linspace(0.0, DURATION, 10 * (samples - 1) + 1), TUNING,
    )  # fmt: skip


def test_gradients_against_central_differences() -> None:
    """The exact gradients chained through the affine coefficient map."""
    limits = PlanLimits(angle_limit=(3.0, 3.0, 3.0), rate_limit=5.0)
    basis = default_basis(DURATION)
    start, goal = np.array(START), np.array(GOAL)
    affine, x0 = affine_map(K, basis, start, goal, 0.2, 0.4, True, False)
    grid = np.linspace(0.0, DURATION, 21)
    rows = limit_rows(limits, "energy", TUNING.backoff)
    problem = Problem(K, affine, rows, "energy", 1.0, DURATION, grid, grid, TUNING)
    trajectory = FlatTrajectory(basis, affine.coefficients(x0))
    plan = Plan(PAPER_ROBOT, K, trajectory, DURATION)
    assert problem.energy(x0) == pytest.approx(plan.input_energy(), rel=EXACT_TOL)
    gradient = problem.energy_gradient(x0)
    jac = problem.row_jacobian(x0).reshape(-1, x0.size)
    for j in range(x0.size):
        h = FD_STEP * max(1.0, abs(x0[j]))
        up, down = x0.copy(), x0.copy()
        up[j] += h
        down[j] -= h
        fd = (problem.energy(up) - problem.energy(down)) / (2 * h)
        assert gradient[j] == pytest.approx(fd, rel=FD_RTOL, abs=FD_RTOL)
        fd_rows = (problem.row_values(up) - problem.row_values(down)).ravel() / (2 * h)
        scale = np.abs(jac[:, j]) + 1.0
        np.testing.assert_allclose(jac[:, j] / scale, fd_rows / scale, rtol=0, atol=FD_RTOL)


def test_objectives_and_their_gradients() -> None:
    """fun/jac of each goal: energy, T x energy, and the epigraph variable (signed)."""
    r = request()
    curve = r.start_curve()
    energy = r.problem("energy", PlanLimits())
    effort = r.problem("effort", PlanLimits())
    assert effort.fun(curve) == pytest.approx(DURATION * energy.fun(curve), rel=EXACT_TOL)
    np.testing.assert_allclose(effort.jac(curve), DURATION * energy.jac(curve), rtol=EXACT_TOL)
    for goal, sign in (("peak_rate", 1.0), ("margin", -1.0), ("violation", 1.0)):
        problem = r.problem(goal, PlanLimits(rate_limit=5.0))
        x = problem.lift(curve)
        problem.normalise(2.0)
        assert problem.fun(x) == sign * x[-1] / 2.0
        np.testing.assert_array_equal(problem.jac(x), np.eye(x.size)[-1] * sign / 2.0)


def test_lift_sets_the_epigraph_variable() -> None:
    """Where its rows hold with equality on the constraint grid."""
    r = request()
    curve = r.start_curve()
    plain = r.problem("energy", PlanLimits()).values(curve, "grid")
    peak = r.problem("peak_rate", PlanLimits())
    assert peak.lift(curve)[-1] == np.max(np.abs(plain[list(RATES)]))
    assert r.problem("margin", PlanLimits()).lift(curve)[-1] == np.min(plain[MARGIN])
    # phase 1: the largest relative excess over the rate limit, (peak - R) / max(1, R)
    violation = r.problem("violation", PlanLimits(rate_limit=5.0))
    x = violation.lift(curve)
    expected = (np.max(np.abs(plain[list(RATES)])) - 5.0 * (1 - TUNING.backoff)) / 5.0
    assert x[-1] == pytest.approx(expected, rel=1e-12)
    assert np.min(violation.row_values(x)[:-1]) == pytest.approx(0.0, abs=1e-12)
    assert r.problem("energy", PlanLimits()).lift(curve) is curve


def test_bounds_from_the_request() -> None:
    """Free end rates above the margin's minimum and within the rate limit; the epigraph
    variable >= 0 (peak, violation) or <= the margin's mean (margin)."""
    r = request()
    limits = PlanLimits(rate_limit=5.0, min_margin=0.1)
    low = (0.1 / math.sin(1.0), 0.1 / math.sin(2.0))
    energy = r.problem("energy", limits)
    assert energy.bounds[0] == (pytest.approx(low[0]), 5.0)
    assert energy.bounds[1] == (pytest.approx(low[1]), 5.0)
    assert set(energy.bounds[2:]) == {(None, None)}
    assert r.problem("peak_rate", limits).bounds[-1] == (0.0, None)
    mean = (math.cos(1.0) - math.cos(2.0)) / DURATION
    assert r.problem("margin", limits).bounds[-1] == (None, pytest.approx(mean))


def test_screening_keeps_the_margin_rows() -> None:
    """Rows far from their limits are left out of a solve; margin rows never."""
    r = request()
    problem = r.problem("energy", PlanLimits(rate_limit=1e3, angle_limit=(9.0, 9.0, 9.0)))
    problem.prepare(r.start_curve())
    margin = problem.rows.quantity == MARGIN
    assert problem.mask[margin].all() and not problem.mask[~margin].any()
    assert problem.cons(r.start_curve()).size == problem.times.size


def test_values_cached_per_decision_vector() -> None:
    r = request()
    problem = r.problem("energy", PlanLimits())
    x = r.start_curve()
    first = problem.values(x, "grid")
    assert problem.values(x.copy(), "grid") is first and problem.evaluations == 1
    problem.values(x + 1e-3, "grid")
    assert problem.evaluations == 2


def test_adopt_takes_over_the_shared_rows() -> None:
    """A looser problem's grid and tightened offsets carry over to the rows both have."""
    r = request()
    loose = r.problem("energy", PlanLimits(min_margin=0.05))
    loose.b[-1] -= 1e-3  # as an exchange round tightens the margin row
    loose.set_times(np.append(loose.times, 0.123))
    tight = r.problem("energy", PlanLimits(rate_limit=5.0, min_margin=0.05))
    before = tight.b.copy()
    tight.adopt(loose)
    assert 0.123 in tight.times and tight.times.size == r.times.size + 1
    assert tight.b[-1] == loose.b[-1]  # the margin row
    np.testing.assert_array_equal(tight.b[:-1], before[:-1])  # the rate rows, its own
