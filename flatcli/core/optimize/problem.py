"""The nonlinear programme in the decision vector: objective, constraints, exact Jacobians.

A ``Problem`` is one goal (an objective, or the phase-1 violation) under one set of limits
on one maneuver: the rows of ``limits`` imposed at the times of a constraint grid (grown by
the exchange rounds of ``solver``), the energy on the composite Gauss-Legendre rule of
``planning.Plan.input_energy``, and a finer check grid on which ``assessment`` measures the
result. Values and gradients come from the flat flag, affine in x (``affine``), through the
pointwise quantities (``quantities``), so they are exact; they are cached per decision
vector, and gradients are formed only for the quantities in use.

A ``Request`` holds what every problem of one call shares (coefficients, basis, ends,
grids, tuning) and builds its problems.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import NDArray

from flatcli.core.curves.basis import Basis, composite_gauss_legendre
from flatcli.core.optimize.affine import Affine, affine_map
from flatcli.core.optimize.feasibility import (
    Ends,
    chain_rate_bounds,
    end_rate_bounds,
    margin_mean,
)
from flatcli.core.optimize.limits import PlanLimits, Rows, limit_rows
from flatcli.core.optimize.objectives import EPIGRAPH, Goal, maximised
from flatcli.core.optimize.quantities import (
    Flat,
    flag_jacobian,
    flag_quantities,
    layout_of,
)
from flatcli.core.optimize.tuning import Tuning
from flatcli.core.plan.planning import ENERGY_ORDER, ENERGY_PIECES

Array = NDArray[np.float64]
#: (low, high) bounds of one decision variable (None: unbounded).
Bound = tuple[float | None, float | None]


class Problem:
    """The programme min fun(x) subject to cons(x) >= 0 and ``bounds``, for SLSQP.

    Pointwise quantities live on two time sets: the constraint grid ("grid": ``times``) and
    the nodes of the energy quadrature ("quad"); the check grid ``check`` is evaluated on
    demand (``check_values``).

    Parameters
    ----------
    k : the flat model the planner believes (``flatmodel``)
    affine : the coefficient map of the decision vector
    rows : the inequality rows (``limits.limit_rows``)
    goal : what is minimised
    sigma : sign of the margin along admissible plans (``feasibility.Ends``)
    duration : T [s]
    times : (n,) constraint grid [s]
    check : (n_check,) check grid [s]
    tuning : screening, scaling and stand-in values (``Tuning``)
    """

    def __init__(
        self,
        k: Flat,
        affine: Affine,
        rows: Rows,
        goal: Goal,
        sigma: float,
        duration: float,
        times: Array,
        check: Array,
        tuning: Tuning,
    ) -> None:
        self.k = k
        #: which rows of the pointwise quantities are angles, rates, the margin
        self.layout = layout_of(k)
        self.affine = affine
        self.rows = rows
        self.objective = goal
        self.sigma = sigma
        self.duration = duration
        self.tuning = tuning
        self.nv = affine.slope.shape[0]
        self.epigraph = goal in EPIGRAPH
        nodes, self.weights = composite_gauss_legendre(duration, ENERGY_PIECES, ENERGY_ORDER)
        self.flags: dict[str, tuple[Array, Array]] = {"quad": affine.flag(nodes)}
        self.needed: dict[str, list[int]] = {
            "quad": list(self.layout.rates),
            "grid": sorted(set(rows.quantity.tolist())),
        }
        self.check = check
        self.check_flag = affine.flag(check)
        self.b = rows.b.copy()  # row offsets, tightened by the exchange rounds
        # which (row, time) pairs the solver sees, and their scaling: set by ``prepare``
        self.mask = np.ones((0, 0), dtype=bool)
        self.weight = np.ones(0)
        #: the objective is divided by this (its value at the start of a solve, typically)
        self.scale = 1.0
        #: (low, high) per decision variable (None: unbounded)
        self.bounds: list[Bound] = [(None, None)] * self.nv
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

    def adopt(self, other: Problem) -> None:
        """Take over the constraint grid and the tightened offsets of the rows both share.

        For a plan found by ``other`` (the same goal under looser limits): its limits are
        then judged as they were imposed there, e.g. which are active.
        """
        self.set_times(np.concatenate([self.times, other.times]))

        def keys(rows: Rows) -> list[tuple[int, float, str]]:
            return list(zip(rows.quantity.tolist(), rows.a.tolist(), rows.label, strict=True))

        index = {key: j for j, key in enumerate(keys(other.rows))}
        for i, key in enumerate(keys(self.rows)):
            j = index.get(key)
            if j is not None:
                self.b[i] = other.b[j]

    def prepare(self, x: Array) -> None:
        """Choose and scale the constraints the solver sees, fixed until the next call.

        Angle, rate and peak-rate rows with a slack above ``Tuning.screen`` max(1, limit or
        peak) at x are left out (the exchange rounds restore any that end up violated); the
        margin rows, the guard against the singular set, are always in. Every row is scaled
        by 1 / (its gradient norm at x): near the singular set th2' is extremely sensitive to
        the coefficients (gradient norms span ~5 orders of magnitude on the paper's maneuver)
        and SLSQP's subproblems stall on such rows unless they are normalised. Neither
        changes the feasible set the exchange rounds enforce.
        """
        r = self.rows
        g = self.row_values(x)
        screened = r.quantity != self.layout.margin
        size = np.where(np.isfinite(r.bound), r.bound, abs(float(x[-1])) if self.epigraph else 1.0)
        loose = g > self.tuning.screen * np.maximum(1.0, size)[:, None]
        self.mask = ~(screened[:, None] & loose)
        norms = np.linalg.norm(self.row_jacobian(x)[self.mask], axis=1)
        self.weight = 1.0 / np.clip(norms, self.tuning.gradient_floor, None)

    def values(self, x: Array, which: str) -> Array:
        """(2 N + 2, n) pointwise quantities (margin signed) on the grid or the quadrature
        nodes."""
        key = x.tobytes()
        hit = self._values.get(which)
        if hit is not None and hit[0] == key:
            return hit[1]
        self.evaluations += which == "grid"
        base, slope = self.flags[which]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            values = np.asarray(flag_quantities(self.k, base + slope @ x), dtype=float)
        values[self.layout.margin] *= self.sigma
        if not np.all(np.isfinite(values)):  # a trial point on the singular set
            big = self.tuning.big
            values = np.nan_to_num(values, nan=-big, posinf=big, neginf=-big)
        self._values[which] = (key, values)
        return values

    def gradients(self, x: Array, which: str) -> Array:
        """(2 N + 2, n, nv) exact gradients of ``values`` (zero for quantities not in use)."""
        key = x.tobytes()
        hit = self._grads.get(which)
        if hit is not None and hit[0] == key:
            return hit[1]
        base, slope = self.flags[which]
        _, jac = flag_jacobian(self.k, base + slope @ x)
        jac[self.layout.margin] *= self.sigma
        grad = np.zeros((self.layout.size, base.shape[1], self.nv))
        for q in self.needed[which]:
            grad[q] = np.einsum("cn,cnv->nv", jac[q], slope)
        if not np.all(np.isfinite(grad)):
            grad = np.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)
        self._grads[which] = (key, grad)
        return grad

    def energy(self, x: Array) -> float:
        """Integral of the squared joint rates th1'^2 + ... + thN'^2 over [0, T] [rad^2/s]."""
        v = self.values(x, "quad")
        return float(self.weights @ sum(v[q] ** 2 for q in self.layout.rates))

    def energy_gradient(self, x: Array) -> Array:
        """(nv,) gradient of ``energy``."""
        v = self.values(x, "quad")
        g = self.gradients(x, "quad")
        w = 2.0 * self.weights
        return np.asarray(sum((w * v[q]) @ g[q] for q in self.layout.rates))

    @property
    def factor(self) -> float:
        """The objective per unit energy: T for "effort", else 1 [s or -]."""
        return self.duration if self.objective == "effort" else 1.0

    def fun(self, x: Array) -> float:
        """Objective (minimised), divided by ``scale``."""
        if self.objective in ("peak_rate", "violation"):
            return float(x[-1]) / self.scale
        if maximised(self.objective):
            return -float(x[-1]) / self.scale
        return self.factor * self.energy(x) / self.scale

    def jac(self, x: Array) -> Array:
        """(nv,) gradient of ``fun``."""
        if self.epigraph:
            out = np.zeros(self.nv)
            out[-1] = (-1.0 if maximised(self.objective) else 1.0) / self.scale
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
        """(2 N + 2, n_check) pointwise quantities on the check grid (non-finite kept)."""
        base, slope = self.check_flag
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            values = np.asarray(flag_quantities(self.k, base + slope @ x), dtype=float)
        values[self.layout.margin] *= self.sigma
        return values

    def lift(self, curve: Array) -> Array:
        """The decision vector of this problem for a flat curve (a decision vector without s).

        The epigraph variable, if any, is set where its rows hold with equality on the grid:
        the peak rate, the least margin, or the largest relative violation.
        """
        if not self.epigraph:
            return curve
        x = np.append(curve, 0.0)
        if self.objective == "peak_rate":
            x[-1] = np.max(np.abs(self.values(x, "grid")[list(self.layout.rates)]))
        elif self.objective == "margin":
            x[-1] = np.min(self.values(x, "grid")[self.layout.margin])
        else:
            g = self.row_values(x)
            relaxed = self.rows.c > 0
            x[-1] = max(0.0, float(np.max(-g[relaxed] / self.rows.c[relaxed, None])))
        return x

    def normalise(self, size: float) -> None:
        """Divide the objective by ``size`` from now on (its value at the start of a solve,
        typically, so that SLSQP's first steps are sane), floored at ``Tuning.scale_floor``."""
        self.scale = max(abs(size), self.tuning.scale_floor)


@dataclass(frozen=True)
class Request:
    """What every problem of one ``optimize_plan`` call shares.

    Attributes
    ----------
    k : the flat model the planner believes (``flatmodel``)
    basis : flat-output basis on [0, T]
    start, goal : (N + 1,) end configurations [rad]
    ends : the margin's sign and the end rates (``feasibility.check_ends``)
    duration : T [s]
    free_rates : the end rates are decision variables
    times : (n,) constraint grid [s]
    check : (n_check,) check grid [s], ``Tuning.check_refinement`` times denser
    tuning : the optimiser's tuning
    """

    k: Flat
    basis: Basis
    start: Array
    goal: Array
    ends: Ends
    duration: float
    free_rates: bool
    times: Array
    check: Array
    tuning: Tuning

    def start_curve(self) -> Array:
        """The decision vector (without s) of the min-acceleration plan with the given end
        rates: the starting guess (the paper's cubic in a basis containing cubics)."""
        return affine_map(*self._map_args(False))[1]

    def problem(self, goal: Goal, limits: PlanLimits) -> Problem:
        """A fresh problem: ``goal`` under ``limits``, with bounds that keep SLSQP's steps
        sane (free end rates within the rate limits, for the paper's robot also on the side
        the margin allows; a peak rate or violation >= 0; a margin <= its mean over the
        maneuver)."""
        affine, _ = affine_map(*self._map_args(goal in EPIGRAPH))
        rows = limit_rows(limits, goal, self.tuning.backoff)
        problem = Problem(
            self.k,
            affine,
            rows,
            goal,
            self.ends.sigma,
            self.duration,
            self.times,
            self.check,
            self.tuning,
        )
        if self.free_rates and self.k.n_joints > 2:
            box = chain_rate_bounds(limits)
            problem.bounds[: 2 * len(box)] = box + box
        elif self.free_rates:  # th1' alone: on the side the margin's sign needs
            problem.bounds[:2] = [
                end_rate_bounds(self.start, limits, cast(float, self.ends.start_rate)),
                end_rate_bounds(self.goal, limits, cast(float, self.ends.goal_rate)),
            ]
        if goal in ("peak_rate", "violation"):
            problem.bounds[-1] = (0.0, None)
        elif goal == "margin":
            mean = margin_mean(self.k, self.start, self.goal, self.duration)
            problem.bounds[-1] = (None, self.ends.sigma * mean)
        return problem

    def _map_args(
        self, epigraph: bool
    ) -> tuple[Flat, Basis, Array, Array, float | Array, float | Array, bool, bool]:
        e = self.ends
        return (
            self.k,
            self.basis,
            self.start,
            self.goal,
            np.asarray(e.start_rate, dtype=float),
            np.asarray(e.goal_rate, dtype=float),
            self.free_rates,
            epigraph,
        )


__all__ = ["Bound", "Problem", "Request"]
