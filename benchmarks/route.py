"""How far one spec key travels: ``track.kp`` followed from the command line to the kernel,
at run time (issue 38's Done-when: at most 12 files, at most 20 returns to a file left).

    python -m benchmarks.route                  # the paper's robot
    python -m benchmarks.route --robot chain4 --set 'track.kp=[123.456,110,120]' \
        --set 'track.kv=[10,13,12]'

It runs ``flatcli track`` in this process (click's runner) with kp_1 = 123.456, a value no
default holds, under ``sys.settrace``, and records every call of a function of flatcli whose
arguments hold that value: directly (the float, a sequence, mapping or float array holding
it, a string spelling it, or a record two attribute levels down), or, for a record that holds
it deeper (the whole spec), a function that names ``kp`` or the gains. Consecutive calls in
one file are one stay. The route ends at the last stay before the compiled kernel runs
(``core/loop/kernels.py``); the stays after it
write the outputs. It prints the stays, the files and the returns to a file already left.

A static walk (``farm-studio walk``) follows every branch the code could take, for every
spec field at once; this follows one run and the one key.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from types import FrameType
from typing import Any

import numpy as np

MARK = 123.456
#: A function holding the spec that names one of these reads the gains.
NAMES = frozenset({"kp", "track.kp", "gains", "Gains"})
#: The route ends in the last of these files before the outputs are written.
KERNEL_FILES = ("core/loop/kernels.py",)


def holds(value: Any, depth: int = 0) -> bool:
    """Whether ``value`` holds MARK (module docstring)."""
    try:
        if isinstance(value, float):
            return value == MARK
        if isinstance(value, str):
            return str(MARK) in value
        if isinstance(value, np.ndarray):
            return value.dtype.kind == "f" and value.size < 10 ** 6 and bool(np.any(value == MARK))
        if isinstance(value, (list, tuple)):
            return any(holds(item, depth) for item in value[:50])
        if isinstance(value, dict):
            return any(holds(item, depth) for item in list(value.values())[:200])
        if depth >= 2 or isinstance(value, type):
            return False
        fields: tuple[str, ...] = ()
        if hasattr(value, "_fields"):
            fields = value._fields
        elif hasattr(value, "__dataclass_fields__"):
            fields = tuple(value.__dataclass_fields__)
        elif hasattr(value, "__dict__"):
            fields = tuple(vars(value))
        return any(holds(getattr(value, name, None), depth + 1) for name in fields[:50])
    except Exception:  # a record whose attribute raises holds nothing we can see
        return False


def tracer(root: str, stays: list[tuple[str, str]]) -> Callable[..., Any]:
    """A ``sys.settrace`` function recording (file under ``root``, function) per stay."""
    def trace(frame: FrameType, event: str, arg: Any) -> None:
        if event != "call" or not frame.f_code.co_filename.startswith(root):
            return
        code = frame.f_code
        count = code.co_argcount + code.co_kwonlyargcount
        arguments = [frame.f_locals.get(name) for name in code.co_varnames[:count]]
        names = set(code.co_names) | set(code.co_varnames) | {
            c for c in code.co_consts if isinstance(c, str)}
        if (any(holds(a, 2) for a in arguments)
                or (names & NAMES and any(holds(a) for a in arguments))):
            stays.append((code.co_filename[len(root):], code.co_name))
    return trace


def route(stays: list[tuple[str, str]]) -> list[tuple[str, list[str]]]:
    """The stays up to the kernel, consecutive calls in one file merged."""
    merged: list[tuple[str, list[str]]] = []
    for name, function in stays:
        if merged and merged[-1][0] == name:
            if function not in merged[-1][1]:
                merged[-1][1].append(function)
        else:
            merged.append((name, [function]))
    last = max((i for i, (name, _) in enumerate(merged) if name in KERNEL_FILES), default=-1)
    return merged[: last + 1]


def returns(files: list[str]) -> int:
    """How many stays enter a file the route had already left."""
    left: set[str] = set()
    count = 0
    for i, name in enumerate(files):
        count += name in left
        if i:
            left.add(files[i - 1])
    return count


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="runs/route", help="the track run's directory")
    _, extra = parser.parse_known_args(argv)
    args = parser.parse_args([a for a in (argv or sys.argv[1:]) if a not in extra])
    from click.testing import CliRunner

    import flatcli
    from flatcli.cli import main as cli
    root = os.path.dirname(os.path.abspath(flatcli.__file__)) + os.sep
    stays: list[tuple[str, str]] = []
    sys.settrace(tracer(root, stays))
    try:
        result = CliRunner().invoke(cli, ["track", "--out", args.out, "--force", "-q", "--set",
                                          f"track.kp=[{MARK},110]", *extra])
    finally:
        sys.settrace(None)
    if result.exit_code != 0:
        print(result.output.strip())
        return 2
    path = route(stays)
    for i, (name, functions) in enumerate(path, 1):
        print(f"{i:3d}  {name:36s} {' '.join(functions[:6])}")
    files = [name for name, _ in path]
    print(f"track.kp from the command line to the kernel: {len(set(files))} files, "
          f"{returns(files)} returns to a file already left")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
