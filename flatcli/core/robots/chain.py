"""A planar free-floating chain of N + 1 bodies: the base (link 0) and joints 1..N.

Link i has mass m_i, inertia I_i about its centre of mass, length l_i (joint O_i to O_i+1)
and its centre of mass at d_i from O_i along the link; angles are relative (th0 the base
attitude, th_j the joint angles), the absolute angles psi_a = th0 + th1 + ... + th_a. With no
external force the system centre of mass is fixed and the angular momentum H about it is
conserved. For N = 2 this is the paper's robot (``model``).

Two independent descriptions of H live here, as in ``model``:

* ``chain_momentum``: from the full link kinematics (positions and velocities of each centre
  of mass, relative to the system's, and each link's spin): the referee.
* the barycentric form used to plan, control and simulate: with L_ia = l_a (a < i),
  d_i (a = i), 0 (a > i), the constant symmetric matrix

      K_ab = sum_i m_i L_ia L_ib - (sum_i m_i L_ia)(sum_i m_i L_ib) / M

  gives the kinetic energy T = 1/2 sum_ab (K_ab cos(psi_a - psi_b) + I_a delta_ab) psi_a'
  psi_b' about the system centre of mass, hence H = dT/dth0' = sum_j h_j(th) th_j' with
  h_j = sum_{b >= j} sum_a (K_ab cos(psi_a - psi_b) + I_a delta_ab) (``momentum_weights``).
  Only differences psi_a - psi_b = th_b+1 + ... + th_a enter: H does not depend on th0.

If the last link's centre of mass sits on joint N (d_N = 0), K_aN = 0 for every a: no link
position depends on th_N, h_N = I_N is constant, and h_0, ..., h_N-1 depend on th_1 ..
th_N-1 only. That is what makes the chain flat (``chainflat``).

Functions take 1-D arrays per link and plain floats, so numba compiles them into the
closed-loop kernels as they are; those of the angles allocate in the dtype of ``theta``, so
complex angles (complex step) pass through them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import allocating_kernel, jitable

Array = NDArray[np.float64]


@jitable
def lever_arms(length: Array, com: Array) -> Array:
    """(N + 1, N + 1) L_ia: how far link a's axis carries body i's centre of mass [m]."""
    n = length.shape[0]
    out = np.zeros((n, n))
    for i in range(n):
        for a in range(i):
            out[i, a] = length[a]
        out[i, i] = com[i]
    return out


@jitable
def barycentric_matrix(mass: Array, length: Array, com: Array) -> Array:
    """(N + 1, N + 1) K_ab [kg m^2]: the chain's inertia about the fixed system centre of
    mass, coupling absolute angles a and b through cos(psi_a - psi_b) (module docstring)."""
    n = mass.shape[0]
    lever = lever_arms(length, com)
    total = 0.0
    for i in range(n):
        total += mass[i]
    first = np.zeros(n)  # sum_i m_i L_ia
    for a in range(n):
        for i in range(n):
            first[a] += mass[i] * lever[i, a]
    out = np.empty((n, n))
    for a in range(n):
        for b in range(n):
            s = 0.0
            for i in range(n):
                s += mass[i] * lever[i, a] * lever[i, b]
            out[a, b] = s - first[a] * first[b] / total
    return out


@allocating_kernel
def barycentric_matrices(params: Array) -> Array:
    """(T, N + 1, N + 1) K of T chains from their parameters (T, 4 (N + 1)): mass, inertia,
    length, com side by side (``barycentric_matrix`` of each row)."""
    count = params.shape[0]
    nb = params.shape[1] // 4
    out = np.empty((count, nb, nb))
    for i in range(count):
        p = params[i]
        out[i] = barycentric_matrix(p[:nb], p[2 * nb: 3 * nb], p[3 * nb:])
    return out


def inertia_scale(mass: Array, inertia: Array, length: Array, com: Array) -> float:
    """J = sum_a (I_a + sum_i m_i L_ia^2) [kg m^2]: the chain's own inertia scale.

    sum_i m_i L_ia^2 = m_a d_a^2 + (m_a+1 + ... + m_N) l_a^2 bounds K_aa, so
    |K_ab| <= sqrt(K_aa K_bb) <= J and sum_a I_a + trace K <= J: a coupling K_ab is small
    when |K_ab| / J is (the design checks, ``model.flatness_check`` and ``design``, use it as
    their scale). l_N does not enter.

    Parameters
    ----------
    mass, inertia, length, com : (N + 1,) [kg, kg m^2, m, m]

    Returns
    -------
    J : float [kg m^2], > 0 for any valid robot (every inertia > 0)
    """
    lever = lever_arms(np.asarray(length, dtype=float), np.asarray(com, dtype=float))
    return float(np.sum(inertia) + np.asarray(mass, dtype=float) @ np.sum(lever**2, axis=1))


@jitable
def link_trig(theta: Array, cs: Array, sn: Array) -> None:
    """cos and sin of every link's angle relative to the base, psi_a - psi_0 = th1 + ... +
    th_a (0 for the base), into ``cs``, ``sn`` (N + 1,), from the relative angles theta
    (N + 1,) [rad]: the one trigonometric evaluation the weights below need, since
    cos(psi_a - psi_b) = cs_a cs_b + sn_a sn_b and sin(psi_a - psi_b) = sn_a cs_b - cs_a sn_b.
    Relative to the base, so a large th0 costs no precision (th0 never enters)."""
    acc = theta[0] - theta[0]  # an exact 0 of theta's dtype (complex for complex steps)
    for a in range(theta.shape[0]):
        if a > 0:
            acc += theta[a]
        cs[a] = np.cos(acc)
        sn[a] = np.sin(acc)


@jitable
def turn_last(cs: Array, sn: Array, cos_a: float, sin_a: float) -> None:
    """The last link's trigonometry (``link_trig``, entry N of cs, sn) turned by an angle
    alpha given as cos_a, sin_a: a centre of mass across the last link makes the robot the
    one with it on the link's axis whose joint N reads th_N + alpha
    (``model.RobotParams.placement``). alpha = 0 (cos_a = 1, sin_a = 0) changes nothing, to
    the bit."""
    if sin_a == 0.0 and cos_a == 1.0:
        return
    n = cs.shape[0] - 1
    c, s = cs[n], sn[n]
    cs[n] = c * cos_a - s * sin_a
    sn[n] = s * cos_a + c * sin_a


@jitable
def momentum_weights(K: Array, inertia: Array, theta: Array, out: Array) -> None:
    """h_j (N + 1,) with H = sum_j h_j th_j' at the angles theta (N + 1,) [kg m^2].

    h_j = sum_{b >= j} c_b, c_b = I_b + sum_a K_ab cos(psi_a - psi_b): the columns of the
    inertia matrix in absolute angles, summed over the bodies joint j moves.
    """
    n = theta.shape[0]
    cs = np.empty(n, dtype=theta.dtype)
    sn = np.empty(n, dtype=theta.dtype)
    link_trig(theta, cs, sn)
    momentum_weights_given(K, inertia, cs, sn, out)


@jitable
def momentum_weights_given(K: Array, inertia: Array, cs: Array, sn: Array, out: Array
                           ) -> None:
    """``momentum_weights`` given the links' trigonometry (``link_trig``)."""
    n = cs.shape[0]
    tail = cs[0] * 0.0
    for b in range(n - 1, -1, -1):
        c = inertia[b] + K[b, b]
        for a in range(n):
            if a != b and K[a, b] != 0.0:
                c += K[a, b] * (cs[a] * cs[b] + sn[a] * sn[b])
        tail += c
        out[b] = tail


@jitable
def base_inertia_slopes(K: Array, inertia: Array, theta: Array, grad: Array, hess: Array
                        ) -> float:
    """h_0 [kg m^2] at the angles theta (N + 1,), and its partial derivatives in the joint
    angles th_1 .. th_N: ``grad`` (N,) [kg m^2], ``hess`` (N, N) [kg m^2] written.

    h_0 = sum I + sum_a K_aa + 2 sum_{a > b} K_ab cos(psi_a - psi_b); psi_a - psi_b contains
    th_k exactly when b < k <= a.
    """
    n = theta.shape[0]
    cs = np.empty(n, dtype=theta.dtype)
    sn = np.empty(n, dtype=theta.dtype)
    link_trig(theta, cs, sn)
    return base_inertia_slopes_given(K, inertia, cs, sn, grad, hess)


@jitable
def base_inertia_slopes_given(K: Array, inertia: Array, cs: Array, sn: Array, grad: Array,
                              hess: Array) -> float:
    """``base_inertia_slopes`` given the links' trigonometry (``link_trig``).

    A pair a > b adds -2 K_ab sin(psi_a - psi_b) to grad over the joints b+1..a and
    -2 K_ab cos(psi_a - psi_b) to the square block of hess over them: each is added as the
    corners of a difference array, then summed up (O(N^2) work for N joints, not O(N^4)).
    """
    n = cs.shape[0]
    m = n - 1  # joints, the size of grad
    h0 = cs[0] * 0.0
    for a in range(n):
        h0 += inertia[a] + K[a, a]
    grad[:] = 0.0
    hess[:, :] = 0.0
    for a in range(n):
        for b in range(a):
            k = K[a, b]
            if k == 0.0:
                continue
            c = cs[a] * cs[b] + sn[a] * sn[b]
            s = sn[a] * cs[b] - cs[a] * sn[b]
            h0 += 2.0 * k * c
            g = -2.0 * k * s
            v = -2.0 * k * c
            grad[b] += g  # joints b+1..a are the entries b..a-1
            hess[b, b] += v
            if a < m:
                grad[a] -= g
                hess[b, a] -= v
                hess[a, b] -= v
                hess[a, a] += v
    for j in range(1, m):
        grad[j] += grad[j - 1]
    for j in range(m):
        for i in range(1, m):
            hess[j, i] += hess[j, i - 1]
    for j in range(1, m):
        for i in range(m):
            hess[j, i] += hess[j - 1, i]
    return h0  # type: ignore[no-any-return]  # complex-safe


@jitable
def weight_slopes(K: Array, theta: Array, out: Array) -> None:
    """d h_j / d th_k into ``out`` (N + 1, N): row j (body/joint 0..N), column k - 1 for the
    joint angles th_k, k = 1..N [kg m^2]."""
    n = theta.shape[0]
    cs = np.empty(n, dtype=theta.dtype)
    sn = np.empty(n, dtype=theta.dtype)
    col = np.empty((n, n - 1), dtype=theta.dtype)
    link_trig(theta, cs, sn)
    weight_slopes_given(K, cs, sn, col, out)


@jitable
def weight_slopes_given(K: Array, cs: Array, sn: Array, col: Array, out: Array) -> None:
    """``weight_slopes`` given the links' trigonometry (``link_trig``) and the scratch
    ``col`` (N + 1, N): d c_b / d th_k gets -K_ab sin(psi_a - psi_b) (with the sign of
    a - b) over the joints between a and b, added as the ends of a difference array over k
    and summed up (O(N^2) work, not O(N^3))."""
    n = cs.shape[0]
    m = n - 1
    col[:, :] = 0.0
    for b in range(n):
        for a in range(n):
            if a == b or K[a, b] == 0.0:
                continue
            s = sn[a] * cs[b] - cs[a] * sn[b]  # sin(psi_a - psi_b)
            lo, hi = (b, a) if a > b else (a, b)
            sign = 1.0 if a > b else -1.0  # d(psi_a - psi_b)/d th_k for lo < k <= hi
            v = -K[a, b] * s * sign
            col[b, lo] += v  # joints lo+1..hi are the entries lo..hi-1
            if hi < m:
                col[b, hi] -= v
    for b in range(n):
        for k in range(1, m):
            col[b, k] += col[b, k - 1]
    for k in range(m):
        tail = cs[0] * 0.0
        for b in range(n - 1, -1, -1):
            tail += col[b, k]
            out[b, k] = tail


def chain_momentum(
    mass: Array, inertia: Array, length: Array, com: Array, theta: Array, theta_dot: Array
) -> Array:
    """Angular momentum about the fixed system centre of mass, from the link kinematics
    (``chain_momentum_given`` at every state; real or complex angles and rates).

    Parameters
    ----------
    mass, inertia, length, com : (N + 1,) [kg, kg m^2, m, m]
    theta : (..., N + 1) relative angles [rad]; theta_dot : (..., N + 1) their rates [rad/s]

    Returns
    -------
    H : (...) [kg m^2/s], complex if an input is
    """
    theta_arr, rates = np.broadcast_arrays(np.asarray(theta), np.asarray(theta_dot))
    dtype = np.result_type(theta_arr, rates, float)
    nb = theta_arr.shape[-1]
    rows = np.ascontiguousarray(theta_arr.reshape(-1, nb), dtype=dtype)
    rate_rows = np.ascontiguousarray(rates.reshape(-1, nb), dtype=dtype)
    params = np.ascontiguousarray(np.concatenate([mass, inertia, length, com]), dtype=float)
    out = np.empty(rows.shape[0], dtype=dtype)
    _momentum_rows(params, rows, rate_rows, out)
    return out.reshape(theta_arr.shape[:-1])


@allocating_kernel
def _momentum_rows(params: Array, theta: Array, theta_dot: Array, out: Array) -> None:
    cs = np.empty(theta.shape[1], dtype=theta.dtype)
    sn = np.empty(theta.shape[1], dtype=theta.dtype)
    for i in range(theta.shape[0]):
        out[i] = chain_momentum_at(params, theta[i], theta_dot[i], cs, sn)


@jitable
def chain_momentum_at(params: Array, theta: Array, theta_dot: Array, cs: Array, sn: Array
                      ) -> float:
    """H of one state from the full link kinematics, for the kernels: ``params``
    (4 (N + 1),) mass, inertia, length, com side by side; theta, theta_dot (N + 1,) [rad,
    rad/s]; cs, sn (N + 1,) scratch (written: ``link_trig`` of theta)."""
    link_trig(theta, cs, sn)
    return chain_momentum_given(params, cs, sn, theta_dot)


@jitable
def chain_momentum_given(params: Array, cs: Array, sn: Array, theta_dot: Array) -> float:
    """Angular momentum about the fixed system centre of mass, from the link kinematics,
    given the links' trigonometry (``link_trig``) [kg m^2/s].

    Each centre of mass is placed along the chain from O0 (r_i = sum_{a<i} l_a e(psi_a) +
    d_i e(psi_i)) and moved with it (absolute angular rates psi_a' = th0' + ... + th_a');
    H = sum_i I_i psi_i' + sum_i m_i r_i x v_i - M r_c x v_c. Vectors are written in the
    base's frame (angles psi_a - th0): planar cross products do not change under a rotation,
    and th0 costs no precision. Nothing here uses K or the h_j. ``params`` (4 (N + 1),):
    mass, inertia, length, com side by side; theta_dot (N + 1,) [rad/s].
    """
    n = cs.shape[0]
    zero = cs[0] * 0.0  # the dtype of the angles (complex for complex steps)
    w = zero
    total = 0.0
    h = zero
    mx = my = mvx = mvy = zero
    # running position (px, py) and velocity (qx, qy) of the current joint O_a
    px = py = qx = qy = zero
    for i in range(n):
        w += theta_dot[i]
        m, inertia, length, com = params[i], params[n + i], params[2 * n + i], params[3 * n + i]
        c, s = cs[i], sn[i]
        x, y = px + com * c, py + com * s
        vx, vy = qx - com * w * s, qy + com * w * c
        h += inertia * w + m * (x * vy - y * vx)
        total += m
        mx += m * x
        my += m * y
        mvx += m * vx
        mvy += m * vy
        px, py = px + length * c, py + length * s
        qx, qy = qx - length * w * s, qy + length * w * c
    return h - (mx * mvy - my * mvx) / total  # type: ignore[no-any-return]  # complex-safe


@jitable
def plan_residual(plan_theta: Array, plan_theta_dot: Array, params: Array, h0: float,
                  cs: Array, sn: Array, cos_p: float = 1.0, sin_p: float = 0.0) -> float:
    """max_j |H - H0| of a plan's own samples (p, N + 1) with a plant's (4 (N + 1),)
    parameters [kg m^2/s] (cs, sn: scratch (N + 1,); cos_p, sin_p: the plant's turn of its
    last link)."""
    residual = 0.0
    for j in range(plan_theta.shape[0]):
        link_trig(plan_theta[j], cs, sn)
        turn_last(cs, sn, cos_p, sin_p)
        residual = max(residual, abs(chain_momentum_given(params, cs, sn, plan_theta_dot[j])
                                     - h0))
    return residual
