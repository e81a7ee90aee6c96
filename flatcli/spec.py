"""Experiment specs: TOML in, validated immutable objects out; ``--set`` overrides in one place.

A spec is a TOML file with the tables ``[robot]``, ``[plan]``, ``[track]``, ``[plant]`` and,
for a sweep, ``[sweep]``; every key has a default (the paper's example), so an empty spec is
the paper. ``SCHEMA`` below is the single list of keys, their types, units and defaults: the
README's spec reference is generated from it.

Bad input raises ``SpecError`` with one line naming the key and what is allowed.
"""

from __future__ import annotations

import copy
import difflib
import hashlib
import json
import math
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from flatcli.core.model import MODELS, FlatcliError
from flatcli.storage import to_jsonable

DISTRIBUTIONS = ("normal", "uniform")
#: Perturbable quantities and the spec key each one perturbs.
PERTURB_TARGETS: dict[str, str] = {
    "initial": "track.initial",
    "initial_rate": "track.initial_rate",
    "mass": "plant.mass",
    "inertia": "plant.inertia",
    "length": "plant.length",
    "com": "plant.com",
    "momentum": "plant.momentum",
}
OBJECTIVES = ("energy", "peak_rate", "effort", "margin")
BASES = ("auto", "poly", "bspline")


class SpecError(FlatcliError):
    """A spec problem, reported to the user as one line."""


@dataclass(frozen=True)
class Key:
    """One spec key: its kind, default, unit and bounds."""

    kind: str  # float | int | bool | str | choice | vec2 | vec3 | vec3_or_float | table
    default: Any
    doc: str
    unit: str = ""
    low: float | None = None
    low_open: bool = False  # True: value must be > low; False: >= low
    choices: tuple[str, ...] = ()
    nullable: bool = False
    allow_inf: bool = False  # inf is a meaningful value (no limit)


def _vec(n: int, default: list[float] | None, doc: str, unit: str, **kw: Any) -> Key:
    return Key(f"vec{n}", default, doc, unit, **kw)


SCHEMA: dict[str, dict[str, Key]] = {
    "": {
        "name": Key("str", "paper_example", "run name; default output directory runs/<name>/"),
    },
    "robot": {
        "mass": _vec(3, [1.0, 1.0, 1.0], "link masses m0, m1, m2", "kg", low=0, low_open=True),
        "inertia": _vec(
            3,
            [0.0533, 0.0533, 0.0533],
            "link inertias about their centres of mass",
            "kg m^2",
            low=0,
            low_open=True,
        ),
        "length": _vec(
            3, [0.2, 0.2, 0.2], "link lengths joint to joint", "m", low=0, low_open=True
        ),
        "com": _vec(3, [0.1, 0.1, 0.0], "d_i, centre of mass from the proximal joint", "m"),
        "model": Key(
            "choice",
            "derived",
            "constraint coefficients the planner and controller believe",
            choices=MODELS,
        ),
    },
    "plan": {
        "duration": Key("float", 2.0, "maneuver time T", "s", low=0, low_open=True),
        "start": _vec(3, [1.8, 1.0, 0.0], "th0, th1, th2 at t = 0", "rad"),
        "goal": _vec(3, [1.2, 2.0, 0.0], "th0, th1, th2 at t = T", "rad"),
        "start_rate": Key("float", 0.1, "th1'(0), the free end rate", "rad/s"),
        "goal_rate": Key("float", 0.5, "th1'(T), the free end rate", "rad/s"),
        "samples": Key("int", 201, "points of the plan's time grid", low=2),
        "basis": Key("choice", "auto", "flat-output basis (auto: the paper's cubic, or quintic "
                     "B-splines when optimising)", choices=BASES),
        "degree": Key("int", None, "polynomial degree (default 3) or B-spline degree (default 5)",
                      low=3, nullable=True),
        "size": Key("int", 12, "number of B-spline coefficients per output", low=4),
    },
    "plan.optimize": {
        "objective": Key(
            "choice",
            None,
            "what to optimise (none: the plain plan)",
            choices=OBJECTIVES,
            nullable=True,
        ),
        "angle_limit": _vec(
            3,
            [math.inf, math.inf, math.inf],
            "|th_i| bound along the plan",
            "rad",
            low=0,
            low_open=True,
            allow_inf=True,
        ),
        "rate_limit": Key(
            "float",
            math.inf,
            "|th1'|, |th2'| bound along the plan",
            "rad/s",
            low=0,
            low_open=True,
            allow_inf=True,
        ),
        "min_margin": Key(
            "float", 0.02, "lower bound on |sin th1 th1'| along the plan", "rad/s", low=0
        ),
        "free_rates": Key("bool", True, "optimise th1'(0) and th1'(T) too"),
        "constraint_samples": Key("int", 201, "grid points where limits are imposed", low=10),
        "max_iter": Key("int", 300, "optimiser iteration limit", low=1),
    },
    "track": {
        "initial": _vec(3, [1.96, 0.8, -0.1], "th(0) of the plant", "rad"),
        "initial_rate": Key("float", 0.1, "u1(0) = th1'(0)", "rad/s"),
        "kp": _vec(2, [10.0, 13.0], "kp1, kp2 (as printed in the paper)", "1/s^2"),
        "kv": _vec(2, [100.0, 110.0], "kv1, kv2 (as printed in the paper)", "1/s"),
        "dt": Key("float", 1e-3, "integration and sampling step", "s", low=0, low_open=True),
        "integrator": Key(
            "choice",
            "rk4",
            "fixed-step RK4 or solve_ivp DOP853 reference",
            choices=("rk4", "dop853"),
        ),
        "singular_threshold": Key(
            "float", 1e-2, "margin below which a sample is a singular hit", "rad/s", low=0
        ),
        "sensor_noise": Key("float", 0.0, "std of the measured angles, per step", "rad", low=0),
        "rate_limit": Key(
            "float",
            math.inf,
            "joint-rate limit |th1'|, |th2'| (inf: none)",
            "rad/s",
            low=0,
            low_open=True,
            allow_inf=True,
        ),
        "divergence_bound": Key(
            "float", 1e4, "a state beyond this stops a trial as diverged", low=0, low_open=True
        ),
        "seed": Key("int", 0, "seed of the sensor noise", low=0),
        "trial": Key(
            "int", 0, "noise stream within the seed (a sweep trial's id, to re-run it)", low=0
        ),
    },
    "plant": {
        "mass": _vec(
            3, None, "plant masses (default: robot.mass)", "kg", low=0, low_open=True, nullable=True
        ),
        "inertia": _vec(
            3,
            None,
            "plant inertias (default: robot.inertia)",
            "kg m^2",
            low=0,
            low_open=True,
            nullable=True,
        ),
        "length": _vec(
            3,
            None,
            "plant lengths (default: robot.length)",
            "m",
            low=0,
            low_open=True,
            nullable=True,
        ),
        "com": _vec(3, None, "plant d_i (default: robot.com)", "m", nullable=True),
        "momentum": Key("float", 0.0, "plant angular momentum H0", "kg m^2/s"),
    },
    "sweep": {
        "trials": Key("int", 1000, "trials per grid cell", low=1),
        "seed": Key("int", 0, "seed of every random draw of the sweep", low=0),
        "chunk": Key(
            "int", None, "trials per task (default: chosen from the spec)", low=1, nullable=True
        ),
        "perturb": Key("table", {}, "random perturbations, see below"),
        "grid": Key("table", {}, "spec keys and their lists of values"),
    },
}


def all_keys() -> list[str]:
    """Every dotted key of the schema."""
    return [f"{sec}.{k}" if sec else k for sec, keys in SCHEMA.items() for k in keys]


def _lookup(dotted: str) -> tuple[str, str, Key]:
    section, _, name = dotted.rpartition(".")
    keys = SCHEMA.get(section)
    if keys is None or name not in keys:
        known = all_keys() + [s for s in SCHEMA if s]
        raise SpecError(f"unknown key {dotted!r}{_suggest(dotted, known)}")
    return section, name, keys[name]


def _suggest(word: str, candidates: Iterable[str]) -> str:
    close = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _number(dotted: str, value: Any, key: Key) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpecError(f"{dotted}: expected a number{_unit(key)}, got {value!r}")
    x = float(value)
    if math.isnan(x) or (math.isinf(x) and not key.allow_inf):
        raise SpecError(f"{dotted}: expected a finite number{_unit(key)}, got {value!r}")
    _check_low(dotted, x, key)
    return x


def _unit(key: Key) -> str:
    return f" [{key.unit}]" if key.unit else ""


def _check_low(dotted: str, x: float, key: Key) -> None:
    if key.low is None:
        return
    unit = f" {key.unit}" if key.unit else ""
    if key.low_open and not x > key.low:
        raise SpecError(f"{dotted}: must be > {key.low:g}{unit}, got {x:g}")
    if not key.low_open and not x >= key.low:
        raise SpecError(f"{dotted}: must be >= {key.low:g}{unit}, got {x:g}")


def check_value(dotted: str, value: Any) -> Any:
    """Validate one value for a dotted key; return it normalised (floats, tuples)."""
    _, _, key = _lookup(dotted)
    if value is None and key.nullable:
        return None
    kind = key.kind
    if kind == "float":
        return _number(dotted, value, key)
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise SpecError(f"{dotted}: expected an integer, got {value!r}")
        _check_low(dotted, value, key)
        return int(value)
    if kind == "bool":
        if not isinstance(value, bool):
            raise SpecError(f"{dotted}: expected true or false, got {value!r}")
        return value
    if kind == "str":
        if not isinstance(value, str) or not value.strip():
            raise SpecError(f"{dotted}: expected a non-empty string, got {value!r}")
        if any(c in value for c in "/\\") or value.startswith("."):
            raise SpecError(f"{dotted}: must not contain '/' or '\\' or start with '.'")
        return value
    if kind == "choice":
        if value not in key.choices:
            raise SpecError(
                f"{dotted}: expected one of {list(key.choices)}, got {value!r}"
                f"{_suggest(str(value), key.choices)}"
            )
        return value
    if kind in ("vec2", "vec3"):
        n = int(kind[-1])
        if not isinstance(value, list | tuple) or len(value) != n:
            raise SpecError(f"{dotted}: expected a list of {n} numbers{_unit(key)}, got {value!r}")
        return tuple(_number(f"{dotted}[{i}]", v, key) for i, v in enumerate(value))
    if kind == "table":
        if not isinstance(value, dict):
            raise SpecError(f"{dotted}: expected a table, got {value!r}")
        return value
    raise AssertionError(kind)  # pragma: no cover


def defaults() -> dict[str, Any]:
    """The paper's example as a nested dict (the embedded default spec)."""
    out: dict[str, Any] = {}
    for section, keys in SCHEMA.items():
        for name, key in keys.items():
            dotted = f"{section}.{name}" if section else name
            value = copy.deepcopy(key.default)
            set_dotted(out, dotted, value if value is None else check_value(dotted, value))
    return out


def set_dotted(tree: dict[str, Any], dotted: str, value: Any) -> None:
    """tree["a"]["b"]["c"] = value for dotted = "a.b.c", creating tables on the way."""
    *parents, leaf = dotted.split(".")
    node = tree
    for part in parents:
        node = node.setdefault(part, {})
    node[leaf] = value


def get_dotted(tree: Mapping[str, Any], dotted: str) -> Any:
    node: Any = tree
    for part in dotted.split("."):
        node = node[part]
    return node


def _flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Dotted keys of a user's nested dict, descending into known sections only."""
    out: dict[str, Any] = {}
    for name, value in tree.items():
        dotted = f"{prefix}.{name}" if prefix else name
        if isinstance(value, dict) and dotted in SCHEMA:
            out.update(_flatten(value, dotted))
        else:
            out[dotted] = value
    return out


def parse_set(items: Iterable[str]) -> dict[str, Any]:
    """``--set KEY=VALUE`` items to {dotted key: value}; VALUE is a TOML value, or a bare word."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise SpecError(f"--set: expected KEY=VALUE, got {item!r}")
        try:
            value = tomllib.loads(f"v = {text.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            if not text.strip().replace("_", "").replace("-", "").isalnum():
                raise SpecError(f"--set {key}: cannot read {text!r} as a TOML value") from None
            value = text.strip()
        out[key] = value
    return out


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML file; SpecError for a missing or unreadable file."""
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise SpecError(f"spec file not found: {path}") from None
    except IsADirectoryError:
        raise SpecError(f"spec file is a directory: {path}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"spec file {path} is not valid TOML: {exc}") from None
    except OSError as exc:
        raise SpecError(f"cannot read spec file {path}: {exc.strerror}") from None


@dataclass(frozen=True)
class Spec:
    """A resolved, validated spec: ``tree`` holds every key (defaults filled in)."""

    tree: dict[str, Any]
    is_sweep: bool = False

    def get(self, dotted: str) -> Any:
        return get_dotted(self.tree, dotted)

    @property
    def name(self) -> str:
        return str(self.tree["name"])

    def to_json(self) -> str:
        """Canonical JSON (sorted keys; inf written as a string)."""
        return json.dumps(to_jsonable(self.tree), sort_keys=True, separators=(",", ":"))

    def digest(self) -> str:
        """SHA-256 of the canonical JSON: what makes two sweeps the same experiment."""
        return hashlib.sha256(self.to_json().encode()).hexdigest()

    def with_overrides(self, overrides: Mapping[str, Any]) -> Spec:
        """A new spec with some dotted keys replaced, validated again."""
        tree = copy.deepcopy(self.tree)
        for dotted, value in overrides.items():
            set_dotted(tree, dotted, check_value(dotted, value))
        return _finish(tree, self.is_sweep)


def _finish(tree: dict[str, Any], is_sweep: bool) -> Spec:
    _validate_sweep(tree)
    return Spec(tree, is_sweep)


def load_spec(path: Path | None, sets: Iterable[str] = (), sweep: bool = False) -> Spec:
    """Defaults, then the file (if any), then ``--set`` items; validated.

    Parameters
    ----------
    path : a TOML spec file, or None for the embedded paper example
    sets : ``KEY=VALUE`` strings, applied in order
    sweep : whether the spec is run as a sweep (``flatcli sweep``); other commands validate
        a ``[sweep]`` table but do not use it
    """
    user = read_toml(path) if path is not None else {}
    return resolve(user, parse_set(sets), sweep=sweep)


def resolve(
    user: Mapping[str, Any], overrides: Mapping[str, Any] | None = None, sweep: bool = False
) -> Spec:
    """Validate a user's nested dict plus dotted overrides over the defaults."""
    tree = defaults()
    flat = _flatten(user)
    flat.update(overrides or {})
    for dotted, value in flat.items():
        if dotted in SCHEMA:  # a whole section given as a scalar
            raise SpecError(f"{dotted}: expected a table")
        set_dotted(tree, dotted, check_value(dotted, value))
    return _finish(tree, sweep)


def _validate_sweep(tree: dict[str, Any]) -> None:
    sweep = tree["sweep"]
    for name, table in sweep["perturb"].items():
        validate_perturbation(name, table)
    for dotted, values in sweep["grid"].items():
        validate_grid_entry(tree, dotted, values)


def validate_perturbation(name: str, table: Any) -> None:
    """Check one ``[sweep.perturb]`` entry; SpecError naming what is wrong."""
    where = f"sweep.perturb.{name}"
    if name not in PERTURB_TARGETS:
        raise SpecError(
            f"{where}: unknown perturbation; allowed: {sorted(PERTURB_TARGETS)}"
            f"{_suggest(name, PERTURB_TARGETS)}"
        )
    if not isinstance(table, dict):
        raise SpecError(
            f'{where}: expected an inline table such as {{ dist = "normal", std = 0.01 }}'
        )
    dist = table.get("dist")
    if dist not in DISTRIBUTIONS:
        raise SpecError(f"{where}.dist: expected one of {list(DISTRIBUTIONS)}, got {dist!r}")
    allowed = {"dist", "relative"} | ({"std", "mean"} if dist == "normal" else {"low", "high"})
    for key in table:
        if key not in allowed:
            raise SpecError(
                f"{where}.{key}: not a parameter of a {dist} perturbation; "
                f"allowed: {sorted(allowed)}{_suggest(key, allowed)}"
            )
    required = ("std",) if dist == "normal" else ("low", "high")
    for key in required:
        if key not in table:
            raise SpecError(f"{where}.{key}: required for a {dist} perturbation")
    vector = name in ("initial", "mass", "inertia", "length", "com")
    for key in ("std", "mean", "low", "high"):
        if key in table:
            _perturb_numbers(f"{where}.{key}", table[key], vector)
    if dist == "normal":
        std = table["std"] if isinstance(table["std"], list) else [table["std"]]
        if any(s < 0 for s in std):
            raise SpecError(f"{where}.std: must be >= 0, got {table['std']!r}")
    else:
        lows = _as_list(table["low"], 3 if vector else 1)
        highs = _as_list(table["high"], 3 if vector else 1)
        if any(lo > hi for lo, hi in zip(lows, highs, strict=True)):
            raise SpecError(
                f"{where}: low must be <= high, got low={table['low']!r}, high={table['high']!r}"
            )
    if "relative" in table and not isinstance(table["relative"], bool):
        raise SpecError(f"{where}.relative: expected true or false")
    if table.get("relative") and name in ("initial", "initial_rate", "momentum"):
        raise SpecError(f"{where}.relative: only mass, inertia, length and com can be relative")


def _as_list(value: Any, n: int) -> list[float]:
    return [float(v) for v in value] if isinstance(value, list) else [float(value)] * n


def _perturb_numbers(where: str, value: Any, vector: bool) -> None:
    items = value if isinstance(value, list) else [value]
    if isinstance(value, list) and (not vector or len(value) != 3):
        raise SpecError(
            f"{where}: expected {'a number or 3 numbers' if vector else 'a number'}, got {value!r}"
        )
    for v in items:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise SpecError(f"{where}: expected finite numbers, got {value!r}")


def grid_overrides(key: str, value: Any) -> dict[str, Any]:
    """The dotted spec keys one grid value sets: itself, or a group's table (minus its label)."""
    if isinstance(value, dict):
        return {k: v for k, v in value.items() if k != "label"}
    return {key: value}


def validate_grid_entry(tree: dict[str, Any], dotted: str, values: Any) -> None:
    """Check one ``[sweep.grid]`` entry and its non-empty list of values.

    An entry is a spec key with a list of values, or a *group*: any other name with a list
    of inline tables of spec keys, varied together (e.g. paired gains), each table
    optionally carrying a ``label`` shown in tables and the trials' column.
    """
    where = f"sweep.grid.{dotted!r}"
    if not isinstance(values, list) or not values:
        raise SpecError(f"{where}: expected a non-empty list of values, got {values!r}")
    if all(isinstance(v, dict) for v in values):
        for table in values:
            if "label" in table and not isinstance(table["label"], str):
                raise SpecError(f"{where}: a group's label must be a string")
            keys = [k for k in table if k != "label"]
            if not keys:
                raise SpecError(f"{where}: a group table needs at least one spec key")
            for key in keys:
                _validate_grid_value(tree, f"{where} group key {key!r}", key, table[key])
        return
    if any(isinstance(v, dict) for v in values):
        raise SpecError(f"{where}: mixes tables and plain values")
    for value in values:
        _validate_grid_value(tree, where, dotted, value)


def _validate_grid_value(tree: dict[str, Any], where: str, dotted: str, value: Any) -> None:
    if dotted.startswith("sweep.perturb."):
        parts = dotted.split(".")
        if len(parts) != 4 or parts[2] not in tree["sweep"]["perturb"]:
            raise SpecError(
                f"{where}: a perturbation grid key is sweep.perturb.NAME.PARAM with NAME one of "
                f"the [sweep.perturb] entries {sorted(tree['sweep']['perturb'])}"
            )
        table = dict(tree["sweep"]["perturb"][parts[2]])
        table[parts[3]] = value
        validate_perturbation(parts[2], table)
        return
    if dotted.startswith("sweep.") or dotted == "name":
        raise SpecError(f"{where}: cannot grid over {dotted!r}")
    try:
        _lookup(dotted)
    except SpecError:
        raise SpecError(f"{where}: not a spec key{_suggest(dotted, all_keys())}") from None
    check_value(dotted, value)
