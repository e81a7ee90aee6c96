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

A chain of N joints (``ChainModel``) is blended the same way: u_j' = y_jd'' + w (u_j'_fb -
y_jd'') for the inner joints and th_N' = th_Nd' + w (th_N'_fb - th_Nd'), the feedback's being
the chain's linearising inputs for v_j = y_jd'' + kv_j (y_jd' - y_j') + kp_j (y_jd - y_j)
(``chainflat.inputs``, as the compiled chain loop commands them), on the kinematic plant of
state (th0..thN, u_1..u_N-1), its joint rates clipped as the paper's (``plants.kinematic``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core.controllers.control import Gains, feedback
from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import ChainModel, PaperModel
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
    """A rest loop's trace on the output grid: times (n,) [s], angles (n, N + 1) [rad], the
    rates the plant applies (n, N + 1) [rad/s], the controller's inner rates u_1..u_N-1
    (n, N - 1) [rad/s], the fade (n,), whether the integration reached T, and per sample
    whether a rate command was at or beyond the rate limit (n,) (clipped)."""

    t: Array
    theta: Array
    theta_dot: Array
    u: Array
    weight: Array
    finished: bool
    clipped: NDArray[np.bool_]

    @property
    def u1(self) -> Array:
        """(n,) u_1 = th1' [rad/s]."""
        return np.asarray(self.u[:, 0], dtype=float)


def track_rest(plan: RestPlan, gains: Gains, plant: RobotParams, initial: Array,
               times: Array, fraction: float, momentum: float = 0.0,
               rate_limit: float = math.inf) -> RestTrace:
    """The closed loop of a rest plan from angles ``initial`` (N + 1,) [rad] at rest (the
    inner rates 0), sampled at ``times`` (n,) [s], its joint rates clipped to ``rate_limit``
    [rad/s] (inf: none): the paper's robot in its closed forms, a chain through
    ``chainflat`` (module docstring).

    Raises
    ------
    FlatcliError for a plan of neither model (an exact plan has no flat outputs).
    """
    if isinstance(plan.model, ChainModel):
        return _track_rest_chain(plan, plan.model, gains, plant, initial, times, fraction,
                                 momentum, rate_limit)
    if not isinstance(plan.model, PaperModel):
        raise FlatcliError("task.rest: a rest plan is tracked through its flat outputs; this "
                           "plan has none")
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
    return RestTrace(np.asarray(times, dtype=float), states[:, :3], applied, states[:, 3:4],
                     fade(times, T, fraction), bool(sol.status == 0), clipped)


def _track_rest_chain(plan: RestPlan, model: ChainModel, gains: Gains, plant: RobotParams,
                      initial: Array, times: Array, fraction: float, momentum: float,
                      rate_limit: float = math.inf) -> RestTrace:
    """``track_rest`` of a chain of N joints (module docstring)."""
    from flatcli.core.models.chainflat import inputs, outputs

    n = model.n_joints
    if gains.n_outputs != n:
        raise FlatcliError(f"track.kp, track.kv: expected {n} gains each (one per flat output), "
                           f"got {gains.n_outputs}")
    kp, kv = np.asarray(gains.kp, dtype=float), np.asarray(gains.kv, dtype=float)
    K_plant = barycentric_matrix(*(np.asarray(v, dtype=float) for v in
                                   (plant.mass, plant.length, plant.com)))
    inertia_plant = np.asarray(plant.inertia, dtype=float)
    T = plan.duration
    weights = np.empty(n + 1)
    y, y_dot = np.empty(n), np.empty(n)
    u_dot = np.empty(n - 1)

    def commands(t: float, x: Array) -> tuple[Array, float]:
        flags = plan.flags(np.array([t]))[0]
        ref, ref_dot, ref_ddot = flags[:n], flags[n:2 * n], flags[2 * n:]
        ff_rate = float(plan.sample(np.array([t])).theta_dot[0, n])
        w = float(fade(t, T, fraction))
        if w == 0.0:
            return ref_ddot[: n - 1].copy(), ff_rate
        theta, u = np.ascontiguousarray(x[: n + 1]), np.ascontiguousarray(x[n + 1:])
        outputs(model.K, model.inertia, theta, u, y, y_dot)
        v = ref_ddot + kv * (ref_dot - y_dot) + kp * (ref - y)
        th_n_dot = float(inputs(model.K, model.inertia, theta, u, v, u_dot))
        return (ref_ddot[: n - 1] + w * (u_dot - ref_ddot[: n - 1]),
                ff_rate + w * (th_n_dot - ff_rate))

    limit = float(rate_limit)

    def rates(t: float, x: Array) -> tuple[Array, Array, bool]:
        accel, th_n_dot = commands(t, x)
        inner = np.clip(x[n + 1:], -limit, limit)
        last = min(max(th_n_dot, -limit), limit)
        # conditional integration: no wind-up while th_j' is clipped
        held = ((x[n + 1:] >= limit) & (accel > 0.0)) | ((x[n + 1:] <= -limit) & (accel < 0.0))
        accel = np.where(held, 0.0, accel)
        momentum_weights(K_plant, inertia_plant, np.ascontiguousarray(x[: n + 1]), weights)
        th0_dot = (momentum - float(weights[1:n] @ inner) - weights[n] * last) / weights[0]
        clipped = bool(np.any(np.abs(inner) >= limit)) or abs(last) >= limit
        return np.array([th0_dot, *inner, last]), accel, clipped

    def rhs(t: float, x: Array) -> Array:
        r, accel, _ = rates(t, x)
        return np.concatenate([r, accel])

    x0 = np.concatenate([np.asarray(initial, dtype=float)[: n + 1], np.zeros(n - 1)])
    with np.errstate(all="ignore"):
        sol = solve_ivp(rhs, (0.0, T), x0, method="DOP853", t_eval=times, rtol=RTOL, atol=ATOL)
    count = len(times)
    states = np.full((count, 2 * n), math.nan)
    states[: sol.y.shape[1]] = sol.y.T
    applied = np.full((count, n + 1), math.nan)
    clipped = np.zeros(count, dtype=bool)
    for i in range(sol.y.shape[1]):
        applied[i], _, clipped[i] = rates(float(times[i]), states[i])
    return RestTrace(np.asarray(times, dtype=float), states[:, : n + 1], applied,
                     states[:, n + 1:], fade(times, T, fraction), bool(sol.status == 0),
                     clipped)


__all__ = ["RestTrace", "fade", "track_rest"]
