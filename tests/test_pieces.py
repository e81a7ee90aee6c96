"""Tests of flatcli.core.curves.pieces: curves as piecewise polynomials.

Referees: numpy's own polynomial evaluation and integration (``numpy.polynomial``), and
closed-form functions (sin, exp) with their derivatives and integrals.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import polynomial as npp

from flatcli.core.curves.pieces import PiecewiseBasis, curves, fit, integral, joined, node_times

#: A polynomial of the fit's degree comes back to rounding (relative to its size).
ROUNDING = 1e-12
#: A smooth function's interpolant on 32 pieces of degree 11: spectral accuracy.
SPECTRAL = 1e-12


def test_fit_reproduces_a_polynomial_and_its_derivatives() -> None:
    """Referee: numpy.polynomial's evaluation of the same polynomial and its derivatives."""
    rng = np.random.default_rng(1)
    coef = rng.normal(size=8)  # degree 7 in t
    edges = np.linspace(0.0, 2.0, 9)
    times = node_times(edges, 9)
    c = fit(edges, 9, npp.polyval(times, coef)[..., None])
    t = rng.uniform(0.0, 2.0, 500)
    for order in range(3):
        want = npp.polyval(t, npp.polyder(coef, order)) if order else npp.polyval(t, coef)
        got = c.derivative(t, order)[:, 0]
        np.testing.assert_allclose(got, want, atol=ROUNDING * 1e3 ** order)


def test_fit_of_a_smooth_function_and_its_exact_integral() -> None:
    """Referee: sin(3t) exp(t/2), its derivative and its integral in closed form."""
    def f(t: np.ndarray) -> np.ndarray:
        return np.sin(3 * t) * np.exp(t / 2)

    def antiderivative(t: np.ndarray) -> np.ndarray:  # of f, by parts
        return np.exp(t / 2) * (0.5 * np.sin(3 * t) - 3 * np.cos(3 * t)) / (0.25 + 9)

    edges = np.linspace(0.0, 2.0, 33)
    c = fit(edges, 11, f(node_times(edges, 11))[..., None])
    t = np.linspace(0.0, 2.0, 1001)
    np.testing.assert_allclose(c.derivative(t, 0)[:, 0], f(t), atol=SPECTRAL)
    start = 0.7
    x = integral(c, [start])
    assert x.basis.degree == 12
    np.testing.assert_allclose(x.derivative(t, 0)[:, 0],
                               start + antiderivative(t) - antiderivative(np.zeros(1)),
                               atol=SPECTRAL)
    np.testing.assert_allclose(x.derivative(t, 1)[:, 0], f(t), atol=SPECTRAL)


def test_basis_matrix_and_curves_agree_and_join() -> None:
    """Referee: the dense basis matrix (``PiecewiseBasis.matrix``) against the piece-by-piece
    evaluation, and joined curves keeping each channel's values."""
    rng = np.random.default_rng(2)
    local = rng.normal(size=(4, 6, 2))
    edges = np.array([0.0, 0.3, 0.5, 1.1, 2.0])
    c = curves(edges, local)
    assert isinstance(c.basis, PiecewiseBasis) and c.basis.size == 24
    t = rng.uniform(0.0, 2.0, 50)
    for order in range(3):
        dense = c.basis.matrix(t, order) @ c.coefficients.T
        np.testing.assert_allclose(c.derivative(t, order), dense, rtol=1e-12, atol=1e-9)
    low = curves(edges, local[:, :3, :1])
    both = joined([low, c])
    np.testing.assert_allclose(both.derivative(t, 0)[:, 0], low.derivative(t, 0)[:, 0])
    np.testing.assert_allclose(both.derivative(t, 1)[:, 1:], c.derivative(t, 1))
    breaks, pieces = both.piecewise()
    np.testing.assert_array_equal(breaks, edges)
    assert pieces.shape == (4, 6, 3)
