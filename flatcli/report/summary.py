"""A sweep's per-cell statistics (summary.parquet) and their Markdown tables (summary.md).

Statistics of a trial's numbers (errors, margin, drift, peak rate, error estimate) are taken
over the trials resolved to the end (``RESOLVED``: ok, singular) only: a diverged or unresolved
trial's numbers stop at an arbitrary time and an error trial has none. Of those, the verified
trials (``verified``: an integrator that controls its error) and the unverified ones (fixed-step
RK4) are never averaged together: a cell's statistics are over its verified trials if it has
any, else over its unverified ones, and ``statistics_of`` says which. What is left out is
counted instead: per status, and as fractions of the cell's trials with a 95 % Wilson score
interval (``wilson_interval``), so a reader sees how much each statistic leaves out.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.stats import binomtest

from flatcli.core.metrics import METRIC_NAMES, RESOLVED, STATUS_NAMES
from flatcli.report.tables import fmt, table

Array = NDArray[np.float64]

#: Trials whose numbers enter the statistics: those resolved to the end (``RESOLVED``).
COMPLETED = RESOLVED
#: The columns of trials.parquet that ``summarize_trials`` reads (those after the metrics
#: may be missing: a directory written before flatcli recorded them).
SUMMARY_INPUTS: tuple[str, ...] = tuple(dict.fromkeys((
    "cell", "status", "singular_hits", *METRIC_NAMES, "verified", "reference_difference",
    "reference_status")))
ERROR_METRICS = ("err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final")
#: Statuses of trials that did not run to the end, reported as fractions of a cell's trials.
FAILURES = ("diverged", "unresolved", "error")


def wilson_interval(successes: Any, trials: Any, confidence: float = 0.95
                    ) -> tuple[Array, Array]:
    """Wilson score interval of a binomial proportion (95 % by default), scipy's
    (``scipy.stats.binomtest(k, n).proportion_ci(confidence, method="wilson")``).

    With p = k / n and z = Phi^-1((1 + confidence) / 2): (p + z^2 / 2n -+ z sqrt(p (1 - p) /
    n + z^2 / 4n^2)) / (1 + z^2 / n) (Wilson 1927; Brown, Cai, DasGupta, Statist. Sci. 16,
    2001). Unlike p -+ z sqrt(p (1 - p) / n) it stays inside [0, 1] and is not empty at
    k = 0 or k = n, which is where a sweep's failure counts usually are.

    Parameters
    ----------
    successes : k, counts (array-like of ints)
    trials : n, same shape (n = 0 gives nan bounds)

    Returns
    -------
    low, high : arrays of k's shape
    """
    k, n = np.broadcast_arrays(np.asarray(successes), np.asarray(trials))
    low = np.full(k.shape, np.nan)
    high = np.full(k.shape, np.nan)
    for i in np.ndindex(k.shape):
        if n[i] > 0:
            ci = binomtest(int(k[i]), int(n[i])).proportion_ci(confidence, method="wilson")
            low[i], high[i] = float(ci.low), float(ci.high)
    return low, high


def summarize_trials(frame: pd.DataFrame, cells: Mapping[int, Mapping[str, Any]]
                     ) -> pd.DataFrame:
    """Per-cell statistics of a sweep's trials (definitions in docs/outputs.md, *Sweep output*).

    Parameters
    ----------
    frame : one row per trial with columns cell, status, singular_hits and the metrics (a
        metric that does not apply is nan or null: it never enters a statistic)
    cells : cell index -> {grid column: the cell's value}

    Returns
    -------
    One row per cell: cell, the grid columns, trials, the count of each status, resolved
    (ok + singular) and simulated (all but error) counts; median, p95 and max of each of
    ``ERROR_METRICS`` and median/max of min_margin, momentum_drift, peak_rate and
    err_estimate over the counted trials (resolved; of those the verified ones where the cell
    has any, ``statistics_of``); the max plan_momentum_residual over simulated trials;
    ``singular_fraction`` (simulated trials with a singular hit) and each of ``FAILURES`` as
    a fraction of the cell's trials, each with its 95 % Wilson interval (``_low``, ``_high``).
    Statistics over no trials are nan (null in summary.parquet).
    """
    rows = []
    for cell, values in cells.items():
        group = frame[frame["cell"] == cell]
        status = group["status"]
        resolved = group[status.isin(RESOLVED)]
        sure = _flag(resolved, "verified")
        kind = "verified" if sure.any() else "unverified" if len(resolved) else None
        done = resolved[sure] if sure.any() else resolved
        simulated = group[status != "error"]
        row: dict[str, Any] = {"cell": cell, **values, "trials": len(group)}
        for name in STATUS_NAMES:
            row[name] = int((status == name).sum())
        for metric in ERROR_METRICS:
            values_ = _present(done[metric])
            row[f"{metric}_median"] = _stat(np.median, values_)
            row[f"{metric}_p95"] = _stat(lambda v: np.percentile(v, 95), values_)
            row[f"{metric}_max"] = _stat(np.max, values_)
        hits = _present(simulated["singular_hits"])
        row["singular_fraction"] = float(np.mean(hits > 0)) if len(hits) else math.nan
        row["min_margin_median"] = _stat(np.median, _present(done["min_margin"]))
        drift = _present(done["momentum_drift"])
        row["momentum_drift_median"] = _stat(np.median, drift)
        row["momentum_drift_max"] = _stat(np.max, drift)
        row["plan_momentum_residual_max"] = _stat(
            np.max, _present(simulated["plan_momentum_residual"]))
        # added after the columns above, which keep their names and places
        row["resolved"] = len(resolved)
        row["simulated"] = len(simulated)
        _fraction(row, "singular", int(np.sum(hits > 0)), len(hits))
        for name in FAILURES:
            _fraction(row, name, row[name], len(group))
        for metric in ("peak_rate", "err_estimate"):
            values_ = _present(done[metric])
            row[f"{metric}_median"] = _stat(np.median, values_)
            row[f"{metric}_max"] = _stat(np.max, values_)
        row["verified_trials"] = int(sure.sum())
        row["unverified_trials"] = len(resolved) - row["verified_trials"]
        row["statistics_of"] = kind
        _reference(row, group)
        rows.append(row)
    return pd.DataFrame(rows)


def _flag(frame: pd.DataFrame, column: str) -> Array:
    """A boolean column as a numpy mask (False where it is missing or null: a directory
    written before flatcli recorded it has no verified trials)."""
    if column not in frame:
        return np.zeros(len(frame), dtype=bool)
    return np.asarray(frame[column].fillna(False).astype(bool).to_numpy(), dtype=bool)


def _reference(row: dict[str, Any], group: pd.DataFrame) -> None:
    """The cell's trials checked against the reference integrator (``sweep.verify``): how
    many, how far the ones that both integrators resolved to the end were from it (median,
    max: a trial stopped at a crossing has no accuracy to compare) and how many ended with
    another status."""
    if "reference_status" in group:
        checked = group[group["reference_status"].notna()]
    else:
        checked = group.iloc[:0]
    row["reference_checked"] = len(checked)
    both = (checked[checked["status"].isin(RESOLVED)
                    & checked["reference_status"].isin(RESOLVED)] if len(checked) else checked)
    gap = _present(both["reference_difference"]) if len(both) else np.zeros(0)
    row["reference_difference_median"] = _stat(np.median, gap)
    row["reference_difference_max"] = _stat(np.max, gap)
    row["reference_status_mismatches"] = int(
        (checked["reference_status"] != checked["status"]).sum()) if len(checked) else 0


def _present(column: pd.Series) -> Array:
    """A column's values that apply (nan and null dropped), as floats."""
    values: Array = column.to_numpy(dtype=np.float64, na_value=np.nan)
    return values[~np.isnan(values)]


def _stat(fn: Callable[[Array], Any], values: Array) -> float:
    return float(fn(values)) if len(values) else math.nan


def _fraction(row: dict[str, Any], name: str, k: int, n: int) -> None:
    """``{name}_fraction`` = k / n and its 95 % Wilson interval, into ``row``."""
    low, high = wilson_interval(k, n)
    row[f"{name}_fraction"] = k / n if n else math.nan
    row[f"{name}_fraction_low"] = float(low)
    row[f"{name}_fraction_high"] = float(high)


def short_key(key: str) -> str:
    """A grid key as a column heading: perturbation keys without their 'sweep.perturb.'."""
    return key.removeprefix("sweep.perturb.")


def with_interval(value: float, low: float, high: float) -> str:
    """A fraction and its interval as percentages: '26.5 (24.6-28.5)'; '-' if undefined."""
    if any(math.isnan(float(x)) for x in (value, low, high)):
        return "-"
    return f"{fmt(100 * value, 3)} ({fmt(100 * low, 2)}-{fmt(100 * high, 2)})"


def summary_markdown(summary: pd.DataFrame, grid_keys: Sequence[str]) -> str:
    """The sweep's summary as Markdown tables, each readable on an 80-column terminal.

    ``grid_keys``: the grid columns of ``summary`` to list in the *Cells* table."""
    def rows(cols: Sequence[str]) -> list[list[object]]:
        return [[int(r["cell"]), *(cell_text(r[c]) for c in cols)]
                for _, r in summary.iterrows()]

    def marked(lines: list[list[object]]) -> list[list[object]]:
        """Rows whose statistics are over unverified trials: the cell marked *."""
        kinds = summary.get("statistics_of")
        if kinds is None:
            return lines
        return [[f"{line[0]}*" if kind == "unverified" else line[0], *line[1:]]
                for line, kind in zip(lines, kinds, strict=True)]

    def shares(names: Sequence[str]) -> list[list[object]]:
        return [[int(r["cell"]), *(with_interval(r[f"{n}_fraction"], r[f"{n}_fraction_low"],
                                                 r[f"{n}_fraction_high"]) for n in names)]
                for _, r in summary.iterrows()]

    parts = []
    if grid_keys:
        parts += ["### Cells\n", table(["cell", *(short_key(k) for k in grid_keys)],
                                       rows(list(grid_keys))), ""]
    parts += [
        "### Trials by status\n",
        table(["cell", "trials", *STATUS_NAMES, "resolved"],
              rows(["trials", *STATUS_NAMES, "resolved"])),
        "\n### Accuracy of the resolved trials\n",
        table(["cell", "resolved", "verified", "unverified", "statistics of"],
              rows(["resolved", "verified_trials", "unverified_trials", "statistics_of"])),
        "\nverified: resolved by an integrator that controls its error (adaptive, dop853),\n"
        "err_estimate (where estimated) within track.accuracy. A cell's statistics below\n"
        "are over its verified trials, or over its unverified ones (rk4, or estimates too\n"
        "large) if it has none: such cells are marked * and never averaged with others.",
        "\n### Failures and singular hits [% of trials, 95 % interval]\n",
        table(["cell", "diverged", "unresolved", "error", "singular hit"],
              shares([*FAILURES, "singular"])),
        "\ndiverged, unresolved, error: share of the cell's trials. singular hit: share of\n"
        "its simulated trials (all but error) with a sample of margin below\n"
        "track.singular_threshold. Intervals: Wilson score, 95 %.",
    ]
    for name in ("theta", "y"):
        cols = [f"err_{name}_{kind}_{stat}" for kind in ("rms", "final")
                for stat in ("median", "p95", "max")]
        parts += [
            f"\n### Tracking error of {name} [rad] (resolved trials: ok, singular)\n",
            table(["cell", "rms med", "rms p95", "rms max", "final med", "final p95",
                   "final max"], marked(rows(cols)), 3),
        ]
    parts += [
        "\n### Singularity, momentum and integration (resolved trials)\n",
        table(["cell", "margin med", "peak rate max", "drift max", "plan res max",
               "err est max"],
              rows(["min_margin_median", "peak_rate_max", "momentum_drift_max",
                    "plan_momentum_residual_max", "err_estimate_max"]), 3),
        "\nmargin med: median of min_margin [rad/s]; peak rate [rad/s]; drift and plan\n"
        "res(idual) of H [kg m^2/s]; err est: the adaptive integrator's estimate of its\n"
        "global error in theta at the end [rad] (- for rk4, dop853 and\n"
        "track.error_estimate = \"none\").",
    ]
    if "reference_checked" in summary and (summary["reference_checked"] > 0).any():
        parts += [
            "\n### Checked against the reference (sweep.verify)\n",
            table(["cell", "checked", "diff med", "diff max", "other status"],
                  rows(["reference_checked", "reference_difference_median",
                        "reference_difference_max", "reference_status_mismatches"]), 3),
            "\nchecked: trials re-run with DOP853 at rtol 1e-10; diff: max over the samples\n"
            "of the norm of the angles' difference [rad]; other status: checked trials whose\n"
            "reference ended with another status.",
        ]
    return "\n".join(parts)


def cell_text(value: Any) -> object:
    """A summary value for a table or a sentence: a list (or array) of numbers as '[a, b]',
    anything else as it is."""
    if isinstance(value, list | tuple | np.ndarray):
        return "[" + ", ".join(fmt(float(v)) for v in value) + "]"
    return value
