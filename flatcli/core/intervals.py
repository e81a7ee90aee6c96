"""Interval arithmetic, just enough to bound a plan's functions over a time interval.

An ``Interval`` is a pair of arrays (lo, hi) of any common shape; every operation returns an
interval that contains every value the operation can take on its arguments' intervals
(the inclusion property), rounded outwards by one ulp per operation (``_out``), so the bounds
hold in floating point too. Division by an interval containing 0 gives (-inf, inf).
``poly`` bounds a polynomial in s over [s_lo, s_hi] by its Taylor expansion at the centre
(exact coefficients, remainder bounded termwise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def _out(lo: Array, hi: Array) -> tuple[Array, Array]:
    return np.nextafter(lo, -np.inf), np.nextafter(hi, np.inf)


@dataclass(frozen=True)
class Interval:
    """[lo, hi] elementwise (arrays of one shape)."""

    lo: Array
    hi: Array

    @staticmethod
    def point(x: Array | float) -> Interval:
        a = np.asarray(x, dtype=float)
        return Interval(a, a)

    def __add__(self, other: Interval | float | Array) -> Interval:
        o = _as(other)
        return Interval(*_out(self.lo + o.lo, self.hi + o.hi))

    __radd__ = __add__

    def __neg__(self) -> Interval:
        return Interval(-self.hi, -self.lo)

    def __sub__(self, other: Interval | float | Array) -> Interval:
        return self + (-_as(other))

    def __rsub__(self, other: float) -> Interval:
        return _as(other) - self

    def __mul__(self, other: Interval | float | Array) -> Interval:
        o = _as(other)
        p = np.stack([self.lo * o.lo, self.lo * o.hi, self.hi * o.lo, self.hi * o.hi])
        p = np.where(np.isnan(p), 0.0, p)  # 0 * inf inside a product of bounds
        return Interval(*_out(p.min(axis=0), p.max(axis=0)))

    __rmul__ = __mul__

    def reciprocal(self) -> Interval:
        safe = (self.lo > 0) | (self.hi < 0)
        with np.errstate(divide="ignore"):
            lo = np.where(safe, 1.0 / np.where(safe, self.hi, 1.0), -np.inf)
            hi = np.where(safe, 1.0 / np.where(safe, self.lo, 1.0), np.inf)
        return Interval(*_out(lo, hi))

    def __truediv__(self, other: Interval | float | Array) -> Interval:
        return self * _as(other).reciprocal()

    def __rtruediv__(self, other: float) -> Interval:
        return _as(other) * self.reciprocal()

    def square(self) -> Interval:
        a, b = np.abs(self.lo), np.abs(self.hi)
        straddles = (self.lo <= 0) & (self.hi >= 0)
        lo = np.where(straddles, 0.0, np.minimum(a, b) ** 2)
        return Interval(*_out(lo, np.maximum(a, b) ** 2))

    def magnitude(self) -> Array:
        """max |x| over the interval."""
        return np.asarray(np.maximum(np.abs(self.lo), np.abs(self.hi)), dtype=float)

    def mignitude(self) -> Array:
        """min |x| over the interval (0 if it contains 0)."""
        straddles = (self.lo <= 0) & (self.hi >= 0)
        return np.asarray(np.where(straddles, 0.0, np.minimum(np.abs(self.lo),
                                                              np.abs(self.hi))), dtype=float)

    def hull(self, other: Interval) -> Interval:
        return Interval(np.minimum(self.lo, other.lo), np.maximum(self.hi, other.hi))


def _as(x: Interval | float | Array) -> Interval:
    return x if isinstance(x, Interval) else Interval.point(x)


def cos(x: Interval) -> Interval:
    """cos over [lo, hi]: the ends' values, widened to +-1 where a multiple of pi (a maximum
    or minimum) lies inside."""
    lo, hi = x.lo, x.hi
    ends = np.stack([np.cos(lo), np.cos(hi)])
    low, high = ends.min(axis=0), ends.max(axis=0)
    wide = (hi - lo) >= 2.0 * math.pi
    k_max = np.ceil(lo / (2.0 * math.pi))  # 2 pi k in [lo, hi]: a maximum
    has_max = wide | (2.0 * math.pi * k_max <= hi)
    k_min = np.ceil((lo - math.pi) / (2.0 * math.pi))  # pi + 2 pi k: a minimum
    has_min = wide | (math.pi + 2.0 * math.pi * k_min <= hi)
    high = np.where(has_max, 1.0, high)
    low = np.where(has_min, -1.0, low)
    lo_o, hi_o = _out(low, high)
    return Interval(np.maximum(lo_o, -1.0), np.minimum(hi_o, 1.0))


def sin(x: Interval) -> Interval:
    """sin = cos(x - pi/2) over the interval."""
    return cos(x - math.pi / 2.0)


def _horner(c: Array, x: Array) -> Array:
    """sum_j c[..., j] x^j, rows of coefficients c (..., degree + 1) at x (...)."""
    out = np.zeros_like(x)
    for j in range(c.shape[-1] - 1, -1, -1):
        out = out * x + c[..., j]
    return out


def poly(coefficients: Array, s_lo: Array, s_hi: Array) -> Interval:
    """Bounds of p(s) = sum_j c_j s^j over [s_lo, s_hi] (arrays (...)), coefficients
    (..., degree + 1) (one row per interval, or one for all): Taylor at the centre m,
    p(m) +- sum_k |p^(k)(m) / k!| r^k, widened by the rounding of its terms."""
    c = np.broadcast_to(np.asarray(coefficients, dtype=float),
                        (*np.shape(s_lo), np.shape(coefficients)[-1]))
    m = 0.5 * (s_lo + s_hi)
    r = 0.5 * (s_hi - s_lo)
    value = _horner(c, m)
    spread = np.zeros_like(m)
    scale = _horner(np.abs(c), np.abs(m))
    current = c
    for k in range(1, c.shape[-1]):
        current = current[..., 1:] * np.arange(1, current.shape[-1])
        taylor = _horner(current, m) / math.factorial(k)
        spread = spread + np.abs(taylor) * r**k
        scale = scale + _horner(np.abs(current), np.abs(m)) / math.factorial(k) * r**k
    pad = 8.0 * c.shape[-1] * np.finfo(float).eps * scale  # rounding of the Taylor terms
    return Interval(*_out(value - spread - pad, value + spread + pad))


__all__ = ["Interval", "cos", "poly", "sin"]
