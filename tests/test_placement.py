"""Tests of a centre of mass across the last link (``RobotParams.com_across``, ``placement``).

Referee: the angular momentum from the link geometry in ``tests/asbuilt_support.py``, where
the centre of mass of the last link is placed at (d_N, e_N) in its frame directly (no turn,
no equivalent robot).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from flatcli.core.errors import FlatcliError
from flatcli.core.loop.simulate import placements
from flatcli.core.models.flatmodel import flat_model
from flatcli.core.robots.design import design_verdict
from flatcli.core.robots.params import RobotParams, flatness_check
from tests.asbuilt_support import momentum

#: Two exact descriptions of one robot agree to rounding.
ROUNDING = 1e-14

ROBOTS = [RobotParams(com=(0.1, 0.1, 0.002), com_across=0.003),
          RobotParams(com=(0.1, 0.1, -0.004), com_across=-0.001),
          RobotParams(mass=(2.0, 1.0, 1.0, 0.5), inertia=(0.1, 0.05, 0.05, 0.15),
                      length=(0.3, 0.2, 0.2, 0.2), com=(0.1, 0.1, 0.1, 0.0), com_across=0.01)]


@pytest.mark.parametrize("robot", ROBOTS)
def test_equivalent_placement_moves_as_the_robot(robot: RobotParams) -> None:
    """Referee: H from the geometry with the centre across the link, against H of the
    equivalent robot (d_N = hypot(d_N, e_N), e_N = 0) at th_N + atan2(e_N, d_N), through
    flatcli's own full kinematics (``FlatModel.momentum``) and the geometry referee."""
    rng = np.random.default_rng(3)
    n = robot.n_joints
    theta = rng.uniform(-3, 3, (50, n + 1))
    rates = rng.normal(size=(50, n + 1))
    equivalent, alpha = robot.placement
    assert equivalent.com_across == 0.0
    assert equivalent.com[-1] == pytest.approx(math.hypot(robot.com[-1], robot.com_across))
    assert alpha == pytest.approx(math.atan2(robot.com_across, robot.com[-1]))
    turned = theta.copy()
    turned[:, -1] += alpha
    want = momentum(robot, theta, rates)
    np.testing.assert_allclose(momentum(equivalent, turned, rates), want, atol=ROUNDING)
    model = flat_model(RobotParams(mass=robot.mass, inertia=robot.inertia,
                                   length=robot.length, com=(*robot.com[:-1], 0.0)))
    np.testing.assert_allclose(model.momentum(robot, theta, rates), want, atol=ROUNDING)


def test_trials_placements_are_the_robots() -> None:
    """Referee: ``RobotParams.placement`` of each plant."""
    plants = [*ROBOTS[:2], RobotParams(com=(0.1, 0.1, 0.002))]
    params, offset = placements(np.stack([p.as_array() for p in plants]),
                                np.array([p.com_across for p in plants]))
    for row, turn, plant in zip(params, offset, plants, strict=True):
        equivalent, alpha = plant.placement
        np.testing.assert_array_equal(row, equivalent.as_array())
        assert turn == alpha


def test_across_offset_is_flat_but_not_closed_form() -> None:
    robot = RobotParams(com_across=0.002)  # d2 = 0, e2 = 2 mm
    check = flatness_check(robot)
    assert not check.is_flat and check.controllable
    assert "com_across = e2 = 0.002 m, not 0" in check.message()
    verdict = design_verdict(robot)
    assert verdict.verdict == "flat"
    with pytest.raises(FlatcliError, match="com_across: must be finite"):
        RobotParams(com_across=float("nan"))
