"""What the optimiser limits and minimises, pointwise, from the flat flag alone.

At each time the flat flag F = (y1, y2, y1', y2', y1'', y2'') fixes the configuration, the
joint rates and the singularity margin in closed form (``flatness.flag_state``), so every
limited quantity is a function of F(t) only, and its derivative along each flag component is
exact by complex step (vectorised over the times and the six directions at once).

The quantities come in a fixed order: the angles (``ANGLES``: th0, th1, th2), the joint rates
(``RATES``: th1', th2'; the base's rate is not limited) and the unsigned margin
sin(y1) y1' (``MARGIN``). Code that loops over a group uses these index tuples, never the
numbers.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from flatcli.core.flatness import flag_state
from flatcli.core.model import Coefficients
from flatcli.core.planning import COMPLEX_STEP

Array = NDArray[np.float64]

#: Rows of ``flag_quantities`` holding the angles th0, th1, th2 [rad] (row i is th_i).
ANGLES: tuple[int, ...] = (0, 1, 2)
#: Rows holding the limited joint rates th1', th2' [rad/s].
RATES: tuple[int, ...] = (3, 4)
#: Row holding the unsigned singularity margin sin(y1) y1' [rad/s].
MARGIN = 5
#: Name of each row, as the messages and active-limit labels print it.
NAMES: tuple[str, ...] = ("th0", "th1", "th2", "th1'", "th2'", "margin")
#: Components of the flat flag: y, y', y'' of the two flat outputs.
FLAG_SIZE = 6


def flag_quantities(k: Coefficients, flag: NDArray[np.generic]) -> NDArray[np.generic]:
    """Pointwise quantities of a plan from its flat flag (real or complex: complex-step safe).

    ``flatness.flag_state`` at each time: th0, th1 = y1, th2, th1' = y1', th2' = u2, and the
    unsigned margin sin(y1) y1'.

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    flag : (6, ...) y1, y2 [rad], y1', y2' [rad/s], y1'', y2'' [rad/s^2]

    Returns
    -------
    (6, ...) th0, th1, th2 [rad], th1', th2' [rad/s], sin(y1) y1' [rad/s] (the unsigned
    margin); inf/nan on the singular set sin y1 y1' = 0
    """
    y1, y2, y1d, y2d, y1dd, y2dd = flag
    th0, th1, th2, u1, _, u2, _ = flag_state(k, y1, y2, y1d, y2d, y1dd, y2dd)
    return np.stack([th0, th1, th2, u1, u2, np.sin(y1) * y1d])


def flag_jacobian(k: Coefficients, flag: Array) -> tuple[Array, Array]:
    """``flag_quantities`` and its exact derivative along each flag component (complex step).

    Parameters
    ----------
    k : Coefficients (d2 = 0)
    flag : (6, n) real flat flag (see ``flag_quantities``)

    Returns
    -------
    values : (6, n) th0, th1, th2, th1', th2', sin(y1) y1'
    jacobian : (6, 6, n) d values[q] / d flag[c] at each time, [q, c, n]
    """
    # (6 components, 6 directions, n): component c carries i h along direction d == c
    perturbed = flag[:, None, :] + (1j * COMPLEX_STEP) * np.eye(FLAG_SIZE)[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = flag_quantities(k, perturbed)  # (6 quantities, 6 directions, n)
    values = np.ascontiguousarray(out[:, 0, :].real, dtype=float)
    jacobian = np.ascontiguousarray(out.imag / COMPLEX_STEP, dtype=float)
    return values, jacobian


__all__ = [
    "ANGLES",
    "FLAG_SIZE",
    "MARGIN",
    "NAMES",
    "RATES",
    "flag_jacobian",
    "flag_quantities",
]
