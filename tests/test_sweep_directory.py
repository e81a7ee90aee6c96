"""A sweep's directory (flatcli/sweep/directory.py): manifest, resume, provenance."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from scipy.stats import binomtest

from flatcli.spec import SpecError, resolve
from flatcli.storage import PARQUET_META_KEY, column_units, read_provenance, write_table
from flatcli.sweep import MANIFEST, TRIALS_DIR, recorded_digest, run_sweep
from flatcli.sweep.directory import check_directory, clear, finished_chunks


def test_a_directory_of_another_spec_is_refused_unless_forced(tmp_path: Path) -> None:
    spec = resolve({})
    check_directory(tmp_path, spec, force=False)  # empty: fine
    (tmp_path / MANIFEST).write_text('{"digest": "abc"}')
    assert recorded_digest(tmp_path) == "abc"
    with pytest.raises(SpecError, match="holds a sweep of a different spec"):
        check_directory(tmp_path, spec, force=False)
    check_directory(tmp_path, spec, force=True)
    (tmp_path / MANIFEST).write_text(f'{{"digest": "{spec.digest()}"}}')
    check_directory(tmp_path, spec, force=False)


def test_only_chunks_of_this_digest_count_as_done(tmp_path: Path) -> None:
    trials = tmp_path / TRIALS_DIR
    table = pa.table({"trial": [0]})
    write_table(trials / "chunk-a.parquet", table, {"digest": "mine"})
    write_table(trials / "chunk-b.parquet", table, {"digest": "other"})
    (trials / "chunk-c.parquet").write_bytes(b"half a file")
    (trials / ".chunk-d.parquet.x.tmp").write_bytes(b"")
    assert finished_chunks(tmp_path, "mine") == {"chunk-a.parquet"}
    assert sorted(p.name for p in trials.iterdir()) == ["chunk-a.parquet", "chunk-b.parquet"]
    assert PARQUET_META_KEY in pa.parquet.read_schema(trials / "chunk-a.parquet").metadata
    assert read_provenance(trials / "chunk-a.parquet") == {"digest": "mine"}
    clear(tmp_path)
    assert list(trials.iterdir()) == []


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
