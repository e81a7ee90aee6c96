"""``make reproduce``'s first section: the paper's example, as printed and corrected.

The paper's maneuver planned with the appendix's coefficients as printed and with flatcli's
derivation (Figs. 2 and 3), and tracked with both readings of the printed gains (Fig. 4);
the table of the paper's numbers beside flatcli's; which gain reading fits Fig. 4; the
constraint coefficients; the corrected plan's headline numbers. Every number is computed
here from the runs it writes into the output directory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from flatcli import api
from flatcli.api import TrackRun
from flatcli.core.plan.planning import Plan, PlanSamples
from flatcli.core.robots.params import constraint_coefficients
from flatcli.outputs import track_limits
from flatcli.report import (
    FigureFile,
    fmt,
    new_figure,
    plan_summary,
    plot_track,
    save_figure,
    styled,
    table,
    track_title,
)
from flatcli.report.figures import PAGE_WIDTH
from flatcli.reproduce.findings import GAIN_READINGS, gains_verdict
from flatcli.reproduce.sections import Context, Outcome, Section
from flatcli.storage import run_record, write_parquet

#: The paper's printed values (Franch et al. 2003, Sec. VI).
PAPER_Y2_DOT_START = -0.065
PAPER_Y2_DOT_GOAL = -0.3512
REPORT_TIMES = (0.5, 1.0, 2.0)
#: The constraint coefficients REPORT.md compares: as printed, and as derived (``robot.model``).
COMPARED_MODELS = ("paper", "derived")
#: The files this section writes (globs under the output directory).
FILES = ("plan_*.parquet", "track_*.parquet", "fig2_flat_outputs.*", "fig3_angles.*",
         "fig4_feedback_*.*")


@styled
def plan_figures(plans: dict[str, tuple[Plan, PlanSamples]], out: Path,
                 figures: FigureFile) -> None:
    """Fig. 2 (flat outputs) and Fig. 3 (angles) for both coefficient sets."""
    styles = {"derived": "-", "paper": "--"}
    fig = new_figure(PAGE_WIDTH / 2, 2.8)
    ax = fig.subplots()
    for model, (_, s) in plans.items():
        ax.plot(s.t, s.y[:, 0], styles[model], color="C0", label=f"$y_{{1d}}$ ({model})")
        ax.plot(s.t, s.y[:, 1], styles[model], color="C1", label=f"$y_{{2d}}$ ({model})")
    ax.set_xlabel("$t$ [s]")
    ax.set_ylabel("flat outputs $y_d$ [rad]")
    ax.legend()
    fig.suptitle("Fig. 2: planned flat outputs\n(cubic, $\\theta_1'(0)$ = 0.1, "
                 "$\\theta_1'(2)$ = 0.5 rad/s)")
    fig.tight_layout()
    save_figure(fig, out / figures.name("fig2_flat_outputs"), figures)

    fig = new_figure(PAGE_WIDTH / 2, 2.8)
    ax = fig.subplots()
    for model, (_, s) in plans.items():
        for i in range(3):
            ax.plot(s.t, s.theta[:, i], styles[model], color=f"C{i}",
                    label=f"$\\theta_{{{i}d}}$ ({model})")
    ax.set_xlabel("$t$ [s]")
    ax.set_ylabel("angles $\\theta_d$ [rad]")
    ax.legend(ncol=2)
    fig.suptitle("Fig. 3: planned angles\n(dashed: the paper's printed coefficients)")
    fig.tight_layout()
    save_figure(fig, out / figures.name("fig3_angles"), figures)


def errors_at(run: TrackRun, times: tuple[float, ...]) -> list[tuple[float, float, float]]:
    """(y1 - y1_ref, y2 - y2_ref, norm of th - th_ref) of a run at the given times."""
    cols = run.columns
    out = []
    for t in times:
        j = round(t / run.scenario.dt)
        e1 = float(cols["y1"][j] - cols["y1_ref"][j])
        e2 = float(cols["y2"][j] - cols["y2_ref"][j])
        eth = float(np.sqrt(sum((cols[f"theta{i}"][j] - cols[f"theta{i}_ref"][j]) ** 2
                                for i in range(3))))
        out.append((e1, e2, eth))
    return out


def paper_table(plans: dict[str, tuple[Plan, PlanSamples]],
                tracks: dict[tuple[str, str], TrackRun]) -> str:
    """Paper value vs flatcli with the paper's coefficients vs flatcli corrected."""
    rows: list[list[Any]] = []
    s_paper = plans["paper"][1]
    s_derived = plans["derived"][1]
    rows.append(["y2'(0) [rad/s]", PAPER_Y2_DOT_START, s_paper.y_dot[0, 1], s_derived.y_dot[0, 1]])
    rows.append(["y2'(2) [rad/s]", PAPER_Y2_DOT_GOAL, s_paper.y_dot[-1, 1],
                 s_derived.y_dot[-1, 1]])
    rows.append(["max abs H along the plan [kg m^2/s]", "0 (claimed)",
                 float(np.max(np.abs(s_paper.momentum))),
                 float(np.max(np.abs(s_derived.momentum)))])
    for reading in GAIN_READINGS:
        paper_err = {model: errors_at(tracks[(model, reading)], REPORT_TIMES)
                     for model in COMPARED_MODELS}
        for k, t in enumerate(REPORT_TIMES):
            def pair(e: tuple[float, float, float]) -> str:
                return f"({fmt(e[0], 3)}, {fmt(e[1], 3)})"
            rows.append([f"{reading} gains: y - y_ref at t = {t:g} s",
                         "Fig. 4 only: \"follows closely\"" if k == 0 else "-",
                         pair(paper_err["paper"][k]), pair(paper_err["derived"][k])])
    return table(["quantity", "paper", "flatcli, paper's coefficients", "flatcli, corrected"],
                 rows, 6)


def run(context: Context) -> Outcome:
    """Plans and closed-loop runs of the paper's example under both models and gains, their
    figures and the section's lines."""
    base, out, steps = context.base, context.out, context.steps
    plans: dict[str, tuple[Plan, PlanSamples]] = {}
    for model in COMPARED_MODELS:
        spec = base.with_overrides({"robot.model": model})
        planned = api.plan(spec)
        assert planned.plan is not None and planned.samples is not None
        plans[model] = (planned.plan, planned.samples)
        write_parquet(out / f"plan_{model}.parquet", planned.frame,
                      run_record("reproduce", spec.tree))
    figures = context.figures
    plan_figures(plans, out, figures)
    tracks: dict[tuple[str, str], TrackRun] = {}
    for model, reading in steps.each("closed loop", [(m, r) for m in COMPARED_MODELS
                                                    for r in GAIN_READINGS]):
        gains = GAIN_READINGS[reading]
        spec = base.with_overrides({"robot.model": model, **gains})
        tracked = api.track(spec, quiet=True)
        run_ = tracked.run
        assert run_ is not None
        tracks[(model, reading)] = run_
        write_parquet(out / f"track_{model}_{reading}.parquet", tracked.frame,
                      run_record("reproduce", spec.tree, metrics=run_.metrics))
        if model == "derived":
            plot_track(run_.columns, out / figures.name(f"fig4_feedback_{reading}"),
                       "Fig. 4: feedback from $\\theta(0)$ = (1.96, 0.8, -0.1), gains "
                       f"{reading}\n" + track_title(spec, run_.metrics),
                       track_limits(run_), figures)
    plan, samples = plans["derived"]
    summary = plan_summary(plan, samples)
    k_paper = constraint_coefficients(plan.robot.links, "paper")
    k_derived = constraint_coefficients(plan.robot.links, "derived")
    coeff_rows = [[name, getattr(k_paper, name), getattr(k_derived, name)]
                  for name in ("a0", "a1", "b0", "b1", "c0")]
    lines = [
        "## Paper vs flatcli",
        "",
        "\"paper's coefficients\" plans and controls with the appendix's coefficients as printed "
        "(`robot.model = \"paper\"`); \"corrected\" with flatcli's derivation "
        "(`robot.model = \"derived\"`, checked against a symbolic derivation of the "
        "angular momentum in the tests). The plant always obeys the correct physics; "
        "|H| is the angular momentum from the full link kinematics.",
        "",
        paper_table(plans, tracks),
        "",
        gains_verdict(tracks[("derived", "printed")], tracks[("derived", "swapped")]),
        "",
        "### Coefficients [kg^2 m^2]",
        "",
        table(["coefficient", "as printed", "derived"], coeff_rows, 6),
        "",
        "The printed b1 = -(m0 (l0 - d0)(m2 l1 + m1 d1) - m0 m2 d0 l1) carries a spurious "
        "term; the correct b1 = -m0 (l0 - d0)(m2 l1 + m1 d1). The paper's own boundary values "
        "were computed with it, which is why its plan does not conserve angular momentum.",
        "",
        "### The corrected plan",
        "",
        table(["quantity", "value", "unit"], [
            ["max abs(theta2)", summary["max_abs_theta2"], "rad"],
            ["peak abs(theta0'), abs(theta2')",
             f"{fmt(summary['peak_rate0'])}, {fmt(summary['peak_rate2'])}", "rad/s"],
            ["min margin abs(sin y1 * y1')", summary["min_margin"], "rad/s"],
            ["input energy (integral of th1'^2 + th2'^2)", summary["input_energy"], "rad^2/s"],
        ]),
        "",
        f"Figures: `{figures.name('fig2_flat_outputs')}`, `{figures.name('fig3_angles')}`, "
        f"`{figures.name('fig4_feedback_printed')}`, "
        f"`{figures.name('fig4_feedback_swapped')}`.",
    ]
    s_paper = plans["paper"][1]
    printed = tracks[("derived", "printed")].metrics
    swapped = tracks[("derived", "swapped")].metrics
    headline = [
        f"the printed b1 is wrong: y2'(0) = {fmt(samples.y_dot[0, 1], 4)} rad/s, not the "
        f"paper's {PAPER_Y2_DOT_START:g}; the paper's plan breaks momentum conservation by "
        f"{fmt(float(np.max(np.abs(s_paper.momentum))), 3)} kg m^2/s, the corrected one by "
        f"{fmt(float(np.max(np.abs(samples.momentum))), 2)}",
        f"the gains fit Fig. 4 only with kv and kp swapped: final y error "
        f"{fmt(swapped['err_y_final'], 2)} rad against {fmt(printed['err_y_final'], 2)} rad "
        "as printed",
    ]
    return Outcome(lines, headline, FILES)


SECTION = Section("paper", "the paper's example: Figs. 2-4, its numbers and the corrections",
                  lambda context: {"spec": context.base.tree}, run)
