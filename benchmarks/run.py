"""``make bench``: flatcli's speed and accuracy, measured in one run beside the alternatives.

Prints the tables and writes them to ``OUT/bench.md`` and ``OUT/bench.json`` (with the
machine, its load before and after each measurement, and every raw number). Benchmarks are
not tests: nothing here asserts a time.

    python -m benchmarks.run [--out runs/bench] [--million] [--quick]

Sweeps run as ``python -m flatcli.cli sweep`` subprocesses (the command a user runs, in a
fresh process); their own run.json gives the in-process throughput and peak memory, and the
wall time around the subprocess adds interpreter start-up and imports.
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
    machine_info,
    numpy_trials_per_second,
    paper_trials,
    pc_optimal,
    pc_point_to_point,
    plan_quality,
    robot_flat_system,
    shooting_plan,
    solve_ivp_trials_per_second,
    timed,
)
from benchmarks.chains import HEADERS as CHAIN_HEADERS
from benchmarks.chains import run_all as run_chains
from benchmarks.integrators import HEADERS as INTEGRATOR_HEADERS
from benchmarks.integrators import run_all as run_integrators
from flatcli.core.model import PAPER_ROBOT
from flatcli.core.optimize import PlanLimits, optimize_plan
from flatcli.core.planning import plan_point_to_point
from flatcli.core.simulate import Scenario, simulate
from flatcli.report import fmt, table
from flatcli.storage import to_jsonable, write_json, write_text
from flatcli.threads import limit_process

HERE = Path(__file__).resolve().parent
SPEC = HERE / "paper_sweep.toml"
GRID_POINTS = 200


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
    """Run ``flatcli sweep`` in a fresh process; its timing, memory and the outer wall time."""
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
        "trials_per_second": timing["trials_per_second"],
        "steady_trials_per_second": timing["steady_trials_per_second"],
        "setup_seconds": timing["setup_seconds"],
        "finish_seconds": timing["finish_seconds"],
        "sweep_seconds": timing["wall_seconds"],
        "process_seconds": wall,
        "peak_rss_mib": timing["peak_rss_mib"],
        "status_counts": record["status_counts"],
        "executor": timing["executor"],
    }


def best_of(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The run with the highest throughput (this shared machine's speed drifts by +-20 %
    over minutes; the best of interleaved repeats compares like with like), all kept."""
    best = dict(max(runs, key=lambda r: float(r["trials_per_second"])))
    best["repeats"] = [r["trials_per_second"] for r in runs]
    return best


def planning(bench: Bench) -> None:
    section = "Planning: the paper's maneuver, evaluated at 200 points"
    t = np.linspace(0.0, PAPER_MANEUVER.duration, GRID_POINTS)
    start, goal = np.array(PAPER_MANEUVER.start), np.array(PAPER_MANEUVER.goal)

    def flat_plan() -> Any:
        return plan_point_to_point(PAPER_ROBOT, start, goal, 0.1, 0.5, 2.0).evaluate(t)

    ours = bench.measure(section, "flatcli", lambda: timed(flat_plan, repeat=300, warmup=20))
    plan_only = timed(lambda: plan_point_to_point(PAPER_ROBOT, start, goal, 0.1, 0.5, 2.0),
                      repeat=300, warmup=20)
    full = timed(lambda: plan_point_to_point(PAPER_ROBOT, start, goal, 0.1, 0.5, 2.0)
                 .sample(t), repeat=100, warmup=5)
    system = robot_flat_system(PAPER_MANEUVER.coefficients)
    runs = bench.measure(section, "python-control", lambda: [
        pc_point_to_point(system=system) for _ in range(3 if bench.quick else 7)])
    pc_seconds = float(np.median([r.seconds for r in runs]))
    shooting = bench.measure(section, "shooting NLP", lambda: [
        shooting_plan() for _ in range(2 if bench.quick else 5)])
    shoot_seconds = float(np.median([s.seconds for s in shooting]))
    shoot_fd = bench.measure(section, "shooting NLP, finite differences",
                             lambda: shooting_plan(exact_gradients=False))
    batch_n = 10_000
    rng = np.random.default_rng(0)
    starts = start + 0.01 * rng.standard_normal((batch_n, 3))
    goals = goal + 0.01 * rng.standard_normal((batch_n, 3))
    rates0, rates1 = np.full(batch_n, 0.1), np.full(batch_n, 0.5)
    batch = bench.measure(section, "flatcli, 10,000 plans", lambda: timed(
        lambda: plan_point_to_point(PAPER_ROBOT, starts, goals, rates0, rates1, 2.0),
        repeat=3))
    batch_eval = timed(lambda: plan_point_to_point(PAPER_ROBOT, starts, goals, rates0, rates1,
                                                   2.0).evaluate(t), repeat=1, warmup=0)
    us = ours.median * 1e6
    bench.row(section, "flatcli: plan + states and inputs at 200 points", f"{us:.0f} us",
              "1x", "plan alone " + f"{plan_only.median * 1e6:.0f} us")
    bench.row(section, "flatcli: plan + full record (exact rates, margin, H)",
              f"{full.median * 1e6:.0f} us", f"{full.median / ours.median:.1f}x", "plan.parquet")
    bench.row(section, "python-control flatsys point_to_point + eval",
              f"{pc_seconds * 1e3:.0f} ms", f"{pc_seconds / ours.median:.0f}x",
              f"same trajectory to {max(r.max_theta_error for r in runs):.1e} rad")
    bench.row(section, "shooting NLP (SLSQP, 40 intervals, exact gradients)",
              f"{shoot_seconds * 1e3:.0f} ms", f"{shoot_seconds / ours.median:.0f}x",
              f"energy {shooting[0].objective:.2f} (not momentum-exact: "
              f"{shooting[0].integration_error:.0e} rad)")
    bench.row(section, "shooting NLP, finite-difference gradients",
              f"{shoot_fd.seconds * 1e3:.0f} ms", f"{shoot_fd.seconds / ours.median:.0f}x",
              f"{shoot_fd.evaluations} evaluations")
    bench.row(section, "flatcli: batch of 10,000 plans",
              f"{batch.median * 1e3:.1f} ms", f"{batch.median / batch_n * 1e6:.1f} us/plan",
              f"+ evaluation at 200 points: {batch_eval.median:.2f} s")
    bench.raw["planning"] = {
        "flatcli_seconds": ours.median, "flatcli_plan_seconds": plan_only.median,
        "flatcli_sample_seconds": full.median, "python_control_seconds": pc_seconds,
        "python_control_agreement_rad": max(r.max_theta_error for r in runs),
        "shooting_seconds": shoot_seconds, "shooting_energy": shooting[0].objective,
        "shooting_fd_seconds": shoot_fd.seconds, "batch_10000_seconds": batch.median,
        "batch_10000_evaluate_seconds": batch_eval.median,
        "ratio_python_control": pc_seconds / ours.median,
    }


def closed_loop(bench: Bench) -> None:
    section = "Closed loop: the paper's Fig. 4 loop, T = 2 s, RK4 dt = 1e-3"
    n = 2000 if bench.quick else 10_000
    trials = paper_trials(n, seed=1)
    plan = PAPER_MANEUVER.cubic()
    scenario = Scenario(plan, PAPER_TRACKING.gains, PAPER_TRACKING.dt).prepared()
    one = trials.subset(slice(0, 1))
    simulate(scenario, one, "rk4")
    simulate(scenario, one)
    single = bench.measure(section, "flatcli one trial",
                           lambda: timed(lambda: simulate(scenario, one, "rk4"), repeat=20))
    batch = bench.measure(section, "flatcli batch",
                          lambda: timed(lambda: simulate(scenario, trials, "rk4"), repeat=2))
    adaptive = bench.measure(section, "flatcli batch, adaptive",
                             lambda: timed(lambda: simulate(scenario, trials), repeat=2))
    compiled2 = bench.measure(section, "compiled kernel, 2 threads",
                              lambda: compiled_trials_per_second(plan, trials, threads=2))
    compiled1 = bench.measure(section, "compiled kernel, 1 thread",
                              lambda: compiled_trials_per_second(plan, trials, threads=1,
                                                                 repeat=2))
    numpy_batch = bench.measure(section, "numpy batch RK4", lambda: numpy_trials_per_second(
        plan, trials.subset(slice(0, min(n, 4000)))))
    ivp = bench.measure(section, "solve_ivp", lambda: solve_ivp_trials_per_second(
        plan, trials.subset(slice(0, 3 if bench.quick else 8))))
    flat_rate = n / batch.median
    bench.row(section, "flatcli simulate, one trial per call", f"{1 / single.median:.0f}",
              "", "all metrics")
    bench.row(section, f"flatcli simulate, batch of {n} (1 core)", f"{flat_rate:.0f}",
              f"{flat_rate / compiled1.trials_per_second:.2f}x compiled (1 thread)",
              "all metrics")
    bench.row(section, f"flatcli simulate, adaptive (default), batch of {n} (1 core)",
              f"{n / adaptive.median:.0f}", f"{n / adaptive.median / flat_rate:.2f}x flatcli RK4",
              "all metrics, 1e-6 rad or better")
    bench.row(section, "compiled RK4 kernel (numba prange), 2 threads",
              f"{compiled2.trials_per_second:.0f}", "", "final states only")
    bench.row(section, "compiled RK4 kernel, 1 thread", f"{compiled1.trials_per_second:.0f}",
              "", "final states only")
    bench.row(section, "numpy vectorised RK4 (1 core)",
              f"{numpy_batch.trials_per_second:.0f}", "", "final states only")
    bench.row(section, "solve_ivp RK45 rtol 1e-8, one trial at a time",
              f"{ivp.trials_per_second:.1f}", "", "final states only")
    bench.raw["closed_loop"] = {
        "trials": n, "flatcli_one_trial_per_second": 1 / single.median,
        "flatcli_batch_per_second": flat_rate,
        "flatcli_adaptive_batch_per_second": n / adaptive.median,
        "compiled_2_threads": compiled2.trials_per_second,
        "compiled_1_thread": compiled1.trials_per_second,
        "numpy_batch": numpy_batch.trials_per_second,
        "solve_ivp": ivp.trials_per_second,
    }


def sweeps(bench: Bench, million: bool) -> None:
    section = "flatcli sweep: benchmarks/paper_sweep.toml, all metrics written"
    work = bench.out / "sweeps"
    n = 2000 if bench.quick else 10_000
    ones: list[dict[str, Any]] = []
    twos: list[dict[str, Any]] = []
    dynamics: list[dict[str, Any]] = []
    for _ in range(1 if bench.quick else 3):  # interleaved, so drifts hit all alike
        ones.append(bench.measure(section, "1 worker", partial(sweep, SPEC, work / "w1", n, 1)))
        twos.append(bench.measure(section, "2 workers", partial(sweep, SPEC, work / "w2", n, 2)))
        dynamics.append(bench.measure(section, "dynamic plant, 2 workers", partial(
            sweep, SPEC, work / "dynamic", n, 2, "--set", "plant.model=dynamic")))
    one, two, dyn = best_of(ones), best_of(twos), best_of(dynamics)
    same = pd.read_parquet(work / "w1" / "trials.parquet").equals(
        pd.read_parquet(work / "w2" / "trials.parquet"))
    cl = bench.raw["closed_loop"]
    rate, steady = two["trials_per_second"], two["steady_trials_per_second"]
    for result in (one, two):
        w = result["workers"]
        bench.row(section, f"{n} trials, {w} worker{'s' if w > 1 else ''} (best of "
                  f"{len(result['repeats'])})",
                  f"{result['trials_per_second']:.0f}",
                  f"{result['steady_trials_per_second']:.0f}", f"{result['sweep_seconds']:.1f} s",
                  f"start-up {result['setup_seconds']:.2f} s, final tables "
                  f"{result['finish_seconds']:.2f} s")
    bench.row(section, "  speed-up, 1 to 2 workers", f"{rate / one['trials_per_second']:.2f}x",
              f"{steady / one['steady_trials_per_second']:.2f}x", "",
              f"target >= 1.8x; identical results: {same}")
    bench.row(section, "  vs solve_ivp one trial at a time", f"{rate / cl['solve_ivp']:.0f}x",
              f"{steady / cl['solve_ivp']:.0f}x", "", "target >= 250x")
    bench.row(section, "  vs compiled kernel, 2 threads",
              f"{rate / cl['compiled_2_threads']:.2f}x",
              f"{steady / cl['compiled_2_threads']:.2f}x", "", "target >= 0.8x")
    cost = {name: pd.read_parquet(work / name / "trials.parquet",
                                  columns=["steps", "rhs_evaluations"]).median()
            for name in ("w2", "dynamic")}
    bench.row(section, f"{n} trials, dynamic plant (plant.model = \"dynamic\"), 2 workers "
              f"(best of {len(dyn['repeats'])})", f"{dyn['trials_per_second']:.0f}",
              f"{dyn['steady_trials_per_second']:.0f}", f"{dyn['sweep_seconds']:.1f} s",
              "servo 100 rad/s, no torque limit; median steps / right-hand sides per trial "
              f"{cost['dynamic']['steps']:.0f} / {cost['dynamic']['rhs_evaluations']:.0f} "
              f"(kinematic {cost['w2']['steps']:.0f} / {cost['w2']['rhs_evaluations']:.0f})")
    bench.row(section, "  dynamic vs kinematic plant, 2 workers",
              f"{dyn['trials_per_second'] / rate:.2f}x",
              f"{dyn['steady_trials_per_second'] / steady:.2f}x", "", "target >= 0.4x")
    bench.row(section, "  command line, start to finish (2 workers)",
              f"{n / two['process_seconds']:.0f}", "", f"{two['process_seconds']:.1f} s",
              "with interpreter start-up and imports")
    dask = bench.measure(section, "dask", lambda: sweep(
        SPEC, work / "dask", n, 2, "--executor", "dask", "--scheduler", "local"))
    same_dask = pd.read_parquet(work / "dask" / "trials.parquet").equals(
        pd.read_parquet(work / "w2" / "trials.parquet"))
    bench.row(section, f"{n} trials, Dask LocalCluster of 2 workers",
              f"{dask['trials_per_second']:.0f}", f"{dask['steady_trials_per_second']:.0f}",
              f"{dask['sweep_seconds']:.1f} s",
              f"start-up (cluster) {dask['setup_seconds']:.1f} s; identical results: {same_dask}")
    bench.raw["sweep"] = {"one_worker": one, "two_workers": two, "dask": dask,
                          "dynamic_two_workers": dyn,
                          "identical_1_vs_2_workers": same, "identical_dask": same_dask}

    section = "Scaling: 2 workers"
    sizes = [1000, 10_000] if bench.quick else [1000, 10_000, 100_000]
    if million:
        sizes.append(1_000_000)
    scaling = []
    for size in sizes:
        result = two if size == n else bench.measure(
            section, f"{size} trials", partial(sweep, SPEC, work / f"n{size}", size, 2))
        scaling.append(result)
        rss = result["peak_rss_mib"]
        bench.row(section, f"{size:,} trials", f"{result['trials_per_second']:.0f}",
                  f"{result['steady_trials_per_second']:.0f}", f"{result['sweep_seconds']:.1f} s",
                  f"{rss['main']:.0f} MiB main, {rss['largest_child']:.0f} MiB per worker")
        shutil.rmtree(work / f"n{size}", ignore_errors=True)

    def spread(key: str) -> float:
        rates = [float(r[key]) for r in scaling]
        return (max(rates) - min(rates)) / max(rates)

    bench.row(section, "spread of trials/s across sizes",
              f"{100 * spread('trials_per_second'):.0f} %",
              f"{100 * spread('steady_trials_per_second'):.0f} %", "", "target within 15 %")
    bench.raw["scaling"] = scaling


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
    "Planning: the paper's maneuver, evaluated at 200 points":
        ["method", "time", "vs flatcli", "note"],
    "Closed loop: the paper's Fig. 4 loop, T = 2 s, RK4 dt = 1e-3":
        ["method", "trials/s", "ratio", "note"],
    "flatcli sweep: benchmarks/paper_sweep.toml, all metrics written":
        ["run", "trials/s", "warm trials/s", "wall", "note"],
    "Scaling: 2 workers": ["sweep", "trials/s", "warm trials/s", "wall", "peak memory (RSS)"],
    **INTEGRATOR_HEADERS,
    **CHAIN_HEADERS,
    **ASBUILT_HEADERS,
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
        "Sweep throughputs: *trials/s* is every trial over the sweep's whole in-process time "
        "(planning the cells and loading the compiled kernel, about 0.3-0.5 s once per "
        "process, then the chunks, then trials.parquet and the summary); *warm trials/s* "
        "leaves out that one-time start-up, as the baselines' timings leave out their "
        "compilation. Neither counts interpreter start-up and imports (the command-line row).",
    ]
    for section, rows in bench.tables.items():
        lines += ["", f"## {section}", "", table(HEADERS[section], rows)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("runs/bench"))
    parser.add_argument("--million", action="store_true", help="also a 10^6-trial sweep")
    parser.add_argument("--quick", action="store_true", help="smaller sizes (a smoke test)")
    args = parser.parse_args(argv)
    limit_process()  # one BLAS thread, as flatcli's own processes run (flatcli.threads)
    bench = Bench(args.out, args.quick)
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"flatcli bench -> {args.out} (load {load()})", flush=True)
    planning(bench)
    closed_loop(bench)
    sweeps(bench, args.million)
    run_integrators(bench, sweep)
    run_chains(bench)
    run_asbuilt(bench, sweep)
    optimised(bench)
    optimised_ladder(bench)
    text = report(bench)
    write_text(args.out / "bench.md", text)
    write_json(args.out / "bench.json", to_jsonable(bench.raw))
    print()
    print(text)


if __name__ == "__main__":
    main()
