"""Running (or resuming) a sweep into a directory: chunks to an executor, files as they come."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from flatcli.executors import make_executor
from flatcli.report import Progress
from flatcli.spec import Spec
from flatcli.storage import versions, write_table
from flatcli.sweep.chunks import run_chunk
from flatcli.sweep.directory import (
    TRIALS_DIR,
    check_directory,
    clear,
    finish_sweep,
    finished_chunks,
    write_manifest,
)
from flatcli.sweep.layout import Chunk, Layout, layout
from flatcli.sweep.tally import status_counts, watch


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


def run_sweep(
    spec: Spec,
    directory: Path,
    executor_kind: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    fail_fast: bool = False,
    progress: Progress | None = None,
) -> SweepResult:
    """Run (or resume) a sweep into ``directory``; write trials, summary and run record.

    Everything that can be refused is checked before anything is written: the spec and
    every grid cell, the directory (a different spec there is refused), the executor.
    """
    started = time.perf_counter()
    lay = layout(spec)
    check_directory(directory, spec, force)
    executor = make_executor(executor_kind, workers, scheduler)
    try:
        if force:
            clear(directory)
        digest = spec.digest()
        write_manifest(directory, lay)
        done = finished_chunks(directory, digest)
        todo = [c for c in lay.chunks() if c.name not in done]
        resumed = lay.total - sum(c.size for c in todo)
        provenance = {"digest": digest, "spec": spec.tree, "versions": versions()}
        if progress is not None:
            progress.start(lay.total, resumed, executor.description)
        if todo and executor_kind == "local":
            warm_up(lay)  # load the kernel once here; forked workers inherit it
        setup = time.perf_counter() - started
        tasks = ((c, (lay.cells[c.cell], c)) for c in todo)
        compute = 0.0
        watcher = watch(progress) if executor_kind == "local" else None  # per-trial counts
        try:
            for chunk, result in executor.run(run_chunk, tasks):
                compute += result.seconds
                write_table(directory / TRIALS_DIR / chunk.name, result.table,
                            {**provenance, "chunk": [chunk.start, chunk.stop]})
                if progress is not None:
                    progress.advance(chunk.size, status_counts(result.table))
                failure = result.first_failure() if fail_fast else None
                if failure is not None:
                    raise FailFastError(f"--fail-fast: trial {failure[0]} {failure[1]} "
                                        f"(finished chunks kept in {directory}/{TRIALS_DIR})")
        finally:
            if watcher is not None:
                watcher.stop()
            if progress is not None:
                progress.close()
        simulated = lay.total - resumed
        running = time.perf_counter() - started - setup
    finally:
        executor.close()
    summary_text = finish_sweep(directory, lay, provenance, started, {
        "setup_seconds": setup,
        "simulate_seconds": running,
        "simulated_trials": simulated,
        "resumed_trials": resumed,
        "compute_seconds": compute,
        "workers": executor.workers,
        "executor": executor.description,
    })
    return SweepResult(directory, lay, simulated, time.perf_counter() - started, summary_text)


def warm_up(lay: Layout) -> None:
    """Simulate one trial of the first cell, so the compiled kernel is loaded."""
    cell = lay.cells[0]
    run_chunk(cell, Chunk(cell.index, 0, 1))
