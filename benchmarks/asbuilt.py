"""make bench: robots as built (issue 22), the goal measured.

At d2 = 3 mm (``configs/asbuilt_goal.toml``): planning the paper's maneuver for the robot as
built through the Python API (``flatcli.plan``, which picks the exact planner) and its parts
(the exact plan in the core, the LQR's design); max abs(H) along the exact plan from the full
link kinematics on a dense grid; and the goal's two sweeps, the as-built pipeline and the
ideal-model one (the same grid, hence the same trials), as ``flatcli sweep`` subprocesses,
with the medians of the final error over the trials both resolved and verified
(``flatcli.reproduce.asbuilt.compare``, as REPORT.md computes them), and Fig. 4's start.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pandas as pd

GOAL = "Robots as built (issue 22): planning at d2 = 3 mm"
SWEEPS = "Robots as built (issue 22): the goal's sweeps at d2 = 3 mm, 2 workers"
HEADERS = {
    GOAL: ["what", "value", "goal", "note"],
    SWEEPS: ["start", "n / trials", "ideal: median [rad]", "as built: median [rad]", "ratio",
             "goal", "note"],
}


def best_time(fn: Callable[[], Any], repeats: int) -> float:
    """The best of ``repeats`` wall times [s] of ``fn`` (after one call to warm it)."""
    fn()
    best = math.inf
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - started)
    return best


def planning(bench: Any) -> dict[str, float]:
    import flatcli
    from flatcli.core.controllers.lqr import tracked
    from flatcli.core.plan.exact import plan_exact
    from flatcli.experiment import plan_from, robot_from
    from flatcli.reproduce.asbuilt import AS_BUILT_COM, GOAL_SPEC, dense_momentum
    from flatcli.spec import load_spec, resolve

    overrides = {"robot.com": list(AS_BUILT_COM)}
    spec = resolve({"robot": {"com": list(AS_BUILT_COM)}})
    robot = robot_from(spec)
    p = spec.plan
    api = bench.measure(GOAL, "flatcli.plan", lambda: best_time(
        lambda: flatcli.plan(overrides=overrides), 15))
    core = bench.measure(GOAL, "plan_exact", lambda: best_time(
        lambda: plan_exact(robot, p.start, p.goal, p.start_rate, p.goal_rate, p.duration),
        15))
    plan = plan_from(spec)
    design = bench.measure(GOAL, "the LQR's design", lambda: best_time(
        lambda: tracked(plan), 3))
    momentum = dense_momentum(load_spec(GOAL_SPEC))
    bench.row(GOAL, "plan the maneuver through the Python API (`flatcli.plan`, best of 15)",
              f"{api * 1e3:.1f} ms", "<= 50 ms", "spec, exact plan, its 201 samples, report")
    bench.row(GOAL, "the exact plan alone (`core.exact.plan_exact`)", f"{core * 1e3:.1f} ms",
              "", "12 quintic B-spline coefficients per joint, Newton on the KKT system")
    bench.row(GOAL, "the as-built LQR's design (`core.lqr.tracked`, best of 3)",
              f"{design * 1e3:.0f} ms", "", "Riccati backwards by DOP853 (rtol 1e-9), gains "
              "fitted; once per sweep cell")
    bench.row(GOAL, "max abs(H) along the exact plan, 20001 samples, full link kinematics",
              f"{momentum:.2g} kg m^2/s", "<= 1e-9", "")
    return {"api_seconds": api, "core_seconds": core, "design_seconds": design,
            "max_abs_momentum": momentum}


def sweeps(bench: Any, sweep: Callable[..., dict[str, Any]]) -> dict[str, Any]:
    from flatcli.experiment import run_track
    from flatcli.reproduce.asbuilt import (
        FIG4,
        GOAL_ERROR,
        GOAL_RATIO,
        GOAL_SPEC,
        IDEAL,
        STD_KEY,
        as_float,
        compare,
        kept,
        paired,
        pipeline,
    )
    from flatcli.spec import load_spec

    trials = 100 if bench.quick else 1000
    frames, timing = {}, {}
    for name in ("ideal", "asbuilt"):
        extra = [w for key, value in IDEAL.items()
                 for w in ("--set", f"{key}={json.dumps(value)}")] if name == "ideal" else []
        out = bench.out / f"asbuilt_goal_{name}"
        timing[name] = bench.measure(SWEEPS, f"{name} sweep", lambda out=out, extra=extra:
                                     sweep(GOAL_SPEC, out, trials, 2, *extra))
        frame = pd.read_parquet(out / "trials.parquet")
        frames[name] = frame.assign(kept=kept(frame))
    joined = paired(frames["ideal"], frames["asbuilt"])
    base = load_spec(GOAL_SPEC)
    fig4 = {name: as_float(run_track(pipeline(base, name).with_overrides(
        {"track.initial": list(FIG4)})).metrics["err_theta_final"])
        for name in ("ideal", "asbuilt")}
    ratio = fig4["ideal"] / fig4["asbuilt"]
    met = fig4["asbuilt"] <= GOAL_ERROR and ratio >= GOAL_RATIO
    bench.row(SWEEPS, "Fig. 4's start", "1 / 1", f"{fig4['ideal']:.3g}",
              f"{fig4['asbuilt']:.3g}", f"{ratio:.3g}", "met" if met else "not met", "")
    cells = {}
    for std, cell in joined.groupby(f"{STD_KEY}_ideal"):
        c = compare(cell)
        cells[as_float(std)] = c
        bench.row(SWEEPS, f"th(0) std {as_float(std):g} rad", f"{c['compared']} / {c['trials']}",
                  f"{c['ideal']:.3g}", f"{c['asbuilt']:.3g}", f"{c['ratio']:.3g}",
                  "met" if c["met"] else "not met",
                  f"lost {c['lost']['ideal']} / {c['lost']['asbuilt']} (ideal / as built)")
    for name in ("ideal", "asbuilt"):
        t = timing[name]
        bench.row(SWEEPS, f"{name} sweep: {3 * trials} trials", "", "", "", "", "",
                  f"{t['trials_per_second']:.0f} trials/s "
                  f"({t['steady_trials_per_second']:.0f} warm), {t['sweep_seconds']:.1f} s")
    return {"trials_per_cell": trials, "fig4": fig4, "cells": cells, "timing": timing,
            "median_pooled": {name: float(np.median(frames[name].loc[frames[name]["kept"],
                                                                      "err_theta_final"]))
                              for name in frames}}


def run_all(bench: Any, sweep: Callable[..., dict[str, Any]]) -> None:
    started = time.perf_counter()
    bench.raw["asbuilt"] = {"planning": planning(bench), "sweeps": sweeps(bench, sweep),
                            "seconds": time.perf_counter() - started}
