"""Free-floating dynamics of a planar chain of n = N + 1 rigid bodies under joint torques.

Bodies a = 0 (the base), 1, ..., N are joined in a chain by revolute joints. Body a has mass
m_a, inertia I_a about its centre of mass, length l_a (joint O_a to O_a+1) and its centre of
mass at distance d_a from O_a along the body. Coordinates are relative, q = (th0, th1, ...,
thN): th0 the base attitude, th_k the angle of joint k; the absolute body angles are
psi_a = th0 + th1 + ... + th_a, i.e. psi = T q with T the lower-triangular matrix of ones.
No external force or torque acts and there is no gravity, so the system centre of mass stays
where it is and the motion about it is all the dynamics.

**Kinetic energy.** Body i's centre of mass is r_i = O0 + sum_a L_ia e(psi_a), with
e(a) = (cos a, sin a) and the lever L_ia = l_a for a < i, d_i for a = i, 0 for a > i.
Relative to the system centre of mass r_c = sum_i m_i r_i / M (M = sum_i m_i),
r_i - r_c = sum_a G_ia e(psi_a) with G_ia = L_ia - sum_k m_k L_ka / M, so

    T = 1/2 sum_ab P_ab(q) psi_a' psi_b',   P_ab = K_ab cos(psi_a - psi_b) + I_a delta_ab,
    K_ab = sum_i m_i G_ia G_ib = sum_i m_i L_ia L_ib - (sum_i m_i L_ia)(sum_i m_i L_ib) / M

(``coupling_matrix``; K is constant, l_N does not enter). **Equations of motion.** Lagrange's
equations in psi are

    sum_b P_ab psi_b'' + sum_b K_ab sin(psi_a - psi_b) psi_b'^2 = Q^psi_a,

and in q (psi'' = T q''): M(q) q'' + C(q, q') q' = Q with M = T^T P T, C(q, q') q' = T^T c^psi
(c^psi_a the sum above), Q = T^T Q^psi. A joint torque tau_k acts on body k and, reacting, on
body k - 1, so Q^psi_a = tau_a - tau_a+1 and Q = (0, tau_1, ..., tau_N): the base is not
actuated. M depends on the joint angles only (th0 is cyclic), so the angular momentum about
the system centre of mass, H = dT/dth0' = (M q')_0 = sum_ab P_ab psi_b', is conserved.

**Eliminating the base.** The base row, M_bb qb'' + M_bj qj'' + c_b = 0, gives the base's
acceleration from the joints', and the joint rows then read

    Mhat qj'' + chat = tau,   Mhat = M_jj - M_jb M_bj / M_bb,   chat = c_j - M_jb c_b / M_bb

(``joint_space``): Mhat is the free-floating joint-space ("generalised") inertia of
space-robotics texts (Umetani & Yoshida 1989).

The functions marked ``jitable`` hold these formulas for any n, written as loops over small
arrays (``chain_terms``, ``joint_space``, ``free_floating_accelerations``); the batch
functions at the end (``mass_matrix``, ``bias_forces``, ``inverse_dynamics``,
``forward_dynamics``, ``kinetic_energy``) run them, compiled, over a batch of states (H is
``chain.chain_momentum``'s, from the link kinematics; the tests check it against (M q')_0).
The compiled closed loop of the three-body robot (``plants.paper``) evaluates the
dynamics some 10^4 times per trial, where the loops over arrays cost six times more than the
same sums written out with floats: ``three_body_terms`` and ``three_body_joint_space`` are
those sums for n = 3. The tests check ``chain_terms`` and ``three_body_terms`` against each
other and both against a sympy Lagrangian built from the link positions (n = 3 and 4), and
H against ``model.momentum``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core._jit import allocating_kernel, jitable
from flatcli.core.errors import FlatcliError
from flatcli.core.robots.chain import barycentric_matrix
from flatcli.core.robots.params import Links

Array = NDArray[np.float64]

#: Rows of the scratch array ``chain_terms`` needs (TRIG_ROWS, n).
TRIG_ROWS = 3


class Chain(NamedTuple):
    """What the dynamics of a chain needs: K (n, n) [kg m^2] and the inertias I (n,) [kg m^2]
    (see the module docstring); build one with ``make_chain`` or ``links_chain``."""

    coupling: Array
    inertia: Array


#: K_ab = sum_i m_i L_ia L_ib - (sum_i m_i L_ia)(sum_i m_i L_ib) / M (module docstring), (n, n)
#: [kg m^2] from mass (n,) [kg], length (n,) and com (n,) [m]: written once, in ``chain``.
coupling_matrix = barycentric_matrix


def make_chain(mass: ArrayLike, inertia: ArrayLike, length: ArrayLike, com: ArrayLike) -> Chain:
    """A validated chain of n >= 2 bodies.

    Parameters
    ----------
    mass : (n,) [kg], each > 0; inertia : (n,) [kg m^2] about each centre of mass, each > 0
    length : (n,) [m], each > 0; com : (n,) d_a [m]

    Returns
    -------
    Chain with read-only arrays
    """
    arrays = {}
    for name, value in (("mass", mass), ("inertia", inertia), ("length", length),
                        ("com", com)):
        arr = np.ascontiguousarray(value, dtype=float)
        if arr.ndim != 1 or arr.shape[0] < 2:
            raise FlatcliError(f"{name}: expected one number per body (n >= 2), got shape "
                               f"{arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise FlatcliError(f"{name}: every value must be finite, got {arr.tolist()}")
        if name != "com" and not np.all(arr > 0):
            raise FlatcliError(f"{name}: every value must be > 0, got {arr.tolist()}")
        arrays[name] = arr
    n = arrays["mass"].shape[0]
    if any(a.shape[0] != n for a in arrays.values()):
        raise FlatcliError("mass, inertia, length, com: expected the same number of bodies")
    K = coupling_matrix(arrays["mass"], arrays["length"], arrays["com"])
    inertia_ = arrays["inertia"].copy()
    K.setflags(write=False)
    inertia_.setflags(write=False)
    return Chain(K, inertia_)


@jitable
def links_chain(p: Links) -> Chain:
    """The chain of the three-body robot (``model.Links``)."""
    mass = np.array([p.m0, p.m1, p.m2])
    length = np.array([p.l0, p.l1, p.l2])
    com = np.array([p.d0, p.d1, p.d2])
    return Chain(coupling_matrix(mass, length, com), np.array([p.i0, p.i1, p.i2]))


class ThreeBody(NamedTuple):
    """A three-body chain as floats, for the compiled loop: K_ab [kg m^2] (upper triangle)
    and the inertias I_a [kg m^2] (``three_body``)."""

    k00: float
    k01: float
    k02: float
    k11: float
    k12: float
    k22: float
    i0: float
    i1: float
    i2: float


@jitable
def three_body(p: Links) -> ThreeBody:
    """The ``ThreeBody`` of the robot's links (K from ``coupling_matrix``)."""
    K = links_chain(p).coupling
    return ThreeBody(K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2], K[2, 2], p.i0, p.i1, p.i2)


@jitable
def three_body_terms(
    b: ThreeBody, c1: float, s1: float, c2: float, s2: float, th0_dot: float, th1_dot: float,
    th2_dot: float,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """``chain_terms`` for n = 3, written out: M(q) and C(q, q') q' of the three-body robot.

    Parameters
    ----------
    b : ThreeBody
    c1, s1, c2, s2 : cos and sin of th1 and of th2
    th0_dot, th1_dot, th2_dot : q' [rad/s]

    Returns
    -------
    M00, M01, M02, M11, M12, M22 [kg m^2] (M is symmetric), then C q' (3,) [N m]
    """
    c12 = c1 * c2 - s1 * s2  # cos(psi2 - psi0) = cos(th1 + th2)
    s12 = s1 * c2 + c1 * s2
    w0 = th0_dot
    w1 = w0 + th1_dot
    w2 = w1 + th2_dot
    # P_ab = K_ab cos(psi_a - psi_b) + I_a delta_ab
    p00, p11, p22 = b.k00 + b.i0, b.k11 + b.i1, b.k22 + b.i2
    p01, p02, p12 = b.k01 * c1, b.k02 * c12, b.k12 * c2
    # c^psi_a = sum_b K_ab sin(psi_a - psi_b) psi_b'^2
    g0 = -b.k01 * s1 * w1 * w1 - b.k02 * s12 * w2 * w2
    g1 = b.k01 * s1 * w0 * w0 - b.k12 * s2 * w2 * w2
    g2 = b.k02 * s12 * w0 * w0 + b.k12 * s2 * w1 * w1
    # M^q = T^T P T, c^q = T^T c^psi
    m22 = p22
    m12 = p12 + p22
    m11 = p11 + 2.0 * p12 + p22
    m02 = p02 + p12 + p22
    m01 = p01 + p02 + p11 + 2.0 * p12 + p22
    m00 = p00 + p11 + p22 + 2.0 * (p01 + p02 + p12)
    return m00, m01, m02, m11, m12, m22, g0 + g1 + g2, g1 + g2, g2


@jitable
def three_body_joint_space(
    m00: float, m01: float, m02: float, m11: float, m12: float, m22: float, h0: float,
    h1: float, h2: float,
) -> tuple[float, float, float, float, float]:
    """``joint_space`` for n = 3: Mhat11, Mhat12, Mhat22 [kg m^2] and chat1, chat2 [N m]
    from M and C q' (``three_body_terms``)."""
    inv = 1.0 / m00
    f1 = m01 * inv
    f2 = m02 * inv
    return m11 - f1 * m01, m12 - f1 * m02, m22 - f2 * m02, h1 - f1 * h0, h2 - f2 * h0


@jitable
def absolute_motion(q: Array, q_dot: Array, trig: Array) -> None:
    """cos psi_a, sin psi_a and psi_a' into the rows of ``trig`` (TRIG_ROWS, n).

    The angles are taken relative to the base (psi_a - th0): the dynamics depends on their
    differences only, so th0 never enters and a large th0 costs no precision.

    Parameters
    ----------
    q : (n,) [rad]; q_dot : (n,) [rad/s]
    """
    n = q.shape[0]
    psi = 0.0
    rate = 0.0
    for a in range(n):
        if a > 0:
            psi += q[a]
        rate += q_dot[a]
        trig[0, a] = math.cos(psi)
        trig[1, a] = math.sin(psi)
        trig[2, a] = rate


@jitable
def chain_terms(chain: Chain, trig: Array, M: Array, c: Array) -> None:
    """M(q) and C(q, q') q' in relative coordinates (module docstring).

    Parameters
    ----------
    chain : Chain of n bodies
    trig : (TRIG_ROWS, n) from ``absolute_motion`` at (q, q')
    M : (n, n) written: the mass matrix [kg m^2]
    c : (n,) written: the Coriolis and centrifugal terms C(q, q') q' [N m]
    """
    K, inertia = chain.coupling, chain.inertia
    n = K.shape[0]
    cs, sn, rate = trig[0], trig[1], trig[2]
    for a in range(n):
        ca, sa = cs[a], sn[a]
        acc = 0.0
        for b in range(n):
            M[a, b] = K[a, b] * (ca * cs[b] + sa * sn[b])  # K_ab cos(psi_a - psi_b)
            acc += K[a, b] * (sa * cs[b] - ca * sn[b]) * rate[b] * rate[b]
        M[a, a] += inertia[a]
        c[a] = acc
    # M^q = T^T P T: M^q_jk = sum_{a >= j, b >= k} P_ab; c^q = T^T c^psi: suffix sums
    for a in range(n):
        for k in range(n - 2, -1, -1):
            M[a, k] += M[a, k + 1]
    for k in range(n):
        for j in range(n - 2, -1, -1):
            M[j, k] += M[j + 1, k]
    for j in range(n - 2, -1, -1):
        c[j] += c[j + 1]


@jitable
def joint_space(M: Array, c: Array, Mhat: Array, chat: Array) -> None:
    """The base eliminated: Mhat = M_jj - M_jb M_bj / M_bb, chat = c_j - M_jb c_b / M_bb.

    Parameters
    ----------
    M : (n, n), c : (n,) from ``chain_terms``
    Mhat : (>= n - 1, >= n - 1) written in its leading block [kg m^2]
    chat : (>= n - 1,) written [N m]
    """
    n = M.shape[0]
    inv = 1.0 / M[0, 0]
    for j in range(1, n):
        f = M[j, 0] * inv
        for k in range(1, n):
            Mhat[j - 1, k - 1] = M[j, k] - f * M[0, k]
        chat[j - 1] = c[j] - f * c[0]


@jitable
def solve_spd(A: Array, b: Array, m: int, x: Array) -> None:
    """x = A^-1 b for a symmetric positive definite m x m block of A (Gaussian elimination
    without pivoting, which a positive definite matrix never needs); A and b are
    overwritten."""
    for k in range(m):
        inv = 1.0 / A[k, k]
        for i in range(k + 1, m):
            f = A[i, k] * inv
            for j in range(k + 1, m):
                A[i, j] -= f * A[k, j]
            b[i] -= f * b[k]
    for i in range(m - 1, -1, -1):
        acc = b[i]
        for j in range(i + 1, m):
            acc -= A[i, j] * x[j]
        x[i] = acc / A[i, i]


@jitable
def free_floating_accelerations(M: Array, c: Array, tau: Array, Mhat: Array, rhs: Array,
                                q_ddot: Array) -> None:
    """q'' of the free-floating chain under joint torques: M q'' + c = (0, tau).

    Parameters
    ----------
    M : (n, n), c : (n,) from ``chain_terms``
    tau : (n - 1,) joint torques [N m]
    Mhat : (>= n - 1, >= n - 1), rhs : (>= n - 1,) scratch
    q_ddot : (n,) written [rad/s^2]
    """
    joint_space(M, c, Mhat, rhs)
    joint_accelerations(M, c, tau, Mhat, rhs, q_ddot)


@jitable
def joint_accelerations(M: Array, c: Array, tau: Array, Mhat: Array, rhs: Array,
                        q_ddot: Array) -> None:
    """``free_floating_accelerations`` given Mhat and chat (in ``rhs``) of ``joint_space``
    at the same state (both overwritten)."""
    n = M.shape[0]
    for j in range(n - 1):
        rhs[j] = tau[j] - rhs[j]
    solve_spd(Mhat, rhs, n - 1, q_ddot[1:])
    acc = c[0]
    for k in range(1, n):
        acc += M[0, k] * q_ddot[k]
    q_ddot[0] = -acc / M[0, 0]


# --------------------------------------------------------------------------------------
# Batches of states, for Python callers (the same jitable functions, compiled once)


@allocating_kernel
def _terms_batch(coupling: Array, inertia: Array, q: Array, q_dot: Array, M: Array,
                 c: Array) -> None:
    chain = Chain(coupling, inertia)
    trig = np.empty((TRIG_ROWS, q.shape[1]))
    for i in range(q.shape[0]):
        absolute_motion(q[i], q_dot[i], trig)
        chain_terms(chain, trig, M[i], c[i])


def _batch(chain: Chain, q: ArrayLike, q_dot: ArrayLike) -> tuple[Array, Array]:
    n = chain.inertia.shape[0]
    q_arr, qd_arr = np.broadcast_arrays(np.asarray(q, dtype=float),
                                        np.asarray(q_dot, dtype=float))
    if q_arr.shape[-1:] != (n,):
        raise ValueError(f"q, q_dot: expected (..., {n}), got {q_arr.shape}")
    shape = q_arr.shape[:-1]
    flat_q = np.ascontiguousarray(q_arr.reshape(-1, n))
    flat_qd = np.ascontiguousarray(qd_arr.reshape(-1, n))
    M = np.empty((flat_q.shape[0], n, n))
    c = np.empty((flat_q.shape[0], n))
    _terms_batch(np.ascontiguousarray(chain.coupling), np.ascontiguousarray(chain.inertia),
                 flat_q, flat_qd, M, c)
    return M.reshape(*shape, n, n), c.reshape(*shape, n)


def mass_matrix(chain: Chain, q: ArrayLike) -> Array:
    """M(q) (..., n, n) [kg m^2] at joint configurations q (..., n) [rad]."""
    q_arr = np.asarray(q, dtype=float)
    return _batch(chain, q_arr, np.zeros_like(q_arr))[0]


def bias_forces(chain: Chain, q: ArrayLike, q_dot: ArrayLike) -> Array:
    """C(q, q') q' (..., n) [N m]: the Coriolis and centrifugal terms at q (..., n) [rad],
    q' (..., n) [rad/s]."""
    return _batch(chain, q, q_dot)[1]


def inverse_dynamics(chain: Chain, q: ArrayLike, q_dot: ArrayLike, q_ddot: ArrayLike) -> Array:
    """M(q) q'' + C(q, q') q' (..., n): the generalised forces a motion needs [N m].

    Its first component is the torque the base would need, dH/dt; a motion of the
    unactuated free-floating chain has it zero, and the rest are the joint torques.
    """
    M, c = _batch(chain, q, q_dot)
    return np.asarray(np.einsum("...jk,...k->...j", M, np.asarray(q_ddot, dtype=float)) + c,
                      dtype=float)


def forward_dynamics(chain: Chain, q: ArrayLike, q_dot: ArrayLike, tau: ArrayLike) -> Array:
    """q'' (..., n) [rad/s^2] of the free-floating chain under joint torques tau (..., n - 1)
    [N m] (the base unactuated): solves M q'' + C q' = (0, tau)."""
    M, c = _batch(chain, q, q_dot)
    tau_arr = np.broadcast_to(np.asarray(tau, dtype=float), (*c.shape[:-1], c.shape[-1] - 1))
    Q = np.concatenate([np.zeros((*c.shape[:-1], 1)), tau_arr], axis=-1)
    return np.asarray(np.linalg.solve(M, (Q - c)[..., None])[..., 0], dtype=float)


def kinetic_energy(chain: Chain, q: ArrayLike, q_dot: ArrayLike) -> Array:
    """T = 1/2 q'^T M(q) q' (...) [J]."""
    M, _ = _batch(chain, q, q_dot)
    qd = np.asarray(q_dot, dtype=float)
    return np.asarray(0.5 * np.einsum("...j,...jk,...k->...", qd, M, qd), dtype=float)


__all__ = [
    "TRIG_ROWS",
    "Chain",
    "ThreeBody",
    "absolute_motion",
    "bias_forces",
    "chain_terms",
    "coupling_matrix",
    "forward_dynamics",
    "free_floating_accelerations",
    "inverse_dynamics",
    "joint_space",
    "kinetic_energy",
    "links_chain",
    "make_chain",
    "mass_matrix",
    "solve_spd",
    "three_body",
    "three_body_joint_space",
    "three_body_terms",
]
