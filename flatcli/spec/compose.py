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
own keys, then ``--set`` items. ``unset = ["plan.goal"]`` in a file removes keys its robot file
and includes gave it (a section name removes all of its keys), and ``--set ~plan.goal`` (as
Hydra's ``~key``) removes a key at that point of the command line: the key takes its default
again, as if never given. A spec that picks a robot and sets no ``name`` anywhere is named
after it (``chain4``, the stem of ``my_robot.toml``; the shipped ``paper`` robot, flatcli's
defaults, keeps the default name): runs, summaries and ``flatcli design`` call it by its
name. A later key replaces an earlier one key by key (a section's keys merge; a table such
as ``sweep.grid`` is one value). An include cycle, a missing file, a
robot no file gives, and more than ``MAX_FILES`` files are refused in one line naming the file.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from flatcli.spec.keys import SpecError, suggest
from flatcli.spec.schema import dotted_keys
from flatcli.spec.tree import read_toml

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


def file_path(name: str, base: Path | None, where: str) -> Path:
    """The file a spec names (``robot = "..."``, ``include``): ``~`` and ``~user`` expanded,
    relative to ``base``; SpecError naming ``where`` for a name no file can have (a NUL
    byte) or a home directory that cannot be found (``~nosuchuser/x.toml``)."""
    if "\0" in name:
        raise SpecError(f"{where}: a file name must not contain a NUL byte")
    try:
        path = Path(name).expanduser()
    except RuntimeError:  # Python's "Could not determine home directory"
        user = name[1:].split("/", 1)[0]
        whose = f"of user {user!r}" if user else "(HOME is not set)"
        named = "" if repr(name) in where else f" {name!r}:"
        raise SpecError(f"{where}:{named} no home directory {whose}") from None
    return path if path.is_absolute() or base is None else base / path


def robot_file(selection: Any, base: Path | None, where: str = "robot") -> Path:
    """The file a robot selection names; SpecError for anything else."""
    if not isinstance(selection, str) or not selection.strip():
        raise SpecError(f"{where}: expected a [robot] table, a robot name "
                        f"({', '.join(robot_names())}) or a robot file (\"my_robot.toml\", "
                        "\"arm.urdf\"), "
                        f"got {selection!r}")
    if is_path(selection):
        return file_path(selection, base, where)
    names = robot_names()
    if selection not in names:
        raise SpecError(f"{where}: unknown robot {selection!r}; shipped: {', '.join(names)}, "
                        f"or a robot file such as \"my_robot.toml\"{suggest(selection, names)}")
    return ROBOTS / f"{selection}.toml"


def remove_key(values: dict[str, Any], dotted: str, where: str) -> None:
    """Remove ``dotted`` from dotted ``values`` (a section: every key in it), so it takes its
    default again as if never given (``unset = [...]``, ``--set ~KEY``); SpecError naming
    ``where`` for a name that is no key or section."""
    from flatcli.spec.schema import SCHEMA, all_keys
    from flatcli.spec.sweeps import is_perturbation_param

    known = dotted in SCHEMA or is_perturbation_param(dotted) or dotted in set(all_keys())
    if not known or not dotted:
        names = all_keys() + [s for s in SCHEMA if s]
        raise SpecError(f"{where}: {dotted!r} is not a spec key or section"
                        f"{suggest(dotted, names)}")
    for key in [k for k in values if k == dotted or k.startswith(f"{dotted}.")]:
        del values[key]


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
        self.robot: Path | None = None  # the robot file the spec is named after
        self.top: bool | None = None  # whether the top level chose it

    def file(self, path: Path, chain: tuple[Path, ...], where: str,
             robot: str | None = None) -> dict[str, Any]:
        """The dotted keys a file gives, its robot file and includes merged below them."""
        try:
            real = path.resolve()
        except (OSError, RuntimeError, ValueError):  # a link loop (RuntimeError before 3.13)
            raise SpecError(f"{where}: cannot read spec file {_shown(path)}: a loop of symbolic "
                            "links") from None
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
        except SpecError as exc:  # named by what chose the file, unless it is the spec itself
            raise SpecError(str(exc) if where == str(path) else f"{where}: {exc}") from None
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
        own = dict(tree)
        include = own.pop("include", [])
        unset = own.pop("unset", [])
        selection: Any = robot  # the command line's choice replaces the file's own
        if "robot" in own and not isinstance(own["robot"], Mapping):
            chosen = own.pop("robot")
            selection = chosen if selection is None else selection
        out: dict[str, Any] = {}
        if selection is not None:
            path = robot_file(selection, base, f"{source}: robot" if chain else "robot")
            where = f"{source}: robot {selection!r}" if chain else f"robot {selection!r}"
            if len(chain) <= 1 or self.top is None:  # the top level's, else the last read
                self.robot = path
                self.top = len(chain) <= 1 or None
            out.update(self.file(path, chain, where))
        if isinstance(include, str) or not isinstance(include, list) or not all(
                isinstance(i, str) and i.strip() for i in include):
            raise SpecError(f"{source}: include: expected a list of spec files (include = "
                            f"[\"my_robot.toml\"]), got {include!r}")
        for name in include:
            where = f"{source}: include {name!r}"
            out.update(self.file(file_path(name, base, where), chain, where))
        if isinstance(unset, str) or not isinstance(unset, list) or not all(
                isinstance(k, str) for k in unset):
            raise SpecError(f"{source}: unset: expected a list of spec keys (unset = "
                            f"[\"plan.goal\"]), got {unset!r}")
        for dotted in unset:
            remove_key(out, dotted, f"{source}: unset")
        out.update(dotted_keys(own))
        return out

    def named(self, out: dict[str, Any]) -> dict[str, Any]:
        """``out`` with the robot's name where no file set ``name`` (module docstring)."""
        from flatcli.spec.keys import SpecError as _Error
        from flatcli.spec.schema import check_value

        if "name" in out or self.robot is None or self.robot.stem == "paper":
            return out
        with contextlib.suppress(_Error):  # a stem that names no directory (".x"): the default
            out["name"] = check_value("name", self.robot.stem)
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
    return composer.named(composer.tree(tree, base, chain,
                                        str(source) if source is not None else "the spec", robot))

