"""Specs that compose, as Hydra's config groups do: a robot file chosen by name, and files
included into a spec.

* ``robot = "chain4"`` (or ``--robot chain4``, ``--set robot=chain4``) picks a robot file: a
  name shipped with flatcli (``flatcli/data/robots/<name>.toml``: ``ROBOTS``) or a path to a
  file of one's own (``robot = "my_robot.toml"``, relative to the file that names it). A robot
  file is a spec fragment: its ``[robot]`` and, because the paper's maneuver and gains are for
  two joints, the ``[plan]`` and ``[track]`` keys that fit that robot. A URDF file
  (``robot = "arm.urdf"``: ``flatcli.urdf``) gives the ``[robot]`` keys alone.
* ``include = ["a.toml", "b.toml"]`` merges other spec files, each relative to the file that
  includes it (they may include others).

The order, lowest first: the defaults, the robot file, the included files in order, the file's
own keys, then ``--set`` items. A later key replaces an earlier one key by key (a section's
keys merge; a table such as ``sweep.grid`` is one value). An include cycle, a missing file, a
robot no file gives, and more than ``MAX_FILES`` files are refused in one line naming the file.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from flatcli.spec.keys import SpecError, suggest

#: Where the shipped robot files are (package data).
ROBOTS = Path(str(resources.files("flatcli") / "data" / "robots"))
#: The most files one spec may be composed of (its robot files and includes, all levels).
MAX_FILES = 64


def robot_names() -> list[str]:
    """The robot files shipped with flatcli, by name."""
    return sorted(p.stem for p in ROBOTS.glob("*.toml"))


def is_path(selection: str) -> bool:
    """Whether a robot selection names a file (``my_robot.toml``, ``robots/x``) rather than a
    shipped robot."""
    return selection.endswith((".toml", ".urdf")) or "/" in selection or "\\" in selection


def robot_file(selection: Any, base: Path | None, where: str = "robot") -> Path:
    """The file a robot selection names; SpecError for anything else."""
    if not isinstance(selection, str) or not selection.strip():
        raise SpecError(f"{where}: expected a [robot] table, a robot name "
                        f"({', '.join(robot_names())}) or a robot file (\"my_robot.toml\", "
                        "\"arm.urdf\"), "
                        f"got {selection!r}")
    if is_path(selection):
        path = Path(selection).expanduser()
        return path if path.is_absolute() or base is None else base / path
    names = robot_names()
    if selection not in names:
        raise SpecError(f"{where}: unknown robot {selection!r}; shipped: {', '.join(names)}, "
                        f"or a robot file such as \"my_robot.toml\"{suggest(selection, names)}")
    return ROBOTS / f"{selection}.toml"


def _shown(path: Path) -> str:
    """A file as a message names it: relative to the current directory when inside it."""
    try:
        return str(path.relative_to(Path.cwd()))
    except ValueError:
        return str(path)


class _Composer:
    """One composition: the files read so far (bounded by ``MAX_FILES``)."""

    def __init__(self) -> None:
        self.files: list[Path] = []

    def file(self, path: Path, chain: tuple[Path, ...], where: str,
             robot: str | None = None) -> dict[str, Any]:
        """The dotted keys a file gives, its robot file and includes merged below them."""
        from flatcli.spec.build import read_toml

        real = path.resolve()
        if real in chain:
            names = " -> ".join(_shown(p) for p in (*chain[chain.index(real):], real))
            raise SpecError(f"{where}: include cycle {names}")
        if len(self.files) >= MAX_FILES:
            raise SpecError(f"{where}: more than {MAX_FILES} spec files in one spec (robot "
                            "files and includes)")
        self.files.append(real)
        if path.suffix.lower() == ".urdf":
            return self.urdf(path, chain, where)
        try:
            tree = read_toml(path)
        except SpecError as exc:
            raise SpecError(str(exc) if not chain else f"{where}: {exc}") from None
        return self.tree(tree, path.parent, (*chain, real), str(path), robot)

    def urdf(self, path: Path, chain: tuple[Path, ...], where: str) -> dict[str, Any]:
        """The ``[robot]`` keys a URDF file gives (``flatcli.urdf``); SpecError naming the
        file and the joint or element for one that is missing, malformed or not planar."""
        from flatcli.core.errors import FlatcliError
        from flatcli.urdf import read_urdf

        try:
            return read_urdf(path).spec_keys()
        except FlatcliError as exc:
            raise SpecError(str(exc) if not chain else f"{where}: {exc}") from None

    def tree(self, tree: Mapping[str, Any], base: Path | None, chain: tuple[Path, ...],
             source: str, robot: str | None = None) -> dict[str, Any]:
        """The dotted keys of a spec tree read from ``source`` (a file, or "the spec"), with
        its robot file and its includes merged below its own keys."""
        from flatcli.spec.build import flatten

        own = dict(tree)
        include = own.pop("include", [])
        selection: Any = robot  # the command line's choice replaces the file's own
        if "robot" in own and not isinstance(own["robot"], Mapping):
            chosen = own.pop("robot")
            selection = chosen if selection is None else selection
        out: dict[str, Any] = {}
        if selection is not None:
            path = robot_file(selection, base, f"{source}: robot" if chain else "robot")
            out.update(self.file(path, chain, f"{source}: robot {selection!r}"))
        if isinstance(include, str) or not isinstance(include, list) or not all(
                isinstance(i, str) and i.strip() for i in include):
            raise SpecError(f"{source}: include: expected a list of spec files (include = "
                            f"[\"my_robot.toml\"]), got {include!r}")
        for name in include:
            path = Path(name).expanduser()
            path = path if path.is_absolute() or base is None else base / path
            out.update(self.file(path, chain, f"{source}: include {name!r}"))
        out.update(flatten(own))
        return out


def compose(tree: Mapping[str, Any], base: Path | None = None, robot: str | None = None,
            source: Path | None = None) -> dict[str, Any]:
    """A spec's dotted keys with its robot file and includes merged in (see the module's
    docstring).

    Parameters
    ----------
    tree : a spec as nested tables (a parsed TOML file, or a dict)
    base : the directory its relative file names are relative to (None: the current one)
    robot : a robot selection replacing the spec's own (``--robot``)
    source : the file ``tree`` was read from (named in messages; guards include cycles)
    """
    chain = () if source is None else (source.resolve(),)
    composer = _Composer()
    if source is not None:
        composer.files.append(source.resolve())
    return composer.tree(tree, base, chain, str(source) if source is not None else "the spec",
                         robot)


def compose_file(path: Path, robot: str | None = None) -> dict[str, Any]:
    """A spec file's dotted keys, composed (``compose``)."""
    return _Composer().file(path, (), str(path), robot)
