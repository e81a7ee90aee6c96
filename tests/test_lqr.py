"""Tests of flatcli.core.controllers.lqr: the as-built law's linearisation, Riccati gains
and channels.

Referees: central differences of th0' = -(h . w) / h_0 with h from the link geometry
(``tests/asbuilt_support.py``); the LQR's cost-to-go theorem (a closed loop with the optimal
gains costs e0^T P(0) e0, integrated here by scipy's DOP853, and any other gain costs more);
the plan's own angles (the tracked channels reproduce them).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from flatcli.core.controllers.lqr import (
    LqrWeights,
    TrackedLayout,
    linearisation,
    reference_channels,
    riccati,
    riccati_gains,
    tracked,
)
from flatcli.core.errors import FlatcliError
from flatcli.core.plan.exact import constraint_of, plan_exact
from flatcli.core.plan.planning import plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams
from tests.asbuilt_support import AS_BUILT, GOAL, START, base_rate

#: Central differences of the referee's base rate (step 1e-6): their truncation.
DIFFERENCE_TOL = 1e-8
#: The closed loop's integrated cost against e0^T P(0) e0 (DOP853 at rtol 1e-10).
COST_RTOL = 1e-5


@pytest.mark.parametrize("robot", [AS_BUILT, RobotParams(com=(0.1, 0.1, 0.002),
                                                         com_across=0.003)])
def test_linearisation_is_the_derivative_of_the_geometry(robot: RobotParams) -> None:
    """Referee: central differences of ``asbuilt_support.base_rate`` (link geometry)."""
    q, w = np.array([1.3, 0.7]), np.array([0.4, -1.1])
    A, B = linearisation(constraint_of(robot), q[None], w[None])
    step = 1e-6
    for k in range(2):
        e = np.eye(2)[k] * step
        dq = (base_rate(robot, q + e, w) - base_rate(robot, q - e, w)) / (2 * step)
        dw = (base_rate(robot, q, w + e) - base_rate(robot, q, w - e)) / (2 * step)
        assert abs(A[0, 0, 1 + k] - dq) <= DIFFERENCE_TOL
        assert abs(B[0, 0, k] - dw) <= DIFFERENCE_TOL
    assert np.all(A[0, 1:] == 0) and np.all(A[0, :, 0] == 0)  # only th0 moves; not by th0
    np.testing.assert_array_equal(B[0, 1:], np.eye(2))
    Al, Bl = linearisation(constraint_of(robot), q[None], w[None], servo=50.0)
    np.testing.assert_array_equal(Al[0, 0, 1:3], A[0, 0, 1:])
    np.testing.assert_array_equal(Al[0, 0, 3:], B[0, 0])
    np.testing.assert_array_equal(Al[0, 3:, 3:], -50.0 * np.eye(2))
    np.testing.assert_array_equal(Bl[0, 3:], 50.0 * np.eye(2))


def test_gains_are_optimal_for_the_linearised_loop() -> None:
    """Referee: the LQR's cost-to-go theorem, the cost integrated by DOP853 along the
    closed loop e' = (A - B L) e of the module's linearisation (checked above), with the
    fitted gains, and the same loop with L scaled by 0.8 and 1.25 costing more."""
    plan = plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0)
    reference = reference_channels(plan)
    weights = LqrWeights(bandwidth=5.0, terminal=1.0, base=10.0)
    constraint = constraint_of(AS_BUILT)
    gains = riccati_gains(constraint, reference, weights)
    Q, b2 = weights.running(2, False), weights.bandwidth**2
    e0 = np.array([0.02, -0.01, 0.015])

    def cost(scale: float) -> float:
        def rhs(t: float, x: np.ndarray) -> np.ndarray:
            tt = np.array([t])
            A, B = linearisation(constraint, reference.derivative(tt, 0)[:, :2],
                                 reference.derivative(tt, 1)[:, :2])
            L = scale * gains.derivative(tt, 0)[0].reshape(2, 3)
            e = x[:3]
            v = -L @ e
            return np.r_[(A[0] + B[0] @ -L) @ e, e @ Q @ e + b2**-1 * (v @ v)]

        sol = solve_ivp(rhs, (0.0, 2.0), np.r_[e0, 0.0], method="DOP853", rtol=1e-10,
                        atol=1e-14)
        e_final = sol.y[:3, -1]
        return float(sol.y[3, -1] + weights.terminal * e_final @ Q @ e_final)

    P0 = riccati(constraint, reference, weights)(2.0).reshape(3, 3)
    optimal = cost(1.0)
    assert optimal == pytest.approx(float(e0 @ P0 @ e0), rel=COST_RTOL)
    assert cost(0.8) > optimal and cost(1.25) > optimal


@pytest.mark.parametrize("flat", [False, True])
def test_tracked_channels_hold_the_plans_angles(flat: bool) -> None:
    """Referee: the plan's own angles (``Plan.sample``), exact or flat."""
    plan = (plan_point_to_point(PAPER_ROBOT, START, GOAL, 0.1, 0.5, 2.0) if flat
            else plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0))
    curves = tracked(plan, LqrWeights())
    layout = TrackedLayout(2, 3)
    assert curves.coefficients.shape[0] == layout.channels == 9 and layout.size == 27
    t = np.linspace(0.0, 2.0, 401)
    theta = plan.sample(t).theta
    values = curves.derivative(t, 0)
    np.testing.assert_allclose(values[:, [2, 0, 1]], theta, atol=1e-9 if flat else 1e-12)
    lagged = tracked(plan, LqrWeights(), servo=100.0)
    assert lagged.coefficients.shape[0] == TrackedLayout(2, 5).channels == 13


def test_weights_are_checked() -> None:
    with pytest.raises(FlatcliError, match=r"track\.lqr_bandwidth: must be a finite number > 0"):
        LqrWeights(bandwidth=0.0)
    with pytest.raises(FlatcliError, match=r"track\.lqr_terminal"):
        LqrWeights(terminal=float("inf"))
    with pytest.raises(FlatcliError, match=r"track\.lqr_base"):
        LqrWeights(base=-1.0)


def test_a_riccati_equation_that_cannot_be_integrated_names_both_weights(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The failure depends on the bandwidth as much as on the terminal weight (a stiff
    equation at b = 1e12 rad/s): the message names both keys and their values."""
    import scipy.integrate

    plan = plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0)

    def failing(*args: object, **kwargs: object) -> object:
        class Failed:
            success, sol = False, None
            message = "Required step size is less than spacing between numbers."
        return Failed()

    monkeypatch.setattr(scipy.integrate, "solve_ivp", failing)
    with pytest.raises(FlatcliError, match=r"^track\.lqr_bandwidth, track\.lqr_terminal: the "
                                           r"Riccati equation could not be integrated .*lower "
                                           r"track\.lqr_bandwidth \(1e\+12 rad/s\)"):
        riccati(constraint_of(AS_BUILT), reference_channels(plan), LqrWeights(bandwidth=1e12))


def test_the_riccati_steps_grow_with_the_bandwidth_as_the_limits_assume() -> None:
    """flatcli.spec.limits prices the design at RICCATI_STEPS_PER_RADIAN x b x T steps: the
    integration this module does takes at least that many (so a design the limit refuses
    would not have fitted), here at b = 5, 50 and 500 rad/s (147, 333 and 1,191 steps when
    measured)."""
    from flatcli.spec.limits import RICCATI_STEPS_PER_RADIAN

    plan = plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0)
    reference = reference_channels(plan)
    for bandwidth in (5.0, 50.0, 500.0):
        solution = riccati(constraint_of(AS_BUILT), reference, LqrWeights(bandwidth=bandwidth))
        steps = len(solution.ts) - 1
        assert steps >= RICCATI_STEPS_PER_RADIAN * bandwidth * 2.0, (bandwidth, steps)
