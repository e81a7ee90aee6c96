"""The bench's own link kinematics in the complex plane (written apart from
``flatcli.core.robots.kinematics``): where the links of a free-floating chain are with its centre of
mass at the origin, and how far each link is from a disc. The referee of the task benches
(``benchmarks.tasks``) and of python-control's plans (``pcflatsys.pc_obstacle_task``)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Complex = NDArray[np.complex128]

#: The grid of the re-check: 100 x a plan's own 200 intervals.
FINE = 100 * 200 + 1
#: The paper's robot (mass, length, com of its three links) (Sec. VI).
PAPER = (np.ones(3), np.full(3, 0.2), np.array([0.1, 0.1, 0.0]))


def link_joints(mass: Array, length: Array, com: Array, theta: Array) -> Complex:
    """(N + 2, n) the links' ends in the complex plane [m] at each row of theta (n, N + 1):
    the base's outer end O_0 first, the end effector last; joints placed from the links'
    definitions, O_0 moved so that the masses' centre is at the origin."""
    psi = np.cumsum(np.asarray(theta, dtype=float).T, axis=0)
    e = np.exp(1j * psi)
    rel = np.zeros((len(mass) + 1, psi.shape[1]), dtype=complex)
    rel[1:] = np.cumsum(length[:, None] * e, axis=0)
    centres = rel[:-1] + com[:, None] * e
    return np.asarray(rel - (mass @ centres) / mass.sum(), dtype=complex)


def disc_gaps(joints: Complex, obstacles: Array) -> Array:
    """(K, N + 1, n) the distance of each link segment (the base's O_0 O_1 first) from each
    disc's surface [m]; joints (N + 2, n) from ``link_joints``, obstacles (K, 3) x, y, radius
    [m]."""
    a = joints[:-1]
    d = joints[1:] - a
    length2 = np.maximum(d.real**2 + d.imag**2, 1e-300)
    ca = (obstacles[:, 0] + 1j * obstacles[:, 1])[:, None, None] - a
    s = np.clip((ca * np.conj(d)).real / length2, 0.0, 1.0)
    return np.asarray(np.abs(ca - s * d) - obstacles[:, 2, None, None], dtype=float)


def link_clearance(mass: Array, length: Array, com: Array, theta: Array,
                   obstacles: Array) -> Array:
    """(n,) the least distance of any link segment from any disc's surface [m] at each row
    of theta (n, N + 1) (``link_joints``, ``disc_gaps``)."""
    joints = link_joints(mass, length, com, theta)
    out = np.full(joints.shape[1], np.inf)
    for disc in np.asarray(obstacles, dtype=float).reshape(-1, 3):
        out = np.minimum(out, disc_gaps(joints, disc[None]).min(axis=(0, 1)))
    return out
