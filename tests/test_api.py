"""The Python API (flatcli/api.py): the same numbers and files as the command line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from matplotlib.figure import Figure
from small_sweep import SPEC, sweep_without_final_tables, write_spec

import flatcli
from flatcli import api
from flatcli.cli import main

HEAVY = ("numpy", "numba", "scipy", "pandas", "pyarrow", "matplotlib")


def cli(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


def test_plan_equals_the_cli_plan(tmp_path: Path) -> None:
    cli("plan", "--out", str(tmp_path / "cli"), "-q", "--set", "plan.duration=3")
    result = flatcli.plan(overrides={"plan.duration": 3.0})
    written = pd.read_parquet(tmp_path / "cli" / "plan.parquet")
    pd.testing.assert_frame_equal(result.frame, written, check_exact=True)
    record = json.loads((tmp_path / "cli" / "run.json").read_text())
    assert result.metrics == record["summary"]
    assert result.optimization is None and result.directory is None
    # saved through the API, the files are the CLI's files
    directory = result.save(tmp_path / "api")
    pd.testing.assert_frame_equal(pd.read_parquet(directory / "plan.parquet"), written,
                                  check_exact=True)
    saved = json.loads((directory / "run.json").read_text())
    assert saved["spec"] == record["spec"] and saved["digest"] == record["digest"]


def test_track_equals_the_cli_track(tmp_path: Path) -> None:
    sets = ["track.kp=[100,110]", "track.kv=[10,13]"]
    cli("track", "--out", str(tmp_path / "cli"), "-q", *(w for s in sets for w in ("--set", s)))
    result = flatcli.track(overrides=sets, quiet=True)
    assert result.metrics == json.loads((tmp_path / "cli" / "metrics.json").read_text())
    pd.testing.assert_frame_equal(result.frame, pd.read_parquet(tmp_path / "cli" / "track.parquet"),
                                  check_exact=True)
    assert result.metrics["err_y_final"] < 1e-4  # swapped gains: ~1e-5 (README, "The gains")
    loaded = flatcli.load(tmp_path / "cli")
    assert isinstance(loaded, api.TrackResult)
    assert loaded.metrics == result.metrics
    pd.testing.assert_frame_equal(loaded.frame, result.frame, check_exact=True)
    assert loaded.spec.digest() == result.spec.digest()


def test_sweep_equals_the_cli_sweep_and_load_reads_it_back(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    cli("sweep", str(spec), "--out", str(tmp_path / "cli"), "-q", "--workers", "2")
    result = flatcli.sweep(spec, tmp_path / "api", workers=1, quiet=True)
    assert isinstance(result, api.SweepResult) and result.complete
    cli_trials = pd.read_parquet(tmp_path / "cli" / "trials.parquet")
    pd.testing.assert_frame_equal(result.trials, cli_trials, check_exact=True)
    pd.testing.assert_frame_equal(result.summary,
                                  pd.read_parquet(tmp_path / "cli" / "summary.parquet"),
                                  check_exact=True)
    counts = json.loads((tmp_path / "cli" / "run.json").read_text())["status_counts"]
    assert result.metrics["trials"] == result.metrics["finished"] == 120
    for status, n in counts.items():
        assert result.metrics[status] == n
    assert result.simulated == 120 and result.wall_seconds is not None
    loaded = flatcli.load(tmp_path / "cli")
    assert isinstance(loaded, api.SweepResult)
    pd.testing.assert_frame_equal(loaded.trials, cli_trials, check_exact=True)
    assert loaded.summary_text == result.summary_text
    # its figures as matplotlib Figures, against a grid key of one's choosing
    fig = loaded.plot("singular", x="track.sensor_noise")
    assert isinstance(fig, Figure)
    assert {ax.get_xlabel() for ax in fig.axes if ax.get_xlabel()} == {
        "track.sensor_noise [rad]"}
    assert set(loaded.figures()) == {"errors", "singular", "margin", "momentum"}
    paths = loaded.save_figures(fmt="svg", dpi=60)
    assert next(p.name for p in paths) == "sweep_errors.svg"
    manifest = json.loads((tmp_path / "cli" / "sweep.json").read_text())
    assert "sweep_errors.svg" in manifest["files"]  # flatcli's: --force may remove it
    with pytest.raises(flatcli.FlatcliError, match="plot: expected one of"):
        loaded.plot("pie")


def test_results_draw_themselves_as_figures(tmp_path: Path) -> None:
    planned = flatcli.plan()
    fig = planned.plot()
    assert isinstance(fig, Figure) and fig.get_suptitle().startswith("plan 'paper_example'")
    tracked = flatcli.track(overrides={"track.kp": [100, 110], "track.kv": [10, 13]},
                            quiet=True)
    directory = tracked.save(tmp_path / "t")
    loaded = flatcli.load(directory)
    assert isinstance(loaded, api.TrackResult) and loaded.run is None
    again = loaded.plot()  # drawn from track.parquet
    y1 = next(ln for ln in again.axes[0].get_lines() if ln.get_label() == "$y_1$")
    assert list(y1.get_ydata()) == list(loaded.frame["y1"])
    assert tracked.trajectory(0.0).theta.tolist() == planned.trajectory(0.0).theta.tolist()


def test_saved_plan_loads_through_latest(tmp_path: Path) -> None:
    result = flatcli.plan({"name": "nb", "plan": {"duration": 2.5}})
    first = result.save(root=tmp_path)
    second = flatcli.plan({"name": "nb"}).save(root=tmp_path)
    assert first.parent == second.parent == tmp_path / "nb" and first != second
    loaded = flatcli.load(tmp_path / "nb")  # a name's directory loads its latest run
    assert isinstance(loaded, api.PlanResult) and loaded.directory == tmp_path / "nb" / "latest"
    assert loaded.spec.plan.duration == 2.0
    pd.testing.assert_frame_equal(flatcli.load(first).frame, result.frame, check_exact=True)


def test_a_spec_can_be_given_five_ways(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('name = "x"\n[track]\nkp = [1, 2]\n')
    digests = {
        api.load_spec(path).digest(),
        api.load_spec(str(path)).digest(),
        api.load_spec({"name": "x", "track": {"kp": [1, 2]}}).digest(),
        api.load_spec({"name": "x", "track.kp": [1, 2]}).digest(),
        api.load_spec(None, ["name=x", "track.kp=[1,2]"]).digest(),
        api.load_spec(api.load_spec(), {"name": "x", "track.kp": [1, 2]}).digest(),
    }
    assert len(digests) == 1


def test_bad_input_raises_the_cli_message() -> None:
    with pytest.raises(flatcli.FlatcliError, match=r"unknown key 'plan\.duraton' \(did you "
                                                   r"mean 'plan\.duration'\?\)"):
        flatcli.plan(overrides={"plan.duraton": 3})
    with pytest.raises(TypeError, match="spec: expected a path"):
        flatcli.plan(3)  # type: ignore[arg-type]
    with pytest.raises(flatcli.FlatcliError, match="holds no flatcli run"):
        flatcli.load(Path(__file__).parent)


def test_load_of_an_interrupted_sweep(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 50"))
    full = flatcli.sweep(spec, tmp_path / "full", workers=1, quiet=True)
    trials, summary = full.trials, full.summary
    sweep_without_final_tables(str(spec), "--out", str(tmp_path / "d"), "--workers", "1")
    chunks = sorted((tmp_path / "d" / "trials").glob("chunk-*.parquet"))
    assert len(chunks) == 4  # 2 cells of 50 trials in chunks of 25
    manifest = json.loads((tmp_path / "d" / "sweep.json").read_text())
    last = manifest["cells"][manifest["grid_cells"][1]]["chunks"][-1]
    (tmp_path / "d" / "trials" / last).unlink()  # cell 1's second chunk never finished
    partial = flatcli.load(tmp_path / "d")
    assert isinstance(partial, api.SweepResult) and not partial.complete
    assert partial.metrics["trials"] == 100 and partial.metrics["finished"] == 75
    pd.testing.assert_frame_equal(partial.trials, trials.iloc[:75], check_exact=True)
    assert partial.summary["trials"].tolist() == [50, 25]
    pd.testing.assert_series_equal(partial.summary.iloc[0], summary.iloc[0],
                                   check_exact=True)
    assert "75 of 100 trials finished (75%), 3 of 4 chunks; 25 trials missing" in \
        partial.summary_text


def test_the_version_is_the_installed_distributions_and_costs_no_metadata_search() -> None:
    """flatcli.__version__ is a constant that pyproject.toml reads; the referee is the
    metadata pip wrote for the installed distribution. Neither ``import flatcli`` nor
    ``flatcli --version`` loads importlib.metadata (its import and the search of sys.path for
    the distribution cost about 20 ms of every process)."""
    from importlib.metadata import version

    assert flatcli.__version__ == version("flatcli")
    code = ("import sys, flatcli\n"
            "from flatcli.cli import main\n"
            "try:\n"
            "    main(['--version'])\n"
            "except SystemExit:\n"
            "    pass\n"
            "print('importlib.metadata' in sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert done.stdout.splitlines() == [f"flatcli, version {flatcli.__version__}", "False"]


def test_import_flatcli_is_light_and_its_functions_stay_functions_whatever_is_imported() -> None:
    """No submodule is named like a public function (the sweeps' package is
    flatcli.montecarlo, the run directories' module flatcli.rundirs), so importing either, before
    or after the API, never rebinds flatcli.sweep or flatcli.runs to a module."""
    code = (
        "import sys, types, flatcli\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
        "import flatcli.montecarlo.layout, flatcli.rundirs\n"
        "names = ('sweep', 'runs', 'plan', 'check')\n"
        "print([isinstance(getattr(flatcli, n), types.FunctionType) for n in names])\n"
        "flatcli.check({'sweep': {'trials': 2}}, calibrate=False)\n"
        "import flatcli.montecarlo.runner, flatcli.catalog\n"
        "print([isinstance(getattr(flatcli, n), types.FunctionType) for n in names])\n"
        "import flatcli.api as api\n"
        "print(flatcli.sweep is api.sweep and flatcli.runs is api.runs)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split("\n")
    assert out[0] == "[]"
    assert out[1] == out[2] == "[True, True, True, True]"
    assert out[3] == "True"


#: Maneuvers around the paper's (Sec. VI: th(0) = (1.8, 1, 0), th(2) = (1.2, 2, 0),
#: th1'(0) = 0.1, th1'(2) = 0.5), each with its own ends and end rates.
MANY_START = [[1.8, 1.0, 0.0], [1.7, 1.1, 0.05], [1.9, 0.9, -0.1], [1.8, 1.2, 0.0]]
MANY_GOAL = [[1.2, 2.0, 0.0], [1.25, 1.9, 0.1], [1.1, 2.1, 0.0], [1.3, 2.0, -0.05]]
MANY_START_RATE = [0.1, 0.12, 0.08, 0.1]
MANY_GOAL_RATE = [0.5, 0.45, 0.55, 0.5]


def test_plan_many_gives_the_plans_flatcli_plan_gives_one_at_a_time() -> None:
    """Within one process, to the bit: the batch's coefficients, samples (the batch's arrays
    and each maneuver's own), frame, metrics and spec against flatcli.plan of each."""
    batch = flatcli.plan_many(start=MANY_START, goal=MANY_GOAL, start_rate=MANY_START_RATE,
                              goal_rate=MANY_GOAL_RATE)
    assert len(batch) == 4
    fields = ("theta", "theta_dot", "u_dot", "y", "y_dot", "y_ddot", "margin", "momentum")
    for i in range(len(batch)):
        one = flatcli.plan(overrides={"plan.start": MANY_START[i], "plan.goal": MANY_GOAL[i],
                                      "plan.start_rate": MANY_START_RATE[i],
                                      "plan.goal_rate": MANY_GOAL_RATE[i]})
        assert one.plan is not None and one.samples is not None
        mine = batch[i]
        assert mine.spec == one.spec
        assert (mine.plan.trajectory.coefficients == one.plan.trajectory.coefficients).all()
        assert (batch.plan.trajectory.coefficients[i] == one.plan.trajectory.coefficients).all()
        for name in fields:
            assert (getattr(batch.samples, name)[i] == getattr(one.samples, name)).all(), name
        pd.testing.assert_frame_equal(mine.frame, one.frame, check_exact=True)
        assert mine.metrics == one.metrics
        assert {k: v[i] for k, v in batch.metrics.items()} == one.metrics
    same = flatcli.plan_many(start=MANY_START[1], goal=MANY_GOAL)  # one start for all
    repeated = flatcli.plan_many(start=[MANY_START[1]] * 4, goal=MANY_GOAL)
    assert len(same) == 4
    assert (same.plan.trajectory.coefficients == repeated.plan.trajectory.coefficients).all()


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"start": [[1.8, 1.0]]}, "plan_many: start: expected shape (M, 3) or (3,) for a robot of "
                              "2 joints, got (1, 2)"),
    ({"start": MANY_START, "goal": MANY_GOAL[:3]},
     "plan_many: start, goal, start_rate and goal_rate: different numbers of maneuvers "
     "(start 4, goal 3)"),
    ({"goal_rate": [0.5, float("nan")]}, "plan_many: goal_rate: not finite (maneuver 1)"),
    ({"start_rate": [0.1, 0.0]}, "plan_many: maneuver 1: plan.start_rate: must be != 0"),
    ({"start": [[1.8, 1.0, 0.0], [1.8, 0.0, 0.0]]}, "plan_many: maneuver 1: plan.start[1] = 0"),
    ({"start": "north"}, "plan_many: start: expected numbers, got str"),
    ({"start": np.zeros((0, 3))}, "plan_many: no maneuvers (M = 0)"),
])
def test_plan_many_refuses_bad_input_naming_the_argument(kwargs: dict[str, object],
                                                         message: str) -> None:
    with pytest.raises(flatcli.FlatcliError) as caught:
        flatcli.plan_many(**kwargs)  # type: ignore[arg-type]
    assert str(caught.value).startswith(message) and "\n" not in str(caught.value)


def test_plan_many_plans_the_papers_robot_and_no_optimised_plans() -> None:
    with pytest.raises(flatcli.FlatcliError, match=r"plan_many: plan\.optimize\.objective is set"):
        flatcli.plan_many(overrides={"plan.optimize.objective": "energy"})
    with pytest.raises(flatcli.FlatcliError, match="plan_many: the robot has 3 joints"):
        flatcli.plan_many(overrides={"robot": "chain4"})
