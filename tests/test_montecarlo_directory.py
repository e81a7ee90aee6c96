"""A sweep's directory (flatcli/montecarlo/directory.py): the manifest, verified chunks, what a
resume keeps, what --force may remove, and the refusals."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from scipy.stats import binomtest

from flatcli.files import MAX_MANIFEST_BYTES
from flatcli.montecarlo import MANIFEST, TRIALS_DIR, layout, recorded_digest, run_chunk, run_sweep
from flatcli.montecarlo.directory import (
    FINAL_FILES,
    RERUN_FILES,
    Previous,
    TrialsAssembly,
    chunk_problem,
    chunk_provenance,
    clear,
    foreign_entries,
    manifest_problem,
    plan_directory,
    record_outputs,
    remove_temporaries,
    spec_differences,
    survey,
    verified_chunks,
    write_manifest,
)
from flatcli.montecarlo.layout import Layout
from flatcli.report.summary import SUMMARY_INPUTS
from flatcli.rundirs import sweep_state
from flatcli.spec import Spec, SpecError, resolve
from flatcli.storage import (
    LOCK_NAME,
    column_units,
    provenance_metadata,
    read_provenance,
    to_jsonable,
    write_table,
)


def small_spec(**sweep: object) -> Spec:
    return resolve({"track": {"dt": 0.004}, "sweep": {
        "trials": 4, "chunk": 2, "seed": 3,
        "perturb": {"initial": {"dist": "normal", "std": 0.01}},
        "grid": {"track.sensor_noise": [0.0, 0.001]}, **sweep}})


def write_chunks(directory: Path, lay: Layout) -> None:
    """Every chunk of a layout, as the runner writes it."""
    base = {"digest": lay.spec.digest(), "spec": lay.spec.tree}
    for chunk in lay.chunks():
        cell = lay.cells[chunk.cell]
        table = run_chunk(cell, chunk).table
        write_table(directory / TRIALS_DIR / chunk.name, table,
                    chunk_provenance(base, cell, chunk, table))


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Layout]:
    """A directory with a manifest and every chunk of a small two-cell sweep."""
    directory = tmp_path_factory.mktemp("finished")
    lay = layout(small_spec())
    write_manifest(directory, lay)
    write_chunks(directory, lay)
    return directory, lay


def copy_of(finished: tuple[Path, Layout], tmp_path: Path) -> tuple[Path, Layout]:
    directory = tmp_path / "d"
    shutil.copytree(finished[0], directory)
    return directory, finished[1]


def test_every_finished_chunk_passes_its_checks(finished: tuple[Path, Layout]) -> None:
    directory, lay = finished
    done, problems = verified_chunks(directory, lay)
    assert problems == []
    assert done == {c.name for c in lay.chunks()}
    meta = read_provenance(directory / TRIALS_DIR / next(lay.chunks()).name)
    first = next(lay.chunks())
    assert meta["trials"] == [first.start, first.stop]
    assert meta["cell_digest"] == lay.cells[0].digest


def test_a_flipped_byte_in_a_data_page_is_found(finished: tuple[Path, Layout],
                                                tmp_path: Path) -> None:
    directory, lay = copy_of(finished, tmp_path)
    chunk = next(lay.chunks())
    path = directory / TRIALS_DIR / chunk.name
    data = bytes(path.read_bytes())
    original = pq.read_table(path).to_pandas()
    footer = int.from_bytes(data[-8:-4], "little")  # Parquet: metadata length, then "PAR1"
    caught = 0
    for offset in range(4, len(data) - footer - 8, 31):  # bytes of the pages, not the footer
        flipped = bytearray(data)
        flipped[offset] ^= 0x01
        path.write_bytes(flipped)
        if chunk_problem(path, lay.cells[0], chunk) is not None:
            caught += 1
            continue
        # not caught: the byte did not change what the file holds (a page statistic, a
        # NaN's payload)
        pd.testing.assert_frame_equal(pq.read_table(path).to_pandas(), original,
                                      check_exact=True, obj=f"flipped byte {offset}")
    assert caught > 0.5 * len(range(4, len(data) - footer - 8, 31))


def test_a_chunk_copied_under_another_name_or_cell_is_found(finished: tuple[Path, Layout],
                                                            tmp_path: Path) -> None:
    directory, lay = copy_of(finished, tmp_path)
    chunks = list(lay.chunks())
    trials = directory / TRIALS_DIR
    shutil.copy(trials / chunks[0].name, trials / chunks[1].name)  # same cell, other trials
    shutil.copy(trials / chunks[0].name, trials / chunks[2].name)  # another cell
    (trials / chunks[3].name).write_bytes(b"PAR1 half a file")
    done, problems = verified_chunks(directory, lay)
    assert done == {c.name for c in chunks} - {chunks[1].name, chunks[2].name, chunks[3].name}
    assert [p.split(":")[0] for p in problems] == [f"{TRIALS_DIR}/{c.name}" for c in chunks[1:4]]
    assert "holds trials" in problems[0]
    assert "another spec or cell" in problems[1]
    assert "not a readable chunk file" in problems[2]


def test_rows_changed_and_written_back_with_valid_metadata_are_found(
        finished: tuple[Path, Layout], tmp_path: Path) -> None:
    directory, lay = copy_of(finished, tmp_path)
    chunk = next(lay.chunks())
    path = directory / TRIALS_DIR / chunk.name
    table = pq.read_table(path)
    metric = table.column("err_y_rms").to_pylist()
    metric[0] = metric[0] * 2
    changed = table.set_column(table.schema.get_field_index("err_y_rms"), "err_y_rms",
                               pa.array(metric))
    pq.write_table(changed, path)  # the old metadata, checksum included, kept
    assert chunk_problem(path, lay.cells[0], chunk) == (
        "its content does not match its checksum (the file was changed)")


def test_another_spec_is_refused_naming_the_keys_that_differ(
        finished: tuple[Path, Layout], tmp_path: Path) -> None:
    directory, _ = copy_of(finished, tmp_path)
    other = layout(small_spec(seed=4, trials=6))
    with pytest.raises(SpecError, match=r"keys that differ: sweep\.seed \(3 -> 4\), "
                                        r"sweep\.trials \(4 -> 6\)\); use --force"):
        plan_directory(directory, other, force=False)
    assert plan_directory(directory, other, force=True).mode == "restart"


def test_without_its_manifest_a_directory_is_still_known_by_its_chunks(
        finished: tuple[Path, Layout], tmp_path: Path) -> None:
    directory, lay = copy_of(finished, tmp_path)
    (directory / MANIFEST).unlink()
    known = survey(directory)
    assert known.spec == to_jsonable(lay.spec.tree) and known.digest == lay.spec.digest()
    assert plan_directory(directory, lay, force=False).mode == "resume"
    with pytest.raises(SpecError, match=r"sweep\.seed \(3 -> 5\)"):
        plan_directory(directory, layout(small_spec(seed=5)), force=False)


def test_only_grid_values_changed_extends_the_study(finished: tuple[Path, Layout],
                                                     tmp_path: Path) -> None:
    directory, lay = copy_of(finished, tmp_path)
    more = layout(small_spec(grid={"track.sensor_noise": [0.002, 0.001, 0.0]}))
    plan = plan_directory(directory, more, force=False)
    assert plan.mode == "extend"
    assert "sweep.grid.'track.sensor_noise'" in plan.note and "2 of the 3 cells" in plan.note
    done, problems = verified_chunks(directory, more)
    assert problems == []
    reused = {c.name for c in lay.chunks()}
    assert done == reused  # the new cell's chunks are the only ones to compute
    write_manifest(directory, more, plan.previous)
    manifest = json.loads((directory / MANIFEST).read_text())
    assert len(manifest["cells"]) == 3
    # a grid key added is another study
    with pytest.raises(SpecError, match=r"sweep\.grid \(keys \['track\.sensor_noise'\] -> "):
        plan_directory(directory, layout(small_spec(grid={
            "track.sensor_noise": [0.0], "track.kp": [[10, 13]]})), force=False)


def test_spec_differences_separate_grid_values_from_keys() -> None:
    a = small_spec().tree
    b = small_spec(grid={"track.sensor_noise": [0.0, 0.5]}).tree
    assert spec_differences(a, b) == ([], ["sweep.grid.'track.sensor_noise'"])
    c = resolve({"name": "x"}).tree
    keys, _ = spec_differences(resolve({}).tree, c)
    assert keys == ['name ("paper_example" -> "x")']


def test_force_removes_only_flatcli_files_and_refuses_others(
        finished: tuple[Path, Layout], tmp_path: Path) -> None:
    directory, lay = copy_of(finished, tmp_path)
    for name in FINAL_FILES[1:]:
        (directory / name).write_text("a final file")
    (directory / LOCK_NAME).write_text("")
    (directory / TRIALS_DIR / f".{next(lay.chunks()).name}.abc123.tmp").write_text("")
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "data.csv").write_text("precious")
    for extra in ("notes.txt", f"{TRIALS_DIR}/data.csv", "sub/", "link"):
        path = directory / extra
        if extra == "link":
            path.symlink_to(outside, target_is_directory=True)
        elif extra.endswith("/"):
            path.mkdir()
        else:
            path.write_text("mine")
        with pytest.raises(SpecError, match=r"--force: .* holds files flatcli did not write "
                                            rf"\({extra}\); nothing was removed"):
            plan_directory(directory, lay, force=True)
        if path.is_dir() and not path.is_symlink():
            path.rmdir()
        else:
            path.unlink()
    assert (outside / "data.csv").read_text() == "precious"
    plan = plan_directory(directory, lay, force=True)
    clear(directory, plan.previous)
    assert sorted(p.name for p in directory.iterdir()) == [LOCK_NAME, TRIALS_DIR]
    assert list((directory / TRIALS_DIR).iterdir()) == []


def test_a_symlinked_trials_directory_is_refused_and_never_followed(tmp_path: Path) -> None:
    lay = layout(small_spec())
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "data.csv").write_text("precious")
    directory = tmp_path / "d"
    directory.mkdir()
    (directory / TRIALS_DIR).symlink_to(outside)
    for force in (False, True):
        with pytest.raises(SpecError, match="is not a directory flatcli made"):
            plan_directory(directory, lay, force=force)
    assert (outside / "data.csv").read_text() == "precious"


def test_a_fresh_sweep_never_replaces_files_it_did_not_write(tmp_path: Path) -> None:
    lay = layout(small_spec())
    (tmp_path / "summary.md").write_text("my summary")
    with pytest.raises(SpecError, match=r"did not write where it would write \(summary\.md\)"):
        plan_directory(tmp_path, lay, force=False)
    with pytest.raises(SpecError, match=r"--force: .*\(summary\.md\)"):
        plan_directory(tmp_path, lay, force=True)
    (tmp_path / "summary.md").unlink()
    (tmp_path / "notes.txt").write_text("mine")
    assert plan_directory(tmp_path, lay, force=False).mode == "fresh"  # beside it: fine


def test_recorded_outputs_and_the_sweeps_figures_are_flatcli_files(
        finished: tuple[Path, Layout], tmp_path: Path) -> None:
    directory, _ = copy_of(finished, tmp_path)
    (directory / "sweep_errors.png").write_bytes(b"png")  # plot_sweep's, recorded or not
    (directory / "my_plot.png").write_bytes(b"png")
    (directory / "rerun-3").mkdir()
    (directory / "rerun-3" / "metrics.json").write_text("{}")
    assert foreign_entries(directory, survey(directory).owned(directory)) == [
        "my_plot.png", "rerun-3/"]
    (directory / "my_plot.png").unlink()
    record_outputs(directory, [directory / "rerun-3" / "metrics.json"])
    previous = survey(directory)
    assert foreign_entries(directory, previous.owned(directory)) == []
    clear(directory, previous)
    assert not (directory / "rerun-3").exists() and not (directory / "sweep_errors.png").exists()


def test_an_unreadable_manifest_is_refused(tmp_path: Path) -> None:
    (tmp_path / MANIFEST).write_text("[1, 2")
    assert recorded_digest(tmp_path) is None
    with pytest.raises(SpecError, match="is not a flatcli sweep manifest"):
        plan_directory(tmp_path, layout(small_spec()), force=True)


def test_a_manifest_written_before_cell_keys_is_a_legacy_sweep(tmp_path: Path) -> None:
    spec = small_spec()
    (tmp_path / MANIFEST).write_text(json.dumps({"digest": spec.digest(), "spec": spec.tree}))
    (tmp_path / TRIALS_DIR).mkdir()
    (tmp_path / TRIALS_DIR / "chunk-000000000000.parquet").write_bytes(b"old")
    lay = layout(spec)
    with pytest.raises(SpecError, match="written by an older flatcli"):
        plan_directory(tmp_path, lay, force=False)
    plan = plan_directory(tmp_path, lay, force=True)
    clear(tmp_path, plan.previous)
    assert os.listdir(tmp_path / TRIALS_DIR) == [] and not (tmp_path / MANIFEST).exists()
    assert Previous().owned() == {LOCK_NAME}


def test_final_tables_have_nulls_units_lists_and_failure_shares(tmp_path: Path) -> None:
    # cell 0: u1(0) drawn around 0 (some cross the singular set: diverged) and masses scaled
    # by 1 + N(0, 0.7^2), some <= 0 (error); cell 1: every mass <= 0, so no trial runs
    spec = resolve({
        "plan": {"duration": 1.0, "start": [1.8, 1.0, 0.0], "goal": [1.5, 1.5, 0.0]},
        "track": {"dt": 0.01, "initial": [1.8, 1.0, 0.0], "initial_rate": 0.1},
        "sweep": {"trials": 30, "seed": 5,
                  "perturb": {"initial_rate": {"dist": "uniform", "low": -0.2, "high": 0.05},
                              "mass": {"dist": "normal", "std": 0.7, "relative": True}},
                  "grid": {"masses": [{"label": "some bad", "sweep.perturb.mass.mean": 0.0},
                                      {"label": "all bad", "sweep.perturb.mass.mean": -5.0,
                                       "sweep.perturb.mass.std": 0.1}],
                           "gains": [{"label": "swapped", "track.kp": [100, 110],
                                      "track.kv": [10, 13]}]}},
    })
    run_sweep(spec, tmp_path, workers=1)
    trials = pq.read_table(tmp_path / "trials.parquet")
    summary = pq.read_table(tmp_path / "summary.parquet")
    for path, table in (("trials", trials), ("summary", summary)):
        units = column_units(tmp_path / f"{path}.parquet")
        for field in table.schema:
            if pa.types.is_floating(field.type) or pa.types.is_list(field.type):
                assert field.name in units, (path, field.name)  # "1" if dimensionless
            if pa.types.is_floating(field.type):
                assert not pc.any(pc.is_nan(table.column(field.name))).as_py(), field.name
    assert column_units(tmp_path / "summary.parquet")["err_theta_rms_median"] == "rad"
    assert pa.types.is_list(trials.schema.field("track.kp").type)
    frame = trials.to_pandas()
    summary_frame = summary.to_pandas()
    assert len(summary_frame) == 2
    assert summary_frame["sweep.perturb.mass.mean"].tolist() == [0.0, -5.0]  # group keys
    assert summary_frame["sweep.perturb.mass.std"].tolist() == [0.7, 0.1]  # as applied
    assert column_units(tmp_path / "summary.parquet")["sweep.perturb.mass.std"] == "1"
    for _, row in summary_frame.iterrows():
        group = frame[frame["cell"] == row["cell"]]
        n = len(group)
        for status in ("diverged", "unresolved", "error"):
            k = int((group["status"] == status).sum())
            assert row[status] == k and row[f"{status}_fraction"] == k / n
            ci = binomtest(k, n).proportion_ci(0.95, method="wilson")
            assert row[f"{status}_fraction_low"] == pytest.approx(ci.low, abs=1e-15)
            assert row[f"{status}_fraction_high"] == pytest.approx(ci.high, abs=1e-15)
        simulated = group[group["status"] != "error"]
        if len(simulated):  # the singular share over the simulated trials, counted once each
            k = int((simulated["singular_hits"] > 0).sum())
            ci = binomtest(k, len(simulated)).proportion_ci(0.95, method="wilson")
            assert row["singular_fraction_high"] == pytest.approx(ci.high, abs=1e-15)
        resolved = group[group["status"].isin(["ok", "singular"])]
        assert row["resolved"] == len(resolved)
        assert row["simulated"] == int((group["status"] != "error").sum())
        if len(resolved) == 0:  # nothing to take statistics of: null, not nan, not 0
            assert pd.isna(row["err_theta_rms_median"]) and pd.isna(row["min_margin_median"])
        else:
            assert row["err_theta_final_max"] == resolved["err_theta_final"].max()
    mixed = summary_frame[(summary_frame["diverged"] > 0) & (summary_frame["error"] > 0)]
    assert not mixed.empty  # the case the shares are for
    nothing = summary_frame[summary_frame["error"] == 30]
    assert not nothing.empty and nothing["singular_fraction"].isna().all()
    assert summary.column("err_theta_rms_median").null_count == len(nothing)
    assert math.isclose(nothing["error_fraction_high"].iloc[0], 1.0)


# ---------------------------------------------------------------------------------------
# Names read from a manifest: only the forms flatcli writes, never outside the directory.

HOSTILE_FILES = ["../victim.txt", "{outside}/victim.txt", "trials/../../victim.txt",
                 "kinematic/../../victim.txt", "rerun-1/../../victim.txt", "notes.txt",
                 "sub/run.json", "rerun-x/run.json", "rerun-1/notes.txt", "./run.json",
                 "trials//chunk-0000000000-000000000.parquet", "run.json/", "",
                 "trials/chunk-0000000000-00000000.parquet", "sweep_Errors.png",
                 "summary.md\n"]
HOSTILE_CHUNKS = ["../../victim.txt", "{outside}/victim.txt", "chunk-0000000000-000000000",
                  "chunk-0000000000-0000000000.parquet", "chunk-00000000000-000000000.parquet",
                  "sub/chunk-0000000000-000000000.parquet", "chunk-0000000000-00000000a.parquet"]


def _victim(tmp_path: Path) -> Path:
    outside = tmp_path / "outside"
    outside.mkdir(exist_ok=True)
    victim = outside / "victim.txt"
    victim.write_text("precious")
    return victim


def _edit_manifest(directory: Path, edit: object) -> None:
    path = directory / MANIFEST
    manifest = json.loads(path.read_text())
    edit(manifest)  # type: ignore[operator]
    path.write_text(json.dumps(manifest))


@pytest.mark.parametrize("name", HOSTILE_FILES)
def test_a_manifest_listing_a_file_flatcli_does_not_write_is_refused(
        finished: tuple[Path, Layout], tmp_path: Path, name: str) -> None:
    directory, lay = copy_of(finished, tmp_path)
    victim = _victim(tmp_path)
    listed = name.format(outside=victim.parent)
    _edit_manifest(directory, lambda m: m["files"].append(listed))
    before = sorted(p.relative_to(directory) for p in directory.rglob("*"))
    for force in (True, False):
        with pytest.raises(SpecError, match=r"sweep\.json is not a flatcli sweep manifest "
                                            r"\(it lists .*, not a file flatcli writes"):
            plan_directory(directory, lay, force=force)
    assert victim.read_text() == "precious"
    assert sorted(p.relative_to(directory) for p in directory.rglob("*")) == before
    assert recorded_digest(directory) is None


@pytest.mark.parametrize("name", [*HOSTILE_CHUNKS, "chunk-0000000001-000000000.parquet"])
def test_a_manifest_listing_a_chunk_flatcli_does_not_write_is_refused(
        finished: tuple[Path, Layout], tmp_path: Path, name: str) -> None:
    directory, lay = copy_of(finished, tmp_path)
    victim = _victim(tmp_path)
    key = str(lay.cells[0].key)
    listed = name.format(outside=victim.parent)
    if name.startswith("chunk-0000000001"):  # the form of another cell's chunk
        listed = name.replace("0000000001", f"{(lay.cells[0].key + 1) % 2**32:010d}")
    _edit_manifest(directory, lambda m: m["cells"][key]["chunks"].append(listed))
    with pytest.raises(SpecError, match=rf"cell {key} lists the chunk .*, not a chunk file "
                                        "name of that cell"):
        plan_directory(directory, lay, force=True)
    assert victim.read_text() == "precious"


@pytest.mark.parametrize(("edit", "problem"), [
    (lambda m: m.update(cells=[1, 2]), "its cells are not a table"),
    (lambda m: m.update(files="run.json"), "its files are not a list of names"),
    (lambda m: m.update(files=[1]), "its files are not a list of names"),
    (lambda m: m["cells"].update({"-1": {"digest": "x"}}), "is not a cell key"),
    (lambda m: m["cells"].update({str(2**32): {"digest": "x"}}), "is not a cell key"),
    (lambda m: m["cells"].update({"7": {"chunks": []}}), "cell 7 has no digest"),
    (lambda m: m["cells"].update({"7": {"digest": "x", "chunks": "chunk"}}),
     "the chunks of cell 7 are not a list"),
    (lambda m: m.update(grid_cells=["12345"]), "its grid_cells are not keys of its cells"),
    (lambda m: m.update(trials_per_cell="4"), "trials_per_cell and chunk are not positive"),
    (lambda m: m.update(trials_per_cell=True), "trials_per_cell and chunk are not positive"),
    (lambda m: m.update(trials_per_cell=10**9 + 1), "trials_per_cell and chunk are not"),
    (lambda m: m.update(chunk=0), "trials_per_cell and chunk are not positive"),
    (lambda m: m.update(digest=None), "no digest and spec"),
])
def test_a_manifest_of_other_types_than_flatcli_writes_is_refused(
        finished: tuple[Path, Layout], tmp_path: Path, edit: object, problem: str) -> None:
    directory, lay = copy_of(finished, tmp_path)
    _edit_manifest(directory, edit)
    with pytest.raises(SpecError, match=re.escape(problem)):
        plan_directory(directory, lay, force=True)
    assert sweep_state(directory) is None  # and summarize / runs do not trust it either


def test_every_name_flatcli_records_passes_the_manifest_check(
        finished: tuple[Path, Layout]) -> None:
    directory, _ = finished
    manifest = json.loads((directory / MANIFEST).read_text())
    recorded = [*FINAL_FILES, LOCK_NAME, "sweep_errors.png", "sweep_singular.png",
                "cells.parquet", "trials.csv", "summary.csv", "cells.csv",
                *(f"rerun-{2**63 - 1}/{n}" for n in RERUN_FILES),
                "kinematic/sweep.json", "kinematic/.flatcli.lock", "kinematic/summary.md",
                "kinematic/trials/chunk-0123456789-000000250.parquet",
                "trials/chunk-000000000250.parquet"]
    assert manifest_problem({**manifest, "files": recorded}) is None
    assert manifest_problem(manifest) is None
    legacy = {"digest": "d", "spec": {}, "cells": 2, "trials_per_cell": 4, "chunk": 2}
    assert manifest_problem(legacy) is None
    assert "not a positive integer" in str(manifest_problem({**legacy, "cells": "2"}))


@pytest.mark.timeout(30, method="thread")  # a FIFO opened blindly would block forever
def test_a_manifest_that_is_not_a_regular_file_or_too_large_is_refused_unread(
        tmp_path: Path) -> None:
    lay = layout(small_spec())
    fifo = tmp_path / "fifo"
    fifo.mkdir()
    os.mkfifo(fifo / MANIFEST)
    big = tmp_path / "big"
    big.mkdir()
    with (big / MANIFEST).open("wb") as fh:
        fh.truncate(MAX_MANIFEST_BYTES + 1)
    deep = tmp_path / "deep"
    deep.mkdir()
    (deep / MANIFEST).write_text("[" * 100_000)
    for directory, problem in ((fifo, "is a FIFO"), (big, "more than the"), (deep, "not JSON")):
        with pytest.raises(SpecError, match=f"not a flatcli sweep manifest .*{problem}"):
            survey(directory)
        with pytest.raises(SpecError, match=r"sweep\.json"):
            plan_directory(directory, lay, force=True)
        assert sweep_state(directory) is None


def test_clear_removes_nothing_through_a_link_or_outside(finished: tuple[Path, Layout],
                                                         tmp_path: Path) -> None:
    directory, _ = copy_of(finished, tmp_path)
    victim = _victim(tmp_path)
    (victim.parent / "run.json").write_text("theirs")
    (victim.parent / "trials").mkdir()
    (victim.parent / "trials" / ".x.abc.tmp").write_text("theirs")
    (directory / "rerun-3").symlink_to(victim.parent, target_is_directory=True)
    (directory / "kinematic").symlink_to(victim.parent, target_is_directory=True)
    (directory / "trials.parquet").symlink_to(victim)
    previous = Previous({"name": "x"}, "d", files={
        "rerun-3/run.json", "kinematic/trials/x", "../outside/victim.txt", "trials.parquet"})
    clear(directory, previous)  # even called without the checks of plan_directory
    assert victim.read_text() == "precious"
    assert (victim.parent / "run.json").read_text() == "theirs"
    assert (victim.parent / "trials" / ".x.abc.tmp").read_text() == "theirs"
    assert (directory / "trials.parquet").is_symlink()


@pytest.mark.parametrize("name", ["trials.parquet", "summary.md", "sweep_errors.png",
                                  "trials/chunk-0000000000-000000000.parquet", LOCK_NAME])
@pytest.mark.parametrize("what", ["a symbolic link", "a directory", "a FIFO"])
def test_an_entry_named_like_a_flatcli_file_is_not_flatclis(
        finished: tuple[Path, Layout], tmp_path: Path, name: str, what: str) -> None:
    directory, lay = copy_of(finished, tmp_path)
    victim = _victim(tmp_path)
    path = directory / name
    if name == "trials/chunk-0000000000-000000000.parquet":
        path = directory / TRIALS_DIR / next(lay.chunks()).name
        name = f"{TRIALS_DIR}/{path.name}"
    path.unlink(missing_ok=True)
    if what == "a symbolic link":
        path.symlink_to(victim)
    elif what == "a directory":
        path.mkdir()
    else:
        os.mkfifo(path)
    assert foreign_entries(directory, survey(directory).owned(directory)) == [
        name + ("/" if what == "a directory" else "")]
    with pytest.raises(SpecError, match=re.escape(name)):
        plan_directory(directory, lay, force=True)
    assert victim.read_text() == "precious" and os.path.lexists(path)


@pytest.mark.timeout(30, method="thread")  # a FIFO opened blindly would block the resume forever
@pytest.mark.parametrize("what", ["a FIFO", "a directory", "a symbolic link"])
def test_a_chunk_that_is_not_a_regular_file_is_refused_before_any_work(
        finished: tuple[Path, Layout], tmp_path: Path, what: str) -> None:
    directory, lay = copy_of(finished, tmp_path)
    chunk = list(lay.chunks())[1]
    path = directory / TRIALS_DIR / chunk.name
    elsewhere = tmp_path / "elsewhere.parquet"
    shutil.move(path, elsewhere)  # a valid chunk, behind a link
    if what == "a FIFO":
        os.mkfifo(path)
    elif what == "a directory":
        path.mkdir()
    else:
        path.symlink_to(elsewhere)
    assert chunk_problem(path, lay.cells[chunk.cell], chunk) == f"is {what}, not a chunk file"
    with pytest.raises(SpecError, match=rf"holds {TRIALS_DIR}/{chunk.name} \({what}\) where "
                                        r"flatcli keeps its own files; .* remove it yourself"):
        plan_directory(directory, lay, force=False)
    state = sweep_state(directory)
    assert state is not None and path not in state.chunk_files


def test_record_outputs_records_only_flatclis_names(finished: tuple[Path, Layout],
                                                    tmp_path: Path) -> None:
    directory, _ = copy_of(finished, tmp_path)
    (directory / "rerun-3").mkdir()
    for name in ("run.json", "notes.txt"):
        (directory / "rerun-3" / name).write_text("{}")
    (directory / "link.png").symlink_to(directory / "rerun-3" / "run.json")
    (directory / "sweep_link.png").symlink_to(directory / "rerun-3" / "run.json")
    record_outputs(directory, [*(directory / "rerun-3").iterdir(), directory / "sweep_link.png",
                               tmp_path / "elsewhere.png"])
    files = json.loads((directory / MANIFEST).read_text())["files"]
    assert "rerun-3/run.json" in files and "rerun-3/notes.txt" not in files
    assert not any("link" in f or "elsewhere" in f for f in files)
    survey(directory)  # the manifest it wrote passes its own check


def test_trials_parquet_grows_in_the_grids_order_from_chunks_in_any_order(
        finished: tuple[Path, Layout], tmp_path: Path) -> None:
    """TrialsAssembly, as a run feeds it: chunks arrive out of order and one was kept from
    before (read from its file when its turn comes); trials.parquet is the chunk files in the
    grid's order (the referee: pyarrow reading each file), and the summary's columns are the
    file's columns as pandas reads them back."""
    directory, lay = copy_of(finished, tmp_path)
    chunks = list(lay.chunks())
    assert len(chunks) == 4
    provenance = {"digest": lay.spec.digest(), "spec": lay.spec.tree}
    assembly = TrialsAssembly(directory, lay, provenance, kept={chunks[1].name})
    for chunk in (chunks[3], chunks[0], chunks[2]):
        assembly.add(chunk, pq.read_table(directory / TRIALS_DIR / chunk.name))
        assert not (directory / "trials.parquet").exists()  # renamed only when whole
    path, columns = assembly.close()
    assert path == directory / "trials.parquet"
    assert not list(directory.glob(".*.tmp"))
    written = pq.read_table(path)
    expected = pa.concat_tables([pq.read_table(directory / TRIALS_DIR / c.name) for c in chunks])
    assert written.equals(expected)
    assert written.schema.metadata == provenance_metadata(provenance)
    frame = pd.read_parquet(path)
    assert set(columns) == set(SUMMARY_INPUTS) & set(frame.columns)
    for name, values in columns.items():
        if values.dtype == object:  # text: None where null, one object per distinct word
            assert values.tolist() == [None if pd.isna(v) else v for v in frame[name]]
            assert len({id(v) for v in values}) == len(set(values.tolist()))
        else:
            np.testing.assert_array_equal(values, frame[name].to_numpy(
                dtype=values.dtype, na_value=False if values.dtype == bool else np.nan))


def test_an_aborted_assembly_leaves_the_trials_parquet_the_directory_had(
        finished: tuple[Path, Layout], tmp_path: Path) -> None:
    directory, lay = copy_of(finished, tmp_path)
    (directory / "trials.parquet").write_bytes(b"the previous file")
    chunk = next(lay.chunks())
    assembly = TrialsAssembly(directory, lay, {"digest": "d"}, kept=())
    assembly.add(chunk, pq.read_table(directory / TRIALS_DIR / chunk.name))
    assert len(list(directory.glob(".trials.parquet.*.tmp"))) == 1  # being written
    assembly.abort()
    assert (directory / "trials.parquet").read_bytes() == b"the previous file"
    assert not list(directory.glob(".*.tmp"))


def test_a_killed_runs_temporary_final_tables_go_and_nothing_else(tmp_path: Path) -> None:
    directory = tmp_path / "d"
    directory.mkdir()
    outside = tmp_path / "outside.txt"
    outside.write_text("keep")
    for name in FINAL_FILES:
        (directory / f".{name}.x1y2z3.tmp").write_text("half")
    (directory / ".notes.txt.abc.tmp").write_text("not flatcli's")
    (directory / ".trials.parquet.link.tmp").symlink_to(outside)
    (directory / "trials.parquet").write_text("the finished one")
    remove_temporaries(directory)
    assert sorted(p.name for p in directory.iterdir()) == [
        ".notes.txt.abc.tmp", ".trials.parquet.link.tmp", "trials.parquet"]
    assert outside.read_text() == "keep"


def test_chunks_held_for_their_turn_are_bounded_and_read_back_past_it(
        finished: tuple[Path, Layout], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunks finishing in reverse order (the first one last, as a slow first chunk or a
    lost Dask worker makes them): at most HELD_CHUNKS wait in memory, the others are read
    from their files when their turn comes; the file is the same (the referee: pyarrow
    reading the chunk files)."""
    import flatcli.montecarlo.directory as directory_module

    monkeypatch.setattr(directory_module, "HELD_CHUNKS", 1)
    directory, lay = copy_of(finished, tmp_path)
    chunks = list(lay.chunks())
    assembly = TrialsAssembly(directory, lay, {"digest": "d"}, kept=())
    for chunk in reversed(chunks):
        assembly.add(chunk, pq.read_table(directory / TRIALS_DIR / chunk.name))
        assert len(assembly._held) <= 1
    path, _ = assembly.close()
    expected = pa.concat_tables([pq.read_table(directory / TRIALS_DIR / c.name) for c in chunks])
    assert pq.read_table(path).equals(expected)


def test_a_full_disk_while_trials_parquet_grows_is_an_os_error_naming_it(
        finished: tuple[Path, Layout], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """pyarrow's OS errors name no file: this one names trials.parquet, with the OS's reason
    (not "other columns than the chunks before it; use --force", which would have the user
    remove the finished chunks); nothing is left behind."""
    import errno

    import flatcli.montecarlo.directory as directory_module

    class FullDisk(pq.ParquetWriter):  # type: ignore[misc]
        def write_table(self, table: pa.Table, row_group_size: int | None = None) -> None:
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(directory_module.pq, "ParquetWriter", FullDisk)
    directory, lay = copy_of(finished, tmp_path)
    chunk = next(lay.chunks())
    assembly = TrialsAssembly(directory, lay, {"digest": "d"}, kept=())
    with pytest.raises(OSError) as caught:
        assembly.add(chunk, pq.read_table(directory / TRIALS_DIR / chunk.name))
    assert not isinstance(caught.value, SpecError)
    assert caught.value.filename == str(directory / "trials.parquet")
    assert caught.value.strerror == "No space left on device"
    assembly.abort()
    assert not list(directory.glob(".*.tmp")) and not (directory / "trials.parquet").exists()


def _rewrite_trials(path: Path, change: object = None, index: bytes | None = None) -> None:
    """trials.parquet written again with its row groups and its chunks' list (or ``index``
    instead), ``change(table) -> table`` applied to its rows."""
    from flatcli.montecarlo.directory import CHUNKS_META_KEY

    with pq.ParquetFile(path) as file:
        listed = file.metadata.metadata[CHUNKS_META_KEY] if index is None else index
        groups = [file.read_row_group(i) for i in range(file.metadata.num_row_groups)]
    if change is not None:
        groups = [change(g) for g in groups]  # type: ignore[operator]
    with pq.ParquetWriter(path, groups[0].schema) as writer:
        for group in groups:
            writer.write_table(group, row_group_size=group.num_rows)
        writer.add_key_value_metadata({CHUNKS_META_KEY.decode(): listed.decode()})


@pytest.fixture(scope="module")
def swept(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Layout]:
    """A small sweep run to its end: its chunks are in trials.parquet only."""
    directory = tmp_path_factory.mktemp("swept")
    spec = small_spec()
    run_sweep(spec, directory, workers=1)
    return directory, layout(spec)


def test_a_finished_sweep_keeps_each_chunk_once_in_trials_parquet(
        swept: tuple[Path, Layout]) -> None:
    from flatcli.montecarlo.directory import StoredChunks

    directory, lay = swept
    assert not (directory / TRIALS_DIR).exists()
    stored = StoredChunks.of(directory)
    assert stored is not None and set(stored.chunks) == {c.name for c in lay.chunks()}
    whole = pq.read_table(directory / "trials.parquet")
    for chunk in lay.chunks():  # the referee: the chunk's rows computed again here
        rows = stored.read(chunk.name)
        fresh = run_chunk(lay.cells[chunk.cell], chunk).table
        assert rows.equals(whole.filter(pc.field("trial").isin(range(chunk.start, chunk.stop))))
        assert rows.select(fresh.column_names).equals(fresh.cast(rows.schema))
        assert stored.problem(lay.cells[chunk.cell], chunk) is None
    assert verified_chunks(directory, lay) == ({c.name for c in lay.chunks()}, [])


def test_a_changed_value_in_trials_parquet_is_found_and_computed_again(
        swept: tuple[Path, Layout], tmp_path: Path) -> None:
    directory, lay = copy_of(swept, tmp_path)
    path = directory / "trials.parquet"
    before = path.read_bytes()
    first = next(lay.chunks())

    def doubled(table: pa.Table) -> pa.Table:
        if table.column("trial")[0].as_py() != first.start:
            return table
        i = table.schema.get_field_index("err_y_rms")
        return table.set_column(i, "err_y_rms", pc.multiply(table.column(i), 2.0))

    _rewrite_trials(path, doubled)
    done, problems = verified_chunks(directory, lay)
    assert done == {c.name for c in lay.chunks()} - {first.name}
    assert problems == [f"trials.parquet (chunk {first.name}): its content does not match "
                        "its checksum (the file was changed)"]
    run_sweep(lay.spec, directory, workers=1)  # computes that chunk again
    assert path.read_bytes() == before


@pytest.mark.parametrize("index", [
    b"not json", b"[]", b'{"format": 1, "cells": {}, "chunks": []}',
    b'{"format": 1, "cells": {"0": {"digest": "x"}}, "chunks": [[0, 2, "x"]]}',  # 2 rows of 8
    b'{"format": 2, "cells": {}, "chunks": []}',
])
def test_a_list_of_chunks_not_as_flatcli_writes_it_holds_none(
        swept: tuple[Path, Layout], tmp_path: Path, index: bytes) -> None:
    from flatcli.montecarlo.directory import StoredChunks

    directory, lay = copy_of(swept, tmp_path)
    before = (directory / "trials.parquet").read_bytes()
    _rewrite_trials(directory / "trials.parquet", index=index)
    assert StoredChunks.of(directory) is None
    assert verified_chunks(directory, lay) == (set(), [])
    run_sweep(lay.spec, directory, workers=1)  # nothing trusted: all computed again
    assert (directory / "trials.parquet").read_bytes() == before


def test_a_full_disk_while_dropped_cells_are_written_back_keeps_the_old_table(
        swept: tuple[Path, Layout], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A grid narrowed to one value: the other cell's chunks, held in trials.parquet only,
    go back to chunk files before the new trials.parquet replaces it. A full disk then (an
    OSError naming the chunk file) leaves the old trials.parquet as it was; once there is
    room the run completes, and widening the grid again computes nothing and gives the
    first file's bytes."""
    import errno

    from flatcli.montecarlo import directory as module

    folder, lay = copy_of(swept, tmp_path)
    before = (folder / "trials.parquet").read_bytes()
    narrow = small_spec(grid={"track.sensor_noise": [0.0]})

    def full(path: Path, *_: object, **__: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    with monkeypatch.context() as patch:
        patch.setattr(module, "write_table", full)
        with pytest.raises(OSError, match=r"No space left on device.*chunk-") as caught:
            run_sweep(narrow, folder, workers=1)
    assert caught.value.errno == errno.ENOSPC
    assert (folder / "trials.parquet").read_bytes() == before
    assert not list(folder.glob(".trials.parquet.*.tmp"))
    done = run_sweep(narrow, folder, workers=1)
    assert done.simulated == 0
    assert len(list((folder / TRIALS_DIR).glob("chunk-*.parquet"))) == 2  # the other cell
    again = run_sweep(lay.spec, folder, workers=1)
    assert again.simulated == 0
    assert (folder / "trials.parquet").read_bytes() == before
    assert not (folder / TRIALS_DIR).exists()
