"""``flatcli export DIR --csv``: a run's Parquet tables as CSV, for tools without Parquet.

Every ``*.parquet`` directly in DIR (plan.parquet, track.parquet, or a sweep's
trials.parquet and summary.parquet; not a sweep's chunk files) becomes ``<name>.csv`` beside
it, or in ``--out``. Missing values (null or NaN: "not applicable") are empty fields;
numbers are written in the shortest form that reads back to the same float; list and
struct values are JSON text. Every file is written atomically.
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from flatcli.core.model import FlatcliError
from flatcli.storage import atomic_path


def tables_in(directory: Path) -> list[Path]:
    """The Parquet tables directly in a run's directory, by name."""
    if not directory.is_dir():
        raise FlatcliError(f"{directory}: not a directory")
    paths = sorted(directory.glob("*.parquet"))
    if not paths:
        raise FlatcliError(f"{directory}: holds no Parquet tables (a run, a finished sweep or "
                           "a reproduce directory has them)")
    return paths


def csv_ready(table: pa.Table) -> pa.Table:
    """The table with NaN as null and nested values (lists, structs) as JSON text."""
    columns = []
    for name in table.column_names:
        column = table.column(name)
        kind = column.type
        if pa.types.is_floating(kind):
            column = pc.if_else(pc.is_nan(column), pa.scalar(None, kind), column)
        elif pa.types.is_nested(kind):
            column = pa.array([None if v is None else json.dumps(v) for v in column.to_pylist()],
                              type=pa.string())
        columns.append(column)
    return pa.table(columns, names=table.column_names)


def export_csv(directory: Path, out: Path | None = None) -> list[Path]:
    """Write every Parquet table of ``directory`` as CSV (beside it, or into ``out``)."""
    paths = tables_in(directory)
    target = out if out is not None else directory
    if target.exists() and not target.is_dir():
        raise FlatcliError(f"--out {target}: is a file")
    written = []
    for path in paths:
        table = csv_ready(pq.read_table(path))
        csv_path = target / f"{path.stem}.csv"
        with atomic_path(csv_path) as tmp:
            pacsv.write_csv(table, tmp, pacsv.WriteOptions(quoting_style="needed"))
        written.append(csv_path)
    return written
