"""REPORT.md's "A capture maneuver among obstacles": an end-effector task of the paper's robot
(``flatcli/data/capture.toml``, docs/tasks.md), planned rest to rest with its obstacles
proven clear over [0, T], tracked in closed loop from the plan's start and from a perturbed
one; its filmstrip ``fig_capture``; and the map of where the end effector can be put from
the same start (``flatcli workspace``), ``fig_workspace``."""

from __future__ import annotations

from importlib import resources
from typing import Any

import numpy as np

from flatcli.api import load_spec, plan, track, workspace
from flatcli.report import fmt, save_figure, table
from flatcli.report.task_figures import filmstrip_figure
from flatcli.reproduce.sections import Context, Outcome, Section
from flatcli.storage import to_jsonable

CAPTURE_SPEC = resources.files("flatcli") / "data" / "capture.toml"
#: The perturbed start of the second closed-loop run [rad], and the start of the third,
#: 0.1 rad off in th0: the rest loop carries it open loop through the fade-in into a disc.
PERTURBED = [1.82, 0.99, 0.01]
PUSHED = [1.9, 1.0, 0.0]
#: The workspace map's window of final base attitudes: the task's +- this [rad].
ATTITUDE_WINDOW = 0.2


def _spec_path() -> str:
    return str(CAPTURE_SPEC)


def inputs(context: Context) -> dict[str, Any]:
    """The capture spec, resolved."""
    return {"spec": to_jsonable(load_spec(_spec_path()).tree)}


def run(context: Context) -> Outcome:
    out = context.out / "capture"
    context.steps.step("capture: plan")
    p = plan(_spec_path())
    p.save(out / "plan", force=True)
    s = p.spec
    context.steps.step("capture: track")
    exact = track(_spec_path(), quiet=True)
    exact.save(out / "track", force=True)
    moved = track(_spec_path(), {"track.initial": PERTURBED}, quiet=True)
    moved.save(out / "track_perturbed", force=True)
    pushed = track(_spec_path(), {"track.initial": PUSHED}, quiet=True)
    pushed.save(out / "track_pushed", force=True)
    frame = p.frame
    theta = frame[[f"theta{i}" for i in range(3)]].to_numpy()
    fig = filmstrip_figure(p.plan.robot if p.plan else None,  # type: ignore[arg-type]
                           frame["t"].to_numpy(), theta, s.task.obstacles, s.task.clearance,
                           s.task.end_effector, "capture among obstacles, rest to rest")
    name = context.figures.name("fig_capture")
    save_figure(fig, context.out / name, context.figures)
    m = p.metrics
    rows = [
        ["plan", "-", fmt(m["ee_error_final"]), fmt(m["base_attitude_error_final"]),
         fmt(m["min_clearance"]), fmt(m["clearance_bound"]), "-"],
        *([f"track, from {where}", r.metrics["outcome"], fmt(r.metrics["ee_error_final"]),
           fmt(r.metrics["base_attitude_error_final"]), fmt(r.metrics["min_clearance"]),
           fmt(r.metrics["clearance_bound"]), fmt(r.metrics["err_theta_max"])]
          for where, r in (("the plan's start", exact), (str(PERTURBED), moved),
                           (str(PUSHED), pushed))),
    ]
    rates = np.abs(frame[["theta0_dot", "theta1_dot", "theta2_dot"]].to_numpy()[[0, -1]]).max()
    lines = [
        f"The paper's robot puts its end effector on {list(s.task.end_effector or ())} m with "
        f"the base at {s.task.base_attitude} rad, from rest to rest (rates at the ends: "
        f"{rates:g} rad/s), every link {s.task.clearance} m clear of three discs, proven over "
        f"all of [0, T] by interval arithmetic ({m['certified_intervals']} intervals; "
        f"{m['task_candidates']} candidate plans tried). Tracked with the feedback faded in "
        "and out (docs/tasks.md).",
        "",
        table(["run", "outcome", "ee_error_final [m]", "base_attitude_error_final [rad]",
               "min_clearance [m]", "clearance bound [m]", "err_theta_max [rad]"], rows),
        "",
        "outcome: reached (every angle within track.goal_tolerance and the end effector "
        "within task.goal_tolerance at T), collided (a link inside a disc at a sample, or "
        "not shown clear between two), missed; why: "
        + "; ".join(f"from {where}: {r.metrics['outcome_reason']}"
                    for where, r in (("the plan's start", exact), (str(PERTURBED), moved),
                                     (str(PUSHED), pushed)))
        + ". Clearance bound: the plan's proven one (interval arithmetic over [0, T]); a "
        "track run's closed-loop bound over its recorded motion (docs/outputs.md, "
        "*Outcomes*).",
        "",
        f"![capture]({name})",
    ]
    context.steps.step("capture: workspace")
    a = float(s.task.base_attitude if s.task.base_attitude is not None
              else p.frame["theta0"].iloc[-1])
    window = (a - ATTITUDE_WINDOW, a + ATTITUDE_WINDOW)
    w = workspace(_spec_path(), attitude=window)
    w.save(out / "workspace", force=True)
    wname = context.figures.name("fig_workspace")
    save_figure(w.plot(), context.out / wname, context.figures)
    wm = w.metrics
    lines += [
        "",
        f"Where the end effector can be put from the same start with th0(T) in "
        f"[{window[0]:g}, {window[1]:g}] rad (`flatcli workspace`, {wm['points']} x "
        f"{wm['points']} targets, {wm['attitudes']} attitudes; docs/tasks.md):",
        "",
        table(["region", "area [m^2]"],
              [[k.replace("_", " "), fmt(wm[f"area_{k}"])]
               for k in ("reachable", "both", "up_only", "down_only", "thin")]),
        "",
        f"![workspace]({wname})",
    ]
    headline = [f"capture: end effector within {fmt(m['ee_error_final'])} m of the target, "
                f"clearance proven >= {fmt(m['clearance_bound'])} m; closed loop from the "
                f"plan's start {exact.metrics['outcome']} "
                f"({fmt(exact.metrics['ee_error_final'])} m), from {PERTURBED} "
                f"{moved.metrics['outcome']}, from {PUSHED} {pushed.metrics['outcome']}"]
    return Outcome(lines, headline, ("capture/**/*", "fig_capture.*", "fig_workspace.*"))


SECTION = Section("capture", "a capture maneuver among obstacles", inputs, run)
