"""The progress of a running sweep."""

from __future__ import annotations

from pathlib import Path

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
