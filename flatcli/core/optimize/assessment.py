"""A candidate plan measured on the check grid: objective, feasibility, what binds.

The solver sees its limits only at the times of the constraint grid; the check grid is
``Tuning.check_refinement`` times denser, and only a plan that meets every limit of the
user's request there (to ``Tuning.feasibility_tol``, relative) counts as feasible. The
objective reported for "peak_rate" and "margin" is measured on the check grid too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.optimize.limits import PlanLimits, describe_violation
from flatcli.core.optimize.problem import Problem

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Assessment:
    """A candidate plan measured on the check grid against the user's limits.

    Attributes
    ----------
    objective : the goal's value (see ``objective_on``; the violation itself for phase 1)
    max_violation : largest excess over a limit, >= 0 [rad or rad/s]
    relative_violation : largest excess / max(1, |limit|), >= 0 [-]
    worst : one line describing the worst violation ('' when feasible)
    row_excess : (rows, n_check) excess over each row (> 0 where missed); for epigraph rows,
        how far the check grid goes past the epigraph variable
    feasibility_tol : the relative violation a feasible plan may have
    """

    objective: float
    max_violation: float
    relative_violation: float
    worst: str
    row_excess: Array
    feasibility_tol: float

    @property
    def feasible(self) -> bool:
        """No limit exceeded beyond the tolerance, and a finite objective."""
        return self.relative_violation <= self.feasibility_tol and math.isfinite(self.objective)


def assess(problem: Problem, x: Array, limits: PlanLimits) -> Assessment:
    """Objective and limit violations of the plan at x on the problem's check grid.

    Parameters
    ----------
    problem : its rows and check grid
    x : (nv,) decision vector
    limits : the user's limits (for the description of a violation)
    """
    values = problem.check_values(x)
    r = problem.rows
    limited = r.limited
    q = values[r.quantity]  # (rows, n_check)
    is_margin = (r.quantity == problem.layout.margin)[:, None]
    # |q| <= L rows (a = -1: q - L; a = +1: -q - L); the margin row: m - q
    excess = np.where(is_margin, r.bound[:, None] - q, -r.a[:, None] * q - r.bound[:, None])
    excess = np.where(np.isnan(excess), math.inf, excess)
    if problem.epigraph:  # where the check grid exceeds the epigraph variable
        s = float(x[-1])
        excess[~limited] = -(r.a[~limited, None] * q[~limited] + r.c[~limited, None] * s)
    scale = np.maximum(1.0, r.bound[limited])
    rel = excess[limited] / scale[:, None]
    max_violation = float(max(0.0, np.max(excess[limited], initial=0.0)))
    relative = float(max(0.0, np.max(rel, initial=0.0)))
    objective = relative if problem.objective == "violation" else objective_on(problem, x, values)
    tol = problem.tuning.feasibility_tol
    worst = ""
    if relative > tol:
        row, j = np.unravel_index(int(np.argmax(rel)), rel.shape)
        quantity = int(r.quantity[np.flatnonzero(limited)[row]])
        worst = describe_violation(
            limits, quantity, float(values[quantity, j]), float(problem.check[j])
        )
    return Assessment(objective, max_violation, relative, worst, excess, tol)


def objective_on(problem: Problem, x: Array, values: Array) -> float:
    """The user-facing objective: energy or effort by quadrature; the peak rate or the least
    margin on the check grid (``values``: (2 N + 2, n_check) from ``Problem.check_values``)."""
    if problem.objective == "peak_rate":
        return float(np.max(np.abs(values[list(problem.layout.rates)])))
    if problem.objective == "margin":
        return float(np.min(values[problem.layout.margin]))
    return problem.factor * problem.energy(x)


def active_limits(problem: Problem, x: Array) -> tuple[str, ...]:
    """Limits with (almost) no slack on the constraint grid, grouped into runs of times.

    Returns
    -------
    labels such as ``"rate_limit on th2' at t=0.31 s"`` or ``"min_margin at t=0.00-0.27 s"``,
    ordered by time
    """
    values = problem.values(x, "grid")
    r = problem.rows
    t = problem.times
    tol = problem.tuning.active_tol
    found: list[tuple[float, str]] = []
    for row, name in enumerate(r.label):
        if not name:
            continue
        slack = r.a[row] * values[r.quantity[row]] + problem.b[row]  # the bound as imposed
        tight = np.flatnonzero(slack <= tol * max(1.0, r.bound[row]))
        for run in np.split(tight, np.flatnonzero(np.diff(tight) > 1) + 1) if tight.size else []:
            first, last = f"{t[run[0]]:.2f}", f"{t[run[-1]]:.2f}"
            when = first if first == last else f"{first}-{last}"
            found.append((float(t[run[0]]), f"{name} at t={when} s"))
    unique: list[str] = []
    for _, text in sorted(found):
        if text not in unique:
            unique.append(text)
    return tuple(unique)


__all__ = ["Assessment", "active_limits", "assess", "objective_on"]
