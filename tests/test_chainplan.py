"""Tests of flatcli.core.plan.planning: N-link plans.

References: for N = 2 the paper's closed-form planner (``planning``, checked against a
sympy derivation and the paper's numbers in tests/test_planning.py); for every N, the angular
momentum from the full link kinematics (``chain.chain_momentum``, which uses none of the
weights h_j the planner plans with) along the plan, the boundary conditions themselves, and a
dense sampling of the margin.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.plan.planning import Plan, plan_chain, plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams

Array = NDArray[np.float64]

#: |H| along a plan from the full kinematics: rounding of sums of terms up to I |rates|
#: (observed <= 3e-14 at rates up to ~100 rad/s for N = 6).
MOMENTUM_BOUND = 1e-11


def example_chain(n: int) -> RobotParams:
    """A chain of n joints: a heavy base, equal links, the last one counterweighted onto its
    joint (d_N = 0) with a large inertia (it must absorb the momentum)."""
    return RobotParams(mass=[2.0] + [1.0] * (n - 1) + [0.6],
                       inertia=[0.08] + [0.03] * (n - 1) + [0.2],
                       length=[0.3] + [0.25] * n, com=[0.12] + [0.1] * (n - 1) + [0.0])


def example_plan(n: int, goal_rate: float = 0.5) -> Plan:
    start = np.r_[0.0, 1.0, np.full(n - 1, 0.3)]
    goal = np.r_[0.4, 2.0, np.full(n - 1, 0.6)]
    start[-1] = goal[-1] = 0.0
    return plan_chain(example_chain(n), start, goal, np.full(n - 1, 0.3),
                      np.full(n - 1, goal_rate), 2.0)


def test_two_links_is_the_papers_plan() -> None:
    paper = plan_point_to_point(PAPER_ROBOT, [1.8, 1.0, 0.0], [1.2, 2.0, 0.0], 0.1, 0.5, 2.0)
    chain = plan_chain(PAPER_ROBOT, [1.8, 1.0, 0.0], [1.2, 2.0, 0.0], [0.1], [0.5], 2.0)
    t = np.linspace(0.0, 2.0, 401)
    a, b = paper.sample(t), chain.sample(t)
    np.testing.assert_allclose(b.theta, a.theta, atol=1e-12)
    np.testing.assert_allclose(b.theta_dot, a.theta_dot, atol=1e-11)
    np.testing.assert_allclose(b.margin, a.margin, atol=1e-14)
    np.testing.assert_allclose(b.u_dot, a.u_dot, atol=1e-11)
    assert chain.input_energy() == pytest.approx(paper.input_energy(), rel=1e-12)


@pytest.mark.parametrize("n", [3, 4, 5, 6])
def test_plans_conserve_momentum_and_meet_their_ends(n: int) -> None:
    plan = example_plan(n)
    s = plan.sample(plan.grid(2001))
    assert np.max(np.abs(s.momentum)) <= MOMENTUM_BOUND
    start = np.r_[0.0, 1.0, np.full(n - 1, 0.3)]
    goal = np.r_[0.4, 2.0, np.full(n - 1, 0.6)]
    start[-1] = goal[-1] = 0.0
    np.testing.assert_allclose(s.theta[0], start, atol=1e-10)
    np.testing.assert_allclose(s.theta[-1], goal, atol=1e-10)
    np.testing.assert_allclose(s.theta_dot[0, 1:n], 0.3, atol=1e-12)
    np.testing.assert_allclose(s.theta_dot[-1, 1:n], 0.5, atol=1e-12)
    # rates are the exact derivatives of the angles (central differences, step 1e-3 s)
    t = np.array([0.5, 1.0, 1.5])
    up, down, mid = plan.sample(t + 1e-5), plan.sample(t - 1e-5), plan.sample(t)
    np.testing.assert_allclose((up.theta - down.theta) / 2e-5, mid.theta_dot, rtol=1e-6,
                               atol=1e-6)
    assert np.all(s.margin > 0)


def test_energy_is_the_integral_of_the_squared_joint_rates() -> None:
    plan = example_plan(3)
    t = np.linspace(0.0, 2.0, 200_001)
    rates = plan.sample(t).theta_dot[:, 1:]
    f = np.sum(rates**2, axis=1)
    trapezoid = float(np.sum((f[1:] + f[:-1]) * np.diff(t)) / 2)
    assert plan.input_energy() == pytest.approx(trapezoid, rel=1e-7)


def test_a_plan_through_the_singular_set_is_refused() -> None:
    """The goal rates against the start's: dh_0/dt must change sign inside the maneuver;
    the refusal names the time, which a dense sampling of the margin brackets."""
    with pytest.raises(FlatcliError, match=r"plan: the margin .* is zero at t = ") as info:
        example_plan(3, goal_rate=-0.5)
    # the same curve, built without the check, samples a sign change at the named time
    from flatcli.core.plan.planning import min_acceleration_trajectory

    plan = example_plan(3)
    curve = min_acceleration_trajectory(
        plan.trajectory.basis,
        plan.model.boundary([0.0, 1.0, 0.3, 0.0], [0.4, 2.0, 0.6, 0.0], [0.3, 0.3],
                            [-0.5, -0.5]))
    crossing = Plan(plan.robot, plan.model, curve, 2.0)
    t = np.linspace(0.0, 2.0, 20_001)
    sigma = crossing.signed_margin(t)
    flips = t[np.flatnonzero(np.sign(sigma[:-1]) != np.sign(sigma[1:]))]
    named = float(str(info.value).split("t = ")[1].split(" s")[0])
    assert flips.size >= 1 and abs(flips[0] - named) < 1e-3


def test_designs_and_ends_are_checked() -> None:
    with pytest.raises(FlatcliError, match="com\\[3\\] = d3"):
        plan_chain(example_chain(3).with_(com=[0.12, 0.1, 0.1, 0.01]), [0, 1, 0.3, 0],
                   [0.4, 2, 0.6, 0], [0.3, 0.3], [0.5, 0.5], 2.0)
    with pytest.raises(FlatcliError, match=r"plan\.start: expected 4 angles"):
        plan_chain(example_chain(3), [0, 1, 0.3], [0.4, 2, 0.6, 0], [0.3, 0.3], [0.5, 0.5], 2.0)
    with pytest.raises(FlatcliError, match=r"plan\.goal_rate: expected 2 rates"):
        plan_chain(example_chain(3), [0, 1, 0.3, 0], [0.4, 2, 0.6, 0], [0.3, 0.3], [0.5], 2.0)
    with pytest.raises(FlatcliError, match=r"plan\.start_rate: the margin"):
        plan_chain(example_chain(3), [0, 1, 0.3, 0], [0.4, 2, 0.6, 0], [0.0, 0.0], [0.5, 0.5],
                   2.0)
