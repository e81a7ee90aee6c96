"""`flatcli check` and `sweep --dry-run` (flatcli/preflight.py): the layout, a calibrated
estimate, warnings that are true, and nothing written."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from small_sweep import SPEC, write_spec

from flatcli import api
from flatcli.cli import main
from flatcli.montecarlo import Chunk, layout, run_chunk
from flatcli.preflight import CheckReport, _warnings, resolved_toml
from flatcli.progress import COMPILING
from flatcli.spec import resolve


def cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.output


def files(root: Path) -> list[Path]:
    return sorted(root.rglob("*"))


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> CheckReport:
    spec = write_spec(tmp_path_factory.mktemp("check"))
    result = api.check(spec, workers=2, quiet=True)
    assert isinstance(result, CheckReport)
    return result


def test_layout_counts(report: CheckReport) -> None:
    # tests/small_sweep.py: 2 cells (sensor noise 0, 0.001) of 60 trials in chunks of 25:
    # 25 + 25 + 10 per cell
    assert [c.size for c in report.chunks] == [25, 25, 10] * 2
    cells = report.cells
    assert cells["track.sensor_noise"].tolist() == [0.0, 0.001]
    assert cells["trials"].tolist() == [60, 60] and cells["chunks"].tolist() == [3, 3]
    text = report.text()
    assert "120 trials: 2 cells of 60, in 6 chunks of 10 to 25 trials" in text
    assert text.rstrip().endswith("nothing written")


def test_calibration_and_estimate(report: CheckReport) -> None:
    cal = report.calibration
    assert cal is not None
    # 1 + ceil(128 / 2) trials per cell, capped at the cell's 60
    assert (cal.per_cell, cal.trials) == (60, 120)
    assert sum(cal.statuses.values()) == cal.trials
    assert cal.per_trial > 0 and cal.per_chunk >= 0
    estimate = report.estimate_seconds
    assert estimate is not None
    # the trials' share: 6 chunks over 2 workers, three chunks' work each at least
    spread = (6 * cal.per_chunk + 120 * cal.per_trial) / 2
    assert estimate >= report.planning_seconds + spread
    memory = report.memory_mib
    assert memory is not None and memory[0] > 50 and memory[1] > 50
    assert "estimate on 2 local workers" in report.text()
    quiet_machine = replace(report, cores=8, load=0.0)
    assert _warnings(quiet_machine) == []


def test_a_busy_machine_and_too_many_workers_are_warnings(report: CheckReport) -> None:
    busy = replace(report, cores=2, load=5.0, workers=3)
    assert _warnings(busy) == [
        "this machine is busy (load average 5.0 on 2 cores): the sweep will take longer "
        "than the estimate, which assumes idle cores",
        "3 workers on 2 cores: no faster than 2",
    ]
    # 3 workers on 2 cores spread the 6 chunks as 2 would
    assert busy.estimate_seconds == replace(report, cores=2, workers=2).estimate_seconds


def test_resolved_spec_reads_back_as_the_same_spec(report: CheckReport) -> None:
    text = resolved_toml(report.spec, report.layout.chunk_size)
    again = resolve(tomllib.loads(text))
    assert again.digest() == report.spec.digest()


def test_no_perturbation_and_no_grid_warns_of_identical_trials(tmp_path: Path) -> None:
    spec = {"sweep": {"trials": 5}}
    result = api.check(spec, workers=1, quiet=True)
    assert any("the 5 trials are identical" in w for w in result.warnings)
    # and they are: the same numbers in every row
    lay = layout(resolve(spec))
    table = run_chunk(lay.cells[0], Chunk(0, 0, 5)).table.drop_columns(["trial"]).to_pandas()
    assert (table.nunique(dropna=False) == 1).all()


def test_a_grid_key_that_changes_nothing_is_named(tmp_path: Path) -> None:
    # track.seed: a sweep's noise comes from sweep.seed and the trial id (README, [sweep])
    text = SPEC.replace('"track.sensor_noise" = [0.0, 0.001]',
                        '"track.seed" = [1, 2]\n"track.sensor_noise" = [0.0, 0.001]')
    spec = write_spec(tmp_path, text)
    result = api.check(spec, overrides=["sweep.trials=3"], workers=1, quiet=True)
    named = [w for w in result.warnings if "changes nothing" in w]
    assert len(named) == 1 and "'track.seed'" in named[0]
    # it is true: cells 0 and 2 differ in track.seed only, and give the same numbers
    lay = layout(api.load_spec(spec, ["sweep.trials=3"]))
    assert lay.cells[0].values["track.sensor_noise"] == lay.cells[2].values[
        "track.sensor_noise"] == 0.0
    a = run_chunk(lay.cells[0], Chunk(0, 0, 3)).table.drop_columns(["cell", "track.seed"])
    b = run_chunk(lay.cells[2], Chunk(2, 0, 3)).table.drop_columns(["cell", "track.seed"])
    assert a.to_pandas().equals(b.to_pandas())


def test_more_workers_than_chunks_is_a_warning() -> None:
    result = api.check({"sweep": {"trials": 4, "perturb": {"initial": {"dist": "normal",
                                                                       "std": 0.01}}}},
                       workers=3, calibrate=False, quiet=True)
    assert result.calibration is None and result.estimate_seconds is None
    assert "1 chunk for 3 workers: 2 would idle (set sweep.chunk smaller)" in result.warnings


def test_dry_run_prints_the_check_and_writes_nothing(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    spec = write_spec(tmp_path / "spec")
    monkeypatch.chdir(tmp_path)
    before = files(tmp_path)
    code, out = cli("sweep", str(spec), "--dry-run", "--workers", "2")
    assert code == 0, out
    out = out.removeprefix(COMPILING + "\n")
    assert "cells (2):" in out and "calibration:" in out and "nothing written" in out
    code, check_out = cli("check", str(spec), "--workers", "2")
    assert code == 0
    assert check_out.split("; planning")[0] == out.split("; planning")[0]  # timings differ
    # -q: nothing but errors, in check as in every command (the exit status says it is valid)
    assert cli("check", str(spec), "--workers", "2", "-q") == (0, "")
    assert cli("sweep", str(spec), "--dry-run", "-q") == (0, "")
    assert files(tmp_path) == before
    code, out = cli("sweep", str(spec), "--dry-run", "--rerun", "3")
    assert code == 2 and "--dry-run: not with --rerun" in out


def test_check_refuses_bad_input_in_one_line(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 0"))
    code, out = cli("check", str(spec))
    assert code == 2 and out == "error: sweep.trials: must be >= 1, got 0\n"
    code, out = cli("check", str(write_spec(tmp_path, name="ok.toml")), "--workers", "0")
    assert code == 2 and out == "error: --workers: must be >= 1, got 0\n"


def test_unchanged_key_check_needs_a_simulated_trial() -> None:
    # every trial invalid (mass scaled by 1 + U(-3, -2) < 0): nothing to compare, no claim
    spec = {"sweep": {"trials": 2, "perturb": {"mass": {"dist": "uniform", "low": -3.0,
                                                        "high": -2.0, "relative": True}},
                      "grid": {"track.seed": [1, 2]}}}
    result = api.check(spec, workers=1, quiet=True)
    assert result.calibration is not None
    assert result.calibration.statuses == {"error": 4}
    assert not any("changes nothing" in w for w in result.warnings)
    assert np.isfinite(result.calibration.per_trial)


def test_a_machine_at_its_load_is_busy(report: CheckReport) -> None:
    # load average at least the cores: the README's "busy" (one runnable process per core)
    at = replace(report, cores=2, load=2.0, workers=2)
    assert any(w.startswith("this machine is busy (load average 2.0") for w in _warnings(at))
    below = replace(report, cores=2, load=1.99, workers=2)
    assert not any(w.startswith("this machine is busy") for w in _warnings(below))


def test_the_calibration_runs_one_plus_128_over_cells_trials_of_each_cell(
        tmp_path: Path) -> None:
    spec = write_spec(tmp_path, """
[plan]
duration = 0.5
[track]
dt = 0.01
[sweep]
trials = 50
[sweep.perturb]
initial = { dist = "normal", std = 0.01 }
[sweep.grid]
"track.sensor_noise" = [0.0, 0.001, 0.002, 0.003, 0.004, 0.005]
""")
    report = api.check(spec, workers=1, quiet=True)
    cal = report.calibration
    assert cal is not None
    # 1 + ceil(128 / 6) = 23 of each cell's 50: not capped, so the count itself shows
    assert (cal.per_cell, cal.trials) == (23, 6 * 23)
    assert f"calibration: {6 * 23} trials (23 per cell" in report.text()
