"""Tests of flatcli.core.controllers.flat: the flat law of an N-link chain in closed loop with
the kinematic plant (flatcli.core.plants.kinematic, composed by flatcli.core.loop.base).

References: for N = 2 the paper's closed-loop kernel (``simulate`` with ``plant``, itself
checked against scipy's DOP853 and the closed-form error dynamics); for N >= 3, scipy's
DOP853 at rtol 1e-11 integrating the same right-hand side, the closed-form solution of the
linear error dynamics e'' + kv e' + kp e = 0 (an exact model gives them), and the angular
momentum from the full kinematics.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core.controllers.control import Gains
from flatcli.core.controllers.flat import chain_shared
from flatcli.core.loop.integrate import plan_flag
from flatcli.core.loop.kernels import Ops, TrialArrays, chain_plant
from flatcli.core.loop.metrics import Metric, Status
from flatcli.core.loop.simulate import NoiseStreams, Scenario, Trials, simulate
from flatcli.core.plan.planning import Plan, plan_chain, plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams

Array = NDArray[np.float64]


def example(n: int) -> tuple[RobotParams, Array, Array]:
    """A chain of n joints (see tests/test_chainplan.py) and its maneuver's ends."""
    robot = RobotParams(mass=[2.0] + [1.0] * (n - 1) + [0.6],
                        inertia=[0.08] + [0.03] * (n - 1) + [0.2],
                        length=[0.3] + [0.25] * n, com=[0.12] + [0.1] * (n - 1) + [0.0])
    start = np.r_[0.0, 1.0, np.full(n - 1, 0.3)]
    goal = np.r_[0.4, 2.0, np.full(n - 1, 0.6)]
    start[-1] = goal[-1] = 0.0
    return robot, start, goal


def scenario(n: int, kp: float = 100.0, kv: float = 20.0) -> tuple[Scenario, RobotParams, Array]:
    robot, start, goal = example(n)
    plan = plan_chain(robot, start, goal, np.full(n - 1, 0.3), np.full(n - 1, 0.5), 2.0)
    return Scenario(plan, Gains((kp,) * n, (kv,) * n), 1e-3), robot, start


def test_two_links_are_the_papers_closed_loop() -> None:
    paper = plan_point_to_point(PAPER_ROBOT, [1.8, 1, 0], [1.2, 2, 0], 0.1, 0.5, 2.0)
    chain = plan_chain(PAPER_ROBOT, [1.8, 1, 0], [1.2, 2, 0], [0.1], [0.5], 2.0)
    trials = Trials(PAPER_ROBOT.with_(com=(0.1, 0.1, 0.004)).as_array()[None], np.array([1e-3]),
                    np.array([[1.96, 0.8, -0.1, 0.1]]), NoiseStreams(1e-3, 3, np.array([5])))
    for kp, kv in (((10.0, 13.0), (100.0, 110.0)), ((100.0, 110.0), (10.0, 13.0))):
        for integrator in ("adaptive", "rk4"):
            a = simulate(Scenario(paper, Gains(kp, kv), 1e-3), trials, integrator, True)
            b = simulate(Scenario(chain, Gains(kp, kv), 1e-3), trials, integrator, True)
            assert a.trace is not None and b.trace is not None
            np.testing.assert_allclose(b.trace[0], a.trace[0], atol=1e-9)
            assert a.status[0] == b.status[0]


@pytest.mark.parametrize("n", [3, 4, 6])
def test_the_closed_loop_converges_from_perturbed_starts(n: int) -> None:
    sc, robot, start = scenario(n)
    rng = np.random.default_rng(n)
    count = 8
    initial = np.hstack([start + rng.normal(0.0, 0.03, (count, n + 1)),
                         0.3 + rng.normal(0.0, 0.01, (count, n - 1))])
    links = np.tile(robot.as_array(), (count, 1))
    out = simulate(sc, Trials(links, np.zeros(count), initial), "adaptive")
    assert np.all(out.status == Status.OK)
    assert np.all(out.metrics[:, Metric.ERR_Y_FINAL] < 1e-5)
    assert np.all(out.metrics[:, Metric.ERR_THETA_FINAL] < 1e-4)
    assert np.all(out.metrics[:, Metric.MOMENTUM_DRIFT] < 1e-11)


def chain_loop(plant_name: str, plan: Plan, plant: RobotParams, servo_is_plant: bool = True,
               h0: float = 0.0, rate_limit: float = np.inf, bandwidth: float = 100.0,
               torque_limit: float = np.inf, kp: float = 100.0, kv: float = 20.0
               ) -> tuple[Ops, object]:
    """The flat law's loop on a chain plant ("kinematic", "dynamic"), one trial's record as
    the kernels make it (``loop.base``), and its ``Ops`` (whose functions run as Python)."""
    from flatcli.core.loop.table import BASE

    ops = BASE[("flat", "chain", plant_name)][0]
    n = plan.n_joints
    params = plant.as_array()
    shared = chain_shared(plan.model, Gains((kp,) * n, (kv,) * n), rate_limit, servo_is_plant,
                          plant)
    trials = TrialArrays(params[None], np.array([h0]), np.array([[bandwidth, torque_limit]]),
                         np.zeros((1, 2 * n)), chain_plant(params[None], plant_name),
                         np.zeros(1))
    return ops, ops.make_loop(shared, trials, 0, ops.scratch(n))


@pytest.mark.parametrize("n", [3, 5])
def test_the_compiled_integrators_agree_with_dop853(n: int) -> None:
    sc, robot, start = scenario(n)
    x0 = np.r_[start + 0.02, np.full(n - 1, 0.3)]
    trials = Trials(robot.as_array()[None], np.zeros(1), x0[None])
    plan = sc.plan
    nb = n + 1
    ops, loop = chain_loop("kinematic", plan, robot)
    breaks, local = sc.pieces
    zero = np.zeros(nb)

    def rhs(t: float, x: Array) -> Array:
        ref = np.empty(3 * n)
        plan_flag(breaks, local, t, ref)
        out = np.empty(2 * n + 1)
        ops.rhs(loop, x, ref, zero, out)
        return out[: 2 * n]

    reference = solve_ivp(rhs, (0.0, 2.0), x0, method="DOP853", t_eval=sc.times, rtol=1e-11,
                          atol=1e-13).y.T
    # relative to the largest angle (the counterweighted link turns tens of rad here)
    scale = max(1.0, float(np.max(np.abs(reference[:, : n + 1]))))
    for integrator, bound in (("adaptive", 1e-7), ("rk4", 1e-6)):
        out = simulate(sc, trials, integrator, record=True)
        assert out.trace is not None
        assert np.max(np.abs(out.trace[0, :, : n + 1] - reference[:, : n + 1])) < bound * scale


def test_an_exact_model_gives_the_linear_error_dynamics() -> None:
    """e = y_d - y obeys e'' + kv e' + kp e = 0 (distinct real roots here): each flat
    output's error against the closed form."""
    n, kp, kv = 3, 100.0, 25.0
    sc, robot, start = scenario(n, kp, kv)
    x0 = np.r_[start + np.array([0.0, 0.01, -0.02, 0.0]), np.full(n - 1, 0.3)]
    out = simulate(sc, Trials(robot.as_array()[None], np.zeros(1), x0[None]), "adaptive",
                   record=True)
    assert out.trace is not None
    from flatcli.core.models.chainflat import outputs

    t = sc.times
    y = np.empty((t.size, n))
    y_dot = np.empty((t.size, n))
    plan = sc.plan
    for j in range(t.size):
        outputs(plan.model.K, plan.model.inertia, out.trace[0, j, : n + 1],
                out.trace[0, j, n + 1: 2 * n], y[j], y_dot[j])
    ref = plan.trajectory.derivative(t, 0)
    ref_dot = plan.trajectory.derivative(t, 1)
    e, e_dot = ref - y, ref_dot - y_dot
    r1, r2 = np.roots([1.0, kv, kp])
    for i in range(n):
        a = (e_dot[0, i] - r2 * e[0, i]) / (r1 - r2)
        b = e[0, i] - a
        expected = a * np.exp(r1 * t) + b * np.exp(r2 * t)
        np.testing.assert_allclose(e[:, i], expected, atol=2e-6)
