"""What people read: terminal tables and PNG figures of plans and closed-loop runs.

Tables are GitHub-flavoured Markdown with aligned columns, so the same text reads well on a
terminal and renders in REPORT.md / summary.md. Figures use matplotlib's object API (no
pyplot state, no display needed).
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from flatcli.core.metrics import STATUS_NAMES
from flatcli.core.optimize import OptimizeResult
from flatcli.core.planning import FlatPlan, PlanSamples
from flatcli.storage import atomic_path

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Array = NDArray[np.float64]


def fmt(value: object, digits: int = 4) -> str:
    """A number for a table: compact, aligned, readable; other values as str."""
    if value is None:
        return "-"
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


# ---------------------------------------------------------------------------------------
# Sweeps: progress while running, summary statistics and tables after.

#: Trials whose errors enter the tracking-error statistics: those that ran to the end
#: (statuses of ``flatcli.core.metrics.STATUS_NAMES``).
COMPLETED = ("ok", "singular")
ERROR_METRICS = ("err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final")


class Progress:
    """A progress bar on a terminal, plain periodic lines otherwise, nothing when quiet.

    Trials are counted as chunks finish (``advance``) and, while a local sweep runs, as
    the workers finish them (``live``, a few times a second; ``flatcli.sweep.tally``): the
    bar shows whichever count is ahead, with the trials of each status so far.
    """

    def __init__(self, name: str, quiet: bool = False, stream: TextIO | None = None,
                 interval: float = 10.0) -> None:
        self.name = name
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.interval = interval
        self._bar: Any = None
        self._lock = threading.Lock()
        self._total = 0
        self._resumed = 0
        self._chunked = 0  # trials of this run in finished chunks
        self._chunk_counts: dict[str, int] = {}
        self._live = 0  # trials of this run the workers have finished
        self._live_counts: dict[str, int] = {}
        self._shown = 0
        self._t0 = 0.0
        self._last = 0.0

    def start(self, total: int, done: int, description: str) -> None:
        self._total, self._resumed = total, done
        self._chunked = self._live = self._shown = 0
        self._chunk_counts, self._live_counts = {}, {}
        self._t0 = self._last = time.perf_counter()
        if self.quiet:
            return
        resumed = f", resuming with {done} done" if done else ""
        print(f"sweep {self.name!r}: {total} trials on {description}{resumed}",
              file=self.stream, flush=True)
        if self.stream.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=total, initial=done, unit="trial", file=self.stream,
                             dynamic_ncols=True, smoothing=0.1)

    @property
    def fresh(self) -> int:
        """Trials finished by this run so far."""
        return max(self._chunked, self._live)

    @property
    def counts(self) -> dict[str, int]:
        """Trials of this run so far by status."""
        return dict(self._live_counts if self._live >= self._chunked else self._chunk_counts)

    def advance(self, n: int, counts: Mapping[str, int] | None = None) -> None:
        """A chunk of ``n`` trials finished (with these statuses)."""
        with self._lock:
            self._chunked += n
            for status, k in (counts or {}).items():
                self._chunk_counts[status] = self._chunk_counts.get(status, 0) + k
            self._show(final=self._resumed + self._chunked >= self._total)

    def live(self, n: int, counts: Mapping[str, int]) -> None:
        """The workers have finished ``n`` trials of this run so far (with these statuses)."""
        with self._lock:
            self._live, self._live_counts = n, dict(counts)
            self._show(final=False)

    def _show(self, final: bool) -> None:
        if self.quiet:
            return
        fresh = self.fresh
        done = self._resumed + fresh
        if self._bar is not None:
            self._bar.set_postfix_str(_counts_text(self.counts), refresh=False)
            if fresh > self._shown:
                self._bar.update(fresh - self._shown)  # redraws (at most 10 times a second)
                self._shown = fresh
            return
        now = time.perf_counter()
        if now - self._last >= self.interval or final:
            self._last = now
            rate = fresh / max(now - self._t0, 1e-9)
            eta = (self._total - done) / rate if rate > 0 else math.inf
            counts = self.counts
            tail = f"; {_counts_text(counts)}" if counts else ""
            print(f"  {done}/{self._total} trials ({100 * done / max(self._total, 1):.0f}%)"
                  f", {rate:.0f} trials/s, ETA {eta:.0f} s{tail}", file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def _counts_text(counts: Mapping[str, int]) -> str:
    """'ok 950, singular 40, diverged 8, unresolved 2' (error only when there is one)."""
    names = [n for n in STATUS_NAMES if n != "error" or counts.get(n)]
    return ", ".join(f"{n} {counts.get(n, 0)}" for n in names)


def summarize_trials(frame: pd.DataFrame, cells: Mapping[int, Mapping[str, Any]]
                     ) -> pd.DataFrame:
    """Per-cell statistics of a sweep's trials (definitions in the README).

    Parameters
    ----------
    frame : one row per trial with columns cell, status, singular_hits and the metrics
    cells : cell index -> {grid key: value as stored in the trials' column}
    """
    rows = []
    for cell, values in cells.items():
        group = frame[frame["cell"] == cell]
        done = group[group["status"].isin(COMPLETED)]
        simulated = group[group["status"] != "error"]
        row: dict[str, Any] = {"cell": cell, **values, "trials": len(group)}
        for status in STATUS_NAMES:
            row[status] = int((group["status"] == status).sum())
        for metric in ERROR_METRICS:
            values_ = done[metric].to_numpy(dtype=float)
            row[f"{metric}_median"] = _stat(np.median, values_)
            row[f"{metric}_p95"] = _stat(lambda v: np.percentile(v, 95), values_)
            row[f"{metric}_max"] = _stat(np.max, values_)
        hits = simulated["singular_hits"].to_numpy()
        row["singular_fraction"] = float(np.mean(hits > 0)) if len(hits) else math.nan
        row["min_margin_median"] = _stat(np.median, simulated["min_margin"].to_numpy(float))
        drift = done["momentum_drift"].to_numpy(dtype=float)
        row["momentum_drift_median"] = _stat(np.median, drift)
        row["momentum_drift_max"] = _stat(np.max, drift)
        row["plan_momentum_residual_max"] = _stat(
            np.max, simulated["plan_momentum_residual"].to_numpy(float))
        rows.append(row)
    return pd.DataFrame(rows)


def _stat(fn: Any, values: Array) -> float:
    return float(fn(values)) if len(values) else math.nan


def short_key(key: str) -> str:
    """A grid key as a column heading: perturbation keys without their 'sweep.perturb.'."""
    return key.removeprefix("sweep.perturb.")


def summary_markdown(summary: pd.DataFrame, grid_keys: Sequence[str]) -> str:
    """The sweep's summary as Markdown tables, each readable on an 80-column terminal."""
    def rows(cols: Sequence[str]) -> list[list[object]]:
        return [[int(r["cell"]), *(r[c] for c in cols)] for _, r in summary.iterrows()]

    parts = []
    if grid_keys:
        parts += ["### Cells\n", table(["cell", *(short_key(k) for k in grid_keys)],
                                       rows(list(grid_keys))), ""]
    parts += [
        "### Trials by status\n",
        table(["cell", "trials", *STATUS_NAMES], rows(["trials", *STATUS_NAMES])),
    ]
    for name in ("theta", "y"):
        cols = [f"err_{name}_{kind}_{stat}" for kind in ("rms", "final")
                for stat in ("median", "p95", "max")]
        parts += [
            f"\n### Tracking error of {name} [rad] (trials that ran to the end)\n",
            table(["cell", "rms med", "rms p95", "rms max", "final med", "final p95",
                   "final max"], rows(cols), 3),
        ]
    parts += [
        "\n### Singularity and momentum\n",
        table(["cell", "hit frac", "min margin med", "drift med", "drift max", "plan res max"],
              rows(["singular_fraction", "min_margin_median", "momentum_drift_median",
                    "momentum_drift_max", "plan_momentum_residual_max"]), 3),
        "\nhit frac: share of simulated trials with a sample of margin below "
        "track.singular_threshold;\nmargin [rad/s]; drift and plan res(idual) of H "
        "[kg m^2/s].",
    ]
    return "\n".join(parts)


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
