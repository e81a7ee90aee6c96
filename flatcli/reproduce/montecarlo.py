"""``make reproduce``'s section "Monte Carlo study": the paper's plan and feedback from random
initial-state errors, with both gain readings, on plants whose counterweight misses its joint
(``flatcli/data/paper_montecarlo.toml``, or the spec given by ``--montecarlo``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatcli.core.loop.metrics import RESOLVED
from flatcli.report import fmt, plot_sweep
from flatcli.reproduce.findings import reached_text, study_findings
from flatcli.reproduce.sections import Context, Outcome, Section
from flatcli.spec import load_spec

#: The directory of the study, inside the output directory.
DIRECTORY = "montecarlo"


def run(context: Context) -> Outcome:
    """The study into OUT/montecarlo (its figures too) and the section's lines."""
    from flatcli import api

    assert context.montecarlo is not None
    spec = load_spec(context.montecarlo, context.sets)
    directory = context.out / DIRECTORY
    context.steps.step(f"{spec.name}: the sweep")
    result = api.sweep(spec, directory, workers=context.workers, force=True,
                       quiet=context.quiet)
    context.steps.step("its figures")
    plot_sweep(directory, context.figures)
    summary = pd.read_parquet(directory / "summary.parquet")
    trials = int(summary["trials"].sum())
    outcomes = pd.read_parquet(directory / "trials.parquet", columns=["outcome"])["outcome"]
    lines = [
        "",
        "## Monte Carlo study",
        "",
        f"`{context.montecarlo.name}`: the paper's plan and feedback from random initial-state "
        "errors of growing size (std of th(0)), with the gains as printed and swapped, on "
        "plants whose counterweight misses joint 2 by d2 = 0, 1, 5 mm (the controller "
        "believes d2 = 0: such a plant is still flat, being controllable and driftless of "
        "codimension one, but the paper's closed-form outputs no longer apply to it, so "
        f"the controller's model is wrong). {trials} trials in {result.wall_seconds:.1f} s on "
        "the adaptive integrator. Whether the robot did its job is each trial's outcome "
        "(reached: every angle within track.goal_tolerance of the goal at T; missed; lost), "
        "counted over all trials; the error statistics named *resolved* are over the trials "
        "resolved to the end only, and say so. Files: `montecarlo/` (trials.parquet, "
        f"summary.md) and `montecarlo/sweep_*.{context.figures.format}`.",
        "",
        f"**Outcome**: {reached_text(outcomes)}.",
        "",
        *study_findings(summary, directory / "trials.parquet"),
        *reference_lines(summary, directory / "trials.parquet", spec.sweep.verify),
        "",
        result.summary_text,
    ]
    resolved = int(summary["resolved"].sum())
    lost = int((summary["diverged"] + summary["unresolved"]).sum())
    headline = [f"{reached_text(outcomes)}; {resolved} resolved to the end, {lost} diverged or "
                f"unresolved; median final y error per cell over its resolved trials "
                f"{fmt(summary['err_y_final_median'].min(), 2)} to "
                f"{fmt(summary['err_y_final_median'].max(), 2)} rad"]
    return Outcome(lines, headline, (f"{DIRECTORY}/**/*",))


def reference_lines(summary: pd.DataFrame, trials: Path, verify: float) -> list[str]:
    """REPORT's sentence on the trials ``sweep.verify`` re-ran under the reference integrator
    (none without ``sweep.verify``), with the trial that differs most from it (its peak joint
    rate and its own error estimate at T, from ``trials``)."""
    if "reference_checked" not in summary or not summary["reference_checked"].sum():
        return []
    checked = int(summary["reference_checked"].sum())
    share = checked / int(summary["trials"].sum())
    mismatches = int(summary["reference_status_mismatches"].sum())
    how = (f"{verify:g} of each cell's trials, rounded up" if verify < 1
           else f"{int(verify)} trials of each cell")
    text = (
        f"**Verified against DOP853** (rtol 1e-10; `sweep.verify = {verify:g}`: {how}) on "
        f"{checked} trials ({share:.2%}): {mismatches} ended with another status; over those "
        "both resolved to the end, the largest difference of the angles at any output sample "
        f"is {fmt(summary['reference_difference_max'].max(), 2)} rad (median per cell "
        f"{fmt(summary['reference_difference_median'].min(), 2)} to "
        f"{fmt(summary['reference_difference_median'].max(), 2)} rad).")
    frame = pd.read_parquet(trials, columns=["status", "reference_status",
                                             "reference_difference", "peak_rate",
                                             "err_estimate"])
    both = frame[frame["status"].isin(RESOLVED) & frame["reference_status"].isin(RESOLVED)]
    both = both[both["reference_difference"].notna()]
    if len(both):
        worst = both.iloc[int(np.argmax(both["reference_difference"].to_numpy(dtype=float)))]
        text += (f" That trial's joints peak at {fmt(worst['peak_rate'], 3)} rad/s, and its "
                 "error estimate at T is "
                 f"{fmt(worst['err_estimate'], 2)} rad")
        if worst["err_estimate"] < worst["reference_difference"] / 10:
            text += (": the difference is mid-course, where the state moves fast, and the "
                     "trial's end is far closer than that")
        text += "."
    return ["", text]


def inputs(context: Context) -> dict[str, object]:
    """The study's resolved spec (its file with the --set items) and the file's name."""
    assert context.montecarlo is not None
    return {"spec": load_spec(context.montecarlo, context.sets).tree,
            "name": context.montecarlo.name}


SECTION = Section("montecarlo", "the Monte Carlo study of the paper's controller", inputs, run,
                  applies=lambda context: context.study)
