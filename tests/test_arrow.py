"""Arrow columns without pyarrow's pandas shim (flatcli/arrow.py): the referee is pyarrow's
own conversion of the same values (pa.array, Array.to_numpy, pq.read_table)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from flatcli.arrow import (
    flags,
    floats,
    null_mask,
    number_lists,
    numbers,
    read_parquet,
    repeated,
    texts,
    to_numpy,
)

VALUES = np.array([1.5, np.nan, -3.0, 0.0, np.nan, 7.25, 1e300, -0.0, 2.0])


def test_built_columns_are_those_pyarrow_makes_of_the_same_values() -> None:
    assert numbers(VALUES).equals(pa.array(VALUES, from_pandas=True))
    counts = np.array([3, 0, 7, -2])
    missing = np.array([False, True, False, False])
    assert numbers(counts, pa.int64(), missing).equals(pa.array(counts, mask=missing))
    assert numbers(counts, pa.int64()).equals(pa.array(counts))
    bits = np.array([True, False, True, True, False, False, True, False, True, True])
    assert flags(bits).equals(pa.array(bits))
    words = ["ok", None, "singular", "", "é ü"]
    assert texts(words).equals(pa.array(words, pa.string()))
    assert texts(words, large=True).equals(pa.array(words, pa.large_string()))
    lists = [[0.1, 0.2], None, [], [3.0]]
    assert number_lists(lists).equals(pa.array(lists, pa.list_(pa.float64())))
    for value, kind in ((2.5, pa.float64()), (4, pa.int64()), (True, pa.bool_()),
                        ("dynamic", pa.string()), ([1.0, 2.0], pa.list_(pa.float64())),
                        (None, pa.float64()), (None, pa.list_(pa.float64()))):
        assert repeated(value, kind, 5).equals(pa.array([value] * 5, kind)), (value, kind)


@pytest.mark.parametrize("kind", [pa.float64(), pa.int64(), pa.int32(), pa.bool_()])
def test_columns_read_back_as_pyarrow_reads_them(kind: pa.DataType) -> None:
    raw = [1, None, 0, 5, None, 2, 1, 1, 0, 3, None] if kind != pa.bool_() else [
        True, None, False, True, None, True, True, False, False, True, None]
    column = pa.array(raw, kind)
    for array in (column, column.slice(3), pa.chunked_array([column.slice(0, 4),
                                                             column.slice(4)])):
        theirs = array.fill_null(False if kind == pa.bool_() else 0).to_numpy(
            zero_copy_only=False)
        ours = to_numpy(array)
        assert ours.dtype == theirs.dtype and np.array_equal(ours, theirs)
        assert np.array_equal(null_mask(array), array.is_null().to_numpy(zero_copy_only=False))
    if kind != pa.bool_():
        expected = column.cast(pa.float64()).to_numpy(zero_copy_only=False)
        assert np.array_equal(floats(column), expected, equal_nan=True)


def test_parquet_read_as_pq_read_table_reads_it(tmp_path: Path) -> None:
    table = pa.table({"a": numbers(VALUES), "b": texts(["x"] * len(VALUES))})
    pq.write_table(table, tmp_path / "t.parquet")
    assert read_parquet(tmp_path / "t.parquet").equals(pq.read_table(tmp_path / "t.parquet"))
    assert read_parquet(tmp_path / "t.parquet", ["b"]).column_names == ["b"]


def test_none_of_it_loads_pandas(tmp_path: Path) -> None:
    code = (
        "import sys, numpy as np, pyarrow as pa, pyarrow.parquet as pq\n"
        "from pathlib import Path\n"
        "from flatcli.arrow import floats, numbers, read_parquet, repeated, texts, to_numpy\n"
        "t = pa.table({'a': numbers(np.array([1.0, np.nan])), 'b': texts(['x', None]),\n"
        "              'c': repeated([1.0], pa.list_(pa.float64()), 2)})\n"
        f"path = Path({str(tmp_path)!r}) / 't.parquet'\n"
        "pq.write_table(t, path)\n"
        "back = read_parquet(path)\n"
        "floats(back.column('a')), to_numpy(back.column('a'))\n"
        "print('pandas' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert done.stdout.strip() == "False"
