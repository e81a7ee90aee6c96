"""Tests of flatcli.core.optimize.solver: SLSQP inside the exchange method."""

from __future__ import annotations

import numpy as np
import pytest
from optimize_support import DURATION, GOAL, START

from flatcli.core.models.flatmodel import flat_model
from flatcli.core.optimize import TUNING, PlanLimits, Tuning, default_basis
from flatcli.core.optimize.assessment import assess
from flatcli.core.optimize.feasibility import Ends
from flatcli.core.optimize.problem import Request
from flatcli.core.optimize.solver import exchange_times, solve
from flatcli.core.robots.params import PAPER_ROBOT

K = flat_model(PAPER_ROBOT)  # the paper's closed form


def request(samples: int = 41, tuning: Tuning = TUNING) -> Request:
    """The paper's maneuver, default basis, guesses th1'(0) = 0.1, th1'(T) = 0.5 rad/s."""
    return Request(
        K, default_basis(DURATION), np.array(START), np.array(GOAL), Ends(1.0, 0.1, 0.5),
        DURATION, True, np.linspace(0.0, DURATION, samples),
        np.linspace(0.0, DURATION, 10 * (samples - 1) + 1), tuning,
    )  # fmt: skip


def test_exchange_times_are_the_violated_local_maxima() -> None:
    check = np.linspace(0.0, 1.0, 11)
    excess = np.array(
        [
            [-1, -1, 0.5, 1.0, 0.5, -1, -1, -1, 0.2, -1, 2.0],  # peaks at 0.3, 0.8, 1.0
            [-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1],  # met everywhere
            [3.0, 1.0, -1, -1, -1, -1, -1, -1, -1, -1, -1],  # peak at 0.0
        ]
    )
    np.testing.assert_allclose(exchange_times(excess, check), [0.0, 0.3, 0.8, 1.0])
    assert exchange_times(-np.ones((2, 11)), check).size == 0


def test_solve_meets_every_limit_on_the_check_grid() -> None:
    """A rate limit the start (peak |th2'| 48.8 rad/s) violates and the optimum binds: the
    exchange rounds add times to the constraint grid until the check grid meets it."""
    r = request()
    limits = PlanLimits(rate_limit=3.9)
    problem = r.problem("energy", limits)
    curve = r.start_curve()
    problem.normalise(problem.energy(curve))
    assert not assess(problem, curve, limits).feasible
    found = solve(problem, curve, limits, 300)
    final = assess(problem, found.x, limits)
    assert final.feasible, final.worst
    assert final.objective < problem.energy(curve) / 3
    assert problem.times.size > r.times.size  # the exchange added times
    assert found.iterations > 0 and found.evaluations > 0
    assert found.converged, found.message


def test_never_worse_than_a_feasible_start() -> None:
    """Cut off after one iteration, the point returned is no worse than the start."""
    r = request()
    limits = PlanLimits()
    problem = r.problem("energy", limits)
    curve = r.start_curve()
    problem.normalise(problem.energy(curve))
    start = assess(problem, curve, limits)
    assert start.feasible
    found = solve(problem, curve, limits, 1)
    assert assess(problem, found.x, limits).objective <= start.objective
    assert not found.converged


@pytest.mark.parametrize("rounds", [1, 3])
def test_rounds_are_bounded_by_the_tuning(rounds: int) -> None:
    """Each round is one SLSQP run of at most max_iter iterations."""
    r = request(tuning=Tuning(exchange_rounds=rounds))
    limits = PlanLimits(rate_limit=3.9)
    problem = r.problem("energy", limits)
    curve = r.start_curve()
    problem.normalise(problem.energy(curve))
    found = solve(problem, curve, limits, 5)
    assert found.iterations <= 5 * rounds
