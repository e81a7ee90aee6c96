"""The closed loop's right-hand side: the controller driving a plant.

The controller (``control.feedback``) believes the nominal model; the plant always obeys the
true physics (the derived constraint for its own parameters, d2 of any value, and its own
angular momentum H0). The kinematic plant's state is x = (th0, th1, th2, u1):

    th1' = sat(u1),  th2' = sat(u2),  th0' = (B th1' + C th2' + M H0) / A,  u1' = v1

where (u1', u2) come from the controller at the measured angles th + noise, and sat clips a
joint rate to +-rate_limit (an actuator limit; infinite by default). While th1' is clipped
the controller's integrator does not wind up: u1' is set to 0 whenever u1 is at or beyond
the limit and v1 would push it further out (conditional integration), so u1 never runs away
from the rate the joint actually turns at.

Every right-hand side here has the same signature and writes the state's derivative into
``out[:nx]`` and the controller's signed margin into ``out[nx]``, so that one integrator
(``integrate``) serves every plant.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.control import Gains, feedback_at
from flatcli.core.model import Coefficients, Links, base_rate_at, momentum_at

Array = NDArray[np.float64]

#: State size of the kinematic plant: th0, th1, th2 [rad], u1 [rad/s].
KINEMATIC_STATE = 4
#: Values ``kinematic_rhs`` writes after the state's derivative: the margin, then the plant's
#: cos th1, sin th1 and cos(th1 + th2) (shared with the metrics).
KINEMATIC_AUX = 4


class Loop(NamedTuple):
    """What one trial's closed loop needs (floats and tuples of floats, for the kernels).

    kc : the controller's coefficients (d2 = 0); gains : Gains
    kq : the plant's constraint coefficients (derived model, its own d2)
    links : the plant's link parameters; total_mass : the plant's M [kg]
    h0 : the plant's angular momentum [kg m^2/s]; rate_limit : joint-rate limit [rad/s]
    flat_plant : the plant has d2 = 0, so its terms in cos th2 and cos(th1 + th2) vanish and
        are skipped (the same numbers to the bit: those terms are multiplied by zero)
    """

    kc: Coefficients
    gains: Gains
    kq: Coefficients
    links: Links
    total_mass: float
    h0: float
    rate_limit: float
    flat_plant: bool


@jitable
def kinematic_rhs(loop: Loop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the kinematic plant's state under the feedback.

    Parameters
    ----------
    loop : Loop
    x : (4,) th0, th1, th2 [rad], u1 [rad/s]
    ref : (6,) plan y1, y2, y1', y2', y1'', y2'' at this instant
    noise : (3,) sensor noise on the three measured angles [rad]
    out : (>= 4 + KINEMATIC_AUX,) written: th0', th1', th2' [rad/s] (the applied joint rates),
        u1' [rad/s^2]; then the controller's signed margin sin(measured th1) * u1 [rad/s]
        (the feedback divides by it: where it changes sign the trial crosses the singular
        set), and the plant's cos th1, sin th1, cos(th1 + th2) (0 for a flat plant)
    """
    x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
    c1 = np.cos(x1)
    s1 = np.sin(x1)
    if noise[1] == 0.0:  # the controller measures th1 exactly: share its trigonometry
        cm1, sm1 = c1, s1
    else:
        cm1, sm1 = np.cos(x1 + noise[1]), np.sin(x1 + noise[1])
    u1_dot, u2 = feedback_at(loop.kc, loop.gains, x0 + noise[0], x1 + noise[1], x2 + noise[2],
                             x3, cm1, sm1, ref)
    limit = loop.rate_limit
    w1 = min(max(x3, -limit), limit)
    w2 = min(max(u2, -limit), limit)
    if loop.flat_plant:
        c2 = c12 = 0.0
    else:
        c2, c12 = np.cos(x2), np.cos(x1 + x2)
    w0 = base_rate_at(loop.kq, loop.total_mass, loop.h0, c1, c2, c12, w1, w2)
    if (x3 >= limit and u1_dot > 0.0) or (x3 <= -limit and u1_dot < 0.0):
        u1_dot = 0.0  # conditional integration: no wind-up while th1' is clipped
    out[0], out[1], out[2], out[3] = w0, w1, w2, u1_dot
    out[4], out[5], out[6], out[7] = sm1 * x3, c1, s1, c12


@jitable
def kinematic_momentum(loop: Loop, x: Array, f: Array) -> float:
    """H of the plant from its full link kinematics at state x with the rates f it applies
    (``model.momentum``; f as written by ``kinematic_rhs``) [kg m^2/s]."""
    s12 = 0.0 if loop.flat_plant else np.sin(x[1] + x[2])  # d2 = 0: s12 is multiplied by 0
    return float(momentum_at(loop.links, f[5], f[6], f[7], s12, f[0], f[1], f[2]))
