"""From TOML and ``--set`` items to a validated ``Spec``: the one place values are checked.

Defaults, then the file (if any), then ``--set`` items in order; every value goes through its
key's check (``flatcli.spec.keys.Key.check``), the sweep's tables through
``flatcli.spec.sweeps``; then the records are built. Bad input raises ``SpecError`` with one
line naming the key and what is allowed.
"""

from __future__ import annotations

import copy
import math
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from flatcli.spec.compose import compose
from flatcli.spec.keys import MAX_INT, SpecError
from flatcli.spec.limits import check_joints, check_limits
from flatcli.spec.schema import (
    SCHEMA,
    SpecRecord,
    check_value,
    find_key,
    fit_sizes,
    from_values,
    lookup,
)
from flatcli.spec.searches import validate_search
from flatcli.spec.sweeps import PERTURB_PREFIX, is_perturbation_param, validate_sweep
from flatcli.spec.tree import read_toml

#: Deepest nesting of lists and tables a spec value may have (a grid of groups of vectors
#: needs 3).
MAX_DEPTH = 8


@dataclass(frozen=True)
class Spec(SpecRecord):
    """A resolved, validated spec: every key has a value (defaults filled in).

    Build one with ``flatcli.spec.resolve`` or ``load_spec``; read it by attribute
    (``spec.track.dt``, ``spec.robot.mass``).
    """

    def with_overrides(self, overrides: Mapping[str, Any]) -> Spec:
        """A new spec with some dotted keys replaced, validated again."""
        return build(with_overrides(self.values(), overrides), parent=self)


def build(values: Mapping[str, Any], parent: Spec | None = None) -> Spec:
    """A Spec from {dotted key: value}, every value checked; keys not given keep defaults.

    ``sweep.perturb.NAME.PARAM`` keys (a grid cell's perturbation parameter) set that
    parameter of the ``[sweep.perturb]`` entry NAME. ``parent``: a validated spec whose
    values these are, some replaced (``Spec.with_overrides``): a value that is the parent's
    own object is not checked again, nor is the parent's grid when the robot keeps its
    joints, so a sweep's N cells cost O(N), not O(N^2) (each cell's spec holds the whole
    grid).
    """
    checked: dict[str, Any] = {}
    params: dict[str, Any] = {}
    known = parent.values() if parent is not None else {}
    fresh = {k: v for k, v in values.items() if not (k in known and known[k] is v)}
    for dotted, value in fresh.items():
        _scan(dotted, value, 0)
    for dotted, value in values.items():
        if dotted in SCHEMA:  # a whole section given as a scalar
            raise SpecError(f"{dotted}: expected a table")
        if is_perturbation_param(dotted):
            params[dotted] = value
        elif dotted not in fresh:
            checked[dotted] = value  # checked and normalised when the parent was built
        else:
            checked[dotted] = check_value(dotted, value)
    if params:
        perturb = copy.deepcopy(dict(checked.get("sweep.perturb", {})))
        for dotted, value in params.items():
            name, param = dotted.removeprefix(PERTURB_PREFIX).split(".")
            perturb[name] = {**perturb.get(name, {}), param: value}
        checked["sweep.perturb"] = perturb
    spec = fit_sizes(from_values(Spec, checked), checked)
    check_joints(spec.joints)  # before anything costs O(N^3)
    grid_checked = (parent is not None and spec.sweep.grid is parent.sweep.grid
                    and spec.joints == parent.joints)
    validate_sweep(spec.sweep, spec.joints, spec.plant.torque_limit,
                   spec.task.end_effector is not None, grid_checked=grid_checked)
    if not grid_checked:
        check_grid_shapes(spec.sweep.grid)
    validate_search(spec)
    check_derived(spec)
    check_verify(spec.sweep.verify)
    check_limits(spec)
    return spec


def check_verify(verify: float) -> None:
    """``sweep.verify`` is a fraction (below 1) or a whole count of trials."""
    if verify >= 1 and (not math.isfinite(verify) or verify != int(verify)):
        raise SpecError(f"sweep.verify: a fraction below 1 or a whole count of trials, got "
                        f"{verify:g}")


def _scan(where: str, value: Any, depth: int) -> None:
    """Refuse what no key takes before any check looks closer: nesting deeper than
    ``MAX_DEPTH``, integers beyond 64 bits, text that is not valid Unicode."""
    if depth > MAX_DEPTH:
        raise SpecError(f"{where}: nested deeper than {MAX_DEPTH} lists or tables")
    if isinstance(value, bool):
        return
    if isinstance(value, int) and abs(value) > MAX_INT:
        raise SpecError(f"{where}: integer out of range (at most 2^63 - 1), got {value:.3g}")
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            raise SpecError(f"{where}: not valid Unicode text") from None
    elif isinstance(value, Mapping):
        for k, v in value.items():
            _scan(f"{where}.{k}", v, depth + 1)
    elif isinstance(value, list | tuple):
        for v in value:
            _scan(where, v, depth + 1)


def _shape(value: Any) -> str:
    """What kind of column a grid value makes: a number, text, a flag, a list, a table."""
    if isinstance(value, bool):
        return "true/false"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "text"
    if isinstance(value, Mapping):
        return "a table"
    return f"a list of {len(value)}"


def _mixed(key: str, shapes: set[str]) -> set[str]:
    """The shapes of a grid key's values that do not fit one column: a key that takes a
    number or one per joint (``Key.kind`` "numbers", e.g. ``plan.goal_rate``) makes a list
    column of numbers and lists alike (a number spread over the joints)."""
    found = find_key(key)  # None: a perturbation parameter or a group's name
    numbers = found is not None and found.kind == "numbers"
    if numbers and any(s.startswith("a list") for s in shapes):
        return shapes - {"a number"}
    return shapes


def check_grid_shapes(grid: Mapping[str, Any]) -> None:
    """Every value of one grid key has the same shape (all numbers, or all lists of the same
    length, ...), and so does every group key across a group's tables: each grid key is one
    column of trials.parquet, with one type (a key that takes a number or one per joint may
    mix the two)."""
    for dotted, values in grid.items():
        where = f"sweep.grid.{dotted!r}"
        if all(isinstance(v, Mapping) for v in values):
            columns: dict[str, set[str]] = {}
            for table in values:
                for key, value in table.items():
                    columns.setdefault(key, set()).add(_shape(value))
            for key, shapes in columns.items():
                shapes = _mixed(key, shapes)
                if len(shapes) > 1:
                    mixed = " and ".join(sorted(shapes))
                    raise SpecError(f"{where}: group key {key!r} mixes {mixed}; give it the "
                                    "same shape in every table")
            continue
        shapes = _mixed(dotted, {_shape(v) for v in values})
        if len(shapes) > 1:
            raise SpecError(f"{where}: mixes {' and '.join(sorted(shapes))}; give every value "
                            "the same shape (e.g. a list of 3 numbers each)")


#: Smallest mass [kg], inertia [kg m^2] and length [m] of a link: the constraint's
#: coefficients are products of up to four of them, which must not underflow.
MIN_PHYSICAL = 1e-12
_PHYSICAL = ("mass", "inertia", "length")


def check_derived(spec: Spec) -> None:
    """Quantities computed from the spec before any run are meaningful numbers: the links'
    masses, inertias and lengths are not so small that products of them underflow, and the
    constraint coefficients of the robot (in its model) and of the plant are finite. (Plans
    are checked where they are made.)"""
    import numpy as np

    from flatcli.core.robots.chain import barycentric_matrix
    from flatcli.core.robots.params import Links, constraint_coefficients

    robot, plant = spec.robot, spec.plant
    for section, record in (("robot", robot), ("plant", plant)):
        for name in _PHYSICAL:
            values = getattr(record, name)
            for i, v in enumerate(values or ()):
                if v < MIN_PHYSICAL:
                    raise SpecError(f"{section}.{name}[{i}]: must be >= {MIN_PHYSICAL:g} "
                                    f"(products of such values underflow), got {v:g}")
    nominal = (robot.mass, robot.inertia, robot.length, robot.com)
    real = (plant.mass or robot.mass, plant.inertia or robot.inertia,
            plant.length or robot.length, plant.com or robot.com)
    for section, values, model in (("robot", nominal, robot.model),
                                   ("plant", real, "derived")):
        if spec.joints == 2:
            k = constraint_coefficients(Links(*(v for group in values for v in group)),
                                        model)  # type: ignore[arg-type]
            bad = [name for name, v in zip(k._fields, k, strict=True) if not math.isfinite(v)]
            what = f"the constraint coefficient {bad[0]}" if bad else ""
        else:  # a chain of N links: its momentum's barycentric matrix K
            mass, _, length, com = (np.asarray(v, dtype=float) for v in values)
            finite = np.isfinite(barycentric_matrix(mass, length, com)).all()
            what = "" if finite else "the barycentric matrix K"
        if what:
            raise SpecError(f"{section}: {what} is not finite for these parameters (mass, "
                            "inertia, length, com); use physical magnitudes")


def resolve(user: Mapping[str, Any], overrides: Mapping[str, Any] | None = None, *,
            base: Path | None = None, source: Path | None = None) -> Spec:
    """Validate a user's nested dict (a parsed TOML file) plus dotted overrides.

    The spec's robot file and includes are merged first (``flatcli.spec.compose``; relative
    names from ``base``, the directory of ``source``, the file ``user`` was read from); a
    ``robot`` override that names a robot file replaces the spec's choice (``--robot``).
    """
    extra = dict(overrides or {})
    if "include" in extra:
        raise SpecError("include: spec files are included by a spec file (include = "
                        "[\"my_robot.toml\"]), not by --set")
    robot = extra.pop("robot") if "robot" in extra and not isinstance(
        extra["robot"], Mapping) else None
    flat = compose(user, base, robot, source)
    return build(with_overrides(flat, extra))


#: An override key ``~KEY`` removes KEY (``--set ~KEY``; ``{"~KEY": None}`` through the API).
UNSET_PREFIX = "~"


def with_overrides(values: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted ``values`` with ``overrides`` applied in order: a key set, or ``~KEY`` removed
    (with every key of a section: it takes its default again, as if never given)."""
    from flatcli.spec.compose import remove_key

    out = dict(values)
    for key, value in overrides.items():
        if key.startswith(UNSET_PREFIX):
            if value is not None:
                raise SpecError(f"--set {key}: removes the key; it takes no value")
            remove_key(out, key[len(UNSET_PREFIX):].strip(), f"--set {key}")
        else:
            out[key] = value
    return out


def resolve_robot(user: Mapping[str, Any], overrides: Mapping[str, Any] | None = None, *,
                  base: Path | None = None, source: Path | None = None) -> Spec:
    """``resolve`` for what describes the robot alone (``flatcli export-robot``): composed and
    overridden as ``resolve`` does, every key checked to exist and ``name`` and the
    ``robot.*`` keys checked, but only they are built (the other sections keep their defaults,
    unchecked against the robot's N), so a robot file without a maneuver (a URDF, a robot
    of N != 2 joints) exports."""
    extra = dict(overrides or {})
    robot = extra.pop("robot") if "robot" in extra and not isinstance(
        extra["robot"], Mapping) else None
    flat = compose(user, base, robot, source)
    flat.update(extra)
    checked: dict[str, Any] = {}
    for dotted, value in flat.items():
        _scan(dotted, value, 0)
        if dotted in SCHEMA:
            raise SpecError(f"{dotted}: expected a table")
        if not is_perturbation_param(dotted):
            key = check_value if dotted == "name" or dotted.startswith("robot.") else None
            if key is None:
                lookup(dotted)
            else:
                checked[dotted] = key(dotted, value)
    spec = from_values(Spec, checked)
    check_joints(spec.joints)
    return spec


def load_spec(path: Path | None, sets: Iterable[str] = ()) -> Spec:
    """Defaults, then the file (if any, composed: its robot file and includes first), then
    ``--set`` items; validated.

    Parameters
    ----------
    path : a TOML spec file, or None for the embedded paper example
    sets : ``KEY=VALUE`` strings, applied in order (``robot=NAME`` picks a robot file)
    """
    if path is None:
        return resolve({}, parse_set(sets))
    return resolve(read_toml(path), parse_set(sets), base=path.parent, source=path)


#: Characters a bare word of ``--set`` may have besides letters and digits (a name, or a
#: file's path: ``--set robot=../robots/my.toml``).
_BARE = str.maketrans("", "", "_-./~")


def parse_set(items: Iterable[str]) -> dict[str, Any]:
    """``--set KEY=VALUE`` items to {dotted key: value}, in the order they apply; VALUE is a
    TOML value, or a bare word (letters, digits and ``_-./~``, taken as text). ``~KEY``
    (Hydra's syntax) removes KEY: {"~KEY": None}."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if key.startswith(UNSET_PREFIX):  # ~KEY: remove KEY here (Hydra's syntax)
            if sep:
                raise SpecError(f"--set {key}: removes the key; it takes no value (--set "
                                f"{key}, then --set {key[1:]}=VALUE to give it another)")
            name = key[len(UNSET_PREFIX):].strip()
            for old in (name, key):
                out.pop(old, None)  # the last of the items wins, in order
            out[f"{UNSET_PREFIX}{name}"] = None
            continue
        if not sep or not key:
            raise SpecError(f"--set: expected KEY=VALUE or ~KEY, got {item!r}")
        if any(c in text for c in "\n\r\0"):
            raise SpecError(f"--set {key}: the value must be one line (no newline or NUL), "
                            f"got {text!r}")
        try:
            parsed = tomllib.loads(f"v = {text.strip()}")
        except tomllib.TOMLDecodeError:
            if not text.strip().translate(_BARE).isalnum():
                raise SpecError(f"--set {key}: cannot read {text!r} as a TOML value") from None
            parsed = {"v": text.strip()}
        except RecursionError:
            raise SpecError(f"--set {key}: the value is nested too deeply") from None
        if list(parsed) != ["v"]:
            raise SpecError(f"--set {key}: cannot read {text!r} as one TOML value")
        out.pop(f"{UNSET_PREFIX}{key}", None)
        out.pop(key, None)  # moved last: it applies after every earlier item
        out[key] = parsed["v"]
    return out
