"""From TOML and ``--set`` items to a validated ``Spec``: the one place values are checked.

Defaults, then the file (if any), then ``--set`` items in order; every value goes through its
key's check (``flatcli.spec.keys.Key.check``), the sweep's tables through
``flatcli.spec.sweeps``; then the records are built. Bad input raises ``SpecError`` with one
line naming the key and what is allowed.
"""

from __future__ import annotations

import copy
import math
import os
import stat
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from flatcli.spec.compose import compose
from flatcli.spec.keys import MAX_INT, SpecError
from flatcli.spec.limits import MAX_SPEC_BYTES, check_joints, check_limits
from flatcli.spec.schema import (
    SCHEMA,
    Spec,
    check_value,
    find_key,
    fit_sizes,
    from_values,
    lookup,
)
from flatcli.spec.sweeps import PERTURB_PREFIX, is_perturbation_param, validate_sweep

#: Deepest nesting of lists and tables a spec value may have (a grid of groups of vectors
#: needs 3).
MAX_DEPTH = 8


def build(values: Mapping[str, Any]) -> Spec:
    """A Spec from {dotted key: value}, every value checked; keys not given keep defaults.

    ``sweep.perturb.NAME.PARAM`` keys (a grid cell's perturbation parameter) set that
    parameter of the ``[sweep.perturb]`` entry NAME.
    """
    checked: dict[str, Any] = {}
    params: dict[str, Any] = {}
    for dotted, value in values.items():
        _scan(dotted, value, 0)
    for dotted, value in values.items():
        if dotted in SCHEMA:  # a whole section given as a scalar
            raise SpecError(f"{dotted}: expected a table")
        if is_perturbation_param(dotted):
            params[dotted] = value
        else:
            checked[dotted] = check_value(dotted, value)
    if params:
        perturb = copy.deepcopy(dict(checked.get("sweep.perturb", {})))
        for dotted, value in params.items():
            name, param = dotted.removeprefix(PERTURB_PREFIX).split(".")
            perturb[name] = {**perturb.get(name, {}), param: value}
        checked["sweep.perturb"] = perturb
    spec = fit_sizes(from_values(checked), checked)
    check_joints(spec.joints)  # before anything costs O(N^3)
    validate_sweep(spec.sweep, spec.joints, spec.plant.torque_limit,
                   spec.task.end_effector is not None)
    check_grid_shapes(spec.sweep.grid)
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
    flat.update(extra)
    return build(flat)


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
    spec = from_values(checked)
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


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Dotted keys of a user's nested dict, descending into known sections only."""
    out: dict[str, Any] = {}
    for name, value in tree.items():
        dotted = f"{prefix}.{name}" if prefix else name
        if isinstance(value, dict) and dotted in SCHEMA:
            out.update(flatten(value, dotted))
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
        if any(c in text for c in "\n\r\0"):
            raise SpecError(f"--set {key}: the value must be one line (no newline or NUL), "
                            f"got {text!r}")
        try:
            parsed = tomllib.loads(f"v = {text.strip()}")
        except tomllib.TOMLDecodeError:
            if not text.strip().replace("_", "").replace("-", "").isalnum():
                raise SpecError(f"--set {key}: cannot read {text!r} as a TOML value") from None
            parsed = {"v": text.strip()}
        except RecursionError:
            raise SpecError(f"--set {key}: the value is nested too deeply") from None
        if list(parsed) != ["v"]:
            raise SpecError(f"--set {key}: cannot read {text!r} as one TOML value")
        out[key] = parsed["v"]
    return out


def read_text(path: Path, what: str = "spec file", limit: int = MAX_SPEC_BYTES) -> str:
    """The UTF-8 text of a file a spec names (``what``: "spec file", "URDF file"); SpecError
    for a missing, unreadable, oversized (> ``limit`` bytes) or non-regular file (a FIFO or
    a device is refused without reading from it) and for text that is not UTF-8."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise SpecError(f"{what} not found: {path}") from None
    except OSError as exc:
        raise SpecError(f"cannot read {what} {path}: {exc.strerror}") from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise SpecError(f"{what} is a directory: {path}")
        if not stat.S_ISREG(info.st_mode):
            raise SpecError(f"{what} {path} is not a regular file (a FIFO, socket or "
                            "device)")
        if info.st_size > limit:
            raise SpecError(f"{what} {path} is {info.st_size} bytes, more than the "
                            f"{limit} a {what.split()[0]} may have")
        data = b""
        while len(data) <= limit:
            block = os.read(fd, limit + 1 - len(data))
            if not block:
                break
            data += block
    except OSError as exc:
        raise SpecError(f"cannot read {what} {path}: {exc.strerror}") from None
    finally:
        os.close(fd)
    if len(data) > limit:
        raise SpecError(f"{what} {path} is more than the {limit} bytes a {what.split()[0]} "
                        "may have")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SpecError(f"{what} {path} is not UTF-8 text (byte {exc.start})") from None
    return text


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML file; SpecError for a missing, unreadable, oversized or non-regular file
    (a FIFO or a device is refused without reading from it), for text that is not UTF-8,
    and for TOML that is invalid or nested too deeply; a URDF given as a spec is named as
    one."""
    if path.suffix.lower() == ".urdf":
        raise SpecError(f"{path} is a URDF, a robot rather than a spec: pass it as --robot "
                        f"{path} (or robot = \"{path.name}\" in a spec)")
    text = read_text(path)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"spec file {path} is not valid TOML: {exc}") from None
    except RecursionError:
        raise SpecError(f"spec file {path}: TOML nested too deeply") from None
