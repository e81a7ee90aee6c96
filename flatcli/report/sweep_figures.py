"""Figures of a finished sweep, drawn from its summary.parquet and trials.parquet.

Every per-cell figure names its cells by their grid values (a small table under the x axis,
outer grid keys spanning their cells), with the number of resolved trials the distributions
are drawn from and the number left out. Distributions are over resolved trials (ok,
singular) only; what is left out is shown beside them as shares of the cell's trials with
95 % Wilson intervals (``flatcli.report.summary``). Boxes: quartiles and median; whiskers:
5th and 95th percentiles (a percentile is the same on a log axis, unlike 1.5 IQR); dots:
trials beyond them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from flatcli.core.metrics import RESOLVED
from flatcli.core.model import FlatcliError
from flatcli.report.figures import new_figure, save_figure
from flatcli.report.summary import FAILURES, short_key
from flatcli.report.tables import fmt
from flatcli.storage import read_provenance

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Array = NDArray[np.float64]

#: Shares drawn beside the error distributions: (summary column prefix, legend, colour).
SHARES = (("diverged", "diverged", "C3"), ("unresolved", "unresolved", "C1"),
          ("error", "error (did not run)", "C7"),
          ("singular", "singular hit (of simulated trials)", "C0"))
#: Trial columns the figures read.
TRIAL_COLUMNS = ["cell", "status", "err_theta_rms", "err_y_rms", "err_y_final", "min_margin",
                 "peak_rate", "momentum_drift"]
#: Values below this are drawn at it on a log axis (and the panel says so).
LOG_FLOOR = 1e-16


def plot_sweep(directory: Path) -> list[Path]:
    """The figures of a finished sweep: sweep_errors.png, sweep_singular.png,
    sweep_margin.png, sweep_momentum.png (the README's *Sweep output* describes them)."""
    sweep = SweepData.load(directory)
    return [
        plot_errors(sweep, directory / "sweep_errors.png"),
        plot_shares_vs_size(sweep, directory / "sweep_singular.png"),
        plot_margin(sweep, directory / "sweep_margin.png"),
        plot_momentum(sweep, directory / "sweep_momentum.png"),
    ]


class SweepData:
    """What the figures read: the summary, the resolved trials, the grid and the spec tree."""

    def __init__(self, summary: pd.DataFrame, trials: pd.DataFrame, tree: Mapping[str, Any]
                 ) -> None:
        self.summary = summary.reset_index(drop=True)
        self.tree = tree
        self.cells: list[int] = [int(c) for c in summary["cell"]]
        self.resolved = trials[trials["status"].isin(RESOLVED)]
        self.axis = grid_axis(summary, tree)

    @classmethod
    def load(cls, directory: Path) -> SweepData:
        """A finished sweep's tables (FlatcliError if they predate the columns drawn)."""
        summary = pd.read_parquet(directory / "summary.parquet")
        if "resolved" not in summary.columns:
            raise FlatcliError(
                f"{directory}/summary.parquet was written by an older flatcli, without the "
                "failure shares the figures draw; run the sweep again with --force")
        trials = pd.read_parquet(directory / "trials.parquet", columns=TRIAL_COLUMNS)
        tree = read_provenance(directory / "summary.parquet").get("spec", {})
        return cls(summary, trials, tree)

    def by_cell(self, metric: str) -> list[Array]:
        """The resolved trials' values of a metric, one array per cell (nulls left out)."""
        out = []
        for cell in self.cells:
            values = self.resolved.loc[self.resolved["cell"] == cell, metric]
            array: Array = values.to_numpy(dtype=np.float64, na_value=np.nan)
            out.append(array[~np.isnan(array)])
        return out

    def setting(self, dotted: str) -> Array:
        """A spec value per cell: its grid column when gridded, else the spec's value
        (``"inf"`` in the spec's JSON is inf: no limit)."""
        if dotted in self.summary.columns:
            return self.summary[dotted].to_numpy(dtype=np.float64)
        node: Any = self.tree
        for part in dotted.split("."):
            node = node.get(part) if isinstance(node, Mapping) else None
        value = math.nan if node is None else float(node)
        return np.full(len(self.cells), value)

    @property
    def width(self) -> float:
        """Figure width [in] for one column per cell."""
        return max(8.0, 0.55 * len(self.cells) + 3.5)


# ---------------------------------------------------------------------------------------
# The cell axis: grid values under it.

def grid_axis(summary: pd.DataFrame, tree: Mapping[str, Any]) -> list[tuple[str, list[str]]]:
    """The rows of the table under a per-cell x axis: (name [unit], text per cell), outer
    grid key first (``tree``: the sweep's spec as JSON).

    A labelled group shows its labels (its keys are in summary.md); an unlabelled one its
    keys. A list-valued key shows only the components that vary (``plant.com[2]``).
    """
    grid = tree.get("sweep", {}).get("grid", {})
    columns = list(summary.columns)
    grid_columns = columns[columns.index("cell") + 1: columns.index("trials")]
    inside_groups = {k for values in grid.values() if _is_group(values)
                     for table in values for k in table if k != "label"}
    shown = []
    for column in grid_columns:
        values = grid.get(column)
        if values is not None and _is_group(values):
            if all("label" in table for table in values):
                shown.append(column)
        elif column in grid or column not in inside_groups or not _labelled(grid, column):
            shown.append(column)
    rows = []
    for column in shown:
        values = summary[column].tolist()
        unit = None if all(isinstance(v, str) for v in values) else key_unit(tree, column)
        rows += _axis_rows(short_key(column), unit, values)
    return rows


def key_unit(tree: Mapping[str, Any], key: str) -> str | None:
    """The unit of a grid key's values (a relative perturbation's are pure numbers, "1")."""
    from flatcli.units import DIMENSIONLESS, spec_key_unit

    name = key.split(".")[2] if key.startswith("sweep.perturb.") else ""
    perturb = tree.get("sweep", {}).get("perturb", {})
    if perturb.get(name, {}).get("relative", False):
        return DIMENSIONLESS
    return spec_key_unit(key)


def _is_group(values: Any) -> bool:
    return isinstance(values, list) and bool(values) and all(isinstance(v, dict) for v in values)


def _labelled(grid: Mapping[str, Any], key: str) -> bool:
    """Whether every group that sets ``key`` is labelled (its label names the key's value)."""
    return all(all("label" in t for t in values) for values in grid.values()
               if _is_group(values) and any(key in t for t in values))


def _axis_rows(name: str, unit: str | None, values: list[Any]
               ) -> list[tuple[str, list[str]]]:
    """One row per grid column; a list column becomes a row per component that varies."""
    suffix = f" [{unit}]" if unit and unit != "1" else ""
    if values and all(isinstance(v, list | tuple | np.ndarray) for v in values):
        lists = [list(v) for v in values]
        length = len(lists[0])
        if all(len(v) == length for v in lists):
            varying = [i for i in range(length) if len({v[i] for v in lists}) > 1]
            if not varying:
                return [(name + suffix, [_text(lists[0])] * len(values))]
            return [(f"{name}[{i}]{suffix}", [fmt(float(v[i]), 3) for v in lists])
                    for i in varying]
    return [(name + suffix, [_text(v) for v in values])]


def _text(value: Any) -> str:
    if isinstance(value, list | tuple | np.ndarray):
        return "[" + ", ".join(fmt(float(v), 3) for v in value) + "]"
    if isinstance(value, float | np.floating):
        return fmt(float(value), 3)
    return str(value)


def cell_axis(ax: Any, sweep: SweepData, counts: bool = True) -> None:
    """Label a per-cell x axis with the grid values (equal neighbours merged, outer keys
    first) and, with ``counts``, the resolved trials per cell and the trials left out."""
    cells = np.arange(len(sweep.cells))
    ax.set_xticks(cells, [""] * len(cells))
    ax.set_xlim(-0.6, len(cells) - 0.4)
    rows = list(sweep.axis)
    if counts:
        summary = sweep.summary
        rows.append(("n resolved", [str(int(v)) for v in summary["resolved"]]))
        rows.append(("left out", [str(int(t - r)) for t, r in
                                  zip(summary["trials"], summary["resolved"], strict=True)]))
    line = 11.0  # points per row
    for r, (name, texts) in enumerate(rows):
        y = -4.0 - line * r
        ax.annotate(name, xy=(0, 0), xycoords="axes fraction", xytext=(-6, y),
                    textcoords="offset points", ha="right", va="top", fontsize=8,
                    style="italic", annotation_clip=False)
        start = 0
        for i in range(1, len(texts) + 1):
            if i == len(texts) or texts[i] != texts[start] or r >= len(sweep.axis) - 1:
                ax.annotate(texts[start], xy=((start + i - 1) / 2, 0),
                            xycoords=ax.get_xaxis_transform(), xytext=(0, y),
                            textcoords="offset points", ha="center", va="top", fontsize=8,
                            annotation_clip=False)
                start = i
    if len(sweep.axis) > 1:  # separate the outermost key's blocks
        outer = sweep.axis[0][1]
        for i in range(1, len(outer)):
            if outer[i] != outer[i - 1]:
                for a in ax.get_figure().axes:
                    if a.get_xlim() == ax.get_xlim():
                        a.axvline(i - 0.5, color="0.6", lw=0.8)


def _table_height(sweep: SweepData, counts: bool = True) -> float:
    """Height [in] the table under the axis needs."""
    rows = len(sweep.axis) + (2 if counts else 0)
    return (4 + 11 * rows) / 72 + 0.1


# ---------------------------------------------------------------------------------------
# Panels.

def log_boxes(ax: Any, data: Sequence[Array], floor: float = LOG_FLOOR) -> None:
    """One box per cell on a log axis; a cell with no values says so."""
    ax.set_yscale("log")
    floored = sum(int(np.sum(d < floor)) for d in data)
    present = [i for i, d in enumerate(data) if len(d)]
    if present:
        ax.boxplot([np.maximum(data[i], floor) for i in present], positions=present,
                   widths=0.6, whis=(5, 95), flierprops={"markersize": 2, "alpha": 0.5},
                   medianprops={"color": "C1"}, manage_ticks=False)
    for i, d in enumerate(data):
        if not len(d):
            ax.annotate("none\nresolved", xy=(i, 0.5), xycoords=ax.get_xaxis_transform(),
                        ha="center", va="center", fontsize=7, color="0.4")
    if floored:
        ax.annotate(f"{floored} values below {floor:g} drawn at it", xy=(0.99, 0.02),
                    xycoords="axes fraction", ha="right", va="bottom", fontsize=7)


def shares(ax: Any, summary: pd.DataFrame, x: Array, names: Sequence[str] | None = None,
           spread: float = 0.15) -> None:
    """Shares of trials with their 95 % Wilson intervals, one marker series per kind."""
    chosen = [s for s in SHARES if names is None or s[0] in names]
    offsets = np.linspace(-spread, spread, len(chosen)) if len(chosen) > 1 else [0.0]
    top = 0.0
    for (name, label, colour), dx in zip(chosen, offsets, strict=True):
        p = summary[f"{name}_fraction"].to_numpy(dtype=np.float64)
        low = summary[f"{name}_fraction_low"].to_numpy(dtype=np.float64)
        high = summary[f"{name}_fraction_high"].to_numpy(dtype=np.float64)
        ax.errorbar(x + dx, p, yerr=[p - low, high - p], fmt="o", ms=3.5, capsize=2,
                    lw=1, color=colour, label=label)
        if np.isfinite(high).any():
            top = max(top, float(np.nanmax(high)))
    ax.set_ylim(-0.02, max(0.05, 1.35 * top))  # headroom for the legend above the points


def _finish(fig: Figure, title: str, path: Path) -> Path:
    """Title, layout (tight_layout makes room for the cell table: its texts belong to the
    axes) and the PNG; its path."""
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    save_figure(fig, path)
    return path


# ---------------------------------------------------------------------------------------
# The figures.

def plot_errors(sweep: SweepData, path: Path) -> Path:
    """Tracking-error distributions per cell, and beside them the shares of trials they
    leave out (diverged, unresolved, error) and of singular hits, with 95 % intervals."""
    bottom = _table_height(sweep)
    fig = new_figure(sweep.width, 9 + bottom)
    axes = fig.subplots(4, 1, sharex=True, gridspec_kw={"height_ratios": [1, 1, 1, 0.9]})
    for ax, metric, label in zip(axes[:3], ("err_theta_rms", "err_y_rms", "err_y_final"),
                                 ("rms error of theta [rad]", "rms error of y [rad]",
                                  "final error of y [rad]"), strict=True):
        log_boxes(ax, sweep.by_cell(metric))
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, axis="y")
    ax = axes[-1]
    shares(ax, sweep.summary, np.arange(len(sweep.cells), dtype=np.float64))
    ax.set_ylabel("share of trials\n(95 % interval)")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=7, ncol=4, loc="upper left")
    cell_axis(ax, sweep)
    return _finish(fig, "Tracking error per cell over resolved trials (ok, singular; box: "
                   "quartiles, whiskers: 5-95 %),\nand the share of trials that diverged, "
                   "were unresolved or could not run, and with a singular hit", path)


def plot_shares_vs_size(sweep: SweepData, path: Path) -> Path:
    """Shares of singular hits and failures against the perturbation size (a numeric
    ``sweep.perturb.*`` grid key), one line per combination of the other grid values;
    per cell when there is no such key."""
    summary = sweep.summary
    grid = sweep.tree.get("sweep", {}).get("grid", {})
    size_key = next((k for k in summary.columns if k.startswith("sweep.perturb.")
                     and k in grid and not _is_group(grid[k])
                     and pd.api.types.is_float_dtype(summary[k]) and summary[k].nunique() > 1),
                    None)
    kinds = ["singular", "diverged", *(n for n in FAILURES
                                       if n != "diverged" and summary[n].sum() > 0)]
    titles = {"singular": "simulated trials with a singular hit",
              "diverged": "trials that diverged",
              "unresolved": "trials unresolved", "error": "trials that could not run"}
    if size_key is None:
        bottom = _table_height(sweep)
        fig = new_figure(sweep.width, 4 + bottom)
        ax = fig.subplots()
        shares(ax, summary, np.arange(len(sweep.cells), dtype=np.float64), kinds)
        ax.set_ylabel("share of trials (95 % interval)")
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=7)
        cell_axis(ax, sweep)
        return _finish(fig, "Singular hits and failures per cell", path)
    others = [name for name, _ in sweep.axis if not name.startswith(short_key(size_key))]
    labels = [", ".join(f"{name} = {texts[i]}" for name, texts in sweep.axis
                        if name in others) for i in range(len(sweep.cells))]
    width = 4.2 * len(kinds) + 1.5
    fig = new_figure(width, 4.6)
    axes = fig.subplots(1, len(kinds), sharex=True, squeeze=False)[0]
    x = summary[size_key].to_numpy(dtype=np.float64)
    log = bool(np.all(x > 0))
    series = list(dict.fromkeys(labels))
    step = 0.03 * (np.ptp(np.log(x)) if log else np.ptp(x)) / max(len(series) - 1, 1)
    for ax, kind in zip(axes, kinds, strict=True):
        for j, label in enumerate(series):
            rows = np.array([lab == label for lab in labels])
            order = np.argsort(x[rows])
            part = summary[rows].iloc[order]
            p = part[f"{kind}_fraction"].to_numpy(dtype=np.float64)
            low = part[f"{kind}_fraction_low"].to_numpy(dtype=np.float64)
            high = part[f"{kind}_fraction_high"].to_numpy(dtype=np.float64)
            shift = step * (j - (len(series) - 1) / 2)
            xs = x[rows][order] * np.exp(shift) if log else x[rows][order] + shift
            ax.errorbar(xs, p, yerr=[p - low, high - p], fmt="o-", ms=3.5, capsize=2, lw=1,
                        label=label or "all cells")
        if log:
            ax.set_xscale("log")
        ax.set_xlabel(f"{short_key(size_key)} [{key_unit(sweep.tree, size_key) or '1'}]")
        ax.set_title(titles[kind], fontsize=10)
        ax.set_ylim(bottom=-0.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("share of trials (95 % interval)")
    handles, names = axes[0].get_legend_handles_labels()
    longest = max(len(n) for n in names)
    ncol = max(1, min(3, len(names), int(width * 14 / (longest + 6))))  # ~14 chars per inch
    fig.legend(handles, names, fontsize=7, loc="lower center", ncol=ncol)
    rows_of_legend = math.ceil(len(names) / ncol)
    fig.suptitle(f"Singular hits and failures against {short_key(size_key)} (points slightly "
                 "spread in x to keep the intervals apart)", fontsize=11)
    fig.tight_layout(rect=(0, 0.05 + 0.045 * rows_of_legend, 1, 0.97))
    save_figure(fig, path)
    return path


def plot_margin(sweep: SweepData, path: Path) -> Path:
    """How close resolved trials came to the singular set (min margin, with the singular
    threshold) and how fast the joints turned (peak rate, with the rate limit)."""
    bottom = _table_height(sweep)
    fig = new_figure(sweep.width, 6.5 + bottom)
    axes = fig.subplots(2, 1, sharex=True)
    log_boxes(axes[0], sweep.by_cell("min_margin"))
    _limit_line(axes[0], sweep.setting("track.singular_threshold"),
                "track.singular_threshold", "rad/s", "C3")
    axes[0].set_ylabel("min margin abs(sin th1 u1)\n[rad/s]")
    log_boxes(axes[1], sweep.by_cell("peak_rate"))
    _limit_line(axes[1], sweep.setting("track.rate_limit"), "track.rate_limit", "rad/s",
                "C3")
    _limit_line(axes[1], sweep.setting("track.divergence_bound"), "track.divergence_bound",
                "rad/s (bounds th and u1 = th1'; th2' is an input)", "0.3")
    axes[1].set_ylabel("peak abs(th1'), abs(th2')\n[rad/s]")
    for ax in axes:
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=7, loc="best")
    cell_axis(axes[-1], sweep)
    return _finish(fig, "Closest approach to the singular set and peak joint rate per cell "
                   "(resolved trials)", path)


def _limit_line(ax: Any, values: Array, key: str, unit: str, colour: str) -> None:
    """A dashed line per cell at a threshold or limit; an infinite one (no limit) is said
    in the legend instead."""
    finite = np.isfinite(values)
    if not finite.any():
        ax.plot([], [], " ", label=f"{key} = inf (no limit)")
        return
    if np.all(values[finite] == values[finite][0]) and finite.all():
        ax.axhline(values[0], ls="--", lw=1.2, color=colour,
                   label=f"{key} = {fmt(float(values[0]))} {unit}")
        return
    label = f"{key} (per cell) [{unit}]"
    for i, v in enumerate(values):
        if np.isfinite(v):
            ax.hlines(v, i - 0.4, i + 0.4, ls="--", lw=1.2, color=colour, label=label)
            label = "_"


def plot_momentum(sweep: SweepData, path: Path) -> Path:
    """Momentum drift of the integrated motion per cell, beside the plan's own momentum
    residual on the plant (the controller's model error)."""
    bottom = _table_height(sweep)
    fig = new_figure(sweep.width, 4.5 + bottom)
    ax = fig.subplots()
    log_boxes(ax, sweep.by_cell("momentum_drift"), floor=1e-18)
    residual = sweep.summary["plan_momentum_residual_max"].to_numpy(dtype=np.float64)
    ax.plot(np.arange(len(sweep.cells)), np.maximum(residual, 1e-18), "x", color="C3",
            label="plan_momentum_residual: the plan's H on the plant (model error)")
    ax.plot([], [], "s", mfc="none", color="k",
            label="momentum_drift: max abs(H - H0) along a trial (resolved trials)")
    ax.set_ylabel("abs(H - H0) [kg m^2/s]")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=7, loc="best")
    cell_axis(ax, sweep)
    return _finish(fig, "Angular momentum of the integrated motion, from the full link "
                   "kinematics, per cell", path)
