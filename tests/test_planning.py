"""Tests of flatcli.core.plan.planning: the paper's plan, its momentum, exact rates, refusals."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import pytest
from numpy.typing import NDArray

from flatcli.core.curves.basis import Basis, BSplineBasis, PolynomialBasis
from flatcli.core.errors import FlatcliError
from flatcli.core.models.flatmodel import paper_margin_zeros as margin_zeros
from flatcli.core.models.flatness import flat_inputs
from flatcli.core.names import MODELS, Model
from flatcli.core.plan.planning import (
    Plan,
    PlanSamples,
    plan_point_to_point,
)
from flatcli.core.robots.params import PAPER_ROBOT, base_rate, momentum

if TYPE_CHECKING:
    from conftest import Maneuver

Array = NDArray[np.float64]

#: Dense grid for maxima along the plan.
DENSE = 2001
#: |H| along the derived plan: rounding of sums of terms up to I |th'| ~ 0.05 x 50 kg m^2/s
#: (observed ~7e-16).
DERIVED_MOMENTUM_BOUND = 1e-10
#: Identities evaluated exactly (rounding only).
EXACT_TOL = 1e-12
#: Angles at the ends come back through the inverse map, which divides by h y1' ~ 3e-3 at
#: t = 0: rounding of y2'(0) is amplified ~300-fold (observed 1.1e-12 with B-splines).
BOUNDARY_TOL = 1e-10
#: 8th-order central differences at h = 1e-3 vs the complex step: truncation ~h^8 th^(9),
#: observed 8e-12 rad/s against rates up to 24 rad/s in the interior.
FD_STEP = 1e-3
FD_TOL = 1e-9


def sample(plan: Plan, n: int = DENSE) -> PlanSamples:
    return plan.sample(plan.grid(n))


def test_momentum_along_derived_plan_vanishes(paper_plan: Plan) -> None:
    """|H| from the full kinematics vanishes to rounding along the corrected plan."""
    s = sample(paper_plan)
    H = momentum(PAPER_ROBOT.links, *s.theta.T, *s.theta_dot.T)
    np.testing.assert_array_equal(s.momentum, H)  # what the plan reports is that referee
    assert np.max(np.abs(H)) < DERIVED_MOMENTUM_BOUND


def test_momentum_along_printed_plan_is_off(paper_plan_as_printed: Plan) -> None:
    """The plan made with the printed coefficients obeys A th0' = B' th1' + C th2' with the
    printed b1' = -0.01 instead of b1 = -0.03 (tests/test_model.py derives both), so its true
    momentum is, in closed form, H = (b1' - b1) cos(th1) th1' / M: compared pointwise with H
    from the full kinematics (its largest value ~1.4e-3 kg m^2/s)."""
    s = sample(paper_plan_as_printed)
    H = momentum(PAPER_ROBOT.links, *s.theta.T, *s.theta_dot.T)
    expected = (-0.01 - -0.03) * np.cos(s.y[:, 0]) * s.y_dot[:, 0] / PAPER_ROBOT.total_mass
    np.testing.assert_allclose(H, expected, atol=1e-14)
    assert np.max(np.abs(H)) > 1e-3


@pytest.mark.parametrize(
    ("model", "t", "expected", "tol"),
    [
        # paper, Sec. VI (as printed, computed with its b1): to the printed digits
        ("paper", 0.0, -0.065, 0.5e-3),
        ("paper", 2.0, -0.3512, 0.5e-4),
        # correct b1: eq. 36 at th2 = 0, y2' = (b0 + b1 cos th1) / (a0 + a1 cos th1) th1',
        # with the paper robot's coefficients a0 = 0.5597, a1 = 0.06, b0 = -0.3798,
        # b1 = -0.03 (tests/test_model.py derives them symbolically)
        ("derived", 0.0, (-0.3798 - 0.03 * np.cos(1.0)) / (0.5597 + 0.06 * np.cos(1.0)) * 0.1,
         1e-12),
        ("derived", 2.0, (-0.3798 - 0.03 * np.cos(2.0)) / (0.5597 + 0.06 * np.cos(2.0)) * 0.5,
         1e-12),
    ],
)
def test_boundary_values_of_y2_dot(
    plan_factory: Callable[..., Plan], model: Model, t: float, expected: float, tol: float
) -> None:
    plan = plan_factory(model)
    y2_dot = plan.trajectory.derivative(np.array([t]), 1)[0, 1]
    assert abs(y2_dot - expected) <= tol


def bases(duration: float) -> list[Basis]:
    return [
        PolynomialBasis(3, duration),
        PolynomialBasis(5, duration),
        BSplineBasis(4, duration, 3),
        BSplineBasis(9, duration, 5),
    ]


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("which", range(4))
def test_plan_meets_its_boundary_conditions(
    plan_factory: Callable[..., Plan], paper_maneuver: Maneuver, model: Model, which: int
) -> None:
    """th(0) = start, th(T) = goal, th1'(0), th1'(T) = the chosen end rates, in every basis."""
    m = paper_maneuver
    plan = plan_factory(model, bases(m.duration)[which])
    s = plan.sample(np.array([0.0, m.duration]))
    np.testing.assert_allclose(s.theta, [m.start, m.goal], atol=BOUNDARY_TOL)
    np.testing.assert_allclose(s.theta_dot[:, 1], [m.start_rate, m.goal_rate], atol=EXACT_TOL)


@pytest.mark.parametrize("which", [1, 2, 3])
def test_richer_bases_reproduce_the_cubic(
    plan_factory: Callable[..., Plan], paper_plan: Plan, which: int
) -> None:
    """The cubic Hermite curve minimises the integral of |y''|^2; every basis here holds it."""
    plan = plan_factory("derived", bases(paper_plan.duration)[which])
    t = paper_plan.grid(101)
    for order in (0, 1, 2):
        np.testing.assert_allclose(
            plan.trajectory.derivative(t, order),
            paper_plan.trajectory.derivative(t, order),
            atol=1e-10,
        )


def central_difference(plan: Plan, t: Array, h: float) -> Array:
    """(n, 3) th'(t) by the 8th-order central difference of th(t) (independent of the plan)."""
    weights = np.array([1 / 280, -4 / 105, 1 / 5, -4 / 5, 0.0, 4 / 5, -1 / 5, 4 / 105, -1 / 280])
    theta = np.stack([plan.sample(t + j * h).theta for j in range(-4, 5)])
    return np.tensordot(weights, theta, axes=(0, 0)) / h


@pytest.mark.parametrize("model", MODELS)
def test_exact_rates_agree_with_finite_differences(
    plan_factory: Callable[..., Plan], model: Model
) -> None:
    plan = plan_factory(model)
    t = np.linspace(0.01, plan.duration - 0.01, 60)
    s = plan.sample(t)
    np.testing.assert_allclose(s.theta_dot, central_difference(plan, t, FD_STEP), atol=FD_TOL)
    # u1 = th1' = y1' and u1' = y1'' (flat output y1 = th1)
    np.testing.assert_allclose(s.theta_dot[:, 1], s.y_dot[:, 0], atol=EXACT_TOL)
    np.testing.assert_allclose(s.u1_dot, s.y_ddot[:, 0], atol=EXACT_TOL)


@pytest.mark.parametrize("model", MODELS)
def test_plan_inputs_are_the_flat_inputs(
    plan_factory: Callable[..., Plan], model: Model
) -> None:
    """u2 = flat_inputs(y'') at the plan's state equals the plan's th2'."""
    plan = plan_factory(model)
    s = sample(plan, 401)
    u1_dot, u2 = flat_inputs(
        plan.coefficients, s.theta[:, 1], s.theta[:, 2], s.y_dot[:, 0], *s.y_ddot.T
    )
    np.testing.assert_allclose(u2, s.u2, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(u1_dot, s.u1_dot, atol=EXACT_TOL)


@pytest.mark.parametrize("model", MODELS)
def test_plan_obeys_its_own_constraint(plan_factory: Callable[..., Plan], model: Model) -> None:
    """th0' (complex step) equals the base rate the planner's model implies (H = 0)."""
    plan = plan_factory(model)
    s = sample(plan, 401)
    th0_dot = base_rate(plan.coefficients, PAPER_ROBOT.total_mass, 0.0, *s.theta[:, 1:].T,
                        *s.theta_dot[:, 1:].T)  # fmt: skip
    np.testing.assert_allclose(s.theta_dot[:, 0], th0_dot, rtol=1e-12, atol=1e-12)


def test_the_corrected_plan_folds_link_2_past_link_1(paper_plan: Plan) -> None:
    """The cubic's start: th1' = 0.1 (its boundary condition), th2'(0) large (eq. 39 divides
    by h th1' = 0.1 h there); and momentum conservation makes th2 pass pi (link 2 folds past
    link 1), as ``required_fold`` (tests/test_optimize_feasibility.py) says any monotone plan
    must reach 2.67 rad; th0' from the constraint (eq. 31) at t = 0 equals the plan's exact
    rate."""
    s = paper_plan.sample(np.linspace(0.0, 2.0, 20001))
    assert s.theta_dot[0, 1] == pytest.approx(0.1, abs=EXACT_TOL)
    assert s.theta_dot[0, 2] > 10.0
    k = paper_plan.coefficients
    th0_dot = base_rate(k, PAPER_ROBOT.total_mass, 0.0, *s.theta[0, 1:], *s.theta_dot[0, 1:])
    assert s.theta_dot[0, 0] == pytest.approx(float(th0_dot), rel=1e-12)
    assert s.theta[:, 2].max() > np.pi


def test_margin_is_reported_along_the_plan(paper_plan: Plan) -> None:
    s = sample(paper_plan, 201)
    np.testing.assert_array_equal(s.margin, np.abs(np.sin(s.y[:, 0]) * s.y_dot[:, 0]))
    # the minimum is at t = 0: sin(1) * 0.1 (paper's start, th1 = 1, th1' = 0.1)
    assert s.margin.min() == pytest.approx(np.sin(1.0) * 0.1, rel=1e-12)


# --------------------------------------------------------------------------------------
# Refusals
# --------------------------------------------------------------------------------------


def plan_with(maneuver: Maneuver, **changes: object) -> Plan:
    args: dict[str, object] = {
        "robot": PAPER_ROBOT,
        "start": np.array(maneuver.start),
        "goal": np.array(maneuver.goal),
        "start_rate": maneuver.start_rate,
        "goal_rate": maneuver.goal_rate,
        "duration": maneuver.duration,
    }
    args.update(changes)
    return plan_point_to_point(**args)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"robot": PAPER_ROBOT.with_(com=(0.1, 0.1, 0.005))}, "d2"),
        ({"robot": PAPER_ROBOT.with_(com=(0.2, 0.1, 0.0))}, "l0 - d0"),
        ({"robot": PAPER_ROBOT.with_(com=(0.1, -0.2, 0.0))}, "m1 d1 \\+ m2 l1"),
        ({"start_rate": 0.0}, "plan\\.start_rate: must be != 0"),
        ({"goal_rate": 0.0}, "plan\\.goal_rate: must be != 0"),
        ({"start": np.array([1.8, 0.0, 0.0])}, "plan\\.start\\[1\\].*sin th1 = 0"),
        ({"goal": np.array([1.2, np.pi, 0.0])}, "plan\\.goal\\[1\\].*sin th1 = 0"),
        ({"goal": np.array([1.2, -2 * np.pi, 0.0])}, "plan\\.goal\\[1\\].*sin th1 = 0"),
        ({"duration": 0.0}, "plan\\.duration"),
        ({"duration": -1.0}, "plan\\.duration"),
    ],
)
def test_plan_refuses_bad_requests(
    paper_maneuver: Maneuver, changes: dict[str, object], match: str
) -> None:
    with pytest.raises(FlatcliError, match=match):
        plan_with(paper_maneuver, **changes)


def test_plan_refuses_a_basis_of_another_duration(paper_maneuver: Maneuver) -> None:
    with pytest.raises(FlatcliError, match="duration"):
        plan_with(paper_maneuver, basis=PolynomialBasis(3, 3.0))


# --------------------------------------------------------------------------------------
# Plans that cross the singular set inside the maneuver
# --------------------------------------------------------------------------------------


def sampled_sign_changes(plan_times: Array, y1: Array, y1_dot: Array) -> Array:
    """Times between samples where sin(y1) y1' changes sign (an independent, sampled look)."""
    signed = np.sin(y1) * y1_dot
    flips = np.flatnonzero(np.sign(signed[:-1]) != np.sign(signed[1:]))
    return plan_times[flips]


def test_a_plan_through_the_singular_set_is_refused(paper_maneuver: Maneuver) -> None:
    """th1'(T) = -0.5 against th1'(0) = +0.1: y1' must pass through 0 inside (0, T). The
    refusal names the time, which a dense sampling of the margin brackets."""
    basis = PolynomialBasis(3, paper_maneuver.duration)
    from flatcli.core.models.flatmodel import boundary_conditions
    from flatcli.core.plan.planning import min_acceleration_trajectory

    k = PAPER_ROBOT.coefficients("derived")
    bc = boundary_conditions(k, paper_maneuver.start, paper_maneuver.goal, 0.1, -0.5)
    curve = min_acceleration_trajectory(basis, bc)
    t = np.linspace(0.0, paper_maneuver.duration, 200_001)
    flips = sampled_sign_changes(t, curve.derivative(t, 0)[:, 0], curve.derivative(t, 1)[:, 0])
    assert flips.size == 1
    zeros = margin_zeros(curve)
    assert zeros.size == 1 and abs(zeros[0] - flips[0]) <= t[1]
    with pytest.raises(FlatcliError, match=rf"t = {zeros[0]:.4g} s .*th1' = 0.*start_rate"):
        plan_with(paper_maneuver, goal_rate=-0.5)


def test_a_plan_that_touches_the_singular_set_is_refused(paper_maneuver: Maneuver) -> None:
    """A cubic whose y1' has a double root inside (0, T): the margin touches zero without
    changing sign, so a sampled sign test misses it; the exact roots do not."""
    T = 2.0
    # y1(t) = 1 + (t - 1)^3 / 3: y1'(t) = (t - 1)^2 >= 0 touches 0 at t = 1
    basis = PolynomialBasis(3, T)
    # in s = t / T: 1 + (2 s - 1)^3 / 3 = 2/3 + 2 s - 4 s^2 + 8/3 s^3 (y2 = t / T, any curve)
    coefficients = np.array([[2.0 / 3.0, 2.0, -4.0, 8.0 / 3.0], [0.0, 1.0, 0.0, 0.0]])
    from flatcli.core.plan.planning import FlatTrajectory

    curve = FlatTrajectory(basis, coefficients)
    t = np.linspace(0.0, T, 10_001)
    np.testing.assert_allclose(curve.derivative(t, 1)[:, 0], (t - 1.0) ** 2, atol=1e-12)
    zeros = margin_zeros(curve)
    assert zeros.size >= 1 and np.all(np.abs(zeros - 1.0) < 1e-6)


def test_a_plan_through_sin_th1_zero_is_refused(paper_maneuver: Maneuver) -> None:
    """th1 from 1 to 4 rad passes pi (sin th1 = 0) though th1' > 0 throughout."""
    with pytest.raises(FlatcliError, match="sin th1 = 0"):
        plan_with(paper_maneuver, goal=np.array([1.2, 4.0, 0.0]), goal_rate=0.5)


def test_a_batch_is_refused_when_any_plan_crosses(paper_maneuver: Maneuver) -> None:
    n = 50
    rates = np.full(n, 0.5)
    start = np.tile(paper_maneuver.start, (n, 1))
    goal = np.tile(paper_maneuver.goal, (n, 1))
    plan = plan_point_to_point(PAPER_ROBOT, start, goal, np.full(n, 0.1), rates, 2.0)
    assert all(margin_zeros(type(plan.trajectory)(plan.trajectory.basis, c)).size == 0
               for c in plan.trajectory.coefficients)
    rates[17] = -0.5
    with pytest.raises(FlatcliError, match="maneuver 17 of the batch"):
        plan_point_to_point(PAPER_ROBOT, start, goal, np.full(n, 0.1), rates, 2.0)


#: Four maneuvers near the paper's (Sec. VI), each off the singular set.
BATCH_START = np.array([[1.8, 1.0, 0.0], [1.7, 1.1, 0.1], [1.9, 0.9, -0.2], [1.6, 1.2, 0.05]])
BATCH_GOAL = np.array([[1.2, 2.0, 0.0], [1.3, 1.9, 0.1], [1.1, 2.1, 0.0], [1.25, 1.8, -0.1]])
BATCH_START_RATE = np.array([0.1, 0.15, 0.12, 0.2])
BATCH_GOAL_RATE = np.array([0.5, 0.4, 0.6, 0.3])


@pytest.mark.parametrize("basis", [None, BSplineBasis(12, 2.0, 5)], ids=["cubic", "bspline"])
def test_a_batch_of_plans_equals_the_plans_made_one_at_a_time(basis: Basis | None) -> None:
    batch = plan_point_to_point(PAPER_ROBOT, BATCH_START, BATCH_GOAL, BATCH_START_RATE,
                                BATCH_GOAL_RATE, 2.0, basis=basis)
    t = np.linspace(0.0, 2.0, 101)
    together = batch.sample(t)
    assert together.theta.shape == (4, 101, 3)
    for i in range(4):
        alone = plan_point_to_point(PAPER_ROBOT, BATCH_START[i], BATCH_GOAL[i],
                                    BATCH_START_RATE[i], BATCH_GOAL_RATE[i], 2.0, basis=basis)
        np.testing.assert_array_equal(batch.trajectory.coefficients[i],
                                      alone.trajectory.coefficients)
        samples = alone.sample(t)
        for field in ("theta", "theta_dot", "u1_dot", "y", "margin", "momentum"):
            np.testing.assert_array_equal(getattr(together, field)[i], getattr(samples, field),
                                          err_msg=f"maneuver {i}: {field}")


@pytest.mark.parametrize("i", range(4))
def test_the_horner_path_of_evaluate_equals_sample(i: int) -> None:
    # evaluate() of one polynomial plan runs a compiled Horner loop; sample() goes through
    # the basis matrices and complex-step rates: two computations of the same quantities
    plan = plan_point_to_point(PAPER_ROBOT, BATCH_START[i], BATCH_GOAL[i],
                               BATCH_START_RATE[i], BATCH_GOAL_RATE[i], 2.0)
    assert isinstance(plan.trajectory.basis, PolynomialBasis)
    t = np.linspace(0.0, 2.0, 257)
    state, inputs = plan.evaluate(t)
    samples = plan.sample(t)
    np.testing.assert_allclose(state[:, :3], samples.theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(state[:, 3], samples.theta_dot[:, 1], rtol=0, atol=1e-12)  # u1
    np.testing.assert_allclose(inputs[:, 0], samples.u1_dot, rtol=0, atol=1e-12)
    np.testing.assert_allclose(inputs[:, 1], samples.theta_dot[:, 2], rtol=0, atol=1e-12)  # u2
