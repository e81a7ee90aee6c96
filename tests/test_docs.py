"""The README as a front door and docs/ as the reference: the two commands on the front page,
every reference page linked from it, every relative link and anchor resolving, and the
reference sections where the links say they are. (docs/spec.md's tables are checked against
the schema in tests/test_spec_markdown.py, docs/outputs.md's units in tests/test_units.py.)"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").glob("*.md"))
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def slug(heading: str) -> str:
    """A heading's anchor as GitHub makes it: lower case, punctuation dropped, spaces to -."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    return {slug(line.lstrip("#")) for line in path.read_text().splitlines()
            if line.startswith("#")}


def test_the_front_door_shows_the_two_commands_and_stays_short() -> None:
    text = README.read_text()
    block = text.split("## Quick start")[1].split("```sh")[1].split("```")[0]
    assert "make reproduce" in block and "make test" in block
    assert len(text.splitlines()) < 150  # a front door, the reference is in docs/


def test_every_reference_page_is_linked_from_the_readme() -> None:
    linked = {m.split("#")[0] for m in LINK.findall(README.read_text())}
    assert {f"docs/{p.name}" for p in DOCS} <= linked
    assert {p.name for p in DOCS} >= {"commands.md", "api.md", "spec.md", "outputs.md",
                                      "failures.md", "performance.md", "physics.md",
                                      "chains.md", "development.md"}


@pytest.mark.parametrize("page", [README, *DOCS], ids=lambda p: p.name)
def test_every_relative_link_and_anchor_resolves(page: Path) -> None:
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target):
            continue  # an address outside the repository
        file, _, anchor = target.partition("#")
        path = (page.parent / file).resolve() if file else page
        assert path.exists(), f"{page.name}: {target}"
        if anchor:
            assert anchor in anchors(path), f"{page.name}: {target}"


def test_the_reference_sections_are_where_the_links_say() -> None:
    where = {"physics.md": ["The physics, and the paper's errata flatcli corrects",
                            "The dynamic plant: a robot with inertia"],
             "outputs.md": ["Output files", "Metrics (one set per trial)", "Sweep output",
                            "On a Dask cluster"],
             "commands.md": ["Runs as data", "Figures", "Shell completion"],
             "spec.md": ["Specs that compose"], "failures.md": ["Failures"],
             "performance.md": ["Performance"], "chains.md": ["Robots of N links"],
             "development.md": ["From the paper's equations to the code and its referee"]}
    for page, headings in where.items():
        found = anchors(ROOT / "docs" / page)
        assert {slug(h) for h in headings} <= found, page
