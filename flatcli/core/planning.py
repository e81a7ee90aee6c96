"""Point-to-point plans in flat outputs, and everything a plan implies along its time grid.

A plan is a pair of curves y(t) = (y1, y2) written in a basis (``basis``: polynomials of any
degree or clamped B-splines), with the boundary values of y and y' imposed exactly. The start
and goal configurations fix y(0), y(T) and, through the forward map, y2'(0) and y2'(T) once
the free end rates th1'(0) = y1'(0) and th1'(T) = y1'(T) are chosen (the paper picks 0.1 and
0.5). Coefficients the boundary conditions leave free are chosen to minimise the acceleration
energy of y (for a cubic there are none); ``flatcli.core.optimize`` chooses them otherwise.

Everything else follows from y through ``flatness.flag_state``: th(t), u1' and u2, and th'(t)
(here by complex step through the inverse map along the flat flag: no finite difference, and
never from the constraint), the singularity margin, and H from the full link kinematics.

A plan whose signed margin sin(y1) y1' changes sign or touches zero inside (0, T) passes
through the singular set, where the inverse map is infinite: it is not a plan, and
``plan_point_to_point`` refuses it (``margin_zeros`` finds those times exactly, from the
roots of the piecewise polynomials y1' and y1 - k pi).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core._jit import allocating_kernel
from flatcli.core.basis import Basis, PolynomialBasis, composite_gauss_legendre, quadrature
from flatcli.core.flatness import flag_state, flat_outputs, flat_state, singularity_margin
from flatcli.core.model import (
    Coefficients,
    FlatcliError,
    Model,
    RobotParams,
    momentum,
    require_flat,
)

Array = NDArray[np.float64]

#: Complex-step size: derivatives exact to rounding, since no difference is taken.
COMPLEX_STEP = 1e-30

#: Composite Gauss-Legendre rule of ``FlatPlan.input_energy`` (and the optimiser's energy):
#: pieces of [0, T], nodes per piece.
ENERGY_PIECES = 64
ENERGY_ORDER = 8

#: A root of y1' (or of y1 - k pi) with |imaginary part| below this (relative to 1 + |root|)
#: counts as real: a double root, where the margin touches zero, comes out as a close pair.
ROOT_IMAG_TOL = 1e-7


@dataclass(frozen=True)
class FlatTrajectory:
    """y(t) = coefficients @ phi(t): coefficients (..., 2, size) in a basis."""

    basis: Basis
    coefficients: Array

    def derivative(self, t: Array, order: int) -> Array:
        """(..., n, 2): d^order y / dt^order at times t (n,) [rad/s^order]."""
        phi = self.basis.matrix(np.atleast_1d(np.asarray(t, dtype=float)), order)
        return phi @ np.swapaxes(self.coefficients, -1, -2)

    def piecewise(self) -> tuple[Array, Array]:
        """One curve as piecewise polynomials: ``Basis.piecewise`` of its coefficients."""
        if self.coefficients.ndim != 2:
            raise ValueError("FlatTrajectory.piecewise: one plan at a time")
        return self.basis.piecewise(self.coefficients)


@dataclass(frozen=True)
class Boundary:
    """Flat boundary conditions: y and y' at t = 0 and t = T, each (2,)."""

    y_start: Array
    y_dot_start: Array
    y_goal: Array
    y_dot_goal: Array


def boundary_conditions(
    k: Coefficients,
    start: ArrayLike,
    goal: ArrayLike,
    start_rate: ArrayLike,
    goal_rate: ArrayLike,
) -> Boundary:
    """Flat boundary values for moving from configuration ``start`` to ``goal``.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    start, goal : (..., 3) th0, th1, th2 [rad]
    start_rate, goal_rate : (...) th1' at the two ends [rad/s], the free choice of the paper

    Returns
    -------
    Boundary with fields (..., 2)

    Raises
    ------
    FlatcliError if an end lies on the singular set (sin th1 = 0 or th1' = 0).
    """
    if np.ndim(start_rate) == 0 and np.ndim(goal_rate) == 0 and np.shape(start) == (3,) == (
        np.shape(goal)
    ):
        return _one_boundary(k, start, goal, float(start_rate), float(goal_rate))  # type: ignore[arg-type]
    # both ends in one vectorised evaluation: axis -1 of ends is (start, goal)
    ends = np.stack(np.broadcast_arrays(np.asarray(start, float), np.asarray(goal, float)),
                    axis=-1)  # (..., 3, 2)
    rates = np.stack(np.broadcast_arrays(np.asarray(start_rate, float),
                                         np.asarray(goal_rate, float)), axis=-1)  # (..., 2)
    if not np.all(rates != 0):
        key = "plan.start_rate" if np.any(rates[..., 0] == 0) else "plan.goal_rate"
        raise FlatcliError(f"{key}: must be != 0, the flat map is singular where th1' = 0")
    near = np.abs(np.sin(ends[..., 1, :])) < 1e-9
    if np.any(near):
        side = 0 if np.any(near[..., 0]) else 1
        th1 = float(ends[..., 1, side][near[..., side]].flat[0])
        raise FlatcliError(
            f"plan.{('start', 'goal')[side]}[1] = {th1:g} rad lies on the singular set "
            "sin th1 = 0; choose th1 away from multiples of pi"
        )
    y1, y2, y1_dot, y2_dot = flat_outputs(k, ends[..., 0, :], ends[..., 1, :], ends[..., 2, :],
                                          rates)
    y = np.stack(np.broadcast_arrays(y1, y2), axis=-1)  # (..., end, output)
    y_dot = np.stack(np.broadcast_arrays(y1_dot, y2_dot), axis=-1)
    return Boundary(y[..., 0, :], y_dot[..., 0, :], y[..., 1, :], y_dot[..., 1, :])


def _one_boundary(
    k: Coefficients, start: Sequence[float], goal: Sequence[float], start_rate: float,
    goal_rate: float,
) -> Boundary:
    """``boundary_conditions`` of one maneuver, in plain floats (numpy's per-call overhead
    would dominate a single plan)."""
    flags = []
    for side, theta, rate in (("start", start, start_rate), ("goal", goal, goal_rate)):
        th0, th1, th2 = (float(v) for v in theta)
        if rate == 0:
            raise FlatcliError(
                f"plan.{side}_rate: must be != 0, the flat map is singular where th1' = 0"
            )
        if abs(math.sin(th1)) < 1e-9:
            raise FlatcliError(
                f"plan.{side}[1] = {th1:g} rad lies on the singular set sin th1 = 0; "
                "choose th1 away from multiples of pi"
            )
        flags.append(flat_outputs(k, th0, th1, th2, rate))
    (a1, a2, a1d, a2d), (b1, b2, b1d, b2d) = flags
    return Boundary(np.array([a1, a2]), np.array([a1d, a2d]), np.array([b1, b2]),
                    np.array([b1d, b2d]))


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
    from scipy.linalg import null_space

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
    N = np.ascontiguousarray(null_space(E))
    for a in (E, P, N):
        a.setflags(write=False)
    return BoundarySystem(E, P, N)


def boundary_rhs(boundary: Boundary) -> Array:
    """(..., 4, 2): y(0), y'(0), y(T), y'(T) of both outputs, matching ``BoundarySystem``."""
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
    boundary conditions (fields (..., 2)) gives a batch of curves.
    """
    operator = min_acceleration_operator(basis)  # type: ignore[arg-type]
    coefficients = operator @ boundary_rhs(boundary)  # (..., size, 2)
    return FlatTrajectory(basis, np.ascontiguousarray(np.swapaxes(coefficients, -1, -2)))


def _unit_interval_roots(a: Array) -> list[float]:
    """Real roots in [0, 1] of the polynomial sum_j a_j s^j (exact zero: every s is one)."""
    scale = float(np.max(np.abs(a)))
    if scale == 0.0:
        return [0.0]
    trimmed = np.trim_zeros(np.where(np.abs(a) > 1e-14 * scale, a, 0.0), "b")
    if trimmed.size <= 1:
        return []
    roots = np.polynomial.polynomial.polyroots(trimmed)
    real = roots.real[np.abs(roots.imag) <= ROOT_IMAG_TOL * (1.0 + np.abs(roots.real))]
    return sorted(float(r) for r in real if 0.0 <= r <= 1.0)


def margin_zeros(trajectory: FlatTrajectory) -> Array:
    """Times in (0, T) where the signed margin sin(y1) y1' of one plan is zero [s].

    y1' = 0 at the real roots of y1' on each polynomial piece (double roots included, where
    the margin touches zero without changing sign); sin y1 = 0 where y1 = k pi between the
    extremes of y1. Empty for a plan that stays off the singular set.
    """
    breaks, local = trajectory.piecewise()
    y1 = local[:, :, 0]  # (m, degree + 1) in s on each piece
    powers = np.arange(1, y1.shape[1])
    times: list[float] = []
    values = [float(y1[0, 0]), float(np.sum(y1[-1]))]  # y1(0), y1(T)
    for i in range(y1.shape[0]):
        lo, width = float(breaks[i]), float(breaks[i + 1] - breaks[i])
        for s in _unit_interval_roots(y1[i, 1:] * powers):  # dy1/ds
            times.append(lo + width * s)
            values.append(float(np.polynomial.polynomial.polyval(s, y1[i])))
    low, high = min(values), max(values)
    for k in range(math.ceil(low / math.pi), math.floor(high / math.pi) + 1):
        shifted = y1.copy()
        shifted[:, 0] -= k * math.pi
        for i in range(y1.shape[0]):
            lo, width = float(breaks[i]), float(breaks[i + 1] - breaks[i])
            times.extend(lo + width * s for s in _unit_interval_roots(shifted[i]))
    duration = float(breaks[-1])
    inside = [t for t in times if 0.0 < t < duration]
    return np.unique(np.asarray(inside, dtype=float))


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


def state_and_rates(k: Coefficients, y: Array, y_dot: Array, y_ddot: Array) -> tuple[Array, Array]:
    """State and its exact time derivative along a flat curve.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    y, y_dot, y_ddot : (..., 2) flat outputs and two derivatives

    Returns
    -------
    state : (..., 4) th0, th1, th2 [rad], u1 [rad/s]
    state_dot : (..., 4) th0', th1', th2' [rad/s], u1' [rad/s^2] (complex step)
    """
    z = [y[..., 0], y[..., 1], y_dot[..., 0], y_dot[..., 1]]
    dz = [y_dot[..., 0], y_dot[..., 1], y_ddot[..., 0], y_ddot[..., 1]]
    with np.errstate(divide="ignore", invalid="ignore"):
        state = np.stack(flat_state(k, *z), axis=-1)
        perturbed = [zi + 1j * COMPLEX_STEP * dzi for zi, dzi in zip(z, dz, strict=True)]
        state_dot = np.stack(flat_state(k, *perturbed), axis=-1).imag / COMPLEX_STEP
    return state, state_dot


@dataclass(frozen=True)
class FlatPlan:
    """A planned maneuver: the flat curve, the robot and model it was planned for."""

    robot: RobotParams
    model: Model
    coefficients: Coefficients
    trajectory: FlatTrajectory
    duration: float

    def sample(self, t: Array) -> PlanSamples:
        """Evaluate the plan at times t (n,) [s] within [0, duration]."""
        t = np.asarray(t, dtype=float)
        y = self.trajectory.derivative(t, 0)
        y_dot = self.trajectory.derivative(t, 1)
        y_ddot = self.trajectory.derivative(t, 2)
        state, state_dot = state_and_rates(self.coefficients, y, y_dot, y_ddot)
        theta, theta_dot = state[..., :3], state_dot[..., :3]
        H = momentum(self.robot.links, *np.moveaxis(theta, -1, 0), *np.moveaxis(theta_dot, -1, 0))
        return PlanSamples(
            t=t,
            theta=theta,
            theta_dot=theta_dot,
            u_dot=state_dot[..., 3:4],
            y=y,
            y_dot=y_dot,
            y_ddot=y_ddot,
            margin=np.asarray(singularity_margin(y[..., 0], y_dot[..., 0])),
            momentum=np.asarray(H),
        )

    def evaluate(self, t: Array) -> tuple[Array, Array]:
        """States and inputs only (what a controller needs; cheaper than ``sample``).

        Parameters
        ----------
        t : (n,) times [s]

        Returns
        -------
        state : (..., n, 4) th0, th1, th2 [rad], u1 [rad/s]
        inputs : (..., n, 2) u1' [rad/s^2], u2 = th2' [rad/s]
        """
        t = np.asarray(t, dtype=float)
        k = self.coefficients
        basis = self.trajectory.basis
        if isinstance(basis, PolynomialBasis) and self.trajectory.coefficients.ndim == 2:
            # one plan in a polynomial basis: a compiled loop (Horner), no numpy call per term
            state = np.empty((t.size, 4))
            inputs = np.empty((t.size, 2))
            _polynomial_state_inputs(self.trajectory.coefficients, basis.duration, t.ravel(),
                                     Coefficients(*map(float, k)), state, inputs)
            return state, inputs
        y = self.trajectory.derivative(t, 0)
        y_dot = self.trajectory.derivative(t, 1)
        y_ddot = self.trajectory.derivative(t, 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            th0, th1, th2, u1, u1_dot, u2, _ = flag_state(
                k, y[..., 0], y[..., 1], y_dot[..., 0], y_dot[..., 1], y_ddot[..., 0],
                y_ddot[..., 1])
        return np.stack([th0, th1, th2, u1], axis=-1), np.stack([u1_dot, u2], axis=-1)

    def grid(self, samples: int) -> Array:
        """(samples,) equally spaced times over [0, duration] [s]."""
        return np.linspace(0.0, self.duration, samples)

    def input_energy(self, pieces: int = ENERGY_PIECES, order: int = ENERGY_ORDER) -> float:
        """Integral over [0, T] of th1'^2 + th2'^2 [rad^2/s] (composite Gauss-Legendre)."""
        t, weights = composite_gauss_legendre(self.duration, pieces, order)
        rates = self.sample(t).theta_dot
        if rates.ndim > 2:
            raise ValueError("input_energy: one plan at a time")
        return float(weights @ (rates[:, 1] ** 2 + rates[:, 2] ** 2))

    def margin_zeros(self) -> Array:
        """Times in (0, T) where the plan meets the singular set [s] (``margin_zeros``)."""
        return margin_zeros(self.trajectory)


@allocating_kernel
def _polynomial_state_inputs(
    coefficients: Array, duration: float, t: Array, k: Coefficients, state: Array,
    inputs: Array,
) -> None:
    """State (n, 4) and inputs (n, 2) of one polynomial plan at times t (n,), by Horner."""
    size = coefficients.shape[1]
    for i in range(t.shape[0]):
        s = t[i] / duration
        flag = np.empty(6)  # y1, y2, y1', y2', y1'', y2''
        for o in range(2):
            p = coefficients[o, size - 1]
            dp = 0.0
            half_ddp = 0.0
            for j in range(size - 2, -1, -1):
                half_ddp = half_ddp * s + dp
                dp = dp * s + p
                p = p * s + coefficients[o, j]
            flag[o] = p
            flag[2 + o] = dp / duration
            flag[4 + o] = 2.0 * half_ddp / (duration * duration)
        th0, th1, th2, u1, u1_dot, u2, _ = flag_state(k, flag[0], flag[1], flag[2], flag[3],
                                                      flag[4], flag[5])
        state[i, 0], state[i, 1], state[i, 2], state[i, 3] = th0, th1, th2, u1
        inputs[i, 0], inputs[i, 1] = u1_dot, u2


def _touches_singular_set(basis: PolynomialBasis, coefficients: Array) -> NDArray[np.bool_]:
    """(B,) which polynomial plans (coefficients (B, 2, size)) meet the singular set inside
    (0, T), all at once: a real root of y1' in (0, 1) (eigenvalues of the companion matrices),
    or a monotone y1 whose ends lie on either side of a multiple of pi."""
    a = coefficients[:, 0, :]  # y1 in s = t / T
    d = a[:, 1:] * np.arange(1, a.shape[1])  # dy1/ds, (B, degree)
    bad = np.zeros(a.shape[0], dtype=bool)
    lead = np.abs(d[:, -1]) > 1e-14 * np.max(np.abs(d), axis=1)
    if d.shape[1] >= 2:
        n = d.shape[1] - 1  # degree of dy1/ds
        companion = np.zeros((int(lead.sum()), n, n))
        companion[:, 1:, :-1] = np.eye(n - 1)
        companion[:, :, -1] = -d[lead, :-1] / d[lead, -1:]
        roots = np.linalg.eigvals(companion)
        real = np.abs(roots.imag) <= ROOT_IMAG_TOL * (1.0 + np.abs(roots.real))
        bad[lead] = np.any(real & (roots.real > 0.0) & (roots.real < 1.0), axis=1)
    for row in np.flatnonzero(~lead):  # degenerate leading coefficient: one at a time
        bad[row] = any(0.0 < s < 1.0 for s in _unit_interval_roots(d[row]))
    ends = np.stack([a[:, 0], a.sum(axis=1)], axis=1)
    crosses_pi = np.floor(ends[:, 0] / math.pi) != np.floor(ends[:, 1] / math.pi)
    return np.asarray(bad | crosses_pi, dtype=bool)


def require_off_singular_set(trajectory: FlatTrajectory) -> None:
    """Raise FlatcliError if a plan (or any plan of a batch) meets the singular set inside
    (0, T): its signed margin sin(y1) y1' changes sign or touches zero (``margin_zeros``)."""
    coefficients = trajectory.coefficients
    batch = coefficients.reshape(-1, *coefficients.shape[-2:])
    if isinstance(trajectory.basis, PolynomialBasis) and len(batch) > 1:
        suspects = np.flatnonzero(_touches_singular_set(trajectory.basis, batch))
    else:
        suspects = np.arange(len(batch))
    for row in suspects:
        single = FlatTrajectory(trajectory.basis, batch[row])
        zeros = margin_zeros(single)
        if zeros.size:
            t = float(zeros[0])
            y1, y1_dot = (float(single.derivative(np.array([t]), order)[0, 0]) for order in (0, 1))
            factor = "th1' = 0" if abs(y1_dot) <= abs(math.sin(y1)) else "sin th1 = 0"
            which = f" (maneuver {row} of the batch)" if len(batch) > 1 else ""
            raise FlatcliError(
                f"plan: the signed margin sin(th1) th1' is zero at t = {t:.4g} s inside the "
                f"maneuver{which} ({factor}): the plan crosses the singular set, where the flat "
                "map is infinite; change plan.start_rate / plan.goal_rate or plan.duration, or "
                "use --optimize, which keeps the margin above plan.optimize.min_margin"
            )


def plan_point_to_point(
    robot: RobotParams,
    start: ArrayLike,
    goal: ArrayLike,
    start_rate: ArrayLike,
    goal_rate: ArrayLike,
    duration: float,
    model: Model = "derived",
    basis: Basis | None = None,
) -> FlatPlan:
    """Flatness-based plan from ``start`` to ``goal`` in ``duration`` seconds.

    Parameters
    ----------
    robot : a flat design (d2 = 0); otherwise FlatcliError says which condition fails
    start, goal : (..., 3) configurations th0, th1, th2 [rad]; a batch of configurations
        (and of rates) plans a batch of maneuvers at once
    start_rate, goal_rate : (...) th1' at the ends [rad/s] (non-zero)
    duration : T [s] > 0
    model : which constraint coefficients the planner believes
    basis : default: cubic polynomials, the paper's choice

    Returns
    -------
    FlatPlan

    Raises
    ------
    FlatcliError, one line naming the key: a design that is not flat, an end on the
    singular set, or a plan that meets the singular set inside (0, T)
    (``require_off_singular_set``).
    """
    require_flat(robot)
    if not (duration > 0 and math.isfinite(duration)):
        raise FlatcliError(f"plan.duration: must be a finite number > 0 s, got {duration}")
    k = robot.coefficients(model)
    if basis is None:
        basis = PolynomialBasis(3, duration)
    elif not math.isclose(basis.duration, duration):
        raise FlatcliError("plan basis: its duration differs from plan.duration")
    bc = boundary_conditions(k, start, goal, start_rate, goal_rate)
    trajectory = min_acceleration_trajectory(basis, bc)
    require_off_singular_set(trajectory)
    return FlatPlan(robot, model, k, trajectory, float(duration))
