"""Tests of flatcli.core.robots.design: is a design flat, with closed-form outputs, or not at all.

The referee is a sympy derivation from the link positions (as in ``tests/test_chain.py``):
each link's centre of mass placed along the chain from O0, h_j = dH/dth_j' by the chain rule,
their derivatives and w ^ dw symbolically; nothing of the code under test (its kinematic H,
its complex step, chain's K) enters it. Designs are built with exact rationals, so that a
design built integrable is proven so (every h_j is a constant after expanding its
exponentials) and a design built controllable shows w ^ dw far from zero at a configuration.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from fractions import Fraction

import numpy as np
import pytest
import sympy as sp
from numpy.typing import NDArray

from flatcli.core.robots.chain import chain_momentum
from flatcli.core.robots.design import (
    INTEGRABILITY_RTOL,
    VERDICTS,
    constraint_form,
    design_verdict,
    form_slopes,
    sample_configurations,
    wedge,
    wedge_components,
)
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams, flatness_check

Array = NDArray[np.float64]
Numbers = Sequence[str | float]

#: Numbers that only rounding separates, relative to J (or J^2): sums of ~N^2 terms.
RTOL = 1e-11
#: Built integrable designs leave rounding only; built controllable ones are far above the
#: tolerance. Measured on the designs below: integrable <= 1e-16, controllable >= 9e-4.
ROUNDING = 1e-15
FAR = 1e-6


def robot(mass: Numbers, inertia: Numbers, length: Numbers, com: Numbers) -> RobotParams:
    return RobotParams(mass=tuple(float(Fraction(v)) for v in mass),
                       inertia=tuple(float(Fraction(v)) for v in inertia),
                       length=tuple(float(Fraction(v)) for v in length),
                       com=tuple(float(Fraction(v)) for v in com))


def exact(r: RobotParams, given: tuple[Numbers, ...] | None = None) -> tuple[list[sp.Expr], ...]:
    """The parameters as sympy rationals: those given as strings (exactly), else the floats'
    shortest decimal (0.3 -> 3/10)."""
    values = given or (r.mass, r.inertia, r.length, r.com)
    return tuple([sp.Rational(str(v)) for v in group] for group in values)


@functools.lru_cache(maxsize=32)
def _derive(params: tuple[tuple[sp.Expr, ...], ...]) -> tuple[tuple[sp.Symbol, ...],
                                                               list[sp.Expr]]:
    mass, inertia, length, com = params
    n = len(mass) - 1
    q = sp.symbols(f"q0:{n + 1}")  # th0 .. thN
    psi = [sum(q[: a + 1]) for a in range(n + 1)]
    xs = [sum(length[a] * sp.cos(psi[a]) for a in range(i)) + com[i] * sp.cos(psi[i])
          for i in range(n + 1)]
    ys = [sum(length[a] * sp.sin(psi[a]) for a in range(i)) + com[i] * sp.sin(psi[i])
          for i in range(n + 1)]
    total = sum(mass)
    X = sum(m * x for m, x in zip(mass, xs, strict=True))
    Y = sum(m * y for m, y in zip(mass, ys, strict=True))
    weights = []
    for j in range(n + 1):  # H = sum_j h_j th_j' about the system centre of mass
        dx = [sp.diff(x, q[j]) for x in xs]
        dy = [sp.diff(y, q[j]) for y in ys]
        h = sum(m * (x * ddy - y * ddx)
                for m, x, y, ddx, ddy in zip(mass, xs, ys, dx, dy, strict=True))
        h -= (X * sum(m * d for m, d in zip(mass, dy, strict=True))
              - Y * sum(m * d for m, d in zip(mass, dx, strict=True))) / total
        h += sum(inertia[i] for i in range(j, n + 1))  # spins of the links joint j moves
        weights.append(h)
    return q, weights


def derivation(params: tuple[list[sp.Expr], ...]) -> tuple[tuple[sp.Symbol, ...],
                                                          list[sp.Expr]]:
    """q = (th0..thN) and the weights h_j(q) of H = sum_j h_j th_j', from the link
    positions."""
    return _derive(tuple(tuple(group) for group in params))


def symbolic_wedge(params: tuple[list[sp.Expr], ...],
                   only: tuple[int, int, int] | None = None) -> Callable[..., list[float]]:
    """The components (i < j < k) of w ^ dw (or the one ``only``), derived and lambdified
    in q."""
    q, h = derivation(params)
    n = len(q)

    def curl(j: int, k: int) -> sp.Expr:  # F_jk = dh_k/dq_j - dh_j/dq_k
        return sp.diff(h[k], q[j]) - sp.diff(h[j], q[k])

    triples = [only] if only else [(i, j, k) for i in range(n) for j in range(i + 1, n)
                                   for k in range(j + 1, n)]
    parts = [h[i] * curl(j, k) - h[j] * curl(i, k) + h[k] * curl(i, j) for i, j, k in triples]
    return sp.lambdify((q,), parts, "numpy", cse=True)  # type: ignore[no-any-return]


def scale(r: RobotParams) -> float:
    """J = sum_a (I_a + sum_i m_i L_ia^2), L_ia = l_a (a < i), d_i (a = i), 0 (a > i): the
    definition (``chain.inertia_scale``), written out."""
    n = r.n_joints
    total = sum(r.inertia)
    for i in range(n + 1):
        total += r.mass[i] * (sum(r.length[a] ** 2 for a in range(i)) + r.com[i] ** 2)
    return float(total)


def constant_weights(params: tuple[list[sp.Expr], ...]) -> list[sp.Expr] | None:
    """The h_j as exact numbers if every one is constant (no angle left once its
    exponentials are expanded), else None."""
    _, h = derivation(params)
    values = [sp.expand(w.rewrite(sp.exp)) for w in h]
    return values if all(not v.free_symbols for v in values) else None


# --------------------------------------------------------------------------------------
# Designs. Integrable ones are built from K_ab = F_b (l_a - F_a / M) (a < b), F_a =
# m_a d_a + (m_a+1 + ... + m_N) l_a: K vanishes off the diagonal when, for every b, either
# F_b = 0 (links b..N balance on joint b) or l_a = F_a / M for every a < b (links 0..a
# balance on joint a + 1). The sympy derivation proves them integrable without using this.
# --------------------------------------------------------------------------------------

PAPER = (("1", "1", "1"), ("0.0533", "0.0533", "0.0533"), ("0.2", "0.2", "0.2"))
CHAIN4 = (("2", "1", "1", "0.5"), ("0.1", "0.0533", "0.0533", "0.15"),
          ("0.3", "0.2", "0.2", "0.2"))
CHAIN5 = (("2", "1", "1", "0.5", "0.5"), ("0.1", "0.05", "0.05", "0.15", "0.1"),
          ("0.3", "0.2", "0.2", "0.2", "0.2"))

INTEGRABLE: dict[str, tuple[Numbers, ...]] = {
    # N = 2, d2 = 0 and l0 = d0: a1 = 0, the paper's c0 a1 != 0 fails
    "n2 l0 = d0": (*PAPER, ("0.2", "0.1", "0")),
    # N = 2, d2 = 0 and m1 d1 + m2 l1 = 0
    "n2 m1 d1 + m2 l1 = 0": (*PAPER, ("0.1", "-0.2", "0")),
    # N = 2, d2 != 0: l0 = d0 and d1 = (m0 + m1) l1 / m1 (base and link 1 balance on joint 2)
    "n2 d2 != 0, balanced": (*PAPER, ("0.2", "0.4", "0.05")),
    # N = 3, the audit's example: chain4 with l0 = d0, F_1 = F_2 = F_3 = 0
    "n3 chain4 com=[0.3,-0.3,-0.1,0]": (*CHAIN4, ("0.3", "-0.3", "-0.1", "0")),
    # N = 3, d3 != 0: l0 = d0, d1 = (m0 + m1) l1 / m1, d2 = (m0 + m1 + m2) l2 / m2
    "n3 d3 != 0, balanced": (*CHAIN4, ("0.3", "0.6", "0.8", "0.07")),
    # N = 4, F_b = 0 for b >= 1: d_b = -(m_b+1 + ... + m_4) l_b / m_b, d4 = 0, any d0
    "n4 counterweighted": (*CHAIN5, ("0.1", "-0.4", "-0.2", "-0.2", "0")),
    # N = 4, mixed: l0 = d0, d1 = (m0 + m1) l1 / m1, then F_2 = F_3 = F_4 = 0
    "n4 mixed": (*CHAIN5, ("0.3", "0.6", "-0.2", "-0.2", "0")),
}

CONTROLLABLE: dict[str, tuple[tuple[Numbers, ...], str]] = {
    "n2 paper": ((*PAPER, ("0.1", "0.1", "0")), "closed_form"),
    "n2 d2 = 2 mm": ((*PAPER, ("0.1", "0.1", "0.002")), "flat"),
    # the audit's: l0 = d0 makes a1 = 0, but d2 != 0 couples links 1 and 2 (K_12 != 0)
    "n2 a1 = 0, d2 != 0 (audit)": ((*PAPER, ("0.2", "0.1", "0.01")), "flat"),
    "n2 m1 d1 + m2 l1 = 0, d2 != 0": ((*PAPER, ("0.1", "-0.2", "0.01")), "flat"),
    "n3 chain4": ((*CHAIN4, ("0.1", "0.1", "0.1", "0")), "closed_form"),
    "n3 chain4 d3 = 1 cm": ((*CHAIN4, ("0.1", "0.1", "0.1", "0.01")), "flat"),
    # l0 = d0: K_10 = 0 (flatcli's planner normalises by it) but K_12 != 0: h_0 varies
    "n3 K_10 = 0, K_12 != 0": ((*CHAIN4, ("0.3", "0.1", "0.1", "0")), "flat"),
    "n4": ((*CHAIN5, ("0.1", "0.1", "0.1", "0.1", "0")), "closed_form"),
    "n4 d4 = 5 mm": ((*CHAIN5, ("0.1", "0.1", "0.1", "0.1", "0.005")), "flat"),
    # the mixed integrable design with link 3 off balance: only K_23, K_24... couple
    "n4 K_10 = 0, outer links coupled": ((*CHAIN5, ("0.3", "0.6", "-0.2", "0.1", "0")),
                                         "flat"),
}


@pytest.mark.parametrize("name", list(INTEGRABLE))
def test_designs_built_integrable_are_not_flat(name: str) -> None:
    """sympy proves every h_j constant; the verdict is not_flat, w ^ dw is at rounding level
    at every sample, the conserved h_j are sympy's, and model.flatness_check agrees."""
    given = INTEGRABLE[name]
    r = robot(*given)
    constants = constant_weights(exact(r, given))
    assert constants is not None, "the design was meant to be integrable"
    v = design_verdict(r)
    assert v.verdict == "not_flat" and not v.controllable
    assert v.wedge <= ROUNDING < INTEGRABILITY_RTOL
    assert v.conserved is not None
    np.testing.assert_allclose(v.conserved, [float(c) for c in constants], rtol=RTOL)
    assert "is conserved" in v.reasons[1] and "reorients the base" in v.reasons[1]
    assert not any("controllable, hence flat" in line for line in v.reasons)
    assert not flatness_check(r).controllable and not flatness_check(r).is_flat


@pytest.mark.parametrize("name", list(CONTROLLABLE))
def test_designs_built_controllable_are_flat(name: str) -> None:
    """The verdict is flat or closed_form as built; its reported max |w ^ dw| / J^2 is
    sympy's at the configuration it names, far above the tolerance; no h_j is constant."""
    given, expected = CONTROLLABLE[name]
    r = robot(*given)
    params = exact(r, given)
    assert constant_weights(params) is None
    v = design_verdict(r)
    assert v.verdict == expected and v.controllable
    assert v.wedge >= FAR > INTEGRABILITY_RTOL
    assert v.wedge_component in wedge_components(r.n_joints)
    referee = symbolic_wedge(params, v.wedge_component)(np.asarray(v.wedge_at))[0]
    assert v.wedge == pytest.approx(abs(referee) / scale(r) ** 2, rel=1e-9)
    assert v.scale == pytest.approx(scale(r), rel=1e-14)
    assert v.conserved is None and flatness_check(r).controllable
    assert flatness_check(r).is_flat == (expected == "closed_form")
    assert "not flat" not in " ".join(v.reasons)


@pytest.mark.parametrize("name", ["n2 d2 = 2 mm", "n3 chain4 d3 = 1 cm", "n4 d4 = 5 mm"])
def test_every_component_equals_the_symbolic_derivation(name: str) -> None:
    """h_j, dh_j/dth_k and every component of w ^ dw at 16 configurations, against sympy
    (relative to J and J^2: the components pass through zero)."""
    given, _ = CONTROLLABLE[name]
    r = robot(*given)
    params = exact(r, given)
    q, h = derivation(params)
    weights = sp.lambdify((q,), h, "numpy")
    slopes = sp.lambdify((q,), [[sp.diff(w, qk) for qk in q] for w in h], "numpy")
    theta = np.random.default_rng(5).uniform(-np.pi, np.pi, (16, r.n_joints + 1))
    J = scale(r)
    got_h, got_slopes, got_wedge = constraint_form(r, theta), form_slopes(r, theta), wedge(r, theta)
    referee = symbolic_wedge(params)
    for row in range(theta.shape[0]):
        np.testing.assert_allclose(got_h[row], weights(theta[row]), rtol=0, atol=RTOL * J)
        np.testing.assert_allclose(got_slopes[row], slopes(theta[row]), rtol=0, atol=RTOL * J)
        np.testing.assert_allclose(got_wedge[row], referee(theta[row]), rtol=0,
                                   atol=RTOL * J**2)


def test_the_chains_momentum_takes_complex_steps() -> None:
    """``form_slopes`` steps ``chain.chain_momentum`` into the complex plane: at real angles
    held as complex numbers it is the real H, and at th + i eps e_k its imaginary part / eps
    is dH/dth_k (against a central difference of the real H, step 1e-6)."""
    r = robot(*CONTROLLABLE["n3 chain4 d3 = 1 cm"][0])
    arrays = [np.asarray(v, dtype=float) for v in (r.mass, r.inertia, r.length, r.com)]
    rng = np.random.default_rng(11)
    theta, rates = rng.uniform(-3, 3, (8, 4)), rng.uniform(-2, 2, (8, 4))
    ours = chain_momentum(*arrays, theta.astype(complex), rates)
    assert ours.dtype == complex
    np.testing.assert_allclose(ours.real, chain_momentum(*arrays, theta, rates), rtol=1e-13)
    assert np.all(ours.imag == 0.0)
    step = 1e-6
    for k in range(4):
        shift = np.zeros(4)
        shift[k] = 1.0
        slope = chain_momentum(*arrays, theta + 1e-30j * shift, rates).imag / 1e-30
        central = (chain_momentum(*arrays, theta + step * shift, rates)
                   - chain_momentum(*arrays, theta - step * shift, rates)) / (2 * step)
        np.testing.assert_allclose(slope, central, rtol=0, atol=1e-9)


def test_the_fourier_coefficient_that_decides_integrability() -> None:
    """The module docstring's step: for N = 2 (th -> psi has Jacobian 1, so the component 012
    is the same in absolute angles) the coefficient of sin(th1) = -sin(psi_0 - psi_1) in
    w ^ dw is 2 ((I_2 + K_22) K_01 - K_02 K_12), with K_ab from its defining sum; sympy's
    w ^ dw on a 32 x 32 grid of (th1, th2) (exact for these trigonometric polynomials)."""
    given, _ = CONTROLLABLE["n2 a1 = 0, d2 != 0 (audit)"]
    for com in (("0.1", "0.1", "0.03"), ("0.2", "0.1", "0.01"), ("0.1", "-0.2", "0.02")):
        r = robot(*given[:3], com)
        referee = symbolic_wedge(exact(r, (*given[:3], com)))
        grid = np.linspace(0, 2 * np.pi, 32, endpoint=False)
        values = np.asarray([[referee(np.array([0.0, a, b]))[0] for b in grid] for a in grid])
        coefficient = 2 * np.mean(values * np.sin(grid)[:, None])
        m, L = np.asarray(r.mass), np.zeros((3, 3))
        for i in range(3):
            L[i, :i] = r.length[:i]
            L[i, i] = r.com[i]
        F = m @ L
        K = L.T @ np.diag(m) @ L - np.outer(F, F) / m.sum()
        expected = 2 * ((r.inertia[2] + K[2, 2]) * K[0, 1] - K[0, 2] * K[1, 2])
        assert coefficient == pytest.approx(expected, rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("coupling", [1e-3, 1e-6, 1e-9])
def test_a_small_coupling_is_still_found(coupling: float) -> None:
    """Near an integrable design (N = 2, l0 = d0, d2 = 0) a d2 of ``coupling`` x l0 makes
    K_12 / J = 0.06 coupling: max |w ^ dw| / J^2 is linear in it (2e-11 at 1e-9: 20 x the
    tolerance, 1e5 x the rounding left on integrable designs)."""
    r = PAPER_ROBOT.with_(com=(0.2, 0.1, 0.2 * coupling))
    v = design_verdict(r)
    base = design_verdict(PAPER_ROBOT.with_(com=(0.2, 0.1, 0.2e-3)))
    assert v.verdict == "flat"
    assert v.wedge == pytest.approx(base.wedge * coupling / 1e-3, rel=1e-3)
    assert v.wedge > 10 * INTEGRABILITY_RTOL


def test_the_verdict_is_deterministic_and_its_numbers_are_exposed() -> None:
    """Fixed samples: the same robot gives the same verdict and numbers (within one run);
    the numbers name K_10, J and where the largest |w ^ dw| was found."""
    first, again = design_verdict(PAPER_ROBOT), design_verdict(PAPER_ROBOT)
    assert first == again and first.verdict == "closed_form"
    assert first.samples == sample_configurations(2).shape[0]
    assert first.wedge_component == (0, 1, 2) and len(first.wedge_at) == 3
    # K_10 = m0 (l0 - d0)(m1 d1 + m2 l1) / M = 1 (0.1)(0.1 + 0.2) / 3, by hand
    assert first.k10 == pytest.approx(0.01, rel=1e-12)
    assert "K_10 = 0.01 kg m^2" in first.numbers() and "|K_10| / J" in first.numbers()
    assert first.headline.startswith("controllable") and set(VERDICTS) == {
        "closed_form", "flat", "not_flat"}


def test_reasons_are_one_line_each_and_name_what_flatcli_does() -> None:
    for given in (INTEGRABLE["n2 l0 = d0"], CONTROLLABLE["n2 d2 = 2 mm"][0],
                  CONTROLLABLE["n3 chain4"][0]):
        v = design_verdict(robot(*given))
        assert v.reasons and all("\n" not in line for line in v.reasons)
    flat = design_verdict(robot(*CONTROLLABLE["n3 K_10 = 0, K_12 != 0"][0]))
    assert "need d3 = 0 and K_10 != 0" in flat.reasons[-1]
    closed = design_verdict(robot(*CONTROLLABLE["n3 chain4"][0]))
    assert "flatcli plans it" in closed.reasons[-1]


@pytest.mark.parametrize("name", ["n2 d2 = 2 mm", "n3 K_10 = 0, K_12 != 0", "n4 d4 = 5 mm"])
def test_a_flat_verdict_says_what_each_plan_method_does_and_it_is_so(name: str) -> None:
    """The verdict's last reason claims plan.method "flat" refuses the design and "auto"
    plans it exactly: the planners' own choice (``exact.method_for``) and the flat planner's
    refusal (``model.require_flat``) are the referees."""
    from flatcli.core.errors import FlatcliError
    from flatcli.core.plan.exact import method_for
    from flatcli.core.robots.params import require_flat

    design = robot(*CONTROLLABLE[name][0])
    text = design_verdict(design).reasons[-1]
    assert 'plan.method = "flat" refuses' in text
    assert '"auto" (the default) and "exact" plan it exactly' in text
    assert "nominal robot with" not in text
    assert method_for(design, "auto") == "exact"
    with pytest.raises(FlatcliError):
        require_flat(design)
