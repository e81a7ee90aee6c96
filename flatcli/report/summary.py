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
import re
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core.loop.metrics import METRIC_NAMES, OUTCOME_NAMES, RESOLVED, STATUS_NAMES
from flatcli.core.loop.outcome import lost_as_infinite
from flatcli.report.tables import fmt, table

if TYPE_CHECKING:  # the statistics are numpy's: a sweep writes them without pandas or scipy
    import pandas as pd
    import pyarrow as pa

Array = NDArray[np.float64]

#: Trials whose numbers enter the statistics: those resolved to the end (``RESOLVED``).
COMPLETED = RESOLVED
ERROR_METRICS = ("err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final")
#: The columns of trials.parquet that ``summarize_trials`` reads, and no others (those after
#: the metrics may be missing: a directory written before flatcli recorded them).
SUMMARY_INPUTS: tuple[str, ...] = (
    "cell", "status", "singular_hits", *ERROR_METRICS, "min_margin", "momentum_drift",
    "plan_momentum_residual", "peak_rate", "err_estimate", "verified", "reference_difference",
    "reference_status", "ee_error_bound", "outcome", "ee_error_final", "clipped_time")
assert set(SUMMARY_INPUTS) <= {"cell", "status", "verified", "reference_difference",
                               "reference_status", "ee_error_bound", "outcome",
                               "ee_error_final", *METRIC_NAMES}
#: The errors whose median over all of a cell's trials is given, lost ones counted as
#: infinitely wrong (``outcome.lost_as_infinite``): ``{name}_median_all``.
ALL_TRIALS_MEDIANS = ("err_theta_final", "err_y_final", "ee_error_final")
#: Statuses of trials that did not run to the end, reported as fractions of a cell's trials.
FAILURES = ("diverged", "unresolved", "error")


#: Phi^-1(0.975) = sqrt(2) erfinv(0.95): the z of a 95 % interval (to 16 digits; e.g.
#: scipy.stats.norm.ppf(0.975), which tests/test_report_summary.py compares).
Z95 = 1.959963984540054


def wilson_interval(successes: Any, trials: Any, confidence: float = 0.95
                    ) -> tuple[Array, Array]:
    """Wilson score interval of a binomial proportion (95 % by default): the closed form
    scipy's ``scipy.stats.binomtest(k, n).proportion_ci(confidence, method="wilson")``
    computes (scipy.stats itself takes 0.6 s to import on this machine, 1.5-3 s loaded: a
    2,000-trial sweep ran at half its rate with it; tests/test_report_summary.py and
    tests/test_outcome.py compare every interval with binomtest's).

    With p = k / n and z = Phi^-1((1 + confidence) / 2): (p + z^2 / 2n -+ z sqrt(p (1 - p) /
    n + z^2 / 4n^2)) / (1 + z^2 / n) (Wilson 1927; Brown, Cai, DasGupta, Statist. Sci. 16,
    2001). Unlike p -+ z sqrt(p (1 - p) / n) it stays inside [0, 1] and is
    not empty at k = 0 or k = n, which is where a sweep's failure counts usually are.

    Parameters
    ----------
    successes : k, counts (array-like of ints)
    trials : n, same shape (n = 0 gives nan bounds)
    confidence : in (0, 1); other than 0.95 its z comes from scipy (loaded then only)

    Returns
    -------
    low, high : arrays of k's shape
    """
    k, n = np.broadcast_arrays(np.asarray(successes, dtype=float),
                               np.asarray(trials, dtype=float))
    z = Z95 if confidence == 0.95 else _normal_quantile((1.0 + confidence) / 2.0)
    with np.errstate(invalid="ignore", divide="ignore"):  # n = 0: nan, set below
        p = k / n
        # in the arithmetic of Newcombe (Statist. Med. 17, 1998), as scipy writes it
        denominator = 2.0 * (n + z * z)
        centre = (2.0 * n * p + z * z) / denominator
        delta = z / denominator * np.sqrt(4.0 * n * p * (1.0 - p) + z * z)
        low = np.where(k == 0, 0.0, centre - delta)
        high = np.where(k == n, 1.0, centre + delta)
    low = np.where(n > 0, low, np.nan)
    high = np.where(n > 0, high, np.nan)
    return np.asarray(low, dtype=float), np.asarray(high, dtype=float)


def _normal_quantile(q: float) -> float:
    from scipy.special import ndtri

    return float(ndtri(q))


#: Columns of trials as ``summary_rows`` reads them: name -> a numpy array per trial (cell:
#: ints; status and reference_status: objects, None for null; verified: booleans, False for
#: null; the rest floats, nan for null).
Columns = Mapping[str, NDArray[Any]]
#: The columns ``summary_rows`` reads as text and as flags.
_TEXT = ("status", "reference_status", "outcome")
_FLAGS = ("verified",)


def frame_columns(frame: pd.DataFrame) -> dict[str, NDArray[Any]]:
    """A DataFrame's columns as ``summary_rows`` reads them (``Columns``)."""
    out: dict[str, NDArray[Any]] = {}
    for name in frame.columns:
        column = frame[name]
        if name in _TEXT:
            out[name] = np.array([None if _null(v) else str(v) for v in column], dtype=object)
        elif name in _FLAGS:
            out[name] = np.array([False if _null(v) else bool(v) for v in column], dtype=bool)
        elif name == "cell":
            out[name] = column.to_numpy(dtype=np.int64)
        else:
            out[name] = column.to_numpy(dtype=np.float64, na_value=np.nan)
    return out


class ColumnsOf:
    """The columns ``summary_rows`` reads (``Columns``), gathered from Arrow tables in turn (a
    sweep's chunks, as trials.parquet receives them): each table's columns of ``names``
    converted as it comes (the rest never), a text column's words held once each (one object
    per distinct word, not one string per row: a sweep of 10^6 trials holds numpy's arrays
    only)."""

    def __init__(self, names: Sequence[str]) -> None:
        self._parts: dict[str, list[NDArray[Any]]] = {name: [] for name in names}
        self._words: dict[str | None, str | None] = {}

    def add(self, table: pa.Table) -> None:
        """Take the columns of one more table (the rows after those taken before)."""
        from flatcli.arrow import floats, to_numpy

        present = set(table.schema.names)
        for name, parts in self._parts.items():
            if name not in present:  # older files lack some
                continue
            column = table.column(name)
            if name in _TEXT:
                words = self._words
                parts.append(np.array([words.setdefault(v, v) for v in column.to_pylist()],
                                      dtype=object))
            elif name in _FLAGS:
                parts.append(np.asarray(to_numpy(column), dtype=bool))  # null: False
            elif name == "cell":
                parts.append(np.asarray(to_numpy(column), dtype=np.int64))
            else:
                parts.append(floats(column))

    def columns(self) -> dict[str, NDArray[Any]]:
        """The columns of every table taken, in order; the parts are let go one column at a
        time (the peak is the columns and one column's parts)."""
        out: dict[str, NDArray[Any]] = {}
        for name in list(self._parts):
            parts = self._parts.pop(name)
            if parts:
                out[name] = parts[0] if len(parts) == 1 else np.concatenate(parts)
        return out


def _null(value: Any) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value)) or \
        type(value).__name__ in ("NAType", "NaTType")


def summarize_trials(frame: pd.DataFrame, cells: Mapping[int, Mapping[str, Any]],
                     reach_tolerance: float | None = None) -> pd.DataFrame:
    """Per-cell statistics of a sweep's trials as a DataFrame (``summary_rows`` of the
    frame's columns)."""
    import pandas as pd

    return pd.DataFrame(summary_rows(frame_columns(frame), cells, reach_tolerance))


def summary_rows(columns: Columns, cells: Mapping[int, Mapping[str, Any]],
                 reach_tolerance: float | None = None) -> list[dict[str, Any]]:
    """Per-cell statistics of a sweep's trials (definitions in docs/outputs.md, *Sweep output*).

    Parameters
    ----------
    columns : one value per trial in each of cell, status, singular_hits and the metrics
        (``Columns``; a metric that does not apply is nan: it never enters a statistic)
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
    A task sweep (an ``ee_error_bound`` column) adds that bound's median, p95 and max over the
    counted trials and, given ``reach_tolerance`` [m] (``summary.reach_tolerance``),
    ``reached_fraction``: the cell's trials resolved to the end with a bound of at most it
    (every other trial counts as not reached), with its Wilson interval. Statistics over no
    trials are nan (null in summary.parquet).
    """
    rows = []
    all_status = np.asarray(columns["status"], dtype=object)
    all_cells = np.asarray(columns["cell"])
    count = len(all_status)
    verified = columns.get("verified", np.zeros(count, dtype=bool))
    outcomes = (np.asarray(columns["outcome"], dtype=object) if "outcome" in columns
                else None)
    for cell, values in cells.items():
        in_cell = all_cells == cell
        status = all_status[in_cell]
        resolved = in_cell & np.isin(all_status, RESOLVED)
        sure = resolved & verified
        kind = "verified" if sure.any() else "unverified" if resolved.any() else None
        done = sure if sure.any() else resolved
        simulated = in_cell & (all_status != "error")

        def present(name: str, where: NDArray[np.bool_]) -> Array:
            values_: Array = np.asarray(columns[name], dtype=np.float64)[where]
            return values_[~np.isnan(values_)]

        row: dict[str, Any] = {"cell": cell, **values, "trials": int(in_cell.sum())}
        if outcomes is not None:  # the headline: what the robot did (older files lack it)
            _outcomes(row, columns, outcomes, in_cell)
        for name in STATUS_NAMES:
            row[name] = int((status == name).sum())
        for metric in ERROR_METRICS:
            values_ = present(metric, done)
            row[f"{metric}_median"] = _stat(np.median, values_)
            row[f"{metric}_p95"] = _stat(lambda v: np.percentile(v, 95), values_)
            row[f"{metric}_max"] = _stat(np.max, values_)
        hits = present("singular_hits", simulated)
        row["singular_fraction"] = float(np.mean(hits > 0)) if len(hits) else math.nan
        row["min_margin_median"] = _stat(np.median, present("min_margin", done))
        drift = present("momentum_drift", done)
        row["momentum_drift_median"] = _stat(np.median, drift)
        row["momentum_drift_max"] = _stat(np.max, drift)
        row["plan_momentum_residual_max"] = _stat(
            np.max, present("plan_momentum_residual", simulated))
        # added after the columns above, which keep their names and places
        row["resolved"] = int(resolved.sum())
        row["simulated"] = int(simulated.sum())
        _fraction(row, "singular", int(np.sum(hits > 0)), len(hits))
        for name in FAILURES:
            _fraction(row, name, row[name], row["trials"])
        for metric in ("peak_rate", "err_estimate"):
            values_ = present(metric, done)
            row[f"{metric}_median"] = _stat(np.median, values_)
            row[f"{metric}_max"] = _stat(np.max, values_)
        row["verified_trials"] = int(sure.sum())
        row["unverified_trials"] = int(resolved.sum()) - row["verified_trials"]
        row["statistics_of"] = kind
        _reference(row, columns, in_cell, present)
        if "ee_error_bound" in columns:
            bound = present("ee_error_bound", done)
            row["ee_error_bound_median"] = _stat(np.median, bound)
            row["ee_error_bound_p95"] = _stat(lambda v: np.percentile(v, 95), bound)
            row["ee_error_bound_max"] = _stat(np.max, bound)
            if reach_tolerance is not None:
                within = np.asarray(columns["ee_error_bound"], dtype=np.float64)[resolved]
                _fraction(row, "ee_error_bound_within", int(np.sum(within <= reach_tolerance)),
                          row["trials"])
        if "clipped_time" in columns:
            clipped = present("clipped_time", done)
            row["clipped_time_median"] = _stat(np.median, clipped)
            row["clipped_time_max"] = _stat(np.max, clipped)
        rows.append(row)
    return rows


def _outcomes(row: dict[str, Any], columns: Columns, outcomes: NDArray[np.object_],
              in_cell: NDArray[np.bool_]) -> None:
    """The cell's outcomes (``core.outcome``) into ``row``: counts of each, the fraction
    reached with its 95 % Wilson interval and the others' fractions with theirs,
    all of the cell's trials; then the median of each of ``ALL_TRIALS_MEDIANS`` over all its
    trials, one that did not reach T (lost) counted as infinitely wrong
    (``outcome.lost_as_infinite``: inf where more than half did not)."""
    outcome = outcomes[in_cell]
    total = int(in_cell.sum())
    for name in OUTCOME_NAMES:
        row[name] = int(np.sum(outcome == name))
    for name in OUTCOME_NAMES:
        _fraction(row, name, row[name], total)
    for metric in ALL_TRIALS_MEDIANS:
        if metric in columns:
            values = lost_as_infinite(np.asarray(columns[metric], dtype=np.float64)[in_cell])
            row[f"{metric}_median_all"] = _stat(np.median, values)


def _reference(row: dict[str, Any], columns: Columns, in_cell: NDArray[np.bool_],
               present: Callable[[str, NDArray[np.bool_]], Array]) -> None:
    """The cell's trials checked against the reference integrator (``sweep.verify``): how
    many, how far the ones that both integrators resolved to the end were from it (median,
    max: a trial stopped at a crossing has no accuracy to compare) and how many ended with
    another status."""
    status = np.asarray(columns["status"], dtype=object)
    if "reference_status" in columns:
        reference = np.asarray(columns["reference_status"], dtype=object)
        checked = in_cell & np.array([v is not None for v in reference], dtype=bool)
    else:
        reference = np.full(len(in_cell), None, dtype=object)
        checked = np.zeros(len(in_cell), dtype=bool)
    row["reference_checked"] = int(checked.sum())
    both = checked & np.isin(status, RESOLVED) & np.isin(reference, RESOLVED)
    gap = present("reference_difference", both) if both.any() else np.zeros(0)
    row["reference_difference_median"] = _stat(np.median, gap)
    row["reference_difference_max"] = _stat(np.max, gap)
    row["reference_status_mismatches"] = int(np.sum(reference[checked] != status[checked]))


def summary_table(rows: Sequence[Mapping[str, Any]], units: Mapping[str, str]) -> pa.Table:
    """summary.parquet's table of ``summary_rows``, typed as a DataFrame of them is written
    (counts int64, statistics float64 with nan as null, text large_string), with units
    (``storage.with_units``)."""
    import pyarrow as pa

    from flatcli.storage import with_units

    names = list(dict.fromkeys(name for row in rows for name in row))
    arrays = [_arrow_column([row.get(name) for row in rows]) for name in names]
    return with_units(pa.table(arrays, names=names), units)


def _arrow_column(values: list[Any]) -> pa.Array:
    """One summary column as Arrow, typed as pandas would type it (built through
    ``flatcli.arrow``, which loads no pandas, where it can be)."""
    import pyarrow as pa

    from flatcli.arrow import flags, number_lists, numbers, texts

    def number(v: Any) -> bool:
        return isinstance(v, int | float | np.integer | np.floating) and not isinstance(
            v, bool | np.bool_)

    if values and all(isinstance(v, bool | np.bool_) for v in values):
        return flags(values)
    if values and all(isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_)
                      for v in values):
        return numbers(values, pa.int64())
    if values and all(number(v) for v in values):
        return numbers(values)  # nan: null
    if all(v is None for v in values):
        return pa.nulls(len(values))
    if all(v is None or isinstance(v, str) for v in values):
        return texts(values, large=True)
    if all(v is None or (isinstance(v, list | tuple | np.ndarray) and all(number(x) for x in v))
           for v in values):
        return number_lists(values)
    return pa.array(values)  # mixed values: as pyarrow infers them


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
    def bound(x: float) -> str:  # two digits, but 100 as 100 (not 1e+02)
        return fmt(100 * x, 3 if 100 * x >= 99.5 else 2)

    return f"{fmt(100 * value, 3)} ({bound(low)}-{bound(high)})"


def summary_markdown(summary: pd.DataFrame | Sequence[Mapping[str, Any]],
                     grid_keys: Sequence[str]) -> str:
    """The sweep's summary as Markdown tables, each readable on an 80-column terminal.

    ``summary``: its rows (``summary_rows``) or a DataFrame of them; ``grid_keys``: the grid
    columns to list in the *Cells* table."""
    records: list[Mapping[str, Any]] = (
        [{str(k): v for k, v in r.items()} for r in summary.to_dict("records")]
        if hasattr(summary, "to_dict") else list(summary))

    def rows(cols: Sequence[str]) -> list[list[object]]:
        return [[int(r["cell"]), *(cell_text(r[c]) for c in cols)] for r in records]

    def marked(lines: list[list[object]]) -> list[list[object]]:
        """Rows whose statistics are over unverified trials: the cell marked *."""
        if not records or "statistics_of" not in records[0]:
            return lines
        kinds = [r["statistics_of"] for r in records]
        return [[f"{line[0]}*" if kind == "unverified" else line[0], *line[1:]]
                for line, kind in zip(lines, kinds, strict=True)]

    def shares(names: Sequence[str]) -> list[list[object]]:
        return [[int(r["cell"]), *(with_interval(r[f"{n}_fraction"], r[f"{n}_fraction_low"],
                                                 r[f"{n}_fraction_high"]) for n in names)]
                for r in records]

    parts = []
    if grid_keys:
        parts += ["### Cells\n", table(["cell", *(short_key(k) for k in grid_keys)],
                                       rows(list(grid_keys))), ""]
    if records and "reached_fraction" in records[0]:
        parts += [*outcome_tables(records, rows, shares), ""]
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
    if any(r.get("reference_checked", 0) > 0 for r in records):
        parts += [
            "\n### Checked against the reference (sweep.verify)\n",
            table(["cell", "checked", "diff med", "diff max", "other status"],
                  rows(["reference_checked", "reference_difference_median",
                        "reference_difference_max", "reference_status_mismatches"]), 3),
            "\nchecked: trials re-run with DOP853 at rtol 1e-10; diff: max over the samples\n"
            "of the norm of the angles' difference [rad]; other status: checked trials whose\n"
            "reference ended with another status.",
        ]
    if records and "ee_error_bound_within_fraction" in records[0]:
        parts += [
            "\n### The task's target: the bound (resolved trials)\n",
            table(["cell", "within [%, 95 % interval]", "bound med", "bound p95",
                   "bound max"],
                  [[line[0], share[1], *line[1:]] for line, share in zip(
                      marked(rows(["ee_error_bound_median", "ee_error_bound_p95",
                                   "ee_error_bound_max"])),
                      shares(["ee_error_bound_within"]), strict=True)],
                  3),
            "\nbound: ee_error_bound, an upper bound on the end effector's final distance from\n"
            "the trial's target [m] from err_theta_final and the plant's links. within: share\n"
            "of the cell's trials resolved to the end with a bound within\n"
            "summary.reach_tolerance (the measured distance, ee_error_final, decides reached).",
        ]
    return "\n".join(parts)


def outcome_tables(records: Sequence[Mapping[str, Any]],
                   rows: Callable[[Sequence[str]], list[list[object]]],
                   shares: Callable[[Sequence[str]], list[list[object]]]) -> list[str]:
    """summary.md's first table: what the robot did, per cell (``_outcomes``)."""
    medians = [m for m in ALL_TRIALS_MEDIANS if f"{m}_median_all" in records[0]]
    heads = {"err_theta_final": "th final med", "err_y_final": "y final med",
             "ee_error_final": "ee final med"}
    lines = [[*share, *line[1:]] for share, line in zip(
        shares(list(OUTCOME_NAMES)), rows([f"{m}_median_all" for m in medians]), strict=True)]
    return [
        "### Outcomes [% of trials, 95 % interval]\n",
        table(["cell", *OUTCOME_NAMES, *(heads[m] for m in medians)], lines, 3),
        "\nreached: resolved to the end, every angle within track.goal_tolerance of the\n"
        "plan's goal at T (and a task's end effector within task.goal_tolerance of its\n"
        "target); collided: entered, or not shown clear of, a task's obstacle; missed:\n"
        "resolved, not within tolerance; lost: diverged, unresolved or error. Shares of\n"
        "all the cell's trials, Wilson score intervals (95 %). final med: median over\n"
        "ALL the cell's trials of the final error (th, y [rad]; ee [m]), a trial that did\n"
        "not reach T counted as infinitely wrong (inf: more than half did not).",
    ]


#: The most cells a headline lists (one screen); beyond, those with the most trials not ok.
HEADLINE_CELLS = 20
#: The most error reasons a headline quotes.
HEADLINE_REASONS = 3


def grid_display(records: Sequence[Mapping[str, Any]], grid_keys: Sequence[str],
                 grid: Mapping[str, Any] | None = None) -> list[tuple[str, list[str]]]:
    """The grid columns a headline shows, as (heading, text per cell): keys whose value
    varies across the cells, a list-valued key by the components that vary (``key[i]``),
    text cut to 16 characters; the keys of a labelled group (``grid``: the spec's
    ``sweep.grid``) by its label only."""
    labelled = {k for values in (grid or {}).values()
                if isinstance(values, list) and values and all(
                    isinstance(v, Mapping) and "label" in v for v in values)
                for table_ in values for k in table_ if k != "label"}
    out: list[tuple[str, list[str]]] = []
    for key in grid_keys:
        if key in labelled and key not in (grid or {}):
            continue
        values = [r.get(key) for r in records]
        if len({repr(v) for v in values}) <= 1:
            continue
        lists = [list(v) for v in values if isinstance(v, list | tuple | np.ndarray)]
        if len(lists) == len(values) and len({len(v) for v in lists}) == 1:
            stacked = lists
            for i in range(len(stacked[0])):
                column = [row[i] for row in stacked]
                if len({repr(v) for v in column}) > 1:
                    out.append((f"{short_key(key)}[{i}]", [str(fmt(float(v))) for v in column]))
            continue
        texts = [str(cell_text(v)) if not isinstance(v, float) else str(fmt(v))
                 for v in values]
        out.append((short_key(key), [t if len(t) <= 16 else t[:15] + "~" for t in texts]))
    return out


def outcome_columns(records: Sequence[Mapping[str, Any]]) -> list[str]:
    """The per-cell outcome counts a headline shows (after the statuses): the summary's
    count of each of ``OUTCOME_NAMES`` (``_outcomes``) but lost (the statuses beside them
    count it: diverged, unresolved, error), ``reached`` and ``missed`` always, ``collided``
    where any cell has one; none for a summary written before trials had outcomes."""
    if not records or not all(name in records[0] for name in OUTCOME_NAMES):
        return []
    return [n for n in OUTCOME_NAMES if n in ("reached", "missed")
            or (n == "collided" and any(int(r[n]) for r in records))]


def outcome_totals(records: Sequence[Mapping[str, Any]]) -> str:
    """'outcomes: reached 300 of 360 trials (83.3 %, 95 % interval 79.1-86.8 %), missed 27,
    lost 33' over all the cells' trials (the interval: Wilson score, ``wilson_interval``); "" for a
    summary without outcomes."""
    if not records or not all(name in records[0] for name in OUTCOME_NAMES):
        return ""
    counts = {n: sum(int(r[n]) for r in records) for n in OUTCOME_NAMES}
    trials = sum(int(r["trials"]) for r in records)
    reached = counts["reached"]
    text = f"outcomes: reached {reached} of {trials} trials"
    if trials:
        low, high = wilson_interval(reached, trials)
        share, interval = with_interval(reached / trials, float(low), float(high)).split(" (")
        text += f" ({share} %, 95 % interval {interval.rstrip(')')} %)"
    return ", ".join([text, *(f"{n} {counts[n]}" for n in OUTCOME_NAMES[1:] if counts[n])])


def grid_columns_of(records: Sequence[Mapping[str, Any]]) -> list[str]:
    """The grid columns of summary rows: those between ``cell`` and ``trials``."""
    if not records:
        return []
    names = list(records[0])
    return names[names.index("cell") + 1: names.index("trials")]


#: Numbers in an error reason (a trial's own target, times, sizes): reasons that differ only
#: in them are one kind of error in a headline.
_NUMBER = re.compile(r"[-+]?\d+(\.\d*)?([eE][-+]?\d+)?")


def error_reasons(paths: Sequence[Any]) -> dict[str, int]:
    """reason -> trials, of the error trials in the Parquet files ``paths`` (trials.parquet,
    or a partial sweep's chunk files), reasons that differ only in their numbers counted as
    one (shown as the first of them); nothing is read but the two columns."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    first: dict[str, str] = {}
    counts: dict[str, int] = {}
    for path in paths:
        table = pq.read_table(path, columns=["status", "reason"])
        errors = table.filter(pc.equal(table.column("status"), "error"))
        for reason in errors.column("reason").to_pylist():
            text = str(reason or "").strip() or "(no reason recorded)"
            kind = _NUMBER.sub("#", text)
            first.setdefault(kind, text)
            counts[kind] = counts.get(kind, 0) + 1
    return {first[kind]: count for kind, count in counts.items()}


def headline(records: Sequence[Mapping[str, Any]], grid_keys: Sequence[str], title: str,
             where: str, reasons: Mapping[str, int] | None = None,
             limit: int = HEADLINE_CELLS, grid: Mapping[str, Any] | None = None) -> str:
    """A sweep's summary in one screen: ``title``, the outcomes of all its trials
    (``outcome_totals``), one row per cell (its varying grid values, its trials by status
    (ok, and the others any cell has), by outcome (``outcome_columns``), the median final
    error of y: over all the cell's trials, a trial that did not reach T as inf, where the
    summary has outcomes (a line under the table says so), else over its resolved trials
    (its heading says so)), up to
    ``limit`` cells (beyond, those with the most trials not ok, in cell order), the most
    frequent error reasons (``reasons``: reason -> trials), and where the full tables are
    (``where``: the sweep's directory)."""
    records = list(records)
    shown = records
    if len(records) > limit:
        worst = sorted(records, key=lambda r: (-(int(r["trials"]) - int(r["ok"])),
                                               int(r["cell"])))[:limit]
        keep = {int(r["cell"]) for r in worst}
        shown = [r for r in records if int(r["cell"]) in keep]
    columns = grid_display(shown, grid_keys, grid)
    outcomes = outcome_columns(records)
    statuses = [n for n in STATUS_NAMES if n == "ok" or any(int(r[n]) for r in records)]
    over_all = bool(outcomes) and "err_y_final_median_all" in records[0]
    median = "err_y_final_median_all" if over_all else "err_y_final_median"
    heads = ["cell", *(h for h, _ in columns), *statuses, *outcomes,
             "err_y_final med [rad]" if over_all else "err_y_final med resolved [rad]"]
    rows = []
    for i, r in enumerate(shown):
        rows.append([int(r["cell"]), *(texts[i] for _, texts in columns),
                     *(int(r[n]) for n in statuses), *(int(r[o]) for o in outcomes),
                     r.get(median, math.nan)])
    totals = outcome_totals(records)
    lines = [title, *([totals] if totals else []), table(heads, rows, 3)]
    if over_all:
        lines.append("med: over all the cell's trials, a lost one (diverged, unresolved, error) "
                     "as inf")
    if len(shown) < len(records):
        lines.append(f"({len(shown)} of {len(records)} cells shown: those with the most "
                     "trials not ok)")
    for reason, count in sorted((reasons or {}).items(), key=lambda kv: -kv[1])[
            :HEADLINE_REASONS]:
        lines.append(f"error ({count} trial{'s' if count != 1 else ''}"
                     f"{' like this' if count != 1 else ''}): {reason}")
    more = len(reasons or {}) - HEADLINE_REASONS
    if more > 0:
        lines.append(f"({more} more error reason{'s' if more != 1 else ''} in "
                     "trials.parquet's reason column)")
    lines += [f"full tables: {where}/summary.md (flatcli summarize {where} --full)",
              f"every trial: {where}/trials.parquet"]
    return "\n".join(lines)


def totals_text(records: Sequence[Mapping[str, Any]]) -> str:
    """'18 cells, 360 trials: ok 327, singular 1, diverged 32, unresolved 0, error 0'."""
    counts = {n: sum(int(r[n]) for r in records) for n in STATUS_NAMES}
    trials = sum(int(r["trials"]) for r in records)
    cells = len(records)
    return (f"{cells} cell{'s' if cells != 1 else ''}, {trials} trials: "
            + ", ".join(f"{n} {counts[n]}" for n in STATUS_NAMES))


def cell_text(value: Any) -> object:
    """A summary value for a table or a sentence: a list (or array) of numbers as '[a, b]',
    anything else as it is."""
    if isinstance(value, list | tuple | np.ndarray):
        return "[" + ", ".join(fmt(float(v)) for v in value) + "]"
    return value
