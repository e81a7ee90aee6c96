"""The linearising feedback of Franch et al. (2003), eqs. 39-42.

The controller knows the prolonged state (th0, th1, th2, u1) (the angles measured, perhaps
with noise; u1 is its own integrator state), computes the flat outputs and rates with its
*nominal* model (``flatness.outputs_at``), asks for

    v_i = y_id'' + kv_i (y_id' - y_i') + kp_i (y_id - y_i),    i = 1, 2

and returns the inputs (u1', u2) that make y'' = v (``flatness.inputs_at``). With an exact
model the flat-output errors e = y_d - y then obey e'' + kv e' + kp e = 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import Real, jitable
from flatcli.core.flatness import chart, chart_slopes, inputs_at, outputs_at
from flatcli.core.model import Coefficients

Array = NDArray[np.float64]


class Gains(NamedTuple):
    """Feedback gains: kp [1/s^2] and kv [1/s] for the two flat outputs."""

    kp1: float
    kp2: float
    kv1: float
    kv2: float


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
    ref : y1, y2, y1', y2', y1'', y2'' of the plan at this instant [rad, rad/s, rad/s^2]

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
    inv_A, g, h = chart(k, c1, s1)
    g_prime, h_prime = chart_slopes(k, c1, s1, inv_A, g)
    _, y2, _, y2_dot = outputs_at(k, inv_A, g, h, th0, th1, th2, u1)
    v1 = ref[4] + gains.kv1 * (ref[2] - u1) + gains.kp1 * (ref[0] - th1)
    v2 = ref[5] + gains.kv2 * (ref[3] - y2_dot) + gains.kp2 * (ref[1] - y2)
    return inputs_at(g, h, g_prime, h_prime, th2, u1, v1, v2)
