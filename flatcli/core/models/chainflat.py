"""Flat outputs of an N-link planar free-floating chain whose last link is counterweighted.

The paper's closing claim (Franch et al. 2003, Sec. VII): the result "extends to a general
n-link planar robot where the center of mass of the last link is on the preceding joint
axis". The derivation, with the notation of ``chain``: if d_N = 0, no link position depends
on th_N, so the momentum constraint (the controller assumes H = 0)

    h_0(q) th0' + sum_{j<N} h_j(q) th_j' + I_N th_N' = 0,      q = (th_1 .. th_N-1),

has h_0, h_j functions of q only and the constant I_N. Prolonging u_j = th_j' (j < N) gives
the state (th0 .. th_N, u_1 .. u_N-1) and inputs (u_j', th_N'), and

    y_j = th_j (j < N),      y_N = th0 + I_N th_N / h_0(q)

are flat outputs: eliminating th0' with the constraint,

    y_N' = -S / h_0 - I_N th_N D / h_0^2,   S = sum_{j<N} h_j u_j,   D = sum_{j<N} dh_0/dth_j u_j,

is affine in th_N with slope -I_N D / h_0^2, so th_N follows from (y, y') wherever the base's
locked inertia is changing, D = d h_0 / dt != 0 (the singular set is D = 0), and th0 from y_N.
Differentiating once more, y_N'' = alpha + beta th_N' with beta = -I_N D / h_0^2 and alpha
from the partial derivatives of S, D and h_0 (``inputs``): the inputs that realise wanted
flat accelerations v.

For N = 2, h_0 = A / M, h_1 = -B / M, I_2 = -c0 / M and D = -a1 sin(th1) th1' / M with the
paper's coefficients (``model``): these are the paper's maps (``flatness``), whose closed
forms flatcli keeps for N = 2; the tests check both against each other.

The *signed margin* is sigma = -D / (2 K_10) [rad/s]: for N = 2 exactly the paper's
sin(th1) th1'. The outputs need I_N != 0 and h_0 not constant. K_10 = m0 (l0 - d0)(m1 d1 +
(m2 + ... + mN) l1) / M; flatcli normalises the margin by it and so plans for K_10 != 0 only
(the paper's conditions m0 != 0, l0 != d0, m1 d1 + m2 l1 != 0, generalised). For N >= 3 a
design with K_10 = 0 is flat when another K_ab (a != b) couples the links (h_0 then still
varies) and not flat when K is diagonal (``design``); flatcli reports it as unsupported
(``model.flatness_check``).

Functions take the controller's K (``chain.barycentric_matrix``) and inertias, angles
(N + 1,) and rates (N - 1,) as 1-D arrays, write into output arrays, and are compiled into
the closed-loop kernels as they are. They are complex-step safe: the arrays they allocate
take the dtype of their inputs and nothing is cast to float, so complex angles and rates (in
complex output arrays) give derivatives exact to rounding (the optimiser's Jacobians,
``optimize.quantities``); real inputs compute exactly what they did before.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.robots.chain import (
    base_inertia_slopes_given,
    link_trig,
    momentum_weights_given,
    weight_slopes_given,
)

Array = NDArray[np.float64]


class Scratch(NamedTuple):
    """Arrays the flat maps' terms are written into, for callers that evaluate them many
    times (the kernels: no allocation per call); ``scratch`` makes one for N joints, of a
    dtype (float, or complex for complex steps)."""

    cs: Array  # (N + 1,) cos of the links' angles relative to the base (``chain.link_trig``)
    sn: Array  # (N + 1,) their sin
    h: Array  # (N + 1,) weights h_j
    grad: Array  # (N,) grad h_0
    hess: Array  # (N, N) its Hessian
    col: Array  # (N + 1, N) d c_b / d th_k (scratch of the slopes)
    slopes: Array  # (N + 1, N) d h_j / d th_k
    at: Array  # (N + 3,) the angles they were last computed at, 1.0 (0.0: none), h_0


def scratch(n: int, dtype: type = float) -> Scratch:
    """A ``Scratch`` for a chain of N = ``n`` joints."""
    nb = n + 1
    return Scratch(np.zeros(nb, dtype=dtype), np.zeros(nb, dtype=dtype),
                   np.zeros(nb, dtype=dtype), np.zeros(n, dtype=dtype),
                   np.zeros((n, n), dtype=dtype), np.zeros((nb, n), dtype=dtype),
                   np.zeros((nb, n), dtype=dtype), np.zeros(nb + 2, dtype=dtype))


@jitable
def scratch_like(theta: Array) -> Scratch:
    """A ``Scratch`` for the angles theta (N + 1,), in their dtype (compiled callers)."""
    nb = theta.shape[0]
    n = nb - 1
    dtype = theta.dtype
    return Scratch(np.empty(nb, dtype=dtype), np.empty(nb, dtype=dtype),
                   np.empty(nb, dtype=dtype), np.empty(n, dtype=dtype),
                   np.empty((n, n), dtype=dtype), np.empty((nb, n), dtype=dtype),
                   np.empty((nb, n), dtype=dtype), np.zeros(nb + 2, dtype=dtype))


@jitable
def first_terms_into(K: Array, inertia: Array, theta: Array, work: Scratch) -> float:
    """h_0 returned; the links' trigonometry (``chain.link_trig``), the weights h (N + 1,),
    grad h_0 (N,) and its Hessian (N, N) at theta written into ``work`` (what the forward
    map needs)."""
    link_trig(theta, work.cs, work.sn)
    h0 = first_terms_given(K, inertia, work)
    nb = theta.shape[0]
    for a in range(nb):
        work.at[a] = theta[a]
    work.at[nb] = 1.0
    work.at[nb + 1] = h0
    return h0


@jitable
def first_terms_at(K: Array, inertia: Array, theta: Array, work: Scratch) -> float:
    """``first_terms_into`` unless ``work`` already holds the terms at exactly these angles
    (the right-hand side's, at the state an output sample then observes); returns h_0."""
    nb = theta.shape[0]
    if work.at[nb] == 1.0:
        same = True
        for a in range(nb):
            if work.at[a] != theta[a]:
                same = False
                break
        if same:
            return work.at[nb + 1]  # type: ignore[no-any-return]
    return first_terms_into(K, inertia, theta, work)


@jitable
def first_terms_given(K: Array, inertia: Array, work: Scratch) -> float:
    """``first_terms_into`` with the links' trigonometry already in ``work.cs``,
    ``work.sn``."""
    momentum_weights_given(K, inertia, work.cs, work.sn, work.h)
    return base_inertia_slopes_given(K, inertia, work.cs, work.sn, work.grad, work.hess)


@jitable
def terms_into(K: Array, inertia: Array, theta: Array, work: Scratch) -> float:
    """``first_terms_into`` and the slopes d h_j / d th_k (N + 1, N) into ``work.slopes``
    (what the inputs need too); returns h_0."""
    h0 = first_terms_into(K, inertia, theta, work)
    weight_slopes_given(K, work.cs, work.sn, work.col, work.slopes)
    return h0


@jitable
def _terms(K: Array, inertia: Array, theta: Array) -> tuple[float, Array, Array, Array]:
    """h_0, the weights h (N + 1,), grad h_0 (N,) and its Hessian (N, N) at theta."""
    work = scratch_like(theta)
    h0 = first_terms_into(K, inertia, theta, work)
    return h0, work.h, work.grad, work.hess


@jitable
def terms(K: Array, inertia: Array, theta: Array) -> tuple[float, Array, Array, Array, Array]:
    """Everything trigonometric of the flat maps, at the angles theta (N + 1,) [rad]: h_0,
    the weights h (N + 1,), grad h_0 (N,), its Hessian (N, N) and the slopes d h_j / d th_k
    (N + 1, N) [kg m^2] (``chain.weight_slopes``).

    With d_N = 0 they depend on q = (th_1..th_N-1) only, not on th0 or th_N (up to the
    rounding of the absolute angles' differences); ``flag_state_given`` takes them.
    """
    work = scratch_like(theta)
    h0 = terms_into(K, inertia, theta, work)
    return h0, work.h, work.grad, work.hess, work.slopes


@jitable
def _sums(h: Array, grad: Array, u: Array) -> tuple[float, float]:
    """S = sum_{j<N} h_j u_j [kg m^2/s] and D = sum_{j<N} dh_0/dth_j u_j = dh_0/dt
    [kg m^2/s] of the module docstring, from the weights h (N + 1,), grad h_0 (N,) and the
    rates u (N - 1,)."""
    s = 0.0
    d = 0.0
    for j in range(1, u.shape[0] + 1):
        s += h[j] * u[j - 1]
        d += grad[j - 1] * u[j - 1]
    return s, d


@jitable
def outputs(K: Array, inertia: Array, theta: Array, u: Array, y: Array, y_dot: Array) -> float:
    """Forward map: state (theta (N + 1,), u (N - 1,)) -> y (N,) [rad], y' (N,) [rad/s],
    written; returns the signed margin sigma = -D / (2 K_10) [rad/s]."""
    h0, h, grad, _ = _terms(K, inertia, theta)
    return outputs_given(K, inertia, h0, h, grad, theta, u, y, y_dot)


@jitable
def outputs_given(K: Array, inertia: Array, h0: float, h: Array, grad: Array, theta: Array,
                  u: Array, y: Array, y_dot: Array) -> float:
    """``outputs`` given the terms at q (``terms``), so that a controller that needs both
    the outputs and the inputs at one state computes the trigonometry once."""
    n = theta.shape[0] - 1
    for j in range(1, n):
        y[j - 1] = theta[j]
        y_dot[j - 1] = u[j - 1]
    s, d = _sums(h, grad, u)
    i_n = inertia[n]
    y[n - 1] = theta[0] + i_n * theta[n] / h0
    y_dot[n - 1] = -s / h0 - i_n * theta[n] * d / (h0 * h0)
    return -d / (2.0 * K[1, 0])  # type: ignore[no-any-return]  # no float(): complex-safe


@jitable
def state(K: Array, inertia: Array, y: Array, y_dot: Array, theta: Array, u: Array) -> float:
    """Inverse map: y (N,), y' (N,) -> theta (N + 1,) [rad], u (N - 1,) [rad/s], written;
    returns sigma. inf/nan where D = 0 (the singular set)."""
    _joints(y, y_dot, theta, u)
    h0, h, grad, _ = _terms(K, inertia, theta)
    return _invert(K, inertia, h0, h, grad, y, y_dot, theta, u)


@jitable
def _joints(y: Array, y_dot: Array, theta: Array, u: Array) -> None:
    """th_j = y_j, u_j = y_j' (j < N) into theta and u; th0 = th_N = 0 for now (h_0, h_j and
    grad do not depend on them: d_N = 0)."""
    n = theta.shape[0] - 1
    theta[0] = 0.0
    for j in range(1, n):
        theta[j] = y[j - 1]
        u[j - 1] = y_dot[j - 1]
    theta[n] = 0.0


@jitable
def _invert(K: Array, inertia: Array, h0: float, h: Array, grad: Array, y: Array,
            y_dot: Array, theta: Array, u: Array) -> float:
    """th_N and th0 into theta from y, y' (theta's joints and u set), given the terms at q;
    returns sigma."""
    n = theta.shape[0] - 1
    s, d = _sums(h, grad, u)
    i_n = inertia[n]
    theta[n] = -h0 * (s + y_dot[n - 1] * h0) / (i_n * d)
    theta[0] = y[n - 1] - i_n * theta[n] / h0
    return -d / (2.0 * K[1, 0])  # type: ignore[no-any-return]  # no float(): complex-safe


@jitable
def inputs(K: Array, inertia: Array, theta: Array, u: Array, v: Array, u_dot: Array) -> float:
    """Inputs that make y'' = v (N,) at a state: u' (N - 1,) [rad/s^2] written, and th_N'
    [rad/s] returned; inf/nan where D = 0.

    y_N' = F(q, u, th_N) = -S / h_0 - I_N th_N D / h_0^2, so y_N'' = alpha + beta th_N' with
    beta = dF/dth_N = -I_N D / h_0^2 and alpha = sum_k (dF/dq_k u_k + dF/du_k v_k):
    dF/du_k = -h_k / h_0 - I_N th_N (dh_0/dq_k) / h_0^2,
    dF/dq_k = -(dS/dq_k) / h_0 + S (dh_0/dq_k) / h_0^2
              - I_N th_N ((dD/dq_k) / h_0^2 - 2 D (dh_0/dq_k) / h_0^3),
    dS/dq_k = sum_j (dh_j/dq_k) u_j, dD/dq_k = sum_j (d^2 h_0 / dq_j dq_k) u_j.
    """
    h0, h, grad, hess, slopes = terms(K, inertia, theta)
    return inputs_given(inertia, h0, h, grad, hess, slopes, theta, u, v, u_dot)


@jitable
def inputs_given(inertia: Array, h0: float, h: Array, grad: Array, hess: Array,
                  slopes: Array, theta: Array, u: Array, v: Array, u_dot: Array) -> float:
    """``inputs`` given the terms at q (``terms``)."""
    n = theta.shape[0] - 1
    s, d = _sums(h, grad, u)
    i_n = inertia[n]
    th_n = theta[n]
    inv = 1.0 / h0
    alpha = 0.0
    for k in range(1, n):
        ds = 0.0
        dd = 0.0
        for j in range(1, n):
            ds += slopes[j, k - 1] * u[j - 1]
            dd += hess[j - 1, k - 1] * u[j - 1]
        g = grad[k - 1]
        df_dq = -ds * inv + s * g * inv * inv - i_n * th_n * (dd * inv * inv
                                                              - 2.0 * d * g * inv * inv * inv)
        df_du = -h[k] * inv - i_n * th_n * g * inv * inv
        alpha += df_dq * u[k - 1] + df_du * v[k - 1]
        u_dot[k - 1] = v[k - 1]
    beta = -i_n * d * inv * inv
    return (v[n - 1] - alpha) / beta  # type: ignore[no-any-return]  # complex-safe


@jitable
def flag_state(K: Array, inertia: Array, y: Array, y_dot: Array, y_ddot: Array, theta: Array,
               theta_dot: Array, u_dot: Array) -> float:
    """The flat flag (y, y', y'') (N,) each -> the state's angles theta (N + 1,) and their
    exact time derivatives theta_dot (N + 1,) [rad/s], and u' (N - 1,) [rad/s^2], written;
    returns sigma. The one map from the flag to states and inputs, for any N.

    th_j' = y_j' (j < N), th_N' from ``inputs`` with v = y'', and th0' the time derivative of
    th0 = y_N - I_N th_N / h_0: th0' = y_N' - I_N (th_N' h_0 - th_N D) / h_0^2 (not the
    momentum constraint).
    """
    n = theta.shape[0] - 1
    u = np.empty(n - 1, dtype=y.dtype)
    sigma = state(K, inertia, y, y_dot, theta, u)
    th_n_dot = inputs(K, inertia, theta, u, y_ddot, u_dot)
    h0, _, grad, _ = _terms(K, inertia, theta)
    _rates(inertia, h0, grad, theta, u, y_dot, th_n_dot, theta_dot)
    return sigma


@jitable
def flag_state_given(K: Array, inertia: Array, h0: float, h: Array, grad: Array, hess: Array,
                     slopes: Array, y: Array, y_dot: Array, y_ddot: Array, theta: Array,
                     theta_dot: Array, u_dot: Array) -> float:
    """``flag_state`` given ``terms`` at q = (y_1..y_N-1), computed once and shared by the
    three steps (``flag_state`` evaluates them per step, at th0 = th_N = 0 and then at the
    state's th0, th_N: the same up to rounding). A complex-step derivative along a flag
    component other than q passes the real terms: only q enters them.
    """
    n = theta.shape[0] - 1
    u = np.empty(n - 1, dtype=y.dtype)
    _joints(y, y_dot, theta, u)
    sigma = _invert(K, inertia, h0, h, grad, y, y_dot, theta, u)
    th_n_dot = inputs_given(inertia, h0, h, grad, hess, slopes, theta, u, y_ddot, u_dot)
    _rates(inertia, h0, grad, theta, u, y_dot, th_n_dot, theta_dot)
    return sigma


@jitable
def _rates(inertia: Array, h0: float, grad: Array, theta: Array, u: Array, y_dot: Array,
           th_n_dot: float, theta_dot: Array) -> None:
    """theta_dot (N + 1,) from u, th_N' and y_N' (see ``flag_state``)."""
    n = theta.shape[0] - 1
    d = 0.0
    for j in range(1, n):
        theta_dot[j] = u[j - 1]
        d += grad[j - 1] * u[j - 1]
    theta_dot[n] = th_n_dot
    i_n = inertia[n]
    theta_dot[0] = y_dot[n - 1] - i_n * (th_n_dot * h0 - theta[n] * d) / (h0 * h0)
