"""Spec -> core objects (flatcli/experiment.py): a robot of N links through the optimiser.

References: the plan's angular momentum from the full link kinematics
(``chain.chain_momentum``, positions and velocities of every centre of mass) and its limits
on 4,001 samples, independent of the optimiser's own check grid.
"""

from __future__ import annotations

import numpy as np

from flatcli.core.plan.planning import Plan
from flatcli.core.robots.chain import chain_momentum
from flatcli.experiment import planned
from flatcli.reproduce.chains import CHAIN_SPECS
from flatcli.spec import load_spec


def test_a_chain_spec_is_optimised_with_its_per_joint_limits() -> None:
    spec = load_spec(CHAIN_SPECS[0], (
        "plan.optimize.objective=energy", "plan.optimize.rate_limit=[3,3,10]",
        "plan.optimize.angle_limit=[inf,inf,inf,0.8]", "plan.optimize.constraint_samples=41",
        "plan.start_rate=[0.3,0.2]"))
    plan, result, _ = planned(spec)
    assert isinstance(plan, Plan) and result is not None and result.success
    assert result.objective < result.initial_objective
    s = plan.sample(plan.grid(4001))
    assert np.all(np.abs(s.theta_dot[:, 1:]).max(axis=0) <= np.array([3, 3, 10]) * (1 + 1e-3))
    assert np.abs(s.theta[:, 3]).max() <= 0.8 * (1 + 1e-3)
    np.testing.assert_allclose(s.theta[[0, -1]], [spec.plan.start, spec.plan.goal], atol=1e-10)
    robot = plan.robot
    h = chain_momentum(
        np.asarray(robot.mass, dtype=float), np.asarray(robot.inertia, dtype=float),
        np.asarray(robot.length, dtype=float), np.asarray(robot.com, dtype=float),
        s.theta, s.theta_dot)
    assert np.abs(h).max() < 1e-12
    assert len(result.start_rates) == 2 and len(result.goal_rates) == 2
