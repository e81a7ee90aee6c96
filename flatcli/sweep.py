"""Monte Carlo sweeps: grid cells x random perturbations -> chunks of trials -> results.

The layout of a sweep depends on its spec only: cells are the Cartesian product of
``[sweep.grid]`` (in the order the keys are written), each cell runs ``sweep.trials`` trials,
and trial ids are global (``trial = cell * trials + i``). Chunks are runs of consecutive trials
of one cell. Every random number of trial ``i`` comes from its own stream
``SeedSequence(sweep.seed, spawn_key=(i, slot))``, so a trial's result does not depend on the
chunk size, the number of workers, the executor, the order in which chunks finish, or a
resume in between.

Perturbations: each trial draws 17 uniform variates from its perturbation stream, one fixed
position per perturbable component (see ``PERTURB_SLOTS``), and transforms those it needs
(uniform: low + (high - low) u; normal: mean + std * Phi^-1(u)). So adding or removing one
perturbation never changes the values another one draws.
"""

from __future__ import annotations

import itertools
import json
import math
import resource
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray
from scipy.special import ndtri

from flatcli.core.metrics import METRIC_NAMES, STATUS_NAMES, describe_status
from flatcli.core.model import FlatcliError
from flatcli.core.planning import FlatPlan
from flatcli.core.simulate import Scenario, Trials, simulate
from flatcli.executors import make_executor
from flatcli.experiment import (
    STREAM_NOISE,
    STREAM_PERTURB,
    plan_from,
    plant_from,
    scenario_from,
    trial_stream,
)
from flatcli.report import Progress, summarize_trials, summary_markdown
from flatcli.spec import PERTURB_TARGETS, Spec, SpecError, grid_overrides, resolve
from flatcli.storage import (
    atomic_path,
    read_provenance,
    run_record,
    to_jsonable,
    versions,
    write_json,
    write_parquet,
    write_table,
    write_text,
)

Array = NDArray[np.float64]

#: Default chunk sizes: about CHUNKS_TARGET chunks per sweep, each of CHUNK_MIN to CHUNK_MAX
#: trials (from the spec alone, so that a resume with other --workers finds the same chunks).
CHUNKS_TARGET = 16
CHUNK_MIN = 250
CHUNK_MAX = 1000


def default_chunk(total: int, per_cell: int) -> int:
    """Trials per chunk when the spec does not say: enough chunks to keep every core busy
    and to lose little to an interruption, few enough to keep per-chunk overhead small."""
    return min(per_cell, max(CHUNK_MIN, min(CHUNK_MAX, math.ceil(total / CHUNKS_TARGET))))

#: Position of each perturbable component among a trial's uniform variates.
PERTURB_SLOTS: dict[str, tuple[int, ...]] = {
    "initial": (0, 1, 2),
    "initial_rate": (3,),
    "mass": (4, 5, 6),
    "inertia": (7, 8, 9),
    "length": (10, 11, 12),
    "com": (13, 14, 15),
    "momentum": (16,),
}
N_VARIATES = 17

STATUS_ERROR = STATUS_NAMES.index("error")


def perturbation_columns(name: str) -> list[str]:
    """Column names of the realised values of a perturbed quantity."""
    return [name] if len(PERTURB_SLOTS[name]) == 1 else [f"{name}_{i}" for i in range(3)]


@dataclass(frozen=True)
class Cell:
    """One grid cell: its index, its grid values, the spec with them applied, and its scenario.

    The scenario (plan and reference tables) is computed once, here, and shipped with every
    chunk of the cell, so every worker tracks the very same reference.
    """

    index: int
    values: dict[str, Any]
    spec: Spec
    scenario: Scenario

    def label(self) -> str:
        return grid_label(self.values)


def grid_label(values: Mapping[str, Any]) -> str:
    """A cell's grid values as text."""
    return ", ".join(f"{k} = {_show(v)}" for k, v in values.items()) or "(no grid)"


def _show(value: Any) -> str:
    if isinstance(value, dict):
        if "label" in value:
            return str(value["label"])
        return "{" + ", ".join(f"{k} = {_show(v)}" for k, v in value.items()) + "}"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


@dataclass(frozen=True)
class Chunk:
    """Trials [start, stop) of one cell; ``name`` is its file name under trials/."""

    cell: int
    start: int
    stop: int

    @property
    def name(self) -> str:
        return f"chunk-{self.start:012d}.parquet"

    @property
    def size(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class Layout:
    """Cells and chunks of a sweep, from its spec alone."""

    spec: Spec
    cells: tuple[Cell, ...]
    trials_per_cell: int
    chunk_size: int

    @property
    def total(self) -> int:
        return len(self.cells) * self.trials_per_cell

    def chunks(self) -> Iterator[Chunk]:
        for cell in self.cells:
            first = cell.index * self.trials_per_cell
            for start in range(first, first + self.trials_per_cell, self.chunk_size):
                yield Chunk(cell.index, start, min(start + self.chunk_size,
                                                   first + self.trials_per_cell))

    @property
    def grid_keys(self) -> list[str]:
        return list(self.spec.get("sweep.grid"))

    @property
    def perturbed(self) -> list[str]:
        """Perturbed quantities, in canonical order."""
        configured = self.spec.get("sweep.perturb")
        return [name for name in PERTURB_SLOTS if name in configured]


def layout(spec: Spec) -> Layout:
    """Expand the grid and plan every cell (SpecError naming the cell if one cannot run)."""
    grid: dict[str, list[Any]] = spec.get("sweep.grid")
    keys = list(grid)
    plans: dict[str, FlatPlan] = {}
    cells = []
    for index, combo in enumerate(itertools.product(*(grid[k] for k in keys))):
        values = dict(zip(keys, combo, strict=True))
        applied = cell_spec(spec, values)
        try:
            # cells that differ only outside [robot] and [plan] share one plan
            key = json.dumps(to_jsonable([applied.tree["robot"], applied.tree["plan"]]),
                             sort_keys=True)
            if key not in plans:
                plans[key] = plan_from(applied)
            scenario = scenario_from(applied, plans[key]).prepared()
            plant_from(applied)
        except FlatcliError as exc:
            raise SpecError(f"sweep.grid cell {index} ({grid_label(values)}): {exc}") from None
        cells.append(Cell(index, values, applied, scenario))
    trials = int(spec.get("sweep.trials"))
    chunk = spec.get("sweep.chunk") or default_chunk(trials * len(cells), trials)
    return Layout(spec, tuple(cells), trials, int(chunk))


def cell_spec(spec: Spec, values: Mapping[str, Any]) -> Spec:
    """The spec of one grid cell: the sweep's spec with the cell's grid values applied."""
    overrides: dict[str, Any] = {}
    for key, value in values.items():
        overrides.update(grid_overrides(key, value))
    applied = spec.with_overrides(
        {k: v for k, v in overrides.items() if not k.startswith("sweep.perturb.")}
    )
    for key, value in overrides.items():
        if key.startswith("sweep.perturb."):
            _, _, name, param = key.split(".")
            table = applied.tree["sweep"]["perturb"]
            table[name] = {**table[name], param: value}
    return applied


def draw_perturbations(
    perturb: Mapping[str, Mapping[str, Any]], nominal: Mapping[str, Array], seed: int,
    trials: Sequence[int],
) -> dict[str, Array]:
    """Realised values of every perturbed quantity for the given trial ids.

    Parameters
    ----------
    perturb : the ``[sweep.perturb]`` table (validated)
    nominal : nominal value of each perturbable quantity, (3,) or (1,)
    seed : sweep.seed
    trials : trial ids (N)

    Returns
    -------
    {name: (N, 3) or (N, 1)} realised values
    """
    u = np.empty((len(trials), N_VARIATES))
    for row, trial in enumerate(trials):
        u[row] = trial_stream(seed, trial, STREAM_PERTURB).random(N_VARIATES)
    out: dict[str, Array] = {}
    for name, slots in PERTURB_SLOTS.items():
        if name not in perturb:
            continue
        table = perturb[name]
        draws = u[:, list(slots)]
        if table["dist"] == "uniform":
            low = np.asarray(table["low"], dtype=float)
            high = np.asarray(table["high"], dtype=float)
            sample = low + (high - low) * draws
        else:
            std = np.asarray(table["std"], dtype=float)
            mean = np.asarray(table.get("mean", 0.0), dtype=float)
            sample = mean + std * ndtri(draws)
        base = nominal[name]
        out[name] = base * (1.0 + sample) if table.get("relative") else base + sample
    return out


def nominal_values(spec: Spec) -> dict[str, Array]:
    """Nominal value of every perturbable quantity of a (cell's) spec."""
    plant = plant_from(spec)
    return {
        "initial": np.asarray(spec.get("track.initial"), dtype=float),
        "initial_rate": np.array([spec.get("track.initial_rate")]),
        "mass": np.asarray(plant.mass),
        "inertia": np.asarray(plant.inertia),
        "length": np.asarray(plant.length),
        "com": np.asarray(plant.com),
        "momentum": np.array([spec.get("plant.momentum")]),
    }


def invalid_plants(links: Array) -> list[str]:
    """For (N, 12) plants: why each is not a valid robot, or '' if it is."""
    bad = ~(np.isfinite(links).all(axis=1) & (links[:, :9] > 0).all(axis=1))
    reasons = [""] * len(links)
    for row in np.flatnonzero(bad):
        values = links[row]
        if not np.all(np.isfinite(values)):
            reasons[row] = "perturbed plant has non-finite parameters"
            continue
        first = int(np.flatnonzero(~(values[:9] > 0))[0])
        name = ("mass", "inertia", "length")[first // 3]
        reasons[row] = f"perturbed plant.{name}[{first % 3}] = {values[first]:.6g} is not > 0"
    return reasons


def run_chunk(cell: Cell, chunk: Chunk) -> ChunkResult:
    """Simulate one chunk; return its columns (a worker's whole job; picklable in and out).

    A trial whose perturbed plant is not a valid robot is recorded as ``error`` with the
    reason; the others are simulated. Nothing here writes files.
    """
    return _simulate_chunk(cell, chunk, time.perf_counter())


def _simulate_chunk(cell: Cell, chunk: Chunk, started: float) -> ChunkResult:
    spec = cell.spec
    scenario = cell.scenario
    ids = np.arange(chunk.start, chunk.stop)
    seed = int(spec.get("sweep.seed"))
    perturb = spec.get("sweep.perturb")
    nominal = nominal_values(spec)
    drawn = draw_perturbations(perturb, nominal, seed, ids.tolist())
    value = {name: np.broadcast_to(drawn.get(name, nominal[name]), (len(ids), nominal[name].size))
             for name in PERTURB_SLOTS}
    links = np.hstack([value["mass"], value["inertia"], value["length"], value["com"]])
    initial = np.hstack([value["initial"], value["initial_rate"]])
    momentum = value["momentum"][:, 0]
    reasons = invalid_plants(links)
    valid = np.array([not r for r in reasons], dtype=bool)
    std = float(spec.get("track.sensor_noise"))
    noise = None
    if std > 0:
        noise = np.stack([std * trial_stream(seed, int(t), STREAM_NOISE).standard_normal(
            (scenario.n_steps, 3)) for t in ids[valid]]) if valid.any() else None
    metrics = np.full((len(ids), len(METRIC_NAMES)), np.nan)
    status = np.full(len(ids), STATUS_ERROR, dtype=np.int64)
    event = np.full(len(ids), np.nan)
    if valid.any():
        trials = Trials(np.ascontiguousarray(links[valid]), np.ascontiguousarray(momentum[valid]),
                        np.ascontiguousarray(initial[valid]), noise)
        outcome = simulate(scenario, trials, spec.get("track.integrator"))
        metrics[valid] = outcome.metrics
        status[valid] = outcome.status
        event[valid] = outcome.event_time
    status_names = []
    reason_texts = []
    for i in range(len(ids)):
        if not valid[i]:
            status_names.append("error")
            reason_texts.append(reasons[i])
            continue
        name, reason = describe_status(int(status[i]), float(event[i]), metrics[i],
                                       scenario.singular_threshold, scenario.divergence_bound)
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
    columns["singular_hits"] = np.nan_to_num(metrics[:, METRIC_NAMES.index("singular_hits")],
                                             nan=-1).astype(np.int64)
    columns["status"] = pa.array(status_names, type=pa.string())
    columns["reason"] = pa.array(reason_texts, type=pa.string())
    return ChunkResult(pa.table(columns), time.perf_counter() - started)


@dataclass(frozen=True)
class ChunkResult:
    """A finished chunk: one row per trial (the columns of trials.parquet), and its time."""

    table: pa.Table
    seconds: float

    def first_failure(self) -> tuple[int, str] | None:
        """The first trial whose status is error or diverged, for --fail-fast."""
        status = self.table.column("status").to_pylist()
        for i, value in enumerate(status):
            if value in ("error", "diverged"):
                trial = self.table.column("trial")[i].as_py()
                return int(trial), f"{value}: {self.table.column('reason')[i].as_py()}"
        return None


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


def rerun_spec(layout_: Layout, row: Mapping[str, Any]) -> Spec:
    """A plain track spec that re-runs one trial of a sweep exactly."""
    cell = layout_.cells[int(row["cell"])]
    tree = {k: v for k, v in cell.spec.tree.items() if k != "sweep"}
    overrides: dict[str, Any] = {}
    for name in layout_.perturbed:
        cols = perturbation_columns(name)
        target = PERTURB_TARGETS[name]
        vals = [float(row[c]) for c in cols]
        overrides[target] = vals[0] if len(vals) == 1 else vals
    overrides["track.seed"] = int(layout_.spec.get("sweep.seed"))
    overrides["track.trial"] = int(row["trial"])
    overrides["name"] = f"{layout_.spec.name}-trial-{int(row['trial'])}"
    return resolve(_without_none(tree), overrides)


def _without_none(tree: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in tree.items():
        if isinstance(v, Mapping):
            out[k] = _without_none(v)
        elif v is not None:
            out[k] = v
    return out


def spec_toml(spec: Spec) -> str:
    """A spec as TOML (floats in repr, so every value round-trips exactly)."""
    lines: list[str] = []

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "inf" if v == math.inf else ("-inf" if v == -math.inf else repr(v))
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, str):
            return json.dumps(v)
        return str(v)

    tree = spec.tree
    for k, v in tree.items():
        if not isinstance(v, dict) and v is not None:
            lines.append(f"{k} = {value(v)}")

    def emit(prefix: str, table: Mapping[str, Any]) -> None:
        scalars = [(k, v) for k, v in table.items() if not isinstance(v, dict) and v is not None]
        subs = [(k, v) for k, v in table.items() if isinstance(v, dict)]
        if scalars:
            lines.append(f"\n[{prefix}]")
            lines.extend(f"{k} = {value(v)}" for k, v in scalars)
        for k, v in subs:
            emit(f"{prefix}.{k}", v)

    for k, v in tree.items():
        if isinstance(v, dict) and k != "sweep":
            emit(k, v)
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------
# Running a sweep into a directory: chunks written atomically, resume, final tables.

MANIFEST = "sweep.json"
TRIALS_DIR = "trials"


class FailFastError(RuntimeError):
    """--fail-fast met a failing trial (finished chunks are kept; exit status 1)."""


@dataclass(frozen=True)
class SweepResult:
    """What a finished sweep wrote and measured."""

    directory: Path
    layout: Layout
    simulated: int  # trials simulated by this invocation (the rest were resumed)
    wall_seconds: float
    summary_text: str


def check_directory(directory: Path, spec: Spec, force: bool) -> None:
    """Refuse a directory holding a different sweep (unless force); never mix two specs."""
    manifest = directory / MANIFEST
    if not manifest.exists():
        return
    try:
        previous = json.loads(manifest.read_text())["digest"]
    except (OSError, ValueError, KeyError):
        previous = None
    if previous != spec.digest() and not force:
        raise SpecError(
            f"{directory} holds a sweep of a different spec (spec hash {str(previous)[:12]} "
            f"vs {spec.digest()[:12]}); use --force to start over there, or another --out"
        )


def _clear(directory: Path) -> None:
    for name in (MANIFEST, "trials.parquet", "summary.parquet", "summary.md", "run.json"):
        (directory / name).unlink(missing_ok=True)
    trials = directory / TRIALS_DIR
    if trials.exists():
        for path in trials.iterdir():
            path.unlink()


def finished_chunks(directory: Path, digest: str) -> set[str]:
    """Names of the complete chunk files of this spec in a directory; stray temp files go."""
    trials = directory / TRIALS_DIR
    done: set[str] = set()
    if not trials.exists():
        return done
    for path in trials.iterdir():
        if path.name.endswith(".tmp"):
            path.unlink(missing_ok=True)
        elif path.suffix == ".parquet":
            try:
                if read_provenance(path).get("digest") == digest:
                    done.add(path.name)
            except (OSError, ValueError, pa.ArrowException):
                path.unlink(missing_ok=True)
    return done


def run_sweep(
    spec: Spec,
    directory: Path,
    executor_kind: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    fail_fast: bool = False,
    progress: Progress | None = None,
) -> SweepResult:
    """Run (or resume) a sweep into ``directory``; write trials, summary and run record.

    Everything that can be refused is checked before anything is written: the spec and
    every grid cell, the directory (a different spec there is refused), the executor.
    """
    started = time.perf_counter()
    lay = layout(spec)
    check_directory(directory, spec, force)
    executor = make_executor(executor_kind, workers, scheduler)
    try:
        if force:
            _clear(directory)
        digest = spec.digest()
        write_json(directory / MANIFEST, {
            "digest": digest, "spec": spec.tree, "cells": len(lay.cells),
            "trials_per_cell": lay.trials_per_cell, "chunk": lay.chunk_size,
        })
        done = finished_chunks(directory, digest)
        todo = [c for c in lay.chunks() if c.name not in done]
        resumed = lay.total - sum(c.size for c in todo)
        provenance = {"digest": digest, "spec": spec.tree, "versions": versions()}
        if progress is not None:
            progress.start(lay.total, resumed, executor.description)
        if todo and executor_kind == "local":
            _warm_up(lay)  # load the kernel once here; forked workers inherit it
        setup = time.perf_counter() - started
        tasks = ((c, (lay.cells[c.cell], c)) for c in todo)
        compute = 0.0
        try:
            for chunk, result in executor.run(run_chunk, tasks):
                compute += result.seconds
                write_table(directory / TRIALS_DIR / chunk.name, result.table,
                            {**provenance, "chunk": [chunk.start, chunk.stop]})
                if progress is not None:
                    progress.advance(chunk.size)
                failure = result.first_failure() if fail_fast else None
                if failure is not None:
                    raise FailFastError(f"--fail-fast: trial {failure[0]} {failure[1]} "
                                        f"(finished chunks kept in {directory}/{TRIALS_DIR})")
        finally:
            if progress is not None:
                progress.close()
        simulated = lay.total - resumed
        running = time.perf_counter() - started - setup
    finally:
        executor.close()
    summary_text = finish_sweep(directory, lay, provenance, started, {
        "setup_seconds": setup,
        "simulate_seconds": running,
        "simulated_trials": simulated,
        "resumed_trials": resumed,

        "compute_seconds": compute,
        "workers": executor.workers,
        "executor": executor.description,
    })
    return SweepResult(directory, lay, simulated, time.perf_counter() - started, summary_text)


def _warm_up(lay: Layout) -> None:
    cell = lay.cells[0]
    _simulate_chunk(cell, Chunk(cell.index, 0, 1), time.perf_counter())


def peak_rss_mib() -> dict[str, float]:
    """Peak resident memory of this process and of its largest child process [MiB]."""
    self_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    child_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return {"main": self_kib / 1024, "largest_child": child_kib / 1024}


def assemble_trials(directory: Path, lay: Layout, provenance: Mapping[str, Any]) -> Path:
    """Concatenate the chunk files, in trial order, into trials.parquet (streamed)."""
    target = directory / "trials.parquet"
    meta = {b"flatcli": json.dumps(to_jsonable(provenance), sort_keys=True).encode()}
    writer = None
    with atomic_path(target) as tmp:
        try:
            for chunk in lay.chunks():
                table = pq.read_table(directory / TRIALS_DIR / chunk.name)
                table = table.replace_schema_metadata(meta)
                if writer is None:
                    writer = pq.ParquetWriter(tmp, table.schema)
                writer.write_table(table.cast(writer.schema))
        finally:
            if writer is not None:
                writer.close()
    return target


def finish_sweep(directory: Path, lay: Layout, provenance: Mapping[str, Any], started: float,
                 timing: Mapping[str, Any]) -> str:
    """trials.parquet, summary.parquet, summary.md and run.json from the chunk files.

    ``timing`` gains the end-to-end figures: ``wall_seconds`` from ``started`` (a
    perf_counter time) to the summary, ``trials_per_second`` over it, and
    ``steady_trials_per_second`` over all but the one-time start-up (``setup_seconds``:
    planning the cells, loading the compiled kernel): chunks and final tables.
    """
    finishing = time.perf_counter()
    trials_path = assemble_trials(directory, lay, provenance)
    columns = ["cell", "status", "singular_hits", *METRIC_NAMES]
    frame = pq.read_table(trials_path, columns=columns).to_pandas()
    cells = {c.index: {k: grid_cell_text(v) for k, v in c.values.items()} for c in lay.cells}
    summary = summarize_trials(frame, cells)
    write_parquet(directory / "summary.parquet", summary, provenance)
    text = summary_markdown(summary, lay.grid_keys)
    write_text(directory / "summary.md", text + "\n")
    counts = frame["status"].value_counts().to_dict()
    now = time.perf_counter()
    wall = now - started
    simulated = timing["simulated_trials"]
    warm = wall - timing["setup_seconds"]
    timing = {**timing, "finish_seconds": now - finishing, "wall_seconds": wall,
              "trials_per_second": simulated / wall,
              "steady_trials_per_second": simulated / warm if warm > 0 else None,
              "peak_rss_mib": peak_rss_mib()}
    write_json(directory / "run.json", run_record(
        "sweep", lay.spec.tree, digest=lay.spec.digest(), cells=len(lay.cells),
        trials=lay.total, chunk=lay.chunk_size, status_counts=counts, timing=timing,
    ))
    return text
