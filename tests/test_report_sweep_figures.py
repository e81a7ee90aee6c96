"""Figures of a finished sweep (flatcli/report/sweep_figures.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flatcli.core.errors import FlatcliError
from flatcli.core.loop.metrics import METRIC_NAMES
from flatcli.report.figures import FigureFile, new_figure
from flatcli.report.summary import summarize_trials
from flatcli.report.sweep_figures import (
    OutcomeAxis,
    SweepData,
    errors_figure,
    grid_axis,
    log_boxes,
    outcomes_figure,
    plot_sweep,
    sweep_figure,
    sweep_figures,
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


def test_plot_sweep_writes_its_four_figures_in_the_format_asked(tmp_path: Path) -> None:
    paths = plot_sweep(_sweep_dir(tmp_path), FigureFile("png", 50))
    assert [p.name for p in paths] == ["sweep_errors.png", "sweep_singular.png",
                                       "sweep_margin.png", "sweep_momentum.png"]
    for path in paths:
        assert path.read_bytes()[:4] == b"\x89PNG"
    width, _ = _png_size(paths[0])
    assert width == pytest.approx(50 * SweepData.load(tmp_path).width, abs=2)  # inches x dpi


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def _panels(fig: object) -> dict[str, object]:
    return {ax.get_title(): ax for ax in fig.axes if ax.get_visible()}  # type: ignore[attr-defined]


def test_outcomes_against_a_chosen_grid_key_with_a_hue(tmp_path: Path) -> None:
    directory = _sweep_dir(tmp_path)
    sweep = SweepData.load(directory)
    fig = outcomes_figure(sweep, OutcomeAxis.choose(sweep, "plant.com", "gains"))
    panels = _panels(fig)
    diverged = panels["trials that diverged"]
    assert diverged.get_ylim()[0] == 0.0  # a share is never drawn below 0
    assert diverged.get_xlabel() == "plant.com[2] [m]"  # the component that varies, its unit
    # one line per gains label and initial.std value; data are the summary's shares
    lines = [c for c in diverged.containers]
    assert len(lines) == 4
    summary = sweep.summary
    for container in lines:
        label = container.get_label()
        gains = label.split(";")[0].removeprefix("gains = ")
        std = float(label.split("initial.std = ")[1])
        rows = summary[(summary["gains"] == gains) &
                       (summary["sweep.perturb.initial.std"] == std)].sort_values("cell")
        y = container.lines[0].get_ydata()
        np.testing.assert_allclose(sorted(y), sorted(rows["diverged_fraction"]))
    # colours by the hue: the two labels, two colours
    colours = {c.get_label().split(";")[0]: c.lines[0].get_color() for c in lines}
    assert len(set(colours.values())) == 2
    error = panels["resolved trials (ok, singular)"]
    assert error.get_yscale() == "log"
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "gains = printed; initial.std = 0.01" in legend
    assert all(h.get_visible() for h in fig.legends[0].legend_handles)


def test_the_default_x_is_the_perturbation_size_on_a_log_axis(tmp_path: Path) -> None:
    sweep = SweepData.load(_sweep_dir(tmp_path))
    axis = OutcomeAxis.choose(sweep, None, None)
    assert axis.key == "sweep.perturb.initial.std" and axis.scale == "log"
    fig = sweep_figure(tmp_path, "singular")
    singular = _panels(fig)["simulated trials with a singular hit"]
    assert singular.get_xscale() == "log" and singular.get_ylim()[0] == 0.0
    assert _panels(fig)["trials that diverged"].get_xlabel() == "initial.std [rad]"
    assert "outcomes against initial.std" in fig.get_suptitle()


def test_a_grid_with_zero_noise_gets_a_symlog_axis(tmp_path: Path) -> None:
    cells = {i: {"track.sensor_noise": v} for i, v in enumerate((0.0, 1e-4, 1e-3, 1e-2))}
    trials = _trials(cells, 12)
    tree = {"name": "noise", "sweep": {"grid": {"track.sensor_noise": [0.0, 1e-4, 1e-3,
                                                                       1e-2]}},
            "plant": {"model": "dynamic", "torque_limit": 50.0}}
    write_parquet(tmp_path / "trials.parquet", trials, {"spec": tree})
    write_parquet(tmp_path / "summary.parquet", summarize_trials(trials, cells), {"spec": tree})
    fig = sweep_figure(tmp_path, "singular", x="track.sensor_noise")
    ax = _panels(fig)["trials that diverged"]
    assert ax.get_xscale() == "symlog" and ax.get_ylim()[0] == 0.0
    assert ax.get_xlabel() == "track.sensor_noise [rad]"
    title = fig.get_suptitle()
    # the title names the plant, the noise (varied here) and the torque limit
    assert "sweep 'noise': dynamic plant, sensor noise per cell, torque limit 50 N m" in title


def test_x_and_hue_must_be_grid_keys(tmp_path: Path) -> None:
    directory = _sweep_dir(tmp_path)
    with pytest.raises(FlatcliError, match=r"--x: 'track.dt' is not a grid key of this sweep; "
                                           r"its grid keys: .*gains"):
        sweep_figures(directory, x="track.dt")
    with pytest.raises(FlatcliError, match=r"--hue: 'gain' is not a grid key.*did you mean "
                                           r"'gains'"):
        sweep_figures(directory, hue="gain")
    with pytest.raises(FlatcliError, match="is the --x key"):
        sweep_figures(directory, x="gains", hue="gains")


def test_a_text_key_on_x_is_drawn_as_categories(tmp_path: Path) -> None:
    fig = sweep_figure(_sweep_dir(tmp_path), "singular", x="gains")
    ax = _panels(fig)["trials that diverged"]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["printed", "swapped"]


def test_a_cell_with_nothing_resolved_is_drawn_and_said(tmp_path: Path) -> None:
    cells = {0: {"track.sensor_noise": 0.0}, 1: {"track.sensor_noise": 0.1}}
    trials = _trials(cells, 10)
    trials.loc[trials["cell"] == 1, "status"] = "error"
    tree = {"sweep": {"grid": {"track.sensor_noise": [0.0, 0.1]}}}
    write_parquet(tmp_path / "trials.parquet", trials, {"spec": tree})
    write_parquet(tmp_path / "summary.parquet", summarize_trials(trials, cells), {"spec": tree})
    fig = errors_figure(SweepData.load(tmp_path))
    share = fig.axes[-1]
    assert share.get_ylim()[0] == 0.0  # shares start at 0
    assert [ax.get_ylabel() for ax in fig.axes[:3]] == [
        r"rms error of $\theta$ [rad]", "rms error of $y$ [rad]", "final error of $y$ [rad]"]
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


@pytest.mark.parametrize("errors", [True, False])
def test_the_outcome_legend_lies_inside_the_page_beside_the_panels(
        tmp_path: Path, errors: bool) -> None:
    """sweep_singular's legend was cut off at both page edges (three columns of long entries
    centred under the panels): it now fills the empty panel (three panels) or sits under the
    panels in as many columns as fit (four). Referee: the legend's and the panels' extents
    as matplotlib's renderer places them, against the page."""
    cells = _cells()
    trials = _trials(cells)
    if not errors:
        trials.loc[trials["status"] == "error", "status"] = "ok"
    write_parquet(tmp_path / "trials.parquet", trials, {"spec": TREE})
    write_parquet(tmp_path / "summary.parquet", summarize_trials(trials, cells), {"spec": TREE})
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = sweep_figure(tmp_path, "singular", x="sweep.perturb.initial.std", hue="gains")
    canvas = FigureCanvasAgg(fig)  # the PNG's renderer (a PDF places the same layout)
    canvas.draw()
    renderer = canvas.get_renderer()
    page = fig.bbox
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend())]
    assert len(legends) == 1
    box = legends[0].get_window_extent(renderer)
    assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1
    panels = [ax for ax in fig.axes if ax.get_visible() and ax.axison]
    assert len(panels) == (4 if errors else 3)
    for ax in panels:
        assert not box.overlaps(ax.get_window_extent(renderer))
    assert len(legends[0].get_texts()) == 4  # (gains) x (the other grid keys that vary)


def test_a_sweep_with_error_trials_draws_their_share_not_the_final_error_twice(
        tmp_path: Path) -> None:
    """The panel of the final error and the share of error trials were both named "error":
    a sweep with error trials drew the final-error panel twice and no share of its errors.
    Referee: the share of error trials of each cell, counted from the trials."""
    fig = sweep_figure(_sweep_dir(tmp_path), "singular", x="sweep.perturb.initial.std")
    titles = [ax.get_title() for ax in fig.axes if ax.axison]
    assert titles.count("resolved trials (ok, singular)") == 1
    assert "trials that could not run" in titles
    ax = next(a for a in fig.axes if a.get_title() == "trials that could not run")
    trials = _trials(_cells())
    counted = trials.groupby("cell")["status"].apply(lambda s: float((s == "error").mean()))
    drawn = sorted({round(float(y), 12) for line in ax.get_lines()
                    for y in line.get_ydata() if line.get_marker() in ("o", "s", "^", "D", "v")})
    assert drawn == sorted({round(v, 12) for v in counted})
