"""Inverse kinematics of the virtual manipulator: joint angles that put the end effector on a
target, for a given (or free) base attitude.

The end effector is r_E = sum_a v_a e(psi_a) (``kinematics``): with the base attitude th0
fixed, p = r_E* - v_0 e(th0) must be reached by links 1..N of lengths v_1..v_N rooted at the
origin. That set is an annulus (a planar chain reaches every radius between
max(0, 2 max |v_a| - sum |v_a|) and sum |v_a|); a target outside it is refused with its
distance from it, a target within ``BOUNDARY_TOL`` of its edge as on the boundary (the arm
straight or folded back, where the inverse kinematics is singular and no neighbourhood of
the target is reachable).

* N = 2 (``two_link``): closed form, cos th2 = (|p|^2 - v_1^2 - v_2^2) / (2 v_1 v_2),
  th1 = atan2(p) - atan2(v_2 sin th2, v_1 + v_2 cos th2); the two elbow branches are the two
  signs of th2 ("up": sin th2 > 0, "down": sin th2 < 0).
* N >= 3 (``redundant``): an (N - 2)-dimensional family (N - 1 with th0 free). flatcli takes
  the configuration nearest the start in joint space: least sum_a (th_a - th_a(0))^2 subject
  to r_E = r_E* (SLSQP, exact Jacobian dr_E/dth_k = sum_{a >= k} v_a e'(psi_a)).

With th0 free (no ``task.base_attitude``) the same objective chooses th0: for N = 2 a scan of
th0 over th0(0) +- pi and a bounded refinement; for N >= 3 th0 is one more unknown.

Angles are returned as the representative nearest the start (th_a(0) + (-pi, pi]); for N = 2
th1 must stay on the start's side of the singular set sin th1 = 0 (a monotone th1 cannot
cross it, ``flatness``), which can rule out a branch.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.names import ELBOWS, Elbow
from flatcli.core.robots.kinematics import end_effector, virtual_links
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: A target closer than this to the edge of the reachable annulus is "on the boundary" [m].
BOUNDARY_TOL = 1e-6
#: Largest residual |r_E - r_E*| of an accepted inverse kinematics solution [m].
IK_TOL = 1e-12
#: Base attitudes scanned for a free th0 (N = 2), over th0(0) +- pi.
TH0_SCAN = 721


def annulus(robot: RobotParams, first: int = 1) -> tuple[float, float]:
    """(inner, outer) radii [m] reachable by links ``first``..N of the virtual manipulator."""
    v = np.abs(virtual_links(robot)[first:])
    outer = float(v.sum())
    return float(max(0.0, 2.0 * v.max() - outer)), outer


def check_reach(robot: RobotParams, target: ArrayLike, th0: float | None, key: str) -> None:
    """FlatcliError (one line naming ``key``, with how far off) unless ``target`` (2,) [m] is
    reachable strictly inside the annulus for base attitude th0 (None: any)."""
    r = np.asarray(target, dtype=float)
    if th0 is None:
        inner, outer = annulus(robot, 0)
        radius = float(np.hypot(*r))
        where = "for any base attitude"
    else:
        inner, outer = annulus(robot, 1)
        v0 = float(virtual_links(robot)[0])
        radius = float(np.hypot(r[0] - v0 * math.cos(th0), r[1] - v0 * math.sin(th0)))
        where = f"at base attitude {th0:g} rad"
    text = f"[{r[0]:g}, {r[1]:g}] m"
    if radius > outer + BOUNDARY_TOL:
        raise FlatcliError(f"{key}: {text} is unreachable {where}: {radius - outer:.3g} m beyond "
                           f"the reach {outer:.6g} m of the virtual manipulator")
    if radius < inner - BOUNDARY_TOL:
        raise FlatcliError(f"{key}: {text} is unreachable {where}: {inner - radius:.3g} m inside "
                           f"the hole of radius {inner:.6g} m the links cannot fold into")
    edge = min(abs(outer - radius), abs(radius - inner)) if inner > 0 else abs(outer - radius)
    if edge <= BOUNDARY_TOL:
        raise FlatcliError(f"{key}: {text} lies on the workspace boundary {where} ({edge:.3g} m "
                           f"from its edge, within {BOUNDARY_TOL:g} m): the arm would be "
                           "straight or folded, where the inverse kinematics is singular; move "
                           "the target inwards")


def nearest(angle: ArrayLike, reference: ArrayLike) -> Array:
    """The representative angle + 2 pi k nearest ``reference`` [rad]."""
    a = np.asarray(angle, dtype=float)
    ref = np.asarray(reference, dtype=float)
    return np.asarray(ref + np.remainder(a - ref + math.pi, 2.0 * math.pi) - math.pi,
                      dtype=float)


def two_link(robot: RobotParams, target: ArrayLike, th0: ArrayLike) -> tuple[Array, Array]:
    """Both elbow branches of the N = 2 inverse kinematics for base attitudes th0 (...).

    Returns
    -------
    up, down : (..., 3) th0, th1, th2 [rad] with th2 in [0, pi] and [-pi, 0]; nan where the
        target is out of reach at that th0 (no check of the boundary: ``check_reach``)
    """
    v0, v1, v2 = (float(v) for v in virtual_links(robot))
    if v1 == 0.0:
        raise FlatcliError("robot: the virtual link v1 = l1 - F_1 / M is 0: the end effector "
                           "does not depend on th1 (task targets need v1 != 0)")
    r = np.asarray(target, dtype=float)
    t0 = np.asarray(th0, dtype=float)
    c, s = np.cos(t0), np.sin(t0)
    qx, qy = r[0] - v0 * c, r[1] - v0 * s
    px, py = c * qx + s * qy, -s * qx + c * qy  # in the base's frame
    cos2 = (px * px + py * py - v1 * v1 - v2 * v2) / (2.0 * v1 * v2)
    with np.errstate(invalid="ignore"):
        th2 = np.arccos(np.where(np.abs(cos2) <= 1.0, cos2, np.nan))
    out = []
    for branch in (th2, -th2):
        th1 = np.arctan2(py, px) - np.arctan2(v2 * np.sin(branch), v1 + v2 * np.cos(branch))
        out.append(np.stack(np.broadcast_arrays(t0, th1, branch), axis=-1))
    return out[0], out[1]


def _represent(q: Array, reference: Array, singular_side: bool) -> Array:
    """q (..., N + 1) with th1..thN moved to the representatives nearest the reference (th0
    as it is); with ``singular_side``, nan rows where th1 lands across sin th1 = 0 from the
    reference's th1 (another representative cannot help: it lies more than pi away)."""
    out = np.array(q, dtype=float)
    out[..., 1:] = nearest(out[..., 1:], reference[1:])
    if singular_side:
        side = math.floor(float(reference[1]) / math.pi)
        th1 = out[..., 1]
        ok = (th1 > side * math.pi) & (th1 < (side + 1) * math.pi)
        out = np.where(ok[..., None], out, np.nan)
    return out


def _cost(q: Array, reference: Array) -> Array:
    return np.asarray(np.sum((q - reference) ** 2, axis=-1), dtype=float)


def two_link_task(robot: RobotParams, target: ArrayLike, th0: float | None,
                  reference: ArrayLike, elbow: Elbow = "auto", key: str = "task.end_effector"
                  ) -> Array:
    """The configuration (3,) [rad] of the N = 2 robot with its end effector on ``target``
    (2,) [m] and base attitude th0 [rad] (None: free, chosen by least sum (th - th(0))^2),
    on the ``elbow`` branch ("auto": the branch nearer ``reference``), th1 on the reference's
    side of sin th1 = 0.

    Raises
    ------
    FlatcliError naming ``key`` (unreachable, on the boundary, or no branch on the start's
    side of the singular set).
    """
    ref = np.asarray(reference, dtype=float)
    check_reach(robot, target, th0, key)
    if th0 is not None:
        candidates = [_represent(b, ref, True) for b in two_link(robot, target, th0)]
    else:
        candidates = [_free_th0(robot, target, ref, i) for i in (0, 1)]
    names = ("up", "down")
    usable = [i for i in (0, 1) if np.isfinite(candidates[i]).all()
              and (elbow == "auto" or names[i] == elbow)]
    if not usable:
        which = "either branch" if elbow == "auto" else f"elbow \"{elbow}\""
        fixed = "some" if th0 is None else f"{th0:g} rad"
        raise FlatcliError(
            f"{key}: reachable only with th1 across the singular set sin th1 = 0 from the "
            f"start's th1 = {ref[1]:g} rad ({which}, base attitude {fixed}): a flat plan "
            "cannot take th1 there; try task.elbow or another target")
    best = min(usable, key=lambda i: float(_cost(candidates[i], ref)))
    return np.asarray(candidates[best], dtype=float)


def _free_th0(robot: RobotParams, target: ArrayLike, ref: Array, branch: int) -> Array:
    """Branch ``branch`` (0 up, 1 down) at the base attitude that minimises the joint-space
    distance from ``ref``; nan if no th0 gives a usable configuration."""
    from scipy.optimize import minimize_scalar

    grid = float(ref[0]) + np.linspace(-math.pi, math.pi, TH0_SCAN)
    q = _represent(two_link(robot, target, grid)[branch], ref, True)
    cost = np.where(np.isfinite(q).all(axis=1), _cost(q, ref), np.inf)
    k = int(np.argmin(cost))
    if not math.isfinite(float(cost[k])):
        return np.full(3, np.nan)
    step = float(grid[1] - grid[0])

    def f(t0: float) -> float:
        row = _represent(two_link(robot, target, np.array([t0]))[branch], ref, True)[0]
        return float(_cost(row, ref)) if np.isfinite(row).all() else math.inf

    lo, hi = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, len(grid) - 1)])
    found = minimize_scalar(f, bounds=(lo, hi), method="bounded",
                            options={"xatol": 1e-12 * max(1.0, step)})
    t0 = float(found.x) if f(float(found.x)) <= float(cost[k]) else float(grid[k])
    return np.asarray(_represent(two_link(robot, target, np.array([t0]))[branch], ref, True)[0],
                      dtype=float)


def redundant_task(robot: RobotParams, target: ArrayLike, th0: float | None,
                   reference: ArrayLike, key: str = "task.end_effector") -> Array:
    """The configuration (N + 1,) [rad] of an N >= 3 robot nearest ``reference`` in joint
    space with its end effector on ``target`` [m] and base attitude th0 (None: free).

    Raises
    ------
    FlatcliError naming ``key`` if the target is out of reach or on the boundary, or the
    solver does not meet it to ``IK_TOL``.
    """
    from scipy.optimize import minimize

    check_reach(robot, target, th0, key)
    ref = np.asarray(reference, dtype=float)
    r = np.asarray(target, dtype=float)
    v = virtual_links(robot)
    free = th0 is None
    lead = 0 if free else 1

    def full(x: Array) -> Array:
        return np.concatenate([[th0], x]) if not free else x

    def residual(x: Array) -> Array:
        return np.asarray(end_effector(robot, full(x)) - r, dtype=float)

    def jacobian(x: Array) -> Array:
        psi = np.cumsum(full(x))
        dx = -np.cumsum((v * np.sin(psi))[::-1])[::-1]  # d r_Ex / d th_k
        dy = np.cumsum((v * np.cos(psi))[::-1])[::-1]
        return np.vstack([dx, dy])[:, lead:]

    x_ref = ref[lead:]
    best: Array | None = None
    rng = np.random.default_rng(0)  # deterministic restarts
    starts = [x_ref] + [x_ref + rng.normal(0.0, 0.5, x_ref.shape) for _ in range(7)]
    for x0 in starts:
        found = minimize(lambda x: float(np.sum((x - x_ref) ** 2)), x0,
                         jac=lambda x: 2.0 * (x - x_ref), method="SLSQP",
                         constraints=[{"type": "eq", "fun": residual, "jac": jacobian}],
                         options={"maxiter": 500, "ftol": 1e-15})
        x = np.asarray(found.x, dtype=float)
        for _ in range(3):  # polish onto the constraint (Gauss-Newton, least change)
            J = jacobian(x)
            x = x - np.linalg.lstsq(J, residual(x), rcond=None)[0]
        if float(np.hypot(*residual(x))) <= IK_TOL and (
                best is None or np.sum((x - x_ref) ** 2) < np.sum((best - x_ref) ** 2)):
            best = x
    if best is None:
        raise FlatcliError(f"{key}: the inverse kinematics did not converge to within "
                           f"{IK_TOL:g} m from the start configuration")
    q = full(best)
    q[1:] = nearest(q[1:], ref[1:])
    return np.asarray(q, dtype=float)


def task_configuration(robot: RobotParams, target: ArrayLike, th0: float | None,
                       reference: ArrayLike, elbow: Elbow = "auto",
                       key: str = "task.end_effector") -> Array:
    """The configuration (N + 1,) [rad] with its end effector on ``target`` and base attitude
    th0 (None: free): ``two_link_task`` for N = 2, ``redundant_task`` beyond."""
    if robot.n_joints == 2:
        return two_link_task(robot, target, th0, reference, elbow, key)
    if elbow != "auto":
        raise FlatcliError(f"task.elbow: \"{elbow}\" picks a branch of the two-joint robot; a "
                           f"robot of {robot.n_joints} joints is redundant (leave it \"auto\")")
    return redundant_task(robot, target, th0, reference, key)


__all__ = [
    "BOUNDARY_TOL",
    "ELBOWS",
    "IK_TOL",
    "Elbow",
    "annulus",
    "check_reach",
    "nearest",
    "redundant_task",
    "task_configuration",
    "two_link",
    "two_link_task",
]
