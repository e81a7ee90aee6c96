"""Point-to-point plans in flat outputs, and everything a plan implies along its time grid.

A plan is N curves y(t) (the flat outputs of a robot of N joints: y1 = th1, y2 = th0 -
c0 th2 / A for the paper's robot, y_j = th_j and y_N = th0 + I_N th_N / h_0 for a chain)
written in a basis (``basis``: polynomials of any degree or clamped B-splines), with the
boundary values of y and y' imposed exactly. The start and goal configurations fix y(0),
y(T) and, through the forward map (``flatmodel``), y'(0) and y'(T) once the free end rates
of the inner joints th_j'(0), th_j'(T), j < N, are chosen (the paper picks th1' = 0.1 and
0.5). Coefficients the boundary conditions leave free are chosen to minimise the
acceleration energy of y (for a cubic there are none); ``flatcli.core.optimize`` chooses
them otherwise. One planner serves every N and basis; the model answers the rest.

Everything else follows from y through the model's inverse map: th(t), its exact rates
(never from the constraint), the inputs, the signed singularity margin, and H from the full
link kinematics. A plan whose signed margin changes sign or touches zero inside (0, T)
passes through the singular set, where the inverse map is infinite: it is not a plan, and
``plan_point_to_point`` refuses it (``FlatModel.margin_zeros``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.curves.basis import (
    Basis,
    FlatTrajectory,
    PolynomialBasis,
    composite_gauss_legendre,
    quadrature,
)
from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import (
    COMPLEX_STEP,
    Boundary,
    ChainModel,
    FlatModel,
    PaperModel,
    flat_model,
)
from flatcli.core.names import RATE_WARNING, Model
from flatcli.core.robots.dynamics import Chain, inverse_dynamics
from flatcli.core.robots.params import Coefficients, RobotParams, require_flat

Array = NDArray[np.float64]

#: Composite Gauss-Legendre rule of ``Plan.input_energy`` (and the optimiser's energy):
#: pieces of [0, T], nodes per piece.
ENERGY_PIECES = 64
ENERGY_ORDER = 8

__all__ = [
    "COMPLEX_STEP",
    "ENERGY_ORDER",
    "ENERGY_PIECES",
    "RATE_WARNING",
    "Boundary",
    "FlatTrajectory",
    "Plan",
    "PlanSamples",
    "boundary_system",
    "fastest_joint",
    "min_acceleration_trajectory",
    "plan_chain",
    "plan_point_to_point",
    "rate_warning_text",
]


@dataclass(frozen=True)
class BoundarySystem:
    """The boundary conditions of a basis as a linear system E c = r for one output.

    Attributes
    ----------
    matrix : (4, size) E, rows phi(0), phi'(0), phi(T), phi'(T)
    particular : (size, 4) E^+, so that E^+ r meets the conditions
    null : (size, size - 4) an orthonormal basis of the null space of E (the coefficients
        the conditions leave free)
    """

    matrix: Array
    particular: Array
    null: Array


@functools.lru_cache(maxsize=64)
def boundary_system(basis: Basis) -> BoundarySystem:  # bases are frozen dataclasses
    """``BoundarySystem`` of a basis (computed once per basis; arrays read-only).

    Raises
    ------
    FlatcliError if the basis is too small or cannot meet arbitrary boundary values.
    """
    ends = np.array([0.0, basis.duration])
    E = np.vstack(
        [
            basis.matrix(ends[:1], 0),
            basis.matrix(ends[:1], 1),
            basis.matrix(ends[1:], 0),
            basis.matrix(ends[1:], 1),
        ]
    )
    if basis.size < E.shape[0]:
        raise FlatcliError(f"plan basis: needs >= 4 coefficients, got {basis.size}")
    P: Array = np.linalg.pinv(E).astype(float)
    if not np.allclose(E @ P, np.eye(E.shape[0]), atol=1e-9):
        raise FlatcliError("plan basis: cannot meet the boundary conditions")
    if basis.size == E.shape[0]:  # a cubic: E is square and regular, nothing is left free
        N = np.zeros((basis.size, 0))
    else:
        from scipy.linalg import null_space  # a richer basis only: a cubic's sweep needs none

        N = np.ascontiguousarray(null_space(E))
    for a in (E, P, N):
        a.setflags(write=False)
    return BoundarySystem(E, P, N)


def boundary_rhs(boundary: Boundary) -> Array:
    """(..., 4, N): y(0), y'(0), y(T), y'(T) of the N outputs, matching ``BoundarySystem``."""
    return np.stack(
        [boundary.y_start, boundary.y_dot_start, boundary.y_goal, boundary.y_dot_goal], axis=-2
    )


def acceleration_gram(basis: Basis) -> Array:
    """(size, size): integral over [0, T] of phi''(t) phi''(t)^T (exact Gauss quadrature)."""
    nodes, weights = quadrature(basis, basis.size + 2)
    d2 = basis.matrix(nodes, 2)
    return (d2 * weights[:, None]).T @ d2


@functools.lru_cache(maxsize=64)
def min_acceleration_operator(basis: Basis) -> Array:
    """(size, 4): coefficients = K @ (y(0), y'(0), y(T), y'(T)) of one output (read-only).

    The least integral of |y''|^2 among the curves of the basis meeting the boundary
    conditions: c = (I - N (N^T Q N)^-1 N^T Q) E^+ r, with E the boundary matrix, N a basis
    of its null space and Q the acceleration Gram matrix. It depends on the basis only, so
    it is computed once per basis.
    """
    system = boundary_system(basis)  # type: ignore[arg-type]
    K = system.particular.copy()
    null = system.null
    if null.shape[1]:
        Q = acceleration_gram(basis)
        K = K - null @ np.linalg.solve(null.T @ Q @ null, null.T @ Q @ K)
    K.setflags(write=False)
    return K


def min_acceleration_trajectory(basis: Basis, boundary: Boundary) -> FlatTrajectory:
    """The y(t) in the basis meeting the boundary conditions with least integral of |y''|^2.

    For a cubic the boundary conditions fix it; for a richer basis this is still the cubic
    when the basis contains it (the cubic Hermite curve minimises that integral). A batch of
    boundary conditions (fields (..., N)) gives a batch of curves.
    """
    operator = min_acceleration_operator(basis)  # type: ignore[arg-type]
    coefficients = operator @ boundary_rhs(boundary)  # (..., size, 2)
    return FlatTrajectory(basis, np.ascontiguousarray(np.swapaxes(coefficients, -1, -2)))


@dataclass(frozen=True)
class PlanSamples:
    """A plan of N joints evaluated on a time grid of n points; a batch of plans adds
    leading axes (...). For the paper's robot N = 2."""

    t: Array  # (n,) [s]
    theta: Array  # (..., n, N + 1) [rad]
    theta_dot: Array  # (..., n, N + 1) [rad/s], exact derivative of the inverse map
    u_dot: Array  # (..., n, N - 1) [rad/s^2], the prolonged inputs u_j' = th_j''
    y: Array  # (..., n, N) [rad]
    y_dot: Array  # (..., n, N) [rad/s]
    y_ddot: Array  # (..., n, N) [rad/s^2]
    margin: Array  # (..., n) |sigma|: |sin y1 y1'| for N = 2 [rad/s]
    momentum: Array  # (..., n) H from the full kinematics of the planning robot [kg m^2/s]

    @property
    def u1_dot(self) -> Array:
        """(..., n) u1' = th1'' [rad/s^2]."""
        return self.u_dot[..., 0]

    @property
    def u2(self) -> Array:
        """(..., n) th2' [rad/s] (the paper's second input, N = 2)."""
        return self.theta_dot[..., 2]


@dataclass(frozen=True)
class Plan:
    """A planned maneuver: the flat curves, the robot and the flat model it was planned for
    (which the controller believes too)."""

    robot: RobotParams
    model: FlatModel
    trajectory: FlatTrajectory  # coefficients (N, size), or (..., N, size) for a batch
    duration: float

    @property
    def n_joints(self) -> int:
        """N, the robot's joints."""
        return self.model.n_joints

    @property
    def coefficients(self) -> Coefficients:
        """The paper's constraint coefficients the plan was made with (the three-link robot
        in closed form only: ``flatmodel.PaperModel``)."""
        if not isinstance(self.model, PaperModel):
            raise FlatcliError("plan: the constraint coefficients exist for the paper's "
                               "three-link robot in closed form only")
        return self.model.coefficients

    def flags(self, t: Array) -> Array:
        """(..., n, 3 N) y, y', y'' at times t (n,) [s]."""
        return np.ascontiguousarray(np.concatenate(
            [self.trajectory.derivative(t, k) for k in range(3)], axis=-1))

    @classmethod
    def flags_of(cls, plans: Sequence[Plan], t: Array) -> Array:
        """(P, n, 3 N) ``flags`` of P plans of this class that share their basis (and its
        size), at times t (n,) [s], in one evaluation."""
        stacked = FlatTrajectory(plans[0].trajectory.basis,
                                 np.stack([p.trajectory.coefficients for p in plans]))
        return np.ascontiguousarray(np.concatenate(
            [stacked.derivative(t, k) for k in range(3)], axis=-1))

    @classmethod
    def states_of(cls, plans: Sequence[Plan], t: Array) -> tuple[Array, Array, Array]:
        """The angles theta (P, n, N + 1) [rad], their rates theta_dot (P, n, N + 1) [rad/s]
        and the margin (P, n) [rad/s] of P plans of this class sharing their robot, model,
        basis and duration, at times t (n,) [s]: ``sample``'s fields for many candidate plans
        in one evaluation (what screening them needs)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        flags = cls.flags_of(plans, t)
        rows = flags.reshape(-1, flags.shape[-1])
        theta, theta_dot, _, sigma = plans[0].model.flags_to_states(rows)
        shape = (len(plans), len(t))
        return (theta.reshape(*shape, -1), theta_dot.reshape(*shape, -1),
                np.abs(np.asarray(sigma)).reshape(shape))

    def sample(self, t: Array) -> PlanSamples:
        """Evaluate the plan at times t (n,) [s] within [0, duration]."""
        t = np.asarray(t, dtype=float)
        flags = self.flags(t)
        theta, theta_dot, u_dot, sigma = self.model.flags_to_states(flags)
        y, y_dot, y_ddot = self.model.flag_outputs(flags)
        return PlanSamples(
            t=t, theta=theta, theta_dot=theta_dot, u_dot=u_dot, y=y, y_dot=y_dot,
            y_ddot=y_ddot, margin=np.abs(np.asarray(sigma)),
            momentum=self.momentum(theta, theta_dot),
        )

    def momentum(self, theta: Array, theta_dot: Array) -> Array:
        """H [kg m^2/s] of the planning robot from its full link kinematics at angles theta
        and rates theta_dot (..., N + 1) (``FlatModel.momentum``)."""
        return self.model.momentum(self.robot, theta, theta_dot)

    def signed_margin(self, t: Array) -> Array:
        """(n,) the signed margin along the plan [rad/s]."""
        return np.asarray(self.model.signed_margin(self.flags(np.asarray(t, dtype=float))))

    def evaluate(self, t: Array) -> tuple[Array, Array]:
        """States and inputs only (what a controller needs; cheaper than ``sample``).

        Parameters
        ----------
        t : (n,) times [s]

        Returns
        -------
        state : (..., n, 2 N) th0..thN [rad], u_1..u_N-1 [rad/s]
        inputs : (..., n, N) u_1'..u_N-1' [rad/s^2], th_N' [rad/s]
        """
        t = np.asarray(t, dtype=float)
        fast = self.model.fast_evaluate(self.trajectory, t)
        if fast is not None:
            return fast
        n = self.n_joints
        theta, theta_dot, u_dot, _ = self.model.flags_to_states(self.flags(t))
        state = np.concatenate([theta, theta_dot[..., 1:n]], axis=-1)
        return state, np.concatenate([u_dot, theta_dot[..., n:]], axis=-1)

    def motion(self, t: Array) -> tuple[Array, Array, Array]:
        """The angles q (n, N + 1) [rad], rates q' [rad/s] and accelerations q'' [rad/s^2] the
        plan asks of the robot at times t (n,) [s], exactly (``FlatModel.motion``)."""
        return self.model.motion(self.trajectory, t)

    def torques(self, chain: Chain, t: Array) -> Array:
        """The generalised forces M q'' + C q' the plan asks of a robot (its ``dynamics.Chain``)
        at times t (n,) [s]: (n, N + 1) [N m], the base's first (dH/dt: ~0 for a plan of this
        robot), then the joint torques an ideal actuator would apply
        (``dynamics.inverse_dynamics``)."""
        q, q_dot, q_ddot = self.motion(t)
        return inverse_dynamics(chain, q, q_dot, q_ddot)

    def grid(self, samples: int) -> Array:
        """(samples,) equally spaced times over [0, duration] [s]."""
        return np.linspace(0.0, self.duration, samples)

    def input_energy(self, pieces: int = ENERGY_PIECES, order: int = ENERGY_ORDER) -> float:
        """Integral over [0, T] of the sum of the joint rates squared, th_1'^2 + ... + th_N'^2
        [rad^2/s] (composite Gauss-Legendre)."""
        t, weights = composite_gauss_legendre(self.duration, pieces, order)
        rates = self.sample(t).theta_dot
        if rates.ndim > 2:
            raise ValueError("input_energy: one plan at a time")
        return float(weights @ np.sum(rates[:, 1:] ** 2, axis=1))

    def margin_zeros(self) -> Array:
        """Times in (0, T) where the plan meets the singular set [s]
        (``FlatModel.margin_zeros``)."""
        return self.model.margin_zeros(self.trajectory)


def fastest_joint(samples: PlanSamples) -> tuple[int, float, float]:
    """(j, peak, t): the joint j in 1..N whose rate abs(th_j') is largest on a plan's samples,
    that peak [rad/s] (inf if a rate is not finite) and its time [s] (one plan)."""
    rates = np.abs(np.asarray(samples.theta_dot, dtype=float)[:, 1:])
    rates = np.where(np.isnan(rates), np.inf, rates)
    where = int(np.argmax(rates))
    k, j = divmod(where, rates.shape[1])
    return j + 1, float(rates[k, j]), float(samples.t[k])


def rate_warning_text(samples: PlanSamples, limit: float) -> str:
    """One line when a plan's fastest joint (``fastest_joint``) exceeds ``limit`` [rad/s]
    (``plan.rate_warning``) on its samples, naming the joint, the peak and the time; "" when
    it does not."""
    joint, peak, when = fastest_joint(samples)
    if peak <= limit:
        return ""
    return (f"warning: the plan's th{joint}' reaches {peak:.4g} rad/s at t = {when:.4g} s, "
            f"above plan.rate_warning = {limit:g} rad/s")


def plan_point_to_point(
    robot: RobotParams,
    start: ArrayLike,
    goal: ArrayLike,
    start_rate: ArrayLike,
    goal_rate: ArrayLike,
    duration: float,
    model: Model | FlatModel = "derived",
    basis: Basis | None = None,
) -> Plan:
    """Flatness-based plan from ``start`` to ``goal`` in ``duration`` seconds, any N.

    Parameters
    ----------
    robot : a design whose closed-form flat outputs apply (``model.flatness_check``)
    start, goal : (N + 1,) configurations th0..thN [rad]; for the paper's robot a batch
        (..., 3) of configurations (and of rates) plans a batch of maneuvers at once
    start_rate, goal_rate : the inner joints' rates th_1'..th_N-1' at the ends [rad/s]
        (non-zero margin): N - 1 numbers, or one for all
    duration : T [s] > 0
    model : which constraint coefficients the planner believes ("paper": the printed ones,
        three links only), or the flat model itself (e.g. the general ``ChainModel`` of a
        three-link robot, whose closed form ``flat_model`` would pick)
    basis : default: cubic polynomials, the paper's choice

    Returns
    -------
    Plan

    Raises
    ------
    FlatcliError, one line naming the key: a design whose outputs do not apply, an end on
    the singular set, or a plan that meets the singular set inside (0, T).
    """
    require_flat(robot)
    if not (duration > 0 and math.isfinite(duration)):
        raise FlatcliError(f"plan.duration: must be a finite number > 0 s, got {duration}")
    flat = model if isinstance(model, FlatModel) else flat_model(robot, model)
    if basis is None:
        basis = PolynomialBasis(3, duration)
    elif not math.isclose(basis.duration, duration):
        raise FlatcliError("plan basis: its duration differs from plan.duration")
    boundary = flat.boundary(start, goal, start_rate, goal_rate)
    trajectory = min_acceleration_trajectory(basis, boundary)
    flat.require_off_singular_set(trajectory)
    return Plan(robot, flat, trajectory, float(duration))


def plan_chain(robot: RobotParams, start: ArrayLike, goal: ArrayLike, start_rate: ArrayLike,
               goal_rate: ArrayLike, duration: float, basis: Basis | None = None) -> Plan:
    """``plan_point_to_point`` through the general N-link model (``flatmodel.ChainModel``)
    for any N, the paper's robot included (whose closed form ``flat_model`` would pick):
    to compare the two, or to run the general code on N = 2."""
    return plan_point_to_point(robot, start, goal, start_rate, goal_rate, duration,
                               ChainModel.of(robot), basis)
