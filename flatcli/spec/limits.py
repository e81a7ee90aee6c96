"""Upper bounds on what a spec may ask for, from estimates of the memory and time it needs.

A request whose estimate exceeds the budget is refused before any work, with one line naming
the estimate, the budget and the key to change. The estimates are rates measured on this
project's machine (docs/failures.md) rounded in the request's favour: memory per plan
sample, per output step, per trial; time per output step of a trial at the fastest any
integrator ran. So a refused request would not have fitted, and a request that fits is never
refused for being large.

Budgets: memory is half of this machine's memory (or of the container's limit), time is 30
days of all cores; ``FLATCLI_MEMORY_BUDGET`` (bytes, or with a K/M/G/T suffix) and
``FLATCLI_TIME_BUDGET`` (seconds, or with an s/m/h/d suffix) set them.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Any

from flatcli.core.names import DEFAULT_BANDWIDTH_PERIODS
from flatcli.machine import cores, physical_memory
from flatcli.spec.keys import SpecError

#: Largest spec file read [bytes].
MAX_SPEC_BYTES = 1 << 20
#: Trials per grid cell at most: a trial's id is ``cell key * ID_STRIDE + i`` with
#: ``i < sweep.trials`` (``flatcli.montecarlo.layout``).
ID_STRIDE = 10**9

#: ``flatcli plan``: the samples, their table and Parquet file [bytes per sample] (measured
#: 317 at 2e6 samples) of the paper's robot: 17 columns (6 N + 5 on N joints:
#: ``plan_sample_bytes``).
BYTES_PER_PLAN_SAMPLE = 300
#: ``flatcli track``: the recorded trace, its columns, table and Parquet file [bytes per
#: output step] (measured 825 at 2e5 steps, 1,060 at 1e6 with --plot) of the paper's robot:
#: 20 columns (7 N + 6 on N joints: ``track_step_bytes``).
BYTES_PER_TRACK_STEP = 800
#: One grid cell of a sweep: the reference tables of its scenario [bytes per output step]
#: (for the paper's robot, N = 2, the (2n + 1, 6) and (n + 1, 3) float tables: 120; on N
#: joints (2n + 1, 3 N) and (n + 1, N + 1): ``cell_step_bytes``), and per cell besides them
#: [bytes].
BYTES_PER_CELL_STEP = 120
BYTES_PER_CELL = 20_000
#: The summary of a sweep reads about 20 numbers and a status per trial [bytes per trial].
BYTES_PER_TRIAL = 200
#: A chunk's rows in a worker and in flight [bytes per trial] (about 60 columns for N = 2;
#: six more perturbation columns per further joint: ``chunk_trial_bytes``).
BYTES_PER_CHUNK_TRIAL = 500
#: A worker process, before its first chunk [bytes] (measured 130 MiB).
BYTES_PER_WORKER = 100 * 2**20
#: A trial's output step at best [s] (measured 1.8e-7 to 1.1e-6 on one core of this
#: project's machine, see docs/performance.md), and a trial's fixed cost at best [s].
SECONDS_PER_STEP = 5e-8
SECONDS_PER_TRIAL = 1e-5

#: An attempted step of the adaptive integrator at best [s]: a trial that cannot meet its
#: tolerance spends all of ``track.max_steps`` (measured about 1.1 us per attempt on the
#: paper's robot: 7e5 attempts in 0.8 s).
SECONDS_PER_ATTEMPT = 5e-7
#: Planning a robot of N > 2 joints at best [s per N^4]: the general chain's flat maps cost
#: O(N^4) per evaluation as the core computes them (``core.robots.chain``); a plan took 1.1 s
#: at N = 50, 16 s at N = 100, 355 s at N = 200 (about 1.6e-7 N^4 s, this project's machine).
SECONDS_PER_CHAIN_PLAN = 4e-8
#: The flat outputs of a ``flatcli track`` trace on N > 2 joints at best [s per output sample
#: per N^4]: the same maps at every sample (measured 2.4e-8 N^4 s per sample, N = 20 to 40).
SECONDS_PER_CHAIN_SAMPLE = 5e-9
#: Checking a spec of N > 2 joints: the barycentric matrix K of the robot and of the plant,
#: O(N^3) each as the core computes it (``flatcli.core.robots.chain.barycentric_matrix``: 0.29 s at
#: N = 100, 2.2 s at 200, 7.3 s at 300) [s per N^3].
SECONDS_PER_CHAIN_CHECK = 2.7e-7
#: The as-built law's Riccati equation (``flatcli.core.controllers.lqr.riccati``) is stiff at the
#: bandwidth b: scipy's DOP853 takes about 0.85 b T steps over a plan of T seconds (measured
#: on the paper's maneuver at d2 = 3 mm: 1,191 steps at b T = 1e3, 8,464 at 1e4, 82,602 at
#: 1e5), each at least this long [s] (measured 4.8 ms per step on this project's machine).
RICCATI_STEPS_PER_RADIAN = 0.8
SECONDS_PER_RICCATI_STEP = 1e-3
#: The most joints a robot may have: beyond it checking one spec (every sweep cell is one)
#: takes seconds, planning at least minutes and a track run hours (the N-link maps cost
#: O(N^3) to check and O(N^4) per point; docs/failures.md).
MAX_JOINTS = 100
#: Estimates above this print a note before a plan or track run starts [s].
NOTICE_SECONDS = 5.0
#: The smallest relative tolerance of the adaptive integrator: 100 x float64's machine
#: epsilon (as scipy's solve_ivp); below it the error test cannot pass in double precision,
#: so the steps shrink until the step budget is spent.
MIN_RTOL = 100 * 2.220446049250313e-16

#: The planner looks for the singular set sin th1 = 0 at every multiple of pi that th1 may
#: pass (``flatcli.core.plan.planning.margin_zeros``), about 10 us each: at most this many.
MAX_HALF_TURNS = 1e5

#: The most cells a sweep's grid may have. Every cell is checked and planned in the main
#: process before the first trial (its plan and reference tables: 5-11 ms for the paper's
#: robot on this project's machine, seconds for an optimised plan or a chain) and is a row of
#: the summary; a study of more settings than this draws them with [sweep.perturb].
MAX_GRID_CELLS = 10_000
#: The most obstacles a task may have. A candidate plan's proof examines every link against
#: every disc on each interval, and its screening holds (candidates x samples x links x
#: discs) distances: 0.06 ms and about 25 KiB per disc and candidate on the paper's robot
#: (1,000 discs: 0.7 s for 12 candidates), up to task.budget candidates.
MAX_OBSTACLES = 1_000

MEMORY_FRACTION = 0.5
DEFAULT_TIME_BUDGET = 30 * 86400.0


def _parse(text: str, units: Mapping[str, float], variable: str) -> float:
    raw = text.strip()
    factor = 1.0
    if raw and raw[-1].upper() in units:
        factor = units[raw[-1].upper()]
        raw = raw[:-1]
    try:
        value = float(raw) * factor
    except ValueError:
        value = math.nan
    if not (value > 0 and math.isfinite(value)):
        raise SpecError(f"{variable}: expected a positive number, got {text!r}")
    return value


def memory_budget() -> float:
    """Memory a run may plan to use [bytes]."""
    text = os.environ.get("FLATCLI_MEMORY_BUDGET")
    if text:
        return _parse(text, {"K": 2.0**10, "M": 2.0**20, "G": 2.0**30, "T": 2.0**40},
                      "FLATCLI_MEMORY_BUDGET")
    return MEMORY_FRACTION * physical_memory()


def time_budget() -> float:
    """Wall time a sweep may plan to take [s]."""
    text = os.environ.get("FLATCLI_TIME_BUDGET")
    if text:
        return _parse(text, {"S": 1.0, "M": 60.0, "H": 3600.0, "D": 86400.0},
                      "FLATCLI_TIME_BUDGET")
    return DEFAULT_TIME_BUDGET


def size_text(n: float) -> str:
    for unit, scale in (("TiB", 2.0**40), ("GiB", 2.0**30), ("MiB", 2.0**20)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n / 2**10:.3g} KiB"


def time_text(seconds: float) -> str:
    for unit, scale in (("years", 365.25 * 86400), ("days", 86400.0), ("h", 3600.0),
                        ("min", 60.0)):
        if seconds >= scale:
            return f"{seconds / scale:.3g} {unit}"
    return f"{seconds:.3g} s"


def require_memory(what: str, estimate: float, change: str, budget: float | None = None
                   ) -> None:
    """SpecError if ``estimate`` [bytes] exceeds the memory budget (``budget`` [bytes] if
    given: one reading of it for many checks)."""
    budget = memory_budget() if budget is None else budget
    if estimate > budget:
        raise SpecError(f"{what} would need about {size_text(estimate)} of memory, more than "
                        f"the {size_text(budget)} budget (FLATCLI_MEMORY_BUDGET); {change}")


def require_time(what: str, estimate: float, change: str) -> None:
    """SpecError if ``estimate`` [s] exceeds the time budget."""
    budget = time_budget()
    if estimate > budget:
        raise SpecError(f"{what} would take at least {time_text(estimate)}, more than the "
                        f"{time_text(budget)} budget (FLATCLI_TIME_BUDGET); {change}")


def cell_step_bytes(joints: int = 2) -> float:
    """A cell's reference tables per output step on a robot of ``joints`` joints [bytes]:
    2 x 3 N floats at half steps and N + 1 plan angles (``BYTES_PER_CELL_STEP`` for N = 2)."""
    return 8.0 * (6 * joints + joints + 1)


def plan_sample_bytes(joints: int = 2) -> float:
    """plan.parquet's row and its arrays per sample on ``joints`` joints [bytes]
    (``BYTES_PER_PLAN_SAMPLE`` for N = 2, per column: 6 N + 5 columns)."""
    return BYTES_PER_PLAN_SAMPLE * (6 * joints + 5) / 17


def track_step_bytes(joints: int = 2) -> float:
    """track.parquet's row and the trace per output step on ``joints`` joints [bytes]
    (``BYTES_PER_TRACK_STEP`` for N = 2, per column: 7 N + 6 columns)."""
    return BYTES_PER_TRACK_STEP * (7 * joints + 6) / 20


def check_joints(joints: int) -> None:
    """Refuse a robot of more than ``MAX_JOINTS`` joints before its spec is checked further
    (checking it alone would take ``SECONDS_PER_CHAIN_CHECK`` N^3 twice)."""
    if joints > MAX_JOINTS:
        check = 2 * SECONDS_PER_CHAIN_CHECK * float(joints) ** 3
        raise SpecError(
            f"robot.mass: {joints + 1} links ({joints} joints), more than the {MAX_JOINTS + 1} "
            f"links ({MAX_JOINTS} joints) flatcli takes: checking a spec of N joints costs "
            f"O(N^3) (about {time_text(check)} here, again for every sweep cell) and planning "
            f"O(N^4) (at least {time_text(plan_seconds(joints))}); use fewer links")


def plan_seconds(joints: int) -> float:
    """Least time to plan a maneuver of a robot of ``joints`` joints [s] (N = 2, the paper's
    closed-form maps: nothing worth counting)."""
    return SECONDS_PER_CHAIN_PLAN * float(joints) ** 4 if joints > 2 else 0.0


def riccati_seconds(spec: Any) -> float:
    """Least time of the as-built law's design (its Riccati equation) [s]; 0 for the flat
    law."""
    if spec.track.controller != "asbuilt":
        return 0.0
    bandwidth = spec.track.lqr_bandwidth
    duration = float(spec.plan.duration)
    periods = (DEFAULT_BANDWIDTH_PERIODS if bandwidth is None
               else float(bandwidth) * duration)  # b T: the default's is fixed
    steps = RICCATI_STEPS_PER_RADIAN * periods
    return steps * SECONDS_PER_RICCATI_STEP


def track_seconds(spec: Any) -> float:
    """Least time of a ``flatcli track`` run [s]: the plan, the as-built law's design, the
    trial's output steps and, on N > 2 joints, the flat outputs of its trace at every
    sample."""
    steps = output_steps(spec)
    joints = int(spec.joints)
    trace = SECONDS_PER_CHAIN_SAMPLE * float(joints) ** 4 * (steps + 1) if joints > 2 else 0.0
    return (plan_seconds(joints) + riccati_seconds(spec) + steps * SECONDS_PER_STEP
            + SECONDS_PER_TRIAL + trace)


def check_track(spec: Any) -> None:
    """Refuse a ``flatcli track`` run that could not end within the time budget."""
    require_time(f"tracking a robot of {spec.joints} joints over {output_steps(spec):.3g} "
                 "output steps (its trace's flat outputs cost O(N^4) per sample)",
                 track_seconds(spec), "use fewer links, raise track.dt or lower plan.duration")


def chunk_trial_bytes(joints: int = 2) -> float:
    """A chunk's row per trial on a robot of ``joints`` joints [bytes]: each joint beyond
    two adds six perturbation columns (initial, initial_rate, mass, inertia, length, com)."""
    return BYTES_PER_CHUNK_TRIAL + 8.0 * 6 * (joints - 2)


def _largest(value: Any) -> float:
    """abs of a number, or the largest abs of a list of them."""
    if isinstance(value, list | tuple):
        return max((abs(float(v)) for v in value), default=0.0)
    return abs(float(value))


def output_steps(spec: Any) -> float:
    """plan.duration / track.dt: the output steps of one trial."""
    return float(spec.plan.duration) / float(spec.track.dt)


def grid_cells(grid: Mapping[str, Any]) -> int:
    """Cells of a grid (the product of its lists' lengths), without expanding it."""
    return math.prod(len(v) for v in grid.values() if isinstance(v, list))


def sweep_seconds(trials: float, steps: float, workers: int) -> float:
    """Least wall time of ``trials`` trials of ``steps`` output steps on ``workers`` [s]."""
    return trials * (steps * SECONDS_PER_STEP + SECONDS_PER_TRIAL) / max(workers, 1)


def check_limits(spec: Any) -> None:
    """Refuse a spec whose plan, trial or sweep would not fit in memory or time (SpecError
    naming the estimate, the budget and the key to change)."""
    budget = memory_budget()  # read once (the machine's files), not per check

    def memory(what: str, estimate: float, change: str) -> None:
        require_memory(what, estimate, change, budget)

    plan, sweep, track = spec.plan, spec.sweep, spec.track
    joints = int(spec.joints)
    require_time(f"planning a robot of {joints} joints (the N-link flat maps cost O(N^4))",
                 plan_seconds(joints), "use fewer links (robot.mass and the other per-link "
                 "keys)")
    memory(f"plan.samples = {plan.samples}",
           plan.samples * plan_sample_bytes(joints), "lower plan.samples")
    steps = output_steps(spec)
    memory(f"plan.duration / track.dt = {steps:.3g} output steps",
           steps * track_step_bytes(joints), "raise track.dt or lower plan.duration")
    memory(f"plan.optimize.constraint_samples = {plan.optimize.constraint_samples}",
           plan.optimize.constraint_samples * plan_sample_bytes(joints),
           "lower plan.optimize.constraint_samples")
    if track.lqr_bandwidth is not None:  # the default's b T is fixed: its cost is small
        require_time(f"track.lqr_bandwidth = {track.lqr_bandwidth:g} rad/s (the as-built "
                     f"law's Riccati equation takes about {RICCATI_STEPS_PER_RADIAN:g} x "
                     "bandwidth x plan.duration integration steps)", riccati_seconds(spec),
                     "lower track.lqr_bandwidth (the default is 10 / plan.duration)")
    if track.integrator == "adaptive":  # a trial that cannot meet its tolerance spends them
        require_time(f"track.max_steps = {track.max_steps:.3g} attempted steps (one trial "
                     "that cannot meet track.rtol spends them all)",
                     track.max_steps * SECONDS_PER_ATTEMPT, "lower track.max_steps")
    terms = plan.size if plan.basis == "bspline" or (
        plan.basis == "auto" and plan.optimize.objective is not None) else (plan.degree or 3) + 1
    points = plan.samples + plan.optimize.constraint_samples + 2 * steps + 1
    memory(f"a flat-output basis of {terms} terms",
           8.0 * (3 * points * terms + 4 * float(terms) ** 2),
           "lower plan.size or plan.degree")
    reach = abs(plan.goal[1] - plan.start[1]) + plan.duration * (_largest(plan.start_rate)
                                                                   + _largest(plan.goal_rate))
    if reach / math.pi > MAX_HALF_TURNS:
        raise SpecError(
            f"plan: th1 may sweep up to {reach:.3g} rad (plan.start[1] to plan.goal[1] at "
            "plan.start_rate, plan.goal_rate over plan.duration), and the singular-set check "
            f"examines every multiple of pi on the way, at most {MAX_HALF_TURNS:.0e}; use "
            "smaller rates or a shorter plan.duration")
    if sweep.trials > ID_STRIDE:  # ids i = 0 .. trials - 1 < ID_STRIDE stay in the cell
        raise SpecError(f"sweep.trials: at most {ID_STRIDE:.0e} trials per cell (a trial's id "
                        f"is cell key * {ID_STRIDE:.0e} + i), got {sweep.trials}")
    cells = grid_cells(sweep.grid)
    if cells > MAX_GRID_CELLS:
        sizes = " x ".join(str(len(v)) for v in sweep.grid.values() if isinstance(v, list))
        raise SpecError(f"sweep.grid: {cells:.4g} cells ({sizes}), more than the "
                        f"{MAX_GRID_CELLS} a sweep plans before its first trial; use fewer "
                        "grid values, or draw the settings with [sweep.perturb]")
    if len(spec.task.obstacles) > MAX_OBSTACLES:
        raise SpecError(f"task.obstacles: {len(spec.task.obstacles)} discs, more than the "
                        f"{MAX_OBSTACLES} a task's proof takes (it examines every link against "
                        "every disc on each interval of every candidate); merge nearby discs "
                        "into larger ones")
    memory(f"sweep.grid of {cells:.3g} cells",
           cells * (BYTES_PER_CELL + steps * cell_step_bytes(joints)),
           "use fewer grid values")
    total = float(cells) * sweep.trials
    memory(f"{total:.3g} trials ({sweep.trials} x {cells} cells)",
           total * BYTES_PER_TRIAL, "lower sweep.trials or use fewer grid values")
    chunk = min(sweep.chunk or 0, sweep.trials)
    memory(f"sweep.chunk = {chunk} trials on {cores()} workers",
           2 * cores() * chunk * chunk_trial_bytes(joints), "lower sweep.chunk")
    require_time(f"{total:.3g} trials of {steps:.3g} output steps on {cores()} cores",
                 sweep_seconds(total, steps, cores()),
                 "lower sweep.trials, use fewer grid values or raise track.dt")


def check_sweep(cell_steps: list[float], trials: int, chunk: int, workers: int,
                joints: int = 2) -> None:
    """A sweep's exact cells (each with its own output steps) on ``workers`` workers, on a
    robot of ``joints`` joints: the parent holds every cell's reference tables, each worker
    up to three cells' and two chunks' rows."""
    step_bytes = cell_step_bytes(joints)
    largest = max(cell_steps, default=0.0)
    cells = len(cell_steps)
    require_memory(f"{cells} grid cells", sum(BYTES_PER_CELL + s * step_bytes
                                             for s in cell_steps), "use fewer grid values")
    per_worker = (BYTES_PER_WORKER + 3 * largest * step_bytes
                  + 2 * chunk * chunk_trial_bytes(joints))
    require_memory(f"--workers {workers}", workers * per_worker, "use fewer --workers")
    require_time(f"{cells * trials:.3g} trials on {workers} workers",
                 sum(sweep_seconds(trials, s, workers) for s in cell_steps),
                 "lower sweep.trials, use fewer grid values, raise track.dt or use more "
                 "--workers")


def require_finite_plan(columns: Mapping[str, Any]) -> None:
    """SpecError if a plan's sampled values (name -> array) are not all finite: the spec's
    numbers are valid one by one but not together (e.g. rates so large that the flat map
    overflows)."""
    import numpy as np

    for name, values in columns.items():
        array = np.asarray(values, dtype=float)
        if not np.isfinite(array).all():
            raise SpecError(f"plan: {name} is not finite along the plan (the spec's magnitudes "
                            "overflow the flat map); use physical values of the robot, rates "
                            "and plan.duration")


def check_workers(workers: int, oversubscribe: bool) -> None:
    """More workers than cores only when asked (``--oversubscribe``)."""
    if workers < 1:
        raise SpecError(f"--workers: must be >= 1, got {workers}")
    available = cores()
    if workers > available and not oversubscribe:
        raise SpecError(f"--workers {workers}: more than the {available} cores this process may "
                        "use; use at most that many, or add --oversubscribe")
