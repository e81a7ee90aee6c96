"""``make bench``: the adaptive integrator against fixed-step RK4, in cost and in accuracy.

* sweeps of ``benchmarks/paper_sweep.toml`` and of the paper study
  (``configs/paper_montecarlo.toml``) with each integrator, 2 workers, interleaved;
* steps and right-hand-side evaluations per trial (median, 95th percentile) by cell;
* accuracy against cost: adaptive rtol 1e-4 .. 1e-10 and RK4 dt 4 .. 0.25 ms, against
  scipy's DOP853 at rtol 1e-12 on the same right-hand side (every output sample);
* the error estimate ``err_estimate`` against the true final error on a few hundred trials;
* the default settings' largest error by gains, plant and robot (nominal, perturbed with
  d2 != 0, residual momentum H0 = 0.2).
"""

from __future__ import annotations

import dataclasses
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from benchmarks.baselines import PAPER_MANEUVER, paper_trials, timed
from flatcli.core.controllers.control import Gains
from flatcli.core.loop.metrics import Metric, Status
from flatcli.core.loop.simulate import (
    Scenario,
    Trials,
    closed_loop_rhs,
    closed_loop_start,
    simulate,
)

Array = NDArray[np.float64]

HERE = Path(__file__).resolve().parent
SPEC = HERE / "paper_sweep.toml"
STUDY = HERE.parent / "configs" / "paper_montecarlo.toml"
PRINTED = Gains((10.0, 13.0), (100.0, 110.0))
SWAPPED = Gains((100.0, 110.0), (10.0, 13.0))
SWEEPS = "Integrators: adaptive (default) against RK4, 2 workers"
CELLS = "Integrators: steps and right-hand sides per trial, paper study, by cell"
ACCURACY = "Accuracy against cost (every output sample against DOP853 at rtol 1e-12)"
ESTIMATE = "err_estimate against the true final error (DOP853 at rtol 1e-12)"
CASES = "Accuracy by gains, plant and robot (every output sample against DOP853 at rtol 1e-12)"
TWINS = ("The twin at looser factors on the tolerances: err_estimate against the true final "
         "error (DOP853 at rtol 1e-12)")
#: The twin's factors ``twin_factors`` prices (``simulate.TWIN_FACTOR`` is the default's).
TWIN_FACTORS = (0.01, 0.1, 0.3)
HEADERS = {
    SWEEPS: ["sweep", "adaptive", "rk4", "ratio", "note"],
    CELLS: ["cell", "grid values", "steps median", "steps p95", "rhs median", "rhs p95",
            "statuses (adaptive)", "statuses (rk4)"],
    ACCURACY: ["integrator", "setting", "max error printed [rad]", "max error swapped [rad]",
               "max error perturbed [rad]", "rhs per trial", "trials/s (1 core)"],
    ESTIMATE: ["gains", "plant", "trials", "within 10x", "smallest ratio", "median ratio",
               "largest ratio"],
    CASES: ["gains", "plant", "robot", "trials", "adaptive max error [rad]",
            "rk4 1 ms max error [rad]"],
    TWINS: ["loop", "factor", "trials", "within 3x", "smallest ratio", "median ratio",
            "largest ratio", "rhs per trial", "over one solution"],
}


#: Right-hand sides a reference solution may take (about a minute of scipy): a trial that
#: passes close to the singular set can make DOP853 at rtol 1e-12 crawl without failing.
REFERENCE_BUDGET = 3_000_000


class _OverBudgetError(Exception):
    """The reference took more than ``REFERENCE_BUDGET`` right-hand sides."""


def reference(scenario: Scenario, trials: Trials, i: int, times: Array) -> Array | None:
    """Trial i by scipy's DOP853 at rtol 1e-12 on the kernel's right-hand side: the angles
    at ``times`` (None if it cannot finish, or not within ``REFERENCE_BUDGET`` right-hand
    sides: a diverging trial has no accuracy to compare)."""
    rhs = closed_loop_rhs(scenario, trials, i)
    calls = [0]

    def counted(t: float, x: Array) -> Array:
        calls[0] += 1
        if calls[0] > REFERENCE_BUDGET:
            raise _OverBudgetError
        return rhs(t, x)

    with np.errstate(all="ignore"):
        try:
            sol = solve_ivp(counted, (0.0, float(times[-1])),
                            closed_loop_start(scenario, trials, i), method="DOP853",
                            t_eval=times, rtol=1e-12, atol=1e-14)
        except _OverBudgetError:
            return None
    return np.asarray(sol.y[:3].T) if sol.status == 0 else None


def accuracy_curve(bench: Any) -> None:
    """Max angle error over every output sample, cost and throughput per setting."""
    plan = PAPER_MANEUVER.cubic()
    fig4 = np.array([[1.96, 0.8, -0.1, 0.1]])
    one = Trials(PAPER_MANEUVER.robot.as_array()[None], np.zeros(1), fig4)
    perturbed = paper_trials(6 if bench.quick else 12, seed=3)
    throughput = paper_trials(300 if bench.quick else 1000, seed=4)
    settings: list[tuple[str, str, dict[str, Any], float]] = [
        *(("adaptive", f"rtol {r:g}", {"rtol": r, "atol": r * 2e-3}, 1e-3)
          for r in (1e-4, 1e-5, 1e-6, 1e-7, 5e-8, 1e-8, 1e-9, 1e-10)),
        *(("rk4", f"dt {dt * 1e3:g} ms", {}, dt) for dt in (4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4)),
    ]
    references: dict[tuple[str, float], list[Array | None]] = {}
    raw = []
    for integrator, label, options, dt in settings:
        errors = {}
        for name, gains, trials in (("printed", PRINTED, one), ("swapped", SWAPPED, one),
                                    ("perturbed", PRINTED, perturbed)):
            scenario = Scenario(plan, gains, dt, **options)
            key = (name, dt)
            if key not in references:
                references[key] = [reference(scenario, trials, i, scenario.times)
                                   for i in range(trials.count)]
            out = simulate(scenario, trials, integrator, record=True)  # type: ignore[arg-type]
            assert out.trace is not None
            worst = 0.0
            for i, ref in enumerate(references[key]):
                if ref is not None and out.status[i] == Status.OK:
                    worst = max(worst, float(np.max(np.abs(out.trace[i, :, :3] - ref))))
            errors[name] = worst
        scenario = Scenario(plan, PRINTED, dt, **options).prepared()
        simulate(scenario, throughput.subset(slice(0, 2)), integrator)  # type: ignore[arg-type]
        cost = bench.measure(ACCURACY, f"{integrator} {label}", partial(
            timed, partial(simulate, scenario, throughput, integrator),  # type: ignore[arg-type]
            repeat=3))
        out = simulate(scenario, throughput, integrator)  # type: ignore[arg-type]
        evaluations = float(np.median(out.metrics[:, Metric.RHS_EVALUATIONS]))
        rate = throughput.count / cost.best
        bench.row(ACCURACY, integrator, label, f"{errors['printed']:.1e}",
                  f"{errors['swapped']:.1e}", f"{errors['perturbed']:.1e}", f"{evaluations:.0f}",
                  f"{rate:.0f}")
        raw.append({"integrator": integrator, "setting": label, **errors,
                    "rhs_evaluations": evaluations, "trials_per_second": rate})
    bench.raw["accuracy_curve"] = raw


def error_estimate(bench: Any) -> None:
    """err_estimate (the twin at a hundredth of the tolerances) against the true final error
    of resolved perturbed trials: the share within 10x and the smallest ratio (the band the
    tests ask for: within 10x on 90 %, never below by more than 3x)."""
    plan = PAPER_MANEUVER.cubic()
    raw = []
    readings = (("printed", PRINTED, "kinematic", 11), ("swapped", SWAPPED, "kinematic", 12),
                ("printed", PRINTED, "dynamic", 13), ("swapped", SWAPPED, "dynamic", 14))
    for name, gains, plant, seed in readings:
        trials = paper_trials(40 if bench.quick else 150, seed=seed, angle_spread=0.05)
        scenario = Scenario(plan, gains, 1e-3, plant=plant)  # type: ignore[arg-type]
        out = simulate(scenario, trials, record=True)
        assert out.trace is not None
        ratios = []
        end = np.array([0.0, plan.duration])
        resolved = (out.status == Status.OK) | (out.status == Status.SINGULAR)
        for i in np.flatnonzero(resolved):
            ref = bench.measure(ESTIMATE, f"{name} {plant} trial {i}",
                                partial(reference, scenario, trials, int(i), end))
            if ref is None:
                continue
            true = float(np.linalg.norm(out.trace[i, -1, :3] - ref[-1]))
            ratios.append(out.metrics[i, Metric.ERR_ESTIMATE] / max(true, 1e-300))
        r = np.asarray(ratios)
        within = float(np.mean((r <= 10) & (r >= 0.1)))
        bench.row(ESTIMATE, name, plant, len(r), f"{within:.1%}", f"{np.min(r):.3g}",
                  f"{np.median(r):.3g}", f"{np.max(r):.3g}")
        raw.append({"gains": name, "plant": plant, "trials": len(r), "within_10x": within,
                    "smallest_ratio": float(np.min(r)), "median_ratio": float(np.median(r)),
                    "largest_ratio": float(np.max(r))})
    bench.raw["error_estimate"] = raw


def twin_factors(bench: Any) -> None:
    """The twin on a cheaper schedule (issue 41, item 1): err_estimate at each factor of
    ``TWIN_FACTORS`` on the tolerances against the true final error of resolved perturbed
    trials (DOP853 at rtol 1e-12, ``reference``), and its right-hand sides against one
    solution's (``twin = 0``), on five loops of the paper's robot."""
    plan = PAPER_MANEUVER.cubic()
    count = 10 if bench.quick else 30
    loops: tuple[tuple[str, Gains, dict[str, Any]], ...] = (
        ("printed", PRINTED, {}), ("swapped", SWAPPED, {}),
        ("dynamic, printed", PRINTED, {"plant": "dynamic"}),
        ("dynamic, swapped", SWAPPED, {"plant": "dynamic"}),
        ("rate limit 0.6 rad/s", PRINTED, {"rate_limit": 0.6}))
    end = np.array([0.0, plan.duration])
    raw = []
    for name, gains, options in loops:
        trials = paper_trials(count, seed=7, spread=0.02, angle_spread=0.05)
        base = Scenario(plan, gains, 1e-3, twin=0.0, **options).prepared()
        refs = [reference(base, trials, i, end) for i in range(count)]
        single = simulate(base, trials)
        for factor in TWIN_FACTORS:
            out = simulate(dataclasses.replace(base, twin=factor), trials, record=True)
            assert out.trace is not None
            kept = [i for i, ref in enumerate(refs)
                    if ref is not None and out.status[i] in (Status.OK, Status.SINGULAR)]
            ratios = np.array([
                out.metrics[i, Metric.ERR_ESTIMATE]
                / max(float(np.linalg.norm(out.trace[i, -1, :3] - ref[-1])), 1e-300)
                for i, ref in enumerate(refs) if i in kept and ref is not None])
            within = int(np.sum((ratios >= 1 / 3) & (ratios <= 3)))
            # right-hand sides over the compared trials (an unresolved one has no twin)
            rhs = float(np.median(out.metrics[kept, Metric.RHS_EVALUATIONS]))
            one = float(np.median(single.metrics[kept, Metric.RHS_EVALUATIONS]))
            bench.row(TWINS, name, f"{factor:g}", len(ratios), within, f"{np.min(ratios):.3g}",
                      f"{np.median(ratios):.3g}", f"{np.max(ratios):.3g}", f"{rhs:.0f}",
                      f"+{(rhs / one - 1) * 100:.0f} %")
            raw.append({"loop": name, "factor": factor, "trials": len(ratios),
                        "within_3x": within, "smallest_ratio": float(np.min(ratios)),
                        "largest_ratio": float(np.max(ratios)), "rhs": rhs, "one": one})
    bench.raw["twin_factors"] = raw


def accuracy_by_case(bench: Any) -> None:
    """The default settings (adaptive at rtol 5e-8, and RK4 at dt = 1 ms) on the paper's
    maneuver: the largest error of any output sample of any resolved trial against DOP853 at
    rtol 1e-12, by gains, plant and robot: the paper's robot from Fig. 4's start; perturbed
    robots (parameters +-2 %, d2 within +-2 mm, H0 within +-1e-4, start within 0.02 rad);
    the same with H0 = 0.2 kg m^2/s of residual momentum."""
    plan = PAPER_MANEUVER.cubic()
    count = 4 if bench.quick else 12
    fig4 = Trials(PAPER_MANEUVER.robot.as_array()[None], np.zeros(1),
                  np.array([[1.96, 0.8, -0.1, 0.1]]))
    perturbed = paper_trials(count, seed=5)
    spinning = Trials(perturbed.links, np.full(count, 0.2), perturbed.initial)
    raw = []
    for gname, gains in (("printed", PRINTED), ("swapped", SWAPPED)):
        for plant in ("kinematic", "dynamic"):
            for rname, trials in (("paper, Fig. 4 start", fig4), ("perturbed", perturbed),
                                  ("perturbed, H0 = 0.2", spinning)):
                scenario = Scenario(plan, gains, 1e-3, plant=plant)
                errors = {}
                refs = [reference(scenario, trials, i, scenario.times)
                        for i in range(trials.count)]
                for integrator in ("adaptive", "rk4"):
                    out = simulate(scenario, trials, integrator,
                                   record=True)
                    assert out.trace is not None
                    worst = 0.0
                    for i, ref in enumerate(refs):
                        if ref is not None and out.status[i] in (Status.OK, Status.SINGULAR):
                            worst = max(worst, float(np.max(np.abs(out.trace[i, :, :3] - ref))))
                    errors[integrator] = worst
                resolved = sum(ref is not None for ref in refs)
                bench.row(CASES, gname, plant, rname, resolved, f"{errors['adaptive']:.1e}",
                          f"{errors['rk4']:.1e}")
                raw.append({"gains": gname, "plant": plant, "robot": rname,
                            "trials": resolved, **errors})
    bench.raw["accuracy_by_case"] = raw


def integrator_sweeps(bench: Any, sweep: Any) -> None:
    """paper_sweep.toml and the paper study with each integrator (2 workers, interleaved,
    best of the repeats), and the integrators' work per trial by cell of the study."""
    work = bench.out / "integrators"
    n = 2000 if bench.quick else 10_000
    repeats = 1 if bench.quick else 3
    runs: dict[str, list[dict[str, Any]]] = {"adaptive": [], "rk4": []}
    for k in range(repeats):
        for integrator in ("adaptive", "rk4"):
            runs[integrator].append(bench.measure(SWEEPS, f"paper_sweep {integrator} {k}", partial(
                sweep, SPEC, work / f"sweep-{integrator}", n, 2,
                "--set", f"track.integrator={integrator}")))
    best = {k: max(v, key=lambda r: float(r["trials_per_second"])) for k, v in runs.items()}
    ratio = best["adaptive"]["trials_per_second"] / best["rk4"]["trials_per_second"]
    frames = {k: pd.read_parquet(work / f"sweep-{k}" / "trials.parquet") for k in runs}
    steps = frames["adaptive"]["steps"]
    bench.row(SWEEPS, f"paper_sweep.toml, {n:,} trials: trials/s (best of {repeats})",
              f"{best['adaptive']['trials_per_second']:.0f}",
              f"{best['rk4']['trials_per_second']:.0f}", f"{ratio:.2f}x",
              f"adaptive steps per trial median {steps.median():.0f}, p95 "
              f"{steps.quantile(0.95):.0f}")
    study: dict[str, dict[str, Any]] = {}
    trials = 400 if bench.quick else 2000
    for integrator in ("adaptive", "rk4"):
        study[integrator] = bench.measure(SWEEPS, f"paper study {integrator}", partial(
            sweep, STUDY, work / f"study-{integrator}", trials, 2,
            "--set", f"track.integrator={integrator}"))
    seconds = {k: float(v["sweep_seconds"]) for k, v in study.items()}
    bench.row(SWEEPS, f"paper study, 18 x {trials:,} trials: wall time",
              f"{seconds['adaptive']:.1f} s", f"{seconds['rk4']:.1f} s",
              f"{seconds['adaptive'] / seconds['rk4']:.2f}x the time",
              "every trial resolved to its tolerance or marked (adaptive)")
    frames = {k: pd.read_parquet(work / f"study-{k}" / "trials.parquet") for k in study}
    grid = [c for c in frames["adaptive"].columns
            if c in ("sweep.perturb.initial.std", "gains", "plant.com")]
    raw = []
    for cell, group in frames["adaptive"].groupby("cell"):
        rk4 = frames["rk4"][frames["rk4"]["cell"] == cell]
        first = group.iloc[0]
        values = ", ".join(_value(first[c]) for c in grid)

        def counts(frame: pd.DataFrame) -> str:
            c = frame["status"].value_counts()
            return " ".join(f"{s[:2]} {int(c.get(s, 0))}" for s in
                            ("ok", "singular", "diverged", "unresolved") if c.get(s, 0))

        row = [cell, values, f"{group['steps'].median():.0f}",
               f"{group['steps'].quantile(0.95):.0f}",
               f"{group['rhs_evaluations'].median():.0f}",
               f"{group['rhs_evaluations'].quantile(0.95):.0f}", counts(group), counts(rk4)]
        bench.row(CELLS, *row)
        raw.append(dict(zip(HEADERS[CELLS], row, strict=True)))
    bench.raw["integrator_sweeps"] = {"paper_sweep": best, "study": study, "cells": raw,
                                      "ratio": ratio}


def _value(v: Any) -> str:
    if isinstance(v, list | tuple | np.ndarray):
        return "[" + ", ".join(f"{float(x):g}" for x in v) + "]"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def run_all(bench: Any, sweep: Any) -> None:
    started = time.perf_counter()
    integrator_sweeps(bench, sweep)
    accuracy_curve(bench)
    error_estimate(bench)
    accuracy_by_case(bench)
    bench.raw["integrators_seconds"] = time.perf_counter() - started
