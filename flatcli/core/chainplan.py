"""Point-to-point plans of an N-link chain in its flat outputs (``chainflat``), N >= 2.

The same construction as the paper's robot (``planning``), one output per joint: y_j = th_j
for j < N and y_N = th0 + I_N th_N / h_0. The start and goal configurations and the free
end rates th_j'(0), th_j'(T) (j < N) fix y and y' at both ends through the forward map;
each output is the least-acceleration curve of the basis meeting them (the paper's cubic by
default). Everything else follows from y through ``chainflat.flag_state``: the angles, their
exact rates (never from the constraint), the inputs, and the signed margin
sigma = -(dh_0/dt) / (2 K_10), which must keep its sign inside (0, T): a plan on which the
base's locked inertia h_0 stops changing passes through the singular set and is refused.

For N = 2 ``planning.plan_point_to_point`` keeps the paper's closed forms (and their
exact polynomial root test of the margin); ``plan_chain`` serves N >= 3 and agrees with it
for N = 2 (tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core._jit import allocating_kernel
from flatcli.core.basis import Basis, PolynomialBasis, composite_gauss_legendre
from flatcli.core.chain import barycentric_matrix, chain_momentum
from flatcli.core.chainflat import flag_state, outputs
from flatcli.core.model import FlatcliError, RobotParams, require_flat
from flatcli.core.planning import (
    ENERGY_ORDER,
    ENERGY_PIECES,
    Boundary,
    FlatPlan,
    FlatTrajectory,
    PlanSamples,
    min_acceleration_trajectory,
)

Array = NDArray[np.float64]
#: Real or complex arrays (the flag map is complex-step safe).
AnyArray = NDArray[Any]

#: Samples per unit of (pieces x degree) in the scan for sign changes of the margin.
MARGIN_SCAN = 64


@dataclass(frozen=True)
class ChainModel:
    """What the planner and the controller believe of a chain: K and the inertias.

    Attributes
    ----------
    K : (N + 1, N + 1) ``chain.barycentric_matrix`` [kg m^2] (d_N = 0: last row zero)
    inertia : (N + 1,) [kg m^2]
    """

    K: Array
    inertia: Array

    @classmethod
    def of(cls, robot: RobotParams) -> ChainModel:
        mass, length, com = (np.asarray(v, dtype=float) for v in
                             (robot.mass, robot.length, robot.com))
        return cls(np.ascontiguousarray(barycentric_matrix(mass, length, com)),
                   np.asarray(robot.inertia, dtype=float))

    @property
    def n_joints(self) -> int:
        return int(self.inertia.shape[0]) - 1


@allocating_kernel
def _flags_to_states(K: Array, inertia: Array, flags: AnyArray, theta: AnyArray,
                     theta_dot: AnyArray, u_dot: AnyArray, sigma: AnyArray) -> None:
    """``flag_state`` at every row of flags (n, 3 N): y, y', y'' (real or complex, the
    outputs of the same dtype)."""
    n_out = flags.shape[1] // 3
    for i in range(flags.shape[0]):
        sigma[i] = flag_state(K, inertia, flags[i, :n_out], flags[i, n_out:2 * n_out],
                              flags[i, 2 * n_out:], theta[i], theta_dot[i], u_dot[i])


def flags_to_states(model: ChainModel, flags: NDArray[np.generic]
                    ) -> tuple[NDArray[np.generic], ...]:
    """``chainflat.flag_state`` at every row of ``flags`` (n, 3 N): y, y', y''.

    Real or complex (complex step): the outputs take the dtype of ``flags``.

    Returns
    -------
    theta (n, N + 1) [rad], theta_dot (n, N + 1) [rad/s], u_dot (n, N - 1) [rad/s^2],
    sigma (n,) [rad/s]; inf/nan on the singular set
    """
    flags = np.ascontiguousarray(flags)
    count, n = flags.shape[0], model.n_joints
    theta = np.empty((count, n + 1), dtype=flags.dtype)
    theta_dot = np.empty((count, n + 1), dtype=flags.dtype)
    u_dot = np.empty((count, n - 1), dtype=flags.dtype)
    sigma = np.empty(count, dtype=flags.dtype)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        _flags_to_states(model.K, model.inertia, flags, theta, theta_dot, u_dot, sigma)
    return theta, theta_dot, u_dot, sigma


def chain_boundary(model: ChainModel, start: ArrayLike, goal: ArrayLike, start_rate: ArrayLike,
                   goal_rate: ArrayLike) -> Boundary:
    """Flat boundary values (fields (N,)) for moving from ``start`` to ``goal`` (N + 1,) [rad]
    with joint rates th_j' (j < N) ``start_rate``, ``goal_rate`` (N - 1,) [rad/s] at the ends.

    Raises FlatcliError if an end lies on the singular set (sigma = 0 there).
    """
    n = model.n_joints
    ends = []
    for side, theta, rate in (("start", start, start_rate), ("goal", goal, goal_rate)):
        th = np.asarray(theta, dtype=float)
        u = np.atleast_1d(np.asarray(rate, dtype=float))
        if th.shape != (n + 1,):
            raise FlatcliError(f"plan.{side}: expected {n + 1} angles (th0..th{n}), got {th.size}")
        if u.shape != (n - 1,):
            raise FlatcliError(
                f"plan.{side}_rate: expected {n - 1} rates (th1'..th{n - 1}'), got {u.size}")
        y, y_dot = np.empty(n), np.empty(n)
        sigma = outputs(model.K, model.inertia, th, u, y, y_dot)
        if not (math.isfinite(sigma) and abs(sigma) > 1e-9):
            raise FlatcliError(
                f"plan.{side}_rate: the margin -(dh_0/dt) / (2 K_10) is {sigma:.3g} rad/s at the "
                f"{side}: the base's locked inertia is stationary there (the singular set); "
                "choose other end rates"
            )
        ends.append((y, y_dot))
    (y0, yd0), (yT, ydT) = ends
    return Boundary(y0, yd0, yT, ydT)


@dataclass(frozen=True)
class ChainPlan:
    """A planned maneuver of an N-link chain: the flat curves, the robot and its model."""

    robot: RobotParams
    model: ChainModel
    trajectory: FlatTrajectory  # coefficients (N, size)
    duration: float
    n_joints: int = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_joints", self.model.n_joints)

    def flags(self, t: Array) -> Array:
        """(n, 3 N) y, y', y'' at times t (n,) [s]."""
        return np.ascontiguousarray(np.hstack([self.trajectory.derivative(t, k)
                                               for k in range(3)]))

    def sample(self, t: Array) -> PlanSamples:
        """Evaluate the plan at times t (n,) [s] within [0, duration]."""
        t = np.asarray(t, dtype=float)
        n = self.n_joints
        flags = self.flags(t)
        theta = np.empty((t.size, n + 1))
        theta_dot = np.empty((t.size, n + 1))
        u_dot = np.empty((t.size, n - 1))
        sigma = np.empty(t.size)
        with np.errstate(divide="ignore", invalid="ignore"):
            _flags_to_states(self.model.K, self.model.inertia, flags, theta, theta_dot, u_dot,
                             sigma)
        mass, inertia, length, com = (np.asarray(v, dtype=float) for v in
                                      (self.robot.mass, self.robot.inertia, self.robot.length,
                                       self.robot.com))
        return PlanSamples(
            t=t, theta=theta, theta_dot=theta_dot, u_dot=u_dot, y=flags[:, :n],
            y_dot=flags[:, n:2 * n], y_ddot=flags[:, 2 * n:], margin=np.abs(sigma),
            momentum=chain_momentum(mass, inertia, length, com, theta, theta_dot),
        )

    def signed_margin(self, t: Array) -> Array:
        """(n,) sigma = -(dh_0/dt) / (2 K_10) along the plan [rad/s]."""
        t = np.asarray(t, dtype=float)
        n = self.n_joints
        sigma = np.empty(t.size)
        _flags_to_states(self.model.K, self.model.inertia, self.flags(t),
                         np.empty((t.size, n + 1)), np.empty((t.size, n + 1)),
                         np.empty((t.size, n - 1)), sigma)
        return sigma

    def grid(self, samples: int) -> Array:
        """(samples,) equally spaced times over [0, duration] [s]."""
        return np.linspace(0.0, self.duration, samples)

    def input_energy(self, pieces: int = ENERGY_PIECES, order: int = ENERGY_ORDER) -> float:
        """Integral over [0, T] of the sum of th_j'^2 over the joints [rad^2/s]."""
        t, weights = composite_gauss_legendre(self.duration, pieces, order)
        rates = self.sample(t).theta_dot[:, 1:]
        return float(weights @ np.sum(rates**2, axis=1))

    def margin_zeros(self) -> Array:
        """Times in (0, T) where sigma changes sign or touches zero [s]: bracketed on a
        scan of ``MARGIN_SCAN`` samples per polynomial piece and degree, refined by Brent's
        method; a local minimum of |sigma| within 1e-9 of zero counts as touching."""
        from scipy.optimize import brentq, minimize_scalar

        breaks, local = self.trajectory.piecewise()
        count = MARGIN_SCAN * (len(breaks) - 1) * local.shape[1] + 1
        t = np.linspace(0.0, self.duration, count)
        sigma = self.signed_margin(t)
        zeros: list[float] = []

        def at(x: float) -> float:
            return float(self.signed_margin(np.array([x]))[0])

        for i in range(count - 1):
            a, b = sigma[i], sigma[i + 1]
            if a == 0.0 and i > 0:
                zeros.append(float(t[i]))
            elif (a > 0) != (b > 0) and b != 0.0:
                zeros.append(float(brentq(at, t[i], t[i + 1], xtol=1e-12)))
        size = float(np.max(np.abs(sigma)))
        for i in range(1, count - 1):  # touching: a local minimum of |sigma| near zero
            if abs(sigma[i]) <= abs(sigma[i - 1]) and abs(sigma[i]) <= abs(sigma[i + 1]):
                found = minimize_scalar(lambda x: abs(at(x)), bounds=(t[i - 1], t[i + 1]),
                                        method="bounded", options={"xatol": 1e-12})
                if abs(found.fun) <= 1e-9 * max(size, 1e-12):
                    zeros.append(float(found.x))
        inside = [z for z in zeros if 0.0 < z < self.duration]
        return np.unique(np.round(np.asarray(inside, dtype=float), 12))


#: A planned maneuver: the paper's robot's (``planning.FlatPlan``) or an N-link chain's.
Plan = FlatPlan | ChainPlan


def plan_chain(
    robot: RobotParams,
    start: ArrayLike,
    goal: ArrayLike,
    start_rate: ArrayLike,
    goal_rate: ArrayLike,
    duration: float,
    basis: Basis | None = None,
) -> ChainPlan:
    """Flatness-based plan of an N-link chain from ``start`` to ``goal`` (N + 1,) [rad].

    Parameters
    ----------
    robot : a chain with d_N = 0 and K_10 != 0 (``model.flatness_check``)
    start, goal : (N + 1,) th0..thN [rad]
    start_rate, goal_rate : (N - 1,) th_1'..th_N-1' at the ends [rad/s]
    duration : T [s] > 0
    basis : default: cubic polynomials

    Raises
    ------
    FlatcliError naming the key: a design whose outputs do not apply, an end on the singular
    set, or a plan whose margin changes sign or touches zero inside (0, T).
    """
    require_flat(robot)
    if not (duration > 0 and math.isfinite(duration)):
        raise FlatcliError(f"plan.duration: must be a finite number > 0 s, got {duration}")
    if basis is None:
        basis = PolynomialBasis(3, duration)
    elif not math.isclose(basis.duration, duration):
        raise FlatcliError("plan basis: its duration differs from plan.duration")
    model = ChainModel.of(robot)
    boundary = chain_boundary(model, start, goal, start_rate, goal_rate)
    plan = ChainPlan(robot, model, min_acceleration_trajectory(basis, boundary), float(duration))
    zeros = plan.margin_zeros()
    if zeros.size:
        raise FlatcliError(
            f"plan: the margin -(dh_0/dt) / (2 K_10) is zero at t = {zeros[0]:.4g} s inside the "
            "maneuver: the plan crosses the singular set, where the flat map is infinite; "
            "change plan.start_rate / plan.goal_rate or plan.duration"
        )
    return plan
