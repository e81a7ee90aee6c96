"""A sweep's layout, from its spec alone: grid cells, their keys and plans, chunks of trials.

Cells are the Cartesian product of ``[sweep.grid]`` (in the order the keys are written), each
cell runs ``sweep.trials`` trials. A cell's *key* comes from its grid values alone (the first
32 bits of the SHA-256 of their canonical JSON; 0 for the one cell of a sweep without a
grid), and trial ids are ``trial = key * ID_STRIDE + i`` for the cell's trials
``i = 0 .. trials - 1``. So adding or removing grid values never renumbers another cell's
trials: a finished cell keeps its ids, its random draws and its chunk files, and a changed
study reuses it. Chunks are runs of consecutive trials of one cell, named by the cell's key
and the first trial's ``i``; their size comes from the cell alone, so a resume with other
``--workers`` or more grid values finds the same chunks.

A cell's *digest* (SHA-256 of its spec without the grid and the name, its key and
``CHUNK_FORMAT``) is what makes two cells the same computation.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from flatcli.core.controllers.settings import settings_of
from flatcli.core.errors import FlatcliError
from flatcli.core.loop.simulate import Scenario
from flatcli.core.plan.planning import Plan
from flatcli.experiment import (
    mpc_kept_limit,
    mpc_kept_torque,
    mpc_reference,
    plan_from,
    plant_from,
    scenario_from,
)
from flatcli.machine import cores
from flatcli.spec import PERTURB_TARGETS, Spec, SpecError, grid_overrides
from flatcli.spec.limits import (
    ID_STRIDE,
    check_sweep,
    output_steps,
    require_finite_plan,
)
from flatcli.storage import to_jsonable

#: Default chunk sizes: about CHUNKS_PER_CELL chunks per cell, each of CHUNK_MIN to CHUNK_MAX
#: trials (from the cell alone, so that a resume with other --workers, or a study with more
#: grid values, finds the same chunks).
CHUNKS_PER_CELL = 16
CHUNK_MIN = 250
CHUNK_MAX = 1000
#: Cell keys are below KEY_SPACE: with ID_STRIDE = 1e9, every trial id fits a signed 64-bit
#: integer.
KEY_SPACE = 2**32
#: Version of what a chunk file holds; a change makes every cell's digest change, so chunks
#: written before are recomputed rather than mixed with new ones.
CHUNK_FORMAT = 2


def default_chunk(per_cell: int) -> int:
    """Trials per chunk when the spec does not say: enough chunks to keep every core busy
    and to lose little to an interruption, few enough to keep per-chunk overhead small."""
    return min(per_cell, max(CHUNK_MIN, min(CHUNK_MAX, math.ceil(per_cell / CHUNKS_PER_CELL))))


def canonical(value: Any) -> Any:
    """A grid value as its cell key sees it: numbers as floats (1 and 1.0 are one value)."""
    if isinstance(value, Mapping):
        return {str(k): canonical(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [canonical(v) for v in value]
    if isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def values_digest(values: Mapping[str, Any]) -> str:
    """SHA-256 of a cell's grid values (canonical JSON, keys sorted)."""
    text = json.dumps(to_jsonable(canonical(values)), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def cell_keys(cells: list[dict[str, Any]]) -> list[int]:
    """The key of each cell (see the module docstring): 0 for the cell of a sweep without a
    grid; else the first 32 bits of its values' digest, where two cells of one grid collide
    the one with the smaller digest keeps it and the other takes the next free key."""
    if cells == [{}]:
        return [0]
    digests = [values_digest(v) for v in cells]
    order = sorted(range(len(cells)), key=lambda i: digests[i])
    keys = [0] * len(cells)
    taken: set[int] = set()
    for i in order:
        key = int(digests[i][:8], 16)
        while key in taken:
            key = (key + 1) % KEY_SPACE
        taken.add(key)
        keys[i] = key
    return keys


#: Grid keys at most whose recorded order ``grid_in_recorded_order`` searches for (7! orders).
ORDER_SEARCH_KEYS = 7


def grid_in_recorded_order(spec: Spec, grid_cells: Sequence[str] | None) -> Spec:
    """``spec`` with its ``[sweep.grid]`` keys in the order that enumerates its cells as
    ``grid_cells`` (a manifest's cell keys, in the order the sweep ran them) lists them.

    A record written before records kept their tables' order holds the grid with its keys
    sorted; the cells of a grid whose keys were not written in alphabetical order then come
    back under other indices. The cell keys come from the values alone, so the order that
    gives the recorded sequence of keys is the sweep's own. ``spec`` as it is when its order
    already gives it, when nothing is recorded, or when no order of at most
    ``ORDER_SEARCH_KEYS`` keys does.
    """
    grid = spec.sweep.grid
    names = list(grid)
    if not grid_cells or len(names) < 2 or len(names) > ORDER_SEARCH_KEYS:
        return spec
    try:
        wanted = [int(k) for k in grid_cells]
    except (TypeError, ValueError):
        return spec
    for order in itertools.permutations(names):
        combos = [dict(zip(order, combo, strict=True))
                  for combo in itertools.product(*(grid[k] for k in order))]
        if cell_keys(combos) == wanted:
            if list(order) == names:
                return spec
            return spec.with_overrides({"sweep.grid": {k: grid[k] for k in order}})
    return spec


def cell_digest(spec: Spec, key: int) -> str:
    """What makes two cells the same computation: the cell's spec (its grid values applied)
    without ``name``, ``sweep.grid`` and the figures' format, its key, and ``CHUNK_FORMAT``."""
    tree = spec.experiment_tree(skip=("name", "sweep.grid"))
    text = json.dumps(to_jsonable({"spec": tree, "key": key, "format": CHUNK_FORMAT}),
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


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
    key: int = 0
    digest: str = ""
    #: the MPC tracks a re-plan of the spec's plan (``experiment.mpc_reference``); None: the
    #: cell's controller is not the MPC
    replanned: bool | None = None

    @property
    def first_trial(self) -> int:
        """The id of the cell's trial 0."""
        return self.key * ID_STRIDE


def family(cell: Cell) -> str:
    """The compiled kernel a cell's trials run, in words: its model and plant
    (``progress.kernel_key``), controller, integrator and joints. Cells of one family run
    the same code, and cost alike per output step (their parameters change the steps)."""
    from flatcli.progress import kernel_key

    return (f"{kernel_key(cell.scenario)}, {cell.scenario.controller} controller, "
            f"{cell.spec.track.integrator}, {cell.spec.joints} joints")


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
    """Trials [start, stop) (ids) of the cell at position ``cell`` of the grid; ``name`` is
    its file name under trials/: the cell's key and the first trial's index in the cell."""

    cell: int
    start: int
    stop: int

    @property
    def name(self) -> str:
        return chunk_name(self.start)

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
            yield from self.cell_chunks(cell)

    def cell_chunks(self, cell: Cell) -> Iterator[Chunk]:
        first = cell.first_trial
        for start in range(first, first + self.trials_per_cell, self.chunk_size):
            yield Chunk(cell.index, start, min(start + self.chunk_size,
                                               first + self.trials_per_cell))

    @property
    def grid_keys(self) -> list[str]:
        return list(self.spec.sweep.grid)

    @property
    def perturbed(self) -> list[str]:
        """Perturbed quantities, in canonical order."""
        return [name for name in PERTURB_TARGETS if name in self.spec.sweep.perturb]


#: The last chunks of a run are computed in pieces: when fewer chunks than workers are left,
#: the idle workers take pieces of the last ones instead of waiting for one worker to finish a
#: whole chunk (up to a chunk's time, 0.3 s for 625 trials of the paper's loop, with one core
#: idle). Each of the last ``workers`` chunks is cut into up to TAIL_PIECES pieces of at least
#: TAIL_PIECE_MIN trials (a piece costs about 4 ms more than its trials, a chunk's set-up:
#: 12 ms for 25 trials of the paper's loop).
TAIL_PIECES = 4
TAIL_PIECE_MIN = 25


def work_pieces(todo: Sequence[Chunk], workers: int) -> list[tuple[Chunk, Chunk]]:
    """(chunk, piece) in the order to compute them: each chunk whole (its piece is itself),
    but with more than one worker each of the last ``workers`` chunks cut into pieces of
    consecutive trials (``TAIL_PIECES``). A chunk's file is written once all its pieces are
    in, joined in order (``ChunkResult.joined``): its rows are those of the whole chunk,
    since a trial's row depends on its cell and id only."""
    if workers < 2:
        return [(c, c) for c in todo]
    tail = max(len(todo) - workers, 0)
    out = [(c, c) for c in todo[:tail]]
    for chunk in todo[tail:]:
        count = max(1, min(TAIL_PIECES, chunk.size // TAIL_PIECE_MIN))
        bounds = [chunk.start + (chunk.size * k) // count for k in range(count + 1)]
        out.extend((chunk, Chunk(chunk.cell, a, b)) for a, b in itertools.pairwise(bounds))
    return out


#: The most shards a sweep may be cut into (``Shard``).
MAX_SHARDS = 100_000


@dataclass(frozen=True)
class Shard:
    """Shard ``index`` of ``count`` (1-based, ``--shard K/N``): the chunks at positions p of
    the layout's ``chunks()`` with p mod count = index - 1 (round robin, so each shard gets
    a share of every cell's cost). The assignment comes from the spec alone, so shards
    started on other machines, at other times, with other --workers, compute disjoint sets
    of chunks that together are the whole study."""

    index: int
    count: int

    def __post_init__(self) -> None:
        if not (1 <= self.count <= MAX_SHARDS and 1 <= self.index <= self.count):
            raise FlatcliError(f"--shard: expected K/N with 1 <= K <= N <= {MAX_SHARDS}, "
                               f"got {self.index}/{self.count}")

    @staticmethod
    def parse(text: str) -> Shard:
        """``K/N`` as a Shard (FlatcliError naming --shard otherwise)."""
        index, slash, count = text.strip().partition("/")
        if not slash or not index.isdigit() or not count.isdigit():
            raise FlatcliError(f"--shard: expected K/N (shard K of N, e.g. 2/8: "
                               f"${{SLURM_ARRAY_TASK_ID}}/8 in an array job 1-8), got {text!r}")
        return Shard(int(index), int(count))

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"

    def chunks(self, lay: Layout) -> list[Chunk]:
        """This shard's chunks of ``lay``, in the layout's order."""
        return [c for p, c in enumerate(lay.chunks()) if p % self.count == self.index - 1]


def chunk_name(start: int) -> str:
    """The file name of the chunk whose first trial is ``start``."""
    key, i = divmod(start, ID_STRIDE)
    return f"chunk-{key:010d}-{i:09d}.parquet"


def layout(spec: Spec, workers: int | None = None,
           progress: Callable[[int, int], None] | None = None) -> Layout:
    """Expand the grid and plan every cell (SpecError naming the cell if one cannot run, or
    the estimate if the cells would not fit in memory or time on ``workers``, default: one
    per core). ``progress(done, total)``: called as the cells are planned (the spec bounds
    their number: ``flatcli.spec.limits.MAX_GRID_CELLS``)."""
    grid = spec.sweep.grid
    names = list(grid)
    combos = [dict(zip(names, combo, strict=True))
              for combo in itertools.product(*(grid[k] for k in names))]
    report = progress if progress is not None else (lambda done, total: None)
    report(0, len(combos))
    specs = []
    for index, values in enumerate(combos):
        try:
            applied = cell_spec(spec, values)
            if applied.joints != spec.joints:
                raise SpecError(f"the robot has {applied.joints} joints, the sweep's [robot] "
                                f"{spec.joints}: one sweep studies one number of joints")
        except FlatcliError as exc:
            raise SpecError(f"sweep.grid cell {index} ({grid_label(values)}): {exc}") from None
        specs.append(applied)
    trials = spec.sweep.trials
    chunk = spec.sweep.chunk or default_chunk(trials)
    check_sweep([output_steps(s) for s in specs], trials, min(chunk, trials),
                workers if workers is not None else cores(), spec.joints)
    plans: dict[Any, Plan] = {}
    references: dict[Any, tuple[Plan, bool | None]] = {}
    cells = []
    for index, (values, applied, key) in enumerate(zip(combos, specs, cell_keys(combos),
                                                       strict=True)):
        try:
            # cells that differ only outside [robot], [plan] and [task] share one plan
            shared = (applied.robot, applied.plan, applied.task)
            if shared not in plans:
                plans[shared] = plan_from(applied)
            # the MPC's reference within its rate and torque limits, once per plan and
            # limits kept (the torque the plan asks depends on the plant)
            torque = mpc_kept_torque(applied)
            tracked = (shared, applied.track.controller, mpc_kept_limit(applied),
                       settings_of(applied.track)["mpc"].margin, torque,
                       applied.plant if math.isfinite(torque) else None)
            if tracked not in references:
                references[tracked] = mpc_reference(applied, plans[shared])
            plan, replanned = references[tracked]
            scenario = scenario_from(applied, plan, replanned).prepared()
            require_finite_plan({"the reference": scenario.reference,
                                 "theta": scenario.theta_reference})
            plant_from(applied)
        except FlatcliError as exc:
            raise SpecError(f"sweep.grid cell {index} ({grid_label(values)}): {exc}") from None
        cells.append(Cell(index, values, applied, scenario, key, cell_digest(applied, key),
                          replanned))
        report(index + 1, len(combos))
    return Layout(spec, tuple(cells), trials, chunk)


def cell_spec(spec: Spec, values: Mapping[str, Any]) -> Spec:
    """The spec of one grid cell: the sweep's spec with the cell's grid values applied."""
    overrides: dict[str, Any] = {}
    for key, value in values.items():
        overrides.update(grid_overrides(key, value))
    return spec.with_overrides(overrides)
