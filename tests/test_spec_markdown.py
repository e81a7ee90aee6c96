"""docs/spec.md's spec tables (flatcli/spec/markdown.py, flatcli/spec/__main__.py) are the
schema's."""

from __future__ import annotations

from pathlib import Path

import pytest

from flatcli.spec import SCHEMA
from flatcli.spec.__main__ import main
from flatcli.spec.markdown import block, readme_sections, section_table, sync_readme

SPEC_DOC = Path(__file__).resolve().parents[1] / "docs" / "spec.md"


def test_the_docs_spec_tables_are_generated_from_the_schema() -> None:
    text = SPEC_DOC.read_text()
    assert readme_sections(text) == list(SCHEMA), "docs/spec.md lacks a spec-table block"
    assert sync_readme(text) == text, (
        "docs/spec.md's spec tables differ from the schema: "
        "run python -m flatcli.spec --update-readme docs/spec.md"
    )


def test_a_stale_table_is_rewritten() -> None:
    stale = "intro\n\n" + block("track").replace("| `dt` | 0.001 |", "| `dt` | 0.002 |")
    assert stale != "intro\n\n" + block("track")
    assert sync_readme(stale) == "intro\n\n" + block("track")


def test_each_key_is_one_row_with_default_unit_and_bounds() -> None:
    rows = section_table("robot").splitlines()
    assert rows[0] == "| key | default | unit | allowed | meaning |"
    assert len(rows) == 2 + len(SCHEMA["robot"])
    assert rows[2].startswith("| `mass` | [1, 1, 1] | kg | N + 1 numbers, each > 0 |")
    assert "| `model` | \"derived\" |  | \"derived\", \"paper\" |" in section_table("robot")
    assert "| inf | rad/s | > 0 (inf: no limit) |" in section_table("track")


def test_module_prints_and_updates(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    main(["--markdown"])
    printed = capsys.readouterr().out
    assert all(block(section) in printed for section in SCHEMA)
    readme = tmp_path / "README.md"
    readme.write_text("# x\n\n" + block("plant").replace("kg m^2/s", "?") + "\n")
    main(["--update-readme", str(readme)])
    assert readme.read_text() == "# x\n\n" + block("plant") + "\n"
