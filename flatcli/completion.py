"""Shell completion of ``--set`` keys and values and of ``--robot``, without the numerical
libraries (a shell asks on every Tab: it must answer at once).

The keys and their words are the schema's (``flatcli.spec.schema``), whose choices come from
``flatcli.core.names``: neither loads numpy or numba (``tests/test_completion.py``). Turn
completion on with ``eval "$(_FLATCLI_COMPLETE=bash_source flatcli)"`` (``zsh_source``,
``fish_source``).
"""

from __future__ import annotations

from functools import cache
from importlib import resources
from typing import Any


@cache
def set_words() -> dict[str, tuple[str, ...]]:
    """Every dotted key of the spec and the words it takes (its choices; true, false for a
    flag; none for a number or a list): completed as ``KEY=``, then after ``KEY=``."""
    from flatcli.spec.schema import SCHEMA

    words: dict[str, tuple[str, ...]] = {}
    for section, keys in SCHEMA.items():
        for name, key in keys.items():
            dotted = f"{section}.{name}" if section else name
            words[dotted] = (tuple(key.choices) if key.kind == "choice" else
                             ("true", "false") if key.kind == "bool" else ())
    return words


def robot_names() -> list[str]:
    """The robot files shipped with flatcli (``flatcli.spec.compose.robot_names``)."""
    folder = resources.files("flatcli") / "data" / "robots"
    return sorted(p.name.removesuffix(".toml") for p in folder.iterdir()
                  if p.name.endswith(".toml"))


def set_items(incomplete: str) -> list[tuple[str, str]]:
    """Completions of a ``--set`` item: ``(value, help)``; a key with ``=`` appended, or after
    ``KEY=`` the key's words (a robot file's name for ``robot=``)."""
    key, sep, value = incomplete.partition("=")
    if sep:
        words = robot_names() if key == "robot" else set_words().get(key, ())
        return [(f"{key}={w}", "") for w in words if w.startswith(value)]
    keys = [*set_words(), "robot"]
    return [(f"{k}=", "robot file (chain4, ...)" if k == "robot" else "")
            for k in keys if k.startswith(incomplete)]


def complete_set(ctx: Any, param: Any, incomplete: str) -> list[Any]:
    """click's ``shell_complete`` of ``--set``: no space after ``KEY=``."""
    from click.shell_completion import CompletionItem

    return [CompletionItem(v, help=h or None) for v, h in set_items(incomplete)]


def complete_robot(ctx: Any, param: Any, incomplete: str) -> list[Any]:
    """click's ``shell_complete`` of ``--robot``: the shipped robots, or a file."""
    from click.shell_completion import CompletionItem

    if "/" in incomplete or incomplete.endswith((".toml", ".urdf")) or incomplete.startswith("."):
        return [CompletionItem(incomplete, type="file")]
    return [CompletionItem(n) for n in robot_names() if n.startswith(incomplete)]
