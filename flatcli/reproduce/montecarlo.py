"""``make reproduce``'s section "Monte Carlo study": the paper's plan and feedback from random
initial-state errors, with both gain readings, on plants whose counterweight misses its joint
(``flatcli/data/paper_montecarlo.toml``, or the spec given by ``--montecarlo``)."""

from __future__ import annotations

import pandas as pd

from flatcli.report import Progress, fmt, plot_sweep
from flatcli.reproduce.findings import study_findings
from flatcli.reproduce.sections import Context, Outcome, Section
from flatcli.spec import load_spec

#: The directory of the study, inside the output directory.
DIRECTORY = "montecarlo"


def run(context: Context) -> Outcome:
    """The study into OUT/montecarlo (its figures too) and the section's lines."""
    from flatcli.sweep import run_sweep

    assert context.montecarlo is not None
    spec = load_spec(context.montecarlo, context.sets)
    directory = context.out / DIRECTORY
    context.steps.step(f"{spec.name}: the sweep")
    result = run_sweep(spec, directory, "local", context.workers, None, force=True,
                       progress=Progress(spec.name, context.quiet))
    context.steps.step("its figures")
    plot_sweep(directory, context.figures)
    summary = pd.read_parquet(directory / "summary.parquet")
    trials = int(summary["trials"].sum())
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
        "the adaptive integrator; only trials resolved to the end enter the error "
        "statistics. Files: `montecarlo/` (trials.parquet, summary.md) and "
        f"`montecarlo/sweep_*.{context.figures.format}`.",
        "",
        *study_findings(summary, directory / "trials.parquet"),
        "",
        result.summary_text,
    ]
    resolved = int(summary["resolved"].sum())
    lost = int((summary["diverged"] + summary["unresolved"]).sum())
    headline = [f"{trials} trials: {resolved} resolved to the end, {lost} lost (diverged or "
                f"unresolved); median final y error per cell "
                f"{fmt(summary['err_y_final_median'].min(), 2)} to "
                f"{fmt(summary['err_y_final_median'].max(), 2)} rad"]
    return Outcome(lines, headline, (f"{DIRECTORY}/**/*",))


def inputs(context: Context) -> dict[str, object]:
    """The study's resolved spec (its file with the --set items) and the file's name."""
    assert context.montecarlo is not None
    return {"spec": load_spec(context.montecarlo, context.sets).tree,
            "name": context.montecarlo.name}


SECTION = Section("montecarlo", "the Monte Carlo study of the paper's controller", inputs, run,
                  applies=lambda context: context.study)
