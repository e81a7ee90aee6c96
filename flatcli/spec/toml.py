"""A spec written back as TOML: what ``flatcli plan --cfg``, ``track --cfg``, ``check`` and
``sweep --rerun N --print-spec`` print, and what reads back as the same spec.

Every key, string and number is written by tomli-w (its escapes are TOML's, for any text);
the layout is flatcli's: one line per key, lists and tables inline, as a person writes a spec.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

import tomli_w

from flatcli.spec.schema import SpecRecord
from flatcli.spec.tree import put

_BARE = re.compile(r"[A-Za-z0-9_-]+")


def toml_key(key: str) -> str:
    """A key as TOML: bare when it may be, else quoted (``"plant.com"``)."""
    if _BARE.fullmatch(key):
        return key
    return tomli_w.dumps({key: 0}).rpartition(" = ")[0]


def toml_value(v: Any) -> str:
    """One value as TOML on one line: lists as ``[a, b]``, tables as ``{ k = v }``, floats
    in repr (every value round-trips exactly), inf as ``inf``."""
    if isinstance(v, Mapping):
        if not v:
            return "{}"
        return "{ " + ", ".join(f"{toml_key(str(k))} = {toml_value(x)}"
                                for k, x in v.items()) + " }"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return tomli_w.dumps({"v": v}).removeprefix("v = ").rstrip("\n")


def _lines(prefix: str, table: Mapping[str, Any], out: list[str],
           notes: Mapping[str, str]) -> None:
    scalars = [(k, v) for k, v in table.items() if not _is_table(prefix, k, v) and v is not None]
    if prefix and scalars:
        out.append(f"\n[{prefix}]")
    for k, v in scalars:
        dotted = f"{prefix}.{k}" if prefix else k
        note = notes.get(dotted)
        out.append(f"{toml_key(k)} = {toml_value(v)}" + (f"  # {note}" if note else ""))
    for k, v in table.items():
        if _is_table(prefix, k, v):
            _lines(f"{prefix}.{toml_key(k)}" if prefix else toml_key(k), v, out, notes)


def _is_table(prefix: str, key: str, value: Any) -> bool:
    """Whether a value is written as a ``[table]`` of its own: a spec section, or the
    sweep's tables (their entries inline)."""
    return isinstance(value, Mapping) and (prefix in ("", "plan") or f"{prefix}.{key}" in (
        "sweep.perturb", "sweep.grid", "search.vary", "search.counterweight"))


def spec_toml(spec: SpecRecord, *, sweep: bool = False, search: bool = False,
              values: Mapping[str, Any] | None = None,
              notes: Mapping[str, str] | None = None) -> str:
    """A spec's keys as TOML (keys left unset, None, are left out), without its ``[sweep]``
    table unless ``sweep`` and its ``[search]`` table unless ``search``; ``values`` replace
    dotted keys' values as written (a chunk size as resolved), ``notes`` add a comment to a
    key's line."""
    tree = spec.tree
    if not sweep:
        tree.pop("sweep", None)
    if not search:
        tree.pop("search", None)
    for dotted, value in (values or {}).items():
        put(tree, dotted, value)
    out: list[str] = []
    _lines("", tree, out, notes or {})
    return "\n".join(out).lstrip("\n") + "\n"
