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
link's frame; where it meets the ray, those two points are its farthest and nearest points on
it (one point if it crosses the ray). A segment that misses the ray admits no exact placement
and is refused. The counterweighted link then has mass m + m_c, inertia
I + m |r|^2 + I_c + m_c |p|^2 about the joint, and d_N = e_N = 0 (``apply``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from flatcli.core.errors import FlatcliError
from flatcli.core.robots.params import RobotParams

#: Relative tolerance of "on the ray" (a segment collinear with it within it).
COLLINEAR_RTOL = 1e-12


@dataclass(frozen=True)
class Counterweight:
    """One counterweight: its mass [kg] and position (x along, y across the link from joint
    N) [m], and the counterweighted link's mass [kg] and inertia about the joint [kg m^2]."""

    mass: float
    x: float
    y: float
    link_mass: float
    link_inertia: float

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
    distances = _on_ray(ends, direction, reach)
    if distances is None:
        raise FlatcliError(
            f"--positions: no allowed position lies on the ray from joint N opposite the link's "
            f"centre of mass (direction ({direction[0] + 0.0:.4g}, {direction[1] + 0.0:.4g})): no "
            "counterweight there puts the centre on the joint")
    far, near = max(distances), min(distances)
    return (_placed(mass, inertia, reach, direction, far, own_inertia),
            _placed(mass, inertia, reach, direction, near, own_inertia))


def _on_ray(ends: np.ndarray, direction: np.ndarray, scale: float
            ) -> tuple[float, ...] | None:
    """The distances t >= 0 from the joint at which the segment meets the ray t direction
    (the two ends of the overlap if the segment lies along it), or None."""
    a, b = ends
    normal = np.array([-direction[1], direction[0]])
    size = max(float(np.abs(ends).max()), scale)
    ha, hb = float(normal @ a), float(normal @ b)  # signed distances from the ray's line
    ta, tb = float(direction @ a), float(direction @ b)  # positions along it
    if abs(ha) <= COLLINEAR_RTOL * size and abs(hb) <= COLLINEAR_RTOL * size:
        lo, hi = max(min(ta, tb), 0.0), max(ta, tb)
        return (lo, hi) if hi > 0 else None
    if ha * hb > 0:
        return None
    t = ta + (tb - ta) * ha / (ha - hb)
    return (t,) if t > 0 else None


def _placed(mass: float, inertia: float, reach: float, direction: np.ndarray,
            distance: float, own_inertia: float) -> Counterweight:
    if not distance > 0:
        raise FlatcliError("--positions: the allowed positions on the ray include the joint "
                           "itself, where no finite counterweight balances the link")
    weight = mass * reach / distance
    link_inertia = inertia + mass * reach**2 + own_inertia + weight * distance**2
    x, y = (float(v) for v in direction * distance)
    return Counterweight(weight, x, y, mass + weight, link_inertia)


def apply(robot: RobotParams, counterweight: Counterweight) -> RobotParams:
    """``robot`` with its last link counterweighted: mass and inertia of ``counterweight``,
    d_N = e_N = 0."""
    n = robot.n_joints
    mass = (*robot.mass[:n], counterweight.link_mass)
    inertia = (*robot.inertia[:n], counterweight.link_inertia)
    com = (*robot.com[:n], 0.0)
    return RobotParams(mass, inertia, robot.length, com, 0.0)


__all__ = ["Counterweight", "apply", "design_counterweight"]
