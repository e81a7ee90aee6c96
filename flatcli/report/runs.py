"""What the terminal shows for a plan, an optimised plan and a closed-loop run."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from flatcli.core.plan.planning import Plan, PlanSamples
from flatcli.report.tables import fmt, table

if TYPE_CHECKING:
    from flatcli.core.optimize import OptimizeResult


def plan_summary(plan: Plan, samples: PlanSamples) -> dict[str, float]:
    """The headline numbers of a plan (see docs/outputs.md for definitions): ``max_abs_theta{i}``
    and ``peak_rate{i}`` for every angle th0..thN."""
    t_min = float(samples.t[int(np.argmin(samples.margin))])
    links = samples.theta.shape[1]
    out = {
        "max_abs_momentum": float(np.max(np.abs(samples.momentum))),
        "min_margin": float(np.min(samples.margin)),
        "min_margin_time": t_min,
    }
    for i in range(links):
        out[f"max_abs_theta{i}"] = float(np.max(np.abs(samples.theta[:, i])))
    for i in range(links):
        out[f"peak_rate{i}"] = float(np.max(np.abs(samples.theta_dot[:, i])))
    out["input_energy"] = plan.input_energy()
    return out


def plan_text(name: str, plan: Plan, samples: PlanSamples) -> str:
    """Terminal summary of a plan."""
    s = plan_summary(plan, samples)
    n = samples.y.shape[1]
    ends = [
        ["t = 0", *samples.y[0], *samples.y_dot[0]],
        [f"t = {plan.duration:g} s", *samples.y[-1], *samples.y_dot[-1]],
    ]
    if plan.model.kind == "exact":  # no flat outputs: its y columns are the joint paths
        outputs = [f"y{j} = th{j} [rad]" for j in range(1, n + 1)]
        rates = [f"y{j}' = th{j}' [rad/s]" for j in range(1, n + 1)]
    else:
        outputs = [f"y{j} [rad]" for j in range(1, n + 1)]
        rates = [f"y{j}' [rad/s]" for j in range(1, n + 1)]
    model, margin = plan.model.name, f"min margin {plan.model.margin_label}"
    energy = ("input energy, integral of th1'^2 + th2'^2" if n == 2
              else f"input energy, integral of th1'^2 + ... + th{n}'^2")
    lines = [
        f"plan {name!r}: {n} joints, model {model}, {type(plan.trajectory.basis).__name__}"
        f" of size {plan.trajectory.basis.size}, T = {plan.duration:g} s,"
        f" {len(samples.t)} samples",
        table(["boundary", *outputs, *rates], ends, 6),
        "",
        table(
            ["quantity", "value", "unit"],
            [
                ["max abs(H) along the plan (full kinematics)", s["max_abs_momentum"], "kg m^2/s"],
                [margin, s["min_margin"], "rad/s"],
                ["  at t", s["min_margin_time"], "s"],
                [f"max abs(theta{n})", s[f"max_abs_theta{n}"], "rad"],
                *([f"peak abs(theta{i}')", s[f"peak_rate{i}"], "rad/s"] for i in range(n + 1)),
                [energy, s["input_energy"], "rad^2/s"],
            ],
        ),
    ]
    return "\n".join(lines)


def optimization_summary(result: OptimizeResult, objective: str) -> dict[str, Any]:
    """The optimiser's report as plain values (for run.json and the terminal)."""
    return {
        "objective": objective,
        "success": bool(result.success),
        "value": float(result.objective),
        "initial_value": float(result.initial_objective),
        "iterations": int(result.iterations),
        "evaluations": int(result.evaluations),
        "start_rate": float(result.start_rate),
        "goal_rate": float(result.goal_rate),
        "start_rates": [float(v) for v in result.start_rates],
        "goal_rates": [float(v) for v in result.goal_rates],
        "active": list(result.active),
        "max_violation": float(result.max_violation),
        "message": result.message,
    }


def _chosen_rates(summary: Mapping[str, Any]) -> list[str]:
    """The row of the end rates the optimiser chose: th1' for the paper's robot, th_1'..
    th_N-1' for a chain."""
    starts = summary.get("start_rates", [summary["start_rate"]])
    goals = summary.get("goal_rates", [summary["goal_rate"]])
    if len(starts) == 1:
        return ["th1'(0), th1'(T) chosen [rad/s]",
                f"{fmt(summary['start_rate'], 5)}, {fmt(summary['goal_rate'], 5)}"]
    n = len(starts) + 1
    return [f"th1'..th{n - 1}' at 0 and T chosen [rad/s]",
            f"({', '.join(fmt(v, 5) for v in starts)}), ({', '.join(fmt(v, 5) for v in goals)})"]


def optimization_text(summary: Mapping[str, Any]) -> str:
    """Terminal summary of an optimised plan."""
    rows = [
        ["objective", f"{summary['objective']}: {fmt(summary['value'], 5)} "
                      f"(starting plan {fmt(summary['initial_value'], 5)})"],
        ["success", "yes" if summary["success"] else f"no: {summary['message']}"],
        _chosen_rates(summary),
        ["iterations, evaluations", f"{summary['iterations']}, {summary['evaluations']}"],
        ["max limit violation (check grid)", fmt(summary["max_violation"])],
        ["active constraints", "; ".join(summary["active"]) or "none"],
    ]
    return table(["optimisation", ""], rows)


def metrics_text(name: str, metrics: Mapping[str, object]) -> str:
    """Terminal summary of one closed-loop run."""
    rows = [[k, v] for k, v in metrics.items() if k not in ("status", "reason", "event_time")]
    head = f"track {name!r}: status {metrics['status']}"
    if metrics.get("reason"):
        head += f" ({metrics['reason']})"
    return head + "\n" + table(["metric", "value"], rows, 5)
