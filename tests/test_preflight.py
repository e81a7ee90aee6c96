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


def cli_stdout(*args: str) -> tuple[int, str]:
    """Exit status and standard output alone (the calibration's progress goes to stderr)."""
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.stdout


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
    # one kernel: its first cell's 1 and 8 trials, twice; then 8 trials of each of the 2
    # cells (ceil(128 / 2), capped at CALIBRATION_CHUNK), the same draws in both, and more
    # of their trials, 8 at a time, for up to CALIBRATION_STEADY_SECONDS
    kernel_trials = 2 * (1 + 8)
    assert (cal.per_cell, cal.measured_cells) == (8, 2)
    assert cal.trials >= kernel_trials + 2 * 8 and (cal.trials - kernel_trials) % 8 == 0
    assert [k.name for k in cal.kernels] == [
        "paper model, kinematic plant, flat controller, adaptive, 2 joints"]
    assert sum(cal.statuses.values()) == cal.trials
    assert cal.per_trial > 0 and cal.per_chunk >= 0 and cal.slowdown >= 1
    assert cal.cell_verify == (0.0, 0.0)  # sweep.verify = 0
    estimate = report.estimate_seconds
    assert estimate is not None
    # the trials' share: 6 chunks (25, 25, 10 trials of each cell) over 2 workers
    work = sum(cal.cell_chunk[c] + n * cal.cell_trial[c] for c in (0, 1) for n in (25, 25, 10))
    assert report.cpu_seconds == pytest.approx(work)
    assert estimate >= report.planning_seconds + work / 2 * cal.slowdown
    memory = report.memory_mib
    assert memory is not None and memory[0] > 50 and memory[1] > 50
    assert "estimate on 2 local workers" in report.text()
    quiet_machine = replace(report, cores=8, load=0.0)
    assert _warnings(quiet_machine) == []


def test_a_busy_machine_and_too_many_workers_are_warnings(report: CheckReport) -> None:
    busy = replace(report, cores=2, load=5.0, workers=3)
    assert _warnings(busy) == [
        "this machine is busy (load average 5.0 on 2 cores): the estimate allows for the "
        "share of the cores the calibration got; the sweep's time follows the load",
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
    code, out = cli_stdout("sweep", str(spec), "--dry-run", "--workers", "2")
    assert code == 0, out
    assert not out.startswith(COMPILING)  # (a compile notice goes to stderr)
    assert "cells (2):" in out and "calibration:" in out and "nothing written" in out
    code, check_out = cli_stdout("check", str(spec), "--workers", "2")
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
    # the first cell's 1 and 2 trials, twice, then 2 of each cell and more: all invalid
    assert set(result.calibration.statuses) == {"error"}
    assert result.calibration.statuses["error"] >= 2 * (1 + 2) + 2 * 2
    assert not any("changes nothing" in w for w in result.warnings)
    assert np.isfinite(result.calibration.per_trial)


def test_a_machine_at_its_load_is_busy(report: CheckReport) -> None:
    # load average at least the cores: the README's "busy" (one runnable process per core)
    at = replace(report, cores=2, load=2.0, workers=2)
    assert any(w.startswith("this machine is busy (load average 2.0") for w in _warnings(at))
    below = replace(report, cores=2, load=1.99, workers=2)
    assert not any(w.startswith("this machine is busy") for w in _warnings(below))


SIX_CELLS = """
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
"""


def test_the_same_draws_run_128_over_cells_trials_of_each_cell_2_to_8(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, SIX_CELLS)
    cal = api.check(spec, workers=1, quiet=True).calibration
    assert cal is not None and (cal.per_cell, cal.measured_cells) == (8, 6)  # 22, capped
    many = SIX_CELLS.replace('"track.sensor_noise" = [0.0, 0.001, 0.002, 0.003, 0.004, 0.005]',
                             '"track.sensor_noise" = [' + ", ".join(
                                 f"{0.0001 * i:.4f}" for i in range(100)) + "]")
    cal = api.check(write_spec(tmp_path, many, "many.toml"), workers=1, quiet=True).calibration
    assert cal is not None and cal.per_cell == 2  # ceil(128 / 100) = 2
    report = api.check(spec, workers=1, quiet=True)
    assert report.calibration is not None
    assert f"calibration: {report.calibration.trials} trials in " in report.text()


def test_the_calibration_stops_at_its_time_and_extrapolates_the_cells_it_did_not_reach(
        tmp_path: Path) -> None:
    """A budget of 0 s: each kernel's first cell is measured (always), no cell's own
    trials; every cell then costs its kernel's per output step times its own steps, and
    which keys change nothing is not told (it needs every cell)."""
    from flatcli.preflight import check_spec

    text = SIX_CELLS.replace('"track.sensor_noise" = [0.0, 0.001, 0.002, 0.003, 0.004, 0.005]',
                             '"plan.duration" = [0.5, 1.0]\n"track.seed" = [1, 2]')
    spec = api.load_spec(write_spec(tmp_path, text))
    report = check_spec(spec, workers=1, quiet=True, budget=0.0)
    cal = report.calibration
    assert cal is not None and cal.measured_cells == 0 and cal.unchanged_keys is None
    (kernel,) = cal.kernels
    steps = [c.scenario.n_steps for c in report.layout.cells]
    assert steps == [50, 50, 100, 100]
    per_step = kernel.per_trial / steps[0]  # its first cell's
    assert cal.cell_trial == pytest.approx([per_step * n for n in steps])
    assert not any("changes nothing" in w for w in report.warnings)


def test_cells_are_grouped_by_the_kernel_they_run(tmp_path: Path) -> None:
    text = SIX_CELLS.replace('"track.sensor_noise" = [0.0, 0.001, 0.002, 0.003, 0.004, 0.005]',
                             '"plant.model" = ["kinematic", "dynamic"]\n'
                             '"track.sensor_noise" = [0.0, 0.001]')
    cal = api.check(write_spec(tmp_path, text), workers=1, quiet=True).calibration
    assert cal is not None
    assert [(k.name, k.cells) for k in cal.kernels] == [
        ("paper model, kinematic plant, flat controller, adaptive, 2 joints", 2),
        ("paper model, dynamic plant, flat controller, adaptive, 2 joints", 2)]


def test_the_calibration_says_what_it_does_as_it_goes(tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["check", str(write_spec(tmp_path, SIX_CELLS)),
                                       "--workers", "1"])
    assert result.exit_code == 0, result.output
    err = [line for line in result.stderr.splitlines() if not line.startswith(
        (COMPILING, "  compil"))]
    assert err[0] == ("calibrating 6 cells of 1 kernel, at most 5 s once loaded, in 1 worker "
                      "process")
    assert err[-1].startswith("  paper model, kinematic plant, flat controller, adaptive, "
                              "2 joints: ") and "ms per trial" in err[-1]


def test_calibration_trials_past_the_verified_ones_cost_no_re_run(tmp_path: Path) -> None:
    """sweep.verify re-runs a cell's first trials with DOP853 (50-500x a trial): the
    calibration's trials are not those (they once were, and made an estimate 40x too long);
    the re-runs are counted apart, verify_count of them per cell."""
    spec = write_spec(tmp_path, SIX_CELLS.replace("trials = 50", "trials = 50\nverify = 2"))
    report = api.check(spec, workers=1, quiet=True)
    cal = report.calibration
    assert cal is not None
    (kernel,) = cal.kernels
    assert kernel.verify > kernel.per_trial  # one DOP853 re-run costs more than a trial
    assert cal.cell_verify == pytest.approx([2 * kernel.verify] * 6)


def test_the_slowdown_is_the_more_of_the_calibrations_and_the_load_averages(
        report: CheckReport) -> None:
    """(other processes + the sweep's busy workers) / cores, or what the calibration's
    workers met, whichever is more; at least 1; a cluster's workers are not this machine's."""
    cal = report.calibration
    assert cal is not None
    idle = replace(report, calibration=replace(cal, slowdown=1.0, other_load=0.0), cores=2)
    assert idle.slowdown == 1.0
    loaded = replace(idle, calibration=replace(cal, slowdown=1.5, other_load=4.0))
    assert loaded.slowdown == pytest.approx((4.0 + 2) / 2)  # 6 runnable on 2 cores
    measured = replace(loaded, calibration=replace(cal, slowdown=3.5, other_load=4.0))
    assert measured.slowdown == 3.5
    assert replace(measured, executor="dask").slowdown == 1.0
    assert measured.estimate_seconds is not None and idle.estimate_seconds is not None
    assert measured.estimate_seconds > idle.estimate_seconds
