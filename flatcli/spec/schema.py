"""The spec's schema: one frozen record per TOML table, each field one key.

A record's docstring starts with the one line the heading of its table in docs/spec.md
shows.

``[robot]``, ``[plan]``, ``[plan.optimize]``, ``[track]``, ``[plant]`` and ``[sweep]`` are the
records below; ``SpecRecord`` holds them and the top-level ``name``. A key is one line: its type,
its helper (``number``, ``integer``, ``vector``, ``choice``, ``flag``, ``text``, ``table``
from ``flatcli.spec.keys``) with default, doc, unit and bounds. ``SCHEMA`` is derived from
these records, and so are docs/spec.md's tables (``python -m flatcli.spec --markdown``).
Choices come from their one home: the core's ``MODELS``, ``OBJECTIVES`` and ``INTEGRATORS``.
A vector's length is a value of its key, checked like its bounds; the per-link, per-joint
and per-output keys follow the robot (``Key.size``): ``robot.mass`` sets the number N of
joints, and ``fit_sizes`` checks every other such key against it.

Records are built only by ``flatcli.spec.build`` (which validates every value first), so
every record in the program holds valid values.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import math
from collections.abc import Collection, Iterator, Mapping
from dataclasses import Field, dataclass, field, fields, is_dataclass
from typing import Any, TypeVar

from flatcli.core.controllers.settings import SETTINGS
from flatcli.core.names import (
    BASES,
    CONTROLLERS,
    DEFAULT_ACCURACY,
    DEFAULT_ATOL,
    DEFAULT_BASE,
    DEFAULT_MAX_STEPS,
    DEFAULT_RTOL,
    DEFAULT_SERVO_BANDWIDTH,
    ELBOWS,
    ERROR_ESTIMATES,
    FIGURE_FORMATS,
    GOAL_TOLERANCE,
    INTEGRATORS,
    METHODS,
    MODELS,
    OBJECTIVES,
    PLANT_MODELS,
    RATE_WARNING,
    SERVO_MODELS,
    TARGET_TOLERANCE,
)
from flatcli.spec.keys import (
    SIZES,
    Key,
    SpecError,
    choice,
    discs,
    flag,
    integer,
    number,
    numbers,
    settings_keys,
    suggest,
    table,
    text,
    vector,
)
from flatcli.spec.limits import MIN_RTOL
from flatcli.spec.searches import (
    APPLY,
    CENTRES,
    QUANTILE_METRICS,
    SEARCH_OBJECTIVES,
    VERDICT_REQUIREMENTS,
)
from flatcli.spec.tree import flatten

#: Numbers of a per-link vector of the paper's robot: links 0 (base), 1, 2. A robot of N
#: joints has N + 1 links (``robot.mass`` sets N); the per-link keys follow it.
LINKS = 3
#: Numbers of a gain vector of the paper's robot: one per flat output y1, y2 (N on N joints).
GAINS = 2
#: Sections that say how results are shown, not what is computed: they enter no digest, so
#: a sweep resumes and a run is "the same run" whatever figures it draws.
PRESENTATION = ("figures", "summary")
#: Sections that no trial reads (besides ``PRESENTATION``): a design search's. They enter no
#: sweep's digest, so ``flatcli sweep`` of a search spec is the sweep it would be without them.
OUTSIDE_TRIALS = ("search",)
INF = math.inf

Vector = tuple[float, ...]
S = TypeVar("S", bound="SpecRecord")


@dataclass(frozen=True)
class RobotSpec:
    """the nominal robot (what the planner and controller believe)"""

    mass: Vector = vector("links", (1.0, 1.0, 1.0), "link masses m0, m1, m2 (the base and N links: "
                          "their number sets the robot's N joints)", "kg", gt=0)
    inertia: Vector = vector("links", (0.0533, 0.0533, 0.0533),
                             "inertias about each link's centre of mass", "kg m^2", gt=0)
    length: Vector = vector("links", (0.2, 0.2, 0.2),
                            "link lengths, joint to joint (the last one, l_N, does not enter the "
                            "dynamics)", "m", gt=0)
    com: Vector = vector("links", (0.1, 0.1, 0.0),
                         "d_i, distance of each link's centre of mass from its proximal joint "
                         "(flat: d_N = 0)", "m")
    com_across: float = number(0.0, "e_N, how far the last link's centre of mass lies across "
                               "the link (perpendicular to it, towards increasing th_N; flat: "
                               "0; docs/asbuilt.md)", "m")
    model: str = choice(MODELS, "derived", "constraint coefficients: \"derived\" (correct) or "
                        "\"paper\" (the appendix as printed)")


@dataclass(frozen=True)
class OptimizeSpec:
    """optimised plans (off unless `objective` is set; `--optimize OBJECTIVE`)"""

    objective: str | None = choice(
        OBJECTIVES, None, "what to optimise (none: the plain plan): \"energy\" (integral of "
        "th1'^2 + ... + thN'^2), \"peak_rate\" (max of abs th1', ..., abs thN'), \"effort\" (T x "
        "energy), \"margin\" (maximise the minimum singularity margin)", nullable=True)
    angle_limit: Vector = vector("links", (INF, INF, INF), "bound on abs th_i along the plan (left "
                                 "out: none on every link)", "rad", gt=0, inf=True)
    rate_limit: float | Vector = numbers("joints", INF, "bound on abs th_j' along the plan (one "
                                         "for every joint, or one per joint)", "rad/s", gt=0,
                                         inf=True)
    min_margin: float = number(0.02, "lower bound on the signed margin along the plan (sin th1 * "
                               "th1' for N = 2, -(dh_0/dt) / (2 K_10) beyond: it never crosses the "
                               "singular set; 0 would let thN' spike without bound between the "
                               "check samples)", "rad/s", gt=0)
    free_rates: bool = flag(True, "optimise th1'(0) and th1'(T) as well (the plan's start_rate "
                            "and goal_rate are the starting guess)")
    constraint_samples: int = integer(201, "grid points where the limits are imposed", ge=10)
    max_iter: int = integer(300, "optimiser iteration limit", ge=1)


@dataclass(frozen=True)
class PlanSpec:
    """the point-to-point maneuver"""

    duration: float = number(2.0, "maneuver time T", "s", gt=0)
    start: Vector = vector("links", (1.8, 1.0, 0.0), "th0, th1, th2 (th0..thN) at t = 0", "rad")
    goal: Vector = vector("links", (1.2, 2.0, 0.0), "th0, th1, th2 (th0..thN) at t = T", "rad")
    start_rate: float | Vector = numbers("inner", 0.1, "th1'(0) (th1'..th_N-1'), a free end rate "
                                         "(non-zero)", "rad/s")
    goal_rate: float | Vector = numbers("inner", 0.5, "th1'(T) (th1'..th_N-1'), a free end rate "
                                        "(non-zero)", "rad/s")
    samples: int = integer(201, "points of the output time grid", ge=2)
    basis: str = choice(BASES, "auto", "flat-output basis: polynomials, clamped B-splines "
                        "(scipy), or auto: the paper's cubic, or quintic B-splines when "
                        "optimising")
    degree: int | None = integer(None, "polynomial or B-spline degree", ge=3, nullable=True,
                                 default_doc="3 (poly), 5 (bspline)")
    size: int = integer(12, "B-spline coefficients per output", ge=4)
    rate_warning: float = number(RATE_WARNING, "a plan whose joint rate abs(th_j') exceeds it "
                                 "on its grid (plan.samples) prints one warning line naming "
                                 "the joint, the peak and the time; a task plan picks end "
                                 "rates that keep below it where a candidate does", "rad/s",
                                 gt=0, inf=True)
    method: str = choice(METHODS, "auto", "how to plan: \"flat\" (the closed-form flat "
                         "outputs; a design without them is refused), \"exact\" (joint paths "
                         "in the basis, the base from the momentum constraint: any "
                         "controllable design; docs/asbuilt.md) or \"auto\" (flat "
                         "where the closed form applies, exact elsewhere)")
    optimize: OptimizeSpec = field(default_factory=OptimizeSpec)


@dataclass(frozen=True)
class TaskSpec:
    """an end-effector task (off unless `end_effector` is set; docs/tasks.md)"""

    end_effector: Vector | None = vector(2, None, "where the end effector must be at t = T, "
                                         "in the inertial frame whose origin is the system's "
                                         "centre of mass (sets plan.goal)", "m", nullable=True)
    base_attitude: float | None = number(None, "the base's th0 at t = T (none: free, chosen "
                                         "with the joints by least joint motion)", "rad",
                                         nullable=True)
    start_end_effector: Vector | None = vector(2, None, "where the end effector is at t = 0 "
                                               "(sets plan.start, at its th0; none: "
                                               "plan.start as it is)", "m", nullable=True)
    rest: bool = flag(False, "start and stop at rest (every rate 0 at t = 0 and T); "
                      "otherwise plan.start_rate and plan.goal_rate are magnitudes whose sign "
                      "follows th1's motion")
    obstacles: tuple[tuple[float, float, float], ...] = discs(
        "discs [x, y, radius] every link (the base as its segment) must clear for all t in "
        "[0, T], proven by interval arithmetic (paper's robot)")
    clearance: float = number(0.0, "least distance of every link from every obstacle's "
                              "surface", "m", ge=0)
    elbow: str = choice(ELBOWS, "auto", "inverse-kinematics branch of the two-joint robot: "
                        "\"up\" (sin th2 > 0), \"down\", or \"auto\" (the one nearer "
                        "plan.start, or the first that clears the obstacles)")
    fade: float = number(0.2, "track with rest: the feedback fades in over the first and out "
                         "over the last fade x T (feedforward alone where the margin "
                         "vanishes)", gt=0, le=0.5)
    goal_tolerance: float = number(TARGET_TOLERANCE, "a trial reaches the task's target "
                                   "(`outcome` reached) where its end effector ends within "
                                   "this of task.end_effector at t = T (beside "
                                   "track.goal_tolerance)", "m", gt=0)
    budget: int = integer(64, "obstacle search: most candidate plans tried (elbow branches, "
                          "the rest plan's skew or the end rates' magnitudes) before saying "
                          "none is proven clear", ge=1)


@dataclass(frozen=True)
@settings_keys(SETTINGS)  # mpc_* and every controller's keys, from its settings record
class TrackSpec:
    """the closed loop"""

    initial: Vector = vector("links", (1.96, 0.8, -0.1), "th(0) of the plant (Fig. 4)", "rad",
                             default_doc="(1.96, 0.8, -0.1), Fig. 4's; for a robot of N != 2 "
                             "joints the plan's start (plan.start)")
    initial_rate: float | Vector | None = numbers(
        "inner", None, "u1(0) = th1'(0) (u_j(0) = th_j'(0), j < N) of the plant and the "
        "controller", "rad/s", nullable=True,
        default_doc="the plan's th1'(0) (plan.start_rate, or the optimised plan's own)")
    kp: Vector = vector("joints", (10.0, 13.0), "kp1, kp2 (kp1..kpN): feedback gains, as printed "
                        "in the paper", "1/s^2", default_doc="(10, 13), as printed; for a "
                        "robot of N != 2 joints 25 per output (a double pole at -5 rad/s)")
    kv: Vector = vector("joints", (100.0, 110.0), "kv1, kv2 (kv1..kvN): feedback gains, as "
                        "printed in the paper", "1/s", default_doc="(100, 110), as printed; "
                        "for a robot of N != 2 joints 10 per output (a double pole at -5 "
                        "rad/s)")
    dt: float = number(1e-3, "output sampling step: trace, metrics, track.parquet (and RK4's "
                       "step); must divide the duration", "s", gt=0)
    integrator: str = choice(INTEGRATORS, "adaptive", "\"adaptive\" (compiled Dormand-Prince "
                             "5(4) with step control, to rtol/atol), \"rk4\" (compiled fixed "
                             "step dt) or \"dop853\" (solve_ivp, rtol 1e-10: the reference)")
    rtol: float = number(DEFAULT_RTOL, "relative tolerance of the adaptive integrator (at "
                         "least 100 x float64's machine epsilon, as solve_ivp: a smaller one "
                         "cannot be met)", ge=MIN_RTOL)
    atol: float = number(DEFAULT_ATOL, "absolute tolerance of the adaptive integrator",
                         "rad, rad/s", gt=0)
    max_steps: int = integer(DEFAULT_MAX_STEPS, "attempted steps the adaptive integrator may "
                             "take per trial before the trial is unresolved", ge=1)
    error_estimate: str = choice(ERROR_ESTIMATES, "twin", "the adaptive integrator's "
                                 "err_estimate: \"twin\" (each trial that reaches T integrated "
                                 "again at a hundredth of rtol and atol: about half the "
                                 "trials/s) or \"none\" (err_estimate null)")
    accuracy: float = number(DEFAULT_ACCURACY, "a resolved trial whose err_estimate exceeds it "
                             "is not verified (its numbers are reported apart)", "rad", gt=0)
    observe_every: int = integer(1, "the metrics observe every k-th output sample (and the "
                                 "last: the final errors are exact at T); k > 1 is faster, and "
                                 "the rms, max, singular hits, margin, momentum drift and "
                                 "peak metrics are then over those samples only (docs/outputs.md)",
                                 ge=1)
    singular_threshold: float = number(1e-2, "a sample whose margin (abs(sin th1 * u1) for N = 2, "
                                       "abs(dh_0/dt) / (2 abs(K_10)) beyond) is below it is a "
                                       "singular hit", "rad/s", ge=0)
    sensor_noise: float = number(0.0, "std of the noise on the measured angles, drawn per "
                                 "output interval dt and held over it", "rad", ge=0)
    rate_limit: float = number(INF, "actuator limit: the joint-rate commands are clipped to "
                               "it (the kinematic plant turns at them)", "rad/s", gt=0,
                               inf=True)
    goal_tolerance: float = number(GOAL_TOLERANCE, "a trial resolved to the end is `reached` "
                                   "(outcome) where every angle th0..thN ends within this of "
                                   "the plan's goal th(T), else `missed` (docs/outputs.md, "
                                   "*Outcomes*)", "rad", gt=0)
    divergence_bound: float = number(1e4, "a state component beyond it (or non-finite) stops "
                                     "the trial as diverged", "rad, rad/s", gt=0)
    controller: str = choice(CONTROLLERS, "flat", "the feedback: \"flat\" (the paper's "
                             "linearising feedback on the flat outputs, gains kp, kv), "
                             "\"asbuilt\" (time-varying LQR of the robot as built about the "
                             "plan, weights lqr_*; docs/asbuilt.md) or \"mpc\" (a correction "
                             "chosen at sample instants by a QP that keeps the rate limit "
                             "and the margin at its predicted samples, wrapping the flat "
                             "law, or the as-built law on an exact plan; settings mpc_*; "
                             "what it guarantees: docs/physics.md)")
    lqr_bandwidth: float | None = number(None, "asbuilt: b, the joint-rate weight R = I / b^2 "
                                         "of the LQR (none: 10 / plan.duration, 5 rad/s at "
                                         "the paper's 2 s; docs/physics.md)", "rad/s", gt=0,
                                         nullable=True)
    lqr_base: float = number(DEFAULT_BASE, "asbuilt: weight of the base angle's error "
                             "relative to a joint angle's (Q = diag(lqr_base, 1, .., 1))", gt=0)
    lqr_terminal: float | None = number(None, "asbuilt: t_f, the weight of the error at t = T "
                                        "as t_f seconds of running error (P_T = t_f Q; none: "
                                        "5e5 x plan.duration, 1e6 s at the paper's 2 s)", "s",
                                        gt=0, nullable=True)
    seed: int = integer(0, "seed of the sensor-noise stream SeedSequence(seed, (trial, 1))", ge=0)
    trial: int = integer(0, "noise stream within the seed (a sweep trial's id, to re-run it)",
                         ge=0)


@dataclass(frozen=True)
class PlantSpec:
    """the robot the simulation integrates (default: the `[robot]`)"""

    mass: Vector | None = vector("links", None, "the plant's masses", "kg", gt=0, nullable=True,
                                 default_doc="robot.mass")
    inertia: Vector | None = vector("links", None, "the plant's inertias", "kg m^2", gt=0,
                                    nullable=True, default_doc="robot.inertia")
    length: Vector | None = vector("links", None, "the plant's lengths", "m", gt=0, nullable=True,
                                   default_doc="robot.length")
    com: Vector | None = vector("links", None, "the plant's d_i, any d_N (an imperfect "
                                "counterweight: the paper's flat outputs no longer apply)", "m",
                                nullable=True, default_doc="robot.com")
    com_across: float | None = number(None, "the plant's e_N (a counterweight placed across "
                                      "the last link)", "m", nullable=True,
                                      default_doc="robot.com_across")
    momentum: float = number(0.0, "the plant's angular momentum H0 (the controller assumes 0)",
                             "kg m^2/s")
    model: str = choice(PLANT_MODELS, "kinematic", "\"kinematic\" (the joints turn at the "
                        "commanded rates) or \"dynamic\" (a robot with inertia: joint torques "
                        "from rate servos; docs/physics.md, *The dynamic plant*)")
    servo_bandwidth: float = number(DEFAULT_SERVO_BANDWIDTH, "dynamic plant: each joint rate "
                                    "follows its command as a first-order lag of this bandwidth "
                                    "(exactly, while the servo's model is right and no torque "
                                    "is clipped)", "rad/s", gt=0)
    torque_limit: float = number(INF, "dynamic plant: the servo's joint torques are clipped to "
                                 "it (0: no torque, the robot drifts freely)", "N m", ge=0,
                                 inf=True)
    servo_model: str = choice(SERVO_MODELS, "robot", "dynamic plant: the model the servo's "
                              "computed torque uses: \"robot\" (the nominal `[robot]`) or "
                              "\"plant\" (the plant itself)")


@dataclass(frozen=True)
class SweepSpec:
    """a Monte Carlo study (used by `flatcli sweep`)"""

    trials: int = integer(1000, "trials per grid cell", ge=1)
    seed: int = integer(0, "seed of every random draw", ge=0)
    chunk: int | None = integer(
        None, "trials per task; from the spec alone, so a resume finds the same chunks "
        "whatever --workers", ge=1, nullable=True,
        default_doc="about 1/16 of all trials, within 250..1000 (and <= trials)")
    verify: float = number(0.0, "trials of each cell re-run with the reference integrator "
                           "(DOP853, rtol 1e-10) and compared (reference_difference): a "
                           "fraction if below 1 (0.01: the first 1 % of each cell's trials, at "
                           "least one), else a whole count", ge=0)
    perturb: Mapping[str, Any] = table("random perturbations (below)")
    grid: Mapping[str, Any] = table("spec keys and their lists of values (below)")


@dataclass(frozen=True)
class FiguresSpec:
    """the files figures are written as (`--format`, `--dpi`; not part of the experiment)"""

    format: str = choice(FIGURE_FORMATS, "png", "file format of every figure a command writes: "
                         "\"png\" (raster), \"pdf\" or \"svg\" (vector, for print)")
    dpi: int = integer(150, "resolution of raster figures (png); pdf and svg are vector, their "
                       "embedded images only use it", "dots/in", ge=50, le=1200)


@dataclass(frozen=True)
class SummarySpec:
    """how a sweep's summary judges its trials (`--set summary.*`; not part of the experiment)"""

    reach_tolerance: float = number(1e-3, "a task sweep's summary counts the trials whose "
                                    "`ee_error_bound`, an upper bound on the end effector's "
                                    "final distance from its target, is at most this "
                                    "(`ee_error_bound_within_fraction`; whether a trial "
                                    "reached is its `outcome`, task.goal_tolerance)", "m",
                                    gt=0)


@dataclass(frozen=True)
class SearchSpec:
    """a design search (used by `flatcli search`; docs/search.md)"""

    vary: Mapping[str, Any] = table("design variables and their bounds: \"robot.mass[1]\" = "
                                    "[low, high] or { relative = r } (docs/search.md)")
    counterweight: Mapping[str, Any] = table(
        "a counterweight on the last link, whose [robot] values are then the bare link's: "
        "distance (placed by the designer) or mass, x, y; inertia (docs/search.md)")
    objective: str = choice(SEARCH_OBJECTIVES, "reached", "\"reached\" (maximise the 95 % Wilson "
                            "lower bound of the fraction of trials reached; between equal "
                            "counts, minimise the quantile below) or \"quantile\" (minimise "
                            "the quantile of metric over all trials, a lost trial or one "
                            "without a value counted as infinite)")
    metric: str = choice(QUANTILE_METRICS, "err_theta_final", "the trial metric whose "
                         "quantile the objective reads")
    quantile: float = number(0.5, "which quantile of metric", gt=0, le=1)
    energy_weight: float = number(0.0, "w of the secondary term w E / E_0 added to the "
                                  "objective: E the candidate's plan input energy, E_0 the "
                                  "spec's own design's", ge=0)
    candidates: int = integer(200, "budget: designs evaluated at most (whole generations)",
                              ge=1, le=10_000_000)
    seconds: float = number(INF, "budget: stop at the first generation boundary after this "
                            "much time (recorded, so a resume stops there too)", "s", gt=0,
                            inf=True)
    population: int | None = integer(None, "designs per generation of the differential "
                                     "evolution", ge=5, le=100_000, nullable=True,
                                     default_doc="5 per variable, at least 10")
    seed: int = integer(0, "seed of the optimiser (the trials' draws come from sweep.seed)",
                        ge=0)
    tol: float = number(0.01, "stop when the population's objectives agree: std <= tol x "
                        "abs(mean) (scipy's differential_evolution tol; 0: run the budget)",
                        ge=0)
    max_mass: float = number(INF, "constraint: total mass of a candidate at most this", "kg",
                             gt=0, inf=True)
    verdict: str = choice(VERDICT_REQUIREMENTS, "any", "constraint: the least flatness "
                          "verdict a candidate must have: \"closed_form\", \"flat\" "
                          "(controllable) or \"any\"")
    centre: str = choice(CENTRES, "free", "constraint: \"on_joint\" (every candidate's last "
                         "link has its centre of mass on its joint, d_N = e_N = 0) or "
                         "\"free\"")
    apply: str = choice(APPLY, "robot", "what a design is: \"robot\" (what the controller "
                        "believes and what is built; a [plant] key the spec sets keeps its "
                        "as-built offset) or \"plant\" (what is built alone; the controller "
                        "keeps [robot]); variables are named after it (robot.mass[1], "
                        "plant.mass[1])")


@dataclass(frozen=True)
class SpecRecord:
    """top level

    The records of a spec, its sections and its name, and what they say of themselves. The
    spec a program holds is ``flatcli.spec.Spec`` (``flatcli.spec.build``: this record
    validated, and rebuilt with overrides).
    """

    name: str = text("paper_example", "run name; default output directory `runs/<name>/`")
    robot: RobotSpec = field(default_factory=RobotSpec)
    plan: PlanSpec = field(default_factory=PlanSpec)
    task: TaskSpec = field(default_factory=TaskSpec)
    track: TrackSpec = field(default_factory=TrackSpec)
    plant: PlantSpec = field(default_factory=PlantSpec)
    sweep: SweepSpec = field(default_factory=SweepSpec)
    figures: FiguresSpec = field(default_factory=FiguresSpec)
    summary: SummarySpec = field(default_factory=SummarySpec)
    search: SearchSpec = field(default_factory=SearchSpec)

    @property
    def joints(self) -> int:
        """N, the robot's joints (2: the paper's base and two links)."""
        return len(self.robot.mass) - 1

    @property
    def tree(self) -> dict[str, Any]:
        """The spec as a nested dict (a fresh copy): what run.json and sweep.json hold."""
        return _tree(self)

    def values(self) -> dict[str, Any]:
        """{dotted key: value} of every key."""
        return dict(_values(self, ""))

    def experiment_tree(self, skip: Collection[str] = ()) -> dict[str, Any]:
        """``tree`` without the sections that only say how results are shown
        (``PRESENTATION``) and those no trial reads (``OUTSIDE_TRIALS``): what the
        experiment is; without the dotted keys ``skip`` too (not copied: a sweep's cells leave
        out the grid they all share)."""
        return experiment(_tree(self, skip))

    def to_json(self) -> str:
        """Canonical JSON of the experiment (``experiment_tree``; sorted keys, no spaces; inf
        written as the string "inf")."""
        from flatcli.storage import to_jsonable  # numpy: not for the schema's other readers

        return json.dumps(to_jsonable(self.experiment_tree()), sort_keys=True,
                          separators=(",", ":"))

    def digest(self) -> str:
        """SHA-256 of the canonical JSON: what makes two sweeps the same experiment (the
        figures' format is not part of it)."""
        return hashlib.sha256(self.to_json().encode()).hexdigest()


def experiment(tree: Mapping[str, Any]) -> dict[str, Any]:
    """A spec tree (a Spec's, or one read from a run's record) without its ``PRESENTATION``
    and ``OUTSIDE_TRIALS`` sections."""
    return {k: v for k, v in tree.items() if k not in PRESENTATION + OUTSIDE_TRIALS}


def _is_section(f: Field[Any]) -> bool:
    return "key" not in f.metadata


def _tree(record: Any, skip: Collection[str] = (), prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in fields(record):
        value = getattr(record, f.name)
        if f"{prefix}{f.name}" in skip:
            continue
        if _is_section(f):
            out[f.name] = _tree(value, skip, f"{prefix}{f.name}.")
        elif isinstance(value, Mapping):
            out[f.name] = copy.deepcopy(dict(value))
        else:
            out[f.name] = value
    return out


def _values(record: Any, prefix: str) -> Iterator[tuple[str, Any]]:
    for f in fields(record):
        dotted = f"{prefix}{f.name}"
        if _is_section(f):
            yield from _values(getattr(record, f.name), f"{dotted}.")
        else:
            yield dotted, getattr(record, f.name)


def _section_type(f: Field[Any]) -> type:
    """The record type of a subsection field (its default factory is the record class)."""
    factory = f.default_factory
    assert isinstance(factory, type) and is_dataclass(factory)
    return factory


def _sections(record_type: type, prefix: str) -> Iterator[tuple[str, type]]:
    yield prefix, record_type
    for f in fields(record_type):
        if _is_section(f):
            yield from _sections(_section_type(f), f"{prefix}.{f.name}" if prefix else f.name)


#: Section name ('' for the top level) -> its record type, in the order of docs/spec.md.
SECTIONS: dict[str, type] = dict(_sections(SpecRecord, ""))

#: Section name -> {key name: Key}: the single list of keys, types, units and defaults.
SCHEMA: dict[str, dict[str, Key]] = {
    section: {f.name: f.metadata["key"] for f in fields(record) if not _is_section(f)}
    for section, record in SECTIONS.items()
}


def dotted_keys(tree: Mapping[str, Any]) -> dict[str, Any]:
    """A user's nested spec (a parsed TOML file) as {dotted key: value}, entering its
    sections only: a table a key takes (``sweep.grid``, ``sweep.perturb``) is one value."""
    return flatten(tree, lambda dotted, table: dotted in SCHEMA)


def all_keys() -> list[str]:
    """Every dotted key of the schema."""
    return [f"{sec}.{k}" if sec else k for sec, keys in SCHEMA.items() for k in keys]


def find_key(dotted: str) -> Key | None:
    """The Key of a dotted name, or None (no error message made: a caller that only asks
    whether a name is a key, e.g. for a column's unit, pays no close-match search)."""
    section, _, name = dotted.rpartition(".")
    keys = SCHEMA.get(section)
    return None if keys is None else keys.get(name)


def lookup(dotted: str) -> Key:
    """The Key of a dotted name; SpecError with a close match if there is none."""
    key = find_key(dotted)
    if key is None:
        known = all_keys() + [s for s in SCHEMA if s]
        raise SpecError(f"unknown key {dotted!r}{suggest(dotted, known)}")
    return key


def check_value(dotted: str, value: Any) -> Any:
    """Validate one value for a dotted key; return it normalised (floats, tuples)."""
    return lookup(dotted).check(dotted, value)


def from_values(record_type: type[S], values: Mapping[str, Any]) -> S:
    """A spec record of ``record_type`` (``SpecRecord`` or a subclass) from {dotted key:
    checked value}; keys not given keep their defaults.

    Only ``flatcli.spec.build`` calls this, after checking every value.
    """
    spec = _record(record_type, "", values)
    assert isinstance(spec, record_type)
    return spec


def _record(record_type: type, prefix: str, values: Mapping[str, Any]) -> object:
    kwargs: dict[str, Any] = {}
    for f in fields(record_type):
        dotted = f"{prefix}{f.name}"
        if _is_section(f):
            kwargs[f.name] = _record(_section_type(f), f"{dotted}.", values)
        elif dotted in values:
            kwargs[f.name] = values[dotted]
    return record_type(**kwargs)


#: The feedback's pole [rad/s] of every flat output for a robot of N != 2 joints whose spec
#: sets no gains: y_j'' = v_j with kp = p^2, kv = 2 p puts a double pole at -p (the shipped
#: robot files' choice); the paper's robot keeps the gains as printed.
SIZED_POLE = 5.0


def sized_defaults(spec: SpecRecord) -> dict[str, tuple[float, ...]]:
    """The defaults of robot-sized keys that follow from the robot and its plan for a robot
    of N != 2 joints (the paper's robot's own defaults do not fit it): the plant starts on
    the plan (``track.initial = plan.start``), every flat output gets a double pole at
    ``-SIZED_POLE``, and a task that gives the end effector's target derives the goal from
    it (``plan.goal`` stands at ``plan.start`` until then: ``goal_is_derived``)."""
    joints = spec.joints
    out = {"track.initial": tuple(spec.plan.start),
           "track.kp": (SIZED_POLE ** 2,) * joints,
           "track.kv": (2 * SIZED_POLE,) * joints}
    if spec.task.end_effector is not None:
        out["plan.goal"] = tuple(spec.plan.start)
    return out


def goal_is_derived(spec: SpecRecord) -> bool:
    """Whether ``plan.goal`` was left for the task to derive: its default (the paper's goal),
    or, on a robot of N != 2 joints with ``task.end_effector`` set, ``plan.start``
    (``sized_defaults``). Read from the values, so a spec written out (run.json, ``--cfg``)
    reads back the same; a goal set equal to the start counts as left out."""
    goal = spec.plan.goal
    if goal == find_key("plan.goal").default:  # type: ignore[union-attr]
        return True
    return (spec.joints != 2 and spec.task.end_effector is not None
            and goal == spec.plan.start)


def fit_sizes(spec: S, given: Collection[str]) -> S:
    """The spec with every robot-sized key checked against N = ``spec.joints``.

    A list must have the length its key's size gives for N (``Key.size``); a "numbers" key's
    single number stands for every item. A key the user did not set (not in ``given``)
    whose default holds one value for every item (``plan.optimize.angle_limit``: inf) takes
    N's length; ``track.initial``, ``track.kp`` and ``track.kv`` follow ``sized_defaults``;
    any other default is the paper's robot's, so a robot of other N must set it
    (``plan.start``, ``plan.goal``, the robot's own parameters).

    Raises
    ------
    SpecError naming the key, the length expected and why.
    """
    joints = spec.joints
    replaced: dict[str, Any] = {}
    derived: dict[str, tuple[float, ...]] | None = None
    for section, keys in SCHEMA.items():
        for name, key in keys.items():
            if not key.size:
                continue
            dotted = f"{section}.{name}" if section else name
            value = _get(spec, dotted)
            if not isinstance(value, tuple):
                continue
            want = SIZES[key.size].length(joints)
            if len(value) != want and dotted not in given and len(set(value)) == 1:
                replaced[dotted] = (value[0],) * want
                continue
            if len(value) != want and dotted not in given and dotted in SIZED_KEYS:
                if derived is None:
                    derived = sized_defaults(_replaced(spec, replaced) if replaced else spec)
                if dotted in derived and len(derived[dotted]) == want:  # else: said below
                    replaced[dotted] = derived[dotted]
                    continue
            hint = "" if dotted in given else " (the default is the paper's robot's: set it)"
            check_size(dotted, value, joints, hint)
    return _replaced(spec, replaced) if replaced else spec


#: The keys ``sized_defaults`` gives.
SIZED_KEYS = frozenset({"track.initial", "track.kp", "track.kv", "plan.goal"})


def check_size(dotted: str, value: Any, joints: int, hint: str = "") -> None:
    """SpecError unless a robot-sized key's list has its length for ``joints`` joints (one
    number always does for a "numbers" key; so does any value of another key)."""
    key = lookup(dotted)
    if not key.size or not isinstance(value, list | tuple):
        return
    size = SIZES[key.size]
    want = size.length(joints)
    if len(value) != want:
        raise SpecError(
            f"{dotted}: expected {want} numbers ({size.items}) for a robot of {joints} "
            f"joints (robot.mass has {joints + 1} links), got {len(value)}{hint}"
        )


def _get(record: Any, dotted: str) -> Any:
    for part in dotted.split("."):
        record = getattr(record, part)
    return record


def _replaced(record: Any, values: Mapping[str, Any], prefix: str = "") -> Any:
    changes: dict[str, Any] = {}
    for f in fields(record):
        dotted = f"{prefix}{f.name}"
        if _is_section(f):
            changes[f.name] = _replaced(getattr(record, f.name), values, f"{dotted}.")
        elif dotted in values:
            changes[f.name] = values[dotted]
    return dataclasses.replace(record, **changes)
