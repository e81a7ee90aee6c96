"""Figures of one plan and one closed-loop run, and what every figure shares.

matplotlib's object API (no pyplot state, no display needed), imported on first use:
plotting is optional work.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core.planning import PlanSamples
from flatcli.storage import atomic_path

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Array = NDArray[np.float64]


def new_figure(width: float, height: float) -> Figure:
    """A matplotlib Figure (imported on first use: plotting is optional work)."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height))


def save_figure(fig: Figure, path: Path) -> None:
    """Write a figure as PNG, atomically."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")


def finish_grid(fig: Figure, ax: Any, title: str, path: Path, legend_size: int = 8) -> None:
    """Grid lines and legends on every panel of a grid of time plots (2 x 2, 2 x 3), t on
    the bottom row; title, layout, and the PNG."""
    for a in ax.flat:
        a.grid(alpha=0.3)
        a.legend(fontsize=legend_size)
    for a in ax[1]:
        a.set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path)


@dataclass(frozen=True)
class Limits:
    """Thresholds and limits drawn as dashed lines on the figures of a plan or a run
    (None, or inf: not drawn; the legend says "no limit" for inf)."""

    singular_threshold: float | None = None  # track.singular_threshold [rad/s]
    min_margin: float | None = None  # plan.optimize.min_margin [rad/s]
    #: track.rate_limit, or plan.optimize.rate_limit (one for every joint or one per joint)
    rate_limit: float | Sequence[float] | None = None  # [rad/s]
    angle_limit: Sequence[float] | None = None  # plan.optimize.angle_limit, per angle [rad]


def limit_line(ax: Any, value: float | None, label: str, unit: str, colour: str = "C3",
               symmetric: bool = False) -> None:
    """A dashed horizontal line at a threshold or limit (at +-value if ``symmetric``)."""
    if value is None:
        return
    if not math.isfinite(value):
        ax.plot([], [], " ", label=f"{label} = inf (no limit)")
        return
    sign = "+-" if symmetric else ""
    ax.axhline(value, ls="--", lw=1.1, color=colour, label=f"{label} = {sign}{value:g} {unit}")
    if symmetric:
        ax.axhline(-value, ls="--", lw=1.1, color=colour)


def plot_plan(samples: PlanSamples, path: Path, title: str, limits: Limits | None = None
              ) -> None:
    """A plan as one PNG (``plan_figure``)."""
    fig = plan_figure(samples, limits)
    finish_grid(fig, np.asarray(fig.axes).reshape(2, 3), title, path)


def plan_figure(samples: PlanSamples, limits: Limits | None = None) -> Figure:
    """A plan's panels: flat outputs (the paper's Fig. 2), angles (Fig. 3), joint rates,
    the singularity margin (log axis: a plan never touches 0) with its thresholds, H from
    the full kinematics on a linear axis of its own (rounding for a correct plan), and the
    input u1'. Limits, when given, are dashed lines."""
    lim = limits or Limits()
    fig = new_figure(14, 7.5)
    ax = fig.subplots(2, 3, sharex=True)
    t = samples.t
    n = samples.y.shape[1]  # N joints
    for j in range(n):
        ax[0, 0].plot(t, samples.y[:, j], label=f"y{j + 1} = th{j + 1}" if j < n - 1
                      else f"y{n}")
    ax[0, 0].set_ylabel("flat outputs [rad]")
    for i in range(n + 1):
        ax[0, 1].plot(t, samples.theta[:, i], color=f"C{i}", label=f"th{i}")
        ax[0, 2].plot(t, samples.theta_dot[:, i], color=f"C{i}", label=f"th{i}'")
        bound = None if lim.angle_limit is None else lim.angle_limit[i]
        if bound is not None and math.isfinite(bound):
            ax[0, 1].axhline(bound, ls="--", lw=1.1, color=f"C{i}",
                             label=f"plan.optimize.angle_limit[{i}] = +-{bound:g} rad")
            ax[0, 1].axhline(-bound, ls="--", lw=1.1, color=f"C{i}")
    if isinstance(lim.rate_limit, Sequence):
        for j, bound in enumerate(lim.rate_limit, start=1):
            if math.isfinite(bound):
                ax[0, 2].axhline(bound, ls="--", lw=1.1, color=f"C{j}",
                                 label=f"plan.optimize.rate_limit[{j - 1}] = +-{bound:g} rad/s")
                ax[0, 2].axhline(-bound, ls="--", lw=1.1, color=f"C{j}")
    else:
        limit_line(ax[0, 2], lim.rate_limit, "plan.optimize.rate_limit", "rad/s",
                   symmetric=True)
    ax[0, 1].set_ylabel("angles [rad]")
    ax[0, 2].set_ylabel("joint rates [rad/s]")
    ax[1, 0].semilogy(t, samples.margin, color="k", label=margin_label(n, "y1 * y1'"))
    limit_line(ax[1, 0], lim.singular_threshold, "track.singular_threshold", "rad/s")
    limit_line(ax[1, 0], lim.min_margin, "plan.optimize.min_margin", "rad/s", colour="C1")
    ax[1, 0].set_ylim(top=30 * float(np.max(samples.margin)))  # room for the legend above
    ax[1, 0].set_ylabel("singularity margin [rad/s]")
    ax[1, 1].plot(t, samples.momentum, color="C4", label="H (full link kinematics)")
    ax[1, 1].set_ylabel("angular momentum H [kg m^2/s]")
    for j in range(1, n):
        ax[1, 2].plot(t, samples.u_dot[:, j - 1], color=f"C{j}", label=f"u{j}' (input)")
    ax[1, 2].set_ylabel("u1' [rad/s^2]" if n == 2 else "u_j' = th_j'' [rad/s^2]")
    return fig


def margin_label(joints: int, paper: str) -> str:
    """The legend of the singularity margin: abs(sin th1 * th1') on the paper's robot, the
    rate of change of the base's locked inertia beyond it."""
    if joints == 2:
        return f"margin abs(sin {paper})"
    return "margin abs(dh_0/dt) / (2 abs(K_10))"


def plot_track(cols: dict[str, Array], path: Path, title: str, limits: Limits | None = None
               ) -> None:
    """A closed-loop run against its reference (the paper's Fig. 4) as one PNG
    (``track_figure``)."""
    fig = track_figure(cols, limits)
    finish_grid(fig, np.asarray(fig.axes).reshape(2, 3), title, path)


def track_figure(cols: dict[str, Array], limits: Limits | None = None) -> Figure:
    """A closed-loop run's panels: flat outputs, angles, applied joint rates, tracking
    errors (log axis), the margin (log axis, with the singular threshold) and H from the
    full kinematics (linear axis). Samples after a trial stopped are empty (nan) and not
    drawn; a dotted line marks the stop."""
    lim = limits or Limits()
    fig = new_figure(14, 7.5)
    ax = fig.subplots(2, 3, sharex=True)
    t = cols["t"]
    n = sum(1 for name in cols if name.startswith("theta") and name[5:].isdigit()) - 1
    for name in (f"y{j}" for j in range(1, n + 1)):
        line = ax[0, 0].plot(t, cols[name], label=name)[0]
        ax[0, 0].plot(t, cols[f"{name}_ref"], "--", color=line.get_color(), label=f"{name} ref")
    for i in range(n + 1):
        line = ax[0, 1].plot(t, cols[f"theta{i}"], label=f"th{i}")[0]
        ax[0, 1].plot(t, cols[f"theta{i}_ref"], "--", color=line.get_color(), label=f"th{i} ref")
    for i in range(1, n + 1):
        ax[0, 2].plot(t, cols[f"theta{i}_dot"], color=f"C{i}", label=f"th{i}' applied")
    assert not isinstance(lim.rate_limit, Sequence)  # track.rate_limit is one number
    limit_line(ax[0, 2], lim.rate_limit, "track.rate_limit", "rad/s", symmetric=True)
    ey = np.sqrt(sum((cols[f"y{j}"] - cols[f"y{j}_ref"]) ** 2 for j in range(1, n + 1)))
    eth = np.sqrt(sum((cols[f"theta{i}"] - cols[f"theta{i}_ref"]) ** 2 for i in range(n + 1)))
    ax[1, 0].semilogy(t, ey, label="norm(y - y_ref)")
    ax[1, 0].semilogy(t, eth, label="norm(th - th_ref)")
    ax[1, 1].semilogy(t, cols["margin"], color="k", label=margin_label(n, "th1 * u1"))
    limit_line(ax[1, 1], lim.singular_threshold, "track.singular_threshold", "rad/s")
    if "momentum" in cols:
        ax[1, 2].plot(t, cols["momentum"], color="C4", label="H (full link kinematics)")
    ax[0, 0].set_ylabel("flat outputs [rad]")
    ax[0, 1].set_ylabel("angles [rad]")
    ax[0, 2].set_ylabel("joint rates [rad/s]")
    ax[1, 0].set_ylabel("tracking error [rad]")
    ax[1, 1].set_ylabel("singularity margin [rad/s]")
    ax[1, 2].set_ylabel("angular momentum H [kg m^2/s]")
    valid = t[np.isfinite(cols["theta0"])]
    if len(valid) and valid[-1] < t[-1]:  # the trial stopped early: say where
        for a in ax.flat:
            a.axvline(valid[-1], ls=":", lw=1.2, color="0.3",
                      label=f"trial stopped after t = {valid[-1]:.4g} s")
    return fig
