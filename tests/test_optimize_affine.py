"""Tests of flatcli.core.optimize.affine: coefficients and flat flag affine in x.

References: ``FlatModel.boundary`` (the flat boundary values of a maneuver),
``FlatTrajectory.derivative`` (the basis evaluated directly), the paper's cubic
(``conftest``: Franch et al. 2003, Sec. VI) and ``flatness.flat_outputs``.
"""

from __future__ import annotations

import numpy as np
import pytest

from flatcli.core.curves.basis import PolynomialBasis
from flatcli.core.models.flatmodel import flat_model
from flatcli.core.models.flatness import flat_outputs
from flatcli.core.optimize import default_basis
from flatcli.core.optimize.affine import affine_map
from flatcli.core.plan.planning import FlatTrajectory, Plan
from flatcli.core.robots.params import PAPER_ROBOT

#: Linear algebra on coefficients of order 1-10 (pseudo-inverse plus null space): observed
#: ~1e-13.
LINEAR_TOL = 1e-10
#: The paper's cubic rebuilt from its decision vector: observed 1.3e-12 relative.
REBUILT_TOL = 1e-9

K = flat_model(PAPER_ROBOT)  # the paper's closed form
START = np.array([1.8, 1.0, 0.0])
GOAL = np.array([1.2, 2.0, 0.0])


@pytest.mark.parametrize("free_rates", [True, False], ids=["free", "fixed"])
def test_any_decision_vector_meets_the_boundary_conditions(free_rates: bool) -> None:
    """Random x: y and y' at both ends are the maneuver's flat boundary values."""
    basis = default_basis(2.0)
    affine, curve = affine_map(K, basis, START, GOAL, 0.2, 0.4, free_rates, False)
    rng = np.random.default_rng(5)
    for _ in range(5):
        x = curve + rng.normal(scale=0.3, size=curve.size)
        rates = (x[0], x[1]) if free_rates else (0.2, 0.4)
        bc = K.boundary(START, GOAL, *rates)
        trajectory = FlatTrajectory(basis, affine.coefficients(x))
        ends = np.array([0.0, 2.0])
        y, y_dot = trajectory.derivative(ends, 0), trajectory.derivative(ends, 1)
        np.testing.assert_allclose(y, [bc.y_start, bc.y_goal], rtol=0, atol=LINEAR_TOL)
        np.testing.assert_allclose(y_dot, [bc.y_dot_start, bc.y_dot_goal], atol=LINEAR_TOL)
    # the free end rates lead the decision vector: 2 + the null space of each output
    free = basis.size - 4
    assert curve.size == (2 if free_rates else 0) + 2 * free


def test_flag_is_the_basis_evaluated() -> None:
    """base + slope x is y, y', y'' of the coefficients at x (an epigraph variable ignored)."""
    basis = default_basis(2.0)
    affine, curve = affine_map(K, basis, START, GOAL, 0.2, 0.4, True, True)
    x = np.append(curve + 0.1, 7.0)
    t = np.linspace(0.0, 2.0, 13)
    base, slope = affine.flag(t)
    flag = base + slope @ x
    trajectory = FlatTrajectory(basis, affine.coefficients(x))
    for order in range(3):
        np.testing.assert_allclose(
            flag[2 * order : 2 * order + 2], trajectory.derivative(t, order).T, atol=LINEAR_TOL
        )
    assert affine.outputs == 2 and slope.shape == (6, t.size, x.size)


def test_starting_guess_is_the_papers_cubic(paper_plan: Plan) -> None:
    """In a cubic basis the min-acceleration start with the paper's rates is the cubic."""
    basis = PolynomialBasis(3, 2.0)
    affine, curve = affine_map(K, basis, START, GOAL, 0.1, 0.5, True, False)
    np.testing.assert_allclose(curve[:2], [0.1, 0.5])
    np.testing.assert_allclose(
        affine.coefficients(curve), paper_plan.trajectory.coefficients, rtol=REBUILT_TOL
    )


def test_the_end_map_is_linear_in_the_rate() -> None:
    """``FlatModel.end_map`` against the forward map (``flatness.flat_outputs``) at two
    rates: y' = slope th1'."""
    y, slope = K.end_map(START)
    for u1 in (0.3, -2.0):
        f = flat_outputs(K.coefficients, *START, u1)
        assert (f[0], f[1]) == (y[0], y[1])
        assert f[2] == pytest.approx(slope[0, 0] * u1, rel=1e-14)
        assert f[3] == pytest.approx(slope[1, 0] * u1, rel=1e-14)
    assert y[0] == START[1]
