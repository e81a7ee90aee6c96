"""The section "Within the actuators" of make reproduce (flatcli/reproduce/within.py): its
cells by outcome from hand-made trial rows, its table and figure, and its study spec.

References: the counts recomputed here from the rows; the Wilson interval from its closed
form (Wilson, J. Am. Stat. Assoc. 22, 1927). End to end, the section is run by
tests/test_reproduce.py.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from flatcli.reproduce.within import (
    CONTROLLER,
    LIMIT,
    STUDY,
    cell_rows,
    outcome_table,
    plot_fraction,
)
from flatcli.spec import load_spec

Z95 = 1.959963984540054  # Phi^-1(0.975)


def wilson(k: int, n: int) -> tuple[float, float]:
    """Wilson's closed form: (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)."""
    p, z = k / n, Z95
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def trials_frame() -> pd.DataFrame:
    """Two limits x two controllers, 5 trials each: with no limit every trial reaches; at 4
    rad/s the paper's feedback misses 4 (error 2 rad) and loses 1, the MPC (re-planned)
    reaches 4 and misses 1, two of its trials needing slack."""
    rows = []
    for limit in (math.inf, 4.0):
        for controller in ("flat", "mpc"):
            for i in range(5):
                if limit == 4.0 and controller == "flat":
                    outcome = "lost" if i == 0 else "missed"
                    error = math.nan if i == 0 else 2.0 + i
                elif limit == 4.0:
                    outcome = "missed" if i == 4 else "reached"
                    error = 0.01 if i == 4 else 1e-9 * (i + 1)
                else:
                    outcome, error = "reached", 1e-5 * (i + 1)
                rows.append({
                    LIMIT: limit, CONTROLLER: controller, "outcome": outcome,
                    "err_theta_final": error,
                    "replanned": None if controller == "flat" else limit == 4.0,
                    "qp_infeasible": None if controller == "flat" else (
                        3 if limit == 4.0 and i >= 3 else 0),
                    "clipped_time": 0.0 if math.isinf(limit) else 0.1 * i,
                })
    return pd.DataFrame(rows)


def test_cells_are_counted_by_outcome_with_their_intervals() -> None:
    rows = cell_rows(trials_frame())
    assert list(zip(rows[LIMIT], rows[CONTROLLER], strict=True)) == [
        (math.inf, "flat"), (math.inf, "mpc"), (4.0, "flat"), (4.0, "mpc")]
    flat4 = rows.iloc[2]
    assert (flat4["trials"], flat4["reached"], flat4["missed"], flat4["lost"]) == (5, 0, 4, 1)
    assert flat4["median"] == pytest.approx(4.5)  # over the 4 that reached T: 3, 4, 5, 6
    assert flat4["replanned"] is None and pd.isna(flat4["slack_trials"])
    mpc4 = rows.iloc[3]
    assert (mpc4["reached"], mpc4["missed"], mpc4["slack_trials"]) == (4, 1, 2)
    assert mpc4["replanned"] is True and rows.iloc[1]["replanned"] is False
    assert mpc4["fraction"] == pytest.approx(0.8)
    low, high = wilson(4, 5)
    assert mpc4["low"] == pytest.approx(low, rel=1e-9)
    assert mpc4["high"] == pytest.approx(high, rel=1e-9)
    assert mpc4["clipped_max"] == pytest.approx(0.4)
    text = outcome_table(rows)
    assert "| 4 | MPC | re-planned | 4 of 5 | 80 % (" in text
    assert "| none | paper's feedback | - | 5 of 5 | 100 % (" in text


def test_the_figure_is_written(tmp_path: Path) -> None:
    path = tmp_path / "fig_within.png"
    plot_fraction(cell_rows(trials_frame()), 5, 0.002, 3.87, path)
    assert path.stat().st_size > 10_000


def test_the_study_compares_both_controllers_over_the_limits() -> None:
    spec = load_spec(STUDY)
    assert spec.sweep.grid[CONTROLLER] == ["flat", "mpc"]
    limits = spec.sweep.grid[LIMIT]
    assert math.isinf(limits[0]) and sorted(limits[1:], reverse=True) == limits[1:]
    assert spec.sweep.perturb["initial"]["std"] == 0.002
