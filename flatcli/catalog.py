"""Runs as data: ``flatcli runs`` and ``flatcli.runs()``, the runs below a directory as rows
one can filter, sort, compare, print as a table that fits the terminal or as JSON, or hand
to pandas (one row per run, its spec keys and metrics as columns, as ``mlflow.search_runs``).

A run's fields: ``run`` (its directory, relative to the root searched), ``command``,
``name``, ``time``, ``status``, ``outcome`` (what the robot did: a track run's outcome, a
sweep's "reached k/n"), ``tags`` (``--tag``), every number its record holds (a track
run's metrics, a plan's summary, a sweep's trials by status) and every key of its resolved
spec, dotted (``plant.model``, ``track.kp``). A filter is ``KEY OP VALUE`` with OP one of
``= != < <= > >= ~`` (``~``: contains); VALUE is read as a TOML value (a number, a list, a
word); ``tag=x`` holds for a run tagged x. A run without the key matches no filter on it.
Everything here reads run records and manifests only (``flatcli.rundirs``): quick for a
thousand runs.
"""

from __future__ import annotations

import json
import math
import re
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from flatcli.report import table
from flatcli.rundirs import (
    LATEST,
    RECORD,
    SWEEP_MANIFEST,
    RunDirectoryError,
    RunInfo,
    followed,
    list_runs,
    run_info,
    shown,
)
from flatcli.spec.keys import SpecError, suggest
from flatcli.spec.tree import flatten

#: The fields every run has, in the order tables and frames show them.
FIELDS = ("run", "command", "name", "time", "status", "outcome", "tags")
#: Filter operators, longest first (so "<=" is not read as "<").
OPERATORS = ("!=", ">=", "<=", "=", "<", ">", "~")
_FILTER = re.compile(r"^\s*(?P<key>[^!<>=~\s][^!<>=~]*?)\s*(?P<op>!=|>=|<=|=|<|>|~)\s*"
                     r"(?P<value>.*?)\s*$")
#: Field that ``--filter tag=x`` reads (``tags`` too).
TAG_KEYS = ("tag", "tags")


# ---------------------------------------------------------------------------------------
# One run's fields.

def flat_spec(tree: Mapping[str, Any]) -> dict[str, Any]:
    """A spec tree as {dotted key: value}, into its tables too (``sweep.perturb.initial.std``,
    ``sweep.grid."plant.com"``)."""
    return flatten(tree, quote=True)


@dataclass(frozen=True)
class Row:
    """A run as a row: its fields (``FIELDS``), numbers and spec keys, by name."""

    info: RunInfo
    where: str  # the run's directory relative to the root searched

    def fields(self) -> dict[str, Any]:
        info = self.info
        return {"run": self.where, "command": info.command, "name": info.name,
                "time": info.time, "status": info.status, "outcome": info.outcome,
                "tags": list(info.tags), **info.values, **flat_spec(info.spec)}

    def get(self, key: str) -> Any:
        """A field's value, or ``_ABSENT``."""
        if key in TAG_KEYS:
            return list(self.info.tags)
        return self.fields().get(key, _ABSENT)


_ABSENT = object()


def rows_below(root: Path) -> list[Row]:
    """The runs below ``root``, oldest first."""
    out = []
    for info in list_runs(root):
        where = str(info.path.relative_to(root)) if info.path != root else "."
        out.append(Row(info, where))
    return out


# ---------------------------------------------------------------------------------------
# Filters and order.

@dataclass(frozen=True)
class Filter:
    """``KEY OP VALUE``: one condition on a run's field."""

    key: str
    op: str
    value: Any
    text: str  # as given, for messages

    @classmethod
    def parse(cls, text: str) -> Filter:
        """A filter from ``--filter`` text; SpecError naming it if it is not one."""
        from flatcli.spec import parse_set

        match = _FILTER.match(text)
        if match is None or not match.group("value"):
            raise SpecError(f"--filter {text!r}: expected KEY OP VALUE with OP one of "
                            f"{' '.join(OPERATORS)}, e.g. 'status=ok' or 'err_y_final<1e-3'")
        key, op, raw = match.group("key"), match.group("op"), match.group("value")
        if op == "~":
            value: Any = raw
        elif key == "time":
            value = _time(raw, text)
        else:
            try:
                value = parse_set([f"v={raw}"])["v"]
            except SpecError:
                value = raw  # text as written ("a b"), compared as text
        if op in ("<", "<=", ">", ">=") and not (_is_number(value) or isinstance(value,
                                                                               datetime)):
            raise SpecError(f"--filter {text!r}: {op} compares numbers and times, got "
                            f"{raw!r}")
        return cls(key, op, value, text)

    def holds(self, row: Row) -> bool:
        """Whether a run meets the condition (never when it has no such field)."""
        actual = row.get(self.key)
        if actual is _ABSENT:
            return False
        if self.key in TAG_KEYS:
            return self._tags(actual)
        if self.op == "~":
            return self.value in _text(actual)
        if self.op in ("=", "!="):
            return _equal(actual, self.value) == (self.op == "=")
        if isinstance(self.value, datetime):
            if not isinstance(actual, datetime):
                return False
            return _ordered(actual.timestamp(), self.op, self.value.timestamp())
        if not _is_number(actual) or (isinstance(actual, float) and math.isnan(actual)):
            return False
        return _ordered(float(actual), self.op, float(self.value))

    def _tags(self, tags: list[str]) -> bool:
        if self.op == "~":
            return any(self.value in t for t in tags)
        present = str(self.value) in tags
        if self.op in ("=", "!="):
            return present == (self.op == "=")
        return False


def _time(raw: str, text: str) -> datetime:
    """A time of a filter: an ISO date or date and time, local unless it says."""
    try:
        return datetime.fromisoformat(raw).astimezone()
    except ValueError:
        raise SpecError(f"--filter {text!r}: a time is an ISO date, e.g. 2026-11-25 or "
                        "2026-11-25T14:00") from None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _ordered(a: float, op: str, b: float) -> bool:
    return {"<": a < b, "<=": a <= b, ">": a > b, ">=": a >= b}[op]


def _canonical(value: Any) -> Any:
    """Numbers as floats (1 and 1.0 are one value), lists and tuples alike."""
    if isinstance(value, list | tuple):
        return [_canonical(v) for v in value]
    if _is_number(value):
        return float(value)
    if isinstance(value, str) and value in ("inf", "-inf"):
        return float(value)  # how a record's JSON holds a spec's inf
    return value


def _equal(a: Any, b: Any) -> bool:
    return bool(_canonical(a) == _canonical(b))


def _text(value: Any) -> str:
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, str):
        return value
    return json.dumps(value)


def known_keys(rows: Sequence[Row]) -> list[str]:
    """Every field some run has."""
    keys: dict[str, None] = dict.fromkeys([*FIELDS, "tag"])
    for row in rows:
        keys.update(dict.fromkeys(row.fields()))
    return list(keys)


def select(rows: Sequence[Row], filters: Sequence[Filter], sort: str | None = None,
           reverse: bool = False) -> list[Row]:
    """The runs meeting every filter, in ``sort``'s order (runs without that field last);
    SpecError for a key no run has."""
    known = known_keys(rows)
    for key in [*(f.key for f in filters), *([sort] if sort else [])]:
        if rows and key not in known:
            raise SpecError(f"--filter/--sort: no run below has {key!r}{suggest(key, known)} "
                            "(fields: run, command, name, time, status, outcome, tag; metrics "
                            "such as err_y_final; spec keys such as plant.model)")
    chosen = [r for r in rows if all(f.holds(r) for f in filters)]
    if sort is None:
        return chosen
    present = [r for r in chosen if _sortable(r.get(sort))]
    missing = [r for r in chosen if not _sortable(r.get(sort))]
    numeric = all(_is_number(r.get(sort)) for r in present)
    present.sort(key=lambda r: _sort_key(r.get(sort), numeric), reverse=reverse)
    return present + missing


def _sortable(value: Any) -> bool:
    if value is _ABSENT or value is None:
        return False
    return not (isinstance(value, float) and math.isnan(value))


def _sort_key(value: Any, numeric: bool) -> Any:
    if numeric:
        return float(value)
    if isinstance(value, datetime):
        return value.isoformat()
    return _text(value)


# ---------------------------------------------------------------------------------------
# What is shown: a table that fits, JSON, a DataFrame.

def _when(time: datetime | None, short: bool = False) -> str:
    if time is None:
        return "-"
    return f"{time:%m-%d %H:%M}" if short else f"{time:%Y-%m-%d %H:%M:%S}"


#: A run directory's stamp (``flatcli.rundirs.stamp``): shown by its id alone where the table
#: must be narrow (the time column has the rest).
_STAMP = re.compile(r"\b[0-9]{8}-[0-9]{6}-([0-9a-f]{6})\b")


def runs_table(root: Path, rows: Sequence[Row] | None = None, width: int | None = None
               ) -> str:
    """``flatcli runs`` as a table (runs that ``latest`` points to are marked), at most
    ``width`` characters wide where it can be. Narrowed step by step, each only if still
    too wide: shorter times and stamps by their ids (``…439c92``; the time column has the
    rest), the name column where every run's directory says it, fewer key metrics per row
    (``(+k)`` says how many more), then the name, tags and outcome columns; a last line says
    what was left out (``--json`` has every field)."""
    rows = rows_below(root) if rows is None else list(rows)
    if not rows:
        return f"no runs in {root}"
    latest = {r for p in root.rglob(LATEST) if p.is_symlink() and (r := followed(p))}
    tagged = any(r.info.tags for r in rows)
    outcomes = any(r.info.outcome for r in rows)
    redundant = all(r.where.split("/")[0] == r.info.name for r in rows)

    def build(short: bool, most: int | None, name: bool, tags: bool,
              outcomes: bool = outcomes) -> str:
        headers = ["run", "command", *(["name"] if name else []), "time", "status",
                   *(["outcome"] if outcomes else []), *(["tags"] if tags else []),
                   "key metrics"]
        body = []
        for row in rows:
            info = row.info
            where = _STAMP.sub(lambda m: "\u2026" + m.group(1), row.where) if short else \
                row.where
            where += " (latest)" if followed(info.path) in latest else ""
            cells = [where, info.command, *([info.name] if name else []),
                     _when(info.time, short), info.status,
                     *([info.outcome] if outcomes else [])]
            if tags:
                cells.append(", ".join(info.tags))
            cells.append(info.metrics_text(most))
            body.append([shown(c) for c in cells])
        return table(headers, body)

    text = build(False, None, True, tagged)
    if width is None or _width(text) <= width:
        return text
    most = max(len(r.info.metrics) for r in rows)
    layouts = [(most, not redundant, tagged, outcomes),
               *((k, not redundant, tagged, outcomes) for k in range(most - 1, 0, -1)),
               (1, False, tagged, outcomes), (1, False, False, outcomes),
               (1, False, False, False)]
    for most_, name, tags, shown_outcomes in layouts:
        text = build(True, most_, name, tags, shown_outcomes)
        if _width(text) <= width:
            break
    dropped = [what for what, shown_ in (("name", name or redundant),
                                         ("tags", tags or not tagged),
                                         ("outcome", shown_outcomes or not outcomes))
               if not shown_]
    if dropped or most_ < most:
        left = [*dropped, *(["some key metrics"] if most_ < most else [])]
        note = f"(narrowed to {width} columns: {', '.join(left)} left out; --json has all)"
        text += "\n" + textwrap.fill(note, max(width, 40))
    return text


def _width(text: str) -> int:
    return max(len(line) for line in text.splitlines())


def runs_json(rows: Sequence[Row]) -> str:
    """The runs as a JSON array, one object per run: its fields, ``metrics`` (every number
    of its record; null where one does not apply) and ``spec`` (as run.json holds it)."""
    from flatcli.storage import to_jsonable

    items = []
    for row in rows:
        info = row.info
        items.append({"run": row.where, "path": str(info.path), "command": info.command,
                      "name": info.name, "time": info.time.isoformat() if info.time else None,
                      "status": info.status, "outcome": info.outcome,
                      "tags": list(info.tags), "metrics": info.values, "spec": info.spec})
    return json.dumps(to_jsonable(items), indent=2, sort_keys=True)


def runs_frame(rows: Sequence[Row]) -> Any:
    """The runs as a pandas DataFrame: one row per run; ``run``, ``path``, ``command``,
    ``name``, ``time`` (a timestamp), ``status``, ``outcome``, ``tags`` (a list), then every
    number of the runs' records (nan where a run has none, or it does not apply), then every
    spec key, dotted (``plant.model``, ``track.kp``). Times are UTC timestamps."""
    import pandas as pd

    records = []
    numbers: dict[str, None] = {}
    keys: dict[str, None] = {}
    for row in rows:
        info = row.info
        spec = flat_spec(info.spec)
        numbers.update(dict.fromkeys(info.values))
        keys.update(dict.fromkeys(k for k in spec if k not in FIELDS))
        records.append({"run": row.where, "path": str(info.path), "command": info.command,
                        "name": info.name, "time": info.time, "status": info.status,
                        "outcome": info.outcome, "tags": list(info.tags),
                        **{k: _cell(v) for k, v in info.values.items()},
                        **{k: _cell(v) for k, v in spec.items() if k not in FIELDS}})
    columns = ["run", "path", "command", "name", "time", "status", "outcome", "tags", *numbers,
               *(k for k in keys if k not in numbers)]
    frame = pd.DataFrame.from_records(records, columns=columns)
    frame["time"] = pd.to_datetime(frame["time"], utc=True)  # one time zone: comparable
    return frame


def _cell(value: Any) -> Any:
    """A value for a DataFrame cell: null metrics as nan, JSON's "inf" as inf."""
    if value is None:
        return math.nan
    if isinstance(value, str) and value in ("inf", "-inf"):
        return float(value)
    if isinstance(value, list):
        return [_cell(v) for v in value]
    return value


# ---------------------------------------------------------------------------------------
# flatcli runs --compare A B [C ...].

def _same(values: Sequence[Any]) -> bool:
    texts = {json.dumps(v, sort_keys=True) for v in values}
    return len(texts) == 1


def _show(value: Any) -> str:
    if value is _ABSENT:
        return "(not set)"
    if isinstance(value, str):
        return shown(value)
    return json.dumps(value, separators=(", ", " = ")).replace('"', "")


def run_of(path: Path) -> RunInfo:
    """The run a directory holds, for --compare: ``runs/<name>`` is its latest run."""
    info = run_info(path)
    if info is None and not (path / RECORD).exists() and not (path / SWEEP_MANIFEST).exists() \
            and (path / LATEST).is_dir():
        info = run_info(path / LATEST)
    if info is None:
        raise RunDirectoryError(f"--compare: {path} holds no run (no run.json or sweep.json)")
    return info


def compare_runs(*paths: Path) -> str:
    """The spec keys two or more runs differ in, one column per run (and their key metrics
    and statuses side by side)."""
    if len(paths) < 2:
        raise RunDirectoryError("--compare: give two runs or more")
    infos = [run_of(p) for p in paths]
    labels = [_label(i) for i in range(len(paths))]
    specs = [flat_spec(i.spec) for i in infos]
    keys = list(dict.fromkeys(k for spec in specs for k in spec))
    rows = []
    for key in keys:
        values = [spec.get(key, _ABSENT) for spec in specs]
        present = {v is not _ABSENT for v in values}
        if len(present) > 1 or not _same([v for v in values if v is not _ABSENT]):
            rows.append([shown(key), *(_show(v) for v in values)])
    lines = [f"{label} = {path} ({shown(info.command)} {info.name!r})"
             for label, path, info in zip(labels, paths, infos, strict=True)]
    lines.append("")
    if rows:
        lines += [f"{len(rows)} spec key{'s differ' if len(rows) > 1 else ' differs'}:", "",
                  table(["key", *labels], rows)]
    else:
        lines.append("the specs are identical")
    metric_keys = list(dict.fromkeys(k for i in infos for k in i.metrics))
    if metric_keys:
        lines += ["", table(["metric", *labels],
                            [[shown(k), *(i.metrics.get(k, "-") for i in infos)]
                             for k in metric_keys])]
    if len({i.status for i in infos}) > 1:
        lines += ["", "status: " + ", ".join(f"{label} {shown(i.status)}"
                                             for label, i in zip(labels, infos, strict=True))]
    return "\n".join(lines)


def _label(index: int) -> str:
    """A, B, ..., Z, AA, AB, ...: the column of a compared run."""
    text = ""
    index += 1
    while index:
        index, rest = divmod(index - 1, 26)
        text = chr(ord("A") + rest) + text
    return text
