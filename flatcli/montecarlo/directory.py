"""A sweep's directory: its manifest, its verified chunk files, what a resume keeps, what
``--force`` may remove, and the final tables.

``sweep.json`` (the manifest) holds the spec, its digest, every cell this directory has
held (key, digest, grid values, chunk files) and every other file flatcli wrote there. A
chunk file under ``trials/`` carries in its Parquet metadata the digest of its cell, its
trial range and a checksum of its content (``flatcli.storage.table_checksum``); on a resume
a chunk counts as done only if all three match, else it is computed again, and the run says
so. A directory holding another spec is refused, naming the keys that differ; one whose
spec differs only in grid values is extended, reusing the cells it has finished. ``--force``
removes only files the manifest lists (or, without a manifest, files whose content shows
flatcli wrote them), never follows a symbolic link, and refuses when the directory holds
anything else. The final tables (trials.parquet, summary.parquet, summary.md, run.json) hold
the chunks' rows alone: trials.parquet grows under a temporary name while the chunks come in
(``TrialsAssembly``) and takes its name when the last is in.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import stat
import sys
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from flatcli.arrow import read_parquet, repeated, to_numpy
from flatcli.core.loop.metrics import OUTCOME_NAMES
from flatcli.files import (
    MAX_MANIFEST_BYTES,
    UnreadableFileError,
    inside,
    is_regular,
    kind,
    not_regular,
    read_bounded,
    real_directory,
)
from flatcli.montecarlo.chunks import grid_columns
from flatcli.montecarlo.layout import KEY_SPACE, Cell, Chunk, Layout, chunk_name
from flatcli.report.summary import (
    SUMMARY_INPUTS,
    Columns,
    ColumnsOf,
    error_reasons,
    grid_columns_of,
    headline,
    summary_markdown,
    summary_rows,
    summary_table,
    totals_text,
)
from flatcli.spec import SpecError
from flatcli.spec.limits import ID_STRIDE
from flatcli.spec.schema import experiment
from flatcli.spec.tree import flatten
from flatcli.storage import (
    LOCK_NAME,
    PARQUET_META_KEY,
    SETUP_LOCK_NAME,
    SHARD_LOCK,
    atomic_path,
    fsync_directory,
    naming_os_errors,
    parquet_options,
    peak_memory_mib,
    provenance_metadata,
    read_provenance,
    run_record,
    table_checksum,
    to_jsonable,
    write_json,
    write_table,
    write_text,
)
from flatcli.units import units_of

MANIFEST = "sweep.json"
TRIALS_DIR = "trials"
#: Version of sweep.json's layout (a manifest without one was written before cell keys).
FORMAT = 2
#: The files a sweep writes beside trials/ (removed by --force).
FINAL_FILES = (MANIFEST, "trials.parquet", "summary.parquet", "summary.md", "run.json")
#: The sweep's figures (``flatcli.report.plot_sweep``, also run by ``make reproduce``),
#: flatcli's wherever they were recorded or not.
FIGURES = re.compile(r"sweep_[a-z_]+\.(?:png|pdf|svg)")
_CHUNK = re.compile(r"chunk-[0-9]{10}-[0-9]{9}\.parquet")
_LEGACY_CHUNK = re.compile(r"chunk-[0-9]{12}\.parquet")
#: The CSV and MATLAB copies ``flatcli export DIR --csv`` / ``--mat`` writes of a sweep's
#: tables (recorded in the manifest, so --force may remove them).
EXPORTS = ("trials.csv", "summary.csv", "cells.csv", "trials.mat", "summary.mat", "cells.mat")
#: The files ``flatcli sweep --rerun TRIAL`` writes into DIR/rerun-TRIAL/ (and its export).
RERUN_FILES = ("track.parquet", "metrics.json", "run.json", "track.png", "track.pdf",
               "track.svg", "track.csv", "track.mat")
#: The directory ``flatcli sweep --rerun TRIAL`` writes into.
RERUN_DIR = re.compile(r"rerun-[0-9]{1,19}")
#: A directory of a nested sweep: the kinematic twin of reproduce's actuators study.
NESTED = "kinematic"


def _either(names: Iterable[str]) -> str:
    return "|".join(re.escape(n) for n in names)


#: Every name a manifest may list, relative to the sweep's directory: the exact forms flatcli
#: writes there (its final files, lock, figures, exports, chunks, a re-run's files, and those
#: of the nested sweep ``NESTED``). Nothing else is ever removed by --force.
_TOP_FILES = (*FINAL_FILES, LOCK_NAME, "cells.parquet", *EXPORTS)
RECORDED = re.compile(
    rf"(?:{NESTED}/)?(?:{_either(_TOP_FILES)}"
    rf"|{FIGURES.pattern}|{TRIALS_DIR}/{_CHUNK.pattern}|{TRIALS_DIR}/{_LEGACY_CHUNK.pattern})"
    rf"|{RERUN_DIR.pattern}/(?:{_either(RERUN_FILES)})")
#: How many problems a refusal or a note names before it says "and N more".
SHOWN = 3


def recorded_digest(directory: Path) -> str | None:
    """The spec digest of the sweep a directory holds, or None (none, or not readable)."""
    try:
        manifest = read_manifest(directory)
    except SpecError:
        return None
    return None if manifest is None else str(manifest["digest"])


def _listing(items: list[str]) -> str:
    shown = ", ".join(items[:SHOWN])
    return shown + (f" and {len(items) - SHOWN} more" if len(items) > SHOWN else "")


# ---------------------------------------------------------------------------------------
# What a directory holds already.

@dataclass
class Previous:
    """What flatcli finds in a directory before a sweep starts there.

    Attributes
    ----------
    spec : the spec tree its files were written with (None: nothing of flatcli's)
    digest : that spec's digest
    legacy : written by a flatcli before cell keys (other chunk names: nothing reusable)
    cells : cell key (text) -> {"digest", "values", "chunks"} of every cell it has held
    files : other files flatcli wrote there, relative to the directory
    """

    spec: dict[str, Any] | None = None
    digest: str | None = None
    legacy: bool = False
    cells: dict[str, dict[str, Any]] = field(default_factory=dict)
    files: set[str] = field(default_factory=set)
    others: list[dict[str, Any]] = field(default_factory=list)  # more specs, no manifest
    tags: list[str] = field(default_factory=list)  # the sweep's labels (--tag)

    def owned(self, directory: Path | None = None) -> set[str]:
        """Relative paths flatcli wrote (or would write) here (with ``directory``: also the
        sweep's figures there)."""
        names = {LOCK_NAME, *self.files}
        if self.spec is not None:
            names.update(FINAL_FILES)
            if directory is not None:
                names.update(p.name for p in _entries(directory) if FIGURES.fullmatch(p.name))
        for cell in self.cells.values():
            names.update(f"{TRIALS_DIR}/{c}" for c in cell.get("chunks", []))
        return names


def read_manifest(directory: Path) -> dict[str, Any] | None:
    """A directory's sweep.json (None if it has none), every name in it checked
    (``manifest_problem``); SpecError if it is not a regular file, too large, not JSON, or
    not a manifest flatcli wrote."""
    path = directory / MANIFEST
    if kind(path) == "missing":
        return None
    try:
        data = json.loads(read_bounded(path, MAX_MANIFEST_BYTES))
    except UnreadableFileError as exc:
        problem: str | None = exc.reason
    except (ValueError, RecursionError):
        problem = "not JSON"
    else:
        problem = manifest_problem(data)
    if problem is not None:
        raise SpecError(f"{path} is not a flatcli sweep manifest ({problem}); nothing was "
                        "removed; remove it yourself or use another --out")
    return dict(data)


def _count(value: Any, most: int | None = None) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1 and (
        most is None or value <= most)


def _strings(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, str) for v in value)


def manifest_problem(data: Any) -> str | None:
    """Why ``data`` (a parsed sweep.json) is not a manifest flatcli wrote, or None.

    Every name it lists must have one of the exact forms flatcli writes (``RECORDED``;
    a cell's chunks: ``chunk-KKKKKKKKKK-IIIIIIIII.parquet`` with that cell's key), so that
    no name can reach outside the directory (no "..", no absolute path, no other file).
    """
    if not isinstance(data, dict):
        return "not a JSON object"
    if not isinstance(data.get("digest"), str) or not isinstance(data.get("spec"), dict):
        return "no digest and spec"
    files = data.get("files", [])
    if not _strings(files):
        return "its files are not a list of names"
    if not _strings(data.get("tags", [])):
        return "its tags are not a list of text"
    for name in files:
        if not RECORDED.fullmatch(name):
            return f"it lists {name[:80]!r}, not a file flatcli writes in a sweep's directory"
    if data.get("format") != FORMAT:  # before cell keys: counts only, chunks found by name
        for key in ("cells", "trials_per_cell", "chunk"):
            if key in data and not _count(data[key]):
                return f"its {key} is not a positive integer"
        return None
    cells = data.get("cells")
    if not isinstance(cells, dict):
        return "its cells are not a table"
    for key, cell in cells.items():
        if not re.fullmatch(r"[0-9]{1,10}", key) or int(key) >= KEY_SPACE:
            return f"{key[:20]!r} is not a cell key (an integer below 2^32)"
        if not isinstance(cell, dict) or not isinstance(cell.get("digest"), str) \
                or not isinstance(cell.get("values", {}), dict):
            return f"cell {key} has no digest and values"
        chunks = cell.get("chunks", [])
        prefix = f"chunk-{int(key):010d}-"
        if not _strings(chunks):
            return f"the chunks of cell {key} are not a list of names"
        for name in chunks:
            if not (name.startswith(prefix) and _CHUNK.fullmatch(name)):
                return (f"cell {key} lists the chunk {name[:80]!r}, not a chunk file name of "
                        "that cell")
    grid = data.get("grid_cells")
    if not isinstance(grid, list) or not all(isinstance(k, str) and k in cells for k in grid):
        return "its grid_cells are not keys of its cells"
    if not _count(data.get("trials_per_cell"), ID_STRIDE) or not _count(data.get("chunk")):
        return "its trials_per_cell and chunk are not positive integers"
    return None


def _chunk_provenance(path: Path) -> dict[str, Any] | None:
    """The provenance of a chunk file flatcli wrote, or None if it is not one."""
    try:
        if not is_regular(path):
            return None
        meta = read_provenance(path)
    except (OSError, ValueError, pa.ArrowException):
        return None
    return meta if isinstance(meta.get("digest"), str) and isinstance(meta.get("spec"), dict) \
        else None


def survey(directory: Path) -> Previous:
    """What ``directory`` holds of flatcli's: from its manifest, or, if that is missing,
    from the provenance of the files themselves."""
    manifest = read_manifest(directory)
    trials = directory / TRIALS_DIR
    if manifest is not None:
        if manifest.get("format") != FORMAT:  # before cell keys: other chunk names
            legacy = {f"{TRIALS_DIR}/{p.name}" for p in _entries(trials)
                      if _LEGACY_CHUNK.fullmatch(p.name) and is_regular(p)}
            return Previous(manifest["spec"], manifest["digest"], True, {}, legacy)
        cells = {str(k): v for k, v in dict(manifest.get("cells", {})).items()}
        files = {str(f) for f in manifest.get("files", [])}
        tags = [str(t) for t in manifest.get("tags", [])]
        return Previous(manifest["spec"], manifest["digest"], False, cells, files, tags=tags)
    found = Previous()
    for path in sorted(_entries(trials)):
        if not (_CHUNK.fullmatch(path.name) or _LEGACY_CHUNK.fullmatch(path.name)):
            continue
        meta = _chunk_provenance(path)
        if meta is None:
            continue
        _adopt(found, meta)
        if _LEGACY_CHUNK.fullmatch(path.name):
            found.legacy = True
            found.files.add(f"{TRIALS_DIR}/{path.name}")
        elif "cell_key" in meta:
            cell = found.cells.setdefault(str(meta["cell_key"]), {
                "digest": meta.get("cell_digest"), "values": meta.get("values", {}),
                "chunks": []})
            cell["chunks"].append(path.name)
    for name in ("trials.parquet", "summary.parquet"):
        meta = _chunk_provenance(directory / name)
        if meta is not None:
            _adopt(found, meta)
    return found


def _adopt(found: Previous, meta: Mapping[str, Any]) -> None:
    if found.spec is None:
        found.spec, found.digest = dict(meta["spec"]), str(meta["digest"])
    elif meta["digest"] != found.digest and meta["spec"] not in found.others:
        found.others.append(dict(meta["spec"]))


def _entries(directory: Path) -> list[Path]:
    """The entries of a real directory (not through a symbolic link); [] otherwise."""
    try:
        if directory.is_symlink() or not directory.is_dir():
            return []
        return list(directory.iterdir())
    except OSError:
        return []


# ---------------------------------------------------------------------------------------
# Comparing specs.

def _flat(tree: Mapping[str, Any]) -> dict[str, Any]:
    """A spec tree's dotted keys, its tables entered but the grid (one value)."""
    return flatten(tree, lambda dotted, table: bool(table) and dotted != "sweep.grid")


def _show(value: Any) -> str:
    text = "(unset)" if value is _MISSING else json.dumps(to_jsonable(value))
    return text if len(text) <= 40 else text[:37] + "..."


_MISSING = object()


def spec_differences(old: Mapping[str, Any], new: Mapping[str, Any]
                     ) -> tuple[list[str], list[str]]:
    """The keys whose values differ between two spec trees, as ``key (old -> new)``; and,
    separately, the grid keys whose lists of values differ (the grid's keys being the same).
    A change of the grid's keys is a key difference of ``sweep.grid``; how figures are drawn
    (``PRESENTATION``) is not compared."""
    a = _flat(to_jsonable(experiment(old)))
    b = _flat(to_jsonable(experiment(new)))
    keys: list[str] = []
    grid: list[str] = []
    for dotted in sorted({*a, *b}):  # alphabetical, whatever order either tree has
        x, y = a.get(dotted, _MISSING), b.get(dotted, _MISSING)
        if x == y:
            continue
        if dotted == "sweep.grid" and isinstance(x, dict) and isinstance(y, dict) \
                and set(x) == set(y):
            grid.extend(f"sweep.grid.{k!r}" for k in x if x[k] != y[k])
        elif dotted == "sweep.grid":
            old_keys = list(x) if isinstance(x, dict) else []
            new_keys = list(y) if isinstance(y, dict) else []
            keys.append(f"sweep.grid (keys {old_keys} -> {new_keys})")
        else:
            keys.append(f"{dotted} ({_show(x)} -> {_show(y)})")
    return keys, grid


# ---------------------------------------------------------------------------------------
# Before a sweep writes anything: may it, and what does it keep?

@dataclass(frozen=True)
class Plan:
    """What a sweep does with its directory: ``mode`` is "fresh" (nothing of flatcli's
    there), "resume" (the same spec), "extend" (the same spec but for grid values: finished
    cells are reused), or "restart" (--force: flatcli's files there are removed first)."""

    mode: str
    previous: Previous
    note: str = ""


def _temporary_of(name: str) -> str | None:
    """The file a temporary file of ``atomic_path`` (``.NAME.random.tmp``) was for."""
    if name.startswith(".") and name.endswith(".tmp"):
        return name[1:-4].rpartition(".")[0] or None
    return None


def _shard_lock(name: str) -> bool:
    """Whether ``name`` is one of the lock files of a sweep's shards (one left by a killed
    shard stays, harmless: ``storage.shard_locks``)."""
    return name == SETUP_LOCK_NAME or SHARD_LOCK.fullmatch(name) is not None


def foreign_entries(directory: Path, owned: Iterable[str]) -> list[str]:
    """Entries under ``directory`` that flatcli did not write (a symbolic link counts as
    one wherever it is, and is never followed), as paths relative to it."""
    owned = set(owned)
    parents = {str(Path(p).parent) for p in owned} | {TRIALS_DIR}
    out: list[str] = []

    def walk(path: Path, rel: str) -> None:
        for entry in sorted(path.iterdir()):
            name = f"{rel}{entry.name}"
            mode = entry.lstat().st_mode
            if stat.S_ISDIR(mode) and name in parents:
                walk(entry, f"{name}/")
            elif stat.S_ISREG(mode) and (name in owned or
                                         f"{rel}{_temporary_of(entry.name)}" in owned
                                         or (not rel and _shard_lock(entry.name))):
                continue
            else:
                out.append(name + ("/" if stat.S_ISDIR(mode) else ""))

    if directory.is_dir():
        walk(directory, "")
    return out


def _not_regular(directory: Path, lay: Layout) -> list[str]:
    """Entries where a sweep of ``lay`` reads or writes its files (the manifest, the final
    tables, this layout's chunks) that are not regular files: a directory, a FIFO, a device,
    a symbolic link; each as ``name (what it is)``."""
    chunks = {c.name for c in lay.chunks()}
    present = [f"{TRIALS_DIR}/{p.name}" for p in _entries(directory / TRIALS_DIR)
               if p.name in chunks]
    return not_regular(directory, [*FINAL_FILES, *sorted(present)])


def plan_directory(directory: Path, lay: Layout, force: bool) -> Plan:
    """Decide what a sweep of ``lay`` may do in ``directory``; SpecError (nothing written)
    if it may not: another spec there (naming the keys that differ) unless --force, files
    flatcli did not write where it would write or, with --force, anywhere in it."""
    if os.path.lexists(directory) and not directory.is_dir():
        raise SpecError(f"--out {directory}: exists and is not a directory")
    trials = directory / TRIALS_DIR
    if os.path.lexists(trials) and (trials.is_symlink() or not trials.is_dir()):
        raise SpecError(f"{trials} is not a directory flatcli made (a symbolic link or a "
                        "file); remove it yourself or use another --out")
    blocked = _not_regular(directory, lay)
    if blocked:
        raise SpecError(f"{directory} holds {_listing(blocked)} where flatcli keeps its own "
                        "files; flatcli neither opens nor replaces such an entry; remove it "
                        "yourself or use another --out")
    previous = survey(directory) if directory.is_dir() else Previous()
    spec = lay.spec
    if force:
        foreign = foreign_entries(directory, previous.owned(directory))
        if foreign:
            raise SpecError(f"--force: {directory} holds files flatcli did not write "
                            f"({_listing(foreign)}); nothing was removed; move them away or "
                            "use another --out")
    if previous.spec is None:
        ours = [*FINAL_FILES, *(f"{TRIALS_DIR}/{c.name}" for c in lay.chunks())]
        taken = [n for n in ours if os.path.lexists(directory / n)]
        if taken:
            raise SpecError(f"{directory} holds files flatcli's sweep did not write where it "
                            f"would write ({_listing(taken)}); use another --out")
        return Plan("fresh", previous)
    if force:
        return Plan("restart", previous)
    if previous.legacy:
        raise SpecError(f"{directory} holds a sweep written by an older flatcli (other chunk "
                        "names); use --force to start over there, or another --out")
    grid: list[str] = []
    for tree in (previous.spec, *previous.others):
        keys, changed = spec_differences(tree, spec.tree)
        if keys:
            raise SpecError(f"{directory} holds a sweep of a different spec (keys that differ: "
                            f"{_listing(keys)}); use --force to start over there, or another "
                            "--out")
        grid = grid or changed
    if not grid and not previous.others and previous.digest == spec.digest():
        return Plan("resume", previous)
    before = sum(previous.cells.get(str(c.key), {}).get("digest") == c.digest
                 for c in lay.cells)
    note = (f"note: {directory} holds this study with other grid values "
            f"({_listing(grid)}); {before} of the {len(lay.cells)} cells were computed there "
            "before, and their finished chunks are reused")
    return Plan("extend", previous, note if grid else "")


def clear(directory: Path, previous: Previous) -> None:
    """Remove flatcli's files from a directory (for --force): the files ``previous`` lists,
    their temporary files, and directories they leave empty (not trials/ or the lock).

    Only regular files are removed, each at a name of the forms flatcli writes
    (``manifest_problem``), reached through real directories only: never through a symbolic
    link, never outside ``directory``.
    """
    owned = previous.owned(directory)
    for name in sorted(owned - {LOCK_NAME}):
        path = inside(directory, name)
        if path is not None and is_regular(path):
            path.unlink()
    for rel in sorted({str(Path(n).parent) for n in owned}, reverse=True):
        parent = real_directory(directory, rel)
        if parent is None:
            continue
        for entry in _entries(parent):
            target = _temporary_of(entry.name)
            if target is not None and str(Path(rel) / target) in owned and is_regular(entry):
                entry.unlink(missing_ok=True)
        if parent not in (directory, directory / TRIALS_DIR):
            with contextlib.suppress(OSError):
                parent.rmdir()


def write_manifest(directory: Path, lay: Layout, previous: Previous | None = None,
                   tags: list[str] | None = None) -> list[str]:
    """sweep.json: this spec, every cell and file this directory holds of flatcli's (the
    previous ones kept when the sweep extends the directory's study), the keys of this
    spec's cells in the grid's order (``grid_cells``) and the sweep's tags (those given, or
    the ones the directory's sweep had); the tags written."""
    spec = lay.spec
    if not tags:
        tags = list(previous.tags) if previous is not None else []
    cells = dict(previous.cells) if previous is not None else {}
    for cell in lay.cells:
        cells[str(cell.key)] = {"digest": cell.digest, "values": to_jsonable(cell.values),
                                "chunks": [c.name for c in lay.cell_chunks(cell)]}
    files = sorted({*FINAL_FILES, *(previous.files if previous is not None else ())})
    write_json(directory / MANIFEST, {
        "format": FORMAT, "digest": spec.digest(), "spec": spec.tree,
        "cells": dict(sorted(cells.items())),
        "grid_cells": [str(cell.key) for cell in lay.cells],
        "trials_per_cell": lay.trials_per_cell,
        "chunk": lay.chunk_size, "files": files, **({"tags": tags} if tags else {}),
    })
    return tags


def record_outputs(directory: Path, paths: Iterable[Path]) -> None:
    """Add files written into a sweep's directory after it finished (figures, re-runs,
    exports) to its manifest, so that --force may remove them. Only names of the forms
    flatcli writes there (``RECORDED``) are recorded; anything else is left out (and stays
    the user's: --force then refuses, naming it)."""
    manifest = read_manifest(directory)
    if manifest is None or manifest.get("format") != FORMAT:
        return
    names = set(manifest.get("files", []))
    for path in paths:
        try:
            name = path.relative_to(directory).as_posix()
        except ValueError:
            try:
                name = path.resolve().relative_to(directory.resolve()).as_posix()
            except ValueError:
                continue
        if RECORDED.fullmatch(name) and is_regular(directory / name):
            names.add(name)
    manifest["files"] = sorted(names)
    write_json(directory / MANIFEST, manifest)


# ---------------------------------------------------------------------------------------
# Chunks: written with what verifies them, verified before they are reused.

def chunk_provenance(base: Mapping[str, Any], cell: Cell, chunk: Chunk, table: pa.Table,
                     checksum: str | None = None) -> dict[str, Any]:
    """What a chunk file records about itself: the sweep's provenance, its cell's key,
    digest and grid values, its trial range and its content's checksum (``checksum``, the
    table's as its worker computed it, or computed here)."""
    return {**base, "cell_key": cell.key, "cell_digest": cell.digest,
            "values": to_jsonable(cell.values), "trials": [chunk.start, chunk.stop],
            "checksum": table_checksum(table) if checksum is None else checksum}


def chunk_problem(path: Path, cell: Cell, chunk: Chunk) -> str | None:
    """Why the file at ``path`` is not a finished ``chunk`` of ``cell`` (None if it is)."""
    if not is_regular(path):  # never opened: a FIFO would block
        return f"is {kind(path)}, not a chunk file"
    try:
        parquet = pq.ParquetFile(path)
        raw = (parquet.schema_arrow.metadata or {}).get(PARQUET_META_KEY)
        meta = json.loads(raw) if raw else {}
        if not isinstance(meta, dict):
            raise ValueError("provenance is not a table")
    except (OSError, ValueError, pa.ArrowException):
        return "not a readable chunk file"
    if meta.get("cell_digest") != cell.digest:
        return "written for another spec or cell"
    if meta.get("trials") != [chunk.start, chunk.stop]:
        return f"holds trials {meta.get('trials')}, not [{chunk.start}, {chunk.stop}]"
    try:
        table = parquet.read()
    except (OSError, ValueError, pa.ArrowException) as exc:
        return f"unreadable data ({(str(exc).splitlines() or [''])[0][:80]})"
    if table.num_rows != chunk.size or "trial" not in table.column_names or not np.array_equal(
            to_numpy(table.column("trial")), np.arange(chunk.start, chunk.stop)):
        return "its trial ids are not those of its name"
    if table_checksum(table) != meta.get("checksum"):
        return "its content does not match its checksum (the file was changed)"
    return None


def reusable_chunks(directory: Path, lay: Layout, stored: StoredChunks | None = None,
                    remove_strays: bool = True) -> tuple[dict[str, str], list[str]]:
    """This layout's finished chunks that pass every check, each with where it is: "file"
    (its chunk file under trials/) or "stored" (in trials.parquet, ``stored``; a chunk file
    that passes is preferred); and a line per chunk that does not (it is computed again).

    ``remove_strays``: remove stray temporary chunk files (``.chunk-*.tmp``) of a killed run;
    only where no other run may be writing chunks (not by a shard: ``shard_locks``)."""
    trials = directory / TRIALS_DIR
    done: dict[str, str] = {}
    problems: list[str] = []
    if remove_strays:
        for path in _entries(trials):
            if path.name.endswith(".tmp") and path.name.startswith(".chunk-") \
                    and is_regular(path):
                path.unlink(missing_ok=True)
    for cell in lay.cells:
        for chunk in lay.cell_chunks(cell):
            path = trials / chunk.name
            problem = None
            if os.path.lexists(path):
                problem = chunk_problem(path, cell, chunk)
                if problem is None:
                    done[chunk.name] = "file"
                    continue
            if stored is not None and chunk.name in stored.chunks:
                in_table = stored.problem(cell, chunk)
                if in_table is None:
                    done[chunk.name] = "stored"
                    continue
                if problem is None:
                    problem = in_table
                    path = directory / "trials.parquet"
            if problem is not None:
                where = (f"{TRIALS_DIR}/{chunk.name}" if path.name == chunk.name
                         else f"trials.parquet (chunk {chunk.name})")
                problems.append(f"{where}: {problem}")
    return done, problems


def verified_chunks(directory: Path, lay: Layout) -> tuple[set[str], list[str]]:
    """Names of this layout's chunk files (and chunks held in trials.parquet) that pass every
    check, and a line per chunk that does not (``reusable_chunks``)."""
    done, problems = reusable_chunks(directory, lay, StoredChunks.of(directory))
    return set(done), problems


def note(text: str) -> None:
    """A line on stderr about the directory (a chunk recomputed, cells reused)."""
    print(text, file=sys.stderr, flush=True)


def peak_rss_mib(largest_worker: float) -> dict[str, float]:
    """Peak resident memory of this process, each as its own (``storage.peak_memory_mib``),
    and the largest a process running chunks reported (``largest_worker``, with the pages a
    forked worker shares with this process) [MiB]."""
    return {"main": peak_memory_mib(), "largest_child": largest_worker}


#: Key of trials.parquet's Parquet metadata that lists the chunks it holds
#: (``StoredChunks``).
CHUNKS_META_KEY = b"flatcli.chunks"
#: Version of that list's layout.
STORED_FORMAT = 1


@dataclass(frozen=True)
class StoredChunk:
    """A chunk held in trials.parquet: trials [start, stop) at rows [offset, offset + stop -
    start), the checksum of those rows as the file holds them (``storage.table_checksum``,
    as of a chunk file), its cell's key, digest and grid values."""

    start: int
    stop: int
    offset: int
    checksum: str
    cell_key: int
    cell_digest: str
    values: dict[str, Any]


class StoredChunks:
    """The chunks a finished sweep's trials.parquet holds (its only copy of the results: the
    chunk files are removed once it is written, ``remove_merged_chunks``), read from the
    list the file carries in its Parquet metadata (``CHUNKS_META_KEY``), which nothing
    trusts: a list that is not exactly of the form flatcli writes, or does not add up to the
    file's rows, makes the file hold no reusable chunk. A chunk is reused only if its rows
    read back give its checksum (``problem``)."""

    def __init__(self, path: Path, provenance: dict[str, Any],
                 chunks: dict[str, StoredChunk], row_groups: list[int]) -> None:
        self.path = path
        self.provenance = provenance
        self.chunks = chunks
        self._starts = np.concatenate([[0], np.cumsum(row_groups)]).astype(np.int64)

    @staticmethod
    def of(directory: Path) -> StoredChunks | None:
        """What ``directory``'s trials.parquet holds (None: no such file, not a regular
        file, not readable, or no valid list of chunks)."""
        path = directory / "trials.parquet"
        if not is_regular(path):
            return None
        try:
            with pq.ParquetFile(path) as file:  # the footer only
                meta = file.metadata.metadata or {}
                groups = [file.metadata.row_group(i).num_rows
                          for i in range(file.metadata.num_row_groups)]
                rows = file.metadata.num_rows
            index = json.loads(meta.get(CHUNKS_META_KEY, b"null"))
            provenance = json.loads(meta.get(PARQUET_META_KEY, b"null"))
        except (OSError, ValueError, RecursionError, pa.ArrowException):
            return None
        chunks = _stored_index(index, rows)
        if chunks is None or not isinstance(provenance, dict):
            return None
        return StoredChunks(path, provenance, chunks, groups)

    def read(self, name: str) -> pa.Table:
        """The rows of chunk ``name`` (``cell``: its cell's position in the grid this file
        was written for)."""
        chunk = self.chunks[name]
        first = int(np.searchsorted(self._starts, chunk.offset, side="right")) - 1
        last = int(np.searchsorted(self._starts, chunk.offset + chunk.stop - chunk.start,
                                   side="left"))
        with pq.ParquetFile(self.path) as file:
            table = file.read_row_groups(list(range(first, last)))
        table = table.slice(chunk.offset - int(self._starts[first]), chunk.stop - chunk.start)
        return table.combine_chunks()

    def problem(self, cell: Cell, chunk: Chunk) -> str | None:
        """Why the stored chunk of ``chunk``'s name is not that finished chunk of ``cell``
        (None if it is): another cell or range, or rows that do not give its checksum."""
        stored = self.chunks[chunk.name]
        if stored.cell_digest != cell.digest or stored.cell_key != cell.key:
            return "written for another spec or cell"
        if (stored.start, stored.stop) != (chunk.start, chunk.stop):
            return f"holds trials [{stored.start}, {stored.stop}], not [{chunk.start}, " \
                   f"{chunk.stop}]"
        try:
            table = self.read(chunk.name)
        except (OSError, ValueError, KeyError, pa.ArrowException) as exc:
            return f"unreadable data ({(str(exc).splitlines() or [''])[0][:80]})"
        if "trial" not in table.column_names or not np.array_equal(
                to_numpy(table.column("trial")), np.arange(chunk.start, chunk.stop)):
            return "its trial ids are not those of its name"
        if table_checksum(table) != stored.checksum:
            return "its content does not match its checksum (the file was changed)"
        return None


def _stored_index(index: Any, rows: int) -> dict[str, StoredChunk] | None:
    """The chunks of a trials.parquet list (``CHUNKS_META_KEY``) by name, or None if it is
    not exactly of the form ``TrialsAssembly`` writes for a file of ``rows`` rows."""
    if not isinstance(index, dict) or index.get("format") != STORED_FORMAT:
        return None
    cells, listed = index.get("cells"), index.get("chunks")
    if not isinstance(cells, dict) or not isinstance(listed, list):
        return None
    for key, cell in cells.items():
        if not (isinstance(key, str) and re.fullmatch(r"[0-9]{1,10}", key)
                and int(key) < KEY_SPACE and isinstance(cell, dict)
                and isinstance(cell.get("digest"), str)
                and isinstance(cell.get("values", {}), dict)):
            return None
    out: dict[str, StoredChunk] = {}
    offset = 0
    for item in listed:
        if not (isinstance(item, list) and len(item) == 3
                and all(isinstance(v, int) and not isinstance(v, bool) for v in item[:2])
                and isinstance(item[2], str)):
            return None
        start, stop, checksum = item
        key = start // ID_STRIDE if start >= 0 else -1
        if not (0 <= start < stop and (stop - 1) // ID_STRIDE == key and str(key) in cells):
            return None
        name = chunk_name(start)
        if name in out:
            return None
        cell = cells[str(key)]
        out[name] = StoredChunk(start, stop, offset, checksum, key, cell["digest"],
                                dict(cell.get("values", {})))
        offset += stop - start
    return out if offset == rows else None


class TrialsAssembly:
    """trials.parquet, written while the sweep runs: the chunks in the grid's order, each
    appended as soon as it and every chunk before it are in (``add``: one finished early
    waits in memory, at most ``HELD_CHUNKS`` of them, the others and those kept from before
    (``kept``: "file", its chunk file, or "stored", in the directory's trials.parquet,
    ``stored``) are read when their turn comes), with ``cell`` the cell's position in this
    spec's grid (a reused chunk may have been written when it had another). The summary's
    columns (``SUMMARY_INPUTS``) are taken as the chunks pass, so the end reads nothing back.

    Each chunk is one row group, and the file lists them in its Parquet metadata
    (``CHUNKS_META_KEY``: trial range, checksum, cell), so that it can stand for the chunk
    files (``StoredChunks``), which are then removed (``remove_merged_chunks``). The file is
    written under a temporary name beside trials.parquet (``atomic_path``) and renamed over
    it by ``close`` once every chunk is in; chunks the old file held for cells this spec no
    longer has are first written back to their chunk files (``_retire``), so no finished
    result is lost. ``abort`` (or a kill) leaves the trials.parquet the directory had, and
    the next run removes the temporary file (``remove_temporaries``)."""

    def __init__(self, directory: Path, lay: Layout, provenance: Mapping[str, Any],
                 kept: Mapping[str, str] | Iterable[str],
                 stored: StoredChunks | None = None) -> None:
        self._directory = directory
        self._order = list(lay.chunks())
        self._kept = dict(kept) if isinstance(kept, Mapping) else dict.fromkeys(kept, "file")
        self._stored = stored
        self._next = 0  # the position in _order of the next chunk to append
        self._held: dict[str, tuple[pa.Table, str | None]] = {}
        self._checksums: dict[str, str | None] = {}  # of chunks let go to be read back
        self._meta = provenance_metadata(provenance)
        self._cells = {str(c.key): {"digest": c.digest, "values": to_jsonable(c.values)}
                       for c in lay.cells}
        self._index: list[list[Any]] = []  # [start, stop, checksum]
        self._summary = ColumnsOf(SUMMARY_INPUTS)
        self._writer: pq.ParquetWriter | None = None
        self._stack = contextlib.ExitStack()
        self._tmp = self._stack.enter_context(atomic_path(directory / "trials.parquet"))

    def add(self, chunk: Chunk, table: pa.Table, checksum: str | None = None) -> None:
        """A chunk just computed and written to its file (its rows, as the file holds them,
        and their checksum, if known)."""
        self._held[chunk.name] = (table, checksum)
        self._append_ready(everything=False)
        if len(self._held) > HELD_CHUNKS:  # read back from its file when its turn comes
            del self._held[chunk.name]
            self._kept[chunk.name] = "file"
            self._checksums[chunk.name] = checksum

    def close(self) -> tuple[Path, Columns]:
        """Append what is left (from the chunk files), retire what the old file held for
        other cells, flush and rename: trials.parquet's path, and the summary's columns of
        all its rows."""
        target = self._directory / "trials.parquet"
        try:
            self._append_ready(everything=True)
            self._retire()
            if self._writer is not None:
                index = {"format": STORED_FORMAT, "cells": self._cells, "chunks": self._index}
                with naming_os_errors(target, self._tmp):
                    self._writer.add_key_value_metadata({CHUNKS_META_KEY.decode(): json.dumps(
                        index, sort_keys=True, separators=(",", ":"))})
                    self._writer.close()
                self._writer = None
        except BaseException:
            self.abort()
            raise
        self._stack.close()
        return target, self._summary.columns()

    def abort(self) -> None:
        """Stop, and remove the temporary file (trials.parquet stays as it was)."""
        with contextlib.suppress(OSError, ValueError, pa.ArrowException):
            if self._writer is not None:
                self._writer.close()
        self._writer = None
        self._stack.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def _append_ready(self, everything: bool) -> None:
        while self._next < len(self._order):
            chunk = self._order[self._next]
            held = self._held.pop(chunk.name, None)
            if held is None:
                source = self._kept.get(chunk.name)
                if not everything and source is None:
                    return  # not computed yet
                held = self._read(chunk.name, source)
            self._append(chunk, *held)
            self._next += 1

    def _read(self, name: str, source: str | None) -> tuple[pa.Table, str | None]:
        """A chunk's rows and checksum from where it is kept."""
        if source == "stored" and self._stored is not None:
            return self._stored.read(name), self._stored.chunks[name].checksum
        path = self._directory / TRIALS_DIR / name
        if name in self._checksums:
            return read_parquet(path), self._checksums[name]
        with pq.ParquetFile(path) as file:
            raw = (file.schema_arrow.metadata or {}).get(PARQUET_META_KEY)
            checksum = json.loads(raw).get("checksum") if raw else None
            return file.read(), checksum if isinstance(checksum, str) else None

    def _append(self, chunk: Chunk, table: pa.Table, checksum: str | None) -> None:
        """Append a chunk's rows as one row group, ``cell`` its position in this grid, and
        list it with the checksum of its rows as written (the worker's, unless the rows
        changed on the way: a reused chunk of a cell that had another position, a cast)."""
        if table.num_rows == 0 or table.column("cell")[0].as_py() != chunk.cell:
            table = table.set_column(table.schema.get_field_index("cell"), "cell",
                                     repeated(chunk.cell, pa.int64(), table.num_rows))
            checksum = None
        table = table.replace_schema_metadata(self._meta)
        try:  # (cast only where the types differ: pyarrow.compute loads for it)
            with naming_os_errors(self._directory / "trials.parquet", self._tmp):
                if self._writer is None:
                    self._writer = pq.ParquetWriter(self._tmp, table.schema,
                                                    **parquet_options(table.schema))
                if not table.schema.equals(self._writer.schema, check_metadata=False):
                    table = table.cast(self._writer.schema)
                    checksum = None
                if checksum is None:  # the rows as this file holds them
                    checksum = table_checksum(table)
                self._writer.write_table(table, row_group_size=max(table.num_rows, 1))
        except OSError:  # a full disk, an I/O error: the file's (never the chunks')
            raise
        except (ValueError, pa.ArrowException) as exc:
            raise SpecError(
                f"{TRIALS_DIR}/{chunk.name} has other columns than the chunks before it "
                f"({str(exc).splitlines()[0][:80]}); use --force to start over"
            ) from None
        self._index.append([chunk.start, chunk.stop, checksum])
        self._summary.add(table)

    def _retire(self) -> None:
        """Write back to their chunk files the chunks the old trials.parquet held for cells
        this spec's grid no longer has (and that have no chunk file), so that replacing the
        file loses none of them: a study whose grid comes back to those cells reuses them.
        A chunk whose rows do not give its checksum is left out (it would be computed
        again)."""
        stored = self._stored
        if stored is None:
            return
        ours = {c.name for c in self._order}
        trials = self._directory / TRIALS_DIR
        base = {k: v for k, v in stored.provenance.items() if k in ("digest", "spec",
                                                                   "versions")}
        for name, chunk in stored.chunks.items():
            if name in ours or os.path.lexists(trials / name):
                continue
            try:
                table = stored.read(name)
            except (OSError, ValueError, pa.ArrowException):
                continue
            if table_checksum(table) != chunk.checksum:
                continue
            write_table(trials / name, table, {
                **base, "cell_key": chunk.cell_key, "cell_digest": chunk.cell_digest,
                "values": chunk.values, "trials": [chunk.start, chunk.stop],
                "checksum": chunk.checksum})


def remove_merged_chunks(directory: Path, lay: Layout) -> int:
    """After a sweep's final tables are on disk: remove the chunk files of this layout,
    which trials.parquet now holds (``StoredChunks``), and trials/ if that leaves it empty;
    how many files went. Only regular files at this layout's chunk names, in a real
    trials/ directory (never through a link). Each result is then on disk once."""
    trials = real_directory(directory, TRIALS_DIR)
    if trials is None:
        return 0
    removed = 0
    for chunk in lay.chunks():
        path = trials / chunk.name
        if is_regular(path):
            path.unlink(missing_ok=True)
            removed += 1
    if removed:
        fsync_directory(trials)
    with contextlib.suppress(OSError):  # not empty: another cell's chunks, the user's files
        trials.rmdir()
    return removed


#: Finished chunks held in memory while an earlier one still runs; past them, a chunk is read
#: back from its file when its turn comes: the main process's memory stays bounded in
#: whatever order the chunks finish (a slow first chunk, a Dask worker lost and its chunk
#: computed again).
HELD_CHUNKS = 16


def remove_temporaries(directory: Path) -> None:
    """Remove the temporary files of the final tables and the manifest (``atomic_path``'s
    ``.NAME.random.tmp``) that a run killed while writing them left. Only under the
    directory's lock: then no other run is writing them."""
    for path in _entries(directory):
        if _temporary_of(path.name) in FINAL_FILES and is_regular(path):
            path.unlink(missing_ok=True)


def summary_cells(lay: Layout) -> dict[int, dict[str, Any]]:
    """Each cell's grid columns as the summary shows them: {cell: {column: value}}."""
    return {c.index: {k: v for k, (_, v) in grid_columns(c.values, c.spec).items()}
            for c in lay.cells}


def finish_sweep(directory: Path, lay: Layout, provenance: Mapping[str, Any], started: float,
                 timing: Mapping[str, Any], trials: TrialsAssembly,
                 tags: list[str] | None = None) -> tuple[str, str]:
    """trials.parquet (``trials``, closed here), summary.parquet, summary.md and run.json from
    the chunks; then the chunk files go (``remove_merged_chunks``: trials.parquet holds
    them). Returns summary.md's text and the headline the terminal shows
    (``report.summary.headline``: one screen).

    ``timing`` gains the end-to-end figures: ``wall_seconds`` from ``started`` (a
    perf_counter time) to the summary, ``trials_per_second`` over it, and
    ``steady_trials_per_second`` over all but the one-time start-up (``setup_seconds``:
    planning the cells, loading the compiled kernel): chunks and final tables.
    """
    finishing = time.perf_counter()
    _, columns = trials.close()
    cells = summary_cells(lay)
    rows = summary_rows(columns, cells, lay.spec.summary.reach_tolerance)
    names = list(rows[0]) if rows else []
    write_table(directory / "summary.parquet", summary_table(rows, units_of(names, lay.spec)),
                provenance)
    text = summary_markdown(rows, list(cells[lay.cells[0].index]))
    write_text(directory / "summary.md", text + "\n")
    errors = sum(int(r["error"]) for r in rows)
    short = headline(rows, grid_columns_of(rows), f"sweep {lay.spec.name!r}: {totals_text(rows)}",
                     str(directory), error_reasons([directory / "trials.parquet"])
                     if errors else None, grid=lay.spec.sweep.grid)
    statuses, tally = np.unique(np.asarray(columns["status"], dtype=str), return_counts=True)
    counts = {str(s): int(c) for s, c in zip(statuses, tally, strict=True)}
    outcome = np.asarray(columns["outcome"], dtype=object) if "outcome" in columns else \
        np.zeros(0, dtype=object)
    outcome_counts = {name: int(np.sum(outcome == name)) for name in OUTCOME_NAMES}
    now = time.perf_counter()
    wall = now - started
    simulated = timing["simulated_trials"]
    warm = wall - timing["setup_seconds"]
    timing = {**timing, "finish_seconds": now - finishing, "wall_seconds": wall,
              "trials_per_second": simulated / wall,
              "steady_trials_per_second": simulated / warm if warm > 0 else None,
              "peak_rss_mib": peak_rss_mib(float(timing.get("worker_peak_mib", 0.0)))}
    write_json(directory / "run.json", run_record(
        "sweep", lay.spec.tree, digest=lay.spec.digest(), cells=len(lay.cells),
        trials=lay.total, chunk=lay.chunk_size, status_counts=counts,
        outcome_counts=outcome_counts, timing=timing,
        **({"tags": tags} if tags else {}),
    ))
    remove_merged_chunks(directory, lay)  # trials.parquet holds them, on disk before them
    return text, short

