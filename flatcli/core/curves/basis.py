"""Bases for the flat outputs, and the quadrature rules defined on them.

A basis is a family of scalar functions phi_j(t), j < size, on [0, T]; a flat output is
y(t) = sum_j c_j phi_j(t). Two families: scaled monomials (any degree >= 3; the paper's
cubic) and clamped B-splines on uniform knots (scipy). Each can also hand its curves over as
piecewise polynomials in a local variable s in [0, 1] per piece (``piecewise``), which is
what the compiled closed loop evaluates at the arbitrary times an adaptive integrator asks.

Quadrature lives here once: ``composite_gauss_legendre`` (equal pieces) and ``quadrature``
(Gauss-Legendre on each smooth piece of a basis, exact for its polynomials when the order is
high enough).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError

Array = NDArray[np.float64]


class Basis(Protocol):
    """A family of scalar functions phi_j(t), j < size, on [0, duration]."""

    @property
    def size(self) -> int: ...

    @property
    def duration(self) -> float: ...

    @property
    def breakpoints(self) -> Array:
        """Times where the basis may lose smoothness, including 0 and T [s]."""
        ...

    def matrix(self, t: Array, order: int) -> Array:
        """(n, size): d^order phi_j / dt^order at the times t (n,) [s]."""
        ...

    def piecewise(self, coefficients: Array) -> tuple[Array, Array]:
        """Curves ``coefficients`` (outputs, size) as piecewise polynomials.

        Returns
        -------
        breaks : (m + 1,) increasing piece boundaries [s], breaks[0] = 0, breaks[m] = T
        local : (m, degree + 1, outputs) coefficients of s^0 .. s^degree on each piece, with
            s = (t - breaks[i]) / (breaks[i + 1] - breaks[i]) in [0, 1]
        """
        ...


def _check_duration(duration: float) -> None:
    if not duration > 0:
        raise FlatcliError(f"plan.duration: must be > 0 s, got {duration}")


@dataclass(frozen=True)
class PolynomialBasis:
    """Scaled monomials phi_j(t) = (t/T)^j, j = 0..degree (well conditioned up to ~12)."""

    degree: int
    duration: float

    def __post_init__(self) -> None:
        if self.degree < 3:
            raise FlatcliError(f"plan.degree: must be >= 3 (a cubic), got {self.degree}")
        _check_duration(self.duration)

    @property
    def size(self) -> int:
        return self.degree + 1

    @property
    def breakpoints(self) -> Array:
        return np.array([0.0, self.duration])

    def matrix(self, t: Array, order: int) -> Array:
        s = np.asarray(t, dtype=float) / self.duration
        powers = np.vander(s, self.size, increasing=True)  # s^0 .. s^degree
        if order == 0:
            return powers
        j = np.arange(order, self.size)
        falling = np.ones(self.size - order)  # j! / (j - order)!
        for r in range(order):
            falling = falling * (j - r)
        out = np.zeros_like(powers)
        out[:, order:] = powers[:, : self.size - order] * (falling / self.duration**order)
        return out

    def piecewise(self, coefficients: Array) -> tuple[Array, Array]:
        local = np.ascontiguousarray(np.asarray(coefficients, dtype=float).T[None, :, :])
        return self.breakpoints, np.asarray(local, dtype=float)


@dataclass(frozen=True)
class BSplineBasis:
    """Clamped B-splines of a given degree on uniform knots over [0, duration] (scipy)."""

    size: int
    duration: float
    degree: int = 5
    knots: Array = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.degree < 3:
            raise FlatcliError(f"plan.degree: must be >= 3 for B-splines, got {self.degree}")
        if self.size < max(4, self.degree + 1):
            raise FlatcliError(
                f"plan.size: a degree-{self.degree} B-spline needs >= {max(4, self.degree + 1)} "
                f"coefficients, got {self.size}"
            )
        _check_duration(self.duration)
        inner = np.linspace(0.0, self.duration, self.size - self.degree + 1)
        knots = np.concatenate(
            [np.full(self.degree, 0.0), inner, np.full(self.degree, self.duration)]
        )
        object.__setattr__(self, "knots", knots)

    @property
    def breakpoints(self) -> Array:
        return np.unique(self.knots)

    def matrix(self, t: Array, order: int) -> Array:
        from scipy.interpolate import BSpline  # imported when B-splines are used

        spline = BSpline(self.knots, np.eye(self.size), self.degree, extrapolate=False)
        if order:
            spline = spline.derivative(order)
        tt = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        return np.asarray(spline(tt), dtype=float)

    def piecewise(self, coefficients: Array) -> tuple[Array, Array]:
        from scipy.interpolate import BSpline, PPoly

        c = np.asarray(coefficients, dtype=float)  # (outputs, size)
        per_output = [PPoly.from_spline(BSpline(self.knots, row, self.degree)) for row in c]
        x = per_output[0].x
        keep = np.flatnonzero(np.diff(x) > 0)  # drop the clamped ends' empty pieces
        breaks = np.append(x[keep], x[keep[-1] + 1])
        width = np.diff(breaks)  # (m,)
        # scipy: c[p, i] multiplies (t - x_i)^(degree - p); here s^j with t - x_i = w s
        powers = np.stack([pp.c[::-1][:, keep] for pp in per_output], axis=-1)  # (d+1, m, out)
        scale = width[None, :, None] ** np.arange(self.degree + 1)[:, None, None]
        local = np.ascontiguousarray(np.transpose(powers * scale, (1, 0, 2)), dtype=float)
        return np.ascontiguousarray(breaks, dtype=float), local


@dataclass(frozen=True)
class FlatTrajectory:
    """Flat outputs y(t) = coefficients @ phi(t) in a basis: coefficients (..., N, size) for
    the N outputs (a leading batch of plans allowed)."""

    basis: Basis
    coefficients: Array

    def derivative(self, t: Array, order: int) -> Array:
        """(..., n, N): d^order y / dt^order at times t (n,) [rad/s^order]."""
        phi = self.basis.matrix(np.atleast_1d(np.asarray(t, dtype=float)), order)
        return phi @ np.swapaxes(self.coefficients, -1, -2)

    def flags(self, t: Array) -> Array:
        """(n, 3 N) y, y', y'' at times t (n,) (one plan)."""
        return np.ascontiguousarray(np.hstack([self.derivative(t, k) for k in range(3)]))

    def piecewise(self) -> tuple[Array, Array]:
        """One curve as piecewise polynomials: ``Basis.piecewise`` of its coefficients."""
        if self.coefficients.ndim != 2:
            raise ValueError("FlatTrajectory.piecewise: one plan at a time")
        return self.basis.piecewise(self.coefficients)


def composite_gauss_legendre(duration: float, pieces: int, order: int) -> tuple[Array, Array]:
    """Nodes and weights of the Gauss-Legendre rule of ``order`` nodes on each of ``pieces``
    equal pieces of [0, duration] [s]."""
    return _gauss_legendre(np.linspace(0.0, duration, pieces + 1), order)


def quadrature(basis: Basis, count: int) -> tuple[Array, Array]:
    """Gauss-Legendre nodes and weights, ``count`` per smooth piece of the basis [s]."""
    return _gauss_legendre(basis.breakpoints, count)


@functools.lru_cache(maxsize=16)
def _legendre_nodes(order: int) -> tuple[Array, Array]:
    """Gauss-Legendre nodes and weights of ``order`` points on [-1, 1] (read-only)."""
    x, w = np.polynomial.legendre.leggauss(order)
    for arr in (x, w):
        arr.setflags(write=False)
    return x, w


def _gauss_legendre(edges: Array, order: int) -> tuple[Array, Array]:
    x, w = _legendre_nodes(order)
    lo, hi = edges[:-1, None], edges[1:, None]
    half = 0.5 * (hi - lo)
    return (half * (x + 1.0) + lo).ravel(), (half * w).ravel()
