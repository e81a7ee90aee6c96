"""Run directories (flatcli/runs.py): where runs go, `flatcli runs`, `--compare`, and
interrupted sweeps."""

from __future__ import annotations

import json
import shutil
from datetime import datetime
from pathlib import Path

import pytest
from click.testing import CliRunner
from small_sweep import write_spec

from flatcli.cli import main
from flatcli.runs import (
    LATEST,
    RunDirectoryError,
    claim,
    compare_runs,
    flat_spec,
    link_latest,
    list_runs,
    runs_table,
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


def test_flat_spec_goes_into_tables() -> None:
    tree = {"name": "x", "track": {"kp": [1, 2]},
            "sweep": {"grid": {"plant.com": [[0, 0, 0]]}, "perturb": {"initial": {"std": 1}}}}
    assert flat_spec(tree) == {"name": "x", "track.kp": [1, 2],
                               'sweep.grid."plant.com"': [[0, 0, 0]],
                               "sweep.perturb.initial.std": 1}


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """runs/: two plans and a track of one name, a finished and an interrupted sweep."""
    root = tmp_path_factory.mktemp("runs")
    for args in (["plan"], ["plan", "--set", "plan.duration=3"],
                 ["track", "--set", "track.kp=[100,110]", "--set", "track.kv=[10,13]"]):
        code, out = cli(*args, "-q", "--out", str(root / "paper_example" / stamp()))
        assert code == 0, out
    spec = write_spec(root.parent / "specs")
    code, out = cli("sweep", str(spec), "--out", str(root / "small"), "-q", "--workers", "1")
    assert code == 0, out
    shutil.copytree(root / "small", root / "cut")
    for name in ("trials.parquet", "summary.parquet", "summary.md", "run.json"):
        (root / "cut" / name).unlink()
    manifest = json.loads((root / "cut" / "sweep.json").read_text())
    first = manifest["cells"][manifest["grid_cells"][0]]["chunks"][0]  # cell 0's first chunk
    (root / "cut" / "trials" / first).unlink()
    return root


def test_runs_lists_every_run_with_status_and_key_metrics(tree: Path) -> None:
    infos = {str(i.path.relative_to(tree)): i for i in list_runs(tree)}
    plans = [i for i in infos.values() if i.command == "plan"]
    assert len(plans) == 2 and all(i.status == "ok" for i in plans)
    assert {round(i.metrics["input_energy"], 6) for i in plans} == {
        round(json.loads((i.path / "run.json").read_text())["summary"]["input_energy"], 6)
        for i in plans}
    (track,) = [i for i in infos.values() if i.command == "track"]
    assert track.status == "ok" and track.metrics["err_y_final"] < 1e-4
    assert infos["small"].status == "done" and infos["small"].metrics["trials"] == 120
    assert infos["cut"].status == "partial 79%"  # 95 of 120 trials: one chunk of 25 lost
    code, out = cli("runs", str(tree))
    assert code == 0, out
    assert [c.strip() for c in out.splitlines()[0].split("|")[1:-1]] == [
        "run", "command", "name", "time", "status", "key metrics"]
    assert "partial 79%" in out and "input_energy" in out and "err_y_final" in out
    assert runs_table(tree) == out.rstrip("\n")


def test_compare_shows_the_keys_that_differ(tree: Path) -> None:
    plans = sorted(i.path for i in list_runs(tree) if i.command == "plan")
    text = compare_runs(plans[0], plans[1])
    assert "1 spec key differs:" in text
    assert "| plan.duration |" in text
    rows = [line for line in text.splitlines() if line.startswith("| plan.")]
    assert len(rows) == 1
    code, out = cli("runs", "--compare", str(plans[0]), str(plans[0]))
    assert code == 0 and "the specs are identical" in out
    code, out = cli("runs", "--compare", str(plans[0]), str(tree / "nowhere"))
    assert code == 2 and out.startswith("error: --compare:") and out.count("\n") == 1


def test_sweep_state_of_an_interrupted_sweep(tree: Path) -> None:
    state = sweep_state(tree / "cut")
    assert state is not None and not state.complete
    # 2 cells of 60 trials in chunks of 25, 25 and 10 (tests/small_sweep.py); one chunk lost
    assert (state.total, state.done, state.chunks_total, len(state.chunk_files)) == \
        (120, 95, 6, 5)
    finished = sweep_state(tree / "small")
    assert finished is not None and finished.complete and finished.done == 120
    assert sweep_state(tree) is None


def test_summarize_a_partial_sweep_says_what_is_missing(tree: Path) -> None:
    code, out = cli("summarize", str(tree / "cut"))
    assert code == 0, out
    assert out.startswith("partial sweep: 95 of 120 trials finished (79%)")
    assert "cells not finished: 0 (of 0-1)" in out and "### Trials by status" in out
    code, out = cli("summarize", str(tree / "cut"), "--plot")
    assert code == 2 and out.startswith("error: --plot: partial sweep") and \
        out.count("\n") == 1
    assert not list((tree / "cut").glob("*.png"))
    code, out = cli("summarize", str(tree / "small"))
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
