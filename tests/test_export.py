"""`flatcli export DIR --csv` and `--mat` (flatcli/export.py): every Parquet table as a CSV
that reads back to the same values, and as a MATLAB file that scipy.io.loadmat reads back to
them (with the units of the Parquet fields and a description)."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from small_sweep import SPEC, sweep, write_spec

from flatcli.cli import main
from flatcli.export import csv_ready, export_csv, export_mat, matlab_fields
from flatcli.storage import DirectoryBusyError, directory_lock, forget_inherited_locks


def cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.output


def test_a_diverged_track_run_exports_exactly(tmp_path: Path) -> None:
    # gains so weak the loop diverges: rows after the stop are not applicable (NaN)
    run = tmp_path / "t"
    code, out = cli("track", "--out", str(run), "-q", "--set", "track.kp=[0.01,0.01]",
                    "--set", "track.kv=[0.01,0.01]", "--set", "track.initial=[1.96,0.05,-0.1]")
    assert code == 0, out
    code, out = cli("export", str(run), "--csv")
    assert code == 0 and out == f"wrote {run}/track.csv\n"
    frame = pd.read_parquet(run / "track.parquet")
    back = pd.read_csv(run / "track.csv")
    assert list(back.columns) == list(frame.columns)
    pd.testing.assert_frame_equal(back, frame, check_exact=True)  # NaN <-> empty field


def test_a_sweep_exports_its_tables_to_out_not_its_chunks(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 10"))
    assert sweep(str(spec), "--out", str(tmp_path / "d"), "-q")[0] == 0
    paths = export_csv(tmp_path / "d", tmp_path / "csv")
    assert [p.name for p in paths] == ["summary.csv", "trials.csv"]
    assert sorted(p.name for p in (tmp_path / "csv").iterdir()) == ["summary.csv", "trials.csv"]
    trials = pd.read_parquet(tmp_path / "d" / "trials.parquet")
    text = [c for c in trials.columns if not pd.api.types.is_numeric_dtype(trials[c])]
    back = pd.read_csv(tmp_path / "csv" / "trials.csv", dtype=dict.fromkeys(text, "string"))
    for column in trials.columns:
        if pd.api.types.is_numeric_dtype(trials[column]):
            np.testing.assert_array_equal(back[column].to_numpy(float),
                                          trials[column].to_numpy(float), err_msg=column)
        else:
            assert back[column].fillna("").astype(str).tolist() == \
                trials[column].fillna("").astype(str).tolist(), column


def test_nested_values_become_json_and_nulls_empty() -> None:
    table = pa.table({"grid": pa.array([[0.1, 0.1, 0.005], None], pa.list_(pa.float64())),
                      "x": pa.array([np.nan, 2.5]), "n": pa.array([None, 3], pa.int64())})
    ready = csv_ready(table)
    assert ready.column("grid").to_pylist() == [json.dumps([0.1, 0.1, 0.005]), None]
    assert ready.column("x").to_pylist() == [None, 2.5]
    buffer = io.BytesIO()
    pq.write_table(ready, buffer)  # still a valid table
    assert pq.read_table(io.BytesIO(buffer.getvalue())).num_rows == 2


def test_bad_export_requests_exit_2(tmp_path: Path) -> None:
    code, out = cli("export", str(tmp_path), "--csv")
    assert code == 2 and "holds no Parquet tables" in out and out.count("\n") == 1
    code, out = cli("export", str(tmp_path))
    assert code == 2 and out == "error: export: choose a format: --csv, --mat (or both)\n"
    code, out = cli("export", str(tmp_path), "--mat")
    assert code == 2 and "holds no Parquet tables" in out and out.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.timeout(30, method="thread")  # a FIFO opened blindly would block
def test_a_table_or_a_csv_name_that_is_not_a_regular_file_is_refused(tmp_path: Path) -> None:
    run = tmp_path / "r"
    code, out = cli("plan", "--out", str(run), "-q")
    assert code == 0, out
    os.mkfifo(run / "extra.parquet")
    code, out = cli("export", str(run), "--csv")
    assert code == 2 and "extra.parquet (a FIFO), not a table" in out and out.count("\n") == 1
    (run / "extra.parquet").unlink()
    (run / "plan.csv").mkdir()
    code, out = cli("export", str(run), "--csv")
    assert code == 2 and "plan.csv (a directory) where export writes" in out, out
    (run / "plan.csv").rmdir()
    outside = tmp_path / "outside.csv"
    outside.write_text("precious")
    (run / "plan.csv").symlink_to(outside)
    code, out = cli("export", str(run), "--csv")
    assert code == 2 and "plan.csv (a symbolic link)" in out, out
    assert outside.read_text() == "precious"


def test_export_into_a_sweep_records_its_files_and_waits_for_no_writer(
        tmp_path: Path) -> None:
    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 4").replace(
        "chunk = 25", "chunk = 2"))
    directory = tmp_path / "d"
    assert sweep(str(spec), "--out", str(directory), "-q", "--workers", "1")[0] == 0
    with directory_lock(directory), pytest.raises(  # a sweep writing there: export refuses
            DirectoryBusyError, match="being written by another flatcli run"):
        export_in_another_process(directory)
    assert not (directory / "trials.csv").exists()
    export_csv(directory)
    files = json.loads((directory / "sweep.json").read_text())["files"]
    assert {"trials.csv", "summary.csv"} <= set(files)


def export_in_another_process(directory: Path) -> None:
    """export_csv as another process would run it (this one holds the lock)."""
    import multiprocessing

    context = multiprocessing.get_context("fork")
    with context.Pool(1) as pool:
        pool.apply(_export_as_another_run, (directory,))


def _export_as_another_run(directory: Path) -> None:
    forget_inherited_locks()  # the forked child holds no lock of its parent's
    export_csv(directory)


# ---------------------------------------------------------------------------------------
# MATLAB files, read back by scipy.io.loadmat (the reader MATLAB's format has in Python)


def loadmat(path: Path) -> dict[str, object]:
    from scipy.io import loadmat as scipy_loadmat

    return dict(scipy_loadmat(path, simplify_cells=True))


def check_mat_against_parquet(mat_path: Path, parquet_path: Path) -> dict[str, object]:
    """Every column of the table in the MATLAB file: the same values (NaN for null), the
    Parquet field's unit, the names mapped one to one; returns the file's variables."""
    mat = loadmat(mat_path)
    table = pq.read_table(parquet_path)
    columns = list(table.column_names)
    assert list(mat["columns"]) == columns  # type: ignore[call-overload]
    fields = list(mat["fields"])  # type: ignore[call-overload]
    assert fields == matlab_fields(columns)
    data, units = mat["data"], mat["units"]
    assert isinstance(data, dict) and isinstance(units, dict)
    assert sorted(data) == sorted(fields)
    for field, column in zip(fields, columns, strict=True):
        values = table.column(column)
        got = np.atleast_1d(data[field])
        assert got.shape == (table.num_rows,), column
        kind = values.type
        if pa.types.is_floating(kind) or (pa.types.is_integer(kind) and values.null_count):
            expected = values.cast(pa.float64()).fill_null(np.nan).to_numpy()
            np.testing.assert_array_equal(got.astype(float), expected, err_msg=column)
        elif pa.types.is_integer(kind):
            assert got.dtype == np.int64, column
            np.testing.assert_array_equal(got, values.to_numpy(), err_msg=column)
        elif pa.types.is_boolean(kind) and not values.null_count:
            np.testing.assert_array_equal(got.astype(bool), values.to_numpy(
                zero_copy_only=False), err_msg=column)
        elif pa.types.is_string(kind) or pa.types.is_dictionary(kind):
            # MATLAB's '' is a 0x0 char, which loadmat gives back as an empty array
            text = [v if isinstance(v, str) else "" if np.size(v) == 0 else str(v)
                    for v in got]
            assert text == ["" if v is None else str(v) for v in values.to_pylist()], column
        unit = (table.schema.field(column).metadata or {}).get(b"unit")
        assert units.get(field) == (None if unit is None else unit.decode()), column
    description = str(mat["description"])
    assert f"{table.num_rows} rows, {len(columns)} columns" in description
    assert "NaN" in description and "docs/outputs.md" in description
    return mat


def test_plan_and_track_runs_export_their_time_series_as_mat(tmp_path: Path) -> None:
    for command in ("plan", "track"):
        run = tmp_path / command
        code, out = cli(command, "--out", str(run), "-q")
        assert code == 0, out
        code, out = cli("export", str(run), "--mat", "--csv")
        assert code == 0 and out == f"wrote {run}/{command}.csv, {run}/{command}.mat\n", out
        mat = check_mat_against_parquet(run / f"{command}.mat", run / f"{command}.parquet")
        assert mat["units"]["t"] == "s" and mat["units"]["theta0"] == "rad"  # type: ignore[index]


def test_a_sweep_exports_trials_and_summary_as_mat_into_its_manifest(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 6"))
    directory = tmp_path / "d"
    assert sweep(str(spec), "--out", str(directory), "-q", "--workers", "1")[0] == 0
    paths = export_mat(directory)
    assert [p.name for p in paths] == ["summary.mat", "trials.mat"]
    trials = check_mat_against_parquet(directory / "trials.mat", directory / "trials.parquet")
    check_mat_against_parquet(directory / "summary.mat", directory / "summary.parquet")
    fields = list(trials["fields"])  # type: ignore[call-overload]
    assert "track_sensor_noise" in fields  # the grid key track.sensor_noise, renamed
    assert set(trials["data"]["status"]) <= {"ok", "singular", "diverged", "failed"}  # type: ignore[index]
    files = json.loads((directory / "sweep.json").read_text())["files"]
    assert {"trials.mat", "summary.mat"} <= set(files)


def test_matlab_field_names_are_identifiers_and_unique() -> None:
    names = matlab_fields(["sweep.perturb.initial.std", "1x", "a-b", "a_b", "x" * 70,
                           "x" * 70])
    assert names[:4] == ["sweep_perturb_initial_std", "x1x", "a_b", "a_b_2"]
    assert all(len(n) <= 63 for n in names) and len(set(names)) == len(names)
    import re

    assert all(re.fullmatch(r"[A-Za-z]\w*", n, flags=re.ASCII) for n in names)


@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_an_unreadable_table_exports_nothing_and_is_one_line(tmp_path: Path,
                                                              damage: str) -> None:
    """summary.parquet sorts before trials.parquet: a damaged trials.parquet must not leave
    summary.csv behind (every CSV is renamed into place only when all were written)."""
    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 10"))
    assert sweep(str(spec), "--out", str(tmp_path / "d"), "-q")[0] == 0
    trials = tmp_path / "d" / "trials.parquet"
    data = trials.read_bytes()
    trials.write_bytes(os.urandom(100) if damage == "garbage" else data[: len(data) // 2])
    before = sorted(p.name for p in (tmp_path / "d").iterdir())
    code, out = cli("export", str(tmp_path / "d"), "--csv")
    assert code == 2 and out.startswith("error: ") and out.count("\n") == 1, out
    assert f"{trials}: not a readable Parquet table" in out and "nothing exported" in out
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == before  # no CSV, no temp
    code, out = cli("export", str(tmp_path / "d"), "--csv", "--out", str(tmp_path / "csv"))
    assert code == 2 and not list((tmp_path / "csv").glob("*"))
    code, out = cli("export", str(tmp_path / "d"), "--mat")  # the same for MATLAB files
    assert code == 2 and "not a readable Parquet table" in out
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == before
