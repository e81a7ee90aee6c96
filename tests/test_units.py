"""The table of units (flatcli/units.py)."""

from __future__ import annotations

from flatcli.core.metrics import METRIC_NAMES, STATUS_NAMES
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
