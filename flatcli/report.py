"""What people read: terminal tables and PNG figures of plans and closed-loop runs.

Tables are GitHub-flavoured Markdown with aligned columns, so the same text reads well on a
terminal and renders in REPORT.md / summary.md. Figures use matplotlib's object API (no
pyplot state, no display needed).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from flatcli.core.planning import FlatPlan, PlanSamples
from flatcli.storage import atomic_path

Array = NDArray[np.float64]


def fmt(value: object, digits: int = 4) -> str:
    """A number for a table: compact, aligned, readable; other values as str."""
    if isinstance(value, bool | np.bool_):
        return str(bool(value)).lower()
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        x = float(value)
        if math.isnan(x):
            return "-"
        if math.isinf(x):
            return "inf" if x > 0 else "-inf"
        if x == 0:
            return "0"
        if 1e-3 <= abs(x) < 1e5:
            return f"{x:.{digits}g}"
        return f"{x:.{max(digits - 2, 1)}e}"
    return str(value)


def table(headers: Sequence[str], rows: Sequence[Sequence[object]], digits: int = 4) -> str:
    """An aligned Markdown table; numbers right-aligned."""
    cells = [[fmt(v, digits) for v in row] for row in rows]
    widths = [
        max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(headers)
    ]
    numeric = [
        all(_is_number(row[i]) for row in rows) if rows else False for i in range(len(headers))
    ]

    def line(items: Sequence[str]) -> str:
        parts = [
            s.rjust(w) if num else s.ljust(w)
            for s, w, num in zip(items, widths, numeric, strict=True)
        ]
        return "| " + " | ".join(parts) + " |"

    rule = (
        "|"
        + "|".join(
            ("-" * (w + 1) + ":") if num else ("-" * (w + 2))
            for w, num in zip(widths, numeric, strict=True)
        )
        + "|"
    )
    return "\n".join([line(list(headers)), rule, *(line(r) for r in cells)])


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


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


def metrics_text(name: str, metrics: dict[str, float | int | str]) -> str:
    """Terminal summary of one closed-loop run."""
    rows = [[k, v] for k, v in metrics.items() if k not in ("status", "reason")]
    head = f"track {name!r}: status {metrics['status']}"
    if metrics.get("reason"):
        head += f" ({metrics['reason']})"
    return head + "\n" + table(["metric", "value"], rows, 5)


def _save(fig: Figure, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")


def plot_plan(samples: PlanSamples, path: Path, title: str) -> None:
    """Flat outputs (Fig. 2), angles (Fig. 3), rates and margin of a plan, as one PNG."""
    fig = Figure(figsize=(11, 7))
    ax = fig.subplots(2, 2, sharex=True)
    t = samples.t
    ax[0, 0].plot(t, samples.y[:, 0], label="y1 = th1")
    ax[0, 0].plot(t, samples.y[:, 1], label="y2")
    ax[0, 0].set_ylabel("flat outputs [rad]")
    for i in range(3):
        ax[0, 1].plot(t, samples.theta[:, i], label=f"th{i}")
        ax[1, 0].plot(t, samples.theta_dot[:, i], label=f"th{i}'")
    ax[0, 1].set_ylabel("angles [rad]")
    ax[1, 0].set_ylabel("rates [rad/s]")
    ax[1, 1].semilogy(t, samples.margin, label="margin |sin y1 y1'| [rad/s]")
    ax[1, 1].semilogy(t, np.abs(samples.momentum) + 1e-300, label="|H| [kg m^2/s]")
    for a in ax.flat:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    for a in ax[1]:
        a.set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)


def plot_track(cols: dict[str, Array], path: Path, title: str) -> None:
    """Closed-loop run against its reference (the paper's Fig. 4), as one PNG."""
    fig = Figure(figsize=(11, 7))
    ax = fig.subplots(2, 2, sharex=True)
    t = cols["t"]
    for name in ("y1", "y2"):
        line = ax[0, 0].plot(t, cols[name], label=name)[0]
        ax[0, 0].plot(t, cols[f"{name}_ref"], "--", color=line.get_color(), label=f"{name} ref")
    for i in range(3):
        line = ax[0, 1].plot(t, cols[f"theta{i}"], label=f"th{i}")[0]
        ax[0, 1].plot(t, cols[f"theta{i}_ref"], "--", color=line.get_color(), label=f"th{i} ref")
    ey = np.hypot(cols["y1"] - cols["y1_ref"], cols["y2"] - cols["y2_ref"])
    eth = np.sqrt(sum((cols[f"theta{i}"] - cols[f"theta{i}_ref"]) ** 2 for i in range(3)))
    ax[1, 0].semilogy(t, ey + 1e-300, label="|y - y_ref|")
    ax[1, 0].semilogy(t, eth + 1e-300, label="|th - th_ref|")
    ax[1, 1].semilogy(t, cols["margin"] + 1e-300, label="margin [rad/s]")
    if "momentum" in cols:
        ax[1, 1].semilogy(t, np.abs(cols["momentum"]) + 1e-300, label="|H| [kg m^2/s]")
    ax[0, 0].set_ylabel("flat outputs [rad]")
    ax[0, 1].set_ylabel("angles [rad]")
    ax[1, 0].set_ylabel("tracking error [rad]")
    for a in ax.flat:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    for a in ax[1]:
        a.set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    _save(fig, path)
