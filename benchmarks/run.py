"""``make bench``: flatcli's speed and accuracy, measured in one run beside the alternatives.

Prints the tables and writes them to ``OUT/bench.md`` and ``OUT/bench.json`` (with the
machine, its load before and after each measurement, and every raw number). Benchmarks are
not tests: nothing here asserts a time.

    python -m benchmarks.run [--out runs/bench] [--million] [--quick] [--sections a,b]

Sweeps run as ``python -m flatcli.cli sweep`` subprocesses (the command a user runs, in a
fresh process); their own run.json gives the in-process throughput and each process's own
peak memory (VmHWM), and the wall time around the subprocess the whole process's. Ratios
are taken between runs interleaved in one call (A B A B ...), pair by pair, and reported as
medians: this shared machine's speed drifts by tens of percent over minutes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from benchmarks.asbuilt import HEADERS as ASBUILT_HEADERS
from benchmarks.asbuilt import run_all as run_asbuilt
from benchmarks.baselines import (
    PAPER_MANEUVER,
    PAPER_TRACKING,
    compiled_trials_per_second,
    dopri_inputs,
    dopri_metrics,
    machine_info,
    numpy_trials_per_second,
    paper_trials,
    pc_optimal,
    pc_point_to_point,
    plan_quality,
    rhs_nanoseconds,
    robot_flat_system,
    shooting_plan,
    solve_ivp_trials_per_second,
    timed,
)
from benchmarks.baselines.floor import floor_seconds
from benchmarks.chains import HEADERS as CHAIN_HEADERS
from benchmarks.chains import run_all as run_chains
from benchmarks.front_door import HEADERS as FRONT_HEADERS
from benchmarks.front_door import compiles as run_compiles
from benchmarks.front_door import run_all as run_front_door
from benchmarks.integrators import HEADERS as INTEGRATOR_HEADERS
from benchmarks.integrators import run_all as run_integrators
from benchmarks.integrators import twin_factors
from benchmarks.mpc import HEADERS as MPC_HEADERS
from benchmarks.mpc import run_all as run_mpc
from benchmarks.outcomes import HEADERS as OUTCOME_HEADERS
from benchmarks.outcomes import run_all as run_outcomes
from benchmarks.search import HEADERS as SEARCH_HEADERS
from benchmarks.search import run_all as run_search
from benchmarks.tasks import HEADERS as TASK_HEADERS
from benchmarks.tasks import run_all as run_tasks
from flatcli.core.loop.metrics import METRIC_NAMES
from flatcli.core.loop.simulate import Scenario, simulate
from flatcli.core.optimize import PlanLimits, optimize_plan
from flatcli.core.plan.planning import plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT
from flatcli.report import fmt, table
from flatcli.storage import to_jsonable, write_json, write_text
from flatcli.threads import limit_process

HERE = Path(__file__).resolve().parent
SPEC = HERE / "paper_sweep.toml"
GRID_POINTS = 200
PLANNING = "Planning: the paper's maneuver"
CLOSED_LOOP = ("Closed loop, the same work: flatcli against a hand-written kernel (adaptive "
               "Dormand-Prince, metrics at every output sample)")
SWEEPS = ("flatcli sweep through the command line: benchmarks/paper_sweep.toml, everything "
          "written")
SCALING = "Scaling: 2 workers, each process's own peak memory"
#: The sections ``make bench`` runs, in this order; ``--sections`` may name them and
#: ``OPTIONAL`` ones (run only when named: minutes each).
SECTIONS = ("planning", "closed_loop", "sweeps", "front_door", "integrators", "chains",
            "asbuilt", "optimised", "tasks", "outcomes", "search", "mpc")
OPTIONAL = ("compiles", "twin_factors")


def load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


class Bench:
    """Collects measurements (rows of tables) and the raw numbers behind them."""

    def __init__(self, out: Path, quick: bool) -> None:
        self.out = out
        self.quick = quick
        self.tables: dict[str, list[list[Any]]] = {}
        self.raw: dict[str, Any] = {"machine": machine_info(), "loads": {}}
        self.started = time.perf_counter()

    def measure(self, section: str, name: str, fn: Callable[[], Any]) -> Any:
        before = load()
        print(f"  {section}: {name} ...", flush=True)
        value = fn()
        self.raw["loads"][f"{section}: {name}"] = {"before": before, "after": load()}
        return value

    def row(self, section: str, *cells: Any) -> None:
        self.tables.setdefault(section, []).append(list(cells))


def sweep(spec: Path, out: Path, trials: int, workers: int, *extra: str) -> dict[str, Any]:
    """Run ``flatcli sweep`` in a fresh process; its timing, memory and the outer wall time.

    ``startup_seconds``: the whole process's wall time less the sweep's own from its first
    chunk on (interpreter, imports, spec, planning the cells, loading the compiled kernel);
    ``steady_trials_per_second`` (the sweep's) leaves it out. Memory: each process's own
    peak (VmHWM, flatcli's run.json), whatever the size of this process that started it."""
    shutil.rmtree(out, ignore_errors=True)
    command = [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out", str(out),
               "-q", "--workers", str(workers), "--set", f"sweep.trials={trials}", *extra]
    t0 = time.perf_counter()
    subprocess.run(command, check=True)
    wall = time.perf_counter() - t0
    record = json.loads((out / "run.json").read_text())
    timing = record["timing"]
    return {
        "trials": trials,
        "workers": workers,
        "extra": list(extra),
        "trials_per_second": timing["trials_per_second"],
        "steady_trials_per_second": timing["steady_trials_per_second"],
        "setup_seconds": timing["setup_seconds"],
        "finish_seconds": timing["finish_seconds"],
        "sweep_seconds": timing["wall_seconds"],
        "process_seconds": wall,
        "process_trials_per_second": trials / wall,
        "startup_seconds": wall - (timing["wall_seconds"] - timing["setup_seconds"]),
        "write_cpu_us_per_trial": 1e6 * timing.get("write_cpu_seconds", math.nan) / trials,
        "sync_us_per_trial": 1e6 * timing.get("sync_seconds", math.nan) / trials,
        "peak_rss_mib": timing["peak_rss_mib"],
        "status_counts": record["status_counts"],
        "executor": timing["executor"],
    }


def median(values: list[float]) -> float:
    return float(np.median(values))


def spread_text(values: list[float], digits: int = 0) -> str:
    """The range of interleaved repeats, 'min-max'."""
    return f"{min(values):.{digits}f}-{max(values):.{digits}f}"


#: Same work as the same-work kernel: one solution per trial (flatcli's default "twin"
#: integrates each trial twice, for its err_estimate).
SAME_WORK = ("--set", "track.error_estimate=none")


def planning(bench: Bench) -> None:
    """The paper's maneuver: flatcli's core planner, flatcli.plan(), python-control's flatsys
    (on flat maps written in the baseline), SLSQP shooting; interleaved rounds, medians."""
    import flatcli

    section = PLANNING
    t = np.linspace(0.0, PAPER_MANEUVER.duration, GRID_POINTS)
    start, goal = np.array(PAPER_MANEUVER.start), np.array(PAPER_MANEUVER.goal)

    def core_plan() -> Any:
        return plan_point_to_point(PAPER_ROBOT, start, goal, 0.1, 0.5, 2.0)

    def core_record() -> Any:  # what flatcli.plan() computes: the plan at its 201 samples
        planned = core_plan()
        return planned.sample(planned.grid(201))

    system = robot_flat_system(PAPER_MANEUVER.coefficients)
    flatcli.plan()  # validates and remembers the default spec, loads the API
    rounds = 3 if bench.quick else 7
    times: dict[str, list[float]] = {k: [] for k in (
        "evaluate", "plan", "record", "api", "api_frame", "python_control")}
    agreement = 0.0
    for _ in range(rounds):  # interleaved: a drift of the machine's speed hits all alike
        times["evaluate"].append(timed(lambda: core_plan().evaluate(t), 100, 5).median)
        times["plan"].append(timed(core_plan, 100, 5).median)
        times["record"].append(timed(core_record, 100, 5).median)
        times["api"].append(timed(flatcli.plan, 100, 5).median)
        times["api_frame"].append(timed(lambda: flatcli.plan().frame, 30, 2).median)
        run = bench.measure(section, "python-control", lambda: pc_point_to_point(system=system))
        times["python_control"].append(run.seconds)
        agreement = max(agreement, run.max_theta_error)
    m = {k: median(v) for k, v in times.items()}
    shooting = bench.measure(section, "shooting NLP", lambda: [
        shooting_plan() for _ in range(2 if bench.quick else 5)])
    shoot_seconds = median([s.seconds for s in shooting])
    shoot_fd = bench.measure(section, "shooting NLP, finite differences",
                             lambda: shooting_plan(exact_gradients=False))
    batch_n = 10_000
    rng = np.random.default_rng(0)
    starts = start + 0.01 * rng.standard_normal((batch_n, 3))
    goals = goal + 0.01 * rng.standard_normal((batch_n, 3))
    many = bench.measure(section, "flatcli.plan_many, 10,000 maneuvers", lambda: timed(
        lambda: flatcli.plan_many(start=starts, goal=goals), repeat=3))
    many_samples = timed(lambda: flatcli.plan_many(start=starts, goal=goals).samples,
                         repeat=1, warmup=0)
    us = 1e6
    bench.row(section, "flatcli core: plan + states and inputs at 200 points",
              f"{m['evaluate'] * us:.0f} us", "", f"plan alone {m['plan'] * us:.0f} us")
    bench.row(section, "flatcli core: plan + full record at 201 samples (the core planner)",
              f"{m['record'] * us:.0f} us", "1x", "states, exact rates, inputs, margin, H")
    bench.row(section, "flatcli.plan() (spec validated once, 201 samples; .frame on first use)",
              f"{m['api'] * us:.0f} us", f"{m['api'] / m['record']:.2f}x",
              f"target <= 2x; with .frame {m['api_frame'] * us:.0f} us")
    bench.row(section, "python-control flatsys point_to_point + eval at 200 points",
              f"{m['python_control'] * 1e3:.1f} ms",
              f"{m['python_control'] / m['record']:.0f}x",
              f"its own flat maps (benchmarks/baselines/pcflatsys.py); same trajectory to "
              f"{agreement:.1e} rad")
    bench.row(section, "  python-control against flatcli.plan()", "",
              f"{m['python_control'] / m['api']:.0f}x", "target >= 100x")
    bench.row(section, "shooting NLP (SLSQP, 40 intervals, exact gradients)",
              f"{shoot_seconds * 1e3:.0f} ms", f"{shoot_seconds / m['record']:.0f}x",
              f"energy {shooting[0].objective:.2f} (not momentum-exact: "
              f"{shooting[0].integration_error:.0e} rad)")
    bench.row(section, "shooting NLP, finite-difference gradients",
              f"{shoot_fd.seconds * 1e3:.0f} ms", f"{shoot_fd.seconds / m['record']:.0f}x",
              f"{shoot_fd.evaluations} evaluations")
    bench.row(section, "flatcli.plan_many: 10,000 maneuvers",
              f"{many.median * 1e3:.1f} ms", f"{many.median / batch_n * us:.1f} us/plan",
              f"+ their samples at 201 points: {many_samples.median:.2f} s "
              f"({many_samples.median / batch_n * us:.0f} us/plan)")
    bench.raw["planning"] = {
        "rounds": rounds, "seconds": times, "medians": m,
        "python_control_agreement_rad": agreement,
        "ratio_api_to_core": m["api"] / m["record"],
        "ratio_python_control_to_core": m["python_control"] / m["record"],
        "ratio_python_control_to_api": m["python_control"] / m["api"],
        "shooting_seconds": shoot_seconds, "shooting_fd_seconds": shoot_fd.seconds,
        "plan_many_10000_seconds": many.median,
        "plan_many_10000_samples_seconds": many_samples.median,
    }


def closed_loop(bench: Bench) -> None:
    """flatcli's simulate against the same-work kernel, in this process: one core against one
    thread, both with one solution per trial; the kernel on two threads; observe_every."""
    section = CLOSED_LOOP
    n = 2000 if bench.quick else 10_000
    trials = paper_trials(n, seed=1)
    plan = PAPER_MANEUVER.cubic()
    gains, dt = PAPER_TRACKING.gains, PAPER_TRACKING.dt
    none = Scenario(plan, gains, dt, twin=0.0).prepared()
    twin = Scenario(plan, gains, dt).prepared()
    sparse = Scenario(plan, gains, dt, twin=0.0, observe_every=10).prepared()
    inputs = dopri_inputs(plan, trials)
    one = trials.subset(slice(0, 2))
    for scenario in (none, twin, sparse):
        simulate(scenario, one)
    dopri_metrics(plan, one)
    rounds = 2 if bench.quick else 3
    rates: dict[str, list[float]] = {k: [] for k in (
        "flatcli", "kernel_1", "kernel_2", "flatcli_twin", "flatcli_every10", "kernel_every10",
        "kernel_ends")}

    def rate(fn: Callable[[], object]) -> float:
        return n / timed(fn, repeat=1, warmup=0).median

    for _ in range(rounds):
        rates["flatcli"].append(bench.measure(section, "flatcli", lambda: rate(
            lambda: simulate(none, trials))))
        rates["kernel_1"].append(bench.measure(section, "kernel, 1 thread", lambda: rate(
            lambda: dopri_metrics(plan, trials, threads=1, inputs=inputs))))
        rates["kernel_2"].append(bench.measure(section, "kernel, 2 threads", lambda: rate(
            lambda: dopri_metrics(plan, trials, threads=2, inputs=inputs))))
        rates["flatcli_twin"].append(rate(lambda: simulate(twin, trials)))
        rates["flatcli_every10"].append(rate(lambda: simulate(sparse, trials)))
        rates["kernel_every10"].append(rate(
            lambda: dopri_metrics(plan, trials, threads=1, inputs=inputs, every=10)))
        rates["kernel_ends"].append(rate(
            lambda: dopri_metrics(plan, trials, threads=1, inputs=inputs,
                                  every=none.n_steps)))
    ratio = [a / b for a, b in zip(rates["flatcli"], rates["kernel_1"], strict=True)]
    ratio10 = [a / b for a, b in zip(rates["flatcli_every10"], rates["kernel_every10"],
                                     strict=True)]
    m = {k: median(v) for k, v in rates.items()}
    counts = simulate(none, trials.subset(slice(0, 200))).metrics
    steps = float(np.median(counts[:, METRIC_NAMES.index("steps")]))
    rhs = float(np.median(counts[:, METRIC_NAMES.index("rhs_evaluations")]))
    bench.row(section, f"flatcli simulate, one solution per trial (error_estimate none), batch "
              f"of {n}", f"{m['flatcli']:.0f}", f"{median(ratio):.2f}x kernel (1 thread)",
              f"{1e6 / m['flatcli']:.0f} us/trial; {steps:.0f} steps, {rhs:.0f} rhs, all "
              "metrics at 2,001 samples")
    bench.row(section, "same-work kernel (benchmarks/baselines/dopri.py), 1 thread",
              f"{m['kernel_1']:.0f}", "", f"{1e6 / m['kernel_1']:.0f} us/trial: the floor with "
              "flatcli's outputs")
    bench.row(section, "same-work kernel, 2 threads", f"{m['kernel_2']:.0f}",
              f"{m['kernel_2'] / m['kernel_1']:.2f}x its 1 thread", "")
    bench.row(section, "flatcli simulate, the default (error_estimate twin)",
              f"{m['flatcli_twin']:.0f}", f"{m['flatcli_twin'] / m['flatcli']:.2f}x none",
              "each trial integrated twice: an honest err_estimate")
    bench.row(section, "flatcli simulate, track.observe_every = 10 (none)",
              f"{m['flatcli_every10']:.0f}", f"{median(ratio10):.2f}x kernel at 10",
              f"{m['flatcli_every10'] / m['flatcli']:.2f}x every sample")
    bench.row(section, "same-work kernel, every 10th sample, 1 thread",
              f"{m['kernel_every10']:.0f}", "", f"{1e6 / m['kernel_every10']:.0f} us/trial")
    bench.row(section, "same-work kernel, samples at t = 0 and T only, 1 thread",
              f"{m['kernel_ends']:.0f}", "", f"{1e6 / m['kernel_ends']:.0f} us/trial: the floor "
              "without outputs")
    ns = rhs_nanoseconds(plan, trials)
    floor_us = rhs * ns / 1000.0
    bench.row(section, "arithmetic floor: right-hand sides x one right-hand side's cost",
              f"{1e6 / floor_us:.0f}", f"flatcli {1e6 / m['flatcli'] / floor_us:.2f}x it",
              f"{floor_us:.0f} us/trial = {rhs:.0f} x {ns:.1f} ns (the plan's flag and the loop "
              "at a state, benchmarks/baselines/dopri.py: rhs_nanoseconds)")
    bench.raw["closed_loop"] = {"trials": n, "rounds": rounds, "trials_per_second": rates,
                                "medians": m, "ratio_flatcli_to_kernel_1_thread": ratio,
                                "ratio_every10": ratio10, "steps_median": steps,
                                "rhs_median": rhs, "rhs_ns": ns, "floor_us": floor_us,
                                "ratio_flatcli_to_floor": 1e6 / m["flatcli"] / floor_us}


def closed_loop_rk4(bench: Bench) -> None:
    section = "Closed loop, fixed step: RK4 dt = 1e-3, other ways to write it"
    n = 2000 if bench.quick else 10_000
    trials = paper_trials(n, seed=1)
    plan = PAPER_MANEUVER.cubic()
    scenario = Scenario(plan, PAPER_TRACKING.gains, PAPER_TRACKING.dt).prepared()
    simulate(scenario, trials.subset(slice(0, 1)), "rk4")
    batch = bench.measure(section, "flatcli batch",
                          lambda: timed(lambda: simulate(scenario, trials, "rk4"), repeat=2))
    compiled1 = bench.measure(section, "compiled kernel, 1 thread",
                              lambda: compiled_trials_per_second(plan, trials, threads=1,
                                                                 repeat=2))
    numpy_batch = bench.measure(section, "numpy batch RK4", lambda: numpy_trials_per_second(
        plan, trials.subset(slice(0, min(n, 4000)))))
    ivp = bench.measure(section, "solve_ivp", lambda: solve_ivp_trials_per_second(
        plan, trials.subset(slice(0, 3 if bench.quick else 8))))
    flat_rate = n / batch.median
    bench.row(section, f"flatcli simulate rk4, batch of {n} (1 core)", f"{flat_rate:.0f}",
              f"{flat_rate / compiled1.trials_per_second:.2f}x compiled RK4", "all metrics")
    bench.row(section, "compiled RK4 kernel (numba), 1 thread",
              f"{compiled1.trials_per_second:.0f}", "", "final states only")
    bench.row(section, "numpy vectorised RK4 (1 core)",
              f"{numpy_batch.trials_per_second:.0f}", "", "final states only")
    bench.row(section, "solve_ivp RK45 rtol 1e-8, one trial at a time",
              f"{ivp.trials_per_second:.1f}", "", "final states only")
    bench.raw["closed_loop_rk4"] = {
        "trials": n, "flatcli_batch_per_second": flat_rate,
        "compiled_1_thread": compiled1.trials_per_second,
        "numpy_batch": numpy_batch.trials_per_second, "solve_ivp": ivp.trials_per_second,
    }


def sweeps(bench: Bench, million: bool) -> None:
    """``flatcli sweep`` through the command line against the same-work kernel on 2 threads,
    each sweep paired with a kernel run just before it (interleaved rounds, medians)."""
    section = SWEEPS
    work = bench.out / "sweeps"
    n = 2000 if bench.quick else 10_000
    plan = PAPER_MANEUVER.cubic()
    trials = paper_trials(n, seed=2003)
    inputs = dopri_inputs(plan, trials)
    dopri_metrics(plan, trials.subset(slice(0, 2)))
    rounds = 1 if bench.quick else 5
    runs: dict[str, list[dict[str, Any]]] = {"w2": [], "w1": [], "twin": [], "w10": []}
    kernel: list[float] = []
    floor: list[float] = []
    floor_seconds(work)  # its first run may compile the probe
    for _ in range(rounds):  # interleaved, so drifts hit all alike
        kernel.append(bench.measure(section, "kernel, 2 threads", lambda: n / timed(
            lambda: dopri_metrics(plan, trials, threads=2, inputs=inputs), 1, 0).median))
        floor.append(bench.measure(section, "start-up floor", partial(floor_seconds, work)))
        runs["w10"].append(bench.measure(section, "10 trials", partial(
            sweep, SPEC, work / "w10", 10, 2, *SAME_WORK)))
        runs["w2"].append(bench.measure(section, "2 workers, none", partial(
            sweep, SPEC, work / "w2", n, 2, *SAME_WORK)))
        runs["w1"].append(bench.measure(section, "1 worker, none", partial(
            sweep, SPEC, work / "w1", n, 1, *SAME_WORK)))
        runs["twin"].append(bench.measure(section, "2 workers, default", partial(
            sweep, SPEC, work / "twin", n, 2)))
    same = pd.read_parquet(work / "w1" / "trials.parquet").equals(
        pd.read_parquet(work / "w2" / "trials.parquet"))

    def paired(key: str, name: str = "w2") -> list[float]:
        return [float(r[key]) / k for r, k in zip(runs[name], kernel, strict=True)]

    def med(name: str, key: str) -> float:
        return median([float(r[key]) for r in runs[name]])

    k2 = median(kernel)
    for name, label in (("w2", "2 workers, error_estimate none (the kernel's work)"),
                        ("w1", "1 worker, error_estimate none"),
                        ("twin", "2 workers, the default (error_estimate twin)")):
        whole = [float(r["process_trials_per_second"]) for r in runs[name]]
        bench.row(section, f"{n} trials, {label}",
                  f"{median(whole):.0f} ({spread_text(whole)})",
                  f"{med(name, 'steady_trials_per_second'):.0f}",
                  f"{med(name, 'process_seconds'):.2f} s",
                  f"start-up {med(name, 'startup_seconds'):.2f} s, final tables "
                  f"{med(name, 'finish_seconds'):.2f} s, writing "
                  f"{med(name, 'write_cpu_us_per_trial'):.1f} us/trial (the main thread's "
                  f"CPU; flushing {med(name, 'sync_us_per_trial'):.1f} us/trial in its own "
                  "thread)")
    bench.row(section, "same-work kernel, 2 threads (in this process, no start-up)",
              f"{k2:.0f} ({spread_text(kernel)})", "", f"{n / k2:.2f} s", "")
    bench.row(section, "  flatcli (none, 2 workers) against the kernel",
              f"{median(paired('process_trials_per_second')):.2f}x",
              f"{median(paired('steady_trials_per_second')):.2f}x", "",
              "whole process: target >= 0.85x; excluding start-up: target >= 1.0x")
    bench.row(section, "  the default (twin) against the kernel",
              f"{median(paired('process_trials_per_second', 'twin')):.2f}x",
              f"{median(paired('steady_trials_per_second', 'twin')):.2f}x", "",
              "twice the integration of the kernel's")
    one_two = [float(a["process_trials_per_second"]) / float(b["process_trials_per_second"])
               for a, b in zip(runs["w2"], runs["w1"], strict=True)]
    steady = [float(a["steady_trials_per_second"]) / float(b["steady_trials_per_second"])
              for a, b in zip(runs["w2"], runs["w1"], strict=True)]
    bench.row(section, "  1 to 2 workers (none)", f"{median(one_two):.2f}x",
              f"{median(steady):.2f}x", "", f"identical results: {same}")
    small = [float(r["process_seconds"]) for r in runs["w10"]]
    distance = [a - b for a, b in zip(small, floor, strict=True)]
    bench.row(section, "start-up floor (benchmarks/baselines/floor.py)", "", "",
              f"{median(floor):.3f} s", f"range {spread_text(floor, 3)} s: numpy, numba, "
              "pyarrow.parquet, click, flatcli's numba set-up, one tiny cached kernel")
    bench.row(section, "10 trials, 2 workers, none: start to exit", "", "",
              f"{median(small):.3f} s", f"{median(distance):.3f} s above the floor (paired); "
              "target: start-up under 0.5 s")
    ceiling = [(n / k) / (n / k + f) for k, f in zip(kernel, floor, strict=True)]
    bench.row(section, f"  the whole-process ratio a sweep at the floor would reach ({n} "
              "trials, steady 1.0x)", f"{median(ceiling):.2f}x", "", "",
              "t / (t + floor), t the kernel's time for the trials")
    dyn = bench.measure(section, "dynamic plant, 2 workers", partial(
        sweep, SPEC, work / "dynamic", n, 2, "--set", "plant.model=dynamic"))
    bench.row(section, f"{n} trials, dynamic plant (plant.model = \"dynamic\"), 2 workers, "
              "default", f"{dyn['process_trials_per_second']:.0f}",
              f"{dyn['steady_trials_per_second']:.0f}", f"{dyn['process_seconds']:.1f} s",
              "servo 100 rad/s, no torque limit")
    dask = bench.measure(section, "dask", lambda: sweep(
        SPEC, work / "dask", n, 2, "--executor", "dask", "--scheduler", "local"))
    same_dask = pd.read_parquet(work / "dask" / "trials.parquet").equals(
        pd.read_parquet(work / "twin" / "trials.parquet"))
    bench.row(section, f"{n} trials, Dask LocalCluster of 2 workers, default",
              f"{dask['process_trials_per_second']:.0f}",
              f"{dask['steady_trials_per_second']:.0f}", f"{dask['process_seconds']:.1f} s",
              f"start-up (cluster) {dask['setup_seconds']:.1f} s; identical results: "
              f"{same_dask}")
    bench.raw["sweep"] = {"runs": runs, "kernel_2_threads": kernel, "floor_seconds": floor,
                          "whole_process_ceiling": ceiling,
                          "ratio_whole_process": paired("process_trials_per_second"),
                          "ratio_steady": paired("steady_trials_per_second"),
                          "one_to_two_workers": one_two, "dynamic": dyn, "dask": dask,
                          "identical_1_vs_2_workers": same, "identical_dask": same_dask}
    scaling(bench, million)


def scaling(bench: Bench, million: bool) -> None:
    """Sweeps of 10^3 .. 10^5 (10^6) trials, 2 workers, the default settings (10^6: error
    estimate none, for time): trials/s, and each process's own peak memory."""
    section = SCALING
    work = bench.out / "sweeps"
    sizes = [1000, 10_000] if bench.quick else [1000, 10_000, 100_000]
    repeats = {1000: 1 if bench.quick else 5, 10_000: 1 if bench.quick else 3, 100_000: 1}
    results: dict[int, list[dict[str, Any]]] = {}
    for _ in range(max(repeats.values())):  # interleaved
        for size in sizes:
            if len(results.setdefault(size, [])) < repeats[size]:
                results[size].append(bench.measure(section, f"{size} trials", partial(
                    sweep, SPEC, work / f"n{size}", size, 2)))
    if million:
        results[1_000_000] = [bench.measure(section, "10^6 trials", partial(
            sweep, SPEC, work / "n1000000", 1_000_000, 2, *SAME_WORK))]
    for size, runs in results.items():
        bench.row(section, f"{size:,} trials" + (" (none)" if size == 1_000_000 else ""),
                  f"{median([r['trials_per_second'] for r in runs]):.0f}",
                  f"{median([r['process_trials_per_second'] for r in runs]):.0f}",
                  f"{median([r['process_seconds'] for r in runs]):.1f} s",
                  f"{max(r['peak_rss_mib']['main'] for r in runs):.0f} MiB main, "
                  f"{max(r['peak_rss_mib']['largest_child'] for r in runs):.0f} MiB largest "
                  f"worker ({len(runs)} run{'s' if len(runs) > 1 else ''})")
        shutil.rmtree(work / f"n{size}", ignore_errors=True)
    if 100_000 in results:
        def rate(size: int, key: str) -> float:
            return median([float(r[key]) for r in results[size]])

        inside = rate(1000, "trials_per_second") / rate(100_000, "trials_per_second")
        whole = (rate(1000, "process_trials_per_second")
                 / rate(100_000, "process_trials_per_second"))
        bench.row(section, "10^3 against 10^5 trials", f"{inside:.2f}x", f"{whole:.2f}x", "",
                  "target >= 0.6x")
    bench.raw["scaling"] = {str(k): v for k, v in results.items()}


def optimised(bench: Bench) -> None:
    section = "Optimised plans: least energy, abs(th2) <= 3, rates <= 20, margin >= 0.05"
    limits = PlanLimits(angle_limit=(math.inf, math.inf, 3.0), rate_limit=20.0, min_margin=0.05)
    start, goal = np.array(PAPER_MANEUVER.start), np.array(PAPER_MANEUVER.goal)

    def flat(free: bool) -> Any:
        t0 = time.perf_counter()
        result = optimize_plan(PAPER_ROBOT, start, goal, 2.0, objective="energy", limits=limits,
                               free_rates=free)
        return result, time.perf_counter() - t0

    free, t_free = bench.measure(section, "flatcli free rates", lambda: flat(True))
    fixed, t_fixed = bench.measure(section, "flatcli fixed rates", lambda: flat(False))
    pc = bench.measure(section, "python-control", lambda: pc_optimal())
    shoot = bench.measure(section, "shooting", lambda: shooting_plan(angle_limit=3.0,
                                                                     rate_limit=20.0))
    cubic = plan_quality(PAPER_MANEUVER.cubic(), 3.0, 20.0, 0.05)
    rows = []
    for name, quality, seconds, note in (
        ("paper's cubic (th1' = 0.1, 0.5)", cubic, float("nan"), "violates the limits"),
        ("flatcli, free end rates", plan_quality(free.plan, 3.0, 20.0, 0.05), t_free,
         f"{free.iterations} iterations"),
        ("flatcli, end rates fixed at 0.1, 0.5", plan_quality(fixed.plan, 3.0, 20.0, 0.05),
         t_fixed, f"{fixed.iterations} iterations"),
        ("python-control flatsys, end rates fixed", pc.quality, pc.seconds,
         f"success {pc.success}; limits on its 41 points"),
    ):
        rows.append([name, quality.energy, quality.violation, quality.max_abs_momentum,
                     seconds, note])
    rows.append(["shooting NLP (no flatness), free end rates", shoot.objective, shoot.violation,
                 shoot.integration_error, shoot.seconds,
                 "H: its own th0 integration error [rad]"])
    for r in rows:
        seconds = float(r[4])
        bench.row(section, r[0], fmt(r[1]), fmt(r[2]), fmt(r[3]),
                  "-" if math.isnan(seconds) else f"{seconds:.2f} s", r[5])
    bench.raw["optimised"] = rows


LADDER = "Optimised plans: a ladder of limits (least energy; loosening never costs energy)"


def optimised_ladder(bench: Bench) -> None:
    """Least energy as one limit is loosened step by step, with the optimiser's time."""
    inf = math.inf
    ladders = [
        ("rate_limit [rad/s], abs(th2) <= 3, margin >= 0.05",
         [(f"{r:g}", PlanLimits((inf, inf, 3.0), r, 0.05)) for r in (5.0, 10.0, 20.0, 50.0, inf)]),
        ("angle_limit[2] [rad]",
         [(f"{a:g}", PlanLimits((inf, inf, a))) for a in (2.8, 2.9, 3.0, 3.5, inf)]),
    ]
    start, goal = np.array(PAPER_MANEUVER.start), np.array(PAPER_MANEUVER.goal)
    raw = []
    for name, rungs in ladders:
        for value, limits in rungs:
            run = partial(optimize_plan, PAPER_ROBOT, start, goal, 2.0, limits=limits)
            t0 = time.perf_counter()
            result = bench.measure(LADDER, f"{name} = {value}", run)
            seconds = time.perf_counter() - t0
            bench.row(LADDER, name, value, f"{result.objective:.4f}", f"{seconds:.2f} s",
                      f"{result.iterations} iterations")
            raw.append({"ladder": name, "value": value, "energy": result.objective,
                        "seconds": seconds, "iterations": result.iterations})
    bench.raw["optimised_ladder"] = raw


HEADERS = {
    PLANNING: ["method", "time", "ratio", "note"],
    CLOSED_LOOP: ["method", "trials/s", "ratio", "note"],
    "Closed loop, fixed step: RK4 dt = 1e-3, other ways to write it":
        ["method", "trials/s", "ratio", "note"],
    SWEEPS: ["run", "trials/s, whole process (range)", "trials/s excluding start-up",
             "wall", "note"],
    SCALING: ["sweep", "trials/s (in process)", "trials/s (whole process)", "wall",
              "peak memory (VmHWM)"],
    **INTEGRATOR_HEADERS,
    **CHAIN_HEADERS,
    **FRONT_HEADERS,
    **ASBUILT_HEADERS,
    **TASK_HEADERS,
    **OUTCOME_HEADERS,
    **MPC_HEADERS,
    **SEARCH_HEADERS,
    "Optimised plans: least energy, abs(th2) <= 3, rates <= 20, margin >= 0.05":
        ["plan", "energy [rad^2/s]", "limit violation", "max abs(H)", "time", "note"],
    LADDER: ["limit", "value", "energy [rad^2/s]", "time", "note"],
}


def report(bench: Bench) -> str:
    m = bench.raw["machine"]
    lines = [
        "# flatcli benchmarks",
        "",
        f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} in one run of "
        f"`make bench` ({time.perf_counter() - bench.started:.0f} s) on {m.get('cpu', '?')}, "
        f"{m.get('cores', '?')} cores, load average {load()} at the end (before/after each "
        "measurement in bench.json).",
        "",
        "Sweep throughputs: *whole process* is every trial over the wall time of the "
        "`flatcli sweep` process, from its start to its exit (interpreter, imports, planning, "
        "loading the compiled kernel, the chunks, trials.parquet and the summary); "
        "*excluding start-up* leaves out everything before the first chunk, as the kernel's "
        "timing leaves out its compilation. Ratios pair each sweep with the kernel run just "
        "before it and take the median of the pairs. Same-work comparisons set "
        "`track.error_estimate = \"none\"` (one solution per trial, as the kernel); the "
        "default, \"twin\", integrates each trial twice for its err_estimate. Memory: each "
        "process's own peak (VmHWM), not the ru_maxrss Linux carries over from the process "
        "that started it.",
    ]
    for section, rows in bench.tables.items():
        lines += ["", f"## {section}", "", table(HEADERS[section], rows)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/bench"))
    parser.add_argument("--million", action="store_true", help="also a 10^6-trial sweep")
    parser.add_argument("--quick", action="store_true", help="smaller sizes (a smoke test)")
    parser.add_argument("--sections", default=",".join(SECTIONS),
                        help=f"comma-separated, of {', '.join(SECTIONS + OPTIONAL)} (default: "
                             f"all but {', '.join(OPTIONAL)})")
    args = parser.parse_args(argv)
    chosen = [s for s in args.sections.split(",") if s]
    unknown = sorted(set(chosen) - set(SECTIONS + OPTIONAL))
    if unknown:
        parser.error(f"--sections: unknown {unknown}; choose from {list(SECTIONS + OPTIONAL)}")
    limit_process()  # one BLAS thread, as flatcli's own processes run (flatcli.threads)
    bench = Bench(args.out, args.quick)
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"flatcli bench -> {args.out} (load {load()})", flush=True)
    steps: dict[str, list[Callable[[], None]]] = {
        "planning": [partial(planning, bench)],
        "closed_loop": [partial(closed_loop, bench), partial(closed_loop_rk4, bench)],
        "sweeps": [partial(sweeps, bench, args.million)],
        "front_door": [partial(run_front_door, bench, sweep)],
        "compiles": [partial(run_compiles, bench)],
        "integrators": [partial(run_integrators, bench, sweep)],
        "twin_factors": [partial(twin_factors, bench)],
        "chains": [partial(run_chains, bench)],
        "asbuilt": [partial(run_asbuilt, bench, sweep)],
        "optimised": [partial(optimised, bench), partial(optimised_ladder, bench)],
        "tasks": [partial(run_tasks, bench)],
        "outcomes": [partial(run_outcomes, bench)],
        "search": [partial(run_search, bench)],
        "mpc": [partial(run_mpc, bench)],
    }
    for name in SECTIONS + OPTIONAL:
        if name in chosen:
            for step in steps[name]:
                step()
    text = report(bench)
    write_text(args.out / "bench.md", text)
    write_json(args.out / "bench.json", to_jsonable(bench.raw))
    print()
    print(text)


if __name__ == "__main__":
    main()
