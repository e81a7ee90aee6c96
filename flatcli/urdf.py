"""Robots from and to URDF (the Unified Robot Description Format of ROS, read and written by
``urdf_parser_py``, ROS's own Python parser).

**Reading** (``read_urdf``; ``robot = "arm.urdf"`` in a spec, ``--robot arm.urdf``): as SPART
does, the URDF describes the chain and its *root link is the free base* (no floating joint).
The robot must be a serial chain of N >= 2 revolute (or continuous) joints whose axes are
parallel; fixed joints join rigid parts to the link they hang from (their masses and
inertias are merged). Every other shape is refused in one line naming the joint or link and
why: a prismatic, planar or floating joint, two moving joints on one link (a branch), axes
that are not parallel, a moving link without mass.

The plane is the one normal to the axes, n = joint 1's axis at the URDF's zero pose, and
flatcli's quantities are read in it, at that pose (``parts_of`` merges each link with what is
fixed to it, ``planar_robot`` measures):

* link k's axis runs from joint k to joint k + 1 (the base's from its centre of mass to
  joint 1, the last link's from joint N to its *tip*, the one massless link fixed to it:
  the end effector); ``length`` l_k is that distance;
* ``mass`` m_k: the link's mass with everything fixed to it;
* ``inertia`` I_k: about the axis n through the link's centre of mass,
  I = sum_i (n^T R_i I_i R_i^T n + m_i rho_i^2) over its parts i (inertia tensor I_i in the
  URDF's inertial frame, turned into the root frame by R_i; rho_i the distance, in the
  plane, of part i's centre of mass from the link's: the parallel-axis theorem);
* ``com`` d_k: the centre of mass's distance from joint k along the axis, and for the last
  link ``com_across`` e_N across it (towards increasing th_N). An inner link whose centre
  of mass lies off its axis is refused (flatcli's model has no such offset: see
  ``RobotParams``); the base's axis passes through its centre of mass by construction, and
  its proximal end O_0 is where the root frame's origin projects onto it (the base's centre
  of mass when that would fall beyond joint 1).

flatcli's angles are measured between these axes, counter-clockwise about n. A URDF joint
value q_k gives th_k = offset_k + sign_k q_k, sign_k = +1 when the joint's axis is n, -1
when it is -n; ``UrdfRobot.angle_offset`` are the offsets (zero for a chain that is straight
at its zero pose with every link's frame along it, as ``urdf_text`` writes it). Only the
planar motion is modelled (a robot on an air-bearing table, as the paper's): offsets along
n and the inertia tensor's other components do not enter.

**Writing** (``urdf_text``; ``flatcli export-robot SPEC --urdf``): a chain in the x-y plane,
axes +z, link k's frame at joint k with x along its axis, its centre of mass at (d_k, e_k, 0),
izz = I_k (ixx = iyy = I_k as well, a physical tensor; they do not enter), continuous joints,
and a massless ``tip`` link fixed at (l_N, 0, 0). Reading it back gives the same robot to
rounding (tests: 1e-12).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]

#: Joint types that are flatcli's joints, and the one that joins rigid parts.
REVOLUTE = ("revolute", "continuous")
FIXED = "fixed"
#: Axes count as parallel when the sine of their angle is below this.
PARALLEL_TOL = 1e-9
#: An inner link's centre of mass counts as on its axis when it lies less than this far
#: across it, relative to the link's size (its length, or the centre's distance from joint k).
ACROSS_TOL = 1e-9
#: A distance in the plane below this [m] counts as zero (coincident joints).
ZERO_LENGTH = 1e-12
#: The largest URDF file read [bytes] (a robot of hundreds of links is far smaller).
MAX_URDF_BYTES = 4 * 1024 * 1024


@dataclass(frozen=True)
class UrdfRobot:
    """A robot read from a URDF file.

    Attributes
    ----------
    robot : RobotParams, the robot flatcli plans and tracks
    name : the URDF's robot name
    links : (N + 1,) the URDF link each of flatcli's links starts with (the root first)
    joints : (N,) the revolute joints 1..N
    tip : the end effector's link (fixed to the last link)
    angle_offset : (N,) th_k at the URDF's zero pose [rad], in (-pi, pi]
    axis_sign : (N,) +1 where joint k turns counter-clockwise about n, -1 where clockwise
    """

    robot: RobotParams
    name: str
    links: tuple[str, ...]
    joints: tuple[str, ...]
    tip: str
    angle_offset: tuple[float, ...]
    axis_sign: tuple[int, ...]

    def spec_keys(self) -> dict[str, Any]:
        """The ``[robot]`` keys of a spec (dotted) that give this robot."""
        r = self.robot
        return {"robot.mass": list(r.mass), "robot.inertia": list(r.inertia),
                "robot.length": list(r.length), "robot.com": list(r.com),
                "robot.com_across": r.com_across}


def rotation(rpy: Any) -> Array:
    """(3, 3) URDF's rotation of roll, pitch, yaw [rad]: Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _pose(origin: Any) -> tuple[Array, Array]:
    """(R (3, 3), p (3,)) of a URDF ``<origin>`` (identity when absent)."""
    if origin is None:
        return np.eye(3), np.zeros(3)
    xyz = np.zeros(3) if origin.xyz is None else np.asarray(origin.xyz, dtype=float)
    rpy = (0.0, 0.0, 0.0) if origin.rpy is None else origin.rpy
    return rotation(rpy), xyz


@dataclass(frozen=True)
class Part:
    """One URDF link at the zero pose, in the frame of the body it belongs to: its frame's
    origin [m], its mass [kg], centre of mass [m] and inertia tensor about it [kg m^2] (zero
    without ``<inertial>``)."""

    name: str
    origin: Array
    mass: float
    com: Array
    tensor: Array


@dataclass(frozen=True)
class Body:
    """A link of flatcli's chain: its URDF parts (the first the link its joint moves)."""

    parts: tuple[Part, ...]

    @property
    def name(self) -> str:
        return self.parts[0].name

    @property
    def mass(self) -> float:
        return sum(p.mass for p in self.parts)

    def com(self) -> Array:
        """(3,) the centre of mass [m] (mass > 0)."""
        return np.asarray(sum(p.mass * p.com for p in self.parts) / self.mass, dtype=float)

    def inertia(self, n: Array) -> float:
        """The inertia about the axis n through the centre of mass [kg m^2]: each part's
        n^T I n plus m rho^2, rho its centre's distance from the body's, across n."""
        centre = self.com()
        total = 0.0
        for p in self.parts:
            offset = p.com - centre
            across = offset - (offset @ n) * n
            total += float(n @ p.tensor @ n) + p.mass * float(across @ across)
        return total


def _number(value: Any, where: str, positive: bool = False) -> float:
    """A finite number read from the URDF (FlatcliError naming ``where`` otherwise)."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise FlatcliError(f"{where}: expected a number, got {value!r}") from None
    if not math.isfinite(out) or (positive and out <= 0):
        raise FlatcliError(f"{where}: expected a finite number{' > 0' if positive else ''}, "
                           f"got {value!r}")
    return out


def _vector(value: Any, where: str) -> Array:
    try:
        out = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise FlatcliError(f"{where}: expected three numbers, got {value!r}") from None
    if out.shape != (3,) or not np.all(np.isfinite(out)):
        raise FlatcliError(f"{where}: expected three finite numbers, got {value!r}")
    return out


def _part(link: Any, rotation_: Array, origin: Array) -> Part:
    """A URDF link at the pose (rotation_, origin) of its frame in its body's frame."""
    inertial = link.inertial
    where = f"link {link.name!r}"
    if inertial is None:
        return Part(link.name, origin, 0.0, origin, np.zeros((3, 3)))
    mass = _number(inertial.mass, f"{where}: <inertial><mass value>")
    if mass < 0:
        raise FlatcliError(f"{where}: <inertial><mass value> must be >= 0, got {mass}")
    R, p = _pose(inertial.origin)
    _vector(p, f"{where}: <inertial><origin xyz>")
    tensor = np.zeros((3, 3))
    if inertial.inertia is not None:
        i = inertial.inertia
        names = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        ixx, ixy, ixz, iyy, iyz, izz = (_number(getattr(i, k), f"{where}: <inertia {k}>")
                                        for k in names)
        tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    turn = rotation_ @ R
    return Part(link.name, origin, mass, origin + rotation_ @ p, turn @ tensor @ turn.T)


@contextlib.contextmanager
def _collected_warnings() -> Iterator[list[str]]:
    """urdf_parser_py reports unknown tags through a module-level hook that prints; collect
    them instead (and put the hook back)."""
    from urdf_parser_py.xml_reflection import core

    seen: list[str] = []
    previous = core.on_error
    core.on_error = seen.append
    try:
        yield seen
    finally:
        core.on_error = previous


def parse(text: str, source: str) -> Any:
    """The URDF ``Robot`` of urdf_parser_py from XML text; FlatcliError naming ``source`` and,
    where the parser says, the element, for text that is not a URDF."""
    from xml.etree.ElementTree import ParseError as XmlError

    from urdf_parser_py import urdf
    from urdf_parser_py.xml_reflection.core import ParseError

    with _collected_warnings():
        try:
            robot = urdf.Robot.from_xml_string(text)
        except XmlError as exc:
            raise FlatcliError(f"{source}: not well-formed XML: {exc}") from None
        except ParseError as exc:
            raise FlatcliError(f"{source}: not a valid URDF at {exc.path}: "
                               f"{_one_line(exc.e)}") from None
        except (ValueError, TypeError, KeyError, AssertionError, AttributeError) as exc:
            where = _bad_number(text) or "a required element or attribute is missing"
            raise FlatcliError(f"{source}: not a valid URDF: {where} "
                               f"({_one_line(exc)})") from None
    return robot


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _bad_number(text: str) -> str | None:
    """Where a numeric attribute of a URDF does not read as numbers (the parser's own
    message names no element): '<mass value> of link 'x''."""
    import xml.etree.ElementTree as ET

    numeric = {"mass": ("value",), "inertia": ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"),
               "origin": ("xyz", "rpy"), "axis": ("xyz",),
               "limit": ("lower", "upper", "effort", "velocity")}
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return None
    for owner in root:
        for node in owner.iter():
            for attribute in numeric.get(node.tag, ()):
                value = node.get(attribute)
                if value is None:
                    if node.tag in ("mass", "inertia"):
                        return (f"<{node.tag} {attribute}> is missing in {owner.tag} "
                                f"{owner.get('name')!r}")
                    continue
                try:
                    [float(v) for v in value.split()]
                except ValueError:
                    return (f"<{node.tag} {attribute}=\"{value}\"> of {owner.tag} "
                            f"{owner.get('name')!r} is not a number")
    return None


def chain_of(robot: Any, source: str) -> tuple[list[Any], list[list[Any]], str]:
    """The revolute joints of a URDF robot in order from the root, the links of each of
    flatcli's links (the root's first: each list starts with the link its joint moves and
    holds what is fixed to it), and the root link's name. FlatcliError for anything that is
    not a serial chain of revolute joints (module docstring)."""
    links = {}
    for link in robot.links:
        if link.name in links:
            raise FlatcliError(f"{source}: two links are named {link.name!r}")
        links[link.name] = link
    if not links:
        raise FlatcliError(f"{source}: no <link>: a URDF robot has at least one")
    children: dict[str, list[Any]] = {name: [] for name in links}
    parent_of: dict[str, Any] = {}
    names = set()
    for joint in robot.joints:
        where = f"{source}: joint {joint.name!r}"
        if joint.name in names:
            raise FlatcliError(f"{source}: two joints are named {joint.name!r}")
        names.add(joint.name)
        for role, link in (("parent", joint.parent), ("child", joint.child)):
            if link not in links:
                raise FlatcliError(f"{where}: its {role} link {link!r} is not a <link> of "
                                   "the robot")
        if joint.type not in (*REVOLUTE, FIXED):
            raise FlatcliError(
                f"{where} is {joint.type}: flatcli's robots are planar chains of revolute "
                "(or continuous) joints; fixed joints join rigid parts; the root link is the "
                "free base, so it needs no floating or planar joint")
        if joint.child in parent_of:
            raise FlatcliError(f"{where}: link {joint.child!r} already hangs from joint "
                               f"{parent_of[joint.child].name!r} (a link has one parent)")
        parent_of[joint.child] = joint
        children[joint.parent].append(joint)
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        raise FlatcliError(f"{source}: expected one root link (the free base), found "
                           f"{len(roots)}: " + (", ".join(repr(r) for r in roots) or
                                                "the joints form a cycle"))
    def fixed_to(start: str) -> list[str]:
        """``start`` and every link joined to it by fixed joints (depth first)."""
        out, stack = [], [start]
        while stack:
            name = stack.pop()
            out.append(name)
            stack.extend(reversed([j.child for j in children[name] if j.type == FIXED]))
        return out

    bodies: list[list[str]] = []
    revolute: list[Any] = []
    current = fixed_to(roots[0])
    while True:
        bodies.append(current)
        moves = [j for name in current for j in children[name] if j.type in REVOLUTE]
        if len(moves) > 1:
            listed = ", ".join(repr(j.name) for j in moves)
            raise FlatcliError(
                f"{source}: link {current[0]!r} carries {len(moves)} moving joints ({listed}):"
                " flatcli's robots are serial chains, no branches")
        if not moves:
            break
        revolute.append(moves[0])
        current = fixed_to(moves[0].child)
    reached = {name for body in bodies for name in body}
    stray = [name for name in links if name not in reached]
    if stray:
        raise FlatcliError(f"{source}: link {stray[0]!r} is not connected to the root link "
                           f"{roots[0]!r} (the joints form a cycle)")
    if len(revolute) < 2:
        raise FlatcliError(f"{source}: {len(revolute)} revolute joint"
                           f"{'' if len(revolute) == 1 else 's'}: flatcli's robots have a base "
                           "and N >= 2 links joined by revolute joints")
    return revolute, [[links[n] for n in body] for body in bodies], roots[0]


@dataclass(frozen=True)
class Frames:
    """A URDF chain at its zero pose: flatcli's links as ``Body`` records, each in its own
    frame (the frame of the link its joint moves; the root link's for the base), that
    frame's rotation into the root frame, and where the next joint (or the tip) is in it."""

    joints: tuple[Any, ...]
    signs: tuple[int, ...]
    bodies: tuple[Body, ...]
    rotations: tuple[Array, ...]
    normal: Array  # n, joint 1's axis in the root frame
    next_joint: tuple[Array, ...]  # (N,) joint k + 1's origin in body k's frame [m]


def parts_of(robot: Any, source: str) -> Frames:
    """The chain of a URDF robot as ``Frames``. FlatcliError for a moving link without mass
    and for axes that are not parallel."""
    revolute, bodies_links, _ = chain_of(robot, source)
    by_child = {j.child: j for j in robot.joints}
    starts = {links[0].name for links in bodies_links}
    local: dict[str, tuple[Array, Array]] = {name: (np.eye(3), np.zeros(3)) for name in starts}

    def pose(name: str) -> tuple[Array, Array]:
        """A link's frame in the frame of the body it belongs to."""
        if name not in local:
            joint = by_child[name]
            R_parent, p_parent = pose(joint.parent)
            R, p = _joint_origin(joint, source)
            local[name] = (R_parent @ R, p_parent + R_parent @ p)
        return local[name]

    bodies = tuple(Body(tuple(_part(link, *pose(link.name)) for link in links))
                   for links in bodies_links)
    rotations = [np.eye(3)]
    next_joint, axes = [], []
    for joint in revolute:
        where = f"{source}: joint {joint.name!r}"
        R_link, p_link = pose(joint.parent)
        R, p = _joint_origin(joint, source)
        next_joint.append(p_link + R_link @ p)
        rotations.append(rotations[-1] @ R_link @ R)
        axis = np.array([1.0, 0.0, 0.0]) if joint.axis is None else _vector(
            joint.axis, f"{where}: <axis xyz>")
        norm = float(np.linalg.norm(axis))
        if norm == 0.0:
            raise FlatcliError(f"{where}: <axis xyz> is zero; a revolute joint needs a "
                               "direction")
        axes.append(rotations[-1] @ axis / norm)
    n = axes[0]
    for joint, axis in zip(revolute[1:], axes[1:], strict=True):
        sine = float(np.linalg.norm(np.cross(n, axis)))
        if sine > PARALLEL_TOL:
            degrees = math.degrees(math.asin(min(sine, 1.0)))
            raise FlatcliError(
                f"{source}: joint {joint.name!r}: its axis {_shown(axis)} is {degrees:.3g} "
                f"deg off joint {revolute[0].name!r}'s {_shown(n)} (in the root frame at the "
                "zero pose): flatcli's robots are planar, every joint axis parallel")
    if bodies[0].mass <= 0:
        raise FlatcliError(f"{source}: the root link {bodies[0].name!r} (the free base) has "
                           "no mass: it needs an <inertial> with a mass > 0")
    for body in bodies[1:]:
        if body.mass <= 0:
            raise FlatcliError(f"{source}: link {body.name!r} has no mass: every moving link "
                               "needs an <inertial> with a mass > 0")
    signs = tuple(1 if float(axis @ n) > 0 else -1 for axis in axes)
    return Frames(tuple(revolute), signs, bodies, tuple(rotations), n, tuple(next_joint))


def _joint_origin(joint: Any, source: str) -> tuple[Array, Array]:
    R, p = _pose(joint.origin)
    if not np.all(np.isfinite(R)):
        raise FlatcliError(f"{source}: joint {joint.name!r}: <origin rpy> must be finite")
    return R, _vector(p, f"{source}: joint {joint.name!r}: <origin xyz>")


def _shown(v: Array) -> str:
    return "(" + ", ".join(f"{x:.4g}" + "" for x in v) + ")"


def _plane(n: Array) -> tuple[Array, Array]:
    """An in-plane basis (e1, e2) with e1 x e2 = n: e1 the root frame's x axis (or y) less
    its part along n."""
    for guess in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
        e1 = guess - (guess @ n) * n
        if np.linalg.norm(e1) > 0.5:
            e1 = e1 / np.linalg.norm(e1)
            return e1, np.cross(n, e1)
    raise AssertionError("unreachable: one of x, y is off a unit vector")


def read_urdf(path: str | Path) -> UrdfRobot:
    """The robot a URDF file describes (module docstring); FlatcliError naming the file and
    the joint, link or element for a file that is missing, not a URDF, or not a planar
    serial chain."""
    from flatcli.files import read_named_text

    path = Path(path)
    text = read_named_text(path, "URDF file", MAX_URDF_BYTES)
    return urdf_robot(text, str(path))


def urdf_robot(text: str, source: str = "the URDF") -> UrdfRobot:
    """``read_urdf`` of URDF text (``source`` names it in messages)."""
    parsed = parse(text, source)
    chain = parts_of(parsed, source)
    joints, bodies, n = chain.joints, chain.bodies, chain.normal
    tip = _tip(bodies[-1], source)
    e1, e2 = _plane(n)
    count = len(joints)
    mass, inertia, length, com = [], [], [], []
    across = 0.0
    directions = []
    for k, body in enumerate(bodies):
        R = chain.rotations[k]

        def flat(v: Array, R: Array = R) -> Array:
            """A vector of body k's frame in the plane's basis [m]."""
            w = R @ v
            return np.array([float(w @ e1), float(w @ e2)])

        end = flat(chain.next_joint[k] if k < count else tip.origin)
        centre = flat(body.com())
        if k == 0:
            unit, d0, l0 = _base_axis(centre, np.zeros(2), end)
            if l0 <= ZERO_LENGTH:
                raise FlatcliError(
                    f"{source}: the root link {body.name!r}: its frame's origin, its centre "
                    f"of mass and joint {joints[0].name!r} coincide in the plane: flatcli "
                    "needs the base's length (put the root frame's origin at the base's far "
                    "end)")
            length.append(l0)
            com.append(d0)
        else:
            reach = float(np.hypot(*end))
            what = f"joint {joints[k].name!r}" if k < count else f"the tip {tip.name!r}"
            if reach < ZERO_LENGTH:
                raise FlatcliError(
                    f"{source}: link {body.name!r}: {what} lies on joint "
                    f"{joints[k - 1].name!r} in the plane: a link needs a length > 0")
            unit = end / reach
            along = float(centre @ unit)
            side = float(centre @ np.array([-unit[1], unit[0]]))
            if k < count:
                size = max(reach, float(np.hypot(*centre)))
                if abs(side) > ACROSS_TOL * size:
                    raise FlatcliError(
                        f"{source}: link {body.name!r}: its centre of mass lies {side:.4g} m "
                        f"across the line from joint {joints[k - 1].name!r} to joint "
                        f"{joints[k].name!r}: flatcli's model allows a centre of mass off "
                        "the link only on the last link (robot.com_across)")
            else:
                across = side
            length.append(reach)
            com.append(along)
        directions.append(math.atan2(unit[1], unit[0]))  # the link's axis in the plane
        mass.append(body.mass)
        value = body.inertia(R.T @ n)
        if value <= 0:
            raise FlatcliError(f"{source}: link {body.name!r}: its inertia about the joint "
                               f"axis is {value:.4g} kg m^2: it must be > 0 (<inertia>)")
        inertia.append(value)
    offsets = tuple(_wrapped(directions[k] - directions[k - 1]) for k in range(1, count + 1))
    try:
        robot = RobotParams(mass=tuple(mass), inertia=tuple(inertia), length=tuple(length),
                            com=tuple(com), com_across=across)
    except FlatcliError as exc:
        raise FlatcliError(f"{source}: {exc}") from None
    return UrdfRobot(robot=robot, name=str(parsed.name or ""),
                     links=tuple(b.name for b in bodies),
                     joints=tuple(j.name for j in joints), tip=tip.name,
                     angle_offset=offsets, axis_sign=chain.signs)


def _base_axis(centre: Array, origin: Array, joint: Array) -> tuple[Array, float, float]:
    """The base's axis in the plane: a unit vector u, d0 and l0 [m] such that its centre of
    mass is O_0 + d0 u and joint 1 is O_0 + l0 u, l0 > 0.

    The axis is the line through the centre of mass and joint 1 (the root frame's origin
    and joint 1 if they coincide), O_0 the root frame's origin projected onto it, u pointing
    from O_0 to joint 1; O_0 is the centre of mass if the origin projects onto joint 1.
    """
    direction = joint - centre
    if float(np.hypot(*direction)) < ZERO_LENGTH:
        direction = joint - origin
        if float(np.hypot(*direction)) < ZERO_LENGTH:
            return np.array([1.0, 0.0]), 0.0, 0.0
    unit = direction / float(np.hypot(*direction))
    start = centre + float((origin - centre) @ unit) * unit
    l0 = float((joint - start) @ unit)
    if abs(l0) <= ZERO_LENGTH:
        start, l0 = centre, float((joint - centre) @ unit)
    if l0 < 0:
        unit, l0 = -unit, -l0
    return unit, float((centre - start) @ unit), l0


def _wrapped(angle: float) -> float:
    """The angle in (-pi, pi] [rad]."""
    out = math.remainder(angle, math.tau)
    return math.pi if out == -math.pi else out


def _tip(last: Body, source: str) -> Part:
    """The end effector: the one massless link fixed to the last link."""
    tips = [p for p in last.parts[1:] if p.mass == 0.0]
    if len(tips) == 1:
        return tips[0]
    if not tips:
        raise FlatcliError(
            f"{source}: link {last.name!r} (the last) has no tip: flatcli needs the end "
            "effector's point, a massless link joined to it by a fixed joint (its origin "
            "sets the last link's length)")
    raise FlatcliError(f"{source}: link {last.name!r} (the last) has {len(tips)} massless "
                       f"links fixed to it ({', '.join(repr(p.name) for p in tips)}): keep "
                       "one, the end effector's tip")


def urdf_text(robot: RobotParams, name: str = "flatcli_robot") -> str:
    """A URDF of ``robot`` (module docstring), as XML text."""
    from urdf_parser_py import urdf

    out = urdf.Robot(name=name)
    count = robot.n_joints
    names = ["base", *(f"link{k}" for k in range(1, count + 1))]
    for k, link_name in enumerate(names):
        across = robot.com_across if k == count else 0.0
        value = float(robot.inertia[k])
        inertial = urdf.Inertial(
            mass=float(robot.mass[k]),
            inertia=urdf.Inertia(ixx=value, ixy=0.0, ixz=0.0, iyy=value, iyz=0.0, izz=value),
            origin=urdf.Pose(xyz=[float(robot.com[k]), float(across), 0.0], rpy=[0.0, 0.0, 0.0]))
        out.add_link(urdf.Link(name=link_name, inertial=inertial))
    out.add_link(urdf.Link(name="tip"))
    for k in range(1, count + 1):
        out.add_joint(urdf.Joint(
            name=f"joint{k}", parent=names[k - 1], child=names[k], joint_type="continuous",
            axis=[0.0, 0.0, 1.0],
            origin=urdf.Pose(xyz=[float(robot.length[k - 1]), 0.0, 0.0], rpy=[0.0, 0.0, 0.0])))
    out.add_joint(urdf.Joint(
        name="tip_joint", parent=names[-1], child="tip", joint_type="fixed",
        origin=urdf.Pose(xyz=[float(robot.length[-1]), 0.0, 0.0], rpy=[0.0, 0.0, 0.0])))
    text: str = out.to_xml_string()
    header, _, body = text.partition("\n")
    note = ("<!-- written by flatcli: a planar free-floating robot, the root link its free base; "
            "link k's frame at joint k, x along the link; izz about each centre of mass is "
            "the planar inertia (ixx, iyy do not enter) -->")
    return f"{header}\n{note}\n{body.rstrip()}\n"


def write_urdf(robot: RobotParams, name: str, path: Path | None = None) -> str:
    """``urdf_text`` of ``robot``, written atomically to ``path`` (when given: nothing is
    written if it cannot be, and an OS error names the file); returns the text."""
    from flatcli.storage import atomic_path, check_output_dir

    text = urdf_text(robot, name)
    if path is not None:
        if path.is_dir():
            raise FlatcliError(f"--out {path}: is a directory; give a file name (arm.urdf)")
        check_output_dir(path.parent if str(path.parent) else Path("."))
        with atomic_path(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
    return text
