"""The rules of a design search's tables: ``[search.vary]`` and ``[search.counterweight]``.

Both tables are kept as written (a search's identity is its spec as written) and checked here,
so a bad variable is refused in one line naming it before anything runs:

* ``[search.vary]`` maps a design variable to its bounds, ``[low, high]`` or ``{ relative = r }``
  (the spec's own value times 1 - r and 1 + r). A variable is an element of a per-link robot
  key (``"robot.mass[1]"``, ``"robot.length[2]"``, ``"robot.inertia[0]"``, ``"robot.com[1]"``),
  ``"robot.com_across"``, or a counterweight quantity (``"counterweight.distance"``,
  ``"counterweight.mass"``, ``"counterweight.x"``, ``"counterweight.y"``,
  ``"counterweight.inertia"``). With ``search.apply = "plant"`` the design is the plant's
  alone (``"plant.mass[1]"``, ...; the controller keeps ``[robot]``).
* ``[search.counterweight]`` puts a counterweight on the last link, whose ``[robot]`` values
  (``[plant]``'s with ``search.apply = "plant"``) are then the bare link's (as ``flatcli design
  --counterweight`` reads them). Its keys give the spec's own counterweight (the value of each
  varied quantity and of the fixed ones): either ``distance`` [m] (placed by the designer on
  the ray from joint N opposite the bare link's centre, with the mass that puts the link's
  centre on its joint), or ``mass`` [kg] with ``x`` and ``y`` [m] (its centre in the link's
  frame: the link's centre moves to the balance of the two), and ``inertia`` [kg m^2], its
  own about its centre (default 0). With ``search.centre = "on_joint"`` a ``mass`` alone is
  placed by the designer too.

The mapping of a design to a robot is ``flatcli.designsearch.design``'s; this module knows
only the names, the bounds and the spec's own values.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from flatcli.core.names import METRIC_NAMES
from flatcli.spec.keys import SpecError, suggest

#: What a search maximises or minimises (``search.objective``).
SEARCH_OBJECTIVES = ("reached", "quantile")
#: The least verdict a candidate design must have (``search.verdict``): any, controllable
#: (hence flat), or flat with the closed-form outputs (``flatcli design``'s verdicts).
VERDICT_REQUIREMENTS = ("any", "flat", "closed_form")
#: Where the last link's centre of mass may be (``search.centre``).
CENTRES = ("free", "on_joint")
#: What a design is (``search.apply``): the robot (what the controller believes and what is
#: built, the plant keeping its as-built offsets) or the plant alone (what is built, under a
#: controller that keeps the spec's [robot]).
APPLY = ("robot", "plant")
#: Metrics whose quantile a search may minimise: every trial metric for which less is better
#: (a time of first event and the least margin are not).
QUANTILE_METRICS: tuple[str, ...] = tuple(
    m for m in METRIC_NAMES if m not in ("first_hit_time", "min_margin", "first_crossing_time"))
#: The per-link robot keys a variable may take an element of, and the scalar one.
ROBOT_VECTORS = ("mass", "inertia", "length", "com")
ROBOT_SCALARS = ("com_across",)
#: Quantities of ``[search.counterweight]`` (each may also be a variable).
COUNTERWEIGHT_KEYS = ("distance", "mass", "x", "y", "inertia")
#: The most design variables one search may have.
MAX_VARIABLES = 32
#: Which values must be > 0 (or >= 0) for every candidate.
_POSITIVE = {("robot", "mass"), ("robot", "inertia"), ("robot", "length"),
             ("counterweight", "distance")}
_NON_NEGATIVE = {("counterweight", "mass"), ("counterweight", "inertia")}

_NAME = re.compile(r"^(robot|plant)\.(mass|inertia|length|com)\[(\d+)\]$"
                   r"|^(robot|plant)\.(com_across)$"
                   r"|^(counterweight)\.(distance|mass|x|y|inertia)$")


@dataclass(frozen=True)
class Variable:
    """One design variable: its name as written, what it sets (``section`` "robot", "plant"
    or "counterweight", ``key``, ``index`` for an element of a per-link key), its bounds and the
    spec's own value (``baseline``)."""

    name: str
    section: str
    key: str
    index: int | None
    low: float
    high: float
    baseline: float

    @property
    def width(self) -> float:
        return self.high - self.low


@dataclass(frozen=True)
class CounterweightSetup:
    """The spec's own counterweight and how candidates place theirs.

    ``designer``: on the balancing ray (the link's centre on its joint), given by ``distance``
    (or, with ``by_mass``, by its ``mass``: distance = m |r| / m_c); otherwise placed at
    ``x``, ``y``. ``values``: the spec's own value of every quantity it gives [kg, m, kg m^2].
    """

    designer: bool
    by_mass: bool
    values: Mapping[str, float]


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SpecError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def counterweight_setup(search: Any) -> CounterweightSetup | None:
    """The ``[search.counterweight]`` table checked (None when the table is empty and no
    counterweight quantity varies); SpecError naming what is wrong."""
    table = search.counterweight
    varied = {name.split(".", 1)[1] for name in search.vary if name.startswith("counterweight.")}
    if not table and not varied:
        return None
    if not isinstance(table, Mapping):
        raise SpecError("search.counterweight: expected a table such as { distance = 0.1 }")
    values: dict[str, float] = {}
    for key, value in table.items():
        if key not in COUNTERWEIGHT_KEYS:
            raise SpecError(f"search.counterweight.{key}: unknown; allowed: "
                            f"{list(COUNTERWEIGHT_KEYS)}{suggest(str(key), COUNTERWEIGHT_KEYS)}")
        values[key] = _number(f"search.counterweight.{key}", value)
    if "distance" in set(values) | varied and {"x", "y"} & varied:
        raise SpecError(f"search.vary.'counterweight.{sorted({'x', 'y'} & varied)[0]}': the "
                        "designer places this counterweight on the balancing ray (it has a "
                        "distance); vary counterweight.distance (or give mass, x and y instead)")
    missing = sorted(varied - set(values))
    if missing:
        raise SpecError(f"search.counterweight.{missing[0]}: counterweight.{missing[0]} varies, "
                        "so give its value in the spec's own design here (the search's first "
                        "candidate, and what relative bounds scale)")
    given = set(values)
    placed = given & {"x", "y"}
    if "distance" in given and given & {"mass", "x", "y"}:
        raise SpecError("search.counterweight: give its place either as distance (the designer "
                        "puts it on the balancing ray, its mass follows) or as mass, x and y, "
                        "not both")
    designer = "distance" in given or (search.centre == "on_joint" and not placed)
    by_mass = designer and "distance" not in given
    if designer and not given & {"distance", "mass"}:
        raise SpecError("search.counterweight: give distance [m] (or, with search.centre = "
                        "\"on_joint\", mass [kg])")
    if not designer:
        if search.centre == "on_joint":
            raise SpecError("search.counterweight: a counterweight placed at x, y leaves the "
                            "link's centre off its joint, which search.centre = \"on_joint\" "
                            "forbids; give distance (or mass alone): the designer places it")
        for key in ("mass", "x"):
            if key not in given:
                raise SpecError(f"search.counterweight.{key}: required for a counterweight "
                                "placed at x, y (or give distance: the designer places it)")
    for key in ("distance",) if designer and not by_mass else ("mass",) if by_mass else ():
        if values[key] <= 0:
            raise SpecError(f"search.counterweight.{key}: must be > 0, got {values[key]:g}")
    if values.get("mass", 0.0) < 0 or values.get("inertia", 0.0) < 0:
        which = "mass" if values.get("mass", 0.0) < 0 else "inertia"
        raise SpecError(f"search.counterweight.{which}: must be >= 0, got {values[which]:g}")
    return CounterweightSetup(designer, by_mass, values)


def search_variables(spec: Any) -> tuple[Variable, ...]:
    """The design variables of ``[search.vary]``, in the order written; SpecError naming a
    variable that is unknown, out of the robot's links, badly bounded or not allowed with the
    spec's other search keys."""
    search = spec.search
    setup = counterweight_setup(search)
    n = spec.joints
    out: list[Variable] = []
    if len(search.vary) > MAX_VARIABLES:
        raise SpecError(f"search.vary: at most {MAX_VARIABLES} variables, got "
                        f"{len(search.vary)}")
    for name, bounds in search.vary.items():
        where = f"search.vary.{name!r}"
        match = _NAME.match(str(name))
        if match is None:
            side = search.apply
            known = [f"{side}.{k}[i]" for k in ROBOT_VECTORS] + [f"{side}.com_across"] + \
                [f"counterweight.{k}" for k in COUNTERWEIGHT_KEYS]
            bare = str(name).split(".", 1)[-1]
            hint = (f": give one element, e.g. {side}.{bare}[1]" if bare in ROBOT_VECTORS
                    and str(name).split(".")[0] in APPLY else suggest(str(name), known))
            raise SpecError(f"{where}: not a design variable; allowed: an element of "
                            f"{side}.{{mass, inertia, length, com}}[i], {side}.com_across, "
                            f"counterweight.{{{', '.join(COUNTERWEIGHT_KEYS)}}}{hint}")
        groups = [g for g in match.groups() if g is not None]
        section, key = groups[0], groups[1]
        index = int(groups[2]) if len(groups) > 2 else None
        if section in APPLY and section != search.apply:
            rest = str(name).split(".", 1)[1]
            raise SpecError(f"{where}: search.apply = \"{search.apply}\" varies the "
                            f"{search.apply}: name it {search.apply}.{rest} (or set "
                            f"search.apply = \"{section}\")")
        if section in APPLY:
            if index is not None and index > n:
                raise SpecError(f"{where}: the robot has links 0..{n} (robot.mass has "
                                f"{n + 1}), got index {index}")
            last = index == n or key == "com_across"
            if key in ("com", "com_across") and last and search.centre == "on_joint" \
                    and setup is None:
                raise SpecError(f"{where}: moves link {n}'s centre off its joint, which "
                                "search.centre = \"on_joint\" forbids (with a "
                                "[search.counterweight] it is the bare link's centre, which "
                                "the designer balances)")
            value = design_value(spec, key)
            baseline = value if index is None else value[index]
        else:
            assert setup is not None
            if setup.designer and key in ("x", "y"):
                raise SpecError(f"{where}: the designer places this counterweight on the "
                                "balancing ray; vary counterweight.distance (or its mass)")
            if setup.designer and key == "mass" and not setup.by_mass:
                raise SpecError(f"{where}: the designer gives the mass of a counterweight "
                                "placed by distance; vary counterweight.distance")
            if setup.designer and key == "distance" and setup.by_mass:
                raise SpecError(f"{where}: this counterweight is given by its mass; give "
                                "search.counterweight.distance instead of mass to vary it")
            baseline = setup.values.get(key, 0.0)
        low, high = _bounds(where, bounds, float(baseline))
        if (section if section == "counterweight" else "robot", key) in _POSITIVE and low <= 0:
            raise SpecError(f"{where}: {section}.{key} must stay > 0, got low = {low:g}")
        if (section if section == "counterweight" else "robot", key) in _NON_NEGATIVE \
                and low < 0:
            raise SpecError(f"{where}: {section}.{key} must stay >= 0, got low = {low:g}")
        if setup is not None and setup.by_mass and key == "mass" and section == "counterweight" \
                and low <= 0:
            raise SpecError(f"{where}: a counterweight placed by its mass needs mass > 0, got "
                            f"low = {low:g}")
        out.append(Variable(str(name), section, key, index, low, high, float(baseline)))
    return tuple(out)


def design_value(spec: Any, key: str) -> Any:
    """The spec's own value of a robot key of the design: ``[robot]``'s, or with
    ``search.apply = "plant"`` the plant's (``[robot]``'s where ``[plant]`` leaves it unset)."""
    robot = getattr(spec.robot, key)
    if spec.search.apply == "plant":
        plant = getattr(spec.plant, key)
        return robot if plant is None else plant
    return robot


def _bounds(where: str, bounds: Any, baseline: float) -> tuple[float, float]:
    """``[low, high]`` or ``{ relative = r }`` as (low, high), low < high."""
    if isinstance(bounds, Mapping):
        if set(bounds) != {"relative"}:
            raise SpecError(f"{where}: expected [low, high] or {{ relative = r }}, got "
                            f"{dict(bounds)!r}")
        r = _number(f"{where}.relative", bounds["relative"])
        if not r > 0:
            raise SpecError(f"{where}.relative: must be > 0, got {r:g}")
        if baseline == 0:
            raise SpecError(f"{where}: relative bounds of a value that is 0 are [0, 0]; give "
                            "[low, high]")
        a, b = baseline * (1 - r), baseline * (1 + r)
        return (min(a, b), max(a, b))
    if not isinstance(bounds, list | tuple) or len(bounds) != 2:
        raise SpecError(f"{where}: expected [low, high] or {{ relative = r }}, got {bounds!r}")
    low, high = (_number(where, v) for v in bounds)
    if not low < high:
        raise SpecError(f"{where}: low must be < high, got [{low:g}, {high:g}]")
    return (low, high)


def validate_search(spec: Any) -> None:
    """Check ``[search]``'s tables against each other and the robot (when it has any)."""
    search = spec.search
    if not search.vary and not search.counterweight:
        return
    if not search.vary:
        raise SpecError("search.vary: a search needs at least one design variable, e.g. "
                        "\"robot.mass[1]\" = { relative = 0.3 }")
    setup = counterweight_setup(search)
    n = spec.joints
    where = search.apply
    along, across = design_value(spec, "com")[n], design_value(spec, "com_across")
    if setup is None and search.centre == "on_joint" and (along != 0 or across != 0):
        raise SpecError(f"search.centre = \"on_joint\": the spec's link {n} centre is at "
                        f"({along:g}, {across:g}) m, off its joint; set {where}.com and "
                        f"{where}.com_across to put it there, or add [search.counterweight]")
    if setup is not None and setup.designer and along == 0 and across == 0:
        raise SpecError(f"search.counterweight: the designer balances link {n}'s bare centre "
                        f"of mass, which the spec puts on its joint already ({where}.com, "
                        f"{where}.com_across): give the bare link's centre")
    search_variables(spec)


__all__ = ["APPLY", "CENTRES", "COUNTERWEIGHT_KEYS", "QUANTILE_METRICS", "SEARCH_OBJECTIVES",
           "VERDICT_REQUIREMENTS", "CounterweightSetup", "Variable", "counterweight_setup",
           "design_value", "search_variables", "validate_search"]
