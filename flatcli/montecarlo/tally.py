"""Live trial counts of a running sweep, by status, for the progress bar.

A chunk is a sweep's unit of work and of resume (up to 1,000 trials, seconds of work); a
progress bar that moved only when a chunk ends would sit still for seconds. So while a
local sweep runs, ``run_chunk`` simulates a chunk in small batches and adds each batch's
statuses to counters in shared memory, which the forked worker processes inherit; a thread
of the parent reads them a few times a second into the bar (``watch``).

Batches change nothing but the timing: every trial is integrated alone, whatever else is in
its batch (``flatcli.core.loop.simulate``). Where the counters do not reach (a Dask worker, a
spawned process) nothing is counted, and the bar moves as chunks finish.
"""

from __future__ import annotations

import multiprocessing
import threading
import time
from typing import Any

import numpy as np
import pyarrow as pa

from flatcli.core.loop.metrics import STATUS_NAMES, Status
from flatcli.core.loop.outcome import MotionClearance
from flatcli.core.loop.simulate import Outcome, Scenario, Trials, simulate
from flatcli.core.names import Integrator
from flatcli.interrupts import critical

#: How often the parent reads the counters into the progress bar [s].
POLL_SECONDS = 0.2
#: Batch sizes: the first batch, the largest, and the time a batch should take [s].
FIRST_BATCH = 4
MAX_BATCH = 512
BATCH_SECONDS = 0.2

_counts: Any = None  # a multiprocessing.Array, one slot per Status, while a sweep is watched


def status_counts(table: pa.Table) -> dict[str, int]:
    """Trials per status in a chunk's table (counted in Python: pyarrow.compute would cost
    a sweep's start-up more than counting a chunk's few hundred words)."""
    counts: dict[str, int] = {}
    for status in table.column("status").to_pylist():
        counts[str(status)] = counts.get(str(status), 0) + 1
    return counts


def counting() -> bool:
    """Whether a running sweep is watching the counters (in this process or its parent)."""
    return _counts is not None


def add(status: np.ndarray) -> None:
    """Add a batch's ``Status`` codes to the counters (nothing if none are watched)."""
    counts = _counts
    if counts is None or len(status) == 0:
        return
    tally = np.bincount(np.asarray(status, dtype=np.int64), minlength=len(STATUS_NAMES))
    with critical(), counts.get_lock():  # no Ctrl-C inside the lock (flatcli.interrupts)
        for i, n in enumerate(tally.tolist()):
            counts[i] += n


def simulate_counted(scenario: Scenario, trials: Trials, integrator: Integrator,
                     obstacles: Any = None) -> Outcome:
    """``simulate`` (with the clearance from ``obstacles``, if any) in batches whose statuses
    are counted as they finish (one call when nothing watches); the outcome is the same
    either way."""
    if not counting():
        return simulate(scenario, trials, integrator, obstacles=obstacles)
    parts: list[Outcome] = []
    start, size = 0, FIRST_BATCH
    while start < trials.count:
        stop = min(start + size, trials.count)
        began = time.perf_counter()
        part = simulate(scenario, trials.subset(slice(start, stop)), integrator,
                        obstacles=obstacles)
        add(part.status)
        parts.append(part)
        took = time.perf_counter() - began
        if took < BATCH_SECONDS / 2:
            size = min(2 * size, MAX_BATCH)
        elif took > 2 * BATCH_SECONDS and size > 1:
            size //= 2
        start = stop
    return Outcome(
        np.concatenate([p.metrics for p in parts]),
        np.concatenate([p.status for p in parts]),
        np.concatenate([p.event for p in parts]),
        np.concatenate([p.event_time for p in parts]),
        None,
        integrator=integrator,
        estimated=parts[0].estimated if parts else False,
        accuracy=parts[0].accuracy if parts else float("inf"),
        final=np.concatenate([p.final for p in parts if p.final is not None]) if parts
        else None,
        clearance=MotionClearance.concatenate([p.clearance for p in parts
                                               if p.clearance is not None])
        if parts and parts[0].clearance is not None else None,
        extra=np.concatenate([p.extra for p in parts if p.extra is not None])
        if parts and parts[0].extra is not None else None,
        extra_columns=parts[0].extra_columns if parts else (),
        extra_counts=parts[0].extra_counts if parts else (),
    )


class Watcher:
    """Reads the counters into a progress bar until stopped."""

    def __init__(self, progress: Any) -> None:
        self.progress = progress
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="flatcli-progress", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        counts = _counts
        if counts is None:
            return
        with counts.get_lock():
            values = list(counts)
        named = {Status(i).name.lower(): int(n) for i, n in enumerate(values)}
        self.progress.live(sum(named.values()), named)

    def _run(self) -> None:
        while not self._stop.wait(POLL_SECONDS):
            self._read()

    def stop(self) -> None:
        """Stop reading (after a last read) and stop counting."""
        global _counts
        self._stop.set()
        self._thread.join()
        self._read()
        _counts = None


def watch(progress: Any) -> Watcher | None:
    """Start counting trials (in this process and in workers forked from now on) and
    reading the counts into ``progress``; None if there is no bar to move."""
    global _counts
    if progress is None or getattr(progress, "quiet", True):
        return None
    _counts = multiprocessing.Array("q", len(STATUS_NAMES))
    return Watcher(progress)
