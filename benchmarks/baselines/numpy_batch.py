"""The closed loop vectorised over trials with numpy, classical RK4."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from benchmarks.baselines.loop import LoopInputs, loop_inputs
from benchmarks.baselines.problem import PAPER_TRACKING, Tracking
from benchmarks.baselines.timing import Throughput, throughput
from flatcli.core.loop.simulate import Trials
from flatcli.core.plan.planning import (
    Plan,
)

Array = NDArray[np.float64]

def _batch_rates(
    x: Sequence[Array],
    ref: Array,
    kc: Array,
    gains: Array,
    p: Array,
    mh0: Array,
    lim: float,
) -> tuple[Array, Array, Array, Array]:
    """Closed-loop rates over a batch: x (4,) of (B,), p (11, B) plant coefficients, mh0 (B,)."""
    x0, x1, x2, x3 = x
    ka0, ka1, kb0, kb1, kc0 = kc
    kp1, kp2, kv1, kv2 = gains
    c1 = np.cos(x1)
    s1 = np.sin(x1)
    inv_a = 1.0 / (ka0 + ka1 * c1)
    g = (kb0 + kb1 * c1) * inv_a
    inv_a2 = inv_a * inv_a
    h = (kc0 * ka1) * s1 * inv_a2
    dg = (g * ka1 - kb1) * s1 * inv_a
    dh = (kc0 * ka1) * (c1 + (2.0 * ka1) * s1 * s1 * inv_a) * inv_a2
    alpha = g - h * x2
    v1 = ref[4] + kv1 * (ref[2] - x3) + kp1 * (ref[0] - x1)
    v2 = ref[5] + kv2 * (ref[3] - alpha * x3) + kp2 * (ref[1] - x0 + kc0 * x2 * inv_a)
    u2 = (alpha * v1 + (dg - dh * x2) * x3 * x3 - v2) / (h * x3)
    w1 = np.clip(x3, -lim, lim)
    w2 = np.clip(u2, -lim, lim)
    c2 = np.cos(x2)
    c12 = np.cos(x1 + x2)
    A = p[0] + p[1] * c1 + p[2] * c2 + p[3] * c12
    B = p[4] + p[5] * c1 + p[6] * c2 + p[7] * c12
    C = p[8] + p[9] * c2 + p[10] * c12
    return (B * w1 + C * w2 + mh0) / A, w1, w2, v1


def numpy_batch_rk4(
    plan: Plan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    chunk: int = 16384,
    inputs: LoopInputs | None = None,
) -> Array:
    """Final states of N closed-loop trials by RK4 vectorised over trials with numpy.

    The same closed loop as ``compiled_closed_loop``; trials are taken ``chunk`` at a time
    so that the working arrays stay in cache, and the time loop runs in Python.

    Parameters
    ----------
    plan, trials, tracking : as ``compiled_closed_loop``
    chunk : trials per vectorised batch
    inputs : precomputed ``loop_inputs``

    Returns
    -------
    final : (N, 4) [rad, rad/s]
    """
    li = inputs if inputs is not None else loop_inputs(plan, tracking, trials)
    N = li.initial.shape[0]
    out = np.empty((N, 4))
    dt, half, sixth = li.dt, 0.5 * li.dt, li.dt / 6.0
    ref = li.reference
    with np.errstate(all="ignore"):
        for lo in range(0, N, chunk):
            hi = min(lo + chunk, N)
            p = np.ascontiguousarray(li.plant[lo:hi].T)
            mh0 = li.total_mass[lo:hi] * li.h0[lo:hi]
            x = [li.initial[lo:hi, j].copy() for j in range(4)]
            args = (li.controller, li.gains, p, mh0, li.rate_limit)
            for s in range(li.steps):
                k1 = _batch_rates(x, ref[2 * s], *args)
                k2 = _batch_rates([xj + half * kj for xj, kj in zip(x, k1, strict=True)],
                                  ref[2 * s + 1], *args)  # fmt: skip
                k3 = _batch_rates([xj + half * kj for xj, kj in zip(x, k2, strict=True)],
                                  ref[2 * s + 1], *args)  # fmt: skip
                k4 = _batch_rates([xj + dt * kj for xj, kj in zip(x, k3, strict=True)],
                                  ref[2 * s + 2], *args)  # fmt: skip
                x = [
                    xj + sixth * (a + 2.0 * b + 2.0 * c + d)
                    for xj, a, b, c, d in zip(x, k1, k2, k3, k4, strict=True)
                ]
            out[lo:hi] = np.column_stack(x)
    return out


def numpy_trials_per_second(
    plan: Plan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    repeat: int = 1,
    chunk: int = 16384,
) -> Throughput:
    """Throughput of ``numpy_batch_rk4`` in this process (one core)."""
    li = loop_inputs(plan, tracking, trials)
    return throughput(lambda: numpy_batch_rk4(plan, trials, tracking, chunk, li),
                      trials.count, 1, repeat, warmup=0)
