"""Live trial counts (flatcli/montecarlo/tally.py): batches change nothing, forked workers'
counts reach the parent's progress bar, by status."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from small_sweep import SPEC, write_spec

from flatcli.core.loop.simulate import NoiseStreams, Trials, simulate
from flatcli.montecarlo import layout, run_sweep, tally
from flatcli.report import Progress
from flatcli.spec import load_spec


class Recorder(Progress):
    """A quiet-looking Progress that records what the counters told it."""

    def __init__(self) -> None:
        super().__init__("rec", quiet=False, stream=io.StringIO(), interval=1e9)
        self.seen: list[tuple[int, dict[str, int]]] = []

    def live(self, n: int, counts: Any) -> None:
        self.seen.append((n, dict(counts)))
        super().live(n, counts)


@pytest.mark.parametrize(("noise", "controller"), [(0.0, "flat"), (0.001, "flat"),
                                                   (0.001, "mpc")])
def test_counted_batches_give_the_same_outcome(tmp_path: Path, noise: float,
                                               controller: str) -> None:
    """Every field of the outcome, the controller's own columns included (the MPC's were
    dropped by the batches: a sweep with a progress bar wrote them null)."""
    spec = load_spec(write_spec(tmp_path), [f"track.sensor_noise={noise}",
                                            f"track.controller={controller}"])
    cell = layout(spec).cells[0]
    rng = np.random.default_rng(3)
    n = 37
    initial = np.tile([1.8, 1.0, 0.0, 0.1], (n, 1)) + rng.normal(0, 0.2, (n, 4))
    links = np.tile(cell.spec.robot.mass + cell.spec.robot.inertia + cell.spec.robot.length
                    + cell.spec.robot.com, (n, 1))
    trials = Trials(links, np.zeros(n), initial, NoiseStreams(noise, 5, np.arange(n)))
    whole = simulate(cell.scenario, trials)
    recorder = Recorder()
    watcher = tally.watch(recorder)
    assert watcher is not None
    try:
        counted = tally.simulate_counted(cell.scenario, trials, "adaptive")
    finally:
        watcher.stop()
    for name in ("metrics", "status", "event", "event_time", "final", "extra"):
        np.testing.assert_array_equal(getattr(counted, name), getattr(whole, name))
    assert (counted.extra_columns, counted.extra_counts) == (whole.extra_columns,
                                                             whole.extra_counts)
    assert bool(whole.extra_columns) == (controller == "mpc")
    total, counts = recorder.seen[-1]
    assert total == n
    assert counts == {s: int((whole.status == i).sum())
                      for i, s in enumerate(("ok", "singular", "diverged", "unresolved",
                                             "error"))}
    assert not tally.counting()


def test_forked_workers_counts_reach_the_parent(tmp_path: Path) -> None:
    spec = load_spec(write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 200")
                                .replace("chunk = 25", "chunk = 100")))
    recorder = Recorder()
    run_sweep(spec, tmp_path / "d", workers=2, progress=recorder)
    frame = pd.read_parquet(tmp_path / "d" / "trials.parquet")
    expected = frame["status"].value_counts().to_dict()
    total, counts = recorder.seen[-1]
    assert total == 400  # every trial, counted in the worker processes as it finished
    assert {k: v for k, v in counts.items() if v} == expected
    assert recorder.fresh == 400 and recorder.counts == counts


def test_nothing_is_counted_when_quiet() -> None:
    assert tally.watch(Progress("q", quiet=True)) is None
    assert tally.watch(None) is None
    assert not tally.counting()


def test_progress_shows_the_count_that_is_ahead(tmp_path: Path) -> None:
    path = tmp_path / "log"
    with path.open("w") as stream:
        progress = Progress("x", stream=stream, interval=0.0)
        progress.start(100, 0, "local")
        progress.live(30, {"ok": 29, "diverged": 1})
        progress.advance(25, {"ok": 25})  # a chunk ends behind the live count
        progress.live(100, {"ok": 97, "diverged": 3})
        progress.advance(75, {"ok": 72, "diverged": 3})
        progress.close()
    lines = path.read_text().splitlines()
    assert lines[1].startswith("  30/100 trials (30%)")
    assert lines[1].endswith("; ok 29, singular 0, diverged 1, unresolved 0")
    assert lines[2].startswith("  30/100 trials")  # the chunk count (25) is behind
    assert lines[-1].startswith("  100/100 trials (100%)")
    assert lines[-1].endswith("ok 97, singular 0, diverged 3, unresolved 0")
