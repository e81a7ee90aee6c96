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
  (events on the divergence bound and on the margin's sign; ``reference``).

Two plants (``Scenario.plant``, ``PLANT_MODELS``): the kinematic plant (joints follow
their commanded rates) and the dynamic plant (a robot with inertia, joint torques from rate
servos; ``plant``), through the same integrators. The dynamic plant's servo bandwidth and
torque limit may differ per trial (``Trials.servo``).

Every trial is integrated alone by the same compiled code, so its result does not depend on
which other trials share the batch, the order, the worker or the executor (bit for bit).
The compiled batch kernels are made by ``kernels`` from a law's part and a plant's
(``base``; the paper's robot's closed forms among them); this module holds the
public API and chooses among them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.controllers import rest
from flatcli.core.controllers.control import Gains
from flatcli.core.controllers.lqr import LqrWeights, tracked
from flatcli.core.controllers.python import continuous
from flatcli.core.controllers.settings import SETTINGS
from flatcli.core.curves.pieces import PiecewiseCurves
from flatcli.core.errors import FlatcliError
from flatcli.core.loop.compose import SampledShared
from flatcli.core.loop.kernels import (
    ADAPTIVE,
    RK4,
    Grid,
    Kernels,
    Results,
    Settings,
    TrialArrays,
)
from flatcli.core.loop.metrics import N_METRICS, Metric, Status
from flatcli.core.loop.outcome import CLEARANCE_BATCH, Geometry, MotionClearance, motion_clearance
from flatcli.core.loop.reference import reference_trial
from flatcli.core.loop.table import SAMPLED, kernels_for
from flatcli.core.names import (
    CONTROLLERS,
    DEFAULT_ACCURACY,
    DEFAULT_ATOL,
    DEFAULT_MAX_STEPS,
    DEFAULT_RTOL,
    DEFAULT_SERVO_BANDWIDTH,
    INTEGRATORS,
    PLANT_MODELS,
    SERVO_MODELS,
    Controller,
    Integrator,
    PlantModel,
    ServoModel,
)
from flatcli.core.plan.planning import Plan
from flatcli.core.plan.rest import RestPlan
from flatcli.core.plants.paper import plant_arrays

Array = NDArray[np.float64]
#: The integrators that control their error (``Outcome.verified``).
ERROR_CONTROLLED: tuple[Integrator, ...] = ("adaptive", "dop853")

#: Columns of a trace: the kinematic plant's state, then the joint rates it applies.
TRACE_COLUMNS: tuple[str, ...] = (
    "theta0", "theta1", "theta2", "u1", "theta0_dot", "theta1_dot", "theta2_dot",
)  # fmt: skip
def trace_columns(scenario: Scenario) -> tuple[str, ...]:
    """The trace columns of a scenario's trials (``Outcome.columns``): the plant's, then for
    a sampled controller (the MPC) the correction it holds: around the flat law dv1..dvN
    [rad/s^2], added to y''; around the as-built law dw1..dwN [rad/s], added to the
    joint-rate commands."""
    columns = chain_dynamic_trace_columns if scenario.plant == "dynamic" else chain_trace_columns
    name = "dv" if scenario.law == "flat" else "dw"
    held = tuple(f"{name}{j}" for j in range(1, scenario.n_joints + 1)) \
        if scenario.sampled is not None else ()
    return (*columns(scenario.n_joints), *held)


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

#: The factor on the tolerances of the twin that estimates a trial's error (``Scenario.twin``).
TWIN_FACTOR = 0.01
#: The twin's relative tolerance is not set below this (100 x float64's epsilon, as scipy's
#: solve_ivp); where that leaves it above TWIN_USEFUL x the trial's, there is no estimate.
TWIN_RTOL_FLOOR = 100 * float(np.finfo(float).eps)
TWIN_USEFUL = 0.5
#: Most output intervals (duration / dt) a scenario may have: its reference tables take
#: 112 bytes per interval, and every trial observes every sample.
MAX_STEPS_PER_TRIAL = 10_000_000

#: spawn_key slot of a trial's sensor-noise stream: SeedSequence(seed, (trial, NOISE_SLOT)).
NOISE_SLOT = 1
#: A trial's servo when ``Trials.servo`` is None: bandwidth [rad/s], torque limit [N m].
DEFAULT_SERVO = (DEFAULT_SERVO_BANDWIDTH, math.inf)


def noise_generator(seed: int, trial: int) -> np.random.Generator:
    """The sensor-noise stream of one trial: ``default_rng(SeedSequence(seed, (trial, 1)))``,
    independent of every other trial and of chunking."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(trial, NOISE_SLOT)))


#: Why the flat controller cannot track an exact plan (``Scenario``; the command line says it
#: before planning: ``experiment.run_track``).
FLAT_ON_EXACT = ("track.controller: \"flat\" tracks the closed-form flat outputs, which an "
                 "exact plan (plan.method) does not have: use track.controller = \"asbuilt\"")


#: Why a rest task is not tracked on the dynamic plant (``Scenario``): measured 2026-12-06 on
#: capture.toml from 2e-3 rad off its start (servo 100 rad/s knowing the plant): the law met
#: its singular set at t = 1.9926 s of 2 s, where a DOP853 of the same law stalls too.
REST_ON_DYNAMIC = ("plant.model: a rest-to-rest task (task.rest) is tracked on the kinematic "
                   "plant only: on the dynamic plant the servos' lag leaves u1 off the plan's "
                   "where the fade-out begins, and the faded law meets its singular set just "
                   "before T (u1 reaches 0 while w > 0)")


@dataclass(frozen=True)
class Scenario:
    """What every trial of a batch shares: the plan, the controller and the time grid.

    Attributes
    ----------
    plan : Plan, whose model the controller believes
    gains : Gains, one kp and kv per flat output
    dt : output sampling step [s] (the trace, the metrics, track.parquet; also RK4's step);
        must divide the plan's duration
    rate_limit : joint-rate limit [rad/s]; inf for none
    singular_threshold : margin below which a sample counts as a singularity hit [rad/s]
    divergence_bound : a state component beyond it (or non-finite) stops the trial
    plan_samples : size of the plan's own grid, on which ``plan_momentum_residual`` is taken
    rtol, atol : the adaptive integrator's relative and absolute tolerances
    max_steps : the adaptive integrator's budget of attempted steps per trial
    plant : "kinematic" or "dynamic" (``PLANT_MODELS``)
    servo_model : what the dynamic plant's servo believes: "robot" (the plan's robot, the
        nominal model) or "plant" (each trial's plant)
    controller : "flat" (the linearising feedback with ``gains``), "asbuilt" (the LQR of
        ``lqr``, designed on the plan's robot with ``lqr``; ``gains`` unused) or "mpc" (model
        predictive control with ``mpc`` wrapping the flat law with ``mpc``'s own gains on a
        flat plan, or the as-built law on an exact plan: ``law``; ``gains`` unused)
    lqr : the as-built law's weights (``lqr.LqrWeights``)
    settings : controllers' settings records by ``track.controller`` (``controllers.settings.
        SETTINGS``: the MPC's ``MpcSettings``); one not given has its record's defaults
        (``settings_for``)
    python : a controller written in Python (``controllers.python``), or None: acting at
        sample instants around the law ``controller`` names ("flat" or "asbuilt"), or, with a
        ``command`` method, in place of the flat law at every evaluation (the paper's robot,
        kinematic plant); it runs with the "dop853" integrator only
    servo_bandwidth : the dynamic plant's nominal servo bandwidth [rad/s], the lag the
        as-built law is designed for there
    torque_replanned : the MPC tracks a plan re-planned within the dynamic plant's torque
        limit (``experiment.mpc_reference``) with no rate limit: its inner gains are then
        ``mpc.TORQUE_INNER_KP``, ``TORQUE_INNER_KV``
    torque_kept : the joint-torque limit the MPC keeps on the dynamic plant [N m]
        (``experiment.mpc_kept_torque``: the cell's ``plant.torque_limit`` (1 -
        ``track.mpc_backoff``); inf: none): the flat law's MPC bounds its servo's predicted
        torques by it (``mpc.servo_torques``); each trial's plant clips at its own
        (``Trials.servo``)
    twin : the adaptive integrator's error estimate: each trial reaching T is integrated a
        second time at its tolerances times this factor in (0, 1) (``kernels.make_batch``;
        not below ``TWIN_RTOL_FLOOR``); 0 for no estimate (``err_estimate`` null)
    accuracy : the largest err_estimate of a verified trial [rad] (``Outcome.verified``)
    observe_every : the metrics observe every k-th output sample and the last (1: every one;
        ``integrate.observed``); the trace, when recorded, keeps every sample
    fade : a rest plan's (``RestPlan``) fade f in (0, 1/2] (``task.fade``): the flat law's
        feedback fades in over the first f T and out over the last (``controllers.rest``;
        the kinematic plant only, ``REST_ON_DYNAMIC``)
    """

    plan: Plan
    gains: Gains
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
    controller: Controller = "flat"
    lqr: LqrWeights = field(default_factory=LqrWeights)
    settings: Mapping[str, Any] = field(default_factory=dict)
    python: Any = None
    servo_bandwidth: float = DEFAULT_SERVO_BANDWIDTH
    torque_replanned: bool = False
    torque_kept: float = math.inf
    twin: float = TWIN_FACTOR
    accuracy: float = DEFAULT_ACCURACY
    observe_every: int = 1
    fade: float = 0.2
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
        if not self.accuracy > 0:
            raise FlatcliError(f"track.accuracy: must be > 0 rad, got {self.accuracy}")
        every = self.observe_every
        if isinstance(every, bool) or not isinstance(every, int | np.integer) or every < 1:
            raise FlatcliError(f"track.observe_every: must be an integer >= 1, got "
                               f"{self.observe_every!r}")
        if not (self.twin == 0 or 0 < self.twin < 1):
            raise FlatcliError(f"track.error_estimate: the twin's factor must be 0 (none) or "
                               f"in (0, 1), got {self.twin}")
        if self.plant not in PLANT_MODELS:
            raise FlatcliError(
                f"plant.model: expected one of {list(PLANT_MODELS)}, got {self.plant!r}")
        if self.servo_model not in SERVO_MODELS:
            raise FlatcliError(f"plant.servo_model: expected one of {list(SERVO_MODELS)}, "
                               f"got {self.servo_model!r}")
        if self.controller not in CONTROLLERS:
            raise FlatcliError(f"track.controller: expected one of {list(CONTROLLERS)}, got "
                               f"{self.controller!r}")
        if self.controller == "flat" and self.plan.model.kind == "exact":
            raise FlatcliError(FLAT_ON_EXACT)
        if isinstance(self.plan, RestPlan):
            if self.controller != "flat" or self.python is not None:
                raise FlatcliError("track.controller: a rest-to-rest task (task.rest) is "
                                   "tracked by the flat law faded at the ends (\"flat\"), got "
                                   + (repr(self.controller) if self.python is None
                                      else "a controller written in Python"))
            if self.plant != "kinematic":
                raise FlatcliError(REST_ON_DYNAMIC)
            if not 0.0 < self.fade <= 0.5:
                raise FlatcliError(f"task.fade: must be in (0, 0.5], got {self.fade}")
        if self.controller in SETTINGS:  # FlatcliError naming the key, if one does not fit
            self.settings_for(self.controller).check(self.dt, self.plan.duration)
        if self.python is not None and self.controller in SAMPLED:
            raise FlatcliError("controller: a Python controller wraps track.controller = "
                               f"\"flat\" or \"asbuilt\", not {self.controller!r}")
        if continuous(self.python) and (self.controller != "flat" or self.plant != "kinematic"
                                        or self.plan.model.kind != "paper"):
            raise FlatcliError("controller: a controller with command() runs in place of the "
                               "flat law on the paper's robot (N = 2) and the kinematic plant "
                               "(track.controller = \"flat\", plant.model = \"kinematic\")")
        n = self.plan.n_joints
        if self.gains.n_outputs != n:
            raise FlatcliError(f"track.kp, track.kv: expected {n} gains each (one per flat "
                               f"output) for a robot of {n} joints, got {self.gains.n_outputs}")
        object.__setattr__(self, "n_steps", steps)

    def settings_for(self, controller: str) -> Any:
        """The settings record of a controller (``settings``, else its defaults)."""
        given = self.settings.get(controller)
        return SETTINGS[controller][0]() if given is None else given

    @property
    def sampled(self) -> str | None:
        """The controller acting at sample instants around the law: ``controller`` where it
        is one (``loop.table.SAMPLED``: "mpc"), "python" (a Python controller, ``python``)
        or None."""
        if self.controller in SAMPLED:
            return self.controller
        return "python" if self.python is not None and not continuous(self.python) else None

    @property
    def law(self) -> str:
        """The law whose reference the kernels track: "flat" (the plan's flat outputs) or
        "asbuilt" (its angles and the LQR's gains); a sampled controller (the MPC) wraps the
        flat law on a flat plan and the as-built law on an exact one; "command": a
        controller written in Python with ``command`` gives the flat law's commands."""
        if self.controller in SAMPLED:
            return "asbuilt" if self.plan.model.kind == "exact" else "flat"
        return "command" if continuous(self.python) else self.controller

    @cached_property
    def sampled_design(self) -> Any:
        """The sampled controller's design (its part's ``design``: the MPC's about the plan,
        a Python controller's sizes), once per scenario; None for the laws without
        samples."""
        if self.sampled is None:
            return None
        part = SAMPLED[self.sampled]
        return None if part.design is None else part.design(self)

    @property
    def inner_gains(self) -> Gains:
        """The flat law's gains: ``gains``, or the sampled controller's inner law's
        (``SampledPart.gains``: the MPC's track.mpc_kp, track.mpc_kv)."""
        part = SAMPLED[self.sampled] if self.sampled is not None else None
        if part is None or part.gains is None:
            return self.gains
        gains: Gains = part.gains(self)
        return gains

    @property
    def n_joints(self) -> int:
        """N: 2 for the paper's robot."""
        return self.plan.n_joints

    def prepared(self) -> Scenario:
        """This scenario with its reference tables computed (before shipping it to workers)."""
        _ = self.reference, self.theta_reference, self.plan_on_own_grid, self.pieces
        _ = self.sampled_design
        return self

    @cached_property
    def tracked(self) -> Any:
        """What the controller tracks, as curves y(t): the plan's flat outputs (the flat
        law; a rest plan's with the fade and its last joint's rate, ``rest.reference``), or
        the plan's angles and the as-built law's gains (``lqr.tracked``)."""
        if self.law == "asbuilt":
            servo = self.servo_bandwidth if self.plant == "dynamic" else None
            curves: PiecewiseCurves = tracked(self.plan, self.lqr, servo)
            return curves
        if isinstance(self.plan, RestPlan):  # its outputs, the fade, th_N's own rate
            return rest.reference(self.plan, self.fade)
        return self.plan.trajectory

    @property
    def times(self) -> Array:
        """(n + 1,) the grid t_j = j dt [s]."""
        return np.arange(self.n_steps + 1, dtype=float) * self.dt

    @cached_property
    def reference(self) -> Array:
        """(2 n + 1, 6) plan y1, y2, y1', y2', y1'', y2'' at half steps j dt / 2."""
        t = np.arange(2 * self.n_steps + 1, dtype=float) * (0.5 * self.dt)
        traj = self.tracked
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
        breaks, local = self.tracked.piecewise()
        return np.ascontiguousarray(breaks), np.ascontiguousarray(local)


@dataclass(frozen=True)
class NoiseStreams:
    """Sensor noise drawn per trial as the integrator goes: std [rad] times the normal
    variates of ``noise_generator(seed, trial)``, one per angle th0..thJ per output
    interval, in order."""

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
    noise : sensor noise on the angles th0..thJ: an (N, n, J + 1) table [rad] (row j held over
        [t_j, t_j+1)), ``NoiseStreams``, or None for none
    servo : (N, 2) the dynamic plant's servo bandwidth [rad/s] (> 0) and torque limit [N m]
        (>= 0, inf for none) per trial, or None for the defaults (``DEFAULT_SERVO``); the
        kinematic plant ignores it
    across : (N,) the plant's last link's centre of mass across the link, e_N [m]
        (``model.RobotParams.com_across``), or None for 0
    """

    links: Array
    momentum: Array
    initial: Array
    noise: Array | NoiseStreams | None = None
    servo: Array | None = None
    across: Array | None = None

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
        elif self.noise is not None and (self.noise.ndim != 3 or self.noise.shape[0] != n
                                         or self.noise.shape[2] != joints + 1):
            raise ValueError("Trials: noise (N, n, J + 1) expected")
        if self.across is not None and (self.across.shape != (n,)
                                        or not np.all(np.isfinite(self.across))):
            raise ValueError("Trials: across (N,) finite values expected")
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
        across = None if self.across is None else self.across[index]
        return Trials(self.links[index], self.momentum[index], self.initial[index], noise, servo,
                      across)

    def servo_table(self) -> Array:
        """(N, 2) servo bandwidth [rad/s] and torque limit [N m] of every trial."""
        if self.servo is None:
            return np.tile(np.array(DEFAULT_SERVO, dtype=float), (self.count, 1))
        return np.ascontiguousarray(self.servo, dtype=float)

    @property
    def angles(self) -> int:
        """Angles th0..thJ of the robot (J + 1 for J joints): a noise table's width."""
        return int(self.links.shape[1]) // 4

    def noise_table(self, index: int, n: int) -> Array:
        """(n, J + 1) the noise trial ``index`` sees on th0..thJ [rad] (zeros without
        noise): ``angles`` wide, as the kernels read it (a narrower table made them read
        past each row, a robot of three joints or more one angle beyond it)."""
        angles = self.angles
        if isinstance(self.noise, NoiseStreams):
            if self.noise.std == 0:
                return np.zeros((n, angles))
            gen = noise_generator(self.noise.seed, int(self.noise.trial_ids[index]))
            return self.noise.std * gen.standard_normal((n, angles))
        if self.noise is None:
            return np.zeros((n, angles))
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
    integrator : the integrator that ran them (``INTEGRATORS``)
    estimated : whether each trial reaching T had its error estimated (the adaptive
        integrator with a twin, ``Scenario.twin``); accuracy : the largest err_estimate of a
        verified trial [rad] (``Scenario.accuracy``)
    final : (N, N_joints + 1) the plant's angles th0..thN at t = T [rad], nan where a trial
        stopped before (None: not kept)
    clearance : the trials' clearance from the obstacles ``simulate`` was given, along their
        recorded motion (``outcome.motion_clearance``); None without obstacles
    extra : (N, E) the controller's own per-trial columns ``extra_columns`` (the MPC's
        ``mpc.COLUMNS``; E = 0 for the flat and as-built laws); extra_counts: those of
        them that count something (integers)
    """

    metrics: Array
    status: NDArray[np.int64]
    event: NDArray[np.int64]
    event_time: Array
    trace: Array | None
    columns: tuple[str, ...] = TRACE_COLUMNS
    integrator: Integrator = "adaptive"
    estimated: bool = False
    accuracy: float = math.inf
    final: Array | None = None
    clearance: MotionClearance | None = None
    extra: Array | None = None
    extra_columns: tuple[str, ...] = ()
    extra_counts: tuple[str, ...] = ()

    @cached_property
    def verified(self) -> NDArray[np.bool_]:
        """(N,) whether each trial's accuracy was verified: it was resolved to the end
        (``ok`` or ``singular``) by an integrator that controls its error
        (``ERROR_CONTROLLED``: every accepted step of the adaptive one met track.rtol and
        track.atol; DOP853 is the reference) and, where its error was estimated, its
        err_estimate is at most ``accuracy`` (a twin that failed leaves it unverified).
        Fixed-step RK4 has no tolerance: its trials are never verified, whatever their
        status."""
        resolved = (self.status == int(Status.OK)) | (self.status == int(Status.SINGULAR))
        if self.estimated:
            with np.errstate(invalid="ignore"):
                resolved &= self.metrics[:, Metric.ERR_ESTIMATE] <= self.accuracy
        return np.asarray(resolved & (self.integrator in ERROR_CONTROLLED), dtype=bool)

    def unverified(self, i: int) -> str:
        """Why resolved trial i is not verified, in one clause ("" if it is, or if it is not
        resolved: its status says what happened)."""
        resolved = int(self.status[i]) in (int(Status.OK), int(Status.SINGULAR))
        if not resolved or self.verified[i]:
            return ""
        if self.integrator not in ERROR_CONTROLLED:
            return (f"not verified: fixed-step {self.integrator} has no error control and no "
                    "err_estimate")
        estimate = float(self.metrics[i, Metric.ERR_ESTIMATE])
        if math.isnan(estimate):
            return ("not verified: its error could not be estimated (the twin at a hundredth "
                    "of the tolerances did not reach T)")
        return (f"not verified: err_estimate {estimate:.3g} rad exceeds track.accuracy "
                f"{self.accuracy:g} rad")


def plant_coefficients(links: Array) -> Array:
    """(N, 11) derived constraint coefficients for (N, 12) plant parameters."""
    return plant_arrays(np.ascontiguousarray(links, dtype=float), "kinematic")


def placements(links: Array, across: Array | None) -> tuple[Array, Array]:
    """Plants' parameters (T, 4 (N + 1)) of their equivalent placements (d_N = hypot(d_N, e_N))
    and the turn of their last link (T,) [rad] (``model.RobotParams.placement``) for their
    centres of mass across the last link ``across`` (T,) [m] (None: 0)."""
    params = np.ascontiguousarray(links, dtype=float)
    offset = np.zeros(params.shape[0])
    if across is None or not np.any(across != 0.0):
        return params, offset
    params = params.copy()
    nb = params.shape[1] // 4
    turned = across != 0.0
    d = params[turned, 4 * nb - 1]
    offset[turned] = np.arctan2(across[turned], d)
    params[turned, 4 * nb - 1] = np.hypot(d, across[turned])
    return params, offset


def kernel_inputs(scenario: Scenario, trials: Trials) -> tuple[
        Kernels, Any, TrialArrays, Grid, Settings]:
    """The kernels of a scenario's (model, plant) and everything they take but the noise,
    the buffers and the results."""
    plan = scenario.plan
    model = "asbuilt" if scenario.law == "asbuilt" else plan.model.kind
    kernels = kernels_for(scenario.sampled or scenario.law, model, scenario.plant)
    params, offset = placements(trials.links, trials.across)
    arrays = TrialArrays(params, np.ascontiguousarray(trials.momentum, dtype=float),
                         trials.servo_table(), np.ascontiguousarray(trials.initial, dtype=float),
                         np.ascontiguousarray(kernels.plant(params, scenario.plant)), offset)
    plan_theta, plan_theta_dot = scenario.plan_on_own_grid
    breaks, local = scenario.pieces
    grid = Grid(scenario.reference, scenario.theta_reference, breaks, local, plan_theta,
                plan_theta_dot)
    settings = Settings(float(scenario.dt), float(scenario.divergence_bound),
                        float(scenario.singular_threshold), float(scenario.rtol),
                        float(scenario.atol), int(scenario.max_steps), False,
                        twin_factor(scenario), int(scenario.observe_every))
    shared = kernels.shared(plan.model, scenario.inner_gains, scenario.rate_limit,
                            scenario.servo_model == "plant", plan.robot)
    if scenario.law == "asbuilt" and scenario.plant == "dynamic":
        shared = shared._replace(lead=1.0 / scenario.servo_bandwidth, lagged=True)
    if scenario.sampled is not None:
        shared = SampledShared(shared, scenario.sampled_design)
    return kernels, shared, arrays, grid, settings


def closed_loop_rhs(scenario: Scenario, trials: Trials, i: int = 0) -> Callable[..., Array]:
    """The compiled closed loop of trial i as a function f(t, x, noise=None) -> x' (the state's
    derivative, a new array; ``noise`` the measured angles' noise, default none), for an
    integrator written elsewhere (scipy's, in the tests and benchmarks)."""
    kernels, shared, arrays, grid, _ = kernel_inputs(scenario, trials)
    joints = scenario.n_joints
    nx = kernels.ops.state(joints)
    buffers = kernels.buffers(joints, grid.ref.shape[1], shared)
    out = np.empty(nx + kernels.ops.aux(joints))
    zero = np.zeros(joints + 1)
    rhs_at = kernels.single[1]

    def rhs(t: float, x: Array, noise: Array | None = None) -> Array:
        rhs_at(shared, arrays, i, grid, buffers, float(t), np.ascontiguousarray(x, dtype=float),
               zero if noise is None else np.ascontiguousarray(noise, dtype=float), out)
        return out[:nx].copy()

    return rhs


def twin_factor(scenario: Scenario) -> float:
    """The factor on the tolerances of a trial's twin (``Scenario.twin``), raised to keep the
    twin's rtol at ``TWIN_RTOL_FLOOR`` or more; 0 (no twin) where that would leave it above
    ``TWIN_USEFUL``."""
    if scenario.twin == 0:
        return 0.0
    factor = max(float(scenario.twin), TWIN_RTOL_FLOOR / float(scenario.rtol))
    return factor if factor <= TWIN_USEFUL else 0.0


def closed_loop_start(scenario: Scenario, trials: Trials, i: int = 0) -> Array:
    """The plant's state at t = 0 of trial i, as ``closed_loop_rhs`` integrates it (nx,): the
    kinematic plant's th, u1; the dynamic plant's th, th' (th1'(0) = u1(0), th2'(0) = the
    controller's first command) and u1."""
    kernels, shared, arrays, grid, _ = kernel_inputs(scenario, trials)
    joints = scenario.n_joints
    out = np.empty(kernels.ops.state(joints))
    kernels.single[0](shared, arrays, i, grid,
                      kernels.buffers(joints, grid.ref.shape[1], shared), out)
    return out


def simulate(
    scenario: Scenario,
    trials: Trials,
    integrator: Integrator = "adaptive",
    record: bool = False,
    obstacles: ArrayLike | None = None,
) -> Outcome:
    """Run N closed-loop trials of a scenario.

    Parameters
    ----------
    scenario : Scenario
    trials : Trials (N)
    integrator : "adaptive", "rk4" or "dop853" (see the module docstring)
    record : keep each trial's trace
    obstacles : (K, 3) discs x, y, radius [m]: compute each trial's clearance from them along
        its recorded motion (``Outcome.clearance``, ``outcome.motion_clearance``). Without
        ``record`` the trials are then recorded ``outcome.CLEARANCE_BATCH`` at a time and
        their traces let go (recording changes no number of a trial but ``rhs_evaluations``
        where ``track.observe_every`` > 1: every sample is then evaluated)

    Returns
    -------
    Outcome
    """
    if integrator not in INTEGRATORS:
        raise FlatcliError(
            f"track.integrator: expected one of {list(INTEGRATORS)}, got {integrator!r}"
        )
    n = scenario.n_steps
    joints = scenario.n_joints
    angles = joints + 1
    if isinstance(trials.noise, np.ndarray) and trials.noise.shape[1:] != (n, angles):
        raise ValueError(f"Trials: noise must be (N, {n}, {angles}) for this scenario")
    if trials.links.shape[1] != 4 * angles:
        raise ValueError(f"Trials: links (N, {4 * angles}) expected for this scenario")
    N = trials.count
    columns = trace_columns(scenario)
    width = len(columns)
    discs = None if obstacles is None else np.asarray(obstacles, dtype=float).reshape(-1, 3)
    if discs is not None and not len(discs):
        discs = None
    kernels, shared, arrays, grid, settings = kernel_inputs(scenario, trials)
    extra_columns = kernels.ops.extra_columns
    results = Results(np.empty((N, N_METRICS)), np.zeros(N, dtype=np.int64),
                      np.zeros(N, dtype=np.int64), np.full(N, math.nan),
                      np.empty((N, n + 1, width)) if record else np.empty((0, 0, width)),
                      np.full((N, angles), math.nan), np.full((N, len(extra_columns)), math.nan))
    if scenario.python is not None and integrator != "dop853":
        raise FlatcliError("track.integrator: a controller written in Python runs with "
                           "\"dop853\" only (its steps are Python calls between scipy's "
                           f"segments), got {integrator!r}")
    buffers = kernels.buffers(joints, grid.ref.shape[1], shared)
    geometry = Geometry.of(trials.links, trials.across) if discs is not None else None
    parts: list[MotionClearance] = []

    def run_range(lo: int, hi: int, trace: Array, keep: bool) -> None:
        """Trials lo..hi - 1, their traces into ``trace`` (hi - lo, n + 1, width) if ``keep``."""
        run_settings = settings._replace(record=keep)
        part_trials = trials.subset(slice(lo, hi))
        if integrator == "dop853":
            part = Results(results.metrics[lo:hi], results.status[lo:hi],
                           results.event[lo:hi], results.event_time[lo:hi], trace,
                           results.final[lo:hi], results.extra[lo:hi])
            for i in range(hi - lo):
                reference_trial(scenario, part_trials, kernels, shared,
                                TrialArrays(*(a[lo:hi] for a in arrays)), grid, run_settings, i,
                                part)
            return
        method = RK4 if integrator == "rk4" else ADAPTIVE

        def run(rows: slice, tables: Array) -> None:
            part = TrialArrays(*(a[lo:hi][rows] for a in arrays))
            out = Results(results.metrics[lo:hi][rows], results.status[lo:hi][rows],
                          results.event[lo:hi][rows], results.event_time[lo:hi][rows],
                          trace[rows] if keep else trace, results.final[lo:hi][rows],
                          results.extra[lo:hi][rows])
            kernels.batch(method, shared, part, grid, run_settings, tables, buffers, out)

        _run_with_noise(run, part_trials, n, angles)

    def clearance_of(lo: int, hi: int, trace: Array) -> MotionClearance:
        assert geometry is not None and discs is not None
        theta = trace[:, :, [columns.index(f"theta{k}") for k in range(angles)]]
        rates = trace[:, :, [columns.index(f"theta{k}_dot") for k in range(angles)]]
        return motion_clearance(geometry.subset(slice(lo, hi)), discs, theta, rates,
                                float(scenario.dt))

    if record:
        run_range(0, N, results.trace, True)
        if discs is not None:
            parts.append(clearance_of(0, N, results.trace))
    elif discs is None:
        run_range(0, N, results.trace, False)
    else:  # recorded a batch at a time for the clearance, the traces let go
        scratch = np.empty((min(N, CLEARANCE_BATCH), n + 1, width))
        for lo in range(0, N, CLEARANCE_BATCH):
            hi = min(lo + CLEARANCE_BATCH, N)
            run_range(lo, hi, scratch[: hi - lo], True)
            parts.append(clearance_of(lo, hi, scratch[: hi - lo]))
    return Outcome(results.metrics, results.status, results.event, results.event_time,
                   results.trace if record else None, columns, integrator,
                   integrator == "adaptive" and settings.twin > 0, float(scenario.accuracy),
                   results.final, MotionClearance.concatenate(parts) if parts else None,
                   results.extra, extra_columns, kernels.ops.extra_counts)


class ReferenceCheck(NamedTuple):
    """Trials run again by the reference integrator and compared (``check_against_reference``).

    difference : (N,) max over the output samples both runs reached (t = 0 at least) of the
        Euclidean norm of the difference of their angles th0..thN [rad]
    status : (N,) the reference's ``metrics.Status`` codes
    """

    difference: Array
    status: NDArray[np.int64]


#: Trials run at once by ``check_against_reference`` (each keeps two traces).
CHECK_BATCH = 16


def check_against_reference(scenario: Scenario, trials: Trials, integrator: Integrator
                            ) -> ReferenceCheck:
    """Run trials with ``integrator`` and with DOP853 (``reference.REFERENCE_RTOL``), both
    recording their traces (recording does not change a run: the same arithmetic, bit for
    bit), and compare the angles sample by sample; ``CHECK_BATCH`` trials at a time."""
    angles = scenario.n_joints + 1
    difference = np.full(trials.count, math.nan)
    status = np.zeros(trials.count, dtype=np.int64)
    for start in range(0, trials.count, CHECK_BATCH):
        rows = slice(start, min(start + CHECK_BATCH, trials.count))
        part = trials.subset(rows)
        ours = simulate(scenario, part, integrator, record=True)
        theirs = simulate(scenario, part, "dop853", record=True)
        assert ours.trace is not None and theirs.trace is not None
        gap = np.linalg.norm(ours.trace[:, :, :angles] - theirs.trace[:, :, :angles], axis=2)
        difference[rows] = np.nanmax(gap, axis=1)  # sample 0 is in both
        status[rows] = theirs.status
    return ReferenceCheck(difference, status)


def _run_with_noise(run: Callable[[slice, Array], None], trials: Trials, n: int,
                    angles: int) -> None:
    """Call a kernel over the trials with their noise: streamed noise one trial at a time
    (its table drawn from its own generator, ``Trials.noise_table``: the trial and its twin
    see the same noise), a table or none all at once."""
    noise = trials.noise
    if isinstance(noise, NoiseStreams) and noise.std > 0:
        for i in range(trials.count):
            run(slice(i, i + 1), np.ascontiguousarray(trials.noise_table(i, n)[None]))
    else:
        tables = np.ascontiguousarray(noise, dtype=float) if isinstance(noise, np.ndarray) \
            else np.zeros((trials.count, 0, angles))
        run(slice(0, trials.count), tables)
