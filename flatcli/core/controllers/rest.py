"""The flat law at rest: feedforward at the ends, the feedback faded in between.

At rest the linearising feedback divides by the margin (sin(th1) u1 = 0 for N = 2, sigma of
``chainflat`` for a chain): its gain on the y_N error grows as 1/t near the ends, and a
measured state a little off the plan would be commanded without bound. So on a rest plan
(``plan.rest.RestPlan``) the flat law (``flat.command``, and the paper's closed form in
``paper.command``) blends its commands with the plan's own:

    u_j' = y_jd'' + w(t) (u_j'_fb - y_jd''),   j < N,
    th_N' = th_Nd' + w(t) (th_N'_fb - th_Nd'),

with th_Nd' the plan's own rate (exact at the ends, ``RestPlan.sample``), u_j'_fb and
th_N'_fb the feedback's and the fade w(t) = S(t / (f T)) S((T - t) / (f T)), S(x) = 3 x^2 -
2 x^3 on [0, 1] (1 beyond): zero with zero slope at the ends, one in the middle (f =
``task.fade``, at most 1/2). Where w = 0 the plant is driven open loop by the plan (the
feedback is not evaluated), so an initial error persists through the fade-in and whatever
error is left when the fade-out begins is carried to T: that is the tracking error the scheme
costs (docs/tasks.md measures it). Where w = 1 the law is the flat law, bit for bit.

The law reads w and th_Nd' from the tracked flag: ``reference`` gives the plan's flat
outputs followed by ``CHANNELS`` more channels (w, th_Nd', and s = +-1 the sign of the plan's
margin), so the flag (3 C,), C = N + 3, holds the values of the C channels, then their first
and second derivatives (``integrate.plan_flag``); a flat plan's flag has C = N (the law is
the flat law's there, w = 1). The law's margin is sigma where w = 1; in the fades s |sigma| / w (its
feedback enters weighted by w: the margin grows without bound towards the ends, where the law
is the plan's feedforward; a zero of sigma there, where u_1 reaches zero a little before T off
the plan, is stepped over as the plan's own ends are), and s inf where w = 0.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import Real, jitable
from flatcli.core.curves.pieces import PiecewiseCurves, curves, fit, node_times
from flatcli.core.plan.rest import RestPlan, reduced_margin

Array = NDArray[np.float64]

#: Channels a rest plan's reference adds after its N flat outputs: w, th_Nd', s.
CHANNELS = 3
#: Degree of the reference's pieces; how many pieces a fade has per unit of task.fade (8 at
#: 0.2: th_Nd' to 1e-10 rad/s or better, below), and the middle.
DEGREE = 11
FADE_PIECES = 40
MIDDLE_PIECES = 2


def fade(t: Array | float, duration: float, fraction: float) -> Array:
    """w(t) in [0, 1] at t [s] (module docstring), for a plan of ``duration`` [s] and
    ``task.fade`` = ``fraction``."""
    width = fraction * duration

    def step(x: Array) -> Array:
        x = np.clip(x, 0.0, 1.0)
        return np.asarray(x * x * (3.0 - 2.0 * x), dtype=float)

    tt = np.asarray(t, dtype=float)
    return np.asarray(step(tt / width) * step((duration - tt) / width), dtype=float)


def _step(a: float, b: float) -> Array:
    """(4,) the coefficients in s of S(a + b s) = 3 x^2 - 2 x^3 (exact zeros where a = 0)."""
    return np.array([a * a * (3.0 - 2.0 * a), 6.0 * a * b * (1.0 - a),
                     3.0 * b * b * (1.0 - 2.0 * a), -2.0 * b ** 3])


def _shifted(coefficients: Array, a: float, b: float) -> Array:
    """(8, N) the coefficients in s of the plan's polynomials (N, 8) in x, at x = a + b s."""
    out = np.zeros((coefficients.shape[1], coefficients.shape[0]))
    for j, row in enumerate(coefficients):
        shifted = np.polynomial.Polynomial(row)(np.polynomial.Polynomial([a, b])).coef
        out[: shifted.size, j] = shifted
    return out


def reference(plan: RestPlan, fraction: float) -> PiecewiseCurves:
    """The channels the flat law tracks on a rest plan (module docstring): y_1..y_N, w,
    th_Nd', s as piecewise polynomials of ``DEGREE``: ``FADE_PIECES`` x f on each fade, whose w is
    exact (0 at t = 0 to the bit), ``MIDDLE_PIECES`` between them, where w is 1 exactly. The
    plan's outputs are its own polynomials of degree 7 re-expressed on each piece (from those
    in s on the first half, in s - 1 on the second: ``RestPlan.derivative``); th_Nd' is fitted
    at the Chebyshev nodes (analytic; read only where w < 1: there within 2e-10 rad/s of
    ``RestPlan.sample`` on the capture task's plan and docs/tasks.md's N = 3 one, f = 0.1 to
    0.5, rates up to 47 rad/s)."""
    T = plan.duration
    width = fraction * T
    n = plan.n_joints
    pieces = math.ceil(FADE_PIECES * fraction)
    ends = [np.linspace(0.0, width, pieces + 1)]
    if T - 2.0 * width > 0.0:
        ends.append(np.linspace(width, T - width, MIDDLE_PIECES + 1)[1:])
    ends.append(np.linspace(T - width, T, pieces + 1)[1:])
    breaks = np.concatenate(ends)
    times = node_times(breaks, DEGREE)
    rate = plan.sample(times.ravel()).theta_dot[:, n]
    local = np.zeros((len(breaks) - 1, DEGREE + 1, n + CHANNELS))
    local[:, :, n + 1] = fit(breaks, DEGREE, rate.reshape(*times.shape, 1)).local[:, :, 0]
    head, tail = plan.trajectory.coefficients, plan.tail
    for i, (lo, hi) in enumerate(itertools.pairwise(breaks)):
        if lo + hi <= T:  # in s = t / T
            local[i, :8, :n] = _shifted(head, lo / T, (hi - lo) / T)
        else:  # in s - 1
            local[i, :8, :n] = _shifted(tail, lo / T - 1.0, (hi - lo) / T)
        if hi <= width:  # x = t / width
            local[i, :4, n] = _step(lo / width, (hi - lo) / width)
        elif lo >= T - width:  # x = (T - t) / width
            local[i, :4, n] = _step((T - lo) / width, -(hi - lo) / width)
        else:
            local[i, 0, n] = 1.0
    sign = np.sign(reduced_margin(plan.model, plan.robot, plan.start, plan.goal,
                                  np.array([0.5]), plan.skew)[0])
    local[:, 0, n + 2] = float(sign)
    return curves(breaks, local)


@jitable
def blended(w: float, planned: float, feedback: Real) -> Real:
    """planned + w (feedback - planned); the plan's alone where w <= 0 (the feedback, which
    may divide by a zero margin there, is not read)."""
    if w <= 0.0:
        return planned
    return planned + w * (feedback - planned)


@jitable
def faded_margin(ref: Any, n: int, w: float, sigma: Real) -> Real:
    """The law's signed margin where w < 1 (module docstring): s |sigma| / w, s inf at w = 0."""
    sign = ref[n + 2]
    if w <= 0.0:
        return sign * math.inf  # type: ignore[no-any-return]
    return sign * abs(sigma) / w  # type: ignore[no-any-return]


@jitable
def faded_paper(ref: Any, u1_dot: Real, u2: Real, sigma: Real) -> tuple[Real, Real, Real]:
    """The paper's robot's (N = 2) commands u1' [rad/s^2], u2 [rad/s] and margin [rad/s]
    from the feedback's and its margin sigma, on a rest plan's flag ``ref`` (3 (2 +
    ``CHANNELS``),): blended where w < 1, the feedback's where w = 1."""
    w = ref[2]
    if w >= 1.0:
        return u1_dot, u2, sigma
    c = ref.shape[0] // 3
    return (blended(w, ref[2 * c], u1_dot), blended(w, ref[3], u2),
            faded_margin(ref, 2, w, sigma))


@jitable
def faded_chain(ref: Any, n: int, u_dot: Any, r: Any, sigma: float) -> float:
    """A chain's commands blended where w < 1 on a rest plan's flag ``ref`` (3 (N +
    ``CHANNELS``),): the inner joints' accelerations u_dot (N - 1,) [rad/s^2] and the rate
    r[N - 1] of joint N [rad/s] in place; returns the law's margin from sigma [rad/s]."""
    w = ref[n]
    if w >= 1.0:
        return sigma
    c = ref.shape[0] // 3
    for j in range(n - 1):
        u_dot[j] = blended(w, ref[2 * c + j], u_dot[j])
    r[n - 1] = blended(w, ref[n + 1], r[n - 1])
    return float(faded_margin(ref, n, w, sigma))


@jitable
def observed_margin(table: Any, j: int, n: int, margin: float) -> float:
    """The margin the metrics observe at output sample j: |sigma| = ``margin``, divided by
    w on a rest plan's reference (``table`` (2 n + 1, 3 C), row 2 j at t_j)."""
    if table.shape[1] <= 3 * n:
        return margin
    w = table[2 * j, n]
    if w >= 1.0:
        return margin
    return margin / w if w > 0.0 else math.inf


__all__ = ["CHANNELS", "blended", "fade", "faded_chain", "faded_margin", "faded_paper",
           "observed_margin", "reference"]
