"""Figures of a finished sweep, drawn from its summary.parquet and trials.parquet."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from flatcli.report.figures import new_figure, save_figure
from flatcli.report.summary import COMPLETED, short_key

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def plot_sweep(directory: Path) -> list[Path]:
    """Figures of a finished sweep: error distributions, singular-hit rate, momentum drift."""
    summary = pd.read_parquet(directory / "summary.parquet")
    trials = pd.read_parquet(
        directory / "trials.parquet",
        columns=["cell", "status", "err_theta_rms", "err_y_rms", "err_y_final",
                 "momentum_drift", "singular_hits"],
    )
    cells = summary["cell"].tolist()
    done = trials[trials["status"].isin(COMPLETED)]
    positions = np.arange(len(cells))
    paths = []

    fig = new_figure(max(8, 0.6 * len(cells) + 4), 8)
    axes = fig.subplots(3, 1, sharex=True)
    for ax, metric in zip(axes, ("err_theta_rms", "err_y_rms", "err_y_final"), strict=True):
        _log_boxplot(ax, done, cells, metric, 1e-16)
        ax.set_ylabel(f"log10 {metric} [rad]")
        ax.grid(alpha=0.3)
    _cell_axis(axes[-1], cells, "cell (see summary.md for its grid values)")
    paths.append(_finish(fig, "Tracking error distribution per cell (trials that ran to the end)",
                         directory / "sweep_errors.png"))

    fig = new_figure(max(8, 0.6 * len(cells) + 4), 5)
    ax = fig.subplots()
    size_key = next((k for k in summary.columns if k.startswith("sweep.perturb.")
                     and pd.api.types.is_numeric_dtype(summary[k])), None)
    if size_key is not None:
        others = [k for k in summary.columns
                  if k not in (size_key, "cell") and k in _grid_columns(summary)]
        groups = summary.groupby(others, sort=False) if others else [((), summary)]
        for key, group in groups:
            key_t = key if isinstance(key, tuple) else (key,)
            label = ", ".join(f"{short_key(k)}={v}" for k, v in zip(others, key_t,
                                                                    strict=True))
            g = group.sort_values(size_key)
            ax.plot(g[size_key], g["singular_fraction"], "o-", label=label or "all")
        ax.set_xlabel(short_key(size_key))
        ax.set_xscale("log")
        ax.legend(fontsize=7)
    else:
        ax.bar(positions, summary["singular_fraction"].to_numpy(dtype=float))
        _cell_axis(ax, cells, "cell (grid values: summary.md)")
    ax.set_ylabel("fraction of trials with a singular hit")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    paths.append(_finish(fig, "Singularity-hit rate vs perturbation size",
                         directory / "sweep_singular.png"))

    fig = new_figure(max(8, 0.6 * len(cells) + 4), 4.5)
    ax = fig.subplots()
    _log_boxplot(ax, done, cells, "momentum_drift", 1e-18)
    _cell_axis(ax, cells, "cell")
    ax.set_ylabel("log10 momentum drift [kg m^2/s]")
    ax.grid(alpha=0.3)
    paths.append(_finish(fig, "Momentum drift of the integrated motion (full kinematics) per cell",
                         directory / "sweep_momentum.png"))
    return paths


def _cell_axis(ax: Any, cells: list[int], label: str) -> None:
    """An x axis of one tick per grid cell."""
    ax.set_xticks(np.arange(len(cells)), [str(c) for c in cells])
    ax.set_xlabel(label)


def _finish(fig: Figure, title: str, path: Path) -> Path:
    """Title, layout and the PNG of a sweep figure; its path."""
    fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, path)
    return path


def _log_boxplot(ax: Any, done: pd.DataFrame, cells: list[int], metric: str,
                 floor: float) -> None:
    """One box per cell of log10(metric), values below ``floor`` drawn at it."""
    data = [np.log10(np.maximum(done.loc[done["cell"] == c, metric].to_numpy(), floor))
            for c in cells]
    ax.boxplot([d if len(d) else [np.nan] for d in data], positions=np.arange(len(cells)),
               widths=0.6, flierprops={"markersize": 2})


def _grid_columns(summary: pd.DataFrame) -> list[str]:
    """The grid-key columns of a summary: those between 'cell' and 'trials'."""
    cols = list(summary.columns)
    return cols[cols.index("cell") + 1: cols.index("trials")]
