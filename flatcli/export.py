"""``flatcli export DIR --csv``: a run's Parquet tables as CSV, for tools without Parquet.

Every ``*.parquet`` directly in DIR (plan.parquet, track.parquet, or a sweep's
trials.parquet and summary.parquet; not a sweep's chunk files) becomes ``<name>.csv`` beside
it, or in ``--out``. Missing values (null or NaN: "not applicable") are empty fields;
numbers are written in the shortest form that reads back to the same float; list and
struct values are JSON text. Every file is written atomically, under the target's lock;
files written into a sweep's directory are recorded in its manifest (``--force`` may then
remove them, as it removes the sweep's own files).
"""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from flatcli.core.errors import FlatcliError
from flatcli.files import kind, not_regular
from flatcli.montecarlo.directory import MANIFEST, RERUN_DIR, record_outputs
from flatcli.storage import atomic_path, check_output_dir, directory_lock


def tables_in(directory: Path) -> list[Path]:
    """The Parquet tables directly in a run's directory, by name (FlatcliError for an entry
    named like one that is not a regular file: it is never opened, a FIFO would block)."""
    if not directory.is_dir():
        raise FlatcliError(f"{directory}: not a directory")
    paths = sorted(directory.glob("*.parquet"))
    blocked = not_regular(directory, [p.name for p in paths])
    if blocked:
        raise FlatcliError(f"{directory} holds {', '.join(blocked)}, not a table flatcli "
                           "wrote; remove it yourself")
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
    """Write every Parquet table of ``directory`` as CSV (beside it, or into ``out``).

    Checked before anything is written: the target can be written, and no entry that is not
    a regular file stands where a CSV file goes. The target's lock is held while writing
    (``flatcli.storage.directory_lock``: not while a sweep writes there); CSV files written
    into a sweep's directory (or a re-run's) are recorded in its manifest, so that
    ``flatcli sweep --force`` knows them as flatcli's.
    """
    paths = tables_in(directory)
    target = out if out is not None else directory
    if target.exists() and not target.is_dir():
        raise FlatcliError(f"--out {target}: is a file")
    check_output_dir(target)
    names = [f"{path.stem}.csv" for path in paths]
    blocked = not_regular(target, names)
    if blocked:
        raise FlatcliError(f"{target} holds {', '.join(blocked)} where export writes; remove "
                           "it yourself, or use another --out")
    sweep = _sweep_of(target)
    written = []
    with directory_lock(sweep if sweep is not None else target):
        for path, name in zip(paths, names, strict=True):
            table = csv_ready(pq.read_table(path))
            csv_path = target / name
            with atomic_path(csv_path) as tmp:
                pacsv.write_csv(table, tmp, pacsv.WriteOptions(quoting_style="needed"))
            written.append(csv_path)
        if sweep is not None:
            record_outputs(sweep, written)
    return written


def _sweep_of(target: Path) -> Path | None:
    """The sweep directory whose manifest lists what is written into ``target``: the target
    itself, or the sweep a re-run directory (``rerun-TRIAL``) belongs to; None for others."""
    if kind(target / MANIFEST) == "file":
        return target
    if RERUN_DIR.fullmatch(target.name) and kind(target.parent / MANIFEST) == "file":
        return target.parent
    return None
