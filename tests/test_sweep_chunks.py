"""One chunk of trials (flatcli/sweep/chunks.py): its rows, and what --fail-fast reads."""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from flatcli.core.metrics import METRIC_NAMES
from flatcli.spec import resolve
from flatcli.sweep import Chunk, ChunkResult, grid_cell_text, layout, run_chunk


def test_a_chunk_has_one_row_per_trial_with_draws_and_metrics_by_name() -> None:
    spec = resolve({"plan": {"duration": 1.0}, "track": {"dt": 0.01, "kp": [100, 110],
                                                         "kv": [20, 21]},
                    "sweep": {"trials": 4, "seed": 3, "grid": {"track.sensor_noise": [0.001]},
                              "perturb": {"initial_rate": {"dist": "normal", "std": 0.01}}}})
    cell = layout(spec).cells[0]
    result = run_chunk(cell, Chunk(0, 1, 4))
    frame = result.table.to_pandas()
    assert frame["trial"].tolist() == [1, 2, 3]
    assert frame["track.sensor_noise"].tolist() == [0.001] * 3
    assert {"initial_rate", *METRIC_NAMES, "status", "reason"} <= set(frame.columns)
    assert frame["singular_hits"].dtype == np.int64
    assert (frame["status"] == "ok").all() and result.first_failure() is None
    # a trial's row does not depend on the chunk it ran in
    alone = run_chunk(cell, Chunk(0, 2, 3)).table.to_pandas()
    assert alone.iloc[0].equals(frame.iloc[1])


def test_a_dynamic_chunk_perturbs_the_servo_and_refuses_an_invalid_one() -> None:
    """Servo bandwidth and torque limit drawn per trial (columns of their own), torques in
    the metrics, and a drawn bandwidth <= 0 an ``error`` with the spec key's message."""
    spec = resolve({"plan": {"duration": 1.0}, "track": {"dt": 0.01, "kp": [100, 110],
                                                         "kv": [20, 21],
                                                         "initial": [1.8, 1.0, 0.0]},
                    "plant": {"model": "dynamic", "servo_bandwidth": 50.0,
                              "torque_limit": 20.0},
                    "sweep": {"trials": 6, "seed": 4, "perturb": {
                        "servo_bandwidth": {"dist": "uniform", "low": -1.2, "high": 0.5,
                                            "relative": True},
                        "torque_limit": {"dist": "uniform", "low": -10.0, "high": 30.0}}}})
    frame = run_chunk(layout(spec).cells[0], Chunk(0, 0, 6)).table.to_pandas()
    bad = frame["servo_bandwidth"] <= 0
    assert bad.any() and (~bad).any()
    assert (frame.loc[bad, "status"] == "error").all()
    assert frame.loc[bad, "reason"].str.startswith("plant.servo_bandwidth: must be > 0").all()
    good = frame[~bad]
    assert (good["status"] != "error").all()  # simulated (some diverge at these limits)
    assert good["torque_limit"].between(10.0, 50.0).all()
    assert (good["peak_torque"] <= good["torque_limit"]).all()
    assert good["peak_torque"].notna().all() and good["torque_saturated"].notna().all()


def test_first_failure_is_the_first_error_or_divergence() -> None:
    table = pa.table({"trial": [4, 5, 6], "status": ["ok", "diverged", "error"],
                      "reason": ["", "state beyond 1e4", "plant.mass[0]: must be > 0 kg"]})
    assert ChunkResult(table, 0.0).first_failure() == (5, "diverged: state beyond 1e4")


def test_grid_values_as_stored_in_a_column() -> None:
    assert grid_cell_text(3) == 3.0
    assert grid_cell_text([10, 13]) == "[10.0, 13.0]"
    assert grid_cell_text({"label": "swapped", "track.kp": [1, 2]}) == "swapped"
    assert grid_cell_text({"track.kp": [1, 2]}) == '{"track.kp": [1, 2]}'
    assert grid_cell_text("rk4") == "rk4"
