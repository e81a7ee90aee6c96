"""Did the robot do its job? Each trial's ``outcome``, from its status, where it ended and how
near its links came to the task's obstacles.

A trial's status (``metrics.Status``) says how its *integration* ended; its outcome says
whether the *robot* did what it was asked (docs/outputs.md, *Outcomes*):

* ``reached``: resolved to the end (``ok``, ``singular``) and at t = T every angle th0..thN
  within ``track.goal_tolerance`` [rad] of the plan's goal th(T) (each angle on its own, no
  angle wrapped: a joint that ends a whole turn away has not reached), and, for a task, the
  end effector within ``task.goal_tolerance`` [m] of its target;
* ``collided``: a link entered one of the task's obstacles at an output sample (before the
  trial ended or stopped), or, in a trial resolved to the end, came so near one that the
  closed-loop clearance (``motion_clearance``) cannot show it clear between two samples;
* ``missed``: resolved to the end, clear of every obstacle, but not within the tolerances;
* ``lost``: ``diverged``, ``unresolved`` or ``error``: where the robot ended is not known.

``outcome_reason`` says why in words: which angle missed by how much, which link and obstacle
and when, how the trial was lost.

**Clearance along the closed-loop motion.** A trial's angles are known at the output samples
t_j = j dt only. Between two samples each angle is enclosed by the cones its rate allows: if
abs(th') <= W on [t_j, t_j+1], then th(t) <= min(th_j + W (t - t_j), th_j+1 + W (t_j+1 - t))
<= (th_j + th_j+1 + W dt) / 2, and likewise below, so th(t) lies in the interval
(th_j + th_j+1) / 2 +- W dt / 2 (which holds both samples, as abs(th_j+1 - th_j) <= W dt).
W is ``RATE_MARGIN`` times the largest of abs(th') at the two samples (the rates the plant
applies there) and the mean rate abs(th_j+1 - th_j) / dt between them: the bound holds
wherever no rate exceeds twice that between two samples (a rate that swings by more than its
own size within one dt is not covered; tests/test_outcome.py checks the bound against the
complex-plane link geometry sampled 100x finer than the output, on both plants, with and
without rate limits and noise). These boxes of angles go through the very interval geometry
``clearance.certify`` proves plans with (``clearance.joint_boxes``,
``clearance.link_clearance_bounds``), with the plant's own links, so the closed-loop
``clearance_bound`` is a lower bound of every link's distance from every obstacle over the
whole recorded motion, and ``min_clearance`` the least distance at the samples (exact there).

Everything here is plain numpy on arrays with a leading trial axis; no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core._jit import kernel
from flatcli.core.loop.metrics import OUTCOME_NAMES, RESOLVED
from flatcli.core.names import GOAL_TOLERANCE, TARGET_TOLERANCE
from flatcli.core.plan import intervals as iv
from flatcli.core.plan.clearance import joint_boxes, link_clearance_bounds
from flatcli.core.robots.kinematics import moments_of

Array = NDArray[np.float64]

#: The closed-loop clearance assumes no rate exceeds this factor times the largest of its
#: sampled magnitudes at the two ends of an output interval and its mean over it.
RATE_MARGIN = 2.0
#: Trials whose clearance is computed at once (each holds its trace's intervals).
CLEARANCE_BATCH = 32


class TrialOutcome(Enum):
    """What a trial achieved (module docstring); the value is the word in the tables."""

    REACHED = "reached"
    COLLIDED = "collided"
    MISSED = "missed"
    LOST = "lost"


assert tuple(o.value for o in TrialOutcome) == OUTCOME_NAMES


class Geometry(NamedTuple):
    """The links of T plants, for their positions (``kinematics``): moments (T, N + 1)
    F_a / M [m], length (T, N + 1) [m], shift (T,) m_N e_N / M [m]."""

    moments: Array
    length: Array
    shift: Array

    @staticmethod
    def of(links: ArrayLike, across: ArrayLike | None = None) -> Geometry:
        """From plants' parameters (T, 4 (N + 1)) mass, inertia, length, com [kg, kg m^2, m,
        m] and their last links' centres of mass across the link e_N (T,) [m] (None: 0)."""
        p = np.atleast_2d(np.asarray(links, dtype=float))
        nb = p.shape[1] // 4
        mass, length, com = p[:, :nb], p[:, 2 * nb: 3 * nb], p[:, 3 * nb:]
        total = mass.sum(axis=1)
        e = np.zeros(len(p)) if across is None else np.broadcast_to(
            np.asarray(across, dtype=float), (len(p),))
        return Geometry(moments_of(mass, length, com) / total[:, None], length,
                        mass[:, -1] * e / total)

    def subset(self, rows: slice | NDArray[np.intp]) -> Geometry:
        return Geometry(self.moments[rows], self.length[rows], self.shift[rows])


def joint_points(geometry: Geometry, theta: Array) -> Array:
    """(T, S, N + 2, 2) the joints O_0 .. O_N+1 [m] of each plant at its angles theta
    (T, S, N + 1) [rad], the system's centre of mass at the origin (as
    ``kinematics.joint_positions`` for one robot)."""
    psi = np.cumsum(theta, axis=-1)
    e = np.stack([np.cos(psi), np.sin(psi)], axis=-1)  # (T, S, N + 1, 2)
    origin = -np.einsum("ta,tsak->tsk", geometry.moments, e)
    shift = geometry.shift[:, None, None]
    last = e[..., -1, :]
    origin = origin - shift * np.stack([-last[..., 1], last[..., 0]], axis=-1)
    along = np.cumsum(geometry.length[:, None, :, None] * e, axis=-2)
    return np.concatenate([origin[..., None, :], origin[..., None, :] + along], axis=-2)


def end_effectors(geometry: Geometry, theta: Array) -> Array:
    """(T, 2) the end effector O_N+1 [m] of each plant at its angles theta (T, N + 1)."""
    return np.asarray(joint_points(geometry, np.asarray(theta, float)[:, None, :])[:, 0, -1],
                      dtype=float)


@dataclass(frozen=True)
class MotionClearance:
    """The clearance of T trials' recorded motions from K obstacles (module docstring).

    Attributes
    ----------
    sampled : (T,) least distance of any link from any obstacle's surface at the samples [m]
        (negative: inside; nan: no sample)
    sampled_time : (T,) when [s]; sampled_link, sampled_obstacle : (T,) which
    bound : (T,) a lower bound of that distance over the whole motion between the first and
        the last valid sample [m] (nan: fewer than two samples)
    bound_time : (T, 2) the output interval [t_j, t_j+1] where it is least [s]
    bound_link, bound_obstacle : (T,) which link and obstacle
    """

    sampled: Array
    sampled_time: Array
    sampled_link: NDArray[np.int64]
    sampled_obstacle: NDArray[np.int64]
    bound: Array
    bound_time: Array
    bound_link: NDArray[np.int64]
    bound_obstacle: NDArray[np.int64]

    @staticmethod
    def concatenate(parts: Sequence[MotionClearance]) -> MotionClearance:
        return MotionClearance(*(np.concatenate([getattr(p, f) for p in parts])
                                 for f in MotionClearance.__dataclass_fields__))


def motion_clearance(geometry: Geometry, obstacles: ArrayLike, theta: Array, rates: Array,
                     dt: float) -> MotionClearance:
    """The clearance of T recorded motions from the obstacles (module docstring).

    Parameters
    ----------
    geometry : the T plants' links (``Geometry``)
    obstacles : (K, 3) discs x, y, radius [m], K >= 1
    theta : (T, S, N + 1) angles at the output samples t_j = j dt [rad], nan after a trial
        stopped
    rates : (T, S, N + 1) the rates th0'..thN' the plant applies there [rad/s]
    dt : the samples' spacing [s]
    """
    obs = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    count = theta.shape[0]
    parts = []
    for start in range(0, count, CLEARANCE_BATCH):
        rows = slice(start, min(start + CLEARANCE_BATCH, count))
        parts.append(_batch_clearance(geometry.subset(rows), obs, theta[rows], rates[rows],
                                      dt))
    return MotionClearance.concatenate(parts)


def _first_min(values: Array) -> tuple[Array, NDArray[np.int64], NDArray[np.int64],
                                       NDArray[np.int64]]:
    """Per trial of values (T, S, L, K) with nan where not known: the least value (nan if
    none) and its first index along S, L and K."""
    t, _, links, k = values.shape
    flat = np.where(np.isnan(values), np.inf, values).reshape(t, -1)
    where = np.argmin(flat, axis=1) if flat.shape[1] else np.zeros(t, dtype=np.int64)
    least = flat[np.arange(t), where] if flat.shape[1] else np.full(t, np.inf)
    least = np.where(np.isinf(least), np.nan, least)
    j, rest = np.divmod(where, links * k)
    link, obstacle = np.divmod(rest, k)
    return least, j.astype(np.int64), link.astype(np.int64), obstacle.astype(np.int64)


#: Intervals of a trial the interval geometry examines in each round (``_batch_clearance``).
REFINE_ROUND = 64


@kernel
def sample_clearances(theta: Array, moments: Array, length: Array, shift: Array, obs: Array,
                      joints: Array, out: Array) -> None:
    """Each link's distance from each disc's surface [m] at every sample, into ``out``
    (T, S, N + 1, K): ``joint_points`` and ``clearance.segment_distance`` less the radii in
    one pass, compiled (angles theta (T, S, N + 1) [rad]; moments, length (T, N + 1) [m];
    shift (T,) [m]; obs (K, 3) discs x, y, radius [m]; joints (N + 2, 2) scratch; nan where
    the angles are).
    The joints are placed relative to O_0 along the absolute angles, O_0 then follows from
    the same cosines and sines (one trigonometric evaluation per angle and sample)."""
    count, samples, angles = theta.shape
    discs = obs.shape[0]
    for t in range(count):
        for j in range(samples):
            psi = 0.0
            ox = 0.0
            oy = 0.0
            x = 0.0
            y = 0.0
            c = 1.0
            s_ = 0.0
            for a in range(angles):
                psi += theta[t, j, a]
                c, s_ = math.cos(psi), math.sin(psi)
                ox -= moments[t, a] * c  # O_0 = -sum_a (F_a / M) e(psi_a) - shift e_perp
                oy -= moments[t, a] * s_
                joints[a, 0], joints[a, 1] = x, y  # O_a - O_0
                x += length[t, a] * c
                y += length[t, a] * s_
            joints[angles, 0], joints[angles, 1] = x, y
            ox += shift[t] * s_
            oy -= shift[t] * c
            for a in range(angles):  # link a: O_a O_a+1
                ax, ay = ox + joints[a, 0], oy + joints[a, 1]
                dx, dy = joints[a + 1, 0] - joints[a, 0], joints[a + 1, 1] - joints[a, 1]
                length2 = dx * dx + dy * dy
                for k in range(discs):
                    cx, cy = obs[k, 0], obs[k, 1]
                    u = ((cx - ax) * dx + (cy - ay) * dy) / (length2 if length2 > 0 else 1.0)
                    u = min(max(u, 0.0), 1.0)
                    ex, ey = cx - (ax + u * dx), cy - (ay + u * dy)
                    out[t, j, a, k] = math.sqrt(ex * ex + ey * ey) - obs[k, 2]


@kernel
def interval_floors(exact: Array, move: Array, pad: Array, valid: NDArray[np.bool_],
                    out: Array) -> None:
    """Each output interval's cheap bound into ``out`` (T, S - 1) [m]: the least over links
    and discs of the larger of the two samples' clearances ``exact`` (T, S, L, K) less
    ``move`` (T, S - 1), how far a joint can move within the interval's box, and ``pad``
    (T,) for rounding (``_batch_clearance``); inf where ``valid`` (T, S - 1) is false."""
    count, intervals = move.shape
    links, discs = exact.shape[2], exact.shape[3]
    for t in range(count):
        for j in range(intervals):
            if not valid[t, j]:
                out[t, j] = math.inf
                continue
            least = math.inf
            for a in range(links):
                for k in range(discs):
                    least = min(least, max(exact[t, j, a, k], exact[t, j + 1, a, k]))
            out[t, j] = least - move[t, j] - pad[t]


def _batch_clearance(geometry: Geometry, obs: Array, theta: Array, rates: Array,
                     dt: float) -> MotionClearance:
    """``motion_clearance`` of a batch. Each output interval's box of angles (module
    docstring) first gets a cheap lower bound: clearance is 1-Lipschitz in the links' end
    points, and within the box no joint moves farther from its place at either sample than
    sum_a (abs(F_a / M) + l_a) P_a + abs(m_N e_N / M) P_N, P_a = sum_{b <= a} (abs(th_j+1,b -
    th_j,b) / 2 + the box's half width in th_b) (abs(e(psi) - e(psi')) <= abs(psi - psi')), so
    the larger of the two samples' exact clearances less that is a bound. The interval
    geometry (``clearance.link_clearance_bounds``) then examines a trial's intervals in the
    order of their bounds, ``REFINE_ROUND`` at a time, each keeping the larger of its two
    bounds, until the least bound of the trial is one it examined: the least of all intervals'
    bounds is then the interval geometry's, found without examining the intervals far from
    every obstacle (most of them)."""
    exact = np.empty((*theta.shape, len(obs)))  # (T, S, L, K)
    sample_clearances(np.ascontiguousarray(theta, dtype=float), geometry.moments,
                      geometry.length, geometry.shift, obs, np.empty((theta.shape[-1] + 1, 2)),
                      exact)
    sampled, j, link, obstacle = _first_min(exact)
    centres = obs[:, :2]
    a, b = theta[:, :-1], theta[:, 1:]
    step = np.abs(b - a)
    w = RATE_MARGIN * np.maximum(np.maximum(np.abs(rates[:, :-1]), np.abs(rates[:, 1:])),
                                 step / dt)
    mid = 0.5 * (a + b)
    half = 0.5 * w * dt
    valid: NDArray[np.bool_] = np.asarray(np.isfinite(mid).all(axis=-1)
                                          & np.isfinite(half).all(axis=-1))  # (T, S - 1)
    mid = np.where(valid[..., None], mid, 0.0)
    half = np.where(valid[..., None], half, 0.0)
    reach = np.cumsum(0.5 * np.where(valid[..., None], step, 0.0) + half, axis=-1)
    coef = np.abs(geometry.moments) + geometry.length  # (T, N + 1)
    move = (np.einsum("ta,tsa->ts", coef, reach)
            + np.abs(geometry.shift)[:, None] * reach[..., -1])  # (T, S - 1)
    pad = 64.0 * np.finfo(float).eps * (1.0 + np.abs(centres).sum() + coef.sum(axis=-1))
    count, intervals = valid.shape
    least = np.empty((count, intervals))  # (T, S - 1): each interval's bound, cheap first
    interval_floors(exact, move, pad, valid, least)
    examined = np.zeros((count, intervals), dtype=bool)
    at = np.zeros((count, intervals, 2), dtype=np.int64)  # an examined one's link, obstacle
    discs = len(obs)
    while intervals:
        best = np.argmin(least, axis=1)
        rows = np.flatnonzero(np.isfinite(least[np.arange(count), best])
                              & ~examined[np.arange(count), best])
        if not len(rows):
            break
        open_ = np.where(examined[rows], np.inf, least[rows])
        take = min(REFINE_ROUND, intervals)
        chosen = np.argpartition(open_, take - 1, axis=1)[:, :take]
        trial = np.repeat(rows, take)
        which = chosen.ravel()
        keep = np.isfinite(open_[np.repeat(np.arange(len(rows)), take), which])
        trial, which = trial[keep], which[keep]
        boxes = [iv.centred(mid[trial, which, k], half[trial, which, k])
                 for k in range(theta.shape[-1])]
        with np.errstate(invalid="ignore", over="ignore"):
            found = link_clearance_bounds(
                joint_boxes(geometry.moments[trial], geometry.length[trial],
                            geometry.shift[trial], boxes), obs)  # (P, L, K)
        cheap = (np.maximum(exact[trial, which], exact[trial, which + 1])
                 - (move[trial, which] + pad[trial])[:, None, None])
        both = np.maximum(cheap, np.where(np.isnan(found), -np.inf, found)).reshape(
            len(trial), -1)
        where = np.argmin(both, axis=1)
        least[trial, which] = both[np.arange(len(trial)), where]
        at[trial, which, 0], at[trial, which, 1] = np.divmod(where, discs)
        examined[trial, which] = True
    i = np.argmin(least, axis=1) if intervals else np.zeros(count, dtype=np.int64)
    bound = least[np.arange(count), i] if intervals else np.full(count, np.inf)
    has = np.isfinite(bound)
    b_link, b_obstacle = at[np.arange(count), i, 0], at[np.arange(count), i, 1]
    return MotionClearance(
        sampled, np.where(np.isnan(sampled), np.nan, j * dt), link, obstacle,
        np.where(has, bound, np.nan),
        np.stack([np.where(has, i * dt, np.nan), np.where(has, (i + 1) * dt, np.nan)],
                 axis=-1), b_link, b_obstacle)


@dataclass(frozen=True)
class Goal:
    """What a trial was asked to reach.

    Attributes
    ----------
    angles : (N + 1,) or (T, N + 1) the plan's th(T) [rad] (one plan, or one per trial)
    tolerance : ``track.goal_tolerance`` [rad], > 0
    target : (2,) or (T, 2) the task's end-effector target [m], or None (no target)
    target_tolerance : ``task.goal_tolerance`` [m], > 0
    """

    angles: Array
    tolerance: float = GOAL_TOLERANCE
    target: Array | None = None
    target_tolerance: float = TARGET_TOLERANCE


class Judged(NamedTuple):
    """Per trial (T,): outcome words (``OUTCOME_NAMES``), reasons, the signed final angle
    errors (T, N + 1) th(T) - goal [rad] (nan where the trial did not reach T), the end
    effector's final distance from its target [m] (nan: no target, or not at T)."""

    outcome: list[str]
    reason: list[str]
    final_error: Array
    target_error: Array


def judge(status: Sequence[str], status_reason: Sequence[str], final: Array, goal: Goal,
          geometry: Geometry | None = None, clearance: MotionClearance | None = None
          ) -> Judged:
    """The outcome of T trials (module docstring).

    Parameters
    ----------
    status : (T,) status words (``metrics.STATUS_NAMES``); status_reason : their reasons
    final : (T, N + 1) the plant's angles at t = T [rad] (nan where it stopped earlier)
    goal : ``Goal``
    geometry : the plants' links (needed with a target: the end effector at T)
    clearance : the motions' clearance from the task's obstacles (None: no obstacles)
    """
    final = np.asarray(final, dtype=float)
    count = final.shape[0]
    error = final - np.broadcast_to(np.asarray(goal.angles, dtype=float), final.shape)
    distance = np.full(count, math.nan)
    if goal.target is not None:
        if geometry is None:
            raise ValueError("judge: a target needs the plants' geometry")
        reached_at = np.isfinite(final).all(axis=1)
        if reached_at.any():
            ee = end_effectors(geometry.subset(np.flatnonzero(reached_at)), final[reached_at])
            target = np.broadcast_to(np.asarray(goal.target, dtype=float), (count, 2))
            distance[reached_at] = np.hypot(*(ee - target[reached_at]).T)
    words: list[str] = []
    reasons: list[str] = []
    for i in range(count):
        word, reason = _judge_one(str(status[i]), str(status_reason[i] or ""), error[i],
                                  distance[i], goal, clearance, i)
        words.append(word)
        reasons.append(reason)
    return Judged(words, reasons, error, distance)


def _collision(clearance: MotionClearance | None, i: int, resolved: bool) -> str:
    """Why trial i collided ("" if it did not): a sample inside an obstacle, or (a trial
    resolved to the end) a closed-loop bound below zero; a lost trial's bound is not read
    (its rates run away before it stops, and the boxes with them)."""
    if clearance is None:
        return ""
    sampled = float(clearance.sampled[i])
    if sampled < 0.0:
        return (f"link {int(clearance.sampled_link[i])} inside obstacle "
                f"{int(clearance.sampled_obstacle[i])} at t = "
                f"{float(clearance.sampled_time[i]):.6g} s (by {-sampled:.3g} m)")
    bound = float(clearance.bound[i])
    if resolved and bound < 0.0:
        t0, t1 = clearance.bound_time[i]
        return (f"link {int(clearance.bound_link[i])} not shown clear of obstacle "
                f"{int(clearance.bound_obstacle[i])} between t = {t0:.6g} and {t1:.6g} s "
                f"(closed-loop bound {bound:.3g} m; every sample clear, by {sampled:.3g} m "
                "at least)")
    return ""


def _judge_one(status: str, why: str, error: Array, distance: float, goal: Goal,
               clearance: MotionClearance | None, i: int) -> tuple[str, str]:
    if status == "error":
        return "lost", f"error: the trial could not run ({why})" if why else \
            "error: the trial could not run"
    hit = _collision(clearance, i, status in RESOLVED)
    if hit:
        return "collided", hit
    if status not in RESOLVED:
        return "lost", f"{status}: where the robot ended is not known ({why})" if why else \
            f"{status}: where the robot ended is not known"
    off = np.abs(error)
    if not np.isfinite(off).all():  # resolved but no final state: cannot be judged
        return "lost", "no final state at T"
    beyond = [k for k in range(len(off)) if not off[k] <= goal.tolerance]
    parts = [f"th{k} off by {off[k]:.3g} rad" for k in beyond]
    if goal.target is not None and not distance <= goal.target_tolerance:
        parts.append(f"end effector {distance:.3g} m from the target")
    if parts:
        limits = f"track.goal_tolerance {goal.tolerance:g} rad"
        if goal.target is not None:
            limits += f", task.goal_tolerance {goal.target_tolerance:g} m"
        return "missed", f"at T {', '.join(parts)} ({limits})"
    worst = int(np.argmax(off))
    text = f"every angle within {goal.tolerance:g} rad at T (largest: th{worst} off by " \
        f"{off[worst]:.3g} rad)"
    if goal.target is not None:
        text += f"; end effector {distance:.3g} m from the target"
    return "reached", text


def lost_as_infinite(values: ArrayLike) -> Array:
    """A final error per trial (T,) with every trial that has none (nan: it did not reach T:
    lost, or stopped after entering an obstacle) set to +inf: infinitely wrong, as where it
    ended is not known. A median over all trials of these is inf where more than half did
    not reach T."""
    out = np.array(values, dtype=float)
    out[np.isnan(out)] = math.inf
    return out


__all__ = [
    "CLEARANCE_BATCH",
    "GOAL_TOLERANCE",
    "OUTCOME_NAMES",
    "RATE_MARGIN",
    "TARGET_TOLERANCE",
    "Geometry",
    "Goal",
    "Judged",
    "MotionClearance",
    "TrialOutcome",
    "end_effectors",
    "joint_points",
    "judge",
    "lost_as_infinite",
    "motion_clearance",
]
