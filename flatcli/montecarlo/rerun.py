"""``flatcli sweep --rerun TRIAL``: one finished trial of a sweep, re-run alone as a track run.

The trial's row in trials.parquet gives its cell and its realised perturbations; with the
sweep's seed and the trial id as ``track.seed`` and ``track.trial`` (its sensor-noise stream),
the plain track spec built here reproduces the trial exactly.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from flatcli.core.errors import FlatcliError
from flatcli.experiment import run_track
from flatcli.files import kind, not_regular
from flatcli.montecarlo.directory import RERUN_FILES, recorded_digest
from flatcli.montecarlo.draws import perturbation_columns
from flatcli.montecarlo.layout import Cell, Layout, layout
from flatcli.report import table, track_title
from flatcli.spec import PERTURB_TARGETS, Spec, build
from flatcli.spec.limits import ID_STRIDE
from flatcli.storage import run_record


def trials_table(directory: Path) -> Path:
    """A finished sweep's trials.parquet; FlatcliError if there is none (or something else
    than a regular file stands there: it is never opened, a FIFO would block)."""
    trials_path = directory / "trials.parquet"
    what = kind(trials_path)
    if what == "missing":
        raise FlatcliError(f"--rerun: {trials_path} not found; run the sweep first")
    if what != "file":
        raise FlatcliError(f"--rerun: {trials_path} is {what}, not the sweep's table; remove "
                           "it yourself and run the sweep again")
    return trials_path


def trial_row(directory: Path, trial: int) -> dict[str, Any]:
    """A finished trial's row of trials.parquet; FlatcliError if there is none to re-run."""
    import pandas as pd  # a re-run loads what a track run loads; a sweep does not

    trials_path = trials_table(directory)
    frame = pd.read_parquet(trials_path, filters=[("trial", "==", trial)])
    if frame.empty:
        raise FlatcliError(f"--rerun: no trial {trial} in {trials_path}")
    row = {str(k): v for k, v in frame.iloc[0].items()}
    if row["status"] == "error":
        raise FlatcliError(f"--rerun: trial {trial} did not simulate ({row['reason']})")
    return row


def trial_cell(lay: Layout, trial: int) -> Cell:
    """The cell a trial id belongs to: the one whose key is the id's (``trial = key *
    ID_STRIDE + i``, ``layout``), found by its key, not by the row's ``cell`` index, which
    counts cells in the grid's order as that sweep wrote it. FlatcliError if the layout has
    no such cell."""
    key = trial // ID_STRIDE
    found = [c for c in lay.cells if c.key == key]
    if not found:
        raise FlatcliError(f"--rerun: trial {trial} belongs to no cell of the sweep's grid "
                           f"(its cell key {key} is not among the grid's)")
    return found[0]


def rerun_spec(lay: Layout, row: Mapping[str, Any]) -> Spec:
    """A plain track spec that re-runs one trial of a sweep exactly."""
    cell = trial_cell(lay, int(row["trial"]))
    values = {k: v for k, v in cell.spec.values().items() if not k.startswith("sweep.")}
    for name in lay.perturbed:
        drawn = [float(row[c]) for c in perturbation_columns(name, cell.spec.joints)]
        values[PERTURB_TARGETS[name]] = drawn[0] if len(drawn) == 1 else drawn
    trial = int(row["trial"])
    values["track.seed"] = lay.spec.sweep.seed
    values["track.trial"] = trial
    values["name"] = f"{lay.spec.name}-trial-{trial}"
    return build(values)


def same(a: Any, b: Any) -> bool:
    """Equal, with nan and None (not applicable) equal to each other (a metric that is not
    applicable in both runs reproduced)."""
    def missing(v: Any) -> bool:
        return v is None or (isinstance(v, float) and math.isnan(v))

    if missing(a) or missing(b):
        return missing(a) and missing(b)
    if isinstance(a, float | int) and isinstance(b, float | int):
        return a == b
    return bool(a == b)


@dataclass(frozen=True)
class Rerun:
    """A re-run trial: its metrics beside the sweep's, and whether the spec was modified."""

    trial: int
    target: Path
    rows: list[list[Any]]  # metric, in trials.parquet, re-run, "yes"/"NO"
    modified: bool  # the spec given differs from the sweep's (--set): differences expected
    files: tuple[str, ...] = ("track.parquet", "metrics.json")  # what it wrote

    @property
    def reproduced(self) -> bool:
        return all(r[3] == "yes" for r in self.rows)

    def text(self, name: str) -> str:
        """What the terminal shows: the comparison table and the files written."""
        head = f"trial {self.trial} of {name!r} re-run alone" + (
            " with a spec that differs from the sweep's (--set): differences are expected"
            if self.modified else ":")
        return "\n".join([
            head,
            table(["metric", "in trials.parquet", "re-run", "identical"], self.rows, 6),
            f"wrote {self.target}/{', '.join(self.files)}",
        ])


def trial_spec(spec: Spec, directory: Path, trial: int) -> Spec:
    """The track spec that re-runs trial ``trial`` of the sweep ``spec`` in ``directory``."""
    return rerun_spec(layout(spec), trial_row(directory, trial))


def rerun_and_compare(spec: Spec, directory: Path, trial: int) -> Rerun:
    """Re-run one trial into ``directory/rerun-TRIAL`` and compare it with its row."""
    row = trial_row(directory, trial)
    track_spec = rerun_spec(layout(spec), row)
    target = directory / f"rerun-{trial}"
    what = kind(target)
    blocked = not_regular(directory, [f"{target.name}/{n}" for n in RERUN_FILES]) if (
        what == "a directory") else [] if what == "missing" else [
        f"{target.name} ({'a file' if what == 'file' else what})"]
    if blocked:  # never written through: a link would lead out of the sweep's directory
        raise FlatcliError(f"--rerun: {directory} holds {', '.join(blocked)} where the re-run "
                           "writes its files; remove it yourself")
    from flatcli.outputs import write_track

    run = run_track(track_spec)
    metrics = run.metrics
    record = run_record("sweep --rerun", track_spec.tree, metrics=metrics, trial=trial)
    names = write_track(target, run, record, f"trial {trial} of the sweep; "
                        + track_title(track_spec, metrics))
    rows = [[k, row[k], v, "yes" if same(row[k], v) else "NO"]
            for k, v in metrics.items() if k != "reason" and k in row]
    bound, final = row.get("ee_error_bound"), metrics.get("ee_error_final")
    if bound is not None and final is not None and not same(bound, None):
        # a task sweep keeps a bound on the distance from the target; the re-run measures it
        rows.append(["ee_error_final <= ee_error_bound", bound, final,
                     "yes" if final <= bound else "NO"])
    return Rerun(trial, target, rows, recorded_digest(directory) != spec.digest(),
                 tuple(names))
