"""What the optimiser limits and minimises, pointwise, from the flat flag alone.

At each time the flat flag F = (y, y', y'') fixes the configuration, the joint rates and the
singularity margin in closed form, so every limited quantity is a function of F(t) only, and
its derivative along each flag component is exact by complex step (vectorised over the times
and the flag's directions at once).

One interface for every robot: the model the planner believes (``flatmodel.FlatModel``: the
paper's closed form for N = 2, margin sin(y1) y1', or an N-link chain, margin
sigma = -(dh_0/dt) / (2 K_10); for N = 2 the two margins are the same function) gives the
quantities and their complex-step derivatives.

The quantities come in a fixed order (``Layout``): the angles th0..thN, the joint rates
th1'..thN' (the base's rate is not limited) and the unsigned margin (not yet multiplied by
the sign it keeps along a plan). ``ANGLES``, ``RATES``, ``MARGIN``, ``NAMES`` and
``FLAG_SIZE`` are the layout of the paper's robot (N = 2); code that loops over a group uses
a layout's index tuples, never the numbers.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from flatcli.core.models.flatmodel import FlatModel

Array = NDArray[np.float64]

#: What the planner believes (``flatmodel``): the paper's closed form (N = 2) or a chain.
Flat = FlatModel


@dataclass(frozen=True)
class Layout:
    """Rows of the pointwise quantities of a robot with N joints.

    Attributes
    ----------
    n_joints : N
    angles : rows of the angles th0..thN [rad] (row i is th_i)
    rates : rows of the limited joint rates th1'..thN' [rad/s]
    margin : row of the unsigned singularity margin [rad/s]
    names : name of each row, as messages and active-limit labels print it
    flag_size : components of the flat flag, y, y', y'' of the N outputs (3 N)
    """

    n_joints: int
    angles: tuple[int, ...]
    rates: tuple[int, ...]
    margin: int
    names: tuple[str, ...]
    flag_size: int

    @property
    def size(self) -> int:
        """Number of quantities (2 N + 2)."""
        return len(self.names)


@functools.lru_cache(maxsize=16)
def layout(n_joints: int) -> Layout:
    """The ``Layout`` of a robot with ``n_joints`` joints (N >= 2)."""
    n = n_joints
    angles = tuple(range(n + 1))
    rates = tuple(range(n + 1, 2 * n + 1))
    names = (*(f"th{i}" for i in range(n + 1)), *(f"th{j}'" for j in range(1, n + 1)), "margin")
    return Layout(n, angles, rates, 2 * n + 1, names, 3 * n)


def layout_of(k: Flat) -> Layout:
    """The layout of the robot a model describes."""
    return layout(k.n_joints)


_PAPER = layout(2)
#: Rows of ``flag_quantities`` holding the angles th0, th1, th2 [rad] (row i is th_i; N = 2).
ANGLES: tuple[int, ...] = _PAPER.angles
#: Rows holding the limited joint rates th1', th2' [rad/s] (N = 2).
RATES: tuple[int, ...] = _PAPER.rates
#: Row holding the unsigned singularity margin sin(y1) y1' [rad/s] (N = 2).
MARGIN = _PAPER.margin
#: Name of each row, as the messages and active-limit labels print it (N = 2).
NAMES: tuple[str, ...] = _PAPER.names
#: Components of the flat flag of the paper's robot: y, y', y'' of the two flat outputs.
FLAG_SIZE = _PAPER.flag_size


def flag_quantities(k: Flat, flag: NDArray[np.generic]) -> NDArray[np.generic]:
    """Pointwise quantities of a plan from its flat flag (real or complex: complex-step safe):
    ``FlatModel.flag_values``.

    Parameters
    ----------
    k : the flat model the planner believes
    flag : (3 N, ...) y_1..y_N [rad], y' [rad/s], y'' [rad/s^2]

    Returns
    -------
    (2 N + 2, ...) th0..thN [rad], th1'..thN' [rad/s], the unsigned margin [rad/s];
    inf/nan on the singular set (where the margin is 0)
    """
    return k.flag_values(flag)


def flag_jacobian(k: Flat, flag: Array) -> tuple[Array, Array]:
    """``flag_quantities`` and its exact derivative along each flag component (complex step;
    ``FlatModel.flag_jacobian``).

    Parameters
    ----------
    k : the flat model the planner believes
    flag : (3 N, n) real flat flag (see ``flag_quantities``)

    Returns
    -------
    values : (2 N + 2, n) the quantities (see ``flag_quantities``)
    jacobian : (2 N + 2, 3 N, n) d values[q] / d flag[c] at each time, [q, c, n]
    """
    return k.flag_jacobian(flag)


__all__ = [
    "ANGLES",
    "FLAG_SIZE",
    "MARGIN",
    "NAMES",
    "RATES",
    "Flat",
    "Layout",
    "flag_jacobian",
    "flag_quantities",
    "layout",
    "layout_of",
]
