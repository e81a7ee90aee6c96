"""Planning with python-control's ``flatsys``: a ``FlatSystem`` for this robot, the paper's
cubic maneuver (``pc_point_to_point``), input energy with constraints (``pc_optimal``) and a
task among discs with the links' clearance imposed at its time points (``pc_obstacle_task``)."""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass
from typing import Any

import control.flatsys as fs
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import NonlinearConstraint

from benchmarks.baselines.links import FINE, disc_gaps, link_clearance, link_joints
from benchmarks.baselines.problem import PAPER_MANEUVER, Maneuver
from benchmarks.baselines.quality import PlanQuality, flat_plan_quality, limits_violation
from flatcli.core.models.flatmodel import state_and_rates
from flatcli.core.models.flatness import flat_inputs
from flatcli.core.plan.planning import Plan
from flatcli.core.robots.params import Coefficients

Array = NDArray[np.float64]

def robot_flat_system(k: Coefficients) -> fs.FlatSystem:
    """The prolonged robot as a python-control ``FlatSystem``, its maps written out here.

    State x = (th0, th1, th2, u1) [rad, rad/s], inputs u = (u1', u2 = th2') [rad/s^2, rad/s],
    flat outputs y1 = th1, y2 = th0 - c0 th2 / A, each with the flag (y, y', y''), for a
    d2 = 0 model with A = a0 + a1 cos th1, B = b0 + b1 cos th1 (the paper's eqs. 34-41,
    derived again below, not flatcli's functions: the ratio in the bench is then python-control
    against flatcli, not python-control running flatcli's maps):

        g = B / A,  h = c0 a1 sin th1 / A^2,  g' = (g a1 - b1) sin th1 / A,
        h' = c0 a1 (cos th1 + 2 a1 sin^2 th1 / A) / A^2        (d/dth1)
        y1' = u1,  y2' = (g - h th2) u1                         (th0' = g u1 + c0 u2 / A)
        y1'' = u1',  y2'' = (g - h th2) u1' + (g' - h' th2) u1^2 - h u1 u2

    ``reverse`` solves them for the state and the inputs; ``updfcn`` is the reduced
    constraint with H0 = 0, so the system can also be simulated.

    Parameters
    ----------
    k : Coefficients of a d2 = 0 model
    """
    a0, a1, b0, b1, c0 = float(k.a0), float(k.a1), float(k.b0), float(k.b1), float(k.c0)

    def chart(th1: float) -> tuple[float, float, float, float, float]:
        c1, s1 = math.cos(th1), math.sin(th1)
        big_a = a0 + a1 * c1
        g = (b0 + b1 * c1) / big_a
        h = c0 * a1 * s1 / big_a**2
        g_prime = (g * a1 - b1) * s1 / big_a
        h_prime = c0 * a1 * (c1 + 2.0 * a1 * s1 * s1 / big_a) / big_a**2
        return big_a, g, h, g_prime, h_prime

    def forward(x: Array, u: Array, params: dict[str, Any] | None = None) -> list[Array]:
        th0, th1, th2, u1 = (float(v) for v in x)
        big_a, g, h, g_prime, h_prime = chart(th1)
        alpha = g - h * th2
        y2_ddot = alpha * u[0] + (g_prime - h_prime * th2) * u1 * u1 - h * u1 * u[1]
        return [np.array([th1, u1, u[0]]),
                np.array([th0 - c0 * th2 / big_a, alpha * u1, y2_ddot])]

    def reverse(zflag: list[Array], params: dict[str, Any] | None = None) -> tuple[Array, Array]:
        (y1, y1_dot, y1_ddot), (y2, y2_dot, y2_ddot) = zflag
        big_a, g, h, g_prime, h_prime = chart(float(y1))
        th2 = (g - y2_dot / y1_dot) / h
        th0 = y2 + c0 * th2 / big_a
        u2 = ((g - h * th2) * y1_ddot + (g_prime - h_prime * th2) * y1_dot**2 - y2_ddot) \
            / (h * y1_dot)
        return np.array([th0, y1, th2, y1_dot]), np.array([y1_ddot, u2])

    def updfcn(t: float, x: Array, u: Array, params: dict[str, Any] | None = None) -> Array:
        big_a, g, _, _, _ = chart(float(x[1]))
        return np.array([g * x[3] + c0 * u[1] / big_a, x[3], u[1], u[0]])

    return fs.flatsys(
        forward,
        reverse,
        updfcn,
        inputs=["u1_dot", "u2"],
        states=["th0", "th1", "th2", "u1"],
        outputs=["y1", "y2"],
        name="space_robot",
    )


def matching_end_inputs(plan: Plan) -> tuple[Array, Array]:
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
        grid_violation=limits_violation(
            state[:, :3], rates, margin, angle_limit, rate_limit, min_margin
        ),
        objective_evaluations=calls // max(timepts - 2, 1),
        seconds=seconds,
    )


def flat_states(k: Coefficients, y: Array, y_dot: Array, y_ddot: Array) -> tuple[Array, Array]:
    """``robot_flat_system``'s reverse map at many points at once (the same formulas, numpy).

    Parameters
    ----------
    k : Coefficients of a d2 = 0 model
    y, y_dot, y_ddot : (n, 2) flat outputs and their derivatives (``pc_flags``)

    Returns
    -------
    state : (n, 4) th0, th1, th2 [rad], u1 [rad/s]
    inputs : (n, 2) u1' [rad/s^2], u2 [rad/s]
    """
    a0, a1, b0, b1, c0 = float(k.a0), float(k.a1), float(k.b0), float(k.b1), float(k.c0)
    y1, y1_dot, y1_ddot = y[:, 0], y_dot[:, 0], y_ddot[:, 0]
    c1, s1 = np.cos(y1), np.sin(y1)
    big_a = a0 + a1 * c1
    g = (b0 + b1 * c1) / big_a
    h = c0 * a1 * s1 / big_a**2
    g_prime = (g * a1 - b1) * s1 / big_a
    h_prime = c0 * a1 * (c1 + 2.0 * a1 * s1 * s1 / big_a) / big_a**2
    th2 = (g - y_dot[:, 1] / y1_dot) / h
    th0 = y[:, 1] + c0 * th2 / big_a
    u2 = ((g - h * th2) * y1_ddot + (g_prime - h_prime * th2) * y1_dot**2 - y_ddot[:, 1]) \
        / (h * y1_dot)
    return np.column_stack([th0, y1, th2, y1_dot]), np.column_stack([y1_ddot, u2])


#: A constraint "holds at python-control's points" within this [m or rad/s] (SLSQP's
#: feasibility is not exact: 3e-6 m short observed on a solution it calls successful).
POINT_TOL = 1e-5
#: The clearance "is broken" on the fine grid below the bound less this [m].
FINE_TOL = 1e-9


@dataclass(frozen=True)
class PcObstacleTask:
    """python-control's ``point_to_point`` among discs, judged on a grid finer than its own.

    Attributes
    ----------
    success, message : from scipy.optimize.minimize, as python-control reports them
    clearance, min_margin : the bounds imposed [m], [rad/s]
    points_clearance : least gap of any link from any disc at python-control's interior
        time points, where it imposes the clearance [m]
    points_margin : least signed margin s sin th1 th1' there (s the sign at t = 0) [rad/s]
    fine_clearance : the least gap on the fine grid (over its finite samples) [m]
    fine_time : when it is reached [s]
    fine_margin : the least signed margin on the fine grid [rad/s]
    nonfinite : fine samples whose state is not finite (the flat map singular there)
    end_error : max |state - the maneuver's| at t = 0 and T, on the fine grid [rad, rad/s]
    seconds : wall time of ``point_to_point`` [s]
    trajectory : python-control's SystemTrajectory
    """

    success: bool
    message: str
    clearance: float
    min_margin: float
    points_clearance: float
    points_margin: float
    fine_clearance: float
    fine_time: float
    fine_margin: float
    nonfinite: int
    end_error: float
    seconds: float
    trajectory: fs.SystemTrajectory

    @property
    def held_at_points(self) -> bool:
        """Clearance and margin hold at python-control's own time points (POINT_TOL)."""
        return (self.points_clearance >= self.clearance - POINT_TOL
                and self.points_margin >= self.min_margin - POINT_TOL)

    @property
    def violated_between(self) -> bool:
        """The clearance holds at the time points and is broken between them (deeper than
        at the points, by FINE_TOL), or the state is not finite somewhere."""
        return self.held_at_points and (
            self.fine_clearance < min(self.clearance, self.points_clearance) - FINE_TOL
            or self.nonfinite > 0)

    @property
    def margin_lost_between(self) -> bool:
        """The singularity margin holds at the time points and not between them."""
        return self.held_at_points and not self.fine_margin >= self.min_margin - POINT_TOL


def pc_obstacle_task(
    maneuver: Maneuver,
    obstacles: Array,
    clearance: float,
    basis_size: int = 12,
    timepts: int = 21,
    min_margin: float = 0.02,
    fine: int = FINE,
    max_iter: int | None = None,
    system: fs.FlatSystem | None = None,
) -> PcObstacleTask:
    """Least input energy among discs, by ``control.flatsys.point_to_point``.

    From ``maneuver.start_state`` to ``maneuver.goal_state`` (th1' at the ends the
    maneuver's; zero end inputs, as ``pc_optimal``), basis ``PolyFamily(basis_size, T)``,
    integral cost th1'^2 + th2'^2 and, at every interior point of ``timepts`` (python-control's
    way), the gap of every link from every disc >= clearance (``benchmarks.tasks``'
    complex-plane kinematics, not flatcli's) and the singularity margin s sin th1 th1' >=
    min_margin, s the sign of sin th1 th1' at the start (th1 moves one way; pc_optimal's
    margin with s = 1). SLSQP, python-control's default, from its default start. The solution
    is then evaluated on ``fine`` points (``pc_flags``, ``flat_states``).

    Parameters
    ----------
    maneuver : Maneuver (its robot must have d2 = 0 and no across offset; start_rate and
        goal_rate non-zero)
    obstacles : (K, 3) discs x, y, radius [m]
    clearance : least gap of every link from every disc's surface [m]
    basis_size : N of ``PolyFamily(N, T)``; > 6
    timepts : points on [0, T] for cost and constraints
    min_margin : lower bound on the signed margin [rad/s]
    fine : points of the grid the solution is judged on
    max_iter : SLSQP's iteration limit (None: scipy's default, 100)
    system : a ``robot_flat_system`` to reuse

    Returns
    -------
    PcObstacleTask
    """
    k = maneuver.coefficients
    if system is None:
        system = robot_flat_system(k)
    robot = maneuver.robot
    mass, length, com = (np.asarray(v, dtype=float) for v in (robot.mass, robot.length,
                                                              robot.com))
    discs = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    x0, xf = maneuver.start_state, maneuver.goal_state
    sign = 1.0 if math.sin(x0[1]) * x0[3] >= 0 else -1.0
    T = maneuver.duration
    grid = np.linspace(0.0, T, timepts)

    def cost(x: Array, u: Array) -> float:
        return float(x[3] ** 2 + u[1] ** 2)

    def constrained(x: Array, u: Array) -> Array:
        gaps = disc_gaps(link_joints(mass, length, com, x[None, :3]), discs).ravel()
        return np.append(gaps, sign * math.sin(x[1]) * x[3])

    lower = np.append(np.full(discs.shape[0] * len(mass), clearance), min_margin)
    constraints = [(NonlinearConstraint, constrained, lower, np.full(lower.size, np.inf))]
    start = time.perf_counter()
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # "unable to solve": reported through success
        traj = fs.point_to_point(
            system,
            grid,
            x0,
            np.zeros(2),
            xf,
            np.zeros(2),
            basis=fs.PolyFamily(basis_size, T),
            integral_cost=cost,
            trajectory_constraints=constraints,
            minimize_options={} if max_iter is None else {"maxiter": max_iter},
        )
    seconds = time.perf_counter() - start

    t = np.linspace(0.0, T, fine)
    with np.errstate(all="ignore"):
        points, _ = flat_states(k, *pc_flags(traj, grid[1:-1]))
        state, _ = flat_states(k, *pc_flags(traj, t))
        gaps = link_clearance(mass, length, com, state[:, :3], discs)
        at_points = link_clearance(mass, length, com, points[:, :3], discs)
    finite = np.isfinite(state).all(axis=1) & np.isfinite(gaps)
    worst = int(np.argmin(np.where(finite, gaps, np.inf)))
    margin = sign * np.sin(state[:, 1]) * state[:, 3]
    return PcObstacleTask(
        success=bool(traj.success),
        message=str(traj.message),
        clearance=clearance,
        min_margin=min_margin,
        points_clearance=float(np.min(at_points)),
        points_margin=float(np.min(sign * np.sin(points[:, 1]) * points[:, 3])),
        fine_clearance=float(gaps[worst]) if finite.any() else math.nan,
        fine_time=float(t[worst]),
        fine_margin=float(np.min(np.where(np.isfinite(margin), margin, -np.inf))),
        nonfinite=int(np.sum(~finite)),
        end_error=float(max(np.max(np.abs(state[0] - x0)), np.max(np.abs(state[-1] - xf)))),
        seconds=seconds,
        trajectory=traj,
    )
