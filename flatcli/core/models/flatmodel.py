"""What the planner and the controller believe of a robot: one flat-model interface.

A flat model answers the questions every flat system answers (python-control's ``FlatSystem``
calls them ``forward`` and ``reverse``): the flat outputs and their rates at a state
(``boundary``, ``outputs``, ``end_map``), the state, its exact rates, the inputs and the
signed singularity margin along a flat flag (``flags_to_states``, ``flag_values``,
``flag_jacobian``), where a flat curve meets the singular set (``margin_zeros``), and what the
compiled closed loop needs of it (``kind``, ``shared``). Two implementations:

* ``ChainModel``: the general one, a chain of N >= 2 joints whose last link is
  counterweighted onto its joint (``chain``, ``chainflat``: y_j = th_j for j < N,
  y_N = th0 + I_N th_N / h_0(q));
* ``PaperModel``: the paper's robot (N = 2) in the closed forms of Franch et al. (2003)
  (``flatness``, coefficients of ``model.constraint_coefficients``), with the appendix's
  coefficients as derived or as printed (``robot.model = "paper"``, which no chain
  reproduces: its b1 breaks the symmetry of K). For the derived coefficients it is the
  chain's N = 2 case, written out: the same maps (the tests check both against each other)
  at a fifth of the chain's cost per right-hand side, and the numbers of every study flatcli
  has published.

``flat_model(robot, name)`` picks: the paper's closed form for N = 2, the chain beyond.
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core._jit import allocating_kernel, kernel
from flatcli.core.curves.basis import FlatTrajectory, PolynomialBasis
from flatcli.core.errors import FlatcliError
from flatcli.core.models.chainflat import flag_state as chain_flag_state
from flatcli.core.models.chainflat import flag_state_given, outputs, terms
from flatcli.core.models.flatness import flag_state, flat_outputs, flat_state
from flatcli.core.names import Model
from flatcli.core.robots.chain import barycentric_matrix, chain_momentum
from flatcli.core.robots.params import Coefficients, RobotParams, momentum, placed

Array = NDArray[np.float64]
#: Real or complex arrays (the maps are complex-step safe).
AnyArray = NDArray[Any]

#: Complex-step size: derivatives exact to rounding, since no difference is taken.
COMPLEX_STEP = 1e-30
#: A root of y1' (or of y1 - k pi) with |imaginary part| below this (relative to 1 + |root|)
#: counts as real: a double root, where the margin touches zero, comes out as a close pair.
ROOT_IMAG_TOL = 1e-7
#: Samples per unit of (pieces x degree) in a chain's scan for sign changes of the margin.
MARGIN_SCAN = 64
#: Which compiled closed loop a model runs in (``table.KERNELS``); "exact" is an exact
#: plan's model (``exact.ExactModel``), which only the as-built law tracks.
Kind = Literal["paper", "chain", "exact"]


@dataclass(frozen=True)
class Boundary:
    """Flat boundary conditions: y and y' at t = 0 and t = T, each (..., N)."""

    y_start: Array
    y_dot_start: Array
    y_goal: Array
    y_dot_goal: Array


class FlatModel(ABC):
    """The interface (module docstring); implementations are immutable."""

    name: Model
    kind: Kind

    @property
    @abstractmethod
    def n_joints(self) -> int:
        """N, the joints; N flat outputs, states of N + 1 angles and N - 1 rates."""

    @abstractmethod
    def boundary(self, start: ArrayLike, goal: ArrayLike, start_rate: ArrayLike,
                 goal_rate: ArrayLike) -> Boundary:
        """Flat boundary values for moving from ``start`` to ``goal`` (N + 1,) [rad] with the
        free joint rates th_1'..th_N-1' ``start_rate``, ``goal_rate`` at the ends [rad/s].

        Raises FlatcliError naming the key if an end lies on the singular set."""

    @abstractmethod
    def flags_to_states(self, flags: Array) -> tuple[Array, Array, Array, Array]:
        """Along a flat flag (n, 3 N) y, y', y'': theta (n, N + 1) [rad], their exact time
        derivatives theta_dot (n, N + 1) [rad/s] (never from the momentum constraint), the
        inputs u' (n, N - 1) [rad/s^2] and the signed margin sigma (n,) [rad/s]; inf/nan on
        the singular set."""

    def flag_outputs(self, flags: Array) -> tuple[Array, Array, Array]:
        """The plan's outputs y (..., N) [rad] and their first and second time derivatives
        [rad/s, rad/s^2] from its flag (..., 3 N): the flat outputs y, y', y'' themselves
        (an exact plan's channels differ: ``exact.ExactModel.flag_outputs``)."""
        n = self.n_joints
        return flags[..., :n], flags[..., n:2 * n], flags[..., 2 * n:3 * n]

    @abstractmethod
    def flag_values(self, flag: AnyArray) -> AnyArray:
        """The optimiser's pointwise quantities from a flag (3 N, ...), real or complex
        (complex step): (2 N + 2, ...) th0..thN, th1'..thN', and the margin sigma."""

    def flag_jacobian(self, flag: Array) -> tuple[Array, Array]:
        """``flag_values`` (2 N + 2, n) of a real flag (3 N, n) and its exact derivative along
        each flag component, (2 N + 2, 3 N, n), by complex step."""
        size = flag.shape[0]
        perturbed = flag[:, None, :] + (1j * COMPLEX_STEP) * np.eye(size)[:, :, None]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            out = self.flag_values(perturbed)
        values = np.ascontiguousarray(out[:, 0, :].real, dtype=float)
        return values, np.ascontiguousarray(out.imag / COMPLEX_STEP, dtype=float)

    @abstractmethod
    def outputs(self, theta: Array, u: Array) -> tuple[Array, Array, Array]:
        """The forward map at states theta (n, N + 1) [rad], u (n, N - 1) [rad/s]: y (n, N),
        y' (n, N) and the signed margin (n,); nan where a state is not finite."""

    def end_map(self, theta: Array) -> tuple[Array, Array]:
        """The flat outputs y (N,) [rad] at a configuration theta (N + 1,), and how their rates
        follow the joint rates there: y' = slope @ u, slope (N, N - 1) (the forward map is
        linear in u)."""
        n = self.n_joints
        theta = np.asarray(theta, dtype=float)
        units = np.eye(n - 1)
        y, y_dot, _ = self.outputs(np.tile(theta, (n - 1, 1)), units)
        return y[0].copy(), y_dot.T.copy()

    def signed_margin(self, flags: Array) -> Array:
        """The signed margin (n,) along a flag (n, 3 N) [rad/s]."""
        return self.flags_to_states(flags)[3]

    @abstractmethod
    def margin_zeros(self, trajectory: FlatTrajectory) -> Array:
        """Times in (0, T) where one plan's signed margin changes sign or touches zero [s]."""

    def require_off_singular_set(self, trajectory: FlatTrajectory) -> None:
        """Raise FlatcliError if a plan (or any plan of a batch) meets the singular set inside
        (0, T)."""
        coefficients = trajectory.coefficients
        batch = coefficients.reshape(-1, *coefficients.shape[-2:])
        for row in self._suspects(trajectory.basis, batch):
            single = FlatTrajectory(trajectory.basis, batch[row])
            zeros = self.margin_zeros(single)
            if zeros.size:
                which = f" (maneuver {row} of the batch)" if len(batch) > 1 else ""
                raise FlatcliError(self._crossing_message(single, float(zeros[0]), which))

    def _suspects(self, basis: Any, batch: Array) -> NDArray[np.intp]:
        """Rows of a batch that may meet the singular set (all, unless a cheap test rules
        some out)."""
        return np.arange(len(batch))

    def _crossing_message(self, trajectory: FlatTrajectory, t: float, which: str) -> str:
        return (f"plan: the margin {self.margin_text} is zero at t = {t:.4g} s inside the "
                f"maneuver{which}: the plan crosses the singular set, where the flat map is "
                "infinite; change plan.start_rate / plan.goal_rate or plan.duration")

    @property
    @abstractmethod
    def margin_text(self) -> str:
        """The signed margin as a formula, for messages."""

    @property
    @abstractmethod
    def margin_label(self) -> str:
        """The unsigned margin as a formula, for reports."""

    @abstractmethod
    def margin_mean(self, start: Array, goal: Array, duration: float) -> float:
        """The signed margin's mean over [0, T] on any plan between two configurations,
        unsigned [rad/s] (its integral depends on the ends alone)."""

    def momentum(self, robot: RobotParams, theta: Array, theta_dot: Array) -> Array:
        """H [kg m^2/s] of ``robot`` from its full link kinematics at angles theta and rates
        theta_dot (..., N + 1) (``chain.chain_momentum``)."""
        equivalent, theta = placed(robot, theta)  # a centre of mass across the last link
        mass, inertia, length, com = (np.asarray(v, dtype=float) for v in (
            equivalent.mass, equivalent.inertia, equivalent.length, equivalent.com))
        return chain_momentum(mass, inertia, length, com, theta, theta_dot)

    def fast_evaluate(self, trajectory: FlatTrajectory, t: Array
                      ) -> tuple[Array, Array] | None:
        """``Plan.evaluate`` by a faster route where the model has one, else None."""
        return None

    def motion(self, trajectory: FlatTrajectory, t: Array) -> tuple[Array, Array, Array]:
        """The angles, rates and accelerations a plan asks of the robot, exactly: q, q'
        from the inverse map along the flag, q'' by complex step of the same map along the
        flag's own derivative (no finite difference). q (n, N + 1) [rad], q' [rad/s],
        q'' [rad/s^2]."""
        t = np.asarray(t, dtype=float)
        y = [trajectory.derivative(t, order) for order in range(4)]
        flags = np.concatenate(y[:3], axis=-1)
        moved = flags + 1j * COMPLEX_STEP * np.concatenate(y[1:], axis=-1)
        q, q_dot, _, _ = self.flags_to_states(flags)
        _, rates, _, _ = self.flags_to_states(moved)
        return (np.asarray(q.real, dtype=float), np.asarray(q_dot.real, dtype=float),
                np.asarray(rates.imag / COMPLEX_STEP, dtype=float))


# --------------------------------------------------------------------------------------
# The general implementation: an N-link chain


@allocating_kernel
def _flags_to_states(K: Array, inertia: Array, flags: AnyArray, theta: AnyArray,
                     theta_dot: AnyArray, u_dot: AnyArray, sigma: AnyArray) -> None:
    """``chainflat.flag_state`` at every row of flags (n, 3 N): y, y', y'' (real or complex,
    the outputs of the same dtype)."""
    n_out = flags.shape[1] // 3
    for i in range(flags.shape[0]):
        sigma[i] = chain_flag_state(K, inertia, flags[i, :n_out], flags[i, n_out:2 * n_out],
                                    flags[i, 2 * n_out:], theta[i], theta_dot[i], u_dot[i])


@allocating_kernel
def _chain_values(K: Array, inertia: Array, flags: Array, values: Array) -> None:
    """A chain's quantities at every row of ``flags`` (m, 3 N) into ``values`` (m, 2 N + 2):
    ``chainflat.flag_state_given`` with the terms at q computed once per row."""
    n = inertia.shape[0] - 1
    theta = np.empty(n + 1)
    theta_dot = np.empty(n + 1)
    u_dot = np.empty(n - 1)
    q = np.zeros(n + 1)
    for i in range(flags.shape[0]):
        for j in range(1, n):
            q[j] = flags[i, j - 1]
        h0, h, grad, hess, slopes = terms(K, inertia, q)
        row = flags[i]
        sigma = flag_state_given(K, inertia, h0, h, grad, hess, slopes, row[:n], row[n:2 * n],
                                 row[2 * n:], theta, theta_dot, u_dot)
        for a in range(n + 1):
            values[i, a] = theta[a]
        for j in range(1, n + 1):
            values[i, n + j] = theta_dot[j]
        values[i, 2 * n + 1] = sigma


@allocating_kernel
def _chain_steps(K: Array, inertia: Array, flags: Array, step: float, values: Array,
                 jacobian: Array) -> None:
    """Complex-step derivatives of a chain's quantities along each flag component, at every
    row of ``flags`` (m, 3 N): ``values`` (m, 2 N + 2) and ``jacobian`` (m, 2 N + 2, 3 N).

    The trigonometric terms (``chainflat.terms``) depend on q = (y_1..y_N-1) only: they are
    evaluated complex along the N - 1 directions of q, and once, real, for the other 2 N + 1
    directions (where they are constant), so each row costs N sets of terms, not 3 N.
    """
    n = inertia.shape[0] - 1
    size = 3 * n
    theta = np.empty(n + 1, dtype=np.complex128)
    theta_dot = np.empty(n + 1, dtype=np.complex128)
    u_dot = np.empty(n - 1, dtype=np.complex128)
    row = np.empty(size, dtype=np.complex128)
    q = np.zeros(n + 1, dtype=np.complex128)
    for i in range(flags.shape[0]):
        for j in range(1, n):
            q[j] = flags[i, j - 1]
        f0, f1, f2, f3, f4 = terms(K, inertia, q)  # real values (zero imaginary parts)
        for c in range(size):
            for j in range(size):
                row[j] = flags[i, j]
            row[c] += 1j * step
            if c < n - 1:  # a direction of q: the terms move
                q[c + 1] += 1j * step
                h0, h, grad, hess, slopes = terms(K, inertia, q)
                q[c + 1] = flags[i, c]
            else:
                h0, h, grad, hess, slopes = f0, f1, f2, f3, f4
            sigma = flag_state_given(K, inertia, h0, h, grad, hess, slopes, row[:n],
                                     row[n:2 * n], row[2 * n:], theta, theta_dot, u_dot)
            for a in range(n + 1):
                jacobian[i, a, c] = theta[a].imag / step
            for j in range(1, n + 1):
                jacobian[i, n + j, c] = theta_dot[j].imag / step
            jacobian[i, 2 * n + 1, c] = sigma.imag / step
            if c == size - 1:  # a direction off q: real parts from the real terms
                for a in range(n + 1):
                    values[i, a] = theta[a].real
                for j in range(1, n + 1):
                    values[i, n + j] = theta_dot[j].real
                values[i, 2 * n + 1] = sigma.real


@allocating_kernel
def _chain_outputs(K: Array, inertia: Array, theta: Array, u: Array, y: Array,
                   y_dot: Array, sigma: Array) -> None:
    """``chainflat.outputs`` at every row; rows with a non-finite state are left nan."""
    for i in range(theta.shape[0]):
        finite = True
        for a in range(theta.shape[1]):
            finite = finite and math.isfinite(theta[i, a])
        for a in range(u.shape[1]):
            finite = finite and math.isfinite(u[i, a])
        if finite:
            sigma[i] = outputs(K, inertia, theta[i], u[i], y[i], y_dot[i])


@dataclass(frozen=True, eq=False)
class ChainModel(FlatModel):
    """What the planner and the controller believe of a chain: its barycentric matrix K
    (N + 1, N + 1) [kg m^2] (``chain.barycentric_matrix``; d_N = 0: last row zero) and the
    link inertias (N + 1,) [kg m^2]."""

    K: Array
    inertia: Array
    name: Model = "derived"
    kind: Kind = "chain"

    @classmethod
    def of(cls, robot: RobotParams) -> ChainModel:
        mass, length, com = (np.asarray(v, dtype=float) for v in
                             (robot.mass, robot.length, robot.com))
        K = np.ascontiguousarray(barycentric_matrix(mass, length, com))
        inertia = np.asarray(robot.inertia, dtype=float)
        K.setflags(write=False)
        inertia.setflags(write=False)
        return cls(K, inertia)

    @property
    def n_joints(self) -> int:
        return int(self.inertia.shape[0]) - 1

    @property
    def margin_text(self) -> str:
        return "-(dh_0/dt) / (2 K_10)"

    @property
    def margin_label(self) -> str:
        return "abs(dh_0/dt) / (2 abs(K_10))"

    def boundary(self, start: ArrayLike, goal: ArrayLike, start_rate: ArrayLike,
                 goal_rate: ArrayLike) -> Boundary:
        n = self.n_joints
        ends = []
        for side, theta, rate in (("start", start, start_rate), ("goal", goal, goal_rate)):
            th = np.asarray(theta, dtype=float)
            given = np.asarray(rate, dtype=float)  # one number for every inner joint, or N - 1
            u = np.full(n - 1, float(given)) if given.ndim == 0 else np.atleast_1d(given)
            if th.shape != (n + 1,):
                raise FlatcliError(f"plan.{side}: expected {n + 1} angles (th0..th{n}), got "
                                   f"{th.size}")
            if u.shape != (n - 1,):
                raise FlatcliError(f"plan.{side}_rate: expected {n - 1} rates "
                                   f"(th1'..th{n - 1}'), got {u.size}")
            y, y_dot = np.empty(n), np.empty(n)
            sigma = outputs(self.K, self.inertia, th, np.ascontiguousarray(u), y, y_dot)
            if not (math.isfinite(sigma) and abs(sigma) > 1e-9):
                raise FlatcliError(
                    f"plan.{side}_rate: the margin {self.margin_text} is {sigma:.3g} rad/s at "
                    f"the {side}: the base's locked inertia is stationary there (the singular "
                    "set); choose other end rates"
                )
            ends.append((y, y_dot))
        (y0, yd0), (yT, ydT) = ends
        return Boundary(y0, yd0, yT, ydT)

    def flags_to_states(self, flags: Array) -> tuple[Array, Array, Array, Array]:
        flags = np.ascontiguousarray(flags)
        count, n = flags.shape[0], self.n_joints
        theta = np.empty((count, n + 1), dtype=flags.dtype)
        theta_dot = np.empty((count, n + 1), dtype=flags.dtype)
        u_dot = np.empty((count, n - 1), dtype=flags.dtype)
        sigma = np.empty(count, dtype=flags.dtype)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            _flags_to_states(self.K, self.inertia, flags, theta, theta_dot, u_dot, sigma)
        return theta, theta_dot, u_dot, sigma

    def flag_values(self, flag: AnyArray) -> AnyArray:
        n = self.n_joints
        rows = np.ascontiguousarray(np.reshape(flag, (3 * n, -1)).T)  # (times, 3 N)
        if np.isrealobj(rows):
            out = np.empty((rows.shape[0], 2 * n + 2))
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                _chain_values(self.K, self.inertia, rows.astype(float), out)
            out = out.T
        else:
            theta, theta_dot, _, sigma = self.flags_to_states(rows)
            out = np.concatenate([theta.T, theta_dot[:, 1:].T, sigma[None, :]])
        return np.reshape(out, (2 * n + 2, *np.shape(flag)[1:]))

    def flag_jacobian(self, flag: Array) -> tuple[Array, Array]:
        n = self.n_joints
        rows = np.ascontiguousarray(flag.T)  # (times, 3 N)
        values = np.empty((rows.shape[0], 2 * n + 2))
        jacobian = np.empty((rows.shape[0], 2 * n + 2, 3 * n))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            _chain_steps(self.K, self.inertia, rows, COMPLEX_STEP, values, jacobian)
        return (np.ascontiguousarray(values.T),
                np.ascontiguousarray(np.transpose(jacobian, (1, 2, 0))))

    def outputs(self, theta: Array, u: Array) -> tuple[Array, Array, Array]:
        count, n = len(theta), self.n_joints
        y = np.full((count, n), np.nan)
        y_dot = np.full((count, n), np.nan)
        sigma = np.full(count, np.nan)
        with np.errstate(all="ignore"):
            _chain_outputs(self.K, self.inertia, np.ascontiguousarray(theta, dtype=float),
                           np.ascontiguousarray(u, dtype=float), y, y_dot, sigma)
        return y, y_dot, sigma

    def margin_zeros(self, trajectory: FlatTrajectory) -> Array:
        """Bracketed on a scan of ``MARGIN_SCAN`` samples per polynomial piece and degree,
        refined by Brent's method; a local minimum of |sigma| within 1e-9 of its largest
        value counts as touching."""
        from scipy.optimize import brentq, minimize_scalar

        breaks, local = trajectory.piecewise()
        duration = float(breaks[-1])
        count = MARGIN_SCAN * (len(breaks) - 1) * local.shape[1] + 1
        t = np.linspace(0.0, duration, count)
        sigma = self.signed_margin(trajectory.flags(t))
        zeros: list[float] = []

        def at(x: float) -> float:
            return float(self.signed_margin(trajectory.flags(np.array([x])))[0])

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
        inside = [z for z in zeros if 0.0 < z < duration]
        return np.unique(np.round(np.asarray(inside, dtype=float), 12))

    def margin_mean(self, start: Array, goal: Array, duration: float) -> float:
        drop = (self.base_inertia(start)[0] - self.base_inertia(goal)[0]) / (
            2.0 * float(self.K[1, 0]))
        return drop / duration

    def base_inertia(self, theta: Array) -> tuple[float, Array]:
        """h_0 [kg m^2] at a configuration (N + 1,), and its gradient in th_1..th_N-1
        (N - 1,) [kg m^2] (h_0 does not depend on th_N)."""
        from flatcli.core.robots.chain import base_inertia_slopes

        n = self.n_joints
        grad = np.empty(n)
        h0 = base_inertia_slopes(self.K, self.inertia, np.asarray(theta, dtype=float), grad,
                                 np.empty((n, n)))
        return float(h0), grad[: n - 1]


# --------------------------------------------------------------------------------------
# The paper's robot in its closed forms


def state_and_rates(k: Coefficients, y: Array, y_dot: Array, y_ddot: Array
                    ) -> tuple[Array, Array]:
    """State and its exact time derivative along a flat curve of the paper's robot.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    y, y_dot, y_ddot : (..., 2) flat outputs and two derivatives

    Returns
    -------
    state : (..., 4) th0, th1, th2 [rad], u1 [rad/s]
    state_dot : (..., 4) th0', th1', th2' [rad/s], u1' [rad/s^2] (complex step of the
        inverse map along the flag)
    """
    z = [y[..., 0], y[..., 1], y_dot[..., 0], y_dot[..., 1]]
    dz = [y_dot[..., 0], y_dot[..., 1], y_ddot[..., 0], y_ddot[..., 1]]
    with np.errstate(divide="ignore", invalid="ignore"):
        state = np.stack(flat_state(k, *z), axis=-1)
        perturbed = [zi + 1j * COMPLEX_STEP * dzi for zi, dzi in zip(z, dz, strict=True)]
        state_dot = np.stack(flat_state(k, *perturbed), axis=-1).imag / COMPLEX_STEP
    return state, state_dot


def boundary_conditions(k: Coefficients, start: ArrayLike, goal: ArrayLike,
                        start_rate: ArrayLike, goal_rate: ArrayLike) -> Boundary:
    """Flat boundary values of the paper's robot for moving from ``start`` to ``goal``.

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


def paper_margin_zeros(trajectory: FlatTrajectory) -> Array:
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


@dataclass(frozen=True, eq=False)
class PaperModel(FlatModel):
    """The paper's robot (N = 2) in closed form: its constraint coefficients (d2 = 0; derived,
    or as printed with ``name = "paper"``)."""

    coefficients: Coefficients
    name: Model = "derived"
    kind: Kind = "paper"

    @property
    def n_joints(self) -> int:
        return 2

    @property
    def margin_text(self) -> str:
        return "sin(th1) th1'"

    @property
    def margin_label(self) -> str:
        return "abs(sin y1 * y1')"

    def boundary(self, start: ArrayLike, goal: ArrayLike, start_rate: ArrayLike,
                 goal_rate: ArrayLike) -> Boundary:
        return boundary_conditions(self.coefficients, start, goal, _one_rate(start_rate),
                                   _one_rate(goal_rate))

    def flags_to_states(self, flags: Array) -> tuple[Array, Array, Array, Array]:
        y, y_dot, y_ddot = flags[..., 0:2], flags[..., 2:4], flags[..., 4:6]
        state, state_dot = state_and_rates(self.coefficients, y, y_dot, y_ddot)
        sigma = np.sin(y[..., 0]) * y_dot[..., 0]
        return state[..., :3], state_dot[..., :3], state_dot[..., 3:4], sigma

    def flag_values(self, flag: AnyArray) -> AnyArray:
        y1, y2, y1d, y2d, y1dd, y2dd = flag
        th0, th1, th2, u1, _, u2, _ = flag_state(self.coefficients, y1, y2, y1d, y2d, y1dd,
                                                 y2dd)
        return np.stack([th0, th1, th2, u1, u2, np.sin(y1) * y1d])

    def outputs(self, theta: Array, u: Array) -> tuple[Array, Array, Array]:
        with np.errstate(all="ignore"):
            y1, y2, y1_dot, y2_dot = flat_outputs(self.coefficients, theta[:, 0], theta[:, 1],
                                                  theta[:, 2], u[:, 0])
            sigma = np.sin(theta[:, 1]) * u[:, 0]
        y = np.column_stack(np.broadcast_arrays(y1, y2))
        y_dot = np.column_stack(np.broadcast_arrays(y1_dot, y2_dot))
        return y, y_dot, np.asarray(sigma)

    def end_map(self, theta: Array) -> tuple[Array, Array]:
        y1, y2, _, slope = flat_outputs(self.coefficients, float(theta[0]), float(theta[1]),
                                        float(theta[2]), 1.0)
        return np.array([float(y1), float(y2)]), np.array([[1.0], [float(slope)]])

    def margin_zeros(self, trajectory: FlatTrajectory) -> Array:
        return paper_margin_zeros(trajectory)

    def _suspects(self, basis: Any, batch: Array) -> NDArray[np.intp]:
        if isinstance(basis, PolynomialBasis) and len(batch) > 1:
            return np.flatnonzero(_touches_singular_set(basis, batch))
        return np.arange(len(batch))

    def _crossing_message(self, trajectory: FlatTrajectory, t: float, which: str) -> str:
        y1, y1_dot = (float(trajectory.derivative(np.array([t]), order)[0, 0])
                      for order in (0, 1))
        factor = "th1' = 0" if abs(y1_dot) <= abs(math.sin(y1)) else "sin th1 = 0"
        return (f"plan: the signed margin sin(th1) th1' is zero at t = {t:.4g} s inside the "
                f"maneuver{which} ({factor}): the plan crosses the singular set, where the flat "
                "map is infinite; change plan.start_rate / plan.goal_rate or plan.duration, or "
                "use --optimize, which keeps the margin above plan.optimize.min_margin")

    def margin_mean(self, start: Array, goal: Array, duration: float) -> float:
        return (math.cos(float(start[1])) - math.cos(float(goal[1]))) / duration

    def momentum(self, robot: RobotParams, theta: Array, theta_dot: Array) -> Array:
        """H of the three-link robot, its full link kinematics written out
        (``model.momentum``)."""
        equivalent, theta = placed(robot, theta)  # a centre of mass across link 2
        return np.asarray(momentum(equivalent.links, *np.moveaxis(theta, -1, 0),
                                   *np.moveaxis(theta_dot, -1, 0)))

    def motion(self, trajectory: FlatTrajectory, t: Array) -> tuple[Array, Array, Array]:
        """``FlatModel.motion`` in closed form: th and th' from ``flatness.flag_state`` (th0'
        the exact derivative of eq. 35, th1' = y1', th2' = u2), th'' by complex step of the
        same map along the flag's own derivative."""
        t = np.asarray(t, dtype=float)
        y = [trajectory.derivative(t, order) for order in range(4)]
        z = [y[0][:, 0], y[0][:, 1], y[1][:, 0], y[1][:, 1], y[2][:, 0], y[2][:, 1]]
        dz = [y[1][:, 0], y[1][:, 1], y[2][:, 0], y[2][:, 1], y[3][:, 0], y[3][:, 1]]
        k = self.coefficients
        with np.errstate(divide="ignore", invalid="ignore"):
            th0, th1, th2, u1, _, u2, th0_dot = flag_state(k, *z)
            moved = [zi + 1j * COMPLEX_STEP * dzi for zi, dzi in zip(z, dz, strict=True)]
            rates = flag_state(k, *moved)
        th0_ddot, u1_dot, u2_dot = (np.asarray(rates[i]).imag / COMPLEX_STEP for i in (6, 3, 5))
        q = np.stack([th0, th1, th2], axis=-1)
        q_dot = np.stack([th0_dot, u1, u2], axis=-1)
        q_ddot = np.stack([th0_ddot, u1_dot, u2_dot], axis=-1)
        return (np.asarray(q, dtype=float), np.asarray(q_dot, dtype=float),
                np.asarray(q_ddot, dtype=float))

    def fast_evaluate(self, trajectory: FlatTrajectory, t: Array
                      ) -> tuple[Array, Array] | None:
        """One polynomial plan: a compiled loop (Horner), no numpy call per term."""
        if not (isinstance(trajectory.basis, PolynomialBasis)
                and trajectory.coefficients.ndim == 2):
            return None
        state = np.empty((t.size, 4))
        inputs = np.empty((t.size, 2))
        _polynomial_state_inputs(trajectory.coefficients, trajectory.basis.duration, t.ravel(),
                                 Coefficients(*map(float, self.coefficients)), np.empty(6),
                                 state, inputs)
        return state, inputs


@kernel
def _polynomial_state_inputs(
    coefficients: Array, duration: float, t: Array, k: Coefficients, flag: Array,
    state: Array, inputs: Array,
) -> None:
    """State (n, 4) and inputs (n, 2) of one polynomial plan at times t (n,), by Horner;
    ``flag`` (6,) scratch: y1, y2, y1', y2', y1'', y2''."""
    size = coefficients.shape[1]
    for i in range(t.shape[0]):
        s = t[i] / duration
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


def _one_rate(rate: ArrayLike) -> Any:
    """th1' of the paper's robot from a rate key (a number, or one number per inner joint:
    one here); arrays of a batch pass as they are."""
    arr = np.asarray(rate, dtype=float)
    if arr.ndim == 1 and arr.shape == (1,):
        return float(arr[0])
    return rate


@functools.lru_cache(maxsize=256)
def _paper_model(robot: RobotParams, name: Model) -> PaperModel:
    return PaperModel(robot.coefficients(name), name)


@functools.lru_cache(maxsize=256)
def _chain_model(robot: RobotParams) -> ChainModel:
    return ChainModel.of(robot)


def flat_model(robot: RobotParams, name: Model = "derived") -> FlatModel:
    """The flat model of a robot: the paper's closed form for N = 2 (either coefficient set),
    the chain beyond (derived only: the printed coefficients exist for three links)."""
    if robot.n_joints == 2:
        return _paper_model(robot, name)
    if name != "derived":
        raise FlatcliError(
            f"robot.model: {name!r} (the appendix as printed) applies to the paper's robot "
            f"(2 joints) only; a robot of {robot.n_joints} joints plans with \"derived\""
        )
    return _chain_model(robot)


__all__ = [
    "COMPLEX_STEP",
    "Boundary",
    "ChainModel",
    "FlatModel",
    "PaperModel",
    "boundary_conditions",
    "flat_model",
    "paper_margin_zeros",
    "state_and_rates",
]
