"""From a validated spec to the core's objects, and the runs of ``plan`` and ``track``.

This is wiring only: every number is computed by ``flatcli.core``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray

from flatcli.core.controllers.control import Gains
from flatcli.core.controllers.lqr import LqrWeights
from flatcli.core.controllers.settings import settings_of
from flatcli.core.curves.basis import Basis, BSplineBasis, PolynomialBasis
from flatcli.core.errors import FlatcliError
from flatcli.core.loop.metrics import COUNT_METRICS, METRIC_NAMES, describe_status
from flatcli.core.loop.outcome import Geometry, Goal, Judged, judge
from flatcli.core.loop.simulate import (
    FLAT_ON_EXACT,
    TWIN_FACTOR,
    NoiseStreams,
    Outcome,
    Scenario,
    Trials,
    simulate,
)
from flatcli.core.names import Objective
from flatcli.core.plan.exact import method_for, plan_exact
from flatcli.core.plan.planning import (
    Plan,
    fastest_joint,
    plan_point_to_point,
    rate_warning_text,
)
from flatcli.core.plan.task import Task, TaskPlan, plan_task, task_ends
from flatcli.core.robots.params import RobotParams
from flatcli.spec import Spec, SpecError
from flatcli.spec.limits import check_track
from flatcli.spec.schema import goal_is_derived
from flatcli.spec.unread import unread_keys

if TYPE_CHECKING:  # the optimiser (scipy's SLSQP) loads only for a spec that optimises
    from flatcli.core.optimize import OptimizeResult

Array = NDArray[np.float64]

#: spawn_key slot of a trial's perturbation stream (SeedSequence(seed, (trial, 0))); its
#: sensor noise comes from slot 1 (``flatcli.core.loop.simulate.noise_generator``).
STREAM_PERTURB = 0


def checked(value: object) -> Any:
    """A spec value handed to the core as it is.

    The spec has checked it against the core's own enumeration (``MODELS``, ``OBJECTIVES``,
    ``INTEGRATORS``) or a vector length; the core's parameter types say so more narrowly
    (``Literal`` names, fixed-length tuples) than the spec's records can.
    """
    return value


def robot_from(spec: Spec) -> RobotParams:
    """The nominal robot (what the planner and controller believe)."""
    robot = spec.robot
    mass, inertia, length, com = checked((robot.mass, robot.inertia, robot.length, robot.com))
    return RobotParams(mass, inertia, length, com, robot.com_across)


def plant_from(spec: Spec) -> RobotParams:
    """The plant: ``[plant]`` overrides of ``[robot]``."""
    robot, plant = spec.robot, spec.plant
    mass, inertia, length, com = checked((
        robot.mass if plant.mass is None else plant.mass,
        robot.inertia if plant.inertia is None else plant.inertia,
        robot.length if plant.length is None else plant.length,
        robot.com if plant.com is None else plant.com,
    ))
    across = robot.com_across if plant.com_across is None else plant.com_across
    return RobotParams(mass, inertia, length, com, across)


def basis_from(spec: Spec, method: str = "flat") -> Basis:
    """The flat-output basis: ``auto`` is the paper's cubic, or the optimiser's default
    (quintic B-splines, ``plan.size`` coefficients) when ``plan.optimize.objective`` is set
    or the plan is exact (the joint paths' basis, ``method``)."""
    plan = spec.plan
    kind = plan.basis
    if kind == "auto":
        flat_cubic = plan.optimize.objective is None and method == "flat"
        kind = "poly" if flat_cubic else "bspline"
    if kind == "bspline":
        from flatcli.core.optimize import DEFAULT_BSPLINE_DEGREE

        return BSplineBasis(plan.size, plan.duration, plan.degree or DEFAULT_BSPLINE_DEGREE)
    return PolynomialBasis(plan.degree or 3, plan.duration)


def joint_rates(value: float | tuple[float, ...], joints: int) -> Array:
    """(N - 1,) rates of th_1..th_N-1 [rad/s] from a spec's rate key (one number: all)."""
    return np.broadcast_to(np.asarray(value, dtype=float), (joints - 1,)).copy()


def task_from(spec: Spec) -> Task:
    """The spec's ``[task]`` as the core's ``Task``."""
    t = spec.task
    return Task(end_effector=checked(t.end_effector), base_attitude=t.base_attitude,
                start_end_effector=checked(t.start_end_effector), rest=t.rest,
                obstacles=t.obstacles, clearance=t.clearance, elbow=checked(t.elbow),
                budget=t.budget)


def _is_default(dotted: str, value: object) -> bool:
    from flatcli.spec import lookup

    return bool(value == lookup(dotted).default)


#: What a spec asks to be planned (``task_kind``): a point-to-point maneuver (no active
#: ``[task]``), an end-effector or obstacle task, or a task that starts and stops at rest.
TaskKind = Literal["maneuver", "task", "rest"]
#: How it is planned (``plan_method``): through the closed-form flat outputs, optimised
#: through them (``plan.optimize.objective``), or exact (``plan.method``, ``exact.method_for``).
PlanMethod = Literal["flat", "optimized", "exact"]
#: A planner: (spec, nominal robot) -> (plan, the optimiser's report, the task's plan).
Planner = Callable[[Spec, RobotParams], "Planned"]
Planned = tuple[Plan, "OptimizeResult | None", TaskPlan | None]


def task_kind(spec: Spec) -> TaskKind:
    """The spec's kind of task (``TaskKind``; ``Task.active``: anything beyond a plain
    plan)."""
    task = task_from(spec)
    if not task.active:
        return "maneuver"
    return "rest" if task.rest else "task"


def plan_method(spec: Spec, robot: RobotParams) -> PlanMethod:
    """How the spec's plan is made (``PlanMethod``)."""
    if method_for(robot, spec.plan.method) == "exact":
        return "exact"
    return "flat" if spec.plan.optimize.objective is None else "optimized"


def _ends(spec: Spec) -> tuple[Array, Array, Array, Array]:
    """start, goal (N + 1,) [rad] and start_rate, goal_rate (N - 1,) [rad/s] of the plan."""
    p, joints = spec.plan, spec.joints
    return (np.asarray(p.start), np.asarray(p.goal), joint_rates(p.start_rate, joints),
            joint_rates(p.goal_rate, joints))


def _task_ends(spec: Spec, robot: RobotParams) -> tuple[Task, list[Array], list[Array]]:
    """The task, and the candidate starts and goals (k, N + 1) its ends allow [rad]."""
    p, task = spec.plan, task_from(spec)
    starts, goals = task_ends(robot, task, np.asarray(p.start), np.asarray(p.goal),
                              _is_default("plan.start", p.start),
                              goal_is_derived(spec))
    return task, starts, goals


def _flat(spec: Spec, robot: RobotParams) -> Planned:
    start, goal, start_rate, goal_rate = _ends(spec)
    return plan_point_to_point(robot, start, goal, start_rate, goal_rate, spec.plan.duration,
                               checked(spec.robot.model), basis_from(spec)), None, None


def _exact(spec: Spec, robot: RobotParams) -> Planned:
    """The exact plan (``exact.plan_exact``): its objective from ``plan.optimize.objective``;
    its limits are the flat optimiser's, refused here."""
    opt = spec.plan.optimize
    for key, value in (("angle_limit", opt.angle_limit), ("rate_limit", opt.rate_limit)):
        if np.any(np.isfinite(np.asarray(value, dtype=float))):
            raise SpecError(f"plan.optimize.{key}: limits apply to flat plans only; an exact "
                            "plan (plan.method) minimises its objective without them")
    return plan_exact(robot, *_ends(spec), spec.plan.duration, basis_from(spec, "exact"),
                      checked(opt.objective)), None, None


def _optimized(spec: Spec, robot: RobotParams, start: Array | None = None,
               goal: Array | None = None) -> Planned:
    from flatcli.core.optimize import PlanLimits, optimize_plan

    p, opt, joints = spec.plan, spec.plan.optimize, spec.joints
    own_start, own_goal, start_rate, goal_rate = _ends(spec)
    limits = PlanLimits(angle_limit=checked(opt.angle_limit),
                        rate_limit=checked(opt.rate_limit), min_margin=opt.min_margin)
    result = optimize_plan(
        robot, own_start if start is None else start, own_goal if goal is None else goal,
        p.duration, model=checked(spec.robot.model), basis=basis_from(spec),
        objective=checked(opt.objective), limits=limits, free_rates=opt.free_rates,
        start_rate=checked(float(start_rate[0]) if joints == 2 else start_rate),
        goal_rate=checked(float(goal_rate[0]) if joints == 2 else goal_rate),
        constraint_samples=opt.constraint_samples, max_iter=opt.max_iter)
    return result.plan, result, None


def _task(spec: Spec, robot: RobotParams) -> Planned:
    """A task's plan through the closed-form flat outputs: its candidates tried until one is
    proven clear (``task.plan_task``; a rest task with its rest-to-rest plan)."""
    task, starts, goals = _task_ends(spec, robot)
    opt, joints, (_, _, start_rate, goal_rate) = spec.plan.optimize, spec.joints, _ends(spec)
    done = plan_task(robot, task, starts, goals, spec.plan.duration, start_rate, goal_rate,
                     checked(spec.robot.model), None if task.rest else basis_from(spec),
                     np.asarray(opt.angle_limit, dtype=float),
                     np.broadcast_to(np.asarray(opt.rate_limit, dtype=float), (joints,)),
                     spec.plan.rate_warning, spec.plan.samples)
    return done.plan, None, done


def _optimized_task(spec: Spec, robot: RobotParams) -> Planned:
    """A task's optimised plan, from its first candidate ends, its obstacles proven clear
    afterwards (SpecError if not: the optimiser does not see them)."""
    from flatcli.core.plan.clearance import Constraints, certify

    task, starts, goals = _task_ends(spec, robot)
    plan, result, _ = _optimized(spec, robot, starts[0], goals[0])
    cert = None
    if task.obstacles:
        cert = certify(plan, Constraints(np.asarray(task.obstacles, dtype=float),
                                         task.clearance))
        if not cert.ok:
            raise SpecError(f"task.obstacles: the optimised plan is not clear: {cert.reason} "
                            "(the optimiser does not see obstacles; plan without --optimize "
                            "to search for a clear plan)")
    return plan, result, TaskPlan(plan, starts[0], goals[0], cert, 1)


#: The planners, by (task kind, method): the one place a spec's plan is chosen.
PLANNERS: dict[tuple[TaskKind, PlanMethod], Planner] = {
    ("maneuver", "flat"): _flat,
    ("maneuver", "optimized"): _optimized,
    ("maneuver", "exact"): _exact,
    ("task", "flat"): _task,
    ("task", "optimized"): _optimized_task,
    ("rest", "flat"): _task,
}
#: Why the other combinations are refused (SpecError).
REFUSED: dict[tuple[TaskKind, PlanMethod], str] = {
    **dict.fromkeys((("task", "exact"), ("rest", "exact")), (
        "plan.method: a [task] is planned through the closed-form flat outputs; the exact "
        "planner (plan.method \"exact\", or \"auto\" on a design without them) does not plan "
        "tasks")),
    ("rest", "optimized"): ("task.rest: not with plan.optimize.objective (the optimiser plans "
                            "with free, non-zero end rates)"),
}


def planned(spec: Spec) -> Planned:
    """The spec's plan by its planner (``PLANNERS[task kind, method]``): the plan, the
    optimiser's report when it optimised one, and for an active ``[task]`` its ``TaskPlan``
    (the ends derived from the task, the certificate of its obstacles and limits)."""
    robot = robot_from(spec)
    model, joints = spec.robot.model, spec.joints
    if joints > 2 and model != "derived":
        raise SpecError(f"robot.model: {model!r} (the appendix as printed) applies to the "
                        f"paper's robot (2 joints) only; a robot of {joints} joints plans with "
                        "\"derived\"")
    key = (task_kind(spec), plan_method(spec, robot))
    planner = PLANNERS.get(key)
    if planner is None:
        raise SpecError(REFUSED[key])
    return planner(spec, robot)


def plan_from(spec: Spec) -> Plan:
    """The reference plan of a spec (optimised when ``plan.optimize.objective`` is set)."""
    return planned(spec)[0]


#: Why a plan the MPC cannot keep within ``track.rate_limit`` is not re-planned, by task kind
#: and plan method (the re-plan is the flat optimiser's, for a maneuver).
NOT_REPLANNED: dict[tuple[TaskKind, PlanMethod], str] = {
    ("maneuver", "exact"): "an exact plan (plan.method) is not re-planned",
    ("task", "flat"): "a task's plan is not re-planned (its obstacles are not re-proven)",
    ("task", "optimized"): "a task's plan is not re-planned (its obstacles are not re-proven)",
}


def peak_joint_rate(plan: Plan, samples: int) -> float:
    """The plan's largest abs(th_j') over its joints j = 1..N on its own grid of ``samples``
    points [rad/s] (``planning.fastest_joint``; inf if a rate is not finite)."""
    return fastest_joint(plan.sample(plan.grid(samples)))[1]


def mpc_kept_limit(spec: Spec) -> float:
    """The joint-rate limit the MPC keeps [rad/s]: ``track.rate_limit`` (1 -
    ``track.mpc_backoff``); inf without a limit."""
    limit = float(spec.track.rate_limit)
    if not np.isfinite(limit):
        return float("inf")
    return limit * (1.0 - float(settings_of(spec.track)["mpc"].backoff))


def mpc_kept_torque(spec: Spec) -> float:
    """The joint-torque limit the MPC keeps [N m]: on the dynamic plant ``plant.torque_limit``
    (1 - ``track.mpc_backoff``); inf on the kinematic plant or without a limit. The cell's
    limit: a limit drawn per trial (``[sweep.perturb] torque_limit``) is not seen."""
    limit = float(spec.plant.torque_limit)
    if spec.plant.model != "dynamic" or not np.isfinite(limit):
        return float("inf")
    return limit * (1.0 - float(settings_of(spec.track)["mpc"].backoff))


def peak_joint_torque(spec: Spec, plan: Plan) -> tuple[int, float, float]:
    """(j, peak, t): the joint j in 1..N whose torque abs(tau_j) is largest of those the plan
    asks of the plant (``plant_from``; inverse dynamics, ``Plan.torques``: exact tracking, no
    servo lag) on the plan's own grid of ``plan.samples`` points, that peak [N m] (inf if a
    torque is not finite) and its time [s]."""
    from flatcli.core.robots.dynamics import make_chain

    plant = plant_from(spec)
    t = plan.grid(spec.plan.samples)
    torques = np.abs(plan.torques(make_chain(plant.mass, plant.inertia, plant.length,
                                             plant.com), t)[:, 1:])
    if not np.all(np.isfinite(torques)):
        return 1, float("inf"), float("nan")
    k, j = np.unravel_index(int(np.argmax(torques)), torques.shape)
    return int(j) + 1, float(torques[k, j]), float(t[k])


def mpc_reference(spec: Spec, plan: Plan) -> tuple[Plan, bool | None]:
    """The plan the MPC tracks, and whether it was re-planned (None: the controller is not
    the MPC). The spec's plan, unless
    - its peak joint rate (``peak_joint_rate``) exceeds the limit the MPC keeps
      (``mpc_kept_limit``): then the plan of least peak joint rate (objective "peak_rate");
    - else, on the dynamic plant, the peak joint torque it asks of the plant
      (``peak_joint_torque``) exceeds the torque limit the MPC keeps (``mpc_kept_torque``):
      then the plan of largest singularity margin (objective "margin": the least peak rate
      plan runs along its margin bound, where the corrections of small errors turn the joints
      fast and ask the torque again; docs/physics.md);
    each between the same ends in the same duration (``optimize_plan``, its end rates free,
    its margin >= max(``plan.optimize.min_margin``, ``track.mpc_margin``), the spec's angle
    limits kept), which the MPC tracks even when it is still beyond the limit
    (``plan_warnings`` says so). The paper's feedback and the as-built law track the spec's
    plan as it is. A plan the optimiser cannot improve (an exact plan, a task's;
    ``NOT_REPLANNED``), or whose re-plan fails, is tracked as it is, with the warning."""
    if spec.track.controller != "mpc":
        return plan, None
    kept, kept_torque = mpc_kept_limit(spec), mpc_kept_torque(spec)
    objective: Objective
    if peak_joint_rate(plan, spec.plan.samples) > kept:
        objective = "peak_rate"
    elif np.isfinite(kept_torque) and peak_joint_torque(spec, plan)[1] > kept_torque:
        objective = "margin"
    else:
        return plan, False
    robot = robot_from(spec)
    if (task_kind(spec), plan_method(spec, robot)) in NOT_REPLANNED:
        return plan, False
    from flatcli.core.optimize import PlanLimits, optimize_plan

    opt, joints = spec.plan.optimize, spec.joints
    start, goal, start_rate, goal_rate = _ends(spec)
    margin = max(opt.min_margin, float(settings_of(spec.track)["mpc"].margin))
    limits = PlanLimits(angle_limit=checked(opt.angle_limit), min_margin=margin)
    try:
        result = optimize_plan(
            robot, start, goal, spec.plan.duration, model=checked(spec.robot.model),
            objective=objective, limits=limits, free_rates=True,
            start_rate=checked(float(start_rate[0]) if joints == 2 else start_rate),
            goal_rate=checked(float(goal_rate[0]) if joints == 2 else goal_rate),
            constraint_samples=opt.constraint_samples, max_iter=opt.max_iter)
    except FlatcliError:  # no plan meets the margin: the spec's, with its warning
        return plan, False
    return result.plan, True


def tracked_plan(spec: Spec) -> tuple[Plan, bool | None]:
    """The plan a spec's controller tracks (``plan_from``, then ``mpc_reference``)."""
    return mpc_reference(spec, plan_from(spec))


def scenario_from(spec: Spec, plan: Plan, replanned: bool | None = None) -> Scenario:
    """The scenario of a spec tracking ``plan``; ``replanned`` as ``mpc_reference`` says
    (a plan re-planned within the torque limit slows the MPC's inner poles:
    ``Scenario.torque_replanned``)."""
    track = spec.track
    kp, kv = track.kp, track.kv
    return Scenario(
        plan=plan,
        gains=Gains(kp, kv),
        dt=track.dt,
        rate_limit=track.rate_limit,
        singular_threshold=track.singular_threshold,
        divergence_bound=track.divergence_bound,
        plan_samples=spec.plan.samples,
        rtol=track.rtol,
        atol=track.atol,
        max_steps=track.max_steps,
        plant=checked(spec.plant.model),
        servo_model=checked(spec.plant.servo_model),
        controller=checked(track.controller),
        lqr=LqrWeights(track.lqr_bandwidth, track.lqr_terminal, track.lqr_base),
        settings=settings_of(track),
        servo_bandwidth=spec.plant.servo_bandwidth,
        torque_replanned=bool(replanned) and math.isfinite(mpc_kept_torque(spec))
        and not math.isfinite(spec.track.rate_limit),
        torque_kept=mpc_kept_torque(spec) if track.controller == "mpc" else math.inf,
        twin=TWIN_FACTOR if track.error_estimate == "twin" else 0.0,
        accuracy=track.accuracy,
        observe_every=track.observe_every,
        fade=spec.task.fade,
    )


def trial_stream(seed: int, trial: int, slot: int) -> np.random.Generator:
    """The random stream of one trial: independent of every other trial and of chunking."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(trial, slot)))


def initial_rates(spec: Spec, plan: Plan) -> Array:
    """(N - 1,) u_j(0) = th_j'(0), j < N [rad/s]: ``track.initial_rate``, or the plan's own
    rates at t = 0 when the spec leaves it out (the optimised plan's chosen rates with
    ``--optimize``)."""
    joints = spec.joints
    if spec.track.initial_rate is not None:
        return joint_rates(spec.track.initial_rate, joints)
    return np.asarray(plan.trajectory.derivative(np.array([0.0]), 1)[0, :joints - 1], dtype=float)


def nominal_trials(spec: Spec, plan: Plan) -> Trials:
    """The single trial a ``track`` spec describes."""
    plant = plant_from(spec)
    track = spec.track
    return Trials(
        links=plant.as_array()[None, :],
        momentum=np.array([spec.plant.momentum]),
        initial=np.array([[*track.initial, *initial_rates(spec, plan)]]),
        noise=NoiseStreams(track.sensor_noise, track.seed, np.array([track.trial])),
        servo=np.array([[spec.plant.servo_bandwidth, spec.plant.torque_limit]]),
        across=np.array([plant.com_across]),
    )


@dataclass(frozen=True)
class TrackRun:
    """One closed-loop run: the plan, the scenario, and the recorded outcome."""

    spec: Spec
    plan: Plan
    scenario: Scenario
    outcome: Outcome
    #: the MPC tracks a re-plan of the spec's plan (``mpc_reference``); None: not the MPC
    replanned: bool | None = None

    @property
    def metrics(self) -> dict[str, float | int | str | None]:
        """Every metric by name, the status, its reason and the event time (None: not
        applicable)."""
        values = self.outcome.metrics[0]
        out: dict[str, float | int | str | None] = {}
        for name, v in zip(METRIC_NAMES, values, strict=True):
            value = float(v)
            out[name] = None if np.isnan(value) else (int(value) if name in COUNT_METRICS
                                                      else value)
        if self.outcome.extra is not None:  # the controller's own (the MPC's qp_*)
            for name, v in zip(self.outcome.extra_columns, self.outcome.extra[0], strict=True):
                value = float(v)
                out[name] = None if np.isnan(value) else (
                    int(value) if name in self.outcome.extra_counts else value)
        status, reason = describe_status(
            int(self.outcome.status[0]),
            int(self.outcome.event[0]),
            float(self.outcome.event_time[0]),
            values,
            self.scenario.singular_threshold,
            self.scenario.divergence_bound,
            self.outcome.unverified(0),
        )
        if self.spec.task.end_effector is not None or self.spec.task.obstacles:
            cols = self.columns
            n = self.spec.joints
            theta = np.column_stack([cols[f"theta{i}"] for i in range(n + 1)])
            ref = np.column_stack([cols[f"theta{i}_ref"] for i in range(n + 1)])
            out.update(task_metrics(self.spec, theta, ref, plant_from(self.spec)))
            clearance = self.outcome.clearance
            if clearance is not None:  # up to a stop too: the samples the trial reached
                for key, value in (("min_clearance", clearance.sampled[0]),
                                   ("clearance_bound", clearance.bound[0])):
                    out[key] = float(value) if np.isfinite(value) else None
        judged = self.judged(status, reason)
        if self.spec.task.end_effector is not None:  # measured as a sweep measures it
            distance = float(judged.target_error[0])
            out["ee_error_final"] = distance if np.isfinite(distance) else None
        for i, value in enumerate(judged.final_error[0]):
            out[f"err_theta{i}_final"] = float(value) if np.isfinite(value) else None
        if self.replanned is not None:
            out["replanned"] = self.replanned
        out["status"] = status
        out["reason"] = reason
        out["outcome"] = judged.outcome[0]
        out["outcome_reason"] = judged.reason[0]
        out["verified"] = bool(self.outcome.verified[0])
        event_time = float(self.outcome.event_time[0])
        out["event_time"] = None if np.isnan(event_time) else event_time
        return out

    def judged(self, status: str, reason: str) -> Judged:
        """The run's outcome (``judge_trials``) given its status and reason."""
        plant = plant_from(self.spec)
        return judge_trials(self.spec, self.scenario, [status], [reason], self.outcome,
                            plant.as_array()[None, :], np.array([plant.com_across]))

    @property
    def warnings(self) -> list[str]:
        """One line each: the plan's fastest joint beyond ``plan.rate_warning``, and each
        controller setting no trial reads (``spec.unread.unread_keys``)."""
        return unread_keys(self.spec) + plan_warnings(self.spec, self.plan)

    @cached_property
    def columns(self) -> dict[str, Array]:
        """Columns of track.parquet: per output sample the state, the plant's rates, y, the
        references, the margin, H and the joint torques (N + 1 angles, N outputs on a robot
        of N joints).

        ``u1..u(N-1)`` are the controller's states th_j' (j < N); ``uN`` is the rate command
        of joint N after the rate limit (on the kinematic plant the rate it turns at);
        ``momentum`` is H from the plant's full link kinematics at the integrated state with
        the plant's rates there (``momentum_drift`` is its largest deviation from H0);
        ``tau1..tauN`` the dynamic plant's joint torques (nan on the kinematic plant). Rows
        after the last valid sample of a trial that stopped early are nan.
        """
        times = self.scenario.times
        trace = self.outcome.trace
        assert trace is not None
        named = {name: trace[0][:, k] for k, name in enumerate(self.outcome.columns)}
        n = self.spec.joints
        ref = self.plan.sample(times)
        theta = np.column_stack([named[f"theta{i}"] for i in range(n + 1)])
        rates = np.column_stack([named[f"theta{i}_dot"] for i in range(n + 1)])
        u = np.column_stack([named[f"u{j}"] for j in range(1, n)])
        command = named.get(f"u{n}", rates[:, n])
        nan = np.full(len(times), np.nan)
        y, margin, H = self._outputs(theta, rates, u)
        cols: dict[str, Array] = {"t": times}
        for i in range(n + 1):
            cols[f"theta{i}"] = theta[:, i]
        for i in range(n + 1):
            cols[f"theta{i}_dot"] = rates[:, i]
        for i in range(n + 1):
            cols[f"theta{i}_ref"] = ref.theta[:, i]
        for j in range(1, n):
            cols[f"u{j}"] = u[:, j - 1]
        cols[f"u{n}"] = command
        for j in range(n):
            cols[f"y{j + 1}"] = y[:, j]
        for j in range(n):
            cols[f"y{j + 1}_ref"] = ref.y[:, j]
        cols["margin"] = margin
        cols["momentum"] = H
        for j in range(1, n + 1):
            cols[f"tau{j}"] = named.get(f"tau{j}", nan)
        for held in ("dv", "dw"):  # the MPC's held correction (``simulate.trace_columns``)
            for j in range(1, n + 1):
                if f"{held}{j}" in named:
                    cols[f"{held}{j}"] = named[f"{held}{j}"]
        cols.update(_positions(plant_from(self.spec), theta))
        return cols

    def _outputs(self, theta: Array, rates: Array, u: Array) -> tuple[Array, Array, Array]:
        """y (n, N) of the true state with the controller's flat map, the controller's
        margin (n,) and the plant's H (n,) from its full link kinematics."""
        plant = plant_from(self.spec)
        model = self.plan.model
        y, _, sigma = model.outputs(theta, u)
        with np.errstate(all="ignore"):
            H = model.momentum(plant, theta, rates)
        return y, np.abs(sigma), np.asarray(H)


def plan_warnings(spec: Spec, plan: Plan) -> list[str]:
    """The warnings of the plan a spec's controller tracks, one line each: its fastest joint
    beyond ``plan.rate_warning`` on its own grid (``plan.samples`` points;
    ``core.planning.rate_warning_text``); with the MPC, its fastest joint beyond the limit
    the MPC keeps (``mpc_kept_limit``): no plan within the limit was found; on the dynamic
    plant, the torque it asks beyond the torque limit the MPC keeps (``mpc_kept_torque``)."""
    samples = plan.sample(plan.grid(spec.plan.samples))
    text = rate_warning_text(samples, spec.plan.rate_warning)
    lines = [text] if text else []
    kept = mpc_kept_limit(spec) if spec.track.controller == "mpc" else float("inf")
    joint, peak, when = fastest_joint(samples)
    if peak > kept:
        why = NOT_REPLANNED.get((task_kind(spec), plan_method(spec, robot_from(spec))),
                                "no plan between the same ends within it was found (the MPC "
                                "tracks the one of least peak rate)")
        lines.append(f"warning: the MPC's reference turns th{joint}' at {peak:.4g} rad/s at "
                     f"t = {when:.4g} s, above the {kept:.4g} rad/s it keeps of "
                     f"track.rate_limit = {spec.track.rate_limit:g} rad/s: {why}")
    kept_torque = mpc_kept_torque(spec) if spec.track.controller == "mpc" else float("inf")
    if np.isfinite(kept_torque):
        joint, peak, when = peak_joint_torque(spec, plan)
        if peak > kept_torque:
            why = NOT_REPLANNED.get((task_kind(spec), plan_method(spec, robot_from(spec))),
                                    "the re-plan between the same ends (docs/physics.md, "
                                    "\"Re-planning within the limit\") asks more")
            lines.append(f"warning: the MPC's reference asks tau{joint} = {peak:.4g} N m at "
                         f"t = {when:.4g} s of the plant, above the {kept_torque:.4g} N m it "
                         f"keeps of plant.torque_limit = {spec.plant.torque_limit:g} N m: "
                         f"{why}")
    return lines


def goal_of(spec: Spec, scenario: Scenario, target: Any = None) -> Goal:
    """What the trials of a scenario were asked: the plan's th(T) (the angles
    ``err_theta_final`` compares with) within ``track.goal_tolerance``, and for a task its
    target (``target`` (2,) or (T, 2) [m]: each trial's own; default task.end_effector)
    within ``task.goal_tolerance``."""
    if target is None and spec.task.end_effector is not None:
        target = np.asarray(spec.task.end_effector, dtype=float)
    return Goal(np.asarray(scenario.theta_reference[-1], dtype=float),
                float(spec.track.goal_tolerance),
                None if target is None else np.asarray(target, dtype=float),
                float(spec.task.goal_tolerance))


def judge_trials(spec: Spec, scenario: Scenario, status: list[str], reason: list[str],
                 outcome: Outcome, links: Array, across: Array, target: Any = None) -> Judged:
    """The outcome of trials run by ``simulate`` (``core.outcome.judge``): their status words
    and reasons, the ``Outcome`` (final angles, clearance), the plants' links (T, 4 (N + 1))
    and e_N (T,) [m], and each trial's own target (None: the task's)."""
    final = outcome.final
    if final is None:
        final = np.full((len(status), spec.joints + 1), np.nan)
    goal = goal_of(spec, scenario, target)
    return judge(status, reason, final, goal, Geometry.of(links, across), outcome.clearance)


def _positions(robot: RobotParams, theta: Array) -> dict[str, Array]:
    """ee_x, ee_y, base_x, base_y [m] at angles theta (n, N + 1) (``core.kinematics``; nan
    where the angles are)."""
    from flatcli.core.robots.kinematics import base_position, end_effector

    ee = end_effector(robot, theta)
    base = base_position(robot, theta)
    return {"ee_x": ee[:, 0], "ee_y": ee[:, 1], "base_x": base[:, 0], "base_y": base[:, 1]}


def task_metrics(spec: Spec, theta: Array, reference: Array | None = None,
                 plant: RobotParams | None = None) -> dict[str, float | None]:
    """The task's metrics along angles theta (n, N + 1) on the output grid: the end
    effector's distance from the target at the end (``ee_error_final`` [m]), its largest
    distance from the plan's end effector (``ee_error_max`` [m], with the plan's angles
    ``reference``; null for a plan), the base attitude's error at the end
    (``base_attitude_error_final`` [rad]) and the least distance of any link from any
    obstacle's surface (``min_clearance`` [m]); null where the task does not ask."""
    from flatcli.core.plan.clearance import segment_distance
    from flatcli.core.robots.kinematics import end_effector, joint_positions

    task = spec.task
    robot = plant or robot_from(spec)
    ee = end_effector(robot, theta)

    def num(x: float) -> float | None:
        return None if not np.isfinite(x) else float(x)

    out: dict[str, float | None] = {
        "ee_error_final": None, "ee_error_max": None, "base_attitude_error_final": None,
        "min_clearance": None}
    if task.end_effector is not None:
        out["ee_error_final"] = num(float(np.hypot(*(ee[-1] - np.asarray(task.end_effector)))))
    if reference is not None:
        planned_ee = end_effector(robot_from(spec), reference)
        out["ee_error_max"] = num(float(np.max(np.hypot(*(ee - planned_ee).T))))
    if task.base_attitude is not None:
        out["base_attitude_error_final"] = num(abs(float(theta[-1, 0]) - task.base_attitude))
    if task.obstacles:
        obs = np.asarray(task.obstacles, dtype=float)
        gaps = segment_distance(joint_positions(robot, theta), obs[:, :2]) - obs[:, 2]
        out["min_clearance"] = num(float(np.min(gaps)))
    return out


def run_track(spec: Spec, before_simulating: Callable[[], object] | None = None,
              controller: Any = None) -> TrackRun:
    """Plan, then simulate the closed loop of a spec, recording the trace (SpecError, before
    any work, if that could not end within the time budget: ``check_track``);
    ``before_simulating`` is called once the plan and scenario are made and valid.
    ``controller``: a controller written in Python (``core.controllers.python``) acting at
    its sample instants around the spec's law, integrated by DOP853."""
    check_track(spec)
    if spec.track.controller == "flat" and not task_from(spec).active and method_for(
            robot_from(spec), spec.plan.method) == "exact":  # before planning compiles
        raise SpecError(FLAT_ON_EXACT)
    plan, replanned = tracked_plan(spec)
    scenario = scenario_from(spec, plan, replanned)
    integrator = checked(spec.track.integrator)
    if controller is not None:
        scenario = replace(scenario, python=controller)
        integrator = "dop853"
    trials = nominal_trials(spec, plan)
    if before_simulating is not None:
        before_simulating()
    outcome = simulate(scenario, trials, integrator, record=True,
                       obstacles=spec.task.obstacles or None)
    return TrackRun(spec, plan, scenario, outcome, replanned)


