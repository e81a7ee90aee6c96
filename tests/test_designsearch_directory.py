"""A search's directory (flatcli/designsearch/directory.py): its identity, its journal (a
torn line dropped and cut off), and what a run may do where."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest
from small_search import SPEC

from flatcli.designsearch.directory import (
    JOURNAL,
    RECORD,
    Journal,
    design_key,
    identity,
    open_directory,
    write_record,
)
from flatcli.designsearch.evaluate import Evaluation
from flatcli.spec import SpecError, resolve
from flatcli.storage import run_record

EVALUATION = Evaluation("evaluated", "", 24, 20, 0, 3, 1, 0.6, 0.9, 1e-4, 10.0, -0.6)


def spec_with(**search: object) -> object:
    tree = tomllib.loads(SPEC)
    tree["search"].update(search)
    return resolve(tree)


def test_only_the_stopping_rules_and_the_name_leave_the_identity() -> None:
    base = identity(spec_with())
    same = [spec_with(candidates=500), spec_with(seconds=30.0), spec_with(tol=0.0),
            resolve({**tomllib.loads(SPEC), "name": "other",
                     "figures": {"format": "pdf"}})]
    assert all(identity(s) == base for s in same)
    other = [spec_with(seed=1), spec_with(population=9), spec_with(max_mass=3.0),
             spec_with(vary={"robot.mass[1]": [0.5, 1.0]}),
             resolve({**tomllib.loads(SPEC), "sweep": {"trials": 25, "seed": 5}})]
    assert all(identity(s) != base for s in other)


def test_a_design_key_is_exact() -> None:
    assert design_key([0.1, 1 / 3]) != design_key([0.1, 1 / 3 + 1e-17 * 3])
    assert design_key([0.1]) == (0.1).hex()


def test_the_journal_keeps_what_was_flushed_and_drops_a_torn_line(tmp_path: Path) -> None:
    path = tmp_path / JOURNAL
    journal = Journal(path)
    journal.add_candidate("a", EVALUATION)
    journal.add_generation(1, 2.5)
    journal.add_candidate("b", EVALUATION)
    good = path.read_bytes()
    path.write_bytes(good + b'{"kind": "candidate", "key": "c", "evalu')  # killed mid-write
    back = Journal.read(path)
    assert set(back.evaluations) == {"a", "b"} and back.generations == {1: 2.5}
    assert back.evaluations["a"] == EVALUATION and back.dropped == 1
    assert path.read_bytes() == good  # cut off before anything is appended
    back.add_candidate("c", EVALUATION)
    assert set(Journal.read(path).evaluations) == {"a", "b", "c"}


def test_a_damaged_line_ends_what_is_read(tmp_path: Path) -> None:
    path = tmp_path / JOURNAL
    journal = Journal(path)
    journal.add_candidate("a", EVALUATION)
    first = path.read_bytes()
    path.write_bytes(first + b'{"kind": "nonsense"}\n')
    journal2 = Journal.read(path)
    assert set(journal2.evaluations) == {"a"} and path.read_bytes() == first


def test_not_a_number_survives_the_journal(tmp_path: Path) -> None:
    journal = Journal(tmp_path / JOURNAL)
    odd = Evaluation("error", "no plan", 0, 0, 0, 0, 0, math.nan, math.nan, math.inf,
                     math.nan, 0.0)
    journal.add_candidate("x", odd)
    back = Journal.read(tmp_path / JOURNAL).evaluations["x"]
    assert back.reason == "no plan" and math.isnan(back.reached_low)
    assert math.isinf(back.quantile)


def test_what_a_run_may_do_in_a_directory(tmp_path: Path) -> None:
    spec = spec_with()
    assert open_directory(tmp_path / "new", spec, False).mode == "fresh"
    here = tmp_path / "search"
    here.mkdir()
    write_record(here, run_record("search", {}, identity=identity(spec)))
    Journal(here / JOURNAL).add_candidate("a", EVALUATION)
    (here / "mine.txt").write_text("a user's notes")
    opened = open_directory(here, spec_with(candidates=99), False)
    assert opened.mode == "resume" and set(opened.journal.evaluations) == {"a"}
    with pytest.raises(SpecError, match=r"holds a search of a different spec or \[search\]"):
        open_directory(here, spec_with(seed=3), False)
    assert open_directory(here, spec_with(seed=3), True).mode == "restart"
    assert not (here / RECORD).exists() and not (here / JOURNAL).exists()
    assert (here / "mine.txt").read_text() == "a user's notes"  # not flatcli's: kept


def test_files_of_ours_without_a_record_are_not_taken(tmp_path: Path) -> None:
    (tmp_path / "search.parquet").write_text("something else")
    with pytest.raises(SpecError, match=r"holds search\.parquet but no search\.json"):
        open_directory(tmp_path, spec_with(), False)
    (tmp_path / RECORD).write_text('{"command": "sweep"}')
    with pytest.raises(SpecError, match=r"not a search record"):
        open_directory(tmp_path, spec_with(), False)
