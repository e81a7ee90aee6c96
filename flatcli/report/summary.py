"""A sweep's per-cell statistics (summary.parquet) and their Markdown tables (summary.md)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from flatcli.core.metrics import STATUS_NAMES
from flatcli.report.tables import table

Array = NDArray[np.float64]

#: Trials whose errors enter the tracking-error statistics: those that ran to the end
#: (statuses of ``flatcli.core.metrics.STATUS_NAMES``).
COMPLETED = ("ok", "singular")
ERROR_METRICS = ("err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final")


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
