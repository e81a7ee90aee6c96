"""Model predictive control on the flat outputs: the least correction to the linearising
feedback that keeps the actuators' limits and the singularity margin and reaches the goal.

Between samples the controller is the flat law (``control``) plus a held correction dv:

    v_j(t) = y_jd''(t) + kv_j (y_jd' - y_j') + kp_j (y_jd - y_j) + dv_j,     t in [t_k, t_k+1)

so that, with the right model, each flat output's error e_j = y_j - y_jd obeys
e_j'' = -kp_j e_j - kv_j e_j' + dv_j exactly: a linear system, discretised here exactly over a
sample (zero-order hold on dv; ``discretise``). At each sample t_k (every ``every`` output
steps) it solves, over the next H samples (the horizon),

    minimise   sum_i  q_p |e_i|^2 + q_v |e_i'|^2 + r |dv_i|^2  (+ the slack's penalty)
    subject to |th_l'| <= R (1 - backoff)     at the start and end of every sample interval
               sign(sigma_d) sigma >= min(m, |sigma_d| / 2)          at every sample
               e(T) = 0, e'(T) = 0            where T is within the horizon

a QP in dv (``qp``): the joint rates th' and the signed margin sigma are functions of the flat
flag (``FlatModel.flag_values``), linearised about the plan at each sample (their exact
derivatives by complex step: ``FlatModel.flag_jacobian``), with the applied flag
y'' = y_d'' - kp e - kv e' + dv. The inequalities are soft: one slack s >= 0, added to each,
costs ``SLACK_QUADRATIC`` s^2 / 2 + ``SLACK_LINEAR`` s, so a state from which the limits
cannot all be kept still gets the correction that violates them least; the terminal
equalities are hard (with two samples or more to go they can always be met; in the last
sample the correction planned one sample earlier is held). The default weights are
q_p = q_v = 0 and r = 1: the least-norm correction, so that where no limit is near and the
goal is beyond the horizon, dv = 0 and the controller is the paper's law.

What it guarantees and what it does not: the limits hold at the samples of the prediction
made with the controller's model and the linearisation, not between samples nor for a plant
that differs from the model; recursive feasibility is not guaranteed (the slack takes what
cannot be met, and a trial counts the samples where it had to: ``qp_infeasible``).

``design`` (numpy, once per plan) tabulates everything a sample needs; ``sample_step``
(compiled into the closed loop, allocating nothing) builds and solves one QP.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from flatcli.core import qp
from flatcli.core._jit import jitable
from flatcli.core.model import FlatcliError

Array = NDArray[np.float64]

#: The slack's penalty: s^2 / 2 times this plus s times ``SLACK_LINEAR``.
SLACK_QUADRATIC = 1e4
SLACK_LINEAR = 1e6
#: A sample whose slack exceeds this [the constraints' units: rad/s] counts as infeasible.
SLACK_TOLERANCE = 1e-9
#: Active-set iterations per QP at most, per variable and constraint.
ITERATIONS_PER_ROW = 3


@dataclass(frozen=True)
class MpcSettings:
    """The MPC's settings (spec ``[track]``, ``track.mpc_*``).

    every : a sample every this many output steps (sample time = every * track.dt)
    horizon : samples predicted, H >= 2
    weight_position, weight_rate : q_p [1/rad^2], q_v [s^2/rad^2] on the flat outputs'
        errors e, e' at each predicted sample
    weight_input : r [s^4/rad^2] on the correction dv (> 0)
    margin : the singularity margin kept, m [rad/s] (0: none)
    backoff : the joint-rate limit is kept at R (1 - backoff)
    """

    every: int = 10
    horizon: int = 20
    weight_position: float = 0.0
    weight_rate: float = 0.0
    weight_input: float = 1.0
    margin: float = 0.05
    backoff: float = 0.01

    def __post_init__(self) -> None:
        if not (isinstance(self.every, int) and self.every >= 1):
            raise FlatcliError(f"track.mpc_every: must be an integer >= 1, got {self.every!r}")
        if not (isinstance(self.horizon, int) and 2 <= self.horizon <= 200):
            raise FlatcliError(f"track.mpc_horizon: must be an integer in [2, 200], got "
                               f"{self.horizon!r}")
        for name, value in (("weight_position", self.weight_position),
                            ("weight_rate", self.weight_rate)):
            if not (value >= 0 and math.isfinite(value)):
                raise FlatcliError(f"track.mpc_{name}: must be a finite number >= 0, got "
                                   f"{value}")
        if not (self.weight_input > 0 and math.isfinite(self.weight_input)):
            raise FlatcliError(f"track.mpc_weight_input: must be a finite number > 0, got "
                               f"{self.weight_input}")
        if not (self.margin >= 0 and math.isfinite(self.margin)):
            raise FlatcliError(f"track.mpc_margin: must be a finite number >= 0 rad/s, got "
                               f"{self.margin}")
        if not 0 <= self.backoff < 1:
            raise FlatcliError(f"track.mpc_backoff: must be in [0, 1), got {self.backoff}")


class Design(NamedTuple):
    """What every sample of one plan's MPC reads (``design``); N outputs, H samples ahead,
    K samples in [0, T], n = N H + 1 variables (the corrections dv_0..dv_H-1 output by
    output within each sample, then the slack).

    kp, kv : (N,) the flat law's gains [1/s^2, 1/s]
    phi : (N, H + 1, 2, 2) the error's transition over i samples, per output
    gamma : (N, H, 2) the error's response after i + 1 samples to a unit dv held one sample
    factors : (H, n, n) ``qp.factor`` of the cost's Hessian with L = 1..H samples costed
    gradients : (H, n, 2 N) the cost's gradient per unit initial error (e_j, e_j' in pairs)
    rates : (K + 1, N) the plan's joint rates th1'..thN' at the samples [rad/s]
    rate_slopes : (K + 1, N, 3 N) their derivatives along the flag (y, y', y'')
    sigma : (K + 1,) the plan's signed margin [rad/s]; sigma_slopes : (K + 1, 2 N) along y, y'
    limit : the joint-rate limit kept [rad/s] (inf: none); margin : m [rad/s]
    samples : K; every : output steps per sample
    """

    kp: Array
    kv: Array
    phi: Array
    gamma: Array
    factors: Array
    gradients: Array
    rates: Array
    rate_slopes: Array
    sigma: Array
    sigma_slopes: Array
    limit: float
    margin: float
    samples: int
    every: int


def discretise(kp: float, kv: float, ts: float) -> tuple[Array, Array]:
    """The exact transition (2, 2) and input response (2,) over ts [s] of e'' = -kp e - kv e'
    + dv with dv held (zero-order hold): the matrix exponential of the augmented system."""
    a = np.array([[0.0, 1.0, 0.0], [-kp, -kv, 1.0], [0.0, 0.0, 0.0]])
    m = scipy.linalg.expm(a * ts)
    return np.ascontiguousarray(m[:2, :2]), np.ascontiguousarray(m[:2, 2])


def predictions(kp: Array, kv: Array, ts: float, horizon: int) -> tuple[Array, Array]:
    """phi (N, H + 1, 2, 2) and gamma (N, H, 2) of ``Design``."""
    n = len(kp)
    phi = np.zeros((n, horizon + 1, 2, 2))
    gamma = np.zeros((n, horizon, 2))
    for j in range(n):
        a, b = discretise(float(kp[j]), float(kv[j]), ts)
        power = np.eye(2)
        for i in range(horizon + 1):
            phi[j, i] = power
            if i < horizon:
                gamma[j, i] = power @ b
            power = a @ power
    return phi, gamma


def condensed_cost(phi: Array, gamma: Array, settings: MpcSettings, costed: int
                   ) -> tuple[Array, Array]:
    """The Hessian (n, n) and the gradient per unit initial error (n, 2 N) of the cost over
    the first ``costed`` samples (the corrections after them cost r alone, so they are 0),
    with the slack's quadratic penalty last."""
    n_out, horizon = phi.shape[0], gamma.shape[1]
    size = n_out * horizon + 1
    hessian = np.zeros((size, size))
    gradient = np.zeros((size, 2 * n_out))
    weights = np.diag([settings.weight_position, settings.weight_rate])
    for j in range(n_out):
        cols = [k * n_out + j for k in range(horizon)]
        for i in range(1, costed + 1):  # the error at sample i: phi_i s0 + sum_k<i gamma
            response = np.zeros((2, horizon))
            for k in range(i):
                response[:, k] = gamma[j, i - 1 - k]
            hessian[np.ix_(cols, cols)] += response.T @ weights @ response
            gradient[np.ix_(cols, [2 * j, 2 * j + 1])] += response.T @ weights @ phi[j, i]
    hessian[np.arange(size - 1), np.arange(size - 1)] += settings.weight_input
    hessian[size - 1, size - 1] = SLACK_QUADRATIC
    return hessian, gradient


def design(model: Any, trajectory: Any, duration: float, dt: float, kp: Array, kv: Array,
           rate_limit: float, settings: MpcSettings) -> Design:
    """The MPC of one plan (``Design``): its predictions, cost factors and the plan's joint
    rates and margin with their slopes at every sample.

    Parameters
    ----------
    model : the flat model the controller believes (``flatmodel.FlatModel``)
    trajectory : the plan's flat outputs (``basis.FlatTrajectory``)
    duration : T [s]; dt : the output step [s] (a sample every ``settings.every`` of them)
    kp, kv : (N,) the flat law's gains
    rate_limit : the joint-rate limit [rad/s] (inf: none)

    Raises FlatcliError naming the key if the samples do not divide T.
    """
    steps = round(duration / dt)
    if steps % settings.every:
        raise FlatcliError(f"track.mpc_every: {settings.every} output steps must divide the "
                           f"{steps} of plan.duration / track.dt")
    samples = steps // settings.every
    ts = settings.every * dt
    kp = np.asarray(kp, dtype=float)
    kv = np.asarray(kv, dtype=float)
    phi, gamma = predictions(kp, kv, ts, settings.horizon)
    factors = []
    gradients = []
    for costed in range(1, settings.horizon + 1):
        hessian, gradient = condensed_cost(phi, gamma, settings, costed)
        factors.append(qp.factor(hessian))
        gradients.append(gradient)
    times = np.arange(samples + 1) * ts
    flag = trajectory.flags(times).T  # (3 N, K + 1)
    values, slopes = model.flag_jacobian(flag)
    n = len(kp)
    rates = np.ascontiguousarray(values[n + 1: 2 * n + 1].T)
    rate_slopes = np.ascontiguousarray(np.transpose(slopes[n + 1: 2 * n + 1], (2, 0, 1)))
    sigma = np.ascontiguousarray(values[2 * n + 1])
    sigma_slopes = np.ascontiguousarray(slopes[2 * n + 1, : 2 * n].T)
    limit = rate_limit * (1.0 - settings.backoff) if math.isfinite(rate_limit) else math.inf
    return Design(kp, kv, phi, gamma, np.ascontiguousarray(np.stack(factors)),
                  np.ascontiguousarray(np.stack(gradients)), rates, rate_slopes, sigma,
                  sigma_slopes, float(limit), float(settings.margin), samples,
                  settings.every)


def rows(design: Design) -> int:
    """The QP's constraints at most: 2 N terminal equalities, per sample 2 N two-sided
    joint-rate rows (both ends of its interval) and the margin's, and the slack's own."""
    n = int(design.kp.shape[0])
    horizon = int(design.gamma.shape[1])
    return 2 * n + horizon * (2 * n + 1) + 1


class Scratch(NamedTuple):
    """One trial's MPC state and buffers (``scratch``): the correction held dv (N,), the last
    solution (n,), whether it exists (valid[0]), the QP's rows C (m, n), their bounds lo, hi
    (m,), widths (m,) and softness (m,) (``qp.solve``), its gradient (n,) and solution (n,),
    the initial errors s0 (2 N,), the predicted errors (2 N,), a row (n,), the QP's buffers,
    and counters: QP iterations, infeasible samples, largest slack."""

    held: Array
    last: Array
    valid: Array
    C: Array
    lo: Array
    hi: Array
    width: NDArray[np.int64]
    soft: Array
    g: Array
    x: Array
    s0: Array
    predicted: Array
    row: Array
    work: qp.Work
    counters: Array


def scratch(design: Design) -> Scratch:
    """Fresh buffers for one trial's samples."""
    n_out = design.kp.shape[0]
    size = design.factors.shape[1]
    m = rows(design)
    return Scratch(np.zeros(n_out), np.zeros(size), np.zeros(1), np.zeros((m, size)),
                   np.zeros(m), np.zeros(m), np.zeros(m, dtype=np.int64), np.zeros(m),
                   np.zeros(size), np.zeros(size), np.zeros(2 * n_out),
                   np.zeros(2 * n_out), np.zeros(size), qp.work(size, m), np.zeros(3))


@jitable
def reset(s: Scratch) -> None:
    """A trial starts: no correction held, no solution, counters at 0."""
    s.held[:] = 0.0
    s.valid[0] = 0.0
    s.counters[:] = 0.0


@jitable
def _predicted(d: Design, s: Scratch, j: int, i: int) -> tuple[float, float]:
    """The error (e_j, e_j') at sample i of the horizon from s0 alone (no correction)."""
    e0 = s.s0[2 * j]
    r0 = s.s0[2 * j + 1]
    return (d.phi[j, i, 0, 0] * e0 + d.phi[j, i, 0, 1] * r0,
            d.phi[j, i, 1, 0] * e0 + d.phi[j, i, 1, 1] * r0)


@jitable
def _state_row(d: Design, s: Scratch, a: Array, b: Array, i: int, direct: Array,
               direct_sample: int) -> float:
    """Into s.row: the coefficients on the corrections of sum_j a_j e_j + b_j e_j' at
    sample i (plus ``direct``_j on dv_j of sample ``direct_sample``, none if < 0); returns
    its value from s0 alone."""
    n_out = d.kp.shape[0]
    s.row[:] = 0.0
    value = 0.0
    for j in range(n_out):
        e, r = _predicted(d, s, j, i)
        value += a[j] * e + b[j] * r
        for k in range(i):
            s.row[k * n_out + j] = a[j] * d.gamma[j, i - 1 - k, 0] + b[j] * d.gamma[j, i - 1 - k, 1]
        if direct_sample >= 0:
            s.row[direct_sample * n_out + j] += direct[j]
    return value


@jitable
def _append(s: Scratch, count: int, width: int, lo: float, hi: float, slack: bool) -> int:
    """Row ``count`` of the QP: lo <= s.row[:width] x (+- the slack) <= hi; returns
    count + 1."""
    for c in range(width):
        s.C[count, c] = s.row[c]
    s.lo[count] = lo
    s.hi[count] = hi
    s.width[count] = width
    s.soft[count] = 1.0 if slack else 0.0
    return count + 1


@jitable
def sample_step(d: Design, s: Scratch, k: int, a: Array, b: Array, direct: Array) -> None:
    """The correction for sample k (0..K - 1) into s.held, from the flat outputs' errors
    s.s0 (e_j, e_j' in pairs) measured there; ``a``, ``b``, ``direct`` (N,) scratch."""
    n_out = d.kp.shape[0]
    horizon = d.gamma.shape[1]
    size = s.row.shape[0]
    remaining = d.samples - k
    if remaining <= 1:  # the last sample: hold what was planned for it one sample ago
        for j in range(n_out):
            s.held[j] = s.last[n_out + j] if s.valid[0] != 0.0 else 0.0
        return
    costed = min(horizon, remaining)
    factor = d.factors[costed - 1]
    gradient = d.gradients[costed - 1]
    for c in range(size):
        acc = 0.0
        for q in range(2 * n_out):
            acc += gradient[c, q] * s.s0[q]
        s.g[c] = acc
    s.g[size - 1] += SLACK_LINEAR
    count = 0
    if remaining <= horizon:  # the goal: e(T) = 0, e'(T) = 0
        for j in range(n_out):
            for which in range(2):
                a[:] = 0.0
                b[:] = 0.0
                if which == 0:
                    a[j] = 1.0
                else:
                    b[j] = 1.0
                value = _state_row(d, s, a, b, remaining, direct, -1)
                count = _append(s, count, remaining * n_out, -value, -value, False)
    meq = count
    for i in range(costed):
        t = k + i
        if math.isfinite(d.limit):
            for end in range(2):  # the rates at the interval's start, and at its end
                at = t + end
                state_sample = i + end
                for lj in range(n_out):
                    slopes = d.rate_slopes[at, lj]
                    commanded = False  # does the rate follow dv (else it is a state)
                    for j in range(n_out):
                        direct[j] = slopes[2 * n_out + j]
                        commanded = commanded or direct[j] != 0.0
                        a[j] = slopes[j] - d.kp[j] * direct[j]
                        b[j] = slopes[n_out + j] - d.kv[j] * direct[j]
                    if end == 1 and not commanded and i < costed - 1:
                        continue  # the same row as the next sample's start
                    value = _state_row(d, s, a, b, state_sample, direct, i)
                    rate = d.rates[at, lj] + value
                    count = _append(s, count, (i + 1) * n_out, -d.limit - rate,
                                    d.limit - rate, True)
        sigma = d.sigma[t]
        if d.margin > 0.0 and i > 0 and math.isfinite(sigma):
            sign = 1.0 if sigma > 0.0 else -1.0
            kept = min(d.margin, 0.5 * abs(sigma))
            for j in range(n_out):
                a[j] = d.sigma_slopes[t, j]
                b[j] = d.sigma_slopes[t, n_out + j]
            value = _state_row(d, s, a, b, i, direct, -1)
            for c in range(i * n_out):
                s.row[c] *= sign
            count = _append(s, count, i * n_out, kept - abs(sigma) - sign * value, math.inf,
                            True)
    count = _append(s, count, 0, 0.0, math.inf, True)  # the slack itself: s >= 0
    status, iterations, _ = qp.solve(factor, s.g, s.C, s.lo, s.hi, s.width, s.soft, meq,
                                     count, s.x, s.work, ITERATIONS_PER_ROW * (size + count))
    s.counters[0] += iterations
    if status != qp.OPTIMAL:  # no correction: the flat law alone
        s.counters[1] += 1.0
        s.held[:] = 0.0
        s.valid[0] = 0.0
        return
    slack = s.x[size - 1]
    if slack > SLACK_TOLERANCE:
        s.counters[1] += 1.0
    s.counters[2] = max(s.counters[2], slack)
    for j in range(n_out):
        s.held[j] = s.x[j]
    for c in range(size):
        s.last[c] = s.x[c]
    s.valid[0] = 1.0
