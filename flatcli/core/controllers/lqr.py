"""A feedback for the robot as built: time-varying LQR of the driftless system about a plan.

With H = 0 the robot is the driftless system (``exact``)

    th' = G(q) w,   G = [g_0(q)^T; I_N],   g_0 = -(h_1 .. h_N) / h_0,   w = (th_1' .. th_N'),

whose state is the N + 1 angles and whose inputs are the joint rates. About a plan
(th_r(t), w_r(t)) the errors e = th - th_r, v = w - w_r obey, to first order,

    e' = A(t) e + B(t) v,   A = d(G w)/dth at the plan (only its row 0 is non-zero: the
    base's rate, through dg_0/dq_k; nothing depends on th0),   B = G(q_r).

The law minimises the integral of e^T Q e + v^T R v over [0, T] plus e(T)^T P_T e(T), with
Q = diag(q_0, 1, .., 1) [1/(rad^2 s)] (q_0 = ``track.lqr_base``: the base angle's error
against a joint's), R = I / b^2 [s/rad^2 per (rad/s)^2] (b = ``track.lqr_bandwidth``
[rad/s]: for a joint alone, the bandwidth of its error decay) and P_T = t_f Q
(t_f = ``track.lqr_terminal`` [s]: the final error weighs as t_f seconds of running error).

How the defaults are chosen (``LqrWeights.resolved``; docs/physics.md, "The as-built law's
weights"). A and B are ratios of the momentum weights (g_0 = -h / h_0) and the plan's rates,
so the masses, inertias and the scale of the lengths cancel: the robot's size needs no
normalising. What sets the problem's scale is the plan's duration T: in the time
tau = t / T every rate scales by T and the cost above by T, so the design is the same for
every T exactly when b T and t_f / T are. The defaults are therefore b = 10 / T
(``DEFAULT_BANDWIDTH_PERIODS``) and t_f = 5e5 T (``DEFAULT_TERMINAL_PERIODS``), q_0 = 10: at the
paper's T = 2 s the weights chosen on the goal study of issue 22 (d2 = 3 mm, the Monte Carlo
study's initial errors; docs/asbuilt.md), trying b in 2..20, q_0 in 1..1000 and t_f in
1e3..1e7: on 400 trials per cell they leave median final errors of 1.2e-6 and 2.1e-5 rad from
errors of std 0.01 and 0.05 rad, every trial verified. An explicit ``track.lqr_bandwidth`` or
``track.lqr_terminal`` is used as given. What the weights cannot change is how strongly the
plan's motion couples the joints to the base at first order (the law's linearisation
corrects a base error only through it): on random designs (tests/test_lqr.py) the median
final error stays below 1e-4 rad, but on designs where that coupling is weak some trials
swing far from the plan and fail near T, where the gains grow large (docs/physics.md). The
Riccati equation

    -P' = A^T P + P A - P B R^-1 B^T P + Q,   P(T) = P_T,

is integrated backwards by scipy (DOP853, rtol ``RICCATI_RTOL``) and the gains
L(t) = R^-1 B^T P (N, N + 1) [1/s] sampled at the Chebyshev nodes of every piece of the plan
and fitted (``pieces``), so the compiled loop evaluates them at any time like the plan itself:

    w = w_r(t) - L(t) (th_measured - th_r(t)).

The law has no integrator, so a rate limit (which clips w) or a torque limit (which slows the
servo that follows it) cannot wind anything up. It is designed on the controller's model of
the robot (``[robot]``: the design as built, counterweight where it was measured) and tracks
any plan: an exact one, or a flat one of a closed-form design (sampled and fitted).

``tracked`` returns what the compiled loop reads from the plan's flag at each instant: the
channels (th_1 .. th_N, th0, L_10 .. L_1N, ..., L_N0 .. L_NN) with their first and second
derivatives (``TrackedLayout``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core.curves.pieces import PiecewiseCurves, fit, joined, node_times
from flatcli.core.errors import FlatcliError
from flatcli.core.names import (
    DEFAULT_BANDWIDTH,
    DEFAULT_BANDWIDTH_PERIODS,
    DEFAULT_BASE,
    DEFAULT_TERMINAL,
    DEFAULT_TERMINAL_PERIODS,
)
from flatcli.core.plan.exact import CURVE_DEGREE, Constraint, constraint_of, plan_pieces, rate_terms
from flatcli.core.plan.planning import Plan

Array = NDArray[np.float64]

DEFAULT_JOINT = 1.0
DEFAULT_RATE = 1e-3
#: Times the last piece of the plan is halved towards T for the gains (``graded``).
END_LEVELS = 14
#: Relative and absolute tolerance of the backward Riccati integration.
RICCATI_RTOL = 1e-9
RICCATI_ATOL = 1e-12


@dataclass(frozen=True)
class TrackedLayout:
    """Where the compiled loop finds each quantity in the tracked flag (3 C,) of N joints:
    values, first and second derivatives of C channels, the N + 1 angles (th_1 .. th_N, th0)
    then the gains L (N, width) row-major; width = N + 1 (the kinematic plant's errors: the
    angles) or 2 N + 1 (the dynamic plant's: the angles and the joint rates)."""

    n: int
    width: int

    @property
    def channels(self) -> int:
        return self.n + 1 + self.n * self.width

    @property
    def size(self) -> int:
        return 3 * self.channels


def graded(breaks: Array, levels: int = END_LEVELS) -> Array:
    """``breaks`` [s] with the last piece halved towards T ``levels`` times: the gains of a
    large terminal weight grow like 1 / (T - t) there, which one polynomial cannot follow."""
    edges = np.asarray(breaks, dtype=float)
    start, end = float(edges[-2]), float(edges[-1])
    extra = end - (end - start) * 0.5 ** np.arange(1, levels + 1)
    return np.concatenate([edges[:-1], extra, [end]])


def reference_channels(plan: Plan) -> PiecewiseCurves:
    """The plan's angles as the channels (th_1 .. th_N, th0), piecewise polynomials on the
    ``graded`` pieces of ``plan_pieces``: an exact plan's own curves re-expressed there (to
    rounding: they are polynomials of ``CURVE_DEGREE`` on the plan's pieces), or a flat plan's
    angles sampled at the Chebyshev nodes and fitted."""
    trajectory = plan.trajectory
    if plan.model.kind == "exact":
        edges = graded(trajectory.basis.breakpoints)
        times = node_times(edges, CURVE_DEGREE)
        values = trajectory.derivative(times.ravel(), 0)
        return fit(edges, CURVE_DEGREE, values.reshape(*times.shape, -1))
    edges = graded(plan_pieces(trajectory.basis))
    times = node_times(edges, CURVE_DEGREE)
    theta = plan.sample(times.ravel()).theta  # (m (D + 1), N + 1)
    channels = np.concatenate([theta[:, 1:], theta[:, :1]], axis=1)
    if not np.all(np.isfinite(channels)):
        raise FlatcliError("track.controller: the plan's angles are not finite on its grid")
    return fit(edges, CURVE_DEGREE, channels.reshape(*times.shape, -1))


def linearisation(constraint: Constraint, q: Array, w: Array, servo: float | None = None
                  ) -> tuple[Array, Array]:
    """A (n, S, S) and B (n, S, N) of the driftless system at joint angles q (n, N) [rad] and
    rates w (n, N) [rad/s] (module docstring): S = N + 1 the angles; with a ``servo``
    bandwidth [rad/s], S = 2 N + 1, the joints' rates as states following the command as the
    first-order lag w_j' = servo (r_j - w_j) (the dynamic plant's servo, exactly when its
    model is right and no torque is clipped), the command r its input."""
    h, slopes = constraint.terms(q)
    _, Fq, Fw, _ = rate_terms(h, slopes, w)
    count, n = q.shape
    eye = np.eye(n)
    if servo is None:
        A = np.zeros((count, n + 1, n + 1))
        A[:, 0, 1:] = Fq
        B = np.zeros((count, n + 1, n))
        B[:, 0, :] = Fw
        B[:, 1:, :] = eye
        return A, B
    size = 2 * n + 1
    A = np.zeros((count, size, size))
    A[:, 0, 1:n + 1] = Fq
    A[:, 0, n + 1:] = Fw
    A[:, 1:n + 1, n + 1:] = eye
    A[:, n + 1:, n + 1:] = -servo * eye
    B = np.zeros((count, size, n))
    B[:, n + 1:, :] = servo * eye
    return A, B


@dataclass(frozen=True)
class LqrWeights:
    """The as-built law's weights (module docstring): ``bandwidth`` b [rad/s] (R = I / b^2),
    ``base`` q_0 and ``joint`` q_j on the angle errors (Q = diag(q_0, q_j, .., q_j)),
    ``terminal`` t_f [s] (P_T = t_f Q), and ``rate`` on the joint-rate errors when the servo's
    lag is a state (the dynamic plant). ``bandwidth`` and ``terminal`` None: from the plan's
    duration (``resolved``)."""

    bandwidth: float | None = None
    terminal: float | None = None
    base: float = DEFAULT_BASE
    joint: float = DEFAULT_JOINT
    rate: float = DEFAULT_RATE

    def __post_init__(self) -> None:
        for name, key in (("bandwidth", "track.lqr_bandwidth"),
                          ("terminal", "track.lqr_terminal"), ("base", "track.lqr_base")):
            value = getattr(self, name)
            if value is None and name != "base":
                continue
            if not (value > 0 and math.isfinite(value)):
                raise FlatcliError(f"{key}: must be a finite number > 0, got {value}")
        for name in ("joint", "rate"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise FlatcliError(f"{name} weight: must be a finite number >= 0, got {value}")

    def resolved(self, duration: float) -> LqrWeights:
        """These weights for a plan of ``duration`` T [s]: b = ``DEFAULT_BANDWIDTH_PERIODS`` / T
        and t_f = ``DEFAULT_TERMINAL_PERIODS`` T where not given (module docstring)."""
        bandwidth = (DEFAULT_BANDWIDTH_PERIODS / duration if self.bandwidth is None
                     else self.bandwidth)
        terminal = DEFAULT_TERMINAL_PERIODS * duration if self.terminal is None else self.terminal
        return LqrWeights(bandwidth, terminal, self.base, self.joint, self.rate)

    @property
    def b(self) -> float:
        """The bandwidth [rad/s] of resolved weights."""
        if self.bandwidth is None:
            raise ValueError("LqrWeights: resolve the weights for a plan first")
        return self.bandwidth

    @property
    def t_f(self) -> float:
        """The terminal weight [s] of resolved weights."""
        if self.terminal is None:
            raise ValueError("LqrWeights: resolve the weights for a plan first")
        return self.terminal

    def running(self, n: int, lagged: bool) -> Array:
        """Q (S, S): the angles' [1/(rad^2 s)], then (lagged) the joint rates' [s/rad^2]."""
        return np.diag([self.base] + [self.joint] * n + ([self.rate] * n if lagged else []))


def riccati(constraint: Constraint, reference: PiecewiseCurves,
            weights: LqrWeights = LqrWeights(), servo: float | None = None) -> Any:
    """The Riccati solution P(t) (S, S) about the reference (module docstring), as scipy's
    dense output in s = T - t (``riccati_gains``; ``servo``: see ``linearisation``).

    Raises
    ------
    FlatcliError if the integration fails (it does not for a finite plan).
    """
    from scipy.integrate import solve_ivp

    n = constraint.n_joints
    duration = reference.basis.duration
    weights = weights.resolved(duration)
    Q = weights.running(n, servo is not None)
    size = Q.shape[0]
    r_inv = weights.b**2  # R^-1 = b^2 I

    def rhs(s: float, p: Array) -> Array:
        t = np.array([duration - s])
        A, B = linearisation(constraint, reference.derivative(t, 0)[:, :n],
                             reference.derivative(t, 1)[:, :n], servo)
        P = p.reshape(size, size)
        PB = P @ B[0]
        dP = A[0].T @ P + P @ A[0] - r_inv * PB @ PB.T + Q
        return np.asarray(0.5 * (dP + dP.T)).ravel()

    final = Q * weights.t_f
    sol = solve_ivp(rhs, (0.0, duration), final.ravel(), method="DOP853",
                    rtol=RICCATI_RTOL, atol=RICCATI_ATOL, dense_output=True)
    if not sol.success or sol.sol is None:
        raise FlatcliError(f"track.lqr_bandwidth, track.lqr_terminal: the Riccati equation "
                           f"could not be integrated ({sol.message}); lower track.lqr_bandwidth "
                           f"({weights.b:g} rad/s) or track.lqr_terminal "
                           f"({weights.t_f:g} s)")
    return sol.sol


def riccati_gains(constraint: Constraint, reference: PiecewiseCurves,
                  weights: LqrWeights = LqrWeights(), servo: float | None = None
                  ) -> PiecewiseCurves:
    """The gains L(t) = R^-1 B^T P (N S channels, row-major: joint j, then the S error
    components) on the reference's pieces (module docstring; ``servo``: see
    ``linearisation``)."""
    n = constraint.n_joints
    size = 2 * n + 1 if servo is not None else n + 1
    solution = riccati(constraint, reference, weights, servo)
    duration = reference.basis.duration
    weights = weights.resolved(duration)
    edges = reference.basis.breakpoints
    times = node_times(edges, CURVE_DEGREE)
    flat = times.ravel()
    P = solution(duration - flat).T.reshape(-1, size, size)
    _, B = linearisation(constraint, reference.derivative(flat, 0)[:, :n],
                         reference.derivative(flat, 1)[:, :n], servo)
    L = weights.b**2 * np.swapaxes(B, 1, 2) @ P  # (count, N, S)
    return fit(edges, CURVE_DEGREE, L.reshape(*times.shape, n * size))


#: The last designs (``tracked``), by (the plan object, weights, servo): a sweep's cells that
#: share a plan (``montecarlo.layout`` plans each robot and maneuver once) share its design, whose
#: Riccati integration costs 0.5-0.8 s; each entry keeps its plan, so an id is never reused.
_DESIGNS: dict[tuple[int, LqrWeights, float | None], tuple[Plan, PiecewiseCurves]] = {}
DESIGN_CACHE = 16


def tracked(plan: Plan, weights: LqrWeights = LqrWeights(), servo: float | None = None
            ) -> PiecewiseCurves:
    """The channels the as-built loop tracks (``TrackedLayout``): the plan's angles and the
    gains designed on the plan's robot (the controller's model), with the servo's lag of
    bandwidth ``servo`` [rad/s] for the dynamic plant (None: the kinematic plant); designed
    once per plan object, weights and servo (``_DESIGNS``)."""
    key = (id(plan), weights, servo)
    hit = _DESIGNS.get(key)
    if hit is not None and hit[0] is plan:
        return hit[1]
    reference = reference_channels(plan)
    gains = riccati_gains(constraint_of(plan.robot), reference, weights, servo)
    curves = joined([reference, gains])
    curves.coefficients.setflags(write=False)  # shared between the cells that use it
    if len(_DESIGNS) >= DESIGN_CACHE:
        del _DESIGNS[next(iter(_DESIGNS))]  # the oldest
    _DESIGNS[key] = (plan, curves)
    return curves


__all__ = ["DEFAULT_BANDWIDTH", "DEFAULT_BANDWIDTH_PERIODS", "DEFAULT_BASE", "DEFAULT_JOINT",
           "DEFAULT_RATE", "DEFAULT_TERMINAL", "DEFAULT_TERMINAL_PERIODS", "LqrWeights",
           "TrackedLayout", "linearisation", "reference_channels",
           "riccati", "riccati_gains", "tracked"]
