"""The referee of the as-built tests: a robot's angular momentum from its link geometry,
written here from scratch (complex numbers for planar vectors), with a centre of mass anywhere
in each link's frame, including across the last link.

Link i's centre of mass sits at r_i = sum_{a<i} l_a e^{j psi_a} + (d_i + j e_i) e^{j psi_i}
(psi_a = th0 + ... + th_a; e_i = 0 except e_N = ``across``); its velocity is the time
derivative of that; H = sum_i I_i psi_i' + m_i Im(conj(r_i) v_i) - M Im(conj(r_c) v_c)
about the fixed system centre of mass r_c. Nothing here uses flatcli's barycentric matrix,
its weights h_j, or ``RobotParams.placement``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: The paper's maneuver (Franch et al. 2003, Sec. VI) and its Fig. 4 start.
START = (1.8, 1.0, 0.0)
GOAL = (1.2, 2.0, 0.0)
FIG4 = (1.96, 0.8, -0.1)
#: The counterweight misplaced by 3 mm along link 2 (the issue's goal).
AS_BUILT = RobotParams(com=(0.1, 0.1, 0.003))


def momentum(robot: RobotParams, theta: ArrayLike, theta_dot: ArrayLike) -> Array:
    """H (...) [kg m^2/s] of ``robot`` at angles theta (..., N + 1) and rates theta_dot."""
    theta = np.asarray(theta, dtype=float)
    theta_dot = np.asarray(theta_dot, dtype=float)
    psi = np.cumsum(theta, axis=-1)
    psi_dot = np.cumsum(theta_dot, axis=-1)
    unit = np.exp(1j * psi)
    n = len(robot.mass)
    total = sum(robot.mass)
    r = np.zeros((*theta.shape[:-1], n), dtype=complex)
    v = np.zeros_like(r)
    for i in range(n):
        for a in range(i):
            r[..., i] += robot.length[a] * unit[..., a]
            v[..., i] += robot.length[a] * 1j * psi_dot[..., a] * unit[..., a]
        arm = robot.com[i] + 1j * (robot.com_across if i == n - 1 else 0.0)
        r[..., i] += arm * unit[..., i]
        v[..., i] += arm * 1j * psi_dot[..., i] * unit[..., i]
    mass = np.asarray(robot.mass)
    rc = (r * mass).sum(axis=-1) / total
    vc = (v * mass).sum(axis=-1) / total
    orbital = (mass * np.imag(np.conj(r) * v)).sum(axis=-1) - total * np.imag(np.conj(rc) * vc)
    return np.asarray((np.asarray(robot.inertia) * psi_dot).sum(axis=-1) + orbital)


def weights(robot: RobotParams, theta: ArrayLike) -> Array:
    """h_j = dH/dth_j' (..., N + 1) [kg m^2] at theta (..., N + 1): ``momentum`` at unit rates."""
    theta = np.asarray(theta, dtype=float)
    n = theta.shape[-1]
    return np.stack([momentum(robot, theta, np.broadcast_to(np.eye(n)[j], theta.shape))
                     for j in range(n)], axis=-1)


def base_rate(robot: RobotParams, q: Sequence[float] | Array, w: Sequence[float] | Array
              ) -> float:
    """th0' [rad/s] with H = 0 at joint angles q (N,) and rates w (N,)."""
    h = weights(robot, np.r_[0.0, q])
    return float(-(h[1:] @ np.asarray(w, dtype=float)) / h[0])


#: The maneuver of a random design (``random_as_built``): the paper's for N = 2, and for
#: N >= 3 the base turned by -0.75 rad while joint 1 goes 1 -> 2 rad and the inner joints
#: 0.3 -> 0.6 rad (the last joint, the counterweight's, starts and ends at 0).
def maneuver(n: int) -> tuple[Array, Array]:
    """Start and goal th0..thN (N + 1,) [rad] of a random design's maneuver (above)."""
    if n == 2:
        return np.array(START), np.array(GOAL)
    start = np.r_[0.0, 1.0, np.full(n - 2, 0.3), 0.0]
    goal = np.r_[-0.75, 2.0, np.full(n - 2, 0.6), 0.0]
    return start, goal


def random_as_built(rng: np.random.Generator, n: int) -> RobotParams:
    """A design of N joints drawn from ``rng``, its counterweight 2 to 5 mm off the last joint
    (either side, along the link): base 2-10 kg, links 0.5-3 kg, lengths 0.15-0.5 m (base
    0.2-0.5 m), centres of mass at 20-80 % of the inner links, inertias m l^2 / 12 (the
    base's m l^2 / 6) times 0.5-2."""
    mass = np.r_[rng.uniform(2.0, 10.0), rng.uniform(0.5, 3.0, n)]
    length = np.r_[rng.uniform(0.2, 0.5), rng.uniform(0.15, 0.5, n)]
    com = np.r_[rng.uniform(0.2, 0.8, n) * length[:n], 0.0]
    inertia = mass * length**2 / 12 * rng.uniform(0.5, 2.0, n + 1)
    inertia[0] = mass[0] * length[0] ** 2 / 6 * rng.uniform(0.5, 2.0)
    com[-1] = rng.uniform(0.002, 0.005) * rng.choice([-1.0, 1.0])
    return RobotParams(mass=tuple(mass), inertia=tuple(inertia), length=tuple(length),
                       com=tuple(com))
