"""The rules of a sweep's tables: ``[sweep.perturb]`` entries and ``[sweep.grid]`` entries.

Both tables are kept as written (their values enter the spec's digest as they are), and
checked here: a perturbation against the distributions it may use, a grid value against
the schema key it sets (``flatcli.spec.schema.check_value``), so a grid value gets the same
message as the same value in a ``[table]`` or a ``--set``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from flatcli.spec.keys import MIN_JOINTS, SIZES, SpecError, suggest, unprintable
from flatcli.spec.schema import SweepSpec, all_keys, check_size, check_value, lookup

#: The distributions a perturbation draws from.
DISTRIBUTIONS = ("normal", "uniform")
#: Perturbable quantities and the spec key each one perturbs (its length is that key's).
PERTURB_TARGETS: dict[str, str] = {
    "initial": "track.initial",
    "initial_rate": "track.initial_rate",
    "mass": "plant.mass",
    "inertia": "plant.inertia",
    "length": "plant.length",
    "com": "plant.com",
    "momentum": "plant.momentum",
    # added after the first seven: their variates come after those of the others, so no
    # existing perturbation draws different numbers (``flatcli.montecarlo.draws``)
    "servo_bandwidth": "plant.servo_bandwidth",
    "torque_limit": "plant.torque_limit",
    # the task's target: each trial plans its own task to its drawn target (a plan per
    # trial, flatcli.montecarlo.chunks), a box of capture points sampled
    "end_effector": "task.end_effector",
}
#: Quantities a perturbation may scale (``relative = true``) rather than shift.
RELATIVE_TARGETS = ("mass", "inertia", "length", "com", "servo_bandwidth", "torque_limit")
PERTURB_PREFIX = "sweep.perturb."


@dataclass(frozen=True)
class Perturbation:
    """One validated ``[sweep.perturb]`` entry (scalars broadcast over the quantity's items).

    A uniform draw is ``low + (high - low) u``, a normal one ``mean + std Phi^-1(u)``;
    ``relative``: the nominal value is multiplied by (1 + draw) instead of shifted by it.
    """

    dist: str
    low: float | tuple[float, ...] = 0.0
    high: float | tuple[float, ...] = 0.0
    std: float | tuple[float, ...] = 0.0
    mean: float | tuple[float, ...] = 0.0
    relative: bool = False


def size(name: str, joints: int = MIN_JOINTS) -> int:
    """How many numbers the quantity ``name`` holds on a robot of ``joints`` joints (its
    key's length, or 1)."""
    key = lookup(PERTURB_TARGETS[name])
    if key.size:
        return SIZES[key.size].length(joints)
    return key.length if key.kind == "vector" else 1


def perturbation(name: str, table: Any, joints: int = MIN_JOINTS) -> Perturbation:
    """Check one ``[sweep.perturb]`` entry of a spec whose robot has ``joints`` joints; its
    record, or SpecError naming what is wrong."""
    where = f"{PERTURB_PREFIX}{name}"
    if name not in PERTURB_TARGETS:
        raise SpecError(
            f"{where}: unknown perturbation; allowed: {sorted(PERTURB_TARGETS)}"
            f"{suggest(name, PERTURB_TARGETS)}"
        )
    if not isinstance(table, dict):
        raise SpecError(
            f'{where}: expected an inline table such as {{ dist = "normal", std = 0.01 }}'
        )
    dist = table.get("dist")
    if dist not in DISTRIBUTIONS:
        raise SpecError(f"{where}.dist: expected one of {list(DISTRIBUTIONS)}, got {dist!r}")
    params = ("std", "mean") if dist == "normal" else ("low", "high")
    allowed = {"dist", "relative", *params}
    for key in table:
        if key not in allowed:
            raise SpecError(
                f"{where}.{key}: not a parameter of a {dist} perturbation; "
                f"allowed: {sorted(allowed)}{suggest(key, allowed)}"
            )
    required = ("std",) if dist == "normal" else ("low", "high")
    for key in required:
        if key not in table:
            raise SpecError(f"{where}.{key}: required for a {dist} perturbation")
    n = size(name, joints)
    numbers = {key: _numbers(f"{where}.{key}", table[key], n) for key in params if key in table}
    if dist == "normal":
        if any(s < 0 for s in _items(numbers["std"], n)):
            raise SpecError(f"{where}.std: must be >= 0, got {table['std']!r}")
    elif any(lo > hi for lo, hi in zip(_items(numbers["low"], n), _items(numbers["high"], n),
                                       strict=True)):
        raise SpecError(
            f"{where}: low must be <= high, got low={table['low']!r}, high={table['high']!r}"
        )
    relative = table.get("relative", False)
    if not isinstance(relative, bool):
        raise SpecError(f"{where}.relative: expected true or false")
    if relative and name not in RELATIVE_TARGETS:
        raise SpecError(f"{where}.relative: only {', '.join(RELATIVE_TARGETS)} can be relative")
    return Perturbation(str(dist), relative=relative, **numbers)


def perturbations(sweep: SweepSpec, joints: int = MIN_JOINTS) -> dict[str, Perturbation]:
    """The records of a sweep's perturbations, in ``PERTURB_TARGETS`` order."""
    return {name: perturbation(name, sweep.perturb[name], joints)
            for name in PERTURB_TARGETS if name in sweep.perturb}


def _items(value: float | tuple[float, ...], n: int) -> tuple[float, ...]:
    return value if isinstance(value, tuple) else (value,) * n


def _numbers(where: str, value: Any, n: int) -> float | tuple[float, ...]:
    if isinstance(value, list) and (n == 1 or len(value) != n):
        expected = f"a number or {n} numbers" if n > 1 else "a number"
        raise SpecError(f"{where}: expected {expected}, got {value!r}")
    items = value if isinstance(value, list) else [value]
    for v in items:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise SpecError(f"{where}: expected finite numbers, got {value!r}")
    return tuple(float(v) for v in value) if isinstance(value, list) else float(value)


def is_perturbation_param(dotted: str) -> bool:
    """Whether a dotted name is ``sweep.perturb.NAME.PARAM`` (a grid key, not a spec key)."""
    return dotted.startswith(PERTURB_PREFIX) and dotted.count(".") == 3


def grid_overrides(key: str, value: Any) -> dict[str, Any]:
    """The dotted keys one grid value sets: itself, or a group's table (minus its label)."""
    if isinstance(value, dict):
        return {k: v for k, v in value.items() if k != "label"}
    return {key: value}


def validate_sweep(sweep: SweepSpec, joints: int = MIN_JOINTS,
                   torque_limit: float = math.inf, has_target: bool = True,
                   grid_checked: bool = False) -> None:
    """Check every perturbation and every grid entry of a ``[sweep]`` (robot of ``joints``,
    plant torque limit ``torque_limit`` [N m], ``has_target``: task.end_effector is set):
    each on its own, then together (no spec key varied by two grid entries; a torque-limit
    perturbation only on finite torque limits; a target perturbation only of a target).
    ``grid_checked``: the grid's values were checked for this robot already (a cell of the
    sweep whose spec it is)."""
    for name, table in sweep.perturb.items():
        perturbation(name, table, joints)
    if not grid_checked:
        for dotted, values in sweep.grid.items():
            validate_grid_entry(sweep.perturb, dotted, values, joints)
    setters = grid_setters(sweep.grid)
    if "end_effector" in sweep.perturb and not has_target:
        raise SpecError(f"{PERTURB_PREFIX}end_effector: needs task.end_effector, the nominal "
                        "target its draws shift [m]; set task.end_effector")
    if "torque_limit" in sweep.perturb:
        entry = setters.get("plant.torque_limit")
        limits = [torque_limit] if entry is None else grid_values(sweep.grid, entry,
                                                                  "plant.torque_limit")
        if not all(math.isfinite(v) for v in limits):
            where = "" if entry is None else f" in every cell ({_entry(sweep.grid, entry)} " \
                "sets it)"
            raise SpecError(f"{PERTURB_PREFIX}torque_limit: needs a finite plant.torque_limit"
                            f"{where}, got inf (inf plus or times any draw is inf: the "
                            "perturbation would change nothing); set plant.torque_limit")


def grid_setters(grid: Mapping[str, Any]) -> dict[str, str]:
    """The grid entry that sets each spec key (a plain entry its own key, a group the keys
    of its tables); SpecError if one key is set by two entries: every cell would then hold
    one entry's value for it and silently drop the other's (and cells would repeat)."""
    setters: dict[str, str] = {}
    for entry, values in grid.items():
        keys = [entry]
        if _is_group(values):
            keys = list(dict.fromkeys(k for table in values for k in table if k != "label"))
        for key in keys:
            if key in setters:
                raise SpecError(f"sweep.grid: {key!r} is set both by "
                                f"{_entry(grid, setters[key])} and by {_entry(grid, entry)}; "
                                "vary each spec key in one grid entry (put it in the group, "
                                "or drop it there)")
            setters[key] = entry
    return setters


def _is_group(values: Any) -> bool:
    return isinstance(values, list) and bool(values) and all(isinstance(v, dict)
                                                             for v in values)


def _entry(grid: Mapping[str, Any], entry: str) -> str:
    return f"the group {entry!r}" if _is_group(grid[entry]) else f"the grid key {entry!r}"


def grid_values(grid: Mapping[str, Any], entry: str, key: str) -> list[Any]:
    """The values a grid entry gives the spec key ``key``."""
    return [v[key] if isinstance(v, dict) else v for v in grid[entry]
            if not isinstance(v, dict) or key in v]


def validate_grid_entry(perturb: Mapping[str, Any], dotted: str, values: Any,
                        joints: int = MIN_JOINTS) -> None:
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
            bad = unprintable(str(table.get("label", "")))
            if bad is not None:
                raise SpecError(f"{where}: a group's label must not contain control "
                                "characters, format characters or line separators, got "
                                f"{bad} in {table['label']!a}")
            keys = [k for k in table if k != "label"]
            if not keys:
                raise SpecError(f"{where}: a group table needs at least one spec key")
            for key in keys:
                _validate_grid_value(perturb, f"{where} group key {key!r}", key, table[key],
                                     joints)
        return
    if any(isinstance(v, dict) for v in values):
        raise SpecError(f"{where}: mixes tables and plain values")
    for value in values:
        _validate_grid_value(perturb, where, dotted, value, joints)


def _validate_grid_value(perturb: Mapping[str, Any], where: str, dotted: str,
                         value: Any, joints: int) -> None:
    if dotted.startswith(PERTURB_PREFIX):
        parts = dotted.split(".")
        if not is_perturbation_param(dotted) or parts[2] not in perturb:
            raise SpecError(
                f"{where}: a perturbation grid key is sweep.perturb.NAME.PARAM with NAME one of "
                f"the [sweep.perturb] entries {sorted(perturb)}"
            )
        perturbation(parts[2], {**perturb[parts[2]], parts[3]: value}, joints)
        return
    if dotted.startswith("sweep.") or dotted == "name":
        raise SpecError(f"{where}: cannot grid over {dotted!r}")
    if dotted.startswith("figures."):
        raise SpecError(f"{where}: cannot grid over {dotted!r}: figures are how a sweep is "
                        "drawn, once for all its cells")
    if dotted.startswith("search."):
        raise SpecError(f"{where}: cannot grid over {dotted!r}: [search] says how flatcli "
                        "search varies the design, and no trial reads it")
    if dotted.startswith("summary."):
        raise SpecError(f"{where}: cannot grid over {dotted!r}: [summary] is how a sweep's "
                        "trials are judged, once for all its cells")
    try:
        lookup(dotted)
    except SpecError:
        raise SpecError(f"{where}: not a spec key{suggest(dotted, all_keys())}") from None
    check_size(dotted, check_value(dotted, value), joints)


def identical_trials(spec: Any) -> str | None:
    """Why the trials of a sweep's cells would all be the same (no ``[sweep.perturb]``, and
    no sensor noise in the spec nor from its grid), or None when they differ."""
    sweep = spec.sweep
    if sweep.perturb:
        return None
    grid = sweep.grid
    noisy = spec.track.sensor_noise > 0 or "track.sensor_noise" in grid or any(
        isinstance(v, dict) and "track.sensor_noise" in v
        for values in grid.values() if isinstance(values, list) for v in values)
    if noisy:
        return None
    return "no [sweep.perturb] and no track.sensor_noise"
