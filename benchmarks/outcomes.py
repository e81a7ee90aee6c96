"""make bench: what outcomes (issue 39) cost a study, each new cost against the trial's own.

* judging a trial in Python (``core.outcome.judge``: its reason in words, the end effector of
  a task at its final angles), per trial, against a trial of the paper's sweep on the
  kernel (both in this process, one thread);
* the closed-loop clearance of a task with obstacles (``simulate(..., obstacles=...)``: each
  trial recorded, 32 at a time, and its motion checked between samples), as the ratio of a
  trial's time with and without it, the kinematic plant on the non-rest capture task;
* scipy.stats, whose ``binomtest`` the summary's Wilson intervals equal (their closed form,
  written out in numpy; the tests compare them): its import in a fresh process that already
  holds numpy and pyarrow, as a sweep's main process does, is what a sweep would pay to call
  binomtest itself; and the summary of a 100-cell sweep with its outcome columns.

The per-sample flag of a clipped rate and the final angles the kernels return (the kernel
changes) are priced by the sweeps section: flatcli's sweep against the same-work hand-written
kernel, the ratio docs/performance.md records before and after.
"""

from __future__ import annotations

import subprocess
import sys
import time
from typing import Any

import numpy as np

from flatcli.core.loop.outcome import Geometry, Goal, judge

SECTION = "Outcomes (issue 39): what judging the trials costs"
HEADERS = {SECTION: ["what", "per trial", "against a trial's own", "note"]}
#: The non-rest capture task of tests/test_outcome.py (the kernels, three discs).
CAPTURE = {"plan.start": [1.8, 1.0, 0.0], "task.end_effector": [-0.25, 0.05],
           "task.base_attitude": 1.0,
           "task.obstacles": [[0.2, 0.2, 0.05], [-0.25, -0.25, 0.04], [0.0, 0.3, 0.03]],
           "task.clearance": 0.01, "track.initial": [1.8, 1.0, 0.0], "track.kp": [100, 110],
           "track.kv": [10, 13]}


def _trial_seconds(scenario: Any, trials: Any, obstacles: Any = None, repeats: int = 3
                   ) -> float:
    """The least, over ``repeats``, of the seconds per trial of ``simulate``."""
    from flatcli.core.loop.simulate import simulate

    simulate(scenario, trials.subset(slice(0, 2)), obstacles=obstacles)  # compiled, warm
    best = np.inf
    for _ in range(repeats):
        started = time.perf_counter()
        simulate(scenario, trials, obstacles=obstacles)
        best = min(best, time.perf_counter() - started)
    return float(best / trials.count)


def _perturbed(spec: Any, plan: Any, count: int) -> Any:
    """``count`` trials of a spec's nominal trial, th(0) off by up to 2 mrad."""
    from flatcli.core.loop.simulate import Trials
    from flatcli.experiment import nominal_trials

    one = nominal_trials(spec, plan)
    rng = np.random.default_rng(39)
    initial = np.repeat(one.initial, count, axis=0)
    initial[:, :3] += rng.uniform(-0.002, 0.002, (count, 3))
    return Trials(np.repeat(one.links, count, axis=0), np.repeat(one.momentum, count),
                  initial, None, np.repeat(one.servo_table(), count, axis=0),
                  np.repeat(one.across, count) if one.across is not None else None)


def judging(bench: Any, count: int) -> dict[str, float]:
    """Seconds per trial of ``judge`` on ``count`` made-up trials of a task (a target, half of
    them within tolerance), and of a paper trial on the kernel."""
    import flatcli
    from flatcli.experiment import robot_from

    rng = np.random.default_rng(3)
    final = rng.normal(0.0, 2e-3, (count, 3))
    robot = robot_from(flatcli.load_spec())
    geometry = Geometry.of(np.tile(robot.as_array(), (count, 1)))
    goal = Goal(np.zeros(3), 1e-3, np.array([0.1, 0.1]), 1e-3)
    started = time.perf_counter()
    judge(["ok"] * count, [""] * count, final, goal, geometry)
    per_judge = (time.perf_counter() - started) / count
    run = flatcli.track(overrides={"track.kp": [100, 110], "track.kv": [10, 13]}, quiet=True).run
    assert run is not None
    trial = _trial_seconds(run.scenario, _perturbed(run.spec, run.plan, 200))
    bench.row(SECTION, f"judging a trial (core.outcome.judge, {count} trials of a task)",
              f"{per_judge * 1e6:.1f} us", f"{per_judge / trial:.3f}x",
              f"a paper trial on the kernel (default twin estimate): {trial * 1e3:.2f} ms")
    return {"judge_seconds": per_judge, "trial_seconds": trial}


def clearance(bench: Any, count: int) -> dict[str, float]:
    """Seconds per trial of the non-rest capture task with and without its closed-loop
    clearance."""
    import flatcli

    run = flatcli.track(overrides=CAPTURE, quiet=True).run
    assert run is not None
    trials = _perturbed(run.spec, run.plan, count)
    without = _trial_seconds(run.scenario, trials)
    with_ = _trial_seconds(run.scenario, trials, run.spec.task.obstacles)
    bench.row(SECTION, f"closed-loop clearance of a task with 3 discs ({count} trials, dt = "
              f"{run.scenario.dt:g} s, {run.scenario.n_steps + 1} samples)",
              f"{(with_ - without) * 1e3:.2f} ms", f"{with_ / without:.2f}x",
              f"a trial {without * 1e3:.2f} ms without it, {with_ * 1e3:.2f} ms with it "
              "(recorded, and its motion checked between samples); only where the spec has "
              "task.obstacles")
    return {"without_seconds": without, "with_seconds": with_}


def statistics(bench: Any, cells: int) -> dict[str, float]:
    """scipy.stats' import in a fresh process holding numpy and pyarrow, and the summary of
    ``cells`` cells of 1,000 trials."""
    from flatcli.report.summary import summary_rows

    code = ("import time, numpy, pyarrow\nt = time.perf_counter()\nimport scipy.stats\n"
            "print(time.perf_counter() - t)")
    imports = [float(subprocess.run([sys.executable, "-c", code], capture_output=True,
                                    text=True, check=True).stdout) for _ in range(3)]
    per = 1000
    n = cells * per
    rng = np.random.default_rng(5)
    columns = {"cell": np.repeat(np.arange(cells), per),
               "status": np.array(["ok"] * n, dtype=object),
               "outcome": rng.choice(np.array(["reached", "missed", "lost"], dtype=object), n),
               **{m: rng.random(n) for m in ("err_theta_rms", "err_theta_final", "err_y_rms",
                                             "err_y_final", "min_margin", "momentum_drift",
                                             "plan_momentum_residual", "peak_rate",
                                             "err_estimate", "singular_hits", "clipped_time")}}
    started = time.perf_counter()
    summary_rows(columns, {c: {} for c in range(cells)})
    seconds = time.perf_counter() - started
    bench.row(SECTION, "scipy.stats imported, fresh process (not done by a sweep: its "
              "Wilson intervals are binomtest's closed form in numpy)",
              f"{np.median(imports):.2f} s once", "",
              f"range {min(imports):.2f}-{max(imports):.2f} s: what calling binomtest "
              "itself would add to every sweep")
    bench.row(SECTION, f"the summary of {cells} cells of {per} trials, outcomes included",
              f"{seconds / n * 1e6:.2f} us", "", f"{seconds:.2f} s in all")
    return {"import_seconds": float(np.median(imports)), "summary_seconds": seconds}


def run_all(bench: Any) -> None:
    quick = bench.quick
    bench.raw["outcomes"] = {
        **judging(bench, 2000 if quick else 20_000),
        **clearance(bench, 32 if quick else 128),
        **statistics(bench, 10 if quick else 100),
    }
