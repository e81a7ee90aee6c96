"""SLSQP on a ``Problem``, inside an exchange method for its semi-infinite constraints.

The limits hold at every time of [0, T], but a problem imposes them on a finite constraint
grid. After each SLSQP solve the limits are re-checked on the check grid
(``Tuning.check_refinement`` times denser); the times where a limit is missed (local maxima
of its excess) join the constraint grid, each violated limit is tightened by twice its excess
(at most ``Tuning.tighten_cap`` of it), and the problem is solved again, for at most
``Tuning.exchange_rounds`` rounds, so that the returned plan meets every limit at every
sample of the check grid.

What keeps SLSQP on track: the rows are screened and normalised per round
(``Problem.prepare``); a round that steps far outside the limits (``Tuning.reject_floor``,
``Tuning.round_reject``) is discarded in favour of its best iterate that met them
(``Tuning.restart_tol``), or ends the search at the best point so far. The point returned is
the best feasible one seen (the start included), or the least violating one if none was.

Polish (chains of N >= 3 joints, energy and effort): when the last round does not converge,
SLSQP is restarted from the best feasible point in coordinates whitened by the Gauss-Newton
Hessian of the energy there, x = x_0 + M z with M = H^(-1/2) (``Tuning.polish_restarts``
restarts of ``Tuning.polish_iter`` iterations, H re-formed at each). The energy's Hessian is
badly conditioned on such chains (eigenvalues spanning ~11 decades on the 4-joint example
chain of ``tests/test_chainplan.py``), and SLSQP's quasi-Newton model, built from
gradients, does not catch up: it crawls, still falling by ~1e-6 relative per iteration after
thousands. The polished point replaces the best one only if it meets every limit on the
check grid and is better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.optimize.assessment import assess
from flatcli.core.optimize.limits import PlanLimits
from flatcli.core.optimize.objectives import maximised
from flatcli.core.optimize.problem import Problem

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Solution:
    """The outcome of ``solve``.

    Attributes
    ----------
    x : (nv,) the best feasible point seen (the least violating one if none was)
    iterations : SLSQP iterations, summed over the rounds
    evaluations : distinct decision vectors evaluated on the constraint grid
    message : SLSQP's last message, and a note if an earlier point was kept
    converged : the last round converged and its point is ``x``
    """

    x: Array
    iterations: int
    evaluations: int
    message: str
    converged: bool


class _Tracker:
    """Solver callback: the best iterate that (nearly) meets every row on the grid.

    Where to go on from if the solver later steps astray.
    """

    def __init__(self, problem: Problem, row_scale: Array) -> None:
        self.problem = problem
        self.row_scale = row_scale
        self.best: tuple[float, Array] | None = None

    def __call__(self, xk: Array) -> None:
        g = self.problem.row_values(xk) / self.row_scale[:, None]
        if np.min(g) >= -self.problem.tuning.restart_tol:
            f = self.problem.fun(xk)
            if self.best is None or f < self.best[0]:
                self.best = (f, np.array(xk, dtype=float))


def solve(
    problem: Problem, x: Array, limits: PlanLimits, max_iter: int, polish_last: bool = True
) -> Solution:
    """SLSQP from x, then exchange rounds until the check grid meets every limit.

    Parameters
    ----------
    problem : the programme (its constraint grid and row offsets grow and tighten here)
    x : (nv,) starting point
    limits : the user's limits, against which each round's plan is assessed
    max_iter : SLSQP iteration limit per round
    polish_last : polish an unconverged chain's energy or effort (module docstring)

    Returns
    -------
    Solution
    """
    tuning = problem.tuning
    rows = problem.rows
    limited = rows.limited
    row_scale = np.maximum(1.0, np.where(limited, rows.bound, 1.0))
    sign = -1.0 if maximised(problem.objective) else 1.0
    evaluations = problem.evaluations
    start = assess(problem, x, limits)
    best = (sign * start.objective, x) if start.feasible else None
    least = (start.relative_violation, x)  # the least violating point, if none is feasible
    iterations = 0
    message = ""
    status = 0
    converged = False
    from scipy.optimize import minimize  # loaded where a plan is optimised: a sweep needs none

    for _ in range(tuning.exchange_rounds):
        problem.prepare(x)
        track = _Tracker(problem, row_scale)
        result = minimize(
            problem.fun,
            x,
            jac=problem.jac,
            method="SLSQP",
            bounds=problem.bounds,
            constraints=[{"type": "ineq", "fun": problem.cons, "jac": problem.cons_jac}],
            options={"maxiter": max_iter, "ftol": tuning.solver_tol},
            callback=track,
        )
        iterations += int(result.nit)
        converged = bool(result.success)
        message = str(result.message)
        status = int(result.status)
        x = np.asarray(result.x, dtype=float)
        found = assess(problem, x, limits)
        if found.feasible and (best is None or sign * found.objective < best[0]):
            best = (sign * found.objective, x)
        if found.relative_violation < least[0]:
            least = (found.relative_violation, x)
        if found.relative_violation > max(least[0] * tuning.round_reject, tuning.reject_floor):
            # the solver went astray (typically near the singular set): solve again from its
            # best sane iterate, or stop at the best point so far
            if track.best is not None:
                x = track.best[1]
                continue
            x = least[1] if best is None else best[1]
            break
        # epigraph rows are refined only where the check grid exceeds them noticeably (the
        # objective is measured on the check grid anyway), limit rows wherever violated
        epigraph_tol = tuning.epigraph_tol * max(1.0, abs(float(x[-1])))
        excess = np.where(limited[:, None], found.row_excess, found.row_excess - epigraph_tol)
        if problem.objective == "violation":  # limits relaxed by s max(1, limit)
            excess -= rows.c[:, None] * float(x[-1])
        missed = exchange_times(excess, problem.check)
        if not missed.size:
            break
        # impose the limits at the missed times too, and tighten each violated limit by
        # twice its excess (capped: a large excess comes from a row that was screened out,
        # not from between samples), so the next round lands inside it
        worst = np.max(excess, axis=1)
        tighten = limited & (worst > 0)
        cap = tuning.tighten_cap * np.maximum(1.0, rows.bound[tighten])
        problem.b[tighten] -= np.minimum(2.0 * worst[tighten], cap)
        problem.set_times(np.concatenate([problem.times, missed]))
    chosen = least[1] if best is None else best[1]
    if polish_last and not converged and best is not None and _polishable(problem):
        y, done, spent = _polish(problem, best[1])
        iterations += spent
        found = assess(problem, y, limits)
        if found.feasible and sign * found.objective < best[0]:
            chosen = x = y
            converged = done
            message = (
                "Optimization terminated successfully" if done else "Iteration limit reached"
            ) + (
                f" (polished: {spent} iterations of SLSQP restarts whitened by the energy's "
                "Gauss-Newton Hessian)"
            )
            status = 0 if done else 9
    if chosen is not x:
        converged = False
        message += "; an earlier point was kept, better than the last round's plan"
    if not converged and status != 0:
        message += stop_note(status, max_iter, problem.nv)
    return Solution(chosen, iterations, problem.evaluations - evaluations, message, converged)


def _polishable(problem: Problem) -> bool:
    """A chain of N >= 3 joints, whose objective is the energy (or the effort)."""
    return len(problem.layout.rates) >= 3 and not problem.epigraph


def _gauss_newton_hessian(problem: Problem, x: Array) -> Array:
    """(nv, nv) Gauss-Newton Hessian of ``problem.fun`` at x (energy or effort): 2 factor
    sum_q G_q^T W G_q / scale, G_q the exact Jacobian of joint rate q at the quadrature
    nodes, W their weights."""
    g = problem.gradients(x, "quad")
    h = sum(g[q].T @ (problem.weights[:, None] * g[q]) for q in problem.layout.rates)
    return np.asarray(2.0 * problem.factor * h / problem.scale)


def _polish(problem: Problem, x: Array) -> tuple[Array, bool, int]:
    """SLSQP restarted from x in coordinates whitened by the Gauss-Newton Hessian (module
    docstring, "Polish"): (nv,) the last point, whether the last restart converged, and the
    iterations spent."""
    tuning = problem.tuning
    spent = 0
    for _ in range(tuning.polish_restarts):
        problem.prepare(x)
        ev, vecs = np.linalg.eigh(_gauss_newton_hessian(problem, x))
        floor = tuning.polish_floor * max(float(ev[-1]), tuning.scale_floor)
        x, done, status, nit = _whitened(
            problem, x, (vecs / np.sqrt(np.maximum(ev, floor))) @ vecs.T
        )
        spent += nit
        if done:
            return x, True, spent
        if status != 9:
            break
    return x, False, spent


def _whitened(problem: Problem, origin: Array, m: Array) -> tuple[Array, bool, int, int]:
    """One SLSQP solve in z, x = origin + m z, from z = 0, within ``Tuning.polish_iter``
    iterations; the bounds of x become linear rows. Returns (x, converged, status, nit)."""

    def at(z: Array) -> Array:
        return np.asarray(origin + m @ z)

    def cons(z: Array) -> Array:
        return np.asarray(problem.cons(at(z)))

    def cons_jac(z: Array) -> Array:
        return np.asarray(problem.cons_jac(at(z)) @ m)

    constraints = [{"type": "ineq", "fun": cons, "jac": cons_jac}]
    for i, (low, high) in enumerate(problem.bounds):
        for bound, sign in ((low, 1.0), (high, -1.0)):
            if bound is not None:
                row = sign * m[i]
                constraints.append(
                    {
                        "type": "ineq",
                        "fun": lambda z, row=row, c=sign * (origin[i] - bound): c + row @ z,
                        "jac": lambda z, row=row: row,
                    }
                )
    from scipy.optimize import minimize

    result = minimize(
        lambda z: problem.fun(at(z)),
        np.zeros(problem.nv),
        jac=lambda z: m.T @ problem.jac(at(z)),
        method="SLSQP",
        constraints=constraints,
        options={"maxiter": problem.tuning.polish_iter, "ftol": problem.tuning.solver_tol},
    )
    z = np.asarray(result.x, dtype=float)
    return at(z), bool(result.success), int(result.status), int(result.nit)


def stop_note(status: int, max_iter: int, nv: int) -> str:
    """What limited an unconverged solve, for its message: SLSQP's ``status`` in the last
    round (9: its iteration limit; any other: its subproblem or line search broke down).

    Observed on chains of N >= 4 joints (8 N + 2 (N - 1) decision variables with the default
    basis): SLSQP crawls, its objective still falling by ~1e-6 relative per iteration after
    thousands, in every round and for every objective; the plan kept is the best one seen that
    meets the limits, but it is not a converged optimum. The energy and effort are then
    polished (module docstring), which converges on the 4-joint example chain; the minimax
    objectives are not.
    """
    if status == 9:
        return (
            f" (SLSQP stopped at plan.optimize.max_iter = {max_iter} iterations in its last "
            f"exchange round, {nv} decision variables: the plan is the best found that meets "
            "the limits, not a converged optimum; a larger max_iter may converge)"
        )
    return (
        f" (SLSQP stopped without converging, status {status}, {nv} decision variables: the "
        "plan is the best found that meets the limits, not a converged optimum)"
    )


def exchange_times(excess: Array, check: Array) -> Array:
    """Check-grid times [s] where a row's excess is positive at a local maximum.

    Parameters
    ----------
    excess : (rows, n_check) excess over each row (> 0 where missed)
    check : (n_check,) the check grid [s]

    Returns
    -------
    (m,) sorted distinct times [s]
    """
    times: list[float] = []
    for row in excess:
        if not np.any(row > 0):
            continue
        padded = np.concatenate([[-math.inf], row, [-math.inf]])
        peak = (padded[1:-1] >= padded[:-2]) & (padded[1:-1] >= padded[2:]) & (row > 0)
        times.extend(check[peak].tolist())
    return np.unique(np.asarray(times, dtype=float))


__all__ = ["Solution", "exchange_times", "solve", "stop_note"]
