"""One chunk of trials: draw, simulate, and return its rows (a worker's whole job).

``run_chunk`` is picklable in and out and writes no file; the runner writes what it returns.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from flatcli.core.metrics import COUNT_METRICS, METRIC_NAMES, Status, describe_status
from flatcli.core.simulate import NoiseStreams, Trials, simulate
from flatcli.experiment import checked
from flatcli.spec import perturbations
from flatcli.sweep.draws import (
    PERTURB_SLOTS,
    draw_perturbations,
    invalid_plants,
    invalid_servos,
    nominal_values,
    perturbation_columns,
)
from flatcli.sweep.layout import Cell, Chunk

#: Statuses ``--fail-fast`` stops at: trials that did not run, or not to the end.
FAILURES = ("error", "diverged", "unresolved")


@dataclass(frozen=True)
class ChunkResult:
    """A finished chunk: one row per trial (the columns of trials.parquet), and its time."""

    table: pa.Table
    seconds: float

    def first_failure(self) -> tuple[int, str] | None:
        """The first trial whose status is one of ``FAILURES``, for --fail-fast."""
        status = self.table.column("status").to_pylist()
        for i, value in enumerate(status):
            if value in FAILURES:
                trial = self.table.column("trial")[i].as_py()
                return int(trial), f"{value}: {self.table.column('reason')[i].as_py()}"
        return None


def run_chunk(cell: Cell, chunk: Chunk) -> ChunkResult:
    """Simulate one chunk; return its columns.

    A trial whose perturbed plant is not a valid robot, or whose perturbed servo is not a
    valid servo, is recorded as ``error`` with the reason; the others are simulated.
    """
    started = time.perf_counter()
    spec = cell.spec
    scenario = cell.scenario
    ids = np.arange(chunk.start, chunk.stop)
    seed = spec.sweep.seed
    nominal = nominal_values(spec, scenario.plan)
    drawn = draw_perturbations(perturbations(spec.sweep), nominal, seed, ids.tolist())
    value = {name: np.broadcast_to(drawn.get(name, nominal[name]), (len(ids), nominal[name].size))
             for name in PERTURB_SLOTS}
    links = np.hstack([value["mass"], value["inertia"], value["length"], value["com"]])
    initial = np.hstack([value["initial"], value["initial_rate"]])
    momentum = value["momentum"][:, 0]
    servo = np.hstack([value["servo_bandwidth"], value["torque_limit"]])
    reasons = [plant or servo_reason for plant, servo_reason
               in zip(invalid_plants(links), invalid_servos(servo), strict=True)]
    valid = np.array([not r for r in reasons], dtype=bool)
    metrics = np.full((len(ids), len(METRIC_NAMES)), np.nan)
    status = np.full(len(ids), int(Status.ERROR), dtype=np.int64)
    event = np.zeros(len(ids), dtype=np.int64)
    event_time = np.full(len(ids), np.nan)
    if valid.any():
        noise = NoiseStreams(spec.track.sensor_noise, seed, ids[valid].astype(np.int64))
        trials = Trials(np.ascontiguousarray(links[valid]), np.ascontiguousarray(momentum[valid]),
                        np.ascontiguousarray(initial[valid]), noise,
                        np.ascontiguousarray(servo[valid]))
        outcome = simulate(scenario, trials, checked(spec.track.integrator))
        metrics[valid] = outcome.metrics
        status[valid] = outcome.status
        event[valid] = outcome.event
        event_time[valid] = outcome.event_time
    status_names = []
    reason_texts = []
    for i in range(len(ids)):
        if not valid[i]:
            status_names.append("error")
            reason_texts.append(reasons[i])
            continue
        name, reason = describe_status(int(status[i]), int(event[i]), float(event_time[i]),
                                       metrics[i], scenario.singular_threshold,
                                       scenario.divergence_bound)
        status_names.append(name)
        reason_texts.append(reason)
    columns: dict[str, Any] = {"trial": ids.astype(np.int64),
                               "cell": np.full(len(ids), chunk.cell, dtype=np.int64)}
    for key, v in cell.values.items():
        columns[key] = [grid_cell_text(v)] * len(ids)
    for name in PERTURB_SLOTS:
        if name in drawn:
            for j, col in enumerate(perturbation_columns(name)):
                columns[col] = np.ascontiguousarray(drawn[name][:, j])
    for j, metric in enumerate(METRIC_NAMES):
        columns[metric] = metrics[:, j]
    for metric in COUNT_METRICS:  # counts as integers, null where not applicable
        values = columns[metric]
        columns[metric] = pa.array(np.nan_to_num(values, nan=0).astype(np.int64),
                                   mask=np.isnan(values), type=pa.int64())
    columns["status"] = pa.array(status_names, type=pa.string())
    columns["reason"] = pa.array(reason_texts, type=pa.string())
    columns["event_time"] = event_time
    return ChunkResult(pa.table(columns), time.perf_counter() - started)


def grid_cell_text(value: Any) -> Any:
    """How a grid value is stored in a column: numbers as floats, strings as is, lists as
    JSON, a group by its label (or its table as JSON)."""
    if isinstance(value, dict):
        return str(value["label"]) if "label" in value else json.dumps(value, sort_keys=True)
    if isinstance(value, list | tuple):
        return json.dumps([float(v) if isinstance(v, int) and not isinstance(v, bool) else v
                           for v in value])
    if isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value
