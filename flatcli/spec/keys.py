"""One spec key: its kind, default, unit, bounds and doc, and the one check of its values.

Every value a spec key can take goes through ``Key.check``: a value read from TOML, a
``--set`` override, a grid value of a sweep, and a perturbed plant's parameter drawn inside a
sweep (``Key.check_item``), so the same bad value gets the same message whichever path finds
it. A key is declared as a field of its section's record (``flatcli.spec.schema``) with one of
the helpers below, e.g. ``dt: float = number(1e-3, "integration step", "s", gt=0)``.
"""

from __future__ import annotations

import difflib
import inspect
import math
import unicodedata
from collections.abc import Iterable, Mapping
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

from flatcli.core.errors import FlatcliError

#: Largest magnitude of a finite number in a spec (keys that allow inf excepted): far beyond
#: any physical value of a planar robot, and small enough that the products and powers the
#: model forms of it (up to the fourth power) stay finite in double precision.
MAX_MAGNITUDE = 1e15
#: Largest integer a spec key takes (a signed 64-bit integer, as Parquet and numpy store it).
MAX_INT = 2**63 - 1
#: Longest text value [UTF-8 bytes]: it names directories, whose names have at most 255.
MAX_TEXT_BYTES = 200


class SpecError(FlatcliError):
    """A spec problem, reported to the user as one line."""


def suggest(word: str, candidates: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest candidate, or ''."""
    close = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


@dataclass(frozen=True)
class Key:
    """One spec key.

    Attributes
    ----------
    kind : "float", "int", "bool", "str", "choice", "vector" (``length`` floats), "discs"
        (a list of [x, y, radius]) or "table"
    default : the paper's value, already normalised (floats, tuples); None where ``nullable``
    doc : one line for the spec tables (docs/spec.md)
    unit : SI unit, '' for none
    low : lower bound of a number or of every item of a vector (None: unbounded)
    low_open : True: the value must be > low; False: >= low
    high : upper bound of a number (None: unbounded), inclusive
    choices : the allowed words of a "choice"
    nullable : None is allowed (it means "see doc")
    allow_inf : inf is a meaningful value (no limit)
    length : how many numbers a "vector" holds (0: as many as ``size`` says)
    default_doc : the spec tables' default column when the default is not a plain value
    size : what a vector's length follows on a robot of N joints (``SIZES``): "links"
        (N + 1), "joints" (N) or "inner" (N - 1, the joints before the last); a "numbers"
        key is one number (for every item) or such a list. The length is checked against
        the robot once the whole spec is read (``fit_sizes``)
    """

    kind: str
    default: Any
    doc: str
    unit: str = ""
    low: float | None = None
    low_open: bool = False
    high: float | None = None
    choices: tuple[str, ...] = ()
    nullable: bool = False
    allow_inf: bool = False
    length: int = 0
    default_doc: str = ""
    size: str = ""

    def check(self, where: str, value: Any) -> Any:
        """``value`` normalised (floats, tuples), or SpecError naming ``where``."""
        if value is None and self.nullable:
            return None
        checker = _CHECKS.get(self.kind)
        if checker is None:  # pragma: no cover - a schema typo
            raise AssertionError(self.kind)
        return checker(self, where, value)

    def check_item(self, where: str, index: int, value: float) -> float:
        """One number of a vector, e.g. a perturbed ``plant.mass[1]``; SpecError if bad."""
        return self._number(f"{where}[{index}]", value)

    def bounds_text(self) -> str:
        """What values are allowed, for the spec tables ('> 0', '>= 1', 'true, false', ...)."""
        if self.kind == "discs":
            return "a list of [x, y, radius], radius > 0"
        if self.kind == "choice":
            text = ", ".join(f'"{c}"' for c in self.choices)
        elif self.kind == "bool":
            text = "true, false"
        elif self.low is None:
            text = ""
        elif self.high is not None:
            text = f"{self.low:g} to {self.high:g}"
        else:
            text = f"{'>' if self.low_open else '>='} {self.low:g}"
        if self.allow_inf:
            text += " (inf: no limit)"
        if self.size:
            count = SIZES[self.size].count
            items = f"{count} numbers" if self.kind == "vector" else f"a number or {count}"
            text = f"{items}, each {text}" if text else items
        return text

    def _unit(self) -> str:
        return f" [{self.unit}]" if self.unit else ""

    def _number(self, where: str, value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SpecError(f"{where}: expected a number{self._unit()}, got {value!r}")
        try:
            x = float(value)
        except OverflowError:  # an integer beyond the range of a float
            x = math.copysign(math.inf, value)
        if math.isnan(x) or (math.isinf(x) and not self.allow_inf):
            raise SpecError(f"{where}: expected a finite number{self._unit()}, got {value!r}")
        if math.isfinite(x) and abs(x) > MAX_MAGNITUDE and not self.allow_inf:
            raise SpecError(f"{where}: must lie within +-{MAX_MAGNITUDE:.0e}{self._unit()}, "
                            f"got {x:g}")
        self._check_low(where, x)
        return x

    def _check_low(self, where: str, x: float) -> None:
        unit = f" {self.unit}" if self.unit else ""
        if self.high is not None and not x <= self.high:
            raise SpecError(f"{where}: must be at most {self.high:g}{unit}, got {x:g}")
        if self.low is None:
            return
        if self.low_open and not x > self.low:
            raise SpecError(f"{where}: must be > {self.low:g}{unit}, got {x:g}")
        if not self.low_open and not x >= self.low:
            raise SpecError(f"{where}: must be >= {self.low:g}{unit}, got {x:g}")


def _check_float(key: Key, where: str, value: Any) -> float:
    return key._number(where, value)


def _check_int(key: Key, where: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise SpecError(f"{where}: expected an integer, got {value!r}")
    if abs(value) > MAX_INT:
        raise SpecError(f"{where}: must be at most {MAX_INT} (2^63 - 1), got {value:.3g}")
    key._check_low(where, value)
    return int(value)


def _check_bool(key: Key, where: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise SpecError(f"{where}: expected true or false, got {value!r}")
    return value


#: Unicode categories no text of a spec may hold: control characters (C0, DEL, C1), format
#: characters (bidirectional controls such as U+202E, zero-width joiners, ...), and the line and
#: paragraph separators U+2028, U+2029: they would end up in directory names and in printed
#: lines, where they hide or reorder what follows.
UNPRINTABLE = ("Cc", "Cf", "Zl", "Zp")


def unprintable(text: str) -> str | None:
    """The first character of ``text`` no spec text may hold, as ``U+`` and its hex code
    point (four digits or more), or None."""
    for c in text:
        if unicodedata.category(c) in UNPRINTABLE:
            return f"U+{ord(c):04X}"
    return None


def _check_str(key: Key, where: str, value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise SpecError(f"{where}: expected a non-empty string, got {value!r}")
    if any(c in value for c in "/\\") or value.startswith("."):
        raise SpecError(f"{where}: must not contain '/' or '\\' or start with '.' (it names a "
                        f"directory: '.' and '..' are not names of their own), got {value!r}")
    bad = unprintable(value)
    if bad is not None:
        raise SpecError(f"{where}: must not contain control characters (C0, C1: NUL, newline, "
                        "U+0085, ...), format characters (U+200B, U+202E, ...) or line "
                        f"separators (U+2028, U+2029), got {bad} in {value!a}")
    try:
        size = len(value.encode("utf-8"))
    except UnicodeEncodeError:  # a lone surrogate
        raise SpecError(f"{where}: not valid Unicode text, got {value!r}") from None
    if size > MAX_TEXT_BYTES:
        raise SpecError(f"{where}: at most {MAX_TEXT_BYTES} bytes (it names a directory), "
                        f"got {size}")
    return value


def _check_choice(key: Key, where: str, value: Any) -> str:
    if value not in key.choices:
        raise SpecError(
            f"{where}: expected one of {list(key.choices)}, got {value!r}"
            f"{suggest(str(value), key.choices)}"
        )
    return str(value)


def _check_vector(key: Key, where: str, value: Any) -> tuple[float, ...]:
    if key.size:
        least = SIZES[key.size].length(MIN_JOINTS)
        if not isinstance(value, list | tuple) or len(value) < least:
            raise SpecError(f"{where}: expected a list of {SIZES[key.size].count} >= {least} "
                            f"numbers{key._unit()}, got {value!r}")
    elif not isinstance(value, list | tuple) or len(value) != key.length:
        raise SpecError(
            f"{where}: expected a list of {key.length} numbers{key._unit()}, got {value!r}"
        )
    return tuple(key.check_item(where, i, v) for i, v in enumerate(value))


def _check_numbers(key: Key, where: str, value: Any) -> float | tuple[float, ...]:
    if isinstance(value, list | tuple):
        if not value:
            raise SpecError(f"{where}: expected a number or a list of "
                            f"{SIZES[key.size].count} numbers{key._unit()}, got {value!r}")
        return tuple(key.check_item(where, i, v) for i, v in enumerate(value))
    return key._number(where, value)


def _check_discs(key: Key, where: str, value: Any) -> tuple[tuple[float, float, float], ...]:
    """A list of discs [x, y, radius] [m]: finite, radius > 0."""
    if not isinstance(value, list | tuple):
        raise SpecError(f"{where}: expected a list of [x, y, radius] discs [m], got {value!r}")
    out = []
    for i, disc in enumerate(value):
        if not isinstance(disc, list | tuple) or len(disc) != 3:
            raise SpecError(f"{where}[{i}]: expected [x, y, radius] [m], got {disc!r}")
        x, y, r = (key._number(f"{where}[{i}]", v) for v in disc)
        if not r > 0:
            raise SpecError(f"{where}[{i}]: the radius must be > 0 m, got {r:g}")
        out.append((x, y, r))
    return tuple(out)


def _check_table(key: Key, where: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise SpecError(f"{where}: expected a table, got {value!r}")
    return value


_CHECKS = {
    "float": _check_float,
    "int": _check_int,
    "bool": _check_bool,
    "str": _check_str,
    "choice": _check_choice,
    "vector": _check_vector,
    "numbers": _check_numbers,
    "table": _check_table,
    "discs": _check_discs,
}


@dataclass(frozen=True)
class Size:
    """What the length of a robot-sized vector counts, for N joints: ``offset`` + N items,
    named ``count`` in messages."""

    offset: int
    count: str
    items: str

    def length(self, joints: int) -> int:
        return joints + self.offset


#: The smallest robot: the paper's base and two links.
MIN_JOINTS = 2
#: The sizes of robot-sized vectors (``Key.size``).
SIZES: dict[str, Size] = {
    "links": Size(1, "N + 1", "one per link 0..N"),
    "joints": Size(0, "N", "one per joint 1..N"),
    "inner": Size(-1, "N - 1", "one per joint 1..N-1"),
}


# ---------------------------------------------------------------------------------------
# Declaring a key as a field of a section record: one line per key.

def _declare(key: Key) -> Any:
    if key.kind == "table":
        return field(default_factory=dict, metadata={"key": key})
    return field(default=key.default, metadata={"key": key})


def _low(gt: float | None, ge: float | None) -> dict[str, Any]:
    if gt is not None:
        return {"low": gt, "low_open": True}
    return {"low": ge, "low_open": False}


def number(default: float | None, doc: str, unit: str = "", *, gt: float | None = None,
           ge: float | None = None, le: float | None = None, inf: bool = False,
           nullable: bool = False, default_doc: str = "") -> Any:
    """A float key; ``gt``/``ge`` bound it below, ``le`` above; ``inf``: inf means no
    limit."""
    return _declare(Key("float", default, doc, unit, high=le, allow_inf=inf, nullable=nullable,
                        default_doc=default_doc, **_low(gt, ge)))


def integer(default: int | None, doc: str, unit: str = "", *, ge: int | None = None,
            le: int | None = None, nullable: bool = False, default_doc: str = "") -> Any:
    """An int key, bounded below by ``ge`` (and above by ``le``)."""
    return _declare(Key("int", default, doc, unit, low=ge, high=le, nullable=nullable,
                        default_doc=default_doc))


def vector(length: int | str, default: tuple[float, ...] | None, doc: str, unit: str = "",
           *, gt: float | None = None, ge: float | None = None, inf: bool = False,
           nullable: bool = False, default_doc: str = "") -> Any:
    """A list of ``length`` floats, each bounded like a number key; a ``SIZES`` name for a
    length that follows the robot's."""
    sized = {"size": length} if isinstance(length, str) else {"length": length}
    return _declare(Key("vector", default, doc, unit, allow_inf=inf, nullable=nullable,
                        default_doc=default_doc, **sized, **_low(gt, ge)))


def numbers(size: str, default: float | None, doc: str, unit: str = "", *,
            gt: float | None = None, ge: float | None = None, inf: bool = False,
            nullable: bool = False, default_doc: str = "") -> Any:
    """One number for every item, or a list of them, as many as ``size`` (``SIZES``) says."""
    return _declare(Key("numbers", default, doc, unit, allow_inf=inf, nullable=nullable,
                        size=size, default_doc=default_doc, **_low(gt, ge)))


def choice(choices: tuple[str, ...], default: str | None, doc: str, *,
           nullable: bool = False) -> Any:
    """One of ``choices`` (taken from the enumeration's one home, e.g. the core's)."""
    return _declare(Key("choice", default, doc, choices=tuple(choices), nullable=nullable))


def flag(default: bool, doc: str) -> Any:
    """true or false."""
    return _declare(Key("bool", default, doc))


def text(default: str, doc: str) -> Any:
    """A non-empty string usable as a directory name."""
    return _declare(Key("str", default, doc))


def discs(doc: str, unit: str = "m") -> Any:
    """A list of discs [x, y, radius] (default: none)."""
    return _declare(Key("discs", (), doc, unit))


def table(doc: str, default_doc: str = "{}") -> Any:
    """A TOML table kept as written (validated by its own rules, see ``flatcli.spec.sweeps``)."""
    return _declare(Key("table", {}, doc, default_doc=default_doc))


def settings_keys(registry: Mapping[str, tuple[type, str]]) -> Any:
    """A class decorator (applied before ``dataclass``) adding to a section's record one key
    ``<prefix><field>`` per field of each controller's settings record in ``registry``
    ({controller: (record, prefix)}, ``core.controllers.settings.SETTINGS``; the fields
    made by ``setting``): kind, default, doc, unit and bounds come from the settings' own
    field, so a controller's keys are generated from its settings alone."""

    def add(record: type) -> type:
        annotations = dict(inspect.get_annotations(record))
        for settings, prefix in registry.values():
            for f in fields(settings):
                name = prefix + f.name
                annotations[name], declared = _setting_key(f)
                setattr(record, name, declared)
        record.__annotations__ = annotations
        return record

    return add


def _setting_key(f: Any) -> tuple[str, Any]:
    """The annotation and the declared key of one settings field (``settings_keys``)."""
    meta = f.metadata["setting"]
    default = None if f.default is MISSING else f.default
    if meta["kind"] == "joints":
        return "Vector | None", vector("joints", default, meta["doc"], meta["unit"],
                                       nullable=True, default_doc="the controller's own")
    if meta["kind"] == "int":
        return "int", integer(default, meta["doc"], meta["unit"], ge=meta["ge"], le=meta["le"])
    return "float", number(default, meta["doc"], meta["unit"], gt=meta["gt"], ge=meta["ge"],
                           le=meta["le"])
