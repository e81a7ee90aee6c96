"""``optimize_plan``: an optimal flat plan under limits, composed of named steps.

The steps (each a function or method below):

1. ``_request``: validate the arguments, run the up-front feasibility checks
   (``feasibility``) and fix the grids: a ``Request``.
2. ``Search.best``: the objective under the limits, from several deterministic starts,
   keeping the best plan that meets them (``search``: why, and which starts).
3. ``Search.least_violation``: if neither the starting guess nor any solve meets the
   limits, phase 1: the plan that exceeds them least; solve again from it if it meets them
   after all, otherwise its worst violation is the error message.
4. ``Search.settle_margin``: for "margin", the least-energy plan whose margin stays within
   ``Tuning.margin_tie`` of the best (the maximiser is not unique).
5. ``_keep_start``: never return a plan worse than a feasible starting guess.
6. ``_result``: the plan and its ``OptimizeResult``.

Every robot is planned through its flat model (``flatmodel.FlatModel``: the paper's closed
form for N = 2, the chain for N >= 3) into one ``planning.Plan``; the steps are the same for
every N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.curves.basis import Basis, BSplineBasis, FlatTrajectory
from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import flat_model
from flatcli.core.names import OBJECTIVES, Model, Objective
from flatcli.core.optimize.assessment import active_limits
from flatcli.core.optimize.feasibility import check_ends
from flatcli.core.optimize.limits import PlanLimits
from flatcli.core.optimize.objectives import better
from flatcli.core.optimize.problem import Request
from flatcli.core.optimize.quantities import Flat
from flatcli.core.optimize.search import Candidate, Search
from flatcli.core.optimize.tuning import TUNING, Tuning
from flatcli.core.plan.planning import ENERGY_ORDER, ENERGY_PIECES, Plan
from flatcli.core.robots.params import RobotParams, require_flat

Array = NDArray[np.float64]

#: Default basis: clamped quintic B-splines with this many coefficients per output. Quintic
#: so y'' (and with it th2' and u1') is C^3; 12 coefficients leave 8 free per output after the
#: four boundary conditions, enough to reach an energy near 1/5 of the paper's cubic on its
#: maneuver, while the local support keeps the problem well conditioned (monomials of
#: degree > 9 are not).
DEFAULT_BSPLINE_SIZE = 12
DEFAULT_BSPLINE_DEGREE = 5


@dataclass(frozen=True)
class OptimizeResult:
    """Outcome of ``optimize_plan``.

    Attributes
    ----------
    plan : the optimised plan (same robot and model, the chosen basis): a
        ``planning.Plan`` for any N
    success : the solver converged and the plan meets every limit on the check grid
    objective : final value of the objective (units of the objective, see ``objectives``)
    initial_objective : its value at the starting guess
    iterations : solver iterations, summed over every solve
    evaluations : distinct decision vectors evaluated
    active : human-readable active limits, e.g. ``"rate_limit on th2' at t=0.31 s"``
    max_violation : worst limit violation on the check grid, >= 0 [rad or rad/s]
    start_rate, goal_rate : the chosen end rates th1'(0), th1'(T) [rad/s]
    message : the solver's message, and any note on the outcome
    start_rates, goal_rates : (N - 1,) the chosen end rates th_1'..th_N-1' at 0 and T
        [rad/s] ((start_rate,) and (goal_rate,) for N = 2)
    """

    plan: Plan
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
    start_rates: tuple[float, ...]
    goal_rates: tuple[float, ...]


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
    start_rate: ArrayLike = 0.1,
    goal_rate: ArrayLike = 0.5,
    constraint_samples: int = 201,
    max_iter: int = 300,
    tuning: Tuning = TUNING,
) -> OptimizeResult:
    """Optimal flat plan from ``start`` to ``goal`` in ``duration`` seconds, under limits.

    Parameters
    ----------
    robot : a flat design (d_N = 0) of N >= 2 joints (``robot.n_joints``): the paper's robot
        (N = 2) or a chain
    start, goal : (N + 1,) configurations th0..thN [rad]
    duration : T [s] > 0
    model : which constraint coefficients the planner believes ("paper": the paper's printed
        ones, N = 2 only)
    basis : flat-output basis on [0, T]; default ``default_basis(duration)`` (quintic
        B-splines with 12 coefficients)
    objective : "energy", "effort", "peak_rate" or "margin" (see ``objectives``; over all
        N joint rates, and the margin sin(th1) th1' for N = 2, -(dh_0/dt) / (2 K_10) for a
        chain). "margin" is solved in two stages: the largest achievable minimum margin s*,
        then the least-energy plan whose margin stays >= (1 - ``Tuning.margin_tie``) s* (the
        maximiser alone is not unique: y_N does not enter the margin, and leaving it
        arbitrary gives wild th_N).
    limits : PlanLimits; default PlanLimits() (no angle or rate limits, margin >= 0.02
        rad/s). Its angle_limit has N + 1 numbers (all inf stands for any N), its rate_limit
        one number or N (``PlanLimits.for_joints``)
    free_rates : optimise the end rates too; otherwise they stay at the given values
    start_rate, goal_rate : end rates of the starting guess (the paper's 0.1 and 0.5), or the
        fixed end rates when ``free_rates`` is False [rad/s]: th1' for N = 2; for a chain
        th_1'..th_N-1', (N - 1,) or one number for all. With free rates they are pointed the
        way the margin's sign needs (for N = 2 the direction th1 moves) and moved into the
        range the margin and the rate limits allow.
    constraint_samples : equally spaced times where the limits are imposed (>= 10); the
        check grid has ``Tuning.check_refinement`` times as many intervals
    max_iter : solver iteration limit per exchange round (>= 1)
    tuning : how the optimiser searches and checks (``Tuning``; default ``TUNING``)

    Returns
    -------
    OptimizeResult; its objective is never worse than the starting guess's when that is
    feasible (the starting guess is returned if the solver does not improve on it). A
    chain's plan is checked for zeros of its margin between the check grid's samples
    (``Plan.margin_zeros``) as ``planning.plan_point_to_point`` does.

    Raises
    ------
    FlatcliError, one line naming the limit that cannot be met and by how much: for a
    request found infeasible up front (``feasibility``), or when no plan meeting the limits
    is found; the line then describes the plan that exceeds them least, found by a phase-1
    solve minimising the largest relative excess over the angle and rate limits (e.g. the
    least achievable peak rate when the rate limit is below it). For N = 2 the fold th2
    must reach (``required_fold``) is checked up front; for a chain it depends on the path,
    so an angle or rate limit that forbids it is found by the solver (``feasibility``).
    """
    limits = (PlanLimits() if limits is None else limits).for_joints(robot.n_joints)
    request = _request(
        robot, model, start, goal, duration, basis, objective, limits, free_rates,
        start_rate, goal_rate, constraint_samples, max_iter, tuning,
    )  # fmt: skip
    search = Search(request, max_iter)
    initial = search.start(objective, limits)
    found = search.best(objective, limits)
    if not found.feasible and not initial.feasible:
        found = search.least_violation(objective, limits, found)
    if objective == "margin" and found.feasible:
        found = search.settle_margin(limits, found)
    found = _keep_start(found, initial)
    if not found.feasible:
        raise FlatcliError(
            found.assessment.worst or f"plan.optimize: the solver failed ({found.message})"
        )
    return _result(robot, model, request, search, found, initial)


def _request(
    robot: RobotParams,
    model: Model,
    start: ArrayLike,
    goal: ArrayLike,
    duration: float,
    basis: Basis | None,
    objective: str,
    limits: PlanLimits,
    free_rates: bool,
    start_rate: ArrayLike,
    goal_rate: ArrayLike,
    constraint_samples: int,
    max_iter: int,
    tuning: Tuning,
) -> Request:
    """Validate the arguments and check the request up front; the shared setting."""
    require_flat(robot)
    n = robot.n_joints
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
    if basis is None:
        basis = default_basis(duration)
    elif not math.isclose(basis.duration, duration):
        raise FlatcliError("plan basis: its duration differs from plan.duration")
    start_arr = np.asarray(start, dtype=float)
    goal_arr = np.asarray(goal, dtype=float)
    if n > 2 and model != "derived":
        raise FlatcliError(
            f"robot.model: {model!r} (the paper's printed coefficients) exists for the "
            f"three-link robot only; a chain of {n} joints is planned with its derived model"
        )
    k: Flat = flat_model(robot, model)
    if n == 2:  # the one inner rate th1' as a number
        rates: tuple[float | NDArray[np.float64], ...] = tuple(
            _one_rate(key, rate) for key, rate in (("start", start_rate), ("goal", goal_rate))
        )
    else:
        rates = tuple(
            _chain_rates(key, rate, n) for key, rate in (("start", start_rate), ("goal", goal_rate))
        )
        for key, arr in (("start", start_arr), ("goal", goal_arr)):
            if arr.shape != (n + 1,):
                raise FlatcliError(
                    f"plan.{key}: expected {n + 1} angles (th0..th{n}), got shape {arr.shape}"
                )
    ends = check_ends(
        k, start_arr, goal_arr, rates[0], rates[1], duration, limits, free_rates,
        tuning.end_rate_clearance,
    )  # fmt: skip
    intervals = tuning.check_refinement * (constraint_samples - 1)
    return Request(
        k=k,
        basis=basis,
        start=start_arr,
        goal=goal_arr,
        ends=ends,
        duration=duration,
        free_rates=free_rates,
        times=np.linspace(0.0, duration, constraint_samples),
        check=np.linspace(0.0, duration, intervals + 1),
        tuning=tuning,
    )


def _one_rate(key: str, rate: ArrayLike) -> float:
    """th1' at one end of the paper's robot: a number (or a list of one) [rad/s]."""
    arr = np.asarray(rate, dtype=float)
    if arr.size != 1:
        raise FlatcliError(f"plan.{key}_rate: expected one number (th1'), got shape {arr.shape}")
    return float(arr.reshape(()))


def _chain_rates(key: str, rate: ArrayLike, n: int) -> NDArray[np.float64]:
    """th_1'..th_N-1' at one end of a chain, (N - 1,) [rad/s]: one number broadcasts."""
    arr = np.asarray(rate, dtype=float)
    if arr.ndim == 0 or arr.shape == (1,):
        return np.full(n - 1, float(arr.reshape(())))
    if arr.shape != (n - 1,):
        raise FlatcliError(
            f"plan.{key}_rate: expected one number or {n - 1} (th1'..th{n - 1}'), got shape "
            f"{arr.shape}"
        )
    return arr


def _keep_start(found: Candidate, initial: Candidate) -> Candidate:
    """Step 5: the starting guess instead of ``found`` if it is feasible and ``found`` is not
    better."""
    goal = initial.problem.objective
    a, b = found.assessment.objective, initial.assessment.objective
    if initial.feasible and not (found.feasible and better(goal, a, b)):
        note = "; the starting guess was kept (the solver did not improve on it)"
        return replace(initial, converged=found.converged, message=found.message + note)
    return found


def _result(
    robot: RobotParams,
    model: Model,
    request: Request,
    search: Search,
    found: Candidate,
    initial: Candidate,
) -> OptimizeResult:
    """Step 6: the plan and its record (energy and effort exactly as the plan's
    ``input_energy`` measures them).

    Raises
    ------
    FlatcliError if a chain's plan has a zero of its margin between the check grid's samples
    """

    def plan_at(candidate: Candidate) -> Plan:
        coefficients = candidate.problem.affine.coefficients(candidate.x)
        trajectory = FlatTrajectory(request.basis, coefficients)
        return Plan(robot, request.k, trajectory, request.duration)

    plan = plan_at(found)
    if plan.n_joints > 2:  # (N = 2: the check grid's margin rows rule crossings out exactly)
        zeros = plan.margin_zeros()
        if zeros.size:
            raise FlatcliError(
                f"plan.optimize: the optimised plan's margin -(dh_0/dt) / (2 K_10) is zero at "
                f"t = {zeros[0]:.4g} s, between the samples of its check grid; raise "
                "plan.optimize.constraint_samples or plan.optimize.min_margin"
            )
    problem = found.problem
    reported, reported_initial = found.assessment.objective, initial.assessment.objective
    if problem.objective in ("energy", "effort"):
        factor = problem.factor
        reported = factor * plan.input_energy(ENERGY_PIECES, ENERGY_ORDER)
        reported_initial = factor * plan_at(initial).input_energy(ENERGY_PIECES, ENERGY_ORDER)
    ends, x = request.ends, found.x
    fixed = () if request.free_rates else ("fixed end rates",)
    r = len(np.atleast_1d(ends.start_rate))
    if request.free_rates:
        start_rates = tuple(float(v) for v in x[:r])
        goal_rates = tuple(float(v) for v in x[r : 2 * r])
    else:
        start_rates = tuple(float(v) for v in np.atleast_1d(ends.start_rate))
        goal_rates = tuple(float(v) for v in np.atleast_1d(ends.goal_rate))
    return OptimizeResult(
        plan=plan,
        success=found.converged,
        objective=reported,
        initial_objective=reported_initial,
        iterations=search.iterations,
        evaluations=search.evaluations,
        active=active_limits(problem, x) + fixed,
        max_violation=found.assessment.max_violation,
        start_rate=start_rates[0],
        goal_rate=goal_rates[0],
        message=found.message,
        start_rates=start_rates,
        goal_rates=goal_rates,
    )


__all__ = [
    "DEFAULT_BSPLINE_DEGREE",
    "DEFAULT_BSPLINE_SIZE",
    "OptimizeResult",
    "default_basis",
    "optimize_plan",
]
