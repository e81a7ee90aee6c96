"""``make reproduce``'s section "Optimised plans": the paper's maneuver planned by the
optimiser (least energy, least peak rate, largest margin, under limits), beside the paper's
cubic; each tracked with both gain readings; the least margin the swapped gains can track.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from flatcli import api
from flatcli.core.optimize import required_fold
from flatcli.core.plan.planning import Plan, PlanSamples
from flatcli.report import FigureFile, finish_grid, fmt, new_figure, plan_summary, styled, table
from flatcli.report.figures import PAGE_WIDTH
from flatcli.reproduce.findings import (
    OPTIMIZED_PLANS,
    margin_ladder,
    paper_plan,
    track_plans,
    tracked_plans_table,
)
from flatcli.reproduce.sections import Context, Outcome, Section

#: Samples on which each plan's numbers are taken.
FINE = 4001


def run(context: Context) -> Outcome:
    """The optimised plans beside the paper's cubic: a figure and tables (docs/spec.md,
    ``[plan.optimize]``)."""
    base, out, steps = context.base, context.out, context.steps
    rows: list[list[Any]] = []
    curves: list[tuple[str, PlanSamples]] = []
    cubic = paper_plan(base)
    entries: list[tuple[str, Plan, str]] = [("paper's cubic, th1' = 0.1, 0.5", cubic, "-")]
    for label, overrides in steps.each("optimising", OPTIMIZED_PLANS):
        planned = api.plan(base.with_overrides(overrides))
        assert planned.plan is not None and planned.optimization is not None
        entries.append((label, planned.plan, f"{planned.optimization['iterations']} it."))
    for label, plan, note in entries:
        samples = plan.sample(plan.grid(FINE))
        s = plan_summary(plan, samples)
        rows.append([label, s["input_energy"], max(s["peak_rate1"], s["peak_rate2"]),
                     s["max_abs_theta2"], s["min_margin"], s["max_abs_momentum"], note])
        curves.append((label, samples))
    fold = required_fold(cubic.model, base.plan.start, base.plan.goal)  # type: ignore[arg-type]
    steps.step("tracking every plan with both gain readings")
    tracked = tracked_plans_table(track_plans(base, [
        ("paper's cubic", {}), *((label, overrides) for label, overrides in OPTIMIZED_PLANS)
    ]))
    steps.step("the least margin the swapped gains track (a ladder of optimised plans)")
    ladder_table, ladder_sentence = margin_ladder(base)
    plot_optimized(curves[:2], out / context.figures.name("fig_optimized_plan"),
                   context.figures)
    lines = [
        "",
        "## Optimised plans",
        "",
        "Same maneuver and robot (derived model), with the free end rates th1'(0), th1'(T) and "
        "the coefficients of a quintic B-spline basis (12 per output) chosen by the optimiser "
        "(`flatcli plan --optimize OBJECTIVE`), subject to a signed singularity margin "
        "(default 0.02 rad/s) so the plan never crosses the singular set. Every plan is "
        "exactly momentum-consistent: H is from the full kinematics on "
        f"{FINE} samples. Energy = integral of th1'^2 + th2'^2 [rad^2/s].",
        "",
        table(["plan", "energy", "peak rate [rad/s]", "max abs(th2) [rad]",
               "min margin [rad/s]", "max abs(H)", "solver"], rows, 4),
        "",
        f"On this maneuver th2 must reach at least {fold:.3f} rad on any flat plan whose th1 "
        "moves monotonically (a margin of one sign, as every plan flatcli accepts has): "
        "momentum conservation then fixes the integral of h(th1) th2 over th1 "
        "(`required_fold`), so a limit that keeps link 2 from folding further than that is "
        "infeasible, and flatcli says so. The bound is for monotone th1 only: a th1 path that "
        "loops back (crossing th1' = 0, which the flat map cannot do in one plan) can fold "
        "link 2 far less (0.71 rad was found in review).",
        "",
        f"Figure: `{context.figures.name('fig_optimized_plan')}`.",
        "",
        "### The optimised plans in closed loop",
        "",
        "Each plan tracked from the paper's initial state th(0) = (1.96, 0.8, -0.1) with "
        "u1(0) = the plan's own th1'(0), with the gains as printed and swapped (plant = the "
        "nominal robot, adaptive integrator):",
        "",
        tracked,
        "",
        ladder_sentence,
        "",
        ladder_table,
    ]
    energy = rows[1][1]
    headline = [f"the least-energy flat plan needs {fmt(energy, 4)} rad^2/s against the "
                f"paper's cubic's {fmt(rows[0][1], 4)}; th2 must fold at least {fold:.3f} rad "
                "on any plan with monotone th1"]
    return Outcome(lines, headline, ("fig_optimized_plan.*",))


SECTION = Section("optimized", "optimised plans beside the paper's cubic, in closed loop",
                  lambda context: {"spec": context.base.tree}, run)


@styled
def plot_optimized(curves: list[tuple[str, PlanSamples]], path: Path, figures: FigureFile
                   ) -> None:
    """The paper's cubic (dashed) beside the least-energy flat plan (solid): angles, the
    rates of joints 2 and 1, and the singularity margin."""
    fig = new_figure(PAGE_WIDTH, 4.6)
    ax = fig.subplots(2, 2, sharex=True)
    for i, (label, samples) in enumerate(curves):
        style = "--" if i == 0 else "-"
        name = label.split(",")[0]
        for j in range(3):
            ax[0, 0].plot(samples.t, samples.theta[:, j], style, color=f"C{j}",
                          label=f"$\\theta_{j}$ ({name})")
        ax[0, 1].plot(samples.t, samples.theta_dot[:, 2], style, color="C2",
                      label=f"$\\theta_2'$ ({name})")
        ax[1, 0].plot(samples.t, samples.theta_dot[:, 1], style, color="C1",
                      label=f"$\\theta_1'$ ({name})")
        ax[1, 1].semilogy(samples.t, samples.margin, style, color="C3",
                          label=f"margin ({name})")
    ax[0, 0].set_ylabel("$\\theta_i$ [rad]")
    ax[0, 1].set_ylabel("$\\theta_2'$ [rad/s]")
    ax[0, 1].set_yscale("symlog", linthresh=5)
    ax[1, 0].set_ylabel("$\\theta_1'$ [rad/s]")
    ax[1, 1].set_ylabel("margin $|\\sin\\theta_1\\,\\theta_1'|$ [rad/s]")
    finish_grid(fig, ax, "The paper's cubic (dashed) and the least-energy flat plan (solid)",
                path, file=figures)
