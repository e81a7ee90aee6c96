"""Interval arithmetic, just enough to bound a plan's functions over a time interval.

An ``Interval`` is a pair of arrays (lo, hi) of any common shape; every operation returns an
interval that contains every value the operation can take on its arguments' intervals
(the inclusion property), rounded outwards by one ulp per operation (``_out``), so the bounds
hold in floating point too. Division by an interval containing 0 gives (-inf, inf); a NaN end
gives NaN (or (-inf, inf)) through every operation: a bound of nothing, which the proof
(``clearance``) never counts as proven. Inputs are valid intervals (lo <= hi): an empty one is
no input (its results are meaningless), and the proof refuses any it finds.
``poly`` bounds a polynomial in s over [s_lo, s_hi] by its Taylor expansion at the centre
(exact coefficients, remainder bounded termwise).
"""

from __future__ import annotations

import functools
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
        # a 0 * inf among the four products is nan and fmin/fmax pass over it: the other
        # products then hold the range (0 times the other factor's finite end is among them,
        # or both its ends are infinite); all four nan stays nan, which no check proves
        o = _as(other)
        a, b = self.lo * o.lo, self.lo * o.hi
        c, d = self.hi * o.lo, self.hi * o.hi
        return Interval(*_out(np.fmin(np.fmin(a, b), np.fmin(c, d)),
                              np.fmax(np.fmax(a, b), np.fmax(c, d))))

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


def centred(middle: Array, radius: Array) -> Interval:
    """[middle - radius, middle + radius] (radius >= 0), rounded outwards."""
    m = np.asarray(middle, dtype=float)
    r = np.asarray(radius, dtype=float)
    return Interval(*_out(m - r, m + r))


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


@functools.lru_cache(maxsize=32)
def _taylor_operators(terms: int) -> tuple[Array, Array]:
    """For polynomials of ``terms`` coefficients: the exponents e[j, k] = j - k (clipped at 0)
    and the weights w[j, k] = binom(j, k) (0 where j < k), so that the k-th Taylor
    coefficient at m is sum_j c_j w[j, k] m^e[j, k] (read-only)."""
    j = np.arange(terms)[:, None]
    k = np.arange(terms)[None, :]
    exponent = np.maximum(j - k, 0)
    weight = np.array([[math.comb(a, b) if a >= b else 0 for b in range(terms)]
                       for a in range(terms)], dtype=float)
    for arr in (exponent, weight):
        arr.setflags(write=False)
    return exponent, weight


def poly(coefficients: Array, s_lo: Array, s_hi: Array) -> Interval:
    """Bounds of p(s) = sum_j c_j s^j over [s_lo, s_hi] (arrays (...)), coefficients
    (..., degree + 1) (one row per interval, or one for all): Taylor at the centre m,
    p(m) +- sum_k |p^(k)(m) / k!| r^k, widened by the rounding of its terms.

    The Taylor coefficients t_k = p^(k)(m) / k! = sum_j c_j binom(j, k) m^(j - k) are sums of
    degree + 1 products of at most degree + 2 rounded factors each, so each is within
    (2 degree + 4) eps of sum_j |c_j| binom(j, k) |m|^(j - k); the pad, 8 (degree + 1) eps
    times sum_k r^k of those sums, covers it with room."""
    c = np.broadcast_to(np.asarray(coefficients, dtype=float),
                        (*np.shape(s_lo), np.shape(coefficients)[-1]))
    terms = c.shape[-1]
    m = 0.5 * (s_lo + s_hi)
    r = 0.5 * (s_hi - s_lo)
    exponent, weight = _taylor_operators(terms)
    powers = np.asarray(m, dtype=float)[..., None] ** np.arange(terms)  # (..., terms)
    lifted = powers[..., exponent] * weight  # (..., j, k): binom(j, k) m^(j - k)
    taylor = np.einsum("...j,...jk->...k", c, lifted)  # (..., k)
    size = np.einsum("...j,...jk->...k", np.abs(c), np.abs(lifted))
    radius = np.asarray(r, dtype=float)[..., None] ** np.arange(terms)
    value = taylor[..., 0]
    spread = np.sum(np.abs(taylor[..., 1:]) * radius[..., 1:], axis=-1)
    scale = np.sum(size * radius, axis=-1)
    pad = 8.0 * terms * np.finfo(float).eps * scale  # rounding of the Taylor terms
    return Interval(*_out(value - spread - pad, value + spread + pad))


__all__ = ["Interval", "centred", "cos", "poly", "sin"]
