"""The closed loop as a hand-written numba kernel (``prange`` over trials), classical RK4."""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from benchmarks.baselines.loop import LoopInputs, loop_inputs
from benchmarks.baselines.problem import PAPER_TRACKING, Tracking
from benchmarks.baselines.timing import Throughput, throughput
from flatcli.core.loop.simulate import Trials
from flatcli.core.plan.planning import (
    Plan,
)

Array = NDArray[np.float64]

@njit(inline="always")
def _loop_rates(
    x0: float,
    x1: float,
    x2: float,
    x3: float,
    ref: Array,
    k: tuple[float, float, float, float, float],
    gains: tuple[float, float, float, float],
    p: tuple[float, ...],
    mh0: float,
    lim: float,
) -> tuple[float, float, float, float]:
    """Closed-loop rates of (th0, th1, th2, u1) at one state.

    k = (a0, a1, b0, b1, c0) of the controller, gains = (kp1, kp2, kv1, kv2), p the plant's
    11 coefficients, mh0 = M H0, lim the joint-rate limit.
    """
    ka0, ka1, kb0, kb1, kc0 = k
    kp1, kp2, kv1, kv2 = gains
    c1 = math.cos(x1)
    s1 = math.sin(x1)
    # controller, nominal d2 = 0 model: A = a0 + a1 c1, g = B/A, h = c0 a1 s1 / A^2
    inv_a = 1.0 / (ka0 + ka1 * c1)
    g = (kb0 + kb1 * c1) * inv_a
    h = kc0 * ka1 * s1 * inv_a * inv_a
    dg = (g * ka1 - kb1) * s1 * inv_a
    dh = kc0 * ka1 * (c1 + 2.0 * ka1 * s1 * s1 * inv_a) * inv_a * inv_a
    alpha = g - h * x2
    y2 = x0 - kc0 * x2 * inv_a
    v1 = ref[4] + kv1 * (ref[2] - x3) + kp1 * (ref[0] - x1)
    v2 = ref[5] + kv2 * (ref[3] - alpha * x3) + kp2 * (ref[1] - y2)
    u2 = (alpha * v1 + (dg - dh * x2) * x3 * x3 - v2) / (h * x3)
    # plant: saturated joint rates, th0' from its general reduced constraint
    w1 = min(max(x3, -lim), lim)
    w2 = min(max(u2, -lim), lim)
    c2 = math.cos(x2)
    c12 = math.cos(x1 + x2)
    A = p[0] + p[1] * c1 + p[2] * c2 + p[3] * c12
    B = p[4] + p[5] * c1 + p[6] * c2 + p[7] * c12
    C = p[8] + p[9] * c2 + p[10] * c12
    return (B * w1 + C * w2 + mh0) / A, w1, w2, v1


@njit(parallel=True, cache=True, error_model="numpy")
def _rk4_kernel(
    reference: Array,
    controller: Array,
    gains: Array,
    plant: Array,
    total_mass: Array,
    h0: Array,
    initial: Array,
    dt: float,
    lim: float,
    out: Array,
) -> None:
    """RK4 of every trial over the grid (IEEE arithmetic); final states go to out (N, 4)."""
    n = (reference.shape[0] - 1) // 2
    k = (controller[0], controller[1], controller[2], controller[3], controller[4])
    gn = (gains[0], gains[1], gains[2], gains[3])
    half = 0.5 * dt
    sixth = dt / 6.0
    for i in prange(initial.shape[0]):
        q = plant[i]
        p = (q[0], q[1], q[2], q[3], q[4], q[5], q[6], q[7], q[8], q[9], q[10])
        mh0 = total_mass[i] * h0[i]
        x0, x1, x2, x3 = initial[i, 0], initial[i, 1], initial[i, 2], initial[i, 3]
        for s in range(n):
            ra, rb, rc = reference[2 * s], reference[2 * s + 1], reference[2 * s + 2]
            # fmt: off
            a0, a1, a2, a3 = _loop_rates(x0, x1, x2, x3, ra, k, gn, p, mh0, lim)
            b0, b1, b2, b3 = _loop_rates(x0 + half * a0, x1 + half * a1, x2 + half * a2,
                                         x3 + half * a3, rb, k, gn, p, mh0, lim)
            c0, c1, c2, c3 = _loop_rates(x0 + half * b0, x1 + half * b1, x2 + half * b2,
                                         x3 + half * b3, rb, k, gn, p, mh0, lim)
            d0, d1, d2, d3 = _loop_rates(x0 + dt * c0, x1 + dt * c1, x2 + dt * c2,
                                         x3 + dt * c3, rc, k, gn, p, mh0, lim)
            # fmt: on
            x0 = x0 + sixth * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
            x1 = x1 + sixth * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
            x2 = x2 + sixth * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
            x3 = x3 + sixth * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x0, x1, x2, x3


def compiled_closed_loop(
    plan: Plan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    threads: int | None = None,
    inputs: LoopInputs | None = None,
) -> Array:
    """Final states of N closed-loop trials by a hand-written numba RK4 kernel.

    Controller: the linearising feedback of the nominal (d2 = 0) model of ``plan``, gains of
    ``tracking``; plant of each trial: th1' = sat(u1), th2' = sat(u2), th0' = (B th1' +
    C th2' + M H0) / A with its own general coefficients; reference from the plan's
    polynomial coefficients at the RK4 stage times. No noise, no metrics, no traces.

    Parameters
    ----------
    plan : Plan in a PolynomialBasis (the cubic by default)
    trials : Trials (N); their noise, if any, is ignored
    tracking : Tracking (gains, dt, rate limit; its initial state is not used: trials')
    threads : numba threads for this call (default: numba's current setting)
    inputs : precomputed ``loop_inputs`` (to keep unpacking out of a timing)

    Returns
    -------
    final : (N, 4) th0, th1, th2 [rad], u1 [rad/s] at t = T
    """
    li = inputs if inputs is not None else loop_inputs(plan, tracking, trials)
    out = np.empty((li.initial.shape[0], 4))
    previous = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(threads)
    try:
        # fmt: off
        _rk4_kernel(li.reference, li.controller, li.gains, li.plant, li.total_mass, li.h0,
                    li.initial, li.dt, li.rate_limit, out)
        # fmt: on
    finally:
        numba.set_num_threads(previous)
    return out


def compiled_trials_per_second(
    plan: Plan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    threads: int = 2,
    repeat: int = 3,
) -> Throughput:
    """Throughput of ``compiled_closed_loop`` after a warm-up (compilation, thread pool)."""
    li = loop_inputs(plan, tracking, trials)
    return throughput(lambda: compiled_closed_loop(plan, trials, tracking, threads, li),
                      trials.count, threads, repeat)
