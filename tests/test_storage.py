"""Atomic writes and provenance."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flatcli.storage import (
    atomic_path,
    read_provenance,
    run_record,
    to_jsonable,
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
    write_json(path, {"b": np.float64(1.5), "a": [np.int64(2), math.inf], "c": np.array([1.0])})
    assert json.loads(path.read_text()) == {"a": [2, "inf"], "b": 1.5, "c": [1.0]}
    assert to_jsonable({"x": (1, math.nan)}) == {"x": [1, "nan"]}


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
