"""Tests of flatcli.core.models.flatness: the flat maps, their inverses, and the singular set.

Away from the singular set (margin |sin y1 * y1'| above ``MARGIN``) every map must be
inverted by its partner; the accelerations are also checked against an independent
differentiation of the forward map along the constrained flow.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from flatcli.core.models.flatness import (
    flag_state,
    flat_accelerations,
    flat_inputs,
    flat_outputs,
    flat_state,
    signed_margin,
    singularity_margin,
)
from flatcli.core.names import MODELS, Model
from flatcli.core.robots.params import PAPER_ROBOT, Coefficients, base_rate, constraint_coefficients

#: Distance from the singular set the property tests keep [rad/s].
MARGIN = 0.05
#: Round trips, relative to 1 + the largest magnitude involved: the inverse map divides by
#: h y1' >= ~1e-3 here, so rounding is amplified by up to ~1e3 (observed <= 3e-13).
ROUND_TRIP_RTOL = 1e-10
#: Complex-step derivative along the flow vs the closed-form accelerations (rounding only).
FLOW_RTOL = 1e-10
#: Complex-step size (no subtraction, so no cancellation).
STEP = 1e-30

ANGLE = st.floats(-np.pi, np.pi)
RATE = st.floats(-10.0, 10.0)
ACCEL = st.floats(-100.0, 100.0)


def coefficients(model: Model) -> Coefficients:
    return constraint_coefficients(PAPER_ROBOT.links, model)


def close(got: tuple, expected: tuple, rtol: float) -> bool:
    got_a, exp_a = np.asarray(got, dtype=float), np.asarray(expected, dtype=float)
    scale = 1.0 + np.max(np.abs(exp_a))
    return bool(np.all(np.abs(got_a - exp_a) <= rtol * scale))


@pytest.mark.parametrize("model", MODELS)
@settings(deadline=None, max_examples=150)
@given(th0=st.floats(-10.0, 10.0), th1=ANGLE, th2=ANGLE, u1=RATE)
def test_inverse_after_forward_is_identity(
    model: Model, th0: float, th1: float, th2: float, u1: float
) -> None:
    assume(abs(np.sin(th1) * u1) > MARGIN)
    k = coefficients(model)
    state = flat_state(k, *flat_outputs(k, th0, th1, th2, u1))
    assert close(state, (th0, th1, th2, u1), ROUND_TRIP_RTOL)


@pytest.mark.parametrize("model", MODELS)
@settings(deadline=None, max_examples=150)
@given(y1=ANGLE, y2=st.floats(-10.0, 10.0), y1_dot=RATE, y2_dot=RATE)
def test_forward_after_inverse_is_identity(
    model: Model, y1: float, y2: float, y1_dot: float, y2_dot: float
) -> None:
    assume(abs(np.sin(y1) * y1_dot) > MARGIN)
    k = coefficients(model)
    state = flat_state(k, y1, y2, y1_dot, y2_dot)
    # th2 may be large here (up to ~1e4 rad for y2' far from g y1'); scale with it
    scale = 1.0 + max(abs(v) for v in state)
    got = np.array(flat_outputs(k, *state))
    assert np.all(np.abs(got - [y1, y2, y1_dot, y2_dot]) <= ROUND_TRIP_RTOL * scale)


@pytest.mark.parametrize("model", MODELS)
@settings(deadline=None, max_examples=150)
@given(th1=ANGLE, th2=ANGLE, u1=RATE, y1_ddot=ACCEL, y2_ddot=ACCEL)
def test_inputs_realise_the_accelerations(
    model: Model, th1: float, th2: float, u1: float, y1_ddot: float, y2_ddot: float
) -> None:
    """flat_accelerations(flat_inputs(y'')) = y''."""
    assume(abs(np.sin(th1) * u1) > MARGIN)
    k = coefficients(model)
    u1_dot, u2 = flat_inputs(k, th1, th2, u1, y1_ddot, y2_ddot)
    got = flat_accelerations(k, th1, th2, u1, u1_dot, u2)
    scale = 1.0 + abs(u2)  # y2'' is a difference of terms of size ~|u2|
    assert np.all(np.abs(np.subtract(got, (y1_ddot, y2_ddot))) <= ROUND_TRIP_RTOL * scale)


@pytest.mark.parametrize("model", MODELS)
@settings(deadline=None, max_examples=150)
@given(th1=ANGLE, th2=ANGLE, u1=RATE, u1_dot=ACCEL, u2=ACCEL)
def test_accelerations_are_inverted_by_inputs(
    model: Model, th1: float, th2: float, u1: float, u1_dot: float, u2: float
) -> None:
    """flat_inputs(flat_accelerations(u)) = u."""
    assume(abs(np.sin(th1) * u1) > MARGIN)
    k = coefficients(model)
    y1_ddot, y2_ddot = flat_accelerations(k, th1, th2, u1, u1_dot, u2)
    assert close(flat_inputs(k, th1, th2, u1, y1_ddot, y2_ddot), (u1_dot, u2), ROUND_TRIP_RTOL)


@pytest.mark.parametrize("model", MODELS)
@settings(deadline=None, max_examples=100)
@given(th0=ANGLE, th1=ANGLE, th2=ANGLE, u1=RATE, u1_dot=ACCEL, u2=ACCEL)
def test_rates_and_accelerations_are_derivatives_along_the_flow(
    model: Model, th0: float, th1: float, th2: float, u1: float, u1_dot: float, u2: float
) -> None:
    """d/dt of flat_outputs along th0' = base_rate, th1' = u1, th2' = u2 (H = 0), u1' = u1_dot.

    Independent of the closed forms: complex step of the forward map in the direction of the
    flow. Its (y1, y2) part must be flat_outputs' (y1', y2'), its (y1', y2') part must be
    flat_accelerations. This is how the model's own constraint defines y2'.
    """
    assume(abs(np.sin(th1) * u1) > MARGIN)
    k = coefficients(model)
    th0_dot = base_rate(k, PAPER_ROBOT.total_mass, 0.0, th1, th2, u1, u2)
    x = np.array([th0, th1, th2, u1], dtype=complex)
    x_dot = np.array([th0_dot, u1, u2, u1_dot])
    d = np.array(flat_outputs(k, *(x + 1j * STEP * x_dot))).imag / STEP
    y = flat_outputs(k, th0, th1, th2, u1)
    expected = (*y[2:], *flat_accelerations(k, th1, th2, u1, u1_dot, u2))
    scale = 1.0 + np.max(np.abs(x_dot))
    assert np.all(np.abs(d - expected) <= FLOW_RTOL * scale)


def test_maps_broadcast_over_a_batch_axis() -> None:
    rng = np.random.default_rng(11)
    k = coefficients("derived")
    th = rng.uniform(0.3, 2.8, (4, 3, 5))  # th1 in (0.3, 2.8): away from sin th1 = 0
    u1 = rng.uniform(0.5, 2.0, (3, 5))
    batch = np.array(flat_outputs(k, th[0], th[1], th[2], u1))
    assert batch.shape == (4, 3, 5)
    one = flat_outputs(k, th[0, 1, 2], th[1, 1, 2], th[2, 1, 2], u1[1, 2])
    np.testing.assert_allclose(batch[:, 1, 2], one, rtol=1e-15)
    np.testing.assert_allclose(np.array(flat_state(k, *batch)), [*th[:3], u1], rtol=1e-12)


def test_margin_and_its_sign() -> None:
    y1 = np.array([0.0, 1.0, np.pi / 2, -2.0])
    y1_dot = np.array([3.0, 0.0, -0.5, 0.25])
    margin = singularity_margin(y1, y1_dot)
    np.testing.assert_array_equal(margin, np.abs(np.sin(y1) * y1_dot))
    np.testing.assert_array_equal(signed_margin(y1, y1_dot), np.sin(y1) * y1_dot)
    np.testing.assert_array_equal(np.abs(signed_margin(y1, y1_dot)), margin)


@pytest.mark.parametrize("model", MODELS)
@settings(deadline=None, max_examples=150)
@given(y1=ANGLE, y2=st.floats(-10.0, 10.0), y1_dot=RATE, y2_dot=RATE, y1_ddot=ACCEL,
       y2_ddot=ACCEL)
def test_flag_state_is_the_inverse_map_and_its_time_derivative(
    model: Model, y1: float, y2: float, y1_dot: float, y2_dot: float, y1_ddot: float,
    y2_ddot: float,
) -> None:
    """flag_state = (flat_state, flat_inputs at it, th0'), and (th0, th2)' along the flag are
    (th0', u2): checked by a complex step of flat_state along (y', y'') (independent of the
    closed forms of u2 and th0')."""
    assume(abs(np.sin(y1) * y1_dot) > MARGIN)
    k = coefficients(model)
    th0, th1, th2, u1, u1_dot, u2, th0_dot = flag_state(k, y1, y2, y1_dot, y2_dot, y1_ddot,
                                                        y2_ddot)
    assert close((th0, th1, th2, u1), flat_state(k, y1, y2, y1_dot, y2_dot), 1e-15)
    assert close((u1_dot, u2), flat_inputs(k, th1, th2, u1, y1_ddot, y2_ddot), 1e-15)
    z = np.array([y1, y2, y1_dot, y2_dot], dtype=complex)
    z_dot = np.array([y1_dot, y2_dot, y1_ddot, y2_ddot])
    rates = np.array(flat_state(k, *(z + 1j * STEP * z_dot))).imag / STEP
    scale = 1.0 + max(abs(th2), abs(u2), abs(th0_dot))
    assert np.all(np.abs(rates - [th0_dot, u1, u2, u1_dot]) <= FLOW_RTOL * scale)


@pytest.mark.parametrize(("y1", "y1_dot"), [(0.0, 0.3), (np.pi, 0.3), (1.0, 0.0)])
def test_maps_do_not_return_finite_garbage_on_the_singular_set(y1: float, y1_dot: float) -> None:
    """On sin y1 * y1' = 0 the inverse map and the inputs are non-finite, never plausible."""
    k = coefficients("derived")
    with np.errstate(divide="ignore", invalid="ignore"):
        # there th2 = (g y1' - y2') / (h y1') divides by zero (y2' != g y1': no state fits)
        _, _, th2, _ = flat_state(k, np.array(y1), np.array(0.2), np.array(y1_dot), np.array(0.05))
        _, u2 = flat_inputs(k, np.array(y1), np.array(0.1), np.array(y1_dot), 0.0, 1.0)
    if y1 == np.pi:
        # sin(pi) = 1.2e-16, not 0: the map is finite but astronomically large
        assert abs(th2) > 1e12
        assert abs(u2) > 1e12
    else:
        assert not np.isfinite(th2)
        assert not np.isfinite(u2)
    assert singularity_margin(y1, y1_dot) < 1e-15
