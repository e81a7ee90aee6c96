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
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.loop.metrics import OUTCOME_NAMES, RESOLVED
from flatcli.report.figures import PAGE_WIDTH, FigureFile, new_figure, save_figure, styled
from flatcli.report.summary import FAILURES, short_key
from flatcli.report.tables import fmt
from flatcli.spec.keys import suggest
from flatcli.spec.tree import value_at
from flatcli.storage import read_provenance

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Array = NDArray[np.float64]

#: Shares drawn beside the error distributions: (summary column prefix, legend, colour).
SHARES = (("reached", "reached (outcome)", "C2"),
          ("diverged", "diverged", "C3"), ("unresolved", "unresolved", "C1"),
          ("error", "error (did not run)", "C8"),
          ("singular", "singular hit (of simulated trials)", "C0"))
#: Trial columns the figures read.
TRIAL_COLUMNS = ["cell", "status", "err_theta_rms", "err_y_rms", "err_y_final", "min_margin",
                 "peak_rate", "momentum_drift"]
#: Values below this are drawn at it on a log axis (and the panel says so).
LOG_FLOOR = 1e-16


#: The figures of a sweep, ``sweep_<name>.<format>``, in the order they are written.
FIGURE_NAMES = ("errors", "singular", "margin", "momentum")


def plot_sweep(directory: Path, file: FigureFile | None = None, x: str | None = None,
               hue: str | None = None) -> list[Path]:
    """The figures of a finished sweep (``sweep_figures``) written into its directory as
    ``sweep_<name>.png`` (or ``file``'s format; default the sweep spec's ``[figures]``);
    their paths (docs/outputs.md, *Sweep output*, describes them)."""
    sweep = SweepData.load(directory, OUTCOME in (x, hue))
    file = file or FigureFile.of_tree(sweep.tree)
    return [save_figure(fig, directory / file.name(f"sweep_{name}"), file)
            for name, fig in _figures(sweep, x, hue).items()]


def check_axes(directory: Path, x: str | None, hue: str | None) -> None:
    """FlatcliError naming ``--x`` or ``--hue`` if the figures of the finished sweep in
    ``directory`` cannot be drawn against them (``OutcomeAxis.choose``): asked before
    anything is printed or drawn."""
    if x is not None or hue is not None:
        OutcomeAxis.choose(SweepData.load(directory), x, hue)


def sweep_figures(directory: Path, x: str | None = None, hue: str | None = None
                  ) -> dict[str, Figure]:
    """The figures of a finished sweep by name (``FIGURE_NAMES``): "errors", "singular"
    (against the grid key ``x``, a colour per value of ``hue``), "margin", "momentum"."""
    return _figures(SweepData.load(directory, OUTCOME in (x, hue)), x, hue)


def sweep_figure(directory: Path, which: str, x: str | None = None, hue: str | None = None
                 ) -> Figure:
    """One figure of a finished sweep (``sweep_figures``)."""
    sweep = SweepData.load(directory, OUTCOME in (x, hue))
    outcome = OutcomeAxis.choose(sweep, x, hue)  # checked whichever figure is drawn
    if which == "singular":
        return outcomes_figure(sweep, outcome)
    return {"errors": errors_figure, "margin": margin_figure,
            "momentum": momentum_figure}[which](sweep)


def _figures(sweep: SweepData, x: str | None, hue: str | None) -> dict[str, Figure]:
    outcome = OutcomeAxis.choose(sweep, x, hue)
    return {"errors": errors_figure(sweep), "singular": outcomes_figure(sweep, outcome),
            "margin": margin_figure(sweep), "momentum": momentum_figure(sweep)}


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
    def load(cls, directory: Path, by_outcome: bool = False) -> SweepData:
        """A finished sweep's tables (FlatcliError if they predate the columns drawn).

        ``by_outcome``: each cell split by its trials' ``outcome`` (``by_outcomes``), so that
        ``outcome`` is one more column of the grid (``--x outcome``, ``--hue outcome``)."""
        summary = pd.read_parquet(directory / "summary.parquet")
        if "resolved" not in summary.columns:
            raise FlatcliError(
                f"{directory}/summary.parquet was written by an older flatcli, without the "
                "failure shares the figures draw; run the sweep again with --force")
        tree = read_provenance(directory / "summary.parquet").get("spec", {})
        if by_outcome:
            summary, trials = by_outcomes(directory, summary)
            return cls(summary, trials[TRIAL_COLUMNS], tree)
        trials = pd.read_parquet(directory / "trials.parquet", columns=TRIAL_COLUMNS)
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
        node = value_at(self.tree, dotted)
        value = math.nan if node is None else float(node)
        return np.full(len(self.cells), value)

    @property
    def width(self) -> float:
        """Figure width [in] for one column per cell: a page's width, wider for many
        cells."""
        return max(PAGE_WIDTH, 0.45 * len(self.cells) + 2.5)


#: The trials' column that ``--x`` and ``--hue`` may name beside the grid keys.
OUTCOME = "outcome"


def by_outcomes(directory: Path, summary: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A sweep's summary and trials with every cell split by outcome: one row per (cell,
    outcome) that has trials, in the cells' order and then ``OUTCOME_NAMES``' order, its
    statistics (``summary_rows``) over those trials only, ``outcome`` a column after the
    grid's; the trials renumbered to those rows (FlatcliError for a sweep written before
    outcomes)."""
    from flatcli.report.summary import SUMMARY_INPUTS, frame_columns, summary_rows

    names = pq_columns(directory / "trials.parquet")
    if OUTCOME not in names:
        raise FlatcliError(f"{directory}/trials.parquet was written by an older flatcli, "
                           "without outcomes; run the sweep again with --force")
    columns = list(summary.columns)
    grid = columns[columns.index("cell") + 1: columns.index("trials")]
    wanted = list(dict.fromkeys(c for c in [*SUMMARY_INPUTS, *TRIAL_COLUMNS] if c in names))
    trials = pd.read_parquet(directory / "trials.parquet", columns=wanted)
    values = {int(c): {k: v for k, v in row.items() if k in grid}
              for c, row in zip(summary["cell"], summary.to_dict("records"), strict=True)}
    rank = {name: i for i, name in enumerate(OUTCOME_NAMES)}
    pairs = sorted({(int(c), str(o)) for c, o in zip(trials["cell"], trials[OUTCOME],
                                                     strict=True)},
                   key=lambda p: (p[0], rank.get(p[1], len(rank))))
    index = {pair: k for k, pair in enumerate(pairs)}
    trials = trials.assign(cell=[index[(int(c), str(o))] for c, o in
                                 zip(trials["cell"], trials[OUTCOME], strict=True)])
    cells = {k: {**values[c], OUTCOME: o} for (c, o), k in index.items()}
    return pd.DataFrame(summary_rows(frame_columns(trials), cells)), trials


def pq_columns(path: Path) -> list[str]:
    """The column names of a Parquet file."""
    import pyarrow.parquet as pq

    return list(pq.read_schema(path).names)


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
    line = 9.0  # points per row
    for r, (name, texts) in enumerate(rows):
        y = -4.0 - line * r
        ax.annotate(name, xy=(0, 0), xycoords="axes fraction", xytext=(-6, y),
                    textcoords="offset points", ha="right", va="top", fontsize=6.5,
                    style="italic", annotation_clip=False)
        start = 0
        for i in range(1, len(texts) + 1):
            if i == len(texts) or texts[i] != texts[start] or r >= len(sweep.axis) - 1:
                ax.annotate(texts[start], xy=((start + i - 1) / 2, 0),
                            xycoords=ax.get_xaxis_transform(), xytext=(0, y),
                            textcoords="offset points", ha="center", va="top",
                            fontsize=6.5, annotation_clip=False)
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
    return (4 + 9 * rows) / 72 + 0.1


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
    chosen = [s for s in SHARES if (names is None or s[0] in names)
              and f"{s[0]}_fraction" in summary.columns]  # (older summaries: no outcomes)
    offsets = np.linspace(-spread, spread, len(chosen)) if len(chosen) > 1 else [0.0]
    top = 0.0
    for (name, label, colour), dx in zip(chosen, offsets, strict=True):
        p = summary[f"{name}_fraction"].to_numpy(dtype=np.float64)
        low = summary[f"{name}_fraction_low"].to_numpy(dtype=np.float64)
        high = summary[f"{name}_fraction_high"].to_numpy(dtype=np.float64)
        ax.errorbar(x + dx, p, yerr=[p - low, high - p], fmt="o", ms=3.5, capsize=2,
                    lw=1, color=colour, label=label, clip_on=False)
        if np.isfinite(high).any():
            top = max(top, float(np.nanmax(high)))
    # a share is never below 0 (markers at 0 drawn whole: clip_on=False); headroom for the
    # legend above the points
    ax.set_ylim(0.0, min(1.3, max(0.05, 1.35 * top)))


def _finish(fig: Figure, title: str) -> Figure:
    """Title and layout (tight_layout makes room for the cell table: its texts belong to the
    axes)."""
    fig.suptitle(title)
    fig.tight_layout()
    return fig


# ---------------------------------------------------------------------------------------
# What a sweep's title says: the conditions every cell shares, or that they vary.

def _varies(sweep: SweepData, key: str) -> bool:
    """Whether a spec key takes more than one value across the sweep's cells (a grid entry
    or a group sets it) or per trial (perturbed)."""
    grid = sweep.tree.get("sweep", {}).get("grid", {})
    perturbed = {f"plant.{k}" for k in sweep.tree.get("sweep", {}).get("perturb", {})}
    return key in grid or key in perturbed or any(
        _is_group(values) and any(key in t for t in values) for values in grid.values())


def conditions(sweep: SweepData) -> str:
    """The plant, the sensor noise and the torque limit of a sweep's cells, as a title
    names them ("per cell" where the grid varies one, "perturbed" where trials do)."""
    def value(key: str, unit: str) -> str:
        if _varies(sweep, key):
            perturbed = key.startswith("plant.") and key.removeprefix("plant.") in \
                sweep.tree.get("sweep", {}).get("perturb", {})
            return "perturbed" if perturbed else "per cell"
        raw = value_at(sweep.tree, key)
        if raw in ("inf", math.inf) or raw is None:
            return "none"
        return f"{raw:g} {unit}" if isinstance(raw, int | float) else str(raw)

    model = "per cell" if _varies(sweep, "plant.model") else str(
        value_at(sweep.tree, "plant.model") or "kinematic")
    plant = f"{model} plant" if model != "per cell" else "plant per cell"
    parts = [plant, f"sensor noise {value('track.sensor_noise', 'rad')}"]
    if model != "kinematic":
        parts.append(f"torque limit {value('plant.torque_limit', 'N m')}")
    name = sweep.tree.get("name", "")
    return f"sweep {name!r}: " + ", ".join(parts)


# ---------------------------------------------------------------------------------------
# The figures.

@styled
def errors_figure(sweep: SweepData) -> Figure:
    """Tracking-error distributions per cell, and beside them the shares of trials they
    leave out (diverged, unresolved, error) and of singular hits, with 95 % intervals."""
    bottom = _table_height(sweep)
    fig = new_figure(sweep.width, 7.0 + bottom)
    axes = fig.subplots(4, 1, sharex=True, gridspec_kw={"height_ratios": [1, 1, 1, 0.9]})
    for ax, metric, label in zip(axes[:3], ("err_theta_rms", "err_y_rms", "err_y_final"),
                                 ("rms error of $\\theta$ [rad]", "rms error of $y$ [rad]",
                                  "final error of $y$ [rad]"), strict=True):
        log_boxes(ax, sweep.by_cell(metric))
        ax.set_ylabel(label)
        ax.grid(axis="x", visible=False)
    ax = axes[-1]
    shares(ax, sweep.summary, np.arange(len(sweep.cells), dtype=np.float64))
    ax.set_ylabel("share of trials\n(95 % interval)")
    ax.grid(axis="x", visible=False)
    ax.legend(ncol=4, loc="upper left")
    cell_axis(ax, sweep)
    return _finish(fig, f"{conditions(sweep)}\ntracking error per cell over resolved trials "
                        "(ok, singular; box: quartiles, whiskers: 5-95 %);\nshares of trials "
                        "that reached the goal, diverged, were unresolved, could not run, or "
                        "had a singular hit")


@dataclass(frozen=True)
class OutcomeAxis:
    """What ``sweep_singular``'s x axis shows: a grid key's value per cell (numeric, or
    categories in the grid's order), the grid key whose values get a colour each
    (``hue``), and each cell's series (its values of every other grid key)."""

    key: str | None  # None: one point per cell, named by the table under the axis
    label: str
    x: Array
    ticks: list[str]  # category names (a text key), else []
    scale: str  # "linear", "log" or "symlog"
    series: list[str]  # per cell: the legend entry of its line
    colours: list[int]  # per cell: its colour (by hue value, or by series)
    styles: list[int]  # per cell: its line style (by the other grid keys' values)

    @classmethod
    def choose(cls, sweep: SweepData, x: str | None, hue: str | None) -> OutcomeAxis:
        """The axis for ``--x`` and ``--hue`` (default: the perturbation size, else the
        first numeric grid key with more than one value; no hue); FlatcliError naming a key
        that is not one of the sweep's grid keys, or that takes one value only."""
        columns = grid_columns(sweep)
        for option, key in (("--x", x), ("--hue", hue)):
            if key is not None and key not in columns:
                raise FlatcliError(f"{option}: {key!r} is not a grid key of this sweep; its "
                                   f"grid keys: {', '.join(columns) or 'none'}"
                                   f"{suggest(key, columns)}")
        if x is not None and x == hue:
            raise FlatcliError(f"--hue: {hue!r} is the --x key; choose another grid key")
        if x is None:
            numeric = [k for k in columns if _numeric(sweep, k) is not None]
            sizes = [k for k in numeric if k.startswith("sweep.perturb.")]
            x = next(iter(sizes or numeric), None)
        if x is None:
            n = len(sweep.cells)
            return cls(None, "", np.arange(n, dtype=np.float64), [], "linear", [""] * n,
                       list(range(n)), [0] * n)
        values = _numeric(sweep, x)
        label = _key_label(sweep, x)
        ticks: list[str] = []
        if values is None:  # text (a group's label, a word): categories, in the grid's order
            texts = [_text(v) for v in sweep.summary[x].tolist()]
            ticks = list(dict.fromkeys(texts))
            if len(ticks) < 2:
                raise FlatcliError(f"--x: {x!r} takes one value in this sweep; nothing to "
                                   "draw against")
            values = np.array([ticks.index(t) for t in texts], dtype=np.float64)
            scale = "linear"
        else:
            scale = _scale(values)
        entries = list(sweep.tree.get("sweep", {}).get("grid", {}))  # not a group's members
        others = [k for k in columns if k in entries and k not in (x, hue) and
                  not _inside(sweep, k, (x, hue)) and _differs(sweep, k)]
        rest = [", ".join(f"{short_key(k)} = {_text(sweep.summary[k].iloc[i])}"
                          for k in others) for i in range(len(sweep.cells))]
        if hue is not None:
            hues = [_text(v) for v in sweep.summary[hue].tolist()]
            order = list(dict.fromkeys(hues))
            series = [f"{short_key(hue)} = {h}" + (f"; {r}" if r else "")
                      for h, r in zip(hues, rest, strict=True)]
            colours = [order.index(h) for h in hues]
            kinds = list(dict.fromkeys(rest))
            styles = [kinds.index(r) for r in rest]
        else:
            series = [r or "all cells" for r in rest]
            kinds = list(dict.fromkeys(series))
            colours = [kinds.index(r) for r in series]
            styles = [0] * len(series)
        return cls(x, label, values, ticks, scale, series, colours, styles)


def _inside(sweep: SweepData, key: str, groups: Sequence[str | None]) -> bool:
    """Whether ``key`` is set by one of the grid's groups named in ``groups``."""
    grid = sweep.tree.get("sweep", {}).get("grid", {})
    return any(g in grid and _is_group(grid[g]) and any(key in t for t in grid[g])
               for g in groups if g is not None)


def grid_columns(sweep: SweepData) -> list[str]:
    """The grid columns of a sweep's summary: its grid keys, its groups (their labels) and
    the spec keys its groups set."""
    columns = list(sweep.summary.columns)
    return columns[columns.index("cell") + 1: columns.index("trials")]


def _numeric(sweep: SweepData, key: str) -> Array | None:
    """A grid column's values as numbers, when they are (a list-valued key: the one
    component that varies); None for text or a list whose components vary otherwise."""
    column = sweep.summary[key]
    values = column.tolist()
    if pd.api.types.is_numeric_dtype(column) and not pd.api.types.is_bool_dtype(column):
        array = column.to_numpy(dtype=np.float64)
        return array if len(set(array.tolist())) > 1 else None
    if values and all(isinstance(v, list | tuple | np.ndarray) for v in values):
        lists = [np.asarray(v, dtype=np.float64) for v in values]
        if len({len(v) for v in lists}) == 1:
            stacked = np.stack(lists)
            varying = [i for i in range(stacked.shape[1]) if len(set(stacked[:, i])) > 1]
            if len(varying) == 1:
                result: Array = stacked[:, varying[0]]
                return result
    return None


def _differs(sweep: SweepData, key: str) -> bool:
    return len({_text(v) for v in sweep.summary[key].tolist()}) > 1


def _key_label(sweep: SweepData, key: str) -> str:
    """An axis label of a grid key: its name (a list's varying component ``[i]``) and
    unit."""
    name = short_key(key)
    values = sweep.summary[key].tolist()
    if values and all(isinstance(v, list | tuple | np.ndarray) for v in values):
        stacked = np.stack([np.asarray(v, dtype=np.float64) for v in values])
        varying = [i for i in range(stacked.shape[1]) if len(set(stacked[:, i])) > 1]
        name += f"[{varying[0]}]" if len(varying) == 1 else ""
    if all(isinstance(v, str) for v in values):
        return name
    unit = key_unit(sweep.tree, key) or "1"
    return f"{name} [{unit}]" if unit != "1" else name


def _scale(x: Array) -> str:
    """log when every value is positive and they span a decade or more; symlog when 0 is
    one of them and the others span two decades (sensor noise 0, 1e-4, 1e-3); else linear."""
    positive = x[x > 0]
    if len(positive) == len(x) and positive.max() >= 10 * positive.min():
        return "log"
    if np.all(x >= 0) and len(positive) >= 2 and positive.max() >= 100 * positive.min():
        return "symlog"
    return "linear"


#: The panels of ``sweep_singular``: (kind, title); a kind's shares are summary columns
#: ``{kind}_fraction`` with ``_low`` and ``_high``.
OUTCOME_TITLES = {"reached": "trials that reached the goal (outcome)",
                  "singular": "simulated trials with a singular hit",
                  "diverged": "trials that diverged", "unresolved": "trials unresolved",
                  "error": "trials that could not run"}


@styled
def outcomes_figure(sweep: SweepData, axis: OutcomeAxis) -> Figure:
    """The final error of y (median, to the 95th percentile) and the shares of singular hits
    and failures (with their 95 % intervals; the share axis starts at 0) against a grid key,
    one line per value of ``hue`` and of the other grid keys; per cell when no grid key is
    numeric or chosen."""
    summary = sweep.summary
    kinds = [*(["reached"] if "reached_fraction" in summary.columns else []),
             "singular", "diverged", *(n for n in FAILURES
                                       if n != "diverged" and summary[n].sum() > 0)]
    if axis.key is None:
        bottom = _table_height(sweep)
        fig = new_figure(sweep.width, 3.2 + bottom)
        ax = fig.subplots()
        shares(ax, summary, axis.x, kinds)
        ax.set_ylabel("share of trials (95 % interval)")
        ax.grid(axis="x", visible=False)
        ax.legend()
        cell_axis(ax, sweep)
        return _finish(fig, f"{conditions(sweep)}\nsingular hits and failures per cell")
    panels = ["final error", *kinds]  # not "error": that is a status's share (kinds)
    columns = 2 if len(panels) <= 4 else 3
    rows = math.ceil(len(panels) / columns)
    fig = new_figure(PAGE_WIDTH, 2.3 * rows + 0.9)
    axes = fig.subplots(rows, columns, sharex=True, squeeze=False).ravel()
    for extra in axes[len(panels):]:
        extra.set_visible(False)
    series = list(dict.fromkeys(axis.series))
    step = _spread(axis, len(series))
    styles = ["-", "--", ":", "-."]
    markers = ["o", "s", "^", "D", "v"]
    for ax, kind in zip(axes, panels, strict=False):
        for j, name in enumerate(series):
            rows_ = np.array([s == name for s in axis.series])
            order = np.argsort(axis.x[rows_], kind="stable")
            part = summary[rows_].iloc[order]
            xs = _shifted(axis.x[rows_][order], step * (j - (len(series) - 1) / 2), axis.scale)
            first = int(np.flatnonzero(rows_)[0])
            look = {"color": f"C{axis.colours[first] % 9}",
                    "ls": styles[axis.styles[first] % len(styles)],
                    "marker": markers[axis.styles[first] % len(markers)]}
            if kind == "final error":
                median = part["err_y_final_median"].to_numpy(dtype=np.float64)
                p95 = part["err_y_final_p95"].to_numpy(dtype=np.float64)
                ax.errorbar(xs, median, yerr=[np.zeros_like(median), p95 - median],
                            capsize=2, lw=1, ms=3.5, label=name or "all cells", **look)
                continue
            p = part[f"{kind}_fraction"].to_numpy(dtype=np.float64)
            low = part[f"{kind}_fraction_low"].to_numpy(dtype=np.float64)
            high = part[f"{kind}_fraction_high"].to_numpy(dtype=np.float64)
            ax.errorbar(xs, p, yerr=[p - low, high - p], capsize=2, lw=1, ms=3.5,
                        clip_on=False, label=name or "all cells", **look)
        if kind == "final error":
            ax.set_yscale("log")
            ax.set_ylabel("final error of $y$ [rad]\n(median to 95th percentile)")
            ax.set_title("resolved trials (ok, singular)")
        else:
            top = float(np.nanmax(summary[f"{kind}_fraction_high"].to_numpy(dtype=np.float64),
                                  initial=0.0))
            ax.set_ylim(0.0, min(1.0, max(0.05, 1.15 * top)))  # a share is never below 0
            ax.set_ylabel("share (95 % interval)")
            ax.set_title(OUTCOME_TITLES[kind])
        if axis.scale == "log":
            ax.set_xscale("log")
        elif axis.scale == "symlog":
            ax.set_xscale("symlog", linthresh=float(np.min(axis.x[axis.x > 0])), linscale=0.5)
        if axis.ticks:
            ax.set_xticks(range(len(axis.ticks)), axis.ticks)
        ax.grid(axis="x", visible=axis.scale != "linear" or not axis.ticks)
    for ax in axes[max(0, len(panels) - columns):len(panels)]:
        ax.set_xlabel(axis.label)
        ax.xaxis.set_tick_params(labelbottom=True)
    handles, names = axes[0].get_legend_handles_labels()
    fig.suptitle(f"{conditions(sweep)}\noutcomes against {short_key(axis.key)} (points "
                 "slightly spread in x to keep the intervals apart)")
    shown = any(names) and names != ["all cells"]
    spare = axes[len(panels)] if len(panels) < len(axes) else None
    if shown and spare is not None:  # the empty panel holds the legend, inside the page
        spare.set_visible(True)
        spare.axis("off")
        spare.legend(handles, names, loc="center", fontsize=7, frameon=False)
        fig.tight_layout()
    elif shown:  # below the panels, in as many columns as fit the page
        widest = max(len(n) for n in names)
        ncol = max(1, min(3, int(PAGE_WIDTH * 72 / (7 * 0.6 * widest + 40))))
        lines = math.ceil(len(names) / ncol)
        fig.legend(handles, names, loc="lower center", ncol=ncol, fontsize=7, frameon=False)
        fig.tight_layout(rect=(0, 0.02 + 0.035 * lines, 1, 1))
    else:
        fig.tight_layout()
    return fig


def _spread(axis: OutcomeAxis, series: int) -> float:
    """How far apart the series' points are drawn in x (in log units on a log axis)."""
    if series < 2:
        return 0.0
    x = axis.x[axis.x > 0] if axis.scale != "linear" else axis.x
    span = float(np.ptp(np.log(x))) if axis.scale != "linear" and len(x) > 1 else float(
        np.ptp(axis.x)) or 1.0
    return 0.03 * span / (series - 1)


def _shifted(x: Array, shift: float, scale: str) -> Array:
    if scale == "linear":
        return x + shift
    shifted: Array = np.where(x > 0, x * np.exp(shift), x)
    return shifted


@styled
def margin_figure(sweep: SweepData) -> Figure:
    """How close resolved trials came to the singular set (min margin, with the singular
    threshold) and how fast the joints turned (peak rate, with the rate limit)."""
    bottom = _table_height(sweep)
    fig = new_figure(sweep.width, 5.0 + bottom)
    axes = fig.subplots(2, 1, sharex=True)
    log_boxes(axes[0], sweep.by_cell("min_margin"))
    notes = []
    notes += _limit_line(axes[0], sweep.setting("track.singular_threshold"),
                         "track.singular_threshold", "rad/s", "C3")
    axes[0].set_ylabel("min margin $|\\sin\\theta_1\\,u_1|$\n[rad/s]")
    log_boxes(axes[1], sweep.by_cell("peak_rate"))
    notes += _limit_line(axes[1], sweep.setting("track.rate_limit"), "track.rate_limit",
                         "rad/s", "C3")
    notes += _limit_line(axes[1], sweep.setting("track.divergence_bound"),
                         "track.divergence_bound", "rad/s (bounds $\\theta$ and $u_1$; "
                         "$\\theta_2'$ is an input)", "0.3")
    axes[1].set_ylabel("peak $|\\theta_1'|$, $|\\theta_2'|$\n[rad/s]")
    for ax in axes:
        ax.grid(axis="x", visible=False)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="best")
    cell_axis(axes[-1], sweep)
    title = (f"{conditions(sweep)}\nclosest approach to the singular set and peak joint rate "
             "per cell (resolved trials)")
    return _finish(fig, title + ("\n" + ", ".join(notes) if notes else ""))


def _limit_line(ax: Any, values: Array, key: str, unit: str, colour: str) -> list[str]:
    """A dashed line per cell at a threshold or limit; an infinite one (no limit) is not
    drawn: the text for the title that says so is returned."""
    finite = np.isfinite(values)
    if not finite.any():
        return [f"{key} = inf (no limit)"]
    if np.all(values[finite] == values[finite][0]) and finite.all():
        ax.axhline(values[0], ls="--", lw=1.0, color=colour,
                   label=f"{key} = {fmt(float(values[0]))} {unit}")
        return []
    label = f"{key} (per cell) [{unit}]"
    for i, v in enumerate(values):
        if np.isfinite(v):
            ax.hlines(v, i - 0.4, i + 0.4, ls="--", lw=1.0, color=colour, label=label)
            label = "_"
    return []


@styled
def momentum_figure(sweep: SweepData) -> Figure:
    """Momentum drift of the integrated motion per cell, beside the plan's own momentum
    residual on the plant (the controller's model error)."""
    bottom = _table_height(sweep)
    fig = new_figure(sweep.width, 3.4 + bottom)
    ax = fig.subplots()
    log_boxes(ax, sweep.by_cell("momentum_drift"), floor=1e-18)
    residual = sweep.summary["plan_momentum_residual_max"].to_numpy(dtype=np.float64)
    ax.plot(np.arange(len(sweep.cells)), np.maximum(residual, 1e-18), "x", color="C3",
            ls="none", label="plan_momentum_residual: the plan's $H$ on the plant "
                             "(model error)")
    ax.plot([], [], "s", mfc="none", color="k", ls="none",
            label="momentum_drift: max $|H - H_0|$ along a trial (resolved trials)")
    ax.set_ylabel("$|H - H_0|$ [kg m$^2$/s]")
    ax.grid(axis="x", visible=False)
    ax.legend(loc="best")
    cell_axis(ax, sweep)
    return _finish(fig, f"{conditions(sweep)}\nangular momentum of the integrated motion, "
                        "from the full link kinematics, per cell")
