"""A sweep's layout from its spec (flatcli/montecarlo/layout.py)."""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from typing import Any

import pytest

from flatcli.montecarlo import cell_spec, grid_label, layout
from flatcli.montecarlo.layout import (
    CHUNK_MAX,
    CHUNK_MIN,
    CHUNKS_PER_CELL,
    ID_STRIDE,
    TAIL_PIECE_MIN,
    TAIL_PIECES,
    Chunk,
    cell_keys,
    default_chunk,
    work_pieces,
)
from flatcli.spec import SpecError, resolve

GRID = {"track.dt": [0.001, 0.002], "gains": [{"label": "a", "track.kp": [1, 2]},
                                              {"label": "b", "track.kp": [3, 4]}]}


def sha_key(values: dict[str, object]) -> int:
    """The README's cell key, computed here: the first 32 bits of the SHA-256 of the cell's
    grid values as JSON with sorted keys, compact separators and numbers as floats."""
    text = json.dumps(values, sort_keys=True, separators=(",", ":"))
    return int(hashlib.sha256(text.encode()).hexdigest()[:8], 16)


def test_layout_is_the_cartesian_product_in_written_order() -> None:
    spec = resolve({"sweep": {"trials": 3, "chunk": 2, "grid": GRID}})
    lay = layout(spec)
    assert [c.values["track.dt"] for c in lay.cells] == [0.001, 0.001, 0.002, 0.002]
    assert [c.spec.track.kp for c in lay.cells] == [(1, 2), (3, 4)] * 2
    first = lay.cells[0]
    expected = sha_key({"gains": {"label": "a", "track.kp": [1.0, 2.0]}, "track.dt": 0.001})
    assert first.key == expected
    base = expected * ID_STRIDE
    chunks = list(lay.chunks())
    assert [(c.cell, c.start, c.stop) for c in chunks[:2]] == [(0, base, base + 2),
                                                              (0, base + 2, base + 3)]
    assert chunks[0].name == f"chunk-{expected:010d}-000000000.parquet"
    assert chunks[1].name == f"chunk-{expected:010d}-000000002.parquet"
    assert chunks[2].cell == 1 and chunks[2].start == lay.cells[1].key * ID_STRIDE
    assert lay.total == 12


def test_a_sweep_without_a_grid_numbers_its_trials_from_0() -> None:
    lay = layout(resolve({"sweep": {"trials": 5, "chunk": 2}}))
    assert [(c.start, c.stop) for c in lay.chunks()] == [(0, 2), (2, 4), (4, 5)]


def test_adding_or_removing_grid_values_keeps_every_other_cells_ids_and_digest() -> None:
    small = layout(resolve({"sweep": {"trials": 4, "grid": {"track.dt": [0.001, 0.002]}}}))
    more = layout(resolve({"sweep": {"trials": 4, "grid": {
        "track.dt": [0.0005, 0.001, 0.004, 0.002]}}}))
    fewer = layout(resolve({"sweep": {"trials": 4, "grid": {"track.dt": [0.002]}}}))
    by_value = {c.values["track.dt"]: c for c in more.cells}
    for cell in (*small.cells, *fewer.cells):
        twin = by_value[cell.values["track.dt"]]
        assert (twin.key, twin.digest) == (cell.key, cell.digest)
        assert [c.name for c in small.cell_chunks(cell)] == [c.name for c in
                                                              more.cell_chunks(twin)]
    # the key is the grid values', not their position or their spelling (2 and 2.0)
    assert cell_keys([{"x": 2}]) == cell_keys([{"x": 2.0}]) == [sha_key({"x": 2.0})]
    # another seed is another computation, with the same ids
    reseeded = layout(resolve({"sweep": {"trials": 4, "seed": 9, "grid": {
        "track.dt": [0.001, 0.002]}}}))
    assert [c.key for c in reseeded.cells] == [c.key for c in small.cells]
    assert all(a.digest != b.digest for a, b in zip(reseeded.cells, small.cells, strict=True))


def test_colliding_cell_keys_are_separated_whatever_the_order() -> None:
    # x = 30622 and x = 61955 share the first 32 bits of their digests (found by trying
    # x = 0, 1, 2, ... until two collided); the smaller full digest keeps the key, the
    # other takes the next one, in whichever order the grid lists them
    a, b = {"x": 30622.0}, {"x": 61955.0}
    assert sha_key(a) == sha_key(b)
    full = {k: hashlib.sha256(json.dumps(v, sort_keys=True, separators=(",", ":"))
                              .encode()).hexdigest() for k, v in (("a", a), ("b", b))}
    first, second = (a, b) if full["a"] < full["b"] else (b, a)
    expected = {json.dumps(first): sha_key(a), json.dumps(second): sha_key(a) + 1}
    for cells in ([a, b], [b, a], [b, {"x": 1.0}, a]):
        keys = cell_keys(cells)
        assert len(set(keys)) == len(cells)
        for cell, key in zip(cells, keys, strict=True):
            if cell in (a, b):
                assert key == expected[json.dumps(cell)]


def test_default_chunks_come_from_the_cell_alone() -> None:
    assert default_chunk(8000) == 8000 // 16  # about 16 chunks per cell
    assert default_chunk(100) == 100  # never more than a cell
    assert default_chunk(10**6) == CHUNK_MAX
    assert default_chunk(2000) == CHUNK_MIN


def test_a_cell_spec_applies_groups_and_perturbation_parameters() -> None:
    spec = resolve({"sweep": {"perturb": {"initial": {"dist": "normal", "std": 0.1}}}})
    cell = cell_spec(spec, {"sweep.perturb.initial.std": 0.3,
                            "gains": {"label": "x", "track.kv": [5, 6]}})
    assert cell.track.kv == (5.0, 6.0)
    assert cell.sweep.perturb["initial"]["std"] == 0.3
    assert grid_label({"track.dt": 0.002, "gains": {"label": "x"}}) == "track.dt = 0.002, gains = x"


def test_a_cell_that_cannot_run_is_named() -> None:
    spec = resolve({"sweep": {"grid": {"plan.start_rate": [0.1, 0.0]}}})
    with pytest.raises(SpecError, match=r"sweep.grid cell 1 \(plan.start_rate = 0\)"):
        layout(spec)


@pytest.mark.parametrize("per_cell", [4001, 8001, 8015, 12_345, 15_999, 16_000])
def test_a_default_chunk_rounds_up_so_a_cell_has_at_most_16_chunks(per_cell: int) -> None:
    # where 1/16 of the cell is not a whole number and the size is not clamped: rounding down
    # would make a 17th chunk of a few trials
    chunk = default_chunk(per_cell)
    assert CHUNK_MIN <= chunk <= CHUNK_MAX
    assert math.ceil(per_cell / chunk) <= CHUNKS_PER_CELL
    assert chunk == math.ceil(per_cell / CHUNKS_PER_CELL)


@pytest.mark.parametrize("per_cell", [1, 249, 250, 251, 3999, 16_001, 10**6])
def test_a_default_chunk_stays_within_its_bounds_and_the_cell(per_cell: int) -> None:
    chunk = default_chunk(per_cell)
    assert chunk == min(per_cell, max(CHUNK_MIN, min(CHUNK_MAX, math.ceil(per_cell / 16))))
    assert chunk <= per_cell and (chunk >= CHUNK_MIN or chunk == per_cell)
    assert chunk <= CHUNK_MAX


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
@pytest.mark.parametrize("sizes", [[625] * 16, [250, 250, 250, 250], [60, 60], [7, 24, 101],
                                   [1000, 999, 3]])
def test_work_pieces_tile_every_chunk_and_cut_only_the_last_ones(workers: int,
                                                                 sizes: list[int]) -> None:
    starts = [sum(sizes[:k]) for k in range(len(sizes))]
    todo = [Chunk(k % 2, a, a + n) for k, (a, n) in enumerate(zip(starts, sizes, strict=True))]
    pieces = work_pieces(todo, workers)
    # every chunk once, in order, its pieces consecutive and covering it exactly
    assert [c for c, _ in pieces] == sorted((c for c, _ in pieces), key=todo.index)
    for chunk in todo:
        mine = [p for c, p in pieces if c == chunk]
        assert mine[0].start == chunk.start and mine[-1].stop == chunk.stop
        assert all(a.stop == b.start for a, b in itertools.pairwise(mine))
        assert all(p.cell == chunk.cell and p.size >= 1 for p in mine)
        last = todo.index(chunk) >= len(todo) - workers
        if workers == 1 or not last:
            assert mine == [chunk]  # whole
        else:  # cut: as many pieces as allowed, none below the minimum unless it is whole
            assert len(mine) == max(1, min(TAIL_PIECES, chunk.size // TAIL_PIECE_MIN))
            assert len(mine) == 1 or min(p.size for p in mine) >= TAIL_PIECE_MIN
            assert max(p.size for p in mine) - min(p.size for p in mine) <= 1


def test_the_cells_cost_linear_time_and_say_how_their_planning_goes(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Each cell's spec holds the whole grid: checking it again per cell made N cells cost
    O(N^2) (1,000 cells: 48 s). The grid is checked once, with the sweep's spec; the cells
    report their progress (done, total) from 0 to N."""
    from flatcli.spec import sweeps

    calls: list[str] = []
    original = sweeps.validate_grid_entry

    def counted(*args: Any, **kwargs: Any) -> None:
        calls.append(args[1])
        original(*args, **kwargs)

    monkeypatch.setattr(sweeps, "validate_grid_entry", counted)
    spec = resolve({"sweep": {"trials": 1, "grid": {
        "plan.goal_rate": [0.5 + 1e-3 * i for i in range(12)], "track.kp": [[100, 110],
                                                                            [90, 100]]}}})
    assert calls == ["plan.goal_rate", "track.kp"]
    seen: list[tuple[int, int]] = []
    lay = layout(spec, 1, lambda done, total: seen.append((done, total)))
    assert len(lay.cells) == 24 and calls == ["plan.goal_rate", "track.kp"]
    assert seen == [(i, 24) for i in range(25)]
    # each cell's spec is still checked: a grid value valid alone but not in its cell
    bad = resolve({"sweep": {"trials": 1, "grid": {"plan.duration": [2.0, 0.001]}}})
    with pytest.raises(SpecError, match=r"sweep\.grid cell 1 \(plan\.duration = 0\.001\)"):
        layout(bad, 1)


def test_the_mpc_is_replanned_per_torque_limit_of_the_dynamic_plant() -> None:
    """Cells that share a plan but not the torque limit get each its own MPC reference: the
    cubic (32.6 N m, tests/test_experiment.py's sympy referee) where the limit kept is above
    it or absent (the spec's plan object itself), a re-plan where below; the kinematic plant
    ignores the limit."""
    spec = resolve({"track": {"controller": "mpc"}, "plant": {"model": "dynamic"},
                    "sweep": {"trials": 2, "grid": {"plant.torque_limit": [math.inf, 100.0,
                                                                            10.0, 5.0]}}})
    lay = layout(spec)
    assert [c.replanned for c in lay.cells] == [False, False, True, True]
    cubic, replan = lay.cells[0].scenario.plan, lay.cells[2].scenario.plan
    assert lay.cells[1].scenario.plan is cubic and lay.cells[3].scenario.plan is not cubic
    assert replan is not cubic
    kinematic = layout(resolve({"track": {"controller": "mpc"}, "sweep": {
        "trials": 2, "grid": {"plant.torque_limit": [math.inf, 10.0]}}}))
    assert [c.replanned for c in kinematic.cells] == [False, False]
