"""Progress (flatcli/progress.py): a running sweep's lines, and the compile notice
(``compile_notices``): said when numba compiles one of flatcli's functions, and only then (the
referee: numba's own compile counters), with the time expected, a progress line while it
compiles, and its time kept for the next notice."""

from __future__ import annotations

import importlib.util
import io
import json
import sys
from pathlib import Path
from types import ModuleType

import numba
import pytest

from flatcli import progress
from flatcli.progress import (
    COMPILE_SECONDS,
    COMPILING,
    Progress,
    compile_notices,
    expected_seconds,
    recorded_seconds,
)

PROBE = """
import numba


@numba.njit(cache=False)
def probe(x):
    total = 0.0
    for i in range(x.shape[0]):
        total += x[i] * x[i] + i
    return total
"""


def probe_module(tmp_path: Path, name: str) -> ModuleType:
    """A module of its own named ``name`` (a flatcli one, or not) holding a jitted function
    numba has not compiled yet."""
    path = tmp_path / f"{name.replace('.', '_')}.py"
    path.write_text(PROBE)
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(autouse=True)
def own_record(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The compile times kept under this test's directory."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return tmp_path / "cache" / "flatcli" / "compile-seconds.json"


def test_a_compile_of_flatclis_is_announced_timed_and_kept(
        tmp_path: Path, own_record: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import numpy as np

    monkeypatch.setattr(progress, "COMPILE_TICK_LOG", 0.001)  # a progress line at once
    module = probe_module(tmp_path, "flatcli.notice_probe")
    key = "the simulation kernel of the paper model, kinematic plant"
    stream = io.StringIO()
    with compile_notices(key, quiet=False, stream=stream) as notice:
        module.probe(np.ones(3))
    assert notice.compiled and sum(module.probe.stats.cache_misses.values()) == 1
    lines = stream.getvalue().splitlines()
    assert lines[0] == (f"{COMPILING} {key} (once, then cached; about "
                        f"{COMPILE_SECONDS[key]:.0f} s, on this project's 2 cores)")
    assert any(line.startswith(f"  {COMPILING}: ") and "of about" in line
               for line in lines[1:-1]), lines
    assert lines[-1].startswith("  compiled in ")
    kept = json.loads(own_record.read_text())
    assert set(kept) == {key} and kept[key] >= 0
    assert expected_seconds(key) == (kept[key], True)
    # compiled now: the same call again says nothing
    stream = io.StringIO()
    with compile_notices(key, quiet=False, stream=stream) as notice:
        module.probe(np.ones(3))
    assert not notice.compiled and stream.getvalue() == ""


def test_quiet_says_nothing_and_another_modules_compile_is_not_flatclis(
        tmp_path: Path) -> None:
    import numpy as np

    stream = io.StringIO()
    quiet = probe_module(tmp_path, "flatcli.quiet_probe")
    with compile_notices("the planner of the chain model", quiet=True,
                         stream=stream) as notice:
        quiet.probe(np.ones(2))
    assert notice.compiled and stream.getvalue() == ""
    users = probe_module(tmp_path, "users_own_probe")
    with compile_notices("the planner of the chain model", quiet=False,
                         stream=stream) as notice:
        users.probe(np.ones(2))  # compiled (numba's counter), but not flatcli's
    assert sum(users.probe.stats.cache_misses.values()) == 1
    assert not notice.compiled and stream.getvalue() == ""


@pytest.mark.parametrize("text", ['{"a": "x", "b": -1, "c": true}', "[1]", "not json", ""])
def test_a_record_not_as_flatcli_writes_it_is_not_trusted(own_record: Path, text: str) -> None:
    own_record.parent.mkdir(parents=True)
    own_record.write_text(text)
    assert recorded_seconds() == {}
    key = "the simulation kernel of the as-built model, dynamic plant"
    assert expected_seconds(key) == (COMPILE_SECONDS[key], False)
    assert expected_seconds("a kernel nobody knows") == (max(COMPILE_SECONDS.values()), False)


def test_every_kernel_family_a_sweep_runs_is_loaded_here_under_its_notice(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A grid over the plant: two kernels, both loaded in the main process (each under its
    own notice) before any worker runs a chunk, not compiled by the workers unannounced."""
    import contextlib

    from flatcli.montecarlo import runner
    from flatcli.spec import resolve

    keys: list[tuple[str, bool]] = []

    @contextlib.contextmanager
    def noted(key: str, quiet: bool) -> object:
        keys.append((key, quiet))
        with compile_notices(key, quiet) as notice:
            yield notice

    monkeypatch.setattr(runner, "compile_notices", noted)
    spec = resolve({"track": {"dt": 0.004}, "sweep": {
        "trials": 4, "chunk": 2, "perturb": {"initial": {"dist": "normal", "std": 0.01}},
        "grid": {"plant.model": ["kinematic", "dynamic"]}}})
    runner.run_sweep(spec, tmp_path / "d", workers=1)
    assert keys == [("the planner of the paper model", True),
                    ("the simulation kernel of the paper model, kinematic plant", True),
                    ("the simulation kernel of the paper model, dynamic plant", True)]
    assert numba.config  # (numba's own counters are the referee of the tests above)


def test_progress_prints_lines_off_a_terminal(tmp_path: Path) -> None:
    path = tmp_path / "log"
    with path.open("w") as stream:
        progress = Progress("x", stream=stream, interval=0.0)
        progress.start(10, 4, "local")
        progress.advance(6)
        progress.close()
    text = path.read_text()
    assert "10 trials on local, resuming with 4 done" in text
    assert "10/10 trials (100%)" in text


def test_quiet_progress_prints_nothing(tmp_path: Path) -> None:
    path = tmp_path / "log"
    with path.open("w") as stream:
        progress = Progress("x", quiet=True, stream=stream, interval=0.0)
        progress.start(10, 0, "local")
        progress.advance(10)
        progress.close()
    assert path.read_text() == ""


def test_the_cells_planning_is_shown_for_a_large_grid_only() -> None:
    import io

    from flatcli.progress import CELLS_SHOWN

    stream = io.StringIO()
    progress = Progress("s", stream=stream, interval=1e9)
    for done in range(CELLS_SHOWN + 1):
        progress.cells(done, CELLS_SHOWN)
    assert stream.getvalue() == ""
    for done in range(CELLS_SHOWN + 2):
        progress.cells(done, CELLS_SHOWN + 1)
    lines = stream.getvalue().splitlines()
    assert lines[0] == f"sweep 's': planning {CELLS_SHOWN + 1} grid cells"
    assert lines[1].startswith(f"  {CELLS_SHOWN + 1}/{CELLS_SHOWN + 1} cells planned (100%)")
    assert len(lines) == 2
    quiet = io.StringIO()
    Progress("s", quiet=True, stream=quiet).cells(0, 10**4)
    assert quiet.getvalue() == ""



def test_the_mpcs_kernel_has_a_notice_of_its_own() -> None:
    """The MPC's loop is another kernel than its inner law's: its notice names it, and the
    table's expected time is the MPC's (40-60 s measured), not the inner loop's."""
    from types import SimpleNamespace

    from flatcli.progress import kernel_text, spec_kernel_text
    from flatcli.spec import resolve

    flat, mpc = (resolve({"track": {"controller": c}}) for c in ("flat", "mpc"))
    assert spec_kernel_text(flat) == "the simulation kernel of the paper model, kinematic plant"
    assert spec_kernel_text(mpc) == spec_kernel_text(flat) + ", mpc controller"
    plan = SimpleNamespace(model=SimpleNamespace(kind="paper"))
    for sampled in (None, "mpc"):
        scenario = SimpleNamespace(controller="flat", plan=plan, plant="kinematic",
                                   sampled=sampled)
        text = kernel_text(scenario)
        assert text == spec_kernel_text(flat if sampled is None else mpc)
        assert COMPILE_SECONDS[text] == (40.0 if sampled is None else 60.0)
