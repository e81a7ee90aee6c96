"""The search of one ``optimize_plan`` call: which problems are solved from where.

Robustness
----------
SLSQP finds a local optimum, and which one depends on where it starts. From the paper's
cubic alone, loosening a limit could return a worse plan than the tighter request (energy
23.80 with th2 <= 3 rad, rates <= 50 rad/s, margin >= 0.05 rad/s, but 21.91 with rates
<= 20). So ``Search.best`` starts from the best plans it knows, deterministically:

* the least-limited plan: the same objective under the margin alone (no angle or rate
  limits), itself solved as below. If it meets the limits it is the answer: a local optimum
  of a problem with more freedom, so every request looser than the limits it happens to
  meet returns that same plan;
* otherwise the limits are solved from that plan and from the starting guess, and the best
  plan that meets them is kept. "peak_rate" starts from the least-energy plan under the same
  limits instead of the starting guess when that plan meets them (SLSQP on the minimax
  problem straight from the cubic, th2' ~ 49 rad/s next to the singular set, can step far
  astray); "margin" starts from it as well as from the starting guess (each wins on some
  limits of the paper's maneuver).

Each (objective, limits) is solved at most once per call (memoised), every solve is scaled
by the objective's value at the starting guess, and on equal objectives the first start
listed wins, so results are reproducible bit for bit. A request the least-limited plan
meets costs what it did before (one solve; two for "peak_rate"); others up to three times
that ("margin" up to seven solves, counting the least-energy plans it starts from).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from flatcli.core.optimize.assessment import Assessment, assess
from flatcli.core.optimize.limits import PlanLimits
from flatcli.core.optimize.objectives import Goal, better
from flatcli.core.optimize.problem import Problem, Request
from flatcli.core.optimize.solver import solve

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Candidate:
    """A plan of one goal under one set of limits, measured on the check grid.

    Attributes
    ----------
    problem : the problem it was found for (its constraint grid as the solver left it)
    x : (nv,) its decision vector
    assessment : its objective and violations on the check grid
    converged : the solve that produced it converged (False for a starting guess)
    message : that solve's message, and any note on the outcome
    """

    problem: Problem
    x: Array
    assessment: Assessment
    converged: bool
    message: str

    @property
    def feasible(self) -> bool:
        return self.assessment.feasible

    @property
    def curve(self) -> Array:
        """The decision vector without the epigraph variable (the flat curve's)."""
        return self.x[:-1] if self.problem.epigraph else self.x

    def beats(self, other: Candidate) -> bool:
        """Feasible and strictly better than ``other`` (or ``other`` infeasible)."""
        if not self.feasible:
            return False
        if not other.feasible:
            return True
        a, b = self.assessment.objective, other.assessment.objective
        return a != b and better(self.problem.objective, a, b)


class Search:
    """The solves of one call: memoised per (goal, limits), counted."""

    def __init__(self, request: Request, max_iter: int) -> None:
        self.request = request
        self.max_iter = max_iter
        self.iterations = 0
        self.evaluations = 0
        self._curve0 = request.start_curve()
        self._best: dict[tuple[Goal, PlanLimits, bool], Candidate] = {}

    def start(self, goal: Goal, limits: PlanLimits) -> Candidate:
        """The starting guess as a plan of ``goal`` under ``limits``."""
        problem = self._problem(goal, limits)
        x = problem.lift(self._curve0)
        return Candidate(problem, x, assess(problem, x, limits), False, "")

    def best(self, goal: Goal, limits: PlanLimits, polish: bool = True) -> Candidate:
        """The best plan of ``goal`` under ``limits`` from the starts of the module
        docstring ("Robustness"); the least violating one if none meets the limits.
        ``polish``: let ``solver.solve`` polish unconverged chains' energy (False for the
        least-energy plans other goals start from, which then stay as they were)."""
        key = (goal, limits, polish)
        if key in self._best:
            return self._best[key]
        relaxed = limits.margin_only()
        free = None if relaxed == limits else self.best(goal, relaxed, polish)
        if free is not None:
            problem = self._problem(goal, limits)
            problem.adopt(free.problem)
            x = problem.lift(free.curve)
            here = assess(problem, x, limits)
            if here.feasible:
                found = Candidate(problem, x, here, free.converged, free.message)
                self._best[key] = found
                return found
        starts = ([] if free is None else [free.curve]) + self._starts(goal, limits)
        found = self.solve(goal, limits, starts[0], polish)
        for curve in starts[1:]:
            other = self.solve(goal, limits, curve, polish)
            if other.beats(found) or (
                not found.feasible
                and other.assessment.relative_violation < found.assessment.relative_violation
            ):
                found = other
        self._best[key] = found
        return found

    def solve(self, goal: Goal, limits: PlanLimits, curve: Array, polish: bool = True) -> Candidate:
        """One ``solver.solve`` of ``goal`` under ``limits`` from a flat curve, counted."""
        problem = self._problem(goal, limits)
        return self._run(problem, problem.lift(curve), limits, polish)

    def least_violation(self, goal: Goal, limits: PlanLimits, found: Candidate) -> Candidate:
        """Phase 1, from the better of the starting guess and the least-energy plan
        under the margin alone; then ``goal`` again if the limits are met after all."""
        relaxed = self.best("energy", limits.margin_only(), polish=False).curve
        phase = self.request.problem("violation", limits)
        cubic = phase.lift(self._curve0)
        start = min((phase.lift(relaxed), cubic), key=lambda x: float(x[-1]))
        # scaled by the starting guess's violation (at least 1), as the objectives are by
        # their value: a larger normalised gradient makes SLSQP's first steps too long
        phase.scale = max(float(cubic[-1]), 1.0)
        least = self._run(phase, start, limits)
        problem = found.problem
        x = problem.lift(least.curve)
        here = assess(problem, x, limits)
        if not here.feasible:
            return Candidate(problem, x, here, found.converged, found.message)
        return self._run(problem, x, limits)

    def settle_margin(self, limits: PlanLimits, found: Candidate) -> Candidate:
        """The least-energy plan whose margin stays within ``Tuning.margin_tie`` of
        the best found, as a plan of "margin" (``found`` if that one misses the limits).

        The band is thin: with the best margin at its mean, the margin must stay almost
        constant. For the paper's robot that fixes th1(t) and the solve is easy; for a chain
        of N >= 3 joints it fixes only h_0(q(t)), and SLSQP from the maximiser crawls along
        the band (the example chain of ``tests/test_chainplan.py``: iteration limit after
        600 iterations). When the solve does not converge, the band is approached from one
        ten times wider (continuation; on that chain both solves converge, 550 iterations).
        """
        tie_fraction = self.request.tuning.margin_tie
        best = found.assessment.objective

        def band(fraction: float) -> PlanLimits:
            return replace(limits, min_margin=max(limits.min_margin, (1 - fraction) * best))

        tie = band(tie_fraction)
        second = self.request.problem("energy", tie)
        second.normalise(second.energy(found.curve))
        settled = self._run(second, found.curve, tie)
        if not settled.converged:
            wide = band(min(10 * tie_fraction, (1 + tie_fraction) / 2))
            first = self.request.problem("energy", wide)
            first.normalise(first.energy(found.curve))
            widened = self._run(first, found.curve, wide)
            if widened.converged and widened.feasible:
                again = self.request.problem("energy", tie)
                again.normalise(again.energy(widened.x))
                narrowed = self._run(again, widened.x, tie)
                if narrowed.feasible and (narrowed.converged or not settled.feasible):
                    settled = narrowed
        problem = found.problem
        x = problem.lift(settled.x)
        here = assess(problem, x, limits)
        message = settled.message
        if not here.feasible:
            x, here = found.x, found.assessment
            message += "; the margin maximiser itself is returned"
        if not settled.converged:
            message += (
                f" (the least-energy plan whose margin stays within Tuning.margin_tie = "
                f"{tie_fraction:g} of the best found, {best:.6g} rad/s, was not found)"
            )
        return Candidate(problem, x, here, settled.converged, message)

    def _starts(self, goal: Goal, limits: PlanLimits) -> list[Array]:
        """The starts of ``goal`` under ``limits`` besides the least-limited plan: the
        starting guess, and for "peak_rate" and "margin" the least-energy plan under the same
        limits when it meets them ("peak_rate" then skips the starting guess)."""
        if goal not in ("peak_rate", "margin"):
            return [self._curve0]
        energy = self.best("energy", limits, polish=False)
        if not energy.feasible:
            return [self._curve0]
        return [energy.curve] if goal == "peak_rate" else [self._curve0, energy.curve]

    def _problem(self, goal: Goal, limits: PlanLimits) -> Problem:
        """A fresh problem, scaled by the goal's value at the starting guess."""
        problem = self.request.problem(goal, limits)
        x0 = problem.lift(self._curve0)
        problem.normalise(assess(problem, x0, limits).objective)
        return problem

    def _run(
        self, problem: Problem, x: Array, limits: PlanLimits, polish: bool = True
    ) -> Candidate:
        found = solve(problem, x, limits, self.max_iter, polish)
        self.iterations += found.iterations
        self.evaluations += found.evaluations
        here = assess(problem, found.x, limits)
        return Candidate(problem, found.x, here, found.converged, found.message)


__all__ = ["Candidate", "Search"]
