"""All file output of flatcli: atomic writes, Parquet with provenance, and run records.

Every file is written to a temporary name in its own directory, flushed to disk, then
renamed over its final name, so a reader (or a resumed sweep) sees either the old file or
the complete new one, never a half-written file.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

import flatcli

#: Key of the Parquet schema metadata holding flatcli's provenance (JSON).
PARQUET_META_KEY = b"flatcli"


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it over ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with tmp.open("rb+") as fh:
            os.fsync(fh.fileno())
        tmp.chmod(0o666 & ~_UMASK)  # mkstemp makes 0600; give the file the usual mode
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def to_jsonable(value: Any) -> Any:
    """JSON-ready copy: numpy scalars and arrays as Python values; nan (not applicable) as
    null; inf and -inf as the strings "inf" and "-inf".

    JSON has no inf. The only infinite values flatcli writes are spec values whose inf means
    "no limit" (``track.rate_limit``, ``plan.optimize.angle_limit``, ...): null there would
    read as "not set" (which a nullable key means something else by), and "inf" is how TOML
    spells it and what the spec's canonical JSON (its digest) has always held. Measured values
    are never inf (a trial stops before its state leaves the divergence bound); a metric that
    does not apply is nan, hence null.
    """
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, float) and math.isinf(value):
        return str(value)
    return value


def write_json(path: Path, obj: Any) -> None:
    """Pretty JSON with sorted keys (nan as null, inf as "inf": ``to_jsonable``)."""
    write_text(path, json.dumps(to_jsonable(obj), indent=2, sort_keys=True) + "\n")


def write_parquet(path: Path, frame: pd.DataFrame, provenance: Mapping[str, Any]) -> None:
    """Write a DataFrame as Parquet, with ``provenance`` as JSON in the schema metadata (nan as
    null, units from ``frame.attrs["units"]``: ``arrow_table``)."""
    write_table(path, arrow_table(frame), provenance)


def write_table(path: Path, table: pa.Table, provenance: Mapping[str, Any]) -> None:
    """Write an Arrow table as Parquet, with ``provenance`` as JSON in the schema metadata."""
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                           **provenance_metadata(provenance)})
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)


def provenance_metadata(provenance: Mapping[str, Any]) -> dict[bytes, bytes]:
    """Parquet schema metadata holding ``provenance`` as JSON under ``PARQUET_META_KEY``."""
    return {PARQUET_META_KEY: json.dumps(to_jsonable(provenance), sort_keys=True).encode()}


def read_provenance(path: Path) -> dict[str, Any]:
    """The provenance a Parquet file was written with ({} if none)."""
    meta = pq.read_schema(path).metadata or {}
    raw = meta.get(PARQUET_META_KEY)
    return json.loads(raw) if raw else {}


def git_state() -> dict[str, Any]:
    """The git commit of flatcli's source tree (if a checkout), and whether it is dirty."""
    source = Path(flatcli.__file__).resolve().parent

    def run(*args: str) -> str:
        return subprocess.run(
            ["git", *args], capture_output=True, text=True, timeout=5, check=True, cwd=source
        ).stdout.strip()

    try:
        commit = run("rev-parse", "HEAD")
        dirty = bool(run("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit, "dirty": dirty}


def versions() -> dict[str, str]:
    import numba
    import scipy

    return {
        "flatcli": flatcli.__version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "pandas": pd.__version__,
        "pyarrow": pa.__version__,
    }


def run_record(command: str, spec_tree: Mapping[str, Any], **extra: Any) -> dict[str, Any]:
    """What a run directory's run.json holds: the resolved spec, versions, git, time, host."""
    return {
        "command": command,
        "argv": sys.argv,
        "spec": spec_tree,
        "versions": versions(),
        "git": git_state(),
        "time": datetime.now(UTC).isoformat(timespec="seconds"),
        "host": socket.gethostname(),
        "platform": platform.platform(),
        **extra,
    }


# ---------------------------------------------------------------------------------------
# Nulls and units of the Parquet tables.

#: Key of an Arrow field's metadata holding its column's unit (``flatcli.units``).
UNIT_KEY = b"unit"


def arrow_table(frame: pd.DataFrame) -> pa.Table:
    """An Arrow table of a DataFrame: nan as null (not applicable), and the units of
    ``frame.attrs["units"]`` ({column: unit}, if any) as field metadata (``with_units``)."""
    table = pa.Table.from_pandas(frame, preserve_index=False)  # nan -> null
    return with_units(table, frame.attrs.get("units", {}))


def null_where_nan(values: Any) -> pa.Array:
    """A float column as Arrow, nan (not applicable) as null."""
    return pa.array(np.asarray(values, dtype=np.float64), from_pandas=True)


def with_units(table: pa.Table, units: Mapping[str, str]) -> pa.Table:
    """``table`` with ``units[name]`` under ``UNIT_KEY`` in the metadata of each named field
    (other fields as they were)."""
    fields = []
    for f in table.schema:
        if f.name in units:
            f = f.with_metadata({**(f.metadata or {}), UNIT_KEY: units[f.name].encode()})
        fields.append(f)
    return table.cast(pa.schema(fields, metadata=table.schema.metadata))


def column_units(path: Path) -> dict[str, str]:
    """{column: unit} of a Parquet file's columns that carry one."""
    return {f.name: f.metadata[UNIT_KEY].decode() for f in pq.read_schema(path)
            if f.metadata and UNIT_KEY in f.metadata}
