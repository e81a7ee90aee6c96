"""Figures of one plan and one closed-loop run, and what every figure shares.

matplotlib's object API (no pyplot state, no display needed), imported on first use:
plotting is optional work.
"""

from __future__ import annotations

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
    """Grid lines and legends on every panel of a 2 x 2 time plot, t on the bottom row;
    title, layout, and the PNG."""
    for a in ax.flat:
        a.grid(alpha=0.3)
        a.legend(fontsize=legend_size)
    for a in ax[1]:
        a.set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path)


def plot_plan(samples: PlanSamples, path: Path, title: str) -> None:
    """Flat outputs (Fig. 2), angles (Fig. 3), rates and margin of a plan, as one PNG."""
    fig = new_figure(11, 7)
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
    finish_grid(fig, ax, title, path)


def plot_track(cols: dict[str, Array], path: Path, title: str) -> None:
    """Closed-loop run against its reference (the paper's Fig. 4), as one PNG."""
    fig = new_figure(11, 7)
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
    finish_grid(fig, ax, title, path)
