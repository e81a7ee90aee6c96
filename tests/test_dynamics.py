"""Tests of flatcli.core.robots.dynamics: the free-floating chain's M(q) and C(q, q') q'.

References, none of them the code under test:

* a sympy Lagrangian derived in this module from the link positions (each centre of mass
  placed along the chain joint by joint, taken relative to the system centre of mass,
  differentiated symbolically): M = d^2 T / dq' dq', C q' = d/dq (dT/dq') q' - dT/dq;
* ``core.robots.params.momentum``, H from the full link kinematics (itself checked against an
  inertial-frame sympy derivation in tests/test_model.py);
* the kinetic energy summed over the links' centre-of-mass velocities and spins
  (``link_kinetic_energy`` below), and numpy's linear algebra.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import pytest
import sympy as sp
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.robots.dynamics import (
    Chain,
    bias_forces,
    forward_dynamics,
    inverse_dynamics,
    joint_space,
    kinetic_energy,
    make_chain,
    mass_matrix,
    solve_spd,
    three_body,
    three_body_joint_space,
    three_body_terms,
)
from flatcli.core.robots.params import PAPER_ROBOT, Links, RobotParams, momentum
from tests.referees import base_row_momentum

Array = NDArray[np.float64]


#: Agreement with the symbolic derivation and between formulations (relative to the largest
#: entry): rounding of sums of a few dozen terms.
EXACT = 1e-12
#: Random designs and states per check.
DRAWS = 12


@functools.cache
def lagrangian(n: int, bias: bool = True) -> tuple[Callable[..., Array], Callable[..., Array]]:
    """M(q) and C(q, q') q' of an n-body chain from its Lagrangian (sympy), as functions of
    (q, q', m, I, l, d); C is None when ``bias`` is False (the n = 4 case checks M only,
    for time)."""
    q = sp.symbols(f"q0:{n}")
    qd = sp.symbols(f"qd0:{n}")
    m = sp.symbols(f"m0:{n}", positive=True)
    inertia = sp.symbols(f"I0:{n}", positive=True)
    length = sp.symbols(f"l0:{n}", positive=True)
    com = sp.symbols(f"d0:{n}")
    joint = sp.Matrix([0, 0])  # O_a, from O_0 at the origin (the system CoM is subtracted)
    psi = sp.Integer(0)
    centres, spins = [], []
    for a in range(n):
        psi = psi + q[a]
        e = sp.Matrix([sp.cos(psi), sp.sin(psi)])
        centres.append(joint + com[a] * e)
        joint = joint + length[a] * e
        spins.append(sum(qd[: a + 1]))
    total = sum(m)
    system = sum((m[i] * centres[i] for i in range(n)), sp.zeros(2, 1)) / total
    T = sp.Integer(0)
    for i in range(n):
        r = centres[i] - system
        v = sum((r.diff(q[k]) * qd[k] for k in range(n)), sp.zeros(2, 1))
        T += m[i] * (v.T * v)[0] / 2 + inertia[i] * spins[i] ** 2 / 2
    M = sp.Matrix(n, n, lambda j, k: sp.diff(T, qd[j], qd[k]))
    args = (q, qd, m, inertia, length, com)
    f_M = sp.lambdify(args, M, "numpy", cse=True)
    if not bias:
        return f_M, None  # type: ignore[return-value]
    p = [sp.diff(T, qd[j]) for j in range(n)]
    C = sp.Matrix([sum(sp.diff(p[j], q[k]) * qd[k] for k in range(n)) - sp.diff(T, q[j])
                   for j in range(n)])
    return f_M, sp.lambdify(args, C, "numpy", cse=True)


def random_design(rng: np.random.Generator, n: int) -> tuple[Array, Array, Array, Array]:
    """Masses, inertias, lengths and centre-of-mass distances of a random n-body chain, d_i
    of either sign and off the link (d2 != 0 included)."""
    return (rng.uniform(0.3, 3.0, n), rng.uniform(0.005, 0.2, n), rng.uniform(0.1, 0.6, n),
            rng.uniform(-0.2, 0.5, n))


def link_kinetic_energy(p: Links, q: Array, qd: Array) -> Array:
    """T = 1/2 sum_i (m_i |v_i - v_c|^2 + I_i w_i^2) from each link's centre-of-mass velocity
    (the chain rule on the positions of ``model.momentum``'s kinematics, written anew here),
    q, qd (..., 3)."""
    psi = np.cumsum(q, axis=-1)
    w = np.cumsum(qd, axis=-1)

    def e_dot(a: int) -> Array:  # d/dt (cos psi_a, sin psi_a)
        return np.stack([-np.sin(psi[..., a]), np.cos(psi[..., a])], -1) * w[..., a, None]

    v0 = p.d0 * e_dot(0)
    v1 = p.l0 * e_dot(0) + p.d1 * e_dot(1)
    v2 = p.l0 * e_dot(0) + p.l1 * e_dot(1) + p.d2 * e_dot(2)
    total = p.m0 + p.m1 + p.m2
    vc = (p.m0 * v0 + p.m1 * v1 + p.m2 * v2) / total
    T = 0.0
    for m, v in ((p.m0, v0), (p.m1, v1), (p.m2, v2)):
        T = T + 0.5 * m * np.sum((v - vc) ** 2, axis=-1)
    return np.asarray(T + 0.5 * (p.i0 * w[..., 0] ** 2 + p.i1 * w[..., 1] ** 2
                                 + p.i2 * w[..., 2] ** 2))


def robot_chain(robot: RobotParams) -> Chain:
    return make_chain(robot.mass, robot.inertia, robot.length, robot.com)


@pytest.mark.parametrize("n", [2, 3])
def test_mass_matrix_and_bias_equal_the_symbolic_lagrangian(n: int) -> None:
    """Random designs (d_i of either sign, so d2 != 0) and states, n = 2 and 3 bodies."""
    f_M, f_C = lagrangian(n)
    rng = np.random.default_rng(n)
    for _ in range(DRAWS):
        m, inertia, length, com = random_design(rng, n)
        q = rng.uniform(-4, 4, n)
        qd = rng.uniform(-5, 5, n)
        chain = make_chain(m, inertia, length, com)
        M_ref = np.array(f_M(q, qd, m, inertia, length, com), dtype=float)
        C_ref = np.array(f_C(q, qd, m, inertia, length, com), dtype=float).ravel()
        np.testing.assert_allclose(mass_matrix(chain, q), M_ref, rtol=0,
                                   atol=EXACT * np.abs(M_ref).max())
        np.testing.assert_allclose(bias_forces(chain, q, qd), C_ref, rtol=0,
                                   atol=EXACT * np.abs(C_ref).max())


def test_four_body_mass_matrix_equals_the_symbolic_lagrangian() -> None:
    """The chain is general: four bodies (issue 13's robots), M against sympy."""
    f_M, _ = lagrangian(4, bias=False)
    rng = np.random.default_rng(4)
    for _ in range(DRAWS):
        m, inertia, length, com = random_design(rng, 4)
        q = rng.uniform(-4, 4, 4)
        M_ref = np.array(f_M(q, np.zeros(4), m, inertia, length, com), dtype=float)
        np.testing.assert_allclose(mass_matrix(make_chain(m, inertia, length, com), q), M_ref,
                                   rtol=0, atol=EXACT * np.abs(M_ref).max())


def test_four_body_bias_conserves_energy_and_momentum() -> None:
    """With no torque, T and H stay constant along the motion: d/dt T = q'^T (M q'' + 1/2
    M' q') = 0 needs C exactly right. Checked at an instant for four bodies: the rates of
    change of T and H computed from M at q + q' dt (central difference, dt = 1e-6 s) and
    q'' = forward_dynamics(tau = 0) vanish."""
    rng = np.random.default_rng(44)
    dt = 1e-6
    for _ in range(DRAWS):
        chain = make_chain(*random_design(rng, 4))
        q = rng.uniform(-4, 4, 4)
        qd = rng.uniform(-3, 3, 4)
        qdd = forward_dynamics(chain, q, qd, np.zeros(3))
        states = [(q + s * qd * dt + 0.5 * qdd * (s * dt) ** 2, qd + s * qdd * dt)
                  for s in (-1.0, 1.0)]
        T = [float(kinetic_energy(chain, a, b)) for a, b in states]
        H = [float(base_row_momentum(chain, a, b)) for a, b in states]
        scale_T = float(kinetic_energy(chain, q, qd))
        assert abs(T[1] - T[0]) / (2 * dt) <= 1e-6 * scale_T * np.abs(qd).max()
        assert abs(H[1] - H[0]) / (2 * dt) <= 1e-6 * abs(scale_T)


def test_momentum_is_the_full_kinematics_momentum() -> None:
    """H = (M q')_0 against ``model.momentum`` for random three-link designs (d2 != 0)."""
    rng = np.random.default_rng(7)
    for _ in range(DRAWS):
        m, inertia, length, com = random_design(rng, 3)
        robot = RobotParams(m, inertia, length, com)
        q = rng.uniform(-4, 4, (5, 3))
        qd = rng.uniform(-5, 5, (5, 3))
        H = base_row_momentum(robot_chain(robot), q, qd)
        reference = momentum(robot.links, *q.T, *qd.T)
        np.testing.assert_allclose(H, reference, rtol=0, atol=EXACT * np.abs(reference).max())


def test_kinetic_energy_is_the_link_kinetic_energy() -> None:
    rng = np.random.default_rng(8)
    for _ in range(DRAWS):
        robot = RobotParams(*random_design(rng, 3))
        q = rng.uniform(-4, 4, (5, 3))
        qd = rng.uniform(-5, 5, (5, 3))
        T = kinetic_energy(robot_chain(robot), q, qd)
        np.testing.assert_allclose(T, link_kinetic_energy(robot.links, q, qd), rtol=EXACT)


def test_three_body_terms_equal_the_general_chain() -> None:
    """The written-out n = 3 sums the compiled loop uses are the general chain's."""
    rng = np.random.default_rng(9)
    for _ in range(DRAWS):
        robot = RobotParams(*random_design(rng, 3))
        q = rng.uniform(-4, 4, 3)
        qd = rng.uniform(-5, 5, 3)
        chain = robot_chain(robot)
        M, c = mass_matrix(chain, q), bias_forces(chain, q, qd)
        got = three_body_terms(three_body(robot.links), np.cos(q[1]), np.sin(q[1]),
                               np.cos(q[2]), np.sin(q[2]), *qd)
        expected = (M[0, 0], M[0, 1], M[0, 2], M[1, 1], M[1, 2], M[2, 2], *c)
        scale = max(np.abs(M).max(), np.abs(c).max())
        np.testing.assert_allclose(got, expected, rtol=0, atol=EXACT * scale)
        hat = np.empty((2, 2))
        chat = np.empty(2)
        joint_space(M, c, hat, chat)
        np.testing.assert_allclose(three_body_joint_space(*got),
                                   (hat[0, 0], hat[0, 1], hat[1, 1], chat[0], chat[1]),
                                   rtol=0, atol=EXACT * scale)


def test_mass_matrix_is_symmetric_positive_definite_and_ignores_th0() -> None:
    rng = np.random.default_rng(10)
    for n in (2, 3, 5):
        chain = make_chain(*random_design(rng, n))
        q = rng.uniform(-4, 4, (20, n))
        M = mass_matrix(chain, q)
        np.testing.assert_allclose(M, np.swapaxes(M, -1, -2), rtol=0, atol=1e-15)
        assert np.all(np.linalg.eigvalsh(M) > 0)
        shifted = q.copy()
        shifted[:, 0] += 100.0
        np.testing.assert_allclose(mass_matrix(chain, shifted), M, rtol=0, atol=1e-15)


def test_joint_space_inertia_is_the_schur_complement() -> None:
    """Mhat = M_jj - M_jb M_bj / M_bb has the inverse (M^-1)_jj (block inversion)."""
    rng = np.random.default_rng(11)
    for n in (2, 3, 5):
        chain = make_chain(*random_design(rng, n))
        q = rng.uniform(-4, 4, n)
        qd = rng.uniform(-3, 3, n)
        M, c = mass_matrix(chain, q), bias_forces(chain, q, qd)
        hat = np.empty((n - 1, n - 1))
        chat = np.empty(n - 1)
        joint_space(M, c, hat, chat)
        np.testing.assert_allclose(np.linalg.inv(hat), np.linalg.inv(M)[1:, 1:], rtol=1e-10)


def test_forward_dynamics_inverts_the_inverse_dynamics_with_the_base_unactuated() -> None:
    rng = np.random.default_rng(12)
    for n in (2, 3, 5):
        chain = make_chain(*random_design(rng, n))
        q = rng.uniform(-4, 4, (6, n))
        qd = rng.uniform(-3, 3, (6, n))
        tau = rng.uniform(-2, 2, (6, n - 1))
        qdd = forward_dynamics(chain, q, qd, tau)
        Q = inverse_dynamics(chain, q, qd, qdd)
        np.testing.assert_allclose(Q[:, 0], 0.0, atol=1e-12)
        np.testing.assert_allclose(Q[:, 1:], tau, rtol=1e-10, atol=1e-12)


def test_solve_spd_equals_numpy() -> None:
    rng = np.random.default_rng(13)
    for m in (1, 2, 4):
        a = rng.normal(size=(m, m))
        A = a @ a.T + m * np.eye(m)
        b = rng.normal(size=m)
        x = np.empty(m)
        solve_spd(A.copy(), b.copy(), m, x)
        np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-12)


def test_paper_robot_chain_is_its_links() -> None:
    """make_chain of the paper's robot and the kernels' three_body agree."""
    chain = robot_chain(PAPER_ROBOT)
    b = three_body(PAPER_ROBOT.links)
    K = chain.coupling
    assert (b.k00, b.k01, b.k02, b.k11, b.k12, b.k22) == (K[0, 0], K[0, 1], K[0, 2], K[1, 1],
                                                          K[1, 2], K[2, 2])
    assert (b.i0, b.i1, b.i2) == tuple(PAPER_ROBOT.inertia)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"mass": [1.0, 0.0, 1.0]}, "mass: every value must be > 0"),
        ({"inertia": [1.0, 1.0]}, "the same number of bodies"),
        ({"length": [1.0]}, "n >= 2"),
        ({"com": [0.1, np.nan, 0.0]}, "must be finite"),
    ],
)
def test_make_chain_rejects_bad_designs(changes: dict[str, list[float]], match: str) -> None:
    values = {"mass": [1.0, 1.0, 1.0], "inertia": [0.1, 0.1, 0.1], "length": [0.2, 0.2, 0.2],
              "com": [0.1, 0.1, 0.0], **changes}
    with pytest.raises(FlatcliError, match=match):
        make_chain(**values)
