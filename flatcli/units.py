"""The unit of every column flatcli writes: the one table of units.

plan.parquet, track.parquet, workspace.parquet, trials.parquet and summary.parquet carry
these as Arrow field metadata (key ``unit``, ``flatcli.storage.UNIT_KEY``) on every numeric
column, so a reader (pyarrow, polars, DuckDB) finds them beside the numbers; docs/outputs.md's
column tables say the same (a test compares them). Units are SI, written as in
docs/outputs.md; ``DIMENSIONLESS`` ("1") marks a pure number: a count, a fraction, a relative
tolerance. Columns without a unit are identifiers (``trial``, ``cell``), text (``status``,
``reason``, a group's label) and flags (workspace.parquet's ``up``).

Columns named after spec keys (a sweep's grid keys) take the spec key's unit; a perturbation
parameter (``sweep.perturb.NAME.PARAM``) takes the unit of the quantity it perturbs, or "1"
when the perturbation is relative.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

from flatcli.core.loop.metrics import OUTCOME_NAMES, STATUS_NAMES
from flatcli.spec import PERTURB_TARGETS, Spec, find_key

#: A pure number: a count, a fraction, a ratio.
DIMENSIONLESS = "1"

_ANGLE, _RATE, _ACCEL, _MOMENTUM = "rad", "rad/s", "rad/s^2", "kg m^2/s"
_TORQUE = "N m"

#: The unit of every fixed column name of flatcli's Parquet tables (a name means the same
#: thing, in the same unit, in every table that has it).
UNITS: dict[str, str] = {
    # plan.parquet and track.parquet: one row per sample
    "t": "s",
    **{f"theta{i}": _ANGLE for i in range(3)},
    **{f"theta{i}_dot": _RATE for i in range(3)},
    **{f"theta{i}_ref": _ANGLE for i in range(3)},
    "u1_dot": _ACCEL,
    "u1": _RATE,
    "u2": _RATE,
    "y1": _ANGLE, "y2": _ANGLE,
    "y1_ref": _ANGLE, "y2_ref": _ANGLE,
    "y1_dot": _RATE, "y2_dot": _RATE,
    "y1_ddot": _ACCEL, "y2_ddot": _ACCEL,
    "margin": _RATE,
    "momentum": _MOMENTUM,  # H along a plan or a run; in trials.parquet the plant's H0
    "tau1": _TORQUE, "tau2": _TORQUE,  # the dynamic plant's joint torques
    # positions with the system's centre of mass at the origin (flatcli.core.robots.kinematics)
    "ee_x": "m", "ee_y": "m", "base_x": "m", "base_y": "m",
    # a task's metrics (metrics.json of a track run, run.json's summary of a plan)
    "ee_error_final": "m", "ee_error_max": "m", "base_attitude_error_final": _ANGLE,
    "min_clearance": "m", "clearance_bound": "m", "certified_intervals": DIMENSIONLESS,
    "task_candidates": DIMENSIONLESS, "rate_factor": DIMENSIONLESS, "rest_skew": DIMENSIONLESS,
    "ee_error_bound": "m",  # trials.parquet of a task sweep
    # workspace.parquet: one row per target (flatcli.core.plan.workspace)
    "target_x": "m", "target_y": "m",
    "abs_sin_th1": DIMENSIONLESS, "abs_sin_th1_up": DIMENSIONLESS,
    "abs_sin_th1_down": DIMENSIONLESS,
    # trials.parquet: the metrics of flatcli.core.loop.metrics (definitions in docs/outputs.md)
    "err_theta_rms": _ANGLE, "err_theta_max": _ANGLE, "err_theta_final": _ANGLE,
    "err_y_rms": _ANGLE, "err_y_max": _ANGLE, "err_y_final": _ANGLE,
    "singular_hits": DIMENSIONLESS,
    "first_hit_time": "s",
    "min_margin": _RATE,
    "momentum_drift": _MOMENTUM,
    "plan_momentum_residual": _MOMENTUM,
    "err_estimate": _ANGLE,
    "peak_rate": _RATE,
    "peak_torque": _TORQUE,
    "torque_saturated": DIMENSIONLESS,
    "steps": DIMENSIONLESS,
    "rhs_evaluations": DIMENSIONLESS,
    "crossings": DIMENSIONLESS,
    "first_crossing_time": "s",
    "clipped_time": "s",
    # a sampled controller's own (the MPC's, flatcli.core.controllers.mpc): counts, and the
    # largest slack of its constraints, joint rates and the margin [rad/s]
    "qp_iterations": DIMENSIONLESS, "qp_infeasible": DIMENSIONLESS, "qp_slack_max": _RATE,
    "event_time": "s",
    "reference_difference": _ANGLE,
    # trials.parquet: the realised perturbed quantities
    **{f"initial_{i}": _ANGLE for i in range(3)},
    "initial_rate": _RATE,
    **{f"mass_{i}": "kg" for i in range(3)},
    **{f"inertia_{i}": "kg m^2" for i in range(3)},
    **{f"length_{i}": "m" for i in range(3)},
    **{f"com_{i}": "m" for i in range(3)},
    "servo_bandwidth": _RATE,
    "torque_limit": _TORQUE,
    "end_effector_0": "m",
    "end_effector_1": "m",
    # summary.parquet: counts per cell (the statistics take their metric's unit)
    "trials": DIMENSIONLESS,
    "resolved": DIMENSIONLESS,
    "simulated": DIMENSIONLESS,
    **{status: DIMENSIONLESS for status in STATUS_NAMES},
    "verified_trials": DIMENSIONLESS,
    "unverified_trials": DIMENSIONLESS,
    "reference_checked": DIMENSIONLESS,
    "reference_status_mismatches": DIMENSIONLESS,
    **{outcome: DIMENSIONLESS for outcome in OUTCOME_NAMES},
}

#: The unit of the indexed columns of a robot of any N joints, by their name with the index
#: written ``#`` (theta3, u2_dot, y4_ref, tau5, mass_6, initial_rate_2, ...).
INDEXED_UNITS: dict[str, str] = {
    "theta#": _ANGLE, "theta#_dot": _RATE, "theta#_ref": _ANGLE,
    "theta#_up": _ANGLE, "theta#_down": _ANGLE,  # workspace.parquet's branches
    "err_theta#_final": _ANGLE,  # th_i(T) - the plan's goal, signed (outcome)
    "u#": _RATE, "u#_dot": _ACCEL,
    "y#": _ANGLE, "y#_dot": _RATE, "y#_ddot": _ACCEL, "y#_ref": _ANGLE,
    "tau#": _TORQUE,
    "dv#": _ACCEL, "dw#": _RATE,  # the MPC's held correction: of y'' (flat), of w (as built)
    "initial_#": _ANGLE, "initial_rate_#": _RATE,
    "mass_#": "kg", "inertia_#": "kg m^2", "length_#": "m", "com_#": "m",
}
_INDEX = re.compile(r"(?<=[a-z_])\d+")

#: Suffixes of summary.parquet's statistics of a metric (in the metric's unit).
STATISTICS = ("_median_all", "_median", "_p95", "_max")
#: Suffixes of summary.parquet's fractions and their confidence bounds (dimensionless).
FRACTIONS = ("_fraction", "_fraction_low", "_fraction_high")


def unit_of(column: str, spec: Spec | None = None) -> str | None:
    """The unit of a column (None: an identifier or text, or a name flatcli does not know).

    ``spec`` resolves the columns named after a sweep's grid keys (relative perturbations).
    """
    if column in UNITS:
        return UNITS[column]
    indexed = _INDEX.sub("#", column, count=1)
    if indexed in INDEXED_UNITS:
        return INDEXED_UNITS[indexed]
    for suffix in FRACTIONS:
        if column.endswith(suffix):
            return DIMENSIONLESS
    for suffix in STATISTICS:
        base = column.removesuffix(suffix)
        if column.endswith(suffix) and base in UNITS:
            return UNITS[base]
    return spec_key_unit(column, spec)


def spec_key_unit(dotted: str, spec: Spec | None = None) -> str | None:
    """The unit of a numeric spec key or perturbation parameter ("1" for a pure number);
    None for a key whose values are not numbers, or a name that is not a key."""
    parts = dotted.split(".")
    if len(parts) == 4 and dotted.startswith("sweep.perturb.") and parts[2] in PERTURB_TARGETS:
        if parts[3] not in ("std", "mean", "low", "high"):
            return None
        table = spec.sweep.perturb.get(parts[2], {}) if spec is not None else {}
        if table.get("relative", False):
            return DIMENSIONLESS
        return spec_key_unit(PERTURB_TARGETS[parts[2]])
    key = find_key(dotted)
    if key is None:
        return None
    if key.kind not in ("float", "int", "vector", "numbers"):
        return None
    return key.unit or DIMENSIONLESS


def units_of(columns: Iterable[str], spec: Spec | None = None) -> dict[str, str]:
    """{column: unit} of the columns that have one."""
    out = {}
    for column in columns:
        unit = unit_of(column, spec)
        if unit is not None:
            out[column] = unit
    return out

