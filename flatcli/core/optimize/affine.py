"""The decision vector, and the coefficients and flat flag that are affine in it.

The boundary conditions are linear in the coefficients, and y2'(0) = k0 th1'(0),
y2'(T) = kT th1'(T) with k0, kT fixed by the end configurations (``flat_outputs``: y2' is
linear in u1). So the coefficients, and with them the flat flag
F(t) = (y1, y2, y1', y2', y1'', y2'') at any time, are affine in the decision vector

    x = (th1'(0), th1'(T), z1, z2[, s])

(the free end rates unless they are fixed; z_j: null-space coordinates of the boundary
matrix for output j; s: an epigraph variable, whose slope is zero). The slopes are constant,
so a problem evaluates the flag at its times once and forms it for any x as base + slope x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.basis import Basis
from flatcli.core.flatness import flat_outputs
from flatcli.core.model import Coefficients
from flatcli.core.planning import (
    boundary_conditions,
    boundary_system,
    min_acceleration_trajectory,
)

Array = NDArray[np.float64]

#: Derivative orders of the flat outputs in the flag: y, y', y''.
FLAG_ORDERS = 3


@dataclass(frozen=True)
class Affine:
    """Coefficients affine in the decision vector: C^T(x) = base + sum_v x_v slope[v].

    Attributes
    ----------
    basis : the flat outputs' basis on [0, T]
    base : (size, outputs) coefficients at x = 0
    slope : (nv, size, outputs) their derivative along each decision variable (nv counts
        every decision variable, an epigraph variable included)
    """

    basis: Basis
    base: Array
    slope: Array

    @property
    def outputs(self) -> int:
        """Number of flat outputs."""
        return int(self.base.shape[1])

    def coefficients(self, x: Array) -> Array:
        """(outputs, size) coefficients of the flat outputs at the decision vector x (nv,)."""
        return np.ascontiguousarray((self.base + np.tensordot(x, self.slope, axes=1)).T)

    def flag(self, t: Array) -> tuple[Array, Array]:
        """The flat flag at times t [s] as an affine function of x.

        Returns
        -------
        base : (3 outputs, n) the flag at x = 0, rows y1, y2, y1', y2', y1'', y2''
        slope : (3 outputs, n, nv) its constant derivative in x
        """
        p = self.outputs
        base = np.empty((FLAG_ORDERS * p, t.size))
        slope = np.empty((FLAG_ORDERS * p, t.size, self.slope.shape[0]))
        for order in range(FLAG_ORDERS):
            phi = self.basis.matrix(t, order)  # (n, size)
            for out in range(p):
                base[p * order + out] = phi @ self.base[:, out]
                slope[p * order + out] = phi @ self.slope[:, :, out].T
        return base, slope


def end_flat(k: Coefficients, theta: Array) -> tuple[float, float, float]:
    """Flat outputs at a configuration, and how y2' scales with th1' there.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    theta : (3,) th0, th1, th2 [rad]

    Returns
    -------
    y1, y2 [rad], and y2' / th1' [-] (y2' is linear in th1')
    """
    y1, y2, _, slope = flat_outputs(k, float(theta[0]), float(theta[1]), float(theta[2]), 1.0)
    return float(y1), float(y2), float(slope)


def affine_map(
    k: Coefficients,
    basis: Basis,
    start: Array,
    goal: Array,
    start_rate: float,
    goal_rate: float,
    free_rates: bool,
    epigraph: bool,
) -> tuple[Affine, Array]:
    """The affine coefficient map and the starting guess.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    basis : flat-output basis on [0, T]
    start, goal : (3,) end configurations [rad]
    start_rate, goal_rate : th1'(0), th1'(T) [rad/s]: of the starting guess, or the fixed end
        rates when ``free_rates`` is False
    free_rates : the end rates are decision variables
    epigraph : append an epigraph variable (zero slope)

    Returns
    -------
    affine : the map x -> coefficients
    curve : (nv without s,) the decision vector of the min-acceleration plan with the given
        end rates (the paper's cubic in any basis that contains cubics)
    """
    system = boundary_system(basis)  # type: ignore[arg-type]
    P = system.particular  # (size, 4)
    N = system.null  # (size, m)
    m = N.shape[1]
    y1_0, y2_0, k0 = end_flat(k, start)  # k0 = y2'(0) / th1'(0)
    y1_T, y2_T, kT = end_flat(k, goal)
    # boundary right-hand sides (rows y(0), y'(0), y(T), y'(T); columns y1, y2): the fixed
    # part R0, and the parts proportional to th1'(0) (Ra) and th1'(T) (Rb)
    R0 = np.zeros((4, 2))
    R0[0] = (y1_0, y2_0)
    R0[2] = (y1_T, y2_T)
    Ra = np.zeros((4, 2))
    Ra[1] = (1.0, k0)
    Rb = np.zeros((4, 2))
    Rb[3] = (1.0, kT)
    slopes: list[Array] = []
    if free_rates:
        base = P @ R0
        slopes += [P @ Ra, P @ Rb]
    else:
        base = P @ (R0 + start_rate * Ra + goal_rate * Rb)
    for out in range(2):
        for j in range(m):
            s = np.zeros((basis.size, 2))
            s[:, out] = N[:, j]
            slopes.append(s)
    if epigraph:
        slopes.append(np.zeros((basis.size, 2)))
    affine = Affine(basis, base, np.asarray(slopes).reshape(-1, basis.size, 2))
    bc = boundary_conditions(k, start, goal, start_rate, goal_rate)
    guess = min_acceleration_trajectory(basis, bc).coefficients.T  # (size, 2)
    rhs = R0 + start_rate * Ra + goal_rate * Rb
    z = N.T @ (guess - P @ rhs)  # (m, 2)
    rates = [start_rate, goal_rate] if free_rates else []
    return affine, np.concatenate([rates, z[:, 0], z[:, 1]])


__all__ = ["Affine", "affine_map", "end_flat"]
