"""Ctrl-C and SIGTERM deferred to where no lock is held (flatcli/interrupts.py).

The hazard these guard against is CPython's: a handler that raises can leave a ``with
lock:`` block without releasing the lock (https://github.com/python/cpython/issues/74174).
A sweep hung for good that way in about 1 SIGTERM in 50 under load; the end-to-end check is
tests/test_montecarlo_runner.py::test_sigterm_is_ctrl_c_and_leaves_no_worker_behind."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from flatcli.executors import LocalExecutor
from flatcli.interrupts import check, critical, deferred, interruptible, last_signal


def _signal_self(signum: int = signal.SIGTERM) -> None:
    os.kill(os.getpid(), signum)
    time.sleep(0.01)  # let the interpreter run the handler


def test_inside_deferred_a_signal_waits_for_check_and_outside_nothing_changed() -> None:
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    lock = threading.Lock()
    with pytest.raises(KeyboardInterrupt), deferred():
        with lock:
            _signal_self(signal.SIGTERM)
            inside_lock = True  # reached: nothing was raised while the lock was held
        assert inside_lock and not lock.locked()
        assert last_signal() == signal.SIGTERM
        check()
        pytest.fail("check() did not raise the recorded signal")
    assert not lock.locked()
    assert {s: signal.getsignal(s) for s in before} == before


def test_a_pending_signal_is_raised_when_the_deferred_block_ends() -> None:
    with pytest.raises(KeyboardInterrupt), deferred():
        _signal_self(signal.SIGINT)
        reached = True
    assert reached and last_signal() == signal.SIGINT


def test_interruptible_raises_at_once_and_critical_not_inside_its_lock() -> None:
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt), deferred(), interruptible():
        _signal_self()
        time.sleep(30)  # a long kernel run: the signal must end it, not wait for it
    assert time.monotonic() - started < 10

    lock = threading.Lock()
    with pytest.raises(KeyboardInterrupt), deferred(), interruptible():
        with critical(), lock:
            _signal_self()
            finished_block = True
        pytest.fail("leaving critical() did not raise the signal recorded inside it")
    assert finished_block and not lock.locked()


def test_a_second_signal_does_not_interrupt_the_cleanup_of_the_first() -> None:
    cleaned = False
    with pytest.raises(KeyboardInterrupt), deferred():
        try:
            _signal_self()
            check()
        finally:
            _signal_self()  # a second Ctrl-C while workers are stopped
            time.sleep(0.05)
            cleaned = True
    assert cleaned


def _slow(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def test_a_pool_waiting_for_workers_sees_a_signal_and_stops_them() -> None:
    executor = LocalExecutor(2)
    started = time.monotonic()
    results = []
    tasks = ((i, (0.2 if i == 0 else 60,)) for i in range(4))
    with pytest.raises(KeyboardInterrupt), deferred():
        try:
            for tag, result in executor.run(_slow, tasks):
                results.append((tag, result))
                _signal_self()  # after the first result; the others take a minute
        finally:
            executor.close(abort=True)
    assert results == [(0, 0.2)]
    assert time.monotonic() - started < 30  # not the minute the other tasks would take


def test_check_raises_a_recorded_signal_once() -> None:
    """After check() raised the recorded signal, the clean-up's own calls of check() (the
    pool's wait loop) go through: one signal, one interrupt."""
    with pytest.raises(KeyboardInterrupt), deferred():
        _signal_self()
        try:
            check()
        except KeyboardInterrupt:
            check()  # a second call during the clean-up: nothing pending any more
            check()
            raise
        pytest.fail("check() did not raise the recorded signal")


def test_a_second_signal_inside_interruptible_does_not_interrupt_its_cleanup() -> None:
    """The first signal raises at once inside interruptible(); a second one during the
    clean-up that follows (still inside it) is ignored, so the clean-up finishes."""
    cleaned = False
    with pytest.raises(KeyboardInterrupt), deferred(), interruptible():
        try:
            _signal_self()
            time.sleep(5)
        finally:
            _signal_self()
            time.sleep(0.05)
            cleaned = True
    assert cleaned


def test_interruptible_raises_a_signal_that_arrived_before_it_on_entry() -> None:
    entered = False
    with pytest.raises(KeyboardInterrupt), deferred():
        _signal_self()  # recorded, pending
        with interruptible():
            entered = True  # never: the pending signal is raised on entry
    assert not entered


def test_a_nested_deferred_block_keeps_the_outer_blocks_pending_signal() -> None:
    """A signal recorded in an outer deferred block survives an inner one (which starts with
    nothing pending and restores the outer state): the outer block raises it at its end."""
    inner_done = False
    with pytest.raises(KeyboardInterrupt), deferred():
        _signal_self()
        with deferred():
            inner_done = True
        reached = True
    assert inner_done and reached
