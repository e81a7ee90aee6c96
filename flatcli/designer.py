"""``flatcli design --counterweight``: the counterweight that puts the last link's centre of
mass on its joint, and what it makes of the design.

The spec's last link (``robot.mass[N]``, ``robot.inertia[N]``, ``robot.com[N]``,
``robot.com_across``) is read as the bare link; ``flatcli.core.robots.counterweight`` finds the
least-mass and the least-inertia counterweight among the allowed positions; each resulting
robot gets its flatness verdict (``core.design.design_verdict``) and the input energy of the
spec's maneuver planned for it (``plan.method`` as the spec says: flat where the closed form
applies).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from flatcli.core.errors import FlatcliError
from flatcli.core.robots.counterweight import (
    POSITION_RTOL,
    Counterweight,
    apply,
    design_counterweight,
)
from flatcli.core.robots.design import DesignVerdict, design_verdict
from flatcli.core.robots.params import RobotParams
from flatcli.experiment import plan_from, robot_from
from flatcli.report import table
from flatcli.spec import Spec


@dataclass(frozen=True)
class Option:
    """One counterweight, the robot it makes, its verdict and its plan's input energy
    [rad^2/s] (None if the maneuver cannot be planned for it: ``reason``)."""

    label: str
    counterweight: Counterweight
    robot: RobotParams
    verdict: DesignVerdict
    energy: float | None
    reason: str


def counterweight_options(spec: Spec, segment: ArrayLike, own_inertia: float = 0.0
                          ) -> tuple[Option, Option]:
    """The least-mass and least-inertia counterweights of the spec's last link
    (module docstring)."""
    bare = robot_from(spec)
    n = bare.n_joints
    least_mass, least_inertia = design_counterweight(
        bare.mass[n], bare.inertia[n], bare.com[n], bare.com_across, segment, own_inertia)
    return (_option(spec, "least mass", least_mass), _option(spec, "least inertia",
                                                              least_inertia))


def _option(spec: Spec, label: str, counterweight: Counterweight) -> Option:
    robot = apply(robot_from(spec), counterweight)
    verdict = design_verdict(robot)
    overrides = {"robot.mass": list(robot.mass), "robot.inertia": list(robot.inertia),
                 "robot.com": list(robot.com), "robot.com_across": 0.0}
    try:
        energy: float | None = plan_from(spec.with_overrides(overrides)).input_energy()
        reason = ""
    except FlatcliError as exc:
        energy, reason = None, str(exc)
    return Option(label, counterweight, robot, verdict, energy, reason)


def counterweight_text(spec: Spec, segment: ArrayLike, options: tuple[Option, ...]) -> str:
    """The designer's report: the bare link, the allowed positions, one row per option."""
    bare = robot_from(spec)
    n = bare.n_joints
    ends = np.asarray(segment, dtype=float)
    head = (f"counterweight for link {n} of robot {spec.name!r}: bare link m = "
            f"{bare.mass[n]:g} kg, I = {bare.inertia[n]:g} kg m^2 about its centre at "
            f"({bare.com[n]:g}, {bare.com_across:g}) m from joint {n}; allowed positions from "
            f"({ends[0, 0]:g}, {ends[0, 1]:g}) to ({ends[1, 0]:g}, {ends[1, 1]:g}) m (x along "
            "the link, y across)")
    rows = [[o.label, o.counterweight.mass, o.counterweight.x, o.counterweight.y,
             o.counterweight.residual, o.counterweight.link_mass,
             o.counterweight.link_inertia, o.verdict.verdict,
             "-" if o.energy is None else o.energy] for o in options]
    band = POSITION_RTOL * max(float(np.abs(ends).max()), float(np.hypot(bare.com[n],
                                                                         bare.com_across)))
    lines = [head, table(["choice", "counterweight [kg]", "x [m]", "y [m]",
                          "centre off joint [m]", f"link {n} mass [kg]",
                          f"link {n} inertia [kg m^2]", "verdict", "plan energy [rad^2/s]"],
                         rows, 6),
             f"positions within {band:.3g} m of the ray count as on it (POSITION_RTOL = "
             f"{POSITION_RTOL:g} of the link's scale); the verdicts and plans are of the link "
             "with its centre on the joint"]
    lines += [f"  {o.label}: {o.reason}" for o in options if o.reason]
    return "\n".join(lines)


__all__ = ["Option", "counterweight_options", "counterweight_text"]
