"""Running (or resuming) a sweep into a directory: chunks to an executor, files as they come.

The directory's lock is held from before its first check to after its last file, so two
runs never write into one directory; everything that can be refused is refused before a
byte is written.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from flatcli.executors import Executor, default_workers, make_executor
from flatcli.experiment import plan_warnings
from flatcli.interrupts import check, deferred, interruptible
from flatcli.montecarlo.chunks import ChunkResult, run_chunk
from flatcli.montecarlo.directory import (
    SHOWN,
    TRIALS_DIR,
    StoredChunks,
    TrialsAssembly,
    chunk_provenance,
    clear,
    finish_sweep,
    note,
    plan_directory,
    remove_temporaries,
    reusable_chunks,
    write_manifest,
)
from flatcli.montecarlo.layout import (
    Cell,
    Chunk,
    Layout,
    Shard,
    family,
    grid_label,
    layout,
    work_pieces,
)
from flatcli.montecarlo.tally import status_counts, watch
from flatcli.progress import Progress, compile_notices, kernel_text, planner_text
from flatcli.spec import Spec, SpecError
from flatcli.spec.limits import check_workers
from flatcli.spec.unread import unread_keys, unseen_draws
from flatcli.storage import (
    DirectoryBusyError,
    ShardLocks,
    Syncer,
    directory_lock,
    shard_locks,
    versions,
    write_table,
)


class FailFastError(RuntimeError):
    """--fail-fast met a failing trial (finished chunks are kept; exit status 1)."""


@dataclass(frozen=True)
class SweepResult:
    """What a sweep wrote and measured. ``complete``: the final tables are written (a shard
    whose study is not finished yet wrote its chunks only: ``missing`` trials of the study
    are still to be computed, by shards ``running`` or to be run again)."""

    directory: Path
    layout: Layout
    simulated: int  # trials simulated by this invocation (the rest were resumed)
    wall_seconds: float
    summary_text: str
    complete: bool = True
    missing: int = 0
    running: bool = False  # (a shard) other shards were still running when it finished
    headline: str = ""  # one screen of it (``report.summary.headline``)


def plan_notes(lay: Layout) -> None:
    """One line for each controller setting no cell reads (``spec.unread.unread_keys``) and
    each draw a controller does not see (``unseen_draws``), then
    one for each cell whose plan's joints turn faster than ``plan.rate_warning``
    (``experiment.plan_warnings``), at most ``SHOWN`` and then how many more."""
    for line in unread_keys(lay.spec) + unseen_draws(lay.spec):
        note(line)
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
    shard: Shard | None = None,
) -> SweepResult:
    """Run (or resume, or extend) a sweep into ``directory``; write trials, summary and run
    record.

    Everything that can be refused is checked before anything is written: the spec and
    every grid cell, the resources they need, the directory (another run writing there,
    another spec there, files flatcli did not write), the executor. ``tags``: the sweep's
    labels (``--tag``), kept in its manifest and run.json (a resume without tags keeps
    those the directory had).

    ``shard``: compute only that shard's chunks (``layout.Shard``), beside the other shards
    of the study, which may run at the same time on other machines sharing the directory:
    they hold its lock together (``storage.shard_locks``), agree on one spec (a shard of
    another spec is refused), and write chunk files only. The shard that finishes last (the
    one that can then take the directory's lock alone) writes the final tables, as a resume
    would, if every chunk is there; else it says what is missing (the same command resumes a
    shard; the sweep without --shard finishes the study).
    """
    started = time.perf_counter()
    if executor_kind == "local" or scheduler == "local":
        check_workers(workers if workers is not None else default_workers(), oversubscribe)
    quiet = progress is None or progress.quiet
    with compile_notices(planner_text(spec), quiet):  # (the chain's maps)
        lay = layout(spec, workers if executor_kind == "local" else None,
                     None if progress is None else progress.cells)
    run = _Run(spec, lay, directory, executor_kind, workers, scheduler, fail_fast, progress,
               tags, started)
    if shard is None:
        with directory_lock(directory):
            return run.sweep(force)
    if force:
        raise SpecError("--force: not with --shard (shards share a study: start over without "
                        "--shard, or use another --out)")
    with shard_locks(directory, shard.index, shard.count) as locks:
        part = run.sweep(False, shard, locks)
    try:
        with directory_lock(directory):  # only the last shard running can take it
            return run.finish(part)
    except DirectoryBusyError:
        return replace(part, running=True)


class _Run:
    """One invocation of ``run_sweep``: what it was asked, and its two steps."""

    def __init__(self, spec: Spec, lay: Layout, directory: Path, executor_kind: str,
                 workers: int | None, scheduler: str | None, fail_fast: bool,
                 progress: Progress | None, tags: list[str] | None, started: float) -> None:
        self.spec, self.lay, self.directory = spec, lay, directory
        self.executor_kind, self.workers, self.scheduler = executor_kind, workers, scheduler
        self.fail_fast, self.progress, self.tags, self.started = (fail_fast, progress, tags,
                                                                  started)

    def sweep(self, force: bool, shard: Shard | None = None,
              locks: ShardLocks | None = None) -> SweepResult:
        """Compute the chunks not yet done (of ``shard`` only, if given, holding its
        ``locks``), then (without a shard) write the final tables."""
        directory, lay, spec = self.directory, self.lay, self.spec
        started = self.started
        guard = locks.setup if locks is not None else contextlib.nullcontext
        with guard():
            plan = plan_directory(directory, lay, force)  # refused before anything is written
        executor = make_executor(self.executor_kind, self.workers, self.scheduler,
                                 self._say)
        try:
            with guard():
                if locks is not None:  # again: another shard may have written meanwhile
                    plan = plan_directory(directory, lay, force)
                if plan.mode == "restart":
                    clear(directory, plan.previous)
                if shard is None:  # (a shard: another shard may be writing final tables)
                    remove_temporaries(directory)  # of a run killed while writing a table
                if plan.note:
                    note(plan.note)
                if self.progress is not None and not self.progress.quiet:  # (-q: none)
                    plan_notes(lay)
                keep = plan.previous if plan.mode in ("resume", "extend") else None
                self.tags = write_manifest(directory, lay, keep, self.tags)
                stored = StoredChunks.of(directory)
                # (a shard leaves stray temporary chunk files: another shard may be writing)
                done, problems = reusable_chunks(directory, lay, stored,
                                                 remove_strays=shard is None)
        except BaseException:
            executor.close(abort=True)
            raise
        if locks is not None:
            locks.running()
        for line in problems[:SHOWN]:
            note(f"note: {line}; computing it again")
        if len(problems) > SHOWN:
            note(f"note: {len(problems) - SHOWN} more chunk files failed their checks; "
                 "computing them again")
        mine = list(lay.chunks()) if shard is None else shard.chunks(lay)
        todo = [c for c in mine if c.name not in done]
        resumed = sum(c.size for c in mine) - sum(c.size for c in todo)
        provenance = {"digest": spec.digest(), "spec": spec.tree, "versions": versions()}
        progress = self.progress
        trials: TrialsAssembly | None = None
        with deferred():  # Ctrl-C and SIGTERM raised where no lock is held
            try:
                cells = executor.share(lay.cells) if todo else []
                if todo:  # every kernel the chunks run, here and on every worker (before
                    # the progress bar: a compile's notice has the terminal's line)
                    self._load_kernels(todo, executor, cells)
                if progress is not None:
                    where = executor.description + (
                        f"; shard {shard} of the study's {lay.total} trials" if shard else "")
                    progress.start(sum(c.size for c in mine), resumed, where)
                setup_seconds = time.perf_counter() - started
                tasks = (((c, piece), (cells[c.cell], piece))
                         for c, piece in work_pieces(todo, executor.workers))
                # (start, size, result) of the pieces computed so far of each chunk not yet whole
                parts: dict[str, list[tuple[int, int, ChunkResult]]] = {}
                compute = writing = 0.0
                worker_peak = 0.0  # the largest peak a chunk's process reported [MiB]
                # per-trial counts
                watcher = watch(progress) if self.executor_kind == "local" else None
                syncer = Syncer()  # chunk files flushed to disk in groups, off this thread
                if shard is None:
                    trials = TrialsAssembly(directory, lay, provenance, done, stored)
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
                        if trials is not None:  # trials.parquet grows in the grid's order
                            trials.add(chunk, result.table, result.checksum)
                        writing += time.thread_time() - began
                        check()  # a Ctrl-C recorded meanwhile: this chunk is written, stop
                        failure = result.first_failure() if self.fail_fast else None
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
                simulated = sum(c.size for c in todo)
                running = time.perf_counter() - started - setup_seconds
            except BaseException:
                executor.close(abort=True)
                if trials is not None:
                    trials.abort()
                raise
            try:
                executor.close()
            except BaseException:
                if trials is not None:
                    trials.abort()  # the temporary trials.parquet goes with the run
                raise
        self.timing = {
            "setup_seconds": setup_seconds,
            "simulate_seconds": running,
            "simulated_trials": simulated,
            "resumed_trials": lay.total - simulated,
            "compute_seconds": compute,
            "write_cpu_seconds": writing,
            "sync_seconds": syncer.seconds,
            "workers": executor.workers,
            "worker_peak_mib": worker_peak,
            "executor": executor.description,
        }
        if trials is None:  # a shard: its chunks are written, the study may not be whole
            return SweepResult(directory, lay, simulated, time.perf_counter() - started, "",
                               complete=False)
        summary_text, short = finish_sweep(directory, lay, provenance, started, self.timing,
                                           trials, self.tags)
        return SweepResult(directory, lay, simulated, time.perf_counter() - started,
                           summary_text, headline=short)

    def _load_kernels(self, todo: list[Chunk], executor: Executor, shared: list[Any]) -> None:
        """Run one trial of a cell of each kernel family ``todo`` needs (``family``) here,
        announcing a kernel numba compiles (``progress.compile_notices``), then make the
        workers ready as this process is (``Executor.warm``: forked workers inherit it, Dask
        workers run that trial too). A kernel first met in a worker would compile there, in
        every worker at once, unannounced."""
        quiet = self.progress is None or self.progress.quiet
        first: dict[str, Cell] = {}
        for chunk in todo:
            cell = self.lay.cells[chunk.cell]
            first.setdefault(family(cell), cell)
        for cell in first.values():
            one = Chunk(cell.index, cell.first_trial, cell.first_trial + 1)
            with compile_notices(kernel_text(cell.scenario), quiet), interruptible():
                run_chunk(cell, one)
            executor.warm(run_chunk, (shared[cell.index], one))

    def _say(self, text: str) -> None:
        """A line on stderr, unless quiet (no progress, or a quiet one)."""
        if self.progress is not None and not self.progress.quiet:
            note(text)

    def finish(self, part: SweepResult) -> SweepResult:
        """The last shard running, holding the directory alone: the final tables, as a
        resume would write them, if every chunk of the study is done; else ``part`` with
        what is missing."""
        directory, lay, spec = self.directory, self.lay, self.spec
        plan = plan_directory(directory, lay, False)  # (refuses a spec changed meanwhile)
        remove_temporaries(directory)
        stored = StoredChunks.of(directory)
        done, problems = reusable_chunks(directory, lay, stored)
        for line in problems[:SHOWN]:
            note(f"note: {line}; the shard that computed it must run again")
        missing = sum(c.size for c in lay.chunks() if c.name not in done)
        if missing:
            return replace(part, missing=missing)
        provenance = {"digest": spec.digest(), "spec": spec.tree, "versions": versions()}
        tags = self.tags or list(plan.previous.tags)
        trials = TrialsAssembly(directory, lay, provenance, done, stored)
        with deferred():
            summary_text, short = finish_sweep(directory, lay, provenance, self.started,
                                               self.timing, trials, tags)
        return replace(part, summary_text=summary_text, headline=short, complete=True,
                       wall_seconds=time.perf_counter() - self.started)
