"""What the terminal shows for a plan, an optimised plan and a closed-loop run."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from flatcli.core.optimize import OptimizeResult
from flatcli.core.planning import FlatPlan, PlanSamples
from flatcli.report.tables import fmt, table


def plan_summary(plan: FlatPlan, samples: PlanSamples) -> dict[str, float]:
    """The headline numbers of a plan (see the README for definitions)."""
    t_min = float(samples.t[int(np.argmin(samples.margin))])
    return {
        "max_abs_momentum": float(np.max(np.abs(samples.momentum))),
        "min_margin": float(np.min(samples.margin)),
        "min_margin_time": t_min,
        "max_abs_theta0": float(np.max(np.abs(samples.theta[:, 0]))),
        "max_abs_theta1": float(np.max(np.abs(samples.theta[:, 1]))),
        "max_abs_theta2": float(np.max(np.abs(samples.theta[:, 2]))),
        "peak_rate0": float(np.max(np.abs(samples.theta_dot[:, 0]))),
        "peak_rate1": float(np.max(np.abs(samples.theta_dot[:, 1]))),
        "peak_rate2": float(np.max(np.abs(samples.theta_dot[:, 2]))),
        "input_energy": plan.input_energy(),
    }


def plan_text(name: str, plan: FlatPlan, samples: PlanSamples) -> str:
    """Terminal summary of a plan."""
    s = plan_summary(plan, samples)
    ends = [
        ["t = 0", *samples.y[0], *samples.y_dot[0]],
        [f"t = {plan.duration:g} s", *samples.y[-1], *samples.y_dot[-1]],
    ]
    lines = [
        f"plan {name!r}: model {plan.model}, {type(plan.trajectory.basis).__name__}"
        f" of size {plan.trajectory.basis.size}, T = {plan.duration:g} s,"
        f" {len(samples.t)} samples",
        table(["boundary", "y1 [rad]", "y2 [rad]", "y1' [rad/s]", "y2' [rad/s]"], ends, 6),
        "",
        table(
            ["quantity", "value", "unit"],
            [
                ["max abs(H) along the plan (full kinematics)", s["max_abs_momentum"], "kg m^2/s"],
                ["min margin abs(sin y1 * y1')", s["min_margin"], "rad/s"],
                ["  at t", s["min_margin_time"], "s"],
                ["max abs(theta2)", s["max_abs_theta2"], "rad"],
                ["peak abs(theta0')", s["peak_rate0"], "rad/s"],
                ["peak abs(theta1')", s["peak_rate1"], "rad/s"],
                ["peak abs(theta2')", s["peak_rate2"], "rad/s"],
                ["input energy, integral of th1'^2 + th2'^2", s["input_energy"], "rad^2/s"],
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
        "active": list(result.active),
        "max_violation": float(result.max_violation),
        "message": result.message,
    }


def optimization_text(summary: Mapping[str, Any]) -> str:
    """Terminal summary of an optimised plan."""
    rows = [
        ["objective", f"{summary['objective']}: {fmt(summary['value'], 5)} "
                      f"(starting plan {fmt(summary['initial_value'], 5)})"],
        ["success", "yes" if summary["success"] else f"no: {summary['message']}"],
        ["th1'(0), th1'(T) chosen [rad/s]",
         f"{fmt(summary['start_rate'], 5)}, {fmt(summary['goal_rate'], 5)}"],
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
