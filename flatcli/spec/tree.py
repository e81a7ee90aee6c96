"""Spec trees (a TOML file, a spec's or a run record's ``tree``) and their dotted keys, each
walk written once: ``read_toml``, ``flatten``, ``value_at``, ``put``."""

from __future__ import annotations

import os
import stat
import tomllib
from collections.abc import Callable, Mapping, MutableMapping
from pathlib import Path
from typing import Any

from flatcli.spec.keys import SpecError
from flatcli.spec.limits import MAX_SPEC_BYTES


def flatten(tree: Mapping[str, Any],
            enter: Callable[[str, Mapping[str, Any]], bool] = lambda dotted, table: bool(table),
            *, quote: bool = False, prefix: str = "") -> dict[str, Any]:
    """{dotted key: value} of a nested tree: a table is entered where ``enter(dotted key,
    table)`` says so (by default every table that is not empty) and is otherwise one value;
    with ``quote`` a name that holds a dot is quoted, as TOML writes it
    (``sweep.grid."plant.com"``)."""
    out: dict[str, Any] = {}
    for name, value in tree.items():
        part = f'"{name}"' if quote and "." in name else name
        dotted = f"{prefix}.{part}" if prefix else part
        if isinstance(value, Mapping) and enter(dotted, value):
            out.update(flatten(value, enter, quote=quote, prefix=dotted))
        else:
            out[dotted] = value
    return out


def value_at(tree: Any, dotted: str) -> Any:
    """The value of a dotted key in a nested tree, or None where the tree has none."""
    node = tree
    for part in dotted.split("."):
        node = node.get(part) if isinstance(node, Mapping) else None
    return node


def put(tree: MutableMapping[str, Any], dotted: str, value: Any) -> None:
    """Set a dotted key of a nested tree whose tables exist."""
    *parents, last = dotted.split(".")
    node = tree
    for part in parents:
        node = node[part]
    node[last] = value


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML file; SpecError for a missing, unreadable, oversized or non-regular file
    (a FIFO or a device is refused without reading from it), for text that is not UTF-8,
    and for TOML that is invalid or nested too deeply."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise SpecError(f"spec file not found: {path}") from None
    except OSError as exc:
        raise SpecError(f"cannot read spec file {path}: {exc.strerror}") from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise SpecError(f"spec file is a directory: {path}")
        if not stat.S_ISREG(info.st_mode):
            raise SpecError(f"spec file {path} is not a regular file (a FIFO, socket or "
                            "device); give a TOML file")
        if info.st_size > MAX_SPEC_BYTES:
            raise SpecError(f"spec file {path} is {info.st_size} bytes, more than the "
                            f"{MAX_SPEC_BYTES} a spec may have")
        data = b""
        while len(data) <= MAX_SPEC_BYTES:
            block = os.read(fd, MAX_SPEC_BYTES + 1 - len(data))
            if not block:
                break
            data += block
    except OSError as exc:
        raise SpecError(f"cannot read spec file {path}: {exc.strerror}") from None
    finally:
        os.close(fd)
    if len(data) > MAX_SPEC_BYTES:
        raise SpecError(f"spec file {path} is more than the {MAX_SPEC_BYTES} bytes a spec may "
                        "have")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SpecError(f"spec file {path} is not UTF-8 text (byte {exc.start})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"spec file {path} is not valid TOML: {exc}") from None
    except RecursionError:
        raise SpecError(f"spec file {path}: TOML nested too deeply") from None
