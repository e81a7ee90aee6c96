"""Tests of flatcli.core.controllers.control: the linearising feedback (Franch et al.
2003, eqs. 39-42).

With an exact model (plant = nominal, no noise, no rate limit) the closed loop must make
the flat-output errors e = y - y_ref obey e'' + kv e' + kp e = 0 exactly; the simulated
errors are compared with the closed-form solution of that ODE from the initial error.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from flatcli.core.controllers.control import Gains, PaperGains, feedback
from flatcli.core.loop.simulate import Scenario, Trials, simulate
from flatcli.core.models.flatness import flat_inputs, flat_outputs
from flatcli.core.names import MODELS, Integrator, Model
from flatcli.core.plan.planning import Plan
from flatcli.core.robots.params import PAPER_ROBOT, constraint_coefficients

Array = NDArray[np.float64]

#: The feedback vs flat_inputs of v: same formulas regrouped (rounding, amplified by 1/(h u1)).
FEEDBACK_RTOL = 1e-10
#: Simulated flat errors vs the closed form at dt = 1 ms. RK4's local error with the fast
#: pole near -100 of the printed gains (dt |lambda| = 0.1) gives ~1e-10 on e and ~1e-8 on e'
#: (observed 7e-11, 9e-9); DOP853 at rtol 1e-10 gives ~1e-11.
#: The adaptive default (rtol 5e-8) resolves the sampled trace to ~1e-7 rad (its dense
#: output), the errors' derivative to ~1e-6 rad/s.
ERROR_TOL = {"rk4": (1e-9, 1e-7), "dop853": (1e-9, 1e-8), "adaptive": (1e-6, 1e-5)}
#: With kv and kp swapped the poles of e'' + kv e' + kp e = 0 have real parts -5 and -6.5:
#: e(2) shrinks below e^-10 ~ 5e-5 of its start.
SWAPPED_FINAL_BOUND = 1e-4


def closed_form(e0: float, e0_dot: float, kp: float, kv: float, t: Array) -> tuple[Array, Array]:
    """e(t), e'(t) solving e'' + kv e' + kp e = 0 from e(0), e'(0) (distinct roots)."""
    r1, r2 = np.roots([1.0, kv, kp]).astype(complex)
    assert abs(r1 - r2) > 1e-6
    c1 = (e0_dot - r2 * e0) / (r1 - r2)
    c2 = e0 - c1
    e = c1 * np.exp(r1 * t) + c2 * np.exp(r2 * t)
    e_dot = c1 * r1 * np.exp(r1 * t) + c2 * r2 * np.exp(r2 * t)
    return e.real, e_dot.real


def initial_flat_error(plan: Plan, initial: Array) -> tuple[Array, Array]:
    """(2,) e(0) and e'(0) from the initial state and the plan at t = 0."""
    y = np.array(flat_outputs(plan.coefficients, *initial))
    t0 = np.array([0.0])
    return (
        y[:2] - plan.trajectory.derivative(t0, 0)[0],
        y[2:] - plan.trajectory.derivative(t0, 1)[0],
    )


def simulated_flat_error(plan: Plan, scenario: Scenario, trace: Array) -> tuple[Array, Array]:
    """(n + 1, 2) y - y_ref and y' - y_ref' from a recorded trace."""
    y = np.array(flat_outputs(plan.coefficients, *trace[:, :4].T)).T
    t = scenario.times
    return (
        y[:, :2] - plan.trajectory.derivative(t, 0),
        y[:, 2:] - plan.trajectory.derivative(t, 1),
    )


def gain_pairs(gains: Gains) -> tuple[tuple[float, float], tuple[float, float]]:
    return (gains.kp[0], gains.kv[0]), (gains.kp[1], gains.kv[1])


# --------------------------------------------------------------------------------------
# The feedback law itself
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS)
def test_feedback_on_the_reference_returns_the_planned_inputs(
    plan_factory: Callable[..., Plan], printed_gains: Gains, model: Model
) -> None:
    """Zero error: v = y_d'', so (u1', u2) are the plan's u1' and th2'."""
    plan = plan_factory(model)
    s = plan.sample(plan.grid(201))
    ref = np.array([*s.y.T, *s.y_dot.T, *s.y_ddot.T])  # y1, y2, y1', y2', y1'', y2''
    u1_dot, u2 = feedback(plan.coefficients, printed_gains.paper(), *s.theta.T, s.y_dot[:, 0],
                          ref)
    np.testing.assert_allclose(u1_dot, s.u1_dot, atol=1e-12)
    np.testing.assert_allclose(u2, s.u2, rtol=1e-10, atol=1e-10)


ANGLE = st.floats(-np.pi, np.pi)
RATE = st.floats(-5.0, 5.0)
GAIN = st.floats(0.0, 200.0)


@pytest.mark.parametrize("model", MODELS)
@settings(deadline=None, max_examples=100)
@given(
    state=st.tuples(ANGLE, ANGLE, ANGLE, RATE),
    ref=st.tuples(ANGLE, ANGLE, RATE, RATE, st.floats(-50, 50), st.floats(-50, 50)),
    gains=st.builds(PaperGains, GAIN, GAIN, GAIN, GAIN),
)
def test_feedback_is_flat_inputs_of_the_linear_law(
    model: Model,
    state: tuple[float, float, float, float],
    ref: tuple[float, ...],
    gains: Gains,
) -> None:
    """feedback = flat_inputs(v) with v_i = y_id'' + kv_i (y_id' - y_i') + kp_i (y_id - y_i)."""
    assume(abs(np.sin(state[1]) * state[3]) > 0.05)
    k = constraint_coefficients(PAPER_ROBOT.links, model)
    y1, y2, y1_dot, y2_dot = flat_outputs(k, *state)
    v1 = ref[4] + gains.kv1 * (ref[2] - y1_dot) + gains.kp1 * (ref[0] - y1)
    v2 = ref[5] + gains.kv2 * (ref[3] - y2_dot) + gains.kp2 * (ref[1] - y2)
    expected = np.array(flat_inputs(k, state[1], state[2], state[3], v1, v2))
    got = np.array(feedback(k, gains, *state, ref))
    scale = 1.0 + np.max(np.abs(expected)) + abs(v1) + abs(v2)
    assert np.all(np.abs(got - expected) <= FEEDBACK_RTOL * scale)


# --------------------------------------------------------------------------------------
# The closed loop with an exact model
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("integrator", ["adaptive", "rk4", "dop853"])
def test_flat_errors_follow_the_linear_error_dynamics(
    paper_plan: Plan,
    paper_gains: Gains,
    fig4_initial: Array,
    trials_factory: Callable[..., Trials],
    integrator: Integrator,
) -> None:
    """Plant = nominal (derived) model, no noise: e'' + kv e' + kp e = 0, both gain readings."""
    scenario = Scenario(paper_plan, paper_gains, 1e-3)
    outcome = simulate(scenario, trials_factory(fig4_initial), integrator, record=True)
    assert outcome.trace is not None
    e, e_dot = simulated_flat_error(paper_plan, scenario, outcome.trace[0])
    e0, e0_dot = initial_flat_error(paper_plan, fig4_initial)
    tol_e, tol_e_dot = ERROR_TOL[integrator]
    for i, (kp, kv) in enumerate(gain_pairs(paper_gains)):
        expected, expected_dot = closed_form(e0[i], e0_dot[i], kp, kv, scenario.times)
        assert np.max(np.abs(e[:, i] - expected)) <= tol_e, f"y{i + 1}"
        assert np.max(np.abs(e_dot[:, i] - expected_dot)) <= tol_e_dot, f"y{i + 1}'"


def test_printed_gains_barely_correct_and_swapped_gains_do(
    paper_plan: Plan, printed_gains: Gains, swapped_gains: Gains, fig4_initial: Array
) -> None:
    """The paper's Fig. 4 start, in closed form: with the gains as printed the slow pole
    (-kv/2 + sqrt(kv^2/4 - kp) ~ -0.1) leaves most of the flat-output error after 2 s (a
    factor ~e^-0.2 of the slow mode); with kv and kp swapped it is gone (< 1e-4 rad)."""
    e0, e0_dot = initial_flat_error(paper_plan, fig4_initial)
    t = np.array([2.0])
    printed = np.array([closed_form(e0[i], e0_dot[i], *p, t)[0][0] for i, p in
                        enumerate(gain_pairs(printed_gains))])  # fmt: skip
    swapped = np.array([closed_form(e0[i], e0_dot[i], *p, t)[0][0] for i, p in
                        enumerate(gain_pairs(swapped_gains))])  # fmt: skip
    assert np.all(np.abs(printed) > 0.5 * np.abs(e0))
    assert np.max(np.abs(swapped)) < SWAPPED_FINAL_BOUND


def test_model_error_breaks_the_linear_error_dynamics(
    paper_plan_as_printed: Plan,
    swapped_gains: Gains,
    fig4_initial: Array,
    trials_factory: Callable[..., Trials],
) -> None:
    """The same check with the printed coefficients in the controller (the plant keeps the true
    physics) fails: the exact-model test above has teeth. Observed deviation ~9e-4 in y2."""
    plan = paper_plan_as_printed
    scenario = Scenario(plan, swapped_gains, 1e-3)
    outcome = simulate(scenario, trials_factory(fig4_initial), record=True)
    assert outcome.trace is not None
    e, _ = simulated_flat_error(plan, scenario, outcome.trace[0])
    e0, e0_dot = initial_flat_error(plan, fig4_initial)
    kp, kv = gain_pairs(swapped_gains)[1]
    expected, _ = closed_form(e0[1], e0_dot[1], kp, kv, scenario.times)
    assert np.max(np.abs(e[:, 1] - expected)) > 1e-4
