"""Starting under a memory limit (flatcli/startup.py): a library that cannot be loaded ends
the command in one line, exit status 1, within bounded time."""

from __future__ import annotations

import importlib
import re
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from flatcli.startup import library_error_text, probe_libraries, while_importing


def test_the_first_failure_and_the_limit_are_named(monkeypatch: pytest.MonkeyPatch) -> None:
    try:
        try:
            raise ImportError("libopenblas.so: failed to map segment from shared object")
        except ImportError as inner:
            raise ImportError("Unable to import required dependency numpy. Please see the "
                              "traceback for details.") from inner
    except ImportError as outer:
        error = outer
    monkeypatch.setattr(resource, "getrlimit", lambda which: (50 * 2**20, 50 * 2**20))
    assert library_error_text(error) == (
        "cannot load the numerical libraries (ImportError: libopenblas.so: failed to map "
        "segment from shared object); this process may use at most 50 MiB of address space "
        "(ulimit -v): raise that limit")
    monkeypatch.setattr(resource, "getrlimit",
                        lambda which: (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
    assert library_error_text(MemoryError()).endswith(
        "(MemoryError); out of memory, or a broken installation")


def test_an_error_while_importing_is_told_from_a_commands_own(tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch
                                                              ) -> None:
    (tmp_path / "broken_module_for_flatcli.py").write_text("raise MemoryError\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(MemoryError) as caught:
        importlib.import_module("broken_module_for_flatcli")
    assert while_importing(caught.value)
    try:
        raise MemoryError
    except MemoryError as own:
        assert not while_importing(own)
    assert while_importing(OSError("Could not find/load shared object file 'libllvmlite.so'"))


def test_nothing_is_probed_without_a_limit_or_once_loaded() -> None:
    assert "numpy" in sys.modules  # the test process: loaded, nothing to probe
    assert probe_libraries() is None


def test_too_little_memory_to_load_the_libraries_is_one_line(tmp_path: Path) -> None:
    # the address space a Python that has loaded flatcli's command line (but no numerics)
    # uses, plus a little: numpy cannot load within it, on any machine
    probe = subprocess.run(
        [sys.executable, "-c", "import flatcli.cli, re; print(re.search(r'VmPeak:\\s+(\\d+)', "
         "open('/proc/self/status').read()).group(1))"],
        capture_output=True, text=True, check=True)
    limit = (int(probe.stdout) + 24 * 1024) * 1024

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    done = subprocess.run([sys.executable, "-m", "flatcli", "plan", "--out",
                           str(tmp_path / "p"), "-q"], capture_output=True, text=True,
                          preexec_fn=limited, timeout=120)
    assert done.returncode == 1, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert re.fullmatch(r"error: cannot load the numerical libraries \(.+\); this process may "
                        rf"use at most {limit / 2**20:.0f} MiB of address space \(ulimit -v\): "
                        r"raise that limit\n", done.stderr), done.stderr
    assert not (tmp_path / "p").exists()
