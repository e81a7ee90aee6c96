"""The closed loop of an N-link chain (N >= 3; the paper's robot keeps ``plant``).

The prolonged state is x = (th0 .. th_N, u_1 .. u_N-1), 2 N numbers. The controller measures
the angles (+ noise), computes the flat outputs with its model (``chainflat.outputs``), asks
for v_j = y_jd'' + kv_j (y_jd' - y_j') + kp_j (y_jd - y_j), j = 1..N, and commands the inputs
that make y'' = v (``chainflat.inputs``): u_j' and th_N'. The kinematic plant
(``plants.kinematic``) turns the joints at the rate commands u_j (j < N) and th_N', clipped
to +-rate_limit, and the base from its own momentum H0 = sum_j h_j th_j' with its own K (any
d_N: an imperfect counterweight included); u_j does not wind up against the limit
(``control.unwound``).

``chain_rhs`` writes the state's derivative into out[:2N] and the controller's signed margin
sigma into out[2N], like ``paperloop.kinematic_rhs``, so the same compiled integrators
(``integrate``) run it; ``chain_kernel`` runs a batch of trials.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.controllers.control import flat_errors, law, unwound
from flatcli.core.loop.metrics import (
    observe_clipped,
    observe_errors,
)
from flatcli.core.models.chainflat import (
    Scratch,
    first_terms_at,
    first_terms_into,
    inputs_given,
    outputs_given,
    terms_into,
)
from flatcli.core.plants.kinematic import kinematic_rates
from flatcli.core.robots.chain import (
    barycentric_matrix,
    chain_momentum_given,
    link_trig,
    turn_last,
)

Array = NDArray[np.float64]



class ChainLoop(NamedTuple):
    """What one trial's closed loop needs (arrays and floats, for the kernels).

    Kc, Ic : the controller's K (N + 1, N + 1) and inertias (N + 1,)
    kp, kv : gains (N,) [1/s^2, 1/s]
    Kq, Iq : the plant's K and inertias; params : the plant's (4 (N + 1),) mass, inertia,
        length, com side by side (for H from the full kinematics)
    h0 : the plant's angular momentum [kg m^2/s]; rate_limit : joint-rate limit [rad/s]
    buffers : (8, N + 1) scratch rows for the right-hand side (the last two: the plant's
        trigonometry when its last link is turned)
    work : the flat maps' scratch (``chainflat.Scratch``)
    cos_p, sin_p : the turn of the plant's last link that a centre of mass across it adds
        (``model.RobotParams.placement``; 1 and 0: none)
    """

    Kc: Array
    Ic: Array
    kp: Array
    kv: Array
    Kq: Array
    Iq: Array
    params: Array
    h0: float
    rate_limit: float
    buffers: Array
    work: Scratch
    cos_p: float = 1.0
    sin_p: float = 0.0


@jitable
def plant_trig(loop: ChainLoop, cs: Array, sn: Array) -> tuple[Array, Array]:
    """The plant's trigonometry: ``cs``, ``sn`` (``chain.link_trig`` of its angles), or their
    turned copy in buffers[6:8] when its last link is turned."""
    if loop.sin_p == 0.0 and loop.cos_p == 1.0:
        return cs, sn
    pcs, psn = loop.buffers[6], loop.buffers[7]
    for a in range(cs.shape[0]):
        pcs[a] = cs[a]
        psn[a] = sn[a]
    turn_last(pcs, psn, loop.cos_p, loop.sin_p)
    return pcs, psn


@jitable
def chain_rhs(loop: ChainLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the chain's prolonged state under the feedback.

    Parameters
    ----------
    loop : ChainLoop
    x : (2 N,) th0..th_N [rad], u_1..u_N-1 [rad/s]
    ref : (3 N,) plan y, y', y'' at this instant
    noise : (N + 1,) sensor noise on the measured angles [rad]
    out : (>= 2 N + 1,) written: th0'..th_N' [rad/s] (the applied rates), u' [rad/s^2], then
        the controller's signed margin sigma [rad/s]
    """
    n = loop.Ic.shape[0] - 1
    buf = loop.buffers
    measured, y, y_dot, v, h = buf[0], buf[1, :n], buf[2, :n], buf[3, :n], buf[4]
    u_dot = buf[5, : n - 1]
    noisy = False
    for i in range(n + 1):
        measured[i] = x[i] + noise[i]
        noisy = noisy or noise[i] != 0.0
    u = x[n + 1: 2 * n]
    work = loop.work
    h0 = terms_into(loop.Kc, loop.Ic, measured, work)  # once for both maps
    h_c, grad, hess, slopes = work.h, work.grad, work.hess, work.slopes
    sigma = outputs_given(loop.Kc, loop.Ic, h0, h_c, grad, measured, u, y, y_dot)
    for j in range(n):
        v[j] = law(ref, j, n, loop.kp[j], loop.kv[j], y[j], y_dot[j])
    command = inputs_given(loop.Ic, h0, h_c, grad, hess, slopes, measured, u, v, u_dot)
    if noisy:  # the plant's own angles (without noise the controller's trigonometry is theirs)
        link_trig(x[: n + 1], work.cs, work.sn)
        work.at[n + 1] = 0.0  # the terms in ``work`` are no longer all at one state
    pcs, psn = plant_trig(loop, work.cs, work.sn)
    r = buf[3]  # v is spent: the rate commands u_j (j < N), th_N'
    for j in range(1, n):
        r[j - 1] = x[n + j]
    r[n - 1] = command
    kinematic_rates(loop.Kq, loop.Iq, loop.h0, loop.rate_limit, pcs, psn, h, r, out)
    for j in range(1, n):
        out[n + j] = unwound(x[n + j], u_dot[j - 1], loop.rate_limit)
    out[2 * n] = sigma


@jitable
def observe_chain(loop: ChainLoop, obs: Any, acc: Array, j: int, x: Array, f: Array) -> None:
    """Metrics of the chain at output sample j (see ``metrics``): angle and flat-output
    errors, the margin |sigma| at the true state, H from the full kinematics at the state
    with the applied rates, the largest applied joint rate."""
    theta_ref, ref, threshold = obs
    n = loop.Ic.shape[0] - 1
    buf = loop.buffers
    y, y_dot = buf[1, :n], buf[2, :n]
    et2 = 0.0
    for i in range(n + 1):
        d = x[i] - theta_ref[j, i]
        et2 += d * d
    work = loop.work
    theta = x[: n + 1]
    h0 = first_terms_at(loop.Kc, loop.Ic, theta, work)  # its trigonometry serves H too
    sigma = outputs_given(loop.Kc, loop.Ic, h0, work.h, work.grad, theta, x[n + 1: 2 * n], y,
                          y_dot)
    ey2 = 0.0
    for i in range(n):
        e = y[i] - ref[2 * j, i]
        ey2 += e * e
    peak = 0.0
    for i in range(1, n + 1):
        peak = max(peak, abs(f[i]))
    pcs, psn = plant_trig(loop, work.cs, work.sn)
    h = chain_momentum_given(loop.params, pcs, psn, f[: n + 1])
    observe_errors(acc, j, et2, ey2, abs(sigma), h, loop.h0, peak, threshold)
    # the joints turn at their commands clipped to the limit: at it exactly where clipped
    observe_clipped(acc, j, peak >= loop.rate_limit)


@jitable
def plan_residual(plan_theta: Array, plan_theta_dot: Array, params: Array, h0: float,
                  cs: Array, sn: Array, cos_p: float = 1.0, sin_p: float = 0.0) -> float:
    """max_j |H - H0| of the plan's own samples with the plant's parameters [kg m^2/s]
    (cs, sn: scratch (N + 1,); cos_p, sin_p: the plant's turn of its last link)."""
    residual = 0.0
    for j in range(plan_theta.shape[0]):
        link_trig(plan_theta[j], cs, sn)
        turn_last(cs, sn, cos_p, sin_p)
        residual = max(residual, abs(chain_momentum_given(params, cs, sn, plan_theta_dot[j])
                                     - h0))
    return residual


def chain_matrix(params: Array, n: int) -> Array:
    """K of a chain from its (4 (N + 1),) parameters (mass, inertia, length, com)."""
    nb = n + 1
    return np.ascontiguousarray(barycentric_matrix(params[:nb], params[2 * nb: 3 * nb],
                                                   params[3 * nb: 4 * nb]))


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
def measure_chain(loop: ChainLoop, x: Array, noise: Array, ref: Array, s0: Array) -> None:
    """What the flat law measures at the kinematic chain's state x (2 N,) with noise (N + 1,):
    its flat outputs' errors from the plan's flag ``ref`` (3 N,) into ``s0`` (2 N,), for a
    law that wraps it (``loop.compose``)."""
    n = loop.Ic.shape[0] - 1
    buf = loop.buffers
    measured = buf[0]
    for i in range(n + 1):
        measured[i] = x[i] + noise[i]
    flat_chain_errors(loop.Kc, loop.Ic, loop.work, measured, x[n + 1: 2 * n], buf[1, :n],
                      buf[2, :n], ref, s0)
