"""Referees written apart from flatcli's kernels: the paper's closed loop with clipped joint
rates, derived with sympy from the full link kinematics, and scipy's DOP853 carried through
the crossings of the controller's singular set.

``ClippedLoop`` shares nothing with ``flatcli.core`` but the plan's flat flag (the reference
the controller tracks). The angular momentum H of the base and two links about their centre
of mass is summed from the links' centres of mass placed in the inertial frame (no reduced
constraint); H is linear in the rates, H = H_0 th0' + H_1 th1' + H_2 th2'. For d2 = 0 the
controller's flat output is y2 = th0 + r(th1) th2 with r = H_2 / H_0 (Franch, Agrawal, Oh,
Fattah, IROS 2003, eq. 16: -c0 / (a0 + a1 cos th1)); with H = H0 const,
y2' = alpha u1, alpha = -H_1 / H_0 + r'(th1) th2, and y2'' = alpha v1 + alpha_th1 u1^2 +
r' u1 u2. The law is the paper's linearising feedback (y1'' = v1, y2'' = v2 with
v = y_ref'' + kv (y_ref' - y') + kp (y_ref - y), eqs. 39-42), solved for u2; the plant applies
th1' = clip(u1), th2' = clip(u2) and turns its base so that H = H0, and u1 integrates v1
except while it is clipped and v1 pushes it further (no wind-up). Every slope is sympy's.

``through_crossings`` integrates a right-hand side with ``solve_ivp`` and restarts it
wherever the margin changes sign, so it passes the jump of the clipped rates there instead of
stepping across it.

``base_row_momentum`` is H by another route than the link kinematics: the base's row of the
Lagrangian mass matrix times the rates, H = (M(q) q')_0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp

from flatcli.core.plan.planning import Plan
from flatcli.core.robots.dynamics import Chain, mass_matrix
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: The restart after a crossing: a first step this short [s], so that a stage taken on the
#: wrong side of the jump (the event's state rounds to either side) costs at most
#: 2 x rate limit x this [rad].
FIRST_STEP = 1e-12


def link_momentum(robot: RobotParams) -> tuple[Any, tuple[Any, ...], tuple[Any, ...]]:
    """sympy's H [kg m^2/s] of the base and two links about the system's centre of mass, with
    the angles and rates it depends on: the base's centre of mass at d0 from its origin along
    its axis (angle th0), joint 1 at l0, link 1's centre of mass d1 beyond joint 1 along
    th0 + th1, joint 2 at l1 beyond it, link 2's centre of mass d2 beyond joint 2 along
    th0 + th1 + th2."""
    th = sp.symbols("th0 th1 th2")
    w = sp.symbols("w0 w1 w2")
    phi = (th[0], th[0] + th[1], th[0] + th[1] + th[2])  # absolute angles
    rate = (w[0], w[0] + w[1], w[0] + w[1] + w[2])
    origin = sp.Matrix([0, 0])
    positions = []
    for k in range(3):
        axis = sp.Matrix([sp.cos(phi[k]), sp.sin(phi[k])])
        positions.append(origin + sp.nsimplify(robot.com[k]) * axis)
        origin = origin + sp.nsimplify(robot.length[k]) * axis
    def velocity(p: Any) -> Any:
        return sum((p.diff(th[k]) * w[k] for k in range(3)), sp.zeros(2, 1))
    m = [sp.nsimplify(v) for v in robot.mass]
    total = sum(m)
    centre = sum((mk * p for mk, p in zip(m, positions, strict=True)), sp.zeros(2, 1)) / total
    h = sp.Integer(0)
    for k in range(3):
        r = positions[k] - centre
        v = velocity(positions[k]) - velocity(centre)
        h += sp.nsimplify(robot.inertia[k]) * rate[k] + m[k] * (r[0] * v[1] - r[1] * v[0])
    return sp.expand(h), th, w


@cache
def _laws(robot: RobotParams) -> tuple[Callable[..., Any], ...]:
    """Numerical functions of (th1, th2): H_0, H_1, H_2, r', alpha, alpha_th1 (the module
    docstring); r at (th1)."""
    h, th, w = link_momentum(robot)
    parts = [sp.simplify(h.diff(wk)) for wk in w]
    if any(p.has(th[0]) for p in parts):
        raise AssertionError("referee: H depends on th0 (it must not: it is invariant)")
    r = parts[2] / parts[0]
    if r.has(th[2]):
        raise AssertionError("referee: this loop needs d2 = 0 (r independent of th2)")
    r1 = sp.diff(r, th[1])
    alpha = -parts[1] / parts[0] + r1 * th[2]
    alpha1 = sp.diff(alpha, th[1])
    args = (th[1], th[2])
    return tuple(sp.lambdify(args, e, "math") for e in (*parts, r, r1, alpha, alpha1))


@dataclass(frozen=True)
class ClippedLoop:
    """The paper's kinematic closed loop with clipped joint rates (module docstring), for a
    nominal trial (the controller's model is the plant).

    robot : the robot, with d2 = 0; plan : the flat plan tracked; kp, kv : (2,) gains;
    h0 : the plant's momentum [kg m^2/s]; rate_limit : [rad/s]
    """

    robot: RobotParams
    plan: Plan
    kp: tuple[float, float]
    kv: tuple[float, float]
    h0: float
    rate_limit: float
    laws: tuple[Callable[..., Any], ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "laws", _laws(self.robot))

    def rhs(self, t: float, x: Array) -> Array:
        """(th0', th1', th2', u1') of the state x = (th0, th1, th2, u1) at time t [s]."""
        th0, th1, th2, u1 = (float(v) for v in x)
        h_0, h_1, h_2, r, r1, alpha, alpha1 = (f(th1, th2) for f in self.laws)
        flag = self.plan.flags(np.array([t]))[0]  # y1, y2, y1', y2', y1'', y2''
        y2 = th0 + r * th2
        v1 = flag[4] + self.kv[0] * (flag[2] - u1) + self.kp[0] * (flag[0] - th1)
        v2 = flag[5] + self.kv[1] * (flag[3] - alpha * u1) + self.kp[1] * (flag[1] - y2)
        u2 = (v2 - alpha * v1 - alpha1 * u1 * u1) / (r1 * u1)
        limit = self.rate_limit
        w1 = min(max(u1, -limit), limit)
        w2 = min(max(u2, -limit), limit)
        w0 = (self.h0 - h_1 * w1 - h_2 * w2) / h_0
        u1_dot = 0.0 if (u1 >= limit and v1 > 0) or (u1 <= -limit and v1 < 0) else v1
        return np.array([w0, w1, w2, u1_dot])

    def outputs(self, x: Array) -> Array:
        """(y1, y2) of a state [rad]."""
        r = self.laws[3](float(x[1]), float(x[2]))
        return np.array([x[1], x[0] + r * x[2]])

    @staticmethod
    def margin(t: float, x: Array) -> float:
        """The controller's signed margin sin th1 * u1 [rad/s]: u2 divides by it."""
        return float(np.sin(x[1]) * x[3])


@dataclass(frozen=True)
class Passage:
    """A run carried through the crossings: the state at T and the crossings' times [s]."""

    final: Array
    crossings: tuple[float, ...]


def through_crossings(
    rhs: Callable[[float, Array], Array],
    margin: Callable[[float, Array], float],
    x0: Array,
    duration: float,
    rtol: float,
    atol: float,
    max_step: float = 1e-3,
    limit: int = 100,
) -> Passage:
    """Integrate x' = rhs(t, x) on [0, duration] by DOP853, stopping at every sign change of
    ``margin`` (a terminal event, located by scipy's root finder) and starting afresh there
    with a first step of ``FIRST_STEP``, the event's direction reversed (the next crossing
    goes back the other way, so the one just passed is not found again)."""
    t, x = 0.0, np.asarray(x0, dtype=float)
    crossings: list[float] = []
    side = 1.0 if margin(t, x) > 0 else -1.0  # the margin's sign where the run is
    for _ in range(limit):
        def event(s: float, y: Array) -> float:
            return margin(s, y)

        event.terminal = True  # type: ignore[attr-defined]
        event.direction = -side  # type: ignore[attr-defined]
        with np.errstate(all="ignore"):
            sol = solve_ivp(rhs, (t, duration), x, method="DOP853", rtol=rtol, atol=atol,
                            max_step=max_step, events=event,
                            first_step=FIRST_STEP if crossings else None)
        if sol.status == -1:
            raise RuntimeError(f"referee: solve_ivp failed at t = {sol.t[-1]}: {sol.message}")
        if sol.status == 0:
            return Passage(sol.y[:, -1], tuple(crossings))
        t = float(sol.t_events[0][0])
        x = np.asarray(sol.y_events[0][0], dtype=float)
        side = -side
        crossings.append(t)
    raise RuntimeError(f"referee: more than {limit} crossings")


def base_row_momentum(chain: Chain, q: ArrayLike, q_dot: ArrayLike) -> NDArray[np.float64]:
    """H = (M(q) q')_0 (...) [kg m^2/s]: the base's row of ``dynamics.mass_matrix`` (the
    Lagrangian's mass matrix, checked against sympy in test_dynamics) times the rates."""
    M = mass_matrix(chain, q)
    return np.asarray(np.einsum("...k,...k->...", M[..., 0, :], np.asarray(q_dot, dtype=float)))
