"""flatcli's robots as python-control flat systems (flatcli/pycontrol.py).

Referees: python-control's own ``point_to_point`` (its polynomial basis and least-squares
solve, not flatcli's planner), the exact time derivative of flatcli's plan (the flag map's
rates, not the momentum constraint) for ``updfcn``, and the angular momentum from the full
link kinematics (``chain.chain_momentum``) along python-control's solution.
"""

from __future__ import annotations

import sys

import control
import control.flatsys as fs
import numpy as np
import pytest

import flatcli
from flatcli.core.errors import FlatcliError
from flatcli.core.robots.chain import chain_momentum
from flatcli.pycontrol import MISSING, end_inputs, end_states, reverse_map

#: python-control's solution against flatcli's plan (the issue's bar: 1e-9; the two agree to
#: about 5e-13 in the states and 5e-12 in the inputs, whose th2' peaks at 49 rad/s).
AGREE = 1e-9
#: updfcn against the plan's exact rates, and H from the full kinematics along the
#: solution [rad/s, kg m^2/s]: rounding.
RATE_TOL = 1e-9
MOMENTUM_TOL = 1e-12

SPECS = {"paper": {}, "printed": {"robot.model": "paper"}, "chain4": {"robot": "chain4"}}


@pytest.mark.parametrize("name", list(SPECS))
def test_point_to_point_reproduces_flatcli_plan(name: str) -> None:
    """The paper's maneuver (and chain4's): python-control imposes the full state and input
    at both ends (flatcli's cubic imposes y and y'; the inputs given are the plan's own, so
    the problems are the same) on quintics, which contain the cubic: the unique solution
    is flatcli's plan."""
    overrides = SPECS[name]
    system = flatcli.flatsystem(overrides=overrides)
    plan = flatcli.plan(overrides=overrides).plan
    assert plan is not None
    n = plan.n_joints
    assert (system.nstates, system.ninputs, system.noutputs) == (2 * n, n, n)
    x0, xf = end_states(plan)
    u0, uf = end_inputs(plan)
    T = plan.duration
    trajectory = fs.point_to_point(system, T, x0, u0, xf, uf, basis=fs.PolyFamily(6, T))
    t = np.linspace(0.0, T, 201)
    x, u = trajectory.eval(t)
    x_plan, u_plan = reverse_map(plan.model, plan.flags(t))
    assert np.max(np.abs(x.T - x_plan)) < AGREE
    assert np.max(np.abs(u.T - u_plan)) < AGREE
    # the ends are the maneuver's, in python-control's own output
    spec = flatcli.load_spec(overrides=overrides)
    assert np.allclose(x[: n + 1, 0], spec.plan.start, atol=1e-12)
    assert np.allclose(x[: n + 1, -1], spec.plan.goal, atol=1e-12)
    # a real robot's motion: zero angular momentum from the full link kinematics
    robot = plan.robot
    rates = np.array([system.updfcn(0.0, x[:, i], u[:, i], {}) for i in range(t.size)])
    theta_dot = np.concatenate([rates[:, :1], x[n + 1:].T, u[n - 1:].T], axis=1)
    H = chain_momentum(*(np.asarray(v, dtype=float) for v in (
        robot.mass, robot.inertia, robot.length, robot.com)), x[: n + 1].T, theta_dot)
    if name != "printed":  # the printed coefficients are not the robot's (the paper's typos)
        assert np.max(np.abs(H)) < MOMENTUM_TOL


@pytest.mark.parametrize("name", ["paper", "chain4"])
def test_updfcn_is_the_time_derivative_of_the_plans_state(name: str) -> None:
    system = flatcli.flatsystem(overrides=SPECS[name])
    plan = flatcli.plan(overrides=SPECS[name]).plan
    assert plan is not None
    n = plan.n_joints
    t = np.linspace(0.05, plan.duration - 0.05, 23)
    x, u = reverse_map(plan.model, plan.flags(t))
    _, q_dot, q_ddot = plan.model.motion(plan.trajectory, t)
    expected = np.concatenate([q_dot, q_ddot[:, 1:n]], axis=1)
    got = np.array([system.updfcn(0.0, x[i], u[i], {}) for i in range(t.size)])
    assert np.max(np.abs(got - expected)) < RATE_TOL
    # and the output is the flat outputs
    y = np.array([system.output(0.0, x[i], u[i]) for i in range(t.size)])
    assert np.max(np.abs(y - plan.trajectory.derivative(t, 0))) < 1e-12


def test_forward_and_reverse_are_inverse_off_the_singular_set() -> None:
    system = flatcli.flatsystem(overrides={"robot": "chain4"})
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = np.concatenate([rng.uniform(-2, 2, 4), rng.uniform(0.2, 1.0, 2)])
        u = rng.uniform(-1, 1, 3)
        back_x, back_u = system.reverse(system.forward(x, u))
        assert np.allclose(back_x, x, atol=1e-10) and np.allclose(back_u, u, atol=1e-9)


def test_rest_is_on_the_singular_set_so_rest_to_rest_cannot_be_expressed() -> None:
    system = flatcli.flatsystem()
    rest = system.forward(np.array([1.8, 1.0, 0.0, 0.0]), np.zeros(2))
    assert rest[0][1] == 0.0  # y1' = th1' = 0: the margin sin(y1) y1' is zero
    with np.errstate(all="ignore"):
        x, u = system.reverse(rest)
    assert not np.all(np.isfinite(x)) or not np.all(np.isfinite(u))


def test_a_design_without_closed_form_outputs_is_refused_with_the_reason() -> None:
    with pytest.raises(FlatcliError, match=r"flatsystem: the paper's flat outputs do not "
                                           r"apply: .*d2"):
        flatcli.flatsystem(overrides={"robot.com": [0.1, 0.1, 0.003]})
    with pytest.raises(FlatcliError, match=r"robot\.com_across is not 0"):
        flatcli.flatsystem(overrides={"robot.com_across": 0.001})


def test_without_python_control_the_error_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "control", None)
    monkeypatch.setitem(sys.modules, "control.flatsys", None)
    with pytest.raises(FlatcliError) as info:
        flatcli.flatsystem()
    assert str(info.value) == MISSING and "pip install 'flatcli[control]'" in MISSING


def test_python_control_simulates_the_planned_inputs_back_to_the_plan() -> None:
    """python-control's own simulation of the plan's inputs (held linear between 401
    samples) from the start state follows the plan: the error shrinks with the sample
    spacing squared (interpolation), 4x per halving."""
    system = flatcli.flatsystem()
    plan = flatcli.plan().plan
    assert plan is not None
    errors = []
    for count in (201, 401):
        t = np.linspace(0.0, plan.duration, count)
        x, u = reverse_map(plan.model, plan.flags(t))
        response = control.input_output_response(
            system, t, u.T, x[0], solve_ivp_method="DOP853",
            solve_ivp_kwargs={"rtol": 1e-8, "atol": 1e-10})
        errors.append(np.max(np.abs(response.states.T - x)))
    assert errors[1] < 3e-3 and 3.0 < errors[0] / errors[1] < 5.0, errors
