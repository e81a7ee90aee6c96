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


_ORDINAL = {3: "cubic", 5: "quintic", 7: "degree-7"}


def curves_text(plan: Plan) -> str:
    """What a plan's curves are, in words (no class names): the flat outputs' (or an exact
    plan's joint paths') basis and its coefficients."""
    from flatcli.core.curves.basis import BSplineBasis, PolynomialBasis
    from flatcli.core.curves.pieces import PiecewiseBasis

    basis = plan.trajectory.basis
    if isinstance(basis, PolynomialBasis):
        kind = f"{_ORDINAL.get(basis.degree, f'degree-{basis.degree}')} polynomials"
        detail = f"{basis.size} coefficients each"
    elif isinstance(basis, BSplineBasis):
        kind = f"{_ORDINAL.get(basis.degree, f'degree-{basis.degree}')} B-splines"
        detail = f"{basis.size} coefficients each"
    elif isinstance(basis, PiecewiseBasis):
        kind = "piecewise polynomials"
        detail = f"{basis.pieces} pieces of degree {basis.degree}"
    else:  # a basis of the API's caller
        kind, detail = "curves", f"{basis.size} coefficients each"
    if plan.model.kind == "exact":
        return f"exact plan (no flat outputs): joint paths and th0 as {kind} ({detail})"
    rest = " rest to rest," if getattr(plan, "start", None) is not None else ""
    return f"{rest} flat outputs as {kind} ({detail})".lstrip()


def plan_text(name: str, plan: Plan, samples: PlanSamples) -> str:
    """Terminal summary of a plan."""
    s = plan_summary(plan, samples)
    n = samples.y.shape[1]
    ends = [
        ["t = 0", *samples.y[0], *samples.y_dot[0]],
        [f"t = {plan.duration:g} s", *samples.y[-1], *samples.y_dot[-1]],
    ]
    symbol = "th" if plan.model.kind == "exact" else "y"  # an exact plan: its joint paths
    outputs = [f"{symbol}{j} [rad]" for j in range(1, n + 1)]
    rates = [f"{symbol}{j}' [rad/s]" for j in range(1, n + 1)]
    model, margin = plan.model.name, f"min margin {plan.model.margin_label}"
    energy = ("input energy, integral of th1'^2 + th2'^2" if n == 2
              else f"input energy, integral of th1'^2 + ... + th{n}'^2")
    lines = [
        f"plan {name!r}: {n} joints, model {model}, {curves_text(plan)}, T = "
        f"{plan.duration:g} s, {len(samples.t)} samples",
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


#: A planned task's results, in the order ``task_text`` shows them.
TASK_ROWS = ("ee_error_final", "base_attitude_error_final", "min_clearance", "clearance_bound",
             "certified_intervals", "task_candidates", "rate_factor", "rest_skew")


def task_text(metrics: Mapping[str, object]) -> str:
    """A planned task's results with their units (those that apply), and a line when the
    search changed the end rates the spec gave."""
    from flatcli.units import DIMENSIONLESS, unit_of

    rows = [[k, metrics[k], "" if (unit := unit_of(k)) in (None, DIMENSIONLESS) else unit]
            for k in TASK_ROWS if metrics.get(k) is not None]
    text = table(["task", "value", "unit"], rows, 5)
    factor = metrics.get("rate_factor")
    if isinstance(factor, float) and factor != 1.0:
        text += (f"\nnote: the end rates are plan.start_rate and plan.goal_rate x {factor:g} "
                 "(the search's candidate: the rates as given did not plan, or were not "
                 "proven clear)")
    return text


def metrics_text(name: str, metrics: Mapping[str, object]) -> str:
    """Terminal summary of one closed-loop run: its outcome first (whether the robot did its
    job, and why not), then the integration's status, then each metric with its unit
    (``flatcli.units``; blank for a count or a flag). A status ``ok`` says only that the
    trial was integrated to T; the outcome says whether it ended at its goal."""
    from flatcli.units import DIMENSIONLESS, unit_of

    rows = [[k, v, "" if (unit := unit_of(k)) in (None, DIMENSIONLESS) else unit]
            for k, v in metrics.items() if k not in ("status", "reason", "event_time")]
    head = f"track {name!r}: "
    if metrics.get("outcome"):
        head += str(metrics["outcome"])
        if metrics.get("outcome_reason"):
            head += f" ({metrics['outcome_reason']})"
        head += "; "
    head += f"status {metrics['status']}"
    if metrics.get("reason"):
        head += f" ({metrics['reason']})"
    return head + "\n" + table(["metric", "value", "unit"], rows, 5)
