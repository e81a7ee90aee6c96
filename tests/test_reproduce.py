"""make reproduce, end to end on a small study; its inputs checked before anything is
written; its study spec shipped with the package."""

from __future__ import annotations

import math
import tomllib
from fnmatch import fnmatch
from pathlib import Path

import pytest
from click.testing import CliRunner

from flatcli.cli import REPRODUCE_SECTIONS, main
from flatcli.reproduce import SECTION_NAMES, STUDY_SPEC, asbuilt, search, within
from flatcli.reproduce.actuators import STUDY
from flatcli.reproduce.chains import CHAIN_SPECS

ROOT = Path(__file__).resolve().parents[1]


def test_reproduce_writes_figures_tables_and_report(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # any directory: the study's spec comes with the package
    # the as-built section's tolerance maps on a few placements and masses (its 37 cells per
    # pipeline, each designing its LQR, are make reproduce's; the wiring is the same)
    monkeypatch.setattr(asbuilt, "ALONG_MM", (0.0, 3.0))
    monkeypatch.setattr(asbuilt, "ACROSS_MM", (0.0, 1.0))
    monkeypatch.setattr(asbuilt, "MASS_PERCENT", (-5.0, 0.0))
    # the design search: two generations, its re-measurements small
    monkeypatch.setattr(search, "BUDGET", 50)
    monkeypatch.setattr(search, "REMEASURE_TRIALS", 12)
    monkeypatch.setattr(search, "OFFSET_TRIALS", 6)
    # within the actuators: two rate limits (each limit the cubic exceeds is a re-plan; the
    # six of make reproduce's grid are wired alike)
    study_spec = within.study_spec
    monkeypatch.setattr(within, "study_spec", lambda context: study_spec(context).with_overrides(
        {"sweep.grid": {"track.rate_limit": [math.inf, 4.0],
                        "track.controller": ["flat", "mpc"]}}))
    # and on the dynamic plant, one torque limit below the cubic's 32.6 N m (a re-plan)
    monkeypatch.setattr(within, "TORQUE_LIMITS", (math.inf, 10.0))
    result = CliRunner().invoke(main, ["reproduce", "--out", "paper", "--set",
                                       "sweep.trials=8", "-q"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "paper"
    for name in ("fig2_flat_outputs.png", "fig3_angles.png", "fig4_feedback_printed.png",
                 "fig4_feedback_swapped.png", "fig_optimized_plan.png", "REPORT.md",
                 "montecarlo/trials.parquet",
                 "montecarlo/sweep_singular.png"):
        assert (out / name).exists(), name
    report = (out / "REPORT.md").read_text()
    # the paper's printed values and the corrected ones (README, *The physics, and the
    # paper's errata*)
    assert "| y2'(0) [rad/s]" in report and "-0.065 " in report and "-0.0668801" in report
    assert "-0.3512 " in report and "-0.343458" in report
    assert "The swapped reading is the one that fits Fig. 4" in report
    assert "**but only in the flat outputs**" in report  # and the joint angles swing
    assert "### The optimised plans in closed loop" in report
    assert "whose th1 moves monotonically" in report
    assert "## Monte Carlo study" in report and "144 trials" in report
    # the optimised plan beside the cubic (energy at most a third of the cubic's 101.19,
    # tests/test_optimize_api.py CUBIC_ENERGY)
    row = next(line for line in report.splitlines() if line.startswith("| least energy "))
    assert float(row.split("|")[2]) < 101.19 / 3
    # the actuators: the study (sweep.trials applies to it too) and its figure
    assert "## What the maneuver asks of the actuators" in report and "**Finding.**" in report
    assert "120 cells of 8 trials" in report
    assert (out / "fig_actuators.png").exists() and (out / "actuators/cells.parquet").exists()
    # within the actuators: both controllers over the rate limits, by outcome, and the figure
    assert "## Within the actuators: the paper's feedback against the MPC" in report
    assert "| 4 | MPC | re-planned | " in report and "| none | paper's feedback | - | " in report
    assert "With no limit and initial errors of std 20 mrad" in report
    assert (out / "fig_within.png").exists() and (out / "within/grid/trials.parquet").exists()
    assert "**On the dynamic plant, within the torque limit.**" in report
    assert "| 10 | MPC | re-planned | " in report
    assert (out / "within/dynamic/trials.parquet").exists()
    # beyond three links: both robots, the closed loop on both plants, the studies
    assert "## Beyond three links" in report and "| chain6 | dynamic " in report
    assert "#### chain4: 32 trials" in report and "#### chain6: 32 trials" in report
    for name in ("fig_chains.png", "chains/chain4/plan.parquet",
                 "chains/chain6/track_dynamic.parquet", "chains/chain6/montecarlo/trials.parquet"):
        assert (out / name).exists(), name
    # the capture maneuver among obstacles (docs/tasks.md): its table and filmstrip
    assert "every link 0.01 m clear of three discs, proven over all of [0, T]" in report
    assert (out / "fig_capture.png").exists() and (out / "capture/plan/plan.parquet").exists()
    assert (out / "fig_workspace.png").exists()
    assert (out / "capture/workspace/workspace.parquet").exists()
    # robots as built: the goal's table (Fig. 4's start and the three cells, the same trials
    # in both pipelines), the maps, the figure, the exact plans' momentum
    assert "## Robots as built" in report
    fig4 = next(line for line in report.splitlines()
                if line.startswith("| Fig. 4's start (1.96, 0.8, -0.1) | "))
    assert "| 1 / 1 |" in fig4 and fig4.count("reached") + fig4.count("missed") == 2
    # conclusions by outcome (issue 39): every study's reached fraction, in its section and
    # its headline; the actuators' cells say over which trials; the capture pushed collides
    assert report.count("trials reached (") >= 5  # montecarlo, actuators, 2 x as built, chains
    headlines = report.split("## Headlines")[1].split("\n## ")[0]
    for section in ("montecarlo", "actuators", "within", "asbuilt", "chains"):
        assert any("trials reached (" in x for x in headlines.splitlines()
                   if x.startswith(f"- **{section}**")), section
    assert "/8 reached; p95 " in report
    assert "from [1.9, 1.0, 0.0] collided" in headlines
    assert "th(0) errors of std 0.05 rad | " in report and "0 crossings in 24 trials" in report
    assert "of 4 counterweight placements" in report and "| -5 | " in report
    assert "**Counterweight designer**" in report and "| least inertia | 0.15 |" in report
    for name in ("fig_asbuilt.png", "asbuilt/goal_asbuilt/trials.parquet",
                 "asbuilt/goal_ideal/trials.parquet", "asbuilt/placement_asbuilt/trials.parquet",
                 "asbuilt/mass_ideal/trials.parquet"):
        assert (out / name).exists(), name
    # searching the design: the search, its files, both designs re-measured on fresh seeds
    assert "## Searching the design" in report and "50 candidates in 2 generations" in report
    assert "on fresh seeds (sweep.seed = 4002, 12 trials each, the same offset)" in report
    assert "| -1          | " in report or "| -1 " in report
    for name in ("search/search.parquet", "search/best_robot.toml", "search/best_robot.urdf",
                 "search/convergence.png", "search/remeasure_best/trials.parquet",
                 "search/remeasure_paper/trials.parquet"):
        assert (out / name).exists(), name
    assert 'robot = "paper"' in (out / "search/remeasure_paper.toml").read_text()
    assert "Made with `flatcli reproduce --out paper --set sweep.trials=8 -q`" in report
    assert "## Headlines" in report

    # a second run reuses every section (nothing changed) and says so; the report's sections
    # are the same
    again = CliRunner().invoke(main, ["reproduce", "--out", "paper", "--set", "sweep.trials=8"])
    assert again.exit_code == 0, again.output
    assert "9 sections (0 computed, 9 reused)" in again.output
    assert again.output.count("reused: unchanged since") == 9
    assert "- paper: the printed b1 is wrong" in again.output  # the headlines, not the report
    assert len(again.output.splitlines()) < 40
    body = report.split("## How this report was made")[0]
    assert (out / "REPORT.md").read_text().split("## How this report was made")[0] == body

    # a file a section wrote is gone: that section alone is computed again
    (out / "fig2_flat_outputs.png").unlink()
    third = CliRunner().invoke(main, ["reproduce", "--out", "paper", "--set", "sweep.trials=8"])
    assert third.exit_code == 0, third.output
    assert "9 sections (1 computed, 8 reused)" in third.output
    assert "fig2_flat_outputs.png changed or is missing" in third.output
    assert (out / "fig2_flat_outputs.png").exists()

    # --only computes the named section (with --force even if unchanged) and keeps the rest;
    # another --set changes the studies' inputs, which --only then leaves out of the report
    only = CliRunner().invoke(main, ["reproduce", "--out", "paper", "--set", "sweep.trials=8",
                                     "--only", "optimized", "--force"])
    assert only.exit_code == 0, only.output
    assert "9 sections (1 computed, 8 reused)" in only.output and "(--force)" in only.output
    other = CliRunner().invoke(main, ["reproduce", "--out", "paper", "--set", "sweep.trials=9",
                                      "--only", "paper"])
    assert other.exit_code == 0, other.output
    assert "3 sections (0 computed, 3 reused)" in other.output  # paper, optimized, capture
    assert "flatcli reproduce --only montecarlo" in (out / "REPORT.md").read_text()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--set", "sweep.trials=0"], "sweep.trials: must be >= 1, got 0"),
        # found only when the study's cells are planned (the paper's own runs come first)
        (["--set", "robot.com=[0.1,0.1,0.003]"], "track.controller: \"flat\" tracks the "
                                                  "closed-form flat outputs"),
        (["--workers", "0"], "--workers: must be >= 1, got 0"),
        (["--no-montecarlo", "--set", "sweep.trials=3"], "--set: changes the Monte Carlo"),
        (["--montecarlo", "missing.toml"], "spec file not found: missing.toml"),
        (["--only", "figures"], "Invalid value for '--only'"),
        (["--no-montecarlo", "--only", "montecarlo"], "skipped by --no-montecarlo"),
        (["--no-montecarlo", "--only", "asbuilt"], "--only asbuilt: the study is skipped"),
        (["--no-montecarlo", "--only", "search"], "--only search: the study is skipped"),
    ],
)
def test_bad_input_is_refused_before_anything_is_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], message: str) -> None:
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(main, ["reproduce", "--out", "paper", *args])
    assert result.exit_code == 2, result.output
    assert result.output.startswith("error: ") and result.output.count("\n") == 1
    assert message in result.output
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("spec", [STUDY_SPEC, STUDY, *CHAIN_SPECS, asbuilt.GOAL_SPEC,
                                  search.SEARCH_SPEC, within.STUDY])
def test_the_study_specs_ship_as_package_data(spec: Path) -> None:
    assert spec.is_file() and spec.parent.name == "data"
    assert spec.parent.parent == ROOT / "flatcli"
    assert (ROOT / "configs" / spec.name).resolve() == spec.resolve()  # configs/ links to it
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    patterns = pyproject["tool"]["setuptools"]["package-data"]["flatcli"]
    assert any(fnmatch(f"data/{spec.name}", p) for p in patterns)


def test_the_command_line_knows_every_section() -> None:
    assert REPRODUCE_SECTIONS == SECTION_NAMES
