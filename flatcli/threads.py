"""Thread limits of the numerical libraries (BLAS, OpenMP), inside flatcli's own work only.

flatcli's matrices are small: a threaded BLAS only adds overhead (SLSQP runs 3-5x slower on
two cores) and oversubscribes the cores a sweep's worker processes already fill. So flatcli's
computations run on one BLAS thread: its worker processes set that for the whole process
(``limit_process``), and the API's functions for the time they compute (``one_thread``), so
that ``import flatcli`` leaves a notebook's own numpy work as it was. The command line, a
process of flatcli's own, sets the libraries' variables before they load (``flatcli.cli``).
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator
from typing import Any, ParamSpec, TypeVar

T = TypeVar("T")
P = ParamSpec("P")

#: The variables the command line sets before numpy loads (a user's own setting wins).
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _load_libraries() -> None:
    """Load the BLAS of numpy and of scipy, so that a limit reaches both (threadpoolctl
    limits the libraries loaded when it is set). Where every thread variable already says 1
    (flatcli's command line and its workers), a BLAS loaded later starts with one thread, so
    scipy is not loaded for it (a sweep never needs scipy's BLAS)."""
    import os

    import numpy  # noqa: F401

    if all(os.environ.get(name) == "1" for name in THREAD_VARIABLES):
        return
    import scipy.linalg  # noqa: F401


#: threadpoolctl's controller (it lists the thread pools of the loaded libraries, a scan of
#: the process's shared objects that costs milliseconds) and len(sys.modules) when it was
#: made: made again only when a module has been loaded since, which is how a library with a
#: pool of its own arrives.
_CONTROLLER: list[Any] = [None, -1]


def _controller() -> Any:
    import sys

    from threadpoolctl import ThreadpoolController

    loaded = len(sys.modules)
    if _CONTROLLER[0] is None or _CONTROLLER[1] != loaded:
        _CONTROLLER[:] = [ThreadpoolController(), loaded]
    return _CONTROLLER[0]


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Within: every loaded BLAS and OpenMP pool runs one thread; afterwards, what it ran
    before."""
    _load_libraries()
    with _controller().limit(limits=1):
        yield


def limit_process() -> None:
    """In a worker process of flatcli's: one BLAS and OpenMP thread from now on."""
    from threadpoolctl import threadpool_limits

    _load_libraries()
    threadpool_limits(limits=1)


def single_threaded(fn: Callable[..., T], *args: Any) -> T:
    """``fn(*args)`` within ``one_thread`` (a task shipped to a Dask worker, which is not
    flatcli's process)."""
    with one_thread():
        return fn(*args)


def computes(fn: Callable[P, T]) -> Callable[P, T]:
    """An API function that runs ``one_thread`` while it computes."""
    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> T:
        with one_thread():
            return fn(*args, **kwargs)

    return wrapper
