"""The local executor: every task runs once and results come back with their tags."""

from __future__ import annotations

import pytest

from flatcli.core.model import FlatcliError
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
