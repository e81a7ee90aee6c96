"""One chunk of trials: draw, simulate, and return its rows (a worker's whole job).

``run_chunk`` is picklable in and out and writes no file; the runner writes what it returns.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from flatcli.arrow import flags, numbers, repeated, texts
from flatcli.core.errors import FlatcliError
from flatcli.core.loop.metrics import (
    COUNT_METRICS,
    METRIC_NAMES,
    STATUS_NAMES,
    Status,
    describe_status,
)
from flatcli.core.loop.outcome import Geometry, Judged, MotionClearance, judge
from flatcli.core.loop.simulate import NoiseStreams, Scenario, Trials, check_against_reference
from flatcli.core.loop.table import CONTROLLER_COLUMNS, CONTROLLER_COUNTS
from flatcli.experiment import (
    checked,
    goal_of,
    initial_rates,
    plant_from,
    scenario_from,
    tracked_plan,
)
from flatcli.montecarlo.draws import (
    draw_perturbations,
    invalid_plants,
    invalid_servos,
    nominal_values,
    perturbation_columns,
)
from flatcli.montecarlo.layout import Cell, Chunk
from flatcli.montecarlo.tally import simulate_counted
from flatcli.spec import PERTURB_TARGETS, Spec, lookup, perturbations
from flatcli.storage import null_where_nan, peak_memory_mib, table_checksum, with_units
from flatcli.units import units_of

#: Statuses ``--fail-fast`` stops at: trials that did not run, or not to the end.
FAILURES = ("error", "diverged", "unresolved")


@dataclass(frozen=True)
class ChunkResult:
    """A finished chunk: one row per trial (the columns of trials.parquet), its time [s],
    the peak resident memory of the process that ran it [MiB] (``peak_memory_mib``), and the
    checksum of its table (``storage.table_checksum``, which its file records), computed by
    the worker that ran it rather than in the main process, which writes every chunk.
    ``checksum`` None: not computed (the writer computes it)."""

    table: pa.Table
    seconds: float
    peak_mib: float = math.nan
    checksum: str | None = None

    @staticmethod
    def joined(parts: Sequence[ChunkResult]) -> ChunkResult:
        """The result of a chunk computed in pieces (``layout.work_pieces``), ``parts`` in
        the order of their trials: the rows in that order (one Arrow chunk per column, as a
        whole chunk's), the pieces' times added, the largest of their peaks."""
        if len(parts) == 1:
            return parts[0]
        table = pa.concat_tables([p.table for p in parts]).combine_chunks()
        peaks = [p.peak_mib for p in parts if not math.isnan(p.peak_mib)]
        return ChunkResult(table, sum(p.seconds for p in parts), max(peaks, default=math.nan),
                           table_checksum(table))

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
    valid servo, is recorded as ``error`` with the reason; the others are simulated. With
    ``[sweep.perturb] end_effector`` every trial plans its own task to its drawn target
    (``trial_task``): one it cannot plan is an ``error`` with the planner's reason.
    """
    started = time.perf_counter()
    spec = cell.spec
    scenario = cell.scenario
    ids = np.arange(chunk.start, chunk.stop)
    seed = spec.sweep.seed
    joints = spec.joints
    nominal = nominal_values(spec, scenario.plan)
    drawn = draw_perturbations(perturbations(spec.sweep, joints), nominal, seed, ids.tolist(),
                               joints)
    value = {name: np.array(np.broadcast_to(drawn.get(name, nominal[name]),
                                            (len(ids), nominal[name].size)))
             for name in PERTURB_TARGETS}
    servo = np.hstack([value["servo_bandwidth"], value["torque_limit"]])
    across = plant_from(spec).com_across  # e_N of every trial's plant [m]
    links = np.hstack([value["mass"], value["inertia"], value["length"], value["com"]])
    reasons = [plant or servo_reason for plant, servo_reason
               in zip(invalid_plants(links), invalid_servos(servo), strict=True)]
    own: list[TrialTask | None] = [None] * len(ids)  # a trial's own task, if it has one
    if "end_effector" in drawn:  # a plan per trial, to its own target
        for i in range(len(ids)):
            if reasons[i]:
                continue
            try:
                task = own[i] = trial_task(spec, value["end_effector"][i])
            except FlatcliError as exc:
                reasons[i] = str(exc)
                continue
            # the plan's own start rates are the trial's nominal ones (as its re-run sees)
            rates = initial_rates(task.spec_of_trial, task.scenario.plan)
            value["initial_rate"][i] = rates + (value["initial_rate"][i]
                                                - nominal["initial_rate"])
            if "initial_rate" in drawn:
                drawn["initial_rate"][i] = value["initial_rate"][i]
    initial = np.hstack([value["initial"], value["initial_rate"]])
    momentum = value["momentum"][:, 0]
    valid = np.array([not r for r in reasons], dtype=bool)
    metrics = np.full((len(ids), len(METRIC_NAMES)), np.nan)
    status = np.full(len(ids), int(Status.ERROR), dtype=np.int64)
    event = np.zeros(len(ids), dtype=np.int64)
    event_time = np.full(len(ids), np.nan)
    verified = np.zeros(len(ids), dtype=bool)
    why_not: list[str] = [""] * len(ids)
    difference = np.full(len(ids), np.nan)
    reference_status: list[str | None] = [None] * len(ids)
    final = np.full((len(ids), joints + 1), np.nan)
    obstacles = spec.task.obstacles or None
    clearance = np.full((len(ids), 2), np.nan)  # min_clearance, clearance_bound [m]
    clearances: list[tuple[NDArray[np.intp], MotionClearance]] = []
    extra = np.full((len(ids), len(CONTROLLER_COLUMNS)), np.nan)  # the controller's own
    if valid.any():
        noise = NoiseStreams(spec.track.sensor_noise, seed, ids[valid].astype(np.int64))
        trials = Trials(np.ascontiguousarray(links[valid]), np.ascontiguousarray(momentum[valid]),
                        np.ascontiguousarray(initial[valid]), noise,
                        np.ascontiguousarray(servo[valid]),
                        np.full(int(valid.sum()), across))
        rows = np.flatnonzero(valid)
        within = ids[rows] - cell.first_trial  # (a trial of another cell's ids: never)
        chosen = (within >= 0) & (within < verify_count(spec.sweep.verify, spec.sweep.trials))
        # one batch for the cell's scenario; a trial with its own plan alone
        batches = ([np.arange(len(rows))] if "end_effector" not in drawn
                   else [np.array([k]) for k in range(len(rows))])
        for batch in batches:
            task = own[rows[batch[0]]]
            sc = scenario if task is None else task.scenario
            part = trials.subset(batch) if len(batches) > 1 else trials
            outcome = simulate_counted(sc, part, checked(spec.track.integrator), obstacles)
            where = rows[batch]
            metrics[where] = outcome.metrics
            if outcome.final is not None:
                final[where] = outcome.final
            if outcome.extra is not None:
                for k, name in enumerate(outcome.extra_columns):
                    extra[where, CONTROLLER_COLUMNS.index(name)] = outcome.extra[:, k]
            if outcome.clearance is not None:
                clearances.append((where, outcome.clearance))
                clearance[where, 0] = outcome.clearance.sampled
                clearance[where, 1] = outcome.clearance.bound
            status[where] = outcome.status
            event[where] = outcome.event
            event_time[where] = outcome.event_time
            verified[where] = outcome.verified
            for k, row in enumerate(where):
                why_not[row] = outcome.unverified(k)
            pick = batch[chosen[batch]]
            if pick.size:
                check = check_against_reference(sc, trials.subset(pick),
                                                checked(spec.track.integrator))
                difference[rows[pick]] = check.difference
                for row, code in zip(rows[pick], check.status, strict=True):
                    reference_status[row] = STATUS_NAMES[int(code)]
    status_names = []
    reason_texts = []
    for i in range(len(ids)):
        if not valid[i]:
            status_names.append("error")
            reason_texts.append(reasons[i])
            continue
        name, reason = describe_status(int(status[i]), int(event[i]), float(event_time[i]),
                                       metrics[i], scenario.singular_threshold,
                                       scenario.divergence_bound, why_not[i])
        status_names.append(name)
        reason_texts.append(reason)
    judged = judge_chunk(spec, scenario, own, status_names, reason_texts, final, links, across,
                         value.get("end_effector"), clearances)
    # built from buffers (``flatcli.arrow``): pa.array would load pandas in every worker
    columns: dict[str, Any] = {"trial": numbers(ids, pa.int64()),
                               "cell": repeated(chunk.cell, pa.int64(), len(ids))}
    for key, (kind, v) in grid_columns(cell.values, spec).items():
        columns[key] = repeated(v, kind, len(ids))
    for name in PERTURB_TARGETS:
        if name in drawn:
            for j, col in enumerate(perturbation_columns(name, joints)):
                columns[col] = numbers(drawn[name][:, j], null=np.zeros(len(ids), dtype=bool))
    for j, metric in enumerate(METRIC_NAMES):  # null where not applicable (nan in the core)
        columns[metric] = null_where_nan(metrics[:, j])
    for metric in COUNT_METRICS:  # counts as integers, null where not applicable
        values = metrics[:, METRIC_NAMES.index(metric)]
        columns[metric] = numbers(np.nan_to_num(values, nan=0).astype(np.int64), pa.int64(),
                                  np.isnan(values))
    for i in range(joints + 1):
        columns[f"err_theta{i}_final"] = null_where_nan(judged.final_error[:, i])
    for k, name in enumerate(CONTROLLER_COLUMNS):  # null for a controller without it
        values = extra[:, k]
        columns[name] = (numbers(np.nan_to_num(values, nan=0).astype(np.int64), pa.int64(),
                                 np.isnan(values)) if name in CONTROLLER_COUNTS
                         else null_where_nan(values))
    columns["status"] = texts(status_names)
    columns["reason"] = texts(reason_texts)
    columns["outcome"] = texts(judged.outcome)
    columns["outcome_reason"] = texts(judged.reason)
    columns["event_time"] = null_where_nan(event_time)
    columns["replanned"] = repeated(cell.replanned, pa.bool_(), len(ids))
    columns["verified"] = flags(verified)
    columns["reference_difference"] = null_where_nan(difference)
    columns["reference_status"] = texts(reference_status)
    if spec.task.end_effector is not None:  # a task sweep: how near the target, at most
        plans = [scenario.plan if task is None else task.scenario.plan for task in own]
        columns["ee_error_bound"] = null_where_nan(
            reach_bounds(spec, plans, value, metrics, valid, across))
        columns["ee_error_final"] = null_where_nan(judged.target_error)
    if obstacles is not None:  # over the samples a trial reached, and between them
        columns["min_clearance"] = null_where_nan(clearance[:, 0])
        columns["clearance_bound"] = null_where_nan(clearance[:, 1])
    table = with_units(pa.table(columns), units_of(columns, spec))
    return ChunkResult(table, time.perf_counter() - started, peak_memory_mib(),
                       table_checksum(table))


def judge_chunk(spec: Spec, scenario: Scenario, own: list[TrialTask | None],
                status: list[str], reason: list[str], final: NDArray[np.float64],
                links: NDArray[np.float64], across: float, targets: Any,
                clearances: list[tuple[NDArray[np.intp], MotionClearance]]) -> Judged:
    """The outcome of a chunk's trials (``core.outcome.judge``): each against the goal of the
    plan it tracked (the cell's, or its own task's) and its own target (``targets`` (n, 2)
    [m], the task's draws; None: no task), with its clearance from the task's obstacles
    where it ran (``clearances``: (rows, their ``MotionClearance``))."""
    goals = np.array([(scenario if task is None else task.scenario).theta_reference[-1]
                      for task in own])
    goal = goal_of(spec, scenario, None if targets is None or spec.task.end_effector is None
                   else np.asarray(targets, dtype=float))
    goal = replace(goal, angles=goals)
    motion = None
    if clearances:
        nan = np.full(len(status), np.nan)
        zeros = np.zeros(len(status), dtype=np.int64)
        motion = MotionClearance(nan.copy(), nan.copy(), zeros.copy(), zeros.copy(),
                                 nan.copy(), np.full((len(status), 2), np.nan), zeros.copy(),
                                 zeros.copy())
        for rows, part in clearances:
            for name in MotionClearance.__dataclass_fields__:
                getattr(motion, name)[rows] = getattr(part, name)
    with np.errstate(all="ignore"):  # an error trial's links may be no robot (mass <= 0)
        geometry = Geometry.of(links, np.full(len(status), across))
    return judge(status, reason, final, goal, geometry, motion)


@dataclass(frozen=True)
class TrialTask:
    """A trial's own task (``[sweep.perturb] end_effector``): its spec (the cell's with the
    drawn target as task.end_effector, as ``sweep --rerun`` builds it) and its scenario."""

    spec_of_trial: Spec
    scenario: Scenario


def trial_task(spec: Spec, target: Any) -> TrialTask:
    """The task of one trial whose target is ``target`` (2,) [m]: planned and prepared as a
    track run of the same spec would (FlatcliError: the planner's reason)."""
    applied = spec.with_overrides({"task.end_effector": [float(v) for v in target]})
    plan, replanned = tracked_plan(applied)
    return TrialTask(applied, scenario_from(applied, plan, replanned).prepared())


def reach_bounds(spec: Spec, plans: list[Any], value: dict[str, Any], metrics: Any,
                 valid: Any, across: float) -> Any:
    """(n,) ``ee_error_bound`` of a chunk's trials [m] (``core.task.end_effector_error_bound``
    from each plant's links and its err_theta_final, against the plan each trial tracked and
    its target: ``value["end_effector"]``); nan for a trial that did not run or did not reach
    the end."""
    from flatcli.core.plan.task import end_effector_error_bound

    bound = np.full(len(valid), np.nan)
    if spec.task.end_effector is None:
        return bound
    final = metrics[:, METRIC_NAMES.index("err_theta_final")]
    groups: dict[int, list[int]] = {}  # the trials of each plan (the cell's, or their own)
    for i in np.flatnonzero(valid):
        groups.setdefault(id(plans[i]), []).append(int(i))
    for rows in groups.values():
        plan = plans[rows[0]]
        planned = plan.sample(np.array([plan.duration])).theta[-1]
        bound[rows] = end_effector_error_bound(
            plan.robot, value["mass"][rows], value["length"][rows], value["com"][rows],
            np.full(len(rows), across), final[rows], planned, value["end_effector"][rows[0]])
    return bound


def verify_count(verify: float, trials: int) -> int:
    """Trials of each cell that ``sweep.verify`` re-runs with the reference integrator (the
    first ones of the cell): a fraction below 1 of ``trials`` (rounded up: at least one), a
    whole count from 1 on (at most ``trials``); 0 for none."""
    if verify <= 0:
        return 0
    if verify < 1:
        return min(trials, max(1, math.ceil(verify * trials)))
    return min(trials, int(verify))


def grid_cell_text(value: Any) -> Any:
    """A grid value as one scalar: numbers as floats, strings as is, lists as JSON, a group by
    its label (or its table as JSON)."""
    if isinstance(value, dict):
        return str(value["label"]) if "label" in value else json.dumps(value, sort_keys=True)
    if isinstance(value, list | tuple):
        return json.dumps([float(v) if isinstance(v, int) and not isinstance(v, bool) else v
                           for v in value])
    if isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def grid_columns(values: Mapping[str, Any], spec: Spec) -> dict[str, tuple[pa.DataType, Any]]:
    """A cell's grid values as columns of its rows: {column: (Arrow type, value)}.

    A spec key (``values``: {grid entry: this cell's value}) is a column of its own type:
    float64, int64, bool, string, or list<float64> for a vector (``plant.com``,
    ``track.kp``). A perturbation parameter (``sweep.perturb.initial.std``) is float64, or
    list<float64> if its grid values are lists (text if they mix the two). A group is a text
    column under its name (its label, or its table as JSON) and one column per spec key it
    sets (``gains`` -> ``track.kp``, ``track.kv``). A spec key's column holds the value the
    cell ran with, ``spec`` being the cell's spec (null: a nullable key not set).
    """
    out: dict[str, tuple[pa.DataType, Any]] = {}
    grid = spec.sweep.grid
    applied = spec.values()
    for entry, value in values.items():
        if not isinstance(value, dict):
            out[entry] = _grid_column(entry, list(grid[entry]), spec, applied)
            continue
        out[entry] = (pa.string(), grid_cell_text(value))
        keys = dict.fromkeys(k for table in grid[entry] for k in table if k != "label")
        for key in keys:  # every key the group sets in any cell, so all chunks match
            seen = [table[key] for table in grid[entry] if key in table]
            out[key] = _grid_column(key, seen, spec, applied)
    return out


def _grid_column(key: str, seen: list[Any], spec: Spec, applied: Mapping[str, Any]
                 ) -> tuple[pa.DataType, Any]:
    """One grid key's column type (``seen``: all its grid values) and the cell's value
    (``spec``, and its ``applied`` {dotted key: value})."""
    if key.startswith("sweep.perturb."):
        _, _, name, param = key.split(".")
        value = spec.sweep.perturb.get(name, {}).get(param)
        if all(_is_number(v) for v in seen):
            return pa.float64(), None if value is None else float(value)
        if all(isinstance(v, list | tuple) for v in seen):
            return pa.list_(pa.float64()), None if value is None else [float(v) for v in value]
        return pa.string(), None if value is None else grid_cell_text(value)
    kind = lookup(key).kind
    value = applied[key]
    if kind == "numbers":  # a number, or a list (one per joint): float64 or list<float64>
        if all(_is_number(v) for v in seen):
            return pa.float64(), None if value is None else float(_one(value))
        if value is None:
            return pa.list_(pa.float64()), None
        width = max(len(v) for v in seen if isinstance(v, list | tuple))
        items = [float(v) for v in value] if isinstance(value, list | tuple) else (
            [float(value)] * width)
        return pa.list_(pa.float64()), items
    if value is None:
        return _ARROW_TYPES[kind], None
    if kind == "vector":
        return _ARROW_TYPES[kind], [float(v) for v in value]
    return _ARROW_TYPES[kind], value


def _one(value: Any) -> Any:
    """A number given as itself or as a list of one."""
    return value[0] if isinstance(value, list | tuple) else value


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


#: Arrow type of a grid column by its spec key's kind (``flatcli.spec.keys.Key.kind``).
_ARROW_TYPES: dict[str, pa.DataType] = {
    "float": pa.float64(), "int": pa.int64(), "bool": pa.bool_(), "str": pa.string(),
    "choice": pa.string(), "vector": pa.list_(pa.float64()),
}
