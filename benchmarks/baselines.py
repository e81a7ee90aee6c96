"""Baselines that ``make bench`` sets beside flatcli: what a user would pick instead.

Each baseline is an honest, competent implementation of the same task, written the way a
user of the tool in question would write it, so the ratios in the bench table mean
something:

* planning with python-control's ``flatsys`` (a ``FlatSystem`` for this robot):
  ``pc_point_to_point`` (the paper's cubic maneuver, which must come out identical to
  flatcli's) and ``pc_optimal`` (input energy with trajectory constraints);
* planning without flatness: ``shooting_plan``, an SLSQP shooting NLP over piecewise-constant
  joint rates;
* the closed loop of the paper (linearising feedback of the nominal d2 = 0 model, plant
  obeying the general reduced constraint), integrated with classical RK4 at a fixed step:
  ``compiled_closed_loop`` (a hand-written numba kernel, ``prange`` over trials),
  ``numpy_batch_rk4`` (vectorised over trials) and ``solve_ivp_trials_per_second`` (one trial at a
  time, RK45);
* ``timed`` and ``machine_info`` for the table.

Nothing here prints; every function returns its results. The closed-loop baselines share no
code with ``flatcli.core.simulate``: the formulas are written out again below, so that
agreeing with flatcli to rounding is a check of both.
"""

from __future__ import annotations

import math
import os
import platform
import statistics
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import control
import control.flatsys as fs
import numba
import numpy as np
import scipy
from numba import njit, prange
from numpy.typing import NDArray
from scipy.integrate import solve_ivp
from scipy.optimize import Bounds, NonlinearConstraint, minimize

from flatcli.core.control import Gains
from flatcli.core.flatness import flat_accelerations, flat_inputs, flat_outputs, flat_state
from flatcli.core.model import (
    PAPER_ROBOT,
    Coefficients,
    Model,
    RobotParams,
    base_rate,
    constraint_coefficients,
    momentum,
)
from flatcli.core.planning import (
    FlatPlan,
    PolynomialBasis,
    plan_point_to_point,
    state_and_rates,
)
from flatcli.core.simulate import Trials

Array = NDArray[np.float64]

Triple = tuple[float, float, float]

#: The paper's printed gains (kp1, kp2, kv1, kv2): closed-loop poles near -0.1 and -100.
PRINTED_GAINS = Gains(kp1=10.0, kp2=13.0, kv1=100.0, kv2=110.0)
#: kp and kv swapped: well-damped poles, errors ~1e-5 at t = T.
SWAPPED_GAINS = Gains(kp1=100.0, kp2=110.0, kv1=10.0, kv2=13.0)


# --------------------------------------------------------------------------------------
# The problem every baseline solves
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Maneuver:
    """A point-to-point maneuver (the paper's, Sec. VI, by default).

    Attributes
    ----------
    robot : RobotParams of the planning model (d2 = 0 for the flat baselines)
    start, goal : th0, th1, th2 at t = 0 and t = T [rad]
    start_rate, goal_rate : th1' at the two ends [rad/s] (the paper's free choice)
    duration : T [s]
    model : constraint coefficients the planners believe ("derived" or "paper")
    """

    robot: RobotParams = PAPER_ROBOT
    start: Triple = (1.8, 1.0, 0.0)
    goal: Triple = (1.2, 2.0, 0.0)
    start_rate: float = 0.1
    goal_rate: float = 0.5
    duration: float = 2.0
    model: Model = "derived"

    @property
    def coefficients(self) -> Coefficients:
        """Reduced-constraint coefficients of the planning model [kg^2 m^2]."""
        return constraint_coefficients(self.robot.links, self.model)

    @property
    def start_state(self) -> Array:
        """(4,) prolonged state th0, th1, th2 [rad], u1 = th1' [rad/s] at t = 0."""
        return np.array([*self.start, self.start_rate])

    @property
    def goal_state(self) -> Array:
        """(4,) prolonged state at t = T."""
        return np.array([*self.goal, self.goal_rate])

    def cubic(self) -> FlatPlan:
        """flatcli's cubic plan of this maneuver (the paper's choice of basis)."""
        return plan_point_to_point(
            self.robot,
            np.asarray(self.start),
            np.asarray(self.goal),
            self.start_rate,
            self.goal_rate,
            self.duration,
            self.model,
        )


PAPER_MANEUVER = Maneuver()


@dataclass(frozen=True)
class Tracking:
    """The closed-loop setting of the paper's Fig. 4.

    Attributes
    ----------
    initial : th(0) of the robot [rad]
    initial_rate : u1(0), the controller's integrator [rad/s] (y1d'(0); not in the paper)
    gains : Gains (``PRINTED_GAINS`` or ``SWAPPED_GAINS``)
    dt : RK4 step [s]
    rate_limit : joint-rate saturation of the plant [rad/s] (inf: none)
    """

    initial: Triple = (1.96, 0.8, -0.1)
    initial_rate: float = 0.1
    gains: Gains = PRINTED_GAINS
    dt: float = 1e-3
    rate_limit: float = math.inf


PAPER_TRACKING = Tracking()


def paper_trials(
    count: int,
    seed: int = 0,
    tracking: Tracking = PAPER_TRACKING,
    robot: RobotParams = PAPER_ROBOT,
    spread: float = 0.02,
    angle_spread: float = 0.02,
    com2_spread: float = 0.002,
    momentum_spread: float = 1e-4,
) -> Trials:
    """Monte Carlo trials around the paper's closed loop, for the closed-loop baselines.

    Every plant parameter is scaled by an independent uniform factor in [1 - spread,
    1 + spread]; d2 = com[2] is drawn uniform in [-com2_spread, com2_spread] [m] (so the
    plant's reduced constraint has all its terms, the controller's model has none); the
    initial angles get uniform offsets of +-angle_spread [rad]; H0 is uniform in
    +-momentum_spread [kg m^2/s].

    Parameters
    ----------
    count : N trials
    seed : seed of numpy's default generator

    Returns
    -------
    Trials with links (N, 12), momentum (N,), initial (N, 4), no noise
    """
    rng = np.random.default_rng(seed)
    links = robot.as_array()[None, :] * rng.uniform(1 - spread, 1 + spread, (count, 12))
    links[:, 11] = rng.uniform(-com2_spread, com2_spread, count) + robot.com[2]
    initial = np.empty((count, 4))
    initial[:, :3] = np.asarray(tracking.initial) + rng.uniform(
        -angle_spread, angle_spread, (count, 3)
    )
    initial[:, 3] = tracking.initial_rate
    h0 = rng.uniform(-momentum_spread, momentum_spread, count)
    return Trials(links=links, momentum=h0, initial=initial)


# --------------------------------------------------------------------------------------
# Timing and machine
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Timing:
    """Wall-clock times of repeated calls [s]."""

    best: float
    median: float
    repeat: int
    times: tuple[float, ...] = field(repr=False)


def timed(fn: Callable[[], object], repeat: int = 5, warmup: int = 1) -> Timing:
    """Time ``fn()`` ``repeat`` times after ``warmup`` untimed calls (compilation, caches).

    Parameters
    ----------
    fn : callable without arguments
    repeat : timed calls (>= 1)
    warmup : untimed calls first

    Returns
    -------
    Timing with the best and the median of the timed calls [s]
    """
    if repeat < 1:
        raise ValueError("timed: repeat must be >= 1")
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return Timing(min(times), statistics.median(times), repeat, tuple(times))


def machine_info() -> dict[str, Any]:
    """CPU model, cores, load, thread settings and versions of the numeric stack."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count() or 1
    try:
        load: list[float] | None = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = None
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "usable_cores": usable,
        "load_average_1_5_15min": load,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
        "numba_threads": numba.get_num_threads(),
        # BLAS threads matter: SLSQP on a loaded 2-core machine runs several times slower
        # with 2 OpenBLAS threads (flatcli, imported first by this package, pins them to 1)
        "thread_env": {
            name: os.environ.get(name)
            for name in (
                "OMP_NUM_THREADS",
                "OPENBLAS_NUM_THREADS",
                "MKL_NUM_THREADS",
                "NUMBA_NUM_THREADS",
            )
        },
        "control": control.__version__,
    }


# --------------------------------------------------------------------------------------
# python-control flatsys
# --------------------------------------------------------------------------------------


def robot_flat_system(k: Coefficients) -> fs.FlatSystem:
    """The prolonged robot as a python-control ``FlatSystem``.

    State x = (th0, th1, th2, u1) [rad, rad/s], inputs u = (u1', u2 = th2') [rad/s^2, rad/s],
    flat outputs y1 = th1, y2 = th0 - c0 th2 / (a0 + a1 cos th1), each with the flag
    (y, y', y''). ``forward`` and ``reverse`` call flatcli's flat maps; ``updfcn`` is the
    reduced constraint, so the system can also be simulated.

    Parameters
    ----------
    k : Coefficients of a d2 = 0 model
    """

    def forward(x: Array, u: Array, params: dict[str, Any] | None = None) -> list[Array]:
        y1, y2, y1_dot, y2_dot = flat_outputs(k, x[0], x[1], x[2], x[3])
        y1_ddot, y2_ddot = flat_accelerations(k, x[1], x[2], x[3], u[0], u[1])
        return [np.array([y1, y1_dot, y1_ddot]), np.array([y2, y2_dot, y2_ddot])]

    def reverse(zflag: list[Array], params: dict[str, Any] | None = None) -> tuple[Array, Array]:
        th0, th1, th2, u1 = flat_state(k, zflag[0][0], zflag[1][0], zflag[0][1], zflag[1][1])
        u1_dot, u2 = flat_inputs(k, th1, th2, u1, zflag[0][2], zflag[1][2])
        return np.array([th0, th1, th2, u1]), np.array([u1_dot, u2])

    def updfcn(t: float, x: Array, u: Array, params: dict[str, Any] | None = None) -> Array:
        th0_dot = base_rate(k, 1.0, 0.0, x[1], x[2], x[3], u[1])  # H0 = 0: M drops out
        return np.array([th0_dot, x[3], u[1], u[0]])

    return fs.flatsys(
        forward,
        reverse,
        updfcn,
        inputs=["u1_dot", "u2"],
        states=["th0", "th1", "th2", "u1"],
        outputs=["y1", "y2"],
        name="space_robot",
    )


def matching_end_inputs(plan: FlatPlan) -> tuple[Array, Array]:
    """Inputs u(0), u(T) whose flat accelerations are those of ``plan`` at its two ends.

    python-control imposes the whole flag (y, y', y'') at both ends, flatcli's cubic only
    y and y'; passing these inputs makes the two problems the same.

    Returns
    -------
    u0, uf : (2,) u1' [rad/s^2], u2 [rad/s] at t = 0 and t = T
    """
    ends = np.array([0.0, plan.duration])
    y_ddot = plan.trajectory.derivative(ends, 2)
    state, _ = state_and_rates(
        plan.coefficients,
        plan.trajectory.derivative(ends, 0),
        plan.trajectory.derivative(ends, 1),
        y_ddot,
    )
    out = []
    for j in range(2):
        _, th1, th2, u1 = state[j]
        out.append(np.array(flat_inputs(plan.coefficients, th1, th2, u1, *y_ddot[j])))
    return out[0], out[1]


def pc_flags(traj: fs.SystemTrajectory, t: Array) -> tuple[Array, Array, Array]:
    """Flat outputs and two derivatives of a python-control trajectory.

    Parameters
    ----------
    traj : SystemTrajectory from ``point_to_point``
    t : (n,) times [s]

    Returns
    -------
    y, y_dot, y_ddot : (n, 2) each
    """
    t = np.asarray(t, dtype=float)
    out = np.zeros((3, t.size, 2))
    for i, coeffs in enumerate(traj.coeffs):
        for j, c in enumerate(coeffs):
            for order in range(3):
                out[order, :, i] += c * traj.basis.eval_deriv(j, order, t, var=None)
    return out[0], out[1], out[2]


@dataclass(frozen=True)
class PcPlan:
    """python-control's solution of the paper's maneuver, on a time grid.

    Attributes
    ----------
    t : (n,) [s]
    state : (n, 4) th0, th1, th2 [rad], u1 [rad/s] from ``SystemTrajectory.eval``
    inputs : (n, 2) u1' [rad/s^2], u2 [rad/s]
    plan_seconds : wall time of ``point_to_point`` [s]
    eval_seconds : wall time of ``eval`` on the grid [s]
    max_theta_error : max over the grid and joints of |th - th of flatcli's plan| [rad]
    max_rate_error : the same for (th1', th2') = (u1, u2) [rad/s]
    """

    t: Array
    state: Array
    inputs: Array
    plan_seconds: float
    eval_seconds: float
    max_theta_error: float
    max_rate_error: float

    @property
    def seconds(self) -> float:
        """Plan + eval [s]."""
        return self.plan_seconds + self.eval_seconds


def pc_point_to_point(
    maneuver: Maneuver = PAPER_MANEUVER,
    samples: int = 200,
    system: fs.FlatSystem | None = None,
) -> PcPlan:
    """The maneuver solved by ``control.flatsys.point_to_point`` and evaluated on a grid.

    The flag of length 3 makes python-control impose y'' at both ends too; they are taken
    from flatcli's cubic (``matching_end_inputs``) and the basis is ``PolyFamily(6, T)``,
    quintics, which contain the cubic: the unique solution is then flatcli's cubic, and
    the result reports how far apart the two are.

    Parameters
    ----------
    maneuver : Maneuver (its robot must have d2 = 0)
    samples : grid size n on [0, T]
    system : a ``robot_flat_system`` to reuse (built here otherwise, not timed)

    Returns
    -------
    PcPlan
    """
    plan = maneuver.cubic()
    if system is None:
        system = robot_flat_system(plan.coefficients)
    u0, uf = matching_end_inputs(plan)
    x0, xf = maneuver.start_state, maneuver.goal_state
    T = maneuver.duration
    t = np.linspace(0.0, T, samples)

    start = time.perf_counter()
    traj = fs.point_to_point(system, T, x0, u0, xf, uf, basis=fs.PolyFamily(6, T))
    planned = time.perf_counter()
    x, u = traj.eval(t)
    done = time.perf_counter()

    reference = plan.sample(t)
    return PcPlan(
        t=t,
        state=x.T,
        inputs=u.T,
        plan_seconds=planned - start,
        eval_seconds=done - planned,
        max_theta_error=float(np.max(np.abs(x[:3].T - reference.theta))),
        max_rate_error=float(
            max(
                np.max(np.abs(x[3] - reference.theta_dot[:, 1])),
                np.max(np.abs(u[1] - reference.theta_dot[:, 2])),
            )
        ),
    )


def flatcli_point_to_point(maneuver: Maneuver = PAPER_MANEUVER, samples: int = 200) -> Array:
    """flatcli's side of the planning comparison: the cubic plan sampled on n points.

    Returns
    -------
    theta : (n, 3) [rad]
    """
    plan = maneuver.cubic()
    return plan.sample(plan.grid(samples)).theta


@dataclass(frozen=True)
class PlanQuality:
    """What a plan costs and how well it keeps the limits, judged on a dense grid.

    Attributes
    ----------
    energy : integral of th1'^2 + th2'^2 over [0, T] [rad^2/s]
    max_abs_theta : (3,) max |th_i| [rad]
    max_abs_rate : (3,) max |th_i'| [rad/s]
    min_margin : min |sin th1 * th1'| [rad/s]
    max_abs_momentum : max |H| from the full kinematics [kg m^2/s]
    violation : max amount by which any imposed limit is exceeded (0: none) [rad or rad/s]
    """

    energy: float
    max_abs_theta: Array
    max_abs_rate: Array
    min_margin: float
    max_abs_momentum: float
    violation: float


def _limits_violation(
    theta: Array,
    rates: Array,
    margin: Array,
    angle_limit: float | None,
    rate_limit: float | None,
    min_margin: float | None,
) -> float:
    """Largest excess over |th2| <= angle_limit, |th1'|, |th2'| <= rate_limit, margin."""
    excess = [0.0]
    if angle_limit is not None:
        excess.append(float(np.max(np.abs(theta[:, 2]))) - angle_limit)
    if rate_limit is not None:
        excess.append(float(np.max(np.abs(rates[:, 1:3]))) - rate_limit)
    if min_margin is not None:
        excess.append(min_margin - float(np.min(margin)))
    return max(excess)


def _gauss_grid(duration: float, pieces: int = 64, order: int = 8) -> tuple[Array, Array]:
    """Composite Gauss-Legendre nodes and weights on [0, duration]."""
    x, w = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(0.0, duration, pieces + 1)
    half = 0.5 * np.diff(edges)[:, None]
    return (half * (x + 1.0) + edges[:-1, None]).ravel(), (half * w).ravel()


def flat_plan_quality(
    k: Coefficients,
    robot: RobotParams,
    flags: Callable[[Array], tuple[Array, Array, Array]],
    duration: float,
    angle_limit: float | None = None,
    rate_limit: float | None = None,
    min_margin: float | None = None,
    samples: int = 2001,
) -> PlanQuality:
    """Judge a flat plan given by its flags y, y', y'' as functions of time.

    Rates are the exact derivative of the inverse flat map (complex step, as flatcli's
    planner does), so H measures the plan itself, not an integration.
    """
    t = np.linspace(0.0, duration, samples)
    y, y_dot, y_ddot = flags(t)
    state, state_dot = state_and_rates(k, y, y_dot, y_ddot)
    theta, rates = state[:, :3], state_dot[:, :3]
    margin = np.abs(np.sin(theta[:, 1]) * rates[:, 1])
    H = momentum(robot.links, *theta.T, *rates.T)
    tq, wq = _gauss_grid(duration)
    _, rq = state_and_rates(k, *flags(tq))
    return PlanQuality(
        energy=float(wq @ (rq[:, 1] ** 2 + rq[:, 2] ** 2)),
        max_abs_theta=np.max(np.abs(theta), axis=0),
        max_abs_rate=np.max(np.abs(rates), axis=0),
        min_margin=float(np.min(margin)),
        max_abs_momentum=float(np.max(np.abs(H))),
        violation=_limits_violation(theta, rates, margin, angle_limit, rate_limit, min_margin),
    )


def plan_quality(
    plan: FlatPlan,
    angle_limit: float | None = None,
    rate_limit: float | None = None,
    min_margin: float | None = None,
) -> PlanQuality:
    """``flat_plan_quality`` of a flatcli plan (the same referee as for python-control's)."""

    def flags(t: Array) -> tuple[Array, Array, Array]:
        curve = plan.trajectory
        return curve.derivative(t, 0), curve.derivative(t, 1), curve.derivative(t, 2)

    return flat_plan_quality(
        plan.coefficients, plan.robot, flags, plan.duration, angle_limit, rate_limit, min_margin
    )


@dataclass(frozen=True)
class PcOptimal:
    """python-control's ``point_to_point`` with a cost and trajectory constraints.

    Attributes
    ----------
    success, message : from scipy.optimize.minimize, as python-control reports them
    cost : python-control's own objective (its rectangle sum over ``timepts``) [rad^2/s]
    quality : PlanQuality on a dense grid (exact energy, limits, |H|, margin)
    grid_violation : limit excess on python-control's own ``timepts`` (where it imposes them)
    objective_evaluations : calls of the trajectory cost by the optimiser
    seconds : wall time of ``point_to_point`` [s]
    """

    success: bool
    message: str
    cost: float
    quality: PlanQuality
    grid_violation: float
    objective_evaluations: int
    seconds: float


def pc_optimal(
    maneuver: Maneuver = PAPER_MANEUVER,
    basis_size: int = 12,
    timepts: int = 41,
    angle_limit: float | None = 3.0,
    rate_limit: float | None = 20.0,
    min_margin: float | None = 0.05,
    end_inputs: tuple[Array, Array] | None = None,
    system: fs.FlatSystem | None = None,
) -> PcOptimal:
    """Least input energy with limits, by ``control.flatsys.point_to_point``.

    Cost: th1'^2 + th2'^2 = x[3]^2 + u[1]^2 (th1' is the state u1, th2' the input u2).
    Constraints at every interior point of ``timepts`` (python-control's way): |th2| <=
    angle_limit, |th1'|, |th2'| <= rate_limit, and the singularity margin sin th1 * th1' >=
    min_margin (without it the optimiser parks the singular set of the flat map between
    grid points, where cost and limits are never looked at). SLSQP, python-control's
    default, from its default start (the least-norm coefficients meeting the ends).

    python-control fixes the whole state and input at both ends: the end rates th1'(0),
    th1'(T) are the maneuver's, and the end inputs default to zero (at rest in th2, no
    angular acceleration of joint 1), unlike flatcli's optimiser, which may free them.

    Parameters
    ----------
    maneuver : Maneuver
    basis_size : N of ``PolyFamily(N, T)`` (polynomials of degree N - 1); > 6
    timepts : points on [0, T] for cost and constraints
    angle_limit : bound on |th2| [rad], None for none
    rate_limit : bound on |th1'| and |th2'| [rad/s], None for none
    min_margin : lower bound on sin th1 * th1' [rad/s], None for none
    end_inputs : (u0, uf), each (2,) u1' [rad/s^2], u2 [rad/s]; default zeros
    system : a ``robot_flat_system`` to reuse

    Returns
    -------
    PcOptimal
    """
    k = maneuver.coefficients
    if system is None:
        system = robot_flat_system(k)
    u0, uf = end_inputs if end_inputs is not None else (np.zeros(2), np.zeros(2))
    T = maneuver.duration
    grid = np.linspace(0.0, T, timepts)
    calls = 0

    def cost(x: Array, u: Array) -> float:
        nonlocal calls
        calls += 1
        return float(x[3] ** 2 + u[1] ** 2)

    inf = np.inf
    a_lim = inf if angle_limit is None else angle_limit
    r_lim = inf if rate_limit is None else rate_limit
    m_lim = -inf if min_margin is None else min_margin

    def limits(x: Array, u: Array) -> Array:
        return np.array([x[2], x[3], u[1], math.sin(x[1]) * x[3]])

    constraints = [
        (NonlinearConstraint, limits, [-a_lim, -r_lim, -r_lim, m_lim], [a_lim, r_lim, r_lim, inf])
    ]
    start = time.perf_counter()
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # "unable to solve": reported through success
        traj = fs.point_to_point(
            system,
            grid,
            maneuver.start_state,
            u0,
            maneuver.goal_state,
            uf,
            basis=fs.PolyFamily(basis_size, T),
            integral_cost=cost,
            trajectory_constraints=constraints,
        )
    seconds = time.perf_counter() - start

    def flags(t: Array) -> tuple[Array, Array, Array]:
        return pc_flags(traj, t)

    with np.errstate(all="ignore"):
        quality = flat_plan_quality(
            k, maneuver.robot, flags, T, angle_limit, rate_limit, min_margin
        )
        state, rates = state_and_rates(k, *flags(grid[1:-1]))
    margin = np.abs(np.sin(state[:, 1]) * rates[:, 1])
    return PcOptimal(
        success=bool(traj.success),
        message=str(traj.message),
        cost=float(traj.cost),
        quality=quality,
        grid_violation=_limits_violation(
            state[:, :3], rates, margin, angle_limit, rate_limit, min_margin
        ),
        objective_evaluations=calls // max(timepts - 2, 1),
        seconds=seconds,
    )


# --------------------------------------------------------------------------------------
# Shooting without flatness
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ShootingPlan:
    """Result of the shooting NLP.

    Attributes
    ----------
    success, message : from SLSQP
    rates : (K, 2) th1', th2' on each interval [rad/s]
    knots : (K + 1,) interval ends [s]
    theta : (K + 1, 3) angles at the knots from the plan's own integration [rad]
    objective : input energy, integral of th1'^2 + th2'^2 (exact for these rates) [rad^2/s]
    terminal_error : max |th(T) - goal| by the plan's own integration [rad]
    integration_error : |th0(T)| difference to the same rates integrated 16x finer [rad]
        (what the robot flying these rates would actually miss the goal by, to leading order)
    violation : max excess over the imposed limits (0: none)
    max_abs_momentum : max |H| from the full kinematics with the rates used (th0' from the
        constraint) at every integration point [kg m^2/s]
    iterations : SLSQP iterations; evaluations : objective evaluations
    seconds : wall time of the solve [s]
    """

    success: bool
    message: str
    rates: Array
    knots: Array
    theta: Array
    objective: float
    terminal_error: float
    integration_error: float
    violation: float
    max_abs_momentum: float
    iterations: int
    evaluations: int
    seconds: float


class _Shooting:
    """th(t) for piecewise-constant joint rates, th0' from the reduced constraint.

    The joint angles are piecewise linear, exactly; th0 is integrated by RK4 on ``substeps``
    steps per interval. Since th0' does not depend on th0 and the joint rates are constant
    on a step, RK4's stages fall at the step's start, middle (twice) and end, so each RK4
    step is Simpson's rule; written that way, every step of every interval is evaluated in
    one vectorised call.
    """

    def __init__(self, maneuver: Maneuver, intervals: int, substeps: int) -> None:
        self.k = maneuver.coefficients
        self.total_mass = maneuver.robot.total_mass
        self.start = np.asarray(maneuver.start, dtype=float)
        self.intervals = intervals
        self.substeps = substeps
        self.h = maneuver.duration / intervals
        self.hs = self.h / substeps
        self.offsets = np.array([0.0, 0.5, 1.0]) * self.hs
        self.simpson = np.array([1.0, 4.0, 1.0]) * (self.hs / 6.0)

    def points(self, rates: Any) -> tuple[Any, Any, Any, Any]:
        """th1, th2 and the rates at every RK4 stage point: (..., K * S, 3) each."""
        per_step = np.repeat(rates, self.substeps, axis=-2)  # (..., Q, 2)
        begin = self.start[1:] + self.hs * (np.cumsum(per_step, axis=-2) - per_step)
        pts = begin[..., :, None, :] + self.offsets[:, None] * per_step[..., :, None, :]
        r = np.broadcast_to(per_step[..., :, None, :], pts.shape)
        return pts[..., 0], pts[..., 1], r[..., 0], r[..., 1]

    def base_rates(self, rates: Any) -> Any:
        """th0' at every stage point, (..., K * S, 3)."""
        th1, th2, r1, r2 = self.points(rates)
        return base_rate(self.k, self.total_mass, 0.0, th1, th2, r1, r2)

    def final_base(self, rates: Any) -> Any:
        """th0(T), (...)."""
        return self.start[0] + np.sum(self.base_rates(rates) @ self.simpson, axis=-1)

    def final_base_gradient(self, rates: Array) -> Array:
        """d th0(T) / d rates, flattened (2K,), exact to rounding.

        The partial derivatives of th0' in th1, th2, th1', th2' at every stage point come
        from a complex step; the chain rule through th_j(t) = th_j(0) + integral of th_j'
        is a reversed cumulative sum, so the whole gradient costs four evaluations.
        """
        step = 1e-30
        args = self.points(rates)
        partial = []
        for a in range(4):
            z = list(args)
            z[a] = z[a] + 1j * step
            partial.append(base_rate(self.k, self.total_mass, 0.0, *z).imag / step)
        grad = np.empty((self.intervals, 2))
        for c in range(2):
            d_angle, d_rate = partial[c], partial[2 + c]  # (Q, 3)
            weight = d_angle @ self.simpson  # (Q,) th0(T) per unit change of th_c on step q
            later = np.cumsum(weight[::-1])[::-1] - weight  # steps after q
            per_step = (
                self.hs * later + d_angle @ (self.simpson * self.offsets) + d_rate @ self.simpson
            )
            grad[:, c] = per_step.reshape(self.intervals, self.substeps).sum(axis=1)
        return grad.ravel()

    def final_base_gradient_batched(self, rates: Array) -> Array:
        """The same gradient by 2K complex steps of the whole integration (for testing)."""
        step = 1e-30
        n = rates.size
        batch = np.broadcast_to(rates.astype(complex), (n, *rates.shape)).copy()
        batch.reshape(n, n)[np.arange(n), np.arange(n)] += 1j * step
        return np.asarray(self.final_base(batch).imag / step)

    def knots_theta(self, rates: Array) -> Array:
        """(K + 1, 3) angles at the interval ends."""
        f = self.base_rates(rates) @ self.simpson  # (Q,)
        th0 = self.start[0] + np.concatenate([[0.0], np.cumsum(f)])[:: self.substeps]
        joints = self.start[1:] + np.concatenate([np.zeros((1, 2)), np.cumsum(rates, 0) * self.h])
        return np.column_stack([th0, joints])


def shooting_plan(
    maneuver: Maneuver = PAPER_MANEUVER,
    intervals: int = 40,
    substeps: int = 4,
    angle_limit: float | None = None,
    rate_limit: float | None = None,
    maxiter: int = 500,
    ftol: float = 1e-10,
    exact_gradients: bool = True,
) -> ShootingPlan:
    """Least input energy from start to goal without flatness: a shooting NLP with SLSQP.

    Decision: piecewise-constant joint rates (th1', th2') on K equal intervals. th0 follows
    from the reduced constraint of the planning model (``base_rate`` with H = 0), integrated
    by RK4 on ``substeps`` steps per interval. Minimise the input energy h sum(th1'^2 +
    th2'^2) subject to reaching the goal angles at T (th1, th2 linear, th0 nonlinear with an
    exact complex-step gradient), |th2| <= angle_limit at the knots (exact: th2 is piecewise
    linear) and |rates| <= rate_limit (bounds). The end rates are free. Start: constant rates
    along the straight line in joint space.

    Parameters
    ----------
    maneuver : Maneuver (start, goal, T, robot and model; its end rates are not used)
    intervals : K
    substeps : RK4 steps per interval
    angle_limit : bound on |th2| [rad] or None
    rate_limit : bound on |th1'|, |th2'| [rad/s] or None
    maxiter, ftol : SLSQP options
    exact_gradients : give SLSQP the exact gradients (default); False lets it take forward
        differences, as a quick script would (2K + 1 integrations per iteration)

    Returns
    -------
    ShootingPlan
    """
    model = _Shooting(maneuver, intervals, substeps)
    K, h = intervals, model.h
    goal = np.asarray(maneuver.goal, dtype=float)
    joint_rows = np.zeros((2, 2 * K))
    joint_rows[0, 0::2] = h
    joint_rows[1, 1::2] = h
    joint_target = goal[1:] - model.start[1:]

    def shape(z: Array) -> Array:
        return z.reshape(K, 2)

    def energy(z: Array) -> float:
        return float(h * (z @ z))

    def energy_grad(z: Array) -> Array:
        return 2.0 * h * z

    def equality(z: Array) -> Array:
        return np.concatenate(
            [[float(model.final_base(shape(z))) - goal[0]], joint_rows @ z - joint_target]
        )

    def equality_jac(z: Array) -> Array:
        return np.vstack([model.final_base_gradient(shape(z)), joint_rows])

    constraints: list[dict[str, Any]] = [{"type": "eq", "fun": equality}]
    if exact_gradients:
        constraints[0]["jac"] = equality_jac
    if angle_limit is not None:
        # th2 at knots 1..K: start + h * cumulative sum of th2'
        cum = np.tril(np.ones((K, K))) * h
        rows = np.zeros((K, 2 * K))
        rows[:, 1::2] = cum
        A = np.vstack([-rows, rows])
        b = np.concatenate(
            [np.full(K, angle_limit + model.start[2]), np.full(K, angle_limit - model.start[2])]
        )

        constraints.append({"type": "ineq", "fun": lambda z: b - A @ z, "jac": lambda z: -A})
    bounds = None if rate_limit is None else Bounds(-rate_limit, rate_limit)
    z0 = np.tile((goal[1:] - model.start[1:]) / maneuver.duration, K)

    start = time.perf_counter()
    res = minimize(
        energy,
        z0,
        jac=energy_grad if exact_gradients else None,
        method="SLSQP",
        bounds=bounds,
        constraints=constraints,
        options={"maxiter": maxiter, "ftol": ftol},
    )
    seconds = time.perf_counter() - start

    rates = shape(res.x)
    theta = model.knots_theta(rates)
    fine = _Shooting(maneuver, intervals, substeps * 16)
    th1, th2, r1, r2 = model.points(rates)
    H = momentum(maneuver.robot.links, 0.0, th1, th2, model.base_rates(rates), r1, r2)
    excess = [0.0]
    if angle_limit is not None:
        excess.append(float(np.max(np.abs(theta[:, 2]))) - angle_limit)
    if rate_limit is not None:
        excess.append(float(np.max(np.abs(rates))) - rate_limit)
    return ShootingPlan(
        success=bool(res.success),
        message=str(res.message),
        rates=rates,
        knots=np.linspace(0.0, maneuver.duration, K + 1),
        theta=theta,
        objective=energy(res.x),
        terminal_error=float(np.max(np.abs(theta[-1] - goal))),
        integration_error=float(abs(fine.final_base(rates) - theta[-1, 0])),
        violation=max(excess),
        max_abs_momentum=float(np.max(np.abs(H))),
        iterations=int(res.nit),
        evaluations=int(res.nfev),
        seconds=seconds,
    )


# --------------------------------------------------------------------------------------
# The closed loop, written out again: shared inputs
# --------------------------------------------------------------------------------------


def plant_coefficients(links: Array) -> Array:
    """(N, 11) reduced-constraint coefficients of N plants, general d2 (physics note).

    Order: a0, a1, a2, a3, b0, b1, b2, b3, c0, c2', c3 [kg^2 m^2]. Written out here from the
    physics note rather than taken from flatcli, so that the closed-loop baselines check it.

    Parameters
    ----------
    links : (N, 12) m0, m1, m2 [kg], I0, I1, I2 [kg m^2], l0, l1, l2, d0, d1, d2 [m]
    """
    m0, m1, m2, I0, I1, I2, l0, l1, _, d0, d1, d2 = np.asarray(links, dtype=float).T
    M = m0 + m1 + m2
    e0, e1 = l0 - d0, l1 - d1
    common = m1 * m2 * e1**2 + m0 * (m2 * l1**2 + m1 * d1**2) + m2 * d2**2 * (m0 + m1)
    k2 = m2 * d2 * (m0 * l1 + m1 * e1)
    k3 = m0 * m2 * d2 * e0
    arm = m0 * e0 * (m2 * l1 + m1 * d1)
    out = np.column_stack(
        [
            M * (I0 + I1 + I2) + m0 * (m1 + m2) * e0**2 + common,
            2 * arm,
            2 * k2,
            2 * k3,
            -(M * (I1 + I2) + common),
            -arm,
            -2 * k2,
            -k3,
            -(M * I2 + m2 * d2**2 * (m0 + m1)),
            -k2,
            -k3,
        ]
    )
    return np.ascontiguousarray(out)


@dataclass(frozen=True)
class LoopInputs:
    """Everything the closed-loop baselines need, as plain arrays.

    Attributes
    ----------
    reference : (2n + 1, 6) y1, y2, y1', y2', y1'', y2'' at t = j dt / 2, from the plan's
        polynomial coefficients (Horner)
    poly : (3, 2, deg + 1) coefficients in s = t/T of y, y', y'' [per s^order], for
        evaluation at any t
    duration : T [s]
    controller : (5,) a0, a1, b0, b1, c0 of the controller's model [kg^2 m^2]
    gains : (4,) kp1, kp2, kv1, kv2
    plant : (N, 11) plant coefficients; total_mass : (N,) [kg]; h0 : (N,) [kg m^2/s]
    initial : (N, 4); dt [s]; steps n; rate_limit [rad/s]
    """

    reference: Array
    poly: Array
    duration: float
    controller: Array
    gains: Array
    plant: Array
    total_mass: Array
    h0: Array
    initial: Array
    dt: float
    steps: int
    rate_limit: float


def loop_inputs(plan: FlatPlan, tracking: Tracking, trials: Trials) -> LoopInputs:
    """Unpack a polynomial plan, a tracking setting and trials into ``LoopInputs``."""
    basis = plan.trajectory.basis
    if not isinstance(basis, PolynomialBasis):
        raise TypeError("closed-loop baselines: the plan must use a PolynomialBasis")
    T = plan.duration
    steps = round(T / tracking.dt)
    if not math.isclose(steps * tracking.dt, T, rel_tol=1e-9):
        raise ValueError("closed-loop baselines: dt must divide the plan's duration")
    c = np.asarray(plan.trajectory.coefficients, dtype=float)  # (2, deg + 1), in s = t/T
    P = np.polynomial.polynomial
    poly = np.zeros((3, 2, c.shape[1]))
    for order in range(3):
        d = P.polyder(c, order, axis=1) / T**order
        poly[order, :, : d.shape[1]] = d
    t = np.arange(2 * steps + 1, dtype=float) * (0.5 * tracking.dt)
    s = t / T
    reference = np.empty((t.size, 6))
    for order in range(3):
        for i in range(2):
            reference[:, 2 * order + i] = P.polyval(s, poly[order, i])
    k = plan.coefficients
    return LoopInputs(
        reference=reference,
        poly=poly,
        duration=T,
        controller=np.array([k.a0, k.a1, k.b0, k.b1, k.c0], dtype=float),
        gains=np.asarray(tracking.gains, dtype=float),
        plant=plant_coefficients(trials.links),
        total_mass=np.ascontiguousarray(trials.links[:, :3].sum(axis=1)),
        h0=np.ascontiguousarray(trials.momentum, dtype=float),
        initial=np.ascontiguousarray(trials.initial, dtype=float),
        dt=float(tracking.dt),
        steps=steps,
        rate_limit=float(tracking.rate_limit),
    )


# --------------------------------------------------------------------------------------
# Compiled RK4 kernel (numba, prange over trials)
# --------------------------------------------------------------------------------------


@njit(inline="always")
def _loop_rates(
    x0: float,
    x1: float,
    x2: float,
    x3: float,
    ref: Array,
    k: tuple[float, float, float, float, float],
    gains: tuple[float, float, float, float],
    p: tuple[float, ...],
    mh0: float,
    lim: float,
) -> tuple[float, float, float, float]:
    """Closed-loop rates of (th0, th1, th2, u1) at one state.

    k = (a0, a1, b0, b1, c0) of the controller, gains = (kp1, kp2, kv1, kv2), p the plant's
    11 coefficients, mh0 = M H0, lim the joint-rate limit.
    """
    ka0, ka1, kb0, kb1, kc0 = k
    kp1, kp2, kv1, kv2 = gains
    c1 = math.cos(x1)
    s1 = math.sin(x1)
    # controller, nominal d2 = 0 model: A = a0 + a1 c1, g = B/A, h = c0 a1 s1 / A^2
    inv_a = 1.0 / (ka0 + ka1 * c1)
    g = (kb0 + kb1 * c1) * inv_a
    h = kc0 * ka1 * s1 * inv_a * inv_a
    dg = (g * ka1 - kb1) * s1 * inv_a
    dh = kc0 * ka1 * (c1 + 2.0 * ka1 * s1 * s1 * inv_a) * inv_a * inv_a
    alpha = g - h * x2
    y2 = x0 - kc0 * x2 * inv_a
    v1 = ref[4] + kv1 * (ref[2] - x3) + kp1 * (ref[0] - x1)
    v2 = ref[5] + kv2 * (ref[3] - alpha * x3) + kp2 * (ref[1] - y2)
    u2 = (alpha * v1 + (dg - dh * x2) * x3 * x3 - v2) / (h * x3)
    # plant: saturated joint rates, th0' from its general reduced constraint
    w1 = min(max(x3, -lim), lim)
    w2 = min(max(u2, -lim), lim)
    c2 = math.cos(x2)
    c12 = math.cos(x1 + x2)
    A = p[0] + p[1] * c1 + p[2] * c2 + p[3] * c12
    B = p[4] + p[5] * c1 + p[6] * c2 + p[7] * c12
    C = p[8] + p[9] * c2 + p[10] * c12
    return (B * w1 + C * w2 + mh0) / A, w1, w2, v1


@njit(parallel=True, cache=True, error_model="numpy")
def _rk4_kernel(
    reference: Array,
    controller: Array,
    gains: Array,
    plant: Array,
    total_mass: Array,
    h0: Array,
    initial: Array,
    dt: float,
    lim: float,
    out: Array,
) -> None:
    """RK4 of every trial over the grid (IEEE arithmetic); final states go to out (N, 4)."""
    n = (reference.shape[0] - 1) // 2
    k = (controller[0], controller[1], controller[2], controller[3], controller[4])
    gn = (gains[0], gains[1], gains[2], gains[3])
    half = 0.5 * dt
    sixth = dt / 6.0
    for i in prange(initial.shape[0]):
        q = plant[i]
        p = (q[0], q[1], q[2], q[3], q[4], q[5], q[6], q[7], q[8], q[9], q[10])
        mh0 = total_mass[i] * h0[i]
        x0, x1, x2, x3 = initial[i, 0], initial[i, 1], initial[i, 2], initial[i, 3]
        for s in range(n):
            ra, rb, rc = reference[2 * s], reference[2 * s + 1], reference[2 * s + 2]
            # fmt: off
            a0, a1, a2, a3 = _loop_rates(x0, x1, x2, x3, ra, k, gn, p, mh0, lim)
            b0, b1, b2, b3 = _loop_rates(x0 + half * a0, x1 + half * a1, x2 + half * a2,
                                         x3 + half * a3, rb, k, gn, p, mh0, lim)
            c0, c1, c2, c3 = _loop_rates(x0 + half * b0, x1 + half * b1, x2 + half * b2,
                                         x3 + half * b3, rb, k, gn, p, mh0, lim)
            d0, d1, d2, d3 = _loop_rates(x0 + dt * c0, x1 + dt * c1, x2 + dt * c2,
                                         x3 + dt * c3, rc, k, gn, p, mh0, lim)
            # fmt: on
            x0 = x0 + sixth * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
            x1 = x1 + sixth * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
            x2 = x2 + sixth * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
            x3 = x3 + sixth * (a3 + 2.0 * b3 + 2.0 * c3 + d3)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x0, x1, x2, x3


def compiled_closed_loop(
    plan: FlatPlan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    threads: int | None = None,
    inputs: LoopInputs | None = None,
) -> Array:
    """Final states of N closed-loop trials by a hand-written numba RK4 kernel.

    Controller: the linearising feedback of the nominal (d2 = 0) model of ``plan``, gains of
    ``tracking``; plant of each trial: th1' = sat(u1), th2' = sat(u2), th0' = (B th1' +
    C th2' + M H0) / A with its own general coefficients; reference from the plan's
    polynomial coefficients at the RK4 stage times. No noise, no metrics, no traces.

    Parameters
    ----------
    plan : FlatPlan in a PolynomialBasis (the cubic by default)
    trials : Trials (N); their noise, if any, is ignored
    tracking : Tracking (gains, dt, rate limit; its initial state is not used: trials')
    threads : numba threads for this call (default: numba's current setting)
    inputs : precomputed ``loop_inputs`` (to keep unpacking out of a timing)

    Returns
    -------
    final : (N, 4) th0, th1, th2 [rad], u1 [rad/s] at t = T
    """
    li = inputs if inputs is not None else loop_inputs(plan, tracking, trials)
    out = np.empty((li.initial.shape[0], 4))
    previous = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(threads)
    try:
        # fmt: off
        _rk4_kernel(li.reference, li.controller, li.gains, li.plant, li.total_mass, li.h0,
                    li.initial, li.dt, li.rate_limit, out)
        # fmt: on
    finally:
        numba.set_num_threads(previous)
    return out


@dataclass(frozen=True)
class Throughput:
    """Trials per second of a closed-loop baseline."""

    trials: int
    timing: Timing
    threads: int = 1

    @property
    def trials_per_second(self) -> float:
        """Trials over the best time [1/s]."""
        return self.trials / self.timing.best

    @property
    def median_trials_per_second(self) -> float:
        """Trials over the median time [1/s]."""
        return self.trials / self.timing.median


def compiled_trials_per_second(
    plan: FlatPlan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    threads: int = 2,
    repeat: int = 3,
) -> Throughput:
    """Throughput of ``compiled_closed_loop`` after a warm-up (compilation, thread pool)."""
    li = loop_inputs(plan, tracking, trials)
    timing = timed(lambda: compiled_closed_loop(plan, trials, tracking, threads, li), repeat)
    return Throughput(trials.count, timing, threads)


# --------------------------------------------------------------------------------------
# numpy: vectorised RK4 over a batch of trials
# --------------------------------------------------------------------------------------


def _batch_rates(
    x: Sequence[Array],
    ref: Array,
    kc: Array,
    gains: Array,
    p: Array,
    mh0: Array,
    lim: float,
) -> tuple[Array, Array, Array, Array]:
    """Closed-loop rates over a batch: x (4,) of (B,), p (11, B) plant coefficients, mh0 (B,)."""
    x0, x1, x2, x3 = x
    ka0, ka1, kb0, kb1, kc0 = kc
    kp1, kp2, kv1, kv2 = gains
    c1 = np.cos(x1)
    s1 = np.sin(x1)
    inv_a = 1.0 / (ka0 + ka1 * c1)
    g = (kb0 + kb1 * c1) * inv_a
    inv_a2 = inv_a * inv_a
    h = (kc0 * ka1) * s1 * inv_a2
    dg = (g * ka1 - kb1) * s1 * inv_a
    dh = (kc0 * ka1) * (c1 + (2.0 * ka1) * s1 * s1 * inv_a) * inv_a2
    alpha = g - h * x2
    v1 = ref[4] + kv1 * (ref[2] - x3) + kp1 * (ref[0] - x1)
    v2 = ref[5] + kv2 * (ref[3] - alpha * x3) + kp2 * (ref[1] - x0 + kc0 * x2 * inv_a)
    u2 = (alpha * v1 + (dg - dh * x2) * x3 * x3 - v2) / (h * x3)
    w1 = np.clip(x3, -lim, lim)
    w2 = np.clip(u2, -lim, lim)
    c2 = np.cos(x2)
    c12 = np.cos(x1 + x2)
    A = p[0] + p[1] * c1 + p[2] * c2 + p[3] * c12
    B = p[4] + p[5] * c1 + p[6] * c2 + p[7] * c12
    C = p[8] + p[9] * c2 + p[10] * c12
    return (B * w1 + C * w2 + mh0) / A, w1, w2, v1


def numpy_batch_rk4(
    plan: FlatPlan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    chunk: int = 16384,
    inputs: LoopInputs | None = None,
) -> Array:
    """Final states of N closed-loop trials by RK4 vectorised over trials with numpy.

    The same closed loop as ``compiled_closed_loop``; trials are taken ``chunk`` at a time
    so that the working arrays stay in cache, and the time loop runs in Python.

    Parameters
    ----------
    plan, trials, tracking : as ``compiled_closed_loop``
    chunk : trials per vectorised batch
    inputs : precomputed ``loop_inputs``

    Returns
    -------
    final : (N, 4) [rad, rad/s]
    """
    li = inputs if inputs is not None else loop_inputs(plan, tracking, trials)
    N = li.initial.shape[0]
    out = np.empty((N, 4))
    dt, half, sixth = li.dt, 0.5 * li.dt, li.dt / 6.0
    ref = li.reference
    with np.errstate(all="ignore"):
        for lo in range(0, N, chunk):
            hi = min(lo + chunk, N)
            p = np.ascontiguousarray(li.plant[lo:hi].T)
            mh0 = li.total_mass[lo:hi] * li.h0[lo:hi]
            x = [li.initial[lo:hi, j].copy() for j in range(4)]
            args = (li.controller, li.gains, p, mh0, li.rate_limit)
            for s in range(li.steps):
                k1 = _batch_rates(x, ref[2 * s], *args)
                k2 = _batch_rates([xj + half * kj for xj, kj in zip(x, k1, strict=True)],
                                  ref[2 * s + 1], *args)  # fmt: skip
                k3 = _batch_rates([xj + half * kj for xj, kj in zip(x, k2, strict=True)],
                                  ref[2 * s + 1], *args)  # fmt: skip
                k4 = _batch_rates([xj + dt * kj for xj, kj in zip(x, k3, strict=True)],
                                  ref[2 * s + 2], *args)  # fmt: skip
                x = [
                    xj + sixth * (a + 2.0 * b + 2.0 * c + d)
                    for xj, a, b, c, d in zip(x, k1, k2, k3, k4, strict=True)
                ]
            out[lo:hi] = np.column_stack(x)
    return out


def numpy_trials_per_second(
    plan: FlatPlan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    repeat: int = 1,
    chunk: int = 16384,
) -> Throughput:
    """Throughput of ``numpy_batch_rk4`` in this process (one core)."""
    li = loop_inputs(plan, tracking, trials)
    timing = timed(lambda: numpy_batch_rk4(plan, trials, tracking, chunk, li), repeat, 0)
    return Throughput(trials.count, timing, 1)


# --------------------------------------------------------------------------------------
# scipy: solve_ivp, one trial at a time
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class IvpRun:
    """One-trial-at-a-time ``solve_ivp`` runs.

    Attributes
    ----------
    final : (N, 4) states at T [rad, rad/s]
    evaluations : (N,) right-hand-side evaluations per trial
    seconds : wall time of all N trials [s]
    """

    final: Array
    evaluations: NDArray[np.int64]
    seconds: float

    @property
    def trials_per_second(self) -> float:
        """Trials over the wall time [1/s]."""
        return float(self.final.shape[0] / self.seconds)


def solve_ivp_trials_per_second(
    plan: FlatPlan,
    trials: Trials,
    tracking: Tracking = PAPER_TRACKING,
    method: str = "RK45",
    rtol: float = 1e-8,
    atol: float = 1e-10,
) -> IvpRun:
    """The closed loop of each trial by ``scipy.integrate.solve_ivp``, one trial at a time.

    The right-hand side is plain Python on floats (``math``): the reference is the plan's
    polynomial evaluated at the solver's t (Horner), the controller and the plant are the
    formulas of ``compiled_closed_loop``. Only the final state is kept.

    Parameters
    ----------
    plan, trials, tracking : as ``compiled_closed_loop`` (tracking.dt is not used)
    method, rtol, atol : solve_ivp's (the issue's reference: RK45, rtol 1e-8)

    Returns
    -------
    IvpRun
    """
    li = loop_inputs(plan, tracking, trials)
    T = li.duration
    poly = [[list(li.poly[o, i][::-1]) for i in range(2)] for o in range(3)]  # Horner order
    ka0, ka1, kb0, kb1, kc0 = (float(v) for v in li.controller)
    kp1, kp2, kv1, kv2 = (float(v) for v in li.gains)
    lim = li.rate_limit
    cos, sin = math.cos, math.sin

    def horner(c: list[float], s: float) -> float:
        acc = 0.0
        for ci in c:
            acc = acc * s + ci
        return acc

    N = li.initial.shape[0]
    final = np.empty((N, 4))
    nfev = np.zeros(N, dtype=np.int64)
    start = time.perf_counter()
    for i in range(N):
        p = [float(v) for v in li.plant[i]]
        mh0 = float(li.total_mass[i] * li.h0[i])

        def rhs(t: float, x: Array, p: list[float] = p, mh0: float = mh0) -> list[float]:
            s = t / T
            y1, y2 = horner(poly[0][0], s), horner(poly[0][1], s)
            d1, d2 = horner(poly[1][0], s), horner(poly[1][1], s)
            dd1, dd2 = horner(poly[2][0], s), horner(poly[2][1], s)
            x0, x1, x2, x3 = x
            c1, s1 = cos(x1), sin(x1)
            inv_a = 1.0 / (ka0 + ka1 * c1)
            g = (kb0 + kb1 * c1) * inv_a
            h = kc0 * ka1 * s1 * inv_a * inv_a
            dg = (g * ka1 - kb1) * s1 * inv_a
            dh = kc0 * ka1 * (c1 + 2.0 * ka1 * s1 * s1 * inv_a) * inv_a * inv_a
            alpha = g - h * x2
            v1 = dd1 + kv1 * (d1 - x3) + kp1 * (y1 - x1)
            v2 = dd2 + kv2 * (d2 - alpha * x3) + kp2 * (y2 - x0 + kc0 * x2 * inv_a)
            u2 = (alpha * v1 + (dg - dh * x2) * x3 * x3 - v2) / (h * x3)
            w1 = min(max(x3, -lim), lim)
            w2 = min(max(u2, -lim), lim)
            c2, c12 = cos(x2), cos(x1 + x2)
            A = p[0] + p[1] * c1 + p[2] * c2 + p[3] * c12
            B = p[4] + p[5] * c1 + p[6] * c2 + p[7] * c12
            C = p[8] + p[9] * c2 + p[10] * c12
            return [(B * w1 + C * w2 + mh0) / A, w1, w2, v1]

        sol = solve_ivp(rhs, (0.0, T), li.initial[i], method=method, rtol=rtol, atol=atol)
        final[i] = sol.y[:, -1]
        nfev[i] = sol.nfev
    return IvpRun(final, nfev, time.perf_counter() - start)
