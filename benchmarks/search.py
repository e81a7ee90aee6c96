"""make bench: design searches (issue 44), the cost goal measured.

The goal: a search costs at most 1.2x running its candidates' sweeps one after another. A
search of ``CANDIDATES`` candidates of ``configs/design_search.toml`` (``TRIALS`` trials each,
2 workers) against the same candidates' studies (read back from its search.parquet, each
candidate's spec rebuilt by ``flatcli.designsearch.design``) run as sweeps one after another,
two ways:

* in one process through the Python API (``flatcli.sweep`` per candidate, the kernel loaded
  once): the demanding comparison, every sweep's start-up already paid;
* as ``flatcli sweep`` commands, one process per candidate: what a user scripting the
  candidates would run.

The search runs as ``flatcli search`` (one process: its wall time around it) and through the
API in this process. Runs interleave (search, sweeps, search, sweeps) and ratios are taken
pair by pair; the shared machine's speed drifts.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

COST = "Design search (issue 44): a search against its candidates' sweeps one after another"
HEADERS = {COST: ["how", "search [s]", "sweeps one after another [s]", "ratio", "goal",
                  "note"]}
CANDIDATES = 50
TRIALS = 200
WORKERS = 2
PAIRS = 2
GOAL_RATIO = 1.2


def _spec() -> Path:
    return Path(__file__).resolve().parents[1] / "configs" / "design_search.toml"


def _overrides() -> dict[str, Any]:
    return {"search.candidates": CANDIDATES, "sweep.trials": TRIALS}


def _sets() -> list[str]:
    return [w for k, v in _overrides().items() for w in ("--set", f"{k}={v}")]


def search_process(out: Path) -> float:
    """``flatcli search`` in a fresh process: its wall time [s]."""
    shutil.rmtree(out, ignore_errors=True)
    command = [sys.executable, "-m", "flatcli.cli", "search", str(_spec()), "--out", str(out),
               "-q", "--workers", str(WORKERS), *_sets()]
    began = time.perf_counter()
    subprocess.run(command, check=True)
    return time.perf_counter() - began


def search_api(out: Path) -> float:
    """``flatcli.search`` in this process: its wall time [s]."""
    import flatcli

    shutil.rmtree(out, ignore_errors=True)
    began = time.perf_counter()
    flatcli.search(_spec(), out, overrides=_overrides(), workers=WORKERS, quiet=True)
    return time.perf_counter() - began


def candidate_specs(directory: Path) -> list[Any]:
    """The specs of a finished search's studied candidates, in its order."""
    import pandas as pd

    from flatcli.api import load_spec
    from flatcli.designsearch.design import Design

    spec = load_spec(_spec(), _overrides())
    design = Design.of(spec)
    frame = pd.read_parquet(directory / "search.parquet")
    frame = frame[frame["status"] == "evaluated"]
    specs = []
    for _, row in frame.iterrows():
        candidate = design.candidate(np.array([row[n] for n in design.names], dtype=float))
        assert candidate.spec is not None
        specs.append(candidate.spec)
    return specs


def sweeps_api(specs: list[Any], root: Path) -> float:
    """Each candidate's study as ``flatcli.sweep`` in this process, one after another [s]."""
    import flatcli

    shutil.rmtree(root, ignore_errors=True)
    began = time.perf_counter()
    for i, spec in enumerate(specs):
        flatcli.sweep(spec, root / f"c{i}", workers=WORKERS, quiet=True)
    return time.perf_counter() - began


def sweeps_process(files: list[Path], root: Path) -> float:
    """Each candidate's study as a ``flatcli sweep`` command, one after another [s]."""
    shutil.rmtree(root, ignore_errors=True)
    began = time.perf_counter()
    for i, path in enumerate(files):
        subprocess.run([sys.executable, "-m", "flatcli.cli", "sweep", str(path), "--out",
                        str(root / f"c{i}"), "-q", "--workers", str(WORKERS)], check=True)
    return time.perf_counter() - began


def run_all(bench: Any) -> None:
    from flatcli.spec import spec_toml

    work = Path(tempfile.mkdtemp(prefix="flatcli-bench-search-"))
    try:
        rows: dict[str, dict[str, list[float]]] = {"api": {"search": [], "sweeps": []},
                                                   "process": {"search": [], "sweeps": []}}
        bench.measure(COST, "warm-up search", lambda: search_api(work / "warm"))
        specs = candidate_specs(work / "warm")
        files = []
        for i, spec in enumerate(specs):
            path = work / f"candidate{i}.toml"
            path.write_text(spec_toml(spec, sweep=True))
            files.append(path)
        for k in range(PAIRS):
            rows["api"]["search"].append(bench.measure(
                COST, f"search through the API {k + 1}", lambda: search_api(work / "s")))
            rows["api"]["sweeps"].append(bench.measure(
                COST, f"{len(specs)} sweeps through the API {k + 1}",
                lambda: sweeps_api(specs, work / "w")))
            rows["process"]["search"].append(bench.measure(
                COST, f"flatcli search {k + 1}", lambda: search_process(work / "p")))
            rows["process"]["sweeps"].append(bench.measure(
                COST, f"{len(files)} flatcli sweep commands {k + 1}",
                lambda: sweeps_process(files, work / "q")))
        record = json.loads((work / "p" / "search.json").read_text())
        for how, label in (("api", "in one process (Python API)"),
                           ("process", "as commands (a process each)")):
            ratios = [s / w for s, w in zip(rows[how]["search"], rows[how]["sweeps"],
                                            strict=True)]
            ratio = float(np.median(ratios))
            pairs = ", ".join(f"{r:.2f}" for r in ratios)
            bench.row(COST, label, f"{np.median(rows[how]['search']):.1f}",
                      f"{np.median(rows[how]['sweeps']):.1f}", f"{ratio:.2f}",
                      f"<= {GOAL_RATIO}", f"{CANDIDATES} candidates ({len(specs)} studied) x "
                      f"{TRIALS} trials, {WORKERS} workers; pairs {pairs}")
        bench.raw["search"] = {"rows": rows, "candidates": CANDIDATES, "studied": len(specs),
                               "trials": TRIALS, "workers": WORKERS,
                               "simulated_trials": record.get("simulated_trials")}
    finally:
        shutil.rmtree(work, ignore_errors=True)
