"""The machine flatcli runs on, as this process sees it: the cores it may use (a container's
CPU quota where that is lower than its affinity) and the memory it may have (a container's
limit where that is lower than the machine's).

One place, read by the spec's limits (``flatcli.spec.limits``: what a sweep may plan to use),
by ``flatcli check`` (``flatcli.preflight``: what it warns of) and by the local executor (its
default number of workers), so that the three never disagree about the machine.
"""

from __future__ import annotations

import os

#: Where a container's CPU quota is written: cgroup v2 ("quota period"; "max period" sets none),
#: then cgroup v1's quota and period [us] (a quota of -1 sets none).
CGROUP_CPU_MAX = ("/sys/fs/cgroup/cpu.max",)
CGROUP_V1_CPU_QUOTA = ("/sys/fs/cgroup/cpu/cpu.cfs_quota_us",
                       "/sys/fs/cgroup/cpu/cpu.cfs_period_us")
#: Where a container's memory limit is written: cgroup v2, then cgroup v1 (a file that holds
#: "max", or is missing, sets no limit).
CGROUP_MEMORY_LIMITS = (
    "/sys/fs/cgroup/memory.max",
    "/sys/fs/cgroup/memory/memory.limit_in_bytes",
)


def _cgroup_fields(path: str) -> list[str] | None:
    """The whitespace-separated fields of a cgroup file, or None if it cannot be read."""
    try:
        with open(path) as fh:
            return fh.read().split()
    except OSError:
        return None


def cpu_quota() -> float | None:
    """A container's CPU quota in cores (``docker run --cpus``, a Kubernetes CPU limit), or
    None where none is set: cgroup v2's ``cpu.max`` ("quota period", or "max period"), then
    cgroup v1's ``cpu.cfs_quota_us`` over ``cpu.cfs_period_us`` (a quota of -1 sets none)."""
    for path in CGROUP_CPU_MAX:
        fields = _cgroup_fields(path)
        if fields is None:
            continue
        if len(fields) == 2 and fields[0].isdigit() and fields[1].isdigit() and int(fields[1]):
            return int(fields[0]) / int(fields[1])
        return None
    values = [_cgroup_fields(path) for path in CGROUP_V1_CPU_QUOTA]
    try:
        quota, period = (int(v[0]) if v and len(v) == 1 else 0 for v in values)
    except ValueError:
        return None
    return quota / period if quota > 0 and period > 0 else None


def cores() -> int:
    """Cores this process may use: its CPU affinity (``taskset``, a container's cpuset),
    fewer where a container's CPU quota is lower (``cpu_quota``, rounded down, at least 1:
    a worker per core of a quota of 1.5 cores would be throttled)."""
    try:
        available = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        available = os.cpu_count() or 1
    quota = cpu_quota()
    if quota is not None:
        available = min(available, max(1, int(quota)))
    return available


def physical_memory() -> float:
    """This machine's memory, or the container's limit if lower [bytes]."""
    total = float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    for path in CGROUP_MEMORY_LIMITS:
        fields = _cgroup_fields(path)
        if fields and len(fields) == 1 and fields[0].isdigit():
            total = min(total, float(fields[0]))
    return total
