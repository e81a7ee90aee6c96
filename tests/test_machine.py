"""The machine's facts (flatcli/machine.py), read the same by the spec's limits, flatcli check
and the executors. Referees: util-linux's taskset (a CPU affinity set from outside) and the
kernel's /proc/meminfo (MemTotal)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from flatcli import machine, preflight
from flatcli.executors import default_workers
from flatcli.spec import limits


@pytest.mark.skipif(shutil.which("taskset") is None, reason="util-linux's taskset is missing")
def test_cores_are_the_affinity_a_process_is_given() -> None:
    code = ("from flatcli.machine import cores; from flatcli.executors import default_workers; "
            "print(cores(), default_workers())")
    out = subprocess.run(["taskset", "-c", "0", sys.executable, "-c", code],
                         capture_output=True, text=True, check=True).stdout.split()
    assert out == ["1", "1"]
    assert default_workers() == machine.cores() >= 1


def _mem_total() -> float:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return float(line.split()[1]) * 1024.0
    raise AssertionError("no MemTotal in /proc/meminfo")


@pytest.mark.skipif(not Path("/proc/meminfo").exists(), reason="Linux only")
def test_memory_is_the_machines_unless_a_container_limits_it_lower(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    unlimited = tmp_path / "memory.max"
    unlimited.write_text("max\n")
    monkeypatch.setattr(machine, "CGROUP_MEMORY_LIMITS", (str(unlimited),))
    assert machine.physical_memory() == _mem_total()

    limit = tmp_path / "memory.limit_in_bytes"
    limit.write_text(f"{2**30}\n")
    monkeypatch.setattr(machine, "CGROUP_MEMORY_LIMITS", (str(tmp_path / "missing"), str(limit)))
    assert machine.physical_memory() == 2.0**30
    # what a sweep may plan to use and what flatcli check warns against: the same limit
    monkeypatch.delenv("FLATCLI_MEMORY_BUDGET", raising=False)
    assert limits.memory_budget() == limits.MEMORY_FRACTION * 2.0**30
    assert preflight._physical_mib() == 1024.0

    limit.write_text(f"{int(_mem_total()) * 4}\n")  # a limit above the machine's memory
    assert machine.physical_memory() == _mem_total()


@pytest.mark.parametrize(("v2", "v1", "expected"), [
    (None, None, None),  # no cgroup files: no quota
    ("max 100000\n", None, None),  # v2 without a quota
    ("150000 100000\n", None, 1.5),  # docker run --cpus=1.5
    ("50000 100000\n", None, 0.5),
    (None, ("-1", "100000"), None),  # v1 without a quota
    (None, ("200000", "100000"), 2.0),
    (None, ("garbage", "100000"), None),
])
def test_a_containers_cpu_quota_caps_the_cores(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, v2: str | None,
        v1: tuple[str, str] | None, expected: float | None) -> None:
    """The quota as the kernel writes it (cgroup v2's cpu.max, v1's cfs quota and period:
    the kernel's Documentation/admin-guide/cgroup-v2.rst and scheduler/sched-bwc.rst), and
    the cores it leaves: min(affinity, floor(quota)), at least 1."""
    cpu_max = tmp_path / "cpu.max"
    quota, period = tmp_path / "cpu.cfs_quota_us", tmp_path / "cpu.cfs_period_us"
    if v2 is not None:
        cpu_max.write_text(v2)
    if v1 is not None:
        quota.write_text(v1[0] + "\n")
        period.write_text(v1[1] + "\n")
    monkeypatch.setattr(machine, "CGROUP_CPU_MAX", (str(cpu_max),))
    monkeypatch.setattr(machine, "CGROUP_V1_CPU_QUOTA", (str(quota), str(period)))
    assert machine.cpu_quota() == expected
    affinity = len(os.sched_getaffinity(0))
    cap = affinity if expected is None else min(affinity, max(1, int(expected)))
    assert machine.cores() == cap
    assert default_workers() == cap
