"""The machine flatcli runs on, as this process sees it: the cores it may use and the memory
it may have (a container's limit where that is lower than the machine's).

One place, read by the spec's limits (``flatcli.spec.limits``: what a sweep may plan to use),
by ``flatcli check`` (``flatcli.preflight``: what it warns of) and by the local executor (its
default number of workers), so that the three never disagree about the machine.
"""

from __future__ import annotations

import os

#: Where a container's memory limit is written: cgroup v2, then cgroup v1 (a file that holds
#: "max", or is missing, sets no limit).
CGROUP_MEMORY_LIMITS = (
    "/sys/fs/cgroup/memory.max",
    "/sys/fs/cgroup/memory/memory.limit_in_bytes",
)


def cores() -> int:
    """Cores this process may run on (its CPU affinity: ``taskset``, a container's cpuset)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def physical_memory() -> float:
    """This machine's memory, or the container's limit if lower [bytes]."""
    total = float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    for path in CGROUP_MEMORY_LIMITS:
        try:
            with open(path) as fh:
                limit = fh.read().strip()
        except OSError:
            continue
        if limit.isdigit():
            total = min(total, float(limit))
    return total
