"""Run directories (flatcli/rundirs.py): where runs go, what a run directory holds, records
that are not trusted, and interrupted sweeps."""

from __future__ import annotations

import json
import os
from datetime import datetime
from pathlib import Path

import pytest
from click.testing import CliRunner
from run_tree import GOOD_PLAN, make_tree

from flatcli.cli import main
from flatcli.rundirs import (
    LATEST,
    RunDirectoryError,
    claim,
    link_latest,
    list_runs,
    stamp,
    sweep_state,
)


def cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.output


def test_stamp_sorts_by_time_and_is_unique() -> None:
    early = stamp(datetime(2024, 1, 2, 3, 4, 5))
    late = stamp(datetime(2024, 1, 2, 3, 4, 6))
    assert early.startswith("20240102-030405-") and len(early) == 22
    assert early < late
    assert len({stamp(datetime(2024, 1, 2, 3, 4, 5)) for _ in range(50)}) == 50


def test_claim_without_out_is_a_new_directory_under_root(tmp_path: Path) -> None:
    target = claim(None, "plan", "demo", "abc", root=tmp_path)
    assert target.fresh and target.path.parent == tmp_path / "demo"
    assert not target.path.exists()  # created only when the run is saved
    directory = target.open()
    target.finish(directory)
    assert directory == target.path
    assert (tmp_path / "demo" / LATEST).resolve() == directory.resolve()
    again = target.open()  # a fresh directory is never reused: another stamp
    assert again != directory and again.parent == directory.parent


def test_claim_of_out_refuses_another_run(tmp_path: Path) -> None:
    out = tmp_path / "o"
    assert not claim(out, "plan", "x", "d1").fresh  # empty or missing: fine
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"command": "plan", "digest": "d1"}))
    claim(out, "plan", "x", "d1")  # the same run again: fine
    with pytest.raises(RunDirectoryError, match="holds a plan run;"):
        claim(out, "track", "x", "d1")
    with pytest.raises(RunDirectoryError, match="holds a plan run of a different spec"):
        claim(out, "plan", "x", "d2")
    (out / "plan.parquet").write_text("old")
    (out / "notes.txt").write_text("mine")
    target = claim(out, "track", "x", "d1", force=True)
    target.open()  # --force removes the run's own files, nothing else
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    (out / "sweep.json").write_text("{}")
    for force in (False, True):
        with pytest.raises(RunDirectoryError, match="holds a sweep"):
            claim(out, "plan", "x", "d1", force=force)
    (tmp_path / "f").write_text("")
    with pytest.raises(RunDirectoryError, match="is a file"):
        claim(tmp_path / "f", "plan", "x", "d1")


def test_latest_link_is_replaced_and_a_real_directory_is_left_alone(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    link_latest(a)
    link_latest(b)
    assert (tmp_path / LATEST).is_symlink() and (tmp_path / LATEST).resolve() == b.resolve()
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []
    other = tmp_path / "elsewhere"
    other.mkdir()
    (other / LATEST).mkdir()
    (other / "c").mkdir()
    link_latest(other / "c")
    assert (other / LATEST).is_dir() and not (other / LATEST).is_symlink()


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """runs/: two plans and a track of one name, a finished and an interrupted sweep."""
    return make_tree(tmp_path_factory.mktemp("runs"))


def test_sweep_state_of_an_interrupted_sweep(tree: Path) -> None:
    state = sweep_state(tree / "cut")
    assert state is not None and not state.complete
    # 2 cells of 60 trials in chunks of 25, 25 and 10 (tests/small_sweep.py); one chunk lost
    assert (state.total, state.done, state.chunks_total, len(state.chunk_files)) == \
        (120, 95, 6, 5)
    finished = sweep_state(tree / "small")
    assert finished is not None and finished.complete and finished.done == 120
    # a finished sweep holds its chunks in trials.parquet alone
    assert (len(finished.chunk_files), len(finished.stored)) == (0, 6)
    assert sweep_state(tree) is None


def test_an_extension_cut_short_counts_what_trials_parquet_holds(tmp_path: Path) -> None:
    """A finished study extended by a grid value and killed before its final tables: its
    old cells are in trials.parquet, the new one's chunks in files; the partial trials are
    both, in the grid's order (the referee: the finished study's own table)."""
    import pandas as pd
    from small_sweep import SPEC, sweep_without_final_tables, write_spec

    from flatcli import load

    spec = write_spec(tmp_path)
    out = tmp_path / "d"
    assert cli("sweep", str(spec), "--out", str(out), "-q", "--workers", "1")[0] == 0
    before = pd.read_parquet(out / "trials.parquet")
    three = write_spec(tmp_path, SPEC.replace('[0.0, 0.001]', '[0.0, 0.001, 0.002]'), "3.toml")
    sweep_without_final_tables(str(three), "--out", str(out), "-q", "--workers", "1")
    state = sweep_state(out)
    assert state is not None and not state.complete
    assert (state.total, state.done, len(state.chunk_files), len(state.stored)) == \
        (180, 180, 3, 6)
    partial = load(out).trials
    pd.testing.assert_frame_equal(partial.iloc[:120].reset_index(drop=True), before,
                                  check_exact=True)
    assert partial["cell"].tolist() == [0] * 60 + [1] * 60 + [2] * 60


def test_summarize_a_partial_sweep_says_what_is_missing(tree: Path) -> None:
    code, out = cli("summarize", str(tree / "cut"))
    assert code == 0, out
    assert out.startswith("partial sweep: 95 of 120 trials finished (79%)")
    assert "the finished trials: 2 cells, 95 trials" in out and "full tables:" in out
    code, out = cli("summarize", str(tree / "cut"), "--full")
    assert out.startswith("partial sweep: 95 of 120 trials finished (79%)")
    assert "cells not finished: 0 (of 0-1)" in out and "### Trials by status" in out
    code, out = cli("summarize", str(tree / "cut"), "--plot")
    assert code == 2 and out.startswith("error: --plot: partial sweep") and \
        out.count("\n") == 1
    assert not list((tree / "cut").glob("*.png"))
    code, out = cli("summarize", str(tree / "small"), "--full")
    assert code == 0 and out == (tree / "small" / "summary.md").read_text()


def test_a_run_json_without_a_digest_is_compared_by_its_spec(tmp_path: Path) -> None:
    from flatcli.spec import resolve
    from flatcli.storage import to_jsonable

    spec = resolve({"plan": {"optimize": {"rate_limit": 5.0}}})  # with inf among its values
    out = tmp_path / "o"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"command": "plan",
                                              "spec": to_jsonable(spec.tree)}, indent=2))
    claim(out, "plan", spec.name, spec.digest())  # the same spec: its files may be rewritten
    other = spec.with_overrides({"plan.duration": 3.0})
    with pytest.raises(RunDirectoryError, match="of a different spec"):
        claim(out, "plan", other.name, other.digest())


# ---------------------------------------------------------------------------------------
# Records flatcli did not write (or that were changed) are never trusted.

@pytest.mark.parametrize(("key", "value"), [
    ("time", 123), ("time", "9999-12-31T23:59:59-23:59"), ("time", "0001-01-01T00:00:00"),
    ("time", "yesterday"), ("time", []),
    ("summary", [1, 2]), ("summary", "x"), ("summary", {"input_energy": "lots"}),
    ("summary", {"input_energy": True}), ("spec", [1]), ("spec", 5), ("optimization", [1]),
    ("optimization", 3), ("command", 7), ("command", None), ("status_counts", {"ok": "x"}),
    ("status_counts", []), ("metrics", {"err_y_final": {}}), ("metrics", [1]),
    ("seconds", "1"), ("digest", 5),
])
def test_a_run_record_of_other_types_is_listed_as_unreadable(tmp_path: Path, key: str,
                                                             value: object) -> None:
    run = tmp_path / "r"
    run.mkdir()
    record = {**GOOD_PLAN, key: value}
    if key == "metrics":  # what a track run's record holds
        record["command"] = "track"
    (run / "run.json").write_text(json.dumps(record))
    (info,) = list_runs(tmp_path)
    assert info.status == "unreadable" and info.metrics == {}
    code, out = cli("runs", str(tmp_path))
    assert code == 0 and "unreadable" in out, out


def test_a_good_record_beside_is_listed_as_it_was(tmp_path: Path) -> None:
    (tmp_path / "run.json").write_text(json.dumps(GOOD_PLAN))
    (info,) = list_runs(tmp_path)
    assert info.status == "ok" and info.metrics["input_energy"] == 1.5
    assert info.time is not None and info.time.year == 2026


@pytest.mark.timeout(30, method="thread")  # a FIFO opened blindly would block flatcli runs forever
def test_a_record_that_is_not_a_regular_file_or_too_large_is_listed_unread(
        tmp_path: Path) -> None:
    from flatcli.files import MAX_RECORD_BYTES

    for name in ("fifo", "dir", "big", "link", "deep", "text"):
        (tmp_path / name).mkdir()
    os.mkfifo(tmp_path / "fifo" / "run.json")
    (tmp_path / "dir" / "run.json").mkdir()
    with (tmp_path / "big" / "run.json").open("wb") as fh:
        fh.truncate(MAX_RECORD_BYTES + 1)  # sparse: a whole read would take 8 MiB for nothing
    (tmp_path / "link" / "run.json").symlink_to("/dev/zero")
    (tmp_path / "deep" / "run.json").write_text("[" * 100_000)
    (tmp_path / "text" / "run.json").write_bytes(b"\xff\xfe not json")
    os.mkfifo(tmp_path / "fifo" / "sweep.json")
    infos = {i.path.name: i for i in list_runs(tmp_path)}
    assert set(infos) == {"fifo", "big", "link", "deep", "text"}  # dir/run.json: no file
    assert {i.status for i in infos.values()} == {"unreadable"}
    assert infos["fifo"].command == "sweep"
    code, out = cli("runs", str(tmp_path))
    assert code == 0 and out.count("unreadable") == 5, out


@pytest.mark.timeout(30, method="thread")
@pytest.mark.parametrize("what", ["fifo", "dir", "link"])
def test_out_holding_something_else_where_a_run_writes_is_refused(tmp_path: Path,
                                                                  what: str) -> None:
    out = tmp_path / "o"
    out.mkdir()
    victim = tmp_path / "victim.json"
    victim.write_text("precious")
    path = out / "run.json"
    if what == "fifo":
        os.mkfifo(path)
    elif what == "dir":
        path.mkdir()
    else:
        path.symlink_to(victim)
    for force in (False, True):
        with pytest.raises(RunDirectoryError, match=r"holds run\.json \(a .*\) where a run "
                                                    "writes its files; remove it yourself"):
            claim(out, "plan", "x", "d1", force=force)
    code, output = cli("plan", "--out", str(out), "--force")
    assert code == 2 and output.count("\n") == 1 and "run.json (a" in output, output
    assert os.path.lexists(path) and victim.read_text() == "precious"
    assert sorted(p.name for p in out.iterdir()) == ["run.json"]  # nothing written


def test_a_run_record_in_place_of_a_sweep_manifest_is_not_a_sweep(tmp_path: Path) -> None:
    (tmp_path / "sweep.json").write_text(json.dumps({"digest": "d", "spec": {},
                                                     "files": ["../../etc/passwd"]}))
    assert sweep_state(tmp_path) is None
    (info,) = list_runs(tmp_path)
    assert info.command == "sweep" and info.status == "unreadable"




def test_latest_is_relative_so_a_moved_tree_still_resolves(tmp_path: Path) -> None:
    """runs/<name>/latest names its run by its directory's name alone: copy or move runs/
    elsewhere and latest still points into it."""
    run = tmp_path / "runs" / "demo" / "20240102-030405-abcdef"
    run.mkdir(parents=True)
    link_latest(run)
    assert os.readlink(tmp_path / "runs" / "demo" / LATEST) == run.name
    (tmp_path / "runs").rename(tmp_path / "moved")
    assert (tmp_path / "moved" / "demo" / LATEST).resolve() == (
        tmp_path / "moved" / "demo" / run.name).resolve()


def test_a_fresh_target_never_writes_into_a_directory_that_exists(tmp_path: Path) -> None:
    """Two runs that drew the same stamp: the second gets another directory (made with
    exist_ok=False), never the first one's."""
    from flatcli.rundirs import Target

    taken = tmp_path / "demo" / "20240102-030405-abcdef"
    taken.mkdir(parents=True)
    (taken / "run.json").write_text("{}")
    made = Target(taken, fresh=True).open()
    assert made != taken and made.parent == taken.parent and list(made.iterdir()) == []


def test_the_missing_trials_of_a_partial_sweep_are_counted(tree: Path) -> None:
    state = sweep_state(tree / "cut")
    assert state is not None
    assert state.missing_text() == ("partial sweep: 95 of 120 trials finished (79%), 5 of 6 "
                                    "chunks; 25 trials missing")


def test_a_sweep_an_older_flatcli_started_in_the_names_directory_resumes_there(
        tmp_path: Path) -> None:
    from flatcli.rundirs import SWEEP_DIR, sweep_directory

    assert sweep_directory("demo", tmp_path) == tmp_path / "demo" / SWEEP_DIR
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "sweep.json").write_text("{}")
    assert sweep_directory("demo", tmp_path) == tmp_path / "demo"


def test_tags_are_kept_once_each_and_bounded() -> None:
    from flatcli.rundirs import MAX_TAGS, check_tags
    from flatcli.spec import SpecError

    assert check_tags(["a", "b", "a"]) == ["a", "b"]
    assert len(check_tags([f"t{i}" for i in range(MAX_TAGS)])) == MAX_TAGS
    with pytest.raises(SpecError, match=f"at most {MAX_TAGS} tags, got {MAX_TAGS + 1}"):
        check_tags([f"t{i}" for i in range(MAX_TAGS + 1)])


def test_a_record_that_is_json_but_not_an_object_is_unreadable(tmp_path: Path) -> None:
    from flatcli.rundirs import read_json

    (tmp_path / "run.json").write_text("[1, 2]")
    assert read_json(tmp_path / "run.json") is None
    (tmp_path / "run.json").write_text('{"command": "plan"}')
    assert read_json(tmp_path / "run.json") == {"command": "plan"}
    (tmp_path / "run.json").write_text("[")
    with pytest.raises(RunDirectoryError, match=r"its run\.json is unreadable"):
        claim(tmp_path, "plan", "x", "d")
