"""Tests of flatcli.core.optimize.limits: PlanLimits and the inequality rows."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from flatcli.core.errors import FlatcliError
from flatcli.core.optimize import PlanLimits
from flatcli.core.optimize.limits import describe_violation, limit_rows
from flatcli.core.optimize.quantities import MARGIN, RATES

BACKOFF = 1e-7


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"angle_limit": (1.0, 0.0, 1.0)}, "plan.optimize.angle_limit"),
        ({"angle_limit": (1.0, math.nan, 1.0)}, "plan.optimize.angle_limit"),
        ({"angle_limit": (1.0, 1.0)}, "plan.optimize.angle_limit"),
        ({"rate_limit": -1.0}, "plan.optimize.rate_limit"),
        ({"min_margin": -0.1}, "plan.optimize.min_margin"),
        ({"min_margin": math.inf}, "plan.optimize.min_margin"),
        ({"min_margin": 0.0}, "plan.optimize.min_margin"),  # th2' could spike unseen
    ],
)
def test_plan_limits_validated(kwargs: dict[str, Any], key: str) -> None:
    with pytest.raises(FlatcliError, match=key.replace(".", r"\.")):
        PlanLimits(**kwargs)


def test_plan_limits_defaults_and_coercion() -> None:
    angles: Any = np.array([1, 2, 3])
    limits = PlanLimits(angle_limit=angles, rate_limit=4, min_margin=1)
    assert limits.angle_limit == (1.0, 2.0, 3.0)
    assert isinstance(limits.rate_limit, float) and isinstance(limits.min_margin, float)
    assert PlanLimits() == PlanLimits((math.inf,) * 3, math.inf, 0.02)
    assert limits.margin_only() == PlanLimits(min_margin=1.0)


def row_values(rows: Any, values: dict[int, float], s: float = 0.0) -> np.ndarray:
    """g = a q + b + c s of each row for one value per quantity."""
    q = np.array([values[int(i)] for i in rows.quantity])
    return np.asarray(rows.a * q + rows.b + rows.c * s)


def test_rows_of_every_limit() -> None:
    """Two rows per finite limit, one margin row; g >= 0 exactly inside the backed-off box."""
    limits = PlanLimits(angle_limit=(math.inf, 2.0, 3.0), rate_limit=5.0, min_margin=0.1)
    rows = limit_rows(limits, "energy", BACKOFF)
    assert rows.label == (
        "angle_limit[1] on th1", "angle_limit[1] on th1",
        "angle_limit[2] on th2", "angle_limit[2] on th2",
        "rate_limit on th1'", "rate_limit on th1'",
        "rate_limit on th2'", "rate_limit on th2'",
        "min_margin",
    )  # fmt: skip
    assert rows.limited.all() and not rows.c.any()
    np.testing.assert_array_equal(rows.bound, [2, 2, 3, 3, 5, 5, 5, 5, 0.1])
    inside = {0: 9.0, 1: -1.99, 2: 2.99, 3: 4.99, 4: -4.99, 5: 0.11}
    assert np.all(row_values(rows, inside) > 0)
    # on a limit itself, the row misses by the backoff, BACKOFF max(1, limit)
    on = {**inside, 2: 3.0}
    g = row_values(rows, on)
    assert g[2] == pytest.approx(-3.0 * BACKOFF, rel=1e-6) and np.all(np.delete(g, 2) > 0)
    on = {**inside, 5: 0.1}
    assert row_values(rows, on)[-1] == pytest.approx(-BACKOFF, rel=1e-6)


def test_epigraph_and_violation_rows() -> None:
    limits = PlanLimits(rate_limit=5.0)
    peak = limit_rows(limits, "peak_rate", BACKOFF)
    epigraph = ~peak.limited
    assert epigraph.sum() == 2 * len(RATES)
    # s - |th'| >= 0: met with s at the peak rate, missed just below it
    values = {0: 0.0, 1: 1.0, 2: 0.0, 3: 2.0, 4: -3.0, 5: 1.0}
    assert np.min(row_values(peak, values, 3.0)[epigraph]) == pytest.approx(0.0, abs=1e-15)
    assert np.min(row_values(peak, values, 2.9)[epigraph]) < 0
    margin = limit_rows(limits, "margin", BACKOFF)
    assert list(margin.quantity[~margin.limited]) == [MARGIN]
    # "violation": rate rows relaxed by s max(1, limit); the margin row never
    relaxed = limit_rows(limits, "violation", BACKOFF)
    np.testing.assert_array_equal(relaxed.c, [5, 5, 5, 5, 0])


def test_describe_violation() -> None:
    limits = PlanLimits(angle_limit=(math.inf, math.inf, 2.8), rate_limit=3.0)
    assert describe_violation(limits, RATES[1], -3.6886, 1.377) == (
        "plan.optimize.rate_limit = 3 rad/s cannot be met: the best plan found reaches "
        "|th2'| = 3.689 rad/s at t = 1.377 s"
    )
    assert describe_violation(limits, 2, 2.9, 1.0).startswith(
        "plan.optimize.angle_limit[2] = 2.8 rad cannot be met: the best plan found reaches "
        "|th2| = 2.9 rad"
    )
    assert "min_margin = 0.02 rad/s" in describe_violation(limits, MARGIN, 0.01, 0.0)


def test_limits_of_a_chain() -> None:
    """N + 1 angle limits and one rate limit per joint: rows per joint, labels naming the
    list entry; the all-inf default stretches to any N, other lengths are refused."""
    limits = PlanLimits(angle_limit=(math.inf, 2.0, math.inf, 3.0), rate_limit=(math.inf, 4.0, 5.0))
    assert limits.n_joints == 3
    assert [limits.rate_of(j) for j in (1, 2, 3)] == [math.inf, 4.0, 5.0]
    rows = limit_rows(limits, "energy", BACKOFF)
    assert rows.label == (
        "angle_limit[1] on th1", "angle_limit[1] on th1",
        "angle_limit[3] on th3", "angle_limit[3] on th3",
        "rate_limit[1] on th2'", "rate_limit[1] on th2'",
        "rate_limit[2] on th3'", "rate_limit[2] on th3'",
        "min_margin",
    )  # fmt: skip
    assert rows.quantity.tolist() == [1, 1, 3, 3, 5, 5, 6, 6, 7]
    assert PlanLimits().for_joints(4).angle_limit == (math.inf,) * 5
    assert limits.for_joints(3) is limits
    assert PlanLimits(rate_limit=2.0).for_joints(5).rate_of(5) == 2.0
    with pytest.raises(FlatcliError, match=r"^plan\.optimize\.angle_limit: expected 5 numbers"):
        limits.for_joints(4)
    with pytest.raises(FlatcliError, match=r"^plan\.optimize\.rate_limit: expected a number or 2"):
        PlanLimits(rate_limit=(1.0, 2.0, 3.0)).for_joints(2)
    with pytest.raises(FlatcliError, match=r"^plan\.optimize\.rate_limit: must be > 0"):
        PlanLimits(rate_limit=(1.0, 0.0, 3.0))
    line = describe_violation(limits, 6, -5.5, 0.25)
    assert line == ("plan.optimize.rate_limit[2] = 5 rad/s cannot be met: the best plan found "
                    "reaches |th3'| = 5.5 rad/s at t = 0.250 s")
