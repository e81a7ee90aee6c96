"""The package's layout (issue 38's Done-when; docs/development.md, "How a parameter travels"):
no import circle anywhere in flatcli/, spec/ included, and nothing in core/ importing a layer
above it.

The graph is read from the source with ``ast`` (nothing is imported): every ``import`` and
``from ... import`` in a module, at its top or inside a function, a class or a ``try``;
``from P import name`` counts as importing the module P.name where that is a module, and P
itself. Importing a module runs its packages' ``__init__`` too: an import of a.b.c from outside
the package a.b adds a.b and a (from inside it they are already running). Imports under
``if TYPE_CHECKING:`` never run and do not count; nor do ``importlib.import_module`` calls
(flatcli/__init__.py's lazy attributes, whose modules are all above every other module).

The referee of the circle finder is a small package with a planted circle, written to a
temporary folder (``test_a_planted_circle_is_found``): the finder is not trusted on the word
of the test that uses it.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def modules(root: Path, package: str) -> dict[str, Path]:
    """{dotted name: file} of every module of ``package`` under ``root`` (a package's name
    for its ``__init__.py``)."""
    found = {}
    for path in (root / package).rglob("*.py"):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    skipped: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for statement in node.body:
                skipped.update(id(inner) for inner in ast.walk(statement))
    return skipped


def import_graph(root: Path, package: str) -> dict[str, set[str]]:
    """{module: the package's modules it imports} (module docstring's rules)."""
    known = modules(root, package)

    def resolve(name: str) -> str | None:
        parts = name.split(".")
        while parts:
            if ".".join(parts) in known:
                return ".".join(parts)
            parts.pop()
        return None

    graph: dict[str, set[str]] = {name: set() for name in known}
    for name, path in known.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        skipped = _type_checking_nodes(tree)
        here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(tree):
            if id(node) in skipped:
                continue
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    prefix = here[: len(here) - (node.level - 1)]
                    base = ".".join(prefix + ([node.module] if node.module else []))
                targets = [base] + [f"{base}.{alias.name}" for alias in node.names]
            else:
                continue
            for target in targets:
                module = resolve(target)
                first = True
                while module is not None:
                    inside = name == module or name.startswith(module + ".")
                    if module != name and (first or not inside):
                        graph[name].add(module)
                    first = False
                    parent = module.rpartition(".")[0]
                    module = parent if parent in known else None
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The graph's strongly connected components of more than one module (Tarjan's
    algorithm, iterative), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            advanced = False
            for successor in successors:
                if successor not in index:
                    index[successor] = low[successor] = counter
                    counter += 1
                    stack.append(successor)
                    on_stack.add(successor)
                    work.append((successor, iter(sorted(graph[successor]))))
                    advanced = True
                    break
                if successor in on_stack:
                    low[node] = min(low[node], index[successor])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_no_import_circle_in_flatcli() -> None:
    graph = import_graph(ROOT, "flatcli")
    assert len(graph) > 100 and "flatcli.spec.build" in graph  # the whole package was read
    assert circles(graph) == []


def test_core_imports_nothing_above_it() -> None:
    graph = import_graph(ROOT, "flatcli")
    upward = sorted((a, b) for a, targets in graph.items() if a.startswith("flatcli.core")
                    for b in targets if not b.startswith("flatcli.core"))
    assert upward == []


def _write(root: Path, files: dict[str, str]) -> None:
    for relative, text in files.items():
        path = root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_a_planted_circle_is_found(tmp_path: Path) -> None:
    # pkg.a imports pkg.b at its top, pkg.b imports pkg.a inside a function: a circle
    _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/a.py": "from pkg import b\n",
        "pkg/b.py": "def f():\n    from pkg.a import thing\n",
        "pkg/c.py": "import pkg.a\n",
    })
    assert circles(import_graph(tmp_path, "pkg")) == [["pkg.a", "pkg.b"]]


def test_a_package_init_run_by_an_import_from_outside_counts(tmp_path: Path) -> None:
    # pkg.sub's __init__ imports pkg.top; pkg.top imports pkg.sub.leaf, which runs
    # pkg.sub's __init__ first: a circle through the package's __init__
    _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/top.py": "from pkg.sub.leaf import x\n",
        "pkg/sub/__init__.py": "from pkg import top\n",
        "pkg/sub/leaf.py": "x = 1\n",
    })
    assert circles(import_graph(tmp_path, "pkg")) == [["pkg.sub", "pkg.top"]]


def test_type_checking_imports_and_siblings_do_not_count(tmp_path: Path) -> None:
    # a package __init__ handing on its modules' names, the modules importing each other's
    # names through absolute imports, and a TYPE_CHECKING import back: no circle
    _write(tmp_path, {
        "pkg/__init__.py": "from pkg.a import A\nfrom pkg.b import B\n",
        "pkg/a.py": "from typing import TYPE_CHECKING\nA = 1\n"
                    "if TYPE_CHECKING:\n    from pkg.b import B\n",
        "pkg/b.py": "from pkg.a import A\nB = A\n",
    })
    graph = import_graph(tmp_path, "pkg")
    assert graph["pkg.a"] == set() and graph["pkg.b"] == {"pkg.a"}
    assert circles(graph) == []
