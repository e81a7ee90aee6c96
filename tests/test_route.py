"""benchmarks/route.py: track.kp followed at run time from the command line to the kernel
(issue 38's Done-when: at most 12 files and 20 returns to a file already left)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchmarks import route


def test_returns_count_a_file_entered_again_after_leaving_it() -> None:
    assert route.returns(["a", "b", "a", "c", "b", "a"]) == 3
    assert route.returns(["a", "b", "c"]) == 0


def test_route_merges_a_files_consecutive_calls_and_ends_at_the_kernel() -> None:
    stays = [("cli.py", "track"), ("cli.py", "run_one"), ("api.py", "load"),
             ("core/loop/kernels.py", "shared"), ("api.py", "save"), ("outputs.py", "write")]
    assert route.route(stays) == [("cli.py", ["track", "run_one"]), ("api.py", ["load"]),
                                  ("core/loop/kernels.py", ["shared"])]


class Record:
    def __init__(self, inner: object) -> None:
        self.inner = inner


@pytest.mark.parametrize("value, depth, expected", [
    (route.MARK, 0, True), ((1.0, route.MARK), 0, True), (np.array([route.MARK]), 0, True),
    ("track.kp=[123.456,110]", 0, True), (Record(Record([route.MARK])), 0, True),
    (Record(Record(Record(route.MARK))), 0, False), (Record(route.MARK), 2, False),
    (123.4561, 0, False)])
def test_holds_looks_two_record_levels_down(value: object, depth: int, expected: bool) -> None:
    assert route.holds(value, depth) is expected


def test_the_papers_kp_reaches_the_kernel_through_few_files(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert route.main(["--out", str(tmp_path / "run")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[1] == "cli.py" and lines[-2].split()[1] == "core/loop/kernels.py"
    files, returns = (int(word) for word in lines[-1].split(": ")[1].split()[::2][:2])
    assert files <= 12 and returns <= 20, lines[-1]
