"""``make bench``'s front door (issue 41): a small sweep against the same-work kernel run as a
whole process, Dask against the local executor per worker, ``flatcli check``'s estimate
against the sweep it estimates, a sweep's bytes on disk; and, on request (``--sections
compiles``), what each kernel takes to compile in a fresh numba cache.

Every ratio pairs runs interleaved in one call (A B A B ...) and reports the median of the
pairs with their range; the machine's load is in bench.json beside each measurement.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.baselines import PAPER_MANEUVER, dopri_inputs, dopri_metrics, paper_trials
from benchmarks.baselines import timed as timed_calls
from benchmarks.baselines.kernel_process import kernel_process_seconds

HERE = Path(__file__).resolve().parent
SPEC = HERE / "paper_sweep.toml"
STUDY = HERE.parent / "flatcli" / "data" / "paper_montecarlo.toml"
SAME_WORK = ("--set", "track.error_estimate=none")
FRONT = "The front door (issue 41): small runs, Dask per worker, flatcli check, bytes on disk"
COMPILES = "Compiling each kernel in a fresh numba cache (make bench --sections compiles)"
HEADERS = {
    FRONT: ["what", "measured (median of pairs, range)", "goal", "note"],
    COMPILES: ["what compiles", "seconds", "load", "the compiles it took"],
}


def _median(values: list[float]) -> float:
    return float(np.median(values))


def _range(values: list[float], digits: int = 2) -> str:
    return f"{min(values):.{digits}f}-{max(values):.{digits}f}"


def small_runs(bench: Any, sweep: Callable[..., dict[str, Any]], work: Path) -> dict[str, Any]:
    """10^3 trials: flatcli's whole process against the kernel's whole process
    (``kernel_process``), and against the kernel in this process (no start-up)."""
    section = FRONT
    n = 1000
    rounds = 1 if bench.quick else 7
    kernel_process_seconds(n)  # its first run may compile the kernel
    plan = PAPER_MANEUVER.cubic()
    trials = paper_trials(n, seed=2003)
    inputs = dopri_inputs(plan, trials)
    dopri_metrics(plan, trials.subset(slice(0, 2)), threads=2, inputs=None)
    runs: list[dict[str, Any]] = []
    process: list[float] = []
    inside: list[float] = []
    for _ in range(rounds):
        process.append(bench.measure(section, "kernel, whole process, 10^3", partial(
            kernel_process_seconds, n)))
        inside.append(bench.measure(section, "kernel, in process, 10^3", lambda: timed_calls(
            lambda: dopri_metrics(plan, trials, threads=2, inputs=inputs), 1, 0).median))
        runs.append(bench.measure(section, "flatcli, 10^3", partial(
            sweep, SPEC, work / "n1000", n, 2, *SAME_WORK)))
    whole = [float(r["process_seconds"]) for r in runs]
    against_process = [k / w for k, w in zip(process, whole, strict=True)]
    against_inside = [k / w for k, w in zip(inside, whole, strict=True)]
    bench.row(section, f"{n} trials (error_estimate none, 2 workers), whole process, against "
              "the same-work kernel's whole process (2 threads)",
              f"{_median(against_process):.2f}x ({_range(against_process)})", ">= 0.5x",
              f"flatcli {_median(whole):.2f} s, the kernel {_median(process):.2f} s "
              "(benchmarks/baselines/kernel_process.py: import, trials, kernel, exit)")
    bench.row(section, "  the same, against the kernel in this process (no start-up)",
              f"{_median(against_inside):.2f}x ({_range(against_inside)})", "",
              f"the kernel's trials alone {1e3 * _median(inside):.0f} ms; issue 41 quoted "
              "0.27x")
    return {"flatcli": runs, "kernel_process_seconds": process,
            "kernel_inside_seconds": inside, "ratio_process": against_process,
            "ratio_inside": against_inside}


def dask_per_worker(bench: Any, sweep: Callable[..., dict[str, Any]],
                    work: Path) -> dict[str, Any]:
    """10^4 trials, the default settings, 2 workers: the local executor and a LocalCluster
    of 2 workers (flatcli's own, ``--scheduler local``) in turn. Per worker at steady state:
    each sweep's trials over its wall time after its start-up (run.json's
    ``steady_trials_per_second``), over its workers; and whether the files are the same."""
    section = FRONT
    n = 2000 if bench.quick else 10_000
    rounds = 1 if bench.quick else 4
    local: list[dict[str, Any]] = []
    dask: list[dict[str, Any]] = []
    for _ in range(rounds):
        local.append(bench.measure(section, "local, 10^4", partial(
            sweep, SPEC, work / "local", n, 2)))
        dask.append(bench.measure(section, "dask, 10^4", partial(
            sweep, SPEC, work / "dask", n, 2, "--executor", "dask", "--scheduler", "local")))
    same = all((work / "dask" / name).read_bytes() == (work / "local" / name).read_bytes()
               for name in ("trials.parquet", "summary.parquet", "summary.md"))
    steady = [float(d["steady_trials_per_second"]) / float(s["steady_trials_per_second"])
              for d, s in zip(dask, local, strict=True)]
    whole = [float(d["process_trials_per_second"]) / float(s["process_trials_per_second"])
             for d, s in zip(dask, local, strict=True)]
    per_worker = _median([float(d["steady_trials_per_second"]) / 2 for d in dask])
    started = (_median([float(d["setup_seconds"]) for d in dask]),
               _median([float(s["setup_seconds"]) for s in local]))
    bench.row(section, f"Dask LocalCluster of 2 workers against the local executor, per "
              f"worker at steady state ({n} trials, the default)",
              f"{_median(steady):.2f}x ({_range(steady)})", ">= 0.85x",
              f"{per_worker:.0f} trials/s a worker; start-up {started[0]:.2f} s against "
              f"{started[1]:.2f} s; the same "
              f"trials.parquet, summary.parquet, summary.md to the byte: {same}")
    bench.row(section, "  the same, whole process", f"{_median(whole):.2f}x ({_range(whole)})",
              "", "the cluster's start included")
    return {"local": local, "dask": dask, "ratio_steady": steady, "ratio_whole": whole,
            "identical": same}


def on_disk(bench: Any, work: Path) -> dict[str, Any]:
    """Bytes a finished sweep keeps, per trial: every file of the directory."""
    out: dict[str, Any] = {}
    for name, label in (("local", "the default (twin)"), ("n1000", "error_estimate none")):
        directory = work / name
        if not (directory / "run.json").exists():
            continue
        trials = int(json.loads((directory / "run.json").read_text())["trials"])
        size = sum(p.stat().st_size for p in directory.rglob("*") if p.is_file())
        chunks = list(directory.glob("trials/chunk-*.parquet"))
        out[name] = {"bytes": size, "trials": trials, "chunk_files": len(chunks)}
        bench.row(FRONT, f"on disk after a finished sweep, {trials} trials, {label}",
                  f"{size / trials:.0f} bytes a trial", "<= 300",
                  f"every file of the directory ({size / 1e6:.2f} MB); chunk files left: "
                  f"{len(chunks)}")
    return out


def check_estimates(bench: Any, sweep: Callable[..., dict[str, Any]],
                    work: Path) -> dict[str, Any]:
    """``flatcli check``'s estimate against the sweep it estimates, each check run just
    before its sweep: the bench's 10^4-trial sweep (2 rounds) and the paper's Monte Carlo
    study (once; 36,000 trials in 18 cells, sweep.verify re-runs 2 trials a cell)."""
    section = FRONT
    out: list[dict[str, Any]] = []
    cases: list[tuple[Path, int | None, str]] = [
        (SPEC, 2000 if bench.quick else 10_000, "benchmarks/paper_sweep.toml")] * (
        1 if bench.quick else 2)
    if not bench.quick:
        cases.append((STUDY, None, "the paper's Monte Carlo study"))
    for spec, trials, label in cases:
        sets = [] if trials is None else ["--set", f"sweep.trials={trials}"]
        command = [sys.executable, "-m", "flatcli.cli", "check", str(spec), "--workers", "2",
                   *sets]
        t0 = time.perf_counter()
        text = bench.measure(section, f"check {label}", partial(
            subprocess.run, command, check=True, capture_output=True, text=True)).stdout
        seconds = time.perf_counter() - t0
        estimate = _estimate_seconds(text)
        ran = bench.measure(section, f"sweep {label}", partial(
            sweep, spec, work / "checked", trials if trials is not None else _trials(spec),
            2))
        measured = float(ran["process_seconds"])
        out.append({"spec": label, "check_seconds": seconds, "estimate": estimate,
                    "measured": measured, "load": os.getloadavg()[0]})
    for label in dict.fromkeys(c[2] for c in cases):
        mine = [o for o in out if o["spec"] == label]
        ratios = [o["estimate"] / o["measured"] for o in mine]
        bench.row(section, f"flatcli check's estimate against the sweep, {label}",
                  f"{_median(ratios):.2f}x ({_range(ratios)})", "within 2x (0.5-2x)",
                  f"estimate {_median([o['estimate'] for o in mine]):.1f} s, measured "
                  f"{_median([o['measured'] for o in mine]):.1f} s (whole process)")
        bench.row(section, f"  flatcli check's own time, {label}",
                  f"{_median([o['check_seconds'] for o in mine]):.1f} s", "<= 10 s",
                  "whole process, kernels cached")
    return {"checks": out}


def _trials(spec: Path) -> int:
    """sweep.trials of a spec file (the sweep helper sets it again, to the same value)."""
    import tomllib

    return int(tomllib.loads(spec.read_text())["sweep"]["trials"])


def _estimate_seconds(text: str) -> float:
    """The estimate ``flatcli check`` printed ("estimate on ...: 25 s (" or "1.5 min (")."""
    found = re.search(r"^estimate on [^\n]*?: ([0-9.]+) (s|min|h) \(", text, re.MULTILINE)
    if found is None:
        raise RuntimeError("flatcli check printed no estimate")
    return float(found.group(1)) * {"s": 1.0, "min": 60.0, "h": 3600.0}[found.group(2)]


def run_all(bench: Any, sweep: Callable[..., dict[str, Any]]) -> None:
    work = bench.out / "front_door"
    started = time.perf_counter()
    raw: dict[str, Any] = {}
    raw["small"] = small_runs(bench, sweep, work)
    raw["dask"] = dask_per_worker(bench, sweep, work)
    raw["disk"] = on_disk(bench, work)
    raw["check"] = check_estimates(bench, sweep, work)
    raw["seconds"] = time.perf_counter() - started
    bench.raw["front_door"] = raw
    shutil.rmtree(work, ignore_errors=True)


#: The kernels ``compiles`` compiles, each by a track run in a fresh process and numba cache:
#: (what the notice calls it, the spec overrides that run it).
FAMILIES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("paper model, kinematic plant", ()),
    ("paper model, dynamic plant", ("plant.model=dynamic",)),
    ("chain model, kinematic plant", ("robot=chain4",)),
    ("chain model, dynamic plant", ("robot=chain4", "plant.model=dynamic")),
    ("as-built model, kinematic plant", (
        "robot.com=[0.1,0.1,0.003]", "plant.com=[0.1,0.1,0.003]", "plan.method=exact",
        "track.controller=asbuilt")),
    ("as-built model, dynamic plant", (
        "robot.com=[0.1,0.1,0.003]", "plant.com=[0.1,0.1,0.003]", "plan.method=exact",
        "track.controller=asbuilt", "plant.model=dynamic")),
)
#: What the fresh process runs: a track run of the overrides, numba's compile events timed.
_COMPILE_SCRIPT = """
import json, sys, time
from numba.core import event
import flatcli
depth, found, start = [0], [], {}
class Timed(event.Listener):
    def on_start(self, ev):
        if depth[0] == 0:
            start["t"] = time.perf_counter()
            f = ev.data["dispatcher"].py_func
            start["name"] = f.__module__ + "." + f.__qualname__
        depth[0] += 1
    def on_end(self, ev):
        depth[0] -= 1
        if depth[0] == 0:
            found.append([start["name"], time.perf_counter() - start["t"]])
event.register("numba:compile", Timed())
t0 = time.perf_counter()
flatcli.track(None, overrides=sys.argv[1:], quiet=True)
print(json.dumps({"seconds": time.perf_counter() - t0, "compiles": found}))
"""


def compiles(bench: Any) -> None:
    """Each kernel family compiled by a track run in a fresh process and a fresh numba
    cache, one after the other (minutes each): the figures ``flatcli.progress``'s notice
    expects (``COMPILE_SECONDS``) before a machine has its own."""
    raw = []
    for name, overrides in FAMILIES:
        with tempfile.TemporaryDirectory(prefix="flatcli-compile-") as cache:
            env = {**os.environ, "NUMBA_CACHE_DIR": cache}
            before = os.getloadavg()[0]
            out = bench.measure(COMPILES, name, partial(
                subprocess.run, [sys.executable, "-c", _COMPILE_SCRIPT, *overrides],
                check=True, capture_output=True, text=True, env=env)).stdout
        result = json.loads(out.strip().splitlines()[-1])
        total = sum(s for _, s in result["compiles"])
        load = f"{before:.1f}-{os.getloadavg()[0]:.1f}"
        parts = ", ".join(f"{n.rsplit('.', 1)[-1]} {s:.0f} s" for n, s in result["compiles"])
        bench.row(COMPILES, name, f"{total:.0f}", load, parts)
        raw.append({"family": name, **result, "load_before": before})
    bench.raw["compiles"] = raw
