"""make reproduce's "Beyond three links" (flatcli/chains.py): the natural drift, the plan
checks and the two robots' specs.

References, none of them the code under test:

* for N = 2, the paper's reduced momentum constraint (a0 + a1 cos th1) th0' = (b0 + b1 cos
  th1) th1' + c0 th2' (H = 0; ``model.constraint_coefficients``, derived from the link
  kinematics and checked against sympy in tests/test_model.py), whose drift with th2 at rest
  is integral (b0 + b1 cos th1) / (a0 + a1 cos th1) dth1, by scipy's quad;
* for N >= 3, th0' solved from H = 0 with H from the full link kinematics
  (``chain.chain_momentum``: positions and velocities of every centre of mass, no h_j),
  integrated by scipy's DOP853 along the plan's joint path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

from flatcli.core.robots.chain import chain_momentum
from flatcli.core.robots.params import constraint_coefficients, flatness_check
from flatcli.experiment import plan_from, robot_from
from flatcli.reproduce.chains import CHAIN_SPECS, natural_drift, path_rates, plan_checks
from flatcli.spec import load_spec, resolve


def test_the_papers_drift_is_the_reduced_constraints_integral_whatever_the_rates() -> None:
    k = constraint_coefficients(robot_from(resolve({})).links, "derived")
    expected, _ = quad(lambda th1: (k.b0 + k.b1 * np.cos(th1)) / (k.a0 + k.a1 * np.cos(th1)),
                       1.0, 2.0, epsabs=1e-13, epsrel=1e-13)
    for start_rate, goal_rate in ((0.1, 0.5), (1.0, 0.1), (0.3, 1.0)):
        spec = resolve({"plan": {"start_rate": start_rate, "goal_rate": goal_rate}})
        assert natural_drift(plan_from(spec)) == pytest.approx(expected, abs=1e-7)


def full_kinematics_drift(spec_path: Path, start_rate: list[float], goal_rate: list[float]
                          ) -> tuple[float, float]:
    """The base's turn with th_N at rest along the plan's joint path: th0' from H = 0, H
    linear in the rates, both of its parts from ``chain_momentum``; and natural_drift's."""
    spec = load_spec(spec_path).with_overrides({"plan.start_rate": start_rate,
                                                "plan.goal_rate": goal_rate})
    plan = plan_from(spec)
    robot = plan.robot
    mass, inertia, length, com = (np.asarray(v, dtype=float) for v in
                                  (robot.mass, robot.inertia, robot.length, robot.com))
    n = robot.n_joints

    def rate(t: float, th0: np.ndarray) -> np.ndarray:
        s = plan.sample(np.array([t]))
        theta = s.theta[0].copy()
        theta[0] = th0[0]
        rates = s.theta_dot[0].copy()
        rates[0] = 0.0
        rates[n] = 0.0  # th_N at rest
        unit = np.zeros(n + 1)
        unit[0] = 1.0
        joints = chain_momentum(mass, inertia, length, com, theta[None], rates[None])[0]
        base = chain_momentum(mass, inertia, length, com, theta[None], unit[None])[0]
        return np.array([-joints / base])

    sol = solve_ivp(rate, (0.0, spec.plan.duration), [spec.plan.start[0]], method="DOP853",
                    rtol=1e-11, atol=1e-13)
    return float(sol.y[0, -1] - spec.plan.start[0]), natural_drift(plan)


@pytest.mark.parametrize("which", [0, 1])
def test_a_chains_drift_is_the_full_kinematics_one_and_depends_on_the_path(which: int) -> None:
    path = CHAIN_SPECS[which]
    joints = load_spec(path).joints
    (a_start, a_goal), (b_start, b_goal) = path_rates(joints)
    a_ref, a = full_kinematics_drift(path, a_start, a_goal)
    b_ref, b = full_kinematics_drift(path, b_start, b_goal)
    assert a == pytest.approx(a_ref, abs=1e-7) and b == pytest.approx(b_ref, abs=1e-7)
    assert abs(a_ref - b_ref) > 0.01  # same ends, another route: another drift


def test_the_example_robots_are_flat_chains_whose_plans_keep_h_zero() -> None:
    for path in CHAIN_SPECS:
        spec = load_spec(path)
        robot = robot_from(spec)
        assert robot.n_joints in (3, 5) and flatness_check(robot).is_flat
        plan = plan_from(spec)
        checks = plan_checks(plan, spec.plan.start, spec.plan.goal)
        assert checks["max_abs_H"] < 1e-12 and checks["end_error"] < 1e-12
        t = plan.grid(2001)
        s = plan.sample(t)
        assert checks["fold"] == pytest.approx(np.abs(s.theta[:, -1]).max(), rel=1e-3)
        assert checks["min_margin"] > 0.1  # far from the singular set


def test_the_two_paths_share_their_ends_and_mirror_each_other() -> None:
    (down, up), (up2, down2) = path_rates(5)
    assert down == down2 and up == up2 and down == up[::-1]
    assert down[0] == 1.0 and down[-1] == pytest.approx(0.1) and len(down) == 4
