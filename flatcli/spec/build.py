"""From TOML and ``--set`` items to a validated ``Spec``: the one place values are checked.

Defaults, then the file (if any), then ``--set`` items in order; every value goes through its
key's check (``flatcli.spec.keys.Key.check``), the sweep's tables through
``flatcli.spec.sweeps``; then the records are built. Bad input raises ``SpecError`` with one
line naming the key and what is allowed.
"""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from flatcli.spec.keys import SpecError
from flatcli.spec.schema import SCHEMA, Spec, check_value, fit_sizes, from_values
from flatcli.spec.sweeps import PERTURB_PREFIX, is_perturbation_param, validate_sweep


def build(values: Mapping[str, Any]) -> Spec:
    """A Spec from {dotted key: value}, every value checked; keys not given keep defaults.

    ``sweep.perturb.NAME.PARAM`` keys (a grid cell's perturbation parameter) set that
    parameter of the ``[sweep.perturb]`` entry NAME.
    """
    checked: dict[str, Any] = {}
    params: dict[str, Any] = {}
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
    validate_sweep(spec.sweep, spec.joints)
    return spec


def resolve(user: Mapping[str, Any], overrides: Mapping[str, Any] | None = None) -> Spec:
    """Validate a user's nested dict (a parsed TOML file) plus dotted overrides."""
    flat = flatten(user)
    flat.update(overrides or {})
    return build(flat)


def load_spec(path: Path | None, sets: Iterable[str] = ()) -> Spec:
    """Defaults, then the file (if any), then ``--set`` items; validated.

    Parameters
    ----------
    path : a TOML spec file, or None for the embedded paper example
    sets : ``KEY=VALUE`` strings, applied in order
    """
    user = read_toml(path) if path is not None else {}
    return resolve(user, parse_set(sets))


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
