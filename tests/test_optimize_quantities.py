"""Tests of flatcli.core.optimize.quantities: pointwise quantities from the flat flag.

References: ``flatmodel.state_and_rates`` (the plan's own state and rates, computed through
its complex-step derivative of the flat map) and central finite differences.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from test_chainplan import example_plan

from flatcli.core.models.flatmodel import ChainModel, state_and_rates
from flatcli.core.optimize.quantities import (
    ANGLES,
    FLAG_SIZE,
    MARGIN,
    NAMES,
    RATES,
    flag_jacobian,
    flag_quantities,
    layout,
    layout_of,
)
from flatcli.core.plan.planning import Plan
from flatcli.core.robots.params import PAPER_ROBOT

#: Identities that hold to rounding.
EXACT_TOL = 1e-12
#: Central differences of a pointwise function at step 1e-6: truncation ~1e-12 x third
#: derivative, rounding ~1e-16 / 1e-6 x value; observed < 1e-7 relative.
FD_STEP = 1e-6
FD_RTOL = 1e-6


def paper_flag(plan: Plan, n: int) -> NDArray[np.float64]:
    """(6, n) flat flag of a plan on n equally spaced times."""
    s = plan.sample(plan.grid(n))
    return np.vstack([s.y.T, s.y_dot.T, s.y_ddot.T])


def test_layout() -> None:
    """Every row is named once, the groups partition the rows."""
    assert sorted((*ANGLES, *RATES, MARGIN)) == list(range(len(NAMES)))
    assert [NAMES[i] for i in ANGLES] == ["th0", "th1", "th2"]
    assert [NAMES[i] for i in RATES] == ["th1'", "th2'"]
    assert FLAG_SIZE == 6


def test_flag_quantities_match_planning(paper_plan: Plan) -> None:
    """The closed-form th2' equals planning's complex-step th' along the paper's cubic."""
    s = paper_plan.sample(paper_plan.grid(101))
    flag = paper_flag(paper_plan, 101)
    q = flag_quantities(paper_plan.model, flag)
    state, state_dot = state_and_rates(paper_plan.coefficients, s.y, s.y_dot, s.y_ddot)
    np.testing.assert_allclose(q[list(ANGLES)].T, state[:, :3], rtol=EXACT_TOL, atol=EXACT_TOL)
    scale = np.max(np.abs(state_dot[:, 1:3]))
    np.testing.assert_allclose(q[list(RATES)].T, state_dot[:, 1:3], rtol=0, atol=EXACT_TOL * scale)
    np.testing.assert_allclose(q[MARGIN], np.sin(s.y[:, 0]) * s.y_dot[:, 0], rtol=EXACT_TOL)


def test_flag_jacobian_against_central_differences(paper_plan: Plan) -> None:
    flag = paper_flag(paper_plan, 41)
    values, jac = flag_jacobian(paper_plan.model, flag)
    real = flag_quantities(paper_plan.model, flag)
    np.testing.assert_allclose(values, real, rtol=EXACT_TOL)  # complex arithmetic: rounding
    for c in range(FLAG_SIZE):
        step = np.zeros((FLAG_SIZE, 1))
        step[c] = FD_STEP * max(1.0, float(np.max(np.abs(flag[c]))))
        up = flag_quantities(paper_plan.model, flag + step)
        down = flag_quantities(paper_plan.model, flag - step)
        fd = (up - down) / (2 * step[c])
        scale = np.max(np.abs(jac[:, c, :]), axis=1, keepdims=True) + 1.0
        np.testing.assert_allclose(jac[:, c, :] / scale, fd / scale, rtol=0, atol=FD_RTOL)


def test_two_link_chain_path_is_the_papers(paper_plan: Plan) -> None:
    """N = 2 through the chain's flag map (``ChainModel``) gives the paper path's quantities
    (``Coefficients``, derived) and their Jacobians along the paper's cubic: the chain's
    margin -(dh_0/dt) / (2 K_10) is sin(y1) y1' for two links."""
    flag = paper_flag(paper_plan, 41)
    chain = ChainModel.of(PAPER_ROBOT)
    assert layout_of(chain) == layout(2) and layout(2).margin == MARGIN
    paper_values, paper_jac = flag_jacobian(paper_plan.model, flag)
    chain_values, chain_jac = flag_jacobian(chain, flag)
    scale = np.max(np.abs(paper_values), axis=1, keepdims=True)
    np.testing.assert_allclose(chain_values / scale, paper_values / scale, rtol=0, atol=1e-10)
    real = np.asarray(flag_quantities(chain, flag), dtype=float)
    np.testing.assert_allclose(real, chain_values, rtol=1e-12, atol=0)
    jscale = np.max(np.abs(paper_jac), axis=(1, 2), keepdims=True) + 1.0
    np.testing.assert_allclose(chain_jac / jscale, paper_jac / jscale, rtol=0, atol=1e-10)


def test_chain_layout_and_jacobian_against_central_differences() -> None:
    """N = 3: rows named once; the compiled complex-step Jacobian of a chain against central
    differences of the real quantities."""
    lay = layout(3)
    assert lay.names == ("th0", "th1", "th2", "th3", "th1'", "th2'", "th3'", "margin")
    assert sorted((*lay.angles, *lay.rates, lay.margin)) == list(range(lay.size))
    plan = example_plan(3)
    t = plan.grid(21)
    flag = np.ascontiguousarray(plan.flags(t).T)  # (9, 21)
    values, jac = flag_jacobian(plan.model, flag)
    s = plan.sample(t)
    np.testing.assert_allclose(values[list(lay.angles)].T, s.theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(values[list(lay.rates)].T, s.theta_dot[:, 1:], rtol=1e-12)
    for c in range(lay.flag_size):
        step = np.zeros((lay.flag_size, 1))
        step[c] = FD_STEP * max(1.0, float(np.max(np.abs(flag[c]))))
        up = np.asarray(flag_quantities(plan.model, flag + step), dtype=float)
        down = np.asarray(flag_quantities(plan.model, flag - step), dtype=float)
        fd = (up - down) / (2 * step[c])
        scale = np.max(np.abs(jac[:, c, :]), axis=1, keepdims=True) + 1.0
        np.testing.assert_allclose(jac[:, c, :] / scale, fd / scale, rtol=0, atol=FD_RTOL)
