"""Flat outputs of the counterweighted robot (d2 = 0) and the maps to and from them.

With d2 = 0 the constraint is ``A(th1) th0' = B(th1) th1' + c0 th2'`` with
``A = a0 + a1 cos th1`` and ``B = b0 + b1 cos th1`` (Franch et al. 2003, eq. 31). Prolonging
the input u1 = th1' gives the state (th0, th1, th2, u1) and inputs (u1', u2 = th2'), and

    y1 = th1,    y2 = th0 - c0 th2 / A(th1)                         (eqs. 34-35)

are flat outputs. Writing g = B/A and h = c0 a1 sin th1 / A^2 (``chart``):

    y2' = (g - h th2) u1                                           (eq. 36)
    y2'' = (g - h th2) u1' + (g' - h' th2) u1^2 - h u1 u2          (eq. 39, gamma3 corrected)

Each formula lives here once:

* ``chart`` and ``chart_slopes``: g, h, 1/A and their th1-derivatives;
* ``outputs_at``: the forward map, state -> (y, y');
* ``inputs_at``: the inputs (u1', u2) that realise wanted flat accelerations at a state;
* ``flag_state``: the inverse map, the flat flag (y, y', y'') -> state, inputs and th0'.

The controller (``control``), the metrics, the planner (``planning``) and the optimiser call
these; ``flat_outputs``, ``flat_state``, ``flat_inputs`` and ``flat_accelerations`` are the
same maps with the trigonometry done for the caller. The maps are singular where h u1 = 0,
i.e. where the *singularity margin* |sin y1 * y1'| vanishes: there they return inf or nan,
and every caller reads ``singularity_margin`` and decides.

All functions take floats or broadcastable arrays of any batch shape (...), real or complex
(complex-step safe), and a ``Coefficients`` whose d2-terms (a2, a3, b2, b3, c2, c3) are zero;
they are plain numpy code that numba also compiles into the closed-loop kernel.
"""

from __future__ import annotations

import numpy as np

from flatcli.core._jit import Real, jitable
from flatcli.core.robots.params import Coefficients


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
def outputs_at(
    k: Coefficients, inv_A: Real, g: Real, h: Real, th0: Real, th1: Real, th2: Real, u1: Real
) -> tuple[Real, Real, Real, Real]:
    """Forward map (eqs. 34-36) given ``chart`` at th1: y1, y2 [rad], y1', y2' [rad/s]."""
    return th1, th0 - k.c0 * th2 * inv_A, u1, (g - h * th2) * u1


@jitable
def inputs_at(
    g: Real, h: Real, g_prime: Real, h_prime: Real, th2: Real, u1: Real, y1_ddot: Real,
    y2_ddot: Real,
) -> tuple[Real, Real]:
    """Inputs (u1', u2) that make the flat accelerations (y1'', y2''), by solving eq. 39.

    Given ``chart`` and ``chart_slopes`` at th1: y2'' = alpha u1' + beta - gamma u2 with
    alpha = g - h th2, beta = (g' - h' th2) u1^2 and gamma = h u1, so
    u2 = (alpha y1'' + beta - y2'') / gamma; inf/nan where gamma = 0.
    """
    alpha = g - h * th2
    return y1_ddot, (alpha * y1_ddot + (g_prime - h_prime * th2) * u1 * u1 - y2_ddot) / (h * u1)


@jitable
def flag_state(
    k: Coefficients, y1: Real, y2: Real, y1_dot: Real, y2_dot: Real, y1_ddot: Real,
    y2_ddot: Real,
) -> tuple[Real, Real, Real, Real, Real, Real, Real]:
    """Inverse map: the flat flag to the state, the inputs and th0' (eqs. 36-38, corrected).

    th2 = (g y1' - y2') / (h y1') from eq. 36, th0 = y2 + c0 th2 / A from eq. 35, the
    inputs from ``inputs_at``, and th0' = y2' + c0 (th2' / A + th2 a1 sin y1 y1' / A^2), the
    exact time derivative of eq. 35 (not the momentum constraint).

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    y1, y2 : flat outputs [rad], (...)
    y1_dot, y2_dot : their rates [rad/s], (...)
    y1_ddot, y2_ddot : their accelerations [rad/s^2], (...)

    Returns
    -------
    th0, th1, th2 [rad], u1 = th1' [rad/s], u1' [rad/s^2], u2 = th2' [rad/s], th0' [rad/s]:
    (...); inf/nan where sin y1 * y1' = 0
    """
    c1 = np.cos(y1)
    s1 = np.sin(y1)
    inv_A, g, h = chart(k, c1, s1)
    g_prime, h_prime = chart_slopes(k, c1, s1, inv_A, g)
    th2 = (g * y1_dot - y2_dot) / (h * y1_dot)
    u1_dot, u2 = inputs_at(g, h, g_prime, h_prime, th2, y1_dot, y1_ddot, y2_ddot)
    th0_dot = y2_dot + k.c0 * (u2 * inv_A + th2 * k.a1 * s1 * y1_dot * inv_A * inv_A)
    return y2 + k.c0 * th2 * inv_A, y1, th2, y1_dot, u1_dot, u2, th0_dot


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
    return outputs_at(k, inv_A, g, h, th0, th1, th2, u1)


@jitable
def flat_state(
    k: Coefficients, y1: Real, y2: Real, y1_dot: Real, y2_dot: Real
) -> tuple[Real, Real, Real, Real]:
    """Inverse map: flat outputs and rates to the state (the state part of ``flag_state``).

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
    c1 = np.cos(th1)
    s1 = np.sin(th1)
    inv_A, g, h = chart(k, c1, s1)
    g_prime, h_prime = chart_slopes(k, c1, s1, inv_A, g)
    return inputs_at(g, h, g_prime, h_prime, th2, u1, y1_ddot, y2_ddot)


@jitable
def flat_accelerations(
    k: Coefficients, th1: Real, th2: Real, u1: Real, u1_dot: Real, u2: Real
) -> tuple[Real, Real]:
    """Flat accelerations (y1'', y2'') produced by inputs (u1', u2) at a state (eq. 39).

    Returns
    -------
    y1_ddot, y2_ddot : (...) [rad/s^2]
    """
    c1 = np.cos(th1)
    s1 = np.sin(th1)
    inv_A, g, h = chart(k, c1, s1)
    g_prime, h_prime = chart_slopes(k, c1, s1, inv_A, g)
    return u1_dot, (g - h * th2) * u1_dot + (g_prime - h_prime * th2) * u1 * u1 - h * u1 * u2


@jitable
def signed_margin(y1: Real, y1_dot: Real) -> Real:
    """sin y1 * y1' [rad/s]: its sign flips exactly where a path crosses the singular set."""
    return np.sin(y1) * y1_dot


@jitable
def singularity_margin(y1: Real, y1_dot: Real) -> Real:
    """|sin y1 * y1'|: zero exactly on the singular set of the flat maps [rad/s], (...)."""
    return np.abs(np.sin(y1) * y1_dot)
