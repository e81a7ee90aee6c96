"""The linearising feedback of Franch et al. (2003), eqs. 39-42, for any N.

The controller knows the prolonged state (the angles measured, perhaps with noise, and its
own integrator states u_j = th_j', j < N), computes the flat outputs and rates with its
*nominal* model, asks for

    v_i = y_id'' + kv_i (y_id' - y_i') + kp_i (y_id - y_i),    i = 1..N       (``law``)

and commands the inputs that make y'' = v (the model's inverse of the flat accelerations:
``flatness.inputs_at`` for the paper's robot, ``chainflat.inputs_given`` for a chain).
With an exact model the flat-output errors e = y_d - y then obey e'' + kv e' + kp e = 0.
``Gains`` are the law's for any N; ``PaperGains`` the same four numbers of the paper's robot
as plain floats, for its compiled closed form (``feedback``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import Real, jitable
from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatness import chart, chart_slopes, inputs_at, outputs_at
from flatcli.core.robots.params import Coefficients

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Gains:
    """Feedback gains kp [1/s^2] and kv [1/s], one each per flat output y_1..y_N."""

    kp: tuple[float, ...]
    kv: tuple[float, ...]

    def __post_init__(self) -> None:
        kp = tuple(float(v) for v in self.kp)
        kv = tuple(float(v) for v in self.kv)
        if len(kp) != len(kv) or len(kp) < 2:
            raise FlatcliError(f"track.kp, track.kv: expected as many gains in each, one per "
                               f"flat output (>= 2), got {len(kp)} and {len(kv)}")
        if not all(math.isfinite(v) for v in (*kp, *kv)):
            raise FlatcliError("track.kp, track.kv: every gain must be finite")
        object.__setattr__(self, "kp", kp)
        object.__setattr__(self, "kv", kv)

    @property
    def n_outputs(self) -> int:
        """N, the flat outputs they act on."""
        return len(self.kp)

    def paper(self) -> PaperGains:
        """The paper's robot's gains as plain floats (N = 2)."""
        if self.n_outputs != 2:
            raise FlatcliError(f"track.kp, track.kv: the paper's robot has 2 flat outputs, got "
                               f"{self.n_outputs} gains")
        return PaperGains(self.kp[0], self.kp[1], self.kv[0], self.kv[1])


class PaperGains(NamedTuple):
    """``Gains`` of the paper's robot as plain floats, for its compiled closed form: kp
    [1/s^2] and kv [1/s] of the two flat outputs."""

    kp1: float
    kp2: float
    kv1: float
    kv2: float


@jitable
def law(ref: Sequence[Real] | Array, j: int, n: int, kp: float, kv: float, y: Real,
        y_dot: Real) -> Real:
    """v_j = y_jd'' + kv (y_jd' - y_j') + kp (y_jd - y_j) for output j, the plan's flag ``ref``
    (3 n,) y, y', y'' of its n channels at this instant (the N flat outputs first: n = N, or
    N + ``rest.CHANNELS`` on a rest plan); y, y_dot (...) [rad, rad/s]."""
    return ref[2 * n + j] + kv * (ref[n + j] - y_dot) + kp * (ref[j] - y)


@jitable
def feedback(
    k: Coefficients,
    gains: PaperGains,
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
    ref : y1, y2, y1', y2', y1'', y2'' of the plan at this instant [rad, rad/s, rad/s^2] (a
        rest plan's flag: its channels' values, then rates, then accelerations, ``rest``)

    Returns
    -------
    u1_dot [rad/s^2], u2 [rad/s] : (...)
    """
    return feedback_at(k, gains, th0, th1, th2, u1, np.cos(th1), np.sin(th1), ref)


@jitable
def feedback_at(
    k: Coefficients,
    gains: PaperGains,
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
    c = len(ref) // 3  # 2, or a rest plan's channels (``rest``)
    v1 = law(ref, 0, c, gains.kp1, gains.kv1, th1, u1)
    v2 = law(ref, 1, c, gains.kp2, gains.kv2, y2, y2_dot)
    return inputs_at(g, h, g_prime, h_prime, th2, u1, v1, v2)


@jitable
def unwound(u: Real, u_dot: Real, limit: float) -> Real:
    """The rate of the law's integrator u_j [rad/s^2] under a plant that clips its command
    u_j to +-limit [rad/s]: 0 while u_j is at or beyond the limit and u_dot would push it
    further out (conditional integration: no wind-up), else u_dot."""
    if (u >= limit and u_dot > 0.0) or (u <= -limit and u_dot < 0.0):
        return 0.0
    return u_dot


@jitable
def add_to_accelerations(ref: Array, dv: Array, out: Array) -> None:
    """The flat law's additive input: ``out`` (3 N,) = the plan's flag ``ref`` with dv (N,)
    [rad/s^2] added to its y'' (``law`` then asks v_j = y_jd'' + dv_j + kv (..) + kp (..):
    the command of a wrapping law, ``loop.compose``)."""
    n = dv.shape[0]
    for c in range(3 * n):
        out[c] = ref[c]
    for j in range(n):
        out[2 * n + j] += dv[j]


@jitable
def flat_errors(ref: Array, y: Array, y_dot: Array, s0: Array) -> None:
    """The flat outputs' errors from the plan's flag ``ref`` (3 N,) into ``s0`` (2 N,):
    s0[2 j] = y_j - y_jd [rad], s0[2 j + 1] = y_j' - y_jd' [rad/s] (the state of the MPC's
    design about a flat plan, ``mpc.flat_design``)."""
    n = y.shape[0]
    for j in range(n):
        s0[2 * j] = y[j] - ref[j]
        s0[2 * j + 1] = y_dot[j] - ref[n + j]
