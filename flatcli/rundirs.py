"""Run directories: where a plan or track run goes, and what a directory of runs holds.

* Without ``--out`` every ``plan`` or ``track`` run gets a directory of its own,
  ``runs/<name>/<YYYYmmdd-HHMMSS>-<6 hex>/``, and ``runs/<name>/latest`` links to the newest
  one (the link is replaced atomically). No run ever writes into another's directory. A
  ``workspace`` map goes to ``runs/<name>/workspace/<stamp>/`` with its own ``latest``
  (``COMMAND_DIRS``), so ``runs/<name>/latest`` stays the newest plan or track run.
* With ``--out DIR``, a DIR that holds a different run (another command, or the same command
  with another spec) is refused unless ``--force``, as a sweep directory already is.
* ``flatcli runs [DIR]`` lists every run below DIR (plan, track, sweep, ``sweep --rerun``,
  reproduce): command, name, time, status and its key metrics; ``--compare A B`` shows the
  spec keys two runs differ in.

Reading a sweep directory, finished or not (``SweepState``), is here too: ``summarize`` and
``flatcli.load`` of an interrupted sweep use it. Everything here reads JSON and Parquet
metadata only, so listing a thousand runs is quick.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import secrets
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from flatcli.files import (
    MAX_RECORD_BYTES,
    UnreadableFileError,
    is_regular,
    kind,
    not_regular,
    read_bounded,
)
from flatcli.report import fmt

#: The file every finished run directory holds (plan, track, sweep, reproduce).
RECORD = "run.json"
#: The file a sweep directory holds from its start (``flatcli.sweep.MANIFEST``).
SWEEP_MANIFEST = "sweep.json"
#: The chunk files of a sweep (``flatcli.sweep.TRIALS_DIR``).
SWEEP_TRIALS = "trials"
#: Name of the link to the newest run of a name.
LATEST = "latest"
#: The files a plan, track or workspace run writes (and ``flatcli export --csv`` beside them);
#: ``--force`` removes these (and only these, if they are regular files) first.
RUN_FILES = ("run.json", "plan.parquet", "plan.png", "plan.pdf", "plan.svg", "track.parquet",
             "track.png", "track.pdf", "track.svg", "metrics.json", "plan.csv", "track.csv",
             "filmstrip.png", "filmstrip.pdf", "filmstrip.svg", "plan.gif",
             "workspace.parquet", "workspace.png", "workspace.pdf", "workspace.svg")
#: Default root of run directories.
ROOT = Path("runs")
#: A sweep's default directory within ``runs/<name>/``, beside the name's plan and track runs
#: (a stamp, ``YYYYmmdd-HHMMSS-xxxxxx``, is never this name).
SWEEP_DIR = "sweep"
#: Where the fresh runs of a command other than plan and track go within ``runs/<name>/``,
#: with a ``latest`` of their own: ``runs/<name>/latest`` is the newest plan or track run,
#: which ``flatcli.load("runs/<name>")`` and ``runs --compare`` read, and a workspace map is
#: neither.
COMMAND_DIRS = {"workspace": "workspace"}
#: The most tags a run may have, and the longest tag [UTF-8 bytes].
MAX_TAGS = 32
MAX_TAG_BYTES = 100


class RunDirectoryError(Exception):
    """A directory that must not be written into (the CLI's exit status 2)."""


# ---------------------------------------------------------------------------------------
# Where a run goes.

def sweep_directory(name: str, root: Path = ROOT) -> Path:
    """A sweep's default directory: ``root/<name>/sweep/``, apart from the plan and track
    runs of that name (so ``flatcli.load("runs/<name>")`` is their latest); a sweep that an
    older flatcli started in ``root/<name>/`` itself resumes there."""
    legacy = root / name
    if kind(legacy / SWEEP_MANIFEST) != "missing":
        return legacy
    return legacy / SWEEP_DIR


def check_tags(tags: Iterable[str]) -> list[str]:
    """A run's tags (``--tag``), each once, in order; SpecError for an empty tag, one with a
    control, format or separator character, one of more than ``MAX_TAG_BYTES`` bytes, or
    more than ``MAX_TAGS`` tags."""
    from flatcli.spec.keys import SpecError, unprintable

    out: list[str] = []
    for tag in tags:
        if not isinstance(tag, str) or not tag.strip():
            raise SpecError(f"--tag: expected a non-empty word, got {tag!r}")
        bad = unprintable(tag)
        if bad is not None:
            raise SpecError(f"--tag: must not contain control, format or separator "
                            f"characters, got {bad} in {tag!a}")
        if len(tag.encode("utf-8", "surrogatepass")) > MAX_TAG_BYTES:
            raise SpecError(f"--tag: at most {MAX_TAG_BYTES} bytes, got {tag[:20]!r}...")
        if tag not in out:
            out.append(tag)
    if len(out) > MAX_TAGS:
        raise SpecError(f"--tag: at most {MAX_TAGS} tags, got {len(out)}")
    return out

def read_json(path: Path) -> dict[str, Any] | None:
    """A JSON object from a file, or None if it is missing or unreadable: not a regular file
    (never opened, so a FIFO cannot block), larger than ``MAX_RECORD_BYTES``, not JSON, not
    an object."""
    try:
        value = json.loads(read_bounded(path, MAX_RECORD_BYTES))
    except (UnreadableFileError, ValueError, RecursionError):
        return None
    return value if isinstance(value, dict) else None


@dataclass(frozen=True)
class Target:
    """Where a run will be written: a directory given with ``--out`` (``fresh`` False), or
    a new directory ``root/<name>/<stamp>`` (``fresh`` True) created when the run is saved."""

    path: Path
    fresh: bool
    force: bool = False

    def open(self) -> Path:
        """Create the directory and return it: a fresh one is new (if another run took its
        name meanwhile, another stamp); ``--force`` removes the previous run's files from a
        given one."""
        if not self.fresh:
            self.path.mkdir(parents=True, exist_ok=True)
            if self.force:
                for name in RUN_FILES:
                    if is_regular(self.path / name):
                        (self.path / name).unlink()
            return self.path
        path = self.path
        while True:
            try:
                path.mkdir(parents=True, exist_ok=False)
                return path
            except FileExistsError:
                path = path.parent / stamp()

    def finish(self, directory: Path) -> None:
        """Point ``latest`` at a fresh run's directory (atomically: a new link renamed over
        the old one); nothing for a directory given with ``--out``."""
        if self.fresh:
            link_latest(directory)


def stamp(now: datetime | None = None) -> str:
    """A run directory's name: local time to the second, and 6 random hex digits."""
    now = now or datetime.now()
    return f"{now:%Y%m%d-%H%M%S}-{secrets.token_hex(3)}"


def link_latest(directory: Path) -> None:
    """Make ``directory.parent / latest`` a relative link to ``directory``, atomically."""
    link = directory.parent / LATEST
    tmp = directory.parent / f".{LATEST}.{secrets.token_hex(4)}.tmp"
    try:
        tmp.symlink_to(directory.name, target_is_directory=True)
        os.replace(tmp, link)
    except OSError:  # e.g. a real directory named "latest", or no symlinks on this system
        tmp.unlink(missing_ok=True)


def recorded_digest(record: Mapping[str, Any]) -> str | None:
    """The spec digest a run.json records; of one written before run.json held it, the
    digest of its spec (``Spec.digest``: SHA-256 of the canonical JSON of its experiment,
    which run.json's spec is, read back, without ``[figures]``)."""
    if "digest" in record:
        return str(record["digest"])
    from flatcli.spec.schema import experiment

    spec = record.get("spec")
    if not isinstance(spec, Mapping):
        return None
    text = json.dumps(experiment(spec), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def claim(out: Path | None, command: str, name: str, digest: str, force: bool = False,
          root: Path = ROOT) -> Target:
    """Where a ``command`` run of spec ``digest`` goes; RunDirectoryError if ``out`` holds a
    different run and ``force`` is not set.

    The same command with the same spec may write into its own directory again (its files
    come out the same); anything else there is refused: the run would replace another's
    files, or mix with a sweep's.
    """
    if out is None:
        home = root / name / COMMAND_DIRS[command] if command in COMMAND_DIRS else root / name
        while True:
            path = home / stamp()
            if not path.exists():
                return Target(path, fresh=True)
    if out.exists() and not out.is_dir():
        raise RunDirectoryError(f"--out {out}: is a file")
    if kind(out / SWEEP_MANIFEST) != "missing":  # even with --force: never mix with a sweep
        raise RunDirectoryError(f"--out {out}: holds a sweep; use another --out")
    blocked = not_regular(out, RUN_FILES)
    if blocked:  # never opened, never replaced, never removed: not flatcli's
        raise RunDirectoryError(f"--out {out}: holds {', '.join(blocked)} where a run writes "
                                "its files; remove it yourself, or use another --out")
    if force:
        return Target(out, fresh=False, force=True)
    record = read_json(out / RECORD)
    if kind(out / RECORD) != "missing" and record is None:
        raise RunDirectoryError(f"--out {out}: its run.json is unreadable; use --force to "
                                "replace that run, or another --out")
    if record is not None:
        previous = str(record.get("command"))
        if previous != command:
            raise RunDirectoryError(
                f"--out {out}: holds a {previous} run; use --force to replace it, or another "
                "--out (without --out every run gets a directory of its own)")
        if recorded_digest(record) != digest:
            raise RunDirectoryError(
                f"--out {out}: holds a {previous} run of a different spec; use --force to "
                "replace it, or another --out (without --out every run gets a directory of "
                "its own)")
    return Target(out, fresh=False)


# ---------------------------------------------------------------------------------------
# A sweep directory, finished or interrupted.

@dataclass(frozen=True)
class SweepState:
    """What a sweep directory holds: its manifest, the finished chunk files of its spec
    (and the position in the spec's grid of each one's cell), and whether the final tables
    are there."""

    directory: Path
    manifest: dict[str, Any]
    chunk_files: tuple[Path, ...]
    done: int  # trials in the finished chunk files
    complete: bool  # trials.parquet, summary and run.json of this spec are written
    chunk_cells: tuple[int, ...] = ()  # the grid position of each chunk file's cell
    #: chunks of the spec's grid that trials.parquet holds (a finished sweep keeps its rows
    #: there only; an extended one reuses them from there), each as (name, grid position)
    stored: tuple[tuple[str, int], ...] = ()

    @property
    def digest(self) -> str:
        return str(self.manifest.get("digest"))

    @property
    def cells(self) -> int:
        """Cells of the spec's grid (``grid_cells``: their keys in the grid's order; a
        manifest written before cell keys holds their number)."""
        cells = self.manifest["cells"]
        return int(cells) if isinstance(cells, int) else len(self.manifest["grid_cells"])

    @property
    def total(self) -> int:
        return self.cells * int(self.manifest["trials_per_cell"])

    @property
    def chunks_total(self) -> int:
        per_cell = math.ceil(int(self.manifest["trials_per_cell"]) / int(self.manifest["chunk"]))
        return self.cells * per_cell

    @property
    def grid_keys(self) -> list[str]:
        return list(self.manifest.get("spec", {}).get("sweep", {}).get("grid", {}))

    def missing_text(self) -> str:
        """One line: how much of the sweep is missing."""
        missing = self.total - self.done
        share = 100 * self.done / self.total if self.total else 100.0
        return (f"partial sweep: {self.done} of {self.total} trials finished ({share:.0f}%), "
                f"{len(self.chunk_files) + len(self.stored)} of {self.chunks_total} chunks; "
                f"{missing} trials missing")


def sweep_state(directory: Path) -> SweepState | None:
    """The state of the sweep in ``directory``, or None if it holds none.

    A chunk file counts if it is one of the chunks the manifest lists for a cell of the
    spec's grid and its provenance carries that cell's digest (a resume checks its content
    too); of a manifest written before cell keys, if its provenance carries the manifest's
    spec digest. Nothing is modified: a sweep may be running there right now.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    from flatcli.montecarlo.directory import StoredChunks, read_manifest
    from flatcli.spec import SpecError
    from flatcli.storage import read_provenance

    try:
        manifest = read_manifest(directory)  # every name and count in it checked
    except SpecError:
        return None
    if manifest is None or not {"digest", "cells", "trials_per_cell", "chunk"} <= set(manifest):
        return None
    cells = manifest["cells"]
    keyed = isinstance(cells, dict)
    digest = manifest["digest"]
    expected: dict[str, tuple[int, str]] = {}  # chunk file -> (grid position, cell digest)
    for position, key in enumerate(manifest.get("grid_cells", []) if keyed else []):
        cell = cells.get(str(key), {})
        for name in cell.get("chunks", []):
            expected[str(name)] = (position, str(cell.get("digest")))
    files = []
    positions = []
    done = 0
    trials = directory / SWEEP_TRIALS
    listed = sorted(trials.glob("chunk-*.parquet")) if kind(trials) == "a directory" else []
    for path in listed:
        if not is_regular(path):  # never opened: a FIFO would block
            continue
        try:
            meta = read_provenance(path)
            if not isinstance(meta, dict):
                continue
            if keyed:
                if path.name not in expected:
                    continue
                position, cell_digest = expected[path.name]
                if meta.get("cell_digest") != cell_digest:
                    continue
            else:
                if meta.get("digest") != digest:
                    continue
                position = -1
            rows = pq.read_metadata(path).num_rows
        except (OSError, ValueError, pa.ArrowException):  # being written, or damaged
            continue
        done += rows
        files.append(path)
        positions.append(position)
    if not keyed:  # the cell column of a chunk written before cell keys is its position
        positions = []
    stored: list[tuple[str, int]] = []
    held = StoredChunks.of(directory) if keyed else None
    if held is not None:
        named = {p.name for p in files}
        for name, (position, cell_digest) in expected.items():
            chunk = held.chunks.get(name)
            if name not in named and chunk is not None and chunk.cell_digest == cell_digest:
                stored.append((name, position))
                done += chunk.stop - chunk.start
    record = read_json(directory / RECORD)
    complete = (record is not None and record.get("digest") == digest
                and is_regular(directory / "trials.parquet")
                and is_regular(directory / "summary.parquet"))
    return SweepState(directory, manifest, tuple(files), done, complete, tuple(positions),
                      tuple(stored))


def chunk_frames(state: SweepState, columns: list[str] | None = None) -> Any:
    """The finished chunk files of a partial sweep as one DataFrame, in trials.parquet's
    order (cells in the grid's order, trials in order), ``cell`` their grid position."""
    import pandas as pd
    import pyarrow.parquet as pq

    from flatcli.montecarlo.directory import StoredChunks

    frames = []
    for i, path in enumerate(state.chunk_files):
        present = None if columns is None else [
            c for c in columns if c in pq.read_schema(path).names]  # older files lack some
        frame = pd.read_parquet(path, columns=present)
        if state.chunk_cells:
            frame["cell"] = state.chunk_cells[i]
        frames.append(frame)
    held = StoredChunks.of(state.directory) if state.stored else None
    for name, position in state.stored:
        if held is None or name not in held.chunks:  # (replaced meanwhile by a finished run)
            continue
        table = held.read(name)
        if columns is not None:
            table = table.select([c for c in columns if c in table.column_names])
        frame = table.to_pandas()
        frame["cell"] = position
        frames.append(frame)
    if not frames:
        return pd.DataFrame(columns=columns)
    frame = pd.concat(frames, ignore_index=True)
    return frame.sort_values(["cell", "trial"], ignore_index=True, kind="stable")


def _reach_tolerance(manifest: Mapping[str, Any]) -> float:
    """The manifest spec's ``summary.reach_tolerance`` [m] if it is a positive number (a
    manifest is not trusted), else the key's default."""
    from flatcli.spec.schema import SummarySpec

    spec = manifest.get("spec")
    section = spec.get("summary") if isinstance(spec, Mapping) else None
    value = section.get("reach_tolerance") if isinstance(section, Mapping) else None
    if isinstance(value, int | float) and not isinstance(value, bool) and \
            math.isfinite(value) and value > 0:
        return float(value)
    return SummarySpec().reach_tolerance


def partial_summary(state: SweepState) -> tuple[Any, str]:
    """Per-cell statistics of the finished trials of an unfinished sweep: the summary
    frame, and its Markdown headed by how much is missing."""

    from flatcli.report import summarize_trials, summary_markdown
    from flatcli.report.summary import SUMMARY_INPUTS

    keys = state.grid_keys
    columns = list(dict.fromkeys(["trial", *SUMMARY_INPUTS, *keys]))
    frame = chunk_frames(state, columns)
    cells: dict[int, dict[str, Any]] = {}
    for values in frame.drop_duplicates("cell").sort_values("cell").to_dict("records"):
        cells[int(values["cell"])] = {k: values[k] for k in keys}
    summary = summarize_trials(frame, cells, _reach_tolerance(state.manifest))
    n_cells = state.cells
    per_cell = int(state.manifest["trials_per_cell"])
    counts = frame.groupby("cell").size().to_dict() if len(frame) else {}
    unfinished = [c for c in range(n_cells) if counts.get(c, 0) < per_cell]
    lines = [state.missing_text() + ".",
             f"cells not finished: {_ranges(unfinished)} (of 0-{n_cells - 1}); the tables "
             "below cover the finished trials only.",
             "Run the same `flatcli sweep` command again to finish it.", ""]
    if cells:
        lines.append(summary_markdown(summary, keys))
    else:
        lines.append("(no finished trials yet)")
    return summary, "\n".join(lines)


def _ranges(values: list[int]) -> str:
    """[0, 1, 2, 5, 7, 8] -> '0-2, 5, 7-8'."""
    parts: list[str] = []
    i = 0
    while i < len(values):
        j = i
        while j + 1 < len(values) and values[j + 1] == values[j] + 1:
            j += 1
        parts.append(str(values[i]) if i == j else f"{values[i]}-{values[j]}")
        i = j + 1
    return ", ".join(parts) or "none"


# ---------------------------------------------------------------------------------------
# flatcli runs: the runs below a directory.

@dataclass(frozen=True)
class RunInfo:
    """One run directory as ``flatcli runs`` shows it: ``metrics`` its key metrics,
    ``values`` every number its record holds (a track run's metrics, a plan's summary, a
    sweep's trials by status and by outcome), ``tags`` its labels (``--tag``), ``outcome``
    what the robot did (a track run's ``outcome``; a sweep's "reached k/n"; "" otherwise)."""

    path: Path
    command: str
    name: str
    time: datetime | None
    status: str
    metrics: dict[str, Any]
    spec: dict[str, Any]
    tags: tuple[str, ...] = ()
    values: dict[str, Any] = field(default_factory=dict)
    outcome: str = ""

    def metrics_text(self, most: int | None = None) -> str:
        """The key metrics as text (at most ``most`` of them, and how many more)."""
        items = list(self.metrics.items())
        shown_ = items if most is None else items[:most]
        text = ", ".join(f"{k} {fmt(v, 3)}" for k, v in shown_)
        return text + (f" (+{len(items) - len(shown_)})" if len(shown_) < len(items) else "")


def _number(value: Any) -> float | int | None:
    """A metric read back from JSON (non-finite floats may be stored as strings; null is not
    applicable, nan); None if it is not a number at all."""
    if isinstance(value, str) and value in ("nan", "inf", "-inf"):
        return float(value)
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return value


#: The metrics ``flatcli runs`` shows per command (all of them are in the run's files).
PLAN_KEYS = ("input_energy", "min_margin", "max_abs_momentum")
TRACK_KEYS = ("err_y_final", "err_theta_rms", "min_margin", "momentum_drift")
WORKSPACE_KEYS = ("area_reachable", "area_both", "area_thin")
#: The status of a run whose record cannot be read (or holds values of the wrong types).
UNREADABLE = "unreadable"


def _metrics(values: Any, keys: tuple[str, ...]) -> dict[str, Any] | None:
    """The numbers of ``keys`` in a record's table (None if it is not a table of numbers)."""
    if not isinstance(values, Mapping):
        return None
    out = {k: _number(values[k]) for k in keys if k in values}
    return None if any(v is None for v in out.values()) else out


def _record_problem(record: Mapping[str, Any]) -> str | None:
    """Why a run.json's values are not of the types flatcli wrote, or None."""
    expected: dict[str, tuple[type, ...]] = {
        "command": (str,), "time": (str,), "spec": (dict,), "summary": (dict,),
        "metrics": (dict,), "optimization": (dict, type(None)), "status_counts": (dict,),
        "digest": (str,), "seconds": (int, float), "tags": (list,)}
    for key, types in expected.items():
        if key in record and (not isinstance(record[key], types)
                              or isinstance(record[key], bool)):
            return f"its {key} is not a {types[0].__name__}"
    if "time" in record and _parse_time(record["time"]) is None:
        return "its time is not a date"
    counts = record.get("status_counts", {})
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in counts.values()):
        return "its status_counts are not counts"
    tags = record.get("tags", [])
    if not isinstance(tags, list) or not all(isinstance(t, str) for t in tags):
        return "its tags are not a list of text"
    return None


def _unreadable(directory: Path, command: str, spec: Any = None) -> RunInfo:
    spec = spec if isinstance(spec, dict) else {}
    name = spec.get("name")
    return RunInfo(directory, command, name if isinstance(name, str) else "", None, UNREADABLE,
                   {}, spec)


def run_info(directory: Path) -> RunInfo | None:
    """What ``flatcli runs`` shows of a directory, or None if it holds no run. A record that
    cannot be read (not a regular file, too large, not JSON, values of other types than
    flatcli writes) is shown with the status "unreadable"; nothing in it is trusted."""
    has_record = kind(directory / RECORD) != "missing"
    has_manifest = kind(directory / SWEEP_MANIFEST) != "missing"
    if not has_record and not has_manifest:
        return None
    record = read_json(directory / RECORD) if has_record else None
    raw = record or {}
    if record is not None and _record_problem(record) is not None:
        record = None
    state = sweep_state(directory) if has_manifest else None
    if has_manifest and state is None:
        return _unreadable(directory, "sweep")
    if state is None and record is None:  # what can be told of it: its command and spec
        command = raw.get("command")
        return _unreadable(directory, command if isinstance(command, str) else "?",
                           raw.get("spec"))
    command = str(record.get("command")) if record is not None else "sweep"
    spec = (record or {}).get("spec") or (state.manifest.get("spec") if state else None) or {}
    when = _parse_time(record.get("time")) if record is not None else None
    tags = tuple(str(t) for t in (record or {}).get("tags", []) or (
        state.manifest.get("tags", []) if state is not None else []))
    metrics: dict[str, Any] = {}
    values: dict[str, Any] = {}
    status = "done"
    outcome = ""
    if state is not None:
        command = "sweep"
        if not state.complete:
            status = f"partial {100 * state.done / max(state.total, 1):.0f}%"
            mtime = (directory / SWEEP_MANIFEST).lstat().st_mtime
            when = datetime.fromtimestamp(mtime).astimezone()
            record = None
        metrics["trials"] = state.total
        counts = (record or {}).get("status_counts", {})
        metrics.update({k: v for k, v in counts.items() if v})
        outcomes = (record or {}).get("outcome_counts", {})
        if not (isinstance(outcomes, Mapping) and all(
                isinstance(v, int) and not isinstance(v, bool) for v in outcomes.values())):
            outcomes = {}
        values = {"trials": state.total, "finished": state.done, **counts,
                  **{str(k): v for k, v in outcomes.items()}}
        if outcomes:
            outcome = f"reached {outcomes.get('reached', 0)}/{sum(outcomes.values())}"
    elif record is not None and command == "plan":
        found = _metrics(record.get("summary", {}), PLAN_KEYS)
        if found is None:
            return _unreadable(directory, command, spec)
        metrics = found
        values = _numbers(record.get("summary", {}))
        optimization = record.get("optimization")
        if optimization:
            status = "optimised" if optimization.get("success") else "optimiser failed"
        else:
            status = "ok"
    elif record is not None and isinstance(record.get("metrics"), Mapping):
        values = record["metrics"]
        found = _metrics(values, WORKSPACE_KEYS if command == "workspace" else TRACK_KEYS)
        if found is None or not isinstance(values.get("status", "done"), str):
            return _unreadable(directory, command, spec)
        status, metrics = str(values.get("status", "done")), found
        said = values.get("outcome")
        outcome = said if isinstance(said, str) else ""
        values = _numbers(values)
    elif record is not None and "seconds" in record:
        metrics = {"seconds": _number(record["seconds"])}
        values = dict(metrics)
    name = spec.get("name", "")
    return RunInfo(directory, command, name if isinstance(name, str) else "", when, status,
                   metrics, spec, tags, values, outcome)


def _numbers(values: Mapping[str, Any]) -> dict[str, Any]:
    """The numbers and flags of a record's table (a metric that does not apply, null, as nan;
    a yes/no metric such as ``verified`` kept as a bool)."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        number = value if isinstance(value, bool) else _number(value)
        if number is not None:
            out[str(key)] = number
    return out


def _parse_time(value: Any) -> datetime | None:
    if not isinstance(value, str):
        return None
    try:
        return datetime.fromisoformat(value).astimezone()
    except (ValueError, OverflowError, OSError):
        return None


def find_runs(root: Path) -> Iterator[Path]:
    """Every directory below ``root`` (and root itself) holding a run or a sweep; a sweep's
    chunk files and ``latest`` links are not entered."""
    for here, dirs, files in os.walk(root):
        if RECORD in files or SWEEP_MANIFEST in files:
            yield Path(here)
        dirs[:] = sorted(d for d in dirs
                         if d != SWEEP_TRIALS and not (Path(here) / d).is_symlink())


def list_runs(root: Path) -> list[RunInfo]:
    """The runs below ``root``, oldest first."""
    infos = [info for path in find_runs(root) if (info := run_info(path)) is not None]
    return sorted(infos, key=lambda i: (i.time.timestamp() if i.time else 0.0, str(i.path)))


def shown(text: str) -> str:
    """Text read from a run's files as a terminal may show it: control, format and separator
    characters (an escape sequence, a bidirectional override) escaped, not printed."""
    return text if text.isprintable() else ascii(text)[1:-1]


def followed(path: Path) -> Path | None:
    """A path with its links followed (None for a loop of links)."""
    try:
        return path.resolve()
    except (OSError, RuntimeError):  # RuntimeError: a symlink loop (Python < 3.13)
        return None

