"""Tests of flatcli.core.optimize.feasibility: the up-front checks and ``required_fold``.

References on the paper's maneuver (Franch et al. 2003, Sec. VI):

* the largest possible least margin, (cos th1(0) - cos th1(T)) / T = 0.4782 rad/s: the
  margin is -d(cos th1)/dt, so this is its mean over [0, T];
* th2 must reach 2.672 rad (``required_fold``): checked against the momentum balance of an
  optimised plan, integrated along it by the trapezoid rule (independent of the
  Gauss-Legendre integrals over th1 in ``required_fold``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from optimize_support import DURATION, GOAL, START, fine, optimize_paper

from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import flat_model
from flatcli.core.models.flatness import chart
from flatcli.core.optimize import PlanLimits, optimize_plan, required_fold
from flatcli.core.optimize.feasibility import Ends, check_ends, end_rate_bounds
from flatcli.core.robots.params import PAPER_ROBOT

#: Where th2 must reach on this maneuver [rad] (``required_fold``, 4 digits; the test
#: below checks it against an optimised plan's own momentum balance).
FOLD = 2.672
K = flat_model(PAPER_ROBOT)  # the paper's closed form


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (
            {"limits": PlanLimits(angle_limit=(math.inf, math.inf, 1.5))},
            r"plan\.optimize\.angle_limit\[2\] = 1\.5 rad cannot be met: momentum "
            r"conservation forces th2 to reach 2\.672 rad",
        ),
        (
            {"limits": PlanLimits(rate_limit=2.0)},
            r"plan\.optimize\.rate_limit = 2 rad/s cannot be met: .* 2\.672 rad/s on average",
        ),
        (
            {"limits": PlanLimits(rate_limit=0.4)},
            r"plan\.optimize\.rate_limit = 0\.4 rad/s cannot be met: th1 must move 1 rad in 2 s",
        ),
        (
            {"limits": PlanLimits(angle_limit=(1.5, math.inf, math.inf))},
            r"plan\.optimize\.angle_limit\[0\] = 1\.5 rad cannot be met: the start "
            r"configuration has \|th0\| = 1\.8 rad",
        ),
        (
            {"limits": PlanLimits(min_margin=0.5)},
            r"plan\.optimize\.min_margin = 0\.5 rad/s cannot be met: .* averages .* = 0\.4782",
        ),
        (
            {"free_rates": False, "start_rate": 0.01},
            r"plan\.optimize\.min_margin = 0\.02 rad/s cannot be met: the fixed "
            r"plan\.start_rate = 0\.01 rad/s gives a margin of 0\.008415",
        ),
        (
            {"free_rates": False, "limits": PlanLimits(rate_limit=3.0), "goal_rate": 3.5},
            r"plan\.optimize\.rate_limit = 3 rad/s cannot be met: plan\.goal_rate = 3\.5",
        ),
        (
            {"free_rates": False, "goal_rate": -0.5},
            r"th1' must cross 0",
        ),
        (
            {"limits": PlanLimits(min_margin=0.2, rate_limit=3.5), "goal": (1.2, 3.1, 0.0)},
            r"plan\.optimize\.min_margin = 0\.2 rad/s cannot be met within "
            r"plan\.optimize\.rate_limit = 3\.5 rad/s at the goal",
        ),
        ({"goal": (1.2, 4.0, 0.0)}, r"plan\.goal\[1\] = 4 rad: th1 would have to cross"),
        ({"goal": (1.2, 1.0, 0.0)}, r"plan\.goal\[1\] equals plan\.start\[1\]"),
    ],
    ids=[
        "th2-fold",
        "th2-rate",
        "th1-rate",
        "start-angle",
        "margin-mean",
        "fixed-rate-margin",
        "fixed-rate-limit",
        "fixed-rate-sign",
        "margin-vs-rate",
        "crosses-pi",
        "no-th1-travel",
    ],
)
def test_infeasible_up_front(kwargs: dict[str, Any], match: str) -> None:
    """Refused before any solve, in one line naming the spec key."""
    goal = kwargs.pop("goal", GOAL)
    with pytest.raises(FlatcliError, match=match) as info:
        optimize_plan(PAPER_ROBOT, START, goal, DURATION, **kwargs)
    assert "\n" not in str(info.value)


def test_ends_of_a_feasible_request() -> None:
    """The margin's sign, and free end-rate guesses pointed and clipped into range."""
    limits = PlanLimits(min_margin=0.2, rate_limit=5.0)
    start, goal = np.array(START), np.array(GOAL)
    ends = check_ends(K, start, goal, -0.1, 9.0, DURATION, limits, True, 1e-3)
    low = 0.2 / math.sin(1.0)  # the margin's minimum |th1'| at the start
    assert ends == Ends(1.0, pytest.approx(low * (1 + 1e-3)), 5.0)
    # th1 moving down on (0, pi): the margin sin(th1) th1' is negative, sigma = -1
    down = check_ends(K, goal, start, 0.1, 0.5, DURATION, PlanLimits(), True, 1e-3)
    assert (down.sigma, down.start_rate, down.goal_rate) == (-1.0, -0.1, -0.5)
    fixed = check_ends(K, start, goal, 0.3, 0.4, DURATION, limits, False, 1e-3)
    assert (fixed.start_rate, fixed.goal_rate) == (0.3, 0.4)


def test_end_rate_bounds() -> None:
    limits = PlanLimits(min_margin=0.2, rate_limit=5.0)
    low = 0.2 / math.sin(1.0)
    assert end_rate_bounds(np.array(START), limits, 0.3) == (pytest.approx(low), 5.0)
    assert end_rate_bounds(np.array(START), limits, -0.3) == (-5.0, pytest.approx(-low))
    assert end_rate_bounds(np.array(START), PlanLimits(), 1.0)[1] is None


def test_required_fold() -> None:
    """th2 must reach 2.672 rad; the optimised plan's own momentum balance agrees."""
    v = required_fold(K, START, GOAL)
    assert v == pytest.approx(FOLD, abs=5e-4)
    assert required_fold(K, START, (1.2, 1.0, 0.0)) == 0.0
    s = fine(optimize_paper().plan)
    assert np.max(s.theta[:, 2]) >= v
    # the identity behind the bound: integral of h th2 dth1 = integral of g dth1 - dy2
    _, g, h = chart(K.coefficients, np.cos(s.y[:, 0]), np.sin(s.y[:, 0]))
    dt = s.t[1] - s.t[0]
    lhs = np.trapezoid(h * s.theta[:, 2] * s.y_dot[:, 0], dx=dt)
    rhs = np.trapezoid(g * s.y_dot[:, 0], dx=dt) - (s.y[-1, 1] - s.y[0, 1])
    assert lhs == pytest.approx(rhs, rel=1e-5)
    assert v == pytest.approx(rhs / np.trapezoid(h * s.y_dot[:, 0], dx=dt), rel=1e-5)
