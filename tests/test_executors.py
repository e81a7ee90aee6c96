"""The local executor: every task runs once and results come back with their tags; its workers
die with their parent, leave Ctrl-C to it, and stop at once when the run is aborted."""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from flatcli.core.errors import FlatcliError
from flatcli.executors import LocalExecutor, make_executor


def square(x: int) -> int:
    return x * x


@pytest.mark.parametrize("workers", [1, 2])
def test_local_executor_runs_every_task_once(workers: int) -> None:
    executor = LocalExecutor(workers)
    try:
        results = dict(executor.run(square, ((i, (i,)) for i in range(23))))
    finally:
        executor.close()
    assert results == {i: i * i for i in range(23)}


def test_bad_executor_options_are_one_line_errors() -> None:
    with pytest.raises(FlatcliError, match="--workers: must be >= 1"):
        make_executor("local", 0, None)
    with pytest.raises(FlatcliError, match="--scheduler: only used with --executor dask"):
        make_executor("local", 1, "tcp://x:1")
    with pytest.raises(FlatcliError, match="--executor: expected one of"):
        make_executor("ray", 1, None)


def worker_state() -> tuple[int, str, bool, int]:
    """What a pool worker looks like from inside: its parent-death signal (Linux prctl
    PR_GET_PDEATHSIG), numpy's overflow setting, whether Ctrl-C is ignored, its parent."""
    libc = ctypes.CDLL(None, use_errno=True)
    signum = ctypes.c_int(-1)
    libc.prctl(2, ctypes.byref(signum), 0, 0, 0)  # PR_GET_PDEATHSIG
    return (signum.value, np.geterr()["over"],
            signal.getsignal(signal.SIGINT) is signal.SIG_IGN, os.getppid())


def nap(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl is Linux's")
def test_pool_workers_die_with_their_parent_and_leave_ctrl_c_to_it() -> None:
    executor = LocalExecutor(2)
    try:
        states = [state for _, state in executor.run(worker_state, ((i, ()) for i in range(4)))]
    finally:
        executor.close()
    for signum, over, ignores_sigint, parent in states:
        assert signum == signal.SIGKILL
        assert over == "ignore"
        assert ignores_sigint
        assert parent == os.getpid()


def test_an_aborted_pool_stops_its_running_tasks_at_once() -> None:
    executor = LocalExecutor(2)
    pool = executor._pool
    assert pool is not None
    futures = [pool.submit(nap, 60.0) for _ in range(4)]  # as run() submits them
    processes = list(pool._processes.values())
    started = time.monotonic()
    executor.close(abort=True)
    assert time.monotonic() - started < 30  # not the 60 s the running tasks would take
    assert all(not p.is_alive() for p in processes)
    assert not any(f.done() and not f.cancelled() and f.exception() is None for f in futures)


def slow_square(x: int) -> int:
    time.sleep(0.005)
    return x * x


@pytest.mark.parametrize("workers", [1, 2])
def test_at_most_two_tasks_per_worker_are_in_flight(workers: int) -> None:
    # the chunks in flight are what the memory estimate counts (two per worker): the pool
    # must not take more tasks from the queue than that before their results come back
    pulled = 0

    def tasks() -> Any:
        nonlocal pulled
        for i in range(30):
            pulled += 1
            yield i, (i,)

    executor = LocalExecutor(workers)
    in_flight = []
    try:
        for done, (tag, result) in enumerate(executor.run(slow_square, tasks())):
            assert result == tag * tag
            in_flight.append(pulled - done)  # taken from the queue, not yet handed back
    finally:
        executor.close()
    assert len(in_flight) == 30 and pulled == 30
    assert max(in_flight) <= (2 * workers if workers > 1 else 1)  # one at a time in process


def test_a_single_task_runs_in_this_process_and_two_in_the_pool() -> None:
    """One task: run here (a pool would only delay it by its start); two or more: in the
    pool's workers, whose pid is not this one (the referee: os.getpid in the task)."""
    executor = LocalExecutor(2)
    try:
        alone = dict(executor.run(task_pid, [(0, ())]))
        pair = dict(executor.run(task_pid, [(0, ()), (1, ())]))
    finally:
        executor.close()
    assert alone == {0: os.getpid()}
    assert sorted(pair) == [0, 1] and os.getpid() not in pair.values()


def task_pid() -> int:
    return os.getpid()


_HALF_WRITTEN = """
import os, struct, sys, time
from flatcli import executors
from flatcli.executors import LocalExecutor, leave

POOL = None

def half_written_result():
    # a worker killed while it writes its result: a message's length, then a part of it
    writer = POOL._result_queue._writer  # inherited through fork
    os.write(writer.fileno(), struct.pack("!i", 1_000_000) + b"partial")
    open(sys.argv[3], "w").close()  # written: the parent may abort now
    time.sleep(60)

if __name__ == "__main__":
    ex = LocalExecutor(2)
    POOL = ex._pool
    future = POOL.submit(half_written_result)
    deadline = time.monotonic() + 50  # the worker has forked and written its half message
    while not os.path.exists(sys.argv[3]) and time.monotonic() < deadline:
        time.sleep(0.01)
    ex.close(abort=True)
    print(len(executors.STUCK_THREADS), flush=True)
    leave(int(sys.argv[1])) if sys.argv[2] == "leave" else sys.exit(int(sys.argv[1]))
"""


def test_a_pool_aborted_with_a_half_written_result_still_ends_the_program(
        tmp_path: Path) -> None:
    """A worker killed while writing its result leaves a partial message in the result pipe,
    which the parent holds open too: the pool's manager thread waits for the rest forever and
    the interpreter joins it at exit (an interrupted sweep printed its line and never exited).
    ``close(abort=True)`` records the stuck thread and ``leave`` ends the program at once with
    the status and the printed lines. Referee: the same program ending with ``sys.exit``
    still runs 6 s after its abort (the hang this guards against)."""
    script = tmp_path / "half.py"
    script.write_text(_HALF_WRITTEN)
    done = subprocess.run([sys.executable, str(script), "3", "leave", str(tmp_path / "a")],
                          capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout) == (3, "1\n")
    # the abort waits for the worker's half message (a machine under load forks slowly)
    hung = subprocess.Popen([sys.executable, str(script), "3", "exit", str(tmp_path / "b")],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert hung.stdout is not None and hung.stdout.readline() == "1\n"  # aborted
        with pytest.raises(subprocess.TimeoutExpired):
            hung.wait(timeout=6)
    finally:
        hung.kill()
        hung.wait()
