"""What the optimiser limits and minimises, pointwise, from the flat flag alone.

At each time the flat flag F = (y, y', y'') fixes the configuration, the joint rates and the
singularity margin in closed form, so every limited quantity is a function of F(t) only, and
its derivative along each flag component is exact by complex step (vectorised over the times
and the flag's directions at once).

Two robots, one interface: the model the planner believes is either the paper's reduced
constraint (``Coefficients``, N = 2: two outputs, ``flatness.flag_state``, margin
sin(y1) y1') or an N-link chain (``chainplan.ChainModel``, any N >= 2: N outputs,
``chainflat.flag_state``, which is complex-step safe, and the margin
sigma = -(dh_0/dt) / (2 K_10)). For N = 2 the two margins are the same function.

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

from flatcli.core._jit import allocating_kernel
from flatcli.core.chainflat import flag_state_given, terms
from flatcli.core.chainplan import ChainModel, flags_to_states
from flatcli.core.flatness import flag_state
from flatcli.core.model import Coefficients
from flatcli.core.planning import COMPLEX_STEP

Array = NDArray[np.float64]

#: What the planner believes: the paper's constraint coefficients (N = 2) or a chain's model.
Flat = Coefficients | ChainModel


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
    return layout(k.n_joints if isinstance(k, ChainModel) else 2)


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
    """Pointwise quantities of a plan from its flat flag (real or complex: complex-step safe).

    The paper's robot (``Coefficients``): ``flatness.flag_state`` at each time: th0,
    th1 = y1, th2, th1' = y1', th2' = u2, and the unsigned margin sin(y1) y1'. A chain
    (``ChainModel``): ``chainflat.flag_state``: th0..thN, th1'..thN' and
    sigma = -(dh_0/dt) / (2 K_10).

    Parameters
    ----------
    k : Coefficients (d2 = 0) or ChainModel (d_N = 0)
    flag : (3 N, ...) y_1..y_N [rad], y' [rad/s], y'' [rad/s^2]

    Returns
    -------
    (2 N + 2, ...) th0..thN [rad], th1'..thN' [rad/s], the unsigned margin [rad/s];
    inf/nan on the singular set (where the margin is 0)
    """
    if isinstance(k, ChainModel):
        return _chain_quantities(k, flag)
    y1, y2, y1d, y2d, y1dd, y2dd = flag
    th0, th1, th2, u1, _, u2, _ = flag_state(k, y1, y2, y1d, y2d, y1dd, y2dd)
    return np.stack([th0, th1, th2, u1, u2, np.sin(y1) * y1d])


def _chain_quantities(model: ChainModel, flag: NDArray[np.generic]) -> NDArray[np.generic]:
    """``flag_quantities`` of a chain: the compiled flag map at every time. Real flags go
    through ``_chain_values`` (the trigonometric terms once per time), complex ones through
    ``chainplan.flags_to_states``."""
    n = model.n_joints
    rows = np.ascontiguousarray(np.reshape(flag, (3 * n, -1)).T)  # (times, 3 N)
    if np.isrealobj(rows):
        out = np.empty((rows.shape[0], 2 * n + 2))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            _chain_values(model.K, model.inertia, rows.astype(float), out)
        out = out.T
    else:
        theta, theta_dot, _, sigma = flags_to_states(model, rows)
        out = np.concatenate([theta.T, theta_dot[:, 1:].T, sigma[None, :]])
    return np.reshape(out, (2 * n + 2, *np.shape(flag)[1:]))


@allocating_kernel
def _chain_values(K: Array, inertia: Array, flags: Array, values: Array) -> None:
    """A chain's quantities at every row of ``flags`` (m, 3 N) into ``values`` (m, 2 N + 2):
    ``chainflat.flag_state_given`` with the terms at q computed once per row."""
    n = inertia.shape[0] - 1
    theta = np.empty(n + 1)
    theta_dot = np.empty(n + 1)
    u_dot = np.empty(n - 1)
    q = np.zeros(n + 1)
    for i in range(flags.shape[0]):
        for j in range(1, n):
            q[j] = flags[i, j - 1]
        h0, h, grad, hess, slopes = terms(K, inertia, q)
        row = flags[i]
        sigma = flag_state_given(K, inertia, h0, h, grad, hess, slopes, row[:n], row[n:2 * n],
                                 row[2 * n:], theta, theta_dot, u_dot)
        for a in range(n + 1):
            values[i, a] = theta[a]
        for j in range(1, n + 1):
            values[i, n + j] = theta_dot[j]
        values[i, 2 * n + 1] = sigma


def flag_jacobian(k: Flat, flag: Array) -> tuple[Array, Array]:
    """``flag_quantities`` and its exact derivative along each flag component (complex step).

    Parameters
    ----------
    k : Coefficients (d2 = 0) or ChainModel (d_N = 0)
    flag : (3 N, n) real flat flag (see ``flag_quantities``)

    Returns
    -------
    values : (2 N + 2, n) the quantities (see ``flag_quantities``)
    jacobian : (2 N + 2, 3 N, n) d values[q] / d flag[c] at each time, [q, c, n]
    """
    if isinstance(k, ChainModel):
        return _chain_jacobian(k, flag)
    size = layout_of(k).flag_size
    # (components, directions, n): component c carries i h along direction d == c
    perturbed = flag[:, None, :] + (1j * COMPLEX_STEP) * np.eye(size)[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = flag_quantities(k, perturbed)  # (quantities, directions, n)
    values = np.ascontiguousarray(out[:, 0, :].real, dtype=float)
    jacobian = np.ascontiguousarray(out.imag / COMPLEX_STEP, dtype=float)
    return values, jacobian


def _chain_jacobian(model: ChainModel, flag: Array) -> tuple[Array, Array]:
    """``flag_jacobian`` of a chain, by the compiled ``_chain_steps``."""
    n = model.n_joints
    rows = np.ascontiguousarray(flag.T)  # (times, 3 N)
    values = np.empty((rows.shape[0], 2 * n + 2))
    jacobian = np.empty((rows.shape[0], 2 * n + 2, 3 * n))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        _chain_steps(model.K, model.inertia, rows, COMPLEX_STEP, values, jacobian)
    return np.ascontiguousarray(values.T), np.ascontiguousarray(np.transpose(jacobian, (1, 2, 0)))


@allocating_kernel
def _chain_steps(K: Array, inertia: Array, flags: Array, step: float, values: Array,
                 jacobian: Array) -> None:
    """Complex-step derivatives of a chain's quantities along each flag component, at every
    row of ``flags`` (m, 3 N): ``values`` (m, 2 N + 2) and ``jacobian`` (m, 2 N + 2, 3 N).

    The trigonometric terms (``chainflat.terms``) depend on q = (y_1..y_N-1) only: they are
    evaluated complex along the N - 1 directions of q, and once, real, for the other 2 N + 1
    directions (where they are constant), so each row costs N sets of terms, not 3 N.
    """
    n = inertia.shape[0] - 1
    size = 3 * n
    theta = np.empty(n + 1, dtype=np.complex128)
    theta_dot = np.empty(n + 1, dtype=np.complex128)
    u_dot = np.empty(n - 1, dtype=np.complex128)
    row = np.empty(size, dtype=np.complex128)
    q = np.zeros(n + 1, dtype=np.complex128)
    for i in range(flags.shape[0]):
        for j in range(1, n):
            q[j] = flags[i, j - 1]
        f0, f1, f2, f3, f4 = terms(K, inertia, q)  # real values (zero imaginary parts)
        for c in range(size):
            for j in range(size):
                row[j] = flags[i, j]
            row[c] += 1j * step
            if c < n - 1:  # a direction of q: the terms move
                q[c + 1] += 1j * step
                h0, h, grad, hess, slopes = terms(K, inertia, q)
                q[c + 1] = flags[i, c]
            else:
                h0, h, grad, hess, slopes = f0, f1, f2, f3, f4
            sigma = flag_state_given(K, inertia, h0, h, grad, hess, slopes, row[:n],
                                     row[n:2 * n], row[2 * n:], theta, theta_dot, u_dot)
            for a in range(n + 1):
                jacobian[i, a, c] = theta[a].imag / step
            for j in range(1, n + 1):
                jacobian[i, n + j, c] = theta_dot[j].imag / step
            jacobian[i, 2 * n + 1, c] = sigma.imag / step
            if c == size - 1:  # a direction off q: real parts from the real terms
                for a in range(n + 1):
                    values[i, a] = theta[a].real
                for j in range(1, n + 1):
                    values[i, n + j] = theta_dot[j].real
                values[i, 2 * n + 1] = sigma.real


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
