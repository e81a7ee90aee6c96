"""The linearising feedback of Franch et al. (2003), eqs. 39-42.

The controller knows the prolonged state (th0, th1, th2, u1) (the angles measured, perhaps
with noise; u1 is its own integrator state), computes the flat outputs and rates with its
*nominal* model, asks for

    v_i = y_id'' + kv_i (y_id' - y_i') + kp_i (y_id - y_i),    i = 1, 2

and returns the inputs (u1', u2) that make y'' = v (``flatness.flat_inputs`` of v at the
state, computed here in one pass). With an exact model the flat-output
errors e = y_d - y then obey e'' + kv e' + kp e = 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import Real, jitable
from flatcli.core.flatness import chart, chart_slopes
from flatcli.core.model import Coefficients

Array = NDArray[np.float64]


class Gains(NamedTuple):
    """Feedback gains: kp [1/s^2] and kv [1/s] for the two flat outputs."""

    kp1: float
    kp2: float
    kv1: float
    kv2: float


class Reference(NamedTuple):
    """The desired flat outputs at one instant (floats or arrays (...))."""

    y1: float
    y2: float
    y1_dot: float
    y2_dot: float
    y1_ddot: float
    y2_ddot: float


@jitable
def feedback(
    k: Coefficients,
    gains: Gains,
    th0: Real,
    th1: Real,
    th2: Real,
    u1: Real,
    ref: Sequence[Real] | Array,
) -> tuple[Real, Real]:
    """Inputs of the linearising feedback.

    Parameters
    ----------
    k : Coefficients the controller believes (d2 = 0)
    gains : Gains
    th0, th1, th2 : measured angles [rad], (...)
    u1 : the controller's th1' [rad/s], (...)
    ref : Reference, or any sequence y1, y2, y1', y2', y1'', y2'' [rad, rad/s, rad/s^2]

    Returns
    -------
    u1_dot [rad/s^2], u2 [rad/s] : (...)
    """
    return feedback_at(k, gains, th0, th1, th2, u1, np.cos(th1), np.sin(th1), ref)


@jitable
def feedback_at(
    k: Coefficients,
    gains: Gains,
    th0: Real,
    th1: Real,
    th2: Real,
    u1: Real,
    c1: Real,
    s1: Real,
    ref: Sequence[Real] | Array,
) -> tuple[Real, Real]:
    """``feedback`` given c1 = cos th1 and s1 = sin th1 (kernels share them with the plant)."""
    # flat_outputs and flat_inputs at one state, with the trigonometry done once
    inv_A, g, h = chart(k, c1, s1)
    g_prime, h_prime = chart_slopes(k, c1, s1, inv_A, g)
    alpha = g - h * th2
    y2 = th0 - k.c0 * th2 * inv_A
    y2_dot = alpha * u1
    v1 = ref[4] + gains.kv1 * (ref[2] - u1) + gains.kp1 * (ref[0] - th1)
    v2 = ref[5] + gains.kv2 * (ref[3] - y2_dot) + gains.kp2 * (ref[1] - y2)
    return v1, (alpha * v1 + (g_prime - h_prime * th2) * u1 * u1 - v2) / (h * u1)
