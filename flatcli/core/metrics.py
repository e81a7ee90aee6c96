"""Per-trial metrics of a closed-loop run, computed from its trace on the simulation grid.

A trace holds the prolonged state (th0, th1, th2, u1) at the n + 1 grid times t_j = j dt.
For each trial (definitions repeated in the README):

* ``err_theta_*``: e_j = |th_j - th_ref,j| (Euclidean norm over the three angles) [rad];
  ``_rms`` = sqrt(mean_j e_j^2), ``_max`` = max_j e_j, ``_final`` = e_n.
* ``err_y_*``: the same for the flat outputs y = (y1, y2) computed from the true state with
  the controller's (nominal) flat map, against the plan's y [rad].
* ``singular_hits``: samples whose margin |sin th1 * u1| is below the threshold;
  ``first_hit_time`` [s] (nan if none); ``min_margin`` [rad/s].
* ``momentum_drift``: max_j |H_j - H0| [kg m^2/s], H_j from the full link kinematics of the
  plant with rates from the trace itself (second-order differences: central inside,
  one-sided at the ends, as numpy.gradient with edge_order=2). The integrated system conserves
  H0 exactly, so this measures the integration error; it shrinks as dt^2.
* ``plan_momentum_residual``: max_j |H(th_ref,j, th_ref',j) - H0| over the plan's own
  sample grid (``plan.samples`` points, the rows of plan.parquet), with the plant's true
  parameters [kg m^2/s]: zero only when the controller's model is right.

A diverged trial (non-finite state, or a state beyond the divergence bound) keeps the
metrics of its samples up to divergence, and nan final errors.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.flatness import chart
from flatcli.core.model import Coefficients, Links, momentum, momentum_at

Array = NDArray[np.float64]

METRIC_NAMES: tuple[str, ...] = (
    "err_theta_rms",
    "err_theta_max",
    "err_theta_final",
    "err_y_rms",
    "err_y_max",
    "err_y_final",
    "singular_hits",
    "first_hit_time",
    "min_margin",
    "momentum_drift",
    "plan_momentum_residual",
)
N_METRICS = len(METRIC_NAMES)

STATUS_OK = 0
STATUS_SINGULAR = 1
STATUS_DIVERGED = 2
STATUS_NAMES: tuple[str, ...] = ("ok", "singular", "diverged", "error")


@jitable
def trace_rates(trace: Array, j: int, last: int, inv_2dt: float) -> tuple[float, float, float]:
    """th' at sample j of a trace (rows 0..last) by second-order differences [rad/s]."""
    if j == 0:
        a, b, c, wa, wb, wc = 0, 1, 2, -3.0, 4.0, -1.0
    elif j == last:
        a, b, c, wa, wb, wc = last - 2, last - 1, last, 1.0, -4.0, 3.0
    else:
        a, b, c, wa, wb, wc = j - 1, j, j + 1, -1.0, 0.0, 1.0
    r0 = (wa * trace[a, 0] + wb * trace[b, 0] + wc * trace[c, 0]) * inv_2dt
    r1 = (wa * trace[a, 1] + wb * trace[b, 1] + wc * trace[c, 1]) * inv_2dt
    r2 = (wa * trace[a, 2] + wb * trace[b, 2] + wc * trace[c, 2]) * inv_2dt
    return r0, r1, r2


@jitable
def trace_metrics(
    out: Array,
    trace: Array,
    last: int,
    diverged: bool,
    ref: Array,
    theta_ref: Array,
    plan_theta: Array,
    plan_theta_dot: Array,
    kc: Coefficients,
    links: Links,
    h0: float,
    dt: float,
    threshold: float,
) -> int:
    """Fill ``out`` (N_METRICS,) from a trace; return the first hit sample (-1 if none).

    Parameters
    ----------
    out : (N_METRICS,) float, written in the order of METRIC_NAMES
    trace : (>= last + 1, 9) th0, th1, th2 [rad], u1 [rad/s], u2 [rad/s], then cos th1,
        sin th1, cos(th1 + th2), sin(th1 + th2) per grid sample (``simulate.TRACE_WIDTH``)
    last : index of the last valid sample
    diverged : whether the run stopped early (final errors are then nan)
    ref : (2 n + 1, 6) plan y1, y2, y1', y2', y1'', y2'' at half steps
    theta_ref : (n + 1, 3) plan angles on the grid [rad]
    plan_theta, plan_theta_dot : (m, 3) plan angles [rad] and exact rates [rad/s] on the
        plan's own grid, for the plan's momentum residual
    kc : Coefficients of the controller; links : Links of the plant; h0 [kg m^2/s]
    dt : grid step [s]; threshold : singularity threshold on the margin [rad/s]
    """
    # squared errors inside the loop; one square root per metric at the end
    sum_et2 = 0.0
    max_et2 = 0.0
    sum_ey2 = 0.0
    max_ey2 = 0.0
    et2 = 0.0
    ey2 = 0.0
    hits = 0
    first = -1
    min_margin = math.inf
    for j in range(last + 1):
        d0 = trace[j, 0] - theta_ref[j, 0]
        d1 = trace[j, 1] - theta_ref[j, 1]
        d2 = trace[j, 2] - theta_ref[j, 2]
        et2 = d0 * d0 + d1 * d1 + d2 * d2
        c1, s1 = trace[j, 5], trace[j, 6]  # cos th1, sin th1 stored by the integrator
        inv_A, _, _ = chart(kc, c1, s1)  # y = flat_outputs(kc, ...), sharing c1 and s1
        e1 = trace[j, 1] - ref[2 * j, 0]
        e2 = trace[j, 0] - kc.c0 * trace[j, 2] * inv_A - ref[2 * j, 1]
        ey2 = e1 * e1 + e2 * e2
        sum_et2 += et2
        sum_ey2 += ey2
        max_et2 = max(max_et2, et2)
        max_ey2 = max(max_ey2, ey2)
        margin = abs(s1 * trace[j, 3])  # singularity_margin
        if margin < threshold:
            hits += 1
            if first < 0:
                first = j
        min_margin = min(min_margin, margin)
    drift = math.nan
    if last >= 2:
        inv_2dt = 0.5 / dt
        drift = max(_sample_drift(trace, 0, last, inv_2dt, links, h0),
                    _sample_drift(trace, last, last, inv_2dt, links, h0))
        for j in range(1, last):  # central differences: the stencil without a branch
            r0 = (trace[j + 1, 0] - trace[j - 1, 0]) * inv_2dt
            r1 = (trace[j + 1, 1] - trace[j - 1, 1]) * inv_2dt
            r2 = (trace[j + 1, 2] - trace[j - 1, 2]) * inv_2dt
            h = momentum_at(links, trace[j, 5], trace[j, 6], trace[j, 7], trace[j, 8], r0, r1, r2)
            drift = max(drift, abs(h - h0))  # type: ignore[call-overload]
    residual = 0.0
    for j in range(plan_theta.shape[0]):
        h = momentum(
            links,
            plan_theta[j, 0],
            plan_theta[j, 1],
            plan_theta[j, 2],
            plan_theta_dot[j, 0],
            plan_theta_dot[j, 1],
            plan_theta_dot[j, 2],
        )
        residual = max(residual, abs(h - h0))  # type: ignore[call-overload]
    count = last + 1
    out[0] = math.sqrt(sum_et2 / count)
    out[1] = math.sqrt(max_et2)
    out[2] = math.nan if diverged else math.sqrt(et2)
    out[3] = math.sqrt(sum_ey2 / count)
    out[4] = math.sqrt(max_ey2)
    out[5] = math.nan if diverged else math.sqrt(ey2)
    out[6] = hits
    out[7] = first * dt if first >= 0 else math.nan
    out[8] = min_margin
    out[9] = drift
    out[10] = residual
    return first


@jitable
def _sample_drift(
    trace: Array, j: int, last: int, inv_2dt: float, links: Links, h0: float
) -> float:
    """|H - H0| at sample j of a trace, rates by ``trace_rates``."""
    r0, r1, r2 = trace_rates(trace, j, last, inv_2dt)
    h = momentum_at(links, trace[j, 5], trace[j, 6], trace[j, 7], trace[j, 8], r0, r1, r2)
    return float(np.abs(h - h0))


def describe_status(
    code: int, event_time: float, metrics: Array, threshold: float, bound: float
) -> tuple[str, str]:
    """Status name and a one-line reason for a trial.

    Parameters
    ----------
    code : STATUS_OK, STATUS_SINGULAR or STATUS_DIVERGED
    event_time : time of divergence [s] (ignored otherwise)
    metrics : (N_METRICS,) as filled by ``trace_metrics``
    threshold : singularity threshold [rad/s]; bound : divergence bound
    """
    if code == STATUS_DIVERGED:
        return "diverged", (f"state non-finite or beyond {bound:g} at t = {event_time:.6g} s")
    if code == STATUS_SINGULAR:
        hits = int(metrics[6])
        return "singular", (
            f"margin |sin th1 * u1| below {threshold:g} rad/s at {hits} samples, first at "
            f"t = {metrics[7]:.6g} s, min {metrics[8]:.3g}"
        )
    return "ok", ""
