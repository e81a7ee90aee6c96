"""Interval arithmetic (flatcli/core/plan/intervals.py): every bound against the exact value.

Referees: exact rational arithmetic (``fractions.Fraction`` of the floats, no rounding), so a
bound that is not rounded outwards, or a wrong formula, is caught even by an ulp; dense
sampling with numpy for cos and sin (whose values are not rational), with the closed-form
extremes (+-1 at the multiples of pi); and the bounds' width against the true range, so a
bound that is sound only because it gave up (inf, a wider enclosure) is caught too.
Inputs are random (hypothesis), NaN and empty (lo > hi) intervals included.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from flatcli.core.plan import intervals as iv
from flatcli.core.plan.intervals import Interval

#: Finite floats of a plan's magnitudes (angles, rates, lengths) and beyond.
FLOATS = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
#: How far a bound may exceed the true range for "tight" [relative to the range's scale]:
#: a few roundings of each operation.
TIGHT = 1e-12


@st.composite
def intervals(draw: st.DrawFn, low: float = -1e6, high: float = 1e6) -> tuple[float, float]:
    a = draw(st.floats(low, high, allow_nan=False, allow_infinity=False))
    b = draw(st.floats(low, high, allow_nan=False, allow_infinity=False))
    return (a, b) if a <= b else (b, a)


def box(pair: tuple[float, float]) -> Interval:
    return Interval(np.array([pair[0]]), np.array([pair[1]]))


def points(pair: tuple[float, float], fraction: float) -> list[Fraction]:
    """The ends and one point inside, exactly."""
    lo, hi = Fraction(pair[0]), Fraction(pair[1])
    return [lo, hi, lo + (hi - lo) * Fraction(fraction).limit_denominator(10**6)]


def vacuous(got: Interval) -> bool:
    """A bound that bounds nothing: (-inf, inf), a NaN end, or lo > hi (empty)."""
    lo, hi = float(got.lo[0]), float(got.hi[0])
    return not (lo <= hi) or (lo == -math.inf and hi == math.inf)


def contains(got: Interval, exact: Fraction) -> bool:
    return Fraction(float(got.lo[0])) <= exact <= Fraction(float(got.hi[0]))


@settings(deadline=None, max_examples=400)
@given(a=intervals(), b=intervals(), u=st.floats(0, 1), v=st.floats(0, 1))
def test_sums_differences_and_products_contain_the_exact_values(
        a: tuple[float, float], b: tuple[float, float], u: float, v: float) -> None:
    """Every exact x + z, x - z, x z, x^2 (x in a, z in b, in rational arithmetic) lies in
    the bounds: they are rounded outwards. And the bounds are the true range's ends to a
    rounding: not wider."""
    A, B = box(a), box(b)
    xs, zs = points(a, u), points(b, v)
    for got, f in ((A + B, lambda x, z: x + z), (A - B, lambda x, z: x - z),
                   (A * B, lambda x, z: x * z)):
        values = [f(x, z) for x in xs for z in zs]
        assert all(contains(got, value) for value in values)
        corners = [f(Fraction(x), Fraction(z)) for x in a for z in b]
        scale = max(abs(float(c)) for c in corners) + 1e-300
        assert float(min(corners)) - float(got.lo[0]) <= TIGHT * scale
        assert float(got.hi[0]) - float(max(corners)) <= TIGHT * scale
    square = A.square()
    assert all(contains(square, x * x) for x in xs)
    true_low = 0.0 if a[0] <= 0 <= a[1] else min(a[0] ** 2, a[1] ** 2)
    assert square.lo[0] <= true_low and true_low - square.lo[0] <= TIGHT * (
        max(a[0] ** 2, a[1] ** 2) + 1e-300)


@settings(deadline=None, max_examples=400)
@given(a=intervals(), b=intervals(), u=st.floats(0, 1), v=st.floats(0, 1))
def test_quotients_contain_the_exact_values_and_are_finite_off_zero(
        a: tuple[float, float], b: tuple[float, float], u: float, v: float) -> None:
    """x / z exactly within the bounds; a divisor interval that excludes 0 gives finite,
    tight bounds (one that holds 0 gives (-inf, inf), and nothing is proven from it)."""
    A, B = box(a), box(b)
    with np.errstate(all="ignore"):
        got = A / B
    if b[0] <= 0 <= b[1]:
        assert vacuous(got)
        return
    assume(min(abs(b[0]), abs(b[1])) > 1e-300)
    for x in points(a, u):
        for z in points(b, v):
            assert contains(got, x / z)
    corners = [Fraction(x) / Fraction(z) for x in a for z in b]
    scale = max(abs(float(c)) for c in corners) + 1e-300
    assert math.isfinite(got.lo[0]) and math.isfinite(got.hi[0])
    assert float(min(corners)) - float(got.lo[0]) <= TIGHT * scale
    assert float(got.hi[0]) - float(max(corners)) <= TIGHT * scale


@settings(deadline=None, max_examples=300)
@given(a=intervals(-100.0, 100.0))
def test_cos_and_sin_bound_every_value_and_reach_their_extremes(
        a: tuple[float, float]) -> None:
    """Sampled values within the bounds; the bounds are +-1 exactly where a maximum or
    minimum lies inside (2 k pi, pi + 2 k pi; sin's shifted by pi / 2), else the larger and
    smaller end value (to a rounding): neither too narrow nor needlessly wide."""
    A = box(a)
    x = np.linspace(a[0], a[1], 20001)
    for fn, got, shift in ((np.cos, iv.cos(A), 0.0), (np.sin, iv.sin(A), math.pi / 2)):
        values = fn(x)
        assert got.lo[0] <= values.min() and values.max() <= got.hi[0]
        assert -1.0 <= got.lo[0] <= got.hi[0] <= 1.0
        k_max = math.ceil((a[0] - shift) / (2 * math.pi))
        has_max = 2 * math.pi * k_max + shift <= a[1]
        k_min = math.ceil((a[0] - shift - math.pi) / (2 * math.pi))
        has_min = math.pi + 2 * math.pi * k_min + shift <= a[1]
        ends = fn(np.array(a))
        top = 1.0 if has_max else float(ends.max())
        bottom = -1.0 if has_min else float(ends.min())
        assert got.hi[0] - top <= 1e-9 and bottom - got.lo[0] <= 1e-9


def _exact_poly(c: list[float], s: Fraction) -> Fraction:
    total = Fraction(0)
    for j, cj in enumerate(c):
        total += Fraction(cj) * s**j
    return total


@settings(deadline=None, max_examples=300)
@given(c=st.lists(st.floats(-1e8, 1e8, allow_nan=False), min_size=1, max_size=9),
       centre=st.floats(-2.0, 2.0), half=st.sampled_from([0.0, 1e-12, 1e-6, 1e-3, 0.1, 1.0]),
       u=st.floats(0, 1))
def test_poly_contains_the_exact_polynomial_on_its_interval(
        c: list[float], centre: float, half: float, u: float) -> None:
    """p(s) in exact arithmetic at both ends and a point inside lies within the Taylor
    bound, for coefficients of mixed sign and size up to 1e8 (cancellation: the rounding pad
    is what holds it) and intervals from a point to width 2."""
    lo, hi = centre - half, centre + half
    got = iv.poly(np.array(c), np.array([lo]), np.array([hi]))
    for s in points((lo, hi), u):
        assert contains(got, _exact_poly(c, s))


def test_poly_is_tight_and_takes_one_row_per_interval() -> None:
    """The Taylor bound of a smooth polynomial converges to its range as the interval
    shrinks (first order); rows of coefficients go with their own intervals."""
    c = np.array([0.3, -1.0, 2.0, 0.5])
    for half in (1e-1, 1e-3, 1e-5):
        s = np.linspace(0.4 - half, 0.4 + half, 1001)
        values = np.polynomial.polynomial.polyval(s, c)
        got = iv.poly(c, np.array([0.4 - half]), np.array([0.4 + half]))
        assert (got.hi[0] - got.lo[0]) <= (values.max() - values.min()) * (1 + 10 * half) + 1e-15
    rows = np.array([[1.0, 0.0], [0.0, 1.0]])
    got = iv.poly(rows, np.array([0.0, 2.0]), np.array([1.0, 3.0]))
    assert got.lo[0] <= 1.0 <= got.hi[0] and got.hi[0] - got.lo[0] < 1e-12  # a constant
    assert got.lo[1] <= 2.0 and got.hi[1] >= 3.0 and got.hi[1] - got.lo[1] < 1 + 1e-12


def test_reciprocal_of_an_interval_off_zero_is_its_image() -> None:
    for lo, hi in ((2.0, 4.0), (-4.0, -2.0), (1e-3, 1e3)):
        got = Interval(np.array([lo]), np.array([hi])).reciprocal()
        assert got.lo[0] <= 1 / hi and got.hi[0] >= 1 / lo
        assert 1 / hi - got.lo[0] < 1e-15 * abs(1 / hi) + 1e-300
        assert got.hi[0] - 1 / lo < 1e-15 * abs(1 / lo) + 1e-300
    touching = Interval(np.array([0.0]), np.array([1.0])).reciprocal()
    assert touching.lo[0] == -math.inf and touching.hi[0] == math.inf


def test_magnitude_mignitude_and_hull() -> None:
    a = Interval(np.array([-3.0, 1.0, -2.0]), np.array([2.0, 4.0, -1.0]))
    assert a.magnitude().tolist() == [3.0, 4.0, 2.0]
    assert a.mignitude().tolist() == [0.0, 1.0, 1.0]
    h = a.hull(Interval(np.array([0.0, -5.0, 7.0]), np.array([1.0, 0.0, 8.0])))
    assert h.lo.tolist() == [-3.0, -5.0, -2.0] and h.hi.tolist() == [2.0, 4.0, 8.0]
    assert (-a).lo.tolist() == [-2.0, -4.0, 1.0]


def test_nan_and_empty_intervals_bound_nothing() -> None:
    """An interval with a NaN end gives NaN or (-inf, inf) through every operation, so the
    proof, which counts such a bound as unproven, proves nothing from it. (An empty interval,
    lo > hi, is no input of the arithmetic, whose results on valid inputs are never empty;
    the proof refuses one where it reads it: tests/test_clearance.py.)"""
    nan = Interval(np.array([math.nan]), np.array([math.nan]))
    one = Interval(np.array([1.0]), np.array([2.0]))
    with np.errstate(all="ignore"):
        for got in (nan + one, nan - one, nan * one, one * nan, nan / one, nan.square(),
                    iv.cos(nan), iv.sin(nan), one / nan):
            assert vacuous(got)
    half_nan = Interval(np.array([math.nan]), np.array([1.0]))
    assert not (half_nan.lo[0] <= half_nan.hi[0])


def test_products_with_an_infinite_end_keep_the_finite_side() -> None:
    """0 * inf among the corner products: [0, 2] x [1, inf] is [0, inf]; [-1, 0] x [1, inf]
    is [-inf, 0]; a nan from 0 * inf never replaces a finite corner (closed forms)."""
    up = Interval(np.array([1.0]), np.array([math.inf]))
    with np.errstate(invalid="ignore"):
        p = Interval(np.array([0.0]), np.array([2.0])) * up
        q = Interval(np.array([-1.0]), np.array([0.0])) * up
    assert p.lo[0] <= 0.0 and p.lo[0] > -1e-300 and p.hi[0] == math.inf
    assert q.lo[0] == -math.inf and 0.0 <= q.hi[0] < 1e-300


@pytest.mark.parametrize("width", [2 * math.pi, 7.0, 100.0])
def test_cos_of_a_wide_interval_is_the_whole_range(width: float) -> None:
    got = iv.cos(Interval(np.array([0.3]), np.array([0.3 + width])))
    assert got.lo[0] == -1.0 and got.hi[0] == 1.0
