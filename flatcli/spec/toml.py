"""A spec written back as TOML (what ``flatcli sweep --rerun N --print-spec`` prints)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from flatcli.spec.schema import Spec


def toml_value(v: Any) -> str:
    """One value as TOML (floats in repr, so every value round-trips exactly)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "inf" if v == math.inf else ("-inf" if v == -math.inf else repr(v))
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return json.dumps(v)
    return str(v)


def spec_toml(spec: Spec) -> str:
    """A spec's keys as TOML, without its ``[sweep]`` table and keys left unset (None)."""
    tree = spec.tree
    lines = [f"{k} = {toml_value(v)}" for k, v in tree.items()
             if not isinstance(v, dict) and v is not None]

    def emit(prefix: str, table: Mapping[str, Any]) -> None:
        scalars = [(k, v) for k, v in table.items() if not isinstance(v, dict) and v is not None]
        if scalars:
            lines.append(f"\n[{prefix}]")
            lines.extend(f"{k} = {toml_value(v)}" for k, v in scalars)
        for k, v in table.items():
            if isinstance(v, dict):
                emit(f"{prefix}.{k}", v)

    for k, v in tree.items():
        if isinstance(v, dict) and k != "sweep":
            emit(k, v)
    return "\n".join(lines) + "\n"
