"""Tests of flatcli.core.curves.basis: the bases, their piecewise form, and the quadrature rules.

References are independent of the code under test: numpy's ``Polynomial`` for monomials,
scipy's ``BSpline`` for B-splines, and closed-form integrals of polynomials.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from numpy.polynomial import Polynomial
from numpy.typing import NDArray
from scipy.interpolate import BSpline

from flatcli.core.curves.basis import (
    Basis,
    BSplineBasis,
    PolynomialBasis,
    composite_gauss_legendre,
    quadrature,
)
from flatcli.core.errors import FlatcliError

Array = NDArray[np.float64]

#: Identities that only rounding separates.
EXACT = 1e-11


def evaluate_piecewise(breaks: Array, local: Array, t: Array, order: int) -> Array:
    """(n, outputs): d^order/dt^order of the piecewise polynomials, with numpy Polynomial."""
    out = np.empty((t.size, local.shape[2]))
    piece = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, len(breaks) - 2)
    for i, (ti, p) in enumerate(zip(t, piece, strict=True)):
        width = breaks[p + 1] - breaks[p]
        for o in range(local.shape[2]):
            poly = Polynomial(local[p, :, o]).deriv(order) if order else Polynomial(local[p, :, o])
            out[i, o] = poly((ti - breaks[p]) / width) / width**order
    return out


@pytest.mark.parametrize(
    "basis", [PolynomialBasis(3, 2.0), PolynomialBasis(7, 1.5), BSplineBasis(12, 2.0, 5),
              BSplineBasis(6, 3.0, 3)], ids=repr,
)
@pytest.mark.parametrize("order", [0, 1, 2])
def test_piecewise_form_equals_the_basis(basis: Basis, order: int) -> None:
    rng = np.random.default_rng(3)
    coefficients = rng.normal(size=(2, basis.size))
    t = np.linspace(0.0, basis.duration, 97)
    expected = basis.matrix(t, order) @ coefficients.T
    breaks, local = basis.piecewise(coefficients)
    assert breaks[0] == 0.0 and breaks[-1] == pytest.approx(basis.duration, rel=1e-15)
    assert np.all(np.diff(breaks) > 0)
    got = evaluate_piecewise(breaks, local, t, order)
    np.testing.assert_allclose(got, expected, rtol=EXACT, atol=EXACT * np.max(np.abs(expected)))


def test_bspline_matrix_is_scipys() -> None:
    basis = BSplineBasis(9, 2.0, 5)
    c = np.random.default_rng(0).normal(size=9)
    t = np.linspace(0.0, 2.0, 31)
    reference = BSpline(basis.knots, c, 5)(t)
    np.testing.assert_allclose(basis.matrix(t, 0) @ c, reference, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize(("pieces", "order"), [(1, 4), (64, 8), (3, 2)])
def test_composite_gauss_legendre_integrates_polynomials_exactly(pieces: int, order: int) -> None:
    """A rule of ``order`` nodes per piece is exact up to degree 2 order - 1 (closed form:
    the integral of t^d over [0, T] is T^(d+1) / (d+1))."""
    T = 1.7
    nodes, weights = composite_gauss_legendre(T, pieces, order)
    assert nodes.size == weights.size == pieces * order
    assert np.all((nodes > 0) & (nodes < T))
    for degree in range(2 * order):
        assert weights @ nodes**degree == pytest.approx(T ** (degree + 1) / (degree + 1),
                                                        rel=1e-13)


def test_quadrature_follows_the_pieces_of_a_basis() -> None:
    """On each knot span of a B-spline basis: exact for the squared second derivatives."""
    basis = BSplineBasis(10, 2.0, 5)
    nodes, weights = quadrature(basis, basis.size + 2)
    edges = basis.breakpoints
    counts = np.histogram(nodes, bins=edges)[0]
    assert np.all(counts == basis.size + 2)
    c = np.random.default_rng(1).normal(size=basis.size)
    d2 = BSpline(basis.knots, c, 5).derivative(2)
    fine = np.linspace(0.0, 2.0, 400_001)
    square = d2(fine) ** 2
    trapezoid = float(np.sum((square[1:] + square[:-1]) * np.diff(fine)) / 2)
    assert weights @ d2(nodes) ** 2 == pytest.approx(trapezoid, rel=1e-8)


@pytest.mark.parametrize(
    "build",
    [
        lambda: PolynomialBasis(2, 1.0),
        lambda: PolynomialBasis(3, 0.0),
        lambda: BSplineBasis(5, 1.0, 5),
        lambda: BSplineBasis(6, 1.0, 2),
    ],
)
def test_bases_reject_unusable_shapes(build: Callable[[], Basis]) -> None:
    with pytest.raises(FlatcliError):
        build()
