"""Runs as data (flatcli/catalog.py): `flatcli runs` with filters, order, JSON and a width that
fits, an N-way `--compare`, and `flatcli.runs()` as a DataFrame."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pandas as pd
import pytest
from run_tree import GOOD_PLAN, cli, make_tree

import flatcli
from flatcli.catalog import Filter, compare_runs, flat_spec, rows_below, runs_table, select
from flatcli.rundirs import link_latest, list_runs, stamp
from flatcli.spec import SpecError


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """make_tree's runs, and a dynamic-plant track run named "dyn" tagged nightly, and a
    tagged plan."""
    root = make_tree(tmp_path_factory.mktemp("runs"))
    code, out = cli("track", "--name", "dyn", "--tag", "nightly", "--tag", "dynamic", "-q",
                    "--set", "plant.model=dynamic", "--set", "track.kp=[100,110]",
                    "--set", "track.kv=[10,13]", "--set", "track.dt=0.004",
                    "--out", str(root / "dyn" / stamp()))
    assert code == 0, out
    code, out = cli("plan", "--tag", "baseline", "-q",
                    "--out", str(root / "paper_example" / stamp()))
    assert code == 0, out
    return root


def test_flat_spec_goes_into_tables() -> None:
    tree = {"name": "x", "track": {"kp": [1, 2]},
            "sweep": {"grid": {"plant.com": [[0, 0, 0]]}, "perturb": {"initial": {"std": 1}}}}
    assert flat_spec(tree) == {"name": "x", "track.kp": [1, 2],
                               'sweep.grid."plant.com"': [[0, 0, 0]],
                               "sweep.perturb.initial.std": 1}


def test_runs_lists_every_run_with_status_tags_and_key_metrics(tree: Path) -> None:
    infos = {str(i.path.relative_to(tree)): i for i in list_runs(tree)}
    plans = [i for i in infos.values() if i.command == "plan"]
    assert len(plans) == 3 and all(i.status == "ok" for i in plans)
    assert {round(i.metrics["input_energy"], 6) for i in plans} == {
        round(json.loads((i.path / "run.json").read_text())["summary"]["input_energy"], 6)
        for i in plans}
    tracks = [i for i in infos.values() if i.command == "track"]
    assert all(i.status == "ok" and i.metrics["err_y_final"] < 1e-2 for i in tracks)
    assert infos["small"].status == "done" and infos["small"].metrics["trials"] == 120
    assert infos["cut"].status == "partial 79%"  # 95 of 120 trials: one chunk of 25 lost
    assert infos["small"].outcome.startswith("reached ") and infos["small"].outcome.endswith(
        "/120")  # what the robot did, from the sweep's run.json (outcome_counts)
    assert all(i.outcome in ("reached", "collided", "missed", "lost") for i in tracks)
    code, out = cli("runs", str(tree))
    assert code == 0, out
    assert [c.strip() for c in out.splitlines()[0].split("|")[1:-1]] == [
        "run", "command", "name", "time", "status", "outcome", "tags", "key metrics"]
    assert "partial 79%" in out and "input_energy" in out and "err_y_final" in out
    assert "nightly, dynamic" in out
    assert runs_table(tree) == out.rstrip("\n")


def test_filters_select_runs_by_field_spec_key_metric_and_tag(tree: Path) -> None:
    rows = rows_below(tree)

    def names(*filters: str) -> list[str]:
        chosen = select(rows, [Filter.parse(f) for f in filters])
        return sorted(r.where.split("/")[0] for r in chosen)

    assert names("plant.model=dynamic") == ["dyn"]
    assert names("status=ok", "command=track") == ["dyn", "paper_example"]
    assert names("tag=nightly") == ["dyn"] and names("tag=baseline") == ["paper_example"]
    assert "dyn" not in names("tag!=nightly", "command=track")
    assert names("plan.duration>2.5") == ["paper_example"]  # the plan of T = 3 s
    assert names("track.kp=[100, 110]", "command=track") == ["dyn", "paper_example"]
    assert names("name~dy") == ["dyn"]
    assert names("err_y_final<1") == ["dyn", "paper_example"]  # plans have none: left out
    assert names("time>=2000-01-01", "command=sweep") == ["cut", "small"]
    assert names("status=done") == ["small"]
    ordered = select(rows, [Filter.parse("command=track")], sort="err_y_final")
    errors = [r.info.values["err_y_final"] for r in ordered]
    assert errors == sorted(errors)
    backwards = select(rows, [Filter.parse("command=track")], sort="err_y_final", reverse=True)
    assert [r.info.values["err_y_final"] for r in backwards] == sorted(errors, reverse=True)
    everything = select(rows, [], sort="err_y_final")  # runs without it come last
    assert all("err_y_final" not in r.info.values for r in everything[2:])


@pytest.mark.parametrize(("text", "message"), [
    ("status", "expected KEY OP VALUE"),
    ("status=", "expected KEY OP VALUE"),
    ("status<ok", "< compares numbers and times"),
    ("time>yesterday", "a time is an ISO date"),
])
def test_a_bad_filter_is_one_line(text: str, message: str) -> None:
    with pytest.raises(SpecError, match=message):
        Filter.parse(text)


def test_a_key_no_run_has_is_refused_with_a_close_match(tree: Path) -> None:
    with pytest.raises(SpecError, match=r"no run below has 'plant.mdel'.*'plant.model'"):
        select(rows_below(tree), [Filter.parse("plant.mdel=dynamic")])
    code, out = cli("runs", str(tree), "--filter", "plant.mdel=dynamic")
    assert code == 2 and out.startswith("error: ") and out.count("\n") == 1


def test_runs_json_holds_every_metric_and_the_spec(tree: Path) -> None:
    code, out = cli("runs", str(tree), "--filter", "status=ok", "--filter",
                    "plant.model=dynamic", "--sort", "err_y_final", "--json")
    assert code == 0, out
    (run,) = json.loads(out)
    assert run["name"] == "dyn" and run["tags"] == ["nightly", "dynamic"]
    assert run["spec"]["plant"]["model"] == "dynamic"
    assert run["metrics"]["peak_torque"] > 0 and "steps" in run["metrics"]
    recorded = json.loads((Path(run["path"]) / "metrics.json").read_text())
    # numbers and flags (verified), not words (status, reason)
    assert run["metrics"] == {k: v for k, v in recorded.items() if not isinstance(v, str)}
    assert run["metrics"]["verified"] is recorded["verified"]


def test_the_table_fits_the_terminal(tree: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    wide = runs_table(tree)
    assert max(len(line) for line in wide.splitlines()) > 100
    narrow = runs_table(tree, width=100)
    assert max(len(line) for line in narrow.splitlines()) <= 100
    assert "(+" in narrow  # how many key metrics were left out, said
    assert "left out; --json has all)" in narrow
    assert all(r.where.split("/")[-1][-6:] in narrow for r in rows_below(tree))  # each run
    monkeypatch.setenv("COLUMNS", "100")
    code, out = cli("runs", str(tree))
    assert code == 0 and max(len(line) for line in out.splitlines()) <= 100


def test_runs_returns_a_dataframe_one_row_per_run(tree: Path) -> None:
    frame = flatcli.runs(tree)
    assert isinstance(frame, pd.DataFrame) and len(frame) == len(list_runs(tree))
    assert list(frame.columns[:8]) == ["run", "path", "command", "name", "time", "status",
                                       "outcome", "tags"]
    assert {"err_y_final", "input_energy", "plant.model", "track.kp", "plan.duration"} <= \
        set(frame.columns)
    dynamic = frame[frame["plant.model"] == "dynamic"]  # a notebook's query
    assert dynamic["name"].tolist() == ["dyn"] and dynamic["tags"].iloc[0] == ["nightly",
                                                                                "dynamic"]
    assert pd.api.types.is_datetime64_any_dtype(frame["time"])
    plan_rows = frame[frame["command"] == "plan"]
    assert plan_rows["err_y_final"].isna().all()  # a plan has no tracking error
    assert math.isinf(frame["track.rate_limit"].dropna().iloc[0])  # "inf" read back as inf
    chosen = flatcli.runs(tree, filters=["command=track"], sort="err_y_final")
    assert chosen["err_y_final"].is_monotonic_increasing and len(chosen) == 2


def test_compare_shows_the_keys_that_differ_between_any_number_of_runs(tree: Path) -> None:
    plans = sorted((i.path for i in list_runs(tree) if i.command == "plan"),
                   key=lambda p: json.loads((p / "run.json").read_text())["spec"]["plan"][
                       "duration"])[1:]  # durations 2 and 3 s
    text = compare_runs(plans[0], plans[1])
    assert "1 spec key differs:" in text
    assert "| plan.duration |" in text
    rows = [line for line in text.splitlines() if line.startswith("| plan.")]
    assert len(rows) == 1
    (dyn,) = [i.path for i in list_runs(tree) if i.name == "dyn"]
    three = compare_runs(plans[0], plans[1], dyn)
    head = next(line for line in three.splitlines() if line.startswith("| key"))
    assert [c.strip() for c in head.strip("|").split("|")] == ["key", "A", "B", "C"]
    assert re.search(r"\| plant\.model +\| ", three) and "C = " in three
    code, out = cli("runs", "--compare", str(plans[0]), str(plans[0]))
    assert code == 0 and "the specs are identical" in out
    code, out = cli("runs", "--compare", str(plans[0]), str(tree / "nowhere"))
    assert code == 2 and out.startswith("error: --compare:") and out.count("\n") == 1
    link_latest(dyn)  # as a run without --out leaves it
    code, out = cli("runs", "--compare", str(tree / "dyn"), str(plans[0]))  # its latest
    assert code == 0 and f"A = {tree / 'dyn'} (track 'dyn')" in out, out


def test_text_from_a_record_is_shown_escaped(tmp_path: Path) -> None:
    # a hostile record: an escape sequence that would clear the terminal, a bidi override
    for name, record in (("a", {**GOOD_PLAN, "spec": {"name": "x\x1b[2Jy\u202e"}}),
                         ("b", {**GOOD_PLAN, "spec": {"name": "z", "k\u2028": "v\x85"}})):
        (tmp_path / name).mkdir()
        (tmp_path / name / "run.json").write_text(json.dumps(record))
    text = runs_table(tmp_path)
    assert "\x1b" not in text and "\u202e" not in text and r"x\x1b[2Jy\u202e" in text
    compared = compare_runs(tmp_path / "a", tmp_path / "b")
    assert compared.isprintable() or all(c.isprintable() or c == "\n" for c in compared)
    assert r"k\u2028" in compared and r"v\x85" in compared
    code, out = cli("runs", "--compare", str(tmp_path / "a"), str(tmp_path / "b"))
    assert code == 0 and "\x1b" not in out
