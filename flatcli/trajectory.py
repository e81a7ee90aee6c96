"""A planned maneuver as a function of time: ``Trajectory``, what ``PlanResult.trajectory``
gives (as python-control's ``SystemTrajectory.eval``).

    >>> p = flatcli.plan()
    >>> x = p.trajectory(0.5)                 # one time [s]: 1-d arrays
    >>> x.theta, x.theta_dot, x.u_dot, x.y    # states, rates, inputs, flat outputs
    >>> p.trajectory(np.linspace(0, 2, 11)).theta.shape    # (11, 3)
    >>> p.trajectory.frame([0.0, 1.0, 2.0])   # plan.parquet's columns at those times

The values are the core's (``flatcli.core``'s plan evaluated exactly at each time: the flat
outputs from their basis, states and rates from the inverse flat map, inputs from the flat
accelerations), not interpolated between the samples of plan.parquet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.plan.planning import Plan

Array = NDArray[np.float64]


@dataclass(frozen=True)
class TrajectoryPoints:
    """A plan of N joints at n times (at one time: the leading axis dropped).

    Attributes
    ----------
    t : (n,) times [s]
    theta : (n, N + 1) th0 (the base's attitude) .. thN [rad]
    theta_dot : (n, N + 1) their rates [rad/s] (exact derivative of the inverse flat map)
    u_dot : (n, N - 1) the inputs u_j' = th_j'' of the inner joints j < N [rad/s^2]
    u : (n,) the input of the last joint, u_N = th_N' [rad/s]
    y, y_dot, y_ddot : (n, N) the flat outputs [rad] and their first two derivatives
        [rad/s, rad/s^2]
    margin : (n,) distance to the singular set, abs(sin y1 * y1') for N = 2 [rad/s]
    momentum : (n,) H from the planning robot's full link kinematics [kg m^2/s] (rounding
        for a correct plan)
    """

    t: Array
    theta: Array
    theta_dot: Array
    u_dot: Array
    u: Array
    y: Array
    y_dot: Array
    y_ddot: Array
    margin: Array
    momentum: Array


class Trajectory:
    """A planned maneuver (the core's ``Plan``) evaluated at any time in [0, T]: ``eval(t)``
    or ``trajectory(t)`` gives its states, rates, inputs and flat outputs
    (``TrajectoryPoints``); ``frame(t)`` the same as plan.parquet's columns."""

    def __init__(self, plan: Plan) -> None:
        self.plan = plan

    @property
    def duration(self) -> float:
        """T [s]: the trajectory is defined on [0, T]."""
        return float(self.plan.duration)

    @property
    def joints(self) -> int:
        """N, the robot's joints."""
        return int(self.plan.robot.n_joints)

    def eval(self, t: ArrayLike) -> TrajectoryPoints:
        """The plan at times ``t`` [s] (a number, or an array of them within [0, T]);
        FlatcliError for a time outside it or not finite."""
        times = np.asarray(t, dtype=np.float64)
        scalar = times.ndim == 0
        flat = np.atleast_1d(times).ravel()
        if flat.size == 0:
            raise FlatcliError("trajectory: give at least one time")
        bad = flat[~np.isfinite(flat) | (flat < 0) | (flat > self.duration)]
        if bad.size:
            raise FlatcliError(f"trajectory: t must lie within [0, {self.duration:g}] s (the "
                               f"maneuver), got {float(bad[0]):g}")
        s = self.plan.sample(flat)
        n = self.joints
        points = TrajectoryPoints(t=s.t, theta=s.theta, theta_dot=s.theta_dot, u_dot=s.u_dot,
                                  u=s.theta_dot[..., n], y=s.y, y_dot=s.y_dot,
                                  y_ddot=s.y_ddot, margin=s.margin, momentum=s.momentum)
        if not scalar:
            return points
        return TrajectoryPoints(**{name: np.asarray(getattr(points, name))[0]
                                   for name in TrajectoryPoints.__dataclass_fields__})

    __call__ = eval

    def frame(self, t: ArrayLike) -> pd.DataFrame:
        """plan.parquet's columns at times ``t`` (with their units in ``attrs["units"]``)."""
        from flatcli.outputs import plan_frame

        times = np.atleast_1d(np.asarray(t, dtype=np.float64))
        self.eval(times)  # the same checks
        return plan_frame(self.plan.sample(times), self.plan.robot)

    def __repr__(self) -> str:
        return f"<flatcli Trajectory: {self.joints} joints, T = {self.duration:g} s>"
