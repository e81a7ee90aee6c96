"""``flatcli export DIR --csv`` / ``--mat``: a run's Parquet tables as CSV or as MATLAB
files, for tools without Parquet.

Every ``*.parquet`` directly in DIR (plan.parquet, track.parquet, or a sweep's
trials.parquet and summary.parquet; not a sweep's chunk files) becomes ``<name>.csv`` or
``<name>.mat`` beside it, or in ``--out``. Every file is written atomically, under the
target's lock; files written into a sweep's directory are recorded in its manifest
(``--force`` may then remove them, as it removes the sweep's own files).

CSV: missing values (null or NaN: "not applicable") are empty fields; numbers are written in
the shortest form that reads back to the same float; list and struct values are JSON text.

MATLAB (``scipy.io.savemat``, format 5, compressed; ``s = load('trials.mat')``):
``s.data`` a struct with one column vector per column (float64; int64 for integers; logical
for flags; a cell array of char for text), ``s.units`` the unit of each numeric column
(the Parquet field's ``unit``: SI, "1" a pure number), ``s.columns`` and ``s.fields`` the
column names and the struct fields they became (a name that is not a MATLAB identifier,
``sweep.perturb.initial.std``, becomes ``sweep_perturb_initial_std``), and ``s.description``
a paragraph saying what the table is and how values are written. Missing values are NaN in
numeric columns (an integer or flag column with a missing value becomes float64) and '' in
text; list and struct values are JSON text.
"""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
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
    def write(path: Path, tmp: Path) -> None:
        table = csv_ready(_read(path))
        pacsv.write_csv(table, tmp, pacsv.WriteOptions(quoting_style="needed"))

    return _export(directory, out, "csv", write)


def export_mat(directory: Path, out: Path | None = None) -> list[Path]:
    """Write every Parquet table of ``directory`` as a MATLAB file (module docstring), with
    the checks, lock and manifest of ``export_csv``."""
    from scipy.io import savemat

    def write(path: Path, tmp: Path) -> None:
        contents = mat_contents(_read(path), path.stem, directory)
        with tmp.open("wb") as handle:
            savemat(handle, contents, do_compression=True, oned_as="column",
                    long_field_names=True)

    return _export(directory, out, "mat", write)


def _export(directory: Path, out: Path | None, suffix: str, write: Any) -> list[Path]:
    paths = tables_in(directory)
    target = out if out is not None else directory
    if target.exists() and not target.is_dir():
        raise FlatcliError(f"--out {target}: is a file")
    check_output_dir(target)
    names = [f"{path.stem}.{suffix}" for path in paths]
    blocked = not_regular(target, names)
    if blocked:
        raise FlatcliError(f"{target} holds {', '.join(blocked)} where export writes; remove "
                           "it yourself, or use another --out")
    sweep = _sweep_of(target)
    written = []
    with directory_lock(sweep if sweep is not None else target):
        # every file goes to its temporary file first and all are renamed together at the
        # end: a table that cannot be read (a damaged trials.parquet) leaves no file of the
        # others behind
        with contextlib.ExitStack() as files:
            for path, name in zip(paths, names, strict=True):
                out_path = target / name
                tmp = files.enter_context(atomic_path(out_path))
                write(path, tmp)
                written.append(out_path)
        if sweep is not None:
            record_outputs(sweep, written)
    return written


def _read(path: Path) -> pa.Table:
    """A Parquet table; FlatcliError naming it if it cannot be read (damaged, truncated, or
    not Parquet), so that nothing is exported."""
    try:
        return pq.read_table(path)
    except (pa.ArrowException, OSError) as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise FlatcliError(f"{path}: not a readable Parquet table ({first}); nothing "
                           "exported") from None


#: What each of flatcli's tables is, for a MATLAB file's description.
TABLES = {
    "plan": "the planned maneuver, one row per sample (time t, angles, rates, flat outputs "
            "and their derivatives, inputs, the singularity margin, the momentum H)",
    "track": "the closed-loop run, one row per recorded sample (time t, the plant's angles "
             "and rates, the reference, the commanded rates, the flat outputs, the margin, "
             "H, joint torques of a dynamic plant, positions)",
    "trials": "a Monte Carlo sweep, one row per trial (its id, grid cell, perturbations "
              "drawn, status and metrics)",
    "summary": "a Monte Carlo sweep's summary, one row per grid cell (counts by status and "
               "statistics of the metrics over its trials)",
    "workspace": "where the end effector can be put, one row per target",
}
#: The longest MATLAB variable or field name.
MATLAB_NAME = 63


def matlab_fields(columns: list[str]) -> list[str]:
    """MATLAB identifiers for column names: other characters as _, a leading non-letter
    prefixed with x, at most 63 characters, made unique with a numeric suffix."""
    out: list[str] = []
    for column in columns:
        name = re.sub(r"\W", "_", column, flags=re.ASCII)
        if not re.match(r"[A-Za-z]", name):
            name = "x" + name
        name = name[:MATLAB_NAME]
        base, count = name, 1
        while name in out:
            count += 1
            tail = f"_{count}"
            name = base[:MATLAB_NAME - len(tail)] + tail
        out.append(name)
    return out


def mat_column(column: pa.ChunkedArray) -> Any:
    """A Parquet column as savemat takes it (module docstring)."""
    kind = column.type
    if pa.types.is_dictionary(kind):
        column = column.cast(kind.value_type)
        kind = column.type
    if pa.types.is_nested(kind):
        return np.array(["" if v is None else json.dumps(v) for v in column.to_pylist()],
                        dtype=object)
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        return np.array(["" if v is None else v for v in column.to_pylist()], dtype=object)
    if pa.types.is_boolean(kind) and column.null_count == 0:
        return np.asarray(column.to_numpy(zero_copy_only=False), dtype=bool)
    if pa.types.is_integer(kind) and column.null_count == 0:
        return np.asarray(column.to_numpy(), dtype=np.int64)
    if pa.types.is_integer(kind) or pa.types.is_floating(kind) or pa.types.is_boolean(kind):
        values = column.cast(pa.float64()).fill_null(float("nan"))
        return np.asarray(values.to_numpy(), dtype=float)
    if pa.types.is_timestamp(kind) or pa.types.is_date(kind):
        return np.array(["" if v is None else v.isoformat() for v in column.to_pylist()],
                        dtype=object)
    return np.array(["" if v is None else str(v) for v in column.to_pylist()], dtype=object)


def mat_contents(table: pa.Table, name: str, directory: Path) -> dict[str, Any]:
    """The variables of a table's MATLAB file: data, units, columns, fields, description."""
    from flatcli import __version__
    from flatcli.storage import UNIT_KEY

    columns = list(table.column_names)
    fields = matlab_fields(columns)
    data = {field: mat_column(table.column(column))
            for field, column in zip(fields, columns, strict=True)}
    units = {}
    for field, schema_field in zip(fields, table.schema, strict=True):
        meta = schema_field.metadata or {}
        unit = meta.get(UNIT_KEY)
        if unit is not None:
            units[field] = unit.decode()
    what = TABLES.get(name, "a table flatcli wrote")
    renamed = sum(f != c for f, c in zip(fields, columns, strict=True))
    description = (
        f"{name}.parquet of {directory} as written by flatcli {__version__}: {what}. "
        f"{table.num_rows} rows, {len(columns)} columns: data.<field> is one column vector "
        "per column (float64; int64 for integers; logical for flags; a cell array of char "
        "for text, lists and structs as JSON text). Missing values (null in the Parquet "
        "file: not applicable) are NaN in numeric columns (an integer or flag column with "
        "one is float64) and '' in text. units.<field> is each numeric column's unit (SI; "
        "'1' a pure number). columns lists the original column names, fields the struct "
        f"fields they became ({renamed} renamed to be MATLAB identifiers). The columns, "
        "metrics and statuses are defined in flatcli's docs/outputs.md.")
    return {"data": data, "units": units, "columns": np.array(columns, dtype=object),
            "fields": np.array(fields, dtype=object), "description": description}


def _sweep_of(target: Path) -> Path | None:
    """The sweep directory whose manifest lists what is written into ``target``: the target
    itself, or the sweep a re-run directory (``rerun-TRIAL``) belongs to; None for others."""
    if kind(target / MANIFEST) == "file":
        return target
    if RERUN_DIR.fullmatch(target.name) and kind(target.parent / MANIFEST) == "file":
        return target.parent
    return None
