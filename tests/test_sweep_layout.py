"""A sweep's layout from its spec (flatcli/sweep/layout.py)."""

from __future__ import annotations

import pytest

from flatcli.spec import SpecError, resolve
from flatcli.sweep import cell_spec, grid_label, layout
from flatcli.sweep.layout import CHUNK_MAX, CHUNK_MIN, default_chunk


def test_layout_is_the_cartesian_product_in_written_order() -> None:
    spec = resolve({"sweep": {"trials": 3, "chunk": 2, "grid": {
        "track.dt": [0.001, 0.002], "gains": [{"label": "a", "track.kp": [1, 2]},
                                              {"label": "b", "track.kp": [3, 4]}]}}})
    lay = layout(spec)
    assert [c.values["track.dt"] for c in lay.cells] == [0.001, 0.001, 0.002, 0.002]
    assert [c.spec.track.kp for c in lay.cells] == [(1, 2), (3, 4)] * 2
    chunks = list(lay.chunks())
    assert [(c.cell, c.start, c.stop) for c in chunks[:3]] == [(0, 0, 2), (0, 2, 3), (1, 3, 5)]
    assert lay.total == 12


def test_default_chunks_come_from_the_spec_alone() -> None:
    assert default_chunk(8000, 2000) == 8000 // 16  # about 16 chunks
    assert default_chunk(100, 100) == 100  # never more than a cell
    assert default_chunk(10**7, 10**6) == CHUNK_MAX
    assert default_chunk(2000, 1000) == CHUNK_MIN


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
