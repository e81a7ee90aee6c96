"""Atomic writes and provenance."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from flatcli.storage import (
    UNIT_KEY,
    atomic_path,
    column_units,
    null_where_nan,
    read_provenance,
    run_record,
    to_jsonable,
    with_units,
    write_json,
    write_parquet,
    write_text,
)


def test_atomic_path_leaves_no_file_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "out.txt"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash mid-write")
    assert not target.exists()
    assert list((tmp_path / "sub").iterdir()) == []


def test_atomic_path_replaces_whole_file(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    write_text(target, "old")
    with atomic_path(target) as tmp:
        tmp.write_text("new")
        assert target.read_text() == "old"  # readers see the old file until the rename
    assert target.read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's 0600


def test_json_handles_numpy_and_non_finite(tmp_path: Path) -> None:
    path = tmp_path / "a.json"
    write_json(path, {"b": np.float64(1.5), "a": [np.int64(2), math.inf], "c": np.array([1.0]),
                      "d": np.float64(math.nan)})
    # nan (not applicable) is null; inf (a spec's "no limit") the string TOML spells it with
    assert json.loads(path.read_text()) == {"a": [2, "inf"], "b": 1.5, "c": [1.0], "d": None}
    assert "nan" not in path.read_text().lower()
    assert to_jsonable({"x": (1, math.nan, -math.inf)}) == {"x": [1, None, "-inf"]}


def test_parquet_nulls_for_nan_and_units_as_field_metadata(tmp_path: Path) -> None:
    frame = pd.DataFrame({"t": [0.0, 1.0], "err": [0.5, math.nan], "status": ["ok", "diverged"],
                          "com": [[0.1, 0.0], [0.1, 0.005]]})
    frame.attrs["units"] = {"t": "s", "err": "rad", "com": "m"}
    path = tmp_path / "x.parquet"
    write_parquet(path, frame, {"digest": "abc"})
    table = pq.read_table(path)
    assert table.column("err").null_count == 1
    assert not pc.any(pc.is_nan(table.column("err"))).as_py()
    assert pa.types.is_list(table.schema.field("com").type)
    assert column_units(path) == {"t": "s", "err": "rad", "com": "m"}
    assert read_provenance(path) == {"digest": "abc"}
    # a table built from arrays: nan -> null, units attached to the named fields only
    arrays = pa.table({"a": null_where_nan([1.0, math.nan]), "b": ["x", "y"]})
    table = with_units(arrays, {"a": "kg"})
    assert table.column("a").null_count == 1
    assert table.schema.field("a").metadata == {UNIT_KEY: b"kg"}
    assert table.schema.field("b").metadata is None


def test_parquet_round_trip_with_provenance(tmp_path: Path) -> None:
    frame = pd.DataFrame({"t": np.linspace(0, 1, 5), "status": ["ok"] * 5})
    path = tmp_path / "x.parquet"
    write_parquet(path, frame, {"digest": "abc", "spec": {"name": "x"}})
    pd.testing.assert_frame_equal(pd.read_parquet(path), frame)
    assert read_provenance(path) == {"digest": "abc", "spec": {"name": "x"}}


def test_run_record_has_versions_git_and_time() -> None:
    record = run_record("plan", {"name": "x"}, extra=1)
    assert record["command"] == "plan" and record["extra"] == 1
    assert {"flatcli", "numpy", "scipy", "numba"} <= set(record["versions"])
    assert set(record["git"]) == {"commit", "dirty"}
    assert record["time"].endswith("+00:00")
