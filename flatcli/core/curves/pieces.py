"""Curves as piecewise polynomials: a basis, fitting at Chebyshev nodes, and integration.

An exact plan (``exact``) and the as-built controller's reference (``lqr``) hold curves that
are not polynomials in t: the base attitude th0(t), the integral of the momentum constraint,
and the feedback gains of a Riccati equation. They are represented as what the compiled
closed loop already evaluates (``integrate.plan_flag``): on each piece [b_i, b_i+1] of [0, T]
a polynomial sum_j a_ij s^j in the local variable s = (t - b_i) / (b_i+1 - b_i) in [0, 1].

* ``PiecewiseBasis`` is that family as a ``basis.Basis`` (its coefficients are the local
  ones, piece after piece), so the curves are a ``basis.FlatTrajectory`` like any plan's;
  ``PiecewiseCurves`` evaluates them piece by piece (Horner), not through the dense basis
  matrix.
* ``fit`` interpolates values given at ``chebyshev_nodes`` of each piece (a polynomial of the
  basis's degree is reproduced to rounding; a smooth function to spectral accuracy);
  ``integral`` integrates curves exactly, piece by piece, from a start value.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.curves.basis import FlatTrajectory

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PiecewiseBasis:
    """Polynomials of ``degree`` in s on each piece between ``breaks`` (m + 1 increasing
    times [s], breaks[0] = 0): coefficient i (degree + 1) + j multiplies s^j on piece i."""

    breaks: tuple[float, ...]
    degree: int

    @property
    def pieces(self) -> int:
        return len(self.breaks) - 1

    @property
    def size(self) -> int:
        return self.pieces * (self.degree + 1)

    @property
    def duration(self) -> float:
        return float(self.breaks[-1])

    @property
    def breakpoints(self) -> Array:
        return np.asarray(self.breaks, dtype=float)

    def locate(self, t: Array) -> tuple[NDArray[np.intp], Array, Array]:
        """For times t (n,) [s]: the piece of each (clamped to the first and last), its local
        s and its width [s]."""
        edges = self.breakpoints
        piece = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, self.pieces - 1)
        width = edges[piece + 1] - edges[piece]
        return piece, (t - edges[piece]) / width, width

    def matrix(self, t: Array, order: int) -> Array:
        """(n, size): d^order phi / dt^order at the times t (n,) (dense; for small n)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        piece, s, width = self.locate(t)
        rows = _power_rows(s, self.degree, order) / width[:, None] ** order
        out = np.zeros((t.size, self.size))
        cols = piece[:, None] * (self.degree + 1) + np.arange(self.degree + 1)
        np.put_along_axis(out, cols, rows, axis=1)
        return out

    def piecewise(self, coefficients: Array) -> tuple[Array, Array]:
        c = np.asarray(coefficients, dtype=float)  # (outputs, size)
        local = c.reshape(c.shape[0], self.pieces, self.degree + 1).transpose(1, 2, 0)
        return self.breakpoints, np.ascontiguousarray(local)


def _power_rows(s: Array, degree: int, order: int) -> Array:
    """(n, degree + 1): d^order s^j / ds^order at s (n,)."""
    j = np.arange(degree + 1)
    falling = np.ones(degree + 1)
    for r in range(order):
        falling = falling * (j - r)
    power = np.clip(j - order, 0, None)
    return np.where(j >= order, falling * s[:, None] ** power, 0.0)


@dataclass(frozen=True)
class PiecewiseCurves(FlatTrajectory):
    """Curves in a ``PiecewiseBasis`` (coefficients (outputs, size)), evaluated piece by piece."""

    basis: PiecewiseBasis

    @functools.cached_property
    def local(self) -> Array:
        """(m, degree + 1, outputs) the local coefficients (computed once: the Riccati
        equation's right-hand side evaluates the curves thousands of times)."""
        return self.basis.piecewise(self.coefficients)[1]

    def derivative(self, t: Array, order: int) -> Array:
        """(n, outputs): d^order / dt^order of every curve at times t (n,) [s]."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        piece, s, width = self.basis.locate(t)
        rows = _power_rows(s, self.basis.degree, order) / width[:, None] ** order
        return np.asarray(np.einsum("nj,njo->no", rows, self.local[piece]), dtype=float)


@functools.lru_cache(maxsize=32)
def chebyshev_nodes(count: int) -> Array:
    """(count,) Chebyshev points of the first kind mapped to s in (0, 1) (read-only)."""
    k = np.arange(count)
    nodes = 0.5 - 0.5 * np.cos((2 * k + 1) * math.pi / (2 * count))
    nodes.setflags(write=False)
    return nodes


@functools.lru_cache(maxsize=32)
def _chebyshev_matrices(degree: int) -> tuple[Array, Array]:
    """(values -> Chebyshev coefficients, Chebyshev -> monomial coefficients in s), both
    (degree + 1, degree + 1), for values at ``chebyshev_nodes``.

    The first is the discrete orthogonality of T_j at the nodes (entries at most 1 in size);
    the second holds the integer coefficients of T_j(2 s - 1), exact in floating point. Going
    through the Chebyshev coefficients, whose rounding errors stay Chebyshev-sized, keeps the
    interpolant accurate to rounding in value; inverting the monomial Vandermonde matrix
    (condition 1e6 at degree 9) would not."""
    count = degree + 1
    k = np.arange(count)
    x = -np.cos((2 * k + 1) * math.pi / (2 * count))  # 2 s - 1 at the nodes
    values = np.cos(np.outer(np.arange(count), np.arccos(x))) * (2.0 / count)  # T_j(x_k)
    values[0] *= 0.5
    monomial = np.zeros((count, count))
    for j in range(count):
        unit = np.zeros(count)
        unit[j] = 1.0
        power_x = np.polynomial.chebyshev.cheb2poly(unit)  # T_j in powers of x = 2 s - 1
        power_s = np.polynomial.polynomial.Polynomial(power_x)(
            np.polynomial.polynomial.Polynomial([-1.0, 2.0])).coef
        monomial[: power_s.size, j] = power_s
    for a in (values, monomial):
        a.setflags(write=False)
    return values, monomial


def node_times(breaks: ArrayLike, degree: int) -> Array:
    """(m, degree + 1) the times [s] of the ``chebyshev_nodes`` of every piece."""
    edges = np.asarray(breaks, dtype=float)
    return edges[:-1, None] + np.diff(edges)[:, None] * chebyshev_nodes(degree + 1)


def fit(breaks: ArrayLike, degree: int, values: Array) -> PiecewiseCurves:
    """The piecewise polynomials of ``degree`` through ``values`` (m, degree + 1, outputs)
    given at ``node_times(breaks, degree)``."""
    to_chebyshev, to_monomial = _chebyshev_matrices(degree)
    chebyshev = np.einsum("jk,mko->mjo", to_chebyshev, values)
    local = np.einsum("ij,mjo->mio", to_monomial, chebyshev)
    return curves(breaks, local)


def curves(breaks: ArrayLike, local: Array) -> PiecewiseCurves:
    """``PiecewiseCurves`` of local coefficients (m, degree + 1, outputs)."""
    m, size, outputs = local.shape
    basis = PiecewiseBasis(tuple(float(b) for b in np.asarray(breaks, dtype=float)), size - 1)
    coefficients = np.ascontiguousarray(local.transpose(2, 0, 1).reshape(outputs, m * size))
    return PiecewiseCurves(basis, coefficients)


def integral(rates: PiecewiseCurves, start: ArrayLike) -> PiecewiseCurves:
    """The curves x(t) = start + integral_0^t rates, exactly (one degree more per piece);
    ``start`` (outputs,)."""
    local = rates.local  # (m, d + 1, outputs)
    m, size, outputs = local.shape
    width = np.diff(rates.basis.breakpoints)
    out = np.zeros((m, size + 1, outputs))
    out[:, 1:, :] = local / np.arange(1, size + 1)[None, :, None] * width[:, None, None]
    gains = out.sum(axis=1)  # (m, outputs): what each piece adds
    out[:, 0, :] = np.asarray(start, dtype=float) + np.concatenate(
        [np.zeros((1, outputs)), np.cumsum(gains, axis=0)[:-1]])
    return curves(rates.basis.breakpoints, out)


def joined(parts: list[PiecewiseCurves]) -> PiecewiseCurves:
    """Curves on the same breaks side by side (outputs in order), raised to the highest
    degree among them."""
    degree = max(p.basis.degree for p in parts)
    locals_ = []
    for p in parts:
        local = p.local
        pad = degree + 1 - local.shape[1]
        locals_.append(np.pad(local, ((0, 0), (0, pad), (0, 0))))
    return curves(parts[0].basis.breakpoints, np.concatenate(locals_, axis=2))


__all__ = ["PiecewiseBasis", "PiecewiseCurves", "chebyshev_nodes", "curves", "fit",
           "integral", "joined", "node_times"]
