"""Progress of a running sweep: a bar on a terminal, plain periodic lines otherwise."""

from __future__ import annotations

import math
import sys
import time
from typing import Any, TextIO


class Progress:
    """A progress bar on a terminal, plain periodic lines otherwise, nothing when quiet."""

    def __init__(self, name: str, quiet: bool = False, stream: TextIO | None = None,
                 interval: float = 10.0) -> None:
        self.name = name
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self._bar: Any = None
        self._total = 0
        self._done = 0
        self._fresh = 0
        self._t0 = 0.0
        self._last = 0.0

    def start(self, total: int, done: int, description: str) -> None:
        self._total, self._done, self._fresh = total, done, 0
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

    def advance(self, n: int) -> None:
        self._done += n
        self._fresh += n
        if self.quiet:
            return
        if self._bar is not None:
            self._bar.update(n)
            return
        now = time.perf_counter()
        if now - self._last >= self.interval or self._done >= self._total:
            self._last = now
            rate = self._fresh / max(now - self._t0, 1e-9)
            eta = (self._total - self._done) / rate if rate > 0 else math.inf
            print(f"  {self._done}/{self._total} trials ({100 * self._done / self._total:.0f}%)"
                  f", {rate:.0f} trials/s, ETA {eta:.0f} s", file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
