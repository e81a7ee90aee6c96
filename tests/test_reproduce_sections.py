"""flatcli.reproduce.sections: when a section of make reproduce is computed again and when it
is reused (the rule of a build system such as Snakemake: same inputs, same code, same files
-> reuse), and that nothing read from a record is trusted."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from flatcli.reproduce import sections
from flatcli.reproduce.sections import (
    Context,
    Outcome,
    Section,
    Steps,
    compute_or_reuse,
    record_path,
    stored_result,
)
from flatcli.spec import resolve


class Counting:
    """A section that writes one file (its content from the inputs) and counts its runs."""

    def __init__(self, name: str = "demo") -> None:
        self.runs = 0
        self.value = 1
        self.section = Section(name, "a demo section", lambda context: {"value": self.value},
                               self.run)

    def run(self, context: Context) -> Outcome:
        self.runs += 1
        (context.out / "demo").mkdir(parents=True, exist_ok=True)
        (context.out / "demo" / "result.txt").write_text(f"value {self.value}\n")
        return Outcome([f"## Demo {self.value}"], [f"value is {self.value}"], ("demo/*",))


@pytest.fixture
def context(tmp_path: Path) -> Context:
    return Context(tmp_path, resolve({}), None, (), None, Steps(quiet=True))


def test_a_section_is_reused_when_nothing_changed(context: Context) -> None:
    demo = Counting()
    first = compute_or_reuse(demo.section, context, force=False)
    second = compute_or_reuse(demo.section, context, force=False)
    assert demo.runs == 1 and not first.reused and second.reused
    assert second.lines == first.lines == ["## Demo 1"] and second.headline == ["value is 1"]


def test_changed_inputs_a_changed_file_and_force_compute_again(context: Context) -> None:
    demo = Counting()
    compute_or_reuse(demo.section, context, force=False)
    demo.value = 2  # an input changed
    assert not compute_or_reuse(demo.section, context, force=False).reused
    assert demo.runs == 2
    (context.out / "demo" / "result.txt").write_text("edited by hand\n")  # a file changed
    assert not compute_or_reuse(demo.section, context, force=False).reused
    (context.out / "demo" / "result.txt").unlink()  # a file is gone
    assert not compute_or_reuse(demo.section, context, force=False).reused
    assert not compute_or_reuse(demo.section, context, force=True).reused
    assert demo.runs == 5
    assert compute_or_reuse(demo.section, context, force=False).reused


def test_changed_code_computes_again(context: Context, monkeypatch: pytest.MonkeyPatch) -> None:
    demo = Counting()
    compute_or_reuse(demo.section, context, force=False)
    monkeypatch.setattr(sections, "code_fingerprint", lambda: "another version of flatcli")
    assert not compute_or_reuse(demo.section, context, force=False).reused
    assert demo.runs == 2


@pytest.mark.parametrize("damage", ["not json", "wrong types", "other version", "escape",
                                    "directory", "fifo"])
def test_a_damaged_record_is_never_trusted(context: Context, damage: str) -> None:
    demo = Counting()
    compute_or_reuse(demo.section, context, force=False)
    path = record_path(context.out, "demo")
    raw = json.loads(path.read_text())
    if damage == "not json":
        path.write_text("{not json")
    elif damage == "wrong types":
        raw["lines"] = [1, 2]
        path.write_text(json.dumps(raw))
    elif damage == "other version":
        raw["version"] = 999
        path.write_text(json.dumps(raw))
    elif damage == "escape":  # a record naming a file outside the directory
        outside = context.out.parent / "outside.txt"
        outside.write_text("x")
        raw["files"] = {"../outside.txt": sections.file_digest(outside)}
        path.write_text(json.dumps(raw))
    elif damage == "directory":
        path.unlink()
        path.mkdir()
    else:
        path.unlink()
        os.mkfifo(path)  # reading it would block forever
    assert stored_result(demo.section, context) is None
    if damage in ("directory", "fifo"):
        return  # the record's place is taken: computing again would fail to write it
    result = compute_or_reuse(demo.section, context, force=False)
    assert not result.reused and demo.runs == 2


def test_the_fingerprint_covers_every_module_and_data_file() -> None:
    package = Path(sections.__file__).resolve().parents[1]
    assert any(package.rglob("data/*.toml")) and any(package.rglob("core/*.py"))
    assert len(sections.code_fingerprint()) == 64
