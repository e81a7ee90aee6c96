"""The referee of the rest-to-rest law (``flatcli.core.controllers.rest``): the blended flat
law integrated by scipy's DOP853 (rtol 1e-11), outside the compiled kernels.

    u_j' = y_jd'' + w (u_j'_fb - y_jd''),   th_N' = th_Nd' + w (th_N'_fb - th_Nd'),

w(t) = S(t / (f T)) S((T - t) / (f T)), S(x) = 3 x^2 - 2 x^3 on [0, 1], written here again;
the plan's flag y, y', y'' from ``RestPlan.flags`` and th_Nd' from ``RestPlan.sample`` at each
t (exact, where the compiled law reads fitted pieces); the feedback's inputs from flatcli's
Python-callable law (the paper's closed form, ``control.feedback``; a chain's
``chainflat.outputs`` and ``inputs``), not evaluated where w = 0. The plant is the kinematic
one: joint rates clipped to +-rate_limit (u_j' held at 0 while u_j is at or beyond the limit
and pushed further out), th0' from H = H0 with the weights of the full link kinematics in
the complex plane (``task_referees.momentum_weights``), not flatcli's barycentric matrices.
This was flatcli/core/loop/restloop.py, the rest loop ``flatcli track`` ran before
the law was compiled (kinematic only, its plant then flatcli's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core.controllers.control import Gains, feedback
from flatcli.core.models.chainflat import inputs, outputs
from flatcli.core.models.flatmodel import ChainModel
from flatcli.core.plan.rest import RestPlan
from flatcli.core.robots.params import RobotParams
from tests import task_referees

Array = NDArray[np.float64]

RTOL = 1e-11
ATOL = 1e-13


def fade(t: float, duration: float, fraction: float) -> float:
    """w(t) (module docstring)."""
    def step(x: float) -> float:
        x = min(max(x, 0.0), 1.0)
        return x * x * (3.0 - 2.0 * x)

    width = fraction * duration
    return step(t / width) * step((duration - t) / width)


@dataclass(frozen=True)
class RestTrace:
    """Times (n,) [s], angles (n, N + 1) [rad], the rates the plant applies (n, N + 1)
    [rad/s], whether the integration reached T."""

    t: Array
    theta: Array
    theta_dot: Array
    finished: bool


def track_rest(plan: RestPlan, gains: Gains, plant: RobotParams, initial: Array,
               times: Array, fraction: float, momentum: float = 0.0,
               rate_limit: float = math.inf) -> RestTrace:
    """The closed loop of a rest plan from angles ``initial`` (N + 1,) [rad] at rest (the
    inner rates 0), sampled at ``times`` (n,) [s] (module docstring)."""
    n = plan.n_joints
    chain = isinstance(plan.model, ChainModel)
    kp, kv = np.asarray(gains.kp, dtype=float), np.asarray(gains.kv, dtype=float)
    T = plan.duration
    limit = float(rate_limit)
    y, y_dot = np.empty(n), np.empty(n)
    u_dot = np.empty(n - 1)

    def commands(t: float, x: Array) -> tuple[Array, float]:
        flags = plan.flags(np.array([t]))[0]
        planned_acc = flags[2 * n: 3 * n - 1]
        planned_rate = float(plan.sample(np.array([t])).theta_dot[0, n])
        w = fade(t, T, fraction)
        if w == 0.0:
            return planned_acc.copy(), planned_rate
        theta, u = np.ascontiguousarray(x[: n + 1]), np.ascontiguousarray(x[n + 1:])
        if chain:
            model = plan.model
            assert isinstance(model, ChainModel)
            outputs(model.K, model.inertia, theta, u, y, y_dot)
            v = flags[2 * n:] + kv * (flags[n: 2 * n] - y_dot) + kp * (flags[:n] - y)
            rate = float(inputs(model.K, model.inertia, theta, u, v, u_dot))
            acc = u_dot.copy()
        else:
            a, r = feedback(plan.model.coefficients, gains.paper(), *theta, u[0], flags)
            acc, rate = np.array([float(a)]), float(r)
        return (planned_acc + w * (acc - planned_acc), planned_rate + w * (rate - planned_rate))

    def rates(t: float, x: Array) -> tuple[Array, Array]:
        acc, last = commands(t, x)
        u = x[n + 1:]
        joints = np.clip(np.array([*u, last]), -limit, limit)
        held = ((u >= limit) & (acc > 0.0)) | ((u <= -limit) & (acc < 0.0))
        acc = np.where(held, 0.0, acc)
        weights = task_referees.momentum_weights(plant, x[: n + 1])
        th0_dot = (momentum - float(weights[1:] @ joints)) / weights[0]
        return np.array([th0_dot, *joints]), acc

    def rhs(t: float, x: Array) -> Array:
        return np.concatenate(rates(t, x))

    x0 = np.concatenate([np.asarray(initial, dtype=float)[: n + 1], np.zeros(n - 1)])
    with np.errstate(all="ignore"):
        sol = solve_ivp(rhs, (0.0, T), x0, method="DOP853", t_eval=times, rtol=RTOL, atol=ATOL)
    count = len(times)
    states = np.full((count, 2 * n), math.nan)
    states[: sol.y.shape[1]] = sol.y.T
    applied = np.full((count, n + 1), math.nan)
    for i in range(sol.y.shape[1]):
        applied[i] = rates(float(times[i]), states[i])[0]
    return RestTrace(np.asarray(times, dtype=float), states[:, : n + 1], applied,
                     bool(sol.status == 0))
