"""The machine's facts (flatcli/machine.py), read the same by the spec's limits, flatcli check
and the executors. Referees: util-linux's taskset (a CPU affinity set from outside) and the
kernel's /proc/meminfo (MemTotal)."""

from __future__ import annotations

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
