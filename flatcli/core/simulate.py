"""Closed-loop trials: the planned reference, the controller, the plant, and an integrator.

``Scenario`` holds what every trial of a batch shares (the plan, the gains, the output grid,
limits and the integrator's tolerances); ``Trials`` what differs (the plant, H0, the initial
state, the sensor noise); ``simulate`` runs them and returns an ``Outcome``: per trial the
metrics (``metrics.Metric``), the status (``metrics.Status``), the event that stopped it
(``metrics.Event``) and its time, and optionally the trace on the output grid.

Three integrators:

* ``"adaptive"`` (default): Dormand-Prince 5(4) with step-size control and dense output,
  compiled (``integrate``); ``track.rtol`` and ``track.atol`` bound the local error, output
  samples come from the dense output, and each trial reports an error estimate.
* ``"rk4"``: classical fixed-step Runge-Kutta on the output grid, compiled; checks the
  controller's margin at each stage so that a step across the singular set stops the trial.
* ``"dop853"``: scipy's ``solve_ivp`` (DOP853, rtol 1e-10, atol 1e-12), one trial at a time:
  the reference the compiled integrators are checked against, with the same stopping rules
  (events on the divergence bound and on the margin's sign).

Two plants (``Scenario.plant``, ``plant.PLANT_MODELS``): the kinematic plant (joints follow
their commanded rates) and the dynamic plant (a robot with inertia, joint torques from rate
servos; ``plant``), through the same integrators. The dynamic plant's servo bandwidth and
torque limit may differ per trial (``Trials.servo``).

Every trial is integrated alone by the same compiled code, so its result does not depend on
which other trials share the batch, the order, the worker or the executor (bit for bit).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core._jit import jitable, kernel
from flatcli.core.chaindynamic import run_chain_dynamic_kernel
from flatcli.core.chainloop import ChainGains, run_chain_kernel
from flatcli.core.chainplan import ChainPlan
from flatcli.core.control import Gains
from flatcli.core.integrate import STALL_MARGIN, WORK_ROWS, make_trial_integrators, plan_flag
from flatcli.core.metrics import (
    ACCUMULATOR_SIZE,
    N_METRICS,
    Event,
    Status,
    conclude_trial,
    finish_metrics,
    observe_sample,
    observe_torque,
    plan_momentum_residual,
    reset_accumulator,
)
from flatcli.core.model import (
    Coefficients,
    FlatcliError,
    Links,
    constraint_coefficients,
)
from flatcli.core.planning import FlatPlan
from flatcli.core.plant import (
    AUX_C1,
    AUX_R2,
    AUX_S1,
    AUX_SATURATED,
    AUX_TAU1,
    AUX_TAU2,
    DEFAULT_SERVO_BANDWIDTH,
    DYNAMIC_AUX,
    DYNAMIC_STATE,
    KINEMATIC_AUX,
    KINEMATIC_STATE,
    PLANT_MODELS,
    SERVO_MODELS,
    DynamicLoop,
    Loop,
    PlantModel,
    ServoModel,
    dynamic_initial,
    dynamic_loop,
    dynamic_momentum,
    dynamic_rhs,
    kinematic_momentum,
    kinematic_rhs,
)

Array = NDArray[np.float64]
Integrator = Literal["adaptive", "rk4", "dop853"]
INTEGRATORS: tuple[Integrator, ...] = ("adaptive", "rk4", "dop853")

#: Columns of a trace: the kinematic plant's state, then the joint rates it applies.
TRACE_COLUMNS: tuple[str, ...] = (
    "theta0", "theta1", "theta2", "u1", "theta0_dot", "theta1_dot", "theta2_dot",
)  # fmt: skip
def chain_trace_columns(n: int) -> tuple[str, ...]:
    """Columns of a trace of an N-link chain: th0..thN, u1..u(N-1), then th0'..thN'."""
    return (*(f"theta{i}" for i in range(n + 1)), *(f"u{j}" for j in range(1, n)),
            *(f"theta{i}_dot" for i in range(n + 1)))


#: Columns of a trace of the dynamic plant: its state, the joint torques it applies [N m]
#: and the rate command r2 of joint 2 [rad/s].
DYNAMIC_TRACE_COLUMNS: tuple[str, ...] = (
    "theta0", "theta1", "theta2", "theta0_dot", "theta1_dot", "theta2_dot", "u1",
    "tau1", "tau2", "u2",
)  # fmt: skip


def chain_dynamic_trace_columns(n: int) -> tuple[str, ...]:
    """Columns of a trace of an N-link chain on the dynamic plant: th0..thN, th0'..thN',
    u1..u(N-1), the joint torques tau1..tauN [N m] and the rate command uN of joint N
    [rad/s] (``DYNAMIC_TRACE_COLUMNS`` for N = 2)."""
    return (*(f"theta{i}" for i in range(n + 1)), *(f"theta{i}_dot" for i in range(n + 1)),
            *(f"u{j}" for j in range(1, n)), *(f"tau{j}" for j in range(1, n + 1)), f"u{n}")

#: Tolerances of the reference integrator.
REFERENCE_RTOL = 1e-10
REFERENCE_ATOL = 1e-12
#: Default tolerances of the adaptive integrator: 1e-6 rad or better at every output sample
#: of the paper's example, printed or swapped gains, against a DOP853 at rtol 1e-12
#: (tests/test_simulate.py measures it).
DEFAULT_RTOL = 5e-8
DEFAULT_ATOL = 1e-10
DEFAULT_MAX_STEPS = 100_000
#: Most output intervals (duration / dt) a scenario may have: its reference tables take
#: 112 bytes per interval, and every trial observes every sample.
MAX_STEPS_PER_TRIAL = 10_000_000

#: spawn_key slot of a trial's sensor-noise stream: SeedSequence(seed, (trial, NOISE_SLOT)).
NOISE_SLOT = 1
#: A trial's servo when ``Trials.servo`` is None: bandwidth [rad/s], torque limit [N m].
DEFAULT_SERVO = (DEFAULT_SERVO_BANDWIDTH, math.inf)

_METHOD_RK4 = 0
_METHOD_ADAPTIVE = 1


def noise_generator(seed: int, trial: int) -> np.random.Generator:
    """The sensor-noise stream of one trial: ``default_rng(SeedSequence(seed, (trial, 1)))``,
    independent of every other trial and of chunking."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(trial, NOISE_SLOT)))


@jitable
def _observe_kinematic(loop: Loop, obs: Any, acc: Array, j: int, x: Array, f: Array) -> None:
    """Metrics of the kinematic plant at output sample j: H from the full link kinematics at
    the state with the joint rates the plant applies there (f)."""
    theta_ref, ref, threshold = obs
    observe_sample(acc, j, x[0], x[1], x[2], x[3], f[5], f[6], f[1], f[2],
                   kinematic_momentum(loop, x, f), theta_ref, ref, loop.kc, loop.h0, threshold)


_rk4_kinematic, _adaptive_kinematic = make_trial_integrators(kinematic_rhs, _observe_kinematic)


@jitable
def _observe_dynamic(loop: DynamicLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
                     ) -> None:
    """Metrics of the dynamic plant at output sample j: H from the full link kinematics at
    the state (its own rates), the joint rates and torques it applies."""
    theta_ref, ref, threshold = obs
    observe_sample(acc, j, x[0], x[1], x[2], x[6], f[AUX_C1], f[AUX_S1], x[4], x[5],
                   dynamic_momentum(loop, x, f), theta_ref, ref, loop.kc, loop.h0, threshold)
    observe_torque(acc, f[AUX_TAU1], f[AUX_TAU2], f[AUX_SATURATED])


@jitable
def _record_dynamic(trace: Array, j: int, nx: int, x: Array, f: Array) -> None:
    """Trace row j of the dynamic plant (``DYNAMIC_TRACE_COLUMNS``)."""
    for i in range(nx):
        trace[j, i] = x[i]
    trace[j, nx] = f[AUX_TAU1]
    trace[j, nx + 1] = f[AUX_TAU2]
    trace[j, nx + 2] = f[AUX_R2]


_rk4_dynamic, _adaptive_dynamic = make_trial_integrators(dynamic_rhs, _observe_dynamic,
                                                         _record_dynamic)


# fmt: off
@jitable
def _links_row(a: Array, i: int) -> Links:
    return Links(a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5],
                 a[i, 6], a[i, 7], a[i, 8], a[i, 9], a[i, 10], a[i, 11])


@jitable
def _coefficients_row(a: Array, i: int) -> Coefficients:
    return Coefficients(a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5],
                        a[i, 6], a[i, 7], a[i, 8], a[i, 9], a[i, 10])
# fmt: on


@jitable
def _is_flat(k: Coefficients) -> bool:
    """Whether a plant's constraint has no d2-terms (d2 = 0)."""
    return (k.a2 == 0.0 and k.a3 == 0.0 and k.b2 == 0.0 and k.b3 == 0.0 and k.c2 == 0.0
            and k.c3 == 0.0)


@kernel
def _kinematic_kernel(
    method: int,
    kc: Coefficients,
    gains: Gains,
    links: Array,
    plant_k: Array,
    h0: Array,
    rate_limit: float,
    initial: Array,
    ref: Array,
    theta_ref: Array,
    breaks: Array,
    local: Array,
    plan_theta: Array,
    plan_theta_dot: Array,
    dt: float,
    bound: float,
    threshold: float,
    rtol: float,
    atol: float,
    max_steps: int,
    tables: Array,
    gen: Any,
    std: float,
    record: bool,
    metrics: Array,
    status: NDArray[np.int64],
    event: NDArray[np.int64],
    event_time: Array,
    trace: Array,
) -> None:
    """Integrate every trial of a batch, one at a time; write metrics, status, events and
    (maybe) traces.

    Shapes: ref (2n+1, 6); theta_ref (n+1, 3); breaks (m+1,), local (m, d+1, 2);
    plan_theta, plan_theta_dot (p, 3); links (N, 12); plant_k (N, 11); h0 (N,);
    initial (N, 4); tables (N, n, 3) or (N, 0, 3); metrics (N, N_METRICS);
    status, event, event_time (N,); trace (N, n+1, 7) if record.
    """
    n = theta_ref.shape[0] - 1
    nx = KINEMATIC_STATE
    work = np.empty((WORK_ROWS, nx + KINEMATIC_AUX))
    acc = np.empty(ACCUMULATOR_SIZE)
    noise = np.zeros(3)
    flag = np.empty(6)
    scratch = np.empty((0, nx + 3))
    obs = (theta_ref, ref, threshold)
    for i in range(links.shape[0]):
        p = _links_row(links, i)
        kq = _coefficients_row(plant_k, i)
        loop = Loop(kc, gains, kq, p, p.m0 + p.m1 + p.m2, h0[i], rate_limit, _is_flat(kq))
        reset_accumulator(acc)
        tr = trace[i] if record else scratch
        x0 = initial[i]
        if method == _METHOD_RK4:
            last, ev, t_ev = _rk4_kinematic(loop, obs, x0, ref, dt, n, bound, tables[i], gen,
                                            std, record, tr, acc, work, noise)
            estimate, steps, evaluations = math.nan, last, 4 * last + 1
        else:
            last, ev, t_ev, estimate, steps, evaluations = _adaptive_kinematic(
                loop, obs, x0, breaks, local, dt, n, bound, rtol, atol, max_steps, 3,
                tables[i], gen, std, record, tr, acc, work, noise, flag, ref)
        _conclude(i, p, h0[i], plan_theta, plan_theta_dot, acc, last, n, ev, t_ev, estimate,
                  steps, evaluations, dt, record, tr, metrics, status, event, event_time)


@jitable
def _conclude(
    i: int, p: Links, h0: float, plan_theta: Array, plan_theta_dot: Array, acc: Array,
    last: int, n: int, ev: int, t_ev: float, estimate: float, steps: int, evaluations: int,
    dt: float, record: bool, tr: Array, metrics: Array, status: NDArray[np.int64],
    event: NDArray[np.int64], event_time: Array,
) -> None:
    """Trial i's metrics, status, event and event time from its run; its trace blanked
    after the last valid sample."""
    conclude_trial(i, plan_momentum_residual(plan_theta, plan_theta_dot, p, h0), acc, last, n,
                   ev, t_ev, estimate, steps, evaluations, dt, record, tr, metrics, status,
                   event, event_time)


@kernel
def _dynamic_kernel(
    method: int,
    kc: Coefficients,
    gains: Gains,
    robot: Links,
    servo_is_plant: bool,
    links: Array,
    h0: Array,
    servo: Array,
    rate_limit: float,
    initial: Array,
    ref: Array,
    theta_ref: Array,
    breaks: Array,
    local: Array,
    plan_theta: Array,
    plan_theta_dot: Array,
    dt: float,
    bound: float,
    threshold: float,
    rtol: float,
    atol: float,
    max_steps: int,
    tables: Array,
    gen: Any,
    std: float,
    record: bool,
    metrics: Array,
    status: NDArray[np.int64],
    event: NDArray[np.int64],
    event_time: Array,
    trace: Array,
) -> None:
    """``_kinematic_kernel`` for the dynamic plant: ``robot`` is the nominal robot (the
    servo's model unless ``servo_is_plant``), servo (N, 2) each trial's bandwidth [rad/s] and
    torque limit [N m], initial (N, 4) th(0) and u1(0) (``plant.dynamic_initial`` completes
    the state); trace (N, n+1, 10) if record (``DYNAMIC_TRACE_COLUMNS``)."""
    n = theta_ref.shape[0] - 1
    nx = DYNAMIC_STATE
    work = np.empty((WORK_ROWS, nx + DYNAMIC_AUX))
    acc = np.empty(ACCUMULATOR_SIZE)
    noise = np.zeros(3)
    flag = np.empty(6)
    scratch = np.empty((0, nx + 3))
    x0 = np.empty(nx)
    obs = (theta_ref, ref, threshold)
    for i in range(links.shape[0]):
        p = _links_row(links, i)
        loop = dynamic_loop(kc, gains, p, robot, servo_is_plant, h0[i], rate_limit,
                            servo[i, 0], servo[i, 1])
        dynamic_initial(loop, initial[i], ref[0], x0)
        reset_accumulator(acc)
        tr = trace[i] if record else scratch
        if method == _METHOD_RK4:
            last, ev, t_ev = _rk4_dynamic(loop, obs, x0, ref, dt, n, bound, tables[i], gen,
                                          std, record, tr, acc, work, noise)
            estimate, steps, evaluations = math.nan, last, 4 * last + 1
        else:
            last, ev, t_ev, estimate, steps, evaluations = _adaptive_dynamic(
                loop, obs, x0, breaks, local, dt, n, bound, rtol, atol, max_steps, 3,
                tables[i], gen, std, record, tr, acc, work, noise, flag, ref)
        _conclude(i, p, h0[i], plan_theta, plan_theta_dot, acc, last, n, ev, t_ev, estimate,
                  steps, evaluations, dt, record, tr, metrics, status, event, event_time)


@kernel
def _dynamic_rhs_kernel(loop: DynamicLoop, x: Array, ref: Array, noise: Array) -> Array:
    out = np.empty(DYNAMIC_STATE + DYNAMIC_AUX)
    dynamic_rhs(loop, x, ref, noise, out)
    return out


@kernel
def _dynamic_rhs_at(
    loop: DynamicLoop, breaks: Array, local: Array, t: float, x: Array, noise: Array
) -> Array:
    """The dynamic plant's state derivative (7,) at time t (for solve_ivp)."""
    ref = np.empty(6)
    plan_flag(breaks, local, t, ref)
    out = np.empty(DYNAMIC_STATE + DYNAMIC_AUX)
    dynamic_rhs(loop, x, ref, noise, out)
    return out[:DYNAMIC_STATE]


@kernel
def _dynamic_start(loop: DynamicLoop, initial: Array, ref: Array) -> Array:
    """The dynamic plant's state at t = 0 (``plant.dynamic_initial``)."""
    x0 = np.empty(DYNAMIC_STATE)
    dynamic_initial(loop, initial, ref, x0)
    return x0


@kernel
def _make_dynamic_loop(kc: Coefficients, gains: Gains, links: Links, robot: Links,
                       servo_is_plant: bool, h0: float, rate_limit: float, bandwidth: float,
                       torque_limit: float) -> DynamicLoop:
    return dynamic_loop(kc, gains, links, robot, servo_is_plant, h0, rate_limit, bandwidth,
                        torque_limit)


@kernel
def _observe_dynamic_trace_kernel(
    loop: DynamicLoop, theta_ref: Array, ref: Array, threshold: float, states: Array,
    rates: Array, last: int, complete: bool, dt: float, plan_theta: Array,
    plan_theta_dot: Array, out: Array,
) -> int:
    """``_observe_trace_kernel`` for the dynamic plant: states (n+1, 7), right-hand sides
    (n+1, 7 + DYNAMIC_AUX)."""
    acc = np.empty(ACCUMULATOR_SIZE)
    reset_accumulator(acc)
    obs = (theta_ref, ref, threshold)
    for j in range(last + 1):
        _observe_dynamic(loop, obs, acc, j, states[j], rates[j])
    residual = plan_momentum_residual(plan_theta, plan_theta_dot, loop.links, loop.h0)
    return finish_metrics(out, acc, complete, dt, residual, math.nan, 0, 0)


@kernel
def _kinematic_rhs_kernel(loop: Loop, x: Array, ref: Array, noise: Array) -> Array:
    out = np.empty(KINEMATIC_STATE + KINEMATIC_AUX)
    kinematic_rhs(loop, x, ref, noise, out)
    return out


@kernel
def _kinematic_rhs_at(
    loop: Loop, breaks: Array, local: Array, t: float, x: Array, noise: Array
) -> Array:
    """The state's derivative (4,) at time t, the plan evaluated there (for solve_ivp)."""
    ref = np.empty(6)
    plan_flag(breaks, local, t, ref)
    out = np.empty(KINEMATIC_STATE + KINEMATIC_AUX)
    kinematic_rhs(loop, x, ref, noise, out)
    return out[:KINEMATIC_STATE]


@kernel
def _observe_trace_kernel(
    loop: Loop, theta_ref: Array, ref: Array, threshold: float, states: Array, rates: Array,
    last: int, complete: bool, dt: float, plan_theta: Array, plan_theta_dot: Array,
    out: Array,
) -> int:
    """Metrics of a trace computed elsewhere (the reference integrator): states (n+1, 4) and
    right-hand sides (n+1, 4 + KINEMATIC_AUX), samples 0..last."""
    acc = np.empty(ACCUMULATOR_SIZE)
    reset_accumulator(acc)
    obs = (theta_ref, ref, threshold)
    for j in range(last + 1):
        _observe_kinematic(loop, obs, acc, j, states[j], rates[j])
    residual = plan_momentum_residual(plan_theta, plan_theta_dot, loop.links, loop.h0)
    return finish_metrics(out, acc, complete, dt, residual, math.nan, 0, 0)


@dataclass(frozen=True)
class Scenario:
    """What every trial of a batch shares: the plan, the controller and the time grid.

    Attributes
    ----------
    plan : FlatPlan (the paper's robot) or ChainPlan (N links), also the controller's model
    gains : Gains, or ChainGains for a ChainPlan
    dt : output sampling step [s] (the trace, the metrics, track.parquet; also RK4's step);
        must divide the plan's duration
    rate_limit : joint-rate limit [rad/s]; inf for none
    singular_threshold : margin below which a sample counts as a singularity hit [rad/s]
    divergence_bound : a state component beyond it (or non-finite) stops the trial
    plan_samples : size of the plan's own grid, on which ``plan_momentum_residual`` is taken
    rtol, atol : the adaptive integrator's relative and absolute tolerances
    max_steps : the adaptive integrator's budget of attempted steps per trial
    plant : "kinematic" or "dynamic" (``plant.PLANT_MODELS``)
    servo_model : what the dynamic plant's servo believes: "robot" (the plan's robot, the
        nominal model) or "plant" (each trial's plant)
    """

    plan: FlatPlan | ChainPlan
    gains: Gains | ChainGains
    dt: float
    rate_limit: float = math.inf
    singular_threshold: float = 1e-2
    divergence_bound: float = 1e4
    plan_samples: int = 201
    rtol: float = DEFAULT_RTOL
    atol: float = DEFAULT_ATOL
    max_steps: int = DEFAULT_MAX_STEPS
    plant: PlantModel = "kinematic"
    servo_model: ServoModel = "robot"
    n_steps: int = field(init=False)

    def __post_init__(self) -> None:
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise FlatcliError(f"track.dt: must be > 0 s, got {self.dt}")
        ratio = self.plan.duration / self.dt
        if not ratio <= MAX_STEPS_PER_TRIAL:
            raise FlatcliError(
                f"track.dt: plan.duration / track.dt = {ratio:.3g} output steps, more than the "
                f"{MAX_STEPS_PER_TRIAL:.0e} a trial may have; choose a larger track.dt"
            )
        steps = round(ratio)
        if steps < 2 or not math.isclose(steps * self.dt, self.plan.duration, rel_tol=1e-9):
            raise FlatcliError(
                f"track.dt: must divide plan.duration = {self.plan.duration:g} s into at "
                f"least 2 steps, got {self.dt:g} s"
            )
        if not self.rate_limit > 0:
            raise FlatcliError(f"track.rate_limit: must be > 0 rad/s, got {self.rate_limit}")
        if not self.singular_threshold >= 0:
            raise FlatcliError("track.singular_threshold: must be >= 0 rad/s")
        if not self.divergence_bound > 0:
            raise FlatcliError("track.divergence_bound: must be > 0")
        if not 0 < self.rtol < 1:
            raise FlatcliError(f"track.rtol: must be in (0, 1), got {self.rtol}")
        if not (self.atol > 0 and math.isfinite(self.atol)):
            raise FlatcliError(f"track.atol: must be a finite number > 0, got {self.atol}")
        if not self.max_steps >= 1:
            raise FlatcliError(f"track.max_steps: must be >= 1, got {self.max_steps}")
        if self.plant not in PLANT_MODELS:
            raise FlatcliError(
                f"plant.model: expected one of {list(PLANT_MODELS)}, got {self.plant!r}")
        if self.servo_model not in SERVO_MODELS:
            raise FlatcliError(f"plant.servo_model: expected one of {list(SERVO_MODELS)}, "
                               f"got {self.servo_model!r}")
        if isinstance(self.plan, ChainPlan):
            n = self.plan.n_joints
            if not (isinstance(self.gains, ChainGains) and len(self.gains.kp) == n
                    and len(self.gains.kv) == n):
                raise FlatcliError(f"track.kp, track.kv: expected {n} gains each (one per flat "
                                   f"output) for a robot of {n} joints")
        elif not isinstance(self.gains, Gains):
            raise FlatcliError("track.kp, track.kv: expected 2 gains each for the three-link "
                               "robot")
        object.__setattr__(self, "n_steps", steps)

    @property
    def n_joints(self) -> int:
        """N: 2 for the paper's robot."""
        return self.plan.n_joints if isinstance(self.plan, ChainPlan) else 2

    def prepared(self) -> Scenario:
        """This scenario with its reference tables computed (before shipping it to workers)."""
        _ = self.reference, self.theta_reference, self.plan_on_own_grid, self.pieces
        return self

    @property
    def times(self) -> Array:
        """(n + 1,) the grid t_j = j dt [s]."""
        return np.arange(self.n_steps + 1, dtype=float) * self.dt

    @cached_property
    def reference(self) -> Array:
        """(2 n + 1, 6) plan y1, y2, y1', y2', y1'', y2'' at half steps j dt / 2."""
        t = np.arange(2 * self.n_steps + 1, dtype=float) * (0.5 * self.dt)
        traj = self.plan.trajectory
        out = np.hstack([traj.derivative(t, 0), traj.derivative(t, 1), traj.derivative(t, 2)])
        return np.ascontiguousarray(out)

    @cached_property
    def theta_reference(self) -> Array:
        """(n + 1, 3) plan angles on the output grid [rad]."""
        return np.ascontiguousarray(self.plan.sample(self.times).theta)

    @cached_property
    def plan_on_own_grid(self) -> tuple[Array, Array]:
        """(plan_samples, 3) plan angles [rad] and their exact rates [rad/s]."""
        samples = self.plan.sample(self.plan.grid(self.plan_samples))
        return np.ascontiguousarray(samples.theta), np.ascontiguousarray(samples.theta_dot)

    @cached_property
    def pieces(self) -> tuple[Array, Array]:
        """The plan's flat outputs as piecewise polynomials (``Basis.piecewise``), which the
        adaptive integrator evaluates at its own times."""
        breaks, local = self.plan.trajectory.piecewise()
        return np.ascontiguousarray(breaks), np.ascontiguousarray(local)


@dataclass(frozen=True)
class NoiseStreams:
    """Sensor noise drawn per trial as the integrator goes: std [rad] times the normal
    variates of ``noise_generator(seed, trial)``, three per output interval, in order."""

    std: float
    seed: int
    trial_ids: NDArray[np.int64]


@dataclass(frozen=True)
class Trials:
    """What differs between trials: the plant, the initial state and the noise; N trials.

    Attributes
    ----------
    links : (N, 12) plant mass, inertia, length, com (see ``Links``)
    momentum : (N,) plant angular momentum H0 [kg m^2/s]
    initial : (N, 4) th0, th1, th2 [rad], u1 [rad/s] at t = 0
    noise : sensor noise on the three angles: an (N, n, 3) table [rad] (row j held over
        [t_j, t_j+1)), ``NoiseStreams``, or None for none
    servo : (N, 2) the dynamic plant's servo bandwidth [rad/s] (> 0) and torque limit [N m]
        (>= 0, inf for none) per trial, or None for the defaults (``DEFAULT_SERVO``); the
        kinematic plant ignores it
    """

    links: Array
    momentum: Array
    initial: Array
    noise: Array | NoiseStreams | None = None
    servo: Array | None = None

    def __post_init__(self) -> None:
        n = self.links.shape[0]
        width = self.links.shape[1] if self.links.ndim == 2 else 0
        joints = width // 4 - 1  # links: (4 (J + 1)) parameters per trial, J >= 2 joints
        if (
            width % 4 or joints < 2
            or self.momentum.shape != (n,)
            or self.initial.shape != (n, 2 * joints)
        ):
            raise ValueError("Trials: links (N, 4 (J + 1)), momentum (N,), initial (N, 2 J) "
                             "expected for J >= 2 joints")
        if isinstance(self.noise, NoiseStreams):
            if self.noise.trial_ids.shape != (n,):
                raise ValueError("Trials: noise streams need one trial id per trial")
            if not (self.noise.std >= 0 and math.isfinite(self.noise.std)):
                raise FlatcliError(f"track.sensor_noise: must be >= 0 rad, got {self.noise.std}")
        elif self.noise is not None and (self.noise.ndim != 3 or self.noise.shape[0] != n):
            raise ValueError("Trials: noise (N, n, 3) expected")
        if self.servo is not None:
            if self.servo.shape != (n, 2):
                raise ValueError("Trials: servo (N, 2) expected")
            bandwidth, torque = self.servo[:, 0], self.servo[:, 1]
            good = (bandwidth > 0) & np.isfinite(bandwidth)
            if not np.all(good):
                raise FlatcliError("plant.servo_bandwidth: must be a finite number > 0 rad/s, "
                                   f"got {bandwidth[~good][0]}")
            if not np.all(torque >= 0):
                raise FlatcliError("plant.torque_limit: must be >= 0 N m, got "
                                   f"{torque[~(torque >= 0)][0]}")

    @property
    def count(self) -> int:
        return int(self.links.shape[0])

    def subset(self, index: slice | NDArray[np.intp]) -> Trials:
        noise = self.noise
        if isinstance(noise, NoiseStreams):
            noise = NoiseStreams(noise.std, noise.seed, noise.trial_ids[index])
        elif noise is not None:
            noise = noise[index]
        servo = None if self.servo is None else self.servo[index]
        return Trials(self.links[index], self.momentum[index], self.initial[index], noise, servo)

    def servo_table(self) -> Array:
        """(N, 2) servo bandwidth [rad/s] and torque limit [N m] of every trial."""
        if self.servo is None:
            return np.tile(np.array(DEFAULT_SERVO, dtype=float), (self.count, 1))
        return np.ascontiguousarray(self.servo, dtype=float)

    def noise_table(self, index: int, n: int) -> Array:
        """(n, 3) the noise trial ``index`` sees [rad] (zeros without noise)."""
        if isinstance(self.noise, NoiseStreams):
            if self.noise.std == 0:
                return np.zeros((n, 3))
            gen = noise_generator(self.noise.seed, int(self.noise.trial_ids[index]))
            return self.noise.std * gen.standard_normal((n, 3))
        if self.noise is None:
            return np.zeros((n, 3))
        return np.asarray(self.noise[index], dtype=float)


@dataclass(frozen=True)
class Outcome:
    """Results of N trials.

    Attributes
    ----------
    metrics : (N, N_METRICS), columns ``metrics.Metric``
    status : (N,) ``metrics.Status`` codes
    event : (N,) ``metrics.Event`` that stopped each trial (``Event.NONE``: it finished)
    event_time : (N,) when it stopped, or the first singular hit of a finished trial [s]
        (nan if neither)
    trace : (N, n + 1, width) per output sample what ``columns`` names (the kinematic
        plant's state and applied rates, ``TRACE_COLUMNS``; the dynamic plant's state,
        torques and command, ``DYNAMIC_TRACE_COLUMNS``), nan after the last valid sample,
        if recorded
    columns : names of the trace's columns
    """

    metrics: Array
    status: NDArray[np.int64]
    event: NDArray[np.int64]
    event_time: Array
    trace: Array | None
    columns: tuple[str, ...] = TRACE_COLUMNS


def plant_coefficients(links: Array) -> Array:
    """(N, 11) derived constraint coefficients for (N, 12) plant parameters."""
    k = constraint_coefficients(Links(*np.asarray(links, dtype=float).T), "derived")
    return np.ascontiguousarray(np.stack(np.broadcast_arrays(*k), axis=-1))


def _plain(k: Coefficients) -> Coefficients:
    return Coefficients(*(float(v) for v in k))


def simulate(
    scenario: Scenario,
    trials: Trials,
    integrator: Integrator = "adaptive",
    record: bool = False,
) -> Outcome:
    """Run N closed-loop trials of a scenario.

    Parameters
    ----------
    scenario : Scenario
    trials : Trials (N)
    integrator : "adaptive", "rk4" or "dop853" (see the module docstring)
    record : keep each trial's trace

    Returns
    -------
    Outcome
    """
    if integrator not in INTEGRATORS:
        raise FlatcliError(
            f"track.integrator: expected one of {list(INTEGRATORS)}, got {integrator!r}"
        )
    n = scenario.n_steps
    angles = scenario.n_joints + 1
    if isinstance(trials.noise, np.ndarray) and trials.noise.shape[1:] != (n, angles):
        raise ValueError(f"Trials: noise must be (N, {n}, {angles}) for this scenario")
    if trials.links.shape[1] != 4 * angles:
        raise ValueError(f"Trials: links (N, {4 * angles}) expected for this scenario")
    N = trials.count
    metrics = np.empty((N, N_METRICS))
    status = np.zeros(N, dtype=np.int64)
    event = np.zeros(N, dtype=np.int64)
    event_time = np.full(N, math.nan)
    dynamic = scenario.plant == "dynamic"
    if isinstance(scenario.plan, ChainPlan):
        columns = (chain_dynamic_trace_columns if dynamic else chain_trace_columns)(
            scenario.plan.n_joints)
    else:
        columns = DYNAMIC_TRACE_COLUMNS if dynamic else TRACE_COLUMNS
    width = len(columns)
    trace = np.empty((N, n + 1, width)) if record else np.empty((0, 0, width))
    if isinstance(scenario.plan, ChainPlan):
        if integrator == "dop853":
            raise FlatcliError("track.integrator: \"dop853\" is the reference of the three-link "
                               "robot; use \"adaptive\" or \"rk4\" for N > 2 links")
        method = _METHOD_RK4 if integrator == "rk4" else _METHOD_ADAPTIVE
        chain_runner = run_chain_dynamic_kernel if dynamic else run_chain_kernel

        def run_chain(rows: slice, tables: Array, gen: np.random.Generator, std: float) -> None:
            chain_runner(scenario, trials, method, record, metrics, status, event, event_time,
                         trace, rows, tables, gen, std)

        _run_with_noise(run_chain, trials, angles)
        return Outcome(metrics, status, event, event_time, trace if record else None, columns)
    kc = _plain(scenario.plan.coefficients)
    assert isinstance(scenario.gains, Gains)  # Scenario checks it against the plan
    gains = Gains(*(float(v) for v in scenario.gains))
    plant_k = plant_coefficients(trials.links)
    links = np.ascontiguousarray(trials.links, dtype=float)
    h0 = np.ascontiguousarray(trials.momentum, dtype=float)
    initial = np.ascontiguousarray(trials.initial, dtype=float)
    servo = trials.servo_table()
    robot = Links(*(float(v) for v in scenario.plan.robot.links))
    servo_is_plant = scenario.servo_model == "plant"
    if integrator == "dop853":
        for i in range(N):
            _reference_trial(scenario, trials, plant_k, kc, gains, i, metrics[i], status,
                             event, event_time, trace[i] if record else None)
        return Outcome(metrics, status, event, event_time, trace if record else None, columns)
    method = _METHOD_RK4 if integrator == "rk4" else _METHOD_ADAPTIVE
    plan_theta, plan_theta_dot = scenario.plan_on_own_grid
    breaks, local = scenario.pieces

    def run(rows: slice, tables: Array, gen: np.random.Generator, std: float) -> None:
        if dynamic:
            _dynamic_kernel(
                method, kc, gains, robot, servo_is_plant, links[rows], h0[rows], servo[rows],
                float(scenario.rate_limit), initial[rows], scenario.reference,
                scenario.theta_reference, breaks, local, plan_theta, plan_theta_dot,
                float(scenario.dt), float(scenario.divergence_bound),
                float(scenario.singular_threshold), float(scenario.rtol),
                float(scenario.atol), int(scenario.max_steps), tables, gen, std, record,
                metrics[rows], status[rows], event[rows], event_time[rows],
                trace[rows] if record else trace,
            )
            return
        _kinematic_kernel(
            method, kc, gains, links[rows], plant_k[rows], h0[rows], float(scenario.rate_limit),
            initial[rows], scenario.reference, scenario.theta_reference, breaks, local,
            plan_theta, plan_theta_dot, float(scenario.dt), float(scenario.divergence_bound),
            float(scenario.singular_threshold), float(scenario.rtol), float(scenario.atol),
            int(scenario.max_steps), tables, gen, std, record, metrics[rows], status[rows],
            event[rows], event_time[rows], trace[rows] if record else trace,
        )

    _run_with_noise(run, trials, angles)
    return Outcome(metrics, status, event, event_time, trace if record else None, columns)


def _run_with_noise(run: Callable[[slice, Array, np.random.Generator, float], None],
                    trials: Trials, angles: int) -> None:
    """Call a kernel over the trials with their noise: streamed noise one trial at a time
    (each has its own generator), a table or none all at once."""
    quiet = np.random.default_rng(0)  # drawn from only when std > 0 and no table is given
    noise = trials.noise
    if isinstance(noise, NoiseStreams) and noise.std > 0:
        none = np.zeros((1, 0, angles))
        for i in range(trials.count):
            run(slice(i, i + 1), none, noise_generator(noise.seed, int(noise.trial_ids[i])),
                float(noise.std))
    else:
        tables = np.ascontiguousarray(noise, dtype=float) if isinstance(noise, np.ndarray) \
            else np.zeros((trials.count, 0, angles))
        run(slice(0, trials.count), tables, quiet, 0.0)


def _reference_trial(
    scenario: Scenario, trials: Trials, plant_k: Array, kc: Coefficients, gains: Gains, i: int,
    out: Array, status: NDArray[np.int64], event: NDArray[np.int64], event_time: Array,
    trace: Array | None,
) -> None:
    """Trial i by solve_ivp (DOP853), with terminal events on the divergence bound and on the
    controller's margin changing sign; its metrics from the same observer as the kernels."""
    n = scenario.n_steps
    times = scenario.times
    p = Links(*(float(v) for v in trials.links[i]))
    dynamic = scenario.plant == "dynamic"
    noise = trials.noise_table(i, n)
    bound = scenario.divergence_bound
    breaks, local = scenario.pieces
    loop: Any  # Loop or DynamicLoop, with the kernels below that take it
    rhs_at: Any
    rhs_full: Any
    if dynamic:
        bandwidth, torque_limit = trials.servo_table()[i]
        robot = Links(*(float(v) for v in scenario.plan.robot.links))
        loop = _make_dynamic_loop(kc, gains, p, robot, scenario.servo_model == "plant",
                                  float(trials.momentum[i]), float(scenario.rate_limit),
                                  float(bandwidth), float(torque_limit))
        nx, aux, u1_index = DYNAMIC_STATE, DYNAMIC_AUX, 6
        rhs_at, rhs_full = _dynamic_rhs_at, _dynamic_rhs_kernel
        start = np.asarray(_dynamic_start(loop, np.asarray(trials.initial[i], dtype=float),
                                          scenario.reference[0]))
    else:
        kq = _plain(Coefficients(*plant_k[i]))
        loop = Loop(kc, gains, kq, p, p.m0 + p.m1 + p.m2, float(trials.momentum[i]),
                    float(scenario.rate_limit), bool(_is_flat(kq)))
        nx, aux, u1_index = KINEMATIC_STATE, KINEMATIC_AUX, 3
        rhs_at, rhs_full = _kinematic_rhs_at, _kinematic_rhs_kernel
        start = np.asarray(trials.initial[i], dtype=float)

    def rhs(t: float, x: Array, noise_row: Array) -> Array:
        return np.asarray(rhs_at(loop, breaks, local, t, x, noise_row))

    def blowup(t: float, x: Array, noise_row: Array) -> float:
        return float(bound - np.max(np.abs(x)))

    def crossing(t: float, x: Array, noise_row: Array) -> float:
        return float(np.sin(x[1] + noise_row[1]) * x[u1_index])

    blowup.terminal = True  # type: ignore[attr-defined]
    crossing.terminal = True  # type: ignore[attr-defined]
    states = np.full((n + 1, nx), math.nan)
    states[0] = start
    stopped, when = int(Event.NONE), math.nan
    # without noise one integration over the whole grid; with noise one per interval, so the
    # solver never steps across a jump of the measured angles
    segments = [(0, n)] if not np.any(noise) else [(s, s + 1) for s in range(n)]
    x = start
    for begin, stop in segments:
        with np.errstate(all="ignore"):
            sol = solve_ivp(rhs, (times[begin], times[stop]), x, method="DOP853",
                            t_eval=times[begin: stop + 1], rtol=REFERENCE_RTOL,
                            atol=REFERENCE_ATOL, args=(noise[begin],),
                            events=[blowup, crossing])
        got = sol.y.T
        states[begin: begin + len(got)] = got
        if sol.status == 1:  # a terminal event; crossing the singular set takes precedence
            if len(sol.t_events[1]):
                stopped, when = int(Event.CROSSED), float(sol.t_events[1][0])
            else:
                stopped, when = int(Event.BOUND), float(sol.t_events[0][0])
            break
        if sol.status == -1 or len(got) < stop - begin + 1:  # the solver gave up
            last_x = sol.y[:, -1] if sol.y.size else x
            near = abs(crossing(float(sol.t[-1]) if sol.t.size else times[begin], last_x,
                                noise[begin])) < STALL_MARGIN
            stopped = int(Event.STALLED if near else Event.STEP_FLOOR)
            when = float(sol.t[-1]) if sol.t.size else float(times[begin])
            break
        x = got[-1]
    finite = np.isfinite(states).all(axis=1) & (np.abs(states) <= bound).all(axis=1)
    last = int(np.argmin(finite)) - 1 if not finite.all() else n
    if stopped == int(Event.NONE) and last < n:
        stopped, when = int(Event.BOUND), float(times[last + 1])
    rates = np.full((n + 1, nx + aux), math.nan)
    for j in range(last + 1):
        ref = scenario.reference[2 * j]
        rates[j] = rhs_full(loop, states[j], ref, noise[min(j, n - 1)])
    theta_ref = scenario.theta_reference
    plan_theta, plan_theta_dot = scenario.plan_on_own_grid
    observe = _observe_dynamic_trace_kernel if dynamic else _observe_trace_kernel
    first = observe(loop, theta_ref, scenario.reference, float(scenario.singular_threshold),
                    states, rates, last, stopped == int(Event.NONE), float(scenario.dt),
                    plan_theta, plan_theta_dot, out)
    code = Status.SINGULAR if first >= 0 else Status.OK
    if stopped != int(Event.NONE):
        code = Event(stopped).status
    status[i] = int(code)
    event[i] = stopped
    if stopped != int(Event.NONE):
        event_time[i] = when
    elif first >= 0:
        event_time[i] = first * scenario.dt
    if trace is not None:
        trace[:, :nx] = states
        trace[:, nx:] = rates[:, [AUX_TAU1, AUX_TAU2, AUX_R2]] if dynamic else rates[:, :3]
        trace[last + 1:] = math.nan
