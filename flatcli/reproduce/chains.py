"""``make reproduce``'s section "Beyond three links": the paper's closing claim as a tool.

A four-link and a six-link robot (``flatcli/data/chain4.toml``, ``chain6.toml``: base + 3 or
5 links, the last counterweighted onto its joint, d_N = 0): their designs checked, their
flatness-based plans checked against the full link kinematics, the closed loop from a
perturbed start on the kinematic and the dynamic plant, a short Monte Carlo study of each, and
the one thing that changes with N: the base's natural drift becomes path-dependent.
``chains_section`` runs it all into ``OUT/chains`` and returns REPORT.md's lines.
"""

from __future__ import annotations

from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from flatcli import api
from flatcli.api import TrackRun
from flatcli.core.models.flatmodel import ChainModel
from flatcli.core.plan.planning import Plan
from flatcli.core.robots.chain import chain_momentum, momentum_weights
from flatcli.core.robots.params import RobotParams, flatness_check
from flatcli.outputs import track_frame
from flatcli.report import FigureFile, fmt, new_figure, save_figure, styled, table
from flatcli.report.figures import PAGE_WIDTH
from flatcli.reproduce.findings import plan_of, reached_text, track_of
from flatcli.reproduce.sections import Context, Outcome, Section, with_shared_sets
from flatcli.spec import Spec, load_spec
from flatcli.storage import run_record, write_parquet

Array = np.ndarray[Any, np.dtype[np.float64]]

#: The robots of this section (package data; configs/ links to them).
CHAIN_SPECS: tuple[Path, ...] = tuple(
    Path(str(resources.files("flatcli") / "data" / f"{name}.toml")) for name in
    ("chain4", "chain6"))
#: Samples on which a plan's drift, fold and momentum are taken (trapezoid rule).
DENSE_SAMPLES = 4001
#: Inner end rates of two paths with the same ends but not the same route [rad/s]: from
#: FAST at joint 1 down to SLOW at joint N - 1 at the start and the other way round at the
#: goal, and the mirror image.
FAST, SLOW = 1.0, 0.1


def path_rates(joints: int) -> tuple[tuple[list[float], list[float]], ...]:
    """The two (start rates, goal rates) pairs of ``FAST`` and ``SLOW`` for ``joints``."""
    down = [float(v) for v in np.linspace(FAST, SLOW, joints - 1)]
    up = down[::-1]
    return ((down, up), (up, down))


#: ``--set`` items of ``make reproduce`` that also apply to these studies.


def natural_drift(plan: Plan, samples: int = DENSE_SAMPLES) -> float:
    """How far the base turns [rad] if the joints th_1..th_N-1 follow the plan and th_N
    stays at rest: -integral of (h_1 th_1' + ... + h_N-1 th_N-1') / h_0 dt (H = 0), by the
    trapezoid rule on ``samples`` points. h_j = ``chain.momentum_weights``: with d_N = 0 they
    depend on th_1..th_N-1 only, so the value is that of the joints' path alone."""
    model = ChainModel.of(plan.robot)
    t = plan.grid(samples)
    s = plan.sample(t)
    h = np.empty(model.n_joints + 1)
    rate = np.empty(t.shape[0])
    for k in range(t.shape[0]):
        momentum_weights(model.K, model.inertia, s.theta[k], h)
        inner = s.theta_dot[k, 1:-1]
        rate[k] = -float(h[1:-1] @ inner) / h[0]
    return float(np.sum((rate[1:] + rate[:-1]) * np.diff(t)) / 2)


def plan_checks(plan: Plan, start: Sequence[float], goal: Sequence[float]) -> dict[str, float]:
    """A plan's figures: its fold max abs(th_N), peak joint and base rates, least margin,
    max abs(H) from the full link kinematics (``chain.chain_momentum``), the largest error at
    its ends and the natural drift of its joints' path."""
    robot = plan.robot
    n = robot.n_joints
    t = plan.grid(DENSE_SAMPLES)
    s = plan.sample(t)
    mass, inertia, length, com = (np.asarray(v, dtype=float) for v in
                                  (robot.mass, robot.inertia, robot.length, robot.com))
    h = chain_momentum(mass, inertia, length, com, s.theta, s.theta_dot)
    ends = max(float(np.abs(s.theta[0] - np.asarray(start)).max()),
               float(np.abs(s.theta[-1] - np.asarray(goal)).max()))
    return {
        "fold": float(np.abs(s.theta[:, n]).max()),
        "peak_joint_rate": float(np.abs(s.theta_dot[:, 1:n]).max()),
        "peak_last_rate": float(np.abs(s.theta_dot[:, n]).max()),
        "peak_base_rate": float(np.abs(s.theta_dot[:, 0]).max()),
        "min_margin": float(s.margin.min()),
        "max_abs_H": float(np.abs(h).max()),
        "end_error": ends,
        "natural_drift": natural_drift(plan),
    }


def design_row(name: str, robot: RobotParams) -> list[Any]:
    """Name, N, masses, K_10 [kg m^2], I_N [kg m^2] and the verdict of ``flatness_check``."""
    model = ChainModel.of(robot)
    check = flatness_check(robot)
    return [name, robot.n_joints, ", ".join(fmt(m) for m in robot.mass),
            float(model.K[1, 0]), float(model.inertia[-1]),
            "yes" if check.is_flat else f"no: {check.message()}"]


def closed_loop_rows(spec: Spec) -> tuple[list[list[Any]], dict[str, TrackRun]]:
    """The spec's closed loop on the kinematic and the dynamic plant: its metrics, and the
    runs."""
    rows, runs = [], {}
    for plant in ("kinematic", "dynamic"):
        run = track_of(spec.with_overrides({"plant.model": plant}))
        runs[plant] = run
        m = run.metrics
        rows.append([spec.name, plant, m["status"], m["err_y_final"], m["err_theta_final"],
                     m["err_theta_max"], m["peak_rate"], m["peak_torque"], m["momentum_drift"],
                     m["min_margin"]])
    return rows, runs


@styled
def plot_chains(runs: dict[str, tuple[Plan, TrackRun]], path: Path,
                figures: FigureFile | None = None) -> None:
    """Per robot: the planned angles (solid) and the closed loop's from the perturbed start
    on the dynamic plant (dashed), and the closed loop's flat-output errors (log scale)."""
    fig = new_figure(PAGE_WIDTH, 2.6 * len(runs))
    axes = fig.subplots(len(runs), 2, squeeze=False)
    for row, (name, (plan, run)) in enumerate(runs.items()):
        n = plan.robot.n_joints
        cols = run.columns
        t = cols["t"]
        ax = axes[row, 0]
        for i in range(n + 1):
            ax.plot(t, cols[f"theta{i}_ref"], color=f"C{i}", label=f"$\\theta_{i}$")
            ax.plot(t, cols[f"theta{i}"], "--", color=f"C{i}")
        ax.plot([], [], "--", color="0.4", label="tracked")
        ax.set_title(f"{name}: angles, planned (solid) and tracked (dashed)")
        ax.set_xlabel("$t$ [s]")
        ax.set_ylabel("$\\theta_i$ [rad]")
        ax.legend(ncol=3)
        ax = axes[row, 1]
        for j in range(1, n + 1):
            err = np.abs(cols[f"y{j}"] - cols[f"y{j}_ref"])
            ax.semilogy(t, np.maximum(err, 1e-16), color=f"C{j}",
                        label=f"$|y_{j} - y_{{{j}d}}|$")
        ax.set_title(f"{name}: flat-output errors (dynamic plant)")
        ax.set_xlabel("$t$ [s]")
        ax.set_ylabel("$|y_j - y_{jd}|$ [rad]")
        ax.grid(which="both")
        ax.legend(ncol=2)
    fig.suptitle("Beyond three links: flatness-based plans and feedback for N = 3 and 5 joints")
    fig.tight_layout()
    save_figure(fig, path, figures)


def run_study(spec: Spec, plan: Plan, directory: Path, quiet: bool, workers: int | None,
              sets: Sequence[str]) -> tuple[str, pd.DataFrame, float]:
    """The spec's Monte Carlo study, started around the plan's start, into ``directory``:
    its summary text, trial table and wall time [s]."""
    study = study_spec(spec, sets)
    result = api.sweep(study, directory, workers=workers, force=True, quiet=quiet)
    assert result.wall_seconds is not None  # run here, not loaded
    return result.summary_text, pd.read_parquet(directory / "trials.parquet"), \
        result.wall_seconds


def study_spec(spec: Spec, sets: Sequence[str]) -> Spec:
    """A robot's Monte Carlo study: its spec started on the plan's start, with the --set items
    of ``make reproduce`` that apply here (``SHARED_SETS``)."""
    return with_shared_sets(
        spec.with_overrides({"track.initial": [float(v) for v in spec.plan.start]}), sets)


def demoted(markdown: str) -> str:
    """A sweep's summary with its headings set two levels lower, under this section's."""
    return "\n".join(f"##{line}" if line.startswith("#") else line
                     for line in markdown.splitlines())


def path_rows(spec: Spec) -> list[list[Any]]:
    """The natural drift and the fold of plans with the same ends and different inner end
    rates (``path_rates``); for N = 2 (the paper's robot) the same with its one inner rate."""
    rows = []
    for start_rate, goal_rate in path_rates(spec.joints):
        s = spec.with_overrides({"plan.start_rate": start_rate, "plan.goal_rate": goal_rate})
        plan = plan_of(s)
        c = plan_checks(plan, s.plan.start, s.plan.goal)
        rows.append([spec.name, ", ".join(fmt(v, 2) for v in start_rate),
                     ", ".join(fmt(v, 2) for v in goal_rate), c["natural_drift"],
                     _left(s, c), c["fold"], c["peak_last_rate"]])
    return rows


def _left(spec: Spec, checks: dict[str, float]) -> float:
    """The base rotation th_N must make up [rad]: th0(T) - th0(0) - the natural drift."""
    return spec.plan.goal[0] - spec.plan.start[0] - checks["natural_drift"]


def paper_drift_rows(base: Spec) -> list[list[Any]]:
    """The paper's robot with two end-rate pairs: its natural drift (the same: it depends on
    th1's ends only) and its fold."""
    rows = []
    for start_rate, goal_rate in ((0.1, 0.5), (1.0, 0.1)):
        s = base.with_overrides({"plan.start_rate": start_rate, "plan.goal_rate": goal_rate})
        plan = plan_of(s)
        c = plan_checks(plan, s.plan.start, s.plan.goal)
        rows.append(["paper (N = 2)", fmt(start_rate, 2), fmt(goal_rate, 2),
                     c["natural_drift"], _left(s, c), c["fold"], c["peak_last_rate"]])
    return rows


def run(context: Context) -> Outcome:
    """REPORT.md's "Beyond three links" (its runs into ``out/chains``, its figure
    ``out/fig_chains.png``); without the study (``--no-montecarlo``) no Monte Carlo. Of
    ``make reproduce``'s --set items, ``sweep.trials`` and ``sweep.seed`` apply here."""
    base, out, steps, study = context.base, context.out, context.steps, context.study
    designs, loop_rows, drift_rows = [], [], paper_drift_rows(base)
    plan_rows: list[list[Any]] = []
    figures: dict[str, tuple[Plan, TrackRun]] = {}
    studies: list[str] = []
    reached: dict[str, str] = {}  # each study's outcomes, in words
    for path in CHAIN_SPECS:
        spec = load_spec(path)
        steps.step(f"{spec.name}: design, plan, closed loop on both plants, paths")
        directory = out / "chains" / spec.name
        planned = api.plan(spec)
        plan = planned.plan
        assert plan is not None
        designs.append(design_row(spec.name, plan.robot))
        c = plan_checks(plan, spec.plan.start, spec.plan.goal)
        plan_rows.append([spec.name, c["fold"], c["peak_joint_rate"], c["peak_last_rate"],
                          c["peak_base_rate"], c["min_margin"], c["max_abs_H"], c["end_error"],
                          c["natural_drift"]])
        write_parquet(directory / "plan.parquet", planned.frame,
                      run_record("reproduce", spec.tree))
        rows, runs = closed_loop_rows(spec)
        loop_rows += rows
        for plant, run in runs.items():
            write_parquet(directory / f"track_{plant}.parquet", track_frame(run),
                          run_record("reproduce", spec.tree, metrics=run.metrics))
        figures[spec.name] = (plan, runs["dynamic"])
        drift_rows += path_rows(spec)
        if study:
            steps.step(f"{spec.name}: Monte Carlo study")
            text, trials, wall = run_study(spec, plan, directory / "montecarlo", context.quiet,
                                           context.workers, context.sets)
            cells = int(trials["cell"].nunique()) if "cell" in trials else 1
            reached[spec.name] = reached_text(trials["outcome"])
            studies += ["", f"#### {spec.name}: {len(trials)} trials in {wall:.1f} s "
                        f"({cells} cells)", "", f"**Outcome**: {reached[spec.name]}.", "",
                        demoted(text)]
    plot_chains(figures, out / context.figures.name("fig_chains"), context.figures)
    lines = [
        "",
        "## Beyond three links",
        "",
        "The paper closes by stating, without a derivation, that its result extends to an "
        "n-link planar robot whose last link has its centre of mass on the preceding joint. "
        "flatcli derives it (flatcli's docs/chains.md): with d_N = 0 no link position "
        "depends on th_N, so H = h_0(q) th0' + sum_j<N h_j(q) th_j' + I_N th_N' with h_0, h_j "
        "functions of q = (th_1..th_N-1) only; y_j = th_j (j < N) and y_N = th0 + I_N th_N / "
        "h_0(q) are flat outputs, singular where dh_0/dt = 0. The robots below are "
        "`configs/chain4.toml` (4 links, N = 3 joints) and `configs/chain6.toml` (6 links, "
        "N = 5); their specs are ordinary flatcli specs (`flatcli plan configs/chain4.toml`).",
        "",
        "### Designs",
        "",
        "K_10: the barycentric coupling of base and link 1, m0 (l0 - d0)(m1 d1 + (m2 + ... + "
        "mN) l1) / M. The outputs need d_N = 0 and I_N != 0; flatcli's planner also needs "
        "K_10 != 0, which generalises the paper's m0 != 0, l0 != d0, m1 d1 + m2 l1 != 0 "
        "(`flatcli design` checks all of them).",
        "",
        table(["robot", "N", "masses [kg]", "K_10 [kg m^2]", "I_N [kg m^2]", "flat"], designs,
              4),
        "",
        "### Plans (cubic flat outputs, checked on "
        f"{DENSE_SAMPLES} samples)",
        "",
        "fold: max abs(th_N) along the plan; max abs(H): the angular momentum from the full "
        "link kinematics (the plan must keep H = 0); end error: the largest difference from "
        "the given start and goal angles; natural drift: how far the joints th_1..th_N-1 "
        "alone would turn the base (th_N at rest), which th_N must make up to reach the goal.",
        "",
        table(["robot", "fold [rad]", "peak th_1..N-1' [rad/s]", "peak th_N' [rad/s]",
               "peak th0' [rad/s]", "min margin [rad/s]", "max abs(H) [kg m^2/s]",
               "end error [rad]", "natural drift [rad]"], plan_rows, 4),
        "",
        "### Closed loop from a perturbed start",
        "",
        "The linearising feedback y'' = v (gains kp = 25, kv = 10 per output) from the spec's "
        "`track.initial`, on the kinematic plant and on the dynamic plant (free-floating "
        "multibody dynamics of all N + 1 bodies under rate servos of 100 rad/s, no torque "
        "limit). momentum drift: max abs(H - H0) from the state (q, q'); on the kinematic "
        "plant H is conserved by construction, on the dynamic one by the physics alone.",
        "",
        table(["robot", "plant", "status", "final y error [rad]", "final angle error [rad]",
               "max angle error [rad]", "peak rate [rad/s]", "peak torque [N m]",
               "momentum drift [kg m^2/s]", "min margin [rad/s]"], loop_rows, 3),
        "",
        f"Figure `{context.figures.name('fig_chains')}`; files in `chains/` (plan.parquet, "
        "track_kinematic.parquet, track_dynamic.parquet per robot).",
        "",
        "### What changes with N: the singular set, and a drift that depends on the path",
        "",
        "The singular set sin(th1) th1' = 0 of the paper becomes D = grad h_0(q) . q' = 0: "
        "the configurations where grad h_0 vanishes (for instance every joint straight or "
        "folded back, th_j = 0 or pi), and elsewhere every joint velocity tangent to the level "
        "set of h_0. For N = 2 that is the one rate th1' = 0; for N >= 3 it is a hyperplane of "
        "joint velocities at each q, so a plan can pass configurations where one joint stops "
        "or turns back as long as the joints together keep changing h_0 (the margin column "
        "above is that rate, scaled by -1 / (2 K_10)).",
        "",
        "For the paper's robot the joints' path is th1(t) alone, so the base's natural drift "
        "-integral h_1/h_0 dth1 depends on th1's ends only, and so does the rotation left for "
        "th2 to make up (from which flatcli's `required_fold` bounds how far th2 must turn). "
        "For N >= 3 the drift is a line integral over a path in q-space whose integrand is "
        "not exact (its curl is not zero), so two plans with the same ends but different "
        "inner end rates drift differently and leave th_N different work. Along any "
        "admissible plan h_0 changes monotonically (its rate is the margin, which may not "
        "change sign), so no admissible plan brings q back to where it was: the joints "
        "cannot cycle to turn the base, as non-holonomic path planners do.",
        "",
        table(["robot", "start rates [rad/s]", "goal rates [rad/s]", "natural drift [rad]",
               "left to th_N [rad]", "fold [rad]", "peak th_N' [rad/s]"], drift_rows, 4),
    ]
    if study:
        lines += [
            "",
            "### Monte Carlo",
            "",
            "Each spec's own `[sweep]`: th(0) errors of std 0.02 and 0.1 rad around the "
            "plan's start and u(0) errors of std 0.01 rad/s, on the nominal plant and on one "
            "whose last counterweight misses its joint by 2 mm (kinematic plant). Files "
            "`chains/<robot>/montecarlo/`.",
            *studies,
        ]
    worst_h = max(float(row[6]) for row in plan_rows)  # max abs(H)
    drifts = [row for row in drift_rows if row[0] != "paper (N = 2)"]
    headline = [f"robots of N = 3 and 5 joints plan with max abs(H) {fmt(worst_h, 2)} "
                "kg m^2/s and track on both plants; the base's natural drift depends on the "
                f"joints' path ({', '.join(fmt(float(r[3]), 3) for r in drifts)} rad)",
                *(f"{name} study: {text}" for name, text in reached.items())]
    return Outcome(lines, headline, ("chains/**/*", "fig_chains.*"))


def inputs(context: Context) -> dict[str, Any]:
    """The robots' specs (their studies' with make reproduce's --set items), and whether the
    studies run."""
    specs = {}
    for path in CHAIN_SPECS:
        spec = load_spec(path)
        specs[spec.name] = (study_spec(spec, context.sets).tree if context.study
                            else spec.tree)
    return {"specs": specs, "base": context.base.tree}


SECTION = Section("chains", "beyond three links: robots of 3 and 5 joints", inputs, run)
