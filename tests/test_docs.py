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


def layout_paths(text: str) -> set[str]:
    """The paths docs/development.md's layout block names: a path at the line's start (a
    directory ends in /), and under a directory the files and folders indented beneath it.
    Continuation lines (a description's second line) name no path."""
    block = text.split("```")[1]
    paths: set[str] = set()
    stack: list[tuple[int, str]] = []  # (indent, directory) of the open directories
    for line in block.splitlines():
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        token = line.split()[0]
        if indent == 0:
            paths.add(token)
            stack = [(0, token)] if token.endswith("/") else []
            continue
        if not re.fullmatch(r"[\w.]+(\.py|/)", token):
            continue
        while stack and stack[-1][0] >= indent:
            stack.pop()
        if stack:
            path = stack[-1][1] + token
            paths.add(path)
            if token.endswith("/"):
                stack.append((indent, path))
    return paths


def test_the_layout_names_every_module_and_only_what_exists() -> None:
    paths = layout_paths((ROOT / "docs" / "development.md").read_text())
    for path in paths:
        assert (ROOT / path).exists(), f"docs/development.md names {path}, which is not there"
    modules = {str(p.relative_to(ROOT)) for p in (ROOT / "flatcli").rglob("*.py")
               if p.name not in ("__init__.py", "__main__.py")}
    packages = {f"{p.parent.relative_to(ROOT)}/" for p in (ROOT / "flatcli").rglob("__init__.py")
                if p.parent != ROOT / "flatcli"}
    assert sorted((modules | packages) - paths) == [], "modules the layout leaves out"


Functions = list[tuple[str, str | None]]


def code_names(cell: str) -> Functions:
    """The (file, function) pairs a cell names (function None for a whole module)."""
    functions: Functions = []
    current = None
    for code in re.findall(r"`([^`]+)`", cell):
        if ".py" in code:
            current, _, name = (part.strip() for part in code.partition(":"))
            functions.append((current, name or None))
        elif current is not None and re.fullmatch(r"[\w.]+", code):
            functions.append((current, code))
    return functions


def equation_map() -> list[tuple[str, Functions, Functions, list[tuple[str, str]]]]:
    """docs/development.md's equation map: per row its equation, the (file, function) pairs
    of the general function (any N) and of the paper's closed form (N = 2), and the (test
    module, test) pairs."""
    text = (ROOT / "docs" / "development.md").read_text()
    table_ = text.split("## From the paper's equations to the code and its referee")[1]
    rows = []
    for line in table_.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.startswith("|") or cells[0] in ("equation", "---"):
            continue
        assert len(cells) == 4, line
        tests: list[tuple[str, str]] = []
        module = None
        for code in re.findall(r"`([^`]+)`", cells[3]):
            if code.startswith("test_") and ".py" in code:
                module, _, name = code.partition("::")
                tests.append((module, name))
            elif code.startswith("::") and module is not None:
                tests.append((module, code[2:]))
        rows.append((cells[0], code_names(cells[1]), code_names(cells[2]), tests))
    return rows


def test_the_equation_map_points_to_functions_and_tests_that_exist() -> None:
    """Each row: one general function (any N), the paper's closed form beside it where there
    is one, never the same function in both, and tests; every name exists in the tree. A
    closed form beside a general function names at least two tests: its referee and its
    comparison at N = 2."""
    rows = equation_map()
    assert len(rows) >= 20
    for equation, general, closed, tests in rows:
        assert (general or closed) and tests, equation
        assert not set(general) & set(closed), equation
        if general and closed:
            assert len(tests) >= 2, equation
        for file, name in general + closed:
            source = (ROOT / "flatcli" / file).read_text()
            if name is not None:
                last = name.split(".")[-1]
                assert re.search(rf"^\s*(def|class) {last}\b|^{last} = ", source, re.M), \
                    f"{equation}: flatcli/{file} defines no {name}"
        for module, name in tests:
            source = (ROOT / "tests" / module).read_text()
            if name:
                assert re.search(rf"^def {name}\b", source, re.M), f"{equation}: {module}::{name}"



def tour_files(text: str) -> tuple[dict[str, str], str]:
    """The README tour's files of one's own (a ```toml block whose first line is `# NAME`
    or `# NAME: what it is`), by name, and its commands (the ```sh block after them)."""
    tour = text.split("## A tour")[1]
    head, _, rest = tour.partition("```sh\n")
    files = {}
    for block in head.split("```toml\n")[1:]:
        body = block.split("```", 1)[0]
        name = body.splitlines()[0].removeprefix("# ").split(":")[0].strip()
        files[name] = body
    return files, rest.split("```", 1)[0]


def test_the_tour_shows_every_file_of_ones_own_before_it_uses_it(tmp_path: Path) -> None:
    """Every spec file the tour's commands name is shipped (configs/...) or shown above
    them; the files shown, saved as the tour says, make a valid spec (my_study.toml includes
    my_gains.toml: chain4's three joints, the gains of the file). The whole tour runs as a
    script on a fresh clone in tests/readme_tour.py (minutes: not in CI)."""
    from flatcli.spec import load_spec

    files, commands = tour_files(README.read_text())
    used = set(re.findall(r"[\w./-]+\.toml", commands))
    assert {"my_study.toml"} <= used
    for name in used:
        assert name in files or (ROOT / name).is_file(), f"the tour uses {name} unshown"
    for name, body in files.items():
        (tmp_path / name).write_text(body)
    for body in files.values():
        for included in re.findall(r'"([\w./-]+\.toml)"', body):
            assert included in files or included.removesuffix(".toml") in (
                "chain4", "chain6", "paper"), f"{included} is not shown"
    spec = load_spec(tmp_path / "my_study.toml")
    assert spec.joints == 3 and spec.track.sensor_noise == 1e-4
    gains = load_spec(tmp_path / "my_gains.toml", ["robot=chain4"]).track
    assert (spec.track.kp, spec.track.kv) == (gains.kp, gains.kv)
