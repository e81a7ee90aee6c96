"""The table of units (flatcli/units.py), and docs/outputs.md's column tables that repeat it."""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

from flatcli.core.loop.metrics import METRIC_NAMES, STATUS_NAMES
from flatcli.experiment import plan_from
from flatcli.outputs import plan_frame
from flatcli.report.summary import summarize_trials
from flatcli.spec import resolve
from flatcli.units import DIMENSIONLESS, UNITS, unit_of, units_of


def test_every_metric_and_status_count_has_a_unit() -> None:
    assert set(METRIC_NAMES) <= set(UNITS)
    assert {UNITS[s] for s in STATUS_NAMES} == {DIMENSIONLESS}
    assert UNITS["err_theta_rms"] == "rad" and UNITS["first_hit_time"] == "s"
    assert UNITS["momentum_drift"] == "kg m^2/s" and UNITS["peak_torque"] == "N m"


def test_statistics_and_fractions_take_their_units() -> None:
    assert unit_of("err_y_final_p95") == "rad"
    assert unit_of("min_margin_median") == "rad/s"
    assert unit_of("diverged_fraction_high") == DIMENSIONLESS
    assert unit_of("singular_fraction") == DIMENSIONLESS
    assert unit_of("trial") is None and unit_of("status") is None and unit_of("gains") is None


def test_grid_columns_take_the_units_of_their_spec_keys() -> None:
    spec = resolve({"sweep": {"perturb": {
        "initial": {"dist": "normal", "std": 0.01},
        "mass": {"dist": "uniform", "low": -0.1, "high": 0.1, "relative": True}}}})
    assert unit_of("plant.com", spec) == "m"
    assert unit_of("track.kp", spec) == "1/s^2"
    assert unit_of("track.rtol", spec) == DIMENSIONLESS  # a number with no unit
    assert unit_of("track.integrator", spec) is None  # a word
    assert unit_of("sweep.perturb.initial.std", spec) == "rad"  # the unit of th(0)
    assert unit_of("sweep.perturb.mass.high", spec) == DIMENSIONLESS  # relative: a ratio
    assert units_of(["cell", "plant.mass", "reason"], spec) == {"plant.mass": "kg"}


def _readme_units() -> dict[str, str]:
    """{column: unit} of every row of docs/outputs.md's column tables (``| column | unit |
    ...``; an empty unit for a column of words or labels)."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "outputs.md").read_text()
    units: dict[str, str] = {}
    in_table = False
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.strip().startswith("| column | unit |"):
            in_table = True
            continue
        if not line.strip().startswith("|"):
            in_table = False
        if in_table and len(cells) > 1 and not set(cells[0]) <= {"-"}:
            for name in re.findall(r"`([^`]+)`", cells[0]):
                units[name] = cells[1]
    return units


def test_the_docs_column_tables_say_what_the_files_hold() -> None:
    readme = _readme_units()
    for name, unit in readme.items():
        assert unit_of(name) == (unit or None), name
    plan = plan_from(resolve({}))
    documented = [*plan_frame(plan.sample(plan.grid(3))).columns, *METRIC_NAMES, "event_time",
                  *TRACK_ONLY]
    frame = pd.DataFrame({"cell": [0], "status": ["ok"], **{m: [1.0] for m in METRIC_NAMES}})
    summary = summarize_trials(frame, {0: {}})
    documented += [c for c in summary.columns if c != "cell" and unit_of(c) is not None]
    assert sorted(set(documented) - set(readme)) == []


#: track.parquet's columns that plan.parquet does not have.
TRACK_ONLY = ["theta0_ref", "theta1_ref", "theta2_ref", "u1", "y1_ref", "y2_ref"]
