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
import threading
import time
import uuid
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, NoReturn, Protocol, TypeVar

import numpy as np

from flatcli.cluster import SLURM, SLURM_WORKER_TIMEOUT
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
#: Dask configuration of the LocalCluster flatcli starts (``--scheduler local``): its
#: processes forked from this one, as the local executor's are (they start with flatcli and
#: its libraries loaded: 0.7 s against 3.7 s to spawn fresh interpreters, at load 9 on 2
#: cores); and, on a worker, less of Dask's own work beside a chunk's, which took 7-8 % of
#: a chunk's CPU time in the worker's other threads (measured on 8 chunks of the paper's
#: loop, the chunks' own thread CPU equal): no statistical profiler sampling the task's
#: thread every 10 ms, the event loop's tick and the memory monitor every second instead of
#: every 20 and 100 ms (then 2 %). ``WORKER_SETTINGS`` are the same as variables.
CLUSTER_CONFIG = {"distributed.worker.multiprocessing-method": "fork",
                  "distributed.worker.profile.enabled": False,
                  "distributed.admin.tick.interval": "1s",
                  "distributed.worker.memory.monitor-interval": "1s"}
#: The settings a Dask worker that is not flatcli's own should have (docs/cluster.md; a
#: SLURM job's script exports them: ``flatcli.cluster``).
WORKER_SETTINGS = {"DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False",
                   "DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL": "1s",
                   "DASK_DISTRIBUTED__WORKER__MEMORY__MONITOR_INTERVAL": "1s"}
#: Environment of that cluster's worker processes: one BLAS and OpenMP thread from their
#: start, as flatcli's own workers (``flatcli.threads``).
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
#: How often a local sweep's main thread, waiting for its workers, looks for a Ctrl-C or
#: SIGTERM recorded meanwhile (``flatcli.interrupts``) [s].
INTERRUPT_POLL_SECONDS = 0.1
_PR_SET_PDEATHSIG = 1
#: How long an aborted pool's manager thread may take to notice its killed workers [s].
MANAGER_JOIN_SECONDS = 2.0
#: Manager threads of aborted pools that did not end: a worker killed while it wrote its
#: result leaves a partial message in the result pipe, which this process holds open too, so
#: the thread reading it waits forever, and the interpreter joins that (non-daemon) thread at
#: exit. A program that aborted such a pool ends with ``leave`` (os._exit) instead.
STUCK_THREADS: list[threading.Thread] = []


def quiet_loggers() -> dict[str, int]:
    """Raise Dask's loggers to ERROR, and to CRITICAL asyncio's and Tornado's, which report
    exceptions in Dask's event loop (a SLURM job that sbatch refused: ``flatcli.cluster``
    says that in one line); their previous levels."""
    names = [n for n in logging.root.manager.loggerDict if n.startswith("distributed")]
    levels = {name: logging.getLogger(name).level
              for name in ["distributed", *names, "tornado.application"]}
    for name in levels:
        logging.getLogger(name).setLevel(logging.CRITICAL if name.startswith("tornado")
                                          else logging.ERROR)
    logging.getLogger("asyncio").setLevel(logging.CRITICAL)  # not restored: see close()
    return levels


def restore_loggers(levels: dict[str, int]) -> None:
    """Dask's loggers back to ``levels``. (asyncio's stays quiet: a gather abandoned after a
    worker died reports itself when it is garbage-collected, possibly at exit.)"""
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


def worker_timeout(default: float | None = None) -> float:
    """How long the Dask executor waits for a worker [s]: FLATCLI_DASK_WORKER_TIMEOUT, else
    ``default`` (else WORKER_TIMEOUT)."""
    fallback = WORKER_TIMEOUT if default is None else default
    try:
        return float(os.environ.get("FLATCLI_DASK_WORKER_TIMEOUT", fallback))
    except ValueError:
        return fallback


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
    """Runs tasks, yielding (tag, result) as each completes. ``share`` hands objects that
    many tasks take (a sweep's cells) to the workers once, returning what a task's arguments
    name them by; ``warm`` makes every worker ready before the work starts (the compiled
    kernels loaded: start-up, not work)."""

    workers: int
    description: str

    def share(self, objects: Sequence[Any]) -> list[Any]: ...

    def warm(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        """Make every worker ready to run ``fn(*args)`` as this process is, which has just
        run it (args: as ``share`` named them)."""

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


def leave(status: int) -> NoReturn:
    """End the program with ``status``: ``sys.exit``, or, if an aborted pool left a thread
    that can never end (``STUCK_THREADS``), ``os._exit`` after flushing stdout and stderr
    (``sys.exit`` would wait for that thread forever)."""
    if STUCK_THREADS:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError, AttributeError):
                stream.flush()
        os._exit(status)
    sys.exit(status)


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

    def share(self, objects: Sequence[Any]) -> list[Any]:
        """The objects themselves (the pool's forked workers pickle a task's arguments)."""
        return list(objects)

    def warm(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        """Nothing: the pool's workers fork from this process, which has run ``fn(*args)``,
        and inherit what it loaded."""

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
            manager = getattr(pool, "_executor_manager_thread", None)  # (shutdown forgets it)
            # the tasks still queued for the killed workers are never read: the queue's feeder
            # thread may be blocked writing them into a full pipe, and the pool's manager
            # thread (which the interpreter joins at exit) would join it forever ("error:
            # interrupted" printed, the process never exiting)
            call_queue = getattr(pool, "_call_queue", None)
            with contextlib.suppress(AttributeError, OSError, ValueError):
                call_queue.cancel_join_thread()  # type: ignore[union-attr]
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
            if isinstance(manager, threading.Thread):
                manager.join(timeout=MANAGER_JOIN_SECONDS)
                if manager.is_alive():
                    STUCK_THREADS.append(manager)
            return
        pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
    """Tasks on a Dask distributed cluster (``scheduler`` address, or "local").

    "local" starts a LocalCluster with one single-threaded worker process per core, as
    flatcli's own workers run: one BLAS thread (``WORKER_ENV``), and without Dask's
    statistical profiler (``CLUSTER_CONFIG``). If a worker dies mid-task the scheduler runs
    the task again elsewhere; the result is the same because a task depends only on its
    arguments.
    """

    def __init__(self, scheduler: str, workers: int | None = None,
                 announce: Callable[[str], None] | None = None) -> None:
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise FlatcliError(
                "--executor dask: dask.distributed is not installed; "
                "pip install 'flatcli[dask]'"
            ) from None
        self._cluster = None
        self._idle_since: float | None = None
        requested = 1  # worker threads of a cluster started here
        # a chunk rescheduled after a worker died is not the user's concern: Dask's warnings
        # (and asyncio's about its abandoned gathers) stay off the terminal
        self._levels = quiet_loggers()
        try:
            if scheduler == "local":
                import dask

                n = requested = workers or default_workers()
                with dask.config.set(CLUSTER_CONFIG):  # (the nannies hand it to the workers)
                    # its workers are flatcli's own processes
                    self._cluster = LocalCluster(
                        n_workers=n, threads_per_worker=1, processes=True,
                        dashboard_address=":0", env={**WORKER_ENV, OWN_PROCESS_VARIABLE: "1"})
                self._client = Client(self._cluster)
            elif scheduler == SLURM:
                from flatcli.cluster import slurm_cluster

                self._cluster, requested = slurm_cluster(workers)
                self._client = Client(self._cluster)
                wait = worker_timeout(SLURM_WORKER_TIMEOUT)
                if announce is not None:
                    announce(f"waiting for SLURM to start the workers' jobs (at most "
                             f"{wait:g} s; squeue -n flatcli-worker shows them)")
            else:
                self._client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except FlatcliError:
            restore_loggers(self._levels)
            raise
        except (OSError, ValueError, TypeError) as exc:  # unreachable; malformed address
            restore_loggers(self._levels)
            if self._cluster is not None:
                self._cluster.close()
            reason = f"cannot connect ({exc})" if isinstance(exc, OSError) else str(exc)
            raise FlatcliError(f"--scheduler {scheduler}: {reason}") from None
        self._scheduler = scheduler
        self._wait = worker_timeout(SLURM_WORKER_TIMEOUT if scheduler == SLURM else None)
        try:
            self._client.wait_for_workers(1, timeout=self._wait)
        except (OSError, TimeoutError) as exc:
            self.close(abort=True)
            start = ("the SLURM jobs did not start (squeue; FLATCLI_DASK_WORKER_TIMEOUT "
                     "waits longer)" if scheduler == SLURM else
                     "start workers (dask worker ADDRESS), or use --executor local")
            raise FlatcliError(f"--scheduler {scheduler}: no worker joined within "
                               f"{self._wait:g} s ({type(exc).__name__}); {start}") from None
        info = self._client.scheduler_info(n_workers=-1)
        threads = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values())
        # a cluster flatcli started will have all it asked for (jobs start one by one)
        self.workers = max(threads, requested)
        plural = "s" if self.workers > 1 else ""
        self.description = (
            f"dask at {info.get('address', scheduler)}, {self.workers} worker thread{plural}"
        )

    def share(self, objects: Sequence[Any]) -> list[Any]:
        """The objects sent to the cluster once, as futures a task's arguments may name: a
        task then carries its piece of work, not its cell's plan and reference tables (250
        kB for the paper's loop), and a worker fetches each cell once. Each is a task's
        result (not scattered data), so one lost with its worker is made again from the
        task, which the scheduler keeps."""
        return [self._client.submit(_same, item, pure=False, key=f"share-{uuid.uuid4().hex}")
                for item in objects]

    def warm(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        """``fn(*args)`` once on every worker there is now, all at once (a worker that joins
        later loads the kernel with its first task)."""
        from distributed import wait as dask_wait

        info = self._client.scheduler_info(n_workers=-1)
        futures = [self._client.submit(single_threaded, fn, *args, workers=[address],
                                       allow_other_workers=False, pure=False,
                                       key=f"warm-{uuid.uuid4().hex}")
                   for address in info.get("workers", {})]
        pending = list(futures)
        while pending:
            with contextlib.suppress(TimeoutError):
                dask_wait(pending, timeout=POLL_SECONDS)
            check()
            self._watch()
            pending = [f for f in pending if not f.done()]
        for future in futures:
            if future.status == "error":  # a worker that died: its chunks go elsewhere
                continue
            future.result()  # (an exception of fn itself is raised here)
            future.release()

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
        elif now - self._idle_since > self._wait:
            raise WorkerLostError(f"no Dask worker for {self._wait:g} s at "
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


def _same(item: T) -> T:
    return item


def make_executor(kind: str, workers: int | None, scheduler: str | None,
                  announce: Callable[[str], None] | None = None) -> Executor:
    """The executor a command line asks for; FlatcliError names a bad option. ``announce``:
    where a line for the user goes while the executor waits (for SLURM's jobs)."""
    if kind == "local":
        if scheduler is not None:
            raise FlatcliError("--scheduler: only used with --executor dask")
        return LocalExecutor(workers if workers is not None else default_workers())
    if kind == "dask":
        return DaskExecutor(scheduler or "local", workers, announce)
    raise FlatcliError(f"--executor: expected one of {list(EXECUTORS)}, got {kind!r}")
