"""Running (or resuming) a sweep into a directory: chunks to an executor, files as they come.

The directory's lock is held from before its first check to after its last file, so two
runs never write into one directory; everything that can be refused is refused before a
byte is written.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from flatcli.executors import default_workers, make_executor
from flatcli.experiment import plan_warnings
from flatcli.interrupts import check, deferred, interruptible
from flatcli.montecarlo.chunks import ChunkResult, run_chunk
from flatcli.montecarlo.directory import (
    SHOWN,
    TRIALS_DIR,
    TrialsAssembly,
    chunk_provenance,
    clear,
    finish_sweep,
    note,
    plan_directory,
    remove_temporaries,
    verified_chunks,
    write_manifest,
)
from flatcli.montecarlo.layout import Chunk, Layout, grid_label, layout, work_pieces
from flatcli.montecarlo.tally import status_counts, watch
from flatcli.progress import Progress
from flatcli.spec import Spec
from flatcli.spec.limits import check_workers
from flatcli.storage import Syncer, directory_lock, versions, write_table


class FailFastError(RuntimeError):
    """--fail-fast met a failing trial (finished chunks are kept; exit status 1)."""


@dataclass(frozen=True)
class SweepResult:
    """What a finished sweep wrote and measured."""

    directory: Path
    layout: Layout
    simulated: int  # trials simulated by this invocation (the rest were resumed)
    wall_seconds: float
    summary_text: str
    headline: str = ""  # one screen of it (``report.summary.headline``)


def plan_notes(lay: Layout) -> None:
    """One line for each cell whose plan's joints turn faster than ``plan.rate_warning``
    (``experiment.plan_warnings``), at most ``SHOWN`` and then how many more."""
    lines = [f"{warning} (cell {cell.index}: {grid_label(cell.values)})"
             for cell in lay.cells for warning in plan_warnings(cell.spec, cell.scenario.plan)]
    for line in lines[:SHOWN]:
        note(line)
    if len(lines) > SHOWN:
        note(f"warning: {len(lines) - SHOWN} more cells' plans exceed plan.rate_warning")


def run_sweep(
    spec: Spec,
    directory: Path,
    executor_kind: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    fail_fast: bool = False,
    progress: Progress | None = None,
    oversubscribe: bool = False,
    tags: list[str] | None = None,
) -> SweepResult:
    """Run (or resume, or extend) a sweep into ``directory``; write trials, summary and run
    record.

    Everything that can be refused is checked before anything is written: the spec and
    every grid cell, the resources they need, the directory (another run writing there,
    another spec there, files flatcli did not write), the executor. ``tags``: the sweep's
    labels (``--tag``), kept in its manifest and run.json (a resume without tags keeps
    those the directory had).
    """
    started = time.perf_counter()
    if executor_kind == "local" or scheduler == "local":
        check_workers(workers if workers is not None else default_workers(), oversubscribe)
    lay = layout(spec, workers if executor_kind == "local" else None,
                 None if progress is None else progress.cells)
    with directory_lock(directory):
        plan = plan_directory(directory, lay, force)
        executor = make_executor(executor_kind, workers, scheduler)
        trials: TrialsAssembly | None = None
        with deferred():  # Ctrl-C and SIGTERM raised where no lock is held
            try:
                if plan.mode == "restart":
                    clear(directory, plan.previous)
                remove_temporaries(directory)  # of a run killed while it wrote a final table
                if plan.note:
                    note(plan.note)
                if progress is not None and not progress.quiet:  # (-q: none)
                    plan_notes(lay)
                digest = spec.digest()
                keep = plan.previous if plan.mode in ("resume", "extend") else None
                tags = write_manifest(directory, lay, keep, tags)
                done, problems = verified_chunks(directory, lay)
                for line in problems[:SHOWN]:
                    note(f"note: {line}; computing it again")
                if len(problems) > SHOWN:
                    note(f"note: {len(problems) - SHOWN} more chunk files failed their checks; "
                         "computing them again")
                todo = [c for c in lay.chunks() if c.name not in done]
                resumed = lay.total - sum(c.size for c in todo)
                provenance = {"digest": digest, "spec": spec.tree, "versions": versions()}
                if progress is not None:
                    progress.start(lay.total, resumed, executor.description)
                if todo and executor_kind == "local":
                    with interruptible():
                        warm_up(lay)  # load the kernel once here; forked workers inherit it
                setup = time.perf_counter() - started
                tasks = (((c, piece), (lay.cells[c.cell], piece))
                         for c, piece in work_pieces(todo, executor.workers))
                # (start, size, result) of the pieces computed so far of each chunk not yet whole
                parts: dict[str, list[tuple[int, int, ChunkResult]]] = {}
                compute = writing = 0.0
                worker_peak = 0.0  # the largest peak a chunk's process reported [MiB]
                # per-trial counts
                watcher = watch(progress) if executor_kind == "local" else None
                syncer = Syncer()  # chunk files flushed to disk in groups, off this thread
                trials = TrialsAssembly(directory, lay, provenance, done)
                try:
                    for (chunk, piece), part in executor.run(run_chunk, tasks):
                        compute += part.seconds
                        worker_peak = max(worker_peak, part.peak_mib)
                        if progress is not None:
                            progress.advance(piece.size, status_counts(part.table))
                        pieces = parts.setdefault(chunk.name, [])
                        pieces.append((piece.start, piece.size, part))
                        if sum(size for _, size, _ in pieces) < chunk.size:
                            continue  # the chunk's file is written when it is whole
                        began = time.thread_time()  # this thread's processor time
                        result = ChunkResult.joined(
                            [p for _, _, p in sorted(parts.pop(chunk.name), key=lambda x: x[0])])
                        cell = lay.cells[chunk.cell]
                        write_table(directory / TRIALS_DIR / chunk.name, result.table,
                                    chunk_provenance(provenance, cell, chunk, result.table,
                                                     result.checksum), syncer)
                        trials.add(chunk, result.table)  # trials.parquet grows in the grid's order
                        writing += time.thread_time() - began
                        check()  # a Ctrl-C recorded meanwhile: this chunk is written, stop
                        failure = result.first_failure() if fail_fast else None
                        if failure is not None:
                            raise FailFastError(
                                f"--fail-fast: trial {failure[0]} {failure[1]} "
                                f"(finished chunks kept in {directory}/{TRIALS_DIR})")
                finally:
                    if watcher is not None:
                        watcher.stop()
                    if progress is not None:
                        progress.close()
                    # every chunk written is on disk before anything else is written; when the
                    # loop failed, that failure is the one to report
                    with contextlib.suppress(*((OSError,) if sys.exc_info()[0] else ())):
                        syncer.close()
                simulated = lay.total - resumed
                running = time.perf_counter() - started - setup
            except BaseException:
                executor.close(abort=True)
                if trials is not None:
                    trials.abort()
                raise
            try:
                executor.close()
            except BaseException:
                trials.abort()  # the temporary trials.parquet goes with the run
                raise
        summary_text, short = finish_sweep(directory, lay, provenance, started, {
            "setup_seconds": setup,
            "simulate_seconds": running,
            "simulated_trials": simulated,
            "resumed_trials": resumed,
            "compute_seconds": compute,
            "write_cpu_seconds": writing,
            "sync_seconds": syncer.seconds,
            "workers": executor.workers,
            "worker_peak_mib": worker_peak,
            "executor": executor.description,
        }, trials, tags)
    return SweepResult(directory, lay, simulated, time.perf_counter() - started, summary_text,
                       short)


def warm_up(lay: Layout) -> None:
    """Simulate one trial of the first cell, so the compiled kernel is loaded."""
    cell = lay.cells[0]
    run_chunk(cell, Chunk(cell.index, cell.first_trial, cell.first_trial + 1))
