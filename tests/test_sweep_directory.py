"""A sweep's directory (flatcli/sweep/directory.py): manifest, resume, provenance."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest

from flatcli.spec import SpecError, resolve
from flatcli.storage import PARQUET_META_KEY, read_provenance, write_table
from flatcli.sweep import MANIFEST, TRIALS_DIR, recorded_digest
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
