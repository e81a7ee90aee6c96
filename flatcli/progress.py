"""Progress of a running sweep: a bar on a terminal, plain periodic lines otherwise; and the
notice of a kernel numba compiles (``compile_notices``)."""

from __future__ import annotations

import contextlib
import functools
import json
import math
import os
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, TextIO

from flatcli.core.loop.metrics import STATUS_NAMES

#: A sweep of more grid cells than this says how its cells' planning goes (``cells``).
CELLS_SHOWN = 50
#: The first word of a compile notice (tests strip the notices by it).
COMPILING = "compiling"
#: What compiling each group of kernels took on this project's machine (2 cores shared with
#: other work: measured 2026-12-04 at load 7-11, docs/performance.md; ``make bench
#: --sections compiles`` measures them again) [s], by what it is (``kernel_text``,
#: ``planner_text``): the time a notice expects until this machine has compiled it itself
#: (then its own time, ``compile_record``). The N of a chain changes nothing: its kernels
#: take any N.
COMPILE_SECONDS: dict[str, float] = {
    "the simulation kernel of the paper model, kinematic plant": 40.0,
    "the simulation kernel of the paper model, dynamic plant": 90.0,
    "the simulation kernel of the chain model, kinematic plant": 235.0,
    "the simulation kernel of the chain model, dynamic plant": 175.0,
    "the simulation kernel of the as-built model, kinematic plant": 250.0,
    "the simulation kernel of the as-built model, dynamic plant": 580.0,
    # the MPC around each law: 40-60 s each, measured 2026-12-05 at load 3-5 (niced)
    **{f"the simulation kernel of the {model} model, {plant} plant, mpc controller": 60.0
       for model in ("paper", "chain", "as-built") for plant in ("kinematic", "dynamic")},
    "the planner of the paper model": 10.0,
    "the planner of the chain model": 30.0,
    "the planner of the as-built model": 10.0,
}
#: A kernel the table does not know (the longest it lists) [s].
COMPILE_SECONDS_UNKNOWN = max(COMPILE_SECONDS.values())
#: How often a compile's progress line is refreshed: on a terminal, in place; elsewhere (a
#: log), as a new line [s].
COMPILE_TICK_TERMINAL = 1.0
COMPILE_TICK_LOG = 60.0


def kernel_key(scenario: Any) -> str:
    """The compiled closed loop a scenario runs, in words: its model (what its controller
    believes: the paper's closed form, the N-link chain, the as-built robot's exact model)
    and its plant (``core.simulate.kernel_inputs`` picks the kernel by them)."""
    model = "as-built" if scenario.controller == "asbuilt" else scenario.plan.model.kind
    law = getattr(scenario, "sampled", None)  # a sampled controller around the law (the MPC)
    return f"{model} model, {scenario.plant} plant" + (f", {law} controller" if law else "")


def _spec_model(spec: Any) -> str:
    """The model a spec's controller believes, from the spec alone (before planning): the
    paper's closed form for N = 2, the chain beyond (``core.flatmodel.flat_model``), the
    as-built robot's exact model under the as-built controller."""
    if spec.track.controller == "asbuilt":
        return "as-built"
    return "paper" if spec.joints == 2 else "chain"


def kernel_text(scenario: Any) -> str:
    """What a notice calls the closed loop a scenario runs."""
    return f"the simulation kernel of the {kernel_key(scenario)}"


def spec_kernel_text(spec: Any) -> str:
    """``kernel_text`` of the loop a spec runs, from the spec alone."""
    law = ", mpc controller" if spec.track.controller == "mpc" else ""
    return (f"the simulation kernel of the {_spec_model(spec)} model, {spec.plant.model} "
            f"plant{law}")


def planner_text(spec: Any) -> str:
    """What a notice calls the kernels a spec's planning may compile (the chain's maps)."""
    return f"the planner of the {_spec_model(spec)} model"


def compile_record() -> Path:
    """Where this machine's compile times are kept: ``compile-seconds.json`` beside
    flatcli's numba caches (``$XDG_CACHE_HOME/flatcli``, default ``~/.cache/flatcli``)."""
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root) / "flatcli" / "compile-seconds.json"


def recorded_seconds() -> dict[str, float]:
    """This machine's compile times by kernel ({} if none, or not a small JSON object of
    positive numbers: nothing read from disk is trusted)."""
    path = compile_record()
    try:
        if path.is_symlink() or not path.is_file() or path.stat().st_size > 65536:
            return {}
        data = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {str(k): float(v) for k, v in data.items()
            if isinstance(v, int | float) and not isinstance(v, bool)
            and math.isfinite(v) and 0 < v < 1e6}


def expected_seconds(key: str) -> tuple[float, bool]:
    """How long compiling the kernel ``key`` should take here [s], and whether that is this
    machine's own time (else the table's, ``COMPILE_SECONDS``)."""
    mine = recorded_seconds().get(key)
    if mine is not None:
        return mine, True
    return COMPILE_SECONDS.get(key, COMPILE_SECONDS_UNKNOWN), False


def _record(key: str, seconds: float) -> None:
    """Keep ``seconds`` as this machine's compile time of ``key`` (best effort: a cache
    that cannot be written keeps nothing)."""
    with contextlib.suppress(OSError):
        path = compile_record()
        path.parent.mkdir(parents=True, exist_ok=True)
        data = {**recorded_seconds(), key: round(seconds, 1)}
        fd, tmp = tempfile.mkstemp(prefix=".compile-seconds.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "w") as fh:
                json.dump(data, fh, sort_keys=True)
            os.replace(tmp, path)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def duration_text(seconds: float) -> str:
    """'45 s', '4.2 min'."""
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"


class _Notice:
    """numba's compile events (``numba.core.event``) while one kernel is first run: the
    first compile of one of flatcli's functions prints the notice, a thread refreshes its
    progress while any runs, and the block's end says how long they took."""

    def __init__(self, key: str, stream: TextIO, quiet: bool) -> None:
        self.key, self.stream, self.quiet = key, stream, quiet
        self.terminal = stream.isatty()
        self.depth = 0
        self.started: float | None = None
        self.compiling = 0.0  # seconds spent in compiles so far
        self._since = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # numba.core.event.Listener's two methods
    def on_start(self, event: Any) -> None:
        if not _flatcli_function(event):
            return
        self.depth += 1
        if self.depth > 1:
            return
        self._since = time.perf_counter()
        if self.started is None:
            self.started = self._since
            if self.quiet:
                return
            expected, own = expected_seconds(self.key)
            where = "this machine's last time" if own else "on this project's 2 cores"
            print(f"{COMPILING} {self.key} (once, then cached; about "
                  f"{duration_text(expected)}, {where})", file=self.stream, flush=True)
            self._thread = threading.Thread(target=self._tick, args=(expected,), daemon=True)
            self._thread.start()

    def on_end(self, event: Any) -> None:
        if not _flatcli_function(event) or self.depth == 0:
            return
        self.depth -= 1
        if self.depth == 0:
            self.compiling += time.perf_counter() - self._since

    def _tick(self, expected: float) -> None:
        tick = COMPILE_TICK_TERMINAL if self.terminal else COMPILE_TICK_LOG
        while not self._stop.wait(tick):
            assert self.started is not None
            elapsed = time.perf_counter() - self.started
            text = f"  {COMPILING}: {duration_text(elapsed)} of about {duration_text(expected)}"
            if self.terminal:
                print(f"\r{text}\033[K", end="", file=self.stream, flush=True)
            else:
                print(text, file=self.stream, flush=True)

    @property
    def compiled(self) -> bool:
        """Whether numba compiled one of flatcli's functions in the block."""
        return self.started is not None

    def close(self) -> None:
        if self.started is None:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        _record(self.key, self.compiling)
        if self.quiet:
            return
        text = f"  compiled in {duration_text(self.compiling)}"
        print(f"\r{text}\033[K" if self.terminal else text, file=self.stream, flush=True)


@functools.cache
def _listener_class() -> type:
    """A ``numba.core.event.Listener`` that hands numba's compile events to a ``_Notice``
    (made once: numba is loaded by then)."""
    from numba.core import event

    class Listener(event.Listener):
        def __init__(self, notice: _Notice) -> None:
            self.notice = notice

        def on_start(self, ev: Any) -> None:
            self.notice.on_start(ev)

        def on_end(self, ev: Any) -> None:
            self.notice.on_end(ev)

    return Listener


def _flatcli_function(event: Any) -> bool:
    dispatcher = (event.data or {}).get("dispatcher")
    module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
    return module.startswith("flatcli.")


@contextlib.contextmanager
def compile_notices(key: str, quiet: bool, stream: TextIO | None = None) -> Iterator[_Notice]:
    """Within: if numba compiles one of flatcli's functions (its cache holds no machine
    code for it), one line says so, naming what compiles (``key``: ``kernel_text``,
    ``planner_text``) and how long it should take (``expected_seconds``); a progress line
    follows while it compiles (in place on a terminal, every minute in a log), and one with
    its time, which is kept for the next notice. Nothing printed when ``quiet``. Accurate
    for every kernel, plant, controller and N: it answers numba's own compile events, not a
    guess from the cache's files. Yields what tells whether a compile happened
    (``.compiled``)."""
    from numba.core import event

    notice = _Notice(key, stream or sys.stderr, quiet)
    listener = _listener_class()(notice)
    event.register("numba:compile", listener)  # type: ignore[no-untyped-call]
    try:
        yield notice
    finally:
        event.unregister("numba:compile", listener)  # type: ignore[no-untyped-call]
        notice.close()


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
