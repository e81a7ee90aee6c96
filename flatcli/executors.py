"""Where chunks run: this machine's cores, or a Dask distributed cluster.

Both executors take the same picklable task (a function and its arguments) and hand results
back to the caller as they complete, so the caller alone writes files. A task's result
depends only on its arguments, which is what makes the outcome identical across executors.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Protocol, TypeVar

from flatcli.core.model import FlatcliError

T = TypeVar("T")

EXECUTORS = ("local", "dask")

#: How long the Dask executor tries to reach a scheduler before giving up.
CONNECT_TIMEOUT = "10s"


class WorkerLostError(RuntimeError):
    """A worker process died (killed, out of memory) and its task could not be run."""


class Executor(Protocol):
    """Runs tasks, yielding (tag, result) as each completes."""

    workers: int
    description: str

    def run(
        self, fn: Callable[..., Any], tasks: Iterable[tuple[T, tuple[Any, ...]]]
    ) -> Iterator[tuple[T, Any]]: ...

    def close(self) -> None: ...


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


class LocalExecutor:
    """In this process (one worker) or a process pool (one process per worker).

    On Linux the pool forks, so workers start with everything the parent already imported
    and compiled; at most two tasks per worker are in flight, so memory stays bounded.
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
                max_workers=workers, mp_context=multiprocessing.get_context(method)
            )

    def run(
        self, fn: Callable[..., Any], tasks: Iterable[tuple[T, tuple[Any, ...]]]
    ) -> Iterator[tuple[T, Any]]:
        if self._pool is None:
            for tag, args in tasks:
                yield tag, fn(*args)
            return
        try:
            yield from self._run_pool(self._pool, fn, tasks)
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
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                tag = pending.pop(future)
                yield tag, future.result()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


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
        try:
            if scheduler == "local":
                n = workers or default_workers()
                self._cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0"
                )
                self._client = Client(self._cluster)
            else:
                self._client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, ValueError) as exc:  # unreachable; malformed address or scheme
            if self._cluster is not None:
                self._cluster.close()
            reason = f"cannot connect ({exc})" if isinstance(exc, OSError) else str(exc)
            raise FlatcliError(f"--scheduler {scheduler}: {reason}") from None
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
        from dask.distributed import as_completed
        from distributed import KilledWorker

        queue = iter(tasks)
        window = max(2 * self.workers, 4)
        tags: dict[Any, T] = {}
        futures = []
        for tag, args in queue:
            future = self._client.submit(fn, *args, pure=False)
            tags[future.key] = tag
            futures.append(future)
            if len(futures) >= window:
                break
        stream = as_completed(futures)
        for future in stream:
            tag = tags.pop(future.key)
            try:
                result = future.result()
            except KilledWorker as exc:
                raise WorkerLostError(f"Dask workers kept dying on a chunk ({exc})") from None
            future.release()
            yield tag, result
            nxt = next(queue, None)
            if nxt is not None:
                new = self._client.submit(fn, *nxt[1], pure=False)
                tags[new.key] = nxt[0]
                stream.add(new)

    def close(self) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(kind: str, workers: int | None, scheduler: str | None) -> Executor:
    """The executor a command line asks for; FlatcliError names a bad option."""
    if kind == "local":
        if scheduler is not None:
            raise FlatcliError("--scheduler: only used with --executor dask")
        return LocalExecutor(workers if workers is not None else default_workers())
    if kind == "dask":
        return DaskExecutor(scheduler or "local", workers)
    raise FlatcliError(f"--executor: expected one of {list(EXECUTORS)}, got {kind!r}")
