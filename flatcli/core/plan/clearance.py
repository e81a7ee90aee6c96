"""Obstacles, clearance and limits held over the whole of [0, T], not at samples.

Obstacles are discs (x, y, radius) [m] in the inertial frame whose origin is the system's
centre of mass; every link, the base included, is the segment between its joints
(``kinematics.joint_positions``: the base O_0 O_1, link k O_k O_k+1). A link clears an
obstacle by the distance from the disc's centre to the segment minus the radius.

``certify`` proves a plan of the paper's robot (N = 2, closed-form flat outputs) meets every
constraint for all t in [0, T], by interval arithmetic and bisection (``intervals``):

1. on a time interval [t_a, t_b] of a polynomial piece, the flat outputs and their
   derivatives are bounded (Taylor at the centre), and carried through the inverse map
   th2 = (B A - r A^2) / (c0 a1 sin y1), r = y2' / y1', th0 = y2 + c0 th2 / A (``flatness``)
   and its time derivative, giving intervals that contain th(t) and th'(t) for every t in it;
   for a rest plan r is the polynomial y2' / y1' (y1' = 6 dth1 s (1 - s) / T divides y2'
   exactly, ``rest``), finite at the ends;
2. the joints' positions follow in interval arithmetic; each link lies in the bounding box of
   its two joints' boxes, and within the larger of the boxes' reaches of the segment between
   their centres, so the distance from a disc's centre to that box, and its distance to that
   segment less the reach, bound the link's clearance from below (the larger of the two is
   taken; the second tends to the true distance as the interval shrinks, the first does not
   for a slanted link); the angles', rates' and margin's intervals bound theirs;
3. an interval whose lower bounds all hold is proven; otherwise the constraints are evaluated
   exactly at its midpoint: a violation there is a counterexample (the plan is refused with
   its time); else the interval is halved. Intervals shorter than ``MIN_WIDTH`` T that are
   still undecided count as violations (the check is conservative: it never accepts what it
   has not proven).

The bounds converge linearly in the interval's width, so a plan that clears by a margin c is
proven after about log2(T L / c) halvings (L a bound on the rates).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import ChainModel, PaperModel
from flatcli.core.plan import intervals as iv
from flatcli.core.plan.intervals import Interval
from flatcli.core.plan.planning import Plan
from flatcli.core.robots.kinematics import joint_positions, mass_moments

Array = NDArray[np.float64]

#: Equal pieces of [0, T] the bisection starts from.
START_PIECES = 64
#: An undecided interval shorter than this fraction of T is a violation (conservative).
MIN_WIDTH = 1e-9
#: Most intervals examined before the check gives up (a violation: not proven).
MAX_INTERVALS = 400_000


@dataclass(frozen=True)
class Constraints:
    """What must hold along a plan for all t in [0, T].

    Attributes
    ----------
    obstacles : (K, 3) discs x, y, radius [m] (K may be 0)
    clearance : least distance of every link from every obstacle's surface [m], >= 0
    angle_limit : (N + 1,) bounds on abs th_a [rad] (inf: none)
    rate_limit : (N,) bounds on abs th_j', j = 1..N [rad/s] (inf: none)
    min_margin : lower bound on the unsigned singularity margin abs(sin y1 y1') [rad/s]
        (0: only its sign is kept; a rest plan's margin is 0 at the ends and is not bounded)
    """

    obstacles: Array
    clearance: float = 0.0
    angle_limit: Array | None = None
    rate_limit: Array | None = None
    min_margin: float = 0.0

    def __post_init__(self) -> None:
        obstacles = np.asarray(self.obstacles, dtype=float).reshape(-1, 3)
        if np.any(obstacles[:, 2] <= 0) or not np.all(np.isfinite(obstacles)):
            raise FlatcliError("task.obstacles: each obstacle is [x, y, radius] with a finite "
                               "radius > 0 [m]")
        if not (self.clearance >= 0 and math.isfinite(self.clearance)):
            raise FlatcliError(f"task.clearance: must be a finite number >= 0 m, got "
                               f"{self.clearance}")
        obstacles.setflags(write=False)
        object.__setattr__(self, "obstacles", obstacles)


@dataclass(frozen=True)
class Certificate:
    """What ``certify`` found.

    Attributes
    ----------
    ok : every constraint proven for all t in [0, T]
    reason : "" when ok, else one clause: what fails and when
    time : the time of the counterexample (or undecided interval) [s]; nan when ok
    lower_bound : a proven lower bound of the least clearance over [0, T] [m] (inf with no
        obstacles; of the intervals examined when not ok)
    intervals : how many intervals were examined
    """

    ok: bool
    reason: str
    time: float
    lower_bound: float
    intervals: int


def segment_distance(points: Array, centre: Array) -> Array:
    """(..., K) distance [m] from each centre (K, 2) to each link's segment: points
    (..., N + 2, 2) the joints; result (..., N + 1, K)."""
    a = points[..., :-1, None, :]
    b = points[..., 1:, None, :]
    c = np.asarray(centre, dtype=float).reshape(-1, 2)
    ab = b - a
    length2 = np.sum(ab * ab, axis=-1)
    u = np.clip(np.sum((c - a) * ab, axis=-1) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    closest = a + u[..., None] * ab
    return np.asarray(np.linalg.norm(c - closest, axis=-1), dtype=float)


def clearances(plan: Plan, obstacles: ArrayLike, theta: Array) -> Array:
    """(..., N + 1, K) each link's distance from each obstacle's surface at angles theta
    (..., N + 1) [m] (negative: inside it)."""
    obs = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    points = joint_positions(plan.robot, theta)
    return np.asarray(segment_distance(points, obs[:, :2]) - obs[:, 2], dtype=float)


def _polys(plan: Plan) -> tuple[Array, Array]:
    """breaks (m + 1,) [s] and local coefficients (m, degree + 1, 2) in s of each piece."""
    return plan.trajectory.piecewise()


def _deriv(c: Array, order: int) -> Array:
    """(n, terms) coefficients in s of the ``order``-th s-derivative of polynomials c (n,
    terms) (a zero row for a constant)."""
    out = c
    for _ in range(order):
        out = out[:, 1:] * np.arange(1, out.shape[1])
    return out if out.shape[1] else np.zeros((c.shape[0], 1))


def _is_rest(plan: Plan, local: Array) -> bool:
    """Whether a plan rests at both ends (``rest.RestPlan``: its rates are 0/0 there)."""
    return getattr(plan, "start", None) is not None and local.shape[1] >= 2


def _bounds(plan: PlanLike, local: Array, width: Array, s_lo: Array, s_hi: Array
            ) -> tuple[list[Interval], list[Interval], Interval]:
    """Intervals of th (N + 1) and th' (N + 1) and of the signed margin over [s_lo, s_hi]
    of pieces of ``width`` [s] with coefficients ``local`` (n, degree + 1, N): the paper's
    closed forms (``PaperModel``) or the chain's maps (``ChainModel``)."""
    if isinstance(plan.model, ChainModel):
        return _chain_bounds(plan.model, local, width, s_lo, s_hi, _is_rest(plan, local))
    return _paper_bounds(plan, local, width, s_lo, s_hi)


def _paper_bounds(plan: PlanLike, local: Array, width: Array, s_lo: Array, s_hi: Array
                  ) -> tuple[list[Interval], list[Interval], Interval]:
    """``_bounds`` of the paper's robot (module docstring)."""
    k = plan.model.coefficients  # type: ignore[attr-defined]
    deg = local.shape[1] - 1
    deriv = _deriv

    def bound(c: Array) -> Interval:
        return iv.poly(c, s_lo, s_hi)

    c1, c2 = local[:, :, 0], local[:, :, 1]
    y1 = bound(c1)
    y2 = bound(c2)
    d1 = bound(deriv(c1, 1)) / width
    d2 = bound(deriv(c2, 1)) / width
    if _is_rest(plan, local):
        # y1_s' = 6 dth1 (s - s^2) divides y2_s' exactly: r is a polynomial in s
        pc, qc = _rest_quotient(c1, c2, deg)
        p_, q_ = bound(pc), bound(qc)
        r = q_ / p_
        r_dot = (bound(deriv(qc, 1)) * p_ - q_ * bound(deriv(pc, 1))) / (p_.square() * width)
    else:
        dd1 = bound(deriv(c1, 2)) / (width * width)
        dd2 = bound(deriv(c2, 2)) / (width * width)
        r = d2 / d1
        r_dot = (dd2 * d1 - d2 * dd1) / d1.square()
    s1, co1 = iv.sin(y1), iv.cos(y1)
    A = k.a0 + k.a1 * co1
    B = k.b0 + k.b1 * co1
    num = B * A - r * A.square()
    den = (k.c0 * k.a1) * s1
    th2 = num / den
    th0 = y2 + k.c0 * th2 / A
    A_dot = (-k.a1) * s1 * d1
    B_dot = (-k.b1) * s1 * d1
    num_dot = B_dot * A + B * A_dot - r_dot * A.square() - 2.0 * r * A * A_dot
    den_dot = (k.c0 * k.a1) * co1 * d1
    th2_dot = (num_dot * den - num * den_dot) / den.square()
    th0_dot = d2 + k.c0 * (th2_dot * A - th2 * A_dot) / A.square()
    return [th0, y1, th2], [th0_dot, d1, th2_dot], s1 * d1


PlanLike = Plan


def _chain_bounds(model: ChainModel, local: Array, width: Array, s_lo: Array, s_hi: Array,
                  rest: bool) -> tuple[list[Interval], list[Interval], Interval]:
    """``_bounds`` of a chain of N joints (``chainflat``): q_j = y_j, u_j = y_j' (j < N),
    and with the weights h_j, grad h_0 (its partials g_k), their slopes and h_0's Hessian
    at q in interval arithmetic (cos and sin of psi_a - psi_b = th_b+1 + ... + th_a),

        th_N = -h_0 (S + y_N' h_0) / (I_N D),   S = sum h_j u_j,   D = sum g_j u_j = h_0',
        th_0 = y_N - I_N th_N / h_0,

    and their exact time derivatives (the quotient rule on th_N with S' = sum (h_j' u_j +
    h_j u_j'), D' = sum (sum_k H_jk u_k) u_j + g_j u_j', h_j' = sum_k (dh_j/dq_k) u_k). For a
    rest plan every y_j' (in s) is divided exactly by s (1 - s) first (``_rest_quotients``:
    u_j = w P_j, y_N' = w R, w = s (1 - s) / width), so th_N, which takes u and y_N' only
    through their ratios, is bounded with P and R and stays finite at the ends. The margin
    is -D / (2 K_10)."""
    n = model.n_joints
    K, inertia = model.K, model.inertia

    def bound(c: Array) -> Interval:
        return iv.poly(c, s_lo, s_hi)

    columns = [local[:, :, j] for j in range(n)]
    y = [bound(c) for c in columns]
    if rest:
        quotients = _rest_quotients(columns)
        ratio = [bound(c) / width for c in quotients]  # P_j [rad/s per unit w], R
        ratio_dot = [bound(_deriv(c, 1)) / (width * width) for c in quotients]
        s_box = Interval(s_lo, s_hi)
        w = s_box * (1.0 - s_box)  # s (1 - s), >= 0 on [0, 1]
    else:
        ratio = [bound(_deriv(c, 1)) / width for c in columns]  # y_j' itself
        ratio_dot = [bound(_deriv(c, 2)) / (width * width) for c in columns]
        w = Interval.point(np.ones_like(s_lo))
    P, R = ratio[: n - 1], ratio[n - 1]
    P_dot, R_dot = ratio_dot[: n - 1], ratio_dot[n - 1]
    u = [w * p for p in P]  # the inner joints' rates
    zero = Interval.point(np.zeros_like(s_lo))
    # psi_a - psi_b = th_b+1 + ... + th_a for a > b (th_N enters nothing: K_aN = 0), summed
    # directly (a difference of two sums would count th_1..th_b twice in its width)
    angle = {}
    for a in range(1, n):
        for b in range(a):
            total = y[b]
            for k in range(b + 2, a + 1):
                total = total + y[k - 1]
            angle[(a, b)] = total
    cos = {pair: iv.cos(value) for pair, value in angle.items()}
    sin = {pair: iv.sin(value) for pair, value in angle.items()}

    def crossing(a: int, b: int, k: int) -> bool:  # th_k in psi_a - psi_b (a > b)
        return b < k <= a

    # h_j = sum_{b >= j} (I_b + K_bb + sum_{a != b} K_ab cos(psi_a - psi_b)), j = 0..N - 1
    columns_c = []
    for b in range(n + 1):
        c = Interval.point(np.full_like(s_lo, float(inertia[b] + K[b, b])))
        for a in range(n):
            if a != b and b < n and K[a, b] != 0.0:
                c = c + float(K[a, b]) * cos[(max(a, b), min(a, b))]
        columns_c.append(c)
    h = [columns_c[n]]
    for b in range(n - 1, -1, -1):
        h.insert(0, h[0] + columns_c[b])
    h0 = h[0]
    # g_k = dh_0/dth_k = -2 sum_{a > b, b < k <= a} K_ab sin(psi_a - psi_b), k = 1..N - 1
    g = []
    for k in range(1, n):
        acc = zero
        for (a, b), sn in sin.items():
            if crossing(a, b, k) and K[a, b] != 0.0:
                acc = acc + (-2.0 * float(K[a, b])) * sn
        g.append(acc)
    # dh_j/dth_k = -sum_{b >= j} sum_{a != b} K_ab sin(psi_a - psi_b) dd(psi_a - psi_b)/dth_k
    slopes = []
    for j in range(n):
        row = []
        for k in range(1, n):
            acc = zero
            for b in range(j, n):
                for a in range(n):
                    if a == b or K[a, b] == 0.0:
                        continue
                    hi, lo = max(a, b), min(a, b)
                    if not crossing(hi, lo, k):
                        continue
                    # d/dth_k cos(psi_a - psi_b) = -sin(psi_a - psi_b) (+1 for a > b, -1
                    # for a < b) = -sin(psi_hi - psi_lo) either way
                    acc = acc + (-float(K[a, b])) * sin[(hi, lo)]
            row.append(acc)
        slopes.append(row)
    # H_kl = d^2 h_0 / dth_k dth_l = -2 sum_{a > b, b < k, l <= a} K_ab cos(psi_a - psi_b)
    hess = [[zero] * (n - 1) for _ in range(n - 1)]
    for k in range(1, n):
        for m in range(k, n):
            acc = zero
            for (a, b), cs in cos.items():
                if crossing(a, b, k) and crossing(a, b, m) and K[a, b] != 0.0:
                    acc = acc + (-2.0 * float(K[a, b])) * cs
            hess[k - 1][m - 1] = hess[m - 1][k - 1] = acc

    def dot(xs: list[Interval], ys: list[Interval]) -> Interval:
        acc = zero
        for x_, y_ in zip(xs, ys, strict=True):
            acc = acc + x_ * y_
        return acc

    i_n = float(inertia[n])
    S_hat = dot(h[1:n], P)  # S / w
    D_hat = dot(g, P)  # D / w
    num = -1.0 * h0 * (S_hat + R * h0)
    den = i_n * D_hat
    th_n = num / den
    th0 = y[n - 1] - i_n * th_n / h0
    D = w * D_hat
    # time derivatives along the plan
    h_dot = [dot(row, u) for row in slopes]  # dh_j/dt, j = 0..N - 1 (h_0' = D)
    g_dot = [dot(hess[k], u) for k in range(n - 1)]
    S_hat_dot = dot(h_dot[1:n], P) + dot(h[1:n], P_dot)
    D_hat_dot = dot(g_dot, P) + dot(g, P_dot)
    num_dot = -1.0 * D * (S_hat + R * h0) - h0 * (S_hat_dot + R_dot * h0 + R * D)
    den_dot = i_n * D_hat_dot
    th_n_dot = (num_dot * den - num * den_dot) / den.square()
    th0_dot = w * R - i_n * (th_n_dot * h0 - th_n * D) / h0.square()
    theta = [th0, *y[: n - 1], th_n]
    rates = [th0_dot, *u, th_n_dot]
    margin = D * (-1.0 / (2.0 * float(K[1, 0])))
    return theta, rates, margin


def _rest_quotients(columns: list[Array]) -> list[Array]:
    """(n, degree + 1) each: every y_j_s' / (s - s^2) of rest pieces (they vanish at s = 0
    and 1), zero-padded; divided once per distinct row."""
    deg = columns[0].shape[1] - 1
    out = [np.zeros((len(c), deg + 1)) for c in columns]
    cache: dict[bytes, list[Array]] = {}
    factor = np.array([0.0, 1.0, -1.0])
    for i in range(len(columns[0])):
        key = b"".join(c[i].tobytes() for c in columns)
        if key not in cache:
            rows = []
            for c in columns:
                d = c[i, 1:] * np.arange(1, deg + 1)
                q = np.atleast_1d(np.polynomial.polynomial.polydiv(d, factor)[0])
                rows.append(np.pad(q, (0, deg + 1 - q.shape[0])))
            cache[key] = rows
        for j, row in enumerate(cache[key]):
            out[j][i] = row
    return out


def _rest_quotient(c1: Array, c2: Array, deg: int) -> tuple[Array, Array]:
    """(n, degree + 1) each: y1_s' / (s - s^2) and y2_s' / (s - s^2) on rest pieces (both
    vanish at s = 0 and 1), zero-padded, so r = y2' / y1' is their ratio, finite at the ends;
    divided once per distinct row."""
    out1 = np.zeros((len(c1), deg + 1))
    out2 = np.zeros((len(c1), deg + 1))
    cache: dict[bytes, tuple[Array, Array]] = {}
    factor = np.array([0.0, 1.0, -1.0])
    for i in range(len(c1)):
        key = c1[i].tobytes() + c2[i].tobytes()
        if key not in cache:
            pair = []
            for c in (c1[i], c2[i]):
                d = c[1:] * np.arange(1, deg + 1)
                q = np.atleast_1d(np.polynomial.polynomial.polydiv(d, factor)[0])
                pair.append(np.pad(q, (0, deg + 1 - q.shape[0])))
            cache[key] = (pair[0], pair[1])
        out1[i], out2[i] = cache[key]
    return out1, out2


def _joint_boxes(plan: Plan, theta: list[Interval]) -> list[tuple[Interval, Interval]]:
    """Boxes (x, y) of each joint O_0 .. O_N+1 from interval angles (module docstring)."""
    robot = plan.robot
    moments = mass_moments(robot) / robot.total_mass
    shift = float(robot.mass[-1] * robot.com_across / robot.total_mass)
    return joint_boxes(moments, np.asarray(robot.length, dtype=float), shift, theta)


def joint_boxes(moments: Array, length: Array, shift: Array | float,
                theta: list[Interval]) -> list[tuple[Interval, Interval]]:
    """Boxes (x, y) that contain each joint O_0 .. O_N+1 [m] (``kinematics.joint_positions``)
    for every angle in the intervals ``theta`` (N + 1 intervals of one shape (...)).

    ``moments`` (..., N + 1) F_a / M [m] and ``length`` (..., N + 1) [m] of the robot (or of
    one robot per element: they broadcast against the intervals' shape along their last
    axis), ``shift`` (...) m_N e_N / M [m] (``kinematics.across_shift``; 0 without a centre
    of mass across the last link). Every operation is rounded outwards (``intervals``)."""
    psi = [theta[0]]
    for a in range(1, len(theta)):
        psi.append(psi[-1] + theta[a])
    e = [(iv.cos(p), iv.sin(p)) for p in psi]
    moments = np.asarray(moments, dtype=float)
    length = np.asarray(length, dtype=float)
    ox = Interval.point(np.zeros_like(theta[0].lo))
    oy = Interval.point(np.zeros_like(theta[0].lo))
    for a, (cx, sx) in enumerate(e):
        ox = ox - cx * moments[..., a]  # (the interval first: numpy's arrays would take it)
        oy = oy - sx * moments[..., a]
    shift = np.asarray(shift, dtype=float)
    if np.any(shift != 0.0):  # O_0 -= shift e_perp(psi_N), e_perp = (-sin, cos)
        cx, sx = e[-1]
        ox = ox + sx * shift
        oy = oy - cx * shift
    joints = [(ox, oy)]
    for a, (cx, sx) in enumerate(e):
        ox = ox + cx * length[..., a]
        oy = oy + sx * length[..., a]
        joints.append((ox, oy))
    return joints


def link_clearance_bounds(joints: list[tuple[Interval, Interval]], obstacles: Array) -> Array:
    """(..., N + 1, K) lower bounds of each link's distance from each obstacle's surface [m]
    over boxes of its joints (``joint_boxes``; link a the segment O_a O_a+1, obstacles (K, 3)
    discs x, y, radius): the larger of the distance from the disc's centre to the link's
    bounding box and to the segment between its joints' boxes' centres less their reach
    (module docstring, step 2), less the radius."""
    out = []
    for near, far in itertools.pairwise(joints):
        box = (near[0].hull(far[0]), near[1].hull(far[1]))  # the link lies in it
        per = []
        for x, y, radius in np.asarray(obstacles, dtype=float).reshape(-1, 3):
            centre = np.array([x, y])
            per.append(np.maximum(_box_distance(box, centre),
                                  _segment_distance_bound(near, far, centre)) - radius)
        out.append(np.stack(per, axis=-1))
    return np.asarray(np.stack(out, axis=-2), dtype=float)


def _box_distance(box: tuple[Interval, Interval], centre: Array) -> Array:
    bx, by = box
    dx = np.maximum(np.maximum(bx.lo - centre[0], centre[0] - bx.hi), 0.0)
    dy = np.maximum(np.maximum(by.lo - centre[1], centre[1] - by.hi), 0.0)
    return np.asarray(np.nextafter(np.hypot(dx, dy), -np.inf), dtype=float)


def _centre_and_reach(box: tuple[Interval, Interval]) -> tuple[Array, Array, Array]:
    """A box's centre (x, y) and the distance from it to the box's farthest corner [m]."""
    bx, by = box
    mx, my = 0.5 * (bx.lo + bx.hi), 0.5 * (by.lo + by.hi)
    reach = np.hypot(np.maximum(bx.hi - mx, mx - bx.lo), np.maximum(by.hi - my, my - by.lo))
    return mx, my, reach


def _segment_distance_bound(a: tuple[Interval, Interval], b: tuple[Interval, Interval],
                            centre: Array) -> Array:
    """A lower bound of the distance from ``centre`` to every segment whose ends lie in the
    boxes a and b [m]: the distance to the segment between the boxes' centres less the larger
    of their reaches (each point (1 - u) p + u q of such a segment is within (1 - u) r_a +
    u r_b of the centres' segment's), less a pad for rounding. It tends to the true distance
    as the boxes shrink, where the distance to the segment's bounding box does not (a disc
    beside a slanted link, inside its box)."""
    ax, ay, ra = _centre_and_reach(a)
    bx, by, rb = _centre_and_reach(b)
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    u = np.clip(((centre[0] - ax) * dx + (centre[1] - ay) * dy)
                / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    gap = np.hypot(centre[0] - (ax + u * dx), centre[1] - (ay + u * dy))
    scale = 1.0 + abs(float(centre[0])) + abs(float(centre[1])) + np.maximum(
        np.maximum(np.abs(ax), np.abs(ay)), np.maximum(np.abs(bx), np.abs(by)))
    pad = 64.0 * np.finfo(float).eps * (scale + ra + rb)
    return np.asarray(gap - np.maximum(ra, rb) - pad, dtype=float)


def _slack(plan: Plan, constraints: Constraints, theta: list[Interval],
           rates: list[Interval], margin: Interval) -> tuple[Array, Array]:
    """(n,) the least lower bound over every constraint (>= 0: all proven) and (n,) the
    least clearance bound [m] (inf without obstacles)."""
    n = len(theta[0].lo)
    worst = np.full(n, np.inf)
    clear = np.full(n, np.inf)
    if len(constraints.obstacles):
        bounds = link_clearance_bounds(_joint_boxes(plan, theta), constraints.obstacles)
        clear = np.minimum(clear, bounds.min(axis=(-2, -1)))
        worst = np.minimum(worst, clear - constraints.clearance)
    if constraints.angle_limit is not None:
        for a, th in enumerate(theta):
            lim = float(constraints.angle_limit[a])
            if math.isfinite(lim):
                worst = np.minimum(worst, lim - th.magnitude())
    if constraints.rate_limit is not None:
        for j in range(1, len(rates)):
            lim = float(constraints.rate_limit[j - 1])
            if math.isfinite(lim):
                worst = np.minimum(worst, lim - rates[j].magnitude())
    if constraints.min_margin > 0:
        worst = np.minimum(worst, margin.mignitude() - constraints.min_margin)
    # an interval with a nan end or lo > hi (empty) bounds nothing: what a constraint reads
    # from one is never proven
    used = list(theta) if (len(constraints.obstacles) or constraints.angle_limit is not None) \
        else []
    if constraints.rate_limit is not None and np.isfinite(constraints.rate_limit).any():
        used += rates[1:]
    if constraints.min_margin > 0:
        used.append(margin)
    broken = np.zeros(n, dtype=bool)
    for x in used:
        broken |= ~(x.lo <= x.hi)  # nan compares false
    worst = np.where(np.isnan(worst) | broken, -np.inf, worst)
    return worst, clear


def _slacks(plan: Plan, constraints: Constraints, theta: Array, theta_dot: Array,
            margin: Array) -> list[tuple[Array, str]]:
    """Each constraint's slack at states theta, theta_dot (..., N + 1) and margin (...)
    (negative: violated), with what it is (for messages): (values (...), text) pairs."""
    out: list[tuple[Array, str]] = []
    if len(constraints.obstacles):
        c = clearances(plan, constraints.obstacles, theta) - constraints.clearance
        for link in range(c.shape[-2]):
            for o in range(c.shape[-1]):
                out.append((c[..., link, o], f"link {link} within task.clearance of obstacle {o}"))
    if constraints.angle_limit is not None:
        for a in range(theta.shape[-1]):
            out.append((float(constraints.angle_limit[a]) - np.abs(theta[..., a]),
                        f"abs th{a} beyond its angle limit"))
    if constraints.rate_limit is not None:
        for j in range(1, theta.shape[-1]):
            out.append((float(constraints.rate_limit[j - 1]) - np.abs(theta_dot[..., j]),
                        f"abs th{j}' beyond its rate limit"))
    if constraints.min_margin > 0:
        out.append((margin - constraints.min_margin, "the margin below its minimum"))
    return out


def point_slack(plan: Plan, constraints: Constraints, t: Array) -> tuple[Array, list[str]]:
    """(n,) the least slack of every constraint at times t (n,) exactly (negative: violated)
    and, per time, what is most violated (for messages)."""
    s = plan.sample(np.asarray(t, dtype=float))
    n = len(s.t)
    worst = np.full(n, np.inf)
    what = [""] * n
    for values, text in _slacks(plan, constraints, s.theta, s.theta_dot, s.margin):
        for i in np.flatnonzero(values < worst):
            what[i] = text
        worst = np.minimum(worst, values)
    worst = np.where(np.isnan(worst), -np.inf, worst)
    return worst, what


def sampled_slack(plans: Sequence[Plan], constraints: Constraints, samples: int) -> Array:
    """(P,) the least slack of every constraint over ``samples`` equally spaced times of
    [0, T] for each of P candidate plans (one class, robot, model, basis and duration:
    ``Plan.states_of``), in one evaluation; negative (or -inf for nan): a violation at a
    sample, so ``certify`` cannot prove that plan."""
    t = plans[0].grid(samples)
    theta, theta_dot, margin = type(plans[0]).states_of(plans, t)
    worst = np.full(len(plans), np.inf)
    for values, _ in _slacks(plans[0], constraints, theta, theta_dot, margin):
        worst = np.minimum(worst, values.reshape(len(plans), -1).min(axis=1))
    return np.asarray(np.where(np.isnan(worst), -np.inf, worst), dtype=float)


def certify(plan: Plan, constraints: Constraints, pieces: int = START_PIECES,
            min_width: float = MIN_WIDTH, max_intervals: int = MAX_INTERVALS) -> Certificate:
    """Prove ``constraints`` hold for all t in [0, T] along ``plan`` (module docstring), or
    find where they fail.

    Raises
    ------
    FlatcliError for a plan the interval bounds do not cover (N >= 3, or a chain model).
    """
    if not isinstance(plan.model, PaperModel | ChainModel):
        raise FlatcliError("task.obstacles: continuous-time checks need the closed-form flat "
                           "outputs (an exact plan of a design without them has none)")
    breaks, local = _polys(plan)
    starts = []
    for i in range(len(breaks) - 1):
        edges = np.linspace(0.0, 1.0, pieces + 1)
        starts += [(i, a, b) for a, b in itertools.pairwise(edges)]
    piece = np.array([p for p, _, _ in starts], dtype=int)
    s_lo = np.array([a for _, a, _ in starts])
    s_hi = np.array([b for _, _, b in starts])
    widths = np.diff(breaks)
    examined = 0
    lower = math.inf
    duration = float(breaks[-1])
    while len(piece):
        examined += len(piece)
        if examined > max_intervals:
            t = float(breaks[piece[0]] + widths[piece[0]] * s_lo[0])
            return Certificate(False, f"not proven within {max_intervals} intervals (near "
                               f"t = {t:.4g} s)", t, lower, examined)
        # an interval through a zero of a divisor is unbounded (inf, and nan from inf - inf
        # or 0 * inf): never proven (_slack), so numpy's warnings about it are noise
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            theta, rates, margin = _bounds(plan, local[piece], widths[piece], s_lo, s_hi)
            slack, clear = _slack(plan, constraints, theta, rates, margin)
        open_ = slack < 0
        if (~open_).any():
            lower = min(lower, float(np.min(clear[~open_])))
        if not open_.any():
            break
        piece, s_lo, s_hi = piece[open_], s_lo[open_], s_hi[open_]
        mid = 0.5 * (s_lo + s_hi)
        t_mid = breaks[piece] + widths[piece] * mid
        exact, what = point_slack(plan, constraints, t_mid)
        if np.any(exact < 0):
            i = int(np.argmin(np.where(exact < 0, t_mid, np.inf)))
            return Certificate(False, f"{what[i]} at t = {t_mid[i]:.6g} s (by "
                               f"{-exact[i]:.3g})", float(t_mid[i]), lower, examined)
        narrow = (s_hi - s_lo) * widths[piece] < min_width * duration
        if narrow.any():
            i = int(np.argmax(narrow))
            return Certificate(False, f"undecided within {min_width:g} T of t = "
                               f"{t_mid[i]:.6g} s (a touch, or the bounds too loose)",
                               float(t_mid[i]), lower, examined)
        piece = np.repeat(piece, 2)
        s_lo, s_hi = (np.column_stack([s_lo, mid]).ravel(),
                      np.column_stack([mid, s_hi]).ravel())
    return Certificate(True, "", math.nan, lower, examined)


__all__ = [
    "Certificate",
    "Constraints",
    "certify",
    "clearances",
    "joint_boxes",
    "link_clearance_bounds",
    "point_slack",
    "sampled_slack",
    "segment_distance",
]
