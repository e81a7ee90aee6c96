"""One candidate's Monte Carlo study, judged: its trials' outcomes, the fraction reached with
its Wilson interval, a quantile of a metric, its plan's energy, and the objective.

Every candidate runs the search spec's own ``[sweep]`` (its ``[sweep.perturb]``, grid, trials and
``sweep.seed``) with the candidate's robot, so trial i of every candidate draws the very same
random numbers (``flatcli.montecarlo.draws``: ``SeedSequence(sweep.seed, (trial, 0))``): common
random numbers, and a difference between two candidates is theirs, not the draws'.

The objective is minimised. With q the ``search.quantile`` quantile of ``search.metric`` over
all trials, a trial lost (not resolved to the end) or without a value counted as infinitely bad
(q is a value of the sample: numpy's "inverted_cdf", no interpolation, so an infinite value
never makes a nan):

* ``reached``: -L + g q / (1 + q), L the 95 % Wilson lower bound of the fraction of trials
  reached and g half the least step between the bounds of two successive counts at this
  number of trials (``tie_step``). Every candidate has the same number of trials and L rises
  with the count, so candidates are ordered by their count of trials reached first and, only
  between equal counts, by q (q / (1 + q) < 1 never bridges a step): where no candidate
  reaches (a plateau of counts 0) the search still moves towards smaller errors;
* ``quantile``: q;

plus ``search.energy_weight`` x E / E_0, E the candidate's plan input energy (the mean over its
grid cells' plans) and E_0 the spec's own design's: a trade-off the user weighs.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.loop.metrics import RESOLVED
from flatcli.montecarlo.chunks import run_chunk
from flatcli.montecarlo.layout import Cell, Chunk, Layout
from flatcli.report.summary import wilson_interval
from flatcli.spec import Spec

#: A trial's outcome words (issue 39's ``outcome`` column; ``trial_outcomes``).
OUTCOMES = ("reached", "collided", "missed", "lost")
#: Statuses of a candidate's row in search.parquet.
EVALUATED, INFEASIBLE, ERROR = "evaluated", "infeasible", "error"


def trial_outcomes(table: pa.Table) -> NDArray[np.str_]:
    """(n,) each trial's outcome (``OUTCOMES``), from the trials' ``outcome`` column (the
    sweep's judgement: ``flatcli.core.loop.outcome``); FlatcliError for a table without one
    (written before outcomes existed) or with a word that is not an outcome."""
    if "outcome" not in table.column_names:
        raise FlatcliError("trials table: no outcome column (written by a flatcli before "
                           "outcomes; run its study again)")
    words = np.asarray(table.column("outcome").to_pylist(), dtype=object)
    unknown = sorted({str(w) for w in words if w not in OUTCOMES})
    if unknown:
        raise FlatcliError(f"trials table: outcome {unknown[0]!r} is not one of "
                           f"{', '.join(OUTCOMES)}")
    return words.astype(str)


def metric_values(table: pa.Table, metric: str) -> NDArray[np.float64]:
    """(n,) the metric of each trial, +inf where the trial is lost or has no value."""
    column = table.column(metric)
    values = np.asarray(column.to_pylist(), dtype=object)
    out = np.array([np.inf if v is None else float(v) for v in values], dtype=float)
    out[np.isnan(out)] = np.inf
    status = np.asarray(table.column("status").to_pylist(), dtype=str)
    out[~np.isin(status, RESOLVED)] = np.inf
    return out


@dataclass(frozen=True)
class Evaluation:
    """A candidate's judged study (the module docstring): trials and outcome counts, the
    reached fraction's 95 % Wilson interval, the quantile q, the plan's input energy
    [rad^2/s] (nan if not planned), the objective, the status (``EVALUATED``,
    ``INFEASIBLE``, ``ERROR``) and why."""

    status: str
    reason: str
    trials: int
    reached: int
    collided: int
    missed: int
    lost: int
    reached_low: float
    reached_high: float
    quantile: float
    energy: float
    objective: float

    @property
    def reached_fraction(self) -> float:
        return self.reached / self.trials if self.trials else math.nan

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(record: Mapping[str, Any]) -> Evaluation:
        """An Evaluation from ``to_json``'s dict (JSON's own numbers: floats come back
        exactly); ValueError or TypeError if it is not one."""
        fields = Evaluation.__dataclass_fields__
        if set(record) != set(fields):
            raise ValueError("not an evaluation record")
        ints = ("trials", "reached", "collided", "missed", "lost")
        texts = ("status", "reason")
        values: dict[str, Any] = {}
        for name in fields:
            v = record[name]
            if name in texts:
                if not isinstance(v, str):
                    raise TypeError(name)
                values[name] = v
            elif name in ints:
                if isinstance(v, bool) or not isinstance(v, int):
                    raise TypeError(name)
                values[name] = v
            else:
                if isinstance(v, bool) or not isinstance(v, int | float):
                    raise TypeError(name)
                values[name] = float(v)
        return Evaluation(**values)


def worst(spec: Spec) -> float:
    """The objective of a candidate that could not be studied (nothing reached, or an
    infinite quantile)."""
    return 0.0 if spec.search.objective == "reached" else math.inf


def failed(spec: Spec, status: str, reason: str) -> Evaluation:
    """The evaluation of a candidate that was not studied."""
    nan = math.nan
    return Evaluation(status, reason, 0, 0, 0, 0, 0, nan, nan, nan, nan, worst(spec))


def plan_energy(lay: Layout) -> float:
    """The mean input energy of a candidate's plans (one per distinct plan of its cells)
    [rad^2/s]."""
    plans = {id(c.scenario.plan): c.scenario.plan for c in lay.cells}
    return float(np.mean([p.input_energy() for p in plans.values()]))


def tie_step(trials: int) -> float:
    """g: half the least difference between the 95 % Wilson lower bounds of k + 1 and k
    trials reached out of ``trials`` (k = 0 .. trials - 1)."""
    low, _ = wilson_interval(np.arange(trials + 1), trials)
    return float(np.min(np.diff(low))) / 2.0


def judge(spec: Spec, tables: Sequence[pa.Table], energy: float, own_energy: float
          ) -> Evaluation:
    """A candidate's study from its trials' tables (``search`` keys of ``spec``, the search
    spec); ``own_energy``: E_0, the spec's own design's plan energy."""
    search = spec.search
    table = pa.concat_tables(tables) if len(tables) > 1 else tables[0]
    outcomes = trial_outcomes(table)
    counts = {name: int(np.count_nonzero(outcomes == name)) for name in OUTCOMES}
    n = table.num_rows
    low, high = (float(v) for v in wilson_interval(counts["reached"], n))
    values = metric_values(table, search.metric)
    quantile = float(np.quantile(values, search.quantile, method="inverted_cdf"))
    if search.objective == "quantile":
        primary = quantile
    else:
        shade = 1.0 if math.isinf(quantile) else quantile / (1.0 + quantile)
        primary = -low + tie_step(n) * shade
    secondary = search.energy_weight * energy / own_energy if search.energy_weight else 0.0
    return Evaluation(EVALUATED, "", n, counts["reached"], counts["collided"], counts["missed"],
                      counts["lost"], low, high, quantile, energy, primary + secondary)


#: The columns a worker sends back of each trial (besides the metric the objective reads).
KEPT_COLUMNS = ("trial", "status", "err_theta_final", "outcome")


def slim_chunk(cell: Cell, chunk: Chunk, metric: str) -> pa.Table:
    """A worker's job: one chunk of a candidate's trials (``run_chunk``), only the columns the
    search reads."""
    table = run_chunk(cell, chunk).table
    keep = [c for c in (*KEPT_COLUMNS, metric) if c in table.column_names]
    return table.select(list(dict.fromkeys(keep)))


def dumps(record: Mapping[str, Any]) -> str:
    """One journal line: JSON (Python's floats written exactly, inf and nan as JSON's
    Infinity and NaN), keys sorted."""
    return json.dumps(record, sort_keys=True, allow_nan=True)


__all__ = ["ERROR", "EVALUATED", "INFEASIBLE", "KEPT_COLUMNS", "OUTCOMES",
           "Evaluation", "dumps", "failed", "judge", "metric_values", "plan_energy",
           "slim_chunk", "tie_step", "trial_outcomes", "worst"]
