"""``flatcli check SPEC`` and ``flatcli sweep SPEC --dry-run``: what a sweep would do.

The resolved spec, the cells with their grid values, the trials and chunks, an estimate of
the wall time and peak memory from a short calibration, and warnings about a study that
would waste its time. Nothing is written (numba's own cache aside: a cold kernel compiles).

After one warm-up trial here (which loads the kernel), the calibration runs in one worker
process forked from this one, as a sweep's are: the first ``k`` trials of every cell (the
same trial ids, so the same random draws; ``k`` about ``CALIBRATION_TRIALS`` / cells), and
the first trial of every cell alone. Their CPU times give the cost of a trial (the
difference: trials 1..k-1) and a chunk's own cost (draws, rows, table); the sweep's chunks
cost that much each, spread over the workers on idle cores (a busy machine is warned of),
and the worker's peak memory is measured.

Running the same draws in every cell also tells which grid keys change nothing: if every
pair of cells that differ only in one key's value gives identical results, that key does
not reach the simulation (e.g. ``track.seed``, which a sweep replaces with ``sweep.seed``),
or not on these trials.
"""

from __future__ import annotations

import io
import itertools
import json
import math
import multiprocessing
import os
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from flatcli.core.loop.metrics import STATUS_NAMES
from flatcli.executors import default_workers
from flatcli.machine import physical_memory
from flatcli.montecarlo import Chunk, Layout, grid_cell_text, grid_label, layout, run_chunk
from flatcli.montecarlo.directory import summary_cells
from flatcli.report import fmt, short_key, table
from flatcli.report.summary import SUMMARY_INPUTS, ColumnsOf, summary_rows
from flatcli.spec import Spec, spec_toml
from flatcli.storage import parquet_options, peak_memory_mib

#: Trials the calibration runs in all (at least one per cell).
CALIBRATION_TRIALS = 128
#: Rows of the synthetic trials table whose summary is timed to estimate the final tables.
FINISH_SAMPLE_ROWS = 20_000
#: Cells listed in the text (the DataFrame ``CheckReport.cells`` has them all).
SHOWN_CELLS = 40
MIB = 1024 * 1024


@dataclass(frozen=True)
class Calibration:
    """The calibration trials: how many, how long, how they ended, how large their rows."""

    per_cell: int
    trials: int
    per_trial: float  # simulating one trial (warm), CPU time [s]
    per_chunk: float  # a chunk's own cost beside its trials (draws, rows, table), CPU [s]
    warm_up_seconds: float  # the first trial: loads (or compiles) the kernel
    compiled: bool  # the kernel was compiled by this check (numba's cache was cold)
    statuses: dict[str, int]
    row_bytes: float  # of a trials.parquet row in memory (Arrow)
    finish_seconds_per_trial: float  # final tables, per trial
    finish_bytes_per_trial: float  # the main process's tables at the end, per trial
    finish_rows: int  # rows of the final tables this check built to time them
    worker_mib: float | None  # peak resident memory of the worker that ran the calibration
    unchanged_keys: tuple[str, ...]  # grid keys whose values gave identical results


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
        """Estimated wall time of the sweep [s]: planning, loading the kernel, the trials
        spread over the workers chunk by chunk, and the final tables."""
        cal = self.calibration
        if cal is None:
            return None
        return self.planning_seconds + self._load_seconds + self._trial_seconds + \
            cal.finish_seconds_per_trial * self.layout.total

    @property
    def _load_seconds(self) -> float:
        cal = self.calibration
        return 0.0 if cal is None or cal.compiled else cal.warm_up_seconds

    @property
    def cpu_seconds(self) -> float | None:
        """Estimated CPU time of the sweep's trials, all workers together [s]."""
        cal = self.calibration
        if cal is None:
            return None
        return sum(cal.per_chunk + c.size * cal.per_trial for c in self.chunks)

    @property
    def _trial_seconds(self) -> float:
        cal = self.calibration
        assert cal is not None
        chunks = self.chunks
        busy = min(self.workers, len(chunks), self.cores if self.executor == "local"
                   else self.workers)
        work = sum(cal.per_chunk + c.size * cal.per_trial for c in chunks)
        largest = max(cal.per_chunk + c.size * cal.per_trial for c in chunks)
        return max(work / busy, largest)

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
            compiled = (f"; the kernel was compiled first ({cal.warm_up_seconds:.0f} s, now "
                        "cached)" if cal.compiled else "")
            lines.append(f"calibration: {cal.trials} trials ({cal.per_cell} per cell, one "
                         f"worker process): {1e3 * cal.per_trial:.3g} ms per trial and "
                         f"{1e3 * cal.per_chunk:.3g} ms per chunk; {counts}{compiled}")
            total = self.estimate_seconds
            assert total is not None
            where = f"{self.workers} {self.executor} worker{'s' if self.workers > 1 else ''}"
            if self.executor == "local":
                where += f", {min(self.workers, self.cores)} idle core" + (
                    "s" if min(self.workers, self.cores) > 1 else "")
            lines.append(
                f"estimate on {where}: {_duration(total)} (planning "
                f"{self.planning_seconds:.1f} s, loading the kernel {self._load_seconds:.1f} s, "
                f"trials {self._trial_seconds:.1f} s, final tables "
                f"{cal.finish_seconds_per_trial * lay.total:.1f} s); the trials take "
                f"{_duration(self.cpu_seconds or 0.0)} of CPU")
            memory = self.memory_mib
            assert memory is not None
            main, worker = memory
            lines.append(f"peak memory: ~{main:.0f} MiB main process, ~{worker:.0f} MiB per "
                         f"worker process (resident, shared pages counted in each)")
        if self.warnings:
            lines += ["", "warnings:", *(f"- {w}" for w in self.warnings)]
        else:
            lines += ["", "no warnings"]
        lines += ["", "nothing written"]
        return "\n".join(lines)


def _duration(seconds: float) -> str:
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
               calibrate: bool = True, quiet: bool = False) -> CheckReport:
    """Lay the sweep out, calibrate, estimate and warn (see the module docstring)."""
    from flatcli.progress import announce_compile

    if workers is not None and workers < 1:
        from flatcli.core.errors import FlatcliError

        raise FlatcliError(f"--workers: must be >= 1, got {workers}")
    started = time.perf_counter()
    lay = layout(spec)
    planning = time.perf_counter() - started
    n_workers = workers if workers is not None else default_workers()
    calibration = None
    if calibrate:
        compiled = announce_compile(quiet)
        calibration = _calibrate(lay, compiled)
    report = CheckReport(spec, lay, n_workers, executor, planning, calibration, _rss_mib(), (),
                         default_workers(), os.getloadavg()[0])
    return replace(report, warnings=tuple(_warnings(report)))


def _rss_mib() -> float:
    """Peak resident memory of this process so far, its own (``storage.peak_memory_mib``:
    not that of the process that started it) [MiB]."""
    return peak_memory_mib()


def _calibration_runs(lay: Layout, k: int) -> tuple[list[pa.Table], float, float]:
    """The calibration chunks (a worker's job): per cell its first trial alone, then its
    first k trials; the tables of the latter, and the two total CPU times [s] (what the
    trials cost on a core of their own, however busy the machine is now)."""
    tables: list[pa.Table] = []
    first_seconds = all_seconds = 0.0
    for cell in lay.cells:
        if k > 1:  # its first trial alone: the chunk's own cost, and that trial's
            began = time.process_time()
            run_chunk(cell, Chunk(cell.index, 0, 1))
            first_seconds += time.process_time() - began
        began = time.process_time()
        result = run_chunk(cell, Chunk(cell.index, 0, k))  # the same draws in every cell
        all_seconds += time.process_time() - began
        tables.append(result.table)
    return tables, first_seconds, all_seconds


def _in_a_worker(lay: Layout, k: int) -> tuple[list[pa.Table], float, float, float | None]:
    """The calibration runs in one worker process forked from this one, as a sweep's
    workers are (they inherit the loaded kernel), and that process's peak resident memory
    [MiB]; in this process (and no peak) where there is no fork."""
    try:
        context = multiprocessing.get_context("fork")
    except ValueError:  # pragma: no cover - not POSIX
        return (*_calibration_runs(lay, k), None)
    with ProcessPoolExecutor(1, mp_context=context) as pool:
        tables, first_seconds, all_seconds, peak = pool.submit(_measured_runs, lay, k).result()
    return tables, first_seconds, all_seconds, peak


def _measured_runs(lay: Layout, k: int) -> tuple[list[pa.Table], float, float, float]:
    """``_calibration_runs`` in a worker, and the worker's own peak memory [MiB]."""
    return (*_calibration_runs(lay, k), peak_memory_mib())


def _calibrate(lay: Layout, compiled: bool) -> Calibration:
    first = lay.cells[0]
    began = time.perf_counter()
    run_chunk(first, Chunk(first.index, 0, 1))  # loads (or compiles) the kernel
    warm_up = time.perf_counter() - began
    n = len(lay.cells)
    k = min(lay.trials_per_cell, 1 + math.ceil(CALIBRATION_TRIALS / n))
    tables, first_seconds, all_seconds, worker_mib = _in_a_worker(lay, k)
    if k > 1:  # trials 1..k-1 cost the difference; the rest is the chunk's own
        per_trial = max(all_seconds - first_seconds, 0.0) / (n * (k - 1))
        per_chunk = max(first_seconds / n - per_trial, 0.0)
    else:
        per_trial, per_chunk = all_seconds / n, 0.0
    statuses: dict[str, int] = {}
    for t in tables:
        for s in t.column("status").to_pylist():
            statuses[s] = statuses.get(s, 0) + 1
    rows = sum(t.num_rows for t in tables)
    row_bytes = sum(t.nbytes for t in tables) / rows
    finish_seconds, finish_bytes, finish_rows = _finish_cost(lay, tables)
    return Calibration(k, rows, per_trial, per_chunk, warm_up, compiled, statuses, row_bytes,
                       finish_seconds, finish_bytes, finish_rows, worker_mib,
                       tuple(_unchanged_keys(lay, tables)))


def _finish_cost(lay: Layout, tables: Sequence[pa.Table]) -> tuple[float, float, int]:
    """Time and memory per trial of the sweep's work in the main process beyond the chunk
    files, measured on the calibration rows repeated to a trials table of up to
    FINISH_SAMPLE_ROWS rows, along the sweep's own path: appended to trials.parquet (here in
    memory) in chunk-sized tables as they come in, the summary's columns taken as they pass
    (``ColumnsOf``), and summarised per cell (``summary_rows``). The appends happen while
    the workers run and the summary after them; both are counted, as if after them."""
    combined = pa.concat_tables([t.cast(tables[0].schema) for t in tables])
    n = min(lay.total, FINISH_SAMPLE_ROWS)
    repeats = math.ceil(n / combined.num_rows)
    big = pa.concat_tables([combined] * repeats).slice(0, n).combine_chunks()
    cells = summary_cells(lay)
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
    """Grid keys whose values never changed a calibration trial's results."""
    keys = lay.grid_keys
    if not keys or not any(s != "error" for t in tables for s in t.column("status").to_pylist()):
        return []
    drop = ["cell", *keys]
    results = [t.drop_columns([c for c in drop if c in t.column_names]).to_pandas()
               for t in tables]
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
    out: list[str] = []
    noiseless = all(c.spec.track.sensor_noise == 0 for c in lay.cells)
    if not spec.sweep.perturb and noiseless and lay.trials_per_cell > 1:
        where = "the" if not lay.grid_keys else "each cell's"
        out.append(f"no [sweep.perturb] and no track.sensor_noise: {where} "
                   f"{lay.trials_per_cell} trials are identical (sweep.trials = 1 would do)")
    cal = report.calibration
    if cal is not None:
        for key in cal.unchanged_keys:
            out.append(f"grid key {key!r} changes nothing: its values gave identical results "
                       f"on all {cal.trials} calibration trials (same draws in every cell); "
                       "it does not reach the simulation (or not on these trials)")
    if report.executor == "local" and report.load >= report.cores:
        out.append(f"this machine is busy (load average {report.load:.1f} on {report.cores} "
                   f"core{'s' if report.cores > 1 else ''}): the sweep will take longer than "
                   "the estimate, which assumes idle cores")
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
