"""Figures of a finished sweep (flatcli/report/sweep_figures.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flatcli.core.metrics import METRIC_NAMES
from flatcli.core.model import FlatcliError
from flatcli.report.figures import new_figure
from flatcli.report.summary import summarize_trials
from flatcli.report.sweep_figures import (
    SweepData,
    grid_axis,
    log_boxes,
    plot_errors,
    plot_sweep,
)
from flatcli.storage import write_parquet

#: A sweep's spec as its provenance holds it (JSON: keys sorted, inf as "inf").
TREE = {"sweep": {"grid": {
    "gains": [{"label": "printed", "track.kp": [10, 13]}, {"label": "swapped",
                                                           "track.kp": [100, 110]}],
    "plant.com": [[0.1, 0.1, 0.0], [0.1, 0.1, 0.005]],
    "sweep.perturb.initial.std": [0.01, 0.2]},
    "perturb": {"initial": {"dist": "normal", "std": 0.05}}},
    "track": {"singular_threshold": 0.01, "rate_limit": "inf", "divergence_bound": 1e4}}


def _cells() -> dict[int, dict[str, object]]:
    cells = {}
    for i, (std, gains, d2) in enumerate(
            (s, g, d) for s in (0.01, 0.2) for g in ("printed", "swapped") for d in (0.0, 0.005)):
        cells[i] = {"sweep.perturb.initial.std": std, "gains": gains,
                    "track.kp": [10.0, 13.0] if gains == "printed" else [100.0, 110.0],
                    "plant.com": [0.1, 0.1, d2]}
    return cells


def _trials(cells: dict[int, dict[str, object]], n: int = 40) -> pd.DataFrame:
    rng = np.random.default_rng(1)
    rows = []
    for cell, values in cells.items():
        for i in range(n):
            bad = values.get("gains") == "swapped" and i < 10 * (cell // 4 + 1)
            status = "diverged" if bad else ("error" if i == n - 1 else "ok")
            row = {"cell": cell, "status": status, "singular_hits": int(i % 7 == 0)}
            row.update({m: float(rng.lognormal(-3, 1)) for m in METRIC_NAMES
                        if m != "singular_hits"})
            rows.append(row)
    return pd.DataFrame(rows)


def _sweep_dir(tmp_path: Path) -> Path:
    cells = _cells()
    trials = _trials(cells)
    write_parquet(tmp_path / "trials.parquet", trials, {"spec": TREE})
    write_parquet(tmp_path / "summary.parquet", summarize_trials(trials, cells), {"spec": TREE})
    return tmp_path


def test_cells_are_named_by_their_grid_values_outer_key_first() -> None:
    summary = summarize_trials(_trials(_cells(), 4), _cells())
    rows = dict(grid_axis(summary, TREE))
    # columns in grid order; a labelled group by its labels (not its keys); a list key by
    # the component that varies, with units
    assert list(rows) == ["initial.std [rad]", "gains", "plant.com[2] [m]"]
    assert rows["initial.std [rad]"] == ["0.01"] * 4 + ["0.2"] * 4
    assert rows["gains"][:4] == ["printed", "printed", "swapped", "swapped"]
    assert rows["plant.com[2] [m]"][:2] == ["0", "0.005"]


def test_plot_sweep_writes_its_four_figures(tmp_path: Path) -> None:
    paths = plot_sweep(_sweep_dir(tmp_path))
    assert [p.name for p in paths] == ["sweep_errors.png", "sweep_singular.png",
                                       "sweep_margin.png", "sweep_momentum.png"]
    for path in paths:
        assert path.read_bytes()[:4] == b"\x89PNG"


def test_a_cell_with_nothing_resolved_is_drawn_and_said(tmp_path: Path) -> None:
    cells = {0: {"track.sensor_noise": 0.0}, 1: {"track.sensor_noise": 0.1}}
    trials = _trials(cells, 10)
    trials.loc[trials["cell"] == 1, "status"] = "error"
    tree = {"sweep": {"grid": {"track.sensor_noise": [0.0, 0.1]}}}
    write_parquet(tmp_path / "trials.parquet", trials, {"spec": tree})
    write_parquet(tmp_path / "summary.parquet", summarize_trials(trials, cells), {"spec": tree})
    assert plot_errors(SweepData.load(tmp_path), tmp_path / "e.png").exists()
    ax = new_figure(4, 3).subplots()
    log_boxes(ax, [np.array([1e-3, 1e-2, 0.0]), np.array([])])
    texts = [t.get_text() for t in ax.texts]
    assert "none\nresolved" in texts  # the empty cell
    assert "1 values below 1e-16 drawn at it" in texts  # the 0 on a log axis


def test_a_summary_without_the_failure_shares_is_refused_in_one_line(tmp_path: Path) -> None:
    directory = _sweep_dir(tmp_path)
    summary = pd.read_parquet(directory / "summary.parquet")
    write_parquet(directory / "summary.parquet", summary.drop(columns=["resolved"]), {})
    with pytest.raises(FlatcliError, match="written by an older flatcli"):
        SweepData.load(directory)
