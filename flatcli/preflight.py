"""``flatcli check SPEC`` and ``flatcli sweep SPEC --dry-run``: what a sweep would do.

The resolved spec, the cells with their grid values, the trials and chunks, an estimate of
the wall time and peak memory from a short calibration, and warnings about a study that
would waste its time. Nothing is written (numba's own cache aside: a cold kernel compiles,
announced with its expected time).

The calibration is bounded in time, whatever the number of cells (``CALIBRATION_SECONDS``
once the kernels are loaded), and says what it does as it goes. Cells are grouped by the
compiled kernel they run (``family``: model, plant, controller, integrator, joints). Here,
each kernel is loaded (or compiled) by one trial; then, in worker processes forked from
this one as a sweep's are, and as many as the sweep would run at once:

* for each kernel, its first cell's trials alone (one, then ``CALIBRATION_CHUNK``; ids
  past the ``sweep.verify`` ones): the CPU time of a trial and a chunk's own cost (draws,
  rows, table), and, when the sweep verifies trials, the cost of one re-run;
* then, kernels taken in turn, each cell's first trials with the same ids in every cell
  (the same random draws), as many cells as the time allows: each cell's own cost per
  trial. A cell not reached costs its kernel's, in proportion to its output steps.

The sweep's chunks then cost that much each, spread over the workers, slowed by what the
calibration's workers met (their wall time over their CPU time: other processes on the
cores, the sweep's own workers), and the worker's peak memory is measured.

Running the same draws in every cell also tells which grid keys change nothing: if every
pair of cells that differ only in one key's value gives identical results, that key does
not reach the simulation (e.g. ``track.seed``, which a sweep replaces with ``sweep.seed``),
or not on these trials. That needs every cell: with more cells than the time allows, it is
not told.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import math
import multiprocessing
import os
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import (
    FIRST_COMPLETED,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from flatcli.core.loop.metrics import STATUS_NAMES
from flatcli.executors import default_workers
from flatcli.machine import physical_memory
from flatcli.montecarlo import Cell, Chunk, Layout, grid_cell_text, grid_label, layout, run_chunk
from flatcli.montecarlo.chunks import verify_count
from flatcli.montecarlo.directory import summary_cells
from flatcli.montecarlo.layout import family
from flatcli.progress import compile_notices, kernel_text, planner_text
from flatcli.report import fmt, short_key, table
from flatcli.report.summary import SUMMARY_INPUTS, ColumnsOf, summary_rows
from flatcli.spec import Spec, spec_toml
from flatcli.spec.unread import unread_keys, unseen_draws
from flatcli.storage import parquet_options, peak_memory_mib

#: Trials the same-draws calibration runs in all, at best (at least ``SAME_DRAWS_MIN`` per
#: cell, at most ``CALIBRATION_CHUNK``).
CALIBRATION_TRIALS = 128
SAME_DRAWS_MIN = 2
#: Trials of a kernel's chunk that measures its cost per trial, and how many times its two
#: chunks (of 1 and of these trials) run: the least CPU time of each is taken.
CALIBRATION_CHUNK = 8
KERNEL_REPEATS = 2
#: The longest the calibration runs once the kernels are loaded [s] (the chunks running
#: then finish; a kernel's first cell is always measured).
CALIBRATION_SECONDS = 5.0
#: The least it runs, however long the layout took [s].
CALIBRATION_MIN_SECONDS = 1.0
#: How long it keeps measuring more trials of each cell once every cell has its same draws
#: (the budget allowing) [s]: the share of the cores the sweep will get shows over seconds
#: of work, where a short burst of it is favoured by the kernel's scheduler.
CALIBRATION_STEADY_SECONDS = 2.0
#: How often the calibration says how far it is [s].
REPORT_EVERY = 1.0
#: Rows, and cells, of the synthetic trials table whose summary is timed to estimate the
#: final tables.
FINISH_SAMPLE_ROWS = 20_000
FINISH_SAMPLE_CELLS = 20
#: The longest ``flatcli check`` takes, its kernels' loading (or compiling) aside [s]: the
#: calibration gives out chunks until this much after the check started, less
#: ``CHECK_RESERVE`` for what follows it, and for ``CALIBRATION_SECONDS`` at most (the
#: first cell of each kernel is always measured).
CHECK_SECONDS = 7.0
CHECK_RESERVE = 1.0
#: Cells listed in the text (the DataFrame ``CheckReport.cells`` has them all).
SHOWN_CELLS = 40
MIB = 1024 * 1024


@dataclass(frozen=True)
class KernelCost:
    """The calibration of the cells that run one compiled kernel (``family``)."""

    name: str  # "paper model, kinematic plant, flat controller, adaptive, 2 joints"
    cells: int  # cells of the study that run it
    per_trial: float  # a trial of its first cell, CPU [s]
    per_chunk: float  # a chunk's own cost beside its trials, CPU [s]
    verify: float  # one ``sweep.verify`` re-run beside its trial, CPU [s] (0: none)
    load_seconds: float  # its first trial here: loading (or compiling) the kernel [s]
    compiled: bool  # numba compiled it here (its cache was cold)


@dataclass(frozen=True)
class Calibration:
    """The calibration trials: how many, how long, how they ended, how large their rows."""

    per_cell: int  # trials of each cell in the same-draws calibration
    trials: int  # trials run in all
    per_trial: float  # a trial of the study, CPU, the mean over its cells [s]
    per_chunk: float  # a chunk's own cost, CPU, the mean over its chunks [s]
    warm_up_seconds: float  # loading (or compiling) the kernels here [s]
    compiled: bool  # a kernel was compiled by this check (numba's cache was cold)
    statuses: dict[str, int]
    row_bytes: float  # of a trials.parquet row in memory (Arrow)
    finish_seconds_per_trial: float  # final tables, per trial
    finish_bytes_per_trial: float  # the main process's tables at the end, per trial
    finish_rows: int  # rows of the final tables this check built to time them
    worker_mib: float | None  # peak resident memory of the calibration's workers
    unchanged_keys: tuple[str, ...] | None  # grid keys that changed nothing (None: untold)
    kernels: tuple[KernelCost, ...] = ()
    cell_trial: tuple[float, ...] = ()  # each cell's cost per trial, CPU [s]
    cell_chunk: tuple[float, ...] = ()  # its kernel's cost per chunk [s]
    cell_verify: tuple[float, ...] = ()  # its sweep.verify re-runs, all of them [s]
    measured_cells: int = 0  # cells whose own trials were run
    slowdown: float = 1.0  # the calibration workers' wall time over their CPU time
    other_load: float = 0.0  # the load average at its end, less its own processes
    processes: int = 1  # worker processes the calibration ran in
    seconds: float = 0.0  # the calibration's wall time after loading the kernels [s]


@dataclass(frozen=True)
class CheckReport:
    """What ``flatcli check`` prints, as values."""

    spec: Spec
    layout: Layout
    workers: int
    executor: str
    planning_seconds: float
    calibration: Calibration | None
    base_rss_mib: float
    warnings: tuple[str, ...]
    cores: int = 1  # this machine's cores (a local sweep's workers share them)
    load: float = 0.0  # its load average over the last minute

    @property
    def chunks(self) -> list[Chunk]:
        return list(self.layout.chunks())

    @property
    def cells(self) -> pd.DataFrame:
        """One row per cell: its index, grid values, trials and chunks."""
        per_cell = math.ceil(self.layout.trials_per_cell / self.layout.chunk_size)
        rows = [{"cell": c.index, **{k: grid_cell_text(v) for k, v in c.values.items()},
                 "trials": self.layout.trials_per_cell, "chunks": per_cell}
                for c in self.layout.cells]
        return pd.DataFrame(rows)

    @property
    def estimate_seconds(self) -> float | None:
        """Estimated wall time of the sweep [s]: planning, loading the kernels, the trials
        spread over the workers chunk by chunk, and the final tables."""
        cal = self.calibration
        if cal is None:
            return None
        return self.planning_seconds + self._load_seconds + self._trial_seconds + \
            cal.finish_seconds_per_trial * self.layout.total

    @property
    def _load_seconds(self) -> float:
        """Loading the kernels, as this check did where they were cached (a compiled one:
        as a cached kernel loads, the others' mean, else nothing)."""
        cal = self.calibration
        if cal is None:
            return 0.0
        cached = [k.load_seconds for k in cal.kernels if not k.compiled]
        typical = sum(cached) / len(cached) if cached else 0.0
        return sum(typical if k.compiled else k.load_seconds for k in cal.kernels)

    def _chunk_cost(self, chunk: Chunk) -> float:
        """A chunk's CPU time [s]: its cell's cost per chunk and per trial."""
        cal = self.calibration
        assert cal is not None
        if not cal.cell_trial:
            return cal.per_chunk + chunk.size * cal.per_trial
        return cal.cell_chunk[chunk.cell] + chunk.size * cal.cell_trial[chunk.cell]

    @property
    def cpu_seconds(self) -> float | None:
        """Estimated CPU time of the sweep's trials, all workers together [s]."""
        cal = self.calibration
        if cal is None:
            return None
        return sum(self._chunk_cost(c) for c in self.chunks) + sum(cal.cell_verify)

    @property
    def slowdown(self) -> float:
        """How much slower than alone the sweep's workers will run here (a local sweep; 1
        elsewhere): the more of what the calibration's workers met (their wall time over
        their CPU time) and what the load average says (the other processes' and the
        workers' runnable processes over the cores). A short calibration sees less than a
        sweep will (the kernel's scheduler favours a process that has just woken), the load
        average more when the load has just fallen (docs/performance.md: how each did)."""
        cal = self.calibration
        if cal is None or self.executor != "local":
            return 1.0
        busy = min(self.workers, len(self.chunks), self.cores)
        return max(1.0, cal.slowdown, (cal.other_load + busy) / self.cores)

    @property
    def _trial_seconds(self) -> float:
        """The trials' wall time [s]: their CPU time over the cores the workers get, times
        ``slowdown``."""
        cal = self.calibration
        assert cal is not None
        chunks = self.chunks
        local = self.executor == "local"
        busy = min(self.workers, len(chunks), self.cores if local else self.workers)
        work = self.cpu_seconds or 0.0
        largest = max(self._chunk_cost(c) for c in chunks)
        return max(work / busy, largest) * self.slowdown

    @property
    def memory_mib(self) -> tuple[float, float] | None:
        """Estimated peak resident memory [MiB] of the main process and of each worker.

        Main: this process's peak, which has done the main process's work on a smaller
        scale (imports, planning, the final tables of ``finish_rows`` trials), plus the
        final tables' bytes of the trials beyond those. Worker: the peak of the worker that
        ran the calibration, plus the rows of a full chunk beyond its ``per_cell`` (twice:
        the arrays and the table built from them).
        """
        cal = self.calibration
        if cal is None:
            return None
        extra_rows = max(self.layout.total - cal.finish_rows, 0)
        main = self.base_rss_mib + extra_rows * cal.finish_bytes_per_trial / MIB
        chunk_rows = 2 * max(self.layout.chunk_size - cal.per_cell, 0) * cal.row_bytes / MIB
        worker = (cal.worker_mib if cal.worker_mib is not None else self.base_rss_mib)
        return main, worker + chunk_rows

    def text(self) -> str:
        """The report as the terminal shows it."""
        lay = self.layout
        chunks = self.chunks
        n_cells = len(lay.cells)
        lines = [f"spec {self.spec.name!r}, resolved (every key; defaults filled in):", "",
                 resolved_toml(self.spec, lay.chunk_size), ""]
        keys = lay.grid_keys
        rows = [[c.index, *(_value_text(c.values[k]) for k in keys), lay.trials_per_cell,
                 math.ceil(lay.trials_per_cell / lay.chunk_size)]
                for c in lay.cells[:SHOWN_CELLS]]
        lines += [f"cells ({n_cells}):", "",
                  table(["cell", *(short_key(k) for k in keys), "trials", "chunks"], rows)]
        if n_cells > SHOWN_CELLS:
            lines.append(f"... and {n_cells - SHOWN_CELLS} more cells")
        sizes = sorted({c.size for c in chunks})
        size_text = f"{sizes[-1]}" if len(sizes) == 1 else f"{sizes[0]} to {sizes[-1]}"
        lines += ["", f"{lay.total} trials: {n_cells} cell{'s' if n_cells > 1 else ''} of "
                      f"{lay.trials_per_cell}, in {len(chunks)} chunks of {size_text} trials; "
                      f"planning the cells took {self.planning_seconds:.2f} s"]
        cal = self.calibration
        if cal is not None:
            counts = ", ".join(f"{s} {cal.statuses.get(s, 0)}" for s in STATUS_NAMES
                               if s != "error" or cal.statuses.get(s))
            compiled = (f"; compiled first ({cal.warm_up_seconds:.0f} s, now cached)"
                        if cal.compiled else "")
            plural = "s" if cal.processes > 1 else ""
            lines.append(f"calibration: {cal.trials} trials in {cal.seconds:.1f} s on "
                         f"{cal.processes} worker process{'es' if plural else ''}, "
                         f"{cal.measured_cells} of {n_cells} cells measured "
                         f"({cal.per_cell} trials each, the same draws): "
                         f"{1e3 * cal.per_trial:.3g} ms per trial and "
                         f"{1e3 * cal.per_chunk:.3g} ms per chunk; {counts}{compiled}")
            for k in cal.kernels:
                verify = (f", {1e3 * k.verify:.3g} ms per sweep.verify re-run"
                          if k.verify else "")
                lines.append(f"  {k.name} ({k.cells} cell{'s' if k.cells > 1 else ''}): "
                             f"{1e3 * k.per_trial:.3g} ms per trial of its first cell"
                             f"{verify}; loaded in {k.load_seconds:.2f} s"
                             + (" (compiled)" if k.compiled else ""))
            total = self.estimate_seconds
            assert total is not None
            where = f"{self.workers} {self.executor} worker{'s' if self.workers > 1 else ''}"
            if self.executor == "local":
                cores = min(self.workers, self.cores)
                where += f" on {cores} core{'s' if cores > 1 else ''}"
                if self.slowdown > 1.05:
                    where += (f", {self.slowdown:.1f}x slower than alone (the calibration's "
                              f"workers {cal.slowdown:.1f}x; the load average "
                              f"{cal.other_load:.1f} besides)")
            lines.append(
                f"estimate on {where}: {duration_estimate(total)} (planning "
                f"{self.planning_seconds:.1f} s, loading the kernel {self._load_seconds:.1f} s, "
                f"trials {self._trial_seconds:.1f} s, final tables "
                f"{cal.finish_seconds_per_trial * lay.total:.1f} s); the trials take "
                f"{duration_estimate(self.cpu_seconds or 0.0)} of CPU")
            memory = self.memory_mib
            assert memory is not None
            main, worker = memory
            lines.append(f"peak memory: ~{main:.0f} MiB main process, ~{worker:.0f} MiB per "
                         f"worker process (resident, shared pages counted in each)")
        lines += closing_lines(self.warnings)
        return "\n".join(lines)


def closing_lines(warnings: Sequence[str]) -> list[str]:
    """The last lines of a check's text: its warnings (or that there are none), and that it
    wrote nothing."""
    said = ["warnings:", *(f"- {w}" for w in warnings)] if warnings else ["no warnings"]
    return ["", *said, "", "nothing written"]


def duration_estimate(seconds: float) -> str:
    """An estimated time in words: '45 s', '4.2 min', '3.1 h'."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def _value_text(value: Any) -> Any:
    if isinstance(value, dict):
        return str(value["label"]) if "label" in value else grid_label(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(fmt(v) for v in value) + "]"
    return value


def resolved_toml(spec: Spec, chunk: int) -> str:
    """The spec as TOML, every key, ``[sweep]`` and its tables included; the chunk size as
    resolved (commented when it is the default)."""
    default = spec.sweep.chunk is None
    return spec_toml(spec, sweep=True, values={"sweep.chunk": chunk},
                     notes={"sweep.chunk": "the default for this sweep"} if default else {}
                     ).rstrip("\n")


# ---------------------------------------------------------------------------------------
# The check.

def check_spec(spec: Spec, workers: int | None = None, executor: str = "local",
               calibrate: bool = True, quiet: bool = False,
               budget: float = CALIBRATION_SECONDS) -> CheckReport:
    """Lay the sweep out, calibrate (at most ``budget`` seconds once the kernels are loaded,
    saying what it does on stderr unless ``quiet``), estimate and warn (see the module
    docstring)."""
    if workers is not None and workers < 1:
        from flatcli.core.errors import FlatcliError

        raise FlatcliError(f"--workers: must be >= 1, got {workers}")
    started = time.perf_counter()
    with compile_notices(planner_text(spec), quiet or not calibrate):
        lay = layout(spec)  # (the planner may compile its maps)
    planning = time.perf_counter() - started
    n_workers = workers if workers is not None else default_workers()
    calibration = None
    if calibrate:
        say = (lambda text: None) if quiet else _stderr
        processes = max(1, min(n_workers, default_workers()))
        left = CHECK_SECONDS - CHECK_RESERVE - (time.perf_counter() - started)
        calibration = _calibrate(lay, processes, min(budget, max(CALIBRATION_MIN_SECONDS,
                                                                  left)), say, quiet)
    report = CheckReport(spec, lay, n_workers, executor, planning, calibration, _rss_mib(), (),
                         default_workers(), os.getloadavg()[0])
    return replace(report, warnings=tuple(_warnings(report)))


def _stderr(text: str) -> None:
    import sys

    print(text, file=sys.stderr, flush=True)


def _rss_mib() -> float:
    """Peak resident memory of this process so far, its own (``storage.peak_memory_mib``:
    not that of the process that started it) [MiB]."""
    return peak_memory_mib()


def _measured(cell: Cell, chunk: Chunk) -> tuple[pa.Table, float, float]:
    """A calibration chunk (a worker's job): its table, CPU time and wall time [s]."""
    wall, cpu = time.perf_counter(), time.process_time()
    table = run_chunk(cell, chunk).table
    return table, time.process_time() - cpu, time.perf_counter() - wall


def _worker_peak() -> float:
    return peak_memory_mib()


def _calibrate(lay: Layout, processes: int, budget: float, say: Callable[[str], None],
               quiet: bool) -> Calibration:
    """The calibration (module docstring), in ``processes`` worker processes, new chunks
    given out for ``budget`` seconds after the kernels are loaded; ``say`` tells how far it
    is."""
    spec = lay.spec
    groups: dict[str, list[Cell]] = {}
    for cell in lay.cells:
        groups.setdefault(family(cell), []).append(cell)
    verify = verify_count(spec.sweep.verify, spec.sweep.trials)
    skip = verify if verify < lay.trials_per_cell else 0  # past the verified trials
    k = max(1, min(CALIBRATION_CHUNK, lay.trials_per_cell - skip))
    per_cell = min(CALIBRATION_CHUNK, lay.trials_per_cell,
                   max(SAME_DRAWS_MIN, math.ceil(CALIBRATION_TRIALS / len(lay.cells))))
    say(f"calibrating {len(lay.cells)} cell{'s' if len(lay.cells) > 1 else ''} of "
        f"{len(groups)} kernel{'s' if len(groups) > 1 else ''}, at most "
        f"{budget:g} s once loaded, in {processes} worker process"
        f"{'es' if processes > 1 else ''}")
    # each kernel loaded (or compiled) here, so the forked workers have it
    loads: dict[str, tuple[float, bool]] = {}
    for name, cells in groups.items():
        lead = cells[0]
        began = time.perf_counter()
        with compile_notices(kernel_text(lead.scenario), quiet) as notice:
            run_chunk(lead, Chunk(lead.index, lead.first_trial + skip,
                                  lead.first_trial + skip + 1))
        loads[name] = (time.perf_counter() - began, notice.compiled)
    began = time.perf_counter()
    deadline = began + budget
    jobs: list[tuple[str, Any, Cell, Chunk]] = []  # (what, its key, cell, chunk)
    for name, cells in groups.items():
        c = cells[0]
        first = c.first_trial
        for again in range(KERNEL_REPEATS):  # the least of each: its own cost, less noise
            jobs.append(("one", (name, again), c, Chunk(c.index, first + skip,
                                                        first + skip + 1)))
            jobs.append(("many", (name, again), c, Chunk(c.index, first + skip,
                                                         first + skip + k)))
        if 0 < verify < lay.trials_per_cell:  # one verified trial: its re-run's cost
            jobs.append(("verified", (name, 0), c, Chunk(c.index, first, first + 1)))
    turns = list(itertools.chain.from_iterable(itertools.zip_longest(*groups.values())))
    order = [c for c in turns if c is not None]  # kernels in turn
    kernel_jobs = len(jobs)
    # the same draws in every cell (ids 0 .. per_cell - 1), then, while the calibration has
    # run less than CALIBRATION_STEADY_SECONDS, more of each cell's trials (the next ids):
    # the cores' share a sweep gets shows over seconds, not over a short burst
    rounds = ((r, c) for r in itertools.count() for c in order)
    results: dict[tuple[str, Any], tuple[pa.Table, float, float]] = {}
    lead = next(iter(groups.values()))[0]
    warm = (lead, Chunk(lead.index, lead.first_trial + skip, lead.first_trial + skip + 1))
    steady = began + min(CALIBRATION_STEADY_SECONDS, budget)
    with _pool(processes, warm) as pool:
        pending: dict[Future[Any], tuple[str, Any]] = {}
        queue = iter(jobs)
        given = 0
        last_said = began
        while True:
            while len(pending) < 2 * processes:
                now = time.perf_counter()
                if given < kernel_jobs:
                    job = next(queue)
                else:
                    r, cell = next(rounds)
                    if now >= deadline or (r > 0 and now >= steady):
                        break
                    # (ids past sweep.verify's: those of the one cell of a sweep without a
                    # grid, key 0, are its own)
                    job = ("same", (cell.index, r), cell,
                           Chunk(cell.index, skip + r * per_cell, skip + (r + 1) * per_cell))
                pending[pool.submit(_measured, job[2], job[3])] = (job[0], job[1])
                given += 1
            if not pending:
                break
            done, _ = wait(pending, timeout=REPORT_EVERY, return_when=FIRST_COMPLETED)
            for future in done:
                results[pending.pop(future)] = future.result()
            now = time.perf_counter()
            if now - last_said >= REPORT_EVERY:
                last_said = now
                measured = sum(1 for what, key in results if what == "same" and key[1] == 0)
                say(f"  {measured} of {len(lay.cells)} cells measured, {now - began:.1f} s")
        worker_mib = max(pool.submit(_worker_peak).result() for _ in range(processes))
    seconds = time.perf_counter() - began
    return _costs(lay, groups, loads, results, k, per_cell, verify, worker_mib, seconds,
                  processes, say)


def _other_load(processes: int, seconds: float) -> float:
    """The 1-minute load average now, less the calibration's own ``processes`` busy for its
    last ``seconds`` (the average weighs the last t seconds by 1 - exp(-t / 60))."""
    own = processes * (1.0 - math.exp(-seconds / 60.0))
    return max(0.0, os.getloadavg()[0] - own)


@contextlib.contextmanager
def _pool(processes: int, warm: tuple[Cell, Chunk]) -> Iterator[Any]:
    """Worker processes forked from this one, as a sweep's are (they inherit the loaded
    kernels), each of which first runs ``warm`` (a chunk: what a process does the first time
    is not what a chunk costs); this process itself where there is no fork."""
    try:
        context = multiprocessing.get_context("fork")
    except ValueError:  # pragma: no cover - not POSIX
        with ThreadPoolExecutor(1) as threads:
            yield threads
        return
    with ProcessPoolExecutor(processes, mp_context=context, initializer=_warmed,
                             initargs=warm) as pool:
        yield pool


def _warmed(cell: Cell, chunk: Chunk) -> None:
    run_chunk(cell, chunk)


def _costs(lay: Layout, groups: dict[str, list[Cell]], loads: dict[str, tuple[float, bool]],
           results: dict[tuple[str, Any], tuple[pa.Table, float, float]], k: int,
           per_cell: int, verify: int, worker_mib: float, seconds: float, processes: int,
           say: Callable[[str], None]) -> Calibration:
    """The calibration's figures from its chunks' tables and times (``_calibrate``)."""
    kernels = []
    trial_of: dict[int, float] = {}  # cell -> CPU per trial, where measured
    chunk_of: dict[str, float] = {}
    step_of: dict[str, float] = {}  # kernel -> CPU per trial and output step
    verify_of: dict[str, float] = {}
    for name, cells in groups.items():
        one = min(results[("one", (name, again))][1] for again in range(KERNEL_REPEATS))
        many = min(results[("many", (name, again))][1] for again in range(KERNEL_REPEATS))
        per_trial = max(many - one, 0.0) / (k - 1) if k > 1 else many
        per_chunk = max(one - per_trial, 0.0) if k > 1 else 0.0
        verified = results.get(("verified", (name, 0)))
        re_run = max(verified[1] - one, 0.0) if verified is not None else 0.0
        chunk_of[name], verify_of[name] = per_chunk, re_run
        steps = []
        for cell in cells:
            runs = [v for (what, key), v in results.items()
                    if what == "same" and key[0] == cell.index]
            if runs:
                cpu = sum(c for _, c, _ in runs) - per_chunk * len(runs)
                trial_of[cell.index] = max(cpu, 0.0) / sum(t.num_rows for t, _, _ in runs)
                steps.append(trial_of[cell.index] / cell.scenario.n_steps)
        step_of[name] = (sum(steps) / len(steps) if steps
                         else per_trial / cells[0].scenario.n_steps)
        kernels.append(KernelCost(name, len(cells), per_trial, per_chunk, re_run,
                                  loads[name][0] - per_trial - per_chunk, loads[name][1]))
        say(f"  {name}: {1e3 * per_trial:.3g} ms per trial, {1e3 * per_chunk:.3g} ms per "
            f"chunk")
    names = {cell.index: name for name, cells in groups.items() for cell in cells}
    cell_trial = tuple(trial_of.get(c.index, step_of[names[c.index]] * c.scenario.n_steps)
                       for c in lay.cells)
    cell_chunk = tuple(chunk_of[names[c.index]] for c in lay.cells)
    cell_verify = tuple(verify * verify_of[names[c.index]] for c in lay.cells)
    tables = [results[("same", (c.index, 0))][0] for c in lay.cells
              if ("same", (c.index, 0)) in results]  # the same draws in every cell
    everything = [t for t, _, _ in results.values()]
    cpu = sum(c for _, c, _ in results.values())
    wall = sum(w for _, _, w in results.values())
    statuses: dict[str, int] = {}
    for t in everything:
        for s in t.column("status").to_pylist():
            statuses[s] = statuses.get(s, 0) + 1
    rows = sum(t.num_rows for t in everything)
    row_bytes = sum(t.nbytes for t in everything) / rows
    finish_seconds, finish_bytes, finish_rows = _finish_cost(lay, everything)
    n_chunks = sum(1 for _ in lay.chunks())
    unchanged = (tuple(_unchanged_keys(lay, tables)) if len(tables) == len(lay.cells)
                 else None)
    return Calibration(
        per_cell, rows, sum(cell_trial) / len(cell_trial),
        sum(cell_chunk[c.cell] for c in lay.chunks()) / n_chunks,
        sum(load for load, _ in loads.values()), any(cold for _, cold in loads.values()),
        statuses, row_bytes, finish_seconds, finish_bytes, finish_rows, worker_mib,
        unchanged, tuple(kernels), cell_trial, cell_chunk, cell_verify, len(trial_of),
        max(1.0, wall / cpu) if cpu > 0 else 1.0, _other_load(processes, seconds),
        processes, seconds)


def _finish_cost(lay: Layout, tables: Sequence[pa.Table]) -> tuple[float, float, int]:
    """Time and memory per trial of the sweep's work in the main process beyond the chunk
    files, measured on a share f of the study (``FINISH_SAMPLE_ROWS`` trials at most, in
    ``FINISH_SAMPLE_CELLS`` cells at most: its cost grows with both), the calibration rows
    repeated, along the sweep's own path: appended to trials.parquet (here in memory) in
    chunk-sized tables as they come in, the summary's columns taken as they pass
    (``ColumnsOf``), and summarised per cell (``summary_rows``). The appends happen while
    the workers run and the summary after them; both are counted, as if after them."""
    combined = pa.concat_tables([t.cast(tables[0].schema) for t in tables])
    share = min(1.0, FINISH_SAMPLE_ROWS / lay.total, FINISH_SAMPLE_CELLS / len(lay.cells))
    n = max(1, math.ceil(lay.total * share))
    chosen = lay.cells[:max(1, math.ceil(len(lay.cells) * share))]
    repeats = math.ceil(n / combined.num_rows)
    big = pa.concat_tables([combined] * repeats).slice(0, n).combine_chunks()
    which = np.array([c.index for c in chosen], dtype=np.int64)[np.arange(n) % len(chosen)]
    big = big.set_column(big.schema.get_field_index("cell"), "cell",
                         pa.array(np.sort(which), pa.int64()))
    every = summary_cells(lay)
    cells = {c.index: every[c.index] for c in chosen}
    began = time.process_time()
    gathered = ColumnsOf(SUMMARY_INPUTS)
    with pq.ParquetWriter(io.BytesIO(), big.schema, **parquet_options(big.schema)) as writer:
        for start in range(0, n, lay.chunk_size):
            part = big.slice(start, lay.chunk_size)
            writer.write_table(part)
            gathered.add(part)
    columns = gathered.columns()
    summary_rows(columns, cells, lay.spec.summary.reach_tolerance)
    seconds = time.process_time() - began
    in_memory = sum(int(values.nbytes) for values in columns.values())
    return seconds / n, in_memory / n, n


def _unchanged_keys(lay: Layout, tables: Sequence[pa.Table]) -> list[str]:
    """Grid keys whose values never changed a calibration trial's results (``tables``: each
    cell's, in the grid's order, with the same draws)."""
    keys = lay.grid_keys
    if not keys or not any(s != "error" for t in tables for s in t.column("status").to_pylist()):
        return []
    drop = ["cell", *keys]
    # (Arrow's equality: a not-applicable metric is null, never nan, so nulls compare alike)
    results = [t.drop_columns([c for c in drop if c in t.column_names]) for t in tables]
    index = {tuple(_freeze(c.values[k]) for k in keys): c.index for c in lay.cells}
    unchanged = []
    for j, key in enumerate(keys):
        values = lay.spec.sweep.grid[key]
        if len(values) < 2:
            continue
        others = [lay.spec.sweep.grid[k] for k in keys if k != key]
        same = True
        for rest in itertools.product(*others):
            group = []
            for v in values:
                combo = list(rest)
                combo.insert(j, v)
                group.append(index[tuple(_freeze(x) for x in combo)])
            first = results[group[0]]
            if not all(results[g].equals(first) for g in group[1:]):
                same = False
                break
        if same:
            unchanged.append(key)
    return unchanged


def _freeze(value: Any) -> str:
    return json.dumps(value, sort_keys=True)


def _warnings(report: CheckReport) -> list[str]:
    lay = report.layout
    spec = lay.spec
    out: list[str] = [w.removeprefix("warning: ")
                      for w in unread_keys(spec) + unseen_draws(spec)]
    noiseless = all(c.spec.track.sensor_noise == 0 for c in lay.cells)
    if not spec.sweep.perturb and noiseless and lay.trials_per_cell > 1:
        where = "the" if not lay.grid_keys else "each cell's"
        out.append(f"no [sweep.perturb] and no track.sensor_noise: {where} "
                   f"{lay.trials_per_cell} trials are identical (sweep.trials = 1 would do)")
    cal = report.calibration
    if cal is not None:
        for key in cal.unchanged_keys or ():
            out.append(f"grid key {key!r} changes nothing: its values gave identical results "
                       f"on all {cal.trials} calibration trials (same draws in every cell); "
                       "it does not reach the simulation (or not on these trials)")
    if report.executor == "local" and report.load >= report.cores:
        out.append(f"this machine is busy (load average {report.load:.1f} on {report.cores} "
                   f"core{'s' if report.cores > 1 else ''}): the estimate allows for the "
                   "share of the cores the calibration got; the sweep's time follows the load")
    if report.executor == "local" and report.workers > report.cores:
        out.append(f"{report.workers} workers on {report.cores} cores: no faster than "
                   f"{report.cores}")
    chunks = len(report.chunks)
    if report.executor == "local" and chunks < report.workers:
        out.append(f"{chunks} chunk{'s' if chunks > 1 else ''} for {report.workers} workers: "
                   f"{report.workers - chunks} would idle (set sweep.chunk smaller)")
    memory = report.memory_mib
    physical = _physical_mib()
    if memory is not None and physical is not None:
        need = memory[0] + report.workers * memory[1]
        if report.executor == "local" and need > physical:
            out.append(f"estimated memory {need:.0f} MiB exceeds this machine's "
                       f"{physical:.0f} MiB")
    return out


def _physical_mib() -> float | None:
    """The memory a sweep here may have [MiB]: the machine's, or its container's limit if
    lower (``flatcli.machine``, as the spec's limits read it)."""
    try:
        return physical_memory() / MIB
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return None
