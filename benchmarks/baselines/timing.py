"""Timing and the machine a bench ran on."""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

@dataclass(frozen=True)
class Timing:
    """Wall-clock times of repeated calls [s]."""

    best: float
    median: float
    repeat: int
    times: tuple[float, ...] = field(repr=False)


def timed(fn: Callable[[], object], repeat: int = 5, warmup: int = 1) -> Timing:
    """Time ``fn()`` ``repeat`` times after ``warmup`` untimed calls (compilation, caches).

    Parameters
    ----------
    fn : callable without arguments
    repeat : timed calls (>= 1)
    warmup : untimed calls first

    Returns
    -------
    Timing with the best and the median of the timed calls [s]
    """
    if repeat < 1:
        raise ValueError("timed: repeat must be >= 1")
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return Timing(min(times), statistics.median(times), repeat, tuple(times))


def machine_info() -> dict[str, Any]:
    """CPU model, cores, load, thread settings and versions of the numeric stack."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count() or 1
    import control  # (here: the kernel's whole process, kernel_process, loads neither)
    import scipy

    try:
        load: list[float] | None = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = None
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "usable_cores": usable,
        "load_average_1_5_15min": load,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "numba_threads": numba.get_num_threads(),
        # BLAS threads matter: SLSQP on a loaded 2-core machine runs several times slower
        # with 2 OpenBLAS threads (flatcli, imported first by this package, pins them to 1)
        "thread_env": {
            name: os.environ.get(name)
            for name in (
                "OMP_NUM_THREADS",
                "OPENBLAS_NUM_THREADS",
                "MKL_NUM_THREADS",
                "NUMBA_NUM_THREADS",
            )
        },
        "control": control.__version__,
    }


@dataclass(frozen=True)
class Throughput:
    """Trials per second of a closed-loop baseline."""

    trials: int
    timing: Timing
    threads: int = 1

    @property
    def trials_per_second(self) -> float:
        """Trials over the best time [1/s]."""
        return self.trials / self.timing.best


def throughput(fn: Callable[[], object], trials: int, workers: int, repeat: int,
               warmup: int = 1) -> Throughput:
    """Trials per second of ``fn`` (a run of ``trials`` trials on ``workers`` cores)."""
    return Throughput(trials, timed(fn, repeat, warmup), workers)
