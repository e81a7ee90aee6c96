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


#: The issue's goal for the as-built law on designs not in the repository: median final
#: error from initial angle errors of std 0.01 rad.
DESIGN_GOAL = 1e-4
#: Trials per design, and the seed of the designs and of their initial errors.
DESIGN_TRIALS = 5
DESIGN_SEED = 2003


def _final_errors(robot: RobotParams, trials: int, seed: int) -> np.ndarray:
    """Final errors ||th(T) - goal|| [rad] of ``trials`` starts with errors of std 0.01 rad,
    integrated by DOP853 (rtol 1e-10) on the link geometry of ``asbuilt_support.weights``
    with the law w = w_r - L (th - th_r) read from the tracked channels (the design under
    test): all trials as one system, or one at a time if one of them leaves the plan beyond
    100 rad (it then counts as infinite)."""
    from tests.asbuilt_support import maneuver, weights

    n = robot.n_joints
    start, goal = maneuver(n)
    plan = plan_exact(robot, start, goal, 0.1, 0.5, 2.0)
    curves = tracked(plan)
    starts = start + np.random.default_rng(seed).normal(0.0, 0.01, (trials, n + 1))

    def rhs(t: float, x: np.ndarray) -> np.ndarray:
        tt = np.array([t])
        values, rates = curves.derivative(tt, 0)[0], curves.derivative(tt, 1)[0]
        ref = np.r_[values[n], values[:n]]
        theta = x.reshape(-1, n + 1)
        w = rates[:n] - (theta - ref) @ values[n + 1:].reshape(n, n + 1).T
        h = weights(robot, theta)
        return np.c_[-(h[:, 1:] * w).sum(axis=1) / h[:, 0], w].ravel()

    def escaped(t: float, x: np.ndarray) -> float:
        return 100.0 - float(np.abs(x).max())

    escaped.terminal = True  # type: ignore[attr-defined]

    def finals(x0: np.ndarray) -> np.ndarray | None:
        sol = solve_ivp(rhs, (0.0, 2.0), x0.ravel(), method="DOP853", rtol=1e-10, atol=1e-12,
                        events=escaped)
        return None if sol.status == 1 else sol.y[:, -1].reshape(-1, n + 1)

    together = finals(starts)
    if together is not None:
        return np.asarray(np.linalg.norm(together - goal, axis=1))
    alone = [finals(x0[None]) for x0 in starts]
    return np.array([np.inf if f is None else float(np.linalg.norm(f[0] - goal))
                     for f in alone])


@pytest.mark.parametrize("n", [2, 3, 4])
def test_default_weights_hold_on_random_designs(n: int) -> None:
    """Referee: DOP853 of the closed loop on the link geometry (``_final_errors``). The first
    design of N joints drawn from DESIGN_SEED (``asbuilt_support.random_as_built``: the
    counterweight 2 to 5 mm off, none of them in the repository; drawn, not chosen) ends within
    the issue's goal with the default weights (measured: medians 1.2e-6, 9.8e-9, 7.3e-9 rad
    over 16 trials each)."""
    from tests.asbuilt_support import maneuver, random_as_built

    rng = np.random.default_rng(DESIGN_SEED)
    robot = None
    for i in range(3 * 10):  # the designs are drawn N = 2, 3, 4, 2, ...; the first that plans
        candidate = random_as_built(rng, 2 + i % 3)
        if candidate.n_joints != n:
            continue
        try:
            start, goal = maneuver(n)
            plan_exact(candidate, start, goal, 0.1, 0.5, 2.0)
        except FlatcliError:
            continue
        robot = candidate
        break
    assert robot is not None
    errors = _final_errors(robot, DESIGN_TRIALS, DESIGN_SEED + n)
    assert np.median(errors) <= DESIGN_GOAL, errors


def test_default_weights_scale_with_the_plans_duration() -> None:
    """The defaults are b = 10 / T and t_f = 5e5 T (the former fixed 5 rad/s and 1e6 s at
    T = 2 s); given values win. Referee: the design at T = 2 s with the former fixed values
    (the gains are the same curves to rounding)."""
    weights = LqrWeights().resolved(4.0)
    assert weights.bandwidth == pytest.approx(2.5) and weights.terminal == pytest.approx(2e6)
    assert LqrWeights(bandwidth=7.0, terminal=3.0).resolved(4.0) == LqrWeights(7.0, 3.0)
    plan = plan_exact(AS_BUILT, START, GOAL, 0.1, 0.5, 2.0)
    t = np.linspace(0.0, 2.0, 101)
    np.testing.assert_allclose(tracked(plan).derivative(t, 0),
                               tracked(plan, LqrWeights(5.0, 1e6)).derivative(t, 0),
                               rtol=1e-12, atol=1e-9)
