"""From a validated spec to the core's objects, and the runs of ``plan`` and ``track``.

This is wiring only: every number is computed by ``flatcli.core``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core.basis import Basis, BSplineBasis, PolynomialBasis
from flatcli.core.control import Gains
from flatcli.core.metrics import COUNT_METRICS, METRIC_NAMES, describe_status
from flatcli.core.model import RobotParams
from flatcli.core.optimize import DEFAULT_BSPLINE_DEGREE, OptimizeResult, PlanLimits, optimize_plan
from flatcli.core.planning import Plan, plan_point_to_point
from flatcli.core.simulate import (
    TWIN_FACTOR,
    NoiseStreams,
    Outcome,
    Scenario,
    Trials,
    simulate,
)
from flatcli.spec import Spec, SpecError
from flatcli.spec.limits import check_track

Array = NDArray[np.float64]

#: spawn_key slot of a trial's perturbation stream (SeedSequence(seed, (trial, 0))); its
#: sensor noise comes from slot 1 (``flatcli.core.simulate.noise_generator``).
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
    return RobotParams(*checked((robot.mass, robot.inertia, robot.length, robot.com)))


def plant_from(spec: Spec) -> RobotParams:
    """The plant: ``[plant]`` overrides of ``[robot]``."""
    robot, plant = spec.robot, spec.plant
    return RobotParams(*checked((
        robot.mass if plant.mass is None else plant.mass,
        robot.inertia if plant.inertia is None else plant.inertia,
        robot.length if plant.length is None else plant.length,
        robot.com if plant.com is None else plant.com,
    )))


def basis_from(spec: Spec) -> Basis:
    """The flat-output basis: ``auto`` is the paper's cubic, or the optimiser's default
    (quintic B-splines, ``plan.size`` coefficients) when ``plan.optimize.objective`` is set."""
    plan = spec.plan
    kind = plan.basis
    if kind == "auto":
        kind = "poly" if plan.optimize.objective is None else "bspline"
    if kind == "bspline":
        return BSplineBasis(plan.size, plan.duration, plan.degree or DEFAULT_BSPLINE_DEGREE)
    return PolynomialBasis(plan.degree or 3, plan.duration)


def joint_rates(value: float | tuple[float, ...], joints: int) -> Array:
    """(N - 1,) rates of th_1..th_N-1 [rad/s] from a spec's rate key (one number: all)."""
    return np.broadcast_to(np.asarray(value, dtype=float), (joints - 1,)).copy()


def plan_and_optimization(spec: Spec) -> tuple[Plan, OptimizeResult | None]:
    """The reference plan of a spec, and the optimiser's report when it optimised one.

    One planner for every N (``planning.plan_point_to_point``, or the optimiser).
    """
    robot = robot_from(spec)
    p, opt = spec.plan, spec.plan.optimize
    start = np.asarray(p.start)
    goal = np.asarray(p.goal)
    model = checked(spec.robot.model)
    joints = spec.joints
    if joints > 2 and model != "derived":
        raise SpecError(f"robot.model: {model!r} (the appendix as printed) applies to the "
                        f"paper's robot (2 joints) only; a robot of {joints} joints plans with "
                        "\"derived\"")
    start_rate = joint_rates(p.start_rate, joints)
    goal_rate = joint_rates(p.goal_rate, joints)
    if opt.objective is None:
        return plan_point_to_point(robot, start, goal, start_rate, goal_rate, p.duration, model,
                                   basis_from(spec)), None
    result = optimize_plan(
        robot, start, goal, p.duration,
        model=model,
        basis=basis_from(spec),
        objective=checked(opt.objective),
        limits=PlanLimits(
            angle_limit=checked(opt.angle_limit),
            rate_limit=checked(opt.rate_limit),
            min_margin=opt.min_margin,
        ),
        free_rates=opt.free_rates,
        start_rate=checked(float(start_rate[0]) if joints == 2 else start_rate),
        goal_rate=checked(float(goal_rate[0]) if joints == 2 else goal_rate),
        constraint_samples=opt.constraint_samples,
        max_iter=opt.max_iter,
    )
    return result.plan, result


def plan_from(spec: Spec) -> Plan:
    """The reference plan of a spec (optimised when ``plan.optimize.objective`` is set)."""
    return plan_and_optimization(spec)[0]


def flat_plan_from(spec: Spec) -> Plan:
    """``plan_from`` where the paper's robot (N = 2) is required: its analyses (the fold,
    the actuators, the findings) are about that robot."""
    plan = plan_from(spec)
    if plan.n_joints != 2:
        raise SpecError(f"robot.mass: this needs the paper's robot (3 links, 2 joints), got "
                        f"{spec.joints + 1} links")
    return plan


def scenario_from(spec: Spec, plan: Plan) -> Scenario:
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
        twin=TWIN_FACTOR if track.error_estimate == "twin" else 0.0,
        accuracy=track.accuracy,
        observe_every=track.observe_every,
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
    )


@dataclass(frozen=True)
class TrackRun:
    """One closed-loop run: the plan, the scenario, and the recorded outcome."""

    spec: Spec
    plan: Plan
    scenario: Scenario
    outcome: Outcome

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
        status, reason = describe_status(
            int(self.outcome.status[0]),
            int(self.outcome.event[0]),
            float(self.outcome.event_time[0]),
            values,
            self.scenario.singular_threshold,
            self.scenario.divergence_bound,
            self.outcome.unverified(0),
        )
        out["status"] = status
        out["reason"] = reason
        out["verified"] = bool(self.outcome.verified[0])
        event_time = float(self.outcome.event_time[0])
        out["event_time"] = None if np.isnan(event_time) else event_time
        return out

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


def run_track(spec: Spec) -> TrackRun:
    """Plan, then simulate the closed loop of a spec, recording the trace (SpecError, before
    any work, if that could not end within the time budget: ``check_track``)."""
    check_track(spec)
    plan = plan_from(spec)
    scenario = scenario_from(spec, plan)
    trials = nominal_trials(spec, plan)
    outcome = simulate(scenario, trials, checked(spec.track.integrator), record=True)
    return TrackRun(spec, plan, scenario, outcome)
