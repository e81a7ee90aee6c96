"""Tests of flatcli.core.optimize.quantities: pointwise quantities from the flat flag.

References: ``planning.state_and_rates`` (the plan's own state and rates, computed through
its complex-step derivative of the flat map) and central finite differences.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from flatcli.core.optimize.quantities import (
    ANGLES,
    FLAG_SIZE,
    MARGIN,
    NAMES,
    RATES,
    flag_jacobian,
    flag_quantities,
)
from flatcli.core.planning import FlatPlan, state_and_rates

#: Identities that hold to rounding.
EXACT_TOL = 1e-12
#: Central differences of a pointwise function at step 1e-6: truncation ~1e-12 x third
#: derivative, rounding ~1e-16 / 1e-6 x value; observed < 1e-7 relative.
FD_STEP = 1e-6
FD_RTOL = 1e-6


def paper_flag(plan: FlatPlan, n: int) -> NDArray[np.float64]:
    """(6, n) flat flag of a plan on n equally spaced times."""
    s = plan.sample(plan.grid(n))
    return np.vstack([s.y.T, s.y_dot.T, s.y_ddot.T])


def test_layout() -> None:
    """Every row is named once, the groups partition the rows."""
    assert sorted((*ANGLES, *RATES, MARGIN)) == list(range(len(NAMES)))
    assert [NAMES[i] for i in ANGLES] == ["th0", "th1", "th2"]
    assert [NAMES[i] for i in RATES] == ["th1'", "th2'"]
    assert FLAG_SIZE == 6


def test_flag_quantities_match_planning(paper_plan: FlatPlan) -> None:
    """The closed-form th2' equals planning's complex-step th' along the paper's cubic."""
    s = paper_plan.sample(paper_plan.grid(101))
    flag = paper_flag(paper_plan, 101)
    q = flag_quantities(paper_plan.coefficients, flag)
    state, state_dot = state_and_rates(paper_plan.coefficients, s.y, s.y_dot, s.y_ddot)
    np.testing.assert_allclose(q[list(ANGLES)].T, state[:, :3], rtol=EXACT_TOL, atol=EXACT_TOL)
    scale = np.max(np.abs(state_dot[:, 1:3]))
    np.testing.assert_allclose(q[list(RATES)].T, state_dot[:, 1:3], rtol=0, atol=EXACT_TOL * scale)
    np.testing.assert_allclose(q[MARGIN], np.sin(s.y[:, 0]) * s.y_dot[:, 0], rtol=EXACT_TOL)


def test_flag_jacobian_against_central_differences(paper_plan: FlatPlan) -> None:
    flag = paper_flag(paper_plan, 41)
    values, jac = flag_jacobian(paper_plan.coefficients, flag)
    real = flag_quantities(paper_plan.coefficients, flag)
    np.testing.assert_allclose(values, real, rtol=EXACT_TOL)  # complex arithmetic: rounding
    for c in range(FLAG_SIZE):
        step = np.zeros((FLAG_SIZE, 1))
        step[c] = FD_STEP * max(1.0, float(np.max(np.abs(flag[c]))))
        up = flag_quantities(paper_plan.coefficients, flag + step)
        down = flag_quantities(paper_plan.coefficients, flag - step)
        fd = (up - down) / (2 * step[c])
        scale = np.max(np.abs(jac[:, c, :]), axis=1, keepdims=True) + 1.0
        np.testing.assert_allclose(jac[:, c, :] / scale, fd / scale, rtol=0, atol=FD_RTOL)
