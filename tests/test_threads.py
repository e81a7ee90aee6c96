"""flatcli.threads: one BLAS thread inside flatcli's work only, never for a user's
interpreter as a whole."""

from __future__ import annotations

import os
import subprocess
import sys

from threadpoolctl import threadpool_info, threadpool_limits

from flatcli.executors import LocalExecutor
from flatcli.threads import THREAD_VARIABLES, computes, one_thread, single_threaded


def blas_threads() -> list[int]:
    """The thread counts of every loaded BLAS."""
    return [int(p["num_threads"]) for p in threadpool_info() if p["user_api"] == "blas"]


def test_import_flatcli_sets_no_thread_variable() -> None:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    code = ("import os, flatcli, flatcli.api\n"
            f"print([v for v in {THREAD_VARIABLES!r} if v in os.environ])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_one_thread_limits_within_and_restores_after() -> None:
    with threadpool_limits(limits=2):
        assert set(blas_threads()) == {2}
        with one_thread():
            assert set(blas_threads()) == {1}
        assert set(blas_threads()) == {2}


def test_an_api_function_computes_on_one_thread_and_gives_them_back() -> None:
    @computes
    def work(x: int) -> tuple[int, list[int]]:
        return x + 1, blas_threads()

    with threadpool_limits(limits=2):
        value, inside = work(1)
        assert value == 2 and set(inside) == {1}
        assert set(blas_threads()) == {2}
    with threadpool_limits(limits=2):
        assert single_threaded(blas_threads) == [1] * len(blas_threads())


def _worker_threads() -> list[int]:
    return blas_threads()


def test_worker_processes_run_one_thread() -> None:
    with threadpool_limits(limits=2):
        executor = LocalExecutor(2)
        try:
            results = [r for _, r in executor.run(_worker_threads, [(0, ()), (1, ())])]
        finally:
            executor.close()
        assert all(set(r) == {1} for r in results)
        assert set(blas_threads()) == {2}  # the parent keeps its threads


def test_limit_process_is_for_the_rest_of_the_process() -> None:
    code = ("from flatcli.threads import limit_process\n"
            "from threadpoolctl import threadpool_info, threadpool_limits\n"
            "threadpool_limits(limits=2)\n"
            "limit_process()\n"
            "print({p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'})")
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "{1}"
