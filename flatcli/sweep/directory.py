"""A sweep's directory: its manifest, its chunk files, what a resume keeps, the final tables.

``sweep.json`` holds the spec's digest (``Spec.digest``); a chunk file under ``trials/`` counts
as done only if its provenance carries the same digest. The final tables (trials.parquet,
summary.parquet, summary.md, run.json) are built from the chunk files alone.
"""

from __future__ import annotations

import json
import resource
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from flatcli.core.metrics import METRIC_NAMES
from flatcli.report import summarize_trials, summary_markdown
from flatcli.spec import Spec, SpecError
from flatcli.storage import (
    atomic_path,
    provenance_metadata,
    read_provenance,
    run_record,
    write_json,
    write_parquet,
    write_text,
)
from flatcli.sweep.chunks import grid_columns
from flatcli.sweep.layout import Layout
from flatcli.units import units_of

MANIFEST = "sweep.json"
TRIALS_DIR = "trials"
#: The files a finished sweep writes beside trials/ (removed by --force).
FINAL_FILES = (MANIFEST, "trials.parquet", "summary.parquet", "summary.md", "run.json")


def recorded_digest(directory: Path) -> str | None:
    """The spec digest of the sweep a directory holds, or None."""
    try:
        return str(json.loads((directory / MANIFEST).read_text())["digest"])
    except (OSError, ValueError, KeyError):
        return None


def check_directory(directory: Path, spec: Spec, force: bool) -> None:
    """Refuse a directory holding a different sweep (unless force); never mix two specs."""
    if not (directory / MANIFEST).exists():
        return
    previous = recorded_digest(directory)
    if previous != spec.digest() and not force:
        raise SpecError(
            f"{directory} holds a sweep of a different spec (spec hash {str(previous)[:12]} "
            f"vs {spec.digest()[:12]}); use --force to start over there, or another --out"
        )


def clear(directory: Path) -> None:
    """Remove a sweep's files from a directory (for --force)."""
    for name in FINAL_FILES:
        (directory / name).unlink(missing_ok=True)
    trials = directory / TRIALS_DIR
    if trials.exists():
        for path in trials.iterdir():
            path.unlink()


def write_manifest(directory: Path, lay: Layout) -> None:
    spec = lay.spec
    write_json(directory / MANIFEST, {
        "digest": spec.digest(), "spec": spec.tree, "cells": len(lay.cells),
        "trials_per_cell": lay.trials_per_cell, "chunk": lay.chunk_size,
    })


def finished_chunks(directory: Path, digest: str) -> set[str]:
    """Names of the complete chunk files of this spec in a directory; stray temp files go."""
    trials = directory / TRIALS_DIR
    done: set[str] = set()
    if not trials.exists():
        return done
    for path in trials.iterdir():
        if path.name.endswith(".tmp"):
            path.unlink(missing_ok=True)
        elif path.suffix == ".parquet":
            try:
                if read_provenance(path).get("digest") == digest:
                    done.add(path.name)
            except (OSError, ValueError, pa.ArrowException):
                path.unlink(missing_ok=True)
    return done


def peak_rss_mib() -> dict[str, float]:
    """Peak resident memory of this process and of its largest child process [MiB]."""
    self_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    child_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return {"main": self_kib / 1024, "largest_child": child_kib / 1024}


def assemble_trials(directory: Path, lay: Layout, provenance: Mapping[str, Any]) -> Path:
    """Concatenate the chunk files, in trial order, into trials.parquet (streamed)."""
    target = directory / "trials.parquet"
    meta = provenance_metadata(provenance)
    writer = None
    with atomic_path(target) as tmp:
        try:
            for chunk in lay.chunks():
                table = pq.read_table(directory / TRIALS_DIR / chunk.name)
                table = table.replace_schema_metadata(meta)
                if writer is None:
                    writer = pq.ParquetWriter(tmp, table.schema)
                writer.write_table(table.cast(writer.schema))
        finally:
            if writer is not None:
                writer.close()
    return target


def finish_sweep(directory: Path, lay: Layout, provenance: Mapping[str, Any], started: float,
                 timing: Mapping[str, Any]) -> str:
    """trials.parquet, summary.parquet, summary.md and run.json from the chunk files.

    ``timing`` gains the end-to-end figures: ``wall_seconds`` from ``started`` (a
    perf_counter time) to the summary, ``trials_per_second`` over it, and
    ``steady_trials_per_second`` over all but the one-time start-up (``setup_seconds``:
    planning the cells, loading the compiled kernel): chunks and final tables.
    """
    finishing = time.perf_counter()
    trials_path = assemble_trials(directory, lay, provenance)
    columns = list(dict.fromkeys(["cell", "status", *METRIC_NAMES]))  # each column once
    frame = pq.read_table(trials_path, columns=columns).to_pandas()
    cells = {c.index: {k: v for k, (_, v) in grid_columns(c.values, c.spec).items()}
             for c in lay.cells}
    summary = summarize_trials(frame, cells)
    summary.attrs["units"] = units_of(summary.columns, lay.spec)
    write_parquet(directory / "summary.parquet", summary, provenance)
    text = summary_markdown(summary, list(cells[lay.cells[0].index]))
    write_text(directory / "summary.md", text + "\n")
    counts = frame["status"].value_counts().to_dict()
    now = time.perf_counter()
    wall = now - started
    simulated = timing["simulated_trials"]
    warm = wall - timing["setup_seconds"]
    timing = {**timing, "finish_seconds": now - finishing, "wall_seconds": wall,
              "trials_per_second": simulated / wall,
              "steady_trials_per_second": simulated / warm if warm > 0 else None,
              "peak_rss_mib": peak_rss_mib()}
    write_json(directory / "run.json", run_record(
        "sweep", lay.spec.tree, digest=lay.spec.digest(), cells=len(lay.cells),
        trials=lay.total, chunk=lay.chunk_size, status_counts=counts, timing=timing,
    ))
    return text
