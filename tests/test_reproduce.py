"""make reproduce, end to end on a small study."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from flatcli.cli import main

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "paper_montecarlo.toml"


def test_reproduce_writes_figures_tables_and_report(tmp_path: Path) -> None:
    out = tmp_path / "paper"
    result = CliRunner().invoke(main, ["reproduce", "--out", str(out), "--montecarlo",
                                       str(CONFIG), "--set", "sweep.trials=8", "-q"])
    assert result.exit_code == 0, result.output
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
    assert "Only the **swapped** reading matches" in report
    assert "## Monte Carlo study" in report and "144 trials" in report
    # the optimised plan beside the cubic (energy at most a third of the cubic's 101.19,
    # tests/test_optimize.py CUBIC_ENERGY)
    row = next(line for line in report.splitlines() if line.startswith("| least energy "))
    assert float(row.split("|")[2]) < 101.19 / 3
    # the actuators: the study (sweep.trials applies to it too) and its figure
    assert "## What the maneuver asks of the actuators" in report and "**Finding.**" in report
    assert "120 cells of 8 trials" in report
    assert (out / "fig_actuators.png").exists() and (out / "actuators/cells.parquet").exists()
