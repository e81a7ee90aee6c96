"""What flatcli finds on disk, looked at before it is opened: only regular files are read,
never through a symbolic link, and never more bytes than a bound.

A FIFO, a socket or a device where flatcli expects one of its files would block (or never
end) if opened blindly; a directory there cannot be replaced by a file; a symbolic link may
lead out of the directory flatcli works in. So every file flatcli reads back (run.json,
sweep.json, metrics.json, chunk files, its tables) is first looked at with ``lstat`` and
refused unless it is a regular file, and JSON records are read with a size bound. Standard
library only: ``flatcli runs`` and the manifest checks need nothing heavier.
"""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Iterable
from pathlib import Path

from flatcli.core.errors import FlatcliError

#: Largest run record (run.json, metrics.json) read back [bytes]: a record holds a spec,
#: metrics and versions (a few KiB; a plan of a 100-link robot, about 100 KiB).
MAX_RECORD_BYTES = 8 << 20
#: Largest sweep manifest (sweep.json) read back [bytes]: about 300 bytes per grid cell, and
#: a sweep's grid has at most a few 1e5 cells (``flatcli.spec.limits``).
MAX_MANIFEST_BYTES = 256 << 20


class UnreadableFileError(OSError):
    """A file flatcli expected to read is missing, not a regular file, or too large (an
    OSError naming the file: the command line's one line for it, exit status 1)."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(errno.EINVAL, reason, str(path))
        self.path = path
        self.reason = reason

    def __str__(self) -> str:
        return f"{self.path}: {self.reason}"


def kind(path: Path) -> str:
    """What ``path`` is, without following a symbolic link: "missing", "file" (a regular
    file), or "a symbolic link", "a directory", "a FIFO", "a socket", "a device"."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return "missing"
    except NotADirectoryError:  # a parent is a file
        return "missing"
    return mode_kind(mode)


def mode_kind(mode: int) -> str:
    """``kind`` of an ``st_mode``."""
    if stat.S_ISREG(mode):
        return "file"
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a device"


def is_regular(path: Path) -> bool:
    """Whether ``path`` is a regular file itself (not a link to one)."""
    return kind(path) == "file"


def read_bounded(path: Path, limit: int) -> bytes:
    """The content of a regular file of at most ``limit`` bytes.

    The file is opened without following a symbolic link and without blocking (a FIFO
    opens at once, and is then refused unread), and at most ``limit + 1`` bytes are read.
    UnreadableFileError with the reason otherwise.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise UnreadableFileError(path, "not found") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise UnreadableFileError(path, "is a symbolic link, not a regular file") from None
        raise UnreadableFileError(path, exc.strerror or type(exc).__name__) from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise UnreadableFileError(path, f"is {mode_kind(info.st_mode)}, not a regular file")
        if info.st_size > limit:
            raise UnreadableFileError(path, f"is {info.st_size} bytes, more than the {limit} "
                                       "flatcli reads")
        chunks = []
        size = 0
        while size <= limit:
            block = os.read(fd, limit + 1 - size)
            if not block:
                break
            chunks.append(block)
            size += len(block)
    except OSError as exc:
        raise UnreadableFileError(path, exc.strerror or type(exc).__name__) from None
    finally:
        os.close(fd)
    if size > limit:
        raise UnreadableFileError(path, f"is more than the {limit} bytes flatcli reads")
    return b"".join(chunks)


def real_directory(directory: Path, relative: str) -> Path | None:
    """``directory / relative`` if ``relative`` is a plain relative path (no "..", no ".",
    not absolute; "." alone is ``directory``) and every component of it is a real
    directory (no symbolic link on the way), else None."""
    if relative in ("", "."):
        return directory
    parts = relative.split("/")
    if relative.startswith("/") or any(p in ("", ".", "..") for p in parts):
        return None
    path = directory
    for part in parts:
        path = path / part
        if kind(path) != "a directory":
            return None
    return path


def inside(directory: Path, relative: str) -> Path | None:
    """``directory / relative`` if every directory between them is a real one (no symbolic
    link on the way) and ``relative`` is a plain relative path, else None. The last
    component itself is not looked at."""
    parts = relative.split("/")
    if relative.startswith("/") or any(p in ("", ".", "..") for p in parts):
        return None
    parent = real_directory(directory, "/".join(parts[:-1]) or ".")
    return None if parent is None else parent / parts[-1]


def not_regular(directory: Path, names: Iterable[str]) -> list[str]:
    """Those of ``names`` (relative to ``directory``) that are there but are not regular
    files (a directory, a FIFO, a device, a symbolic link), each as ``name (what it is)``:
    where flatcli would read or replace one of its files, none of these may stand."""
    return [f"{name} ({what})" for name in names
            if (what := kind(directory / name)) not in ("missing", "file")]


def read_text(path: Path, limit: int = MAX_MANIFEST_BYTES) -> str:
    """A regular file's text (``read_bounded``; bytes that are not UTF-8 replaced)."""
    return read_bounded(path, limit).decode("utf-8", "replace")


def read_named_text(path: Path, what: str, limit: int) -> str:
    """The UTF-8 text of a file a user names (``what``: "spec file", "URDF file"), following
    a symbolic link; FlatcliError naming it for a missing, unreadable, oversized (> ``limit``
    bytes) or non-regular file (a FIFO or a device is refused without reading from it) and
    for text that is not UTF-8."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise FlatcliError(f"{what} not found: {path}") from None
    except OSError as exc:
        raise FlatcliError(f"cannot read {what} {path}: {exc.strerror}") from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise FlatcliError(f"{what} is a directory: {path}")
        if not stat.S_ISREG(info.st_mode):
            raise FlatcliError(f"{what} {path} is not a regular file (a FIFO, socket or "
                            "device)")
        if info.st_size > limit:
            raise FlatcliError(f"{what} {path} is {info.st_size} bytes, more than the "
                            f"{limit} a {what.split()[0]} may have")
        data = b""
        while len(data) <= limit:
            block = os.read(fd, limit + 1 - len(data))
            if not block:
                break
            data += block
    except OSError as exc:
        raise FlatcliError(f"cannot read {what} {path}: {exc.strerror}") from None
    finally:
        os.close(fd)
    if len(data) > limit:
        raise FlatcliError(f"{what} {path} is more than the {limit} bytes a {what.split()[0]} "
                        "may have")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FlatcliError(f"{what} {path} is not UTF-8 text (byte {exc.start})") from None
    return text
