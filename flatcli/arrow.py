"""Arrow columns from numpy and Python values, and numpy arrays from Arrow columns, without
pyarrow's pandas shim.

pyarrow imports pandas (about 0.3 s) the first time ``pa.array``, ``Array.to_numpy`` or
``Array.fill_null`` is called, to ask whether its argument is a pandas object, and
``pq.read_table`` imports it through ``pyarrow.dataset``. A sweep's processes need none of
pandas, so the tables they write and read go through these few functions instead, which
build arrays from their buffers (``pa.Array.from_buffers``) and read them back the same way.
The arrays are those ``pa.array`` makes of the same values (tests/test_arrow.py compares
them with pyarrow's own conversions); readers outside a sweep keep using pyarrow and pandas.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

FLOAT64 = pa.float64()


def _validity(valid: NDArray[np.bool_] | None) -> tuple[pa.Buffer | None, int]:
    """The validity bitmap of ``valid`` (None: all valid) and the count of nulls."""
    if valid is None or valid.all():
        return None, 0
    bits = np.packbits(np.ascontiguousarray(valid, dtype=bool), bitorder="little")
    return pa.py_buffer(bits), int(np.count_nonzero(~valid))


def numbers(values: Any, kind: pa.DataType = FLOAT64,
            null: NDArray[np.bool_] | None = None) -> pa.Array:
    """A float64 (or int64) column of ``values``, null where ``null`` is True; for float64
    without ``null``, null where a value is nan (not applicable), as ``null_where_nan``."""
    dtype = np.float64 if pa.types.is_floating(kind) else np.int64
    data = np.ascontiguousarray(values, dtype=dtype)
    if null is None and dtype is np.float64:
        null = np.isnan(data)
    valid = None if null is None else ~np.asarray(null, dtype=bool)
    bitmap, nulls = _validity(valid)
    return pa.Array.from_buffers(pa.float64() if dtype is np.float64 else pa.int64(),
                                 len(data), [bitmap, pa.py_buffer(data)], null_count=nulls)


def flags(values: Any) -> pa.Array:
    """A bool column of ``values`` (no nulls)."""
    data = np.ascontiguousarray(values, dtype=bool)
    bits = np.packbits(data, bitorder="little")
    return pa.Array.from_buffers(pa.bool_(), len(data), [None, pa.py_buffer(bits)],
                                 null_count=0)


def texts(values: Sequence[str | None], large: bool = False) -> pa.Array:
    """A string column of ``values`` (None: null); ``large``: large_string (int64 offsets)."""
    encoded = [b"" if v is None else v.encode() for v in values]
    offsets = np.zeros(len(encoded) + 1, dtype=np.int64 if large else np.int32)
    np.cumsum([len(e) for e in encoded], out=offsets[1:])
    bitmap, nulls = _validity(np.array([v is not None for v in values], dtype=bool))
    return pa.Array.from_buffers(pa.large_string() if large else pa.string(), len(encoded),
                                 [bitmap, pa.py_buffer(offsets), pa.py_buffer(b"".join(encoded))],
                                 null_count=nulls)


def repeated(value: Any, kind: pa.DataType, count: int) -> pa.Array:
    """A column of ``count`` copies of one value of type ``kind`` (float64, int64, bool,
    string, list<float64>; None: nulls)."""
    if value is None:
        return pa.nulls(count, kind)
    if pa.types.is_floating(kind) or pa.types.is_integer(kind):
        return numbers(np.full(count, value), kind, np.zeros(count, dtype=bool))
    if pa.types.is_boolean(kind):
        return flags(np.full(count, bool(value)))
    if pa.types.is_string(kind):
        return texts([str(value)] * count)
    if pa.types.is_list(kind):
        items = np.asarray(value, dtype=np.float64)
        offsets = numbers(np.arange(count + 1) * len(items), pa.int64(),
                          np.zeros(count + 1, dtype=bool)).cast(pa.int32())
        return pa.ListArray.from_arrays(offsets, numbers(np.tile(items, count),
                                                         null=np.zeros(count * len(items),
                                                                       dtype=bool)))
    raise TypeError(f"no repeated column of type {kind}")


def number_lists(values: Sequence[Sequence[float] | None]) -> pa.Array:
    """A list<float64> column of ``values`` (None: null)."""
    sizes = [0 if v is None else len(v) for v in values]
    offsets = np.zeros(len(values) + 1, dtype=np.int32)
    np.cumsum(sizes, out=offsets[1:])
    items = [float(x) for v in values if v is not None for x in v]
    bitmap, nulls = _validity(np.array([v is not None for v in values], dtype=bool))
    child = numbers(items, null=np.zeros(len(items), dtype=bool))
    return pa.Array.from_buffers(pa.list_(pa.float64()), len(values),
                                 [bitmap, pa.py_buffer(offsets)], null_count=nulls,
                                 children=[child])


def to_numpy(column: pa.Array | pa.ChunkedArray) -> NDArray[Any]:
    """A numeric or bool column as numpy (int64, float64, bool, ...), nulls as 0 (False); a
    copy, so it may be written to. ``null_mask`` says where the nulls were."""
    array = _one_chunk(column)
    kind = array.type
    buffers = array.buffers()
    n, offset = len(array), array.offset
    if pa.types.is_boolean(kind):
        bits = np.unpackbits(np.frombuffer(buffers[1], dtype=np.uint8), bitorder="little")
        out: NDArray[Any] = bits[offset:offset + n].astype(bool)
    elif pa.types.is_integer(kind) or pa.types.is_floating(kind):
        code = "f" if pa.types.is_floating(kind) else "i" if pa.types.is_signed_integer(
            kind) else "u"
        dtype = np.dtype(f"<{code}{kind.bit_width // 8}")
        out = np.frombuffer(buffers[1], dtype=dtype, count=n, offset=offset * dtype.itemsize
                            ).copy()
    else:
        raise TypeError(f"to_numpy: a numeric or bool column expected, got {kind}")
    if array.null_count:
        out[null_mask(array)] = 0
    return out


def null_mask(column: pa.Array | pa.ChunkedArray) -> NDArray[np.bool_]:
    """Where a column is null (bool, one per value)."""
    array = _one_chunk(column)
    bitmap = array.buffers()[0]
    if bitmap is None or array.null_count == 0:
        return np.zeros(len(array), dtype=bool)
    bits = np.unpackbits(np.frombuffer(bitmap, dtype=np.uint8), bitorder="little")
    return ~bits[array.offset:array.offset + len(array)].astype(bool)


def floats(column: pa.Array | pa.ChunkedArray) -> NDArray[np.float64]:
    """A numeric column as float64, nan where null."""
    out = np.asarray(to_numpy(column), dtype=np.float64)
    out[null_mask(column)] = np.nan
    return out


def _one_chunk(column: pa.Array | pa.ChunkedArray) -> pa.Array:
    if isinstance(column, pa.ChunkedArray):
        if column.num_chunks == 1:
            return column.chunk(0)
        if column.num_chunks == 0:
            return pa.nulls(0, column.type)
        return column.combine_chunks()
    return column


def read_parquet(path: Path, columns: Sequence[str] | None = None) -> pa.Table:
    """A Parquet file as an Arrow table (``pq.ParquetFile``, not ``pq.read_table``, which
    loads pandas through ``pyarrow.dataset``)."""
    with pq.ParquetFile(path) as file:
        return file.read(columns=None if columns is None else list(columns))
