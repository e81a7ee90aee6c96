"""The closed loop of a rest-to-rest plan: feedforward at the ends, feedback faded in between.

At rest the linearising feedback divides by the margin sin(th1) u1 = 0 (``control``): its
gain on the y2 error grows as 1/t near the ends, and a measured state a little off the plan
would be commanded without bound. So the commands are blended (N = 2, the paper's robot):

    u1' = y1d'' + w(t) (v1 - y1d''),     u2 = th2d' + w(t) (u2_fb - th2d'),

with th2d' the plan's own rate (exact at the ends, ``rest.RestPlan``), u2_fb the feedback's
(eqs. 39-42) and the fade w(t) = S(t / (f T)) S((T - t) / (f T)), S(x) = 3 x^2 - 2 x^3 on
[0, 1] (1 beyond): zero with zero slope at the ends, one in the middle (f = ``task.fade``).
Where w = 0 the plant is driven open loop by the plan, so an initial error persists through
the fade-in and whatever error is left when the fade-out begins is carried to T: that is the
tracking error the scheme costs (docs/tasks.md measures it).

The plant is the kinematic one: th1' = sat(u1), th2' = sat(u2) (sat clips a joint rate to
+-rate_limit, as ``paperloop.kinematic_rhs``; u1' is 0 while u1 is at or beyond the limit and
the command pushes it further out, so u1 does not wind up) and th0' from H = H0 with the
plant's own momentum weights (``chain.momentum_weights``), integrated by scipy's DOP853.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core.controllers.control import Gains, feedback
from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import PaperModel
from flatcli.core.plan.rest import RestPlan
from flatcli.core.robots.chain import barycentric_matrix, momentum_weights
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: Tolerances of the rest loop's DOP853.
RTOL = 1e-10
ATOL = 1e-12


def fade(t: Array | float, duration: float, fraction: float) -> Array:
    """w(t) in [0, 1] (module docstring)."""
    width = fraction * duration

    def step(x: Array) -> Array:
        x = np.clip(x, 0.0, 1.0)
        return np.asarray(x * x * (3.0 - 2.0 * x), dtype=float)

    tt = np.asarray(t, dtype=float)
    return np.asarray(step(tt / width) * step((duration - tt) / width), dtype=float)


@dataclass(frozen=True)
class RestTrace:
    """A rest loop's trace on the output grid: times (n,) [s], angles (n, 3) [rad], the
    rates the plant applies (n, 3) [rad/s], the controller's u1 (n,) [rad/s], the fade
    (n,), whether the integration reached T, and per sample whether a rate command was at
    or beyond the rate limit (n,) (clipped)."""

    t: Array
    theta: Array
    theta_dot: Array
    u1: Array
    weight: Array
    finished: bool
    clipped: NDArray[np.bool_]


def track_rest(plan: RestPlan, gains: Gains, plant: RobotParams, initial: Array,
               times: Array, fraction: float, momentum: float = 0.0,
               rate_limit: float = math.inf) -> RestTrace:
    """The closed loop of a rest plan of the paper's robot from angles ``initial`` (3,)
    [rad] at rest (u1(0) = 0), sampled at ``times`` (n,) [s], its joint rates clipped to
    ``rate_limit`` [rad/s] (inf: none).

    Raises
    ------
    FlatcliError for a plan that is not the paper's robot's (the loop is written for N = 2).
    """
    if not isinstance(plan.model, PaperModel):
        raise FlatcliError("task.rest: tracking a rest plan is implemented for the paper's "
                           "robot (2 joints) only; plan it with flatcli plan")
    k = plan.model.coefficients
    g = gains.paper()
    K = barycentric_matrix(*(np.asarray(v, dtype=float) for v in
                             (plant.mass, plant.length, plant.com)))
    inertia = np.asarray(plant.inertia, dtype=float)
    T = plan.duration
    weights = np.empty(3)

    def commands(t: float, x: Array) -> tuple[float, float]:
        flags = plan.flags(np.array([t]))[0]
        ff_rate = float(plan.sample(np.array([t])).theta_dot[0, 2])
        w = float(fade(t, T, fraction))
        if w == 0.0:
            return float(flags[4]), ff_rate
        u1_dot, u2 = feedback(k, g, x[0], x[1], x[2], x[3], flags)
        return (float(flags[4]) + w * (float(u1_dot) - float(flags[4])),
                ff_rate + w * (float(u2) - ff_rate))

    limit = float(rate_limit)

    def rates(t: float, x: Array) -> tuple[Array, float, bool]:
        u1_dot, u2 = commands(t, x)
        w1 = min(max(float(x[3]), -limit), limit)
        w2 = min(max(u2, -limit), limit)
        if (x[3] >= limit and u1_dot > 0.0) or (x[3] <= -limit and u1_dot < 0.0):
            u1_dot = 0.0  # conditional integration: no wind-up while th1' is clipped
        momentum_weights(K, inertia, np.array([x[0], x[1], x[2]]), weights)
        th0_dot = (momentum - weights[1] * w1 - weights[2] * w2) / weights[0]
        return np.array([th0_dot, w1, w2]), u1_dot, abs(w1) >= limit or abs(w2) >= limit

    def rhs(t: float, x: Array) -> Array:
        r, u1_dot, _ = rates(t, x)
        return np.array([r[0], r[1], r[2], u1_dot])

    x0 = np.array([*np.asarray(initial, dtype=float)[:3], 0.0])
    with np.errstate(all="ignore"):
        sol = solve_ivp(rhs, (0.0, T), x0, method="DOP853", t_eval=times, rtol=RTOL, atol=ATOL)
    n = len(times)
    states = np.full((n, 4), math.nan)
    states[: sol.y.shape[1]] = sol.y.T
    applied = np.full((n, 3), math.nan)
    clipped = np.zeros(n, dtype=bool)
    for i in range(sol.y.shape[1]):
        applied[i], _, clipped[i] = rates(float(times[i]), states[i])
    return RestTrace(np.asarray(times, dtype=float), states[:, :3], applied, states[:, 3],
                     fade(times, T, fraction), bool(sol.status == 0), clipped)


__all__ = ["RestTrace", "fade", "track_rest"]
