"""Flat outputs of the counterweighted robot (d2 = 0) and the maps to and from them.

With d2 = 0 the constraint is ``A(th1) th0' = B(th1) th1' + c0 th2'`` with
``A = a0 + a1 cos th1`` and ``B = b0 + b1 cos th1`` (Franch et al. 2003, eq. 31). Prolonging
the input u1 = th1' gives the state (th0, th1, th2, u1) and inputs (u1', u2 = th2'), and

    y1 = th1,    y2 = th0 - c0 th2 / A(th1)                         (eqs. 34-35)

are flat outputs. Writing g = B/A and h = c0 a1 sin th1 / A^2:

    y2' = (g - h th2) u1
    y2'' = (g - h th2) u1' + (g' - h' th2) u1^2 - h u1 u2

so the maps below are exact, and singular where h u1 = 0, i.e. where the *singularity margin*
|sin y1 * y1'| vanishes. Nothing here hides that: at the singular set the maps return
inf or nan, and every caller reads ``singularity_margin`` and decides.

All functions take floats or broadcastable arrays of any batch shape (...), and a
``Coefficients`` whose d2-terms (a2, a3, b2, b3, c2, c3) are zero; they are plain numpy code
that numba can also compile into the closed-loop kernel.
"""

from __future__ import annotations

import numpy as np

from flatcli.core._jit import Real, jitable
from flatcli.core.model import Coefficients


@jitable
def chart(k: Coefficients, c1: Real, s1: Real) -> tuple[Real, Real, Real]:
    """1/A, g = B/A and h = c0 a1 sin th1 / A^2 (A = a0 + a1 cos th1), from cos th1, sin th1."""
    inv_A = 1.0 / (k.a0 + k.a1 * c1)
    return inv_A, (k.b0 + k.b1 * c1) * inv_A, k.c0 * k.a1 * s1 * inv_A * inv_A


@jitable
def chart_slopes(k: Coefficients, c1: Real, s1: Real, inv_A: Real, g: Real) -> tuple[Real, Real]:
    """dg/dth1 and dh/dth1, given 1/A and g from ``chart`` at the same th1."""
    g_prime = (g * k.a1 - k.b1) * s1 * inv_A
    h_prime = k.c0 * k.a1 * (c1 + 2.0 * k.a1 * s1 * s1 * inv_A) * inv_A * inv_A
    return g_prime, h_prime


@jitable
def _acceleration_terms(k: Coefficients, th1: Real, th2: Real, u1: Real) -> tuple[Real, Real, Real]:
    """(alpha, beta, gamma) with y2'' = alpha u1' + beta - gamma u2 at a state."""
    c1 = np.cos(th1)
    s1 = np.sin(th1)
    inv_A, g, h = chart(k, c1, s1)
    g_prime, h_prime = chart_slopes(k, c1, s1, inv_A, g)
    return g - h * th2, (g_prime - h_prime * th2) * u1 * u1, h * u1


@jitable
def flat_outputs(
    k: Coefficients, th0: Real, th1: Real, th2: Real, u1: Real
) -> tuple[Real, Real, Real, Real]:
    """Forward map: state (th, u1) to flat outputs and their rates.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    th0, th1, th2 : angles [rad], (...)
    u1 : th1' [rad/s], (...)

    Returns
    -------
    y1 [rad], y2 [rad], y1_dot [rad/s], y2_dot [rad/s] : (...)
    """
    inv_A, g, h = chart(k, np.cos(th1), np.sin(th1))
    return th1, th0 - k.c0 * th2 * inv_A, u1, (g - h * th2) * u1


@jitable
def flat_state(
    k: Coefficients, y1: Real, y2: Real, y1_dot: Real, y2_dot: Real
) -> tuple[Real, Real, Real, Real]:
    """Inverse map: flat outputs and rates to the state (eqs. 36-38, corrected).

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    y1, y2 : flat outputs [rad], (...)
    y1_dot, y2_dot : their rates [rad/s], (...)

    Returns
    -------
    th0, th1, th2 [rad], u1 [rad/s] : (...); inf/nan where sin y1 * y1_dot = 0
    """
    inv_A, g, h = chart(k, np.cos(y1), np.sin(y1))
    th2 = (g * y1_dot - y2_dot) / (h * y1_dot)
    return y2 + k.c0 * th2 * inv_A, y1, th2, y1_dot


@jitable
def flat_inputs(
    k: Coefficients, th1: Real, th2: Real, u1: Real, y1_ddot: Real, y2_ddot: Real
) -> tuple[Real, Real]:
    """Inputs (u1', u2) that realise the flat accelerations (y1'', y2'') from a state.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    th1, th2 : joint angles [rad], (...)
    u1 : th1' [rad/s], (...)
    y1_ddot, y2_ddot : wanted flat accelerations [rad/s^2], (...)

    Returns
    -------
    u1_dot [rad/s^2], u2 = th2' [rad/s] : (...); inf/nan where sin th1 * u1 = 0
    """
    alpha, beta, gamma = _acceleration_terms(k, th1, th2, u1)
    return y1_ddot, (alpha * y1_ddot + beta - y2_ddot) / gamma


@jitable
def flat_accelerations(
    k: Coefficients, th1: Real, th2: Real, u1: Real, u1_dot: Real, u2: Real
) -> tuple[Real, Real]:
    """Flat accelerations (y1'', y2'') produced by inputs (u1', u2) at a state.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    th1, th2 : joint angles [rad], (...)
    u1 : th1' [rad/s], (...)
    u1_dot : [rad/s^2], (...)
    u2 : th2' [rad/s], (...)

    Returns
    -------
    y1_ddot, y2_ddot : (...) [rad/s^2]
    """
    alpha, beta, gamma = _acceleration_terms(k, th1, th2, u1)
    return u1_dot, alpha * u1_dot + beta - gamma * u2


@jitable
def singularity_margin(y1: Real, y1_dot: Real) -> Real:
    """|sin y1 * y1'|: zero exactly on the singular set of the flat maps [rad/s], (...)."""
    return np.abs(np.sin(y1) * y1_dot)


def margin_factors(y1: Real, y1_dot: Real) -> tuple[Real, Real]:
    """The two factors of the margin: |sin y1| [-] and |y1'| [rad/s], each (...)."""
    return np.abs(np.sin(y1)), np.abs(y1_dot)
