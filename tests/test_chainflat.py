"""Tests of flatcli.core.models.chainflat: the N-link flat maps.

References: for N = 2, the paper's closed-form maps (``flatness``, themselves checked against
a sympy derivation in tests/test_model.py and tests/test_flatness.py); for any N, the
constrained flow itself: integrating th0' from the full-kinematics momentum H = 0
(``chain.chain_momentum``, which uses no weights h_j), the flat outputs must move with the
rates and accelerations the maps claim (fourth-order central differences along the flow).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from flatcli.core.models import chainflat
from flatcli.core.models.flatness import flat_inputs, flat_outputs, flat_state
from flatcli.core.robots.chain import barycentric_matrix, chain_momentum
from flatcli.core.robots.params import PAPER_ROBOT

Array = NDArray[np.float64]

#: Round trips: rounding, amplified by 1 / D near the singular set (kept away from here).
ROUND_TRIP = 1e-10
#: Fourth-order central differences with step 1e-3 along a smooth flow: truncation ~1e-12
#: times the fifth derivative, relative ~1e-8 at the rates used here.
FLOW_RTOL = 1e-7


def chain(n: int, seed: int) -> tuple[Array, Array, Array, Array, Array]:
    """A random counterweighted chain: mass, inertia, length, com (d_N = 0), K."""
    rng = np.random.default_rng(seed)
    mass = rng.uniform(0.5, 2.0, n + 1)
    inertia = rng.uniform(0.01, 0.1, n + 1)
    length = rng.uniform(0.1, 0.4, n + 1)
    com = rng.uniform(0.02, 0.3, n + 1)
    com[-1] = 0.0
    return mass, inertia, length, com, barycentric_matrix(mass, length, com)


def test_two_links_are_the_papers_maps() -> None:
    r = PAPER_ROBOT
    mass, inertia, length, com = (np.array(v, dtype=float) for v in
                                  (r.mass, r.inertia, r.length, r.com))
    K = barycentric_matrix(mass, length, com)
    k = r.coefficients()
    rng = np.random.default_rng(0)
    for _ in range(50):
        th = rng.uniform(-3, 3, 3)
        th[1] = rng.uniform(0.3, 2.8)
        u = rng.uniform(0.2, 2.0, 1)
        v = rng.uniform(-5, 5, 2)
        y, y_dot = np.empty(2), np.empty(2)
        sigma = chainflat.outputs(K, inertia, th, u, y, y_dot)
        expected = flat_outputs(k, *th, u[0])
        np.testing.assert_allclose([*y, *y_dot], expected, rtol=1e-12, atol=1e-13)
        assert sigma == pytest.approx(np.sin(th[1]) * u[0], rel=1e-12)
        back, ub = np.empty(3), np.empty(1)
        chainflat.state(K, inertia, y, y_dot, back, ub)
        np.testing.assert_allclose([*back, *ub], flat_state(k, *expected), rtol=1e-10,
                                   atol=1e-10)
        u_dot = np.empty(1)
        th_n_dot = chainflat.inputs(K, inertia, th, u, v, u_dot)
        reference = flat_inputs(k, th[1], th[2], u[0], *v)
        assert u_dot[0] == reference[0]
        assert th_n_dot == pytest.approx(reference[1], rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("n", [3, 4, 6])
def test_the_inverse_map_inverts_the_forward_map(n: int) -> None:
    _, inertia, _, _, K = chain(n, n)
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(40):
        th = rng.uniform(-2.5, 2.5, n + 1)
        u = rng.uniform(-1.5, 1.5, n - 1)
        y, y_dot = np.empty(n), np.empty(n)
        sigma = chainflat.outputs(K, inertia, th, u, y, y_dot)
        if abs(sigma) < 0.05:
            continue  # near the singular set 1/D amplifies rounding
        back, ub = np.empty(n + 1), np.empty(n - 1)
        assert chainflat.state(K, inertia, y, y_dot, back, ub) == pytest.approx(sigma, rel=1e-12)
        np.testing.assert_allclose(back, th, rtol=ROUND_TRIP, atol=ROUND_TRIP)
        np.testing.assert_allclose(ub, u, rtol=ROUND_TRIP, atol=ROUND_TRIP)
        checked += 1
    assert checked > 20


def base_rate(mass: Array, inertia: Array, length: Array, com: Array, th: Array,
              joint_rates: Array) -> float:
    """th0' that makes the full-kinematics H zero (H is linear in the rates)."""
    rates = np.concatenate([[0.0], joint_rates])
    h_joints = chain_momentum(mass, inertia, length, com, th, rates)
    h_base = chain_momentum(mass, inertia, length, com, th, np.eye(len(th))[0])
    return float(-h_joints / h_base)


@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_outputs_move_with_the_rates_and_inputs_they_claim(n: int) -> None:
    """Along the constrained flow (th0' from H = 0 by the full kinematics, th_j' = u_j,
    u_j' = v_j, th_N' = what ``inputs`` returns for v, held), y' is ``outputs``' rate and
    y'' = v: both by fourth-order central differences of ``outputs`` along the flow."""
    mass, inertia, length, com, K = chain(n, 10 + n)
    rng = np.random.default_rng(2)
    th = rng.uniform(-2.0, 2.0, n + 1)
    th[1] = 1.0
    u = rng.uniform(0.5, 1.5, n - 1)
    v = rng.uniform(-1.0, 1.0, n)
    u_dot = np.empty(n - 1)
    th_n_dot = chainflat.inputs(K, inertia, th, u, v, u_dot)
    np.testing.assert_array_equal(u_dot, v[:-1])

    def flow(s: float) -> tuple[Array, Array]:
        """The state moved by s along its rates at t = 0: right to first order, which is all
        the first derivative of y at 0 sees."""
        rates = np.concatenate([[0.0], u, [th_n_dot]])
        th0_rate = base_rate(mass, inertia, length, com, th, rates[1:])
        x = th + s * np.concatenate([[th0_rate], rates[1:]])
        return x, u + s * v[:-1]

    def y_at(s: float) -> Array:
        x, uu = flow(s)
        y, y_dot = np.empty(n), np.empty(n)
        chainflat.outputs(K, inertia, x, uu, y, y_dot)
        return y

    h = 1e-3
    points = [y_at(k * h) for k in (-2, -1, 0, 1, 2)]
    first = (points[0] - 8 * points[1] + 8 * points[3] - points[4]) / (12 * h)
    y, y_dot = np.empty(n), np.empty(n)
    chainflat.outputs(K, inertia, th, u, y, y_dot)
    np.testing.assert_allclose(first, y_dot, rtol=FLOW_RTOL, atol=FLOW_RTOL)

    accel = second_derivative_along_flow(mass, inertia, length, com, K, th, u, v, th_n_dot)
    np.testing.assert_allclose(accel, v, rtol=1e-5, atol=1e-6)


def second_derivative_along_flow(mass: Array, inertia: Array, length: Array, com: Array,
                                 K: Array, th: Array, u: Array, v: Array,
                                 th_n_dot: float) -> Array:
    """y'' at t = 0 by integrating the constrained flow (RK4, tiny steps) over +-2 h and
    taking fourth-order central differences of y; th0' from the full-kinematics H = 0 at
    every stage, th_j' = u_j, u_j' = v_j, th_N' held at ``th_n_dot``."""
    n = len(th) - 1

    def rates(x: Array) -> Array:
        uu = x[n + 1:]
        joints = np.concatenate([uu, [th_n_dot]])
        th0_rate = base_rate(mass, inertia, length, com, x[: n + 1], joints)
        return np.concatenate([[th0_rate], joints, v[:-1]])

    def integrate(x: Array, t: float, steps: int = 40) -> Array:
        dt = t / steps
        for _ in range(steps):
            k1 = rates(x)
            k2 = rates(x + 0.5 * dt * k1)
            k3 = rates(x + 0.5 * dt * k2)
            k4 = rates(x + dt * k3)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return x

    h = 2e-3
    x0 = np.concatenate([th, u])
    ys = []
    for k in (-2, -1, 0, 1, 2):
        x = integrate(x0, k * h) if k else x0
        y, y_dot = np.empty(n), np.empty(n)
        chainflat.outputs(K, inertia, x[: n + 1], x[n + 1:], y, y_dot)
        ys.append(y)
    return np.asarray((-ys[0] + 16 * ys[1] - 30 * ys[2] + 16 * ys[3] - ys[4]) / (12 * h * h))
