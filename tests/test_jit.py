"""The compiled-code cache (flatcli/core/_jit.py): keyed by the core's source hash in every
configuration, never in the package's own directory."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from flatcli.core import _jit

PACKAGE = Path(_jit.__file__).resolve().parents[1]


def test_the_source_hash_changes_with_any_file_of_the_core(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    copy = tmp_path / "core"
    shutil.copytree(Path(_jit.__file__).parent, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(_jit, "_CORE_DIR", copy)
    before = _jit.core_source_hash()
    assert before == _jit.core_source_hash()
    metrics = copy / "metrics.py"  # a module the kernel inlines, not the kernel's own file
    metrics.write_text(metrics.read_text() + "\n# an edit\n")
    assert _jit.core_source_hash() != before


def test_a_users_numba_cache_dir_gets_a_hash_subdirectory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert _jit.cache_dir("abc123") == tmp_path / "mine" / "flatcli-abc123"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _jit.cache_dir("abc123") == tmp_path / "xdg" / "flatcli" / "numba" / "abc123"


def test_an_unwritable_cache_falls_back_to_a_temporary_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")  # no directory can be made under a regular file
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocker / "cache"))
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(_jit.tempfile, "tempdir", None)  # read TMPDIR again
    found = _jit.cache_dir("abc123")
    assert found is not None and found.parent.parent == tmp_path / "tmp"
    assert found.name == "abc123"
    # nothing writable at all: no disk cache
    monkeypatch.setattr(_jit.tempfile, "gettempdir", lambda: str(blocker))
    assert _jit.cache_dir("abc123") is None
    for candidate in _jit.cache_candidates("abc123"):
        assert PACKAGE not in candidate.parents


def test_numba_uses_the_hash_keyed_directory_in_a_fresh_process(tmp_path: Path) -> None:
    code = ("import numba, flatcli.core.simulate as s, flatcli.core._jit as j; "
            "print(numba.config.CACHE_DIR, j.CACHING, j.core_source_hash())")
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "n")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=300, check=True).stdout.split()
    assert out[1] == "True"
    assert out[0] == str(tmp_path / "n" / f"flatcli-{out[2]}")
