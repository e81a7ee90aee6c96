"""The spec tables of docs/spec.md, generated from the schema.

Each table sits in docs/spec.md between ``<!-- spec-table: SECTION -->`` and
``<!-- end spec-table -->``; ``sync_readme`` rewrites those blocks and the test of this module
fails when docs/spec.md differs from what it would write. Regenerate with
``python -m flatcli.spec --update-readme docs/spec.md``.
"""

from __future__ import annotations

import math
import re
from typing import Any

from flatcli.report.tables import table
from flatcli.spec.keys import Key
from flatcli.spec.schema import SCHEMA, SECTIONS

BEGIN = "<!-- spec-table: {} -->"
END = "<!-- end spec-table -->"
_BLOCK = re.compile(r"<!-- spec-table: (?P<section>[\w.]*) -->\n.*?<!-- end spec-table -->",
                    re.DOTALL)


def show_default(key: Key) -> str:
    """A key's default as the spec tables show it."""
    if key.default_doc:
        return key.default_doc
    return _show(key.default)


def _show(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def heading(section: str) -> str:
    """A section's heading: its name and the first line of its record's docstring."""
    doc = (SECTIONS[section].__doc__ or "").strip().splitlines()[0]
    return f"#### {doc}" if not section else f"#### `[{section}]`: {doc}"


def section_table(section: str) -> str:
    """The Markdown table of one section's keys."""
    rows = [[f"`{name}`", show_default(key), key.unit, key.bounds_text(), key.doc]
            for name, key in SCHEMA[section].items()]
    return table(["key", "default", "unit", "allowed", "meaning"], rows, align=False)


def block(section: str) -> str:
    """A document's block: markers around the heading and the table of one section."""
    return "\n".join([BEGIN.format(section), heading(section), "", section_table(section), END])


def markdown() -> str:
    """Every section's block, in schema order."""
    return "\n\n".join(block(section) for section in SCHEMA)


def sync_readme(text: str) -> str:
    """A document's text with every spec-table block regenerated from the schema."""
    return _BLOCK.sub(lambda m: block(m.group("section")), text)


def readme_sections(text: str) -> list[str]:
    """The sections whose blocks a document holds, in order."""
    return [m.group("section") for m in _BLOCK.finditer(text)]
