"""Ctrl-C and SIGTERM that stop a run cleanly, never in the middle of a lock.

Python runs a signal's handler in the main thread between two bytecodes, wherever that
thread is. A handler that raises (``KeyboardInterrupt``) can land inside a ``with lock:``
block in a way that leaves the lock held (CPython issue 74174, formerly bpo-29988); the
thread that needs the lock next then waits forever. A sweep's main thread takes such locks
all the time: its own file flusher's (``flatcli.storage.Syncer``), the process pool's, the
live counters' (``flatcli.montecarlo.tally``). One SIGTERM in about 50, sent to a loaded machine,
left ``flatcli sweep`` hung for good.

So while a sweep runs (``deferred``), a signal is only recorded. It becomes a
``KeyboardInterrupt`` where no lock is held: when the main thread next calls ``check``
(between chunks, and at least every ``flatcli.executors.POLL_SECONDS`` while it waits for
workers), or at once inside ``interruptible`` (a chunk simulated in this process), except in
a ``critical`` block there. Outside ``deferred`` (every other command) a signal raises at
once, as Python's own Ctrl-C does.

The exit status says which signal it was: ``128 + last_signal()``.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from types import FrameType

SIGNALS = (signal.SIGINT, signal.SIGTERM)

_state: dict[str, int | bool | None] = {
    "signal": int(signal.SIGINT),  # the last signal that interrupted (or is about to)
    "pending": None,  # a signal recorded inside ``deferred``, not raised yet
    "immediate": False,  # inside ``interruptible`` and outside ``critical``
    "raised": False,  # this ``deferred`` block has raised its interrupt already
}


def last_signal() -> int:
    """The number of the signal that interrupted the run (SIGINT if none did)."""
    return int(_state["signal"] or signal.SIGINT)


def raise_interrupt(signum: int, frame: FrameType | None) -> None:
    """A handler: SIGTERM (or any signal) stops the run as Ctrl-C does."""
    _state["signal"] = signum
    raise KeyboardInterrupt


def _record(signum: int, frame: FrameType | None) -> None:
    """The handler inside ``deferred``: remember the signal; raise only where it is safe."""
    if _state["raised"]:
        return  # cleaning up after the first one: a second Ctrl-C waits for it
    _state["signal"] = signum
    if _state["immediate"]:
        _state["raised"] = True
        raise KeyboardInterrupt
    _state["pending"] = signum


def check() -> None:
    """Raise ``KeyboardInterrupt`` if a signal arrived inside ``deferred`` (once)."""
    if _state["pending"] is not None and not _state["raised"]:
        _state["pending"] = None
        _state["raised"] = True
        raise KeyboardInterrupt


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """Within: Ctrl-C and SIGTERM are recorded, and raised by ``check`` (or inside
    ``interruptible``); one still pending at the end is raised then. Only the main thread
    receives signals: elsewhere this changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in SIGNALS}
    outer = dict(_state)
    _state.update(pending=None, immediate=False, raised=False)
    for s in SIGNALS:
        signal.signal(s, _record)
    try:
        yield
        check()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _state.update(pending=outer["pending"], immediate=outer["immediate"],
                      raised=outer["raised"])


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Within ``deferred``: a signal raises at once (for work that holds no lock, such as a
    compiled kernel's run); one that arrived before is raised on entry."""
    check()
    was = _state["immediate"]
    _state["immediate"] = True
    try:
        yield
    finally:
        _state["immediate"] = was


@contextlib.contextmanager
def critical() -> Iterator[None]:
    """Within ``interruptible``: a block that takes a lock, where a signal is only recorded
    (and raised by the next ``check``, or at the end of the ``interruptible`` block)."""
    was = _state["immediate"]
    _state["immediate"] = False
    try:
        yield
    finally:
        _state["immediate"] = was
    if was:
        check()
