"""The problem every baseline solves: the paper's maneuver, its tracking task and trials."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.controllers.control import Gains
from flatcli.core.loop.simulate import Trials
from flatcli.core.names import Model
from flatcli.core.plan.planning import (
    Plan,
    plan_point_to_point,
)
from flatcli.core.robots.params import (
    PAPER_ROBOT,
    Coefficients,
    RobotParams,
    constraint_coefficients,
)

Array = NDArray[np.float64]
Triple = tuple[float, float, float]

#: The paper's printed gains (kp1, kp2, kv1, kv2): closed-loop poles near -0.1 and -100.
PRINTED_GAINS = Gains((10.0, 13.0), (100.0, 110.0))
#: kp and kv swapped: well-damped poles, errors ~1e-5 at t = T.
SWAPPED_GAINS = Gains((100.0, 110.0), (10.0, 13.0))


@dataclass(frozen=True)
class Maneuver:
    """A point-to-point maneuver (the paper's, Sec. VI, by default).

    Attributes
    ----------
    robot : RobotParams of the planning model (d2 = 0 for the flat baselines)
    start, goal : th0, th1, th2 at t = 0 and t = T [rad]
    start_rate, goal_rate : th1' at the two ends [rad/s] (the paper's free choice)
    duration : T [s]
    model : constraint coefficients the planners believe ("derived" or "paper")
    """

    robot: RobotParams = PAPER_ROBOT
    start: Triple = (1.8, 1.0, 0.0)
    goal: Triple = (1.2, 2.0, 0.0)
    start_rate: float = 0.1
    goal_rate: float = 0.5
    duration: float = 2.0
    model: Model = "derived"

    @property
    def coefficients(self) -> Coefficients:
        """Reduced-constraint coefficients of the planning model [kg^2 m^2]."""
        return constraint_coefficients(self.robot.links, self.model)

    @property
    def start_state(self) -> Array:
        """(4,) prolonged state th0, th1, th2 [rad], u1 = th1' [rad/s] at t = 0."""
        return np.array([*self.start, self.start_rate])

    @property
    def goal_state(self) -> Array:
        """(4,) prolonged state at t = T."""
        return np.array([*self.goal, self.goal_rate])

    def cubic(self) -> Plan:
        """flatcli's cubic plan of this maneuver (the paper's choice of basis)."""
        return plan_point_to_point(
            self.robot,
            np.asarray(self.start),
            np.asarray(self.goal),
            self.start_rate,
            self.goal_rate,
            self.duration,
            self.model,
        )


PAPER_MANEUVER = Maneuver()


@dataclass(frozen=True)
class Tracking:
    """The closed-loop setting of the paper's Fig. 4.

    Attributes
    ----------
    initial : th(0) of the robot [rad]
    initial_rate : u1(0), the controller's integrator [rad/s] (y1d'(0); not in the paper)
    gains : Gains (``PRINTED_GAINS`` or ``SWAPPED_GAINS``)
    dt : RK4 step [s]
    rate_limit : joint-rate saturation of the plant [rad/s] (inf: none)
    """

    initial: Triple = (1.96, 0.8, -0.1)
    initial_rate: float = 0.1
    gains: Gains = PRINTED_GAINS
    dt: float = 1e-3
    rate_limit: float = math.inf


PAPER_TRACKING = Tracking()


def paper_trials(
    count: int,
    seed: int = 0,
    tracking: Tracking = PAPER_TRACKING,
    robot: RobotParams = PAPER_ROBOT,
    spread: float = 0.02,
    angle_spread: float = 0.02,
    com2_spread: float = 0.002,
    momentum_spread: float = 1e-4,
) -> Trials:
    """Monte Carlo trials around the paper's closed loop, for the closed-loop baselines.

    Every plant parameter is scaled by an independent uniform factor in [1 - spread,
    1 + spread]; d2 = com[2] is drawn uniform in [-com2_spread, com2_spread] [m] (so the
    plant's reduced constraint has all its terms, the controller's model has none); the
    initial angles get uniform offsets of +-angle_spread [rad]; H0 is uniform in
    +-momentum_spread [kg m^2/s].

    Parameters
    ----------
    count : N trials
    seed : seed of numpy's default generator

    Returns
    -------
    Trials with links (N, 12), momentum (N,), initial (N, 4), no noise
    """
    rng = np.random.default_rng(seed)
    links = robot.as_array()[None, :] * rng.uniform(1 - spread, 1 + spread, (count, 12))
    links[:, 11] = rng.uniform(-com2_spread, com2_spread, count) + robot.com[2]
    initial = np.empty((count, 4))
    initial[:, :3] = np.asarray(tracking.initial) + rng.uniform(
        -angle_spread, angle_spread, (count, 3)
    )
    initial[:, 3] = tracking.initial_rate
    h0 = rng.uniform(-momentum_spread, momentum_spread, count)
    return Trials(links=links, momentum=h0, initial=initial)
