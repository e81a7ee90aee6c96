"""The sections of ``make reproduce``, and why a section is computed again or reused.

Each section of REPORT.md (the paper's example, the optimised plans, the Monte Carlo study,
the actuators, robots of N links) is a ``Section``: a name, what its results depend on
besides the code (``inputs``: the resolved specs and ``--set`` items it reads) and how to
compute it (``run``), which writes its files under the output directory and returns its
part of the report (``Outcome``). Like a Snakemake rule, a section is *reused* when nothing
it depends on changed since it was last computed into that directory:

* its *key*, the SHA-256 of its name, its inputs, the source of every module of the
  flatcli package and its data files, and the versions of Python and the numerical
  libraries, equals the one recorded in ``OUT/.reproduce/<name>.json``; and
* every file it wrote is still there with the SHA-256 recorded then.

Then its report lines are taken from the record and nothing is computed; otherwise (or with
``--force``) it runs again. The worker count is not an input: results are the same, bit for
bit, whatever it is. The key covers the whole package, not only the modules a section
calls, so a change anywhere in flatcli recomputes every section: a stale section is never
reused, at the price of recomputing some that a finer key would keep.
"""

from __future__ import annotations

import hashlib
import json
import platform
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from functools import cache
from pathlib import Path
from typing import Any, TextIO, TypeGuard

from flatcli.report.figures import FigureFile
from flatcli.spec import Spec
from flatcli.storage import to_jsonable, write_json

#: Where the sections' records are kept, inside the output directory.
RECORDS_DIR = ".reproduce"
#: Version of the record's layout: a record of another layout is never reused.
RECORD_VERSION = 1
_PACKAGE = Path(__file__).resolve().parents[1]


#: The --set items of ``make reproduce`` that the sections' own studies take too.
SHARED_SETS = ("sweep.trials=", "sweep.seed=")


def with_shared_sets(spec: Spec, sets: Sequence[str]) -> Spec:
    """``spec`` with the --set items of ``make reproduce`` that apply to a section's own
    study (``SHARED_SETS``: its trials and seed)."""
    for item in sets:
        if item.startswith(SHARED_SETS):
            key, _, value = item.partition("=")
            spec = spec.with_overrides({key: int(value)})
    return spec


@dataclass(frozen=True)
class Context:
    """What every section is computed from.

    out : the output directory; base : the resolved default spec (the paper's example)
    montecarlo : the Monte Carlo study's spec file, or None (``--no-montecarlo``: the
        sections then run without their studies)
    sets : ``--set`` items for the studies' specs; workers : worker processes (None: all)
    steps : where a section reports its progress
    figures : the format and resolution every figure is written in (``--format``,
        ``--dpi``)
    """

    out: Path
    base: Spec
    montecarlo: Path | None
    sets: tuple[str, ...]
    workers: int | None
    steps: Steps
    figures: FigureFile = field(default_factory=FigureFile)

    @property
    def quiet(self) -> bool:
        return self.steps.quiet

    @property
    def study(self) -> bool:
        """Whether the sections run their Monte Carlo studies."""
        return self.montecarlo is not None


@dataclass(frozen=True)
class Outcome:
    """A section's part of REPORT.md (``lines``), its findings in a few lines for the
    terminal (``headline``), and the files it wrote, relative to the output directory
    (``files``: globs, expanded after the run)."""

    lines: list[str]
    headline: list[str]
    files: tuple[str, ...]


@dataclass(frozen=True)
class Section:
    """One section of the report: ``inputs(context)`` is what it depends on besides the code
    (JSON-able), ``run(context)`` computes it."""

    name: str
    title: str
    inputs: Callable[[Context], Mapping[str, Any]]
    run: Callable[[Context], Outcome]
    #: None: always; else a predicate on the context (a section of the study only)
    applies: Callable[[Context], bool] | None = None

    def wanted(self, context: Context) -> bool:
        return self.applies is None or self.applies(context)


@dataclass
class Steps:
    """Progress of ``reproduce``: one line per section and per long step within it, on
    stderr (a sweep's own progress bar shows its trials); nothing when quiet."""

    quiet: bool = False
    stream: TextIO = field(default_factory=lambda: sys.stderr)
    _started: float = field(default_factory=time.perf_counter)

    def say(self, text: str) -> None:
        if not self.quiet:
            print(text, file=self.stream, flush=True)

    def section(self, index: int, total: int, title: str) -> None:
        self._started = time.perf_counter()
        self.say(f"[{index}/{total}] {title}")

    def step(self, text: str) -> None:
        """A step of the current section begins (with the time since the section began)."""
        self.say(f"      {text} (at {time.perf_counter() - self._started:.0f} s)")

    def each(self, label: str, items: Sequence[Any]) -> Iterable[Any]:
        """``items``, announcing each: '<label> k/n: item'."""
        for k, item in enumerate(items, 1):
            name = item[0] if isinstance(item, tuple) else item
            self.step(f"{label} {k}/{len(items)}: {name}")
            yield item


@cache
def code_fingerprint() -> str:
    """SHA-256 over the flatcli package's source and data files and the versions of Python
    and the libraries its numbers come from."""
    import matplotlib
    import numba
    import numpy
    import pandas
    import pyarrow
    import scipy

    digest = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*")):
        if path.suffix in (".py", ".toml") and "__pycache__" not in path.parts:
            digest.update(path.relative_to(_PACKAGE).as_posix().encode())
            digest.update(path.read_bytes())
    for module in (numpy, scipy, numba, pandas, pyarrow, matplotlib):
        digest.update(f"{module.__name__} {module.__version__}".encode())
    digest.update(platform.python_version().encode())
    return digest.hexdigest()


def section_key(section: Section, context: Context) -> str:
    """The SHA-256 that must match for ``section`` to be reused (module docstring)."""
    figures = {"figures": [context.figures.format, context.figures.dpi]}
    inputs = json.dumps(to_jsonable({**section.inputs(context), **figures}), sort_keys=True,
                        separators=(",", ":"))
    text = f"{RECORD_VERSION}\n{section.name}\n{inputs}\n{code_fingerprint()}"
    return hashlib.sha256(text.encode()).hexdigest()


def file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def expand(out: Path, patterns: Iterable[str]) -> dict[str, str]:
    """Every regular file (no link) under ``out`` matching ``patterns``, with its SHA-256."""
    found: dict[str, str] = {}
    for pattern in patterns:
        for path in sorted(out.glob(pattern)):
            if path.is_file() and not path.is_symlink() and RECORDS_DIR not in path.parts:
                found[path.relative_to(out).as_posix()] = file_digest(path)
    return found


def record_path(out: Path, name: str) -> Path:
    return out / RECORDS_DIR / f"{name}.json"


@dataclass(frozen=True)
class Record:
    """What a section's last run into a directory left (``OUT/.reproduce/<name>.json``)."""

    key: str
    lines: list[str]
    headline: list[str]
    files: dict[str, str]
    seconds: float
    finished: str


def read_record(out: Path, name: str) -> Record | None:
    """The section's record, or None if there is none or it cannot be trusted (not a
    regular file, not JSON, a field of the wrong type: then the section runs again)."""
    path = record_path(out, name)
    try:
        if not path.is_file() or path.is_symlink() or path.stat().st_size > 1 << 24:
            return None
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(raw, dict) or raw.get("version") != RECORD_VERSION:
        return None
    key, lines, headline = raw.get("key"), raw.get("lines"), raw.get("headline")
    files, seconds, finished = raw.get("files"), raw.get("seconds"), raw.get("finished")
    if not (isinstance(key, str) and _strings(lines) and _strings(headline)
            and isinstance(files, dict) and _strings(list(files.keys()))
            and _strings(list(files.values()))
            and isinstance(seconds, int | float) and isinstance(finished, str)):
        return None
    return Record(key, list(lines), list(headline), dict(files), float(seconds), finished)


def _strings(values: Any) -> TypeGuard[list[str]]:
    return isinstance(values, list) and all(isinstance(v, str) for v in values)


def still_valid(out: Path, record: Record, key: str) -> str | None:
    """None if the record can be reused for ``key``; else why not (one phrase)."""
    if record.key != key:
        return "its inputs or flatcli's code changed"
    for name, digest in record.files.items():
        path = out / name
        if ".." in Path(name).parts or Path(name).is_absolute():
            return f"its record names {name!r}"
        try:
            if not path.is_file() or path.is_symlink() or file_digest(path) != digest:
                return f"{name} changed or is missing"
        except OSError:
            return f"{name} cannot be read"
    return None


def write_record(out: Path, name: str, key: str, outcome: Outcome, seconds: float) -> None:
    write_json(record_path(out, name), {
        "version": RECORD_VERSION,
        "key": key,
        "lines": outcome.lines,
        "headline": outcome.headline,
        "files": expand(out, outcome.files),
        "seconds": seconds,
        "finished": datetime.now(UTC).isoformat(timespec="seconds"),
    })


@dataclass(frozen=True)
class Result:
    """A section as REPORT.md gets it: its lines and headline, whether it was reused, and
    how long it took when computed [s]."""

    section: Section
    lines: list[str]
    headline: list[str]
    reused: bool
    seconds: float
    finished: str


def compute_or_reuse(section: Section, context: Context, force: bool) -> Result:
    """``section`` reused from its record when still valid (and not ``force``), else run
    and recorded."""
    key = section_key(section, context)
    record = None if force else read_record(context.out, section.name)
    why = "--force" if force else "never computed here"
    if record is not None:
        reason = still_valid(context.out, record, key)
        if reason is None:
            context.steps.say(f"      reused: unchanged since {record.finished} "
                              f"(computed in {record.seconds:.0f} s)")
            return Result(section, record.lines, record.headline, True, record.seconds,
                          record.finished)
        why = reason
    context.steps.step(f"computing ({why})")
    started = time.perf_counter()
    outcome = section.run(context)
    seconds = time.perf_counter() - started
    write_record(context.out, section.name, key, outcome, seconds)
    context.steps.say(f"      done in {seconds:.0f} s")
    return Result(section, outcome.lines, outcome.headline, False, seconds,
                  datetime.now(UTC).isoformat(timespec="seconds"))


def stored_result(section: Section, context: Context) -> Result | None:
    """The section's last result in the directory if it is still valid (for ``--only``,
    which computes other sections and keeps these), else None."""
    record = read_record(context.out, section.name)
    if record is None or still_valid(context.out, record, section_key(section, context)):
        return None
    return Result(section, record.lines, record.headline, True, record.seconds,
                  record.finished)
