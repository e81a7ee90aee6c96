"""Progress of a running sweep: a bar on a terminal, plain periodic lines otherwise; and the
one line that says the simulation kernel is being compiled (``announce_compile``)."""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TextIO

from flatcli.core.loop.metrics import STATUS_NAMES

#: A sweep of more grid cells than this says how its cells' planning goes (``cells``).
CELLS_SHOWN = 50
#: What the first simulation prints when numba's cache holds no compiled kernel yet.
COMPILING = "compiling the simulation kernel (once, ~30 s)"


def kernel_cached() -> bool:
    """Whether the kernels' on-disk cache (``flatcli.core._jit.CACHE_DIRECTORY``) holds a
    readable index of the closed-loop kernel, so a simulation starts without compiling (a
    damaged index is compiled again: ``_jit._RepairingIndexFile``)."""
    from flatcli.core._jit import CACHE_DIRECTORY

    root = CACHE_DIRECTORY
    return root is not None and root.is_dir() and any(
        _readable_index(p) for p in root.glob("**/*kernels.*_batch-*.nbi"))


def _readable_index(path: Path) -> bool:
    """Whether numba can read a cache index: its version, then its pickled entries (as
    ``numba.core.caching.IndexDataCacheFile._load_index`` reads them)."""
    import pickle

    try:
        with path.open("rb") as f:
            pickle.load(f)
            pickle.loads(f.read())
    except Exception:  # damaged: numba's load raises anything pickle can
        return False
    return True


def announce_compile(quiet: bool, stream: TextIO | None = None) -> bool:
    """Print the one-line compile notice when the kernel's cache is cold; whether it was."""
    cold = not kernel_cached()
    if cold and not quiet:
        print(COMPILING, file=stream or sys.stderr, flush=True)
    return cold


class Progress:
    """A progress bar on a terminal, plain periodic lines otherwise, nothing when quiet.

    Trials are counted as chunks finish (``advance``) and, while a local sweep runs, as
    the workers finish them (``live``, a few times a second; ``flatcli.montecarlo.tally``): the
    bar shows whichever count is ahead, with the trials of each status so far.
    """

    def __init__(self, name: str, quiet: bool = False, stream: TextIO | None = None,
                 interval: float = 10.0) -> None:
        self.name = name
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self._bar: Any = None
        self._lock = threading.Lock()
        self._total = 0
        self._resumed = 0
        self._chunked = 0  # trials of this run in finished chunks
        self._chunk_counts: dict[str, int] = {}
        self._live = 0  # trials of this run the workers have finished
        self._live_counts: dict[str, int] = {}
        self._shown = 0
        self._t0 = 0.0
        self._last = 0.0

    def start(self, total: int, done: int, description: str) -> None:
        self._total, self._resumed = total, done
        self._chunked = self._live = self._shown = 0
        self._chunk_counts, self._live_counts = {}, {}
        self._t0 = self._last = time.perf_counter()
        if self.quiet:
            return
        resumed = f", resuming with {done} done" if done else ""
        print(f"sweep {self.name!r}: {total} trials on {description}{resumed}",
              file=self.stream, flush=True)
        if self.stream.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, initial=done, unit="trial", file=self.stream,
                             dynamic_ncols=True, smoothing=0.1)

    def cells(self, done: int, total: int) -> None:
        """``done`` of the sweep's ``total`` grid cells are checked and planned (before the
        first trial: each cell's plan and reference tables are made in this process); shown
        from the first call, every ``interval`` seconds and at the end, for a grid of more
        than ``CELLS_SHOWN`` cells."""
        if self.quiet or total <= CELLS_SHOWN:
            return
        now = time.perf_counter()
        if done == 0:
            self._t0 = self._last = now
            print(f"sweep {self.name!r}: planning {total} grid cells", file=self.stream,
                  flush=True)
            return
        if now - self._last >= self.interval or done == total:
            self._last = now
            rate = done / max(now - self._t0, 1e-9)
            print(f"  {done}/{total} cells planned ({100 * done / total:.0f}%), ETA "
                  f"{(total - done) / rate:.0f} s", file=self.stream, flush=True)

    @property
    def fresh(self) -> int:
        """Trials finished by this run so far."""
        return max(self._chunked, self._live)

    @property
    def counts(self) -> dict[str, int]:
        """Trials of this run so far by status."""
        return dict(self._live_counts if self._live >= self._chunked else self._chunk_counts)

    def advance(self, n: int, counts: Mapping[str, int] | None = None) -> None:
        """A chunk of ``n`` trials finished (with these statuses)."""
        with self._lock:
            self._chunked += n
            for status, k in (counts or {}).items():
                self._chunk_counts[status] = self._chunk_counts.get(status, 0) + k
            self._show(final=self._resumed + self._chunked >= self._total)

    def live(self, n: int, counts: Mapping[str, int]) -> None:
        """The workers have finished ``n`` trials of this run so far (with these statuses)."""
        with self._lock:
            self._live, self._live_counts = n, dict(counts)
            self._show(final=False)

    def _show(self, final: bool) -> None:
        if self.quiet:
            return
        fresh = self.fresh
        done = self._resumed + fresh
        if self._bar is not None:
            self._bar.set_postfix_str(_counts_text(self.counts), refresh=False)
            if fresh > self._shown:
                self._bar.update(fresh - self._shown)  # redraws (at most 10 times a second)
                self._shown = fresh
            return
        now = time.perf_counter()
        if now - self._last >= self.interval or final:
            self._last = now
            rate = fresh / max(now - self._t0, 1e-9)
            eta = (self._total - done) / rate if rate > 0 else math.inf
            counts = self.counts
            tail = f"; {_counts_text(counts)}" if counts else ""
            print(f"  {done}/{self._total} trials ({100 * done / max(self._total, 1):.0f}%)"
                  f", {rate:.0f} trials/s, ETA {eta:.0f} s{tail}", file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def _counts_text(counts: Mapping[str, int]) -> str:
    """'ok 950, singular 40, diverged 8, unresolved 2' (error only when there is one)."""
    names = [n for n in STATUS_NAMES if n != "error" or counts.get(n)]
    return ", ".join(f"{n} {counts.get(n, 0)}" for n in names)
