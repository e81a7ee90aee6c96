"""Markdown tables, the one helper every table of flatcli goes through: aligned columns that
read well on a terminal and render in REPORT.md and summary.md alike, or compact rows for
documents whose cells are long (the spec tables of docs/spec.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def fmt(value: object, digits: int = 4) -> str:
    """A number for a table: compact, aligned, readable; other values as str."""
    if value is None:
        return "-"
    if isinstance(value, bool | np.bool_):
        return str(bool(value)).lower()
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        x = float(value)
        if math.isnan(x):
            return "-"
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        if x == 0:
            return "0"
        if 1e-3 <= abs(x) < 1e5:
            return f"{x:.{digits}g}"
        return f"{x:.{max(digits - 2, 1)}e}"
    return str(value)


def table(headers: Sequence[str], rows: Sequence[Sequence[object]], digits: int = 4,
          align: bool = True) -> str:
    """A Markdown table; numbers right-aligned. ``align``: columns padded to one width (for
    a terminal), else each row as short as it can be (for a document with long cells). A
    ``|`` in a cell is escaped, so no cell can split its row."""
    cells = [[fmt(v, digits).replace("|", "\\|") for v in row] for row in rows]
    numeric = [
        all(_is_number(row[i]) for row in rows) if rows else False for i in range(len(headers))
    ]
    if not align:
        rule = "|" + "|".join("---:" if num else "---" for num in numeric) + "|"
        return "\n".join(["| " + " | ".join(items) + " |"
                          for items in [list(headers)]] + [rule] +
                         ["| " + " | ".join(r) + " |" for r in cells])
    widths = [
        max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(headers)
    ]

    def line(items: Sequence[str]) -> str:
        parts = [
            s.rjust(w) if num else s.ljust(w)
            for s, w, num in zip(items, widths, numeric, strict=True)
        ]
        return "| " + " | ".join(parts) + " |"

    rule = (
        "|"
        + "|".join(
            ("-" * (w + 1) + ":") if num else ("-" * (w + 2))
            for w, num in zip(widths, numeric, strict=True)
        )
        + "|"
    )
    return "\n".join([line(list(headers)), rule, *(line(r) for r in cells)])


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )
