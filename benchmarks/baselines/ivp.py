"""The closed loop one trial at a time with scipy's solve_ivp (RK45)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from benchmarks.baselines.loop import loop_inputs
from benchmarks.baselines.problem import PAPER_TRACKING, Tracking
from flatcli.core.loop.simulate import Trials
from flatcli.core.plan.planning import (
    Plan,
)

Array = NDArray[np.float64]

@dataclass(frozen=True)
class IvpRun:
    """One-trial-at-a-time ``solve_ivp`` runs.

    Attributes
    ----------
    final : (N, 4) states at T [rad, rad/s]
    evaluations : (N,) right-hand-side evaluations per trial
    seconds : wall time of all N trials [s]
    """

    final: Array
    evaluations: NDArray[np.int64]
    seconds: float

    @property
    def trials_per_second(self) -> float:
        """Trials over the wall time [1/s]."""
        return float(self.final.shape[0] / self.seconds)


def solve_ivp_trials_per_second(
    plan: Plan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    method: str = "RK45",
    rtol: float = 1e-8,
    atol: float = 1e-10,
) -> IvpRun:
    """The closed loop of each trial by ``scipy.integrate.solve_ivp``, one trial at a time.

    The right-hand side is plain Python on floats (``math``): the reference is the plan's
    polynomial evaluated at the solver's t (Horner), the controller and the plant are the
    formulas of ``compiled_closed_loop``. Only the final state is kept.

    Parameters
    ----------
    plan, trials, tracking : as ``compiled_closed_loop`` (tracking.dt is not used)
    method, rtol, atol : solve_ivp's (the issue's reference: RK45, rtol 1e-8)

    Returns
    -------
    IvpRun
    """
    li = loop_inputs(plan, tracking, trials)
    T = li.duration
    poly = [[list(li.poly[o, i][::-1]) for i in range(2)] for o in range(3)]  # Horner order
    ka0, ka1, kb0, kb1, kc0 = (float(v) for v in li.controller)
    kp1, kp2, kv1, kv2 = (float(v) for v in li.gains)
    lim = li.rate_limit
    cos, sin = math.cos, math.sin

    def horner(c: list[float], s: float) -> float:
        acc = 0.0
        for ci in c:
            acc = acc * s + ci
        return acc

    N = li.initial.shape[0]
    final = np.empty((N, 4))
    nfev = np.zeros(N, dtype=np.int64)
    start = time.perf_counter()
    for i in range(N):
        p = [float(v) for v in li.plant[i]]
        mh0 = float(li.total_mass[i] * li.h0[i])

        def rhs(t: float, x: Array, p: list[float] = p, mh0: float = mh0) -> list[float]:
            s = t / T
            y1, y2 = horner(poly[0][0], s), horner(poly[0][1], s)
            d1, d2 = horner(poly[1][0], s), horner(poly[1][1], s)
            dd1, dd2 = horner(poly[2][0], s), horner(poly[2][1], s)
            x0, x1, x2, x3 = x
            c1, s1 = cos(x1), sin(x1)
            inv_a = 1.0 / (ka0 + ka1 * c1)
            g = (kb0 + kb1 * c1) * inv_a
            h = kc0 * ka1 * s1 * inv_a * inv_a
            dg = (g * ka1 - kb1) * s1 * inv_a
            dh = kc0 * ka1 * (c1 + 2.0 * ka1 * s1 * s1 * inv_a) * inv_a * inv_a
            alpha = g - h * x2
            v1 = dd1 + kv1 * (d1 - x3) + kp1 * (y1 - x1)
            v2 = dd2 + kv2 * (d2 - alpha * x3) + kp2 * (y2 - x0 + kc0 * x2 * inv_a)
            u2 = (alpha * v1 + (dg - dh * x2) * x3 * x3 - v2) / (h * x3)
            w1 = min(max(x3, -lim), lim)
            w2 = min(max(u2, -lim), lim)
            c2, c12 = cos(x2), cos(x1 + x2)
            A = p[0] + p[1] * c1 + p[2] * c2 + p[3] * c12
            B = p[4] + p[5] * c1 + p[6] * c2 + p[7] * c12
            C = p[8] + p[9] * c2 + p[10] * c12
            return [(B * w1 + C * w2 + mh0) / A, w1, w2, v1]

        sol = solve_ivp(rhs, (0.0, T), li.initial[i], method=method, rtol=rtol, atol=atol)
        final[i] = sol.y[:, -1]
        nfev[i] = sol.nfev
    return IvpRun(final, nfev, time.perf_counter() - start)
