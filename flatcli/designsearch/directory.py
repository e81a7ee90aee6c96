"""A search's directory: its record, its journal, its files, and what a new run may do there.

* ``search.json``: the run record (command, spec, identity, versions, status; timings and the
  stop when finished);
* ``journal.jsonl``: one line per evaluated candidate (its design, exactly, and its
  evaluation) and per finished generation (the search's seconds so far), appended and flushed
  to disk as each is known. A kill loses at most the candidates being computed; a torn last
  line is dropped (and cut off before anything is appended);
* ``search.parquet``, ``summary.md``, ``convergence.png``, ``best_robot.toml``,
  ``best_robot.urdf``, ``best_spec.toml``: the results (``flatcli.designsearch.report``).

A search is resumed by running it again from the start: the optimiser is deterministic, so it
asks for the same candidates in the same order, and those in the journal are answered from it
(``flatcli.designsearch.runner``). The journal therefore belongs to one search *identity*: the spec
without its name, its figures' format and the stopping rules (``search.candidates``,
``search.seconds``, ``search.tol``), which decide only where the same sequence stops. Another
identity in the directory is refused (``--force`` starts over, removing only the files named
here).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from flatcli.designsearch.evaluate import Evaluation, dumps
from flatcli.spec import Spec, SpecError
from flatcli.storage import to_jsonable, write_json

RECORD = "search.json"
JOURNAL = "journal.jsonl"
TABLE = "search.parquet"
SUMMARY = "summary.md"
FIGURE_STEM = "convergence"
BEST_ROBOT = "best_robot.toml"
BEST_URDF = "best_robot.urdf"
BEST_SPEC = "best_spec.toml"
#: Every file a search writes (and ``--force`` may remove), figures in any format.
FILES = (RECORD, JOURNAL, TABLE, SUMMARY, BEST_ROBOT, BEST_URDF, BEST_SPEC,
         *(f"{FIGURE_STEM}.{ext}" for ext in ("png", "pdf", "svg")))
#: What the record's format is.
FORMAT = 1
#: The keys that only decide where a search stops (not part of its identity).
STOPPING = ("candidates", "seconds", "tol")


def identity(spec: Spec) -> str:
    """SHA-256 of what makes two searches the same sequence of candidates: the experiment
    (``Spec.to_json``, without the name) and ``[search]`` without ``STOPPING``."""
    tree = spec.experiment_tree()
    tree.pop("name", None)
    search = {k: v for k, v in spec.tree["search"].items() if k not in STOPPING}
    text = json.dumps(to_jsonable({"experiment": tree, "search": search, "format": FORMAT}),
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def design_key(x: Any) -> str:
    """A design's exact identity: its floats' hexadecimal forms."""
    return ",".join(float(v).hex() for v in x)


@dataclass
class Journal:
    """The evaluated candidates (by ``design_key``) and each finished generation's seconds,
    read from the journal; ``append_*`` add to both, flushed to disk."""

    path: Path
    evaluations: dict[str, Evaluation] = field(default_factory=dict)
    generations: dict[int, float] = field(default_factory=dict)
    dropped: int = 0  # unreadable lines at the end (a torn write), cut off

    @staticmethod
    def read(path: Path) -> Journal:
        """The journal at ``path`` (empty if there is none): its lines up to the first that
        cannot be read (a torn write at the end), the rest counted in ``dropped`` and cut off
        the file."""
        journal = Journal(path)
        if not path.exists():
            return journal
        data = path.read_bytes()
        *complete, tail = data.split(b"\n")  # tail: the text after the last newline
        good = 0
        for i, raw in enumerate(complete):
            try:
                journal._take(json.loads(raw.decode("utf-8")))
            except (ValueError, TypeError, KeyError, UnicodeDecodeError):
                journal.dropped = len(complete) - i
                break
            good += len(raw) + 1
        journal.dropped += 1 if tail else 0
        if good < len(data):
            with open(path, "r+b") as fh:
                fh.truncate(good)
                fh.flush()
                os.fsync(fh.fileno())
        return journal

    def _take(self, record: Mapping[str, Any]) -> None:
        kind = record["kind"]
        if kind == "candidate":
            key = record["key"]
            if not isinstance(key, str):
                raise TypeError("key")
            self.evaluations[key] = Evaluation.from_json(record["evaluation"])
        elif kind == "generation":
            g, seconds = record["generation"], record["seconds"]
            if isinstance(g, bool) or not isinstance(g, int) or isinstance(seconds, bool) \
                    or not isinstance(seconds, int | float):
                raise TypeError("generation")
            self.generations[g] = float(seconds)
        else:
            raise ValueError(kind)

    def _append(self, record: Mapping[str, Any]) -> None:
        with open(self.path, "a", encoding="utf-8") as fh:
            fh.write(dumps(record) + "\n")
            fh.flush()
            os.fsync(fh.fileno())

    def add_candidate(self, key: str, evaluation: Evaluation) -> None:
        self.evaluations[key] = evaluation
        self._append({"kind": "candidate", "key": key, "evaluation": evaluation.to_json()})

    def add_generation(self, generation: int, seconds: float) -> None:
        self.generations[generation] = seconds
        self._append({"kind": "generation", "generation": generation, "seconds": seconds})


@dataclass(frozen=True)
class Opened:
    """What a run found in its directory: ``mode`` "fresh", "resume" or "restart", and the
    journal it continues (empty unless resumed)."""

    mode: str
    journal: Journal


def read_record(directory: Path) -> dict[str, Any] | None:
    """The directory's search.json, or None if it has none; FlatcliError if it is not a
    search's record."""
    path = directory / RECORD
    if not path.exists():
        return None
    if path.is_symlink() or not path.is_file():
        raise SpecError(f"{path} is not a file flatcli wrote; remove it or use another --out")
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise SpecError(f"{path}: not a search record ({exc}); use --force to start over "
                        "there, or another --out") from None
    if not isinstance(record, dict) or record.get("command") != "search":
        raise SpecError(f"{path}: not a search record; use another --out")
    return record


def _ours(directory: Path) -> Iterator[str]:
    for name in FILES:
        if os.path.lexists(directory / name):
            yield name


def open_directory(directory: Path, spec: Spec, force: bool) -> Opened:
    """Decide what a search of ``spec`` may do in ``directory`` (SpecError, nothing written,
    if it may not) and read its journal to resume."""
    if os.path.lexists(directory) and not directory.is_dir():
        raise SpecError(f"--out {directory}: exists and is not a directory")
    for name in _ours(directory):
        path = directory / name
        if path.is_symlink() or not path.is_file():
            raise SpecError(f"{path} is not a regular file flatcli wrote; remove it yourself "
                            "or use another --out")
    record = read_record(directory) if directory.is_dir() else None
    if record is None:
        taken = list(_ours(directory))
        if taken:
            raise SpecError(f"{directory} holds {', '.join(taken)} but no {RECORD}: not a "
                            "search flatcli wrote; use another --out")
        return Opened("fresh", Journal(directory / JOURNAL))
    if force:
        for name in _ours(directory):
            (directory / name).unlink()
        return Opened("restart", Journal(directory / JOURNAL))
    if record.get("identity") != identity(spec):
        raise SpecError(f"{directory} holds a search of a different spec or [search] (only "
                        f"search.{', search.'.join(STOPPING)} and the name may change between "
                        "runs); use --force to start over there, or another --out")
    return Opened("resume", Journal.read(directory / JOURNAL))


def write_record(directory: Path, record: Mapping[str, Any]) -> None:
    """search.json, atomically."""
    write_json(directory / RECORD, record)


def remove_best(directory: Path) -> None:
    """The best design's files of an earlier run, removed by a run that found no best (so an
    older best is never left beside a table that does not hold it)."""
    for name in (BEST_ROBOT, BEST_URDF, BEST_SPEC):
        path = directory / name
        if path.is_file() and not path.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()


__all__ = ["BEST_ROBOT", "BEST_SPEC", "BEST_URDF", "FIGURE_STEM", "FILES", "JOURNAL", "RECORD",
           "STOPPING", "SUMMARY", "TABLE", "Journal", "Opened", "design_key", "identity",
           "open_directory", "read_record", "remove_best", "write_record"]
