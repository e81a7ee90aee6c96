"""make bench: tasks among obstacles (issue 21), the goals measured.

* the capture task (``flatcli/data/capture.toml``: three discs, rest to rest, clearance proven
  over [0, T]) planned and verified through the public API, ``flatcli.plan`` and its metrics:
  the median of repeated calls against the goal of 10 ms;
* random tasks of the paper's robot from its start (a target in its annulus, a final base
  attitude, three discs 3 cm clear of the robot at its start), each planned through
  ``flatcli.plan``, most of them refused (the refusals' reasons counted); every plan flatcli
  accepts re-checked on a grid 100x finer than its own (20,001 samples) by link kinematics
  written here in the complex plane (the centre of mass solved for, nothing taken from
  ``flatcli.core.robots.kinematics``): violations counted, the goal is none;
* feasible random tasks (``feasible_tasks``): a witness drawn first, the obstacle-free plan
  (``flatcli.plan``) of a random target and base attitude, rest to rest or not (half each),
  then three discs near it, each cleared by the witness's links by task.clearance + 3 mm to
  task.clearance + 4 cm at every one of the 20,001 samples (the kinematics here): the task is
  feasible by a check that is not flatcli's. flatcli plans the task with its discs; its plan
  is re-checked on the same samples: violations and refusals counted, the goal is none of
  either;
* the same tasks through python-control's flatsys (``python_control_tasks``, the tasks that
  do not rest: python-control's flat maps divide by th1' and cannot start at rest; the first
  50): ``pc_obstacle_task``, least th1'^2 + th2'^2 with every link's clearance from every
  disc and the singularity margin imposed at its 21 time points (SLSQP, its iteration limit
  raised to 1000), its solution evaluated on the 20,001 samples: solutions that keep the
  clearance at its points and break it between them counted, beside flatcli's figures on
  the same tasks.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchmarks.baselines.links import FINE, PAPER, Complex, disc_gaps, link_clearance, link_joints

TIMING = "Tasks (issue 21): the capture task through the public API"
RANDOM = "Tasks (issue 21): random tasks among three discs, re-checked 100x finer"
FEASIBLE = ("Tasks (issue 21): feasible random tasks (a witness clears three discs near it on "
            "20,001 samples), planned by flatcli and re-checked 100x finer")
PYTHON_CONTROL = ("Tasks (issue 21): the feasible tasks that do not rest, python-control's "
                  "flatsys with the constraints at its 21 time points, re-checked 100x finer")
HEADERS = {
    TIMING: ["what", "value", "goal", "note"],
    RANDOM: ["tasks", "planned", "refused", "violations", "least margin [m]", "goal", "note"],
    FEASIBLE: ["tasks", "rest", "planned", "refused", "violations", "least margin [m]",
               "median plan [ms]", "goal", "note"],
    PYTHON_CONTROL: ["tasks", "flatcli planned", "flatcli violations", "flatcli median [ms]",
                     "python-control solved", "violated between points",
                     "deepest violation [m]", "python-control median [s]", "note"],
}
START = np.array([1.8, 1.0, 0.0])
#: task.clearance of the feasible tasks [m], and how far beyond it a drawn disc lies from the
#: witness's links at the closest, least and most [m].
CLEARANCE = 0.01
NEAR = (0.003, 0.04)
#: Discs of a feasible task; candidates drawn at once; the most tried for one witness.
DISCS, BATCH, MOST_CANDIDATES = 3, 64, 4096
#: The coarse and medium grids of the disc draw: every this many fine samples.
SCREENS = (100, 10)
#: |th1'| at t = 0 and T of the tasks that do not rest (the paper's) [rad/s].
RATES = (0.1, 0.5)
#: Refusal messages kept.
MESSAGES = 5
#: SLSQP's iteration limit for python-control (scipy's default, 100, stopped 8 of the first
#: 12 tasks short in a trial; with 1000 all 12 were solved, in about the same time).
PC_MAX_ITER = 1000
#: A violation between python-control's points counted apart when deeper than this [m].
DEEP = 1e-4

Array = NDArray[np.float64]


def capture_timing(bench: Any) -> dict[str, Any]:
    import flatcli

    spec = "flatcli/data/capture.toml"
    assert flatcli.plan(spec).metrics  # warm: the spec, numba's caches
    times: list[float] = []
    for _ in range(15 if bench.quick else 41):
        started = time.perf_counter()
        p = flatcli.plan(spec)
        assert p.metrics  # the certificate and the task's metrics are part of the call
        times.append(time.perf_counter() - started)
    median = float(np.median(times))
    m = p.metrics
    bench.row(TIMING, "plan and prove the capture task (`flatcli.plan`, median)",
              f"{median * 1e3:.1f} ms", "<= 10 ms", f"{'met' if median <= 0.01 else 'not met'}:"
              f" {m['task_candidates']} candidates, the first {m['task_candidates'] - 1} refuted "
              f"at samples, the last proven on {m['certified_intervals']} intervals")
    out: dict[str, Any] = {"median_seconds": median, "times": times}
    return out


def random_tasks(bench: Any, count: int, seed: int = 21) -> dict[str, Any]:
    import flatcli
    from flatcli.core.errors import FlatcliError

    rng = np.random.default_rng(seed)
    planned = refused = violations = 0
    least = math.inf
    reasons: dict[str, int] = {}
    started = time.perf_counter()
    for _ in range(count):
        radius = rng.uniform(0.12, 0.3)
        angle = rng.uniform(-math.pi, math.pi)
        discs: list[list[float]] = []
        while len(discs) < 3:  # three discs 3 cm clear of the robot at its start
            disc = [float(rng.uniform(-0.35, 0.35)), float(rng.uniform(-0.35, 0.35)),
                    float(rng.uniform(0.02, 0.05))]
            if link_clearance(*PAPER, START[None, :], np.array([disc]))[0] > 0.03:
                discs.append(disc)
        target = [radius * math.cos(angle), radius * math.sin(angle)]
        overrides: dict[str, Any] = {"task.end_effector": target,
                     "task.base_attitude": float(rng.uniform(0.6, 1.4)), "task.rest": True,
                     "task.obstacles": discs, "task.clearance": 0.01}
        try:
            p = flatcli.plan(overrides=overrides)
        except FlatcliError as exc:
            refused += 1
            key = str(exc).split(":")[0]
            reasons[key] = reasons.get(key, 0) + 1
            continue
        planned += 1
        assert p.plan is not None
        theta = p.plan.sample(np.linspace(0.0, p.plan.duration, FINE)).theta
        robot = p.plan.robot
        gap = link_clearance(np.asarray(robot.mass), np.asarray(robot.length),
                             np.asarray(robot.com), theta, np.asarray(discs))
        margin = float(gap.min()) - 0.01
        least = min(least, margin)
        violations += int(margin < 0)
    seconds = time.perf_counter() - started
    why = ", ".join(f"{n} {k}" for k, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
    bench.row(RANDOM, count, planned, refused, violations, f"{least:.3g}",
              "met" if violations == 0 else "not met",
              f"{seconds:.0f} s in all; refused by {why or 'nothing'}")
    return {"tasks": count, "planned": planned, "refused": refused, "violations": violations,
            "least_margin": least, "seconds": seconds, "refused_by": reasons}


def near_discs(rng: np.random.Generator, joints: Complex, count: int, low: float,
               high: float) -> Array | None:
    """(count, 3) discs x, y, radius [m] whose least gap from the links over every sample of
    joints (N + 2, n) (``link_joints``) lies in [low, high] [m], drawn by rejection: centres
    uniform in [-0.35, 0.35]^2 [m], radii in [0.02, 0.05] [m], BATCH at a time; None when
    MOST_CANDIDATES are not enough.

    The coarser grids (every ``SCREENS``-th sample) only rule candidates out: with D the
    farthest any joint gets from its grid's nearest sample, the gap at every sample lies in
    [g - D, g] of the grid's least gap g (a point's distance from a segment moves by no more
    than the segment's ends do), so g < low or g - D > high rules a disc out; every disc kept
    is decided on all n samples."""
    n = joints.shape[1]
    screens = []
    for step in SCREENS:
        last = (n - 1) // step * step
        nearest = np.minimum((np.arange(n) + step // 2) // step * step, last)
        screens.append((joints[:, ::step], float(np.abs(joints - joints[:, nearest]).max())))
    found: list[Array] = []
    for _ in range(MOST_CANDIDATES // BATCH):
        candidates = np.column_stack([rng.uniform(-0.35, 0.35, (BATCH, 2)),
                                      rng.uniform(0.02, 0.05, BATCH)])
        keep = np.ones(BATCH, dtype=bool)
        for grid, reach in screens:
            least = disc_gaps(grid, candidates[keep]).min(axis=(1, 2))
            keep[keep] = (least >= low) & (least - reach <= high)
        for disc in candidates[keep]:
            if low <= float(disc_gaps(joints, disc[None]).min()) <= high:
                found.append(disc)
                if len(found) == count:
                    return np.array(found)
    return None


@dataclass(frozen=True)
class FeasibleTask:
    """A feasible random task (``feasible_tasks``) and what flatcli made of it.

    Attributes
    ----------
    rest : rest to rest (else th1' = +-RATES at the ends, the sign th1's motion's)
    start, goal : (4,) the witness's th0, th1, th2 [rad], th1' [rad/s] at t = 0 and T
    duration : T [s]
    obstacles : (DISCS, 3) discs x, y, radius [m]
    witness_gap : least gap of the witness's links from the discs on the FINE grid [m]
    witness_step : the farthest any of its joints moves between two FINE samples [m] (up to
        NEAR[0], the draw's margin covers the motion between samples; beyond it the task is
        feasible on the grid only)
    planned : flatcli planned it (else refused)
    margin : least gap of flatcli's plan from the discs on the FINE grid less CLEARANCE [m]
        (nan: refused)
    seconds : ``flatcli.plan`` of the task with its discs [s]
    candidates : flatcli's task_candidates (0: refused)
    witness_kept : flatcli's plan is the witness (the same angles on the FINE grid, to 1e-12
        rad)
    """

    rest: bool
    start: Array
    goal: Array
    duration: float
    obstacles: Array
    witness_gap: float
    witness_step: float
    planned: bool
    margin: float
    seconds: float
    candidates: int
    witness_kept: bool


def _states(plan: Any, t: Array) -> Array:
    """(n, 4) th0, th1, th2 [rad], th1' [rad/s] of a flatcli plan at times t (n,) [s]."""
    return np.asarray(plan.evaluate(t)[0], dtype=float)


def feasible_tasks(bench: Any, count: int, seed: int = 2121,
                   keep: int = 50) -> tuple[dict[str, Any], list[FeasibleTask]]:
    """``count`` feasible random tasks planned by flatcli and re-checked (module docstring).

    Task i rests when i is even. A draw whose obstacle-free task flatcli refuses (target out
    of reach, only across sin th1 = 0, a margin zero inside) or where no three discs are
    found is drawn again, and counted.

    Returns
    -------
    the raw numbers, and the first ``keep`` tasks that do not rest (for python-control)
    """
    import flatcli
    from flatcli.core.errors import FlatcliError

    rng = np.random.default_rng(seed)
    mass, length, com = PAPER
    low, high = CLEARANCE + NEAR[0], CLEARANCE + NEAR[1]
    tasks: list[FeasibleTask] = []
    kept: list[FeasibleTask] = []
    witness_refused = crowded = 0
    witness_refusals: dict[str, int] = {}
    messages: list[str] = []
    refused_tasks: list[dict[str, Any]] = []  # the first refusals' overrides, to reproduce
    started = time.perf_counter()
    for i in range(count):
        rest = i % 2 == 0
        while True:
            radius = rng.uniform(0.12, 0.3)
            angle = rng.uniform(-math.pi, math.pi)
            overrides: dict[str, Any] = {
                "task.end_effector": [radius * math.cos(angle), radius * math.sin(angle)],
                "task.base_attitude": float(rng.uniform(0.6, 1.4)), "task.rest": rest}
            if not rest:
                overrides.update({"plan.start_rate": RATES[0], "plan.goal_rate": RATES[1]})
            try:
                witness = flatcli.plan(overrides=overrides).plan
            except FlatcliError as exc:
                witness_refused += 1
                key = str(exc).split(":")[0]
                witness_refusals[key] = witness_refusals.get(key, 0) + 1
                continue
            assert witness is not None
            robot = witness.robot
            assert np.array_equal(robot.mass, mass) and np.array_equal(robot.length, length) \
                and np.array_equal(robot.com, com), "the spec's robot is not the paper's"
            t = np.linspace(0.0, witness.duration, FINE)
            state = _states(witness, t)
            joints = link_joints(mass, length, com, state[:, :3])
            discs = near_discs(rng, joints, DISCS, low, high)
            if discs is None:
                crowded += 1
                continue
            break
        step = float(np.abs(np.diff(joints, axis=1)).max())
        witness_gap = float(disc_gaps(joints, discs).min())
        assert low <= witness_gap <= high
        overrides.update({"task.obstacles": discs.tolist(), "task.clearance": CLEARANCE})
        clock = time.perf_counter()
        try:
            p = flatcli.plan(overrides=overrides)
            seconds = time.perf_counter() - clock
        except FlatcliError as exc:
            seconds = time.perf_counter() - clock
            if len(messages) < MESSAGES:
                messages.append(str(exc))
                refused_tasks.append(dict(overrides))
            task = FeasibleTask(rest, state[0], state[-1], witness.duration, discs,
                                witness_gap, step, False, math.nan, seconds, 0, False)
        else:
            assert p.plan is not None
            theta = _states(p.plan, t)[:, :3]
            margin = float(link_clearance(mass, length, com, theta, discs).min()) - CLEARANCE
            task = FeasibleTask(rest, state[0], state[-1], witness.duration, discs,
                                witness_gap, step, True, margin, seconds,
                                int(p.metrics["task_candidates"]),
                                bool(np.allclose(theta, state[:, :3], rtol=0, atol=1e-12)))
        tasks.append(task)
        if not rest and len(kept) < keep:
            kept.append(task)
    total = time.perf_counter() - started

    def figures(group: list[FeasibleTask]) -> dict[str, Any]:
        planned = [x for x in group if x.planned]
        margins = [x.margin for x in planned]
        return {
            "tasks": len(group), "planned": len(planned),
            "refused": len(group) - len(planned),
            "refused_slow_witness": sum(not x.planned and x.witness_step <= NEAR[0]
                                        for x in group),
            "violations": sum(m < 0 for m in margins),
            "least_margin": min(margins, default=math.nan),
            "median_plan_seconds": float(np.median([x.seconds for x in planned]))
            if planned else math.nan,
            "max_seconds": max((x.seconds for x in group), default=math.nan),
            "witness_kept": sum(x.witness_kept for x in planned),
            "candidates": [x.candidates for x in group],
        }

    out: dict[str, Any] = {
        "all": figures(tasks),
        "rest": figures([x for x in tasks if x.rest]),
        "not_rest": figures([x for x in tasks if not x.rest]),
        "seconds": total,
        "seconds_per_task": total / max(count, 1),
        "witness_refused": witness_refused,
        "witness_refused_by": witness_refusals,
        "crowded": crowded,
        "least_witness_gap": min((x.witness_gap for x in tasks), default=math.nan),
        "witness_steps_beyond_margin": sum(x.witness_step > NEAR[0] for x in tasks),
        "witness_max_step": max((x.witness_step for x in tasks), default=math.nan),
        "refusal_messages": messages,
        "refused_overrides": refused_tasks,
        "plan_seconds": [x.seconds for x in tasks],
    }
    for name, label in (("rest", "rest to rest"), ("not_rest", "not at rest"), ("all", "all")):
        f = out[name]
        met = f["violations"] == 0 and f["refused"] == 0
        if name == "all":
            note = (f"{total:.0f} s in all ({1e3 * out['seconds_per_task']:.0f} ms a task); "
                    f"{witness_refused} witness draws refused, {crowded} without room for "
                    f"discs; {out['witness_steps_beyond_margin']} witnesses move a joint more "
                    f"than {NEAR[0] * 1e3:.0f} mm between two samples (at most "
                    f"{out['witness_max_step'] * 1e3:.3g} mm): feasible on the grid only"
                    + (f"; the first refusal: {messages[0][:150]}" if messages else ""))
        else:
            note = (f"slowest {1e3 * f['max_seconds']:.0f} ms; flatcli's plan is the "
                    f"witness {f['witness_kept']} times; refused with a witness that moves "
                    f"<= {NEAR[0] * 1e3:.0f} mm between samples: {f['refused_slow_witness']}")
        bench.row(FEASIBLE, f["tasks"], label, f["planned"], f["refused"], f["violations"],
                  f"{f['least_margin']:.3g}", f"{1e3 * f['median_plan_seconds']:.1f}",
                  "met" if met else "not met", note)
    return out, kept


def python_control_tasks(bench: Any, tasks: list[FeasibleTask]) -> dict[str, Any]:
    """The tasks (``feasible_tasks``' that do not rest) through python-control's flatsys
    (``pc_obstacle_task``, SLSQP's iteration limit PC_MAX_ITER): from the witness's start
    state to its goal state, zero end inputs, the clearance and the singularity margin at its
    time points; beside flatcli's figures on the same tasks."""
    from benchmarks.baselines.pcflatsys import pc_obstacle_task, robot_flat_system
    from benchmarks.baselines.problem import Maneuver

    system = robot_flat_system(Maneuver().coefficients)
    runs = []
    started = time.perf_counter()
    for task in tasks:
        maneuver = Maneuver(start=(float(task.start[0]), float(task.start[1]),
                                   float(task.start[2])),
                            goal=(float(task.goal[0]), float(task.goal[1]),
                                  float(task.goal[2])),
                            start_rate=float(task.start[3]), goal_rate=float(task.goal[3]),
                            duration=task.duration)
        runs.append(pc_obstacle_task(maneuver, task.obstacles, CLEARANCE,
                                     max_iter=PC_MAX_ITER, system=system))
    total = time.perf_counter() - started

    def depth(r: Any) -> float:  # [m], inf: not finite anywhere on the fine grid
        return CLEARANCE - r.fine_clearance if math.isfinite(r.fine_clearance) else math.inf

    solved = [r for r in runs if r.success]
    unsolved = [r for r in runs if not r.success]
    between = [r for r in solved if r.violated_between]
    deepest = max((depth(r) for r in solved), default=math.nan)
    planned = [x for x in tasks if x.planned]
    flat_violations = sum(x.margin < 0 for x in planned)
    flat_median = float(np.median([x.seconds for x in planned])) if planned else math.nan
    pc_median = float(np.median([r.seconds for r in runs])) if runs else math.nan
    margin_lost = sum(r.margin_lost_between for r in solved)
    at_points = sum(not r.held_at_points for r in solved)
    deep = sum(depth(r) > DEEP for r in between)
    unsolved_between = sum(r.violated_between for r in unsolved)
    why = ", ".join(sorted({r.message for r in unsolved}))
    bench.row(PYTHON_CONTROL, len(tasks), len(planned), flat_violations,
              f"{1e3 * flat_median:.1f}", len(solved), len(between),
              f"{max(deepest, 0.0):.3g}" if solved else "-", f"{pc_median:.2f}",
              f"SLSQP maxiter {PC_MAX_ITER}, {total:.0f} s in all; of the solved, {deep} "
              f"break the clearance between points by more than {DEEP * 1e3:.1f} mm, "
              f"{at_points} break a constraint at their own points, {margin_lost} lose the "
              f"singularity margin between them; {len(unsolved)} unsolved"
              + (f" ({why}), {unsolved_between} of them held at their points and broken "
                 "between" if unsolved else ""))
    return {
        "tasks": len(tasks), "flatcli_planned": len(planned),
        "flatcli_violations": flat_violations, "flatcli_median_seconds": flat_median,
        "max_iter": PC_MAX_ITER, "solved": len(solved),
        "violated_between_points": len(between), "deeper_than": {"m": DEEP, "count": deep},
        "broken_at_points": at_points, "margin_lost_between_points": margin_lost,
        "unsolved_violated_between_points": unsolved_between,
        "deepest_violation": deepest, "median_seconds": pc_median, "seconds": total,
        "runs": [{"success": r.success, "message": r.message,
                  "points_clearance": r.points_clearance, "fine_clearance": r.fine_clearance,
                  "fine_time": r.fine_time, "points_margin": r.points_margin,
                  "fine_margin": r.fine_margin, "end_error": r.end_error,
                  "nonfinite": r.nonfinite, "seconds": r.seconds} for r in runs],
    }


def run_all(bench: Any) -> None:
    started = time.perf_counter()
    out: dict[str, Any] = {"capture": capture_timing(bench),
                           "random": random_tasks(bench, 40 if bench.quick else 300)}
    out["feasible"], subset = feasible_tasks(bench, 200 if bench.quick else 10_000,
                                             keep=5 if bench.quick else 50)
    out["python_control"] = python_control_tasks(bench, subset)
    out["seconds"] = time.perf_counter() - started
    bench.raw["tasks"] = out
