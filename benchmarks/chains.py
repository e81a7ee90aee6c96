"""make bench: the closed loop of an N-link chain, N = 2, 3, 4, 6 joints.

The same family of robots for every N (a heavy base, equal links, the last one
counterweighted onto its joint with a large inertia, as tests/test_chainplan.py's), a cubic
plan through ``chainplan.plan_chain`` (the N-link path also for N = 2, so every N runs the
same code), gains 100 / 20 per output, perturbed starts; one core, one batch per plant and
integrator. Reported: trials/s, the median of steps and right-hand sides per trial, and the
cost of one right-hand side, whose growth with N says where the time goes; and the same work
as when issue 19 set its goal (3x the trials/s of N = 3, 4, 6 on both plants): no twin
(``track.error_estimate = "none"``), side by side with that day's code (``FILED_COMMIT``,
taken from git by ``git archive`` into the output folder and run in a subprocess with its own
numba cache, right after each of today's measurements); without git, against that day's
published figures (``FILED``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from flatcli.core.controllers.control import Gains
from flatcli.core.loop.metrics import Metric
from flatcli.core.loop.simulate import Scenario, Trials, simulate
from flatcli.core.plan.planning import plan_chain
from flatcli.core.robots.params import RobotParams

JOINTS = (2, 3, 4, 6)
SECTION = "Robots of N links: closed loop, adaptive integrator, one core"
SAME_WORK = ("Robots of N links: the same work as when issue 19 set its goal (no twin), "
             "side by side with that day's code (then: commit f6a3882)")
HEADERS = {SECTION: ["N joints", "plant", "trials/s (1 core)", "steps / trial", "rhs / trial",
                     "us per rhs", "us per rhs / N^2"],
           SAME_WORK: ["N joints", "plant", "trials/s (1 core)", "rhs / trial",
                       "then: trials/s", "then: rhs / trial", "ratio", "goal"]}
#: The commit whose chain code issue 19's goal measured (README.md there, "Robots of N links").
FILED_COMMIT = "f6a3882"
#: trials/s and right-hand sides per trial of this section then (that README: an idle machine,
#: perhaps another CPU; no twin then), for when that commit cannot be run.
FILED: dict[tuple[int, str], tuple[float, float]] = {
    (2, "kinematic"): (253, 2871), (3, "kinematic"): (194, 2967), (4, "kinematic"): (146, 2997),
    (6, "kinematic"): (85, 3033), (2, "dynamic"): (130, 5229), (3, "dynamic"): (107, 5187),
    (4, "dynamic"): (88, 5151), (6, "dynamic"): (55, 5061),
}


def robot(n: int) -> RobotParams:
    """The benchmark's chain of ``n`` joints."""
    return RobotParams(mass=(2.0, *[1.0] * (n - 1), 0.6),
                       inertia=(0.08, *[0.03] * (n - 1), 0.2),
                       length=(0.3, *[0.25] * n), com=(0.12, *[0.1] * (n - 1), 0.0))


def scenario_and_trials(n: int, count: int, plant: Literal["kinematic", "dynamic"]
                        ) -> tuple[Scenario, Trials]:
    r = robot(n)
    start = np.r_[0.0, 1.0, np.full(n - 1, 0.3)]
    goal = np.r_[0.4, 2.0, np.full(n - 1, 0.6)]
    start[-1] = goal[-1] = 0.0
    plan = plan_chain(r, start, goal, np.full(n - 1, 0.3), np.full(n - 1, 0.5), 2.0)
    sc = Scenario(plan, Gains((100.0,) * n, (20.0,) * n), 1e-3, plant=plant).prepared()
    rng = np.random.default_rng(n)
    initial = np.hstack([start + rng.normal(0.0, 0.01, (count, n + 1)),
                         0.3 + rng.normal(0.0, 0.005, (count, n - 1))])
    return sc, Trials(np.tile(r.as_array(), (count, 1)), np.zeros(count), initial)


def measure(n: int, count: int, plant: Literal["kinematic", "dynamic"], twin: bool = True
            ) -> dict[str, Any]:
    sc, trials = scenario_and_trials(n, count, plant)
    if not twin:
        sc = replace(sc, twin=0.0)
    simulate(sc, trials.subset(slice(0, 2)))  # compile / load the kernel
    best = np.inf
    for _ in range(2):
        started = time.perf_counter()
        out = simulate(sc, trials)
        best = min(best, time.perf_counter() - started)
    steps = float(np.median(out.metrics[:, Metric.STEPS]))
    rhs = float(np.median(out.metrics[:, Metric.RHS_EVALUATIONS]))
    total_rhs = float(np.sum(out.metrics[:, Metric.RHS_EVALUATIONS]))
    us = best / total_rhs * 1e6
    return {"joints": n, "plant": plant, "trials_per_second": count / best, "steps": steps,
            "rhs": rhs, "us_per_rhs": us, "us_per_rhs_over_n2": us / n ** 2}


def run_all(bench: Any) -> None:
    section = SECTION
    count = 200 if bench.quick else 1000
    results = []
    plants: tuple[Literal["kinematic", "dynamic"], ...] = ("kinematic", "dynamic")
    for plant in plants:
        for n in JOINTS:
            r = bench.measure(section, f"N = {n}, {plant}", lambda n=n, plant=plant:
                              measure(n, count, plant))
            results.append(r)
            bench.row(section, n, plant, f"{r['trials_per_second']:.0f}", f"{r['steps']:.0f}",
                      f"{r['rhs']:.0f}", f"{r['us_per_rhs']:.2f}",
                      f"{r['us_per_rhs_over_n2']:.3f}")
    same_work = []
    tree = filed_tree(bench.out)
    rounds = 1 if bench.quick else 3
    for plant in plants:
        for n in JOINTS:
            ours: list[dict[str, Any]] = []
            theirs: list[dict[str, Any]] = []
            for _ in range(rounds if tree is not None else 1):  # interleaved: A B A B ...
                ours.append(bench.measure(SAME_WORK, f"N = {n}, {plant}, no twin",
                                          lambda n=n, plant=plant:
                                          measure(n, count, plant, twin=False)))
                if tree is not None:
                    theirs.append(bench.measure(
                        SAME_WORK, f"N = {n}, {plant}, {FILED_COMMIT}", lambda n=n, plant=plant:
                        measure_filed(tree, n, count, plant)))
            r = max(ours, key=lambda m: m["trials_per_second"])
            if theirs:
                then = float(np.median([m["trials_per_second"] for m in theirs]))
                then_rhs = theirs[0]["rhs"]
                ratio = float(np.median([a["trials_per_second"] / b["trials_per_second"]
                                         for a, b in zip(ours, theirs, strict=True)]))
            else:
                then, then_rhs = FILED[(n, plant)]
                ratio = r["trials_per_second"] / then
            same_work.append({**r, "filed": then, "filed_rhs": then_rhs, "ratio": ratio,
                              "filed_measured_now": bool(theirs),
                              "rounds": [(a["trials_per_second"], b["trials_per_second"])
                                         for a, b in zip(ours, theirs, strict=True)]})
            goal = "" if n == 2 else ("met" if ratio >= 3.0 else "not met") + " (>= 3x)"
            now = float(np.median([m["trials_per_second"] for m in ours]))
            bench.row(SAME_WORK, n, plant, f"{now:.0f}", f"{r['rhs']:.0f}",
                      f"{then:.0f}" + ("" if theirs else " (published)"),
                      f"{then_rhs:.0f}", f"{ratio:.2f}x", goal)
    bench.raw["chains"] = {"trials": count, "results": results, "same_work": same_work,
                           "filed_commit": FILED_COMMIT, "filed_run": tree is not None}
    paper_loop(bench)


#: One script for both trees: the paper's closed loop (Fig. 4's gains, the cubic plan) on
#: perturbed plants (benchmarks.baselines.paper_trials), adaptive integrator, no twin (the
#: filing day had none), one core: trials/s, best of two.
PAPER_LOOP = """
import dataclasses, json, sys, time
from benchmarks.baselines import PAPER_MANEUVER, PAPER_TRACKING, paper_trials
from flatcli.core.loop.simulate import Scenario, simulate
n = int(sys.argv[1])
trials = paper_trials(n, seed=1)
sc = Scenario(PAPER_MANEUVER.cubic(), PAPER_TRACKING.gains, PAPER_TRACKING.dt).prepared()
if hasattr(sc, "twin"):
    sc = dataclasses.replace(sc, twin=0.0)
simulate(sc, trials.subset(slice(0, 2)))
best = float("inf")
for _ in range(2):
    began = time.perf_counter()
    out = simulate(sc, trials)
    best = min(best, time.perf_counter() - began)
print(json.dumps({"trials_per_second": n / best}))
"""
PAPER = ("The paper's closed loop (issue 19: at least 0.95x the filing day's trials/s), side "
         "by side with that day's code (then: commit f6a3882)")
HEADERS[PAPER] = ["trials", "trials/s (1 core)", "then: trials/s", "ratio", "goal"]


def paper_loop(bench: Any) -> None:
    """The paper's loop today against ``FILED_COMMIT``'s (``PAPER_LOOP`` in a subprocess for
    each, interleaved, median of the paired ratios)."""
    tree = filed_tree(bench.out)
    if tree is None:
        return
    count = 1000 if bench.quick else 4000
    here = Path(__file__).resolve().parent.parent
    pairs = []
    for _ in range(1 if bench.quick else 3):
        now = bench.measure(PAPER, "today", lambda: run_script(here, PAPER_LOOP, count,
                                                               own_cache=False))
        then = bench.measure(PAPER, FILED_COMMIT, lambda: run_script(tree, PAPER_LOOP, count))
        pairs.append((now["trials_per_second"], then["trials_per_second"]))
    ratio = float(np.median([a / b for a, b in pairs]))
    bench.row(PAPER, count, f"{np.median([a for a, _ in pairs]):.0f}",
              f"{np.median([b for _, b in pairs]):.0f}", f"{ratio:.2f}x",
              ("met" if ratio >= 0.95 else "not met") + " (>= 0.95x)")
    bench.raw["paper_loop"] = {"trials": count, "pairs": pairs, "ratio": ratio,
                               "filed_commit": FILED_COMMIT}


def run_script(tree: Path, script: str, *args: Any, own_cache: bool = True) -> dict[str, Any]:
    """Run ``script`` with ``tree`` first on the path (and, ``own_cache``, a numba cache of
    its own in it: the filing day's tree, under the bench's output); its last line of output
    as JSON."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    if own_cache:
        env["NUMBA_CACHE_DIR"] = str(tree / ".numba")
    done = subprocess.run([sys.executable, "-c", script, *map(str, args)], cwd=tree, env=env,
                          check=True, capture_output=True, text=True, timeout=1800)
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def filed_tree(out: Path) -> Path | None:
    """``FILED_COMMIT``'s tree under ``out`` (``git archive``), or None without git or the
    commit (a tarball of the sources, say)."""
    target = out / f"filed-{FILED_COMMIT}"
    if (target / "benchmarks" / "chains.py").is_file():
        return target
    root = Path(__file__).resolve().parent.parent
    target.mkdir(parents=True, exist_ok=True)
    try:
        archive = subprocess.run(["git", "-C", str(root), "archive", FILED_COMMIT],
                                 capture_output=True, check=True, timeout=120).stdout
        subprocess.run(["tar", "-x", "-C", str(target)], input=archive, check=True,
                       timeout=120)
    except (OSError, subprocess.SubprocessError):
        return None
    return target


def measure_filed(tree: Path, n: int, count: int, plant: str) -> dict[str, Any]:
    """``measure`` of the filing day's code (its benchmarks/chains.py, no twin then) in a
    subprocess (``run_script``)."""
    return run_script(tree, "import json; from benchmarks.chains import measure; "
                      f"print(json.dumps(measure({n}, {count}, {plant!r})))")
