"""Optimised flat plans: choose the free end rates and free coefficients under limits.

The paper fixes the free end rates th1'(0) = 0.1 and th1'(T) = 0.5 rad/s by hand and uses
cubics. Here they, and every coefficient the boundary conditions leave free in a richer
basis, are decision variables of a smooth nonlinear programme solved by scipy's SLSQP.

Structure exploited
-------------------
The boundary conditions are linear in the coefficients, and y2'(0) = k0 th1'(0),
y2'(T) = kT th1'(T) with k0, kT fixed by the end configurations (``flat_outputs``: y2' is
linear in u1). So the coefficients, and with them the flat flag
F(t) = (y1, y2, y1', y2', y1'', y2'') at any time, are *affine* in the decision vector

    x = (th1'(0), th1'(T), z1, z2)      (z: null-space coordinates of the boundary matrix)

and every pointwise quantity (th, th1', th2', the margin) is a closed-form function of F(t)
alone. Gradients are exact: each pointwise function is differentiated by complex step along
the six flag components at once (vectorised over the grid) and chained through the constant
affine map. th2' is written in closed form (no nested complex step), so it is checked against
``planning.state_and_rates`` in the tests. The plan is therefore exactly momentum-consistent
whatever the optimiser does: only the flat curve is optimised.

Objectives (all over [0, T])
----------------------------
* ``"energy"``: integral of th1'^2 + th2'^2 [rad^2/s], on the same composite Gauss-Legendre
  rule as ``FlatPlan.input_energy`` (64 pieces of 8 nodes); the value reported is
  ``input_energy`` of the returned plan.
* ``"effort"``: T times the energy [rad^2]: invariant under time scaling (stretching a plan
  by a factor c divides the energy by c and multiplies T by c), useful when comparing plans
  of different durations. At fixed T it is a constant multiple of the energy: same optimum.
* ``"peak_rate"``: max of |th1'| and |th2'| [rad/s], as an epigraph variable s with
  s >= +-th1', s >= +-th2' at every grid time; solved from the least-energy plan (a good,
  robust start for the minimax problem). Reported: the maximum on the check grid.
* ``"margin"``: maximise the least signed margin [rad/s] (epigraph: margin >= s). The
  maximiser is not unique (y2 does not enter the margin, and left arbitrary it gives wild
  th2), so a second stage returns the least-energy plan whose margin stays within
  ``MARGIN_TIE`` of the best. Reported: the minimum on the check grid.

Constraints (imposed at ``constraint_samples`` equally spaced times)
----------------------------------------------------------------------
|th_i| <= angle_limit_i, |th1'|, |th2'| <= rate_limit, and the signed margin
sigma sin(y1) y1' >= min_margin with sigma = sign(sin y1(0) y1'(0)) of the starting guess:
the plan can never cross th1' = 0 or sin th1 = 0. With ``free_rates=False`` the end rates
are not decision variables; free end rates are bounded to the side of zero the margin
allows. After each solve the limits are re-checked on a finer grid (``CHECK_REFINEMENT``
times denser); the worst violating times are added to the constraint grid, each violated
limit is tightened by twice its excess, and the problem is solved again (an exchange method
for this semi-infinite programme), so the returned plan meets every limit at every sample of
the check grid. Limits are imposed backed off by ``BACKOFF`` (relative) so that the solver's
own tolerance cannot show up as a violation.

What keeps SLSQP on track (``_Problem.prepare``, ``_solve``): each constraint row is scaled
by its gradient norm (th2' is extremely sensitive to the coefficients near the singular set),
angle and rate rows far from their limits are left out of a round (the exchange restores
them if needed), and a round that steps far outside the limits is discarded in favour of
its best iterate that met them.

Necessary conditions checked before optimising
----------------------------------------------
The signed margin is sigma sin(y1) y1' = -sigma d(cos y1)/dt, so its integral over [0, T] is
sigma (cos th1(0) - cos th1(T)): the margin can stay >= m only if that is >= m T, and th1 must
move monotonically within one interval (k pi, (k + 1) pi). Along such a th1 path, momentum
conservation fixes the integral of h(y1) th2 dy1 (``flatness``: y2' = (g - h th2) y1'), so
th2 must reach a value ``required_fold`` fixes (2.67 rad on the paper's maneuver), which
bounds the th2 angle limit and, with th2's travel there and back, the rate limit. End
configurations outside their angle limits, fixed end rates outside the rate limit or inside
the margin, and th1 travel faster than the rate limit allows are reported likewise, each as
one line naming the spec key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize

from flatcli.core.basis import Basis, BSplineBasis, composite_gauss_legendre
from flatcli.core.flatness import chart, flag_state, flat_outputs
from flatcli.core.model import (
    Coefficients,
    FlatcliError,
    Model,
    RobotParams,
    constraint_coefficients,
    require_flat,
)
from flatcli.core.planning import (
    COMPLEX_STEP,
    ENERGY_ORDER,
    ENERGY_PIECES,
    FlatPlan,
    FlatTrajectory,
    boundary_conditions,
    boundary_system,
    min_acceleration_trajectory,
)

Array = NDArray[np.float64]

Objective = Literal["energy", "peak_rate", "effort", "margin"]
OBJECTIVES: tuple[Objective, ...] = ("energy", "peak_rate", "effort", "margin")
#: What a ``_Problem`` minimises: an objective, or (phase 1, for infeasible requests) the
#: largest relative limit violation.
_Goal = Literal["energy", "peak_rate", "effort", "margin", "violation"]
#: Goals with an epigraph variable s, the last decision variable.
_EPIGRAPH: tuple[_Goal, ...] = ("peak_rate", "margin", "violation")

#: Default basis: clamped quintic B-splines with this many coefficients per output. Quintic
#: so y'' (and with it th2' and u1') is C^3; 12 coefficients leave 8 free per output after the
#: four boundary conditions, enough to reach an energy near 1/5 of the paper's cubic on its
#: maneuver, while the local support keeps the problem well conditioned (monomials of
#: degree > 9 are not).
DEFAULT_BSPLINE_SIZE = 12
DEFAULT_BSPLINE_DEGREE = 5

#: Angle and rate rows with more slack than this fraction of max(1, limit) are left out of a
#: solve (see ``_Problem.prepare``).
SCREEN = 0.5
#: A round whose plan violates a limit by more than REJECT_FLOOR of it, and ROUND_REJECT
#: times more than the least violating plan so far, is discarded (smaller violations are
#: what the exchange rounds repair).
ROUND_REJECT = 100.0
REJECT_FLOOR = 1e-2
#: ... and the next round starts from the best iterate of that round that missed no row on
#: the constraint grid by more than this fraction of max(1, limit).
RESTART_TOL = 1e-4
#: Epigraph rows (peak_rate, margin) are refined where the check grid exceeds them by more
#: than this fraction of max(1, |epigraph variable|).
EPIGRAPH_TOL = 1e-4
#: An exchange round tightens a violated limit by at most this fraction of max(1, limit).
TIGHTEN_CAP = 1e-3
#: The check grid has CHECK_REFINEMENT times as many intervals as the constraint grid.
CHECK_REFINEMENT = 10
#: Limits are imposed tightened by this fraction of max(1, |limit|).
BACKOFF = 1e-7
#: A limit counts as active when its slack is below this fraction of max(1, |limit|).
ACTIVE_TOL = 1e-5
#: A plan is feasible when no limit is exceeded by more than this fraction of max(1, |limit|).
FEASIBILITY_TOL = 1e-9
#: The "margin" objective's second stage keeps the margin within this fraction of the best.
MARGIN_TIE = 1e-3
#: Rounds of the exchange method (solve, re-check on the fine grid, add violating times).
EXCHANGE_ROUNDS = 6
#: SLSQP's tolerance on the (normalised) objective.
SOLVER_TOL = 1e-10
#: Stand-in for non-finite values (a trial point on the singular set) seen by the solver.
_BIG = 1e6

# Rows of the pointwise quantities returned by ``flag_quantities``.
_TH0, _TH1, _TH2, _RATE1, _RATE2, _MARGIN = range(6)
_QUANTITY_NAMES = ("th0", "th1", "th2", "th1'", "th2'", "margin")


@dataclass(frozen=True)
class PlanLimits:
    """Limits an optimised plan must respect along its whole path.

    Attributes
    ----------
    angle_limit : (3,) bound on |th0|, |th1|, |th2| [rad], each > 0 (inf: none)
    rate_limit : bound on |th1'| and |th2'| [rad/s], > 0 (inf: none)
    min_margin : lower bound on the signed singularity margin sigma sin(th1) th1' [rad/s],
        >= 0 and finite (sigma: the sign at t = 0)

    Raises
    ------
    FlatcliError naming the spec key ``plan.optimize.*`` when a value is out of range.
    """

    angle_limit: tuple[float, float, float] = (math.inf, math.inf, math.inf)
    rate_limit: float = math.inf
    min_margin: float = 0.02

    def __post_init__(self) -> None:
        angles = np.asarray(self.angle_limit, dtype=float)
        if angles.shape != (3,):
            raise FlatcliError(
                f"plan.optimize.angle_limit: expected 3 numbers (th0, th1, th2), "
                f"got shape {angles.shape}"
            )
        if np.any(np.isnan(angles)) or np.any(angles <= 0):
            raise FlatcliError(
                f"plan.optimize.angle_limit: every value must be > 0 rad (inf: no limit), "
                f"got {angles.tolist()}"
            )
        object.__setattr__(
            self, "angle_limit", (float(angles[0]), float(angles[1]), float(angles[2]))
        )
        rate = float(self.rate_limit)
        if math.isnan(rate) or rate <= 0:
            raise FlatcliError(
                f"plan.optimize.rate_limit: must be > 0 rad/s (inf: no limit), got {rate}"
            )
        object.__setattr__(self, "rate_limit", rate)
        margin = float(self.min_margin)
        if not math.isfinite(margin) or margin < 0:
            raise FlatcliError(
                f"plan.optimize.min_margin: must be finite and >= 0 rad/s, got {margin}"
            )
        object.__setattr__(self, "min_margin", margin)


@dataclass(frozen=True)
class OptimizeResult:
    """Outcome of ``optimize_plan``.

    Attributes
    ----------
    plan : the optimised plan (same robot and model, the chosen basis)
    success : the solver converged and the plan meets every limit on the check grid
    objective : final value of the objective (units of the objective, see the module doc)
    initial_objective : its value at the starting guess
    iterations : solver iterations, summed over the exchange rounds
    evaluations : distinct decision vectors evaluated
    active : human-readable active limits, e.g. ``"rate_limit on th2' at t=0.31 s"``
    max_violation : worst limit violation on the check grid, >= 0 [rad or rad/s]
    start_rate, goal_rate : the chosen end rates th1'(0), th1'(T) [rad/s]
    message : the solver's message, and any note on the outcome
    """

    plan: FlatPlan
    success: bool
    objective: float
    initial_objective: float
    iterations: int
    evaluations: int
    active: tuple[str, ...]
    max_violation: float
    start_rate: float
    goal_rate: float
    message: str


def default_basis(duration: float) -> BSplineBasis:
    """The basis ``optimize_plan`` uses when none is given (see ``DEFAULT_BSPLINE_SIZE``).

    Parameters
    ----------
    duration : T [s]

    Returns
    -------
    BSplineBasis with ``DEFAULT_BSPLINE_SIZE`` coefficients of degree ``DEFAULT_BSPLINE_DEGREE``
    """
    return BSplineBasis(DEFAULT_BSPLINE_SIZE, duration, DEFAULT_BSPLINE_DEGREE)


def flag_quantities(k: Coefficients, flag: NDArray[np.generic]) -> NDArray[np.generic]:
    """Pointwise quantities of a plan from its flat flag (real or complex: complex-step safe).

    ``flatness.flag_state`` at each time: th0, th1 = y1, th2, th1' = y1', th2' = u2, and the
    unsigned margin sin(y1) y1'.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    flag : (6, ...) y1, y2 [rad], y1', y2' [rad/s], y1'', y2'' [rad/s^2]

    Returns
    -------
    (6, ...) th0, th1, th2 [rad], th1', th2' [rad/s], sin(y1) y1' [rad/s] (the unsigned
    margin); inf/nan on the singular set sin y1 y1' = 0
    """
    y1, y2, y1d, y2d, y1dd, y2dd = flag
    th0, th1, th2, u1, _, u2, _ = flag_state(k, y1, y2, y1d, y2d, y1dd, y2dd)
    return np.stack([th0, th1, th2, u1, u2, np.sin(y1) * y1d])


def flag_jacobian(k: Coefficients, flag: Array) -> tuple[Array, Array]:
    """``flag_quantities`` and its exact derivative along each flag component (complex step).

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    flag : (6, n) real flat flag (see ``flag_quantities``)

    Returns
    -------
    values : (6, n) th0, th1, th2, th1', th2', sin(y1) y1'
    jacobian : (6, 6, n) d values[q] / d flag[c] at each time, [q, c, n]
    """
    # (6 components, 6 directions, n): component c carries i h along direction d == c
    perturbed = flag[:, None, :] + (1j * COMPLEX_STEP) * np.eye(6)[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = flag_quantities(k, perturbed)  # (6 quantities, 6 directions, n)
    values = np.ascontiguousarray(out[:, 0, :].real, dtype=float)
    jacobian = np.ascontiguousarray(out.imag / COMPLEX_STEP, dtype=float)
    return values, jacobian


@dataclass(frozen=True)
class _Affine:
    """Coefficients affine in the decision vector: C^T(x) = base + sum_v x_v slope[v].

    base : (size, 2); slope : (nv, size, 2), nv counting every decision variable (including
    an epigraph variable, whose slope is zero).
    """

    basis: Basis
    base: Array
    slope: Array

    def coefficients(self, x: Array) -> Array:
        """(2, size) coefficients of y1, y2 at the decision vector x (nv,)."""
        return np.ascontiguousarray((self.base + np.tensordot(x, self.slope, axes=1)).T)

    def flag(self, t: Array) -> tuple[Array, Array]:
        """Flag at x = 0, (6, n), and its constant derivative in x, (6, n, nv), at times t."""
        base = np.empty((6, t.size))
        slope = np.empty((6, t.size, self.slope.shape[0]))
        for order in range(3):
            phi = self.basis.matrix(t, order)  # (n, size)
            for out in range(2):
                base[2 * order + out] = phi @ self.base[:, out]
                slope[2 * order + out] = phi @ self.slope[:, :, out].T
        return base, slope


@dataclass(frozen=True)
class _Rows:
    """Inequality rows g = a q[quantity, time] + b + c s >= 0 (s: the epigraph variable)."""

    quantity: NDArray[np.intp]
    a: Array
    b: Array
    c: Array
    bound: Array  # the user's limit behind each row (inf for epigraph rows)
    label: tuple[str, ...]


def _limit_rows(limits: PlanLimits, objective: _Goal) -> _Rows:
    """The inequality rows of a problem.

    Each finite limit (both signs), the margin, and the epigraph rows of the "peak_rate" or
    "margin" objective (unlabelled, bound inf). For "violation" every angle and rate row is
    relaxed by s max(1, |limit|), so that the least s is their largest relative violation.
    """
    relax = objective == "violation"
    quantity: list[int] = []
    a: list[float] = []
    b: list[float] = []
    c: list[float] = []
    bound: list[float] = []
    label: list[str] = []

    def add(q: int, sign: float, limit: float, eps: float, name: str) -> None:
        quantity.append(q)
        a.append(sign)
        b.append(limit - BACKOFF * max(1.0, abs(limit)) if name else limit)
        c.append(max(1.0, abs(limit)) if relax and name else eps)
        bound.append(abs(limit) if name else math.inf)
        label.append(name)

    for i, lim in enumerate(limits.angle_limit):
        if math.isfinite(lim):
            for sign in (-1.0, 1.0):
                add(i, sign, lim, 0.0, f"angle_limit[{i}] on th{i}")
    if math.isfinite(limits.rate_limit):
        for q in (_RATE1, _RATE2):
            for sign in (-1.0, 1.0):
                add(q, sign, limits.rate_limit, 0.0, f"rate_limit on {_QUANTITY_NAMES[q]}")
    # the margin row: sigma sin(y1) y1' - m >= 0 (sigma is folded into the quantity)
    quantity.append(_MARGIN)
    a.append(1.0)
    b.append(-limits.min_margin - BACKOFF * max(1.0, limits.min_margin))
    c.append(0.0)  # never relaxed: it keeps every plan off the singular set
    bound.append(limits.min_margin)
    label.append("min_margin")
    if objective == "peak_rate":
        for q in (_RATE1, _RATE2):
            for sign in (-1.0, 1.0):
                add(q, sign, 0.0, 1.0, "")
    elif objective == "margin":
        add(_MARGIN, 1.0, 0.0, -1.0, "")
    return _Rows(
        np.asarray(quantity, dtype=np.intp),
        np.asarray(a),
        np.asarray(b),
        np.asarray(c),
        np.asarray(bound),
        tuple(label),
    )


class _Problem:
    """The nonlinear programme in x: objective, constraints and their exact Jacobians.

    Pointwise quantities live on two time sets: the constraint grid (``times``, grown by the
    exchange rounds) and the nodes of the energy quadrature. Values and gradients are cached
    per decision vector, and gradients are formed only for the quantities that are used.
    """

    def __init__(
        self,
        k: Coefficients,
        affine: _Affine,
        rows: _Rows,
        objective: _Goal,
        sigma: float,
        duration: float,
        times: Array,
        check: Array,
    ) -> None:
        self.k = k
        self.affine = affine
        self.rows = rows
        self.objective = objective
        self.sigma = sigma
        self.duration = duration
        self.nv = affine.slope.shape[0]
        self.epigraph = objective in _EPIGRAPH
        nodes, self.weights = composite_gauss_legendre(duration, ENERGY_PIECES, ENERGY_ORDER)
        self.flags: dict[str, tuple[Array, Array]] = {"quad": affine.flag(nodes)}
        self.needed: dict[str, list[int]] = {
            "quad": [_RATE1, _RATE2],
            "grid": sorted(set(rows.quantity.tolist())),
        }
        self.check = check
        self.check_flag = affine.flag(check)
        self.b = rows.b.copy()  # row offsets, tightened by the exchange rounds
        # which (row, time) pairs the solver sees, and their scaling: set by ``prepare``
        self.mask = np.ones((0, 0), dtype=bool)
        self.weight = np.ones(0)
        self.scale = 1.0
        #: (low, high) per decision variable (None: unbounded), set by ``optimize_plan``
        self.bounds: list[tuple[float | None, float | None]] = [(None, None)] * self.nv
        self.evaluations = 0
        self._values: dict[str, tuple[bytes, Array]] = {}
        self._grads: dict[str, tuple[bytes, Array]] = {}
        self.set_times(times)

    def set_times(self, times: Array) -> None:
        """Impose the limits at these times [s] (sorted, duplicates dropped)."""
        self.times = np.unique(times)
        self.flags["grid"] = self.affine.flag(self.times)
        self._values.pop("grid", None)
        self._grads.pop("grid", None)
        self.mask = np.ones((len(self.rows.label), self.times.size), dtype=bool)
        self.weight = np.ones(self.mask.sum())

    def prepare(self, x: Array) -> None:
        """Choose and scale the constraints the solver sees, fixed until the next call.

        Angle, rate and peak-rate rows with a slack above ``SCREEN`` max(1, limit or peak)
        at x are left out (the exchange rounds restore any that end up violated); the margin
        rows, the guard against the singular set, are always in. Every row is scaled by
        1 / (its gradient norm at x): near the singular set th2' is extremely sensitive to the
        coefficients (gradient norms span ~5 orders of magnitude on the paper's maneuver) and
        SLSQP's subproblems stall on such rows unless they are normalised. Neither changes
        the feasible set the exchange rounds enforce.
        """
        r = self.rows
        g = self.row_values(x)
        screened = r.quantity != _MARGIN
        size = np.where(np.isfinite(r.bound), r.bound, abs(float(x[-1])) if self.epigraph else 1.0)
        loose = g > SCREEN * np.maximum(1.0, size)[:, None]
        self.mask = ~(screened[:, None] & loose)
        norms = np.linalg.norm(self.row_jacobian(x)[self.mask], axis=1)
        self.weight = 1.0 / np.clip(norms, 1e-8, None)

    def values(self, x: Array, which: str) -> Array:
        """(6, n) pointwise quantities (margin signed) on the grid or the quadrature nodes."""
        key = x.tobytes()
        hit = self._values.get(which)
        if hit is not None and hit[0] == key:
            return hit[1]
        self.evaluations += which == "grid"
        base, slope = self.flags[which]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            values = np.asarray(flag_quantities(self.k, base + slope @ x), dtype=float)
        values[_MARGIN] *= self.sigma
        if not np.all(np.isfinite(values)):  # a trial point on the singular set
            values = np.nan_to_num(values, nan=-_BIG, posinf=_BIG, neginf=-_BIG)
        self._values[which] = (key, values)
        return values

    def gradients(self, x: Array, which: str) -> Array:
        """(6, n, nv) exact gradients of ``values`` (zero for quantities not in use)."""
        key = x.tobytes()
        hit = self._grads.get(which)
        if hit is not None and hit[0] == key:
            return hit[1]
        base, slope = self.flags[which]
        _, jac = flag_jacobian(self.k, base + slope @ x)
        jac[_MARGIN] *= self.sigma
        grad = np.zeros((6, base.shape[1], self.nv))
        for q in self.needed[which]:
            grad[q] = np.einsum("cn,cnv->nv", jac[q], slope)
        if not np.all(np.isfinite(grad)):
            grad = np.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)
        self._grads[which] = (key, grad)
        return grad

    def energy(self, x: Array) -> float:
        """Integral of th1'^2 + th2'^2 over [0, T] [rad^2/s]."""
        v = self.values(x, "quad")
        return float(self.weights @ (v[_RATE1] ** 2 + v[_RATE2] ** 2))

    def energy_gradient(self, x: Array) -> Array:
        """(nv,) gradient of ``energy``."""
        v = self.values(x, "quad")
        g = self.gradients(x, "quad")
        w = 2.0 * self.weights
        return np.asarray((w * v[_RATE1]) @ g[_RATE1] + (w * v[_RATE2]) @ g[_RATE2])

    @property
    def factor(self) -> float:
        return self.duration if self.objective == "effort" else 1.0

    def fun(self, x: Array) -> float:
        """Objective (minimised), divided by ``scale``."""
        if self.objective in ("peak_rate", "violation"):
            return float(x[-1]) / self.scale
        if self.objective == "margin":
            return -float(x[-1]) / self.scale
        return self.factor * self.energy(x) / self.scale

    def jac(self, x: Array) -> Array:
        """(nv,) gradient of ``fun``."""
        if self.epigraph:
            out = np.zeros(self.nv)
            out[-1] = (-1.0 if self.objective == "margin" else 1.0) / self.scale
            return out
        return self.factor * self.energy_gradient(x) / self.scale

    def row_values(self, x: Array) -> Array:
        """(rows, times) every inequality row on the grid, >= 0 when met (unscaled)."""
        v = self.values(x, "grid")
        r = self.rows
        s = float(x[-1]) if self.epigraph else 0.0
        return np.asarray(r.a[:, None] * v[r.quantity] + (self.b + r.c * s)[:, None])

    def row_jacobian(self, x: Array) -> Array:
        """(rows, times, nv) gradients of ``row_values``."""
        grad = self.gradients(x, "grid")
        r = self.rows
        out = r.a[:, None, None] * grad[r.quantity]
        if self.epigraph:
            out[:, :, -1] += r.c[:, None]
        return np.asarray(out)

    def cons(self, x: Array) -> Array:
        """The rows the solver sees (see ``prepare``), scaled, >= 0 when met."""
        return np.asarray(self.weight * self.row_values(x)[self.mask])

    def cons_jac(self, x: Array) -> Array:
        """Jacobian of ``cons``."""
        return np.asarray(self.weight[:, None] * self.row_jacobian(x)[self.mask])

    def check_values(self, x: Array) -> Array:
        """(6, n_check) pointwise quantities on the check grid (non-finite kept)."""
        base, slope = self.check_flag
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            values = np.asarray(flag_quantities(self.k, base + slope @ x), dtype=float)
        values[_MARGIN] *= self.sigma
        return values


@dataclass(frozen=True)
class _Assessment:
    """A candidate plan measured on the check grid against the user's limits."""

    objective: float
    max_violation: float  # absolute, >= 0 [rad or rad/s]
    relative_violation: float  # largest excess / max(1, |limit|), >= 0
    worst: str  # a one-line description of the worst violation ('' if feasible)
    row_excess: Array  # (rows, n_check): excess over each row (> 0 where missed)

    @property
    def feasible(self) -> bool:
        return self.relative_violation <= FEASIBILITY_TOL and math.isfinite(self.objective)


def _assess(problem: _Problem, x: Array, limits: PlanLimits) -> _Assessment:
    """Objective and limit violations of the plan at x on the problem's check grid."""
    values = problem.check_values(x)
    r = problem.rows
    limit_rows = np.array([bool(name) for name in r.label])
    q = values[r.quantity]  # (rows, n_check)
    is_margin = (r.quantity == _MARGIN)[:, None]
    # |q| <= L rows (a = -1: q - L; a = +1: -q - L); the margin row: m - q
    excess = np.where(is_margin, r.bound[:, None] - q, -r.a[:, None] * q - r.bound[:, None])
    excess = np.where(np.isnan(excess), math.inf, excess)
    if problem.epigraph:  # where the check grid exceeds the epigraph variable
        s = float(x[-1])
        excess[~limit_rows] = -(
            r.a[~limit_rows, None] * q[~limit_rows] + r.c[~limit_rows, None] * s
        )
    scale = np.maximum(1.0, r.bound[limit_rows])
    rel = excess[limit_rows] / scale[:, None]
    max_violation = float(max(0.0, np.max(excess[limit_rows], initial=0.0)))
    relative = float(max(0.0, np.max(rel, initial=0.0)))
    objective = relative if problem.objective == "violation" else _objective_on(problem, x, values)
    worst = ""
    if relative > FEASIBILITY_TOL:
        row, j = np.unravel_index(int(np.argmax(rel)), rel.shape)
        worst = _describe(
            r, int(np.flatnonzero(limit_rows)[row]), values, problem.check, int(j), limits
        )
    return _Assessment(objective, max_violation, relative, worst, excess)


def _objective_on(problem: _Problem, x: Array, values: Array) -> float:
    """The user-facing objective: energy/effort by quadrature, peak/margin on the check grid."""
    if problem.objective == "peak_rate":
        return float(np.max(np.abs(values[[_RATE1, _RATE2]])))
    if problem.objective == "margin":
        return float(np.min(values[_MARGIN]))
    return problem.factor * problem.energy(x)


def _describe(r: _Rows, row: int, values: Array, check: Array, j: int, limits: PlanLimits) -> str:
    """One line naming a violated limit, its value and how far the plan goes past it."""
    q = int(r.quantity[row])
    t = float(check[j])
    value = float(values[q, j])
    if q == _MARGIN:
        return (
            f"plan.optimize.min_margin = {limits.min_margin:g} rad/s cannot be met: the best "
            f"plan found has a margin of {value:.4g} rad/s at t = {t:.3f} s"
        )
    if q in (_RATE1, _RATE2):
        return (
            f"plan.optimize.rate_limit = {limits.rate_limit:g} rad/s cannot be met: the best "
            f"plan found reaches |{_QUANTITY_NAMES[q]}| = {abs(value):.4g} rad/s at t = {t:.3f} s"
        )
    return (
        f"plan.optimize.angle_limit[{q}] = {limits.angle_limit[q]:g} rad cannot be met: the "
        f"best plan found reaches |th{q}| = {abs(value):.4g} rad at t = {t:.3f} s"
    )


def _active(problem: _Problem, x: Array) -> tuple[str, ...]:
    """Limits with (almost) no slack on the constraint grid, grouped into runs of times."""
    values = problem.values(x, "grid")
    r = problem.rows
    t = problem.times
    found: list[tuple[float, str]] = []
    for row, name in enumerate(r.label):
        if not name:
            continue
        slack = r.a[row] * values[r.quantity[row]] + problem.b[row]  # the bound as imposed
        tight = np.flatnonzero(slack <= ACTIVE_TOL * max(1.0, r.bound[row]))
        for run in np.split(tight, np.flatnonzero(np.diff(tight) > 1) + 1) if tight.size else []:
            first, last = f"{t[run[0]]:.2f}", f"{t[run[-1]]:.2f}"
            when = first if first == last else f"{first}-{last}"
            found.append((float(t[run[0]]), f"{name} at t={when} s"))
    unique: list[str] = []
    for _, text in sorted(found):
        if text not in unique:
            unique.append(text)
    return tuple(unique)


def _check_ends(
    k: Coefficients,
    start: Array,
    goal: Array,
    start_rate: float,
    goal_rate: float,
    duration: float,
    limits: PlanLimits,
    free_rates: bool,
) -> tuple[float, float, float]:
    """Up-front feasibility checks; returns the signed margin sigma and feasible end rates."""
    for key, theta in (("start", start), ("goal", goal)):
        for i in range(3):
            if abs(theta[i]) > limits.angle_limit[i]:
                raise FlatcliError(
                    f"plan.optimize.angle_limit[{i}] = {limits.angle_limit[i]:g} rad cannot be "
                    f"met: the {key} configuration has |th{i}| = {abs(theta[i]):g} rad"
                )
    th1_0, th1_T = float(start[1]), float(goal[1])
    m = limits.min_margin
    # sin th1 must keep its sign: th1 stays inside one interval (k pi, (k + 1) pi)
    if math.floor(th1_0 / math.pi) != math.floor(th1_T / math.pi):
        raise FlatcliError(
            f"plan.goal[1] = {th1_T:g} rad: th1 would have to cross a multiple of pi from "
            f"plan.start[1] = {th1_0:g} rad, where the flat map is singular (sin th1 = 0)"
        )
    travel = th1_T - th1_0
    if travel == 0:
        raise FlatcliError(
            "plan.goal[1] equals plan.start[1]: th1 would have to stop and turn back, crossing "
            "the singular set th1' = 0; a flat plan needs th1 to move monotonically"
        )
    direction = math.copysign(1.0, travel)
    if free_rates:
        # the sign of th1' is forced by the direction of travel; clip the guesses to the limits
        start_rate = direction * abs(start_rate)
        goal_rate = direction * abs(goal_rate)
    elif math.copysign(1.0, start_rate) != direction or math.copysign(1.0, goal_rate) != direction:
        raise FlatcliError(
            f"plan.optimize.min_margin = {m:g} rad/s cannot be met: th1 moves from "
            f"{th1_0:g} to {th1_T:g} rad but the fixed end rates plan.start_rate = "
            f"{start_rate:g} and plan.goal_rate = {goal_rate:g} rad/s do not both point that "
            "way, so th1' must cross 0"
        )
    sigma = math.copysign(1.0, math.sin(th1_0) * start_rate)
    available = sigma * (math.cos(th1_0) - math.cos(th1_T))
    if available < m * duration:
        raise FlatcliError(
            f"plan.optimize.min_margin = {m:g} rad/s cannot be met: the margin "
            f"|sin th1 th1'| = |d(cos th1)/dt| averages |cos th1(0) - cos th1(T)| / T = "
            f"{available / duration:.4g} rad/s over this maneuver"
        )
    R = limits.rate_limit
    if abs(travel) > R * duration:
        raise FlatcliError(
            f"plan.optimize.rate_limit = {R:g} rad/s cannot be met: th1 must move "
            f"{abs(travel):g} rad in {duration:g} s, {abs(travel) / duration:.4g} rad/s on average"
        )
    rates = []
    for key, th1, rate in (("start", th1_0, start_rate), ("goal", th1_T, goal_rate)):
        low = m / abs(math.sin(th1))
        if free_rates:
            if low > R:
                raise FlatcliError(
                    f"plan.optimize.min_margin = {m:g} rad/s cannot be met within "
                    f"plan.optimize.rate_limit = {R:g} rad/s at the {key}: |sin th1| = "
                    f"{abs(math.sin(th1)):.4g} needs |th1'| >= {low:.4g} rad/s there"
                )
            rate = math.copysign(min(max(abs(rate), low * (1 + 1e-3)), R), rate)
        else:
            if abs(rate) > R:
                raise FlatcliError(
                    f"plan.optimize.rate_limit = {R:g} rad/s cannot be met: plan.{key}_rate = "
                    f"{rate:g} rad/s is fixed (free_rates = false)"
                )
            if abs(math.sin(th1) * rate) < m:
                raise FlatcliError(
                    f"plan.optimize.min_margin = {m:g} rad/s cannot be met: the fixed "
                    f"plan.{key}_rate = {rate:g} rad/s gives a margin of "
                    f"{abs(math.sin(th1) * rate):.4g} rad/s at the {key} (free_rates = false)"
                )
        rates.append(rate)
    _check_fold(k, start, goal, duration, limits)
    return sigma, rates[0], rates[1]


def required_fold(k: Coefficients, start: ArrayLike, goal: ArrayLike, nodes: int = 32) -> float:
    """A value th2 must reach somewhere on any flat plan from ``start`` to ``goal`` [rad].

    With th1 moving monotonically (as a positive margin forces) the flat output obeys
    y2' = (g - h th2) th1' (``flatness``), so, integrating over th1 instead of time,

        integral of h th2 dth1 = integral of g dth1 - (y2(T) - y2(0)) =: D.

    h has one sign between th1(0) and th1(T), so th2 cannot stay strictly on the near side
    of v = D / (integral of h dth1) throughout: th2 >= v somewhere if v > 0, th2 <= v
    somewhere if v < 0. Only the end configurations enter, so this is a necessary condition
    for any flat plan of the maneuver, whatever the basis or the end rates; the bound is
    approached only by th2 staying at v the whole time, so real plans fold further.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    start, goal : (3,) th0, th1, th2 [rad]; th1 must differ and sin th1 keep its sign
    nodes : Gauss-Legendre nodes for the two integrals over th1 (smooth integrands)

    Returns
    -------
    v : float [rad]; 0 when th1 does not move
    """
    start = np.asarray(start, dtype=float)
    goal = np.asarray(goal, dtype=float)
    lo, hi = float(start[1]), float(goal[1])
    if lo == hi:
        return 0.0
    x, w = np.polynomial.legendre.leggauss(nodes)
    th1 = 0.5 * (hi - lo) * (x + 1.0) + lo
    weights = 0.5 * (hi - lo) * w
    _, g, h = chart(k, np.cos(th1), np.sin(th1))
    rise = _end_flat(k, goal)[1] - _end_flat(k, start)[1]
    return (float(weights @ g) - rise) / float(weights @ h)


def _check_fold(
    k: Coefficients, start: Array, goal: Array, duration: float, limits: PlanLimits
) -> None:
    """th2 must reach ``required_fold``: against the th2 angle limit and the rate limit."""
    v = required_fold(k, start, goal)
    lim = limits.angle_limit[2]
    if abs(v) > lim:
        raise FlatcliError(
            f"plan.optimize.angle_limit[2] = {lim:g} rad cannot be met: momentum conservation "
            f"forces th2 to reach {v:.4g} rad somewhere on any plan of this maneuver"
        )
    side = math.copysign(1.0, v)
    travel = max(0.0, side * (v - start[2])) + max(0.0, side * (v - goal[2]))
    R = limits.rate_limit
    if travel > R * duration:
        raise FlatcliError(
            f"plan.optimize.rate_limit = {R:g} rad/s cannot be met: momentum conservation "
            f"forces th2 from {start[2]:g} to {v:.4g} and on to {goal[2]:g} rad, "
            f"{travel / duration:.4g} rad/s on average"
        )


def _affine_map(
    k: Coefficients,
    basis: Basis,
    start: Array,
    goal: Array,
    start_rate: float,
    goal_rate: float,
    free_rates: bool,
    epigraph: bool,
) -> tuple[_Affine, Array]:
    """The affine coefficient map and the starting guess x0 (the min-acceleration plan)."""
    system = boundary_system(basis)  # type: ignore[arg-type]
    P = system.particular  # (size, 4)
    N = system.null  # (size, m)
    m = N.shape[1]
    y1_0, y2_0, k0 = _end_flat(k, start)  # k0 = y2'(0) / th1'(0)
    y1_T, y2_T, kT = _end_flat(k, goal)
    R0 = np.zeros((4, 2))
    R0[0] = (y1_0, y2_0)
    R0[2] = (y1_T, y2_T)
    Ra = np.zeros((4, 2))
    Ra[1] = (1.0, k0)
    Rb = np.zeros((4, 2))
    Rb[3] = (1.0, kT)
    slopes: list[Array] = []
    if free_rates:
        base = P @ R0
        slopes += [P @ Ra, P @ Rb]
    else:
        base = P @ (R0 + start_rate * Ra + goal_rate * Rb)
    for out in range(2):
        for j in range(m):
            s = np.zeros((basis.size, 2))
            s[:, out] = N[:, j]
            slopes.append(s)
    if epigraph:
        slopes.append(np.zeros((basis.size, 2)))
    affine = _Affine(basis, base, np.asarray(slopes).reshape(-1, basis.size, 2))
    bc = boundary_conditions(k, start, goal, start_rate, goal_rate)
    guess = min_acceleration_trajectory(basis, bc).coefficients.T  # (size, 2)
    rhs = R0 + start_rate * Ra + goal_rate * Rb
    z = N.T @ (guess - P @ rhs)  # (m, 2)
    rates = [start_rate, goal_rate] if free_rates else []
    epigraph_start = [0.0] if epigraph else []
    return affine, np.concatenate([rates, z[:, 0], z[:, 1], epigraph_start])


def _rate_bounds(
    theta: Array, limits: PlanLimits, rate: float
) -> tuple[float | None, float | None]:
    """Bounds on a free end rate [rad/s]: sign of ``rate``, margin and rate limit."""
    low = limits.min_margin / abs(math.sin(theta[1]))
    high = None if math.isinf(limits.rate_limit) else limits.rate_limit
    if rate > 0:
        return low, high
    return (None if high is None else -high), -low


def _end_flat(k: Coefficients, theta: Array) -> tuple[float, float, float]:
    """y1, y2 [rad] and y2' / th1' [-] at a configuration (y2' is linear in th1')."""
    y1, y2, _, slope = flat_outputs(k, float(theta[0]), float(theta[1]), float(theta[2]), 1.0)
    return float(y1), float(y2), float(slope)


class _Tracker:
    """Solver callback: the best iterate that (nearly) meets every row on the grid.

    Where to go on from if the solver later steps astray.
    """

    def __init__(self, problem: _Problem, row_scale: Array) -> None:
        self.problem = problem
        self.row_scale = row_scale
        self.best: tuple[float, Array] | None = None

    def __call__(self, xk: Array) -> None:
        g = self.problem.row_values(xk) / self.row_scale[:, None]
        if np.min(g) >= -RESTART_TOL:
            f = self.problem.fun(xk)
            if self.best is None or f < self.best[0]:
                self.best = (f, np.array(xk, dtype=float))


def _solve(
    problem: _Problem, x: Array, limits: PlanLimits, max_iter: int
) -> tuple[Array, int, str]:
    """SLSQP from x, then exchange rounds until the check grid meets every limit.

    Returns the best feasible point seen (the least violating one if none was), the
    iterations summed over the rounds and the last solver message, prefixed "ok: " when
    that round converged and its plan is the one returned.
    """
    limit_rows = np.array([bool(name) for name in problem.rows.label])
    row_scale = np.maximum(1.0, np.where(limit_rows, problem.rows.bound, 1.0))
    sign = -1.0 if problem.objective == "margin" else 1.0  # margin is maximised
    start = _assess(problem, x, limits)
    best = (sign * start.objective, x) if start.feasible else None
    least = (start.relative_violation, x)  # the least violating point, if none is feasible
    iterations = 0
    message = ""
    for _ in range(EXCHANGE_ROUNDS):
        problem.prepare(x)
        track = _Tracker(problem, row_scale)
        result = minimize(
            problem.fun,
            x,
            jac=problem.jac,
            method="SLSQP",
            bounds=problem.bounds,
            constraints=[{"type": "ineq", "fun": problem.cons, "jac": problem.cons_jac}],
            options={"maxiter": max_iter, "ftol": SOLVER_TOL},
            callback=track,
        )
        iterations += int(result.nit)
        message = ("ok: " if result.success else "") + str(result.message)
        x = np.asarray(result.x, dtype=float)
        found = _assess(problem, x, limits)
        if found.feasible and (best is None or sign * found.objective < best[0]):
            best = (sign * found.objective, x)
        if found.relative_violation < least[0]:
            least = (found.relative_violation, x)
        if found.relative_violation > max(least[0] * ROUND_REJECT, REJECT_FLOOR):
            # the solver went astray (typically near the singular set): solve again from its
            # best sane iterate, or stop at the best point so far
            if track.best is not None:
                x = track.best[1]
                continue
            x = least[1] if best is None else best[1]
            break
        # epigraph rows are refined only where the check grid exceeds them noticeably (the
        # objective is measured on the check grid anyway), limit rows wherever violated
        epigraph_tol = EPIGRAPH_TOL * max(1.0, abs(float(x[-1])))
        excess = np.where(limit_rows[:, None], found.row_excess, found.row_excess - epigraph_tol)
        if problem.objective == "violation":  # limits relaxed by s max(1, limit)
            excess -= problem.rows.c[:, None] * float(x[-1])
        missed = _exchange_times(excess, problem.check)
        if not missed.size:
            break
        # impose the limits at the missed times too, and tighten each violated limit by
        # twice its excess (at most TIGHTEN_CAP of it: a large excess comes from a row that
        # was screened out, not from between samples), so the next round lands inside it
        worst = np.max(excess, axis=1)
        tighten = limit_rows & (worst > 0)
        cap = TIGHTEN_CAP * np.maximum(1.0, problem.rows.bound[tighten])
        problem.b[tighten] -= np.minimum(2.0 * worst[tighten], cap)
        problem.set_times(np.concatenate([problem.times, missed]))
    chosen = least[1] if best is None else best[1]
    if chosen is not x:
        message = (
            message.removeprefix("ok: ") + "; an earlier point was kept, better than the last "
            "round's plan"
        )
    return chosen, iterations, message


def _exchange_times(excess: Array, check: Array) -> Array:
    """Check-grid times [s] where a row's excess is positive at a local maximum."""
    times: list[float] = []
    for row in excess:
        if not np.any(row > 0):
            continue
        padded = np.concatenate([[-math.inf], row, [-math.inf]])
        peak = (padded[1:-1] >= padded[:-2]) & (padded[1:-1] >= padded[2:]) & (row > 0)
        times.extend(check[peak].tolist())
    return np.unique(np.asarray(times, dtype=float))


def _lift(problem: _Problem, curve: Array) -> Array:
    """The decision vector of ``problem`` for the flat curve ``curve`` (x without s).

    The epigraph variable, if any, is set where its rows hold with equality on the grid:
    the peak rate, the least margin, or the largest relative violation.
    """
    if not problem.epigraph:
        return curve
    x = np.append(curve, 0.0)
    if problem.objective == "peak_rate":
        x[-1] = np.max(np.abs(problem.values(x, "grid")[[_RATE1, _RATE2]]))
    elif problem.objective == "margin":
        x[-1] = np.min(problem.values(x, "grid")[_MARGIN])
    else:
        g = problem.row_values(x)
        relaxed = problem.rows.c > 0
        x[-1] = max(0.0, float(np.max(-g[relaxed] / problem.rows.c[relaxed, None])))
    return x


def optimize_plan(
    robot: RobotParams,
    start: ArrayLike,
    goal: ArrayLike,
    duration: float,
    *,
    model: Model = "derived",
    basis: Basis | None = None,
    objective: Objective = "energy",
    limits: PlanLimits | None = None,
    free_rates: bool = True,
    start_rate: float = 0.1,
    goal_rate: float = 0.5,
    constraint_samples: int = 201,
    max_iter: int = 300,
) -> OptimizeResult:
    """Optimal flat plan from ``start`` to ``goal`` in ``duration`` seconds, under limits.

    Parameters
    ----------
    robot : a flat design (d2 = 0)
    start, goal : (3,) configurations th0, th1, th2 [rad]
    duration : T [s] > 0
    model : which constraint coefficients the planner believes
    basis : flat-output basis on [0, T]; default ``default_basis(duration)`` (quintic
        B-splines with 12 coefficients)
    objective : "energy", "effort", "peak_rate" or "margin" (see the module docstring).
        "margin" is solved in two stages: the largest achievable minimum margin s*, then
        the least-energy plan whose margin stays >= (1 - ``MARGIN_TIE``) s* (the maximiser
        alone is not unique: y2 does not enter the margin, and leaving it arbitrary gives
        wild th2).
    limits : PlanLimits; default PlanLimits() (no angle or rate limits, margin >= 0.02 rad/s)
    free_rates : optimise th1'(0) and th1'(T) too; otherwise they stay at the given values
    start_rate, goal_rate : th1'(0), th1'(T) [rad/s] of the starting guess (the paper's 0.1
        and 0.5), or the fixed end rates when ``free_rates`` is False. With free rates their
        signs follow the direction th1 moves and they are clipped into the range the limits
        allow.
    constraint_samples : equally spaced times where the limits are imposed (>= 10); the
        check grid has ``CHECK_REFINEMENT`` times as many intervals
    max_iter : solver iteration limit per exchange round (>= 1)

    Returns
    -------
    OptimizeResult; its objective is never worse than the starting guess's when that is
    feasible (the starting guess is returned if the solver does not improve on it)

    Raises
    ------
    FlatcliError, one line naming the limit that cannot be met and by how much: for a
    request found infeasible up front (see the module docstring), or when no plan meeting
    the limits is found; the line then describes the plan that exceeds them least, found by
    a phase-1 solve minimising the largest relative excess over the angle and rate limits
    (e.g. the least achievable peak rate when the rate limit is below it).
    """
    require_flat(robot)
    if objective not in OBJECTIVES:
        raise FlatcliError(
            f"plan.optimize.objective: expected one of {list(OBJECTIVES)}, got {objective!r}"
        )
    if not duration > 0:
        raise FlatcliError(f"plan.duration: must be > 0 s, got {duration}")
    if constraint_samples < 10:
        raise FlatcliError(
            f"plan.optimize.constraint_samples: must be >= 10, got {constraint_samples}"
        )
    if max_iter < 1:
        raise FlatcliError(f"plan.optimize.max_iter: must be >= 1, got {max_iter}")
    limits = PlanLimits() if limits is None else limits
    start_arr = np.asarray(start, dtype=float)
    goal_arr = np.asarray(goal, dtype=float)
    if basis is None:
        basis = default_basis(duration)
    elif not math.isclose(basis.duration, duration):
        raise FlatcliError("plan basis: its duration differs from plan.duration")
    k = constraint_coefficients(robot.links, model)
    sigma, r0, rT = _check_ends(
        k, start_arr, goal_arr, start_rate, goal_rate, duration, limits, free_rates
    )
    times = np.linspace(0.0, duration, constraint_samples)
    check = np.linspace(0.0, duration, CHECK_REFINEMENT * (constraint_samples - 1) + 1)

    def setup(goal: _Goal, limits: PlanLimits) -> _Problem:
        affine, _ = _affine_map(
            k, basis, start_arr, goal_arr, r0, rT, free_rates, goal in _EPIGRAPH
        )
        problem = _Problem(
            k, affine, _limit_rows(limits, goal), goal, sigma, duration, times, check
        )
        # bounds keep SLSQP's steps sane: the end rates on the side the margin allows, a
        # peak rate or violation >= 0, a margin <= its mean over the maneuver (``_check_ends``)
        if free_rates:
            problem.bounds[:2] = [
                _rate_bounds(th, limits, r) for th, r in ((start_arr, r0), (goal_arr, rT))
            ]
        if goal in ("peak_rate", "violation"):
            problem.bounds[-1] = (0.0, None)
        elif goal == "margin":
            mean = sigma * (math.cos(start_arr[1]) - math.cos(goal_arr[1])) / duration
            problem.bounds[-1] = (None, mean)
        return problem

    _, curve0 = _affine_map(k, basis, start_arr, goal_arr, r0, rT, free_rates, False)
    problem = setup(objective, limits)
    x0 = _lift(problem, curve0)
    initial = _assess(problem, x0, limits)
    problem.scale = max(abs(initial.objective), 1e-12)
    x, iterations, evaluations = x0, 0, 0
    if objective == "peak_rate":
        # warm start from the least-energy plan: SLSQP on the minimax problem straight from
        # the cubic (th2' ~ 49 rad/s next to the singular set) can step far astray
        first = setup("energy", limits)
        first.scale = max(first.energy(curve0), 1e-12)
        curve, iterations, _ = _solve(first, curve0, limits, max_iter)
        evaluations = first.evaluations
        warm = _lift(problem, curve)
        if _assess(problem, warm, limits).feasible:
            x = warm
    x, more, message = _solve(problem, x, limits, max_iter)
    iterations += more
    evaluations += problem.evaluations
    final = _assess(problem, x, limits)
    if not final.feasible and not initial.feasible:
        # phase 1: the plan that violates the limits least; from there, solve again if it
        # meets them after all, otherwise it measures how far the request is out of reach
        # (started from the least-energy plan under the margin alone, for the reason above)
        margin_only = PlanLimits(min_margin=limits.min_margin)
        first = setup("energy", margin_only)
        first.scale = max(first.energy(curve0), 1e-12)
        curve, more, _ = _solve(first, curve0, margin_only, max_iter)
        iterations += more
        evaluations += first.evaluations
        phase = setup("violation", limits)
        cubic = _lift(phase, curve0)
        start = min((_lift(phase, curve), cubic), key=lambda x: float(x[-1]))
        # scaled by the starting guess's violation, as the objectives are by its value:
        # a larger normalised gradient makes SLSQP's first steps too long to stay sane
        phase.scale = max(float(cubic[-1]), 1.0)
        curve, more, _ = _solve(phase, start, limits, max_iter)
        iterations += more
        evaluations += phase.evaluations
        x = _lift(problem, curve[:-1])
        final = _assess(problem, x, limits)
        if final.feasible:
            x, more, message = _solve(problem, x, limits, max_iter)
            iterations += more
            final = _assess(problem, x, limits)
    if objective == "margin" and final.feasible:
        # stage 2: the least-energy plan whose margin stays within MARGIN_TIE of the best
        tie = replace(limits, min_margin=max(limits.min_margin, (1 - MARGIN_TIE) * final.objective))
        second = setup("energy", tie)
        second.scale = max(second.energy(x[:-1]), 1e-12)
        curve, more, message = _solve(second, x[:-1], tie, max_iter)
        iterations += more
        evaluations += second.evaluations
        settled = _lift(problem, curve)
        if _assess(problem, settled, limits).feasible:
            x = settled
        final = _assess(problem, x, limits)

    better = (
        final.objective >= initial.objective
        if objective == "margin"
        else (final.objective <= initial.objective)
    )
    if initial.feasible and not (final.feasible and better):
        x, final = x0, initial
        message += "; the starting guess was kept (the solver did not improve on it)"
    if not final.feasible:
        raise FlatcliError(final.worst or f"plan.optimize: the solver failed ({message})")

    def plan_at(x: Array) -> FlatPlan:
        trajectory = FlatTrajectory(basis, problem.affine.coefficients(x))
        return FlatPlan(robot, model, k, trajectory, duration)

    plan = plan_at(x)
    reported, reported_initial = final.objective, initial.objective
    if objective in ("energy", "effort"):  # exactly what FlatPlan.input_energy says
        factor = problem.factor
        reported = factor * plan.input_energy(ENERGY_PIECES, ENERGY_ORDER)
        reported_initial = factor * plan_at(x0).input_energy(ENERGY_PIECES, ENERGY_ORDER)
    return OptimizeResult(
        plan=plan,
        success=message.startswith("ok: "),
        objective=reported,
        initial_objective=reported_initial,
        iterations=iterations,
        evaluations=evaluations,
        active=_active(problem, x) + (() if free_rates else ("fixed end rates",)),
        max_violation=final.max_violation,
        start_rate=float(x[0]) if free_rates else r0,
        goal_rate=float(x[1]) if free_rates else rT,
        message=message.removeprefix("ok: "),
    )


__all__ = [
    "OBJECTIVES",
    "Objective",
    "OptimizeResult",
    "PlanLimits",
    "default_basis",
    "flag_jacobian",
    "flag_quantities",
    "optimize_plan",
    "required_fold",
]
