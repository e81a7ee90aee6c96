"""Plan and track figures (flatcli/report/figures.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from flatcli.core.model import PAPER_ROBOT
from flatcli.core.planning import plan_point_to_point
from flatcli.report.figures import plot_plan


def test_plan_figure_is_a_png(tmp_path: Path) -> None:
    plan = plan_point_to_point(PAPER_ROBOT, np.array([1.8, 1, 0]), np.array([1.2, 2, 0]), 0.1,
                               0.5, 2.0)
    plot_plan(plan.sample(plan.grid(201)), tmp_path / "p.png", "t")
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
