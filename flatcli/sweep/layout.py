"""A sweep's layout, from its spec alone: grid cells, their plans, and chunks of trials.

Cells are the Cartesian product of ``[sweep.grid]`` (in the order the keys are written), each
cell runs ``sweep.trials`` trials, and trial ids are global (``trial = cell * trials + i``).
Chunks are runs of consecutive trials of one cell; their size comes from the spec alone, so
a resume with other ``--workers`` finds the same chunks.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from flatcli.core.chainplan import Plan
from flatcli.core.model import FlatcliError
from flatcli.core.simulate import Scenario
from flatcli.experiment import plan_from, plant_from, scenario_from
from flatcli.spec import PERTURB_TARGETS, Spec, SpecError, grid_overrides

#: Default chunk sizes: about CHUNKS_TARGET chunks per sweep, each of CHUNK_MIN to CHUNK_MAX
#: trials (from the spec alone, so that a resume with other --workers finds the same chunks).
CHUNKS_TARGET = 16
CHUNK_MIN = 250
CHUNK_MAX = 1000


def default_chunk(total: int, per_cell: int) -> int:
    """Trials per chunk when the spec does not say: enough chunks to keep every core busy
    and to lose little to an interruption, few enough to keep per-chunk overhead small."""
    return min(per_cell, max(CHUNK_MIN, min(CHUNK_MAX, math.ceil(total / CHUNKS_TARGET))))


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
        return list(self.spec.sweep.grid)

    @property
    def perturbed(self) -> list[str]:
        """Perturbed quantities, in canonical order."""
        return [name for name in PERTURB_TARGETS if name in self.spec.sweep.perturb]


def layout(spec: Spec) -> Layout:
    """Expand the grid and plan every cell (SpecError naming the cell if one cannot run)."""
    grid = spec.sweep.grid
    keys = list(grid)
    plans: dict[Any, Plan] = {}
    cells = []
    for index, combo in enumerate(itertools.product(*(grid[k] for k in keys))):
        values = dict(zip(keys, combo, strict=True))
        try:
            applied = cell_spec(spec, values)
            if applied.joints != spec.joints:
                raise SpecError(f"the robot has {applied.joints} joints, the sweep's [robot] "
                                f"{spec.joints}: one sweep studies one number of joints")
            # cells that differ only outside [robot] and [plan] share one plan
            key = (applied.robot, applied.plan)
            if key not in plans:
                plans[key] = plan_from(applied)
            scenario = scenario_from(applied, plans[key]).prepared()
            plant_from(applied)
        except FlatcliError as exc:
            raise SpecError(f"sweep.grid cell {index} ({grid_label(values)}): {exc}") from None
        cells.append(Cell(index, values, applied, scenario))
    trials = spec.sweep.trials
    chunk = spec.sweep.chunk or default_chunk(trials * len(cells), trials)
    return Layout(spec, tuple(cells), trials, chunk)


def cell_spec(spec: Spec, values: Mapping[str, Any]) -> Spec:
    """The spec of one grid cell: the sweep's spec with the cell's grid values applied."""
    overrides: dict[str, Any] = {}
    for key, value in values.items():
        overrides.update(grid_overrides(key, value))
    return spec.with_overrides(overrides)
