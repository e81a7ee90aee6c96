"""Tests of the task core: flatcli.core.robots.kinematics, inverse, rest, intervals and clearance.

Referees: the links placed in the complex plane from their definitions with the centre of
mass solved for (tests/task_referees.py), sympy's H of the three-link robot
(tests/referees.py::link_momentum), scipy's DOP853 at rtol 1e-12 on the momentum constraint
written from the complex kinematics, and dense sampling 100x finer than the checks' own grid.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core.errors import FlatcliError
from flatcli.core.plan import intervals as iv
from flatcli.core.plan.clearance import Constraints, certify, sampled_slack
from flatcli.core.plan.intervals import Interval
from flatcli.core.plan.inverse import BOUNDARY_TOL, redundant_task, task_configuration, two_link
from flatcli.core.plan.planning import plan_point_to_point
from flatcli.core.plan.rest import plan_rest_to_rest
from flatcli.core.robots.kinematics import (
    base_position,
    end_effector,
    joint_positions,
    reach,
    system_com,
    virtual_links,
)
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams
from tests import task_referees as ref
from tests.referees import link_momentum

Array = NDArray[np.float64]

#: Positions from two ways of summing the same few terms of size <= 0.5 m.
POSITION_TOL = 1e-15 * 8
#: The inverse kinematics' own acceptance tolerance (flatcli.core.plan.inverse.IK_TOL) plus the
#: rounding of the referee's sums.
IK_CHECK = 1e-12 + 1e-15
#: H along a plan from the referee's kinematics: rounding of terms up to I |rates|.
MOMENTUM_BOUND = 1e-13
CHAIN4 = RobotParams(mass=(2.0, 1.0, 1.0, 0.5), inertia=(0.1, 0.0533, 0.0533, 0.15),
                     length=(0.3, 0.2, 0.2, 0.2), com=(0.1, 0.1, 0.1, 0.0))  # robots/chain4
START = np.array([1.8, 1.0, 0.0])  # the paper's maneuver, Sec. VI
GOAL = np.array([1.2, 2.0, 0.0])


#: A paper robot as built: its last link's centre of mass 2 cm off the joint, 1 cm across.
AS_BUILT = RobotParams(mass=(1.0, 1.0, 1.0), inertia=(0.0533, 0.0533, 0.0533),
                       length=(0.2, 0.2, 0.2), com=(0.1, 0.1, 0.02), com_across=0.01)


@pytest.mark.parametrize("robot", [PAPER_ROBOT, CHAIN4, AS_BUILT])
def test_positions_equal_the_complex_kinematics(robot: RobotParams) -> None:
    rng = np.random.default_rng(1)
    theta = rng.uniform(-3, 3, (50, robot.n_joints + 1))
    z = ref.joints(robot, theta)
    points = joint_positions(robot, theta)
    assert np.max(np.abs(points[..., 0] + 1j * points[..., 1] - z)) < POSITION_TOL
    ee = end_effector(robot, theta)
    assert np.max(np.abs(ee[:, 0] + 1j * ee[:, 1] - z[:, -1])) < POSITION_TOL
    c0 = ref.centres(robot, theta)[:, 0]
    base = base_position(robot, theta)
    assert np.max(np.abs(base[:, 0] + 1j * base[:, 1] - c0)) < POSITION_TOL
    assert np.max(np.abs(system_com(robot, theta))) < POSITION_TOL


def test_paper_virtual_links_by_hand() -> None:
    # m = 1, l = 0.2, d = (0.1, 0.1, 0): v_a = l_a - (m_a d_a + sum_{i>a} m_i l_a) / 3
    assert virtual_links(PAPER_ROBOT) == pytest.approx([0.2 - 0.5 / 3, 0.2 - 0.3 / 3, 0.2],
                                                       abs=1e-15)
    assert reach(PAPER_ROBOT) == pytest.approx((0.2 - 0.1 - 0.2 / 6, 1.0 / 3), abs=1e-15)


@pytest.mark.parametrize("th0", [1.2, -0.4])
def test_two_link_branches_reach_the_target(th0: float) -> None:
    target = ref.end_effector(PAPER_ROBOT, np.array([th0, 1.7, 0.6]))
    up, down = two_link(PAPER_ROBOT, [target.real, target.imag], th0)
    for q in (up, down):
        assert abs(ref.end_effector(PAPER_ROBOT, q) - target) < IK_CHECK
        assert q[0] == th0
    assert up[2] > 0 > down[2]
    assert up[2] == pytest.approx(0.6, abs=1e-12)  # the configuration it came from


def test_task_configuration_picks_the_branch_and_keeps_th1_off_the_singular_set() -> None:
    target = ref.end_effector(PAPER_ROBOT, np.array([1.2, 1.7, 0.6]))
    xy = [target.real, target.imag]
    up = task_configuration(PAPER_ROBOT, xy, 1.2, START, "up")
    down = task_configuration(PAPER_ROBOT, xy, 1.2, START, "down")
    assert up[2] > 0 > down[2]
    for q in (up, down):
        assert abs(ref.end_effector(PAPER_ROBOT, q) - target) < IK_CHECK
        assert 0 < q[1] < math.pi  # the start's side of sin th1 = 0
    auto = task_configuration(PAPER_ROBOT, xy, 1.2, START)
    cost = [float(np.sum((q - START) ** 2)) for q in (up, down)]
    assert np.array_equal(auto, (up, down)[int(np.argmin(cost))])


def test_free_base_attitude_minimises_the_joint_motion() -> None:
    target = ref.end_effector(PAPER_ROBOT, np.array([1.2, 1.7, 0.6]))
    xy = [target.real, target.imag]
    q = task_configuration(PAPER_ROBOT, xy, None, START)
    assert abs(ref.end_effector(PAPER_ROBOT, q) - target) < IK_CHECK
    best = float(np.sum((q - START) ** 2))
    # referee: a brute scan of th0 with both branches at every th0
    for th0 in q[0] + np.linspace(-0.5, 0.5, 201):
        for b in two_link(PAPER_ROBOT, xy, th0):
            b = b.copy()
            b[1:] = START[1:] + np.remainder(b[1:] - START[1:] + math.pi, 2 * math.pi) - math.pi
            if 0 < b[1] < math.pi:
                assert float(np.sum((b - START) ** 2)) >= best - 1e-9


def test_unreachable_and_boundary_targets_are_refused_with_how_far() -> None:
    inner, outer = 0.1, 0.3  # links 1, 2 of the paper's virtual manipulator: 0.1 and 0.2
    v0 = 1.0 / 30.0
    th0 = 0.0
    with pytest.raises(FlatcliError, match=r"task.end_effector: .* unreachable .* 0\.05 m "
                       r"beyond the reach 0\.3 m"):
        task_configuration(PAPER_ROBOT, [v0 + outer + 0.05, 0.0], th0, START)
    with pytest.raises(FlatcliError, match=r"0\.04 m inside the hole"):
        task_configuration(PAPER_ROBOT, [v0 + inner - 0.04, 0.0], th0, START)
    with pytest.raises(FlatcliError, match="on the workspace boundary"):
        task_configuration(PAPER_ROBOT, [v0 + outer - BOUNDARY_TOL / 2, 0.0], th0, START)
    with pytest.raises(FlatcliError, match=r"beyond the reach 0\.333333 m of the virtual "
                       "manipulator"):
        task_configuration(PAPER_ROBOT, [0.0, 0.4], None, START)


def test_target_across_the_singular_set_is_refused() -> None:
    # th1 < 0 on both branches: a monotone th1 from 1 rad cannot get there
    target = ref.end_effector(PAPER_ROBOT, np.array([1.2, -1.0, 0.3]))
    with pytest.raises(FlatcliError, match="across the singular set sin th1 = 0"):
        task_configuration(PAPER_ROBOT, [target.real, target.imag], 1.2, START, "down")


def test_redundant_ik_is_the_least_joint_motion_on_the_constraint() -> None:
    start = np.array([0.0, 1.0, 0.3, 0.0])
    target = ref.end_effector(CHAIN4, np.array([-0.75, 2.0, 0.6, 0.4]))
    q = redundant_task(CHAIN4, [target.real, target.imag], -0.75, start)
    assert abs(ref.end_effector(CHAIN4, q) - target) < IK_CHECK
    assert q[0] == -0.75
    # Lagrange: q - start is normal to the solution set, i.e. in the row space of the
    # referee's Jacobian (central differences of its end effector in th1..th3)
    J = np.array([ref.end_effector(CHAIN4, q + np.eye(4)[k] * 1e-7)
                  - ref.end_effector(CHAIN4, q - np.eye(4)[k] * 1e-7) for k in (1, 2, 3)]) / 2e-7
    rows = np.vstack([J.real, J.imag])  # (2, 3)
    step = (q - start)[1:]
    residual = step - rows.T @ np.linalg.lstsq(rows.T, step, rcond=None)[0]
    assert np.linalg.norm(residual) < 1e-6 * max(1.0, np.linalg.norm(step))


def test_elbow_is_refused_on_a_redundant_robot() -> None:
    with pytest.raises(FlatcliError, match=r'task\.elbow: "up" picks a branch of the two-joint'):
        task_configuration(CHAIN4, [0.1, 0.1], 0.0, np.zeros(4), "up")


# ---------------------------------------------------------------------------------------
# Rest to rest


def test_rest_plan_starts_and_ends_at_rest_and_conserves_h() -> None:
    plan = plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0)
    t = np.linspace(0.0, 2.0, 401)
    s = plan.sample(t)
    assert np.array_equal(s.theta[0], START) and np.array_equal(s.theta[-1], GOAL)
    assert np.all(s.theta_dot[[0, -1]] == 0.0)
    assert np.all(np.isfinite(s.theta)) and np.all(np.isfinite(s.theta_dot))
    # sympy's H from the link kinematics, with the plan's own rates
    h, th, w = link_momentum(PAPER_ROBOT)
    H = sp.lambdify((*th, *w), h, "numpy")
    assert np.max(np.abs(H(*s.theta.T, *s.theta_dot.T))) < MOMENTUM_BOUND
    assert np.max(np.abs(ref.momentum(PAPER_ROBOT, s.theta, s.theta_dot))) < MOMENTUM_BOUND


def test_rest_plan_approaches_rest_continuously() -> None:
    plan = plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0)
    for t, end in ((np.array([1e-6, 1e-5]), START), (np.array([2 - 1e-6, 2 - 1e-5]), GOAL)):
        s = plan.sample(t)
        # th - th(end) = O(t^2) and th' = O(t) (docs/tasks.md): with |th''| <= 40 rad/s^2
        assert np.all(np.abs(s.theta - end) <= 40 * (t[:, None] - (0 if end is START else 2)) ** 2)
        dt = np.abs(t - (0 if end is START else 2))[:, None]
        assert np.all(np.abs(s.theta_dot) <= 40 * dt)


def test_rest_plan_drives_the_momentum_constraint_to_its_goal() -> None:
    # referee: th1, th2 follow the plan's joint rates; th0' = -(H_1 th1' + H_2 th2') / H_0
    # from the complex kinematics (H = 0), integrated by DOP853 from rest
    plan = plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0)

    def rhs(t: float, x: Array) -> Array:
        rates = plan.sample(np.array([t])).theta_dot[0]
        weights = ref.momentum_weights(PAPER_ROBOT, np.array([x[0], x[1], x[2]]))
        th0_dot = -(weights[1] * rates[1] + weights[2] * rates[2]) / weights[0]
        return np.array([th0_dot, rates[1], rates[2]])

    sol = solve_ivp(rhs, (0.0, 2.0), START, method="DOP853", rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(sol.y[:, -1] - GOAL)) < 1e-8


def test_rest_plan_refuses_a_th1_that_does_not_move_or_crosses_pi() -> None:
    with pytest.raises(FlatcliError, match=r"task\.rest: the inner joints"):
        plan_rest_to_rest(PAPER_ROBOT, START, np.array([1.0, 1.0, 0.5]), 2.0)
    with pytest.raises(FlatcliError, match=r"task\.rest: th1 moves .* sin th1 = 0"):
        plan_rest_to_rest(PAPER_ROBOT, START, np.array([1.0, 3.5, 0.5]), 2.0)


def test_rest_plan_of_a_chain_is_at_rest_and_conserves_h() -> None:
    start = np.array([0.0, 1.0, 0.3, 0.0])
    goal = np.array([-0.3, 2.0, 0.6, 0.2])
    plan = plan_rest_to_rest(CHAIN4, start, goal, 2.0)
    s = plan.sample(np.linspace(0.0, 2.0, 201))
    assert np.all(np.isfinite(s.theta_dot))
    assert np.all(s.theta_dot[[0, -1]] == 0)
    assert np.max(np.abs(ref.momentum(CHAIN4, s.theta, s.theta_dot))) < 1e-12
    near = plan.sample(np.array([1e-5, 2 - 1e-5]))
    assert np.max(np.abs(near.theta[0] - start)) < 1e-7
    assert np.max(np.abs(near.theta[1] - goal)) < 1e-7


# ---------------------------------------------------------------------------------------
# Intervals and the continuous-time check


def test_interval_operations_contain_every_value() -> None:
    rng = np.random.default_rng(3)
    lo = rng.uniform(-4, 4, 200)
    hi = lo + rng.uniform(0, 3, 200)
    lo2 = rng.uniform(0.1, 2, 200)
    hi2 = lo2 + rng.uniform(0, 1, 200)
    a, b = Interval(lo, hi), Interval(lo2, hi2)
    x = lo[:, None] + (hi - lo)[:, None] * np.linspace(0, 1, 101)
    z = lo2[:, None] + (hi2 - lo2)[:, None] * np.linspace(0, 1, 101)[::-1]
    for got, values in ((a + b, x + z), (a - b, x - z), (a * b, x * z), (a / b, x / z),
                        (a.square(), x * x), (iv.cos(a), np.cos(x)), (iv.sin(a), np.sin(x))):
        assert np.all(got.lo[:, None] <= values) and np.all(values <= got.hi[:, None])
    c = rng.normal(size=6)
    p = iv.poly(c, lo / 8, hi / 8)
    values = np.polynomial.polynomial.polyval(x / 8, c)
    assert np.all(p.lo[:, None] <= values) and np.all(values <= p.hi[:, None])


def _planted(plan_samples: int = 201) -> tuple[object, Array, float]:
    """A rest plan, and a disc on the end effector's path exactly between two samples of a
    ``plan_samples`` grid, small enough that every sample clears it."""
    plan = plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0)
    grid = np.linspace(0.0, 2.0, plan_samples)
    t_star = 0.5 * (grid[100] + grid[101])
    tip = ref.end_effector(PAPER_ROBOT, plan.sample(np.array([t_star])).theta[0])
    at_samples = ref.link_clearance(PAPER_ROBOT, plan.sample(grid).theta,
                                    np.array([[tip.real, tip.imag, 0.0]]))
    radius = 0.3 * float(at_samples.min())
    return plan, np.array([[tip.real, tip.imag, radius]]), t_star


def test_a_violation_planted_between_two_samples_is_caught() -> None:
    plan, obstacle, t_star = _planted()
    grid = np.linspace(0.0, 2.0, 201)
    assert ref.link_clearance(PAPER_ROBOT, plan.sample(grid).theta, obstacle).min() > 0
    assert ref.link_clearance(PAPER_ROBOT, plan.sample(np.array([t_star])).theta,  # type: ignore[attr-defined]
                              obstacle)[0] < 0
    cert = certify(plan, Constraints(obstacle, 0.0))  # type: ignore[attr-defined]
    assert not cert.ok
    # the counterexample is real (the referee's kinematics) and lies between two samples
    at = ref.link_clearance(PAPER_ROBOT, plan.sample(np.array([cert.time])).theta,  # type: ignore[attr-defined]
                            obstacle)[0]
    assert at < 0
    assert np.min(np.abs(grid - cert.time)) > 0


def test_a_proven_plan_clears_on_a_grid_100x_finer() -> None:
    plan = plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0)
    obstacles = np.array([[0.25, 0.2, 0.05], [-0.3, -0.25, 0.05], [0.0, 0.3, 0.03]])
    cert = certify(plan, Constraints(obstacles, 0.01))
    assert cert.ok
    fine = np.linspace(0.0, 2.0, 64 * 100 + 1)  # 100x the check's 64 starting pieces
    dense = ref.link_clearance(PAPER_ROBOT, plan.sample(fine).theta, obstacles)
    assert dense.min() >= 0.01
    assert cert.lower_bound <= dense.min()  # a lower bound never exceeds the truth


def test_limits_between_samples_are_proven_or_refuted() -> None:
    plan = plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0)
    fine = plan.sample(np.linspace(0.0, 2.0, 20001))
    peak = float(np.abs(fine.theta[:, 2]).max())
    rate = float(np.abs(fine.theta_dot[:, 2]).max())
    inf = math.inf
    good = Constraints(np.zeros((0, 3)), 0.0, np.array([inf, inf, peak * 1.001]),
                       np.array([inf, rate * 1.001]))
    assert certify(plan, good).ok
    bad = Constraints(np.zeros((0, 3)), 0.0, np.array([inf, inf, peak * 0.999]))
    cert = certify(plan, bad)
    assert not cert.ok and "th2 beyond its angle limit" in cert.reason
    bad_rate = Constraints(np.zeros((0, 3)), 0.0, None, np.array([inf, rate * 0.999]))
    assert "th2' beyond its rate limit" in certify(plan, bad_rate).reason


@pytest.mark.parametrize("rest", [True, False])
def test_candidates_screened_together_have_each_plans_own_least_slack(rest: bool) -> None:
    """clearance.sampled_slack evaluates several candidates at once; each one's least slack
    over the samples is what the referee's complex-plane kinematics and each plan's own
    samples give (the ends of a rest plan included)."""
    if rest:
        plans = [plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0, skew=b)
                 for b in (0.0, 0.3, -0.6, 0.85)]
    else:
        plans = [plan_point_to_point(PAPER_ROBOT, START, GOAL, 0.1 * f, 0.5 * f, 2.0)
                 for f in (1.0, 0.5, 2.0)]
    obstacles = np.array([[0.25, 0.2, 0.05], [-0.3, -0.25, 0.05], [0.0, 0.3, 0.03]])
    inf = math.inf
    rate_limit = np.array([inf, 0.9])
    constraints = Constraints(obstacles, 0.01, None, rate_limit)
    got = sampled_slack(plans, constraints, 65)
    for plan, least in zip(plans, got, strict=True):
        s = plan.sample(np.linspace(0.0, 2.0, 65))
        clear = ref.link_clearance(PAPER_ROBOT, s.theta, obstacles) - 0.01
        rate = rate_limit[1] - np.abs(s.theta_dot[:, 2])
        assert least == pytest.approx(min(clear.min(), rate.min()), abs=1e-12)
    assert len(set(got.tolist())) == len(plans)  # four (three) different plans


def test_products_with_infinite_bounds_contain_every_value() -> None:
    """0 * inf among the corner products: [0, 2] x [1, inf] is [0, inf]; [-1, 0] x [1, inf]
    is [-inf, 0] (closed forms)."""
    up = Interval(np.array([1.0]), np.array([math.inf]))
    with np.errstate(invalid="ignore"):  # the 0 * inf corner
        p = Interval(np.array([0.0]), np.array([2.0])) * up
        q = Interval(np.array([-1.0]), np.array([0.0])) * up
    assert p.lo[0] <= 0.0 and p.hi[0] == math.inf
    assert q.lo[0] == -math.inf and q.hi[0] >= 0.0


def test_a_disc_beside_a_slanted_link_inside_its_box_is_proven_clear() -> None:
    """A disc 2 cm beside the base's segment at the start, its centre inside that segment's
    bounding box (where the distance to the box is 0 however short the time interval), with
    half the least distance the referee finds over the plan as its radius: certify proves
    it (a box alone never could near t = 0), and its bound is below the referee's truth."""
    plan = plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0)
    z = ref.joints(PAPER_ROBOT, START[None, :])[0]
    a, b = z[0], z[1]
    centre = 0.5 * (a + b) - 0.02j * (b - a) / abs(b - a)
    assert min(a.real, b.real) < centre.real < max(a.real, b.real)
    assert min(a.imag, b.imag) < centre.imag < max(a.imag, b.imag)
    fine = plan.sample(np.linspace(0.0, 2.0, 20001)).theta
    point = np.array([[centre.real, centre.imag, 1e-12]])
    radius = 0.5 * float(ref.link_clearance(PAPER_ROBOT, fine, point).min())
    disc = np.array([[centre.real, centre.imag, radius]])
    cert = certify(plan, Constraints(disc, 0.0))
    assert cert.ok, cert.reason
    assert 0.0 < cert.lower_bound <= float(ref.link_clearance(PAPER_ROBOT, fine, disc).min())
