"""The flat law on the dynamic plant of an N-link chain (N >= 2 joints).

The plant is ``plants.dynamic`` (the free-floating chain with inertia driven by a rate servo
on every joint, torque-limited); the law is the chain's linearising feedback (``chainloop``,
``chainflat``) at the measured angles th + noise: v_j = y_jd'' + kv_j (y_jd' - y_j')
+ kp_j (y_jd - y_j), and the inputs that make y'' = v: u_j' (j < N) and th_N'. Its rate
commands are r_j = u_j (j < N) and r_N = th_N' (the plant clips them to the rate limit); u_j'
is 0 while u_j is at or beyond the limit and the command pushes it further out
(``control.unwound``). The servo's model is the nominal robot or the plant itself. For N = 2
it is the paper's robot, whose own compiled plant (``paperloop.dynamic_rhs``, written out for
three bodies) stays what ``simulate`` runs for a ``FlatPlan``; the tests check that both agree.

The state is x = (th0 .. th_N, th0' .. th_N', u_1 .. u_N-1), 3 N + 1 numbers.
``chain_dynamic_rhs`` writes the state's derivative into out[:3N+1], the controller's signed
margin sigma = -D / (2 K_10) into out[3N+1] (as ``chainloop.chain_rhs``: the integrators stop
where it changes sign), then the plant's aux values (tau_1 .. tau_N [N m], 1.0 if a torque
was clipped, else 0.0, the rate commands r_1 .. r_N [rad/s]).

Initial state (``chain_dynamic_initial``): th(0) and u(0) given; th_j'(0) = r_j(0), the rate
commands of the controller at t = 0 at the true angles (the servo starts in equilibrium);
th0'(0) such that H = (M q')_0 = H0 of the plant.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.controllers.control import law, unwound
from flatcli.core.loop.chainloop import flat_chain_errors
from flatcli.core.loop.metrics import (
    observe_clipped,
    observe_errors,
    observe_torque,
)
from flatcli.core.models.chainflat import (
    Scratch,
    first_terms_at,
    inputs_given,
    outputs_given,
    terms_into,
)
from flatcli.core.plants import dynamic
from flatcli.core.plants.dynamic import R, ServoPlant, servo_plant, servo_rates
from flatcli.core.robots.chain import chain_momentum_given, turn_last

Array = NDArray[np.float64]


#: Rows of ``ChainDynamicLoop.rows`` (each N + 1 long): measured angles, y, y', v, u', the
#: plant's turned cos and sin (for H).
_MEASURED, _Y, _Y_DOT, _V, _U_DOT, _PLANT_CS, _PLANT_SN = range(7)
ROWS = 7


def chain_dynamic_state(n: int) -> int:
    """State size of the N-link dynamic plant: th (N + 1), th' (N + 1), u (N - 1)."""
    return 3 * n + 1


def chain_dynamic_aux(n: int) -> int:
    """Values ``chain_dynamic_rhs`` writes after the state's derivative: sigma, then the
    plant's (``plants.dynamic.aux``: tau_1 .. tau_N, the saturation flag, r_1 .. r_N)."""
    return 1 + dynamic.aux(n)


class ChainDynamicLoop(NamedTuple):
    """What one trial's closed loop with the N-link dynamic plant needs (for the kernels).

    Kc, Ic : the controller's K (N + 1, N + 1) [kg m^2] and inertias (N + 1,) [kg m^2]
    kp, kv : gains (N,) [1/s^2, 1/s]
    params : the plant's (4 (N + 1),) mass, inertia, length, com (H from the full kinematics)
    rows : (ROWS, N + 1) the law's scratch; work : the flat maps' (``chainflat.Scratch``)
    plant : the dynamic plant (``plants.dynamic.ServoPlant``: its chain, servo, H0, limits)
    """

    Kc: Array
    Ic: Array
    kp: Array
    kv: Array
    params: Array
    rows: Array
    work: Scratch
    plant: ServoPlant


@jitable
def chain_dynamic_loop(
    Kc: Array, Ic: Array, kp: Array, kv: Array, Kq: Array, Iq: Array, servo_is_plant: bool,
    params: Array, h0: float, rate_limit: float, bandwidth: float, torque_limit: float,
    rows: Array, plant_rows: Array, trig: Array, servo_trig: Array, matrices: Array,
    work: Scratch, offset: float = 0.0,
) -> ChainDynamicLoop:
    """A ``ChainDynamicLoop`` for a plant (its K ``Kq`` and inertias ``Iq``, its last link
    turned by ``offset`` [rad]) and a servo model: the plant (``servo_is_plant``) or the
    controller's nominal chain (Kc, Ic), turned as the plant (the nominal robot has d_N = 0,
    which th_N does not enter)."""
    sp = servo_plant(Kq, Iq, Kc, Ic, servo_is_plant, offset, np.cos(offset), np.sin(offset),
                     h0, rate_limit, bandwidth, torque_limit, plant_rows, trig, servo_trig,
                     matrices, True)
    return ChainDynamicLoop(Kc, Ic, kp, kv, params, rows, work, sp)


@jitable
def _commands(loop: ChainDynamicLoop, measured: Array, u: Array, ref: Array) -> float:
    """The feedback at the measured angles (N + 1,) and u (N - 1,): the rate commands (N,)
    (u_j, then th_N'; the plant clips them) into the plant's rows[R] and the commands u'
    (N - 1,) into rows[_U_DOT]; returns sigma [rad/s]. ``ref`` (3 N,): the plan's y, y',
    y''."""
    n = loop.Ic.shape[0] - 1
    buf = loop.rows
    y, y_dot, v, r = buf[_Y, :n], buf[_Y_DOT, :n], buf[_V, :n], loop.plant.rows[R]
    work = loop.work
    h0 = terms_into(loop.Kc, loop.Ic, measured, work)  # once for both maps
    h_c, grad, hess, slopes = work.h, work.grad, work.hess, work.slopes
    sigma = outputs_given(loop.Kc, loop.Ic, h0, h_c, grad, measured, u, y, y_dot)
    for j in range(n):
        v[j] = law(ref, j, n, loop.kp[j], loop.kv[j], y[j], y_dot[j])
    r[n - 1] = inputs_given(loop.Ic, h0, h_c, grad, hess, slopes, measured, u, v,
                            buf[_U_DOT, : n - 1])
    for j in range(n - 1):
        r[j] = u[j]
    return sigma


@jitable
def chain_dynamic_rhs(loop: ChainDynamicLoop, x: Array, ref: Array, noise: Array, out: Array
                      ) -> None:
    """Rates of the N-link dynamic plant's state under the feedback and the servos.

    Parameters
    ----------
    loop : ChainDynamicLoop
    x : (3 N + 1,) th0..th_N [rad], th0'..th_N' [rad/s], u_1..u_N-1 [rad/s]
    ref : (3 N,) plan y, y', y'' at this instant
    noise : (N + 1,) sensor noise on the measured angles [rad]
    out : (>= 3 N + 1 + ``chain_dynamic_aux(N)``,) written: th' [rad/s], th'' [rad/s^2],
        u' [rad/s^2]; then the controller's signed margin sigma [rad/s], tau_1..tau_N
        [N m], 1.0 if a torque was clipped (else 0.0), the rate commands r_1..r_N [rad/s]
    """
    _chain_dynamic_rates(loop, x, ref, noise, out, True)


@jitable
def chain_dynamic_stage(loop: ChainDynamicLoop, x: Array, ref: Array, noise: Array,
                        out: Array) -> None:
    """``chain_dynamic_rhs`` for an integrator's stage, whose torques nobody observes: the
    same state's derivative and sigma, bit for bit, and the same r; but where the servo's
    model is the plant and there is no torque limit the torques are not computed
    (``plants.dynamic.servo_rates``) and are written as nan."""
    _chain_dynamic_rates(loop, x, ref, noise, out, False)


@jitable
def _chain_dynamic_rates(loop: ChainDynamicLoop, x: Array, ref: Array, noise: Array,
                         out: Array, torques: bool) -> None:
    """``chain_dynamic_rhs`` (``torques``) or ``chain_dynamic_stage``: the law's commands,
    then the plant's rates under them (``plants.dynamic.servo_rates``)."""
    n = loop.Ic.shape[0] - 1
    nb = n + 1
    nx = 3 * n + 1
    theta, rates, u = x[:nb], x[nb: 2 * nb], x[2 * nb: nx]
    measured = loop.rows[_MEASURED]
    noisy = False
    for i in range(nb):
        measured[i] = theta[i] + noise[i]
        noisy = noisy or noise[i] != 0.0
    sigma = _commands(loop, measured, u, ref)
    if not noisy:  # the controller's trigonometry is the plant's (the same sums)
        dynamic.trig_given(loop.plant, loop.work.cs, loop.work.sn, rates)
    servo_rates(loop.plant, theta, rates, out, nx + 1, torques, not noisy)
    limit = loop.plant.rate_limit
    u_dot = loop.rows[_U_DOT]
    for j in range(n - 1):
        out[2 * nb + j] = unwound(u[j], u_dot[j], limit)
    out[nx] = sigma


@jitable
def chain_dynamic_initial(loop: ChainDynamicLoop, initial: Array, ref: Array, x0: Array
                          ) -> None:
    """The state at t = 0 into ``x0`` (3 N + 1,) from ``initial`` (2 N,) th(0) [rad] and
    u(0) [rad/s]: th_j'(0) = r_j, the controller's rate commands at t = 0 at the true
    angles, clipped (the servo in equilibrium), th0'(0) such that H = (M q')_0 = H0 of the
    plant (``plants.dynamic.initial_base_rate``). ``ref`` (3 N,) is the plan's flag at
    t = 0."""
    n = loop.Ic.shape[0] - 1
    nb = n + 1
    theta = initial[:nb]
    u = initial[nb: 2 * n]
    _commands(loop, theta, u, ref)
    dynamic.clip_commands(loop.plant, n)
    r = loop.plant.rows[R]
    for i in range(nb):
        x0[i] = theta[i]
    for j in range(n):
        x0[nb + 1 + j] = r[j]
    for j in range(n - 1):
        x0[2 * nb + j] = u[j]
    dynamic.initial_base_rate(loop.plant, x0)


@jitable
def chain_dynamic_momentum(loop: ChainDynamicLoop, x: Array) -> float:
    """H of the plant from its full link kinematics (``chain.chain_momentum_given``) at state
    x with its own rates [kg m^2/s], given the trigonometry of its angles in
    ``loop.work`` (``chain.link_trig``)."""
    nb = loop.Ic.shape[0]
    cs, sn = loop.work.cs, loop.work.sn
    sp = loop.plant
    if sp.sin_p != 0.0 or sp.cos_p != 1.0:  # the plant's last link turned: a copy
        cs, sn = loop.rows[_PLANT_CS], loop.rows[_PLANT_SN]
        for a in range(nb):
            cs[a] = loop.work.cs[a]
            sn[a] = loop.work.sn[a]
        turn_last(cs, sn, sp.cos_p, sp.sin_p)
    return float(chain_momentum_given(loop.params, cs, sn, x[nb: 2 * nb]))


@jitable
def observe_chain_dynamic(loop: ChainDynamicLoop, obs: Any, acc: Array, j: int, x: Array,
                          f: Array) -> None:
    """Metrics at output sample j (see ``metrics``): angle and flat-output errors (the
    controller's flat map at the true state), the margin |sigma| there, H from the full
    kinematics with the plant's own rates, the largest joint rate and torque, saturation."""
    theta_ref, ref, threshold = obs
    n = loop.Ic.shape[0] - 1
    nb = n + 1
    nx = 3 * n + 1
    y, y_dot = loop.rows[_Y, :n], loop.rows[_Y_DOT, :n]
    et2 = 0.0
    for i in range(nb):
        d = x[i] - theta_ref[j, i]
        et2 += d * d
    work = loop.work
    h0 = first_terms_at(loop.Kc, loop.Ic, x[:nb], work)  # its trigonometry serves H too
    sigma = outputs_given(loop.Kc, loop.Ic, h0, work.h, work.grad, x[:nb], x[2 * nb: nx], y,
                          y_dot)
    ey2 = 0.0
    for i in range(n):
        e = y[i] - ref[2 * j, i]
        ey2 += e * e
    peak = 0.0
    torque = 0.0
    for i in range(n):
        peak = max(peak, abs(x[nb + 1 + i]))
        torque = max(torque, abs(f[nx + 1 + i]))
    observe_errors(acc, j, et2, ey2, abs(sigma), chain_dynamic_momentum(loop, x),
                   loop.plant.h0, peak, threshold)
    observe_torque(acc, torque, 0.0, f[nx + 1 + n])
    # the servos' set points: sat(u_j) (j < N) and r_N, clipped where at or beyond the limit
    limit = loop.plant.rate_limit
    clipped = abs(f[nx + 1 + 2 * n]) >= limit
    for i in range(n - 1):
        clipped = clipped or abs(x[2 * nb + i]) >= limit
    observe_clipped(acc, j, clipped)


@jitable
def record_chain_dynamic(loop: Any, trace: Array, j: int, nx: int, x: Array, f: Array
                         ) -> None:
    """Trace row j: the state, the torques tau_1..tau_N, the rate command r_N
    (``simulate.chain_dynamic_trace_columns``)."""
    n = (nx - 1) // 3
    for i in range(nx):
        trace[j, i] = x[i]
    for i in range(n):
        trace[j, nx + i] = f[nx + 1 + i]
    trace[j, nx + n] = f[nx + 1 + 2 * n]


def make_scratch(n: int) -> tuple[Array, Array, Array, Array, Array]:
    """Scratch arrays of a ``ChainDynamicLoop`` of N joints: the law's rows, then the
    plant's (``plants.dynamic.make_scratch``: rows, trig, servo_trig, matrices)."""
    return (np.zeros((ROWS, n + 1)), *dynamic.make_scratch(n))


@jitable
def measure_chain_dynamic(loop: ChainDynamicLoop, x: Array, noise: Array, ref: Array,
                          s0: Array) -> None:
    """What the flat law measures at the dynamic chain's state x (3 N + 1,) with noise
    (N + 1,): its flat outputs' errors from the plan's flag ``ref`` (3 N,) into ``s0``
    (2 N,), for a law that wraps it (``loop.compose``)."""
    n = loop.Ic.shape[0] - 1
    nb = n + 1
    measured = loop.rows[_MEASURED]
    for i in range(nb):
        measured[i] = x[i] + noise[i]
    flat_chain_errors(loop.Kc, loop.Ic, loop.work, measured, x[2 * nb: 3 * n + 1],
                      loop.rows[_Y, :n], loop.rows[_Y_DOT, :n], ref, s0)
