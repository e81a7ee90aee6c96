"""The planar free-floating robot: parameters, momentum constraint, and the flatness design check.

Links 0 (the base), 1 and 2 are joined in a chain by revolute joints. Link i has mass m_i,
inertia I_i about its centre of mass, length l_i (joint O_i to O_{i+1}) and its centre of
mass at distance d_i from O_i along the link. Angles are relative: th0 is the base attitude,
th1 and th2 the joint angles, so the absolute link angles are th0, th0 + th1, th0 + th1 + th2.
With no external force or torque the system centre of mass is inertially fixed and the total
angular momentum H about it is conserved.

Two independent descriptions of H live here:

* ``momentum``: H from the full link kinematics (positions and velocities of every link's
  centre of mass relative to the system centre of mass, plus each link's spin). This is the
  referee every test and metric uses.
* ``constraint_coefficients``: the reduced constraint
  ``A th0' = B th1' + C th2' + M H`` with ``A = a0 + a1 c1 + a2 c2 + a3 c12``,
  ``B = b0 + b1 c1 + b2 c2 + b3 c12``, ``C = c0 + c2 c2 + c3 c12``
  (c1 = cos th1, c2 = cos th2, c12 = cos(th1 + th2), M = m0 + m1 + m2), which the planner,
  controller and plant integrate. ``model="derived"`` is our own derivation (verified against
  ``momentum`` symbolically in the tests); ``model="paper"`` is the appendix of Franch et al.
  (IROS 2003) exactly as printed, typos included, so the paper's numbers can be reproduced.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core._jit import Real, jitable
from flatcli.core.errors import FlatcliError
from flatcli.core.names import MODELS, Model
from flatcli.core.robots.chain import barycentric_matrix, inertia_scale

#: Tolerance below which a design quantity counts as zero in the flatness check (relative).
DESIGN_ZERO_TOL = 1e-12


class Links(NamedTuple):
    """The twelve link parameters as plain floats (or broadcastable arrays), for kernels.

    m0..m2 [kg], i0..i2 [kg m^2] about each link's centre of mass, l0..l2 [m], d0..d2 [m].
    """

    m0: float
    m1: float
    m2: float
    i0: float
    i1: float
    i2: float
    l0: float
    l1: float
    l2: float
    d0: float
    d1: float
    d2: float


class Coefficients(NamedTuple):
    """Coefficients of the reduced momentum constraint (see the module docstring).

    ``c2`` is the coefficient of cos th2 in C (c2' elsewhere, to tell it from cos th2). All in
    [kg^2 m^2]. With d2 = 0 only a0, a1, b0, b1, c0 are non-zero.
    """

    a0: float
    a1: float
    a2: float
    a3: float
    b0: float
    b1: float
    b2: float
    b3: float
    c0: float
    c2: float
    c3: float


Triple = tuple[float, float, float]
#: Per-link values of a chain of N + 1 bodies (base + N links), N >= 2.
PerLink = tuple[float, ...]


def _per_link(name: str, value: ArrayLike) -> PerLink:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise FlatcliError(
            f"{name}: expected one number per link (base + N links, N >= 2), got {value!r}"
        ) from None
    if arr.ndim != 1 or arr.shape[0] < 3:
        raise FlatcliError(
            f"{name}: expected one number per link (base + N links, N >= 2), got shape "
            f"{arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise FlatcliError(f"{name}: every value must be finite, got {arr.tolist()}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class RobotParams:
    """Validated, immutable parameters of the links: the base (link 0) and N >= 2 links.

    Attributes
    ----------
    mass : (N + 1,) [kg], each > 0
    inertia : (N + 1,) [kg m^2] about each link's centre of mass, each > 0
    length : (N + 1,) [m] joint-to-joint, each > 0 (the last length does not enter the
        dynamics)
    com : (N + 1,) [m] d_i, distance of each link's centre of mass from its proximal joint O_i
        along the link
    com_across : [m] e_N, how far the last link's centre of mass lies across the link
        (perpendicular to it, towards increasing th_N); 0 for every robot of the paper.
        Only the last link's: its centre of mass at (d_N, e_N) in the link's frame is at
        distance rho = hypot(d_N, e_N) along a line turned by alpha = atan2(e_N, d_N), and
        l_N does not enter the dynamics, so the robot is exactly the one with d_N = rho and
        e_N = 0 whose joint N reads th_N + alpha (``placement``); an inner link's offset
        would couple its neighbours through sin terms no model here has

    The paper's robot has N = 2 (three links); ``links`` and ``coefficients`` (its reduced
    constraint) exist for N = 2 only, the chain functions (``chain``) for any N.
    """

    mass: PerLink = (1.0, 1.0, 1.0)
    inertia: PerLink = (0.0533, 0.0533, 0.0533)
    length: PerLink = (0.2, 0.2, 0.2)
    com: PerLink = (0.1, 0.1, 0.0)
    com_across: float = 0.0

    def __post_init__(self) -> None:
        for name in ("mass", "inertia", "length", "com"):
            object.__setattr__(self, name, _per_link(name, getattr(self, name)))
        across = float(self.com_across)
        if not math.isfinite(across):
            raise FlatcliError(f"com_across: must be finite, got {self.com_across!r}")
        object.__setattr__(self, "com_across", across)
        for name in ("inertia", "length", "com"):
            size = len(getattr(self, name))
            if size != len(self.mass):
                raise FlatcliError(
                    f"{name}: expected {len(self.mass)} numbers, one per link as in mass "
                    f"(the same number of links in each), got {size}"
                )
        for name in ("mass", "inertia", "length"):
            values = getattr(self, name)
            if min(values) <= 0:
                raise FlatcliError(f"{name}: every value must be > 0, got {list(values)}")

    @property
    def n_joints(self) -> int:
        """N, the number of joints (links after the base)."""
        return len(self.mass) - 1

    @property
    def links(self) -> Links:
        """The twelve parameters of the paper's three-link robot (N = 2 only)."""
        if self.n_joints != 2:
            raise FlatcliError(f"this needs the three-link robot (N = 2), got N = {self.n_joints}")
        return Links(*self.mass, *self.inertia, *self.length, *self.com)

    @property
    def total_mass(self) -> float:
        """M = m0 + m1 + ... + mN [kg]."""
        return float(sum(self.mass))

    @property
    def placement(self) -> tuple[RobotParams, float]:
        """The robot with the last link's centre of mass on its axis that moves exactly as
        this one, and the angle alpha [rad] its joint N is turned by: d_N = hypot(d_N, e_N),
        alpha = atan2(e_N, d_N) (the robot itself and 0 when e_N = 0). H, h_j, M(q) of this
        robot at th are those of the equivalent at th + alpha e_N (``com_across``)."""
        if self.com_across == 0.0:
            return self, 0.0
        d, e = self.com[-1], self.com_across
        equivalent = replace(self, com=(*self.com[:-1], math.hypot(d, e)), com_across=0.0)
        return equivalent, math.atan2(e, d)

    def with_(self, **changes: ArrayLike) -> RobotParams:
        """A copy with some fields replaced (validated again)."""
        return replace(self, **changes)  # type: ignore[arg-type]

    def as_array(self) -> NDArray[np.float64]:
        """(4 (N + 1),) mass, inertia, length, com concatenated ((12,) for N = 2)."""
        return np.asarray([*self.mass, *self.inertia, *self.length, *self.com], dtype=float)

    def coefficients(self, model: Model = "derived") -> Coefficients:
        """``constraint_coefficients`` of this robot (computed once per robot and model)."""
        return _robot_coefficients(self, model)


def placed(robot: RobotParams, theta: ArrayLike) -> tuple[RobotParams, NDArray[np.float64]]:
    """The robot's equivalent placement (``RobotParams.placement``) and the angles theta
    (..., N + 1) [rad] at which it moves as ``robot`` does at theta (th_N + alpha): what every
    function of a robot's angles that knows only d_N takes."""
    equivalent, offset = robot.placement
    angles = np.array(theta, dtype=np.result_type(np.asarray(theta), float))
    if offset != 0.0:
        angles[..., -1] += offset
    return equivalent, angles


@functools.lru_cache(maxsize=256)
def _robot_coefficients(robot: RobotParams, model: Model) -> Coefficients:
    return constraint_coefficients(robot.links, model)


#: The robot of the paper's example (Section VI): m_i = 1, l_i = 0.2, I_i = 0.0533,
#: d0 = d1 = l/2, d2 = 0 (link 2 counterweighted onto joint 2).
PAPER_ROBOT = RobotParams()


def constraint_coefficients(links: Links, model: Model = "derived") -> Coefficients:
    """Coefficients of the reduced constraint for general d2.

    Parameters
    ----------
    links : Links of floats or of arrays of a common shape (...)
    model : "derived" (correct) or "paper" (the appendix as printed; its a4 term, which
        multiplies the position of the system centre of mass, is taken with that centre at
        the origin, where it vanishes)

    Returns
    -------
    Coefficients of floats or arrays (...) [kg^2 m^2]
    """
    m0, m1, m2, I0, I1, I2, l0, l1, _l2, d0, d1, d2 = links
    M = m0 + m1 + m2
    e0 = l0 - d0
    e1 = l1 - d1
    arm = m2 * l1 + m1 * d1
    if model == "derived":
        common = m1 * m2 * e1**2 + m0 * (m2 * l1**2 + m1 * d1**2) + m2 * d2**2 * (m0 + m1)
        k2 = m2 * d2 * (m0 * l1 + m1 * e1)
        k3 = m0 * m2 * d2 * e0
        return Coefficients(
            a0=M * (I0 + I1 + I2) + m0 * (m1 + m2) * e0**2 + common,
            a1=2 * m0 * e0 * arm,
            a2=2 * k2,
            a3=2 * k3,
            b0=-(M * (I1 + I2) + common),
            b1=-m0 * e0 * arm,
            b2=-2 * k2,
            b3=-k3,
            c0=-(M * I2 + m2 * d2**2 * (m0 + m1)),
            c2=-k2,
            c3=-k3,
        )
    if model == "paper":
        return Coefficients(
            a0=m1 * m2 * e1**2
            + m0 * e0**2 * (m1 + m2)
            + m2 * d2**2 * M
            + (I0 + I1 + I2) * M
            + m0 * (m2 * l1**2 + m1 * d1**2),
            a1=2 * m0 * e0 * arm + m2 * l1 * d2 * M,
            a2=m1 * m2 * d2 * e1 + m0 * m2 * l1 * d2 + m2 * l1 * d2 * M,
            a3=m0 * m2 * d2 * e0 + m2 * l0 * d2 * M,
            b0=-(
                m1 * m2 * e1**2
                + (I1 + I2) * M
                + m0 * (m2 * l1**2 + m1 * d1**2)
                + m2 * d2**2 * (m0 + m1)
            ),
            b1=-(m0 * e0 * arm - m0 * m2 * d0 * l1),
            b2=-(2 * m1 * m2 * d2 * e1 + 2 * m0 * m2 * l1 * d2),
            b3=-(m0 * m2 * d2 * e0),
            c0=-(m2 * d2**2 * (m0 + m1) + I2 * M),
            c2=-(m1 * m2 * d2 * e1 + m0 * m2 * l1 * d2),
            c3=-(m0 * m2 * d2 * e0),
        )
    raise FlatcliError(f"robot.model: expected one of {list(MODELS)}, got {model!r}")


@jitable
def base_rate(
    k: Coefficients, total_mass: float, h0: Real, th1: Real, th2: Real, th1_dot: Real,
    th2_dot: Real,
) -> Real:
    """th0' that the reduced constraint imposes.

    Parameters
    ----------
    k : Coefficients
    total_mass : M [kg]
    h0 : angular momentum about the system centre of mass [kg m^2/s]
    th1, th2 : joint angles [rad], floats or arrays (...)
    th1_dot, th2_dot : joint rates [rad/s], (...)

    Returns
    -------
    th0_dot : (...) [rad/s]
    """
    return base_rate_at(k, total_mass, h0, np.cos(th1), np.cos(th2), np.cos(th1 + th2),
                        th1_dot, th2_dot)


@jitable
def base_rate_at(
    k: Coefficients, total_mass: float, h0: Real, c1: Real, c2: Real, c12: Real,
    th1_dot: Real, th2_dot: Real,
) -> Real:
    """``base_rate`` given c1 = cos th1, c2 = cos th2 and c12 = cos(th1 + th2).

    For a plant with d2 = 0 (a2 = a3 = b2 = b3 = c2 = c3 = 0) any c2 and c12, 0 included,
    give the same result to the bit: kernels then skip those two cosines.
    """
    A = k.a0 + k.a1 * c1 + k.a2 * c2 + k.a3 * c12
    B = k.b0 + k.b1 * c1 + k.b2 * c2 + k.b3 * c12
    C = k.c0 + k.c2 * c2 + k.c3 * c12
    return (B * th1_dot + C * th2_dot + total_mass * h0) / A


@jitable
def momentum(
    p: Links, th0: Real, th1: Real, th2: Real, th0_dot: Real, th1_dot: Real, th2_dot: Real
) -> Real:
    """Total angular momentum about the fixed system centre of mass, from the link kinematics.

    Every link's centre of mass is placed and moved along the joint chain from O0; taking
    positions and velocities relative to the system centre of mass (which is where the
    free-floating base puts it, so O0 never needs to be known) gives
    H = sum_i I_i w_i + sum_i m_i r_i x v_i - M r_c x v_c, with w_i the absolute angular rates.
    Vectors are written in the base's frame: planar cross products do not change under a
    rotation, so th0 itself drops out (the tests check this against an inertial-frame
    derivation). Nothing here uses the reduced constraint.

    Parameters
    ----------
    p : Links
    th0, th1, th2 : relative angles [rad], floats or arrays (...); th0 does not enter
    th0_dot, th1_dot, th2_dot : their rates [rad/s], (...)

    Returns
    -------
    H : (...) [kg m^2/s]
    """
    c1, s1 = np.cos(th1), np.sin(th1)
    c12, s12 = np.cos(th1 + th2), np.sin(th1 + th2)
    return momentum_at(p, c1, s1, c12, s12, th0_dot, th1_dot, th2_dot)


@jitable
def momentum_at(
    p: Links,
    c1: Real,
    s1: Real,
    c12: Real,
    s12: Real,
    th0_dot: Real,
    th1_dot: Real,
    th2_dot: Real,
) -> Real:
    """``momentum`` given cos and sin of th1 and of th1 + th2."""
    w0 = th0_dot
    w1 = w0 + th1_dot
    w2 = w1 + th2_dot
    # positions (x, y) and velocities (vx, vy) of each centre of mass, relative to O0
    x0, y0, vx0, vy0 = p.d0, 0.0, 0.0, w0 * p.d0
    x1 = p.l0 + p.d1 * c1
    y1 = p.d1 * s1
    vx1 = -w1 * p.d1 * s1
    vy1 = w0 * p.l0 + w1 * p.d1 * c1
    x2 = p.l0 + p.l1 * c1 + p.d2 * c12
    y2 = p.l1 * s1 + p.d2 * s12
    vx2 = -w1 * p.l1 * s1 - w2 * p.d2 * s12
    vy2 = w0 * p.l0 + w1 * p.l1 * c1 + w2 * p.d2 * c12
    M = p.m0 + p.m1 + p.m2
    mx = p.m0 * x0 + p.m1 * x1 + p.m2 * x2
    my = p.m0 * y0 + p.m1 * y1 + p.m2 * y2
    mvx = p.m0 * vx0 + p.m1 * vx1 + p.m2 * vx2
    mvy = p.m0 * vy0 + p.m1 * vy1 + p.m2 * vy2
    h = p.i0 * w0 + p.i1 * w1 + p.i2 * w2
    h = h + p.m0 * (x0 * vy0 - y0 * vx0)
    h = h + p.m1 * (x1 * vy1 - y1 * vx1)
    h = h + p.m2 * (x2 * vy2 - y2 * vx2)
    return h - (mx * mvy - my * mvx) / M


@dataclass(frozen=True)
class FlatnessCheck:
    """Outcome of the design check: which conditions for the closed-form flat outputs fail.

    ``failures`` lists every failing condition as one line (none of them says whether the
    robot is controllable); ``controllable`` is False when every coupling K_ab (a != b) of
    ``chain.barycentric_matrix`` vanishes (relative to ``chain.inertia_scale``): then every
    h_j is constant, the constraint integrates and the robot is not controllable, hence not
    flat. Otherwise it is controllable and, driftless of codimension one, flat: K diagonal is
    exactly when w ^ dw = 0 (``design``, which decides it from the link kinematics), so a
    robot that fails only d_N = 0 or K_10 != 0 is flat with outputs not known in closed form.
    """

    failures: tuple[str, ...]
    controllable: bool = True
    #: N >= 3 only: K_10 = 0, which flatcli's planner cannot use (it normalises by K_10)
    unsupported: bool = False

    @property
    def is_flat(self) -> bool:
        """The closed-form flat outputs apply (y1 = th1, y2 = th0 - c0 th2 / A for N = 2)."""
        return not self.failures

    def message(self) -> str:
        """One line for a user; empty when the design is flat."""
        return "; ".join(self.failures)


def flatness_check(params: RobotParams) -> FlatnessCheck:
    """Do the paper's flat outputs (and their n-link generalisation, ``chainflat``) apply?

    The conditions (Franch et al. 2003, Sec. V, with "!=" where the extracted text has "="):
    d2 = 0 (link 2's centre of mass on joint 2), and c0 a1 != 0, i.e. I2 != 0, m0 != 0,
    l0 != d0 and m1 d1 + m2 l1 != 0, since det[g1, g2, [g1, g2]] = c0 a1 sin th1 / A^2.
    For N links: d_N = 0, I_N != 0, and the base's locked inertia h_0(q) not constant (the
    outputs are flat where dh_0/dt != 0, ``chainflat``). flatcli's N-link planner scales the
    margin by K_10 = m0 (l0 - d0)(m1 d1 + (m2 + ... + mN) l1) / M and needs K_10 != 0 (for
    N = 2, a1 = 2 M K_10). K_10 and the other couplings count as zero when
    |K_ab| <= DESIGN_ZERO_TOL J, J = ``chain.inertia_scale`` (the robot's own scale; d_N
    relative to the longest link). A design failing a condition may still be controllable
    (``FlatnessCheck``): for N >= 3, K_10 = 0 is reported ``unsupported``. I_N > 0 and
    m0 > 0 hold for every valid RobotParams, so only the others can fail here.
    """
    n = params.n_joints
    mass, length, com = params.mass, params.length, params.com
    l0, l1 = length[0], length[1]
    d0, d1, d_last = com[0], com[1], com[n]
    arm = mass[1] * d1 + sum(mass[2:]) * l1
    equivalent = params.placement[0]
    arrays = [np.asarray(v, dtype=float) for v in (mass, params.inertia, length, equivalent.com)]
    K = barycentric_matrix(arrays[0], arrays[2], arrays[3])
    scale = inertia_scale(*arrays)
    zero = DESIGN_ZERO_TOL * scale
    controllable = bool(np.max(np.abs(K - np.diag(np.diag(K)))) > zero)
    zero_k10 = abs(K[1, 0]) <= zero
    failures = []
    if abs(d_last) > DESIGN_ZERO_TOL * max(length):
        outputs = ("y1 = th1, y2 = th0 - c0 th2/(a0 + a1 cos th1)" if n == 2 else
                   f"y_j = th_j (j < {n}), y{n} = th0 + I{n} th{n} / h_0")
        failures.append(
            f"com[{n}] = d{n} = {d_last:g} m, not 0: link {n}'s centre of mass is off joint {n}, "
            f"and the closed-form flat outputs {outputs} need it on the joint (d{n} = 0)"
        )
    if abs(params.com_across) > DESIGN_ZERO_TOL * max(length):
        failures.append(
            f"com_across = e{n} = {params.com_across:g} m, not 0: link {n}'s centre of mass "
            f"lies across the link, off joint {n}, and the closed-form flat outputs need it on "
            "the joint"
        )
    # K_10 = 0 is decided relative to J; name the factors that vanish (each to its own scale)
    zero_offset = zero_k10 and abs(l0 - d0) <= DESIGN_ZERO_TOL * max(length)
    zero_arm = zero_k10 and abs(arm) <= DESIGN_ZERO_TOL * max(mass) * max(length)
    if n > 2 and zero_k10:
        why = ("l0 = d0" if zero_offset else f"m1 d1 + (m2 + ... + m{n}) l1 = 0" if zero_arm
               else f"|K_10| / J = {abs(K[1, 0]) / scale:.3g}")
        failures.append(
            f"{why} makes K_10 = m0 (l0 - d0)(m1 d1 + (m2 + ... + m{n}) l1) / M = 0: h_0 loses "
            f"its cos(th1) term, and flatcli's {n}-link planner, which scales the singularity "
            "margin by K_10, cannot plan for it"
        )
        return FlatnessCheck(tuple(failures), controllable, unsupported=True)
    need = ("and the paper's outputs need c0 a1 != 0 (with d2 = 0, det[g1, g2, [g1, g2]] = "
            "c0 a1 sin th1 / A^2)")
    if zero_offset:
        failures.append(f"length[0] = com[0] = {l0:g} m: l0 - d0 = 0 makes a1 = 2 M K_10 = 0, "
                        + need)
    if zero_arm:
        failures.append("m1 d1 + m2 l1 = 0 makes a1 = 2 M K_10 = 0, " + need)
    if zero_k10 and not (zero_offset or zero_arm):
        failures.append(f"|K_10| / J = {abs(K[1, 0]) / scale:.3g} makes "
                        "a1 = 2 M K_10 = 0, " + need)
    return FlatnessCheck(tuple(failures), controllable)


@functools.lru_cache(maxsize=256)
def _flatness_verdict(params: RobotParams) -> FlatnessCheck:
    """``flatness_check``, remembered: both are immutable, and a task's search plans many
    candidates for one robot."""
    return flatness_check(params)


def require_flat(params: RobotParams) -> None:
    """Raise FlatcliError naming the failing condition if the closed-form flat outputs do not
    apply to the design (flatcli plans with them only)."""
    check = _flatness_verdict(params)
    if not check.is_flat:
        what, tail = (
            ("robot is not differentially flat", "every h_j is constant: the momentum "
             "constraint integrates") if not check.controllable
            else ("flatcli cannot plan for this design", "the robot is still controllable, "
                  "hence flat, but not with the closed-form outputs") if check.unsupported
            else ("the paper's flat outputs do not apply", "the robot is still controllable, "
                  "hence flat, with outputs not known in closed form"))
        raise FlatcliError(f"{what}: {check.message()}; {tail}")
