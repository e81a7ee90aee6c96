"""The as-built controller in closed loop: the kernels' functions for both plants, any N.

The controller (``lqr``) reads from the tracked flag (``lqr.TrackedLayout``) the plan's angles
th_r, the joints' rates w_r and accelerations a_r, and the gains L, and commands the joint
rates

    w = w_r - L (th_measured - th_r),      r = sat(w)  (kinematic plant),
                                           r = sat(w + a_r / bandwidth)  (dynamic plant),

the dynamic plant's command leading its servo's first-order lag by the plan's acceleration
(so that a servo whose model is right follows the plan exactly when the state is on it).
There is no integrator in the law, so nothing winds up against a rate or torque limit.

The plants are those of ``chainloop`` and ``chaindynamic`` (the same functions of ``chain``
and ``dynamics``), any d_N, with the plant's centre of mass across its last link as the turn
of that link's trigonometry (``chain.turn_last``; the plant's parameters are those of its
equivalent placement, ``model.RobotParams.placement``):

* kinematic, x = (th0 .. th_N): th_j' = r_j, th0' = (H0 - sum_j h_j r_j) / h_0;
* dynamic, x = (th, th'): M q'' + C q' = (0, tau), tau from the rate servo of
  ``chaindynamic.servo_demand`` (its model the plant's, or the controller's robot turned by
  the robot's own offset).

Each right-hand side writes the state's derivative, then 1.0 where the integrators look for
the controller's signed margin (the law has no singular set: the margin never changes sign,
so no trial meets a crossing, ``crossings`` is 0), then the plant's aux values (the dynamic
plant's torques, saturation flag and every rate command). The metrics
(``metrics.observe_errors``) observe an infinite margin: no singular hits, ``min_margin``
null (no status ``singular``); err_y is the error of the joint angles th_1..th_N (the
"outputs" of an exact plan).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.controllers.control import Gains
from flatcli.core.loop.chainloop import plan_residual
from flatcli.core.loop.kernels import Ops, TrialArrays
from flatcli.core.loop.metrics import observe_clipped, observe_errors, observe_torque
from flatcli.core.plan.exact import constraint_of
from flatcli.core.plants import dynamic
from flatcli.core.plants.dynamic import R, ServoPlant, servo_plant, servo_rates
from flatcli.core.plants.kinematic import kinematic_rates
from flatcli.core.robots.chain import chain_momentum_given, link_trig, turn_last
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: The threshold the metrics compare the margin with: none (below any margin), and the
#: margin they observe: the law has no singular set.
NO_THRESHOLD = -1.0
NO_MARGIN = math.inf
#: Rows of ``AsbuiltScratch.rows`` (each N + 1 long): measured angles, rate commands,
#: h, the plant's cos, sin.
_MEAS, _CMD, _H, _CS, _SN = range(5)
ROWS = 5


class AsbuiltShared(NamedTuple):
    """What every trial shares: the controller's robot (its equivalent placement's K and
    inertias, for the dynamic plant's servo model), cos and sin of its offset, the joint-rate
    limit [rad/s], whether the servo knows the plant, and (the dynamic plant) the lead
    1 / b_s [s] of the servo the law was designed for and whether the gains act on the joint
    rates too."""

    Kc: Array
    Ic: Array
    cos_c: float
    sin_c: float
    rate_limit: float
    servo_is_plant: bool
    lead: float = 0.0
    lagged: bool = False


class AsbuiltScratch(NamedTuple):
    """A loop's buffers: rows (ROWS, N + 1) and the dynamic plant's
    (``plants.dynamic.make_scratch``)."""

    rows: Array
    plant_rows: Array
    trig: Array
    servo_trig: Array
    matrices: Array


def asbuilt_scratch(n: int) -> AsbuiltScratch:
    return AsbuiltScratch(np.zeros((ROWS, n + 1)), *dynamic.make_scratch(n))


class AsbuiltLoop(NamedTuple):
    """One trial: the plant's K, inertias, parameters (4 (N + 1),) of its equivalent
    placement and cos, sin of its offset; H0 [kg m^2/s]; the shared record; the buffers; the
    dynamic plant (``plants.dynamic.ServoPlant``: its servo, limits and matrices)."""

    Kq: Array
    Iq: Array
    params: Array
    cos_p: float
    sin_p: float
    h0: float
    shared: AsbuiltShared
    rows: Array
    dyn: ServoPlant


@jitable
def asbuilt_loop(shared: AsbuiltShared, Kq: Array, params: Array, offset: float, h0: float,
                 bandwidth: float, torque_limit: float, work: AsbuiltScratch) -> AsbuiltLoop:
    """Trial's loop record (``offset``: its plant's turn of the last link [rad]); the servo's
    model is the plant or the controller's robot, turned by the robot's own offset. Its
    dynamic plant solves for the accelerations even where the servo's model is the plant's
    (``ServoPlant.lag_shortcut`` off: the as-built loop's numbers as they were)."""
    nb = shared.Ic.shape[0]
    Iq = params[nb: 2 * nb]
    dyn = servo_plant(Kq, Iq, shared.Kc, shared.Ic, shared.servo_is_plant, offset,
                      shared.cos_c, shared.sin_c, h0, shared.rate_limit, bandwidth,
                      torque_limit, work.plant_rows, work.trig, work.servo_trig, work.matrices,
                      False)
    return AsbuiltLoop(Kq, Iq, params, dyn.cos_p, dyn.sin_p, h0, shared, work.rows, dyn)


@jitable
def commands(loop: AsbuiltLoop, x: Array, ref: Array, noise: Array, cmd: Array) -> None:
    """The rate commands r_j (N,) into ``cmd``: the law at the measured angles x[:N + 1] +
    noise (and, lagged, the joints' rates x[N + 2:]), plus the lead times the plan's joint
    accelerations (``lqr.TrackedLayout``); the plant clips them to its rate limit."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    shared = loop.shared
    width = 2 * n + 1 if shared.lagged else nb
    c = nb + n * width
    meas = loop.rows[_MEAS]
    for a in range(nb):
        meas[a] = x[a] + noise[a]
    for j in range(1, nb):
        w = ref[c + j - 1] + shared.lead * ref[2 * c + j - 1]
        base = nb + (j - 1) * width
        w -= ref[base] * (meas[0] - ref[n])
        for a in range(1, nb):
            w -= ref[base + a] * (meas[a] - ref[a - 1])
        if shared.lagged:
            for k in range(1, nb):
                w -= ref[base + n + k] * (x[nb + k] - ref[c + k - 1])
        cmd[j - 1] = w


@jitable
def plant_trig(loop: AsbuiltLoop, theta: Array) -> None:
    """The plant's trigonometry at theta[:N + 1] into rows[_CS], rows[_SN] (turned; an
    integrator's state rows are longer than the state)."""
    cs, sn = loop.rows[_CS], loop.rows[_SN]
    link_trig(theta[: cs.shape[0]], cs, sn)
    turn_last(cs, sn, loop.cos_p, loop.sin_p)


@jitable
def kinematic_rhs(loop: AsbuiltLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the kinematic plant under the as-built law.

    Parameters
    ----------
    x : (N + 1,) th0..th_N [rad]; ref : the tracked flag (``lqr.TrackedLayout``)
    noise : (N + 1,) sensor noise on the measured angles [rad]
    out : (>= N + 2,) written: th0'..th_N' [rad/s] (the applied rates), then 1.0
    """
    nb = loop.Iq.shape[0]
    cmd = loop.rows[_CMD]
    commands(loop, x, ref, noise, cmd)
    plant_trig(loop, x[:nb])
    kinematic_rates(loop.Kq, loop.Iq, loop.h0, loop.shared.rate_limit, loop.rows[_CS],
                    loop.rows[_SN], loop.rows[_H], cmd, out)
    out[nb] = 1.0


@jitable
def squared_errors(obs: Any, j: int, x: Array, nb: int) -> tuple[float, float]:
    """At output sample j, the squared norms of the angles' error from the plan (th0..thN)
    and of the joint angles' error from the plan's y (th1..thN, the as-built law's
    outputs); ``obs`` = (theta_ref, ref, threshold) as the kernels pass it (the singular
    threshold does not apply: module docstring)."""
    theta_ref, ref, _ = obs
    et2 = 0.0
    ey2 = 0.0
    for i in range(nb):
        d = x[i] - theta_ref[j, i]
        et2 += d * d
        if i > 0:
            e = x[i] - ref[2 * j, i - 1]
            ey2 += e * e
    return et2, ey2


@jitable
def observe_kinematic(loop: AsbuiltLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
                      ) -> None:
    """Metrics of the kinematic plant at output sample j (module docstring)."""
    nb = loop.Iq.shape[0]
    et2, ey2 = squared_errors(obs, j, x, nb)
    plant_trig(loop, x[:nb])
    peak = 0.0
    for i in range(1, nb):
        peak = max(peak, abs(f[i]))
    h = chain_momentum_given(loop.params, loop.rows[_CS], loop.rows[_SN], f[:nb])
    observe_errors(acc, j, et2, ey2, NO_MARGIN, h, loop.h0, peak, NO_THRESHOLD)
    # the joints turn at the clipped commands: at the limit exactly where one was clipped
    observe_clipped(acc, j, peak >= loop.shared.rate_limit)


@jitable
def record_kinematic(loop: Any, trace: Array, j: int, nx: int, x: Array, f: Array
                     ) -> None:
    """Trace row j (``simulate.chain_trace_columns``): th, the rate commands of joints
    1..N-1 (in the columns of the flat loop's u_j), then th0'..th_N'."""
    n = nx - 1
    for i in range(nx):
        trace[j, i] = x[i]
    for i in range(1, n):
        trace[j, nx + i - 1] = f[i]
    for i in range(nx):
        trace[j, nx + n - 1 + i] = f[i]


@jitable
def kinematic_initial(loop: AsbuiltLoop, initial: Array, ref: Array, x0: Array) -> None:
    """th(0) into x0 (N + 1,) (the kinematic plant has no rate state: u(0) does not enter)."""
    for k in range(x0.shape[0]):
        x0[k] = initial[k]


@jitable
def dynamic_rhs(loop: AsbuiltLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
    """Rates of the dynamic plant under the as-built law and the rate servos.

    Parameters
    ----------
    x : (2 N + 2,) th [rad], th' [rad/s]; ref : the tracked flag; noise : (N + 1,) [rad]
    out : (>= 2 N + 2 + ``dynamic_aux(N)``,) written: th' [rad/s], th'' [rad/s^2]; 1.0;
        tau_1..tau_N [N m], 1.0 if a torque was clipped (else 0.0), r_1..r_N [rad/s]
    """
    nb = loop.Iq.shape[0]
    nx = 2 * nb
    commands(loop, x, ref, noise, loop.dyn.rows[R])
    servo_rates(loop.dyn, x[:nb], x[nb:nx], out, nx + 1, True, False)
    out[nx] = 1.0


def dynamic_aux(n: int) -> int:
    """Values ``dynamic_rhs`` writes after the state's derivative: 1.0, then the plant's
    (``plants.dynamic.aux``: tau (N), the saturation flag, r (N))."""
    return 1 + dynamic.aux(n)


@jitable
def dynamic_initial(loop: AsbuiltLoop, initial: Array, ref: Array, x0: Array) -> None:
    """The dynamic plant's state at t = 0 into x0 (2 N + 2,): th(0) and the rates th_j'(0)
    = u_j(0) of joints j < N from ``initial`` (2 N,), joint N at the plan's rate, th0' such
    that H = (M q')_0 = H0 (the law acts on the rate errors from there)."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    width = 2 * n + 1 if loop.shared.lagged else nb
    c = nb + n * width
    for a in range(nb):
        x0[a] = initial[a]
    x0[nb] = 0.0
    for j in range(1, n):
        x0[nb + j] = initial[nb + j - 1]
    x0[nb + n] = ref[c + n - 1]
    dynamic.initial_base_rate(loop.dyn, x0)


@jitable
def observe_dynamic(loop: AsbuiltLoop, obs: Any, acc: Array, j: int, x: Array, f: Array
                    ) -> None:
    """Metrics of the dynamic plant at output sample j: errors, the margin of its motion,
    H from the full kinematics with its own rates, peak joint rate and torque, saturation."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    nx = 2 * nb
    et2, ey2 = squared_errors(obs, j, x, nb)
    plant_trig(loop, x[:nb])
    rates = x[nb:nx]
    peak = 0.0
    torque = 0.0
    for i in range(n):
        peak = max(peak, abs(rates[i + 1]))
        torque = max(torque, abs(f[nx + 1 + i]))
    h = chain_momentum_given(loop.params, loop.rows[_CS], loop.rows[_SN], rates)
    observe_errors(acc, j, et2, ey2, NO_MARGIN, h, loop.h0, peak, NO_THRESHOLD)
    observe_torque(acc, torque, 0.0, f[nx + 1 + n])
    # the servos' set points r_1..r_N (clipped commands): at the limit where one was clipped
    limit = loop.shared.rate_limit
    clipped = False
    for i in range(n):
        clipped = clipped or abs(f[nx + 2 + n + i]) >= limit
    observe_clipped(acc, j, clipped)


@jitable
def record_dynamic(loop: Any, trace: Array, j: int, nx: int, x: Array, f: Array
                   ) -> None:
    """Trace row j (``simulate.chain_dynamic_trace_columns``): the state, the rate commands
    r_1..r_N-1 (the flat loop's u_j columns), tau_1..tau_N, r_N."""
    n = (nx - 2) // 2
    for i in range(nx):
        trace[j, i] = x[i]
    for i in range(n - 1):
        trace[j, nx + i] = f[nx + 2 + n + i]
    for i in range(n):
        trace[j, nx + n - 1 + i] = f[nx + 1 + i]
    trace[j, nx + 2 * n - 1] = f[nx + 1 + 2 * n]


@jitable
def additive(loop: AsbuiltLoop, ref: Array, dv: Array, out: Array) -> None:
    """The as-built law's additive input: ``out`` = the tracked flag ``ref`` with dv (N,)
    [rad/s] added to the joint-rate commands w (``commands``): on the plan's joint rates w_r
    (the kinematic plant's law), or, where w_r enters the rate errors too (the dynamic
    plant's, ``AsbuiltShared.lagged``), on the lead's channel a_r as dv / lead (for a law that
    wraps it, ``loop.compose``)."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    shared = loop.shared
    width = 2 * n + 1 if shared.lagged else nb
    c = nb + n * width
    for k in range(3 * c):
        out[k] = ref[k]
    for j in range(1, nb):
        if shared.lagged:
            out[2 * c + j - 1] += dv[j - 1] / shared.lead
        else:
            out[c + j - 1] += dv[j - 1]


@jitable
def measure(loop: AsbuiltLoop, x: Array, noise: Array, ref: Array, s0: Array) -> None:
    """What the as-built law measures at state x with noise (N + 1,): the errors its gains
    act on, from the tracked flag ``ref``, into ``s0``: the measured angles' th0 - th0_r,
    th_j - th_jr (j = 1..N), and where the law acts on the joint rates (the dynamic plant)
    th_j' - w_jr (the order of ``lqr.linearisation``; for ``loop.compose``)."""
    nb = loop.Iq.shape[0]
    n = nb - 1
    shared = loop.shared
    width = 2 * n + 1 if shared.lagged else nb
    c = nb + n * width
    s0[0] = x[0] + noise[0] - ref[n]
    for a in range(1, nb):
        s0[a] = x[a] + noise[a] - ref[a - 1]
    if shared.lagged:
        for k in range(1, nb):
            s0[n + k] = x[nb + k] - ref[c + k - 1]


@jitable
def _loop(shared: AsbuiltShared, trials: TrialArrays, i: int, scratch: AsbuiltScratch
          ) -> Any:
    return asbuilt_loop(shared, trials.plant[i], trials.params[i], trials.offset[i],
                        trials.h0[i], trials.servo[i, 0], trials.servo[i, 1], scratch)


@jitable
def _residual(loop: Any, trials: TrialArrays, i: int, plan_theta: Array,
              plan_theta_dot: Array) -> float:
    return plan_residual(plan_theta, plan_theta_dot, loop.params, loop.h0, loop.rows[_CS],
                         loop.rows[_SN], loop.cos_p, loop.sin_p)


@jitable
def _bounded(loop: Any) -> bool:
    """The as-built law has no singular set: its commands are bounded everywhere (finite
    gains about a finite plan), and its margin (1.0) never changes sign, so no trial meets
    a crossing to stop at or to pass (``crossings`` is 0)."""
    return True


#: The as-built law on the kinematic and the dynamic plant (``kernels.Ops``; compiled by
#: ``table``), any N.
ASBUILT_KINEMATIC = Ops(_loop, _bounded, kinematic_initial, kinematic_rhs, observe_kinematic,
                        record_kinematic, _residual, lambda n: n + 1, lambda n: 1,
                        lambda n: 3 * n + 1, asbuilt_scratch, additive=additive,
                        measure=measure)
ASBUILT_DYNAMIC = Ops(_loop, _bounded, dynamic_initial, dynamic_rhs, observe_dynamic,
                      record_dynamic, _residual, lambda n: 2 * n + 2, dynamic_aux,
                      lambda n: 4 * n + 2, asbuilt_scratch, additive=additive,
                      measure=measure)


def asbuilt_shared(model: Any, gains: Gains, rate_limit: float, servo_is_plant: bool,
                   robot: RobotParams) -> AsbuiltShared:
    """What every trial shares: the controller's robot (``exact.Constraint`` of ``robot``,
    writable copies), the rate limit, the servo's model (``gains`` and ``model`` are the
    flat law's: the as-built law's gains are in the tracked flag)."""
    constraint = constraint_of(robot)
    return AsbuiltShared(np.array(constraint.K, dtype=float),
                         np.array(constraint.inertia, dtype=float),
                         float(np.cos(constraint.offset)), float(np.sin(constraint.offset)),
                         float(rate_limit), servo_is_plant)
