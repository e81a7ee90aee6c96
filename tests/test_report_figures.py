"""Plan and track figures (flatcli/report/figures.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from flatcli.core.model import PAPER_ROBOT
from flatcli.core.planning import PlanSamples, plan_point_to_point
from flatcli.experiment import run_track
from flatcli.report.figures import Limits, plan_figure, plot_plan, plot_track, track_figure
from flatcli.spec import resolve


@pytest.fixture(scope="module")
def samples() -> PlanSamples:
    plan = plan_point_to_point(PAPER_ROBOT, np.array([1.8, 1, 0]), np.array([1.2, 2, 0]), 0.1,
                               0.5, 2.0)
    return plan.sample(plan.grid(201))


def _legend(ax: Any) -> list[str]:
    return [str(h.get_label()) for h in ax.get_legend_handles_labels()[0]]


def test_plan_figure_has_honest_separate_axes_for_margin_and_momentum(
    samples: PlanSamples, tmp_path: Path
) -> None:
    fig = plan_figure(samples, Limits(singular_threshold=0.01, min_margin=0.02, rate_limit=60.0,
                                      angle_limit=(np.inf, np.inf, 5.0)))
    axes = {ax.get_ylabel(): ax for ax in fig.axes}
    margin = axes["singularity margin [rad/s]"]
    momentum = axes["angular momentum H [kg m^2/s]"]
    assert margin is not momentum
    assert momentum.get_yscale() == "linear"  # H of a correct plan is rounding: shown as such
    low, high = momentum.get_ylim()
    assert max(abs(low), abs(high)) < 1e-14
    # the margin's log axis spans the margin (and its thresholds), not 1e-300
    assert margin.get_yscale() == "log" and margin.get_ylim()[0] > 1e-3
    assert "track.singular_threshold = 0.01 rad/s" in _legend(margin)
    assert "plan.optimize.min_margin = 0.02 rad/s" in _legend(margin)
    assert "plan.optimize.rate_limit = +-60 rad/s" in _legend(axes["joint rates [rad/s]"])
    assert "plan.optimize.angle_limit[2] = +-5 rad" in _legend(axes["angles [rad]"])
    plot_plan(samples, tmp_path / "p.png", "t")
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


def test_track_figure_marks_where_a_trial_stopped(tmp_path: Path) -> None:
    # u1(0) of the wrong sign: the loop meets the singular set and the trial stops
    run = run_track(resolve({"track": {"dt": 0.01, "initial_rate": -0.05}}))
    assert run.metrics["status"] == "diverged"
    fig = track_figure(run.columns, Limits(singular_threshold=0.01, rate_limit=np.inf))
    axes = {ax.get_ylabel(): ax for ax in fig.axes}
    assert "track.rate_limit = inf (no limit)" in _legend(axes["joint rates [rad/s]"])
    assert any(label.startswith("trial stopped after t = ")
               for label in _legend(axes["singularity margin [rad/s]"]))
    assert axes["angular momentum H [kg m^2/s]"].get_yscale() == "linear"
    plot_track(run.columns, tmp_path / "t.png", "t")
    assert (tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"
