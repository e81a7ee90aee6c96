"""Correctness of the bench baselines (no timing here: benchmarks are not tests)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks import baselines as b
from benchmarks.baselines import pcflatsys, shooting
from benchmarks.baselines.links import PAPER, disc_gaps, link_clearance, link_joints
from benchmarks.tasks import near_discs
from flatcli.core.controllers.control import Gains
from flatcli.core.loop.metrics import METRIC_NAMES
from flatcli.core.loop.simulate import Scenario, simulate
from flatcli.core.plan.planning import Plan
from flatcli.core.robots.params import Links, constraint_coefficients

#: python-control's quintic with flatcli's end accelerations is flatcli's cubic: the two
#: differ by the rounding of two least-squares solves and the flat maps.
SAME_PLAN_TOL = 1e-9
#: Two RK4 implementations of one closed loop, same steps, different rounding.
SAME_LOOP_TOL = 1e-9
#: Two implementations of one adaptive Dormand-Prince loop: the same steps, different rounding
#: (observed: 1e-13 relative, 5e-13 rad, on 2,000 perturbed trials); relative, and [rad].
SAME_DOPRI_TOL = 1e-10
#: RK45 at rtol 1e-8 against RK4 at dt = 1e-3 (both errors ~1e-8 on this loop).
IVP_TOL = 1e-6
#: Constraint residuals SLSQP is asked to reach.
SOLVER_TOL = 1e-8
#: |H| of a flat plan from the full kinematics: rounding only.
MOMENTUM_TOL = 1e-12
#: Two evaluations of one python-control trajectory (its own ``eval``, the bench's flags and
#: vectorised reverse map): rounding only [rad, m].
SAME_TRAJECTORY_TOL = 1e-9


@pytest.fixture(scope="module")
def cubic() -> Plan:
    return b.PAPER_MANEUVER.cubic()


def test_python_control_reproduces_flatcli_cubic() -> None:
    result = b.pc_point_to_point(samples=200)
    assert result.state.shape == (200, 4)
    assert result.max_theta_error < SAME_PLAN_TOL
    assert result.max_rate_error < SAME_PLAN_TOL
    # the ends are the maneuver's, in python-control's own output
    np.testing.assert_allclose(result.state[0], b.PAPER_MANEUVER.start_state, atol=1e-12)
    np.testing.assert_allclose(result.state[-1], b.PAPER_MANEUVER.goal_state, atol=1e-12)


def test_flat_system_round_trip(cubic: Plan) -> None:
    system = b.robot_flat_system(cubic.coefficients)
    x = np.array([1.7, 1.3, 0.4, 0.3])
    u = np.array([0.2, -1.5])
    x_back, u_back = system.reverse(system.forward(x, u))
    np.testing.assert_allclose(x_back, x, atol=1e-12)
    np.testing.assert_allclose(u_back, u, atol=1e-12)


def test_python_control_optimal_is_flat_and_within_limits() -> None:
    result = b.pc_optimal(basis_size=8, timepts=21, angle_limit=None, rate_limit=None)
    assert result.success, result.message
    assert result.quality.max_abs_momentum < MOMENTUM_TOL
    # python-control imposes the limits on its own grid only
    assert result.grid_violation <= 1e-6
    # the optimum is no worse than the paper's cubic (energy ~101)
    assert result.quality.energy < b.PAPER_MANEUVER.cubic().input_energy()


def test_plant_coefficients_match_flatcli() -> None:
    rng = np.random.default_rng(3)
    links = rng.uniform(0.05, 1.5, (20, 12))
    ours = b.plant_coefficients(links)
    theirs = np.stack(constraint_coefficients(Links(*links.T), "derived"), axis=-1)
    np.testing.assert_allclose(ours, theirs, rtol=1e-14, atol=1e-15)


# With the swapped gains a 2 % spread of the plant parameters makes about a quarter of the
# trials diverge (in flatcli and here alike); those cases keep the nominal parameters.
@pytest.mark.parametrize(
    ("gains", "rate_limit", "spread"),
    [
        (b.PRINTED_GAINS, math.inf, 0.02),
        (b.SWAPPED_GAINS, math.inf, 0.0),
        (b.SWAPPED_GAINS, 30.0, 0.0),
    ],
)
def test_compiled_kernel_matches_flatcli_simulate(
    cubic: Plan, gains: Gains, rate_limit: float, spread: float
) -> None:
    tracking = b.Tracking(gains=gains, rate_limit=rate_limit)
    trials = b.paper_trials(6, seed=1, tracking=tracking, spread=spread)
    scenario = Scenario(cubic, gains, tracking.dt, rate_limit=rate_limit)
    outcome = simulate(scenario, trials, "rk4", record=True)
    assert outcome.trace is not None
    expected = outcome.trace[:, -1, :4]
    assert np.all(np.isfinite(expected))
    got = b.compiled_closed_loop(cubic, trials, tracking, threads=2)
    np.testing.assert_allclose(got, expected, rtol=0, atol=SAME_LOOP_TOL)
    batch = b.numpy_batch_rk4(cubic, trials, tracking, chunk=4)
    np.testing.assert_allclose(batch, expected, rtol=0, atol=SAME_LOOP_TOL)


def test_compiled_kernel_independent_of_threads(cubic: Plan) -> None:
    trials = b.paper_trials(64, seed=2)
    one = b.compiled_closed_loop(cubic, trials, threads=1)
    two = b.compiled_closed_loop(cubic, trials, threads=2)
    np.testing.assert_array_equal(one, two)


@pytest.mark.parametrize(("gains", "spread"), [(b.PRINTED_GAINS, 0.02), (b.SWAPPED_GAINS, 0.0)])
def test_same_work_kernel_does_flatclis_work(cubic: Plan, gains: Gains, spread: float) -> None:
    """The same-work kernel (benchmarks/baselines/dopri.py) against flatcli with one solution
    per trial (error_estimate none): the very same steps and right-hand sides, the same
    metrics at the same samples."""
    tracking = b.Tracking(gains=gains)
    trials = b.paper_trials(12, seed=4, tracking=tracking, spread=spread)
    outcome = simulate(Scenario(cubic, gains, tracking.dt, twin=0.0), trials)
    assert (outcome.status == 0).all()  # resolved to the end, no singular hit: comparable
    got = b.dopri_metrics(cubic, trials, tracking, threads=2)
    column = {name: i for i, name in enumerate(METRIC_NAMES)}
    assert not got[:, b.DOPRI_METRICS.index("crossed")].any()
    for k, name in enumerate(b.DOPRI_METRICS):
        if name == "crossed":
            continue
        theirs = outcome.metrics[:, column[name]]
        if name in ("steps", "rhs_evaluations", "singular_hits"):
            np.testing.assert_array_equal(got[:, k], theirs, err_msg=name)
        elif name == "momentum_drift":  # rounding of H ~ 1e-15 in both
            assert got[:, k].max() < MOMENTUM_TOL and theirs.max() < MOMENTUM_TOL
        else:
            np.testing.assert_allclose(got[:, k], theirs, rtol=SAME_DOPRI_TOL,
                                       atol=SAME_DOPRI_TOL, err_msg=name)
    every = simulate(Scenario(cubic, gains, tracking.dt, twin=0.0, observe_every=7), trials)
    sparse = b.dopri_metrics(cubic, trials, tracking, threads=1, every=7)
    for name in ("err_theta_rms", "err_y_max", "peak_rate", "rhs_evaluations", "steps"):
        k = b.DOPRI_METRICS.index(name)
        np.testing.assert_allclose(sparse[:, k], every.metrics[:, column[name]],
                                   rtol=SAME_DOPRI_TOL, atol=SAME_DOPRI_TOL, err_msg=name)


def test_solve_ivp_agrees_with_rk4(cubic: Plan) -> None:
    trials = b.paper_trials(2, seed=4)
    run = b.solve_ivp_trials_per_second(cubic, trials)
    rk4 = b.compiled_closed_loop(cubic, trials)
    np.testing.assert_allclose(run.final, rk4, rtol=0, atol=IVP_TOL)
    assert run.trials_per_second > 0
    assert np.all(run.evaluations > 0)


def test_shooting_gradient_is_exact() -> None:
    model = shooting._Shooting(b.PAPER_MANEUVER, intervals=6, substeps=3)
    rates = np.random.default_rng(5).normal(size=(6, 2))
    # the same gradient by 2K complex steps of the whole integration
    step = 1e-30
    n = rates.size
    batch = np.broadcast_to(rates.astype(complex), (n, *rates.shape)).copy()
    batch.reshape(n, n)[np.arange(n), np.arange(n)] += 1j * step
    reference = np.asarray(model.final_base(batch).imag / step)
    np.testing.assert_allclose(model.final_base_gradient(rates), reference, atol=1e-14)


def test_shooting_reaches_goal() -> None:
    result = b.shooting_plan(intervals=10, substeps=2)
    assert result.success, result.message
    assert result.terminal_error < SOLVER_TOL
    assert result.max_abs_momentum < MOMENTUM_TOL
    np.testing.assert_allclose(result.theta[0], b.PAPER_MANEUVER.start, atol=0)
    # far below the paper's cubic (~101): the end rates are free here
    assert result.objective < 20.0


@pytest.mark.parametrize(("angle_limit", "rate_limit"), [(1.5, None), (None, 2.2)])
def test_shooting_respects_active_limits(
    angle_limit: float | None, rate_limit: float | None
) -> None:
    # unconstrained, max |th2| is ~1.9 rad and max |rate| ~2.5 rad/s: both limits bind
    free = b.shooting_plan(intervals=10, substeps=2)
    result = b.shooting_plan(
        intervals=10, substeps=2, angle_limit=angle_limit, rate_limit=rate_limit
    )
    assert result.success, result.message
    assert result.terminal_error < SOLVER_TOL
    assert result.violation <= SOLVER_TOL
    if angle_limit is not None:
        assert np.max(np.abs(free.theta[:, 2])) > angle_limit
        assert np.max(np.abs(result.theta[:, 2])) == pytest.approx(angle_limit, abs=1e-6)
    if rate_limit is not None:
        assert np.max(np.abs(free.rates)) > rate_limit
        assert np.max(np.abs(result.rates)) == pytest.approx(rate_limit, abs=1e-6)
    assert result.objective > free.objective


def test_timed_and_machine_info() -> None:
    timing = b.timed(lambda: sum(range(100)), repeat=3)
    assert 0 <= timing.best <= timing.median
    assert timing.repeat == 3
    info = b.machine_info()
    for key in ("cpu", "cores", "python", "numpy", "numba", "scipy", "control"):
        assert info[key]


def test_flat_system_dynamics_match_plan(cubic: Plan) -> None:
    system = b.robot_flat_system(cubic.coefficients)
    samples = cubic.sample(np.linspace(0.1, 1.9, 7))
    for j in range(samples.t.size):
        x = np.array([*samples.theta[j], samples.theta_dot[j, 1]])
        u = np.array([samples.u1_dot[j], samples.theta_dot[j, 2]])
        rates = system.dynamics(samples.t[j], x, u)
        expected = [*samples.theta_dot[j], samples.u1_dot[j]]
        np.testing.assert_allclose(rates, expected, rtol=1e-12, atol=1e-12)


def test_plan_quality_of_the_cubic(cubic: Plan) -> None:
    # the paper's cubic, derived model: th2 reaches 3.93 rad, th2'(0) = 48.8 rad/s
    # (tests/test_planning.py::test_derived_plan_matches_physics_note) and the input energy
    # is about 101 (tests/test_optimize_api.py, CUBIC_ENERGY = 101.19)
    quality = b.plan_quality(cubic, angle_limit=3.0)
    assert quality.energy == pytest.approx(cubic.input_energy(), rel=1e-9)
    assert quality.energy == pytest.approx(101.2, abs=0.1)
    assert quality.max_abs_theta[2] == pytest.approx(3.93, abs=0.01)
    assert quality.max_abs_rate[2] == pytest.approx(48.8, abs=0.1)
    assert quality.violation == pytest.approx(quality.max_abs_theta[2] - 3.0)
    assert quality.max_abs_momentum < MOMENTUM_TOL


def test_bench_link_kinematics_closed_form() -> None:
    # the paper's robot straight along x: link centres at 0.1, 0.3, 0.4 m from O_0, their
    # mean 4/15 m, so the joints O_0..O_3 at (-4, -1, 2, 5) / 15 m; turned by th0 = pi/2,
    # the same along y
    theta = np.array([[0.0, 0.0, 0.0], [math.pi / 2, 0.0, 0.0]])
    joints = link_joints(*PAPER, theta)
    straight = np.array([-4.0, -1.0, 2.0, 5.0]) / 15.0
    np.testing.assert_allclose(joints[:, 0], straight, atol=1e-15)
    np.testing.assert_allclose(joints[:, 1], 1j * straight, atol=1e-15)
    discs = np.array([[0.0, 0.1, 0.02], [0.5, 0.0, 0.01]])
    gaps = disc_gaps(joints, discs)
    assert gaps.shape == (2, 3, 2)
    # disc 0's centre (0, 0.1) is 0.1 m above link 1 (x in [-1/15, 2/15]) of the straight
    # robot and on it when turned; disc 1's (0.5, 0) is 0.5 - 1/3 m beyond link 2's end
    assert gaps[0, 1, 0] == pytest.approx(0.1 - 0.02, abs=1e-15)
    assert gaps[0, 1, 1] == pytest.approx(-0.02, abs=1e-15)
    assert gaps[1, 2, 0] == pytest.approx(0.5 - 1.0 / 3.0 - 0.01, abs=1e-15)
    np.testing.assert_allclose(link_clearance(*PAPER, theta, discs), gaps.min(axis=(0, 1)))


def test_bench_near_discs_lie_in_their_band() -> None:
    t = np.linspace(0.0, 1.0, 2001)
    theta = np.column_stack([1.8 - 0.6 * t, 1.0 + t, 3.0 * np.sin(2.0 * t)])
    joints = link_joints(*PAPER, theta)
    discs = near_discs(np.random.default_rng(7), joints, 3, 0.013, 0.05)
    assert discs is not None and discs.shape == (3, 3)
    for disc in discs:  # decided on every sample, the screens notwithstanding
        least = link_clearance(*PAPER, theta, disc[None]).min()
        assert 0.013 <= least <= 0.05
        assert 0.02 <= disc[2] <= 0.05 and np.all(np.abs(disc[:2]) <= 0.35)
    assert near_discs(np.random.default_rng(7), joints, 3, 10.0, 11.0) is None  # no room


def test_python_control_obstacle_task_meets_its_ends_and_points() -> None:
    """One disc that python-control's optimum without it would cross (by 1.3 cm on 20,001
    samples): the solution meets the ends and keeps the clearance at its own time points,
    checked here on python-control's own ``eval`` with the bench's kinematics.

    With one BLAS thread, as flatcli's processes run: SLSQP's success on such problems turns
    on the rounding of its linear algebra (at 21 time points it solves this one with several
    threads and stops short with one); at 15 points it solves it with either."""
    from threadpoolctl import threadpool_limits

    disc = np.array([[-0.1, 0.1, 0.03]])
    clearance = 0.01
    points = 15
    with threadpool_limits(limits=1):
        result = b.pc_obstacle_task(b.PAPER_MANEUVER, disc, clearance, timepts=points,
                                    max_iter=1000)
    assert result.success, result.message
    grid = np.linspace(0.0, b.PAPER_MANEUVER.duration, points)
    x, u = result.trajectory.eval(grid)
    np.testing.assert_allclose(x[:, 0], b.PAPER_MANEUVER.start_state, atol=1e-9)
    np.testing.assert_allclose(x[:, -1], b.PAPER_MANEUVER.goal_state, atol=1e-9)
    np.testing.assert_allclose(u[:, [0, -1]], 0.0, atol=1e-9)
    assert result.end_error < SAME_TRAJECTORY_TOL
    gaps = link_clearance(*PAPER, x[:3, 1:-1].T, disc)
    assert gaps.min() >= clearance - pcflatsys.POINT_TOL
    assert np.min(np.sin(x[1, 1:-1]) * x[3, 1:-1]) >= 0.02 - pcflatsys.POINT_TOL
    assert result.held_at_points
    assert result.points_clearance == pytest.approx(gaps.min(), abs=SAME_TRAJECTORY_TOL)
    # the fine grid (20,001 samples, the time points among them) reports its least gap and
    # when; python-control's own eval agrees there
    assert math.isfinite(result.fine_clearance) and result.nonfinite == 0
    assert result.fine_clearance <= result.points_clearance + SAME_TRAJECTORY_TOL
    x_worst, _ = result.trajectory.eval(np.array([result.fine_time]))
    assert link_clearance(*PAPER, x_worst[:3].T, disc)[0] == pytest.approx(
        result.fine_clearance, abs=SAME_TRAJECTORY_TOL)
    assert result.violated_between == (result.fine_clearance < clearance - pcflatsys.FINE_TOL)
    assert result.violated_between  # between its points it cuts into the disc (by 1.4 cm)


def test_the_start_up_floor_runs_its_kernel_and_nothing_of_flatcli_but_its_numba_set_up(
        tmp_path: Path) -> None:
    """benchmarks/baselines/floor.py: the floor's process, run twice (the second from the
    cache), prints 3.0 (the closed form: the sum of the squares of three ones) and loads none
    of flatcli's modules but the package, its empty core package and ``_jit``."""
    import json
    import subprocess
    import sys

    from benchmarks.baselines.floor import floor_script, floor_seconds

    assert floor_seconds(tmp_path) > 0 and floor_seconds(tmp_path) > 0
    listing = floor_script(tmp_path, "import json; print(json.dumps(sorted(m for m in "
                           "sys.modules if m.startswith('flatcli'))))")
    out = subprocess.run([sys.executable, "-c", listing], check=True, capture_output=True,
                         text=True).stdout.splitlines()
    assert out[0] == "3.0"
    assert json.loads(out[1]) == ["flatcli", "flatcli.core", "flatcli.core._jit",
                                  "flatcli.floor_probe"]


def test_the_kernels_whole_process_runs_its_trials_and_loads_no_other_baseline() -> None:
    """benchmarks/baselines/kernel_process.py: the same-work kernel as a process of its own
    (what make bench sets a 10^3-trial sweep beside) prints its trials' count, and loads the
    kernel's module alone, not the package's other baselines (python-control, scipy's
    optimisers): a user of a hand-written kernel would not."""
    import json
    import subprocess
    import sys

    from benchmarks.baselines import kernel_process

    assert kernel_process.kernel_process_seconds(5, 1) > 0
    root = str(Path(kernel_process.__file__).resolve().parents[2])
    code = (f"import json, runpy, sys; sys.path.insert(0, {root!r}); "
            f"ns = runpy.run_path({kernel_process.__file__!r}); ns['_package_alone'](); "
            "n = ns['run'](4, 1); print(json.dumps([n, 'control' in sys.modules, "
            "'scipy.optimize' in sys.modules, 'benchmarks.baselines.shooting' in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True).stdout
    assert json.loads(out.splitlines()[-1]) == [4, False, False, False]
