"""``make reproduce``'s section "What the maneuver asks of the actuators".

The paper's maneuver on the robot with inertia (``plant.model = "dynamic"``): what the paper's
cubic and the optimised plans of REPORT.md ask of the joints (torque, rate), ideally and
through rate servos in closed loop, and a Monte Carlo study over servo bandwidth and torque
limit (``configs/actuators_montecarlo.toml``) whose cells say which actuators make each plan
trackable. ``actuators_section`` runs it all into ``OUT/actuators`` and returns REPORT.md's
lines; every number in them is computed here from those runs.
"""

from __future__ import annotations

import contextlib
import math
import textwrap
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from flatcli import api
from flatcli.core.loop.metrics import STATUS_NAMES
from flatcli.core.names import DEFAULT_SERVO_BANDWIDTH, GOAL_TOLERANCE
from flatcli.core.robots.dynamics import make_chain
from flatcli.report import (
    COMPLETED,
    FigureFile,
    fmt,
    new_figure,
    save_figure,
    styled,
    table,
)
from flatcli.report.figures import PAGE_WIDTH
from flatcli.report.summary import wilson_interval
from flatcli.reproduce.findings import OPTIMIZED_PLANS, paper_plan, reached_text, track_of
from flatcli.reproduce.sections import Context, Outcome, Section, Steps
from flatcli.spec import Spec, load_spec
from flatcli.storage import run_record, write_parquet

#: The study's spec, shipped with flatcli (package data; configs/ links to it).
STUDY = Path(str(resources.files("flatcli") / "data" / "actuators_montecarlo.toml"))
#: The feedback of this section: the gains swapped (docs/physics.md, "The gains").
SWAPPED = {"track.kp": [100.0, 110.0], "track.kv": [10.0, 13.0]}
#: A crossed trial "tumbled" when it ended farther than this from the plan [rad] (a cell is
#: trackable when every one of its trials reached: its outcome, ``track.goal_tolerance``).
TRACKABLE_ERROR = 1e-2
#: Samples of a plan on which its ideal torques and rates are taken.
PLAN_SAMPLES = 4001
#: Statuses that lose a trial.
LOST = tuple(s for s in STATUS_NAMES if s not in COMPLETED)
BANDWIDTH, LIMIT, MANEUVER = "plant.servo_bandwidth", "plant.torque_limit", "maneuver"


def study_path() -> Path:
    """The study's spec file (``STUDY``)."""
    return STUDY


def plan_demands(base: Spec, plans: Sequence[tuple[str, Mapping[str, Any]]],
                 steps: Steps | None = None) -> list[list[Any]]:
    """Per plan: the ideal peak torques and rates (inverse dynamics of the plan,
    ``Plan.torques``) and the closed loop on the dynamic plant (default servo, no
    torque limit, gains swapped) from the plan's start and from Fig. 4's."""
    rows = []
    chain_of: dict[Any, Any] = {}
    for label, overrides in (plans if steps is None else steps.each("demands of", plans)):
        spec = base.with_overrides({**overrides, **SWAPPED, "plant.model": "dynamic"})
        plan = paper_plan(spec)
        robot = plan.robot
        if robot not in chain_of:
            chain_of[robot] = make_chain(robot.mass, robot.inertia, robot.length, robot.com)
        t = plan.grid(PLAN_SAMPLES)
        torques = plan.torques(chain_of[robot], t)
        _, rates, _ = plan.motion(t)
        on_plan = track_of(spec.with_overrides({"track.initial": list(spec.plan.start)}))
        fig4 = track_of(spec)
        m, f = on_plan.metrics, fig4.metrics
        rows.append([
            label,
            float(np.abs(torques[:, 1]).max()), float(np.abs(torques[:, 2]).max()),
            float(np.abs(rates[:, 1:]).max()),
            m["peak_torque"], m["peak_rate"], m["err_theta_final"],
            f["peak_torque"] if f["status"] in COMPLETED else f"{f['status']}",
            f["err_theta_final"],
        ])
    return rows


def run_study(out: Path, quiet: bool, workers: int | None, sets: Sequence[str] = ()
              ) -> tuple[Spec, pd.DataFrame, pd.DataFrame, float]:
    """The study (``study_path()`` with the ``--set`` items ``sets``) into out/actuators, and
    the same trials on the kinematic plant into out/actuators/kinematic (the limit of
    infinite bandwidth): its spec, both trial tables and the study's wall time [s]."""
    from flatcli.montecarlo.directory import record_outputs
    from flatcli.storage import directory_lock

    spec = load_spec(study_path(), sets)
    directory = out / "actuators"
    with directory_lock(directory):
        forget_study(directory)
        result = api.sweep(spec, directory, workers=workers, force=True, quiet=quiet)
        kinematic = spec.with_overrides({
            "plant.model": "kinematic",
            "sweep.grid": {MANEUVER: spec.sweep.grid[MANEUVER]},
        })
        api.sweep(kinematic, directory / "kinematic", workers=workers, force=True, quiet=quiet)
        # the kinematic sweep's files are flatcli's too (``flatcli sweep --force`` there)
        record_outputs(directory, (p for p in (directory / "kinematic").rglob("*")
                                   if p.is_file() and not p.is_symlink()))
    assert result.wall_seconds is not None  # run here, not loaded
    return (spec, pd.read_parquet(directory / "trials.parquet"),
            pd.read_parquet(directory / "kinematic" / "trials.parquet"), result.wall_seconds)


def forget_study(directory: Path) -> None:
    """Before the study runs again into ``directory`` (out/actuators): remove what an
    earlier run of it wrote beside the sweep's own files, which the sweep's ``--force``
    would refuse as not its own: ``cells.parquet`` and the kinematic sweep under
    ``kinematic/`` (only files flatcli wrote, as ``--force`` removes them; anything else
    there stays, and the sweep then refuses, naming it)."""
    from flatcli.montecarlo.directory import TRIALS_DIR, clear, foreign_entries, survey
    from flatcli.storage import LOCK_NAME, directory_lock, read_provenance

    cells = directory / "cells.parquet"
    with contextlib.suppress(OSError, ValueError):
        if cells.is_file() and not cells.is_symlink() and read_provenance(cells).get(
                "command") == "reproduce":
            cells.unlink()
    nested = directory / "kinematic"
    if not nested.is_dir() or nested.is_symlink():
        return
    with directory_lock(nested):
        previous = survey(nested)
        if previous.spec is None or foreign_entries(nested, previous.owned(nested)):
            return
        clear(nested, previous)
    with contextlib.suppress(OSError):
        (nested / LOCK_NAME).unlink()
    for folder in (nested / TRIALS_DIR, nested):  # each if it is there and empty (a
        with contextlib.suppress(OSError):        # finished sweep leaves no trials/)
            folder.rmdir()


def record_cells(directory: Path) -> None:
    """List cells.parquet in the study's sweep manifest (flatcli's file: ``--force`` may
    remove it)."""
    from flatcli.montecarlo.directory import record_outputs
    from flatcli.storage import directory_lock

    with directory_lock(directory):
        record_outputs(directory, [directory / "cells.parquet"])


def _column(frame: pd.DataFrame, name: str, missing: Any) -> pd.Series:
    """A column of a trials table, or ``missing`` for every row of a table without it."""
    if name in frame:
        return frame[name]
    return pd.Series([missing] * len(frame), index=frame.index)


def cell_table(trials: pd.DataFrame) -> pd.DataFrame:
    """Per cell (maneuver, bandwidth, torque limit): trials, the fraction lost (diverged,
    unresolved, error), the fraction of simulated trials that crossed the singular set (and
    went on: the actuators bound the plant there) and of those that then ended beyond
    ``TRACKABLE_ERROR`` from the plan (``tumbled``), the fraction of resolved trials not
    verified; the median and 95th percentile of the final angle error and the median peak
    torque over the verified resolved trials (over the unverified ones where a cell has no
    verified one; ``counted`` of them), the fraction of simulated trials whose torque
    saturated, the median and max momentum drift; the trials' outcomes (``reached``,
    ``missed``, ``collided`` as fractions of the cell's trials, ``reached_count``) and the
    count that crossed. A cell is trackable when every one of its trials reached (outcome:
    each angle within track.goal_tolerance of the goal at T)."""
    rows = []
    keys = [MANEUVER, BANDWIDTH, LIMIT]
    for values, group in trials.groupby(keys, sort=False):
        resolved = group[group["status"].isin(COMPLETED)]
        sure = _column(resolved, "verified", False).fillna(False).astype(bool)
        done = resolved[sure] if sure.any() else resolved
        simulated = group[group["status"] != "error"]
        row: dict[str, Any] = dict(zip(keys, values, strict=True))
        row["trials"] = len(group)
        for status in LOST:
            row[status] = float((group["status"] == status).mean())
        row["lost"] = float(group["status"].isin(LOST).mean())
        crossings = _column(simulated, "crossings", 0).fillna(0).to_numpy(dtype=float)
        row["crossed"] = float((crossings > 0).mean()) if len(simulated) else math.nan
        final_all = simulated["err_theta_final"].to_numpy(dtype=float)
        row["tumbled"] = (float(((crossings > 0) & ~(final_all <= TRACKABLE_ERROR)).mean())
                          if len(simulated) else math.nan)
        row["unverified"] = float(1 - sure.mean()) if len(resolved) else math.nan
        final = done["err_theta_final"].to_numpy(dtype=float)
        row["err_final_median"] = float(np.median(final)) if len(final) else math.nan
        row["err_final_p95"] = float(np.quantile(final, 0.95)) if len(final) else math.nan
        row["peak_torque_median"] = (float(done["peak_torque"].median()) if len(done)
                                     else math.nan)
        row["saturated"] = (float((simulated["torque_saturated"] > 0).mean()) if len(simulated)
                            else math.nan)
        drift = done["momentum_drift"].to_numpy(dtype=float)
        row["drift_median"] = float(np.median(drift)) if len(drift) else math.nan
        row["drift_max"] = float(drift.max()) if len(drift) else math.nan
        outcome = _column(group, "outcome", "")
        row["reached_count"] = int((outcome == "reached").sum())
        for name in ("reached", "missed", "collided"):
            row[name] = float((outcome == name).mean())
        row["counted"] = len(done)
        row["crossed_count"] = int((crossings > 0).sum())
        row["trackable"] = bool(row["reached_count"] == len(group))
        rows.append(row)
    return pd.DataFrame(rows)


def kinematic_levels(trials: pd.DataFrame) -> dict[str, tuple[float, float, float]]:
    """Per maneuver, the kinematic plant's 95th-percentile final angle error (verified
    resolved trials; the unverified ones where none is verified), the fraction lost and the
    fraction reached (outcome, of all its trials)."""
    out = {}
    for label, group in trials.groupby(MANEUVER, sort=False):
        resolved = group[group["status"].isin(COMPLETED)]
        sure = _column(resolved, "verified", False).fillna(False).astype(bool)
        done = (resolved[sure] if sure.any() else resolved)["err_theta_final"].to_numpy(
            dtype=float)
        out[str(label)] = (float(np.quantile(done, 0.95)) if len(done) else math.nan,
                           float(group["status"].isin(LOST).mean()),
                           float((_column(group, "outcome", "") == "reached").mean()))
    return out


def limit_text(limit: float) -> str:
    """A torque limit for a table or a legend [N m]."""
    return "none" if math.isinf(limit) else f"{limit:g}"


def lost_interval(lost: float, trials: int) -> tuple[float, float]:
    """95 % Wilson interval of a fraction of trials lost."""
    low, high = wilson_interval(round(lost * trials), trials)
    return float(low), float(high)


@styled
def plot_study(cells: pd.DataFrame, kinematic: Mapping[str, tuple[float, float, float]],
               path: Path, figures: FigureFile | None = None) -> None:
    """Final angle error (95th percentile, verified resolved trials) and the fraction of
    the cell's trials that did not reach the goal (outcome), with its 95 % Wilson interval,
    against servo bandwidth, one panel per maneuver, one line per torque limit."""
    maneuvers = list(dict.fromkeys(cells[MANEUVER]))
    limits = list(dict.fromkeys(cells[LIMIT]))
    fig = new_figure(max(PAGE_WIDTH, 2.6 * len(maneuvers)), 5.2)
    ax = fig.subplots(2, len(maneuvers), sharex=True, squeeze=False)
    for j, maneuver in enumerate(maneuvers):
        sel = cells[cells[MANEUVER] == maneuver]
        for k, limit in enumerate(limits):
            line = sel[sel[LIMIT] == limit].sort_values(BANDWIDTH)
            label = ("no torque limit" if math.isinf(limit)
                     else f"torque limit {limit_text(limit)} N m")
            ax[0, j].loglog(line[BANDWIDTH], line["err_final_p95"], "o-", color=f"C{k}",
                            label=label, ms=5 - 0.6 * k, lw=1.8 - 0.3 * k)
            failed = (1.0 - line["reached"]).to_numpy()
            bounds = np.array([lost_interval(f, r["trials"])
                               for f, (_, r) in zip(failed, line.iterrows(), strict=True)])
            spread = np.abs(bounds.T - failed)
            ax[1, j].errorbar(line[BANDWIDTH] * 1.04 ** (k - 2), failed, yerr=spread,
                              fmt="o-", color=f"C{k}", label=label, ms=4, capsize=2,
                              clip_on=False)
            ax[1, j].set_xscale("log")
        level, _, reached = kinematic[maneuver]
        ax[0, j].axhline(level, color="k", ls=":", label="kinematic plant")
        ax[0, j].axhline(GOAL_TOLERANCE, color="0.5", ls="--", label="track.goal_tolerance")
        ax[1, j].axhline(1.0 - reached, color="k", ls=":", label="kinematic plant")
        ax[0, j].set_title(textwrap.fill(maneuver, 40))
        ax[1, j].set_xlabel("servo bandwidth $b$ [rad/s]")
        ax[1, j].set_ylim(0.0, 1.03)  # a fraction is never below 0
        for a in ax[:, j]:
            a.grid(which="both")
    ax[0, 0].set_ylabel("final angle error,\n95th percentile [rad]")
    ax[1, 0].set_ylabel("fraction of trials not reached\n(outcome; 95 % Wilson interval)")
    ax[0, -1].legend()
    fig.suptitle("The maneuver on the robot with inertia: tracking against servo bandwidth "
                 "and torque limit\n(dynamic plant, gains swapped, $\\theta(0)$ errors of std "
                 "2 mrad, no sensor noise)")
    fig.tight_layout()
    save_figure(fig, path, figures)


def matrix_entry(cell: Mapping[str, Any]) -> str:
    """A cell of REPORT's bandwidth x torque-limit matrix, each number saying over which
    trials it is: reached k/n (of all the cell's trials); the 95th percentile of the final
    error over the m trials counted (verified resolved; ``*``: unverified, where the cell has
    no verified one), "p95 x of m"; crossed c/n (of all its trials)."""
    n = int(cell["trials"])
    text = f"{int(cell['reached_count'])}/{n} reached"
    if cell["counted"]:
        text += (f"; p95 {fmt(cell['err_final_p95'], 2)} of {int(cell['counted'])}"
                 + ("*" if cell["unverified"] == 1 else ""))
    if cell["crossed_count"]:
        text += f"; {int(cell['crossed_count'])}/{n} crossed"
    return text


def _bandwidths(values: pd.Series) -> str:
    return ", ".join(fmt(v) for v in values)


#: The law "final error x bandwidth is constant" holds over a range of bandwidths where the
#: product stays within this factor of its value at the study's largest bandwidth.
LAW_FACTOR = 1.5


def bandwidth_law(cells: pd.DataFrame) -> dict[str, tuple[float, float, float]]:
    """Per maneuver, with unlimited torque: the least bandwidth b_min [rad/s] from which up
    to the study's largest every cell has 95th-percentile final error x bandwidth within
    ``LAW_FACTOR`` of the largest bandwidth's (the error falls as 1 / bandwidth there), that
    constant [rad^2/s], and the product at the next bandwidth below b_min (nan
    where there is none or it has no verified trial)."""
    out = {}
    free = cells[np.isinf(cells[LIMIT].astype(float))]
    for maneuver, group in free.groupby(MANEUVER, sort=False):
        line = group.sort_values(BANDWIDTH, ascending=False)
        product = (line["err_final_p95"] * line[BANDWIDTH]).to_numpy(dtype=float)
        bandwidths = line[BANDWIDTH].to_numpy(dtype=float)
        reference = product[0]
        k = 0
        while (k + 1 < len(product) and math.isfinite(product[k + 1])
               and abs(math.log(product[k + 1] / reference)) <= math.log(LAW_FACTOR)):
            k += 1
        below = product[k + 1] if k + 1 < len(product) else math.nan
        out[str(maneuver)] = (float(bandwidths[k]), float(reference), float(below))
    return out


def crossing_accounting(trials: pd.DataFrame) -> dict[str, Any]:
    """What the trials that crossed the controller's singular set became: how many crossed,
    under which torque limits, when they first crossed, how many ended within
    ``TRACKABLE_ERROR`` of the plan, the range of the others' final errors and error
    estimates, how many were verified; and the real divergences (the state unbounded:
    where no torque limit bounds the servo at the crossing) by torque limit and bandwidth."""
    crossed = trials[_column(trials, "crossings", 0).fillna(0) > 0]
    final = crossed["err_theta_final"].to_numpy(dtype=float)
    diverged = trials[trials["status"] == "diverged"]
    return {
        "crossed": len(crossed),
        "limits": sorted({float(v) for v in crossed[LIMIT]}),
        "first_median": float(crossed["first_crossing_time"].median()) if len(crossed)
        else math.nan,
        "recovered": int((final <= TRACKABLE_ERROR).sum()),
        "final_min": float(final.min()) if len(final) else math.nan,
        "final_median": float(np.median(final)) if len(final) else math.nan,
        "final_max": float(final.max()) if len(final) else math.nan,
        "estimate_median": float(crossed["err_estimate"].median()) if len(crossed)
        else math.nan,
        "verified": int(_column(crossed, "verified", False).fillna(False).astype(bool).sum()),
        **{name: int((_column(crossed, "outcome", "") == name).sum())
           for name in ("reached", "missed", "lost")},
        "diverged": len(diverged),
        "diverged_limits": sorted({float(v) for v in diverged[LIMIT]}),
        "diverged_bandwidth_max": float(diverged[BANDWIDTH].max()) if len(diverged)
        else math.nan,
    }


def finding(cells: pd.DataFrame, demands: Mapping[str, list[Any]],
            accounting: Mapping[str, Any] | None = None) -> str:
    """One paragraph: per maneuver, the least bandwidth that tracks with unlimited torque,
    the torque its joints then use, and the least torque limit that still tracks; the range
    of bandwidths where the error falls as 1 / bandwidth; and (with ``accounting``, from
    ``crossing_accounting``) what the trials that crossed the singular set became."""
    parts = []
    for maneuver in dict.fromkeys(cells[MANEUVER]):
        sel = cells[(cells[MANEUVER] == maneuver) & cells["trackable"]]
        free = sel[np.isinf(sel[LIMIT].astype(float))].sort_values(BANDWIDTH)
        name = f"the {maneuver}" if maneuver == "paper's cubic" else f"the {maneuver} plan"
        ideal = demands.get(str(maneuver))
        need = (f" (the plan itself needs {fmt(max(ideal[1], ideal[2]), 3)} N m and "
                f"{fmt(ideal[3], 3)} rad/s)") if ideal else ""
        if free.empty:
            best = cells[(cells[MANEUVER] == maneuver) & (cells["lost"] == 0)]
            best = best.sort_values("err_final_p95")
            text = (f"{name}{need} is trackable at no bandwidth of the study, even with "
                    "unlimited torque")
            if not best.empty:
                text += (f" (at best {fmt(best.iloc[0]['err_final_p95'], 2)} rad at "
                         f"{fmt(best.iloc[0][BANDWIDTH])} rad/s)")
            parts.append(text)
            continue
        first = free.iloc[0]
        limited = sel[np.isfinite(sel[LIMIT].astype(float))]
        text = (f"{name}{need} is trackable from a bandwidth of {fmt(first[BANDWIDTH])} rad/s "
                f"with unlimited torque, its joints then peaking at "
                f"{fmt(first['peak_torque_median'], 3)} N m (median over the trials)")
        if limited.empty:
            text += ", and under none of the torque limits of the study"
        else:
            least = limited[LIMIT].astype(float).min()
            where = limited[limited[LIMIT].astype(float) == least][BANDWIDTH]
            text += (f"; the least torque limit that still tracks is {fmt(least)} N m "
                     f"(at {_bandwidths(where)} rad/s)")
        parts.append(text)
    law = bandwidth_law(cells)
    ranges = "; ".join(
        f"{name}: from {fmt(low)} rad/s up (error x bandwidth {fmt(product, 2)} rad^2/s"
        + (f", against {fmt(below, 2)} one step below" if math.isfinite(below) else "")
        + ")" for name, (low, product, below) in law.items())
    text = (
        "**Finding.** A cell counts as trackable when every one of its trials reached "
        f"(outcome: each angle within track.goal_tolerance = {GOAL_TOLERANCE:g} rad of the "
        "goal at T; the number of trials is the study's per cell). "
        f"With the gains swapped and start errors of 2 mrad, {'; '.join(parts)}. With "
        "unlimited torque the joints lag their commands by about th'' / bandwidth and the "
        "final error falls as 1 / bandwidth, but only over a range of bandwidths (the product "
        f"within a factor {LAW_FACTOR:g} of its value at the largest bandwidth): {ranges}.")
    if accounting is None or not accounting["crossed"]:
        return text
    a = accounting
    limits = ", ".join(limit_text(v) for v in a["limits"])
    text += (
        f" {a['crossed']} trials crossed the controller's singular set (the margin "
        "sin th1 * u1 changed sign), all of them under a torque limit "
        f"({limits} N m), first at a median t = {fmt(a['first_median'], 2)} s: the servo "
        "saturates while the closed loop corrects the start error with torques far above the "
        "plan's own, the joints fall behind commands that the linearising feedback, which "
        "believes its rates are applied, keeps raising, and the margin reaches zero. Earlier "
        "versions of flatcli stopped every such trial there and called it diverged; the "
        "torque limit bounds the plant at the crossing, so flatcli now simulates on. Of them "
        f"{a['reached']} reached, {a['missed']} missed and {a['lost']} were lost (outcome); "
        f"{a['recovered']} ended within {TRACKABLE_ERROR:g} rad of the plan; the others ended "
        f"{fmt(a['final_min'], 2)} to {fmt(a['final_max'], 3)} rad from it (median "
        f"{fmt(a['final_median'], 3)} rad): the robot tumbles, a real loss of the maneuver, "
        "not the stopping rule's. Their final states are not verified (the twin solution's "
        f"estimate of their error has median {fmt(a['estimate_median'], 2)} rad against "
        f"track.accuracy; {a['verified']} of them meet it), so the tables leave them out of "
        "the error statistics and count them in the *crossed* column.")
    if a["diverged"]:
        limits = ", ".join(limit_text(v) for v in a["diverged_limits"])
        text += (
            f" The {a['diverged']} trials lost as diverged are real divergences: torque limit "
            f"{limits}, bandwidths up to {fmt(a['diverged_bandwidth_max'])} rad/s, where "
            "nothing bounds the servo's torque at the crossing and the state grows without "
            "bound.")
    return text


def run(context: Context) -> Outcome:
    """REPORT.md's "What the maneuver asks of the actuators" (and its runs into
    ``out/actuators``, its figure ``out/fig_actuators.png``); without the study (``--no-
    montecarlo``) the plans' demands only. The ``--set`` items of ``make reproduce`` apply to
    the study's spec too (e.g. ``sweep.trials``)."""
    base, out, steps = context.base, context.out, context.steps
    plans = [("paper's cubic", {}), *OPTIMIZED_PLANS]
    demands = plan_demands(base, plans, steps)
    lines = [
        "",
        "## What the maneuver asks of the actuators",
        "",
        "On the robot with inertia (`plant.model = \"dynamic\"`: free-floating multibody "
        "dynamics driven by joint torques from rate servos; flatcli's docs/physics.md, "
        "*The dynamic plant*). "
        "*Plan*: the joint torques M q'' + C q' that follow the plan exactly (inverse "
        f"dynamics on {PLAN_SAMPLES} samples, accelerations by complex step) and its peak "
        f"joint rate. *Closed loop*: the feedback with the gains swapped, servo bandwidth "
        f"{DEFAULT_SERVO_BANDWIDTH:g} rad/s, no torque limit, started on the plan or at "
        "Fig. 4's th(0) = (1.96, 0.8, -0.1); peak torque and rate, and the final angle "
        "error.",
        "",
        table(["plan", "plan: peak tau1 [N m]", "plan: peak tau2 [N m]",
               "plan: peak joint rate [rad/s]", "on plan: peak torque [N m]",
               "on plan: peak rate [rad/s]", "on plan: final error [rad]",
               "Fig. 4 start: peak torque [N m]", "Fig. 4 start: final error [rad]"],
              demands, 3),
    ]
    worst = max(demands, key=lambda row: max(row[1], row[2]))
    headline = [f"following a plan exactly takes up to {fmt(max(worst[1], worst[2]), 3)} N m "
                f"({worst[0]}); the closed loop from Fig. 4's start asks far more"]
    if not context.study:
        return Outcome(lines, headline, ())
    steps.step("the study: servo bandwidth x torque limit")
    spec, trials, kinematic_trials, wall = run_study(out, context.quiet, context.workers,
                                                     context.sets)
    cells = cell_table(trials)
    kinematic = kinematic_levels(kinematic_trials)
    plot_study(cells, kinematic, out / context.figures.name("fig_actuators"), context.figures)
    write_parquet(out / "actuators" / "cells.parquet", cells,
                  run_record("reproduce", spec.tree, study=STUDY.name))
    record_cells(out / "actuators")
    by_label = {row[0]: row for row in demands}
    matrix = []
    for maneuver in dict.fromkeys(cells[MANEUVER]):
        for limit in dict.fromkeys(cells[LIMIT]):
            sel = cells[(cells[MANEUVER] == maneuver) & (cells[LIMIT] == limit)]
            sel = sel.sort_values(BANDWIDTH)
            matrix.append([maneuver, limit_text(limit), *(
                matrix_entry(r) for _, r in sel.iterrows())])
    bandwidths = sorted(cells[BANDWIDTH].unique())
    order = {name: i for i, name in enumerate(dict.fromkeys(cells[MANEUVER]))}
    ordered = cells.assign(_m=cells[MANEUVER].map(order), _l=-cells[LIMIT].astype(float))
    ordered = ordered.sort_values(["_m", "_l", BANDWIDTH])
    full = [[r[MANEUVER], r[BANDWIDTH], limit_text(r[LIMIT]), r["trials"], r["reached"],
             r["lost"],
             r["diverged"], r["unresolved"], r["crossed"], r["tumbled"], r["unverified"],
             r["err_final_median"], r["err_final_p95"], r["peak_torque_median"],
             r["saturated"], r["drift_median"], r["drift_max"]]
            for _, r in ordered.iterrows()]
    levels = ", ".join(f"{name} {fmt(p95, 2)} rad ({reached:.0%} of its trials reached, "
                       f"{lost:.0%} lost)" for name, (p95, lost, reached) in kinematic.items())
    trackable = cells[cells["trackable"]]
    headline.append(f"study: {reached_text(_column(trials, 'outcome', ''))}")
    headline.append(f"{len(trackable)} of {len(cells)} (maneuver, servo bandwidth, torque limit) "
                    "cells track (every trial reached: each angle within "
                    f"{GOAL_TOLERANCE:g} rad of the goal at T)")
    return Outcome([
        *lines,
        "",
        "### Monte Carlo study: servo bandwidth and torque limit",
        "",
        f"`{STUDY.name}`: {len(cells)} cells of {spec.sweep.trials} trials "
        f"({len(trials)} in {wall:.0f} s), the gains swapped, th(0) = the plan's start plus "
        "errors of std 2 mrad, the nominal plant (the servo's computed torque is exact, so "
        "the actuators are the only difference from the kinematic plant). The same trials on "
        f"the kinematic plant: 95th percentile of the final angle error {levels}. Files: "
        "`actuators/` (trials.parquet, summary.md, cells.parquet; `kinematic/`), figure "
        f"`{context.figures.name('fig_actuators')}`.",
        "",
        finding(cells, by_label, crossing_accounting(trials)),
        "",
        "Each cell, by servo bandwidth [rad/s], says over which trials each number is: "
        "*k/n reached*, the trials whose outcome is reached of all n of the cell; *p95 x of "
        "m*, the 95th percentile of the final angle error [rad] over the m trials resolved "
        "to the end and verified (marked * where a cell has none and its m unverified ones "
        "are shown); *c/n crossed*, the trials of all n that crossed the singular set:",
        "",
        table(["maneuver", "torque limit [N m]", *(fmt(b) for b in bandwidths)], matrix, 2),
        "",
        "Every cell: fractions of its trials reached (outcome), lost (all, diverged, "
        "unresolved), that crossed the singular set, that crossed and ended beyond "
        f"{TRACKABLE_ERROR:g} rad (tumbled), and of the resolved trials not verified; median "
        "and 95th percentile of the final angle error [rad] and median peak torque [N m] "
        "(verified resolved trials), share of simulated trials whose servo hit the torque "
        "limit, median and max momentum drift max abs(H - H0) [kg m^2/s] (resolved trials; "
        "H from the full link kinematics, conserved by the dynamics alone: the "
        "integration's error).",
        "",
        table(["maneuver", "bandwidth", "torque limit", "trials", "reached", "lost", "diverged",
               "unresolved", "crossed", "tumbled", "unverified", "final error median",
               "final error p95", "peak torque median", "saturated", "drift median",
               "drift max"], full, 3),
    ], headline, FILES)


#: The files this section writes (globs under the output directory).
FILES = ("actuators/**/*", "fig_actuators.*")


def inputs(context: Context) -> dict[str, Any]:
    """The base spec and, with the study, its resolved spec (with the --set items)."""
    study = load_spec(study_path(), context.sets).tree if context.study else None
    return {"spec": context.base.tree, "study": study}


SECTION = Section("actuators", "what the maneuver asks of the actuators (the dynamic plant)",
                  inputs, run)
