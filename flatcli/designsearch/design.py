"""A search's design space: from a vector of design variables to a robot, its constraints, and
the spec of one candidate.

The variables (``flatcli.spec.searches.search_variables``) set elements of ``[robot]`` keys and
the quantities of a counterweight on the last link. With ``[search.counterweight]`` the spec's
last link is the bare link and each candidate's last link carries the counterweight: placed by
the designer (``core.robots.counterweight.design_counterweight`` at the given distance on the
ray opposite the bare link's centre, or at the distance its mass needs) so that the link's
centre is on its joint, or attached at (x, y) (``attach``).

With ``search.apply = "robot"`` (the default) a design is the robot: what the planner and the
controller believe, and what is built. The plant follows it: a ``[plant]`` key the spec sets
keeps its as-built offset from the spec's own design (``plant = spec's plant + (candidate's
robot - spec's own robot)``, item by item), so a counterweight that misses its joint by 1 mm as
built misses it by 1 mm in every candidate; a key the spec leaves unset is the candidate's
robot's. With ``search.apply = "plant"`` a design is the plant alone (what is built), and the
controller keeps the spec's ``[robot]``: where must the counterweight go for the nominal
feedback to work?

Constraints (``violations``), each 0 when met: the total mass above ``search.max_mass`` [kg];
the flatness verdict below ``search.verdict`` (1); the last link's centre off its joint under
``search.centre = "on_joint"`` [m]. The verdict is ``flatness_check``'s (closed-form conditions,
and controllable unless every coupling K_ab vanishes), which is ``design_verdict``'s without its
64 sampled configurations (``core.robots.design`` shows K diagonal exactly when w ^ dw = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.robots.counterweight import apply, attach, design_counterweight
from flatcli.core.robots.params import DESIGN_ZERO_TOL, RobotParams, flatness_check
from flatcli.experiment import robot_from
from flatcli.spec import Spec, SpecError
from flatcli.spec.searches import (
    CounterweightSetup,
    Variable,
    counterweight_setup,
    design_value,
    search_variables,
)

Array = NDArray[np.float64]

#: The constraints, in the order of ``violations``' rows, with their units.
CONSTRAINTS = (("mass_excess", "kg"), ("verdict_short", ""), ("centre_offset", "m"))
#: The plant keys that follow the design (each the robot key of the same name).
PLANT_KEYS = ("mass", "inertia", "length", "com", "com_across")
#: How each verdict ranks: a candidate meets ``search.verdict`` when its rank is at least.
_RANK = {"not_flat": 0, "flat": 1, "closed_form": 2}
_REQUIRED = {"any": 0, "flat": 1, "closed_form": 2}


@dataclass(frozen=True)
class Candidate:
    """One design: its robot (None if it cannot be built: ``reason``), the constraints'
    violations (``CONSTRAINTS``), its verdict, and its spec (None unless feasible and built)."""

    x: tuple[float, ...]
    robot: RobotParams | None
    violations: tuple[float, ...]
    verdict: str
    reason: str
    spec: Spec | None

    @property
    def feasible(self) -> bool:
        return self.robot is not None and not any(v > 0 for v in self.violations)


@dataclass(frozen=True)
class Design:
    """The design space of a search spec (module docstring)."""

    spec: Spec
    variables: tuple[Variable, ...]
    counterweight: CounterweightSetup | None
    own_robot: RobotParams

    @staticmethod
    def of(spec: Spec) -> Design:
        """The design space of ``spec``; SpecError if it has no ``[search.vary]`` or its own
        design cannot be built."""
        variables = search_variables(spec)
        if not variables:
            raise SpecError("search.vary: a search needs at least one design variable, e.g. "
                            "\"robot.mass[1]\" = { relative = 0.3 }")
        setup = counterweight_setup(spec.search)
        partial = Design(spec, variables, setup, robot_from(spec))  # own_robot set below
        try:
            own = partial.robot(partial.baseline)
        except FlatcliError as exc:
            raise SpecError(f"search: the spec's own design cannot be built: {exc}") from None
        return Design(spec, variables, setup, own)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.variables)

    @property
    def bounds(self) -> list[tuple[float, float]]:
        return [(v.low, v.high) for v in self.variables]

    @property
    def baseline(self) -> Array:
        """(n,) the spec's own design."""
        return np.array([v.baseline for v in self.variables])

    @property
    def baseline_inside(self) -> bool:
        """Whether the spec's own design lies within the bounds (then it is candidate 0)."""
        return all(v.low <= v.baseline <= v.high for v in self.variables)

    def robot(self, x: Array) -> RobotParams:
        """The robot of design ``x`` (n,) (FlatcliError if it is not a valid robot)."""
        values: dict[str, Any] = {key: design_value(self.spec, key) for key in PLANT_KEYS}
        for key in ("mass", "inertia", "length", "com"):
            values[key] = list(values[key])
        weight = dict(self.counterweight.values) if self.counterweight else {}
        for var, value in zip(self.variables, x, strict=True):
            if var.section == "counterweight":
                weight[var.key] = float(value)
            elif var.index is None:
                values[var.key] = float(value)
            else:
                values[var.key][var.index] = float(value)
        bare = RobotParams(values["mass"], values["inertia"], values["length"], values["com"],
                           values["com_across"])
        setup = self.counterweight
        if setup is None:
            return bare
        own = weight.get("inertia", 0.0)
        if not setup.designer:
            return attach(bare, weight["mass"], weight["x"], weight.get("y", 0.0), own)
        n = bare.n_joints
        d, e = bare.com[n], bare.com_across
        reach = math.hypot(d, e)
        if reach == 0.0:
            raise FlatcliError(f"the bare link {n}'s centre of mass is on its joint: it needs no "
                               "counterweight")
        distance = (bare.mass[n] * reach / weight["mass"] if setup.by_mass
                    else weight["distance"])
        point = [-d / reach * distance, -e / reach * distance]
        least_mass, _ = design_counterweight(bare.mass[n], bare.inertia[n], d, e,
                                             [point, point], own)
        return apply(bare, least_mass)

    def counterweight_of(self, x: Array) -> dict[str, float]:
        """The counterweight of design ``x``: mass [kg], x, y [m] in the link's frame (empty
        without one); the designer's mass and place where it places it."""
        setup = self.counterweight
        if setup is None:
            return {}
        weight = dict(setup.values)
        for var, value in zip(self.variables, x, strict=True):
            if var.section == "counterweight":
                weight[var.key] = float(value)
        if not setup.designer:
            return {"mass": weight["mass"], "x": weight["x"], "y": weight.get("y", 0.0)}
        bare = self.robot_without_counterweight(x)
        n = bare.n_joints
        d, e = bare.com[n], bare.com_across
        reach = math.hypot(d, e)
        distance = (bare.mass[n] * reach / weight["mass"] if setup.by_mass
                    else weight["distance"])
        return {"mass": bare.mass[n] * reach / distance, "x": -d / reach * distance,
                "y": -e / reach * distance}

    def robot_without_counterweight(self, x: Array) -> RobotParams:
        """The robot of design ``x`` with its bare last link."""
        plain = Design(self.spec, self.variables, None, self.own_robot)
        return plain.robot(x)

    def violations(self, robot: RobotParams) -> tuple[tuple[float, ...], str]:
        """(``CONSTRAINTS`` violations, verdict) of a candidate robot."""
        search = self.spec.search
        excess = max(robot.total_mass - search.max_mass, 0.0)
        check = flatness_check(robot)
        verdict = ("closed_form" if check.is_flat else "flat" if check.controllable
                   else "not_flat")
        short = float(_RANK[verdict] < _REQUIRED[search.verdict])
        offset = 0.0
        if search.centre == "on_joint":
            n = robot.n_joints
            reach = math.hypot(robot.com[n], robot.com_across)
            offset = reach if reach > DESIGN_ZERO_TOL * max(robot.length) else 0.0
        return (excess, short, offset), verdict

    def candidate(self, x: Array) -> Candidate:
        """Design ``x`` built, judged against the constraints and, if it meets them, turned
        into the spec its Monte Carlo study runs (``candidate_spec``)."""
        point = tuple(float(v) for v in x)
        try:
            robot = self.robot(np.asarray(x, dtype=float))
        except FlatcliError as exc:
            return Candidate(point, None, (math.inf,) * len(CONSTRAINTS), "", str(exc), None)
        violations, verdict = self.violations(robot)
        if any(v > 0 for v in violations):
            return Candidate(point, robot, violations, verdict,
                             violation_text(violations, self.spec, verdict), None)
        try:
            spec = self.candidate_spec(robot)
        except FlatcliError as exc:
            return Candidate(point, None, (math.inf,) * len(CONSTRAINTS), verdict, str(exc),
                             None)
        return Candidate(point, robot, violations, verdict, "", spec)

    def candidate_spec(self, robot: RobotParams) -> Spec:
        """The spec of a candidate: the search spec with ``robot`` as ``[robot]``, its plant
        keeping the spec's as-built offsets (or, with ``search.apply = "plant"``, ``robot`` as
        the ``[plant]``: module docstring), and no ``[search]`` tables."""
        spec = self.spec
        own = self.own_robot
        overrides: dict[str, Any] = {"search.vary": {}, "search.counterweight": {}}
        side = spec.search.apply
        overrides.update({f"{side}.{key}": (list(getattr(robot, key)) if key != "com_across"
                                            else robot.com_across) for key in PLANT_KEYS})
        if side == "plant":
            return spec.with_overrides(overrides)
        for key in PLANT_KEYS:
            given = getattr(spec.plant, key)
            if given is None:
                continue
            if key == "com_across":
                overrides["plant.com_across"] = given + (robot.com_across - own.com_across)
            else:
                overrides[f"plant.{key}"] = [g + (a - b) for g, a, b in
                                             zip(given, getattr(robot, key), getattr(own, key),
                                                 strict=True)]
        return spec.with_overrides(overrides)


def violation_text(violations: tuple[float, ...], spec: Spec, verdict: str) -> str:
    """The constraints a candidate breaks, in words."""
    search = spec.search
    excess, short, offset = violations
    out = []
    if excess > 0:
        out.append(f"total mass {search.max_mass + excess:.6g} kg > search.max_mass "
                   f"{search.max_mass:g} kg")
    if short > 0:
        out.append(f"verdict {verdict}, search.verdict asks for {search.verdict}")
    if offset > 0:
        out.append(f"last link's centre {offset:.3g} m off its joint (search.centre = "
                   "\"on_joint\")")
    return "; ".join(out)


__all__ = ["CONSTRAINTS", "Candidate", "Design", "violation_text"]
