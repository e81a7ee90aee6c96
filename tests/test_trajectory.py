"""The trajectory object of the API (flatcli/trajectory.py): states, rates, inputs and flat
outputs of a plan at any time, checked against the plan's boundary conditions and against
finite differences of itself (an independent derivative)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import flatcli
from flatcli.trajectory import Trajectory

#: Central differences with step H [s] are accurate to about H^2 times the third derivative
#: (|th2'''| reaches ~1e4 rad/s^3 near t = 0 on the paper's cubic): compared well inside.
H = 1e-5
DIFF_TOL = 1e-4
#: Boundary values come out of the inverse flat map: rounding only.
END_TOL = 1e-9


@pytest.fixture(scope="module")
def paper() -> flatcli.PlanResult:
    return flatcli.plan()


def test_the_ends_are_the_specs_boundary_conditions(paper: flatcli.PlanResult) -> None:
    trajectory = paper.trajectory
    assert isinstance(trajectory, Trajectory) and trajectory.duration == 2.0
    start, goal = trajectory(0.0), trajectory(2.0)
    np.testing.assert_allclose(start.theta, [1.8, 1.0, 0.0], atol=END_TOL)  # Sec. VI
    np.testing.assert_allclose(goal.theta, [1.2, 2.0, 0.0], atol=END_TOL)
    assert start.theta_dot[1] == pytest.approx(0.1, abs=END_TOL)  # plan.start_rate
    assert goal.theta_dot[1] == pytest.approx(0.5, abs=END_TOL)  # plan.goal_rate
    assert start.y[0] == start.theta[1]  # y1 = th1
    assert abs(start.momentum) < 1e-12


def test_rates_and_inputs_are_the_derivatives_of_the_states(paper: flatcli.PlanResult) -> None:
    trajectory = paper.trajectory
    t = np.array([0.3, 0.9, 1.6])
    here, before, after = trajectory(t), trajectory(t - H), trajectory(t + H)
    np.testing.assert_allclose((after.theta - before.theta) / (2 * H), here.theta_dot,
                               atol=DIFF_TOL)
    np.testing.assert_allclose((after.theta_dot[:, 1] - before.theta_dot[:, 1]) / (2 * H),
                               here.u_dot[:, 0], atol=DIFF_TOL)
    np.testing.assert_allclose((after.y - before.y) / (2 * H), here.y_dot, atol=DIFF_TOL)
    np.testing.assert_array_equal(here.u, here.theta_dot[:, 2])  # u_N = th_N'


def test_shapes_follow_the_times_and_the_robot(paper: flatcli.PlanResult) -> None:
    many = paper.trajectory(np.linspace(0, 2, 7))
    assert many.theta.shape == (7, 3) and many.u_dot.shape == (7, 1) and many.y.shape == (7, 2)
    one = paper.trajectory(1.0)
    assert one.theta.shape == (3,) and one.margin.shape == () and float(one.t) == 1.0
    chain = flatcli.plan(overrides={"robot": "chain4"}).trajectory(np.array([0.0, 1.0]))
    assert chain.theta.shape == (2, 4) and chain.u_dot.shape == (2, 2) and chain.y.shape == (2, 3)


def test_it_is_plan_parquets_rows_at_its_times(paper: flatcli.PlanResult, tmp_path: Path) -> None:
    frame = paper.trajectory.frame(paper.frame["t"].to_numpy())
    assert list(frame.columns) == list(paper.frame.columns)
    np.testing.assert_array_equal(frame.to_numpy(), paper.frame.to_numpy())  # one process
    loaded = flatcli.load(paper.save(tmp_path / "p"))
    assert isinstance(loaded, flatcli.PlanResult) and loaded.plan is None
    np.testing.assert_allclose(loaded.trajectory(0.7).theta, paper.trajectory(0.7).theta,
                               rtol=1e-12)  # planned again from the record's spec


@pytest.mark.parametrize("t", [-0.1, 2.5, float("nan"), []])
def test_a_time_outside_the_maneuver_is_refused(paper: flatcli.PlanResult, t: object) -> None:
    with pytest.raises(flatcli.FlatcliError, match="trajectory: "):
        paper.trajectory(t)  # type: ignore[arg-type]
