"""Referees of the task tests, written apart from flatcli.core.robots.kinematics: the links placed
in the complex plane from their definitions alone.

Body i's centre of mass is z_i = O_0 + sum_{a<i} l_a e^{i psi_a} + d_i e^{i psi_i} (the last
body's also + e_N i e^{i psi_N}, its offset across the link, ``com_across``); the system's
centre of mass sum_i m_i z_i / M = 0 fixes O_0 (solved here, not taken from a formula); the
joints are O_k = O_0 + sum_{a<k} l_a e^{i psi_a} and the end effector O_N+1. H is summed
from each body's centre-of-mass velocity (the derivative of z_i along the rates, written out
in complex numbers) and its spin: H = sum_i m_i Im(conj(z_i) z_i') + I_i psi_i'.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]
Complex = NDArray[np.complex128]


def _psi(theta: Array) -> Array:
    return np.cumsum(np.asarray(theta, dtype=float), axis=-1)


def joints(robot: RobotParams, theta: Array) -> Complex:
    """(..., N + 2) joint positions O_0..O_N+1 as complex numbers [m]."""
    psi = _psi(theta)
    e = np.exp(1j * psi)
    length = np.asarray(robot.length)
    com = np.asarray(robot.com)
    mass = np.asarray(robot.mass)
    n = len(mass)
    # relative to O_0 = 0: the joints, then the centres of mass
    rel = np.concatenate([np.zeros((*psi.shape[:-1], 1)), np.cumsum(length * e, axis=-1)],
                         axis=-1)
    centres = rel[..., :n] + com * e
    centres[..., -1] += robot.com_across * 1j * e[..., -1]
    origin = -np.sum(mass * centres, axis=-1) / mass.sum()  # so that the CoM is 0
    return rel + origin[..., None]


def end_effector(robot: RobotParams, theta: Array) -> Complex:
    """(...) the end effector O_N+1 [m], complex."""
    return joints(robot, theta)[..., -1]


def centres(robot: RobotParams, theta: Array) -> Complex:
    """(..., N + 1) every body's centre of mass [m], complex."""
    z = joints(robot, theta)
    e = np.exp(1j * _psi(theta))
    out = z[..., :-1] + np.asarray(robot.com) * e
    out[..., -1] += robot.com_across * 1j * e[..., -1]
    return out


def momentum(robot: RobotParams, theta: Array, rates: Array) -> Array:
    """H (...) [kg m^2/s] from the complex positions and their velocities (d z / d psi_a
    by a complex step in each absolute angle is avoided: each term c e^{i psi} moves at
    i c psi' e^{i psi})."""
    theta = np.asarray(theta, dtype=float)
    rates = np.asarray(rates, dtype=float)
    psi = _psi(theta)
    w = np.cumsum(rates, axis=-1)
    e = np.exp(1j * psi)
    length = np.asarray(robot.length)
    com = np.asarray(robot.com)
    mass = np.asarray(robot.mass)
    inertia = np.asarray(robot.inertia)
    n = len(mass)
    rel = np.concatenate([np.zeros((*psi.shape[:-1], 1)),
                          np.cumsum(length * e, axis=-1)], axis=-1)[..., :n]
    rel_v = np.concatenate([np.zeros((*psi.shape[:-1], 1)),
                            np.cumsum(1j * length * w * e, axis=-1)], axis=-1)[..., :n]
    z = rel + com * e
    v = rel_v + 1j * com * w * e
    M = mass.sum()
    zc = np.sum(mass * z, axis=-1) / M
    vc = np.sum(mass * v, axis=-1) / M
    z = z - zc[..., None]
    v = v - vc[..., None]
    return np.asarray(np.sum(mass * np.imag(np.conj(z) * v), axis=-1)
                      + np.sum(inertia * w, axis=-1), dtype=float)


def momentum_weights(robot: RobotParams, theta: Array) -> Array:
    """(..., N + 1) H per unit rate of each angle (H is linear in the rates)."""
    theta = np.asarray(theta, dtype=float)
    n = theta.shape[-1]
    return np.stack([momentum(robot, theta, np.broadcast_to(np.eye(n)[k], theta.shape))
                     for k in range(n)], axis=-1)


def segment_distance(a: complex, b: complex, c: complex) -> float:
    """Distance from c to the segment ab [m]."""
    ab = b - a
    u = 0.0 if ab == 0 else min(1.0, max(0.0, ((c - a) * np.conj(ab)).real / abs(ab) ** 2))
    return float(abs(c - (a + u * ab)))


def link_clearance(robot: RobotParams, theta: Array, obstacles: Array) -> Array:
    """(n,) the least distance of any link segment from any disc's surface at each row of
    theta (n, N + 1) [m]."""
    z = joints(robot, theta)
    out = np.full(len(z), np.inf)
    for i, row in enumerate(z):
        for x, y, radius in obstacles:
            for k in range(len(row) - 1):
                out[i] = min(out[i], segment_distance(row[k], row[k + 1], complex(x, y)) - radius)
    return out
