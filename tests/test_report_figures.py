"""Plan and track figures and what every figure shares (flatcli/report/figures.py): checked
by their axes' labels, limits and data, never by pixels."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import pytest

from flatcli.core.plan.planning import plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT
from flatcli.experiment import run_track
from flatcli.outputs import plan_frame, track_frame
from flatcli.report.figures import (
    STYLE,
    FigureFile,
    Limits,
    new_figure,
    plan_figure,
    plan_title,
    save_figure,
    style,
    track_figure,
    track_title,
)
from flatcli.spec import resolve


@pytest.fixture(scope="module")
def frame() -> Any:
    """plan.parquet's rows of the paper's cubic (Sec. VI)."""
    plan = plan_point_to_point(PAPER_ROBOT, np.array([1.8, 1, 0]), np.array([1.2, 2, 0]), 0.1,
                               0.5, 2.0)
    return plan_frame(plan.sample(plan.grid(201)))


def _legend(ax: Any) -> list[str]:
    return [str(h) for h in ax.get_legend_handles_labels()[1]]


def _by_label(fig: Any) -> dict[str, Any]:
    return {ax.get_ylabel(): ax for ax in fig.axes}


def _every_legend_entry_has_a_line(fig: Any) -> None:
    """A legend entry is a line or a marker someone can match to the data, never an empty
    handle standing for a sentence."""
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is None:
            continue
        for handle in legend.legend_handles:
            line = handle.get_linestyle() not in ("None", "none", "", " ")
            marker = handle.get_marker() not in ("None", "none", "", " ", None)
            assert handle.get_visible() and (line or marker), handle.get_label()


def test_plan_figure_has_units_honest_axes_and_its_limits(frame: Any) -> None:
    fig = plan_figure(frame, Limits(singular_threshold=0.01, min_margin=0.02, rate_limit=60.0,
                                    angle_limit=(np.inf, np.inf, 5.0)), "a title")
    axes = _by_label(fig)
    assert set(axes) == {"$y_j$ [rad]", r"$\theta_i$ [rad]", r"$\theta_i'$ [rad/s]",
                         "singularity margin [rad/s]", "$H$ [kg m$^2$/s]",
                         "$u_j'$ [rad/s$^2$]"}
    margin, momentum = axes["singularity margin [rad/s]"], axes["$H$ [kg m$^2$/s]"]
    assert momentum.get_yscale() == "linear"  # H of a correct plan is rounding: shown as such
    low, high = momentum.get_ylim()
    assert max(abs(low), abs(high)) < 1e-14
    assert margin.get_yscale() == "log" and margin.get_ylim()[0] > 1e-3
    assert "singular_threshold\n= 0.01 rad/s" in _legend(margin)
    assert "min_margin = 0.02 rad/s" in _legend(margin)
    assert r"rate_limit = $\pm$60 rad/s" in _legend(axes[r"$\theta_i'$ [rad/s]"])
    assert r"angle_limit[2] = $\pm$5 rad" in _legend(axes[r"$\theta_i$ [rad]"])
    # an infinite limit is drawn nowhere and has no legend entry (the title says "none")
    assert not any("angle_limit[0]" in t for t in _legend(axes[r"$\theta_i$ [rad]"]))
    # the data: theta2 of the cubic reaches 3.93 rad (tests/test_report_runs.py)
    (theta2,) = [ln for ln in axes[r"$\theta_i$ [rad]"].get_lines()
                 if ln.get_label() == r"$\theta_2$"]
    assert round(float(np.max(np.abs(theta2.get_ydata()))), 2) == 3.93
    assert [a.get_xlabel() for a in fig.axes[3:]] == ["$t$ [s]"] * 3
    assert fig.get_suptitle() == "a title"
    _every_legend_entry_has_a_line(fig)


def test_plan_title_names_the_robot_and_the_objective() -> None:
    spec = resolve({"name": "p"})
    assert plan_title(spec) == "plan 'p': the paper's robot, derived model, T = 2 s"
    assert plan_title(spec, {"objective": "energy", "success": False}).endswith(
        "optimised for energy (not converged)")


@pytest.fixture(scope="module")
def stopped() -> Any:
    """A run that stops early: u1(0) of the wrong sign meets the singular set."""
    spec = resolve({"track": {"dt": 0.01, "initial_rate": -0.05}})
    run = run_track(spec)
    assert run.metrics["status"] == "diverged"
    return spec, run


def test_track_figure_marks_where_a_trial_stopped(stopped: Any) -> None:
    spec, run = stopped
    fig = track_figure(track_frame(run), Limits.of_track(spec), track_title(spec, run.metrics))
    axes = _by_label(fig)
    assert len(fig.axes) == 6  # the kinematic plant: no actuator row
    rates = axes[r"applied $\theta_j'$ [rad/s]"]
    assert _legend(rates) == [r"$\theta_1'$", r"$\theta_2'$"]  # rate limit inf: no line
    stop = [t for t in _legend(axes["$y_j$ [rad]"]) if t.startswith("stopped after")]
    assert len(stop) == 1  # said once, drawn in every panel
    assert all(any(ln.get_linestyle() == ":" for ln in ax.get_lines()) for ax in fig.axes)
    assert axes["$H$ [kg m$^2$/s]"].get_yscale() == "linear"
    assert "reference" in " ".join(_legend(axes["$y_j$ [rad]"]))
    title = fig.get_suptitle()
    assert "kinematic plant" in title and "sensor noise 0 rad" in title
    assert "rate limit none" in title and "torque limit n/a (no torques)" in title
    assert "status diverged at $t$ = " in title
    _every_legend_entry_has_a_line(fig)


def test_the_dynamic_plants_figure_has_torque_and_servo_panels() -> None:
    spec = resolve({"track": {"kp": [100, 110], "kv": [10, 13], "dt": 0.004,
                              "sensor_noise": 1e-4},
                    "plant": {"model": "dynamic", "torque_limit": 3000.0}})
    run = run_track(spec)
    frame = track_frame(run)
    fig = track_figure(frame, Limits.of_track(spec), track_title(spec, run.metrics))
    axes = _by_label(fig)
    assert len(fig.axes) == 9
    torques = axes[r"$\tau_j$ [N m]"]
    assert r"torque_limit = $\pm$3000 N m" in _legend(torques)
    (tau2,) = [ln for ln in torques.get_lines() if ln.get_label() == r"$\tau_2$"]
    np.testing.assert_array_equal(tau2.get_ydata(), frame["tau2"].to_numpy())
    servo = axes["servo rate error [rad/s]"]
    (lag2,) = [ln for ln in servo.get_lines() if ln.get_label() == r"$u_2 - \theta_2'$"]
    np.testing.assert_array_equal(lag2.get_ydata(),
                                  (frame["u2"] - frame["theta2_dot"]).to_numpy())
    assert "joint power [W]" in axes
    title = fig.get_suptitle()
    assert "dynamic plant (servo 100 rad/s, the robot's model)" in title
    assert "sensor noise 0.0001 rad" in title and "torque limit 3000 N m" in title
    assert "$k_p$ = (100, 110), $k_v$ = (10, 13)" in title
    _every_legend_entry_has_a_line(fig)


def test_the_style_sheet_applies_while_flatcli_draws_only() -> None:
    before = dict(matplotlib.rcParams)
    with style():
        assert matplotlib.rcParams["pdf.fonttype"] == 42  # TrueType, not Type 3
        assert matplotlib.rcParams["axes.spines.top"] is False
        fig = new_figure(3.5, 2.5)
        text = fig.text(0.5, 0.5, "x")
        assert text.get_fontsize() == 8.0  # print size: 8 pt at a column's width
    assert dict(matplotlib.rcParams) == before  # a user's settings are left alone
    assert STYLE.is_file() and STYLE.name == "flatcli.mplstyle"


def test_a_figure_is_written_as_png_pdf_or_svg_at_its_dpi(tmp_path: Path) -> None:
    fig = new_figure(2.0, 1.0)
    fig.subplots().plot([0, 1], [0, 1])
    for fmt, magic in (("png", b"\x89PNG"), ("pdf", b"%PDF-"), ("svg", b"<?xml")):
        file = FigureFile(fmt, 100)
        path = save_figure(fig, tmp_path / file.name("f"), file)
        assert path.name == f"f.{fmt}" and path.read_bytes().startswith(magic)
    assert b"CreationDate" not in (tmp_path / "f.pdf").read_bytes()  # no date: same bytes
    data = save_figure(fig, tmp_path / "g.png", FigureFile("png", 300)).read_bytes()
    assert int.from_bytes(data[16:20], "big") == 600  # 2 in at 300 dots per inch


def test_the_figure_file_comes_from_the_spec_or_its_record() -> None:
    assert FigureFile.of(resolve({"figures": {"format": "pdf", "dpi": 300}})) == \
        FigureFile("pdf", 300)
    assert FigureFile.of_tree({"figures": {"format": "svg"}}) == FigureFile("svg", 150)
    assert FigureFile.of_tree({}) == FigureFile()  # a record written before [figures]


def test_an_exact_plans_figure_says_it_has_no_margin() -> None:
    """An exact plan (d2 = 3 mm, plan.method = "auto") records no margin (all NaN): its
    figure draws, and says so where the margin would be (a log axis of NaN raised before)."""
    import flatcli

    result = flatcli.plan(overrides={"robot.com": [0.1, 0.1, 0.003]})
    assert result.frame["margin"].isna().all()
    figure = result.plot()
    texts = [t.get_text() for ax in figure.axes for t in ax.texts]
    assert any("no singularity margin" in t for t in texts)
