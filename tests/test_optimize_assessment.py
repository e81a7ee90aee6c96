"""Tests of flatcli.core.optimize.assessment: candidates measured on the check grid.

Reference: the paper's cubic (Franch et al. 2003, Sec. VI; ``conftest.paper_plan``) sampled
by ``Plan.sample`` on the same check grid.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from optimize_support import DURATION, GOAL, START

from flatcli.core.curves.basis import PolynomialBasis
from flatcli.core.models.flatmodel import flat_model
from flatcli.core.optimize import TUNING, PlanLimits
from flatcli.core.optimize.assessment import active_limits, assess
from flatcli.core.optimize.feasibility import Ends
from flatcli.core.optimize.problem import Request
from flatcli.core.plan.planning import Plan
from flatcli.core.robots.params import PAPER_ROBOT

K = flat_model(PAPER_ROBOT)  # the paper's closed form


def cubic_request() -> Request:
    """The paper's maneuver in a cubic basis, guesses 0.1 and 0.5 rad/s: the paper's cubic."""
    return Request(
        K, PolynomialBasis(3, DURATION), np.array(START), np.array(GOAL), Ends(1.0, 0.1, 0.5),
        DURATION, True, np.linspace(0.0, DURATION, 21), np.linspace(0.0, DURATION, 201),
        TUNING,
    )  # fmt: skip


def test_the_cubic_against_a_rate_limit(paper_plan: Plan) -> None:
    r = cubic_request()
    s = paper_plan.sample(r.check)
    peak = float(np.max(np.abs(s.theta_dot[:, 1:])))
    j = int(np.argmax(np.abs(s.theta_dot[:, 2])))
    limits = PlanLimits(rate_limit=20.0)
    found = assess(r.problem("energy", limits), r.start_curve(), limits)
    assert not found.feasible
    assert found.max_violation == pytest.approx(peak - 20.0, rel=1e-9)
    assert found.relative_violation == pytest.approx((peak - 20.0) / 20.0, rel=1e-9)
    assert found.objective == pytest.approx(paper_plan.input_energy(), rel=1e-9)
    assert found.worst == (
        f"plan.optimize.rate_limit = 20 rad/s cannot be met: the best plan found reaches "
        f"|th2'| = {peak:.4g} rad/s at t = {r.check[j]:.3f} s"
    )
    # the excess of each row at each check time: positive exactly where the cubic is past
    excess = found.row_excess[[2, 3]]  # th2' <= 20 and -th2' <= 20
    np.testing.assert_array_equal(np.max(excess, axis=0) > 0, np.abs(s.theta_dot[:, 2]) > 20.0)


def test_objectives_on_the_check_grid(paper_plan: Plan) -> None:
    r = cubic_request()
    s = paper_plan.sample(r.check)
    curve = r.start_curve()
    for goal, expected in (
        ("peak_rate", np.max(np.abs(s.theta_dot[:, 1:]))),
        ("margin", np.min(np.sin(s.theta[:, 1]) * s.theta_dot[:, 1])),
        ("effort", DURATION * paper_plan.input_energy()),
    ):
        problem = r.problem(goal, PlanLimits())
        found = assess(problem, problem.lift(curve), PlanLimits())
        assert found.feasible and found.worst == ""
        assert found.objective == pytest.approx(expected, rel=1e-9)


def test_active_limits() -> None:
    """A margin limit equal to the cubic's margin at t = 0 (sin(1) 0.1, the paper's start
    rate) is active there only; a loose rate limit never."""
    r = cubic_request()
    limits = PlanLimits(rate_limit=60.0, min_margin=math.sin(1.0) * 0.1)
    problem = r.problem("energy", limits)
    assert active_limits(problem, r.start_curve()) == ("min_margin at t=0.00 s",)
    assert active_limits(r.problem("energy", PlanLimits()), r.start_curve()) == ()
