"""Where the links are: positions from the angles alone, with the system's centre of mass
fixed at the origin (Vafa and Dubowsky's virtual manipulator).

With no external force the system's centre of mass is inertially fixed; flatcli puts it at
the origin of the inertial frame. Joint O_k (k = 0..N+1: O_0 the base's proximal end, O_k+1
the far end of link k, O_N+1 the end effector) sits at

    O_k = O_0 + sum_{a<k} l_a e(psi_a),      psi_a = th0 + th1 + ... + th_a,

and the centre of mass, sum_i m_i (O_i + d_i e(psi_i)) / M = 0, fixes the base's position:

    O_0 = -sum_a (F_a / M) e(psi_a),     F_a = sum_i m_i L_ia = m_a d_a + (m_a+1 + ... + m_N) l_a

(L_ia of ``chain.lever_arms``). So every joint is a sum of constant "virtual link" vectors
along the absolute angles; the end effector is

    r_E = sum_a v_a e(psi_a),            v_a = l_a - F_a / M       (``virtual_links``),

a fixed-base manipulator of link lengths v_0..v_N rooted at the origin (v_N = l_N: the last
link carries no mass beyond it). A robot as built whose last link's centre of mass lies
e_N across the link (``RobotParams.com_across``) adds - (m_N e_N / M) e_perp(psi_N) to O_0
and so to every joint and the end effector (e_perp(psi) = (-sin psi, cos psi)).

The base's position reported (``base_x``, ``base_y``) is its
centre of mass C_0 = O_0 + d_0 e(th0). The base drawn and checked against obstacles is its
segment O_0 O_1, link k the segment O_k O_k+1.

Functions take angles theta (..., N + 1) [rad] of any batch shape and return positions in
the inertial frame [m]; they are plain numpy (no I/O).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]


def mass_moments(robot: RobotParams) -> Array:
    """(N + 1,) F_a = sum_i m_i L_ia [kg m]: how far link a's axis carries the system's mass
    (m_a d_a + (m_a+1 + ... + m_N) l_a)."""
    return moments_of(np.asarray(robot.mass, dtype=float), np.asarray(robot.length, dtype=float),
                      np.asarray(robot.com, dtype=float))


def moments_of(mass: Array, length: Array, com: Array) -> Array:
    """``mass_moments`` of robots given by their links' masses [kg], lengths and centres [m],
    each (..., N + 1) (a batch of robots at once)."""
    beyond = np.concatenate([np.cumsum(mass[..., ::-1], axis=-1)[..., ::-1][..., 1:],
                             np.zeros_like(mass[..., :1])], axis=-1)  # m_a+1 + ... + m_N
    return np.asarray(mass * com + beyond * length, dtype=float)


def virtual_links(robot: RobotParams) -> Array:
    """(N + 1,) v_a = l_a - F_a / M [m]: the end effector's virtual manipulator (module
    docstring); signed (v_a < 0 points backwards along link a)."""
    return virtual_links_of(np.asarray(robot.mass, dtype=float),
                            np.asarray(robot.length, dtype=float),
                            np.asarray(robot.com, dtype=float), robot.total_mass)


def virtual_links_of(mass: Array, length: Array, com: Array,
                     total: float | Array | None = None) -> Array:
    """``virtual_links`` of a batch of robots (..., N + 1) [kg], [m], [m] -> (..., N + 1) [m];
    ``total`` their masses M [kg] (default: summed here)."""
    if total is None:
        total = mass.sum(axis=-1, keepdims=True)
    return np.asarray(length - moments_of(mass, length, com) / total, dtype=float)


def absolute_angles(theta: ArrayLike) -> Array:
    """(..., N + 1) psi_a = th0 + ... + th_a [rad] from the relative angles (..., N + 1)."""
    return np.asarray(np.cumsum(np.asarray(theta, dtype=float), axis=-1), dtype=float)


def joint_positions(robot: RobotParams, theta: ArrayLike) -> Array:
    """(..., N + 2, 2) O_0 .. O_N+1 [m] (O_0 the base's proximal end, O_N+1 the end
    effector), with the system's centre of mass at the origin."""
    psi = absolute_angles(theta)
    e = np.stack([np.cos(psi), np.sin(psi)], axis=-1)  # (..., N + 1, 2)
    moments = mass_moments(robot) / robot.total_mass
    origin = -np.einsum("a,...ak->...k", moments, e)
    if robot.com_across != 0.0:
        origin = origin - across_shift(robot) * _perpendicular(e[..., -1, :])
    steps = np.asarray(robot.length, dtype=float)[:, None] * e
    along = np.cumsum(steps, axis=-2)
    return np.concatenate([origin[..., None, :], origin[..., None, :] + along], axis=-2)


def end_effector(robot: RobotParams, theta: ArrayLike) -> Array:
    """(..., 2) r_E = sum_a v_a e(psi_a) [m] (minus ``across_shift`` e_perp(psi_N) for a last
    link's centre of mass off its axis), the far end of link N."""
    psi = absolute_angles(theta)
    v = virtual_links(robot)
    out = np.stack([np.cos(psi) @ v, np.sin(psi) @ v], axis=-1)
    if robot.com_across != 0.0:
        last = psi[..., -1]
        out = out - across_shift(robot) * np.stack([-np.sin(last), np.cos(last)], axis=-1)
    return np.asarray(out, dtype=float)


def across_shift(robot: RobotParams) -> float:
    """m_N e_N / M [m]: how far the whole robot sits from its axis-only twin, along
    -e_perp(psi_N), when the last link's centre of mass lies e_N across the link."""
    return float(robot.mass[-1] * robot.com_across / robot.total_mass)


def _perpendicular(e: Array) -> Array:
    """(..., 2) e_perp = (-e_y, e_x) of unit vectors e (..., 2)."""
    return np.stack([-e[..., 1], e[..., 0]], axis=-1)


def base_position(robot: RobotParams, theta: ArrayLike) -> Array:
    """(..., 2) the base's centre of mass C_0 = O_0 + d_0 e(th0) [m]."""
    points = joint_positions(robot, theta)
    th0 = np.asarray(theta, dtype=float)[..., 0]
    d0 = float(robot.com[0])
    return np.asarray(points[..., 0, :] + d0 * np.stack([np.cos(th0), np.sin(th0)], axis=-1),
                      dtype=float)


def system_com(robot: RobotParams, theta: ArrayLike) -> Array:
    """(..., 2) the system's centre of mass from ``joint_positions`` [m] (0 up to rounding:
    a check of the construction)."""
    points = joint_positions(robot, theta)
    psi = absolute_angles(theta)
    e = np.stack([np.cos(psi), np.sin(psi)], axis=-1)
    com = np.asarray(robot.com, dtype=float)[:, None] * e
    centres = points[..., :-1, :] + com
    if robot.com_across != 0.0:
        centres[..., -1, :] += robot.com_across * _perpendicular(e[..., -1, :])
    mass = np.asarray(robot.mass, dtype=float)
    return np.asarray(np.einsum("i,...ik->...k", mass, centres) / robot.total_mass, dtype=float)


def reach(robot: RobotParams) -> tuple[float, float]:
    """The annulus the end effector can reach for some angles [m]: (inner, outer) radii of
    the virtual manipulator (every base attitude)."""
    v = np.abs(virtual_links(robot))
    outer = float(v.sum())
    inner = float(max(0.0, 2.0 * v.max() - outer))
    return inner, outer


__all__ = [
    "absolute_angles",
    "across_shift",
    "base_position",
    "end_effector",
    "joint_positions",
    "mass_moments",
    "moments_of",
    "reach",
    "system_com",
    "virtual_links",
    "virtual_links_of",
]
