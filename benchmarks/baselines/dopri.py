"""The closed loop and its metrics as a hand-written numba kernel doing flatcli's work: the
adaptive Dormand-Prince 5(4) integrator with dense output, the metrics at every output
sample, ``prange`` over trials.

The same work as ``flatcli.core.loop.simulate`` with ``track.error_estimate = "none"`` (one
solution per trial): the same tolerances, step-size controller and first step, so the same
steps and right-hand sides per trial (``same_work_check`` counts them), and at every output
sample t_j = j dt the state from the dense output, the closed loop's rates there, and the
metrics flatcli reports: the angle and flat-output errors (rms, max, final), the singular
hits and the least margin, H from the full link kinematics against H0, the peak joint rate,
and per trial the plan's momentum residual on the plant. What is left out is what flatcli
does besides (its statuses' reasons, tables, files; crossings of the singular set, which no
benchmark trial meets, are only detected here, as flatcli detects them).

Nothing here calls flatcli's closed loop: the controller, the plant, the momentum and the
integrator are written out again, as scalars, from their equations (docs/physics.md; the
Dormand-Prince tableau, error weights and dense output of Dormand & Prince 1980 as scipy's
``RK45`` writes them; the first step of Hairer, Norsett & Wanner, II.4), so that agreeing
with flatcli to rounding (``tests/test_baselines.py``) checks both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from benchmarks.baselines.loop import LoopInputs, loop_inputs
from benchmarks.baselines.problem import PAPER_TRACKING, Tracking
from benchmarks.baselines.timing import Throughput, throughput
from flatcli.core.loop.simulate import Trials
from flatcli.core.names import DEFAULT_ATOL, DEFAULT_RTOL
from flatcli.core.plan.planning import Plan

Array = NDArray[np.float64]

#: The metrics the kernel writes per trial, in its output's columns (flatcli's names).
METRICS = ("err_theta_rms", "err_theta_max", "err_theta_final", "err_y_rms", "err_y_max",
           "err_y_final", "singular_hits", "first_hit_time", "min_margin", "momentum_drift",
           "plan_momentum_residual", "peak_rate", "steps", "rhs_evaluations", "crossed")

# Dormand-Prince 5(4) (scipy.integrate._ivp.rk.RK45: C, A, B, E, P)
C2, C3, C4, C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9
A21 = 1 / 5
A31, A32 = 3 / 40, 9 / 40
A41, A42, A43 = 44 / 45, -56 / 15, 32 / 9
A51, A52, A53, A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
A61, A62, A63, A64, A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
B1, B3, B4, B5, B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
E1, E3, E4, E5, E6, E7 = -71 / 57600, 71 / 16695, -71 / 1920, 17253 / 339200, -22 / 525, 1 / 40
P = np.array([
    [1, -8048581381 / 2820520608, 8663915743 / 2820520608, -12715105075 / 11282082432],
    [0, 0, 0, 0],
    [0, 131558114200 / 32700410799, -68118460800 / 10900136933, 87487479700 / 32700410799],
    [0, -1754552775 / 470086768, 14199869525 / 1410260304, -10690763975 / 1880347072],
    [0, 127303824393 / 49829197408, -318862633887 / 49829197408,
     701980252875 / 199316789632],
    [0, -282668133 / 205662961, 2019193451 / 616988883, -1453857185 / 822651844],
    [0, 40617522 / 29380423, -110615467 / 29380423, 69997945 / 29380423],
])  # fmt: skip


@njit(inline="always")
def _plan(poly: Array, s: float) -> tuple[float, float, float, float, float, float]:
    """y1, y2, y1', y2', y1'', y2'' of the plan at s = t / T (Horner on ``poly``)."""
    out = [0.0] * 6
    for order in range(3):
        for i in range(2):
            v = 0.0
            for c in range(poly.shape[2] - 1, -1, -1):
                v = v * s + poly[order, i, c]
            out[2 * order + i] = v
    return out[0], out[1], out[2], out[3], out[4], out[5]


@njit(inline="always")
def _rates(x0: float, x1: float, x2: float, x3: float, ref: tuple[float, ...],
           k: Array, gains: Array, p: Array, mh0: float, lim: float
           ) -> tuple[float, float, float, float, float, float, float, float]:
    """The closed loop at one state: th0', th1', th2', u1' and the margin sin th1 u1 [rad/s],
    cos th1, sin th1, cos(th1 + th2) (k: the controller's a0, a1, b0, b1, c0; p: the plant's
    11 coefficients; mh0 = M H0)."""
    c1 = math.cos(x1)
    s1 = math.sin(x1)
    inv_a = 1.0 / (k[0] + k[1] * c1)
    g = (k[2] + k[3] * c1) * inv_a
    h = k[4] * k[1] * s1 * inv_a * inv_a
    dg = (g * k[1] - k[3]) * s1 * inv_a
    dh = k[4] * k[1] * (c1 + 2.0 * k[1] * s1 * s1 * inv_a) * inv_a * inv_a
    y2 = x0 - k[4] * x2 * inv_a
    y2_dot = (g - h * x2) * x3
    v1 = ref[4] + gains[2] * (ref[2] - x3) + gains[0] * (ref[0] - x1)
    v2 = ref[5] + gains[3] * (ref[3] - y2_dot) + gains[1] * (ref[1] - y2)
    u2 = ((g - h * x2) * v1 + (dg - dh * x2) * x3 * x3 - v2) / (h * x3)
    w1 = min(max(x3, -lim), lim)
    w2 = min(max(u2, -lim), lim)
    c2 = math.cos(x2)
    c12 = math.cos(x1 + x2)
    a = p[0] + p[1] * c1 + p[2] * c2 + p[3] * c12
    b = p[4] + p[5] * c1 + p[6] * c2 + p[7] * c12
    c = p[8] + p[9] * c2 + p[10] * c12
    if (x3 >= lim and v1 > 0.0) or (x3 <= -lim and v1 < 0.0):
        v1 = 0.0  # no wind-up while th1' is clipped
    return (b * w1 + c * w2 + mh0) / a, w1, w2, v1, s1 * x3, c1, s1, c12


@njit(inline="always")
def _momentum(q: Array, c1: float, s1: float, c12: float, s12: float, w0: float, w1: float,
              w2: float) -> float:
    """H about the system's centre of mass from the three links' positions and velocities
    (q: m0, m1, m2, I0, I1, I2, l0, l1, l2, d0, d1, d2; w: th0', th1', th2')."""
    m0, m1, m2, i0, i1, i2, l0, l1, d0, d1, d2 = (q[0], q[1], q[2], q[3], q[4], q[5], q[6],
                                                  q[7], q[9], q[10], q[11])
    o1 = w0 + w1
    o2 = o1 + w2
    px0, py0, vx0, vy0 = d0, 0.0, 0.0, w0 * d0
    px1, py1 = l0 + d1 * c1, d1 * s1
    vx1, vy1 = -o1 * d1 * s1, w0 * l0 + o1 * d1 * c1
    px2, py2 = l0 + l1 * c1 + d2 * c12, l1 * s1 + d2 * s12
    vx2 = -o1 * l1 * s1 - o2 * d2 * s12
    vy2 = w0 * l0 + o1 * l1 * c1 + o2 * d2 * c12
    mass = m0 + m1 + m2
    own = i0 * w0 + i1 * o1 + i2 * o2 + m0 * (px0 * vy0 - py0 * vx0) \
        + m1 * (px1 * vy1 - py1 * vx1) + m2 * (px2 * vy2 - py2 * vx2)
    mx = m0 * px0 + m1 * px1 + m2 * px2
    my = m0 * py0 + m1 * py1 + m2 * py2
    mvx = m0 * vx0 + m1 * vx1 + m2 * vx2
    mvy = m0 * vy0 + m1 * vy1 + m2 * vy2
    return float(own - (mx * mvy - my * mvx) / mass)


@njit(parallel=True, cache=True, error_model="numpy")
def _dopri_kernel(poly: Array, duration: float, theta_ref: Array, y_ref: Array,
                  plan_theta: Array, plan_theta_dot: Array, controller: Array, gains: Array,
                  plant: Array, links: Array, total_mass: Array, h0: Array, initial: Array,
                  dt: float, n: int, lim: float, rtol: float, atol: float, threshold: float,
                  every: int, out: Array) -> None:
    """Every trial integrated alone (module docstring); its metrics into out[i], over the
    output samples 0, every, 2 every, ... and n (``every`` = 1: all of them)."""
    for i in prange(initial.shape[0]):
        p = plant[i]
        q = links[i]
        mh0 = total_mass[i] * h0[i]
        x0, x1, x2, x3 = initial[i, 0], initial[i, 1], initial[i, 2], initial[i, 3]
        # metrics
        sum_et2 = max_et2 = sum_ey2 = max_ey2 = last_et2 = last_ey2 = 0.0
        hits = 0
        first_hit = -1
        min_margin = math.inf
        drift = 0.0
        peak = 0.0
        count = 0
        ref = _plan(poly, 0.0)
        f0, f1, f2, f3, sig, c1, s1, c12 = _rates(x0, x1, x2, x3, ref, controller, gains, p,
                                                  mh0, lim)
        evaluations = 1
        # sample 0
        d0, d1, d2 = x0 - theta_ref[0, 0], x1 - theta_ref[0, 1], x2 - theta_ref[0, 2]
        et2 = d0 * d0 + d1 * d1 + d2 * d2
        e2 = x0 - controller[4] * x2 / (controller[0] + controller[1] * c1) - y_ref[0, 1]
        ey2 = (x1 - y_ref[0, 0]) ** 2 + e2 * e2
        sum_et2 += et2
        sum_ey2 += ey2
        max_et2 = max(max_et2, et2)
        max_ey2 = max(max_ey2, ey2)
        last_et2, last_ey2 = et2, ey2
        margin = abs(sig)
        if margin < threshold:
            hits += 1
            if first_hit < 0:
                first_hit = 0
        min_margin = min(min_margin, margin)
        hm = _momentum(q, c1, s1, c12, math.sin(x1 + x2), f0, f1, f2)
        drift = max(drift, abs(hm - h0[i]))
        peak = max(peak, abs(f1), abs(f2))
        count += 1
        # first step (Hairer, Norsett & Wanner, II.4)
        sc0 = atol + rtol * abs(x0)
        sc1 = atol + rtol * abs(x1)
        sc2 = atol + rtol * abs(x2)
        sc3 = atol + rtol * abs(x3)
        dd0 = math.sqrt(((x0 / sc0) ** 2 + (x1 / sc1) ** 2 + (x2 / sc2) ** 2 + (x3 / sc3) ** 2)
                        / 4.0)
        dd1 = math.sqrt(((f0 / sc0) ** 2 + (f1 / sc1) ** 2 + (f2 / sc2) ** 2 + (f3 / sc3) ** 2)
                        / 4.0)
        hh = 1e-6 if dd0 < 1e-5 or dd1 < 1e-5 else 0.01 * dd0 / dd1
        hh = min(hh, duration)
        ref = _plan(poly, hh / duration)
        g0, g1, g2, g3, _, _, _, _ = _rates(x0 + hh * f0, x1 + hh * f1, x2 + hh * f2,
                                            x3 + hh * f3, ref, controller, gains, p, mh0, lim)
        evaluations += 1
        dd2 = math.sqrt((((g0 - f0) / sc0) ** 2 + ((g1 - f1) / sc1) ** 2
                         + ((g2 - f2) / sc2) ** 2 + ((g3 - f3) / sc3) ** 2) / 4.0) / hh
        if dd1 <= 1e-15 and dd2 <= 1e-15:
            h1 = max(1e-6, hh * 1e-3)
        else:
            h1 = (0.01 / max(dd1, dd2)) ** 0.2
        h = min(100.0 * hh, h1, duration)
        t = 0.0
        last = 0
        steps = 0
        rejected = False
        crossed = 0.0
        while t < duration:
            if h >= duration - t or duration - t - h < 1e-10 * (duration - t):
                h = duration - t
                t_new = duration
            else:
                t_new = t + h
            k10, k11, k12, k13 = f0, f1, f2, f3
            ref = _plan(poly, (t + C2 * h) / duration)
            k20, k21, k22, k23, m2, _, _, _ = _rates(
                x0 + h * A21 * k10, x1 + h * A21 * k11, x2 + h * A21 * k12, x3 + h * A21 * k13,
                ref, controller, gains, p, mh0, lim)
            ref = _plan(poly, (t + C3 * h) / duration)
            k30, k31, k32, k33, m3, _, _, _ = _rates(
                x0 + h * (A31 * k10 + A32 * k20), x1 + h * (A31 * k11 + A32 * k21),
                x2 + h * (A31 * k12 + A32 * k22), x3 + h * (A31 * k13 + A32 * k23),
                ref, controller, gains, p, mh0, lim)
            ref = _plan(poly, (t + C4 * h) / duration)
            k40, k41, k42, k43, m4, _, _, _ = _rates(
                x0 + h * (A41 * k10 + A42 * k20 + A43 * k30),
                x1 + h * (A41 * k11 + A42 * k21 + A43 * k31),
                x2 + h * (A41 * k12 + A42 * k22 + A43 * k32),
                x3 + h * (A41 * k13 + A42 * k23 + A43 * k33), ref, controller, gains, p, mh0,
                lim)
            ref = _plan(poly, (t + C5 * h) / duration)
            k50, k51, k52, k53, m5, _, _, _ = _rates(
                x0 + h * (A51 * k10 + A52 * k20 + A53 * k30 + A54 * k40),
                x1 + h * (A51 * k11 + A52 * k21 + A53 * k31 + A54 * k41),
                x2 + h * (A51 * k12 + A52 * k22 + A53 * k32 + A54 * k42),
                x3 + h * (A51 * k13 + A52 * k23 + A53 * k33 + A54 * k43), ref, controller,
                gains, p, mh0, lim)
            ref = _plan(poly, t_new / duration)
            k60, k61, k62, k63, m6, _, _, _ = _rates(
                x0 + h * (A61 * k10 + A62 * k20 + A63 * k30 + A64 * k40 + A65 * k50),
                x1 + h * (A61 * k11 + A62 * k21 + A63 * k31 + A64 * k41 + A65 * k51),
                x2 + h * (A61 * k12 + A62 * k22 + A63 * k32 + A64 * k42 + A65 * k52),
                x3 + h * (A61 * k13 + A62 * k23 + A63 * k33 + A64 * k43 + A65 * k53), ref,
                controller, gains, p, mh0, lim)
            n0 = x0 + h * (B1 * k10 + B3 * k30 + B4 * k40 + B5 * k50 + B6 * k60)
            n1 = x1 + h * (B1 * k11 + B3 * k31 + B4 * k41 + B5 * k51 + B6 * k61)
            n2 = x2 + h * (B1 * k12 + B3 * k32 + B4 * k42 + B5 * k52 + B6 * k62)
            n3 = x3 + h * (B1 * k13 + B3 * k33 + B4 * k43 + B5 * k53 + B6 * k63)
            k70, k71, k72, k73, m7, e_c1, e_s1, e_c12 = _rates(n0, n1, n2, n3, ref, controller,
                                                                gains, p, mh0, lim)
            evaluations += 6
            r0 = h * (E1 * k10 + E3 * k30 + E4 * k40 + E5 * k50 + E6 * k60 + E7 * k70)
            r1 = h * (E1 * k11 + E3 * k31 + E4 * k41 + E5 * k51 + E6 * k61 + E7 * k71)
            r2 = h * (E1 * k12 + E3 * k32 + E4 * k42 + E5 * k52 + E6 * k62 + E7 * k72)
            r3 = h * (E1 * k13 + E3 * k33 + E4 * k43 + E5 * k53 + E6 * k63 + E7 * k73)
            norm = math.sqrt(((r0 / (atol + rtol * max(abs(x0), abs(n0)))) ** 2
                              + (r1 / (atol + rtol * max(abs(x1), abs(n1)))) ** 2
                              + (r2 / (atol + rtol * max(abs(x2), abs(n2)))) ** 2
                              + (r3 / (atol + rtol * max(abs(x3), abs(n3)))) ** 2) / 4.0)
            if norm <= 1.0:
                if ((sig > 0.0) != (m2 > 0.0) or (sig > 0.0) != (m3 > 0.0)
                        or (sig > 0.0) != (m4 > 0.0) or (sig > 0.0) != (m5 > 0.0)
                        or (sig > 0.0) != (m6 > 0.0) or (sig > 0.0) != (m7 > 0.0)):
                    crossed = 1.0  # the margin changed sign: flatcli stops such a trial
                    break
                dense = False
                q00 = q01 = q02 = q03 = q10 = q11 = q12 = q13 = 0.0
                q20 = q21 = q22 = q23 = q30 = q31 = q32 = q33 = 0.0
                while last < n and (last + 1) * dt < t_new * (1.0 - 1e-14):
                    j = last + 1
                    if every > 1 and j % every != 0 and j != n:
                        last = j  # not observed: nothing to evaluate
                        continue
                    th = (j * dt - t) / h
                    if not dense:
                        q00 = (k10 * P[0, 0] + k30 * P[2, 0] + k40 * P[3, 0] + k50 * P[4, 0]
                               + k60 * P[5, 0] + k70 * P[6, 0])
                        q01 = (k10 * P[0, 1] + k30 * P[2, 1] + k40 * P[3, 1] + k50 * P[4, 1]
                               + k60 * P[5, 1] + k70 * P[6, 1])
                        q02 = (k10 * P[0, 2] + k30 * P[2, 2] + k40 * P[3, 2] + k50 * P[4, 2]
                               + k60 * P[5, 2] + k70 * P[6, 2])
                        q03 = (k10 * P[0, 3] + k30 * P[2, 3] + k40 * P[3, 3] + k50 * P[4, 3]
                               + k60 * P[5, 3] + k70 * P[6, 3])
                        q10 = (k11 * P[0, 0] + k31 * P[2, 0] + k41 * P[3, 0] + k51 * P[4, 0]
                               + k61 * P[5, 0] + k71 * P[6, 0])
                        q11 = (k11 * P[0, 1] + k31 * P[2, 1] + k41 * P[3, 1] + k51 * P[4, 1]
                               + k61 * P[5, 1] + k71 * P[6, 1])
                        q12 = (k11 * P[0, 2] + k31 * P[2, 2] + k41 * P[3, 2] + k51 * P[4, 2]
                               + k61 * P[5, 2] + k71 * P[6, 2])
                        q13 = (k11 * P[0, 3] + k31 * P[2, 3] + k41 * P[3, 3] + k51 * P[4, 3]
                               + k61 * P[5, 3] + k71 * P[6, 3])
                        q20 = (k12 * P[0, 0] + k32 * P[2, 0] + k42 * P[3, 0] + k52 * P[4, 0]
                               + k62 * P[5, 0] + k72 * P[6, 0])
                        q21 = (k12 * P[0, 1] + k32 * P[2, 1] + k42 * P[3, 1] + k52 * P[4, 1]
                               + k62 * P[5, 1] + k72 * P[6, 1])
                        q22 = (k12 * P[0, 2] + k32 * P[2, 2] + k42 * P[3, 2] + k52 * P[4, 2]
                               + k62 * P[5, 2] + k72 * P[6, 2])
                        q23 = (k12 * P[0, 3] + k32 * P[2, 3] + k42 * P[3, 3] + k52 * P[4, 3]
                               + k62 * P[5, 3] + k72 * P[6, 3])
                        q30 = (k13 * P[0, 0] + k33 * P[2, 0] + k43 * P[3, 0] + k53 * P[4, 0]
                               + k63 * P[5, 0] + k73 * P[6, 0])
                        q31 = (k13 * P[0, 1] + k33 * P[2, 1] + k43 * P[3, 1] + k53 * P[4, 1]
                               + k63 * P[5, 1] + k73 * P[6, 1])
                        q32 = (k13 * P[0, 2] + k33 * P[2, 2] + k43 * P[3, 2] + k53 * P[4, 2]
                               + k63 * P[5, 2] + k73 * P[6, 2])
                        q33 = (k13 * P[0, 3] + k33 * P[2, 3] + k43 * P[3, 3] + k53 * P[4, 3]
                               + k63 * P[5, 3] + k73 * P[6, 3])
                        dense = True
                    s0 = x0 + h * th * (q00 + th * (q01 + th * (q02 + th * q03)))
                    s1_ = x1 + h * th * (q10 + th * (q11 + th * (q12 + th * q13)))
                    s2_ = x2 + h * th * (q20 + th * (q21 + th * (q22 + th * q23)))
                    s3 = x3 + h * th * (q30 + th * (q31 + th * (q32 + th * q33)))
                    ref = (y_ref[j, 0], y_ref[j, 1], y_ref[j, 2], y_ref[j, 3], y_ref[j, 4],
                           y_ref[j, 5])
                    a0, a1, a2, _, sm, sc1_, ss1, sc12 = _rates(s0, s1_, s2_, s3, ref,
                                                                controller, gains, p, mh0, lim)
                    evaluations += 1
                    d0, d1, d2 = (s0 - theta_ref[j, 0], s1_ - theta_ref[j, 1],
                                  s2_ - theta_ref[j, 2])
                    et2 = d0 * d0 + d1 * d1 + d2 * d2
                    e2 = s0 - controller[4] * s2_ / (controller[0] + controller[1] * sc1_) \
                        - y_ref[j, 1]
                    ey2 = (s1_ - y_ref[j, 0]) ** 2 + e2 * e2
                    sum_et2 += et2
                    sum_ey2 += ey2
                    max_et2 = max(max_et2, et2)
                    max_ey2 = max(max_ey2, ey2)
                    last_et2, last_ey2 = et2, ey2
                    margin = abs(sm)
                    if margin < threshold:
                        hits += 1
                        if first_hit < 0:
                            first_hit = j
                    min_margin = min(min_margin, margin)
                    hm = _momentum(q, sc1_, ss1, sc12, math.sin(s1_ + s2_), a0, a1, a2)
                    drift = max(drift, abs(hm - h0[i]))
                    peak = max(peak, abs(a1), abs(a2))
                    count += 1
                    last = j
                steps += 1
                t = t_new
                x0, x1, x2, x3 = n0, n1, n2, n3
                f0, f1, f2, f3, sig = k70, k71, k72, k73, m7
                if last < n and (last + 1) * dt <= t * (1.0 + 1e-14):
                    last += 1  # a sample at the step's end
                    if every == 1 or last % every == 0 or last == n:
                        d0, d1, d2 = (x0 - theta_ref[last, 0], x1 - theta_ref[last, 1],
                                      x2 - theta_ref[last, 2])
                        et2 = d0 * d0 + d1 * d1 + d2 * d2
                        e2 = x0 - controller[4] * x2 / (controller[0] + controller[1] * e_c1) \
                            - y_ref[last, 1]
                        ey2 = (x1 - y_ref[last, 0]) ** 2 + e2 * e2
                        sum_et2 += et2
                        sum_ey2 += ey2
                        max_et2 = max(max_et2, et2)
                        max_ey2 = max(max_ey2, ey2)
                        last_et2, last_ey2 = et2, ey2
                        margin = abs(sig)
                        if margin < threshold:
                            hits += 1
                            if first_hit < 0:
                                first_hit = last
                        min_margin = min(min_margin, margin)
                        hm = _momentum(q, e_c1, e_s1, e_c12, math.sin(x1 + x2), f0, f1, f2)
                        drift = max(drift, abs(hm - h0[i]))
                        peak = max(peak, abs(f1), abs(f2))
                        count += 1
                if last >= n:
                    break
                grow = 10.0 if norm == 0.0 else min(10.0, 0.9 * norm ** -0.2)
                h = h * (min(1.0, grow) if rejected else grow)
                rejected = False
            else:
                h = h * (0.2 if not math.isfinite(norm) else max(0.2, 0.9 * norm ** -0.2))
                rejected = True
        residual = 0.0
        for r in range(plan_theta.shape[0]):
            a, b = plan_theta[r, 1], plan_theta[r, 1] + plan_theta[r, 2]
            hp = _momentum(q, math.cos(a), math.sin(a), math.cos(b), math.sin(b),
                           plan_theta_dot[r, 0], plan_theta_dot[r, 1], plan_theta_dot[r, 2])
            residual = max(residual, abs(hp - h0[i]))
        out[i, 0] = math.sqrt(sum_et2 / count)
        out[i, 1] = math.sqrt(max_et2)
        out[i, 2] = math.sqrt(last_et2) if last >= n else math.nan
        out[i, 3] = math.sqrt(sum_ey2 / count)
        out[i, 4] = math.sqrt(max_ey2)
        out[i, 5] = math.sqrt(last_ey2) if last >= n else math.nan
        out[i, 6] = hits
        out[i, 7] = first_hit * dt if first_hit >= 0 else math.nan
        out[i, 8] = min_margin
        out[i, 9] = drift
        out[i, 10] = residual
        out[i, 11] = peak
        out[i, 12] = steps
        out[i, 13] = evaluations
        out[i, 14] = crossed


@dataclass(frozen=True)
class DopriInputs:
    """``LoopInputs`` and what the metrics need besides: the plan's angles theta_ref and
    flat outputs y_ref (y, y', y'') at the output samples, its angles and rates on its own
    grid (for the momentum residual), the plants' link parameters, the tolerances."""

    loop: LoopInputs
    theta_ref: Array
    y_ref: Array
    plan_theta: Array
    plan_theta_dot: Array
    links: Array
    rtol: float
    atol: float
    threshold: float


def dopri_inputs(plan: Plan, trials: Trials, tracking: Tracking = PAPER_TRACKING,
                 plan_samples: int = 201, rtol: float = DEFAULT_RTOL,
                 atol: float = DEFAULT_ATOL, threshold: float = 1e-2) -> DopriInputs:
    """The kernel's inputs. theta_ref comes from the plan's flat outputs by the inverse map
    (eqs. 36-37, written out here: th1 = y1, th2 = (g - y2' / y1') / h, th0 = y2 + c0 th2 /
    A); the momentum residual's grid from ``plan.sample`` (the plan's own samples, as
    flatcli takes it)."""
    li = loop_inputs(plan, tracking, trials)
    y_ref = np.ascontiguousarray(li.reference[::2])  # the output samples t_j = j dt
    a0, a1, b0, b1, c0 = li.controller
    y1, y2, y1_dot, y2_dot = y_ref[:, 0], y_ref[:, 1], y_ref[:, 2], y_ref[:, 3]
    c1, s1 = np.cos(y1), np.sin(y1)
    big_a = a0 + a1 * c1
    g = (b0 + b1 * c1) / big_a
    h = c0 * a1 * s1 / big_a**2
    th2 = (g - y2_dot / y1_dot) / h
    theta_ref = np.column_stack([y2 + c0 * th2 / big_a, y1, th2])
    own = plan.sample(plan.grid(plan_samples))
    return DopriInputs(li, np.ascontiguousarray(theta_ref), y_ref,
                       np.ascontiguousarray(own.theta), np.ascontiguousarray(own.theta_dot),
                       np.ascontiguousarray(trials.links, dtype=float), rtol, atol, threshold)


def dopri_metrics(plan: Plan, trials: Trials, tracking: Tracking = PAPER_TRACKING,
                  threads: int | None = None, inputs: DopriInputs | None = None,
                  every: int = 1) -> Array:
    """(N, len(METRICS)) the metrics of N closed-loop trials by the same-work kernel
    (columns ``METRICS``; ``crossed`` 1.0 where a trial met the singular set and stopped),
    over every ``every``-th output sample and the last (flatcli's ``track.observe_every``)."""
    di = inputs if inputs is not None else dopri_inputs(plan, trials, tracking)
    li = di.loop
    out = np.empty((li.initial.shape[0], len(METRICS)))
    previous = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(threads)
    try:
        _dopri_kernel(li.poly, li.duration, di.theta_ref, di.y_ref, di.plan_theta,
                      di.plan_theta_dot, li.controller, li.gains, li.plant, di.links,
                      li.total_mass, li.h0, li.initial, li.dt, li.steps, li.rate_limit,
                      di.rtol, di.atol, di.threshold, every, out)
    finally:
        numba.set_num_threads(previous)
    return out


@njit(cache=True, error_model="numpy")
def _rhs_loop(poly: Array, duration: float, controller: Array, gains: Array, plant: Array,
              states: Array, times: Array, lim: float) -> float:
    """Every state (M, 4) at its time (M,) through the plan's flag and the closed loop's
    right-hand side, one after another; a sum of the rates (so nothing is skipped)."""
    total = 0.0
    degree = poly.shape[2] - 1
    for i in range(states.shape[0]):
        s = times[i] / duration
        f0 = f1 = f2 = f3 = f4 = f5 = 0.0  # Horner, in registers (``_plan`` builds a list)
        for c in range(degree, -1, -1):
            f0 = f0 * s + poly[0, 0, c]
            f1 = f1 * s + poly[0, 1, c]
            f2 = f2 * s + poly[1, 0, c]
            f3 = f3 * s + poly[1, 1, c]
            f4 = f4 * s + poly[2, 0, c]
            f5 = f5 * s + poly[2, 1, c]
        ref = (f0, f1, f2, f3, f4, f5)
        r = _rates(states[i, 0], states[i, 1], states[i, 2], states[i, 3], ref, controller,
                   gains, plant[0], 0.0, lim)
        total += r[0] + r[1] + r[2] + r[3]
    return total


def rhs_nanoseconds(plan: Plan, trials: Trials, tracking: Tracking = PAPER_TRACKING,
                    count: int = 1_000_000, repeat: int = 5) -> float:
    """The arithmetic floor of one right-hand side [ns]: the plan's flag and the closed loop
    at one state (``_plan``, ``_rates``: what each Dormand-Prince stage evaluates), over
    ``count`` states near the trials' starts, one thread, the least of ``repeat`` runs.
    The states are independent, so the processor may overlap them; the integrator's stages
    depend on each other, so this is a floor, not the integrator's cost."""
    import time

    li = loop_inputs(plan, tracking, trials)
    rng = np.random.default_rng(0)
    start = li.initial[rng.integers(0, li.initial.shape[0], count)]
    states = np.ascontiguousarray(start + rng.normal(0.0, 1e-3, start.shape))
    times = rng.uniform(0.0, li.duration, count)
    args = (li.poly, li.duration, li.controller, li.gains, li.plant, states, times,
            li.rate_limit)
    _rhs_loop(*args)
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        _rhs_loop(*args)
        best = min(best, time.perf_counter() - t0)
    return 1e9 * best / count


def dopri_trials_per_second(plan: Plan, trials: Trials, tracking: Tracking = PAPER_TRACKING,
                            threads: int = 2, repeat: int = 3, every: int = 1) -> Throughput:
    """Throughput of ``dopri_metrics`` after a warm-up (compilation, thread pool)."""
    di = dopri_inputs(plan, trials, tracking)
    return throughput(lambda: dopri_metrics(plan, trials, tracking, threads, di, every),
                      trials.count, threads, repeat)
