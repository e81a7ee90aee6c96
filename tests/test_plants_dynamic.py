"""Tests of the flat law on the dynamic plant of an N-link chain in closed loop
(flatcli.core.plants.dynamic and flatcli.core.controllers.flat, composed by
flatcli.core.loop.base).

References, none of them the code under test:

* for N = 2, the paper's robot on its own compiled dynamic plant (``plants.paper.DYNAMIC``,
  the three-body sums written out; tests/test_plants_paper.py checks it against a sympy Lagrangian,
  the link kinematics and scipy's DOP853);
* the general-n dynamics as numpy batch functions (``dynamics.mass_matrix``,
  ``bias_forces``, ``forward_dynamics``, built with ``dynamics.make_chain``; checked against
  a sympy Lagrangian in tests/test_dynamics.py) for the servo law, the equations of motion
  and an independent right-hand side integrated by scipy's DOP853 at rtol 1e-12;
* the angular momentum from the full link kinematics (``chain.chain_momentum``) and the
  kinetic energy summed over the links' velocities (``link_kinetic_energy`` below);
* the closed form of a first-order lag, q' = r + (q'(0) - r) e^{-b t};
* the kinematic N-link closed loop (checked against DOP853 and the closed-form error
  dynamics in tests/test_controllers_flat.py) as the limit of infinite servo bandwidth.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.integrate import solve_ivp
from test_controllers_flat import chain_loop, example

from flatcli.core.controllers.control import Gains
from flatcli.core.loop.metrics import Metric, Status
from flatcli.core.loop.simulate import (
    DYNAMIC_TRACE_COLUMNS,
    NoiseStreams,
    Outcome,
    Scenario,
    Trials,
    chain_dynamic_trace_columns,
    noise_generator,
    simulate,
)
from flatcli.core.loop.table import BASE
from flatcli.core.models.chainflat import inputs, outputs
from flatcli.core.plan.planning import Plan, plan_chain, plan_point_to_point
from flatcli.core.robots.chain import chain_momentum
from flatcli.core.robots.dynamics import (
    Chain,
    bias_forces,
    forward_dynamics,
    kinetic_energy,
    make_chain,
    mass_matrix,
)
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams

Array = NDArray[np.float64]

#: The flat law on the dynamic chain plant (``loop.base``): its right-hand side and stage.
DYNAMIC = BASE[("flat", "chain", "dynamic")][0]
STAGE = DYNAMIC.stage

#: Tight tolerances for the checks of invariants: far below what they check.
TIGHT = {"rtol": 1e-12, "atol": 1e-14}
#: Free motion: H and T constant to this (relative); observed 3e-13 to 3e-12.
CONSERVED = 1e-10
#: Rounding in the right-hand side (an (N + 1) x (N + 1) solve against numpy's).
RHS_EXACT = 1e-10
#: N = 2 against the three-body plant, default tolerances: the same equations summed in
#: another order, so the adaptive steps may differ by rounding. Observed at most 4e-9 rad
#: in the angles, and 1.6e-7 of a column's largest value in the rates, torques and command
#: (and in the metrics), where a clipped servo kinks the right-hand side.
AGREE_ANGLES = 1e-7
AGREE_COLUMNS = 1e-6
#: The compiled plant against DOP853 at rtol 1e-12 on the numpy right-hand side, N = 4 with
#: both limits clipping: at the default tolerances observed 7e-6 rad (in th_4, which turns
#: 20 rad at up to 30 rad/s) and 1e-4 rad/s; at rtol 1e-10 (TIGHTER) 3e-10 to 2e-8 rad:
#: the gap is the compiled integrator's own error, largest where a clipped rate or torque
#: kinks the right-hand side, and there it depends on where the steps fall (two builds
#: whose terms round differently in the last bit moved it from 3e-10 to 2e-8 rad).
AGREE_WITH_DOP853 = 2e-5
TIGHTER = {"rtol": 1e-10, "atol": 1e-13}
AGREE_TIGHTER = 1e-7
#: The paper's start and u1(0) = its th1'(0) = 0.1 (paper, Sec. VI), and Fig. 4's start.
ON_PLAN = (1.8, 1.0, 0.0, 0.1)
FIG4 = (1.96, 0.8, -0.1, 0.1)


def chain_plan(n: int) -> tuple[Plan, RobotParams, Array]:
    """The maneuver of tests/test_controllers_flat.py for n joints: plan, robot, start."""
    robot, start, goal = example(n)
    return plan_chain(robot, start, goal, np.full(n - 1, 0.3), np.full(n - 1, 0.5), 2.0), \
        robot, start


def gains(n: int, kp: float = 100.0, kv: float = 20.0) -> Gains:
    return Gains((kp,) * n, (kv,) * n)


def dynamic_trials(initial: Array, plant: RobotParams, h0: float = 0.0,
                   servo: tuple[float, float] = (100.0, np.inf),
                   noise: NoiseStreams | None = None) -> Trials:
    x = np.atleast_2d(np.asarray(initial, dtype=float))
    count = len(x)
    return Trials(np.tile(plant.as_array(), (count, 1)), np.full(count, h0), x, noise,
                  np.tile(servo, (count, 1)))


def run(scenario: Scenario, trials: Trials, integrator: str = "adaptive") -> Outcome:
    return simulate(scenario, trials, integrator, record=True)  # type: ignore[arg-type]


def split(outcome: Outcome, n: int, i: int = 0) -> dict[str, Array]:
    """A trial's trace by part: q, q' (.., N + 1), u (.., N - 1), tau (.., N), u_N."""
    assert outcome.trace is not None
    assert outcome.columns == chain_dynamic_trace_columns(n)
    tr = outcome.trace[i]
    nb = n + 1
    nx = 3 * n + 1
    return {"q": tr[:, :nb], "qd": tr[:, nb:2 * nb], "u": tr[:, 2 * nb:nx],
            "tau": tr[:, nx:nx + n], "u_last": tr[:, nx + n]}


def robot_chain(robot: RobotParams) -> Chain:
    return make_chain(robot.mass, robot.inertia, robot.length, robot.com)


def joint_space_np(M: Array, c: Array) -> tuple[Array, Array]:
    """Mhat (.., N, N) and chat (.., N): the base row eliminated, in numpy."""
    hat = M[..., 1:, 1:] - M[..., 1:, :1] * M[..., :1, 1:] / M[..., :1, :1]
    chat = c[..., 1:] - M[..., 1:, 0] * (c[..., 0] / M[..., 0, 0])[..., None]
    return hat, chat


def link_kinetic_energy(robot: RobotParams, q: Array, qd: Array) -> Array:
    """T = 1/2 sum_i (m_i |v_i - v_c|^2 + I_i psi_i'^2) from each link's centre-of-mass
    velocity, v_i = sum_{a<i} l_a e'(psi_a) + d_i e'(psi_i) (the chain's link kinematics,
    written anew here), q, qd (.., N + 1)."""
    mass, inertia, length, com = (np.asarray(v, dtype=float) for v in
                                  (robot.mass, robot.inertia, robot.length, robot.com))
    psi = np.cumsum(q, axis=-1)
    w = np.cumsum(qd, axis=-1)
    e_dot = np.stack([-np.sin(psi), np.cos(psi)], -1) * w[..., None]  # (.., N + 1, 2)
    v = np.zeros(e_dot.shape)
    for i in range(len(mass)):
        v[..., i, :] = (np.einsum("a,...ak->...k", length[:i], e_dot[..., :i, :])
                        + com[i] * e_dot[..., i, :])
    vc = np.einsum("i,...ik->...k", mass, v) / mass.sum()
    T = 0.5 * np.einsum("i,...i->...", mass, np.sum((v - vc[..., None, :]) ** 2, axis=-1))
    return np.asarray(T + 0.5 * np.einsum("i,...i->...", inertia, w ** 2))


def full_momentum(robot: RobotParams, q: Array, qd: Array) -> Array:
    return chain_momentum(*(np.asarray(v, dtype=float) for v in
                            (robot.mass, robot.inertia, robot.length, robot.com)), q, qd)


# --------------------------------------------------------------------------------------
# The scenario and its trace
# --------------------------------------------------------------------------------------


def test_the_dynamic_plant_runs_any_number_of_joints() -> None:
    """Scenario accepts plant = "dynamic" for a Plan; the trace has the N-link columns
    (the three-body plant's for N = 2) and torques, and the kinematic metrics of torque stay
    null while the dynamic ones are filled."""
    assert chain_dynamic_trace_columns(2) == DYNAMIC_TRACE_COLUMNS
    assert chain_dynamic_trace_columns(3) == (
        "theta0", "theta1", "theta2", "theta3", "theta0_dot", "theta1_dot", "theta2_dot",
        "theta3_dot", "u1", "u2", "tau1", "tau2", "tau3", "u3")
    plan, robot, start = chain_plan(3)
    initial = np.r_[start, 0.3, 0.3]
    out = run(Scenario(plan, gains(3), 1e-3, plant="dynamic"), dynamic_trials(initial, robot))
    assert out.status[0] == Status.OK
    assert out.trace is not None and out.trace.shape == (1, 2001, 14)
    assert out.metrics[0, Metric.PEAK_TORQUE] > 0
    assert out.metrics[0, Metric.TORQUE_SATURATED] == 0
    kinematic = run(Scenario(plan, gains(3), 1e-3), dynamic_trials(initial, robot))
    assert np.isnan(kinematic.metrics[0, Metric.PEAK_TORQUE])
    assert np.isnan(kinematic.metrics[0, Metric.TORQUE_SATURATED])


# --------------------------------------------------------------------------------------
# N = 2: the paper's robot on its own plant
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("noise", [0.0, 1e-4])
@pytest.mark.parametrize("servo_model", ["robot", "plant"])
def test_two_joints_agree_with_the_three_body_plant(servo_model: str, noise: float) -> None:
    """The paper's maneuver as a Plan on this plant and as a Plan on the three-body
    plant: the same trials (an imperfect counterweight d2 = 4 mm, H0 = 1e-3, printed gains;
    no torque limit, and a 30 N m limit that clips the servo where th2' is turned round on
    the plan's start: from Fig. 4's start the clipped robot crosses the singular set and
    tumbles to T, far from the plan and too sensitive to verify) give the same statuses,
    traces (up to the first crossing), torques and metrics (of the verified trials)."""
    paper = plan_point_to_point(PAPER_ROBOT, [1.8, 1, 0], [1.2, 2, 0], 0.1, 0.5, 2.0)
    chain = plan_chain(PAPER_ROBOT, [1.8, 1, 0], [1.2, 2, 0], [0.1], [0.5], 2.0)
    plant = PAPER_ROBOT.with_(com=(0.1, 0.1, 0.004))
    initial = np.array([ON_PLAN, ON_PLAN, FIG4, FIG4])
    servo = np.array([[100.0, np.inf], [100.0, 30.0], [100.0, np.inf], [100.0, 30.0]])
    trials = Trials(np.tile(plant.as_array(), (4, 1)), np.full(4, 1e-3), initial,
                    NoiseStreams(noise, 3, np.arange(4)), servo)
    kp, kv = (10.0, 13.0), (100.0, 110.0)
    three = run(Scenario(paper, Gains(kp, kv), 1e-3, plant="dynamic",
                         servo_model=servo_model), trials)  # type: ignore[arg-type]
    ours = run(Scenario(chain, Gains(kp, kv), 1e-3, plant="dynamic",
                        servo_model=servo_model), trials)  # type: ignore[arg-type]
    assert three.trace is not None and ours.trace is not None
    assert ours.columns == three.columns
    np.testing.assert_array_equal(three.status, [Status.OK, Status.OK, Status.OK,
                                                 Status.SINGULAR])
    np.testing.assert_array_equal(ours.status, three.status)
    # free of limits the trials are verified; the tumbling one is not (err_estimate 0.02 to
    # 0.5 rad); the one the limit clips on the plan lies near track.accuracy (2.4e-8 to 2.2e-6)
    assert three.verified[[0, 2]].all() and ours.verified[[0, 2]].all()
    assert not three.verified[3] and not ours.verified[3]
    assert three.metrics[1, Metric.TORQUE_SATURATED] > 0  # the limit binds and is survived
    crossed = three.metrics[:, Metric.FIRST_CROSSING_TIME]
    assert np.isnan(crossed[:3]).all() and crossed[3] > 0
    np.testing.assert_allclose(ours.metrics[:, Metric.FIRST_CROSSING_TIME], crossed, atol=1e-9)
    for i in range(4):
        valid = np.isfinite(three.trace[i, :, 0])
        np.testing.assert_array_equal(np.isfinite(ours.trace[i, :, 0]), valid)
        if np.isfinite(crossed[i]):  # the same up to the crossing, which the clipping passes
            valid &= np.arange(valid.size) * 1e-3 < crossed[i]
        gap = np.abs(ours.trace[i, valid] - three.trace[i, valid]).max(axis=0)
        assert gap[:3].max() <= AGREE_ANGLES, gap
        assert np.all(gap <= AGREE_COLUMNS * np.abs(three.trace[i, valid]).max(axis=0)), gap
    sure = three.verified & ours.verified
    for name in ("ERR_THETA_RMS", "ERR_THETA_FINAL", "ERR_Y_MAX", "ERR_Y_FINAL",
                 "MIN_MARGIN", "PEAK_RATE", "PEAK_TORQUE"):
        np.testing.assert_allclose(ours.metrics[sure, Metric[name]],
                                   three.metrics[sure, Metric[name]], rtol=AGREE_COLUMNS)
    np.testing.assert_array_equal(ours.metrics[sure, Metric.TORQUE_SATURATED],
                                  three.metrics[sure, Metric.TORQUE_SATURATED])
    # the drift is the integration's own error (1e-10 to 4e-7 here): the same to 1e-5
    np.testing.assert_allclose(ours.metrics[sure, Metric.MOMENTUM_DRIFT],
                               three.metrics[sure, Metric.MOMENTUM_DRIFT], rtol=1e-5,
                               atol=1e-12)


# --------------------------------------------------------------------------------------
# The right-hand side: equations of motion, servo law, initial state
# --------------------------------------------------------------------------------------


def loop_for(plan: Plan, plant: RobotParams, servo_is_plant: bool, h0: float = 0.0,
             rate_limit: float = np.inf, bandwidth: float = 100.0,
             torque_limit: float = np.inf, kp: float = 100.0, kv: float = 20.0) -> object:
    return chain_loop("dynamic", plan, plant, servo_is_plant, h0, rate_limit, bandwidth,
                      torque_limit, kp, kv)[1]


@pytest.mark.parametrize("n", [3, 5])
def test_rhs_solves_the_equations_of_motion_and_the_servo_law(n: int) -> None:
    """At random states: M q'' + C q' = (0, tau) with M, C of the general chain (numpy batch
    functions), tau the computed torque of the servo's model (Mhat_s a + chat_s,
    a = bandwidth (r - qj')), r the controller's commands (u_j and its th_N', clipped), u'
    the controller's; with the servo's model exact each joint obeys qj'' = bandwidth
    (r_j - qj'), unless a torque limit clips tau (then the equations of motion still hold
    with the clipped torques)."""
    rng = np.random.default_rng(n)
    plan, robot, start = chain_plan(n)
    nb = n + 1
    com = np.array(robot.com)
    com[-1] = 0.004
    plant = robot.with_(mass=np.array(robot.mass) * rng.uniform(0.95, 1.05, nb), com=com)
    out = np.empty(DYNAMIC.state(n) + DYNAMIC.aux(n))
    ref = plan.flags(np.array([0.3]))[0]
    clipped = 0
    for servo_is_plant, torque_limit in ((True, np.inf), (False, np.inf), (True, 0.05)):
        for _ in range(10):
            x = np.r_[start + rng.uniform(-0.3, 0.3, nb), rng.uniform(-3, 3, nb),
                      rng.uniform(0.1, 0.6, n - 1)]
            bandwidth = float(rng.uniform(5, 500))
            loop = loop_for(plan, plant, servo_is_plant, rate_limit=4.0, bandwidth=bandwidth,
                            torque_limit=torque_limit)
            DYNAMIC.rhs(loop, x, ref, np.zeros(nb), out)  # type: ignore[arg-type]
            q, qd, qdd = x[:nb], x[nb:2 * nb], out[nb:2 * nb]
            nx = 3 * n + 1
            tau = out[nx + 1:nx + 1 + n]
            np.testing.assert_array_equal(out[:nb], qd)
            y, y_dot, v = np.empty(n), np.empty(n), np.empty(n)
            u = x[2 * nb:]
            sigma = outputs(plan.model.K, plan.model.inertia, q, u, y, y_dot)
            v[:] = ref[2 * n:] + 20.0 * (ref[n:2 * n] - y_dot) + 100.0 * (ref[:n] - y)
            u_dot = np.empty(n - 1)
            command = inputs(plan.model.K, plan.model.inertia, q, u, v, u_dot)
            assert out[nx] == sigma
            np.testing.assert_array_equal(out[2 * nb:nx], u_dot)
            r = np.clip(np.r_[u, command], -4.0, 4.0)
            assert out[nx + 1 + 2 * n] == r[-1]
            plant_chain = robot_chain(plant)
            Q = mass_matrix(plant_chain, q) @ qdd + bias_forces(plant_chain, q, qd)
            scale = np.abs(Q).max() + np.abs(tau).max()
            np.testing.assert_allclose(Q, np.r_[0.0, tau], rtol=0, atol=RHS_EXACT * scale)
            model = robot_chain(plant if servo_is_plant else robot)
            hat, chat = joint_space_np(mass_matrix(model, q), bias_forces(model, q, qd))
            a = bandwidth * (r - qd[1:])
            np.testing.assert_allclose(tau, np.clip(hat @ a + chat, -torque_limit, torque_limit),
                                       rtol=RHS_EXACT, atol=RHS_EXACT * scale)
            if np.isinf(torque_limit):
                assert out[nx + 1 + n] == 0.0  # no torque limit: never clipped
            clipped += int(out[nx + 1 + n] == 1.0)
            if servo_is_plant and out[nx + 1 + n] == 0.0:
                np.testing.assert_allclose(qdd[1:], a, rtol=RHS_EXACT,
                                           atol=RHS_EXACT * np.abs(a).max())
    assert clipped >= 5  # the clipped branch was exercised


@pytest.mark.parametrize("n", [3, 5])
def test_a_stage_derivative_is_the_right_hand_sides_bit_for_bit(n: int) -> None:
    """The loop's ``stage`` (what the integrators' stages call) against its full ``rhs``
    (checked above against the numpy chain) at random states, sensor
    noise and the three regimes: the state's derivative, sigma and r_N are the same bit for
    bit; the torques and the saturation flag too where they enter the derivative (a torque
    limit, or a servo that believes another robot), and nan, not stale numbers, where they
    do not (the exact servo without a limit, where each joint is a first-order lag)."""
    rng = np.random.default_rng(10 + n)
    plan, robot, start = chain_plan(n)
    nb = n + 1
    nx = 3 * n + 1
    com = np.array(robot.com)
    com[-1] = 0.004
    plant = robot.with_(mass=np.array(robot.mass) * rng.uniform(0.95, 1.05, nb), com=com)
    ref = plan.flags(np.array([0.7]))[0]
    full = np.empty(DYNAMIC.state(n) + DYNAMIC.aux(n))
    stage = np.empty_like(full)
    for servo_is_plant, torque_limit, exact in ((True, np.inf, True), (False, np.inf, False),
                                                (True, 0.05, False)):
        for trial in range(8):
            x = np.r_[start + rng.uniform(-0.3, 0.3, nb), rng.uniform(-3, 3, nb),
                      rng.uniform(0.1, 0.6, n - 1)]
            noise = rng.normal(0.0, 1e-3, nb) if trial % 2 else np.zeros(nb)
            args = (plan, plant, servo_is_plant)
            kw = {"rate_limit": 4.0, "bandwidth": float(rng.uniform(5, 500)),
                  "torque_limit": torque_limit}
            DYNAMIC.rhs(loop_for(*args, **kw), x, ref, noise, full)  # type: ignore[arg-type]
            stage[:] = 7.0  # what a stage row held before
            STAGE(loop_for(*args, **kw), x, ref, noise, stage)  # type: ignore[arg-type]
            np.testing.assert_array_equal(stage[:nx + 1], full[:nx + 1])
            assert stage[nx + 1 + 2 * n] == full[nx + 1 + 2 * n]
            if exact:
                assert np.isnan(stage[nx + 1:nx + 2 + n]).all()
            else:
                np.testing.assert_array_equal(stage[nx + 1:nx + 2 + n], full[nx + 1:nx + 2 + n])


def test_observed_torques_are_the_servos_where_every_sample_ends_a_step() -> None:
    """With sensor noise the adaptive integrator ends a step at every output sample and
    observes the right-hand side it evaluated there (its stages do not compute torques):
    with the exact servo and no torque limit, every recorded torque is the servo law
    recomputed from the recorded state with the numpy chain, and peak_torque is their
    largest, on both integrators."""
    n, bandwidth = 3, 100.0
    plan, robot, start = chain_plan(n)
    initial = np.r_[start + np.array([0.0, 0.02, -0.02, 0.01]), 0.3, 0.3]
    scenario = Scenario(plan, gains(n), 1e-3, plant="dynamic", servo_model="plant")
    trials = dynamic_trials(initial, robot, noise=NoiseStreams(1e-4, 3, np.array([0])))
    for integrator in ("adaptive", "rk4"):
        out = run(scenario, trials, integrator)
        assert out.status[0] == Status.OK
        tr = split(out, n)
        q, qd = tr["q"], tr["qd"]
        model = robot_chain(robot)
        hat, chat = joint_space_np(mass_matrix(model, q), bias_forces(model, q, qd))
        r = np.c_[tr["u"], tr["u_last"]]
        demand = np.einsum("njk,nk->nj", hat, bandwidth * (r - qd[:, 1:])) + chat
        assert np.isfinite(tr["tau"]).all()
        np.testing.assert_allclose(tr["tau"], demand, rtol=1e-9,
                                   atol=1e-9 * np.abs(demand).max())
        assert out.metrics[0, Metric.PEAK_TORQUE] == np.abs(tr["tau"]).max()
        assert out.metrics[0, Metric.TORQUE_SATURATED] == 0


def test_the_servo_is_a_first_order_lag() -> None:
    """The servo's model exact, no torque limit, commands held constant at the rate limit
    (u_j beyond it and pushed further out, so it does not integrate back in; the last
    joint's command beyond it as well): from joint rates away from the commands, each joint
    rate is r + (q'(0) - r) e^{-b t} (closed form), integrated by DOP853 at rtol 1e-12."""
    n, limit, bandwidth = 3, 1.0, 40.0
    plan, robot, start = chain_plan(n)
    nb = n + 1
    loop = loop_for(plan, robot, True, rate_limit=limit, bandwidth=bandwidth, kp=0.0, kv=0.0)
    noise = np.zeros(nb)
    out = np.empty(DYNAMIC.state(n) + DYNAMIC.aux(n))
    nx = 3 * n + 1

    def rhs(t: float, x: Array) -> Array:
        DYNAMIC.rhs(loop, x, plan.flags(np.array([t]))[0], noise, out)  # type: ignore[arg-type]
        return out[:nx].copy()

    x0 = np.r_[start, 0.4, -2.0, 0.5, 3.0, 5.0, 5.0]
    t = np.linspace(0.0, 0.15, 31)
    sol = solve_ivp(rhs, (0.0, 0.15), x0, method="DOP853", t_eval=t, rtol=1e-12, atol=1e-12)
    commands = []
    for x in sol.y.T:
        rhs(0.0, x)
        commands.append(out[nx + 1 + 2 * n])
    assert np.all(np.array(commands) == limit)  # the last joint's command, clipped throughout
    assert np.all(sol.y[2 * nb:] > limit)  # u_1, u_2 beyond the limit throughout
    r = np.array([limit, limit, limit])
    expected = r + (x0[nb + 1:2 * nb] - r) * np.exp(-bandwidth * t)[:, None]
    np.testing.assert_allclose(sol.y[nb + 1:2 * nb].T, expected, rtol=0, atol=1e-9)
    assert np.ptp(sol.y[nb]) > 0.1  # the base reacts


def test_initial_state_starts_the_servo_in_equilibrium_with_the_plants_momentum() -> None:
    """th_j'(0) = u_j(0) (j < N), th_N'(0) = the controller's command at t = 0 at the true
    angles, H(0) from the full link kinematics = H0 of the plant."""
    n = 4
    plan, robot, start = chain_plan(n)
    com = np.array(robot.com)
    com[-1] = 0.003
    plant = robot.with_(com=com)
    h0 = 0.02
    initial = np.r_[start + 0.05, 0.25, 0.3, 0.35]
    out = run(Scenario(plan, gains(n), 1e-3, plant="dynamic"),
              dynamic_trials(initial, plant, h0))
    tr = split(out, n)
    nb = n + 1
    y, y_dot, u_dot = np.empty(n), np.empty(n), np.empty(n - 1)
    ref = plan.flags(np.array([0.0]))[0]
    outputs(plan.model.K, plan.model.inertia, initial[:nb], initial[nb:], y, y_dot)
    v = ref[2 * n:] + 20.0 * (ref[n:2 * n] - y_dot) + 100.0 * (ref[:n] - y)
    command = inputs(plan.model.K, plan.model.inertia, initial[:nb], initial[nb:], v, u_dot)
    np.testing.assert_array_equal(tr["q"][0], initial[:nb])
    np.testing.assert_array_equal(tr["qd"][0, 1:n], initial[nb:])
    np.testing.assert_array_equal(tr["u"][0], initial[nb:])
    assert tr["qd"][0, n] == pytest.approx(command, rel=1e-12)
    assert tr["u_last"][0] == tr["qd"][0, n]
    # rounding relative to the largest term of H (th_N' of tens of rad/s: ~10 kg m^2/s)
    terms = np.abs(mass_matrix(robot_chain(plant), tr["q"][0])[0] * tr["qd"][0]).max()
    assert full_momentum(plant, tr["q"][0], tr["qd"][0]) == pytest.approx(h0, abs=1e-15 * terms)


# --------------------------------------------------------------------------------------
# Free motion, tracking, the kinematic limit, DOP853
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [3, 4, 5, 6])
def test_free_motion_conserves_momentum_and_kinetic_energy(n: int) -> None:
    """torque_limit = 0: no torque at all. From joints spread over 0.7 pi, joint rates 1
    rad/s and the last joint's command clipped to 3 rad/s (track.rate_limit; no feedback:
    gains 0, so the controller's margin stays positive and the trial runs its 2 s), an
    imperfect counterweight (d_N = 3 mm) tumbles with joint rates changing by several
    rad/s; H from the full link kinematics and T from the links' velocities (and
    ``dynamics.kinetic_energy``) stay constant to 1e-10 relative."""
    plan, robot, _ = chain_plan(n)
    com = np.array(robot.com)
    com[-1] = 0.003
    plant = robot.with_(com=com)
    h0 = 0.05
    scenario = Scenario(plan, gains(n, 0.0, 0.0), 1e-3, rate_limit=3.0, plant="dynamic",
                        **TIGHT)  # type: ignore[arg-type]
    initial = np.r_[0.0, np.full(n - 1, 0.7 * np.pi / (n - 1)), 0.0, np.full(n - 1, 1.0)]
    out = run(scenario, dynamic_trials(initial, plant, h0, servo=(100.0, 0.0)))
    assert out.status[0] == Status.OK
    tr = split(out, n)
    q, qd = tr["q"], tr["qd"]
    np.testing.assert_array_equal(tr["tau"], 0.0)
    assert np.ptp(qd[:, 1:], axis=0).max() > 4.0  # the joints do move, and unevenly
    T = link_kinetic_energy(plant, q, qd)
    np.testing.assert_allclose(kinetic_energy(robot_chain(plant), q, qd), T, rtol=1e-12)
    assert np.abs(T - T[0]).max() <= CONSERVED * T[0]
    H = full_momentum(plant, q, qd)
    terms = np.abs(mass_matrix(robot_chain(plant), q)[:, 0, :] * qd).max()
    assert np.abs(H - h0).max() <= CONSERVED * max(h0, terms)
    assert out.metrics[0, Metric.MOMENTUM_DRIFT] == pytest.approx(np.abs(H - h0).max(),
                                                                  abs=1e-15)


@pytest.mark.parametrize("n", [3, 4, 6])
def test_the_kinematic_chain_is_recovered_as_the_bandwidth_grows(n: int) -> None:
    """The servo's model exact, no torque limit, from perturbed starts: every trial tracks
    (the flat-output error at the end is a small fraction of its largest), and the gap to
    the kinematic closed loop (joints turning at the commanded rates) shrinks as
    1/bandwidth (log-log slope -1 within 10 %; observed 0.13-3.2 rad at 100 rad/s, where
    the loop asks for th_N' of tens of rad/s at once, to 0.012-0.27 at 1000)."""
    plan, robot, start = chain_plan(n)
    rng = np.random.default_rng(n)
    count = 3
    initial = np.hstack([start + rng.normal(0.0, 0.03, (count, n + 1)),
                         0.3 + rng.normal(0.0, 0.01, (count, n - 1))])
    kinematic = run(Scenario(plan, gains(n), 1e-3),
                    Trials(np.tile(robot.as_array(), (count, 1)), np.zeros(count), initial))
    assert kinematic.trace is not None
    bandwidths = np.array([100.0, 300.0, 1000.0])
    gaps = []
    for bandwidth in bandwidths:
        out = run(Scenario(plan, gains(n), 1e-3, plant="dynamic", servo_model="plant"),
                  dynamic_trials(initial, robot, servo=(bandwidth, np.inf)))
        assert np.all(out.status == Status.OK)
        m = out.metrics
        assert np.all(m[:, Metric.ERR_Y_FINAL] < m[:, Metric.ERR_Y_MAX] / 10)
        assert np.all(m[:, Metric.TORQUE_SATURATED] == 0)
        assert out.trace is not None
        gaps.append(np.abs(out.trace[:, :, :n + 1]
                           - kinematic.trace[:, :, :n + 1]).max(axis=(1, 2)))
    for trial in np.array(gaps).T:
        slope = np.polyfit(np.log(bandwidths), np.log(trial), 1)[0]
        assert -1.1 <= slope <= -0.9, (trial, slope)


def test_the_compiled_plant_agrees_with_dop853_on_a_numpy_right_hand_side() -> None:
    """N = 4, an imperfect plant (masses +-5 %, d_N = 3 mm, H0 = 0.01) under the nominal
    servo model, with a rate limit and a torque limit that both clip (the loop asks for
    th_N' = 54 rad/s and 340 N m without them), from a perturbed start: the compiled
    adaptive integrator at its default tolerances against scipy's DOP853 at rtol 1e-12 on
    the closed loop written here in numpy (the controller's flat maps, then the servo and
    the equations of motion from ``dynamics.mass_matrix``, ``bias_forces`` and
    ``forward_dynamics``), from the initial state built here too."""
    n = 4
    nb = n + 1
    plan, robot, start = chain_plan(n)
    com = np.array(robot.com)
    com[-1] = 0.003
    plant = robot.with_(mass=np.array(robot.mass) * [1.05, 0.95, 1.02, 0.98, 1.03], com=com)
    h0, bandwidth, limit, torque_limit = 0.01, 100.0, 30.0, 100.0
    plant_chain, servo_chain = robot_chain(plant), robot_chain(robot)
    K, inertia = plan.model.K, plan.model.inertia

    def commands(q: Array, u: Array, t: float) -> tuple[Array, Array, float]:
        ref = plan.flags(np.array([t]))[0]
        y, y_dot, u_dot = np.empty(n), np.empty(n), np.empty(n - 1)
        sigma = outputs(K, inertia, q, u, y, y_dot)
        v = ref[2 * n:] + 20.0 * (ref[n:2 * n] - y_dot) + 100.0 * (ref[:n] - y)
        command = inputs(K, inertia, q, u, v, u_dot)
        return np.clip(np.r_[u, command], -limit, limit), u_dot, sigma

    def rhs(t: float, x: Array) -> Array:
        q, qd, u = x[:nb], x[nb:2 * nb], x[2 * nb:]
        r, u_dot, _ = commands(q, u, t)
        hat, chat = joint_space_np(mass_matrix(servo_chain, q), bias_forces(servo_chain, q, qd))
        tau = np.clip(hat @ (bandwidth * (r - qd[1:])) + chat, -torque_limit, torque_limit)
        u_dot[((u >= limit) & (u_dot > 0)) | ((u <= -limit) & (u_dot < 0))] = 0.0
        return np.r_[qd, forward_dynamics(plant_chain, q, qd, tau), u_dot]

    initial = np.r_[start + np.array([0.02, -0.03, 0.02, 0.01, 0.0]), 0.3, 0.32, 0.28]
    r0, _, _ = commands(initial[:nb], initial[nb:], 0.0)
    M0 = mass_matrix(plant_chain, initial[:nb])
    x0 = np.r_[initial[:nb], (h0 - M0[0, 1:] @ r0) / M0[0, 0], r0, initial[nb:]]
    trials = dynamic_trials(initial, plant, h0, servo=(bandwidth, torque_limit))
    scenario = Scenario(plan, gains(n), 1e-3, plant="dynamic", rate_limit=limit)
    reference = solve_ivp(rhs, (0.0, 2.0), x0, method="DOP853", t_eval=scenario.times,
                          rtol=1e-12, atol=1e-12).y.T
    rate_scale = np.abs(reference[:, nb:2 * nb]).max()
    for tolerances, bound in (({}, AGREE_WITH_DOP853), (TIGHTER, AGREE_TIGHTER)):
        out = run(Scenario(plan, gains(n), 1e-3, plant="dynamic", rate_limit=limit,
                           **tolerances), trials)  # type: ignore[arg-type]
        assert out.status[0] == Status.OK
        assert out.metrics[0, Metric.TORQUE_SATURATED] > 0  # the limits bind
        tr = split(out, n)
        assert np.abs(tr["u_last"]).max() == limit
        np.testing.assert_allclose(np.r_[tr["q"][0], tr["qd"][0], tr["u"][0]], x0,
                                   rtol=1e-12, atol=1e-12)
        assert np.abs(tr["q"] - reference[:, :nb]).max() <= bound
        assert np.abs(tr["qd"] - reference[:, nb:2 * nb]).max() <= bound * rate_scale


# --------------------------------------------------------------------------------------
# Limits, metrics, batches
# --------------------------------------------------------------------------------------


def test_torques_follow_the_servo_law_and_the_metrics_are_what_their_names_say() -> None:
    """N = 3, an imperfect plant under the nominal servo model, commands clipped to 30 rad/s
    and a 100 N m torque limit, half of what the loop asks: at every sample the applied
    torques are the servo's demand recomputed from the trace with the general chain (numpy)
    clipped to the limit, the samples counted saturated are exactly those whose demand
    exceeds it, and peak_torque, peak_rate and momentum_drift (H from the full kinematics)
    are the trace's."""
    n, limit, bandwidth, h0 = 3, 100.0, 100.0, 0.01
    plan, robot, start = chain_plan(n)
    com = np.array(robot.com)
    com[-1] = 0.002
    plant = robot.with_(inertia=np.array(robot.inertia) * 1.03, com=com)
    initial = np.r_[start + np.array([0.0, 0.02, -0.02, 0.01]), 0.3, 0.3]
    scenario = Scenario(plan, gains(n), 1e-3, plant="dynamic", rate_limit=30.0)
    free = run(scenario, dynamic_trials(initial, plant, h0, servo=(bandwidth, np.inf)))
    assert free.metrics[0, Metric.PEAK_TORQUE] > 2 * limit
    out = run(scenario, dynamic_trials(initial, plant, h0, servo=(bandwidth, limit)))
    assert out.status[0] == Status.OK
    tr = split(out, n)
    q, qd = tr["q"], tr["qd"]
    hat, chat = joint_space_np(mass_matrix(robot_chain(robot), q),
                               bias_forces(robot_chain(robot), q, qd))
    r = np.c_[tr["u"], tr["u_last"]]
    demand = np.einsum("njk,nk->nj", hat, bandwidth * (r - qd[:, 1:])) + chat
    np.testing.assert_allclose(tr["tau"], np.clip(demand, -limit, limit), rtol=1e-9,
                               atol=1e-9)
    over = (np.abs(demand) > limit).any(axis=1)
    m = out.metrics[0]
    assert m[Metric.TORQUE_SATURATED] == over.sum() > 0
    assert m[Metric.PEAK_TORQUE] == np.abs(tr["tau"]).max() == limit
    assert m[Metric.PEAK_RATE] == np.abs(qd[:, 1:]).max()
    H = full_momentum(plant, q, qd)
    assert m[Metric.MOMENTUM_DRIFT] == pytest.approx(np.abs(H - h0).max(), abs=1e-15)
    assert 0 < m[Metric.MOMENTUM_DRIFT] < 1e-7


def test_a_rate_limit_clips_the_commands_and_holds_with_an_exact_servo() -> None:
    """With the servo's model exact, a first-order lag towards clipped commands never
    exceeds the limit; u_j does not wind up beyond it (conditional integration)."""
    n, limit = 4, 20.0
    plan, robot, start = chain_plan(n)
    initial = np.r_[start + 0.02, 0.3, 0.3, 0.3]
    free = run(Scenario(plan, gains(n), 1e-3, plant="dynamic"), dynamic_trials(initial, robot))
    assert np.abs(split(free, n)["u_last"]).max() > 2 * limit
    out = run(Scenario(plan, gains(n), 1e-3, plant="dynamic", servo_model="plant",
                       rate_limit=limit), dynamic_trials(initial, robot))
    assert out.status[0] in (Status.OK, Status.SINGULAR)
    tr = split(out, n)
    assert np.abs(tr["u_last"]).max() == limit
    assert np.abs(tr["qd"][:, 1:]).max() <= limit * (1 + 1e-9)
    assert np.abs(tr["u"]).max() <= limit


def test_batch_equals_one_at_a_time_bit_for_bit() -> None:
    """Trials with different plants, servos and noise streams, batched or alone."""
    n = 3
    plan, robot, start = chain_plan(n)
    rng = np.random.default_rng(5)
    count = 4
    links = robot.as_array() * (1 + rng.uniform(-0.02, 0.02, (count, 4 * (n + 1))))
    links[:, -1] = [0.0, 0.001, 0.0, 0.002]  # d_N
    initial = np.r_[start, 0.3, 0.3] + np.c_[rng.normal(0, 0.02, (count, n + 1)),
                                              np.zeros((count, n - 1))]
    servo = np.c_[[50.0, 100.0, 200.0, 400.0], [np.inf, 30.0, 300.0, np.inf]]
    trials = Trials(links, np.full(count, 1e-3), initial,
                    NoiseStreams(1e-4, 3, np.arange(count)), servo)
    scenario = Scenario(plan, gains(n), 1e-3, plant="dynamic")
    for integrator in ("adaptive", "rk4"):
        batch = run(scenario, trials, integrator)
        assert batch.trace is not None
        assert len(set(batch.metrics[:, Metric.PEAK_TORQUE])) == count  # all different
        for i in range(count):
            one = run(scenario, trials.subset(slice(i, i + 1)), integrator)
            assert one.trace is not None
            np.testing.assert_array_equal(one.metrics[0], batch.metrics[i])
            np.testing.assert_array_equal(one.trace[0], batch.trace[i])
            assert one.status[0] == batch.status[i]


@pytest.mark.parametrize("n", [3, 4, 5, 6])
def test_dop853_runs_every_chain_and_agrees_with_the_adaptive_integrator(n: int) -> None:
    """``track.integrator = "dop853"`` (scipy's solve_ivp, rtol 1e-10) on the N-link dynamic
    plant from a perturbed start: the same status, the angles within AGREE_WITH_DOP853 of
    the compiled adaptive integrator's at every output sample (its own error at the default
    tolerances), and real step and right-hand-side counts."""
    plan, robot, start = chain_plan(n)
    initial = np.r_[start + 0.01, np.full(n - 1, 0.3)]
    scenario = Scenario(plan, gains(n), 1e-3, plant="dynamic")
    trials = dynamic_trials(initial, robot)
    reference = run(scenario, trials, "dop853")
    compiled = run(scenario, trials)
    assert reference.status[0] == compiled.status[0] == Status.OK
    assert reference.trace is not None and compiled.trace is not None
    gap = np.abs(reference.trace[0, :, :n + 1] - compiled.trace[0, :, :n + 1]).max()
    assert gap <= AGREE_WITH_DOP853, gap
    steps = reference.metrics[0, Metric.STEPS]
    assert steps > 10 and reference.metrics[0, Metric.RHS_EVALUATIONS] > 12 * steps


def test_sensor_noise_covers_every_angle_of_a_chain() -> None:
    """The noise table of a robot of N joints holds one column per angle th0..thN (the
    kernels read N + 1): its variates are noise_generator's own standard normals, and noise
    on th_N alone (an explicit table) changes the closed loop, which a table too narrow for
    the kernels could not express. Run twice, a noisy trial is the same bit for bit."""
    n = 3
    plan, robot, start = chain_plan(n)
    links = robot.as_array()[None]
    initial = np.r_[start, 0.3, 0.3][None]
    streams = Trials(links, np.zeros(1), initial, NoiseStreams(1e-4, 7, np.array([11])))
    table = streams.noise_table(0, 5)
    expected = 1e-4 * noise_generator(7, 11).standard_normal((5, n + 1))  # the stream itself
    np.testing.assert_array_equal(table, expected)
    scenario = Scenario(plan, gains(n), 1e-3, plant="dynamic")
    first, again = run(scenario, streams), run(scenario, streams)
    np.testing.assert_array_equal(first.metrics, again.metrics)
    steps = scenario.n_steps
    quiet = np.zeros((1, steps, n + 1))
    last_only = quiet.copy()
    last_only[0, :, n] = 1e-3
    a = run(scenario, Trials(links, np.zeros(1), initial, quiet))
    b = run(scenario, Trials(links, np.zeros(1), initial, last_only))
    assert a.metrics[0, Metric.ERR_THETA_FINAL] != b.metrics[0, Metric.ERR_THETA_FINAL]
    with pytest.raises(ValueError, match="noise"):
        Trials(links, np.zeros(1), initial, np.zeros((1, steps, n)))
