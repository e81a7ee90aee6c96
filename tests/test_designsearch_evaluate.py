"""A candidate's study judged (flatcli/designsearch/evaluate.py): outcomes, the Wilson bound,
the quantile, the objective's order.

Referees: the reached rule recomputed from each trial's own columns; scipy.stats.binomtest's
Wilson interval; the quantile read off the sorted sample by hand; brute force over every pair
of counts for the objective's order."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pyarrow as pa
import pytest
from scipy.stats import binomtest
from small_search import SPEC

from flatcli.core.errors import FlatcliError
from flatcli.designsearch.evaluate import (
    OUTCOMES,
    Evaluation,
    judge,
    metric_values,
    tie_step,
    trial_outcomes,
)
from flatcli.spec import resolve

STATUSES = ["ok", "ok", "singular", "ok", "diverged", "error", "ok", "unresolved"]
FINAL = [1e-4, 2e-3, 5e-4, 1e-3, None, None, math.nan, None]
#: the sweep's own judgement of these trials (``outcome``): 3 reached, 2 missed, 3 lost
OUTCOME = ["reached", "missed", "reached", "reached", "lost", "lost", "missed", "lost"]


def trials_table(statuses: list[str] = STATUSES, final: list[float | None] = FINAL
                 ) -> pa.Table:
    return pa.table({"trial": list(range(len(statuses))), "status": statuses,
                     "err_theta_final": pa.array(final, pa.float64()),
                     "outcome": OUTCOME[:len(statuses)],
                     "peak_rate": pa.array([3.0, 1.0, 2.0, 5.0, 9.0, None, 4.0, 7.0],
                                           pa.float64())})


def test_the_outcome_is_the_trials_own_column_and_nothing_else() -> None:
    """The search counts the sweep's own judgement (the outcome column); a table without one
    (written before outcomes) or with a word that is no outcome is refused, not guessed."""
    words = ["collided", "reached", "missed", "lost", "reached", "lost", "missed", "lost"]
    bare = trials_table().drop_columns(["outcome"])
    assert trial_outcomes(bare.append_column("outcome", pa.array(words))).tolist() == words
    assert set(words) == set(OUTCOMES)
    with pytest.raises(FlatcliError, match="no outcome column"):
        trial_outcomes(bare)
    bad = bare.append_column("outcome", pa.array(["reached"] * 7 + ["won"]))
    with pytest.raises(FlatcliError, match="outcome 'won' is not one of"):
        trial_outcomes(bad)


def test_a_lost_trial_or_a_missing_value_counts_as_infinite() -> None:
    values = metric_values(trials_table(), "peak_rate")
    assert values.tolist() == [3.0, 1.0, 2.0, 5.0, math.inf, math.inf, 4.0, math.inf]


@pytest.mark.parametrize("q", [0.1, 0.5, 0.62, 0.9, 1.0])
def test_the_judged_study(q: float) -> None:
    tree = tomllib.loads(SPEC)
    tree["search"].update(metric="peak_rate", quantile=q)
    spec = resolve(tree)
    table = trials_table()
    e = judge(spec, [table.slice(0, 3), table.slice(3)], 7.0, 14.0)
    assert (e.trials, e.reached, e.missed, e.lost, e.collided) == (8, 3, 2, 3, 0)
    interval = binomtest(3, 8).proportion_ci(0.95, method="wilson")
    assert (e.reached_low, e.reached_high) == pytest.approx((interval.low, interval.high),
                                                            rel=1e-12)
    ordered = sorted([3.0, 1.0, 2.0, 5.0, math.inf, math.inf, 4.0, math.inf])
    assert e.quantile == ordered[math.ceil(q * 8) - 1]  # the inverted-cdf quantile, by hand
    shade = 1.0 if math.isinf(e.quantile) else e.quantile / (1 + e.quantile)
    assert e.objective == pytest.approx(-interval.low + tie_step(8) * shade, rel=1e-12)
    weighted = resolve({**tree, "search": {**tree["search"], "energy_weight": 0.5}})
    assert judge(weighted, [table], 7.0, 14.0).objective == pytest.approx(e.objective + 0.25)
    by_quantile = resolve({**tree, "search": {**tree["search"], "objective": "quantile"}})
    assert judge(by_quantile, [table], 7.0, 14.0).objective == e.quantile


@pytest.mark.parametrize("n", [1, 2, 7, 100, 1000])
def test_the_objective_orders_by_count_first(n: int) -> None:
    """Brute force: every count k + 1 beats every count k, whatever the quantiles."""
    step = tie_step(n)
    low = np.array([0.0 if k == 0 else binomtest(k, n).proportion_ci(method="wilson").low
                    for k in range(n + 1)])
    assert step > 0
    worst_of_more = -low[1:] + step * 1.0  # count k + 1 with an infinite quantile
    best_of_fewer = -low[:-1] + step * 0.0  # count k with a zero quantile
    assert np.all(worst_of_more < best_of_fewer)


def test_an_evaluation_survives_json_exactly() -> None:
    import json

    e = Evaluation("evaluated", "", 24, 20, 0, 3, 1, 0.1 + 0.2, 1 / 3, math.inf, math.nan,
                   -0.6234567890123457)
    back = Evaluation.from_json(json.loads(json.dumps(e.to_json())))
    assert back.reached_low == e.reached_low and back.objective == e.objective
    assert math.isinf(back.quantile) and math.isnan(back.energy)
    with pytest.raises((ValueError, TypeError)):
        Evaluation.from_json({**e.to_json(), "trials": "24"})
    with pytest.raises((ValueError, TypeError)):
        Evaluation.from_json({"status": "evaluated"})
