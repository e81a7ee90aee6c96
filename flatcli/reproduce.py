"""``flatcli reproduce``: the paper's Figs. 2-4 and numbers, and the Monte Carlo study.

Writes into one directory (``runs/paper`` from ``make reproduce``): the figures, the plans
and closed-loop runs as Parquet, the sweep under ``montecarlo/``, and REPORT.md, whose every
number is computed here from those runs.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from flatcli import __version__
from flatcli.actuators import actuators_section
from flatcli.chains import chains_section
from flatcli.core.chainplan import Plan
from flatcli.core.model import constraint_coefficients
from flatcli.core.optimize import required_fold
from flatcli.core.planning import PlanSamples
from flatcli.experiment import (
    TrackRun,
    flat_plan_from,
    plan_and_optimization,
    plan_from,
    run_track,
)
from flatcli.findings import (
    GAIN_READINGS,
    gains_verdict,
    margin_ladder,
    study_findings,
    track_plans,
    tracked_plans_table,
)
from flatcli.outputs import plan_frame, track_frame, track_limits
from flatcli.report import (
    Progress,
    finish_grid,
    fmt,
    new_figure,
    plan_summary,
    plot_sweep,
    plot_track,
    save_figure,
    table,
)
from flatcli.spec import Spec, load_spec, resolve
from flatcli.storage import run_record, write_json, write_parquet, write_text

#: The Monte Carlo study's spec, shipped with flatcli (package data; configs/ links to it).
STUDY_SPEC = Path(str(resources.files("flatcli") / "data" / "paper_montecarlo.toml"))

#: The paper's printed values (Franch et al. 2003, Sec. VI).
PAPER_Y2_DOT_START = -0.065
PAPER_Y2_DOT_GOAL = -0.3512
REPORT_TIMES = (0.5, 1.0, 2.0)
#: The constraint coefficients REPORT.md compares: as printed, and as derived (``robot.model``).
COMPARED_MODELS = ("paper", "derived")


@dataclass
class Reproduction:
    """Everything REPORT.md is written from."""

    plans: dict[str, tuple[Plan, PlanSamples]]
    tracks: dict[tuple[str, str], TrackRun]
    sections: list[str]


def _say(quiet: bool, text: str) -> None:
    if not quiet:
        print(text, flush=True)


def plan_figures(plans: dict[str, tuple[Plan, PlanSamples]], out: Path) -> None:
    """Fig. 2 (flat outputs) and Fig. 3 (angles) for both coefficient sets."""
    styles = {"derived": "-", "paper": "--"}
    fig = new_figure(8, 4.5)
    ax = fig.subplots()
    for model, (_, s) in plans.items():
        ax.plot(s.t, s.y[:, 0], styles[model], color="C0", label=f"y1d ({model})")
        ax.plot(s.t, s.y[:, 1], styles[model], color="C1", label=f"y2d ({model})")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("flat outputs [rad]")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.suptitle("Fig. 2: planned flat outputs (cubic, th1'(0) = 0.1, th1'(2) = 0.5)")
    fig.tight_layout()
    save_figure(fig, out / "fig2_flat_outputs.png")

    fig = new_figure(8, 4.5)
    ax = fig.subplots()
    for model, (_, s) in plans.items():
        for i in range(3):
            ax.plot(s.t, s.theta[:, i], styles[model], color=f"C{i}",
                    label=f"th{i}d ({model})")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("angles [rad]")
    ax.grid(alpha=0.3)
    ax.legend(ncol=2, fontsize=8)
    fig.suptitle("Fig. 3: planned angles (dashed: the paper's printed coefficients)")
    fig.tight_layout()
    save_figure(fig, out / "fig3_angles.png")


def _errors_at(run: TrackRun, times: tuple[float, ...]) -> list[tuple[float, float, float]]:
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


def run_paper(base: Spec, out: Path, quiet: bool) -> Reproduction:
    """Plans and closed-loop runs of the paper's example under both models and gains."""
    plans: dict[str, tuple[Plan, PlanSamples]] = {}
    for model in COMPARED_MODELS:
        spec = base.with_overrides({"robot.model": model})
        plan = plan_from(spec)
        samples = plan.sample(plan.grid(spec.plan.samples))
        plans[model] = (plan, samples)
        write_parquet(out / f"plan_{model}.parquet", plan_frame(samples),
                      run_record("reproduce", spec.tree))
    plan_figures(plans, out)
    tracks: dict[tuple[str, str], TrackRun] = {}
    for model in COMPARED_MODELS:
        for reading, gains in GAIN_READINGS.items():
            spec = base.with_overrides({"robot.model": model, **gains})
            run = run_track(spec)
            tracks[(model, reading)] = run
            cols = run.columns
            write_parquet(out / f"track_{model}_{reading}.parquet", track_frame(run),
                          run_record("reproduce", spec.tree, metrics=run.metrics))
            if model == "derived":
                plot_track(cols, out / f"fig4_feedback_{reading}.png",
                           f"Fig. 4: feedback from th(0) = (1.96, 0.8, -0.1), gains {reading}: "
                           f"kp = {gains['track.kp']}, kv = {gains['track.kv']}",
                           track_limits(run))
    _say(quiet, f"plans, Figs. 2-4 and closed-loop runs written to {out}")
    return Reproduction(plans, tracks, [])


def paper_table(rep: Reproduction) -> str:
    """Paper value vs flatcli with the paper's coefficients vs flatcli corrected."""
    rows: list[list[Any]] = []
    s_paper = rep.plans["paper"][1]
    s_derived = rep.plans["derived"][1]
    rows.append(["y2'(0) [rad/s]", PAPER_Y2_DOT_START, s_paper.y_dot[0, 1], s_derived.y_dot[0, 1]])
    rows.append(["y2'(2) [rad/s]", PAPER_Y2_DOT_GOAL, s_paper.y_dot[-1, 1],
                 s_derived.y_dot[-1, 1]])
    rows.append(["max abs H along the plan [kg m^2/s]", "0 (claimed)",
                 float(np.max(np.abs(s_paper.momentum))),
                 float(np.max(np.abs(s_derived.momentum)))])
    for reading in GAIN_READINGS:
        paper_err = {model: _errors_at(rep.tracks[(model, reading)], REPORT_TIMES)
                     for model in COMPARED_MODELS}
        for k, t in enumerate(REPORT_TIMES):
            def pair(e: tuple[float, float, float]) -> str:
                return f"({fmt(e[0], 3)}, {fmt(e[1], 3)})"
            rows.append([f"{reading} gains: y - y_ref at t = {t:g} s",
                         "Fig. 4 only: \"follows closely\"" if k == 0 else "-",
                         pair(paper_err["paper"][k]), pair(paper_err["derived"][k])])
    return table(["quantity", "paper", "flatcli, paper's coefficients", "flatcli, corrected"],
                  rows, 6)


def write_report(rep: Reproduction, out: Path, base: Spec) -> Path:
    plan, samples = rep.plans["derived"]
    summary = plan_summary(plan, samples)
    k_paper = constraint_coefficients(plan.robot.links, "paper")
    k_derived = constraint_coefficients(plan.robot.links, "derived")
    coeff_rows = [[name, getattr(k_paper, name), getattr(k_derived, name)]
                  for name in ("a0", "a1", "b0", "b1", "c0")]
    lines = [
        "# Reproducing Franch, Agrawal, Oh, Fattah (IROS 2003) with flatcli",
        "",
        "Every number below was computed by `make reproduce` (`flatcli reproduce`) from the runs "
        "in this directory. The robot is the paper's (m_i = 1 kg, l_i = 0.2 m, "
        "I_i = 0.0533 kg m^2, d0 = d1 = 0.1 m, d2 = 0); the maneuver goes from "
        "th = (1.8, 1, 0) to (1.2, 2, 0) rad in 2 s with th1'(0) = 0.1 and th1'(2) = 0.5 rad/s.",
        "",
        "## Paper vs flatcli",
        "",
        "\"paper's coefficients\" plans and controls with the appendix's coefficients as printed "
        "(`robot.model = \"paper\"`); \"corrected\" with flatcli's derivation "
        "(`robot.model = \"derived\"`, checked against a symbolic derivation of the "
        "angular momentum in the tests). The plant always obeys the correct physics; "
        "|H| is the angular momentum from the full link kinematics.",
        "",
        paper_table(rep),
        "",
        gains_verdict(rep.tracks[("derived", "printed")], rep.tracks[("derived", "swapped")]),
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
        "Figures: `fig2_flat_outputs.png`, `fig3_angles.png`, `fig4_feedback_printed.png`, "
        "`fig4_feedback_swapped.png`.",
    ]
    lines += rep.sections
    path = out / "REPORT.md"
    write_text(path, "\n".join(lines) + "\n")
    return path


#: The optimised plans REPORT.md sets beside the paper's cubic (label, plan.optimize overrides).
OPTIMIZED_PLANS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("least energy", {"plan.optimize.objective": "energy"}),
    ("least energy, abs(th2) <= 3 rad, rates <= 5 rad/s, margin >= 0.05",
     {"plan.optimize.objective": "energy", "plan.optimize.angle_limit": [math.inf, math.inf, 3.0],
      "plan.optimize.rate_limit": 5.0, "plan.optimize.min_margin": 0.05}),
    ("least peak rate", {"plan.optimize.objective": "peak_rate"}),
    ("largest margin", {"plan.optimize.objective": "margin"}),
)


def optimized_plans_section(base: Spec, out: Path) -> list[str]:
    """The optimised plans beside the paper's cubic: a figure and a table (README,
    ``[plan.optimize]``)."""
    rows: list[list[Any]] = []
    curves: list[tuple[str, PlanSamples]] = []
    fine = 4001
    cubic = flat_plan_from(base)
    entries: list[tuple[str, Plan, str]] = [("paper's cubic, th1' = 0.1, 0.5", cubic, "-")]
    for label, overrides in OPTIMIZED_PLANS:
        plan, result = plan_and_optimization(base.with_overrides(overrides))
        assert result is not None
        entries.append((label, plan, f"{result.iterations} it."))
    for label, plan, note in entries:
        samples = plan.sample(plan.grid(fine))
        s = plan_summary(plan, samples)
        rows.append([label, s["input_energy"], max(s["peak_rate1"], s["peak_rate2"]),
                     s["max_abs_theta2"], s["min_margin"], s["max_abs_momentum"], note])
        curves.append((label, samples))
    fold = required_fold(cubic.coefficients, base.plan.start, base.plan.goal)
    ladder_table, ladder_sentence = margin_ladder(base)
    fig = new_figure(11, 7)
    ax = fig.subplots(2, 2, sharex=True)
    for i, (label, samples) in enumerate(curves[:2]):
        style = "--" if i == 0 else "-"
        for j in range(3):
            ax[0, 0].plot(samples.t, samples.theta[:, j], style, color=f"C{j}",
                          label=f"th{j} ({label.split(',')[0]})")
        ax[0, 1].plot(samples.t, samples.theta_dot[:, 2], style, color="C2",
                      label=f"th2' ({label.split(',')[0]})")
        ax[1, 0].plot(samples.t, samples.theta_dot[:, 1], style, color="C1",
                      label=f"th1' ({label.split(',')[0]})")
        ax[1, 1].semilogy(samples.t, samples.margin, style, color="C3",
                          label=f"margin ({label.split(',')[0]})")
    ax[0, 0].set_ylabel("angles [rad]")
    ax[0, 1].set_ylabel("th2' [rad/s]")
    ax[0, 1].set_yscale("symlog", linthresh=5)
    ax[1, 0].set_ylabel("th1' [rad/s]")
    ax[1, 1].set_ylabel("margin abs(sin th1 th1') [rad/s]")
    finish_grid(fig, ax, "The paper's cubic (dashed) and the least-energy flat plan (solid)",
                out / "fig_optimized_plan.png", legend_size=7)
    return [
        "",
        "## Optimised plans",
        "",
        "Same maneuver and robot (derived model), with the free end rates th1'(0), th1'(T) and "
        "the coefficients of a quintic B-spline basis (12 per output) chosen by the optimiser "
        "(`flatcli plan --optimize OBJECTIVE`), subject to a signed singularity margin "
        "(default 0.02 rad/s) so the plan never crosses the singular set. Every plan is "
        "exactly momentum-consistent: H is from the full kinematics on "
        f"{fine} samples. Energy = integral of th1'^2 + th2'^2 [rad^2/s].",
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
        "Figure: `fig_optimized_plan.png`.",
        "",
        "### The optimised plans in closed loop",
        "",
        "Each plan tracked from the paper's initial state th(0) = (1.96, 0.8, -0.1) with "
        "u1(0) = the plan's own th1'(0), with the gains as printed and swapped (plant = the "
        "nominal robot, adaptive integrator):",
        "",
        tracked_plans_table(track_plans(base, [
            ("paper's cubic", {}), *((label, overrides) for label, overrides in OPTIMIZED_PLANS)
        ])),
        "",
        ladder_sentence,
        "",
        ladder_table,
    ]


def run_montecarlo(spec_path: Path, out: Path, quiet: bool, workers: int | None,
                   sets: tuple[str, ...]) -> tuple[str, pd.DataFrame, float]:
    """The Monte Carlo study into out/montecarlo; its summary text, table and wall time."""
    from flatcli.sweep import run_sweep

    spec = load_spec(spec_path, sets)
    directory = out / "montecarlo"
    result = run_sweep(spec, directory, "local", workers, None, force=True,
                       progress=Progress(spec.name, quiet))
    plot_sweep(directory)
    summary = pd.read_parquet(directory / "summary.parquet")
    return result.summary_text, summary, result.wall_seconds


def check_inputs(out: Path, montecarlo: Path | None, workers: int | None,
                 sets: tuple[str, ...]) -> None:
    """Every input of ``reproduce``, checked before anything is written: the output
    directory, the study's spec with its --set items (every grid cell planned), --workers."""
    from flatcli.core.model import FlatcliError
    from flatcli.sweep import layout

    if out.exists() and not out.is_dir():
        raise FlatcliError(f"--out {out}: is a file")
    if workers is not None and workers < 1:
        raise FlatcliError(f"--workers: must be >= 1, got {workers}")
    if montecarlo is None:
        if sets:
            raise FlatcliError("--set: changes the Monte Carlo study, which --no-montecarlo "
                               "skips")
        return
    layout(load_spec(montecarlo, sets))


def reproduce(out: Path, montecarlo: Path | None, quiet: bool = False,
              workers: int | None = None, sets: tuple[str, ...] = (),
              command: str | None = None) -> Path:
    """Run everything ``make reproduce`` promises into ``out``; return REPORT.md's path.

    ``command``: the command line, recorded at the end of REPORT.md.
    """
    started = time.perf_counter()
    check_inputs(out, montecarlo, workers, sets)
    base = resolve({})
    rep = run_paper(base, out, quiet)
    rep.sections += optimized_plans_section(base, out)
    _say(quiet, "optimised plans written")
    if montecarlo is not None:
        text, summary, wall = run_montecarlo(montecarlo, out, quiet, workers, sets)
        trials = int(summary["trials"].sum())
        rep.sections += [
            "",
            "## Monte Carlo study",
            "",
            f"`{montecarlo.name}`: the paper's plan and feedback from random initial-state "
            "errors of growing size (std of th(0)), with the gains as printed and swapped, on "
            "plants whose counterweight misses joint 2 by d2 = 0, 1, 5 mm (the controller "
            "believes d2 = 0: such a plant is still flat, being controllable and driftless of "
            "codimension one, but the paper's closed-form outputs no longer apply to it, so "
            f"the controller's model is wrong). {trials} trials in {wall:.1f} s on the "
            "adaptive integrator; only trials resolved to the end enter the error statistics. "
            "Files: `montecarlo/` "
            "(trials.parquet, summary.md) and `montecarlo/sweep_*.png`.",
            "",
            *study_findings(summary, out / "montecarlo" / "trials.parquet"),
            "",
            text,
        ]
    rep.sections += actuators_section(base, out, quiet, workers, montecarlo is not None, sets)
    rep.sections += chains_section(base, out, quiet, workers, montecarlo is not None, sets)
    if command is not None:
        rep.sections += ["", f"Made with `{command}` (flatcli {__version__})."]
    write_json(out / "run.json", run_record("reproduce", base.tree,
                                            seconds=time.perf_counter() - started))
    path = write_report(rep, out, base)
    _say(quiet, f"wrote {path} in {time.perf_counter() - started:.1f} s")
    return path
