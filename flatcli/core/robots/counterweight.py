"""A counterweight for the last link: the mass and place that put its centre of mass on its
joint (d_N = e_N = 0, the paper's design condition).

The bare link has mass m [kg], inertia I [kg m^2] about its own centre of mass, and that
centre at r = (d, e) [m] in the link's frame (x along the link from joint N, y across it).
A counterweight of mass m_c (inertia I_c about its own centre) at p moves the link's centre
of mass to (m r + m_c p) / (m + m_c), which is the joint exactly when

    m_c p = -m r:   p on the ray from the joint opposite r,  m_c = m |r| / |p|.

So along that ray the farther the counterweight sits, the less mass it needs (least added
mass: the farthest allowed point), and the added inertia about the joint,
I_c + m_c |p|^2 = I_c + m |r| |p|, grows with |p| (least added inertia: the nearest allowed
point; the link's own m |r|^2 is there in both). The allowed positions are a segment in the
link's frame; the points of it within ``POSITION_RTOL`` of the ray (relative to the larger of
|r| and the segment's farthest coordinate: 10 um on a 0.1 m link, well inside a machined
part's tolerance) count as on it, and the
farthest and nearest of them are the two answers, placed where the segment has them, with
m_c = m |r| / t for their distance t along the ray. Where the segment lies along the ray those
are its ends on the ray; where it crosses the ray at an angle, the ends of its short piece
within the band. So the answers change continuously with the segment, whatever the rounding
of its ends: a segment 1e-7 m off a 0.1 m ray gives the same counterweights as one on it (to
1e-7 m), where an exact "on the ray" test took a segment along the ray as crossing it at one
end (0.34 -> 0.53 kg). A counterweight off the ray by h <= the band leaves the link's centre
of mass m_c h / (m + m_c) across the joint (``Counterweight.residual``, reported); a segment
that misses the band is refused. The counterweighted link then has mass m + m_c, inertia
I + m |r|^2 + I_c + m_c |p|^2 about the joint, and d_N = e_N = 0 (``apply``: the design, to
that residual).

A counterweight placed anywhere else (``attach``: a design search tries such placements)
leaves the link's centre of mass at c = (m r + m_c p) / (m + m_c), and the link's inertia about
that centre is, by the parallel-axis theorem, I + m |r - c|^2 + I_c + m_c |p - c|^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from flatcli.core.errors import FlatcliError
from flatcli.core.robots.params import RobotParams

#: How far from the ray an allowed position may be and still count as on it, relative to the
#: larger of |r| and the segment's farthest coordinate (module docstring).
POSITION_RTOL = 1e-4


@dataclass(frozen=True)
class Counterweight:
    """One counterweight: its mass [kg] and position (x along, y across the link from joint
    N) [m], and the counterweighted link's mass [kg] and inertia about the joint [kg m^2]."""

    mass: float
    x: float
    y: float
    link_mass: float
    link_inertia: float
    residual: float = 0.0  # the link's centre of mass from joint N with it [m]

    @property
    def distance(self) -> float:
        """|p| [m]: the counterweight's distance from the joint."""
        return math.hypot(self.x, self.y)


def design_counterweight(mass: float, inertia: float, along: float, across: float,
                         segment: ArrayLike, own_inertia: float = 0.0
                         ) -> tuple[Counterweight, Counterweight]:
    """The least-mass and the least-inertia counterweight (module docstring).

    Parameters
    ----------
    mass, inertia : the bare link's mass [kg] (> 0) and inertia about its centre [kg m^2]
        (> 0)
    along, across : its centre of mass (d, e) from joint N [m]
    segment : (2, 2) the allowed positions' ends (x1, y1), (x2, y2) in the link's frame [m]
    own_inertia : the counterweight's inertia about its own centre [kg m^2] (>= 0)

    Returns
    -------
    (least mass, least inertia) : Counterweight, the same one when the segment meets the ray
    at one point

    Raises
    ------
    FlatcliError if an input is out of range, the link's centre is already on the joint, or
    no allowed position lies on the ray opposite it.
    """
    ends = np.asarray(segment, dtype=float)
    if ends.shape != (2, 2) or not np.all(np.isfinite(ends)):
        raise FlatcliError("--positions: expected two finite points x1 y1 x2 y2 [m]")
    if not (mass > 0 and inertia > 0 and math.isfinite(mass) and math.isfinite(inertia)):
        raise FlatcliError(f"robot.mass, robot.inertia of the last link: must be > 0, got "
                           f"{mass}, {inertia}")
    if not (own_inertia >= 0 and math.isfinite(own_inertia)):
        raise FlatcliError(f"--counterweight-inertia: must be >= 0 kg m^2, got {own_inertia}")
    reach = math.hypot(along, across)
    if reach == 0.0:
        raise FlatcliError("robot.com: the last link's centre of mass is on its joint already "
                           "(d_N = e_N = 0): it needs no counterweight")
    direction = -np.array([along, across]) / reach  # the ray opposite the link's centre
    band = POSITION_RTOL * max(float(np.abs(ends).max()), reach)
    found = _on_ray(ends, direction, band)
    if found is None:
        raise FlatcliError(
            f"--positions: no allowed position lies on the ray from joint N opposite the link's "
            f"centre of mass (direction ({direction[0] + 0.0:.4g}, {direction[1] + 0.0:.4g}), "
            f"within {band:.3g} m of it): no counterweight there puts the centre on the joint")
    far, near = found
    return (_placed(mass, inertia, reach, direction, far, own_inertia),
            _placed(mass, inertia, reach, direction, near, own_inertia))


def _on_ray(ends: np.ndarray, direction: np.ndarray, band: float
            ) -> tuple[np.ndarray, np.ndarray] | None:
    """The farthest and the nearest point (2,) [m] along the ray of the segment's points
    within ``band`` [m] of the ray (ahead of the joint: t >= 0), or None."""
    a, b = ends
    normal = np.array([-direction[1], direction[0]])
    ha, hb = float(normal @ a), float(normal @ b)  # signed distances from the ray's line
    ta, tb = float(direction @ a), float(direction @ b)  # positions along it
    lo, hi = 0.0, 1.0  # the part u of the segment a + u (b - a) in the band
    if ha == hb:
        if abs(ha) > band:
            return None
    else:
        u1, u2 = sorted(((-band - ha) / (hb - ha), (band - ha) / (hb - ha)))
        lo, hi = max(lo, u1), min(hi, u2)
    if ta != tb:  # ahead of the joint: t(u) >= 0
        cross = -ta / (tb - ta)
        lo, hi = (max(lo, cross), hi) if tb > ta else (lo, min(hi, cross))
    elif ta < 0:
        return None
    if lo > hi:
        return None
    ends_in = [a + u * (b - a) for u in (lo, hi)]
    far, near = sorted(ends_in, key=lambda p: float(direction @ p), reverse=True)
    return far, near


def _placed(mass: float, inertia: float, reach: float, direction: np.ndarray,
            point: np.ndarray, own_inertia: float) -> Counterweight:
    distance = float(direction @ point)  # along the ray
    if not distance > 0:
        raise FlatcliError("--positions: the allowed positions on the ray include the joint "
                           "itself, where no finite counterweight balances the link")
    weight = mass * reach / distance
    x, y = (float(v) for v in point)
    link_inertia = inertia + mass * reach**2 + own_inertia + weight * (x * x + y * y)
    centre = (-direction * reach * mass + weight * point) / (mass + weight)
    return Counterweight(weight, x, y, mass + weight, link_inertia,
                         float(np.hypot(*centre)))


def apply(robot: RobotParams, counterweight: Counterweight) -> RobotParams:
    """``robot`` with its last link counterweighted: mass and inertia of ``counterweight``,
    d_N = e_N = 0."""
    n = robot.n_joints
    mass = (*robot.mass[:n], counterweight.link_mass)
    inertia = (*robot.inertia[:n], counterweight.link_inertia)
    com = (*robot.com[:n], 0.0)
    return RobotParams(mass, inertia, robot.length, com, 0.0)


def attach(robot: RobotParams, mass: float, x: float, y: float, own_inertia: float = 0.0
           ) -> RobotParams:
    """``robot`` whose last link (read as the bare link) carries a counterweight anywhere.

    Parameters
    ----------
    robot : the robot with its bare last link: mass m [kg], inertia I about its own centre
        [kg m^2], that centre at r = (d_N, e_N) (``com[N]``, ``com_across``) [m]
    mass : m_c, the counterweight's mass [kg] (>= 0; 0: the bare link)
    x, y : p, its centre in the link's frame (x along the link from joint N, y across) [m]
    own_inertia : I_c, its inertia about its own centre [kg m^2] (>= 0)

    Returns
    -------
    RobotParams whose last link has mass m + m_c, its centre c = (m r + m_c p) / (m + m_c)
    (``com[N]`` = c_x, ``com_across`` = c_y) and inertia I + m |r - c|^2 + I_c + m_c |p - c|^2
    about c (the module docstring); exactly ``apply`` of the designer's counterweight when p
    balances the link (there c = 0 to rounding)

    Raises
    ------
    FlatcliError if a value is negative or not finite.
    """
    values = (mass, x, y, own_inertia)
    if not all(math.isfinite(v) for v in values) or mass < 0 or own_inertia < 0:
        raise FlatcliError(f"counterweight: mass and own inertia must be >= 0 and every value "
                           f"finite, got mass {mass:g} kg at ({x:g}, {y:g}) m, own inertia "
                           f"{own_inertia:g} kg m^2")
    n = robot.n_joints
    m, inertia = robot.mass[n], robot.inertia[n]
    r = np.array([robot.com[n], robot.com_across])
    p = np.array([x, y])
    total = m + mass
    centre = (m * r + mass * p) / total
    link_inertia = (inertia + m * float((r - centre) @ (r - centre)) + own_inertia
                    + mass * float((p - centre) @ (p - centre)))
    return RobotParams((*robot.mass[:n], total), (*robot.inertia[:n], link_inertia),
                       robot.length, (*robot.com[:n], float(centre[0])), float(centre[1]))


__all__ = ["Counterweight", "apply", "attach", "design_counterweight"]
