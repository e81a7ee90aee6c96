"""Tests of flatcli.core.plan.exact: exact plans of any controllable design.

Referees: the angular momentum from the link geometry written in ``tests/asbuilt_support.py``
(complex planar vectors; no barycentric matrix, no h_j of flatcli), scipy's DOP853 at rtol
1e-12 integrating th0' = -(h_1 th_1' + ... + h_N th_N') / h_0 with those h_j along the plan's
joint paths, and scipy's SLSQP re-solving the programme from the plan.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import minimize

from flatcli.core.curves.basis import PolynomialBasis
from flatcli.core.errors import FlatcliError
from flatcli.core.names import METHODS
from flatcli.core.plan import exact
from flatcli.core.plan.exact import method_for, plan_exact, problem
from flatcli.core.robots.chain import chain_momentum
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams
from tests.asbuilt_support import AS_BUILT, GOAL, START, base_rate, momentum, weights

#: |H| along an exact plan from the geometry referee, th0' from the plan's own curve: the
#: issue's goal.
MOMENTUM_GOAL = 1e-9
#: th0(t) of the plan against a DOP853 of the constraint at rtol 1e-12.
BASE_TOL = 1e-9
#: End values the plan must meet (its joint curves are its basis's, re-expressed).
ENDS_TOL = 1e-10

DESIGNS = {
    "as built, d2 = 3 mm": AS_BUILT,
    "counterweight on its joint": PAPER_ROBOT,
    "across, e2 = 2 mm": RobotParams(com=(0.1, 0.1, 0.001), com_across=0.002),
    "three joints, d3 = 5 mm": RobotParams(mass=(2.0, 1.0, 1.0, 0.5),
                                           inertia=(0.1, 0.0533, 0.0533, 0.15),
                                           length=(0.3, 0.2, 0.2, 0.2),
                                           com=(0.1, 0.1, 0.1, 0.005)),
}


def _ends(robot: RobotParams) -> tuple[list[float], list[float], list[float], list[float]]:
    if robot.n_joints == 2:
        return list(START), list(GOAL), [0.1], [0.5]
    return [0.0, 1.0, 0.3, 0.0], [-0.75, 2.0, 0.6, 0.0], [0.3, 0.3], [0.5, 0.4]


@pytest.mark.parametrize("name", list(DESIGNS))
def test_plan_meets_its_ends_and_conserves_momentum(name: str) -> None:
    """Referee: H from the link geometry (``asbuilt_support.momentum``) at the plan's angles
    and rates, th0' the derivative of the plan's own th0 curve (not the constraint)."""
    robot = DESIGNS[name]
    start, goal, rate0, rate1 = _ends(robot)
    plan = plan_exact(robot, start, goal, rate0, rate1, 2.0)
    assert plan.model.kind == "exact"
    t = plan.grid(2001)
    s = plan.sample(t)
    np.testing.assert_allclose(s.theta[0], start, atol=ENDS_TOL)
    np.testing.assert_allclose(s.theta[-1], goal, atol=ENDS_TOL)
    n = robot.n_joints
    np.testing.assert_allclose(s.theta_dot[0, 1:n], rate0, atol=ENDS_TOL)
    np.testing.assert_allclose(s.theta_dot[-1, 1:n], rate1, atol=ENDS_TOL)
    assert np.max(np.abs(momentum(robot, s.theta, s.theta_dot))) <= MOMENTUM_GOAL
    np.testing.assert_allclose(s.momentum, momentum(robot, s.theta, s.theta_dot), atol=1e-14)
    np.testing.assert_array_equal(s.y, s.theta[:, 1:])  # the "outputs": the joint paths
    np.testing.assert_array_equal(s.y_dot, s.theta_dot[:, 1:])  # ... their rates
    # ... and accelerations: the joint rates' central differences (a referee of their own)
    h = t[1] - t[0]
    np.testing.assert_allclose(s.y_ddot[1:-1], (s.theta_dot[2:, 1:] - s.theta_dot[:-2, 1:])
                               / (2 * h), rtol=1e-4, atol=1e-4)
    assert np.all(np.isnan(s.margin))  # no singular set


def test_base_follows_a_tight_dop853_of_the_constraint() -> None:
    """Referee: DOP853 (rtol 1e-12) of th0' = -(h_1 th1' + h_2 th2') / h_0 with h_j from the
    link geometry, along the plan's joint paths, from th0(0)."""
    plan = plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0)
    curves = plan.trajectory

    def rhs(t: float, x: np.ndarray) -> np.ndarray:
        q = curves.derivative(np.array([t]), 0)[0, :2]
        w = curves.derivative(np.array([t]), 1)[0, :2]
        return np.array([base_rate(AS_BUILT, q, w)])

    t = np.linspace(0.0, 2.0, 41)
    sol = solve_ivp(rhs, (0.0, 2.0), [START[0]], method="DOP853", rtol=1e-12, atol=1e-14,
                    t_eval=t)
    np.testing.assert_allclose(plan.sample(t).theta[:, 0], sol.y[0], atol=BASE_TOL)


def test_plan_is_optimal_against_slsqp() -> None:
    """Referee: scipy's SLSQP from the plan's own coefficients finds nothing better on the
    same programme (objective and the equation Phi = 0, whose quadrature the DOP853 test
    checks), and the first-order optimality condition grad J = -lambda grad Phi holds with
    grad Phi by central differences."""
    robot = AS_BUILT
    basis = exact.BSplineBasis(exact.DEFAULT_SIZE, 2.0, exact.DEFAULT_DEGREE)
    prob = problem(exact.constraint_of(robot), basis, np.array(START), np.array(GOAL),
                   np.array([0.1]), np.array([0.5]), 1)
    z, _ = exact.solve(prob)
    assert abs(prob.residual(z)) <= 1e-11
    res = minimize(prob.objective, z, method="SLSQP", tol=1e-14,
                   constraints=[{"type": "eq", "fun": prob.residual}],
                   options={"maxiter": 200})
    assert res.fun >= prob.objective(z) - 1e-7 * abs(prob.objective(z))
    step = 1e-6
    grad_phi = np.array([(prob.residual(z + step * e) - prob.residual(z - step * e)) / (2 * step)
                         for e in np.eye(z.size)])
    grad_j = 2.0 * (prob.H @ z + prob.g)
    lam = -(grad_phi @ grad_j) / (grad_phi @ grad_phi)
    np.testing.assert_allclose(grad_j + lam * grad_phi, 0.0, atol=1e-6 * np.abs(grad_j).max())


def test_energy_objective_beats_the_least_acceleration_plan() -> None:
    """Referee: the two objectives' own definitions (each plan minimises its own)."""
    acc = plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0)
    energy = plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0, objective="energy")
    assert energy.input_energy() < acc.input_energy()


def test_not_flat_design_is_refused_unless_its_goal_is_the_conserved_one() -> None:
    """Referee: for a design with K diagonal (l0 = d0, links 1-2 balanced on joint 2:
    README's example), sum_i h_i th_i is conserved with constant h_i from the geometry."""
    robot = RobotParams(com=(0.2, 0.1, 0.0))  # l0 = d0 and d2 = 0: not flat
    h = weights(robot, np.zeros(3))
    np.testing.assert_allclose(weights(robot, [0.3, 1.1, -0.7]), h, atol=1e-15)  # constant
    with pytest.raises(FlatcliError, match=r"^plan.goal\[0\]: the robot is not flat") as info:
        plan_exact(robot, START, GOAL, 0.1, 0.5, 2.0)
    assert "\n" not in str(info.value)
    conserved = START[0] + (h[1] * (START[1] - GOAL[1]) + h[2] * (START[2] - GOAL[2])) / h[0]
    plan = plan_exact(robot, START, (conserved, *GOAL[1:]), 0.1, 0.5, 2.0)
    np.testing.assert_allclose(plan.sample(np.array([2.0])).theta[0, 0], conserved, atol=1e-10)


def test_unreachable_goal_is_refused_in_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    """Referee: the solver given no iterations cannot meet the goal (the message names the
    key and the miss)."""
    monkeypatch.setattr(exact, "MAX_RESTORATION", 0)
    monkeypatch.setattr(exact, "MAX_NEWTON", 0)
    with pytest.raises(FlatcliError, match=r"^plan.goal\[0\]: no joint paths in the basis found "
                                           r"that bring th0 to 1.2 rad"):
        plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0, basis=PolynomialBasis(5, 2.0))


def test_methods_and_bad_input() -> None:
    assert METHODS == ("auto", "flat", "exact")
    assert method_for(PAPER_ROBOT, "auto") == "flat"
    assert method_for(AS_BUILT, "auto") == "exact"
    assert method_for(PAPER_ROBOT, "exact") == "exact"
    with pytest.raises(FlatcliError, match=r"plan\.method: expected one of"):
        method_for(PAPER_ROBOT, "closest")
    with pytest.raises(FlatcliError, match=r"plan\.optimize\.objective: an exact plan minimises"):
        plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0, objective="margin")
    with pytest.raises(FlatcliError, match=r"plan\.duration"):
        plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 0.0)


def test_chain_momentum_agrees_with_the_geometry_referee_along_an_exact_plan() -> None:
    """Referee: the geometry referee against chain.chain_momentum (flatcli's full link
    kinematics, which the plan's momentum column uses) along an exact plan of the paper's
    robot."""
    plan = plan_exact(PAPER_ROBOT, START, GOAL, 0.1, 0.5, 2.0)
    s = plan.sample(plan.grid(501))
    arrays = [np.asarray(v, dtype=float) for v in
              (PAPER_ROBOT.mass, PAPER_ROBOT.inertia, PAPER_ROBOT.length, PAPER_ROBOT.com)]
    np.testing.assert_allclose(chain_momentum(*arrays, s.theta, s.theta_dot),
                               momentum(PAPER_ROBOT, s.theta, s.theta_dot), atol=1e-14)
