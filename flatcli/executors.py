"""Where chunks run: this machine's cores, or a Dask distributed cluster.

Both executors take the same picklable task (a function and its arguments) and hand results
back to the caller as they complete, so the caller alone writes files. A task's result
depends only on its arguments, which is what makes the outcome identical across executors.

Neither leaves processes behind: a local worker asks the kernel to kill it when its parent
dies (``prctl(PR_SET_PDEATHSIG)``), however the parent dies, and ignores Ctrl-C (the parent
stops it); the Dask executor gives up, with one line, when the scheduler is lost or no
worker is there to run the chunks for ``WORKER_TIMEOUT`` seconds.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import logging
import multiprocessing
import os
import signal
import sys
import time
import uuid
import warnings
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Protocol, TypeVar

import numpy as np

from flatcli.core import OWN_PROCESS_VARIABLE
from flatcli.core.errors import FlatcliError
from flatcli.core.names import EXECUTORS
from flatcli.interrupts import check, interruptible
from flatcli.machine import cores
from flatcli.storage import forget_inherited_locks
from flatcli.threads import limit_process, single_threaded

T = TypeVar("T")


#: How long the Dask executor tries to reach a scheduler before giving up.
CONNECT_TIMEOUT = "10s"
#: How long the Dask executor waits for a worker (at the start, or when all have left) [s];
#: FLATCLI_DASK_WORKER_TIMEOUT sets it.
WORKER_TIMEOUT = 60.0
#: How often the Dask executor looks at the cluster while it waits for results [s].
POLL_SECONDS = 1.0
#: How often a local sweep's main thread, waiting for its workers, looks for a Ctrl-C or
#: SIGTERM recorded meanwhile (``flatcli.interrupts``) [s].
INTERRUPT_POLL_SECONDS = 0.1
_PR_SET_PDEATHSIG = 1


def quiet_loggers() -> dict[str, int]:
    """Raise Dask's loggers to ERROR and asyncio's to CRITICAL; their previous levels."""
    names = [n for n in logging.root.manager.loggerDict if n.startswith("distributed")]
    levels = {name: logging.getLogger(name).level for name in ["distributed", *names]}
    for name in levels:
        logging.getLogger(name).setLevel(logging.ERROR)
    logging.getLogger("asyncio").setLevel(logging.CRITICAL)  # not restored: see close()
    return levels


def restore_loggers(levels: dict[str, int]) -> None:
    """Dask's loggers back to ``levels``. (asyncio's stays quiet: a gather abandoned after a
    worker died reports itself when it is garbage-collected, possibly at exit.)"""
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


def worker_timeout() -> float:
    try:
        return float(os.environ.get("FLATCLI_DASK_WORKER_TIMEOUT", WORKER_TIMEOUT))
    except ValueError:
        return WORKER_TIMEOUT


def die_with_parent(parent: int) -> None:
    """In a worker process: be killed when the parent process ends (Linux), and end now if
    it already has. Also: leave Ctrl-C to the parent, drop its directory locks, make the
    process flatcli's own (``flatcli.core._jit.own_process``), run one BLAS thread
    (``flatcli.threads``), and keep numpy's floating-point warnings off the terminal (the
    metrics say what went wrong)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    forget_inherited_locks()
    from flatcli.core._jit import own_process

    own_process()  # a worker is flatcli's own process, whoever started the sweep
    limit_process()
    np.seterr(all="ignore")
    warnings.simplefilter("ignore", RuntimeWarning)


class WorkerLostError(RuntimeError):
    """A worker process died (killed, out of memory) and its task could not be run."""


class Executor(Protocol):
    """Runs tasks, yielding (tag, result) as each completes."""

    workers: int
    description: str

    def run(
        self, fn: Callable[..., Any], tasks: Iterable[tuple[T, tuple[Any, ...]]]
    ) -> Iterator[tuple[T, Any]]: ...

    def close(self, abort: bool = False) -> None: ...


def _alive(process: Any) -> bool:
    """Whether a pool's worker process is still running (False once it cannot be asked)."""
    try:
        return bool(process.is_alive())
    except (OSError, ValueError, AssertionError):
        return False


def default_workers() -> int:
    """One worker per core this process may use (``flatcli.machine.cores``)."""
    return cores()


class LocalExecutor:
    """In this process (one worker) or a process pool (one process per worker).

    On Linux the pool forks, so workers start with everything the parent already imported
    and compiled; at most two tasks per worker are in flight, so memory stays bounded. A run
    of a single task runs it in this process, as one worker would: the pool is not started.
    """

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise FlatcliError(f"--workers: must be >= 1, got {workers}")
        self.workers = workers
        self.description = f"local, {workers} worker{'s' if workers > 1 else ''}"
        self._pool: ProcessPoolExecutor | None = None
        if workers > 1:
            method = "fork" if sys.platform.startswith("linux") else "spawn"
            self._pool = ProcessPoolExecutor(
                max_workers=workers, mp_context=multiprocessing.get_context(method),
                initializer=die_with_parent, initargs=(os.getpid(),),
            )

    def run(
        self, fn: Callable[..., Any], tasks: Iterable[tuple[T, tuple[Any, ...]]]
    ) -> Iterator[tuple[T, Any]]:
        queue = iter(tasks)
        head = list(itertools.islice(queue, 2)) if self._pool is not None else []
        if self._pool is None or len(head) < 2:
            # in this process: one worker, or a single task (which a pool would only delay
            # by its start: forking the workers, sending the task, 30-40 ms)
            for tag, args in itertools.chain(head, queue):
                with interruptible():  # a kernel's run holds no lock: Ctrl-C ends it at once
                    result = fn(*args)
                yield tag, result
            return
        try:
            yield from self._run_pool(self._pool, fn, itertools.chain(head, queue))
        except BrokenProcessPool:
            raise WorkerLostError("a worker process died (killed or out of memory)") from None

    def _run_pool(
        self, pool: ProcessPoolExecutor, fn: Callable[..., Any],
        tasks: Iterable[tuple[T, tuple[Any, ...]]],
    ) -> Iterator[tuple[T, Any]]:
        pending: dict[Future[Any], T] = {}
        queue = iter(tasks)
        window = 2 * self.workers
        exhausted = False
        while True:
            while not exhausted and len(pending) < window:
                try:
                    tag, args = next(queue)
                except StopIteration:
                    exhausted = True
                    break
                pending[pool.submit(fn, *args)] = tag
            if not pending:
                return
            # a signal is raised here, not inside the pool's locks (flatcli.interrupts)
            done, _ = wait(pending, timeout=INTERRUPT_POLL_SECONDS, return_when=FIRST_COMPLETED)
            check()
            for future in done:
                tag = pending.pop(future)
                yield tag, future.result()

    def close(self, abort: bool = False) -> None:
        """Stop the pool: after the running tasks (or at once, killing them, if ``abort``)."""
        if self._pool is None:
            return
        pool, self._pool = self._pool, None
        if abort:
            # the pool has no public way to stop running tasks; its processes are known
            processes = list(getattr(pool, "_processes", {}).values())
            for process in processes:
                with contextlib.suppress(OSError, ValueError):
                    process.kill()
            pool.shutdown(wait=False, cancel_futures=True)
            deadline = time.monotonic() + 5.0
            for process in processes:
                with contextlib.suppress(OSError, ValueError, AssertionError):
                    process.join(timeout=5)
            # the pool's own thread may reap a killed worker at the same moment (then our
            # join returns before the exit status is recorded): wait until it is
            while any(_alive(p) for p in processes) and time.monotonic() < deadline:
                time.sleep(0.01)
            return
        pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
    """Tasks on a Dask distributed cluster (``scheduler`` address, or "local").

    "local" starts a LocalCluster with one single-threaded worker process per core. If a
    worker dies mid-task the scheduler runs the task again elsewhere; the result is the same
    because a task depends only on its arguments.
    """

    def __init__(self, scheduler: str, workers: int | None = None) -> None:
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise FlatcliError(
                "--executor dask: dask.distributed is not installed; "
                "pip install 'flatcli[dask]'"
            ) from None
        self._cluster = None
        self._idle_since: float | None = None
        # a chunk rescheduled after a worker died is not the user's concern: Dask's warnings
        # (and asyncio's about its abandoned gathers) stay off the terminal
        self._levels = quiet_loggers()
        try:
            if scheduler == "local":
                n = workers or default_workers()
                self._cluster = LocalCluster(  # its workers are flatcli's own processes
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                    env={OWN_PROCESS_VARIABLE: "1"})
                self._client = Client(self._cluster)
            else:
                self._client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, ValueError, TypeError) as exc:  # unreachable; malformed address
            restore_loggers(self._levels)
            if self._cluster is not None:
                self._cluster.close()
            reason = f"cannot connect ({exc})" if isinstance(exc, OSError) else str(exc)
            raise FlatcliError(f"--scheduler {scheduler}: {reason}") from None
        self._scheduler = scheduler
        try:
            self._client.wait_for_workers(1, timeout=worker_timeout())
        except (OSError, TimeoutError) as exc:
            self.close(abort=True)
            raise FlatcliError(f"--scheduler {scheduler}: no worker joined within "
                               f"{worker_timeout():g} s ({type(exc).__name__}); start workers "
                               "(dask worker ADDRESS), or use --executor local") from None
        info = self._client.scheduler_info()
        threads = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values())
        self.workers = max(threads, 1)
        plural = "s" if self.workers > 1 else ""
        self.description = (
            f"dask at {info.get('address', scheduler)}, {self.workers} worker thread{plural}"
        )

    def run(
        self, fn: Callable[..., Any], tasks: Iterable[tuple[T, tuple[Any, ...]]]
    ) -> Iterator[tuple[T, Any]]:
        try:
            yield from self._run(fn, tasks)
        except WorkerLostError:
            raise
        except Exception as exc:  # the scheduler or the connection to it is gone
            if not self._lost(exc):
                raise
            reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
            raise WorkerLostError(f"lost the Dask scheduler {self._scheduler} ({reason})"
                                  ) from None

    @staticmethod
    def _lost(exc: BaseException) -> bool:
        from distributed.client import FutureCancelledError
        from distributed.comm.core import CommClosedError

        return isinstance(exc, OSError | TimeoutError | CommClosedError | FutureCancelledError)

    def _run(
        self, fn: Callable[..., Any], tasks: Iterable[tuple[T, tuple[Any, ...]]]
    ) -> Iterator[tuple[T, Any]]:
        from distributed import KilledWorker
        from distributed import wait as dask_wait

        queue = iter(tasks)
        window = max(2 * self.workers, 4)
        pending: dict[Any, T] = {}

        def submit() -> bool:
            item = next(queue, None)
            if item is None:
                return False
            # a Dask worker is not flatcli's process: one BLAS thread for the task only; the
            # task keeps its function's name (run_chunk-...) on the dashboard
            key = f"{getattr(fn, '__name__', 'task')}-{uuid.uuid4().hex}"
            future = self._client.submit(single_threaded, fn, *item[1], key=key, pure=False)
            pending[future] = item[0]
            return True

        while len(pending) < window and submit():
            pass
        self._idle_since = None
        while pending:
            try:
                done, _ = dask_wait(list(pending), timeout=POLL_SECONDS,
                                    return_when="FIRST_COMPLETED")
            except TimeoutError:
                check()
                self._watch()
                continue
            for future in done:
                tag = pending.pop(future)
                while True:  # a result lost with its worker is computed again: wait, watching
                    try:
                        result = future.result(timeout=POLL_SECONDS)
                        break
                    except TimeoutError:
                        check()
                        self._watch()
                    except KilledWorker as exc:
                        raise WorkerLostError(f"Dask workers kept dying on a chunk ({exc})"
                                              ) from None
                self._idle_since = None
                future.release()
                yield tag, result
                submit()

    def _watch(self) -> None:
        """While waiting: give up when the scheduler is gone, or when it has had no worker
        for ``worker_timeout()`` seconds (WorkerLostError)."""
        if self._client.status not in ("running", "connecting"):
            raise WorkerLostError(f"lost the Dask scheduler {self._scheduler} "
                                  f"(client {self._client.status})")
        workers = self._client.scheduler_info(n_workers=1).get("workers", {})
        now = time.monotonic()
        if workers:
            self._idle_since = None
        elif self._idle_since is None:
            self._idle_since = now
        elif now - self._idle_since > worker_timeout():
            raise WorkerLostError(f"no Dask worker for {worker_timeout():g} s at "
                                  f"{self._scheduler}")

    def close(self, abort: bool = False) -> None:
        with contextlib.suppress(Exception):
            if abort:
                self._client.close(timeout=5)
            else:
                self._client.close()
        if self._cluster is not None:
            with contextlib.suppress(Exception):
                self._cluster.close(timeout=5 if abort else None)
        restore_loggers(self._levels)


def make_executor(kind: str, workers: int | None, scheduler: str | None) -> Executor:
    """The executor a command line asks for; FlatcliError names a bad option."""
    if kind == "local":
        if scheduler is not None:
            raise FlatcliError("--scheduler: only used with --executor dask")
        return LocalExecutor(workers if workers is not None else default_workers())
    if kind == "dask":
        return DaskExecutor(scheduler or "local", workers)
    raise FlatcliError(f"--executor: expected one of {list(EXECUTORS)}, got {kind!r}")
