"""The flat law of an N-link chain (N >= 2 joints), as a part any chain plant runs
(``parts.LawPart``; ``loop.base`` composes it with a plant).

Its states are the integrators u_1..u_N-1. At the measured angles th + noise it computes the
flat outputs with its model (``chainflat.outputs``), asks for v_j = y_jd'' + kv_j (y_jd' -
y_j') + kp_j (y_jd - y_j), j = 1..N, and the inputs that make y'' = v (``chainflat.inputs``):
u_j' and th_N'. Its rate commands are r_j = u_j (j < N) and r_N = th_N' (the plant clips
them to +-rate_limit); u_j' is 0 while u_j is at or beyond the limit and the command pushes it
further out (``control.unwound``: no wind-up). Its signed margin sigma (``chainflat``)
changes sign on its singular set. On a rest plan it reads the fade w and the plan's th_N'
from the flag and blends its commands with the plan's (``rest``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.controllers.control import (
    Gains,
    add_to_accelerations,
    flat_errors,
    law,
    unwound,
)
from flatcli.core.controllers.parts import LawPart
from flatcli.core.controllers.rest import faded_chain, observed_margin
from flatcli.core.models.chainflat import (
    Scratch,
    first_terms_at,
    first_terms_into,
    inputs_given,
    outputs_given,
    terms_into,
)
from flatcli.core.models.chainflat import (
    scratch as maps_scratch,
)
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: Rows of ``FlatLaw.rows`` (each N + 1 long): y, y', v, u'.
_Y, _Y_DOT, _V, _U_DOT = range(4)
ROWS = 4


class ChainShared(NamedTuple):
    """The controller of a chain: its K (N + 1, N + 1) and inertias (N + 1,), gains kp, kv
    (N,), the joint-rate limit [rad/s], and whether the dynamic plant's servo knows the
    plant (else it believes the controller's chain)."""

    Kc: Array
    Ic: Array
    kp: Array
    kv: Array
    rate_limit: float
    servo_is_plant: bool


class FlatLaw(NamedTuple):
    """One trial's law: the controller's K, inertias, gains, the rate limit [rad/s]; rows
    (ROWS, N + 1) and the flat maps' scratch (``chainflat.Scratch``)."""

    Kc: Array
    Ic: Array
    kp: Array
    kv: Array
    rate_limit: float
    rows: Array
    work: Scratch


def chain_shared(model: Any, gains: Gains, rate_limit: float, servo_is_plant: bool,
                 robot: RobotParams) -> ChainShared:
    """What every trial shares in the general chain: the controller's K and inertias,
    gains, the rate limit, whether the servo knows the plant (writable copies: the model's
    arrays are read-only, a type the kernels' plant records do not share)."""
    return ChainShared(np.array(model.K, dtype=float), np.array(model.inertia, dtype=float),
                       np.asarray(gains.kp, dtype=float), np.asarray(gains.kv, dtype=float),
                       float(rate_limit), servo_is_plant)


def scratch(n: int) -> tuple[Array, Scratch]:
    """The law's rows and the flat maps' scratch for N joints."""
    return np.zeros((ROWS, n + 1)), maps_scratch(n)


@jitable
def make(shared: ChainShared, buffers: Any) -> FlatLaw:
    return FlatLaw(shared.Kc, shared.Ic, shared.kp, shared.kv, shared.rate_limit, buffers[0],
                   buffers[1])


@jitable
def joints(law_: FlatLaw) -> int:
    return law_.Ic.shape[0] - 1  # type: ignore[no-any-return]


@jitable
def states(n: int) -> int:
    """u_1..u_N-1."""
    return n - 1


@jitable
def servo(shared: ChainShared, offset: float) -> Any:
    """The servo's model: the controller's chain, turned as the plant (the nominal robot has
    d_N = 0, which th_N does not enter); the lag without a solve where it is the plant's."""
    return shared.Kc, shared.Ic, np.cos(offset), np.sin(offset), shared.servo_is_plant, True


@jitable
def command(law_: FlatLaw, measured: Array, rates: Array, z: Array, ref: Array, r: Array,
            z_dot: Array) -> float:
    """``LawPart.command``: at the measured angles (N + 1,) and u = z (N - 1,), the rate
    commands (u_j, then th_N'; the plant clips them) into r (N,), u' unwound against the
    plant's clip into z_dot; returns sigma [rad/s]. ``ref`` (3 N,): the plan's y, y', y''
    (a rest plan's channels: blended, ``rest``)."""
    n = law_.Ic.shape[0] - 1
    buf = law_.rows
    y, y_dot, v, u_dot = buf[_Y, :n], buf[_Y_DOT, :n], buf[_V, :n], buf[_U_DOT, : n - 1]
    work = law_.work
    h0 = terms_into(law_.Kc, law_.Ic, measured, work)  # once for both maps
    h_c, grad, hess, slopes = work.h, work.grad, work.hess, work.slopes
    sigma = outputs_given(law_.Kc, law_.Ic, h0, h_c, grad, measured, z, y, y_dot)
    c = ref.shape[0] // 3  # N, or a rest plan's channels (``rest``)
    for j in range(n):
        v[j] = law(ref, j, c, law_.kp[j], law_.kv[j], y[j], y_dot[j])
    r[n - 1] = inputs_given(law_.Ic, h0, h_c, grad, hess, slopes, measured, z, v, u_dot)
    if c > n:  # a rest plan's flag: the feedback faded at the ends
        sigma = faded_chain(ref, n, u_dot, r, sigma)
    for j in range(n - 1):
        r[j] = z[j]
        z_dot[j] = unwound(z[j], u_dot[j], law_.rate_limit)
    return sigma


@jitable
def start(law_: FlatLaw, initial: Array, z0: Array) -> None:
    """u(0) from the trial's initial state."""
    nb = law_.Ic.shape[0]
    for j in range(nb - 2):
        z0[j] = initial[nb + j]


@jitable
def start_rates(law_: FlatLaw, initial: Array, ref: Array, r: Array) -> None:
    """The commands at t = 0 at the true angles, clipped to the rate limit."""
    nb = law_.Ic.shape[0]
    u_dot = law_.rows[_U_DOT, : nb - 2]
    command(law_, initial[:nb], initial[nb:nb], initial[nb: 2 * nb - 2], ref, r, u_dot)
    limit = law_.rate_limit
    for j in range(nb - 1):
        r[j] = min(max(r[j], -limit), limit)


@jitable
def trig(law_: FlatLaw) -> tuple[Array, Array]:
    return law_.work.cs, law_.work.sn


@jitable
def observed(law_: FlatLaw, obs: Any, j: int, theta: Array, z: Array, f: Array, at: int
             ) -> tuple[float, float, float]:
    """The flat outputs' squared error (the controller's flat map at the true state), the
    margin |sigma| there, the singular threshold."""
    _, ref, threshold = obs
    n = law_.Ic.shape[0] - 1
    y, y_dot = law_.rows[_Y, :n], law_.rows[_Y_DOT, :n]
    work = law_.work
    h0 = first_terms_at(law_.Kc, law_.Ic, theta, work)  # its trigonometry serves H too
    sigma = outputs_given(law_.Kc, law_.Ic, h0, work.h, work.grad, theta, z, y, y_dot)
    ey2 = 0.0
    for i in range(n):
        e = y[i] - ref[2 * j, i]
        ey2 += e * e
    return ey2, observed_margin(ref, j, n, abs(sigma)), threshold


@jitable
def additive(law_: FlatLaw, ref: Array, dv: Array, out: Array) -> None:
    """dv added to the plan's y'' (``control.add_to_accelerations``)."""
    add_to_accelerations(ref, dv, out)


@jitable
def flat_chain_errors(Kc: Array, Ic: Array, work: Scratch, measured: Array, u: Array,
                      y: Array, y_dot: Array, ref: Array, s0: Array) -> None:
    """The flat outputs' errors (``control.flat_errors``) of a chain's controller at the
    measured angles (N + 1,) and its integrators u (N - 1,) into ``s0`` (2 N,); y, y_dot
    (N,) scratch; ``work`` the flat maps' (left holding the terms at ``measured``)."""
    h0 = first_terms_into(Kc, Ic, measured, work)
    outputs_given(Kc, Ic, h0, work.h, work.grad, measured, u, y, y_dot)
    flat_errors(ref, y, y_dot, s0)


@jitable
def measure(law_: FlatLaw, measured: Array, rates: Array, z: Array, ref: Array, s0: Array
            ) -> None:
    """Its flat outputs' errors at the measured angles from the plan's flag ``ref`` (3 N,)
    into ``s0`` (2 N,)."""
    n = law_.Ic.shape[0] - 1
    flat_chain_errors(law_.Kc, law_.Ic, law_.work, measured, z, law_.rows[_Y, :n],
                      law_.rows[_Y_DOT, :n], ref, s0)


LAW = LawPart("flat", chain_shared, scratch, make, joints, states, servo, command, start,
              start_rates, trig, observed, additive, measure, shares_trig=True, bounded=False)
