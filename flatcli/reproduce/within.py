"""``make reproduce``'s section "Within the actuators": the paper's feedback against the MPC
over a grid of joint-rate limits.

The paper's maneuver on the kinematic plant, whose joint rates are clipped at
``track.rate_limit`` (``flatcli/data/within_actuators.toml``): the paper's feedback (gains
swapped) tracks the paper's cubic, which peaks at 48.8 rad/s, whatever the limit; the MPC
(``track.controller = "mpc"``, default settings) tracks the plan of least peak joint rate
between the same ends when the cubic turns faster than the limit it keeps (docs/physics.md,
"Re-planning within the limit"). Each cell is counted by outcome (reached, collided, missed,
lost; the reached fraction with its 95 % Wilson interval), over all its trials. A second,
smaller study repeats the comparison with no limit and initial errors ten times larger
(``WIDE_STD``), where the paper's feedback loses trials through the singular set. A third
(``dynamic_spec``) compares them on the dynamic plant over torque limits (``TORQUE_LIMITS``),
where the MPC re-plans within the limit (docs/physics.md, "Within the torque limit").
"""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from flatcli.report import FigureFile, fmt, new_figure, save_figure, styled, table
from flatcli.report.summary import wilson_interval
from flatcli.reproduce.findings import outcome_counts, reached_text
from flatcli.reproduce.sections import Context, Outcome, Section, with_shared_sets
from flatcli.spec import Spec, load_spec

#: The study's spec, shipped with flatcli (package data; configs/ links to it).
STUDY = Path(str(resources.files("flatcli") / "data" / "within_actuators.toml"))
#: The section's directory, inside the output directory, and its figure's file name.
DIRECTORY = "within"
FIGURE = "fig_within"
LIMIT, CONTROLLER = "track.rate_limit", "track.controller"
CONTROLLERS = ("flat", "mpc")
NAMES = {"flat": "paper's feedback", "mpc": "MPC"}
#: The second study: no limit, initial errors of this std [rad].
WIDE_STD = 0.02
#: The issue's goal for the MPC: the reached fraction at the limits of the grid where a
#: plan within the limit exists, and with no limit at ``WIDE_STD``.
GOAL_FRACTION = 0.99
#: The third study: the dynamic plant (``benchmarks/mpc_torque.toml``'s settings: the paper's
#: cubic, servo bandwidth ``BANDWIDTH``, the servo's model right) over these torque limits
#: [N m], at most ``DYNAMIC_TRIALS`` trials a cell (fewer when ``sweep.trials`` is).
TORQUE = "plant.torque_limit"
TORQUE_LIMITS = (math.inf, 30.0, 10.0, 3.0, 1.0)
BANDWIDTH = 100.0
DYNAMIC_TRIALS = 40
#: The issue's goal on the dynamic plant: the MPC's reached fraction at the torque limits
#: where the paper's feedback loses most trials (over half not reached).
DYNAMIC_GOAL = 0.95


def study_spec(context: Context) -> Spec:
    """The study's spec with the --set items that apply (its trials and seed)."""
    return with_shared_sets(load_spec(STUDY), context.sets)


def wide_spec(spec: Spec) -> Spec:
    """The second study: ``spec`` with no limit and initial errors of std ``WIDE_STD``."""
    return spec.with_overrides({
        "name": "within_actuators_wide",
        "sweep.grid": {CONTROLLER: list(CONTROLLERS)},
        "sweep.perturb": {"initial": {"dist": "normal", "std": WIDE_STD}}})


def dynamic_spec(spec: Spec) -> Spec:
    """The third study: ``spec`` on the dynamic plant (servo bandwidth ``BANDWIDTH``, the
    servo's model the nominal robot, which is the plant), the paper's cubic (``plan.basis``
    "poly"), no rate limit, both controllers over ``TORQUE_LIMITS``, at most
    ``DYNAMIC_TRIALS`` trials a cell."""
    return spec.with_overrides({
        "name": "within_actuators_dynamic",
        "plant.model": "dynamic", "plant.servo_bandwidth": BANDWIDTH,
        "plant.servo_model": "robot", "plan.basis": "poly",
        "sweep.trials": min(DYNAMIC_TRIALS, int(spec.sweep.trials)),
        "sweep.grid": {TORQUE: list(TORQUE_LIMITS), CONTROLLER: list(CONTROLLERS)}})


def _sweep(spec: Spec, directory: Path, context: Context) -> pd.DataFrame:
    from flatcli import api

    api.sweep(spec, directory, workers=context.workers, force=True, quiet=context.quiet)
    return pd.read_parquet(directory / "trials.parquet")


def cell_rows(trials: pd.DataFrame, key: str = LIMIT) -> pd.DataFrame:
    """One row per (limit, controller), in the grid's order (``key``: the limit's spec key,
    ``LIMIT`` or ``TORQUE``; inf where the trials have no such column): the trials, the count
    of each outcome, the reached fraction and its 95 % Wilson interval, the median final error
    (over the trials that reached T: outcome reached or missed), whether the MPC re-planned,
    its samples that needed slack (trials with any), the longest clipped time [s], the trials
    of status singular, and on the dynamic plant the median peak torque applied [N m] and the
    trials whose torque was clipped (NaN where the columns are absent or null)."""
    rows = []
    limits = trials[key] if key in trials else pd.Series(math.inf, index=trials.index)
    keyed = trials.assign(**{key: limits})
    for (limit, controller), cell in keyed.groupby([key, CONTROLLER], sort=False):
        counts = outcome_counts(cell["outcome"])
        n = counts["trials"]
        low, high = wilson_interval(counts["reached"], n)
        ended = cell[cell["outcome"].isin(("reached", "missed"))]
        replanned: Any = cell["replanned"].dropna().unique() if "replanned" in cell else []
        slack = (cell["qp_infeasible"].fillna(0) > 0).sum() if "qp_infeasible" in cell else 0
        torque = (cell["peak_torque"].astype(float) if "peak_torque" in cell
                  else pd.Series(math.nan, index=cell.index))
        saturated = (cell["torque_saturated"].astype(float) if "torque_saturated" in cell
                     else pd.Series(math.nan, index=cell.index))
        rows.append({
            key: float(limit), CONTROLLER: str(controller), **counts,  # type: ignore[arg-type]
            "fraction": counts["reached"] / n if n else math.nan,
            "low": float(low), "high": float(high),
            "median": float(ended["err_theta_final"].median()) if len(ended) else math.nan,
            "replanned": bool(replanned[0]) if len(replanned) else None,
            "slack_trials": int(slack) if controller == "mpc" else None,
            "clipped_max": float(cell["clipped_time"].max()),
            "singular": int((cell["status"] == "singular").sum()) if "status" in cell else 0,
            "peak_torque": float(torque.median()) if torque.notna().any() else math.nan,
            "torque_clipped": (int((saturated > 0).sum()) if saturated.notna().any()
                               else math.nan),
            "clipped_unreached": (int(((saturated > 0) & (cell["outcome"] != "reached")).sum())
                                  if saturated.notna().any() else math.nan),
        })
    return pd.DataFrame(rows)


def gains(values: Any) -> str:
    """Gains in a sentence: "[100, 110]"."""
    return "[" + ", ".join(f"{float(v):g}" for v in values) + "]"


def limit_text(limit: float) -> str:
    """A rate limit for a table: "none" for inf, else its value [rad/s]."""
    return "none" if math.isinf(limit) else f"{limit:g}"


def percent(low: float, high: float) -> str:
    return f"{100 * low:.3g}-{100 * high:.3g} %"


def _cell_head(r: pd.Series, key: str) -> list[Any]:
    """A cell's first columns in both tables: its limit (``key``), controller, the plan it
    tracked, reached of trials, and the reached fraction with its interval."""
    replan = "-" if pd.isna(r["replanned"]) else ("re-planned" if r["replanned"]
                                                 else "as planned")
    return [limit_text(r[key]), NAMES[r[CONTROLLER]], replan,
            f"{r['reached']} of {r['trials']}",
            f"{100 * r['fraction']:.3g} % ({percent(r['low'], r['high'])})"]


def outcome_table(rows: pd.DataFrame) -> str:
    """The cells as a Markdown table, by outcome."""
    body = []
    for _, r in rows.iterrows():
        body.append([*_cell_head(r, LIMIT), r["collided"], r["missed"], r["lost"],
                     r["median"], "-" if pd.isna(r["slack_trials"]) else int(r["slack_trials"]),
                     r["clipped_max"]])
    return table(["rate limit [rad/s]", "controller", "plan tracked", "reached",
                  "reached (95 % interval)", "collided", "missed", "lost",
                  "median final error [rad]", "trials with QP slack",
                  "longest clipped [s]"], body, 3, align=False)


def torque_table(rows: pd.DataFrame) -> str:
    """The dynamic study's cells (``cell_rows(.., TORQUE)``) as a Markdown table, by
    outcome."""
    body = []
    for _, r in rows.iterrows():
        body.append([*_cell_head(r, TORQUE), r["missed"], r["lost"], r["singular"],
                     r["median"], r["peak_torque"], r["torque_clipped"]])
    return table(["torque limit [N m]", "controller", "plan tracked", "reached",
                  "reached (95 % interval)", "missed", "lost", "status singular",
                  "median final error [rad]", "median peak torque [N m]",
                  "trials with torque clipped"], body, 3, align=False)


def torque_at(limit: float) -> str:
    """A torque limit in a sentence: "with no torque limit" or "at 30 N m"."""
    return "with no torque limit" if math.isinf(limit) else f"at {limit:g} N m"


def torque_finding(rows: pd.DataFrame) -> str:
    """The dynamic study's finding, from its cells (``cell_rows(.., TORQUE)``): at each
    torque limit where the paper's feedback loses most trials (over half not reached), the
    two controllers' reached fractions; where the MPC reaches fewer than ``DYNAMIC_GOAL``,
    how many of its trials had their torque clipped (its corrections' own torque)."""
    flat = rows[rows[CONTROLLER] == "flat"]
    mpc = rows[rows[CONTROLLER] == "mpc"].set_index(TORQUE)
    losing = [r for _, r in flat.iterrows() if r["reached"] < r["trials"] / 2]
    parts, short = [], []
    for r in losing:
        m = mpc.loc[r[TORQUE]]
        parts.append(f"{torque_at(r[TORQUE])} the paper's feedback reaches "
                     f"{100 * r['fraction']:.3g} % ({r['missed']} missed, {r['lost']} lost; "
                     f"{r['singular']} singular), the MPC {100 * m['fraction']:.3g} % "
                     f"({percent(m['low'], m['high'])})")
        if m["fraction"] < DYNAMIC_GOAL:
            short.append((r[TORQUE], m))
    met = [r[TORQUE] for r in losing if mpc.loc[r[TORQUE]]["fraction"] >= DYNAMIC_GOAL]
    if not losing:
        return "The paper's feedback reaches at least half the trials at every torque limit."
    joined = "; ".join(parts)
    text = (joined[:1].upper() + joined[1:] + f". The MPC keeps at least "
            f"{100 * DYNAMIC_GOAL:g} % reached at {len(met)} of these {len(losing)} limits")
    if short:
        text += "; it cannot " + "; ".join(
            f"{torque_at(v)} ({m['reached']} of {m['trials']} reached; {m['torque_clipped']} "
            f"of its trials had their torque clipped, {m['clipped_unreached']} of the "
            f"{m['trials'] - m['reached']} not reached among them; median peak torque "
            f"{fmt(m['peak_torque'], 3)} N m)" for v, m in short)
        text += (": the re-plan keeps the limit and the QP's torque rows bound the torque "
                 "the MPC predicts, but their model misses the servo's by about 0.02 N m (of "
                 "order 1/b) and its start, and there the corrections of the start errors "
                 "exceed it (docs/physics.md, \"The torque rows\")")
    return text + "."


@styled
def plot_fraction(rows: pd.DataFrame, trials: int, std: float, lowest: float, path: Path,
                  figures: FigureFile | None = None) -> None:
    """The fraction of trials reached against the rate limit, both controllers, with their
    95 % intervals; no limit drawn at the right beyond the grid's largest limit; a dotted
    line at ``lowest``, the least limit a plan can keep [rad/s]."""
    finite = sorted({float(v) for v in rows[LIMIT] if math.isfinite(v)})
    unlimited = finite[-1] * 2.0 if finite else 1.0
    fig = new_figure(5.2, 3.2)
    fig.set_layout_engine("constrained")
    ax = fig.subplots()
    ax.axvline(lowest, color="0.4", ls=":", lw=1.0,
               label=f"least limit a plan keeps ({lowest:.3g} rad/s)")
    for k, controller in reversed(list(enumerate(CONTROLLERS))):  # the MPC's below
        sel = rows[rows[CONTROLLER] == controller].copy()
        x = np.array([unlimited if math.isinf(v) else v for v in sel[LIMIT]])
        order = np.argsort(x)
        y = sel["fraction"].to_numpy(dtype=float)[order]
        error = np.vstack([y - sel["low"].to_numpy(dtype=float)[order],
                           sel["high"].to_numpy(dtype=float)[order] - y])
        ax.errorbar(x[order], 100 * y, yerr=100 * error, fmt="os"[k] + "-", color=f"C{k}",
                    capsize=3, ms=4 if k == 0 else 7, label=NAMES[controller] + (
                        " (paper's cubic)" if controller == "flat" else " (re-plans when needed)"))
    ax.set_xscale("log")
    ticks = [*finite, unlimited]
    ax.set_xticks(ticks)
    ax.set_xticklabels([f"{v:g}" for v in finite] + ["none"])
    ax.minorticks_off()
    ax.set_ylim(-5, 105)
    ax.set_xlabel("joint-rate limit [rad/s] (log scale)")
    ax.set_ylabel("trials reached [%]")
    handles, labels = ax.get_legend_handles_labels()
    ax.legend(handles[::-1], labels[::-1], loc="center right")
    ax.set_title(f"Paper's maneuver, kinematic plant: {trials} trials per point,\n"
                 f"initial errors of std {std * 1000:g} mrad (bars: 95 % Wilson intervals)")
    save_figure(fig, path, figures)


def _fraction_at(rows: pd.DataFrame, controller: str, limit: float) -> Any:
    return rows[(rows[CONTROLLER] == controller) & (rows[LIMIT] == limit)].iloc[0]


def mpc_settings(spec: Spec) -> Any:
    """The spec's MPC settings (``track.mpc_*``)."""
    from flatcli.core.controllers.settings import settings_of

    return settings_of(spec.track)["mpc"]


def least_peak(spec: Spec) -> float:
    """The least peak joint rate of a plan of the study's maneuver whose margin is at least
    the MPC's [rad/s] (the plan the MPC tracks under a limit the cubic exceeds), through the
    public API: ``flatcli.plan`` with ``plan.optimize.objective = "peak_rate"``."""
    import flatcli

    planned = flatcli.plan(spec, {"plan.optimize.objective": "peak_rate",
                                  "plan.optimize.min_margin": mpc_settings(spec).margin})
    plan = planned.plan
    assert plan is not None  # a maneuver's plan
    samples = plan.sample(plan.grid(spec.plan.samples))
    return float(np.abs(samples.theta_dot[:, 1:]).max())


def run(context: Context) -> Outcome:
    """Both studies into OUT/within, the figure, and the section's lines."""
    out = context.out / DIRECTORY
    spec = study_spec(context)
    context.steps.step("the rate-limit grid: both controllers' sweep")
    grid = _sweep(spec, out / "grid", context)
    rows = cell_rows(grid)
    context.steps.step(f"no limit, errors of std {WIDE_STD:g} rad: both controllers' sweep")
    wide_trials = _sweep(wide_spec(spec), out / "wide", context)
    wide = cell_rows(wide_trials)
    context.steps.step("the dynamic plant over torque limits: both controllers' sweep")
    dyn = dynamic_spec(spec)
    dynamic = cell_rows(_sweep(dyn, out / "dynamic", context), TORQUE)
    std = float(spec.sweep.perturb["initial"]["std"])
    trials = int(spec.sweep.trials)
    figure = context.figures.name(FIGURE)
    peak = least_peak(spec)
    kept = 1.0 - float(mpc_settings(spec).backoff)
    plot_fraction(rows, trials, std, peak / kept, context.out / figure, context.figures)
    feasible = [float(v) for v in rows[LIMIT].unique() if v * kept >= peak]
    infeasible = [float(v) for v in rows[LIMIT].unique() if v * kept < peak]
    met = [v for v in feasible if _fraction_at(rows, "mpc", v)["fraction"] >= GOAL_FRACTION]
    mpc_wide = _fraction_at(wide, "mpc", math.inf)
    flat_wide = _fraction_at(wide, "flat", math.inf)
    flat_text = {limit_text(v): _fraction_at(rows, "flat", v) for v in (4.0, 6.0)
                 if v in set(rows[LIMIT])}
    lines = [
        "",
        "## Within the actuators: the paper's feedback against the MPC",
        "",
        "No controller of the paper knows the actuators: the paper's feedback commands "
        "whatever rate its law asks and the plant clips it at `track.rate_limit`. The MPC "
        "(`track.controller = \"mpc\"`, docs/physics.md) keeps the joint rates within the "
        "limit (1 - `mpc_backoff`) and the singularity margin at the predicted samples, and "
        "brings the error to zero at T; when the plan itself turns faster than that (the "
        "paper's cubic peaks at 48.8 rad/s) it tracks the plan of least peak joint rate "
        "between the same ends in the same duration (column `replanned`). The paper's "
        "feedback tracks the paper's cubic whatever the limit. The paper's maneuver on the "
        f"kinematic plant (`{STUDY.name}`, files `{DIRECTORY}/grid`), {trials} trials per "
        f"cell from th(0) errors of std {std * 1000:g} mrad; each cell by outcome over all "
        "its trials (reached: every angle within track.goal_tolerance of the goal at T), "
        "the median final error over the trials that reached T. The least peak joint rate "
        f"of a plan of this maneuver with the MPC's margin is {fmt(peak, 4)} rad/s, so the "
        "MPC can keep limits down to "
        f"{fmt(peak / kept, 3)} rad/s; below, it tracks that plan and warns.",
        "",
        outcome_table(rows),
        "",
        f"**Finding.** The MPC reaches the goal in at least {100 * GOAL_FRACTION:g} % of "
        f"the trials at {len(met)} of the {len(feasible)} limits a plan can keep"
        + (f" ({', '.join(limit_text(v) for v in sorted(met, reverse=True))} rad/s)"
           if met else "")
        + (f"; at {', '.join(limit_text(v) for v in infeasible)} rad/s no plan of this "
           "maneuver keeps the limit, and it misses" if infeasible else "")
        + ". The paper's feedback on the cubic "
        + "; ".join(f"at {k} rad/s reaches {r['reached']} of {r['trials']} (median final "
                    f"error {fmt(r['median'], 3)} rad)" for k, r in flat_text.items())
        + ". With no limit and initial errors of std "
        f"{WIDE_STD * 1000:g} mrad (files `{DIRECTORY}/wide`): MPC "
        f"{reached_text(wide_trials[wide_trials[CONTROLLER] == 'mpc']['outcome'])}; paper's "
        f"feedback {reached_text(wide_trials[wide_trials[CONTROLLER] == 'flat']['outcome'])}.",
        "",
        f"Figure `{figure}`: the fraction reached against the rate limit, both controllers.",
        "",
        "**On the dynamic plant, within the torque limit.** The same maneuver on the dynamic "
        f"plant (joint rates from servos of bandwidth {BANDWIDTH:g} rad/s, the servo's model "
        "right; no rate limit), the joint torques clipped at `plant.torque_limit` (files "
        f"`{DIRECTORY}/dynamic`, {int(dyn.sweep.trials)} trials per cell, th(0) errors of std "
        f"{std * 1000:g} mrad, the study's gains kp = {gains(dyn.track.kp)}, kv = "
        f"{gains(dyn.track.kv)}; else `benchmarks/mpc_torque.toml`'s settings). The paper's "
        "cubic "
        "asks 32.6 N m; at a limit below that (less `mpc_backoff`) the MPC tracks the plan "
        "of largest singularity margin between the same ends, which asks 0.325 N m "
        "(docs/physics.md, \"Within the torque limit\"); the paper's feedback the cubic. "
        "Singular: trials whose margin crossed or came near the singular set (status "
        "`singular`, among the outcomes).",
        "",
        torque_table(dynamic),
        "",
        f"**Finding.** {torque_finding(dynamic)}",
    ]
    tightest = min(feasible)
    at = grid[grid[LIMIT] == tightest]
    headline = [
        f"at {limit_text(tightest)} rad/s, MPC (re-planned): "
        f"{reached_text(at[at[CONTROLLER] == 'mpc']['outcome'])}; paper's feedback: "
        f"{reached_text(at[at[CONTROLLER] == 'flat']['outcome'])}",
        "MPC within the joint-rate limits: "
        + ", ".join(f"{limit_text(r[LIMIT])} rad/s {r['reached']}/{r['trials']}"
                    for _, r in rows[rows[CONTROLLER] == "mpc"].iterrows())
        + " trials reached; paper's feedback "
        + ", ".join(f"{limit_text(r[LIMIT])} {r['reached']}/{r['trials']}"
                    for _, r in rows[rows[CONTROLLER] == "flat"].iterrows())
        + f"; no limit, {WIDE_STD * 1000:g} mrad: MPC {mpc_wide['reached']}/"
        f"{mpc_wide['trials']}, paper's feedback {flat_wide['reached']}/{flat_wide['trials']}",
        "dynamic plant, MPC within the torque limits: "
        + ", ".join(f"{limit_text(r[TORQUE])} N m {r['reached']}/{r['trials']}"
                    for _, r in dynamic[dynamic[CONTROLLER] == "mpc"].iterrows())
        + " trials reached; paper's feedback "
        + ", ".join(f"{limit_text(r[TORQUE])} {r['reached']}/{r['trials']}"
                    for _, r in dynamic[dynamic[CONTROLLER] == "flat"].iterrows())]
    return Outcome(lines, headline, (f"{DIRECTORY}/**/*", f"{FIGURE}.*"))


def inputs(context: Context) -> dict[str, object]:
    """The study's resolved spec (with the --set items that apply), the wide study's std and
    the dynamic study's resolved spec."""
    spec = study_spec(context)
    return {"spec": spec.tree, "wide_std": WIDE_STD, "dynamic": dynamic_spec(spec).tree}


SECTION = Section("within", "within the actuators: the paper's feedback against the MPC",
                  inputs, run, applies=lambda context: context.study)

