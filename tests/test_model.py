"""Tests of flatcli.core.robots.params: coefficients, momentum, base rate, design check, parameters.

The referee is an independent symbolic derivation of the angular momentum from the link
kinematics in the inertial frame (``derivation`` below), not the paper's formulas.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import pytest
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from sympy import QQ
from sympy.polys.rings import PolyElement, PolyRing, ring

from flatcli.core.errors import FlatcliError
from flatcli.core.names import MODELS
from flatcli.core.robots.chain import barycentric_matrix
from flatcli.core.robots.params import (
    PAPER_ROBOT,
    Links,
    RobotParams,
    base_rate,
    constraint_coefficients,
    flatness_check,
    momentum,
    require_flat,
)

Array = NDArray[np.float64]

#: Coefficients and H evaluated at floats vs the exact symbolic result: rounding only.
NUMERIC_RTOL = 1e-12
#: Printed example values that are exact decimals (0.5597 = 3 * 0.1599 + 0.08, ...).
EXAMPLE_ATOL = 1e-12
#: Momentum conservation through base_rate, relative to the size of the cancelling terms.
CONSERVATION_RTOL = 1e-10


# --------------------------------------------------------------------------------------
# The symbolic referee
# --------------------------------------------------------------------------------------


class Derivation(NamedTuple):
    """H of the free-floating chain, derived in the inertial frame (see ``derivation``)."""

    R: PolyRing
    gens: dict[str, PolyElement]
    M2H: PolyElement  # M^2 H, polynomial in parameters, c_i, s_i and rates q_i
    h: tuple[PolyElement, PolyElement, PolyElement]  # M^2 dH/dq_j
    ideal: list[PolyElement]  # s_i^2 + c_i^2 - 1


@pytest.fixture(scope="module")
def derivation() -> Derivation:
    """Total angular momentum about the fixed system CoM, from the joint chain.

    Inertial frame with the base attitude th0 included. The relative angles enter through
    c_i = cos th_i, s_i = sin th_i; the absolute link directions th0, th0 + th1,
    th0 + th1 + th2 follow from the addition formulas; time derivatives by the chain rule
    d c_i/dt = -s_i q_i, d s_i/dt = c_i q_i (q_i = th_i'). Link CoMs (the paper's
    conventions, Sec. II): C0 = O0 + d0 e0, C1 = O0 + l0 e0 + d1 e01,
    C2 = O0 + l0 e0 + l1 e01 + d2 e012. The system CoM is fixed (put at the origin), which
    fixes O0 = -sum_i m_i (C_i - O0) / M. Then H = sum_i m_i r_i x v_i + I_i w_i with
    w0 = q0, w1 = q0 + q1, w2 = q0 + q1 + q2. Everything is a polynomial once multiplied by
    M^2, so identities are checked exactly in QQ[...] modulo s_i^2 + c_i^2 = 1 (the same
    check through trigsimp takes minutes).
    """
    names = "m0 m1 m2 I0 I1 I2 l0 l1 d0 d1 d2 c0 c1 c2 s0 s1 s2 q0 q1 q2"
    R, *symbols = ring(names, QQ)
    g = dict(zip(names.split(), symbols, strict=True))
    m = (g["m0"], g["m1"], g["m2"])
    inertia = (g["I0"], g["I1"], g["I2"])
    l0, l1, d0, d1, d2 = g["l0"], g["l1"], g["d0"], g["d1"], g["d2"]
    c0, c1, c2, s0, s1, s2 = g["c0"], g["c1"], g["c2"], g["s0"], g["s1"], g["s2"]
    q0, q1, q2 = g["q0"], g["q1"], g["q2"]

    def rotate(ca: PolyElement, sa: PolyElement, cb: PolyElement, sb: PolyElement) -> tuple:
        return ca * cb - sa * sb, sa * cb + ca * sb

    e0 = (c0, s0)
    e01 = rotate(*e0, c1, s1)
    e012 = rotate(*e01, c2, s2)
    rel = [  # C_i - O0
        (d0 * e0[0], d0 * e0[1]),
        (l0 * e0[0] + d1 * e01[0], l0 * e0[1] + d1 * e01[1]),
        (l0 * e0[0] + l1 * e01[0] + d2 * e012[0], l0 * e0[1] + l1 * e01[1] + d2 * e012[1]),
    ]
    M = m[0] + m[1] + m[2]
    # M * O0 = -sum m_i (C_i - O0), so M r_i = M (C_i - O0) + M O0 is polynomial
    mo = [-sum((m[i] * rel[i][a] for i in range(3)), R.zero) for a in range(2)]
    Mr = [(M * x + mo[0], M * y + mo[1]) for x, y in rel]

    def dt(p: PolyElement) -> PolyElement:
        return sum(
            (
                p.diff(c) * (-s) * q + p.diff(s) * c * q
                for c, s, q in ((c0, s0, q0), (c1, s1, q1), (c2, s2, q2))
            ),
            R.zero,
        )

    Mv = [(dt(x), dt(y)) for x, y in Mr]
    w = (q0, q0 + q1, q0 + q1 + q2)
    M2H = sum(
        (m[i] * (Mr[i][0] * Mv[i][1] - Mr[i][1] * Mv[i][0]) for i in range(3)), R.zero
    ) + M * M * sum((inertia[i] * w[i] for i in range(3)), R.zero)
    h = (M2H.diff(q0), M2H.diff(q1), M2H.diff(q2))
    ideal = [s0**2 + c0**2 - 1, s1**2 + c1**2 - 1, s2**2 + c2**2 - 1]
    return Derivation(R, g, M2H, h, ideal)


def symbolic_links(d: Derivation, d2_zero: bool = False) -> Links:
    g = d.gens
    return Links(
        g["m0"], g["m1"], g["m2"], g["I0"], g["I1"], g["I2"], g["l0"], g["l1"], d.R.zero,
        g["d0"], g["d1"], d.R.zero if d2_zero else g["d2"],
    )  # fmt: skip


def reduced_abc(d: Derivation, model: str, d2_zero: bool = False) -> tuple:
    """A, B, C of ``constraint_coefficients`` as ring polynomials."""
    k = constraint_coefficients(symbolic_links(d, d2_zero), model)  # type: ignore[arg-type]
    g = d.gens
    c1, c2, s1, s2 = g["c1"], g["c2"], g["s1"], g["s2"]
    c12 = c1 * c2 - s1 * s2
    A = k.a0 + k.a1 * c1 + k.a2 * c2 + k.a3 * c12
    B = k.b0 + k.b1 * c1 + k.b2 * c2 + k.b3 * c12
    C = k.c0 + k.c2 * c2 + k.c3 * c12
    return A, B, C


def total_mass(d: Derivation) -> PolyElement:
    return d.gens["m0"] + d.gens["m1"] + d.gens["m2"]


# --------------------------------------------------------------------------------------
# Coefficients against the kinematics
# --------------------------------------------------------------------------------------


def test_derived_coefficients_equal_kinematic_derivation(derivation: Derivation) -> None:
    """H M = A th0' - B th1' - C th2' holds identically for general d2 (exact)."""
    A, B, C = reduced_abc(derivation, "derived")
    M = total_mass(derivation)
    h0, h1, h2 = derivation.h  # M^2 dH/dth_j'
    assert (h0 - M * A).rem(derivation.ideal) == 0
    assert (h1 + M * B).rem(derivation.ideal) == 0
    assert (h2 + M * C).rem(derivation.ideal) == 0


def test_symbolic_momentum_does_not_depend_on_base_attitude(derivation: Derivation) -> None:
    """H does not depend on th0 (so no coefficient does, and the paper's a4 term is 0)."""
    reduced = derivation.M2H.rem(derivation.ideal)
    g = derivation.gens
    for name in ("c0", "s0"):
        assert reduced.degree(g[name]) <= 0, name


def test_paper_coefficients_differ_only_in_b1_when_d2_is_zero(derivation: Derivation) -> None:
    """At d2 = 0 the paper's printed coefficients differ from the derivation in b1 only, by
    m0 m2 d0 l1 (its eq. 32 carries a spurious term)."""
    derived = reduced_abc(derivation, "derived", d2_zero=True)
    paper = reduced_abc(derivation, "paper", d2_zero=True)
    g = derivation.gens
    c1 = g["c1"]
    assert paper[0] - derived[0] == 0
    assert paper[2] - derived[2] == 0
    assert paper[1] - derived[1] == g["m0"] * g["m2"] * g["d0"] * g["l1"] * c1


@pytest.mark.parametrize("which", ["A", "B", "C"])
def test_printed_coefficients_against_the_kinematics(derivation: Derivation, which: str) -> None:
    """Against the derivation: the printed A is wrong for d2 != 0, B through b1; C is right
    (general d2)."""
    A, B, C = reduced_abc(derivation, "paper")
    M = total_mass(derivation)
    h0, h1, h2 = derivation.h
    residual = {"A": h0 - M * A, "B": h1 + M * B, "C": h2 + M * C}[which]
    if which == "C":
        # C as printed is right: c0, c2', c3 agree with the derivation
        assert residual.rem(derivation.ideal) == 0
    else:
        assert residual.rem(derivation.ideal) != 0


def lambdify_ring(d: Derivation, poly: PolyElement) -> Callable[..., Array]:
    """A numpy function of the 20 ring generators, in the order of ``d.gens``."""
    symbols = sp.symbols(list(d.gens))
    return sp.lambdify(symbols, poly.as_expr(*symbols), "numpy")  # type: ignore[no-any-return]


def random_designs(rng: np.random.Generator, n: int) -> dict[str, Array]:
    """Random (not necessarily flat) designs: positive masses, inertias, lengths; any d_i."""
    return {
        "m": rng.uniform(0.2, 5.0, (3, n)),
        "I": rng.uniform(0.005, 0.5, (3, n)),
        "l": rng.uniform(0.1, 1.0, (3, n)),
        "d": rng.uniform(-0.5, 1.0, (3, n)),
    }


def links_of(design: dict[str, Array]) -> Links:
    return Links(*design["m"], *design["I"], *design["l"], *design["d"])


def test_coefficients_numerically_at_random_designs(derivation: Derivation) -> None:
    """Float, batch-axis evaluation of the coefficients vs the derivation at random designs."""
    rng = np.random.default_rng(20030101)
    n = 50
    design = random_designs(rng, n)
    th = rng.uniform(-np.pi, np.pi, (3, n))
    k = constraint_coefficients(links_of(design), "derived")
    c1, c2, c12 = np.cos(th[1]), np.cos(th[2]), np.cos(th[1] + th[2])
    A = k.a0 + k.a1 * c1 + k.a2 * c2 + k.a3 * c12
    B = k.b0 + k.b1 * c1 + k.b2 * c2 + k.b3 * c12
    C = k.c0 + k.c2 * c2 + k.c3 * c12
    args = (
        *design["m"], *design["I"], design["l"][0], design["l"][1], *design["d"],
        *np.cos(th), *np.sin(th), *np.zeros((3, n)),
    )  # fmt: skip
    M = design["m"].sum(axis=0)
    for poly, got, sign in zip(derivation.h, (A, B, C), (1, -1, -1), strict=True):
        expected = sign * lambdify_ring(derivation, poly)(*args) / M
        np.testing.assert_allclose(got, expected, rtol=NUMERIC_RTOL)


def test_momentum_equals_inertial_frame_derivation(derivation: Derivation) -> None:
    """``momentum`` (base frame, th0 dropped) vs the inertial-frame H at random states."""
    rng = np.random.default_rng(7)
    n = 200
    design = random_designs(rng, n)
    th = rng.uniform(-2 * np.pi, 2 * np.pi, (3, n))
    rates = rng.uniform(-20.0, 20.0, (3, n))
    M = design["m"].sum(axis=0)
    args = (
        *design["m"], *design["I"], design["l"][0], design["l"][1], *design["d"],
        *np.cos(th), *np.sin(th), *rates,
    )  # fmt: skip
    expected = lambdify_ring(derivation, derivation.M2H)(*args) / M**2
    got = momentum(links_of(design), *th, *rates)
    # relative to the size of H's terms, so states where H nearly cancels are fair
    terms = sum(
        np.abs(lambdify_ring(derivation, hj)(*args)) / M**2 * np.abs(r)
        for hj, r in zip(derivation.h, rates, strict=True)
    )
    assert np.all(np.abs(got - expected) <= NUMERIC_RTOL * terms)
    # and th0 really drops out: a different base attitude changes nothing
    np.testing.assert_array_equal(got, momentum(links_of(design), th[0] + 1.0, *th[1:], *rates))


def test_momentum_broadcasts_over_batch_shapes() -> None:
    rng = np.random.default_rng(3)
    th = rng.uniform(-3, 3, (3, 4, 5))
    rates = rng.uniform(-3, 3, (3, 4, 5))
    batch = np.asarray(momentum(PAPER_ROBOT.links, *th, *rates))
    assert batch.shape == (4, 5)
    one = momentum(PAPER_ROBOT.links, *th[:, 2, 3], *rates[:, 2, 3])
    assert batch[2, 3] == pytest.approx(one, rel=1e-15, abs=1e-16)


# --------------------------------------------------------------------------------------
# The paper's example numbers
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("model", "name", "value"),
    [
        # the appendix's formulas at the paper's robot (Sec. VI: m_i = 1, l_i = 0.2,
        # I_i = 0.0533, d0 = d1 = 0.1, d2 = 0) by hand, e.g. a0 = 3 (3 x 0.0533) + 2 x 0.01
        # + 0.01 + (0.04 + 0.01) = 0.5597; the same for both models at d2 = 0
        *[(m, "a0", 0.5597) for m in MODELS],
        *[(m, "a1", 0.06) for m in MODELS],
        *[(m, "b0", -0.3798) for m in MODELS],
        *[(m, "c0", -0.1599) for m in MODELS],
        ("paper", "b1", -0.01),  # paper, eq. 32 as printed
        ("derived", "b1", -0.03),  # -m0 (l0 - d0)(m2 l1 + m1 d1) = -0.1 x 0.3 (derivation)
        *[(m, n, 0.0) for m in MODELS for n in ("a2", "a3", "b2", "b3", "c2", "c3")],
    ],
)
def test_paper_example_coefficients(model: str, name: str, value: float) -> None:
    k = constraint_coefficients(PAPER_ROBOT.links, model)  # type: ignore[arg-type]
    assert getattr(k, name) == pytest.approx(value, abs=EXAMPLE_ATOL)


def test_unknown_model_is_a_domain_error() -> None:
    with pytest.raises(FlatcliError, match=r"robot\.model"):
        constraint_coefficients(PAPER_ROBOT.links, "printed")  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------
# The reduced constraint vs full-kinematics H, random designs (hypothesis)
# --------------------------------------------------------------------------------------

positive = st.floats(0.05, 10.0)
designs = st.builds(
    RobotParams,
    mass=st.tuples(positive, positive, positive),
    inertia=st.tuples(*[st.floats(1e-3, 1.0)] * 3),
    length=st.tuples(*[st.floats(0.05, 2.0)] * 3),
    com=st.tuples(*[st.floats(-1.0, 2.0)] * 3),
)
angles = st.floats(-10.0, 10.0)
rates = st.floats(-50.0, 50.0)


@settings(deadline=None, max_examples=200)
@given(
    robot=designs,
    th=st.tuples(angles, angles, angles),
    th1_dot=rates,
    th2_dot=rates,
    h0=st.floats(-5.0, 5.0),
)
def test_base_rate_makes_full_kinematics_conserve_h0(
    robot: RobotParams,
    th: tuple[float, float, float],
    th1_dot: float,
    th2_dot: float,
    h0: float,
) -> None:
    """th0' = base_rate(...) gives momentum(...) = H0 for any design, d2 included."""
    k = constraint_coefficients(robot.links, "derived")
    M = robot.total_mass
    th0_dot = base_rate(k, M, h0, th[1], th[2], th1_dot, th2_dot)
    H = momentum(robot.links, *th, th0_dot, th1_dot, th2_dot)
    c1, c2, c12 = np.cos(th[1]), np.cos(th[2]), np.cos(th[1] + th[2])
    A = k.a0 + k.a1 * c1 + k.a2 * c2 + k.a3 * c12
    B = k.b0 + k.b1 * c1 + k.b2 * c2 + k.b3 * c12
    C = k.c0 + k.c2 * c2 + k.c3 * c12
    scale = abs(h0) + (abs(A * th0_dot) + abs(B * th1_dot) + abs(C * th2_dot)) / M
    assert abs(H - h0) <= CONSERVATION_RTOL * scale


def test_base_rate_with_printed_b1_violates_momentum() -> None:
    """The printed b1 does not conserve H on the paper's robot (d2 = 0).

    Expected H = (b1_paper - b1_derived) cos th1 th1' / M (from H M = A th0' - B th1' - C th2').
    """
    th1, th2, th1_dot, th2_dot = 1.0, 0.3, 0.7, -0.2
    k = constraint_coefficients(PAPER_ROBOT.links, "paper")
    th0_dot = base_rate(k, PAPER_ROBOT.total_mass, 0.0, th1, th2, th1_dot, th2_dot)
    H = momentum(PAPER_ROBOT.links, 0.0, th1, th2, th0_dot, th1_dot, th2_dot)
    expected = (-0.01 + 0.03) * np.cos(th1) * th1_dot / PAPER_ROBOT.total_mass
    assert pytest.approx(expected, rel=1e-12) == H


# --------------------------------------------------------------------------------------
# Design check and parameter validation
# --------------------------------------------------------------------------------------


def test_paper_robot_is_flat() -> None:
    check = flatness_check(PAPER_ROBOT)
    assert check.is_flat
    assert check.message() == ""
    require_flat(PAPER_ROBOT)


@pytest.mark.parametrize(
    ("changes", "named", "controllable"),
    [
        ({"com": (0.1, 0.1, 0.005)}, "d2", True),  # link 2's CoM 5 mm off joint 2
        ({"com": (0.2, 0.1, 0.0)}, "l0 - d0", False),  # l0 = d0 = 0.2
        ({"com": (0.1, -0.2, 0.0)}, "m1 d1 + m2 l1", False),  # 1 * (-0.2) + 1 * 0.2 = 0
    ],
)
def test_flatness_check_flags_each_condition(changes: dict, named: str,
                                             controllable: bool) -> None:
    """d2 != 0 keeps the robot controllable (flat, outputs unknown in closed form): the
    paper's outputs do not apply; a1 = 0 loses controllability: not flat."""
    robot = PAPER_ROBOT.with_(**changes)
    check = flatness_check(robot)
    assert not check.is_flat
    assert check.controllable == controllable
    assert len(check.failures) == 1
    assert named in check.message()
    expected = "the paper's flat outputs do not apply" if controllable else (
        "not differentially flat")
    with pytest.raises(FlatcliError, match=expected) as info:
        require_flat(robot)
    assert named in str(info.value)


def test_flatness_check_reports_every_failing_condition() -> None:
    # d2 != 0, l0 = d0 and m1 d1 + m2 l1 = 0 at once
    robot = RobotParams(mass=(1, 2, 1), length=(0.3, 0.4, 0.2), com=(0.3, -0.2, 0.01))
    message = flatness_check(robot).message()
    assert len(flatness_check(robot).failures) == 3
    for named in ("d2", "l0 - d0", "m1 d1 + m2 l1"):
        assert named in message


def test_a_longer_chain_with_k10_zero_is_unsupported_not_uncontrollable() -> None:
    """N = 3 with l0 = d0: every K_0b vanishes (the base's centre of mass on joint 1: its
    offset from the system's does not move with the arm, G_i0 = 0 in K = G^T diag(m) G),
    but K_12 does not, so h_0 still varies with th2: flatcli says it cannot plan for the
    design, not that the robot is uncontrollable."""
    robot = RobotParams(mass=(2, 1, 1, 0.6), inertia=(0.08, 0.03, 0.03, 0.2),
                        length=(0.3, 0.25, 0.25, 0.25), com=(0.3, 0.1, 0.1, 0.0))
    K = barycentric_matrix(*(np.asarray(v, dtype=float) for v in
                             (robot.mass, robot.length, robot.com)))
    assert np.all(K[0] == 0) and K[1, 2] != 0
    check = flatness_check(robot)
    assert check.unsupported and check.controllable and not check.is_flat
    assert "l0 = d0 makes K_10" in check.message() and "cannot plan for it" in check.message()
    with pytest.raises(FlatcliError, match=r"^flatcli cannot plan for this design: l0 = d0.*; "
                       r"the robot is still controllable, hence flat"):
        require_flat(robot)
    assert flatness_check(robot.with_(com=(0.12, 0.1, 0.1, 0.0))).is_flat


@pytest.mark.parametrize(
    ("robot", "controllable"),
    [
        # N = 2, l0 = d0 (a1 = 0) but d2 != 0: K_12 = m2 d2 (m0 l1 + m1 (l1 - d1)) / M != 0
        (PAPER_ROBOT.with_(com=(0.2, 0.1, 0.01)), True),
        # N = 2, l0 = d0 and d1 = (m0 + m1) l1 / m1: base and link 1 balance on joint 2, so
        # K_12 = 0 as well and K is diagonal whatever d2 is
        (PAPER_ROBOT.with_(com=(0.2, 0.4, 0.05)), False),
        # chain4 with l0 = d0, m1 d1 + (m2 + m3) l1 = 0 and m2 d2 + m3 l2 = 0 (the audit's)
        (RobotParams(mass=(2, 1, 1, 0.5), inertia=(0.1, 0.0533, 0.0533, 0.15),
                     length=(0.3, 0.2, 0.2, 0.2), com=(0.3, -0.3, -0.1, 0.0)), False),
    ],
)
def test_controllable_is_a_coupling_between_links(robot: RobotParams,
                                                   controllable: bool) -> None:
    """``controllable`` is False exactly when K is diagonal (every h_j constant), whichever
    closed-form condition fails; the error says so and never calls an integrable robot flat.
    (tests/test_core_design.py checks the same designs against w ^ dw from sympy.)"""
    check = flatness_check(robot)
    assert not check.is_flat and check.controllable == controllable
    with pytest.raises(FlatcliError) as info:
        require_flat(robot)
    message = str(info.value)
    assert ("not differentially flat" in message) != controllable
    assert ("hence flat" in message) == controllable


def test_k10_is_zero_relative_to_the_robots_own_scale() -> None:
    """The paper's robot scaled down to micro-units (lengths x 1e-6, masses x 1e-6, inertias
    x 1e-18: K_10 = 1e-20 kg m^2) keeps its verdict; K_10 at rounding level of the robot's
    inertia (l0 - d0 = 1e-14 l0) counts as 0."""
    r = PAPER_ROBOT
    tiny = RobotParams(mass=tuple(1e-6 * m for m in r.mass),
                       inertia=tuple(1e-18 * i for i in r.inertia),
                       length=tuple(1e-6 * v for v in r.length),
                       com=tuple(1e-6 * v for v in r.com))
    assert flatness_check(tiny).is_flat
    nearly = r.with_(com=(0.2 * (1 - 1e-14), 0.1, 0.0))
    check = flatness_check(nearly)
    assert not check.is_flat and not check.controllable


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("mass", (0.0, 1.0, 1.0), "> 0"),
        ("mass", (1.0, -1.0, 1.0), "> 0"),
        ("inertia", (0.05, 0.05, 0.0), "> 0"),
        ("length", (0.2, -0.1, 0.2), "> 0"),
        ("mass", (float("nan"), 1.0, 1.0), "finite"),
        ("inertia", (0.05, float("inf"), 0.05), "finite"),
        ("com", (0.1, float("-inf"), 0.0), "finite"),
        ("com", (0.1, 0.1), "one number per link"),
        ("length", (0.2, 0.2, 0.2, 0.2), "the same number of links"),  # 4 against 3
        ("mass", [[1.0, 1.0, 1.0]], "one number per link"),
        ("inertia", 0.05, "one number per link"),
        ("mass", [1.0, [2.0, 3.0], 4.0], "one number per link"),  # ragged
        ("com", ("a", 0.1, 0.0), "one number per link"),
    ],
)
def test_robot_params_rejects_bad_values(field: str, value: object, match: str) -> None:
    with pytest.raises(FlatcliError, match=match) as info:
        RobotParams(**{field: value})  # type: ignore[arg-type]
    assert str(info.value).startswith(field)
    with pytest.raises(FlatcliError, match=match):
        PAPER_ROBOT.with_(**{field: value})  # type: ignore[arg-type]


def test_robot_params_are_immutable_and_normalised() -> None:
    robot = RobotParams(mass=np.array([1, 2, 3]))
    assert robot.mass == (1.0, 2.0, 3.0)
    assert all(type(v) is float for v in robot.mass)
    assert robot.total_mass == 6.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        robot.mass = (1.0, 1.0, 1.0)  # type: ignore[misc]
    np.testing.assert_array_equal(
        PAPER_ROBOT.as_array(),
        [1, 1, 1, 0.0533, 0.0533, 0.0533, 0.2, 0.2, 0.2, 0.1, 0.1, 0.0],  # paper, Sec. VI
    )
