"""Limits a plan must respect, and the inequality rows that impose them pointwise.

Each finite limit becomes rows g = a q + b + c s >= 0 on a quantity q of ``quantities``
(s: the epigraph variable, when the goal has one), imposed at every time of a grid:

* |th_i| <= angle_limit_i: rows -th_i + L >= 0 and th_i + L >= 0;
* |th_j'| <= rate_limit for each limited joint rate, likewise;
* the signed margin sigma sin(y1) y1' >= min_margin: one row, always present (it keeps every
  plan off the singular set; sigma is folded into the quantity by the problem);
* "peak_rate": s -+ th_j' >= 0; "margin": margin - s >= 0 (epigraph rows, unlabelled);
* "violation": every angle and rate row relaxed by s max(1, |limit|), so that the least s
  is the largest relative violation.

Limits are imposed backed off by ``Tuning.backoff`` (relative) so that the solver's own
tolerance cannot show up as a violation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.model import FlatcliError
from flatcli.core.optimize.objectives import Goal
from flatcli.core.optimize.quantities import ANGLES, MARGIN, NAMES, RATES

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PlanLimits:
    """Limits an optimised plan must respect along its whole path.

    Attributes
    ----------
    angle_limit : (3,) bound on |th0|, |th1|, |th2| [rad], each > 0 (inf: none)
    rate_limit : bound on |th1'| and |th2'| [rad/s], > 0 (inf: none)
    min_margin : lower bound on the signed singularity margin sigma sin(th1) th1' [rad/s],
        >= 0 and finite (sigma: the sign at t = 0)

    Raises
    ------
    FlatcliError naming the spec key ``plan.optimize.*`` when a value is out of range.
    """

    angle_limit: tuple[float, float, float] = (math.inf, math.inf, math.inf)
    rate_limit: float = math.inf
    min_margin: float = 0.02

    def __post_init__(self) -> None:
        angles = np.asarray(self.angle_limit, dtype=float)
        if angles.shape != (len(ANGLES),):
            raise FlatcliError(
                f"plan.optimize.angle_limit: expected 3 numbers (th0, th1, th2), "
                f"got shape {angles.shape}"
            )
        if np.any(np.isnan(angles)) or np.any(angles <= 0):
            raise FlatcliError(
                f"plan.optimize.angle_limit: every value must be > 0 rad (inf: no limit), "
                f"got {angles.tolist()}"
            )
        object.__setattr__(
            self, "angle_limit", (float(angles[0]), float(angles[1]), float(angles[2]))
        )
        rate = float(self.rate_limit)
        if math.isnan(rate) or rate <= 0:
            raise FlatcliError(
                f"plan.optimize.rate_limit: must be > 0 rad/s (inf: no limit), got {rate}"
            )
        object.__setattr__(self, "rate_limit", rate)
        margin = float(self.min_margin)
        if not (math.isfinite(margin) and margin > 0):
            raise FlatcliError(
                f"plan.optimize.min_margin: must be finite and > 0 rad/s (at 0 th2' can spike "
                f"without bound between the check samples), got {margin}"
            )
        object.__setattr__(self, "min_margin", margin)

    def margin_only(self) -> PlanLimits:
        """The least limited request with the same margin (no angle or rate limits)."""
        return PlanLimits(min_margin=self.min_margin)


@dataclass(frozen=True)
class Rows:
    """Inequality rows g = a q[quantity, time] + b + c s >= 0 (s: the epigraph variable).

    Attributes
    ----------
    quantity : (rows,) row of ``flag_quantities`` each inequality bounds
    a, b, c : (rows,) sign of the quantity, offset (the limit as imposed, backed off) and
        weight of the epigraph variable
    bound : (rows,) the user's limit behind each row [rad or rad/s] (inf for epigraph rows)
    label : (rows,) e.g. "rate_limit on th2'" ('' for epigraph rows)
    """

    quantity: NDArray[np.intp]
    a: Array
    b: Array
    c: Array
    bound: Array
    label: tuple[str, ...]

    @property
    def limited(self) -> NDArray[np.bool_]:
        """(rows,) True for the rows of a user's limit, False for epigraph rows."""
        return np.array([bool(name) for name in self.label], dtype=bool)


def limit_rows(limits: PlanLimits, goal: Goal, backoff: float) -> Rows:
    """The inequality rows of a problem (see the module docstring).

    Parameters
    ----------
    limits : the user's limits
    goal : what the problem minimises (decides the epigraph rows and the relaxation)
    backoff : relative tightening of each limit as imposed (``Tuning.backoff``)

    Returns
    -------
    Rows: per finite angle and rate limit two rows (both signs), then the margin row, then
    the epigraph rows
    """
    relax = goal == "violation"
    quantity: list[int] = []
    a: list[float] = []
    b: list[float] = []
    c: list[float] = []
    bound: list[float] = []
    label: list[str] = []

    def add(q: int, sign: float, limit: float, eps: float, name: str) -> None:
        quantity.append(q)
        a.append(sign)
        b.append(limit - backoff * max(1.0, abs(limit)) if name else limit)
        c.append(max(1.0, abs(limit)) if relax and name else eps)
        bound.append(abs(limit) if name else math.inf)
        label.append(name)

    for i in ANGLES:
        lim = limits.angle_limit[i]
        if math.isfinite(lim):
            for sign in (-1.0, 1.0):
                add(i, sign, lim, 0.0, f"angle_limit[{i}] on {NAMES[i]}")
    if math.isfinite(limits.rate_limit):
        for q in RATES:
            for sign in (-1.0, 1.0):
                add(q, sign, limits.rate_limit, 0.0, f"rate_limit on {NAMES[q]}")
    # the margin row: sigma sin(y1) y1' - m >= 0 (never relaxed: it keeps every plan off the
    # singular set)
    quantity.append(MARGIN)
    a.append(1.0)
    b.append(-limits.min_margin - backoff * max(1.0, limits.min_margin))
    c.append(0.0)
    bound.append(limits.min_margin)
    label.append("min_margin")
    if goal == "peak_rate":
        for q in RATES:
            for sign in (-1.0, 1.0):
                add(q, sign, 0.0, 1.0, "")
    elif goal == "margin":
        add(MARGIN, 1.0, 0.0, -1.0, "")
    return Rows(
        np.asarray(quantity, dtype=np.intp),
        np.asarray(a),
        np.asarray(b),
        np.asarray(c),
        np.asarray(bound),
        tuple(label),
    )


def describe_violation(limits: PlanLimits, quantity: int, value: float, time: float) -> str:
    """One line naming a violated limit, its value and how far the plan goes past it.

    Parameters
    ----------
    limits : the user's limits
    quantity : row of ``flag_quantities`` that misses its limit
    value : its value there [rad or rad/s] (the margin signed)
    time : where [s]
    """
    if quantity == MARGIN:
        return (
            f"plan.optimize.min_margin = {limits.min_margin:g} rad/s cannot be met: the best "
            f"plan found has a margin of {value:.4g} rad/s at t = {time:.3f} s"
        )
    if quantity in RATES:
        return (
            f"plan.optimize.rate_limit = {limits.rate_limit:g} rad/s cannot be met: the best "
            f"plan found reaches |{NAMES[quantity]}| = {abs(value):.4g} rad/s at t = {time:.3f} s"
        )
    return (
        f"plan.optimize.angle_limit[{quantity}] = {limits.angle_limit[quantity]:g} rad cannot "
        f"be met: the best plan found reaches |{NAMES[quantity]}| = {abs(value):.4g} rad at "
        f"t = {time:.3f} s"
    )


__all__ = ["PlanLimits", "Rows", "describe_violation", "limit_rows"]
