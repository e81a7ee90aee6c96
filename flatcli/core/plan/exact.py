"""Exact plans for any controllable design: the joints in a basis, the base from the momentum.

With d_N != 0 (an imperfect counterweight) the closed-form flat outputs do not apply, yet the
robot stays controllable, driftless of codimension one, hence flat (``design``). Planning it
does not need its flat outputs: with H = 0 the base follows from the joints,

    th0' = F(q, q') = -(h_1(q) th_1' + ... + h_N(q) th_N') / h_0(q),     q = (th_1 .. th_N),

(h_j from the robot's barycentric form, ``chain.momentum_weights``; they do not depend on th0),
so th0(T) = th0(0) + integral_0^T F dt is one number fixed by the joints' paths. A plan is:

1. joint paths th_j(t) = sum_k c_jk phi_k(t) in a basis (``basis``; quintic B-splines by
   default), meeting th_j(0), th_j(T) and, for the inner joints j < N, the end rates
   th_j'(0), th_j'(T) of the spec (th_N's end rates are left free, as on a flat plan);
2. the free coefficients z chosen to minimise a quadratic objective (``ORDERS``: the
   integral of sum_j th_j''^2 by default, of sum_j th_j'^2 for "energy" and "effort") subject
   to the one equation Phi(z) = th0(0) + integral F dt - th0_goal = 0, by Newton's method on
   its optimality conditions (exact gradient and Hessian of Phi: the slopes of h_j in closed
   form, their own slopes by complex step), after a restoration phase that first meets the
   equation (``solve``);
3. the plan's curves (``pieces``): the joints re-expressed on ``pieces`` of [0, T] and th0
   the exact integral of an interpolant of F at Chebyshev nodes of each piece, so th0' = F
   to the interpolation's accuracy (about 1e-13 rad/s) and H, from the full link kinematics
   at th0' of the curve, is at that level.

A design the constraint integrates (``design.design_verdict``: not_flat) fixes th0(T) by the
joints' ends: a goal elsewhere is refused, with the value it would need; so is a goal the
solver cannot reach (one line: the closest th0(T) it found).

The plan is a ``planning.Plan`` whose model is an ``ExactModel`` and whose curves are the
N + 1 channels (th_1 .. th_N, th0): what the compiled closed loop tracks (``lqr``).
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core._jit import allocating_kernel
from flatcli.core.curves.basis import Basis, BSplineBasis, FlatTrajectory
from flatcli.core.curves.pieces import PiecewiseCurves, fit, integral, joined, node_times
from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import Boundary, FlatModel, Kind
from flatcli.core.names import METHODS, Model
from flatcli.core.plan.planning import Plan, boundary_system
from flatcli.core.robots.chain import barycentric_matrix, momentum_weights, weight_slopes
from flatcli.core.robots.params import RobotParams, flatness_check

Array = NDArray[np.float64]
AnyArray = NDArray[Any]

#: Joint-path objectives: the derivative whose square is integrated (``None``: the plain
#: plan, least acceleration; "energy" and "effort", the same minimiser, least joint rate).
ORDERS: dict[str | None, int] = {None: 2, "energy": 1, "effort": 1}
#: Default basis of an exact plan: clamped quintic B-splines of this many coefficients.
DEFAULT_SIZE = 12
DEFAULT_DEGREE = 5
#: The plan's curves: at least this many pieces of [0, T] (each piece of the joints' basis
#: split into equal parts), polynomials of this degree on each.
MIN_PIECES = 32
CURVE_DEGREE = 11
#: Gauss-Legendre nodes per piece of the constraint's quadrature.
QUAD_ORDER = 12
#: |th0(T) - goal| [rad] a plan must reach, and the optimality residual (relative to the
#: objective's gradient) the solver stops at.
GOAL_TOL = 1e-11
KKT_RTOL = 1e-9
#: Iteration limits of the restoration and Newton phases.
MAX_RESTORATION = 60
MAX_NEWTON = 60
#: Complex step of the constraint's second derivatives [rad].
COMPLEX_STEP = 1e-30
#: The plan's margin: exact plans have no singular set.
NO_MARGIN = math.nan


@allocating_kernel
def _weight_rows(K: AnyArray, inertia: AnyArray, theta: AnyArray, h: AnyArray,
                 slopes: AnyArray) -> None:
    """``chain.momentum_weights`` (h (n, N + 1)) and ``chain.weight_slopes`` (slopes
    (n, N + 1, N)) at every row of theta (n, N + 1), real or complex."""
    for i in range(theta.shape[0]):
        momentum_weights(K, inertia, theta[i], h[i])
        weight_slopes(K, theta[i], slopes[i])


@dataclass(frozen=True, eq=False)
class Constraint:
    """The momentum constraint of a robot as planned and tracked: its barycentric matrix K
    (N + 1, N + 1) [kg m^2] and inertias (N + 1,) [kg m^2], of the robot's equivalent placement
    (``RobotParams.placement``), and the angle ``offset`` [rad] that placement adds to th_N."""

    K: Array
    inertia: Array
    offset: float = 0.0

    @classmethod
    def of(cls, robot: RobotParams) -> Constraint:
        equivalent, offset = robot.placement
        mass, length, com = (np.asarray(v, dtype=float) for v in
                             (equivalent.mass, equivalent.length, equivalent.com))
        K = np.ascontiguousarray(barycentric_matrix(mass, length, com))
        inertia = np.asarray(equivalent.inertia, dtype=float)
        K.setflags(write=False)
        inertia.setflags(write=False)
        return cls(K, inertia, float(offset))

    @property
    def n_joints(self) -> int:
        return int(self.inertia.shape[0]) - 1

    def terms(self, q: AnyArray) -> tuple[AnyArray, AnyArray]:
        """h (n, N + 1) [kg m^2] and dh_j/dth_k (n, N + 1, N) [kg m^2/rad] at the joint angles
        q (n, N) [rad], real or complex (then both complex)."""
        n = self.n_joints
        theta = np.zeros((q.shape[0], n + 1), dtype=q.dtype)
        theta[:, 1:] = q
        theta[:, n] += self.offset
        h = np.empty((q.shape[0], n + 1), dtype=q.dtype)
        slopes = np.empty((q.shape[0], n + 1, n), dtype=q.dtype)
        _weight_rows(np.ascontiguousarray(self.K, dtype=q.dtype),
                     np.ascontiguousarray(self.inertia, dtype=q.dtype), theta, h, slopes)
        return h, slopes

    def base_rate(self, q: AnyArray, w: AnyArray) -> AnyArray:
        """th0' = -(sum_j h_j w_j) / h_0 (n,) [rad/s] at joint angles q (n, N) [rad] and rates
        w (n, N) [rad/s] (H = 0)."""
        h, _ = self.terms(q)
        return np.asarray(-np.sum(h[:, 1:] * w, axis=1) / h[:, 0])


@functools.lru_cache(maxsize=256)
def constraint_of(robot: RobotParams) -> Constraint:
    """``Constraint.of`` computed once per robot."""
    return Constraint.of(robot)


@dataclass(frozen=True, eq=False)
class ExactModel(FlatModel):
    """What an exact plan (and the as-built controller) believes of a robot: its momentum
    constraint (``Constraint``). A plan's channels are (th_1 .. th_N, th0); its "outputs"
    y_j are the joint paths th_j (there are no closed-form flat outputs), its margin is nan
    (there is no singular set)."""

    robot: RobotParams
    constraint: Constraint
    name: Model = "derived"
    kind: Kind = "exact"

    @property
    def n_joints(self) -> int:
        return self.constraint.n_joints

    def boundary(self, start: ArrayLike, goal: ArrayLike, start_rate: ArrayLike,
                 goal_rate: ArrayLike) -> Boundary:
        raise FlatcliError("plan: an exact plan has no flat boundary values (plan_exact)")

    def flags_to_states(self, flags: AnyArray) -> tuple[AnyArray, AnyArray, AnyArray, AnyArray]:
        n = self.n_joints
        c = n + 1  # channels
        value, rate, accel = flags[..., :c], flags[..., c:2 * c], flags[..., 2 * c:3 * c]
        theta = np.concatenate([value[..., n:], value[..., :n]], axis=-1)
        theta_dot = np.concatenate([rate[..., n:], rate[..., :n]], axis=-1)
        sigma = np.full(flags.shape[:-1], NO_MARGIN)
        return theta, theta_dot, accel[..., : n - 1], sigma

    def flag_outputs(self, flags: Array) -> tuple[Array, Array, Array]:
        """An exact plan's "outputs" are its joint paths: y_j = th_j (j = 1..N), their rates
        th_j' and accelerations th_j'' (the flag's channels are th_1..th_N, th0, each with its
        two derivatives)."""
        n = self.n_joints
        c = n + 1
        return flags[..., :n], flags[..., c:c + n], flags[..., 2 * c:2 * c + n]

    def flag_values(self, flag: AnyArray) -> AnyArray:
        raise FlatcliError("plan.optimize: the flat optimiser does not apply to exact plans")

    def outputs(self, theta: Array, u: Array) -> tuple[Array, Array, Array]:
        n = self.n_joints
        y = np.asarray(theta[:, 1:n + 1], dtype=float)
        y_dot = np.full(y.shape, math.nan)
        y_dot[:, : n - 1] = u
        return y, y_dot, np.full(theta.shape[0], NO_MARGIN)

    def margin_zeros(self, trajectory: FlatTrajectory) -> Array:
        return np.zeros(0)

    @property
    def margin_text(self) -> str:
        return "none (an exact plan has no singular set)"

    @property
    def margin_label(self) -> str:
        return "none (exact plan)"

    def margin_mean(self, start: Array, goal: Array, duration: float) -> float:
        return NO_MARGIN


@functools.lru_cache(maxsize=256)
def _verdict(robot: RobotParams) -> str:
    """``design.design_verdict`` of a robot, once per robot."""
    from flatcli.core.robots.design import design_verdict

    return design_verdict(robot).verdict


def method_for(robot: RobotParams, method: str) -> Literal["flat", "exact"]:
    """The planner ``method`` ("auto", "flat", "exact") picks for a robot: "auto" is "flat"
    where the closed-form flat outputs apply (``model.flatness_check``), "exact" elsewhere."""
    if method not in METHODS:
        raise FlatcliError(f"plan.method: expected one of {list(METHODS)}, got {method!r}")
    if method == "auto":
        return "flat" if flatness_check(robot).is_flat else "exact"
    return "flat" if method == "flat" else "exact"


@functools.lru_cache(maxsize=256)
def exact_model(robot: RobotParams) -> ExactModel:
    """The ``ExactModel`` of a robot (computed once per robot)."""
    return ExactModel(robot, constraint_of(robot))


# --------------------------------------------------------------------------------------
# The programme: joint paths affine in z, the objective quadratic, one nonlinear equation


@functools.lru_cache(maxsize=64)
def _ends_system(basis: Basis) -> tuple[Array, Array]:
    """(E^+ (size, 2), null (size, size - 2)) of the rows phi(0), phi(T): the last joint,
    whose end rates are free."""
    from scipy.linalg import null_space

    ends = np.array([0.0, basis.duration])
    E = basis.matrix(ends, 0)
    P = np.asarray(np.linalg.pinv(E), dtype=float)
    N = np.ascontiguousarray(null_space(E), dtype=float)
    for a in (P, N):
        a.setflags(write=False)
    return P, N


def plan_pieces(basis: Basis) -> Array:
    """The breaks of an exact plan's curves: every piece of the joints' basis split into
    equal parts, at least ``MIN_PIECES`` pieces in all [s]."""
    edges = np.asarray(basis.breakpoints, dtype=float)
    parts = math.ceil(MIN_PIECES / (len(edges) - 1))
    fine = [np.linspace(a, b, parts + 1)[:-1] for a, b in itertools.pairwise(edges)]
    return np.append(np.concatenate(fine), edges[-1])


@functools.lru_cache(maxsize=64)
def _gram(basis: Basis, order: int) -> Array:
    """(size, size): integral over [0, T] of phi^(order) phi^(order)^T (Gauss, exact for
    the basis's polynomials)."""
    nodes, weights = _quadrature(basis)  # type: ignore[arg-type]  # frozen
    d = basis.matrix(nodes, order)
    gram: Array = (d * weights[:, None]).T @ d
    gram.setflags(write=False)
    return gram


@functools.lru_cache(maxsize=64)
def _quadrature(basis: Basis) -> tuple[Array, Array]:
    """Gauss-Legendre nodes and weights on the plan's pieces (``plan_pieces``) [s]
    (read-only; computed once per basis)."""
    edges = plan_pieces(basis)
    x, w = np.polynomial.legendre.leggauss(QUAD_ORDER)
    lo, hi = edges[:-1, None], edges[1:, None]
    half = 0.5 * (hi - lo)
    nodes, weights = (half * (x + 1.0) + lo).ravel(), (half * w).ravel()
    for a in (nodes, weights):
        a.setflags(write=False)
    return nodes, weights


@dataclass(frozen=True)
class Problem:
    """One exact-planning problem. The joint paths at the quadrature nodes are affine in the
    decision z (m,): q = q0 + Q0 z, q' = w0 + W0 z ((G, N) and (G, N, m)); the objective is
    z^T H z + 2 g^T z + const; Phi(z) = th0(0) - th0_goal + sum_g weight_g F(q_g, q'_g)."""

    constraint: Constraint
    basis: Basis
    weights: Array  # (G,) quadrature weights [s]
    q0: Array
    Q0: Array
    w0: Array
    W0: Array
    H: Array
    g: Array
    rise: float  # th0(0) - th0_goal [rad]
    particular: tuple[Array, ...]  # per joint: (size,) coefficients of the boundary values
    null: tuple[Array, ...]  # per joint: (size, m_j)
    offsets: tuple[int, ...]  # where joint j's block of z starts

    def coefficients(self, z: Array) -> Array:
        """(N, size) the joints' coefficients."""
        return np.stack([p + N @ z[a: a + N.shape[1]] for p, N, a in
                         zip(self.particular, self.null, self.offsets, strict=True)])

    def paths(self, z: Array) -> tuple[Array, Array]:
        return self.q0 + self.Q0 @ z, self.w0 + self.W0 @ z

    def objective(self, z: Array) -> float:
        return float(z @ self.H @ z + 2.0 * self.g @ z)

    def residual(self, z: Array) -> float:
        """Phi(z) [rad]."""
        q, w = self.paths(z)
        return self.rise + float(self.weights @ self.constraint.base_rate(q, w))

    def derivatives(self, z: Array, hessian: bool) -> tuple[float, Array, Array | None]:
        """Phi(z), its gradient (m,) and, if asked, its Hessian (m, m)."""
        q, w = self.paths(z)
        h, slopes = self.constraint.terms(q)
        F, Fq, Fw, Fqw = rate_terms(h, slopes, w)
        value = self.rise + float(self.weights @ F)
        m = self.H.shape[0]
        wt = self.weights[:, None]
        Q0, W0 = self.Q0.reshape(-1, m), self.W0.reshape(-1, m)  # (G N, m)
        grad = (wt * Fq).ravel() @ Q0 + (wt * Fw).ravel() @ W0
        if not hessian:
            return value, grad, None
        Fqq = self._second(q, w) * self.weights[:, None, None]
        Fqw = Fqw * self.weights[:, None, None]
        cross = Q0.T @ np.matmul(Fqw, self.W0).reshape(-1, m)
        hess = Q0.T @ np.matmul(Fqq, self.Q0).reshape(-1, m) + cross + cross.T
        return value, grad, hess

    def _second(self, q: Array, w: Array) -> Array:
        """d^2 F / dq_k dq_l (G, N, N), by complex step of dF/dq along each q_l."""
        n = q.shape[1]
        out = np.empty((q.shape[0], n, n))
        for l_ in range(n):
            qc = q.astype(complex)
            qc[:, l_] += 1j * COMPLEX_STEP
            h, slopes = self.constraint.terms(qc)
            _, Fq, _, _ = rate_terms(h, slopes, w.astype(complex))
            out[:, :, l_] = Fq.imag / COMPLEX_STEP
        return out


def rate_terms(h: AnyArray, slopes: AnyArray, w: AnyArray
                ) -> tuple[AnyArray, AnyArray, AnyArray, AnyArray]:
    """F = -(h . w) / h_0 (G,), dF/dq (G, N), dF/dw (G, N) and d^2F/dq dw (G, N, N) from the
    weights h (G, N + 1), their slopes (G, N + 1, N) and the rates w (G, N)."""
    h0 = h[:, 0]
    hw = np.sum(h[:, 1:] * w, axis=1)
    F = -hw / h0
    s0 = slopes[:, 0, :]  # dh_0/dq_k
    sw = np.einsum("gjk,gj->gk", slopes[:, 1:, :], w)  # sum_j dh_j/dq_k w_j
    Fq = -sw / h0[:, None] + (hw / h0**2)[:, None] * s0
    Fw = -h[:, 1:] / h0[:, None]
    Fqw = (-np.swapaxes(slopes[:, 1:, :], 1, 2) / h0[:, None, None]
           + s0[:, :, None] * h[:, None, 1:] / (h0**2)[:, None, None])
    return F, Fq, Fw, Fqw


def problem(constraint: Constraint, basis: Basis, start: Array, goal: Array,
            start_rate: Array, goal_rate: Array, order: int) -> Problem:
    """The ``Problem`` of moving from ``start`` to ``goal`` (N + 1,) [rad] with the inner
    joints' end rates (N - 1,) [rad/s], minimising the integral of the squared ``order``-th
    derivative of the joint paths."""
    n = constraint.n_joints
    inner = boundary_system(basis)  # type: ignore[arg-type]  # bases are frozen dataclasses
    last_p, last_null = _ends_system(basis)  # type: ignore[arg-type]  # frozen dataclasses
    nodes, weights = _quadrature(basis)  # type: ignore[arg-type]  # frozen dataclasses
    phi0, phi1 = basis.matrix(nodes, 0), basis.matrix(nodes, 1)
    gram = _gram(basis, order)  # type: ignore[arg-type]
    particular, null = [], []
    for j in range(1, n + 1):
        if j < n:
            rhs = np.array([start[j], start_rate[j - 1], goal[j], goal_rate[j - 1]])
            particular.append(inner.particular @ rhs)
            null.append(np.asarray(inner.null))
        else:
            particular.append(last_p @ np.array([start[j], goal[j]]))
            null.append(np.asarray(last_null))
    sizes = [N.shape[1] for N in null]
    offsets = tuple(int(v) for v in np.concatenate([[0], np.cumsum(sizes)[:-1]]))
    m = int(sum(sizes))
    G = nodes.size
    Q0, W0 = np.zeros((G, n, m)), np.zeros((G, n, m))
    H, g = np.zeros((m, m)), np.zeros(m)
    q0, w0 = np.empty((G, n)), np.empty((G, n))
    for j, (p, N, a) in enumerate(zip(particular, null, offsets, strict=True)):
        block = slice(a, a + N.shape[1])
        q0[:, j], w0[:, j] = phi0 @ p, phi1 @ p
        Q0[:, j, block], W0[:, j, block] = phi0 @ N, phi1 @ N
        H[block, block] = N.T @ gram @ N
        g[block] = N.T @ gram @ p
    return Problem(constraint, basis, weights, q0, Q0, w0, W0, H, g,
                   float(start[0] - goal[0]), tuple(particular), tuple(null), offsets)


def solve(prob: Problem) -> tuple[Array, int]:
    """The decision z (m,) of least objective with Phi(z) = 0, and the iterations taken.

    Restoration from the unconstrained optimum z = -H^-1 g: steps of least H-norm that
    cancel the linearised Phi, halved until |Phi| shrinks, until |Phi| <= 1e-3; then Newton
    on the optimality conditions 2 H z + 2 g + lambda grad Phi = 0, Phi = 0 (the exact
    Hessian of Phi), each step halved until the residual of both shrinks.

    Raises
    ------
    FlatcliError (``UnreachableError``) if no z meets Phi = 0 to ``GOAL_TOL``.
    """
    H, g = prob.H, prob.g
    z: Array = np.asarray(np.linalg.solve(H, -g), dtype=float)
    Hinv = np.linalg.inv(H)
    iterations = 0
    value, grad, _ = prob.derivatives(z, False)
    best = (abs(value), z)
    for _ in range(MAX_RESTORATION):
        if abs(value) <= 1e-3:
            break
        iterations += 1
        direction = Hinv @ grad
        denominator = float(grad @ direction)
        if not denominator > 0:
            break
        step = -value * direction / denominator
        t = 1.0
        while t > 1e-6:
            trial = prob.residual(z + t * step)
            if abs(trial) < (1.0 - 0.25 * t) * abs(value):
                break
            t *= 0.5
        else:
            break
        z = np.asarray(z + t * step, dtype=float)
        value, grad, _ = prob.derivatives(z, False)
        if abs(value) < best[0]:
            best = (abs(value), z)
    lam = -float(grad @ (2.0 * (H @ z + g))) / max(float(grad @ grad), 1e-300)
    scale = max(1.0, float(np.linalg.norm(2.0 * (H @ z + g))))
    for _ in range(MAX_NEWTON):
        value, grad, hess = prob.derivatives(z, True)
        assert hess is not None
        if abs(value) < best[0]:
            best = (abs(value), z)
        r1 = 2.0 * (H @ z + g) + lam * grad
        norm = math.hypot(float(np.linalg.norm(r1)) / scale, value)
        if abs(value) <= GOAL_TOL and float(np.linalg.norm(r1)) <= KKT_RTOL * scale:
            return z, iterations
        iterations += 1
        m = z.size
        kkt = np.zeros((m + 1, m + 1))
        kkt[:m, :m] = 2.0 * H + lam * hess
        kkt[:m, m] = kkt[m, :m] = grad
        try:
            delta = np.linalg.solve(kkt, -np.append(r1, value))
        except np.linalg.LinAlgError:
            break
        t = 1.0
        while t > 1e-8:
            zt, lt = np.asarray(z + t * delta[:m], dtype=float), lam + t * float(delta[m])
            vt, gt, _ = prob.derivatives(zt, False)
            rt = 2.0 * (H @ zt + g) + lt * gt
            if math.hypot(float(np.linalg.norm(rt)) / scale, vt) < (1.0 - 1e-4 * t) * norm:
                break
            t *= 0.5
        else:
            break
        z, lam = zt, lt
    if best[0] <= GOAL_TOL:  # met the goal, not quite optimal: keep the best plan met
        return best[1], iterations
    raise UnreachableError(best[0])


class UnreachableError(FlatcliError):
    """No joint paths found whose base reaches th0(T) (``miss``: the least |th0(T) - goal|
    found [rad])."""

    def __init__(self, miss: float) -> None:
        super().__init__(f"{miss:.3g}")
        self.miss = miss


def _curves(prob: Problem, z: Array, start_th0: float) -> PiecewiseCurves:
    """The plan's channels (th_1 .. th_N, th0) on ``plan_pieces`` (module docstring)."""
    joints = FlatTrajectory(prob.basis, prob.coefficients(z))
    edges = plan_pieces(prob.basis)
    times = node_times(edges, CURVE_DEGREE)  # (m, D + 1)
    flat = times.ravel()
    values = joints.derivative(flat, 0).reshape(*times.shape, -1)
    joint_curves = fit(edges, CURVE_DEGREE, values)
    rate_times = node_times(edges, CURVE_DEGREE - 1)
    q = joints.derivative(rate_times.ravel(), 0)
    w = joints.derivative(rate_times.ravel(), 1)
    rates = prob.constraint.base_rate(q, w).reshape(*rate_times.shape, 1)
    base = integral(fit(edges, CURVE_DEGREE - 1, rates), [start_th0])
    return joined([joint_curves, base])


def plan_exact(
    robot: RobotParams,
    start: ArrayLike,
    goal: ArrayLike,
    start_rate: ArrayLike,
    goal_rate: ArrayLike,
    duration: float,
    basis: Basis | None = None,
    objective: str | None = None,
) -> Plan:
    """An exact plan of ``robot`` (any design, module docstring) from ``start`` to ``goal``.

    Parameters
    ----------
    robot : the robot as built (any d_N, ``com_across``)
    start, goal : (N + 1,) th0..thN [rad]
    start_rate, goal_rate : the inner joints' end rates th_1'..th_N-1' [rad/s] (N - 1, or one
        for all; zero allowed: an exact plan has no singular set)
    duration : T [s] > 0
    basis : the joint paths' basis (default: clamped quintic B-splines of ``DEFAULT_SIZE``)
    objective : None (least acceleration), "energy" or "effort" (least joint rates)

    Returns
    -------
    Plan whose model is an ``ExactModel`` and whose trajectory the N + 1 channels
    (th_1 .. th_N, th0) as ``pieces.PiecewiseCurves``

    Raises
    ------
    FlatcliError, one line naming the key: a design that cannot reach the goal's th0 (the
    constraint integrates, or no joint paths were found), an objective that does not apply.
    """
    if not (duration > 0 and math.isfinite(duration)):
        raise FlatcliError(f"plan.duration: must be a finite number > 0 s, got {duration}")
    if objective not in ORDERS:
        raise FlatcliError(f"plan.optimize.objective: an exact plan minimises "
                           f"{', '.join(repr(k) for k in ORDERS if k)} or nothing (the least "
                           f"acceleration); {objective!r} applies to flat plans only")
    n = robot.n_joints
    start_arr, goal_arr = (np.asarray(v, dtype=float).reshape(n + 1) for v in (start, goal))
    rates0, rates1 = (np.broadcast_to(np.asarray(v, dtype=float), (n - 1,)).copy()
                      for v in (start_rate, goal_rate))
    if basis is None:
        basis = BSplineBasis(DEFAULT_SIZE, duration, DEFAULT_DEGREE)
    elif not math.isclose(basis.duration, duration):
        raise FlatcliError("plan basis: its duration differs from plan.duration")
    model = exact_model(robot)
    prob = problem(model.constraint, basis, start_arr, goal_arr, rates0, rates1,
                   ORDERS[objective])
    if _verdict(robot) == "not_flat":
        z = np.asarray(np.linalg.solve(prob.H, -prob.g), dtype=float)
        miss = prob.residual(z)
        if abs(miss) > GOAL_TOL:
            raise FlatcliError(
                f"plan.goal[0]: the robot is not flat (the momentum constraint integrates, "
                f"flatcli design): its joints' ends fix th0(T) = {goal_arr[0] + miss:.6g} rad, "
                f"not {goal_arr[0]:g}")
    else:
        try:
            z, _ = solve(prob)
        except UnreachableError as exc:
            raise FlatcliError(
                f"plan.goal[0]: no joint paths in the basis found that bring th0 to "
                f"{goal_arr[0]:g} rad at t = T (closest: {exc.miss:.3g} rad off); try "
                "another plan.duration, plan.size or end rates") from None
    curves = _curves(prob, z, float(start_arr[0]))
    return Plan(robot, model, curves, float(duration))


__all__ = [
    "CURVE_DEGREE",
    "METHODS",
    "ORDERS",
    "Constraint",
    "ExactModel",
    "Problem",
    "constraint_of",
    "exact_model",
    "method_for",
    "plan_exact",
    "plan_pieces",
    "problem",
    "solve",
]
