"""End-effector tasks: from "put the end effector there, the base at that attitude, at rest,
clear of these obstacles" to a flat plan (docs/tasks.md).

``Task`` is the validated request; ``task_ends`` turns it into start and goal configurations
(``inverse``), agreeing with the configurations the caller already has or refusing them;
``plan_task`` plans (``planning`` or ``rest``), proves the obstacles and limits over all of
[0, T] (``clearance``) and, when a candidate fails, searches within ``Task.budget``
candidates: the other elbow branch (when the goal is derived), the rest plan's skew
(``rest.plan_rest_to_rest``) or the free end rates' magnitudes of a plan that does not rest.
It says so when none within the budget is proven.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.curves.basis import Basis
from flatcli.core.errors import FlatcliError
from flatcli.core.names import Elbow, Model
from flatcli.core.plan.clearance import Certificate, Constraints, certify, sampled_slack
from flatcli.core.plan.inverse import task_configuration, two_link_task
from flatcli.core.plan.planning import Plan, fastest_joint, plan_point_to_point
from flatcli.core.plan.rest import plan_rest_to_rest
from flatcli.core.robots.kinematics import (
    across_shift,
    end_effector,
    virtual_links,
    virtual_links_of,
)
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: A configuration meets a task's end-effector target within this [m].
TARGET_TOL = 1e-9
#: ... and its base attitude within this [rad].
ATTITUDE_TOL = 1e-12
#: Skews of a rest plan tried in turn, and factors on the end rates of one that does not rest.
SKEWS = (0.0, 0.3, -0.3, 0.6, -0.6, 0.85, -0.85, 0.15, -0.15, 0.45, -0.45, 0.75, -0.75)
RATE_FACTORS = (1.0, 0.5, 2.0, 0.25, 4.0, 0.7, 1.4, 0.35, 2.8, 8.0, 0.125)


@dataclass(frozen=True)
class Task:
    """A validated end-effector task.

    Attributes
    ----------
    end_effector : (2,) target at t = T [m], or None (the goal configuration as given)
    base_attitude : th0 at T [rad], or None (free)
    start_end_effector : (2,) where it is at t = 0 [m], or None (the start as given)
    rest : start and stop at rest
    obstacles : (K, 3) discs x, y, radius [m]
    clearance : least distance of every link from every obstacle [m]
    elbow : branch of the N = 2 inverse kinematics
    budget : most candidate plans the obstacle search tries
    """

    end_effector: tuple[float, float] | None = None
    base_attitude: float | None = None
    start_end_effector: tuple[float, float] | None = None
    rest: bool = False
    obstacles: tuple[tuple[float, float, float], ...] = ()
    clearance: float = 0.0
    elbow: Elbow = "auto"
    budget: int = 64

    @property
    def active(self) -> bool:
        """Whether anything is asked beyond a plain plan."""
        return (self.end_effector is not None or self.start_end_effector is not None
                or self.rest or bool(self.obstacles))


@dataclass(frozen=True)
class TaskPlan:
    """A planned task: the plan, its ends, the certificate of its constraints (None: no
    obstacles or limits to prove), how many candidates the search tried, and the chosen
    candidate's shape: the factor on the end rates' magnitudes of a plan that does not rest,
    the skew of a rest plan (``plan_task``)."""

    plan: Plan
    start: Array
    goal: Array
    certificate: Certificate | None
    candidates: int
    shape: float = 1.0


def _meets(robot: RobotParams, q: Array, target: tuple[float, float] | None,
           th0: float | None) -> tuple[float, float]:
    """(distance from the target [m], attitude error [rad]) of configuration q."""
    dist = 0.0 if target is None else float(np.hypot(*(end_effector(robot, q) - target)))
    att = 0.0 if th0 is None else abs(float(q[0]) - th0)
    return dist, att


def _end(robot: RobotParams, given: Array, is_default: bool, target: tuple[float, float] | None,
         th0: float | None, reference: Array, elbow: Elbow, side: str) -> list[Array]:
    """The candidate configurations of one end: ``given`` if it meets the task, else (when
    it is the schema's default) the inverse kinematics' branches; FlatcliError naming both
    keys when a configuration the user set contradicts the task."""
    if target is None:
        return [given]
    dist, att = _meets(robot, given, target, th0)
    if dist <= TARGET_TOL and att <= ATTITUDE_TOL:
        return [given]
    key = "task.end_effector" if side == "goal" else "task.start_end_effector"
    if not is_default:
        extra = f" and th0 = {given[0]:g} rad, not task.base_attitude = {th0:g}" if (
            att > ATTITUDE_TOL and th0 is not None) else ""
        raise FlatcliError(f"plan.{side}: puts the end effector {dist:.3g} m from {key}{extra}; "
                           f"set {key} or plan.{side}, not both (or make them agree)")
    if robot.n_joints == 2 and elbow == "auto":
        out = []
        for branch in ("up", "down"):
            try:
                out.append(two_link_task(robot, target, th0, reference, branch, key))
            except FlatcliError as exc:
                if "across the singular set" not in str(exc):
                    raise
        if out:
            out.sort(key=lambda q: float(np.sum((q - reference) ** 2)))
            return out
    return [task_configuration(robot, target, th0, reference, elbow, key)]


def task_ends(robot: RobotParams, task: Task, start: ArrayLike, goal: ArrayLike,
              start_is_default: bool, goal_is_default: bool) -> tuple[list[Array], list[Array]]:
    """Candidate start and goal configurations (N + 1,) [rad] of a task, best first.

    The start keeps its th0 (``plan.start[0]``) when ``start_end_effector`` moves it; the
    goal's reference for "nearest" is the start.
    """
    s = np.asarray(start, dtype=float)
    g = np.asarray(goal, dtype=float)
    starts = _end(robot, s, start_is_default, task.start_end_effector, float(s[0]), s, "auto",
                  "start")
    goals = _end(robot, g, goal_is_default, task.end_effector, task.base_attitude, starts[0],
                 task.elbow, "goal")
    return starts, goals


def _oriented(rate: ArrayLike, start: Array, goal: Array, n: int,
              robot: RobotParams | None = None, end: Array | None = None) -> Array:
    """End rates (magnitudes as given) whose signs make the plan leave or reach ``end`` moving
    towards the goal: for N = 2, th1's motion (the margin sin th1 th1' keeps one sign); for
    N >= 3 (``robot`` given), the signs that make dh_0/dt at ``end`` have the sign of
    h_0(goal) - h_0(start): along a flat plan h_0 is monotone (its rate is the margin, which
    may not change sign), so end rates against that change make the plan cross the singular
    set. A joint whose slope there is 0 follows its own motion."""
    r = np.broadcast_to(np.abs(np.asarray(rate, dtype=float)), (n - 1,)).copy()
    step = goal[1:n] - start[1:n]
    signs = np.where(step < 0, -1.0, 1.0)
    if n >= 3 and robot is not None and end is not None:
        from flatcli.core.models.flatmodel import ChainModel
        from flatcli.core.robots.chain import base_inertia_slopes

        model = ChainModel.of(robot)
        grad, hess = np.empty(n), np.empty((n, n))
        h_start = base_inertia_slopes(model.K, model.inertia, np.asarray(start, float), grad,
                                      hess)
        h_goal = base_inertia_slopes(model.K, model.inertia, np.asarray(goal, float), grad,
                                     hess)
        base_inertia_slopes(model.K, model.inertia, np.asarray(end, float), grad, hess)
        wanted = np.sign(h_goal - h_start) * grad[: n - 1]
        signs = np.where(wanted != 0, np.sign(wanted), signs)
    return np.asarray(signs * r, dtype=float)


#: Samples at which a candidate is checked before its proof is tried: a violation there
#: rejects it at a fraction of the proof's cost (the first candidate that is proven is the
#: same either way).
SCREEN_SAMPLES = 65
#: Candidates planned and checked at the samples together (``clearance.sampled_slack``): one
#: evaluation for several costs little more than for one; the first is checked alone, as
#: most tasks need no second.
SCREEN_BATCH = 4


def _candidate(robot: RobotParams, task: Task, start: Array, goal: Array, shape: float,
               duration: float, start_rate: ArrayLike, goal_rate: ArrayLike, model: Model,
               basis: Basis | None) -> Plan:
    """The candidate plan of one (start, goal, shape): a rest plan of that skew, or the
    point-to-point plan with its end rates scaled by ``shape`` (FlatcliError if none)."""
    n = robot.n_joints
    if task.rest:
        return plan_rest_to_rest(robot, start, goal, duration, model, skew=shape)
    return plan_point_to_point(
        robot, start, goal, _oriented(start_rate, start, goal, n, robot, start) * shape,
        _oriented(goal_rate, start, goal, n, robot, goal) * shape, duration, model, basis)


def plan_task(robot: RobotParams, task: Task, starts: list[Array], goals: list[Array],
              duration: float, start_rate: ArrayLike, goal_rate: ArrayLike,
              model: Model = "derived", basis: Basis | None = None,
              angle_limit: Array | None = None, rate_limit: Array | None = None,
              rate_warning: float = math.inf, samples: int = 201) -> TaskPlan:
    """The task's plan (module docstring): the first candidate whose constraints are proven
    over [0, T] and whose joints stay within ``rate_warning`` [rad/s] on ``samples`` points
    of [0, T] (``plan.rate_warning``, ``plan.samples``: ``planning.fastest_joint``).
    Candidates are taken in order (start, goal, then shape) up to ``task.budget``; they are
    checked at ``SCREEN_SAMPLES`` samples in batches (``SCREEN_BATCH``) and proven
    (``certify``) in order when they pass. Without obstacles or limits the first candidate
    that can be planned is taken, every branch with the end rates as given first (shape 1),
    then the other shapes: a candidate that crosses the singular set (a chain's end rates,
    which ``_oriented`` turns towards the goal's h_0, can still) is not the end of the
    search. Where no accepted candidate keeps within ``rate_warning``, the one whose fastest
    joint is slowest (the first of equals) is returned: its plan then carries the warning
    (``planning.rate_warning_text``).

    Raises
    ------
    FlatcliError naming the key: no candidate plans (the last reason), or none within
    ``task.budget`` is proven clear (the best one's reason).
    """
    limits = (angle_limit is not None and np.isfinite(angle_limit).any()) or (
        rate_limit is not None and np.isfinite(rate_limit).any())
    constraints = Constraints(np.asarray(task.obstacles, dtype=float).reshape(-1, 3),
                              task.clearance, angle_limit, rate_limit) \
        if (task.obstacles or limits) else None
    shapes: tuple[float, ...] = SKEWS if task.rest else RATE_FACTORS
    if constraints is None:  # the end rates as given on every branch first, then scaled
        candidates = [(start, goal, shape) for shape in shapes for start in starts
                      for goal in goals][:task.budget]
    else:
        candidates = [(start, goal, shape) for start in starts for goal in goals
                      for shape in shapes][:task.budget]
    last_error: FlatcliError | None = None
    best: tuple[float, Certificate] | None = None
    fast: tuple[float, TaskPlan] | None = None  # the slowest accepted one above the warning
    refuted: list[Plan] = []  # failed at a sample: certify would refute them too

    def slow_enough(found: TaskPlan) -> bool:
        """Whether an accepted candidate keeps within the warning (else it is remembered)."""
        nonlocal fast
        if not math.isfinite(rate_warning):
            return True
        peak = fastest_joint(found.plan.sample(found.plan.grid(samples)))[1]
        if peak <= rate_warning:
            return True
        if fast is None or peak < fast[0]:
            fast = (peak, found)
        return False

    first = 0
    while first < len(candidates):
        size = 1 if first == 0 else SCREEN_BATCH
        batch: list[tuple[int, Array, Array, float, Plan]] = []
        for index, (start, goal, shape) in enumerate(candidates[first:first + size], first + 1):
            try:
                plan = _candidate(robot, task, start, goal, shape, duration, start_rate,
                                  goal_rate, model, basis)
            except FlatcliError as exc:
                last_error = exc
                continue
            if constraints is None:
                found = TaskPlan(plan, start, goal, None, index, shape)
                if slow_enough(found):
                    return found
                continue
            batch.append((index, start, goal, shape, plan))
        first += size
        if not batch:
            continue
        assert constraints is not None
        slack = sampled_slack([plan for *_, plan in batch], constraints, SCREEN_SAMPLES)
        for (index, start, goal, shape, plan), least in zip(batch, slack, strict=True):
            if least < 0:
                refuted.append(plan)  # a violation at a sample is one: no proof needed
                continue
            cert = certify(plan, constraints)
            if cert.ok:
                found = TaskPlan(plan, start, goal, cert, index, shape)
                if slow_enough(found):
                    return found
                continue
            if best is None or cert.lower_bound > best[0]:
                best = (cert.lower_bound, cert)
    if fast is not None:
        return fast[1]
    if constraints is not None:
        for plan in refuted:  # the message names the best of all, as certify ranks them
            cert = certify(plan, constraints)
            if best is None or cert.lower_bound > best[0]:
                best = (cert.lower_bound, cert)
    if best is None:
        assert last_error is not None
        raise last_error
    what = "task.obstacles" if task.obstacles else "plan.optimize.angle_limit / rate_limit"
    raise FlatcliError(f"{what}: no plan among the {len(candidates)} candidates tried "
                       f"(task.budget = {task.budget}) is proven clear over [0, T]; the best: "
                       f"{best[1].reason}")


def task_errors(robot: RobotParams, task: Task, theta: Array) -> dict[str, float]:
    """The task's errors at the final configuration theta (N + 1,): ``ee_error_final`` [m]
    (nan without a target) and ``base_attitude_error_final`` [rad] (nan without one)."""
    dist, att = _meets(robot, np.asarray(theta, dtype=float), task.end_effector,
                       task.base_attitude)
    return {"ee_error_final": dist if task.end_effector is not None else math.nan,
            "base_attitude_error_final": att if task.base_attitude is not None else math.nan}


def end_effector_error_bound(nominal: RobotParams, mass: Array, length: Array, com: Array,
                             com_across: Array, err_theta_final: Array, planned: Array,
                             target: ArrayLike) -> Array:
    """(n,) An upper bound on each trial's final distance of the end effector from the target
    [m], from its final angle error alone (a sweep's trials keep no states).

    Trial k's plant (links mass, length, com (n, N + 1) [kg, m, m], ``com_across`` (n,) [m])
    ends at th = th_ref(T) + d, ``err_theta_final`` (n,) = |d| [rad], where the plan on the
    ``nominal`` robot ends at ``planned`` (N + 1,) [rad]. With r_E = sum_a v_a e(psi_a) +
    w e_perp(psi_N) (``kinematics``; w = -m_N e_N / M) and |e(a) - e(b)| <= |a - b|:

        |r_E^plant(th) - r*| <= |r_E^plant(th) - r_E^plant(th_ref)|       (the angle error)
                              + |r_E^plant(th_ref) - r_E^nominal(th_ref)|  (the model error)
                              + |r_E^nominal(th_ref) - r*|                 (the plan's error)
                             <= |d| (sum_a |v_a| sqrt(a + 1) + |w| sqrt(N + 1))
                              + sum_a |v_a - v_a^nominal| + |w - w^nominal|
                              + |r_E^nominal(th_ref(T)) - r*|,

    as |psi_a - psi_a'| = |d_0 + ... + d_a| <= sqrt(a + 1) |d|; and never more than
    |r_E^plant| + |r*| <= sum_a |v_a| + |w| + |r*| (a large angle error wraps around). nan where
    err_theta_final is (a trial that did not reach the end).
    """
    total = mass.sum(axis=1)
    v = virtual_links_of(mass, length, com, total[:, None])  # (n, N + 1)
    w = mass[:, -1] * com_across / total  # across_shift of each plant (its sign is no matter)
    v_nominal = virtual_links(nominal)
    w_nominal = across_shift(nominal)
    roots = np.sqrt(np.arange(1, v.shape[1] + 1, dtype=float))
    lipschitz = np.abs(v) @ roots + np.abs(w) * roots[-1]
    model = np.abs(v - v_nominal).sum(axis=1) + np.abs(w - w_nominal)
    plan_error = float(np.hypot(*(end_effector(nominal, np.asarray(planned, dtype=float))
                                  - np.asarray(target, dtype=float))))
    bound = lipschitz * np.asarray(err_theta_final, dtype=float) + model + plan_error
    farthest = np.abs(v).sum(axis=1) + np.abs(w) + float(np.hypot(*np.asarray(target, float)))
    return np.asarray(np.where(np.isnan(bound), np.nan, np.minimum(bound, farthest)),
                      dtype=float)


__all__ = ["TARGET_TOL", "Task", "TaskPlan", "end_effector_error_bound", "plan_task", "task_ends",
           "task_errors"]
