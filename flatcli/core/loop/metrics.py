"""Per-trial metrics of a closed-loop run, statuses, and how a trial ended.

The integrators (``integrate``) hand every output sample t_j = j dt, j = 0..n, to an
accumulator as they produce it: the plant state x_j and its right-hand side f_j, i.e. the
joint rates the plant actually applies there (with that sample's sensor noise). Nothing is
kept per sample unless a trace is recorded, so memory does not grow with n. For each trial
(definitions repeated in the README):

* ``err_theta_*``: e_j = |th_j - th_ref,j| (Euclidean norm over the three angles) [rad];
  ``_rms`` = sqrt(mean_j e_j^2), ``_max`` = max_j e_j, ``_final`` = e_n.
* ``err_y_*``: the same for the flat outputs y = (y1, y2) computed from the true state with
  the controller's (nominal) flat map, against the plan's y [rad].
* ``singular_hits``: samples whose margin |sin th1 * u1| is below the threshold;
  ``first_hit_time`` [s] (nan if none); ``min_margin`` [rad/s].
* ``momentum_drift``: max_j |H(x_j, f_j) - H0| [kg m^2/s], H from the plant's full link
  kinematics at the integrated state with the joint rates the plant applies there (its own
  right-hand side). The kinematic plant solves th0' from the momentum constraint, so this is
  rounding (~1e-16) unless the constraint and the kinematics disagree; a plant with inertia
  conserves H only through its dynamics, and then this measures the integration.
* ``plan_momentum_residual``: max_j |H(th_ref,j, th_ref',j) - H0| over the plan's own
  sample grid (``plan.samples`` points, the rows of plan.parquet), with the plant's true
  parameters [kg m^2/s]: zero only when the controller's model is right.
* ``err_estimate``: the adaptive integrator's estimate of the global error in th at the end
  [rad]: the sum over accepted steps of the Euclidean norm of the embedded (order 4 vs 5)
  local error estimate of th0, th1, th2 (nan for the other integrators).
* ``peak_rate``: max_j of |th1'|, |th2'| applied by the plant [rad/s].
* ``peak_torque``: max_j of |tau1|, |tau2| applied by a plant with inertia [N m];
  ``torque_saturated``: samples where the servo asked for more torque than the limit (so the
  applied torque was clipped). Both nan on the kinematic plant.
* ``steps``, ``rhs_evaluations``: accepted integration steps and right-hand-side
  evaluations, the cost of the trial.
* ``clipped_time``: how long a joint-rate command was at or beyond the rate limit [s], the
  trapezoidal integral of that indicator over the observed samples (``observe_clipped``); a
  clipping shorter than the samples' spacing that falls between two samples is not seen, and
  each episode's ends are known to half a spacing.

A trial that stops early (``Event``) keeps the metrics of its samples up to that point and
nan final errors; see ``Status`` for what each status means.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.names import METRIC_NAMES, Metric

Array = NDArray[np.float64]


# the metric columns as plain ints, for the kernels
_M_ERR_THETA_RMS = int(Metric.ERR_THETA_RMS)
_M_ERR_THETA_MAX = int(Metric.ERR_THETA_MAX)
_M_ERR_THETA_FINAL = int(Metric.ERR_THETA_FINAL)
_M_ERR_Y_RMS = int(Metric.ERR_Y_RMS)
_M_ERR_Y_MAX = int(Metric.ERR_Y_MAX)
_M_ERR_Y_FINAL = int(Metric.ERR_Y_FINAL)
_M_SINGULAR_HITS = int(Metric.SINGULAR_HITS)
_M_FIRST_HIT_TIME = int(Metric.FIRST_HIT_TIME)
_M_MIN_MARGIN = int(Metric.MIN_MARGIN)
_M_MOMENTUM_DRIFT = int(Metric.MOMENTUM_DRIFT)
_M_PLAN_MOMENTUM_RESIDUAL = int(Metric.PLAN_MOMENTUM_RESIDUAL)
_M_ERR_ESTIMATE = int(Metric.ERR_ESTIMATE)
_M_PEAK_RATE = int(Metric.PEAK_RATE)
_M_PEAK_TORQUE = int(Metric.PEAK_TORQUE)
_M_TORQUE_SATURATED = int(Metric.TORQUE_SATURATED)
_M_STEPS = int(Metric.STEPS)
_M_RHS_EVALUATIONS = int(Metric.RHS_EVALUATIONS)
_M_CROSSINGS = int(Metric.CROSSINGS)
_M_FIRST_CROSSING_TIME = int(Metric.FIRST_CROSSING_TIME)
_M_CLIPPED_TIME = int(Metric.CLIPPED_TIME)

N_METRICS = len(METRIC_NAMES)
#: Metrics that count things (integers in the tables).
COUNT_METRICS: tuple[str, ...] = ("singular_hits", "torque_saturated", "steps",
                                  "rhs_evaluations", "crossings")


class Status(IntEnum):
    """How a trial ended.

    * ``ok``: resolved to the end, never near the singular set.
    * ``singular``: resolved to the end, but the margin fell below the singular threshold.
    * ``diverged``: stopped early: a state beyond the divergence bound or non-finite, or the
      controller met its singular set (the margin sin th1 * u1 changed sign, or the step
      size collapsed onto it), where the feedback is unbounded and no integrator can pass.
    * ``unresolved``: the adaptive integrator could not meet its tolerance (step size below
      its floor away from the singular set, or ``max_steps`` spent).
    * ``error``: the trial could not run at all (e.g. a perturbed mass <= 0; sweeps only).

    Only ``ok`` and ``singular`` trials are resolved to the end; their errors are numbers a
    study may average.
    """

    OK = 0
    SINGULAR = 1
    DIVERGED = 2
    UNRESOLVED = 3
    ERROR = 4


STATUS_NAMES: tuple[str, ...] = tuple(s.name.lower() for s in Status)
#: Statuses of trials resolved to the end.
RESOLVED: tuple[str, ...] = ("ok", "singular")
#: What a trial achieved, its ``outcome`` (``flatcli.core.loop.outcome``): reached, collided,
#: missed, lost.
OUTCOME_NAMES: tuple[str, ...] = ("reached", "collided", "missed", "lost")


class Event(IntEnum):
    """Why a trial stopped before the end (``NONE``: it did not)."""

    NONE = 0
    BOUND = 1  # a state beyond the divergence bound, or non-finite
    CROSSED = 2  # the controller's margin sin th1 * u1 changed sign within a step
    STALLED = 3  # the step size collapsed where the margin is ~0 (onto the singular set)
    STEP_FLOOR = 4  # the step size fell below its floor elsewhere
    MAX_STEPS = 5  # track.max_steps spent

    @property
    def status(self) -> Status:
        if self is Event.NONE:
            return Status.OK
        if self in (Event.STEP_FLOOR, Event.MAX_STEPS):
            return Status.UNRESOLVED
        return Status.DIVERGED


#: Accumulator layout (``new_accumulator``): running sums and extremes over the samples.
_SUM_ET2, _MAX_ET2, _SUM_EY2, _MAX_EY2, _LAST_ET2, _LAST_EY2 = 0, 1, 2, 3, 4, 5
_HITS, _FIRST, _MIN_MARGIN, _DRIFT, _PEAK_RATE, _COUNT = 6, 7, 8, 9, 10, 11
_PEAK_TORQUE, _SATURATED, _CROSSINGS, _FIRST_CROSSING = 12, 13, 14, 15
#: the clipped time's trapezoidal sum [samples], the last observed sample j (-1: none) and
#: whether a rate command was clipped there (``observe_clipped``)
_CLIP_SUM, _CLIP_LAST_J, _CLIP_LAST = 16, 17, 18
ACCUMULATOR_SIZE = 19


@jitable
def reset_accumulator(acc: Array) -> None:
    """Empty running metrics in ``acc`` (ACCUMULATOR_SIZE,)."""
    acc[:] = 0.0
    acc[_FIRST] = -1.0
    acc[_MIN_MARGIN] = math.inf
    acc[_PEAK_TORQUE] = math.nan
    acc[_SATURATED] = math.nan
    acc[_FIRST_CROSSING] = math.nan
    acc[_CLIP_LAST_J] = -1.0


@jitable
def observe_clipped(acc: Array, j: int, clipped: bool) -> None:
    """Fold into the running metrics whether a joint-rate command was clipped at output
    sample j (at or beyond ``track.rate_limit``: the joint turned, or its servo was asked to
    turn it, at the limit rather than at the command). ``clipped_time`` is the trapezoidal
    integral over the observed samples of that indicator: each pair of consecutive observed
    samples j < k adds (k - j) dt times the mean of their two flags (so a trial clipped at
    every sample is clipped for T, one clipped at one inner sample of every dt for dt)."""
    flag = 1.0 if clipped else 0.0
    last = acc[_CLIP_LAST_J]
    if last >= 0.0:
        acc[_CLIP_SUM] += 0.5 * (j - last) * (flag + acc[_CLIP_LAST])
    acc[_CLIP_LAST_J] = j
    acc[_CLIP_LAST] = flag


def clipped_time_of(clipped: NDArray[np.bool_], dt: float) -> float:
    """``clipped_time`` [s] of flags at the output samples 0..n (every one observed), as
    ``observe_clipped`` sums them: the trapezoidal integral of the indicator."""
    flags = np.asarray(clipped, dtype=float)
    return float(0.5 * dt * np.sum(flags[1:] + flags[:-1])) if len(flags) else math.nan


@jitable
def observe_crossing(acc: Array, t: float) -> None:
    """The controller's margin changed sign at time t [s] (between output samples: the
    integrator located it, and went through because the actuators bound the plant's rates
    there): a crossing, counted among the singular hits with margin 0."""
    acc[_CROSSINGS] += 1.0
    if math.isnan(acc[_FIRST_CROSSING]):
        acc[_FIRST_CROSSING] = t


@jitable
def crossings_of(acc: Array) -> int:
    """The crossings of the singular set recorded so far."""
    return int(acc[_CROSSINGS])


@jitable
def observe_torque(acc: Array, tau1: float, tau2: float, saturated: float) -> None:
    """Fold the joint torques of a plant with inertia at one output sample into the running
    metrics (after ``observe_errors``); the kinematic plant never calls it, so its
    ``peak_torque`` and ``torque_saturated`` stay nan.

    Parameters
    ----------
    acc : (ACCUMULATOR_SIZE,) running metrics
    tau1, tau2 : joint torques applied [N m]
    saturated : 1.0 if the servo asked for more than the torque limit at this sample, else 0.0
    """
    if math.isnan(acc[_PEAK_TORQUE]):
        acc[_PEAK_TORQUE] = 0.0
        acc[_SATURATED] = 0.0
    acc[_PEAK_TORQUE] = max(acc[_PEAK_TORQUE], abs(tau1), abs(tau2))
    acc[_SATURATED] += saturated


@jitable
def finish_metrics(
    out: Array, acc: Array, complete: bool, dt: float, residual: float, err_estimate: float,
    steps: int, evaluations: int,
) -> float:
    """Write the metrics row ``out`` (N_METRICS,) from the running metrics; return the time
    of the first singular hit (a sample below the threshold, or a crossing) [s], nan if none.
    ``complete``: the trial reached the end. A crossing counts as a hit with margin 0."""
    count = acc[_COUNT]
    first = int(acc[_FIRST])
    crossings = acc[_CROSSINGS]
    first_hit = first * dt if first >= 0 else math.nan
    crossed_at = acc[_FIRST_CROSSING]
    if crossings > 0 and not crossed_at >= first_hit:  # (nan first_hit included)
        first_hit = crossed_at
    out[_M_ERR_THETA_RMS] = math.sqrt(acc[_SUM_ET2] / count) if count else math.nan
    out[_M_ERR_THETA_MAX] = math.sqrt(acc[_MAX_ET2]) if count else math.nan
    out[_M_ERR_THETA_FINAL] = math.sqrt(acc[_LAST_ET2]) if complete else math.nan
    out[_M_ERR_Y_RMS] = math.sqrt(acc[_SUM_EY2] / count) if count else math.nan
    out[_M_ERR_Y_MAX] = math.sqrt(acc[_MAX_EY2]) if count else math.nan
    out[_M_ERR_Y_FINAL] = math.sqrt(acc[_LAST_EY2]) if complete else math.nan
    out[_M_SINGULAR_HITS] = acc[_HITS] + crossings
    out[_M_FIRST_HIT_TIME] = first_hit
    # a controller without a singular set observes an infinite margin: min_margin null
    least = acc[_MIN_MARGIN] if math.isfinite(acc[_MIN_MARGIN]) else math.nan
    out[_M_MIN_MARGIN] = (0.0 if crossings > 0 else least) if count else math.nan
    out[_M_MOMENTUM_DRIFT] = acc[_DRIFT] if count else math.nan
    out[_M_PLAN_MOMENTUM_RESIDUAL] = residual
    out[_M_ERR_ESTIMATE] = err_estimate
    out[_M_PEAK_RATE] = acc[_PEAK_RATE] if count else math.nan
    out[_M_PEAK_TORQUE] = acc[_PEAK_TORQUE]
    out[_M_TORQUE_SATURATED] = acc[_SATURATED]
    out[_M_STEPS] = steps
    out[_M_RHS_EVALUATIONS] = evaluations
    out[_M_CROSSINGS] = crossings
    out[_M_FIRST_CROSSING_TIME] = crossed_at if crossings > 0 else math.nan
    out[_M_CLIPPED_TIME] = acc[_CLIP_SUM] * dt if count else math.nan
    return first_hit


def _count(value: float) -> int:
    """A count metric as an int (0 where it is not recorded: nan)."""
    return int(value) if math.isfinite(value) else 0


def describe_status(
    code: int, event: int, event_time: float, metrics: Array, threshold: float, bound: float,
    unverified: str = "",
) -> tuple[str, str]:
    """Status name and a one-line reason for a trial.

    Parameters
    ----------
    code : a ``Status``
    event : the ``Event`` that stopped the trial (``Event.NONE`` if it reached the end)
    event_time : when it stopped [s] (ignored otherwise)
    metrics : (N_METRICS,) as written by ``finish_metrics``
    threshold : singularity threshold [rad/s]; bound : divergence bound
    unverified : why a resolved trial's accuracy is not verified ("" if it is:
        ``simulate.Outcome.unverified``), added to its reason
    """
    name, reason = _describe(code, event, event_time, metrics, threshold, bound)
    if name in RESOLVED and unverified:
        reason = f"{reason}; {unverified}" if reason else unverified
    return name, reason


def _describe(
    code: int, event: int, event_time: float, metrics: Array, threshold: float, bound: float
) -> tuple[str, str]:
    status = Status(code)
    at = f"t = {event_time:.6g} s"
    if status is Status.DIVERGED:
        why = Event(event)
        if why is Event.CROSSED:
            return "diverged", (
                f"crossed the singular set at {at}: the controller's margin changed sign, where "
                "the feedback is unbounded and nothing limits the joint it drives (no finite "
                "track.rate_limit or plant.torque_limit)"
            )
        if why is Event.STALLED:
            return "diverged", (
                f"met the singular set at {at}: the step size collapsed where the controller's "
                "margin vanishes and the feedback is unbounded"
            )
        return "diverged", f"state non-finite or beyond {bound:g} at {at}"
    if status is Status.UNRESOLVED:
        if Event(event) is Event.MAX_STEPS:
            return "unresolved", (
                f"track.max_steps spent at {at} ({int(metrics[Metric.STEPS])} steps): the "
                "tolerance could not be met within the step budget"
            )
        return "unresolved", (
            f"step size fell below its floor at {at}: the tolerance (track.rtol, track.atol) "
            "could not be met there"
        )
    if status is Status.SINGULAR:
        hits = _count(metrics[Metric.SINGULAR_HITS])
        crossings = _count(metrics[Metric.CROSSINGS])
        samples = hits - crossings
        parts = []
        if crossings:
            parts.append(
                f"crossed the singular set {crossings} time{'s' if crossings > 1 else ''}, first "
                f"at t = {metrics[Metric.FIRST_CROSSING_TIME]:.6g} s, where the actuators' limits "
                "kept the plant's rates bounded")
        if samples:
            parts.append(f"margin below {threshold:g} rad/s at {samples} samples")
        return "singular", (
            f"{'; '.join(parts)}; first hit at t = {metrics[Metric.FIRST_HIT_TIME]:.6g} s, min "
            f"margin {metrics[Metric.MIN_MARGIN]:.3g}"
        )
    if status is Status.ERROR:
        return "error", ""
    return "ok", ""


__all__ = [
    "ACCUMULATOR_SIZE",
    "COUNT_METRICS",
    "METRIC_NAMES",
    "N_METRICS",
    "OUTCOME_NAMES",
    "RESOLVED",
    "STATUS_NAMES",
    "Event",
    "Metric",
    "Status",
    "clipped_time_of",
    "crossings_of",
    "describe_status",
    "finish_metrics",
    "observe_clipped",
    "observe_crossing",
    "observe_torque",
    "reset_accumulator",
]


@jitable
def observe_errors(acc: Array, j: int, et2: float, ey2: float, margin: float, h: float,
                   h0: float, peak_rate: float, threshold: float) -> None:
    """Fold output sample j into the running metrics, given its squared angle error et2
    [rad^2], squared flat-output error ey2 [rad^2], margin [rad/s], H from the full
    kinematics [kg m^2/s] and the largest applied joint rate [rad/s] (any number of links)."""
    acc[_SUM_ET2] += et2
    acc[_SUM_EY2] += ey2
    acc[_MAX_ET2] = max(acc[_MAX_ET2], et2)
    acc[_MAX_EY2] = max(acc[_MAX_EY2], ey2)
    acc[_LAST_ET2] = et2
    acc[_LAST_EY2] = ey2
    if margin < threshold:
        acc[_HITS] += 1.0
        if acc[_FIRST] < 0.0:
            acc[_FIRST] = j
    acc[_MIN_MARGIN] = min(acc[_MIN_MARGIN], margin)
    acc[_DRIFT] = max(acc[_DRIFT], abs(h - h0))
    acc[_PEAK_RATE] = max(acc[_PEAK_RATE], peak_rate)
    acc[_COUNT] += 1.0


_EVENT_NONE = int(Event.NONE)
_EVENT_FIRST_UNRESOLVED = int(Event.STEP_FLOOR)  # events from here on leave a trial unresolved
_STATUS_OK, _STATUS_SINGULAR = int(Status.OK), int(Status.SINGULAR)
_STATUS_DIVERGED, _STATUS_UNRESOLVED = int(Status.DIVERGED), int(Status.UNRESOLVED)


@jitable
def status_of(event: int, first_hit: float) -> int:
    """A trial's ``Status`` from its integrator's ``Event`` and the time of its first
    singular hit (nan: none)."""
    if event != _EVENT_NONE:
        return _STATUS_UNRESOLVED if event >= _EVENT_FIRST_UNRESOLVED else _STATUS_DIVERGED
    return _STATUS_OK if math.isnan(first_hit) else _STATUS_SINGULAR


@jitable
def conclude_trial(
    i: int, residual: float, acc: Array, last: int, n: int, ev: int, t_ev: float,
    estimate: float, steps: int, evaluations: int, dt: float, record: bool, tr: Array,
    metrics: Array, status: NDArray[np.int64], event: NDArray[np.int64], event_time: Array,
) -> None:
    """Trial i of a batch concluded: its metrics (``finish_metrics``, with the plan's momentum
    ``residual``), status, event and event time [s] (the event's, else the first singular
    sample's, else nan); its trace ``tr`` (n + 1 samples) blanked after the last valid one."""
    first_hit = finish_metrics(metrics[i], acc, ev == _EVENT_NONE, dt, residual, estimate,
                               steps, evaluations)
    status[i] = status_of(ev, first_hit)
    event[i] = ev
    event_time[i] = t_ev if ev != _EVENT_NONE else first_hit
    if record and last < n:
        tr[last + 1:, :] = math.nan
