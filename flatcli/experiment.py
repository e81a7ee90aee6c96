"""From a validated spec to the core's objects, and the runs of ``plan`` and ``track``.

This is wiring only: every number is computed by ``flatcli.core``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from flatcli.core.control import Gains
from flatcli.core.flatness import flat_outputs, singularity_margin
from flatcli.core.metrics import METRIC_NAMES, describe_status
from flatcli.core.model import RobotParams, momentum
from flatcli.core.optimize import DEFAULT_BSPLINE_DEGREE, OptimizeResult, PlanLimits, optimize_plan
from flatcli.core.planning import (
    Basis,
    BSplineBasis,
    FlatPlan,
    PolynomialBasis,
    plan_point_to_point,
)
from flatcli.core.simulate import Outcome, Scenario, Trials, simulate
from flatcli.spec import Spec

Array = NDArray[np.float64]

#: spawn_key slots of the per-trial random streams (SeedSequence(seed, (trial, slot))).
STREAM_PERTURB = 0
STREAM_NOISE = 1


def robot_from(spec: Spec) -> RobotParams:
    """The nominal robot (what the planner and controller believe)."""
    return RobotParams(*(spec.get(f"robot.{k}") for k in ("mass", "inertia", "length", "com")))


def plant_from(spec: Spec) -> RobotParams:
    """The plant: ``[plant]`` overrides of ``[robot]``."""
    values = []
    for key in ("mass", "inertia", "length", "com"):
        value = spec.get(f"plant.{key}")
        values.append(spec.get(f"robot.{key}") if value is None else value)
    return RobotParams(*values)


def basis_from(spec: Spec) -> Basis:
    """The flat-output basis: ``auto`` is the paper's cubic, or the optimiser's default
    (quintic B-splines, ``plan.size`` coefficients) when ``plan.optimize.objective`` is set."""
    duration = spec.get("plan.duration")
    kind = spec.get("plan.basis")
    degree = spec.get("plan.degree")
    if kind == "auto":
        kind = "poly" if spec.get("plan.optimize.objective") is None else "bspline"
    if kind == "bspline":
        return BSplineBasis(spec.get("plan.size"), duration, degree or DEFAULT_BSPLINE_DEGREE)
    return PolynomialBasis(degree or 3, duration)


def plan_and_optimization(spec: Spec) -> tuple[FlatPlan, OptimizeResult | None]:
    """The reference plan of a spec, and the optimiser's report when it optimised one."""
    robot = robot_from(spec)
    start = np.asarray(spec.get("plan.start"))
    goal = np.asarray(spec.get("plan.goal"))
    objective = spec.get("plan.optimize.objective")
    if objective is None:
        plan = plan_point_to_point(
            robot, start, goal, spec.get("plan.start_rate"), spec.get("plan.goal_rate"),
            spec.get("plan.duration"), spec.get("robot.model"), basis_from(spec),
        )
        return plan, None
    result = optimize_plan(
        robot, start, goal, spec.get("plan.duration"),
        model=spec.get("robot.model"),
        basis=basis_from(spec),
        objective=objective,
        limits=PlanLimits(
            angle_limit=spec.get("plan.optimize.angle_limit"),
            rate_limit=spec.get("plan.optimize.rate_limit"),
            min_margin=spec.get("plan.optimize.min_margin"),
        ),
        free_rates=spec.get("plan.optimize.free_rates"),
        start_rate=spec.get("plan.start_rate"),
        goal_rate=spec.get("plan.goal_rate"),
        constraint_samples=spec.get("plan.optimize.constraint_samples"),
        max_iter=spec.get("plan.optimize.max_iter"),
    )
    return result.plan, result


def plan_from(spec: Spec) -> FlatPlan:
    """The reference plan of a spec (optimised when ``plan.optimize.objective`` is set)."""
    return plan_and_optimization(spec)[0]


def scenario_from(spec: Spec, plan: FlatPlan) -> Scenario:
    kp, kv = spec.get("track.kp"), spec.get("track.kv")
    return Scenario(
        plan=plan,
        gains=Gains(kp[0], kp[1], kv[0], kv[1]),
        dt=spec.get("track.dt"),
        rate_limit=spec.get("track.rate_limit"),
        singular_threshold=spec.get("track.singular_threshold"),
        divergence_bound=spec.get("track.divergence_bound"),
        plan_samples=spec.get("plan.samples"),
    )


def trial_stream(seed: int, trial: int, slot: int) -> np.random.Generator:
    """The random stream of one trial: independent of every other trial and of chunking."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(trial, slot)))


def sensor_noise(std: float, n_steps: int, seed: int, trial: int) -> Array | None:
    """(n_steps, 3) noise on the measured angles [rad], or None when std = 0."""
    if std == 0:
        return None
    return std * trial_stream(seed, trial, STREAM_NOISE).standard_normal((n_steps, 3))


def nominal_trials(spec: Spec, scenario: Scenario) -> Trials:
    """The single trial a ``track`` spec describes."""
    plant = plant_from(spec)
    initial = np.array([[*spec.get("track.initial"), spec.get("track.initial_rate")]])
    noise = sensor_noise(
        spec.get("track.sensor_noise"),
        scenario.n_steps,
        spec.get("track.seed"),
        spec.get("track.trial"),
    )
    return Trials(
        links=plant.as_array()[None, :],
        momentum=np.array([spec.get("plant.momentum")]),
        initial=initial,
        noise=None if noise is None else noise[None],
    )


@dataclass(frozen=True)
class TrackRun:
    """One closed-loop run: the plan, the scenario, and the recorded outcome."""

    spec: Spec
    plan: FlatPlan
    scenario: Scenario
    outcome: Outcome

    @property
    def metrics(self) -> dict[str, float | int | str]:
        values = self.outcome.metrics[0]
        out: dict[str, float | int | str] = {
            name: float(v) for name, v in zip(METRIC_NAMES, values, strict=True)
        }
        out["singular_hits"] = int(values[METRIC_NAMES.index("singular_hits")])
        status, reason = describe_status(
            int(self.outcome.status[0]),
            float(self.outcome.event_time[0]),
            values,
            self.scenario.singular_threshold,
            self.scenario.divergence_bound,
        )
        out["status"] = status
        out["reason"] = reason
        return out

    @cached_property
    def columns(self) -> dict[str, Array]:
        """Columns of track.parquet: the trace, u2, y, references, margin and H per sample.

        ``momentum`` is H from the plant's full link kinematics with rates taken from the
        trace itself (numpy.gradient, second order), the same estimate ``momentum_drift``
        takes its maximum deviation from.
        """
        times = self.scenario.times
        trace = self.outcome.trace
        assert trace is not None
        x = trace[0]
        ref = self.plan.sample(times)
        plant = plant_from(self.spec)
        with np.errstate(all="ignore"):
            y1, y2, _, _ = flat_outputs(self.plan.coefficients, *x[:, :4].T)
            rates = np.gradient(x[:, :3], self.scenario.dt, axis=0, edge_order=2)
            H = momentum(plant.links, *x[:, :3].T, *rates.T)
        cols: dict[str, Array] = {"t": times}
        for i in range(3):
            cols[f"theta{i}"] = x[:, i]
        for i in range(3):
            cols[f"theta{i}_ref"] = ref.theta[:, i]
        cols["u1"] = x[:, 3]
        cols["u2"] = x[:, 4]
        cols["y1"], cols["y2"] = np.asarray(y1), np.asarray(y2)
        cols["y1_ref"], cols["y2_ref"] = ref.y[:, 0], ref.y[:, 1]
        cols["margin"] = np.asarray(singularity_margin(x[:, 1], x[:, 3]))
        cols["momentum"] = np.asarray(H)
        return cols


def run_track(spec: Spec) -> TrackRun:
    """Plan, then simulate the closed loop of a spec, recording the trace."""
    plan = plan_from(spec)
    scenario = scenario_from(spec, plan)
    trials = nominal_trials(spec, scenario)
    outcome = simulate(scenario, trials, spec.get("track.integrator"), record=True)
    return TrackRun(spec, plan, scenario, outcome)
