"""Re-running one trial of a sweep alone (flatcli/montecarlo/rerun.py)."""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path

import pandas as pd
import pytest
from small_sweep import SPEC, sweep, write_spec

from flatcli.core.errors import FlatcliError
from flatcli.montecarlo import layout, rerun_spec
from flatcli.montecarlo.rerun import rerun_and_compare, same, trial_row
from flatcli.spec import resolve


def test_rerun_reproduces_a_trial_exactly(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    out_dir = tmp_path / "d"
    assert sweep(str(spec), "--out", str(out_dir), "-q")[0] == 0
    trial = str(pd.read_parquet(out_dir / "trials.parquet")["trial"].iloc[97])  # cell 1
    code, out = sweep(str(spec), "--out", str(out_dir), "--rerun", trial)
    assert code == 0, out
    assert "NO" not in out and "identical" in out
    rerun = pd.read_parquet(out_dir / f"rerun-{trial}" / "track.parquet")
    assert len(rerun) == 501
    code, text = sweep(str(spec), "--out", str(out_dir), "--rerun", trial, "--print-spec")
    assert code == 0
    assert f"trial = {trial}" in text and "sensor_noise = 0.001" in text
    # a finer step for the same trial: allowed, and said to differ
    code, out = sweep(str(spec), "--out", str(out_dir), "--rerun", trial, "--set",
                      "track.dt=0.001")
    assert code == 0, out
    assert "differs from the sweep's" in out and "NO" in out
    assert len(pd.read_parquet(out_dir / f"rerun-{trial}" / "track.parquet")) == 1001


DYNAMIC = """
name = "small_dynamic"
[plan]
duration = 1.0
start = [1.8, 1.0, 0.0]
goal = [1.5, 1.5, 0.0]
[track]
initial = [1.8, 1.0, 0.0]
dt = 0.005
kp = [100, 110]
kv = [20, 21]
sensor_noise = 0.0005
[plant]
model = "dynamic"
torque_limit = 12.0
[sweep]
trials = 6
seed = 5
[sweep.perturb]
initial = { dist = "normal", std = 0.02 }
servo_bandwidth = { dist = "uniform", low = -0.5, high = 0.5, relative = true }
torque_limit = { dist = "uniform", low = -6.0, high = 6.0 }
"""


def test_rerun_reproduces_a_dynamic_trial_with_a_drawn_servo(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, DYNAMIC)
    out_dir = tmp_path / "d"
    assert sweep(str(spec), "--out", str(out_dir), "-q")[0] == 0
    row = pd.read_parquet(out_dir / "trials.parquet").iloc[4]
    assert row["peak_torque"] <= row["torque_limit"]
    code, out = sweep(str(spec), "--out", str(out_dir), "--rerun", "4")
    assert code == 0, out
    assert "NO" not in out and "identical" in out
    code, text = sweep(str(spec), "--out", str(out_dir), "--rerun", "4", "--print-spec")
    assert f"servo_bandwidth = {float(row['servo_bandwidth'])!r}" in text
    assert f"torque_limit = {float(row['torque_limit'])!r}" in text
    rerun = pd.read_parquet(out_dir / "rerun-4" / "track.parquet")
    assert rerun["tau1"].abs().max() <= row["torque_limit"]


BOX = """
name = "small_box"
[plan]
start = [1.8, 1.0, 0.0]
start_rate = 0.2
goal_rate = 0.2
[task]
end_effector = [-0.25, 0.05]
base_attitude = 1.0
[track]
initial = [1.8, 1.0, 0.0]
kp = [100.0, 110.0]
kv = [10.0, 13.0]
[sweep]
trials = 4
seed = 3
[sweep.perturb]
end_effector = { dist = "uniform", low = [-0.02, -0.02], high = [0.02, 0.02] }
"""


def test_rerun_of_a_task_sweep_reproduces_its_own_target_and_checks_the_bound(
        tmp_path: Path) -> None:
    """A task sweep's re-run (a track run, which measures ee_error_final exactly by the
    links' kinematics) reproduces the row's metrics and finds the distance within the row's
    ee_error_bound; it once failed on the track run's task metrics, absent from the row."""
    spec = write_spec(tmp_path, BOX)
    out_dir = tmp_path / "d"
    assert sweep(str(spec), "--out", str(out_dir), "-q")[0] == 0
    code, out = sweep(str(spec), "--out", str(out_dir), "--rerun", "2")
    assert code == 0, out
    assert "NO" not in out and "Traceback" not in out
    line = next(x for x in out.splitlines() if "ee_error_final <= ee_error_bound" in x)
    assert line.rstrip(" |").endswith("yes")
    code, text = sweep(str(spec), "--out", str(out_dir), "--rerun", "2", "--print-spec")
    row = pd.read_parquet(out_dir / "trials.parquet").iloc[2]
    assert repr(float(row["end_effector_0"])) in text and repr(float(row["end_effector_1"])) in text


def test_a_trial_row_is_refused_before_the_sweep_ran(tmp_path: Path) -> None:
    with pytest.raises(FlatcliError, match=r"trials\.parquet not found; run the sweep first"):
        trial_row(tmp_path, 3)


def test_the_rerun_spec_sets_the_drawn_values_and_the_noise_stream() -> None:
    spec = resolve({"name": "s", "sweep": {"trials": 2, "seed": 9, "perturb": {
        "initial_rate": {"dist": "normal", "std": 0.1},
        "com": {"dist": "uniform", "low": 0, "high": [0, 0, 0.01]}}}})
    row = {"cell": 0, "trial": 1, "initial_rate": 0.125, "com_0": 0.1, "com_1": 0.1,
           "com_2": 0.003}
    track = rerun_spec(layout(spec), row)
    assert track.track.initial_rate == 0.125 and track.plant.com == (0.1, 0.1, 0.003)
    assert (track.track.seed, track.track.trial, track.name) == (9, 1, "s-trial-1")
    assert track.sweep.perturb == {}


def test_same_treats_nan_as_reproduced() -> None:
    assert same(math.nan, math.nan) and same(1.0, 1) and same("ok", "ok")
    assert not same(1.0, 1.0 + 1e-15) and not same(math.nan, 0.0)


@pytest.mark.timeout(30, method="thread")  # a FIFO opened blindly would block
def test_a_trials_table_that_is_not_a_regular_file_is_refused_unread(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "trials.parquet")
    with pytest.raises(FlatcliError, match=r"trials\.parquet is a FIFO, not the sweep's table"):
        trial_row(tmp_path, 3)


@pytest.mark.parametrize("what", ["link", "file", "fifo inside", "directory inside"])
def test_a_rerun_never_writes_through_a_link_or_over_something_else(
        tmp_path: Path, what: str) -> None:
    text = "\n".join(line for line in SPEC.splitlines()
                     if not line.startswith(("trials =", "chunk =")))
    spec_path = write_spec(tmp_path, text.replace("[sweep]", "[sweep]\ntrials = 2\nchunk = 2"))
    directory = tmp_path / "d"
    assert sweep(str(spec_path), "--out", str(directory), "-q", "--workers", "1")[0] == 0
    spec = resolve(tomllib.loads(spec_path.read_text()))
    outside = tmp_path / "outside"
    outside.mkdir()
    trial = int(pd.read_parquet(directory / "trials.parquet")["trial"].iloc[1])
    target = directory / f"rerun-{trial}"
    if what == "link":
        target.symlink_to(outside, target_is_directory=True)
    elif what == "file":
        target.write_text("mine")
    else:
        target.mkdir()
        if what == "fifo inside":
            os.mkfifo(target / "run.json")
        else:
            (target / "track.parquet").mkdir()
    with pytest.raises(FlatcliError, match=rf"--rerun: .* holds rerun-{trial}.* where the "
                                           "re-run writes its files; remove it yourself"):
        rerun_and_compare(spec, directory, trial)
    assert list(outside.iterdir()) == []


#: A grid whose keys are not in alphabetical order ("track.sensor_noise" > "track.kp"): a
#: record that sorted them would enumerate its cells in another order.
UNSORTED_GRID = """
name = "unsorted"
[plan]
duration = 1.0
start = [1.8, 1.0, 0.0]
goal = [1.5, 1.5, 0.0]
[track]
initial = [1.8, 1.0, 0.0]
dt = 0.01
kv = [20, 21]
[sweep]
trials = 2
seed = 3
[sweep.perturb]
initial = { dist = "normal", std = 0.01 }
[sweep.grid]
"track.sensor_noise" = [0.0, 0.001, 0.002]
"track.kp" = [[100, 110], [60, 70]]
"""


def _rerun_cli(*args: str) -> tuple[int, str]:
    from click.testing import CliRunner

    from flatcli.cli import main

    result = CliRunner().invoke(main, ["rerun", *args])
    return result.exit_code, result.output


def test_rerun_of_a_directory_finds_each_trials_own_cell(tmp_path: Path) -> None:
    """``flatcli rerun DIR TRIAL`` (the spec read back from the sweep's record) re-runs the
    trial's own cell for every cell of a grid whose keys are not in alphabetical order; the
    referee is the trial's own row (its grid values and every metric)."""
    from flatcli import api

    spec = write_spec(tmp_path, UNSORTED_GRID)
    out_dir = tmp_path / "d"
    assert sweep(str(spec), "--out", str(out_dir), "-q")[0] == 0
    loaded = api.load(out_dir)
    assert list(loaded.spec.sweep.grid) == ["track.sensor_noise", "track.kp"]
    table = pd.read_parquet(out_dir / "trials.parquet")
    for cell in range(6):
        row = table[table["cell"] == cell].iloc[0]
        code, out = _rerun_cli(str(out_dir), str(int(row["trial"])), "-q")
        assert code == 0, out
        rerun_spec_text = tomllib.loads(_rerun_cli(str(out_dir), str(int(row["trial"])),
                                                   "--print-spec")[1])
        assert rerun_spec_text["track"]["sensor_noise"] == row["track.sensor_noise"]


def test_a_record_with_sorted_grid_keys_comes_back_in_the_sweeps_order(tmp_path: Path) -> None:
    """A sweep.json written by an older flatcli (every key sorted, the grid's too) gives the
    grid back in the order the sweep ran it, from the manifest's cell keys (grid_cells)."""
    import json

    from flatcli import api

    spec = write_spec(tmp_path, UNSORTED_GRID)
    out_dir = tmp_path / "d"
    assert sweep(str(spec), "--out", str(out_dir), "-q")[0] == 0
    manifest = out_dir / "sweep.json"
    data = json.loads(manifest.read_text())
    manifest.write_text(json.dumps(data, indent=2, sort_keys=True))
    assert list(json.loads(manifest.read_text())["spec"]["sweep"]["grid"]) == [
        "track.kp", "track.sensor_noise"]
    assert list(api.load(out_dir).spec.sweep.grid) == ["track.sensor_noise", "track.kp"]
    row = pd.read_parquet(out_dir / "trials.parquet").iloc[5]  # cell 2
    code, out = _rerun_cli(str(out_dir), str(int(row["trial"])), "-q")
    assert code == 0, out
