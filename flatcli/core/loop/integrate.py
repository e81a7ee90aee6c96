"""Compiled integrators of one closed-loop trial: fixed-step RK4 and adaptive Dormand-Prince.

Both integrate a state x of any size with a right-hand side ``rhs(loop, x, ref, noise, out)``
(``plant``), hand every output sample t_j = j dt (j = 0..n) to an observer
``observe(loop, obs, acc, j, x, f)`` with f = rhs at that sample (the rates the plant applies
there), and stop a trial early, with an ``metrics.Event``, where its numbers could not be
trusted:

* a state beyond the divergence bound, or non-finite (``BOUND``);
* the controller's signed margin (written by ``rhs`` after the state's derivative) changing
  sign within a step (``CROSSED``): the feedback divides by it, so the trial has crossed the
  singular set, where no integrator can pass; a fixed step would jump over the pole and
  carry on with finite garbage. Both integrators check the margin at every stage and at the
  step's end (the adaptive one on the steps it accepts), before the divergence bound;
* (adaptive only) the step size falling below ``STEP_FLOOR`` T: onto the singular set
  (|margin| < ``STALL_MARGIN``: ``STALLED``) or elsewhere (``STEP_FLOOR``), or
  ``max_steps`` attempted steps spent (``MAX_STEPS``).

Sensor noise is held over each output interval [t_j, t_j+1): row j of a given table, or
three normal variates per interval drawn in order from the trial's generator (numba's
``Generator.standard_normal`` gives numpy's numbers bit for bit), so memory does not grow
with n and no tolerance ever changes the noise a trial sees. With noise the adaptive
integrator never steps across an output time (the right-hand side jumps there).

The adaptive integrator is the Dormand-Prince 5(4) pair (Dormand & Prince, J. Comp. Appl.
Math. 6, 1980; the tableau, error weights and order-4 dense output of scipy's ``RK45``) with
local extrapolation and the standard step-size controller (safety 0.9, growth within
[0.2, 10], no growth after a rejection); error norm: RMS over the components of
err_i / (atol + rtol max(|x_i|, |x_new,i|)). Output samples inside a step come from the
dense output. Its global-error estimate for the angles is the sum over accepted steps of the
Euclidean norm of the embedded error estimate of the first ``n_angles`` components.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable, jitable_variant, variant_tag
from flatcli.core.loop.metrics import Event, observe_crossing

Array = NDArray[np.float64]

#: The adaptive step size may not fall below STEP_FLOOR * T.
STEP_FLOOR = 1e-12
#: A step size collapsing where |margin| is below this [rad/s] is the singular set.
STALL_MARGIN = 1e-6
#: A crossing of the singular set that the actuators bound is passed in a step of at most
#: CROSS_STEP * T: the integration closes in on it to there (the right-hand side jumps where
#: the margin changes sign, so a step across it is only as accurate as it is short: with
#: rates bounded by R, off by at most 2 R CROSS_STEP T).
CROSS_STEP = 1e-11

_NONE = int(Event.NONE)
_BOUND = int(Event.BOUND)
_CROSSED = int(Event.CROSSED)
_STALLED = int(Event.STALLED)
_STEP_FLOOR = int(Event.STEP_FLOOR)
_MAX_STEPS = int(Event.MAX_STEPS)

# Dormand-Prince 5(4): nodes, stages, 5th-order weights, error weights (5th - 4th), dense
# output (scipy.integrate._ivp.rk.RK45: C, A, B, E, P).
_C2, _C3, _C4, _C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9
_A21 = 1 / 5
_A31, _A32 = 3 / 40, 9 / 40
_A41, _A42, _A43 = 44 / 45, -56 / 15, 32 / 9
_A51, _A52, _A53, _A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
_A61, _A62, _A63, _A64, _A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
_B1, _B3, _B4, _B5, _B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
_E1, _E3, _E4, _E5, _E6, _E7 = (-71 / 57600, 71 / 16695, -71 / 1920, 17253 / 339200,
                                -22 / 525, 1 / 40)
DENSE = np.array([
    [1, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432],
    [0, 0, 0, 0],
    [0, 131558114200 / 32700410799, -68118460800 / 10900136933,
     87487479700 / 32700410799],
    [0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072],
    [0, 127303824393 / 49829197408, -318862633887 / 49829197408,
     701980252875 / 199316789632],
    [0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844],
    [0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423],
])  # fmt: skip
DENSE.setflags(write=False)

#: Rows of an integrator's work buffer (WORK_ROWS, nx).
_X, _XN, _K1, _K2, _K3, _K4, _K5, _K6, _K7, _Y, _XS, _FS, _Q0, _Q1, _Q2, _Q3 = range(16)
WORK_ROWS = 16


@jitable
def plan_flag(breaks: Array, local: Array, t: float, out: Array) -> None:
    """The plan's flat flag y, y', y'' (N outputs each) at time t into ``out`` (3 N,), from
    its piecewise polynomials (``basis.Basis.piecewise``: breaks (m + 1,), local
    (m, d + 1, N)); for the paper's robot y1, y2, y1', y2', y1'', y2''."""
    m = breaks.shape[0] - 1
    lo, hi = 0, m
    while hi - lo > 1:  # the piece with breaks[i] <= t (clamped to the first and last)
        mid = (lo + hi) // 2
        if breaks[mid] <= t:
            lo = mid
        else:
            hi = mid
    i = lo
    width = breaks[i + 1] - breaks[i]
    s = (t - breaks[i]) / width
    degree = local.shape[1] - 1
    outputs = local.shape[2]
    for o in range(outputs):
        p = local[i, degree, o]
        dp = 0.0
        half_ddp = 0.0
        for j in range(degree - 1, -1, -1):
            half_ddp = half_ddp * s + dp
            dp = dp * s + p
            p = p * s + local[i, j, o]
        out[o] = p
        out[outputs + o] = dp / width
        out[2 * outputs + o] = 2.0 * half_ddp / (width * width)


@jitable
def load_noise(j: int, table: Array, noise: Array) -> None:
    """Sensor noise of output interval j into ``noise`` (one per measured angle): row j of
    ``table`` if it has rows (else none: ``noise`` keeps its zeros)."""
    if table.shape[0] > 0:
        for i in range(noise.shape[0]):
            noise[i] = table[j, i]


@jitable
def _out_of_bounds(x: Array, bound: float) -> bool:
    for i in range(x.shape[0]):  # noqa: SIM110 (numba: a plain loop, no generator)
        if not abs(x[i]) <= bound:  # nan included
            return True
    return False


@jitable
def _finite(x: Array) -> bool:
    for i in range(x.shape[0]):  # noqa: SIM110 (numba: a plain loop, no generator)
        if not math.isfinite(x[i]):
            return False
    return True


@jitable
def _flipped(a: float, b: float) -> bool:
    """Whether the margin changed sign (or reached zero) from a to b."""
    return (a > 0.0) != (b > 0.0) or b == 0.0


@jitable
def _fraction(a: float, b: float) -> float:
    """Where, between a margin a (at 0) and b (at 1) of the other sign (or zero), the linear
    interpolation between them is zero: in [0, 1]."""
    if b == 0.0:
        return 1.0
    return min(max(a / (a - b), 0.0), 1.0)


@jitable
def _stage_margin(node: float, k2: Array, k3: Array, k4: Array, k5: Array, k6: Array,
                  nx: int) -> float:
    """The margin the Dormand-Prince stage at ``node`` (``_first_flip``) found."""
    if node == _C2:
        return k2[nx]  # type: ignore[no-any-return]
    if node == _C3:
        return k3[nx]  # type: ignore[no-any-return]
    if node == _C4:
        return k4[nx]  # type: ignore[no-any-return]
    if node == _C5:
        return k5[nx]  # type: ignore[no-any-return]
    return k6[nx]  # type: ignore[no-any-return]


@jitable
def _first_flip(sigma: float, m2: float, m3: float, m4: float, m5: float, m6: float) -> float:
    """The node (fraction of the step) of the first Dormand-Prince stage whose margin has the
    other sign than ``sigma`` (-1 if none)."""
    if _flipped(sigma, m2):
        return _C2
    if _flipped(sigma, m3):
        return _C3
    if _flipped(sigma, m4):
        return _C4
    if _flipped(sigma, m5):
        return _C5
    if _flipped(sigma, m6):
        return 1.0
    return -1.0


@jitable
def _on_sample(t: float, dt: float) -> bool:
    """Whether time t [s] is an output time j dt, within the relative 1e-14 by which the
    adaptive integrator's step's end meets one (a margin ten times as wide, so that no
    sample the integrator observes at a step's end is missed)."""
    j = math.floor(t / dt + 0.5)
    return abs(j * dt - t) <= 1e-13 * t


@jitable
def observed(j: int, n: int, every: int) -> bool:
    """Whether output sample j of 0..n enters the metrics when they observe every
    ``every``-th sample (``track.observe_every``): j = 0, 1k, 2k, ... and always the last, n,
    whose state gives the final errors."""
    return every == 1 or j % every == 0 or j == n


@jitable
def record_rates(loop: Any, trace: Array, j: int, nx: int, x: Array, f: Array
                 ) -> None:
    """Trace row j: the state x (nx,), then the first ``width - nx`` rates f the plant applies
    (th0', th1', ...; the default ``record`` of ``make_trial_integrators``)."""
    for i in range(nx):
        trace[j, i] = x[i]
    for i in range(trace.shape[1] - nx):
        trace[j, nx + i] = f[i]


@jitable
def no_reset(loop: Any) -> None:
    """A loop whose controller keeps nothing between trials (``make_trial_integrators``)."""


@jitable
def no_period(loop: Any) -> int:
    """A loop whose controller acts at no sample instants: 0 (``make_trial_integrators``)."""
    return 0


@jitable
def no_sample(loop: Any, x: Array, noise: Array, ref: Array, j: int) -> None:
    """A controller with nothing to do at sample instants (``make_trial_integrators``)."""


def make_trial_integrators(
    rhs: Callable[..., None],
    observe: Callable[..., None],
    record_sample: Callable[..., None] = record_rates,
    stage: Callable[..., None] | None = None,
    reset: Callable[..., None] = no_reset,
    period: Callable[..., int] = no_period,
    sample: Callable[..., None] = no_sample,
) -> tuple[Callable[..., Any], Callable[..., Any]]:
    """(rk4_trial, adaptive_trial): the two integrators of one trial for a plant, compiled
    inline with its right-hand side ``rhs`` (which writes the state's derivative into
    out[:nx] and the controller's signed margin into out[nx]), its ``observe``r, and
    ``record_sample(loop, trace, j, nx, x, f)``, which writes trace row j (``record_rates``).
    ``stage`` (default ``rhs``): the right-hand side where nothing after out[nx] is read,
    which must write out[:nx + 1] exactly as ``rhs`` does (the stages of a step and the
    first-step estimate; a step's end only where no output sample falls on it); ``observe``
    and ``record_sample`` are only ever given ``rhs``'s values.

    Shared arguments (see the module docstring): ``loop`` (the plant's and controller's
    parameters), ``obs`` (the observer's tables), ``x0`` (nx,), ``dt`` [s], ``n`` output
    intervals, ``bound``, ``bounded`` (the actuators bound the right-hand side at the
    singular set: a crossing is passed, not a stop), the noise source (``table`` (n, angles)
    or (0, angles), ``gen``, ``std``), ``record`` and ``trace`` (n + 1, width: what
    ``record_sample`` writes per sample), ``acc`` (the observer's accumulator, where crossings
    are counted too) and ``work`` (WORK_ROWS, >= nx + 1: the right-hand side's outputs).

    A controller that acts at sample instants (``loop.compose``) gives three more:
    ``reset(loop)``, called as each integration starts (a trial, and its twin: the controller
    starts afresh); ``period(loop)``, the output steps p between its samples (0: none); and
    ``sample(loop, x, noise, ref, j)``, called at every output sample j = 0, p, 2 p, .. < n
    with the state there, the noise of interval j and the plan's flag at t_j, before the
    right-hand side is evaluated there (what it changes holds until its next sample). RK4
    steps on the output grid; the adaptive integrator never steps across a sample instant
    (as it does not across a noise interval's end) and starts afresh at each. The defaults
    do nothing, and the kernels of the laws without samples compute what they did before.
    """
    stage_rhs = rhs if stage is None else stage
    hooks = () if (reset is no_reset and period is no_period and sample is no_sample) else (
        reset, period, sample)
    variant = jitable_variant(variant_tag(rhs, observe, record_sample, stage_rhs, *hooks))

    @variant
    def rk4_step(loop: Any, nx: int, x: Array, k1: Array, h: float, ref_mid: Array,
                 ref_end: Array, noise: Array, k2: Array, k3: Array, k4: Array, y: Array,
                 out: Array) -> float:
        """One classical RK4 step of size h from x (k1 = rhs at x given) into ``out``;
        returns the fraction of the step where a stage first found the margin of the other
        sign (-1: none; the step's end is not checked here)."""
        sigma = k1[nx]
        half = 0.5 * h
        for i in range(nx):
            y[i] = x[i] + half * k1[i]
        stage_rhs(loop, y, ref_mid, noise, k2)
        for i in range(nx):
            y[i] = x[i] + half * k2[i]
        stage_rhs(loop, y, ref_mid, noise, k3)
        for i in range(nx):
            y[i] = x[i] + h * k3[i]
        stage_rhs(loop, y, ref_end, noise, k4)
        sixth = h / 6.0
        for i in range(nx):
            out[i] = x[i] + sixth * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        if _flipped(sigma, k2[nx]):
            return 0.5 * _fraction(sigma, k2[nx])
        if _flipped(sigma, k3[nx]):
            return 0.5 * _fraction(sigma, k3[nx])
        if _flipped(sigma, k4[nx]):
            return _fraction(sigma, k4[nx])
        return -1.0

    @variant
    def rk4_trial(
        loop: Any, obs: Any, x0: Array, ref: Array, breaks: Array, local: Array,
        flag_mid: Array, flag_end: Array, dt: float, n: int, bound: float, bounded: bool,
        table: Array, record: bool, trace: Array, acc: Array, work: Array, noise: Array,
        every: int,
    ) -> tuple[int, int, float, int]:
        """Classical RK4 on the output grid; ``ref`` (2 n + 1, 3 N) the plan at half steps;
        the metrics observe the samples ``observed(j, n, every)`` says.
        Where a step meets the singular set and the actuators bound the plant there, the
        output interval is integrated in sub-steps that close in on the crossing (each a
        tenth of the way, from where the margin's interpolation puts it), pass it in a step
        of at most ``CROSS_STEP`` T, and go on to the interval's end.

        Returns (last sample observed, Event, event time [s], right-hand-side evaluations).
        """
        nx = x0.shape[0]
        x, k1, k2, k3, k4, y = work[_X], work[_K1], work[_K2], work[_K3], work[_K4], work[_Y]
        xn, ke = work[_XN], work[_K7]
        for i in range(nx):
            x[i] = x0[i]
        noise[:] = 0.0
        evaluations = 0
        floor = CROSS_STEP * n * dt
        before = 0.0
        reset(loop)
        sampling = period(loop)
        for s in range(n + 1):
            if s < n:
                load_noise(s, table, noise)
                if sampling > 0 and s % sampling == 0:
                    sample(loop, x, noise, ref[2 * s], s)
            rhs(loop, x, ref[2 * s], noise, k1)
            evaluations += 1
            if s > 0 and _flipped(before, k1[nx]):
                # the margin here has the other sign than at the last step's start, though no
                # stage of that step had: it changed sign in the step's last sliver, or the
                # noise of the new interval moved the measured angles across
                if not bounded:
                    t_cross = (s - 1 + _fraction(before, k1[nx])) * dt
                    observe_crossing(acc, t_cross)
                    return s - 1, _CROSSED, t_cross, evaluations
                observe_crossing(acc, s * dt)
            if observed(s, n, every):
                observe(loop, obs, acc, s, x, k1)
            if record:
                record_sample(loop, trace, s, nx, x, k1)
            if s == n:
                break
            before = k1[nx]
            frac = rk4_step(loop, nx, x, k1, dt, ref[2 * s + 1], ref[2 * s + 2], noise, k2, k3,
                            k4, y, xn)
            evaluations += 3
            if frac >= 0.0 and not bounded:
                observe_crossing(acc, (s + frac) * dt)
                return s, _CROSSED, (s + frac) * dt, evaluations
            if frac < 0.0:
                for i in range(nx):
                    x[i] = xn[i]
            else:  # sub-steps through the crossing, to the interval's end
                t = s * dt
                t_end = (s + 1) * dt
                h = frac * dt * 0.9
                while t < t_end:
                    h = min(h, t_end - t)
                    plan_flag(breaks, local, t + 0.5 * h, flag_mid)
                    plan_flag(breaks, local, t + h, flag_end)
                    frac = rk4_step(loop, nx, x, k1, h, flag_mid, flag_end, noise, k2, k3, k4,
                                    y, xn)
                    stage_rhs(loop, xn, flag_end, noise, ke)  # its margin only
                    evaluations += 4
                    if frac < 0.0 and _flipped(k1[nx], ke[nx]):
                        frac = _fraction(k1[nx], ke[nx])
                    if frac >= 0.0 and h > floor:
                        h = 0.9 * frac * h if frac * h > floor else floor
                        continue
                    if frac >= 0.0:  # a step of at most the floor across: passed
                        observe_crossing(acc, t + max(frac, 0.0) * h)
                    t = t_end if t_end - t - h <= 1e-12 * dt else t + h
                    for i in range(nx):
                        x[i] = xn[i]
                    for i in range(nx + 1):
                        k1[i] = ke[i]
                    h = t_end - t
                before = k1[nx]
            if _out_of_bounds(x[:nx], bound):
                return s, _BOUND, (s + 1) * dt, evaluations
        return n, _NONE, math.nan, evaluations

    @variant
    def initial_step(loop: Any, nx: int, x: Array, f: Array, ref: Array, noise: Array,
                     rtol: float, atol: float, limit: float, y: Array, f1: Array, breaks: Array,
                     local: Array, t: float) -> float:
        """First step size (Hairer, Norsett & Wanner, Solving ODEs I, II.4; scipy's
        ``select_initial_step`` for order 5) for the first nx components, from time t."""
        d0 = 0.0
        d1 = 0.0
        for i in range(nx):
            scale = atol + rtol * abs(x[i])
            d0 += (x[i] / scale) ** 2
            d1 += (f[i] / scale) ** 2
        d0 = math.sqrt(d0 / nx)
        d1 = math.sqrt(d1 / nx)
        h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
        h0 = min(h0, limit)
        for i in range(nx):
            y[i] = x[i] + h0 * f[i]
        plan_flag(breaks, local, t + h0, ref)
        stage_rhs(loop, y, ref, noise, f1)
        d2 = 0.0
        for i in range(nx):
            scale = atol + rtol * abs(x[i])
            d2 += ((f1[i] - f[i]) / scale) ** 2
        d2 = math.sqrt(d2 / nx) / h0
        if not math.isfinite(d2):
            return min(h0, limit)
        quiet = d1 <= 1e-15 and d2 <= 1e-15
        h1 = max(1e-6, h0 * 1e-3) if quiet else (0.01 / max(d1, d2)) ** 0.2
        return min(100.0 * h0, h1, limit)

    @variant
    def adaptive_trial(
        loop: Any, obs: Any, x0: Array, breaks: Array, local: Array, dt: float, n: int,
        bound: float, rtol: float, atol: float, max_steps: int, table: Array, record: bool,
        trace: Array, acc: Array, work: Array, noise: Array, ref: Array, samples_ref: Array,
        bounded: bool, observing: bool, every: int,
    ) -> tuple[int, int, float, int, int]:
        """Dormand-Prince 5(4) with step control and dense output (see the module docstring);
        ``breaks``, ``local`` the plan's pieces (``plan_flag``), ``samples_ref`` (2 n + 1, 3 N)
        the plan at half steps (row 2 j at output sample j).

        Where a step meets the singular set: without ``bounded`` the trial stops there
        (``CROSSED``); with it the step is taken again, shorter, closing in on the crossing
        (each time a tenth of the way, from where the margin's interpolation between the
        stages puts it), until a step of at most ``CROSS_STEP`` T passes it; the crossing is
        counted (``metrics.observe_crossing``) and the integration restarts on the far side
        with a fresh first stage. Without ``observing`` nothing is observed or recorded and
        the steps need not meet the output times (a twin solution, ``err_estimate``). The
        metrics observe the samples ``observed(j, n, every)`` says; the others are passed
        without evaluating anything (unless a trace is recorded, or the step ends beyond the
        divergence bound: then every sample is evaluated, and only the metrics skip them).

        Returns (last sample observed, Event, event time [s], accepted steps,
        right-hand-side evaluations); the final state is left in ``work[_X]``.
        """
        nx = x0.shape[0]
        x, xn, y, xs = work[_X], work[_XN], work[_Y], work[_XS]
        k1, k2, k3, k4, k5, k6, k7 = (work[_K1], work[_K2], work[_K3], work[_K4], work[_K5],
                                      work[_K6], work[_K7])
        duration = n * dt
        noisy = table.shape[0] > 0
        sampling = period(loop)
        # output steps between the instants a step may not cross (0: none before T): each
        # noise interval's end, else each of the controller's sample instants
        stride = 1 if noisy else sampling
        floor = STEP_FLOOR * duration
        cross_floor = CROSS_STEP * duration
        for i in range(nx):
            x[i] = x0[i]
        noise[:] = 0.0
        load_noise(0, table, noise)
        plan_flag(breaks, local, 0.0, ref)
        reset(loop)
        if sampling > 0:
            sample(loop, x, noise, ref, 0)
        rhs(loop, x, ref, noise, k1)
        evaluations = 1
        if observing:
            observe(loop, obs, acc, 0, x, k1)
            if record:
                record_sample(loop, trace, 0, nx, x, k1)
        if not _finite(k1[:nx]):
            return 0, _BOUND, 0.0, 0, evaluations
        last = 0
        interval = 0  # the output sample j of the last instant stopped at (t_j)
        t = 0.0
        h = initial_step(loop, nx, x, k1, ref, noise, rtol, atol,
                         stride * dt if stride > 0 else duration, y, k2, breaks, local, 0.0)
        evaluations += 1
        sigma = k1[nx]
        steps = 0
        attempts = 0
        rejected = False
        while t < duration:
            if attempts >= max_steps:
                return last, _MAX_STEPS, t, steps, evaluations
            attempts += 1
            stop = (interval + stride) * dt if stride > 0 else duration
            if h >= stop - t or stop - t - h < 1e-10 * (stop - t):
                h = stop - t
                t_new = stop
            else:
                t_new = t + h
            for i in range(nx):
                y[i] = x[i] + h * (_A21 * k1[i])
            plan_flag(breaks, local, t + _C2 * h, ref)
            stage_rhs(loop, y, ref, noise, k2)
            for i in range(nx):
                y[i] = x[i] + h * (_A31 * k1[i] + _A32 * k2[i])
            plan_flag(breaks, local, t + _C3 * h, ref)
            stage_rhs(loop, y, ref, noise, k3)
            for i in range(nx):
                y[i] = x[i] + h * (_A41 * k1[i] + _A42 * k2[i] + _A43 * k3[i])
            plan_flag(breaks, local, t + _C4 * h, ref)
            stage_rhs(loop, y, ref, noise, k4)
            for i in range(nx):
                y[i] = x[i] + h * (_A51 * k1[i] + _A52 * k2[i] + _A53 * k3[i] + _A54 * k4[i])
            plan_flag(breaks, local, t + _C5 * h, ref)
            stage_rhs(loop, y, ref, noise, k5)
            for i in range(nx):
                y[i] = x[i] + h * (_A61 * k1[i] + _A62 * k2[i] + _A63 * k3[i] + _A64 * k4[i]
                                   + _A65 * k5[i])
            plan_flag(breaks, local, t_new, ref)
            stage_rhs(loop, y, ref, noise, k6)
            for i in range(nx):
                xn[i] = x[i] + h * (_B1 * k1[i] + _B3 * k3[i] + _B4 * k4[i] + _B5 * k5[i]
                                    + _B6 * k6[i])
            if observing and _on_sample(t_new, dt):  # observed there if the step is taken
                rhs(loop, xn, ref, noise, k7)
            else:
                stage_rhs(loop, xn, ref, noise, k7)
            evaluations += 6
            norm = 0.0
            for i in range(nx):
                err = h * (_E1 * k1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i]
                           + _E6 * k6[i] + _E7 * k7[i])
                norm += (err / (atol + rtol * max(abs(x[i]), abs(xn[i])))) ** 2
            norm = math.sqrt(norm / nx)
            after = k7[nx]
            stage = _first_flip(sigma, k2[nx], k3[nx], k4[nx], k5[nx], k6[nx])
            crossed = _flipped(sigma, after) or stage >= 0.0
            passing = False
            if crossed:
                # where the margin changes sign: interpolated between the step's start and
                # the first stage (or its end) on the other side
                if stage >= 0.0:
                    fraction = stage * _fraction(sigma, _stage_margin(stage, k2, k3, k4, k5,
                                                                      k6, nx))
                else:
                    fraction = _fraction(sigma, after)
                if not bounded:
                    if norm <= 1.0:  # accepted: the trial met the singular set
                        if observing:
                            observe_crossing(acc, t + fraction * h)
                        return last, _CROSSED, t + fraction * h, steps, evaluations
                elif h > cross_floor:  # close in: take the step again, short of it
                    h = max(0.9 * fraction * h, cross_floor)
                    rejected = True
                    continue
                else:  # a step of at most the floor across: passed
                    passing = True
                    if observing:
                        observe_crossing(acc, t + fraction * h)
            if norm <= 1.0 or passing:  # accepted (a nan norm is not)
                beyond = _out_of_bounds(xn[:nx], bound) or not _finite(k7[:nx])
                # output samples inside (t, t_new), from the dense output, up to the first
                # beyond the bound (when the step ends beyond it)
                dense = False  # the step's dense-output polynomial, made at its first sample
                q0, q1, q2, q3 = work[_Q0], work[_Q1], work[_Q2], work[_Q3]
                while observing and last < n and (last + 1) * dt < t_new * (1.0 - 1e-14):
                    j = last + 1
                    wanted = observed(j, n, every)
                    if not (wanted or record or beyond):
                        last = j  # a sample the metrics do not observe: nothing to evaluate
                        continue
                    theta = ((j * dt) - t) / h
                    if not dense:
                        for i in range(nx):
                            q0[i] = (k1[i] * DENSE[0, 0] + k3[i] * DENSE[2, 0]
                                     + k4[i] * DENSE[3, 0] + k5[i] * DENSE[4, 0]
                                     + k6[i] * DENSE[5, 0] + k7[i] * DENSE[6, 0])
                            q1[i] = (k1[i] * DENSE[0, 1] + k3[i] * DENSE[2, 1]
                                     + k4[i] * DENSE[3, 1] + k5[i] * DENSE[4, 1]
                                     + k6[i] * DENSE[5, 1] + k7[i] * DENSE[6, 1])
                            q2[i] = (k1[i] * DENSE[0, 2] + k3[i] * DENSE[2, 2]
                                     + k4[i] * DENSE[3, 2] + k5[i] * DENSE[4, 2]
                                     + k6[i] * DENSE[5, 2] + k7[i] * DENSE[6, 2])
                            q3[i] = (k1[i] * DENSE[0, 3] + k3[i] * DENSE[2, 3]
                                     + k4[i] * DENSE[3, 3] + k5[i] * DENSE[4, 3]
                                     + k6[i] * DENSE[5, 3] + k7[i] * DENSE[6, 3])
                        dense = True
                    for i in range(nx):
                        xs[i] = x[i] + h * theta * (q0[i] + theta * (q1[i] + theta * (
                            q2[i] + theta * q3[i])))
                    if beyond and _out_of_bounds(xs[:nx], bound):
                        return last, _BOUND, j * dt, steps, evaluations
                    fs = work[_FS]
                    rhs(loop, xs, samples_ref[2 * j], noise, fs)
                    evaluations += 1
                    if beyond and not _finite(fs[:nx]):
                        return last, _BOUND, j * dt, steps, evaluations
                    if wanted:
                        observe(loop, obs, acc, j, xs, fs)
                    if record:
                        record_sample(loop, trace, j, nx, xs, fs)
                    last = j
                if beyond:
                    return last, _BOUND, t_new, steps, evaluations
                steps += 1
                t = t_new
                for i in range(x.shape[0]):  # (element by element: no runtime needed)
                    x[i] = xn[i]
                    k1[i] = k7[i]
                sigma = after
                if (stride > 0 and interval + stride < n
                        and t >= (interval + stride) * dt * (1.0 - 1e-14)):
                    # a new noise interval or a sample instant: the measured angles or the
                    # controller's held values jump, the rates with them
                    interval += stride
                    load_noise(interval, table, noise)
                    plan_flag(breaks, local, t, ref)
                    if sampling > 0 and interval % sampling == 0:
                        sample(loop, x, noise, ref, interval)
                    rhs(loop, x, ref, noise, k1)
                    evaluations += 1
                    if not _finite(k1[:nx]):
                        return last, _BOUND, t, steps, evaluations
                    sigma_new = k1[nx]
                    if _flipped(sigma, sigma_new):
                        if observing:
                            observe_crossing(acc, t)
                        if not bounded:
                            return last, _CROSSED, t, steps, evaluations
                    sigma = sigma_new
                # the output sample at the step's end, if there is one (exactly)
                if observing and last < n and (last + 1) * dt <= t * (1.0 + 1e-14):
                    last += 1
                    if observed(last, n, every):
                        observe(loop, obs, acc, last, x, k1)
                    if record:
                        record_sample(loop, trace, last, nx, x, k1)
                if (observing and last >= n) or t >= duration * (1.0 - 1e-14):
                    break
                if passing:  # on the far side the right-hand side is another: start afresh
                    stop = (interval + stride) * dt if stride > 0 else duration
                    h = initial_step(loop, nx, x, k1, ref, noise, rtol, atol, stop - t, y, k2,
                                     breaks, local, t)
                    evaluations += 1
                    rejected = False
                    continue
                grow = 10.0 if norm == 0.0 else min(10.0, 0.9 * norm ** -0.2)
                h = h * (min(1.0, grow) if rejected else grow)
                rejected = False
            else:
                shrink = 0.2 if not math.isfinite(norm) else max(0.2, 0.9 * norm ** -0.2)
                h = h * shrink
                rejected = True
            if h < floor:
                event = _STALLED if abs(sigma) < STALL_MARGIN else _STEP_FLOOR
                return last, event, t, steps, evaluations
        return n if observing else last, _NONE, math.nan, steps, evaluations

    return rk4_trial, adaptive_trial
