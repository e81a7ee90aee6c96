"""The findings REPORT.md states in words, each computed from the runs it describes.

``make reproduce`` (``flatcli.reproduce``) lays out the report; the sentences here that draw
conclusions (which gain reading the paper meant, which optimised plans a controller can
track, which study trials the integrator could not resolve) read their numbers from the
closed-loop runs and the study's tables, never from constants typed in.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from flatcli import api
from flatcli.api import TrackRun
from flatcli.core.loop.metrics import OUTCOME_NAMES, RESOLVED, Metric, Status
from flatcli.core.plan.planning import Plan
from flatcli.report import cell_text, fmt, table
from flatcli.spec import Spec, SpecError

#: The two readings of the printed gains "kv1 = 100, kp1 = 10, kv2 = 110, kp2 = 13".
GAIN_READINGS: dict[str, dict[str, list[float]]] = {
    "printed": {"track.kp": [10.0, 13.0], "track.kv": [100.0, 110.0]},
    "swapped": {"track.kp": [100.0, 110.0], "track.kv": [10.0, 13.0]},
}
#: The optimised plans REPORT.md sets beside the paper's cubic (label, plan.optimize
#: overrides): the "Optimised plans" section and the actuators' demands.
OPTIMIZED_PLANS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("least energy", {"plan.optimize.objective": "energy"}),
    ("least energy, abs(th2) <= 3 rad, rates <= 5 rad/s, margin >= 0.05",
     {"plan.optimize.objective": "energy", "plan.optimize.angle_limit": [math.inf, math.inf, 3.0],
      "plan.optimize.rate_limit": 5.0, "plan.optimize.min_margin": 0.05}),
    ("least peak rate", {"plan.optimize.objective": "peak_rate"}),
    ("largest margin", {"plan.optimize.objective": "margin"}),
)
#: Lower bounds on the signed margin the least-energy plan is re-optimised under, to find
#: the least that the swapped gains can track from the paper's initial state [rad/s].
MARGIN_LADDER = (0.02, 0.05, 0.1, 0.2, 0.3, 0.4)


def plan_of(spec: Spec) -> Plan:
    """The spec's plan, through the public API (``flatcli.plan``)."""
    plan = api.plan(spec).plan
    assert plan is not None  # computed, not loaded
    return plan


def paper_plan(spec: Spec) -> Plan:
    """``plan_of`` where the analysis is of the paper's robot (N = 2)."""
    if spec.joints != 2:
        raise SpecError(f"robot.mass: this needs the paper's robot (3 links, 2 joints), got "
                        f"{spec.joints + 1} links")
    return plan_of(spec)


def track_of(spec: Spec) -> TrackRun:
    """The spec's closed-loop run, through the public API (``flatcli.track``)."""
    run = api.track(spec, quiet=True).run
    assert run is not None  # computed, not loaded
    return run


def _metric(run: TrackRun, metric: Metric) -> float:
    return float(run.outcome.metrics[0, metric])


def _status(run: TrackRun) -> str:
    return Status(int(run.outcome.status[0])).name.lower()


def gains_verdict(printed: TrackRun, swapped: TrackRun) -> str:
    """Which reading of the gains matches the paper's Fig. 4 claim, looking at the flat
    outputs and at the joint angles."""
    kp1, kv1 = (GAIN_READINGS["printed"][k][0] for k in ("track.kp", "track.kv"))
    slow = (-kv1 + np.sqrt(kv1 * kv1 - 4 * kp1)) / 2
    theta2 = swapped.columns["theta2"]
    return (
        f"With the gains as printed (kv1 = {kv1:g}, kp1 = {kp1:g}) the error dynamics "
        f"e'' + kv e' + kp e = 0 have a slow pole at {slow:.3f} rad/s: after 2 s the flat-"
        f"output error is still {fmt(_metric(printed, Metric.ERR_Y_FINAL), 3)} rad. With kv and "
        f"kp swapped it is {fmt(_metric(swapped, Metric.ERR_Y_FINAL), 3)} rad, which matches the "
        "paper's claim that the trajectories follow the desired ones closely (Fig. 4), **but "
        "only in the flat outputs**: on the way th2 swings from "
        f"{np.nanmax(theta2):+.2f} to {np.nanmin(theta2):+.2f} rad and the largest joint-angle "
        f"error is {fmt(_metric(swapped, Metric.ERR_THETA_MAX), 3)} rad (printed gains: "
        f"{fmt(_metric(printed, Metric.ERR_THETA_MAX), 3)} rad), the peak joint rate "
        f"{fmt(_metric(swapped, Metric.PEAK_RATE), 3)} rad/s. The swapped reading is the one "
        "that fits Fig. 4; neither keeps the arm near its planned angles in the first 0.5 s."
    )


@dataclass(frozen=True)
class TrackedPlan:
    """A plan tracked from the paper's initial state with both gain readings."""

    label: str
    plan: Plan
    runs: Mapping[str, TrackRun]


def track_plans(base: Spec, plans: Sequence[tuple[str, Mapping[str, Any]]]) -> list[TrackedPlan]:
    """Each plan of ``plans`` (label, spec overrides) planned and tracked from the spec's
    ``track.initial`` with the printed and the swapped gains (u1(0) = the plan's th1'(0))."""
    out = []
    for label, overrides in plans:
        runs = {reading: track_of(base.with_overrides({**overrides, **gains}))
                for reading, gains in GAIN_READINGS.items()}
        out.append(TrackedPlan(label, runs["printed"].plan, runs))
    return out


def tracked_plans_table(tracked: Sequence[TrackedPlan]) -> str:
    rows: list[list[Any]] = []
    for entry in tracked:
        rate0 = float(entry.plan.trajectory.derivative(np.array([0.0]), 1)[0, 0])
        rateT = float(entry.plan.trajectory.derivative(np.array([entry.plan.duration]), 1)[0, 0])
        for reading, run in entry.runs.items():
            rows.append([entry.label, f"{fmt(rate0, 3)}, {fmt(rateT, 3)}", reading, _status(run),
                         _metric(run, Metric.ERR_Y_FINAL), _metric(run, Metric.ERR_THETA_MAX),
                         _metric(run, Metric.PEAK_RATE), _metric(run, Metric.MIN_MARGIN)])
    return table(["plan", "th1'(0), th1'(T) [rad/s]", "gains", "status", "final y error [rad]",
                  "max theta error [rad]", "peak joint rate [rad/s]", "min margin [rad/s]"],
                 rows, 3)


def margin_ladder(base: Spec) -> tuple[str, str]:
    """The least-energy plan re-optimised under growing margin bounds, tracked with the
    swapped gains: a table, and the sentence naming the least margin that tracks."""
    rows: list[list[Any]] = []
    trackable: float | None = None
    for margin in MARGIN_LADDER:
        overrides = {"plan.optimize.objective": "energy", "plan.optimize.min_margin": margin}
        plan = plan_of(base.with_overrides(overrides))
        run = track_of(base.with_overrides({**overrides, **GAIN_READINGS["swapped"]}))
        status = _status(run)
        if trackable is None and status == "ok":
            trackable = margin
        rows.append([margin, plan.input_energy(), status, _metric(run, Metric.ERR_Y_FINAL),
                     _metric(run, Metric.ERR_THETA_MAX), _metric(run, Metric.PEAK_RATE)])
    text = table(["min margin [rad/s]", "energy [rad^2/s]", "status (swapped gains)",
                  "final y error [rad]", "max theta error [rad]", "peak joint rate [rad/s]"],
                 rows, 4)
    if trackable is None:
        sentence = (f"None of the margins {list(MARGIN_LADDER)} rad/s made the least-energy plan "
                    "trackable with the swapped gains from the paper's initial state.")
    else:
        energy = rows[MARGIN_LADDER.index(trackable)][1]
        sentence = (
            "The least-energy plan rides the margin floor and the swapped gains lose it from "
            "the paper's initial state (the controller's margin sin th1 * u1 reaches zero); "
            f"a margin of at least {trackable:g} rad/s makes it trackable (ok, no singular hits), "
            f"at an energy of {fmt(energy, 4)} rad^2/s instead of "
            f"{fmt(rows[0][1], 4)}.")
    return text, sentence


def outcome_counts(outcomes: Sequence[str] | pd.Series) -> dict[str, int]:
    """How many trials had each outcome (``OUTCOME_NAMES``), and ``trials`` in all."""
    values = [str(o) for o in outcomes]
    return {"trials": len(values), **{name: values.count(name) for name in OUTCOME_NAMES}}


def reached_text(outcomes: Sequence[str] | pd.Series) -> str:
    """"k of n trials reached (p %, 95 % interval a-b %); c collided, m missed, l lost": a
    study's outcomes in words (the interval: Wilson's score interval), over all its
    trials."""
    from flatcli.report.summary import wilson_interval

    c = outcome_counts(outcomes)
    n = c["trials"]
    if not n:
        return "no trials"
    low, high = wilson_interval(c["reached"], n)
    return (f"{c['reached']} of {n} trials reached ({100 * c['reached'] / n:.3g} %, 95 % "
            f"interval {100 * float(low):.3g}-{100 * float(high):.3g} %); {c['collided']} "
            f"collided, {c['missed']} missed, {c['lost']} lost")


def study_findings(summary: pd.DataFrame, trials_path: Path) -> list[str]:
    """What the Monte Carlo study found, by gain reading: singular hits, final errors of the
    trials resolved to the end, and which cells hold the trials that were not."""
    lines: list[str] = []
    if "gains" not in summary.columns:
        return lines
    frame = pd.read_parquet(trials_path, columns=["cell", "gains", "status", "steps",
                                                  "momentum_drift", "err_estimate", "outcome",
                                                  "err_theta_final"])
    grid = [k for k in summary.columns[1: list(summary.columns).index("trials")] if k != "gains"]
    for label in GAIN_READINGS:
        sel = summary[summary["gains"] == label]
        trials = frame[frame["gains"] == label]
        if sel.empty:
            continue
        resolved = trials[trials["status"].isin(RESOLVED)]
        unresolved = int((trials["status"] == "unresolved").sum())
        diverged = int((trials["status"] == "diverged").sum())
        failing = sel[(sel["diverged"] + sel["unresolved"]) > 0]
        where = "; ".join(
            f"cell {int(r['cell'])} ({', '.join(f'{k} = {cell_text(r[k])}' for k in grid)}): "
            f"{int(r['diverged'])} diverged, {int(r['unresolved'])} unresolved"
            for _, r in failing.iterrows())
        best = sel.sort_values("reached_fraction", ascending=False).iloc[0]
        worst = sel.sort_values("reached_fraction").iloc[0]
        lines.append(
            f"- gains {label}: {reached_text(trials['outcome'])} (reached: every angle within "
            "track.goal_tolerance of the goal at T); per cell from "
            f"{100 * worst['reached_fraction']:.3g} % (cell {int(worst['cell'])}) to "
            f"{100 * best['reached_fraction']:.3g} % (cell {int(best['cell'])}). Median final "
            "angle error over ALL its trials, a lost one counted as infinitely wrong, "
            f"{fmt(sel['err_theta_final_median_all'].min(), 3)} to "
            f"{fmt(sel['err_theta_final_median_all'].max(), 3)} rad across cells. "
            f"{len(resolved)} of {len(trials)} trials resolved to the end (ok or singular); "
            f"singular-hit rate {fmt(sel['singular_fraction'].min(), 3)} to "
            f"{fmt(sel['singular_fraction'].max(), 3)} across cells; median final y error "
            f"over the resolved trials {fmt(sel['err_y_final_median'].min(), 3)} to "
            f"{fmt(sel['err_y_final_median'].max(), 3)} rad; {diverged} diverged and "
            f"{unresolved} unresolved" + (f", in {where}." if where else ".")
        )
        if len(resolved):
            lines.append(
                f"  Their integration: median {int(resolved['steps'].median())} steps "
                f"(95th percentile {int(resolved['steps'].quantile(0.95))}), error estimate "
                f"median {fmt(resolved['err_estimate'].median(), 2)} rad, largest momentum "
                f"drift {fmt(resolved['momentum_drift'].max(), 2)} kg m^2/s (H from the full "
                "kinematics at the plant's applied rates: rounding)."
            )
    return lines
