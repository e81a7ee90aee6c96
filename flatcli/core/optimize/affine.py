"""The decision vector, and the coefficients and flat flag that are affine in it.

The boundary conditions are linear in the coefficients, and the flat outputs' rates at an
end are linear in the joint rates there: for the paper's robot y1' = th1', y2' = k th1' with
k fixed by the end configuration (``flat_outputs``); for a chain of N joints y_j' = th_j'
(j < N) and y_N' = -(S + I_N th_N D / h_0) / h_0, S and D linear in th_1'..th_N-1'
(``chainflat.outputs``). So the coefficients, and with them the flat flag
F(t) = (y, y', y'') at any time, are affine in the decision vector

    x = (u(0), u(T), z_1, ..., z_N[, s])

(u: the free end rates th_1'..th_N-1' unless they are fixed, th1' alone for the paper's
robot; z_j: null-space coordinates of the boundary matrix for output j; s: an epigraph
variable, whose slope is zero). The slopes are constant, so a problem evaluates the flag at
its times once and forms it for any x as base + slope x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.curves.basis import Basis
from flatcli.core.optimize.quantities import Flat
from flatcli.core.plan.planning import boundary_system, min_acceleration_trajectory

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
        base : (3 outputs, n) the flag at x = 0, rows y, y', y'' (y1, y2, y1', ... for two
            outputs)
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


def end_map(k: Flat, theta: Array) -> tuple[Array, Array]:
    """Flat outputs at a configuration, and how their rates follow the joint rates there
    (``FlatModel.end_map``).

    Parameters
    ----------
    k : the flat model the planner believes
    theta : (N + 1,) th0..thN [rad]

    Returns
    -------
    y : (N,) the flat outputs [rad]
    slope : (N, N - 1) dy'/du, u = (th_1'..th_N-1') [-]: y' = slope @ u
    """
    return k.end_map(theta)


def affine_map(
    k: Flat,
    basis: Basis,
    start: Array,
    goal: Array,
    start_rate: float | Array,
    goal_rate: float | Array,
    free_rates: bool,
    epigraph: bool,
) -> tuple[Affine, Array]:
    """The affine coefficient map and the starting guess.

    Parameters
    ----------
    k : the flat model the planner believes
    basis : flat-output basis on [0, T]
    start, goal : (N + 1,) end configurations [rad]
    start_rate, goal_rate : end rates u(0), u(T) (th1' for the paper's robot, (N - 1,)
        th_1'..th_N-1' for a chain) [rad/s]: of the starting guess, or the fixed end rates
        when ``free_rates`` is False
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
    y_0, slope_0 = end_map(k, start)  # y'(0) = slope_0 @ u(0)
    y_T, slope_T = end_map(k, goal)
    p, r = slope_0.shape  # outputs, end rates per end
    u_0 = np.atleast_1d(np.asarray(start_rate, dtype=float))
    u_T = np.atleast_1d(np.asarray(goal_rate, dtype=float))
    # boundary right-hand sides (rows y(0), y'(0), y(T), y'(T); columns the outputs): the
    # fixed part R0, and the parts proportional to each end rate at t = 0 (Ra) and T (Rb)
    R0 = np.zeros((4, p))
    R0[0] = y_0
    R0[2] = y_T
    Ra = np.zeros((r, 4, p))
    Ra[:, 1] = slope_0.T
    Rb = np.zeros((r, 4, p))
    Rb[:, 3] = slope_T.T
    rhs = R0
    for j in range(r):
        rhs = rhs + u_0[j] * Ra[j]
    for j in range(r):
        rhs = rhs + u_T[j] * Rb[j]
    slopes: list[Array] = []
    if free_rates:
        base = P @ R0
        slopes += [P @ R for R in (*Ra, *Rb)]
    else:
        base = P @ rhs
    for out in range(p):
        for j in range(m):
            s = np.zeros((basis.size, p))
            s[:, out] = N[:, j]
            slopes.append(s)
    if epigraph:
        slopes.append(np.zeros((basis.size, p)))
    affine = Affine(basis, base, np.asarray(slopes).reshape(-1, basis.size, p))
    bc = k.boundary(start, goal, u_0, u_T)
    guess = min_acceleration_trajectory(basis, bc).coefficients.T  # (size, p)
    z = N.T @ (guess - P @ rhs)  # (m, p)
    rates = np.concatenate([u_0, u_T]) if free_rates else np.zeros(0)
    return affine, np.concatenate([rates, *z.T])


__all__ = ["Affine", "affine_map", "end_map"]
