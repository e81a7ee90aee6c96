"""The progress of a running sweep."""

from __future__ import annotations

from pathlib import Path

import pytest

from flatcli.progress import Progress


def test_progress_prints_lines_off_a_terminal(tmp_path: Path) -> None:
    path = tmp_path / "log"
    with path.open("w") as stream:
        progress = Progress("x", stream=stream, interval=0.0)
        progress.start(10, 4, "local")
        progress.advance(6)
        progress.close()
    text = path.read_text()
    assert "10 trials on local, resuming with 4 done" in text
    assert "10/10 trials (100%)" in text


def test_quiet_progress_prints_nothing(tmp_path: Path) -> None:
    path = tmp_path / "log"
    with path.open("w") as stream:
        progress = Progress("x", quiet=True, stream=stream, interval=0.0)
        progress.start(10, 0, "local")
        progress.advance(10)
        progress.close()
    assert path.read_text() == ""


def test_the_cells_planning_is_shown_for_a_large_grid_only() -> None:
    import io

    from flatcli.progress import CELLS_SHOWN

    stream = io.StringIO()
    progress = Progress("s", stream=stream, interval=1e9)
    for done in range(CELLS_SHOWN + 1):
        progress.cells(done, CELLS_SHOWN)
    assert stream.getvalue() == ""
    for done in range(CELLS_SHOWN + 2):
        progress.cells(done, CELLS_SHOWN + 1)
    lines = stream.getvalue().splitlines()
    assert lines[0] == f"sweep 's': planning {CELLS_SHOWN + 1} grid cells"
    assert lines[1].startswith(f"  {CELLS_SHOWN + 1}/{CELLS_SHOWN + 1} cells planned (100%)")
    assert len(lines) == 2
    quiet = io.StringIO()
    Progress("s", quiet=True, stream=quiet).cells(0, 10**4)
    assert quiet.getvalue() == ""


def test_a_damaged_kernel_index_counts_as_not_cached(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """The compile notice is printed when the kernel's index cannot be read (numba compiles
    it again: flatcli/core/_jit.py), not only when it is missing. The kernels' cache is
    ``_jit.CACHE_DIRECTORY`` (numba.config.CACHE_DIR is no longer read)."""
    import pickle

    from flatcli.core import _jit
    from flatcli.progress import kernel_cached

    monkeypatch.setattr(_jit, "CACHE_DIRECTORY", tmp_path)
    index = tmp_path / "core" / "kernels.paper_kinematic_batch-532.py311.nbi"
    index.parent.mkdir()
    assert not kernel_cached()
    index.write_bytes(pickle.dumps("0.68.1") + pickle.dumps((1.0, {"key": "data"})))
    assert kernel_cached()
    index.write_bytes(bytes(range(7, 207)))
    assert not kernel_cached()
    index.write_bytes(b"")
    assert not kernel_cached()
