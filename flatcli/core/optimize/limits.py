"""Limits a plan must respect, and the inequality rows that impose them pointwise.

Each finite limit becomes rows g = a q + b + c s >= 0 on a quantity q of ``quantities``
(s: the epigraph variable, when the goal has one), imposed at every time of a grid:

* |th_i| <= angle_limit_i: rows -th_i + L >= 0 and th_i + L >= 0;
* |th_j'| <= the rate limit of joint j, for each joint j = 1..N, likewise;
* the signed margin sigma m(t) >= min_margin: one row, always present (it keeps every plan
  off the singular set; m is sin(y1) y1' for the paper's robot, -(dh_0/dt) / (2 K_10) for a
  chain, and its sign sigma is folded into the quantity by the problem);
* "peak_rate": s -+ th_j' >= 0; "margin": margin - s >= 0 (epigraph rows, unlabelled);
* "violation": every angle and rate row relaxed by s max(1, |limit|), so that the least s
  is the largest relative violation.

Limits are imposed backed off by ``Tuning.backoff`` (relative) so that the solver's own
tolerance cannot show up as a violation. The number of joints N follows from the length of
``PlanLimits.angle_limit`` (N + 1 angles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.optimize.objectives import Goal
from flatcli.core.optimize.quantities import Layout, layout

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PlanLimits:
    """Limits an optimised plan must respect along its whole path.

    Attributes
    ----------
    angle_limit : (N + 1,) bound on |th0|, ..., |thN| [rad], each > 0 (inf: none); three
        numbers for the paper's robot. All inf (no angle limit, the default) stands for any N
        (``for_joints``)
    rate_limit : bound on every joint rate |th1'|..|thN'| [rad/s], > 0 (inf: none), or (N,)
        one bound per joint th1'..thN'
    min_margin : lower bound on the signed singularity margin [rad/s], > 0 and finite: sigma
        sin(th1) th1' for the paper's robot, -sigma (dh_0/dt) / (2 K_10) for a chain (sigma:
        the sign it keeps along the maneuver)

    Raises
    ------
    FlatcliError naming the spec key ``plan.optimize.*`` when a value is out of range.
    """

    angle_limit: tuple[float, ...] = (math.inf, math.inf, math.inf)
    rate_limit: float | tuple[float, ...] = math.inf
    min_margin: float = 0.02

    def __post_init__(self) -> None:
        angles = np.asarray(self.angle_limit, dtype=float)
        if angles.ndim != 1 or angles.size < 3:
            raise FlatcliError(
                f"plan.optimize.angle_limit: expected 3 numbers (th0, th1, th2), or N + 1 "
                f"(th0..thN) for a chain of N joints, got shape {angles.shape}"
            )
        if np.any(np.isnan(angles)) or np.any(angles <= 0):
            raise FlatcliError(
                f"plan.optimize.angle_limit: every value must be > 0 rad (inf: no limit), "
                f"got {angles.tolist()}"
            )
        object.__setattr__(self, "angle_limit", tuple(float(a) for a in angles))
        rates = np.asarray(self.rate_limit, dtype=float)
        if rates.ndim > 1 or (rates.ndim == 1 and rates.size < 2):
            raise FlatcliError(
                f"plan.optimize.rate_limit: expected a number, or one per joint (th1'..thN'), "
                f"got shape {rates.shape}"
            )
        if np.any(np.isnan(rates)) or np.any(rates <= 0):
            raise FlatcliError(
                f"plan.optimize.rate_limit: must be > 0 rad/s (inf: no limit), got "
                f"{rates.tolist()}"
            )
        rate: float | tuple[float, ...] = (
            float(rates) if rates.ndim == 0 else tuple(float(r) for r in rates)
        )
        object.__setattr__(self, "rate_limit", rate)
        margin = float(self.min_margin)
        if not (math.isfinite(margin) and margin > 0):
            raise FlatcliError(
                f"plan.optimize.min_margin: must be finite and > 0 rad/s (at 0 th2' can spike "
                f"without bound between the check samples), got {margin}"
            )
        object.__setattr__(self, "min_margin", margin)

    @property
    def n_joints(self) -> int:
        """N, from the number of angle limits."""
        return len(self.angle_limit) - 1

    def rate_of(self, joint: int) -> float:
        """The bound on |th_joint'| [rad/s] (joint = 1..N)."""
        if isinstance(self.rate_limit, tuple):
            return self.rate_limit[joint - 1]
        return self.rate_limit

    def rate_key(self, joint: int) -> str:
        """The spec key of joint ``joint``'s rate limit: ``rate_limit`` or ``rate_limit[j]``
        (j = joint - 1, the index into the list)."""
        if isinstance(self.rate_limit, tuple):
            return f"rate_limit[{joint - 1}]"
        return "rate_limit"

    def for_joints(self, n_joints: int) -> PlanLimits:
        """These limits for a robot of ``n_joints`` joints: an all-inf angle limit stretched
        to N + 1 angles.

        Raises
        ------
        FlatcliError naming ``plan.optimize.angle_limit`` or ``plan.optimize.rate_limit`` when
        their lengths do not match N
        """
        n = n_joints
        angles = self.angle_limit
        if len(angles) != n + 1:
            if not all(math.isinf(a) for a in angles):
                raise FlatcliError(
                    f"plan.optimize.angle_limit: expected {n + 1} numbers (th0..th{n}) for "
                    f"this robot of {n} joints, got {len(angles)}"
                )
            angles = (math.inf,) * (n + 1)
        if isinstance(self.rate_limit, tuple) and len(self.rate_limit) != n:
            raise FlatcliError(
                f"plan.optimize.rate_limit: expected a number or {n} (th1'..th{n}') for this "
                f"robot of {n} joints, got {len(self.rate_limit)}"
            )
        if angles is self.angle_limit:
            return self
        return PlanLimits(angles, self.rate_limit, self.min_margin)

    def margin_only(self) -> PlanLimits:
        """The least limited request with the same margin (no angle or rate limits)."""
        return PlanLimits((math.inf,) * len(self.angle_limit), min_margin=self.min_margin)


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
    limits : the user's limits (for a robot of ``limits.n_joints`` joints)
    goal : what the problem minimises (decides the epigraph rows and the relaxation)
    backoff : relative tightening of each limit as imposed (``Tuning.backoff``)

    Returns
    -------
    Rows: per finite angle and rate limit two rows (both signs), then the margin row, then
    the epigraph rows
    """
    lay = layout(limits.n_joints)
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

    for i in lay.angles:
        lim = limits.angle_limit[i]
        if math.isfinite(lim):
            for sign in (-1.0, 1.0):
                add(i, sign, lim, 0.0, f"angle_limit[{i}] on {lay.names[i]}")
    for q in lay.rates:
        joint = _joint(lay, q)
        lim = limits.rate_of(joint)
        if math.isfinite(lim):
            for sign in (-1.0, 1.0):
                add(q, sign, lim, 0.0, f"{limits.rate_key(joint)} on {lay.names[q]}")
    # the margin row: sigma m(t) - min_margin >= 0 (never relaxed: it keeps every plan off
    # the singular set)
    quantity.append(lay.margin)
    a.append(1.0)
    b.append(-limits.min_margin - backoff * max(1.0, limits.min_margin))
    c.append(0.0)
    bound.append(limits.min_margin)
    label.append("min_margin")
    if goal == "peak_rate":
        for q in lay.rates:
            for sign in (-1.0, 1.0):
                add(q, sign, 0.0, 1.0, "")
    elif goal == "margin":
        add(lay.margin, 1.0, 0.0, -1.0, "")
    return Rows(
        np.asarray(quantity, dtype=np.intp),
        np.asarray(a),
        np.asarray(b),
        np.asarray(c),
        np.asarray(bound),
        tuple(label),
    )


def _joint(lay: Layout, quantity: int) -> int:
    """The joint j (1..N) whose rate th_j' is row ``quantity``."""
    return quantity - lay.rates[0] + 1


def describe_violation(limits: PlanLimits, quantity: int, value: float, time: float) -> str:
    """One line naming a violated limit, its value and how far the plan goes past it.

    Parameters
    ----------
    limits : the user's limits
    quantity : row of ``flag_quantities`` that misses its limit
    value : its value there [rad or rad/s] (the margin signed)
    time : where [s]
    """
    lay = layout(limits.n_joints)
    if quantity == lay.margin:
        return (
            f"plan.optimize.min_margin = {limits.min_margin:g} rad/s cannot be met: the best "
            f"plan found has a margin of {value:.4g} rad/s at t = {time:.3f} s"
        )
    if quantity in lay.rates:
        joint = _joint(lay, quantity)
        return (
            f"plan.optimize.{limits.rate_key(joint)} = {limits.rate_of(joint):g} rad/s cannot "
            f"be met: the best plan found reaches |{lay.names[quantity]}| = {abs(value):.4g} "
            f"rad/s at t = {time:.3f} s"
        )
    return (
        f"plan.optimize.angle_limit[{quantity}] = {limits.angle_limit[quantity]:g} rad cannot "
        f"be met: the best plan found reaches |{lay.names[quantity]}| = {abs(value):.4g} rad at "
        f"t = {time:.3f} s"
    )


__all__ = ["PlanLimits", "Rows", "describe_violation", "limit_rows"]
