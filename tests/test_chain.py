"""Tests of flatcli.core.robots.chain: the N-link chain's momentum, against a sympy derivation.

The referee derives H for N = 2..6 from the link kinematics with sympy: each link's centre
of mass placed along the chain from the base's joint O0, velocities by the chain rule through
the angles, H = sum_i m_i r_i x v_i - M r_c x v_c + sum_i I_i w_i about the system centre of
mass. Nothing of the barycentric matrix K or the weights h_j enters it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import sympy as sp
from numpy.typing import NDArray

from flatcli.core.robots.chain import (
    barycentric_matrices,
    barycentric_matrix,
    base_inertia_slopes,
    chain_momentum,
    momentum_weights,
    weight_slopes,
)
from flatcli.core.robots.params import PAPER_ROBOT, momentum

Array = NDArray[np.float64]

#: Numbers that only rounding separates (sums of ~N^2 terms of size ~0.1).
RTOL = 1e-11


def derivation(params: tuple[Array, ...]) -> tuple[Callable[..., Array], Callable[..., Array]]:
    """The weights h_j = dH/dth_j' and the gradient of h_0 in th_1..th_N, derived with sympy
    for one chain (its parameters as exact numbers) and lambdified in the angles."""
    mass, inertia, length, com = params
    n = len(mass) - 1
    q = sp.symbols(f"q0:{n + 1}")  # th0 .. thN
    psi = [sum(q[: a + 1]) for a in range(n + 1)]
    m = [sp.Float(v) for v in mass]
    # centres of mass relative to O0; velocities by the chain rule through the angles
    xs = [sum(sp.Float(length[a]) * sp.cos(psi[a]) for a in range(i))
          + sp.Float(com[i]) * sp.cos(psi[i]) for i in range(n + 1)]
    ys = [sum(sp.Float(length[a]) * sp.sin(psi[a]) for a in range(i))
          + sp.Float(com[i]) * sp.sin(psi[i]) for i in range(n + 1)]
    total = sum(m)
    X = sum(mi * x for mi, x in zip(m, xs, strict=True))
    Y = sum(mi * y for mi, y in zip(m, ys, strict=True))
    weights = []
    for j in range(n + 1):  # H = sum_j w_j th_j': sum_i m_i r_i x dr_i/dth_j - M r_c x dr_c/dth_j
        dx = [sp.diff(x, q[j]) for x in xs]
        dy = [sp.diff(y, q[j]) for y in ys]
        w = sum(mi * (x * ddy - y * ddx) for mi, x, y, ddx, ddy in zip(m, xs, ys, dx, dy,
                                                                       strict=True))
        w -= (X * sum(mi * d for mi, d in zip(m, dy, strict=True))
              - Y * sum(mi * d for mi, d in zip(m, dx, strict=True))) / total
        w += sum(sp.Float(inertia[i]) for i in range(j, n + 1))  # spins of the links moved
        weights.append(w)
    grad = [sp.diff(weights[0], q[k]) for k in range(1, n + 1)]
    return sp.lambdify((q,), weights, "numpy"), sp.lambdify((q,), grad, "numpy")


def random_chain(n: int, rng: np.random.Generator, last_on_joint: bool) -> tuple[Array, ...]:
    mass = rng.uniform(0.5, 2.0, n + 1)
    inertia = rng.uniform(0.01, 0.1, n + 1)
    length = rng.uniform(0.1, 0.4, n + 1)
    com = rng.uniform(-0.05, 0.3, n + 1)
    if last_on_joint:
        com[-1] = 0.0
    return mass, inertia, length, com


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
@pytest.mark.parametrize("last_on_joint", [True, False])
def test_momentum_and_its_weights_equal_the_symbolic_derivation(n: int,
                                                                last_on_joint: bool) -> None:
    """h_j, H and grad h_0 against sympy; the Hessian of h_0 against central differences of
    the symbolic gradient (step 1e-5: error ~1e-10)."""
    rng = np.random.default_rng(100 + n)
    params = random_chain(n, rng, last_on_joint)
    weights, grad = derivation(params)
    K = barycentric_matrix(params[0], params[2], params[3])
    for _ in range(5):
        th = rng.uniform(-np.pi, np.pi, n + 1)
        rates = rng.uniform(-2.0, 2.0, n + 1)
        expected = np.asarray(weights(th), dtype=float)
        h = np.empty(n + 1)
        momentum_weights(K, params[1], th, h)
        np.testing.assert_allclose(h, expected, rtol=RTOL, atol=1e-14)
        H = float(expected @ rates)
        assert chain_momentum(*params, th, rates) == pytest.approx(H, rel=RTOL, abs=1e-14)
        g, hs = np.empty(n), np.empty((n, n))
        h0 = base_inertia_slopes(K, params[1], th, g, hs)
        assert h0 == pytest.approx(expected[0], rel=RTOL)
        np.testing.assert_allclose(g, np.asarray(grad(th), dtype=float), rtol=RTOL, atol=1e-14)
        step = 1e-5
        for k in range(1, n + 1):
            up, down = th.copy(), th.copy()
            up[k] += step
            down[k] -= step
            column = (np.asarray(grad(up)) - np.asarray(grad(down))) / (2 * step)
            np.testing.assert_allclose(hs[:, k - 1], column, atol=1e-8)


@pytest.mark.parametrize("n", [2, 3, 5])
def test_weight_slopes_are_the_derivatives_of_the_weights(n: int) -> None:
    """Against central differences of momentum_weights (step 1e-6: error ~1e-12)."""
    rng = np.random.default_rng(7)
    params = random_chain(n, rng, last_on_joint=False)
    K = barycentric_matrix(params[0], params[2], params[3])
    th = rng.uniform(-np.pi, np.pi, n + 1)
    slopes = np.empty((n + 1, n))
    weight_slopes(K, th, slopes)
    step = 1e-6
    for k in range(1, n + 1):
        up, down = th.copy(), th.copy()
        up[k] += step
        down[k] -= step
        hu, hd = np.empty(n + 1), np.empty(n + 1)
        momentum_weights(K, params[1], up, hu)
        momentum_weights(K, params[1], down, hd)
        np.testing.assert_allclose(slopes[:, k - 1], (hu - hd) / (2 * step), atol=1e-9)


@pytest.mark.parametrize("n", [2, 4])
def test_a_counterweighted_last_link_decouples_its_joint(n: int) -> None:
    """d_N = 0: K's last row and column vanish, h_N = I_N, and no weight depends on th_N."""
    rng = np.random.default_rng(3)
    mass, inertia, length, com = random_chain(n, rng, last_on_joint=True)
    K = barycentric_matrix(mass, length, com)
    np.testing.assert_allclose(K[-1], 0.0, atol=1e-15)
    th = rng.uniform(-3, 3, n + 1)
    h, turned = np.empty(n + 1), np.empty(n + 1)
    momentum_weights(K, inertia, th, h)
    th[-1] += 1.234
    momentum_weights(K, inertia, th, turned)
    np.testing.assert_array_equal(h, turned)
    assert h[-1] == inertia[-1]


def test_the_papers_robot_is_the_two_link_chain() -> None:
    """N = 2 with the paper's robot: K_10 = a1 / (2 M) (the paper's a1 coefficient, model.py)
    and H equals the three-link momentum of model.py."""
    r = PAPER_ROBOT
    mass, inertia, length, com = (np.array(v, dtype=float) for v in
                                  (r.mass, r.inertia, r.length, r.com))
    K = barycentric_matrix(mass, length, com)
    assert 2 * K[1, 0] == pytest.approx(r.coefficients().a1 / r.total_mass, rel=1e-14)
    th, rates = np.array([0.2, 1.1, -0.7]), np.array([0.3, -0.5, 2.0])
    assert chain_momentum(mass, inertia, length, com, th, rates) == pytest.approx(
        float(momentum(r.links, *th, *rates)), rel=1e-14)


@pytest.mark.parametrize("n", [2, 3, 6])
def test_the_barycentric_matrix_in_python_is_the_compiled_one_to_the_bit(n: int) -> None:
    """``barycentric_matrix`` run as Python (what the paper's loop builds its nominal K
    with, ``controllers.paper.paper_shared``) against the compiled batch ``barycentric_matrices``,
    on 50 random chains of each size: the same IEEE operations in the same order, so the
    same bits."""
    rng = np.random.default_rng(n)
    chains = [random_chain(n, rng, last_on_joint=bool(k % 2)) for k in range(50)]
    params = np.array([np.concatenate(c) for c in chains])
    compiled = barycentric_matrices(params)
    for k, (mass, _inertia, length, com) in enumerate(chains):
        python = barycentric_matrix(mass, length, com)
        assert python.tobytes() == compiled[k].tobytes()
