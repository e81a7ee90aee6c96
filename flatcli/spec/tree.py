"""Spec trees (a TOML file, a spec's or a run record's ``tree``) and their dotted keys, each
walk written once: ``read_toml``, ``flatten``, ``value_at``, ``put``."""

from __future__ import annotations

import tomllib
from collections.abc import Callable, Mapping, MutableMapping
from pathlib import Path
from typing import Any

from flatcli.core.errors import FlatcliError
from flatcli.files import read_named_text
from flatcli.spec.keys import SpecError
from flatcli.spec.limits import MAX_SPEC_BYTES


def flatten(tree: Mapping[str, Any],
            enter: Callable[[str, Mapping[str, Any]], bool] = lambda dotted, table: bool(table),
            *, quote: bool = False, prefix: str = "") -> dict[str, Any]:
    """{dotted key: value} of a nested tree: a table is entered where ``enter(dotted key,
    table)`` says so (by default every table that is not empty) and is otherwise one value;
    with ``quote`` a name that holds a dot is quoted, as TOML writes it
    (``sweep.grid."plant.com"``)."""
    out: dict[str, Any] = {}
    for name, value in tree.items():
        part = f'"{name}"' if quote and "." in name else name
        dotted = f"{prefix}.{part}" if prefix else part
        if isinstance(value, Mapping) and enter(dotted, value):
            out.update(flatten(value, enter, quote=quote, prefix=dotted))
        else:
            out[dotted] = value
    return out


def value_at(tree: Any, dotted: str) -> Any:
    """The value of a dotted key in a nested tree, or None where the tree has none."""
    node = tree
    for part in dotted.split("."):
        node = node.get(part) if isinstance(node, Mapping) else None
    return node


def put(tree: MutableMapping[str, Any], dotted: str, value: Any) -> None:
    """Set a dotted key of a nested tree whose tables exist."""
    *parents, last = dotted.split(".")
    node = tree
    for part in parents:
        node = node[part]
    node[last] = value


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML file; SpecError for a missing, unreadable, oversized or non-regular file
    (a FIFO or a device is refused without reading from it), for text that is not UTF-8,
    and for TOML that is invalid or nested too deeply; a URDF given as a spec is named as
    one."""
    if path.suffix.lower() == ".urdf":
        raise SpecError(f"{path} is a URDF, a robot rather than a spec: pass it as --robot "
                        f"{path} (or robot = \"{path.name}\" in a spec)")
    try:
        text = read_named_text(path, "spec file", MAX_SPEC_BYTES)
    except FlatcliError as exc:
        raise SpecError(str(exc)) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"spec file {path} is not valid TOML: {exc}") from None
    except RecursionError:
        raise SpecError(f"spec file {path}: TOML nested too deeply") from None
