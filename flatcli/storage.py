"""All file output of flatcli: atomic writes, Parquet with provenance, run records, and the
one-writer lock of an output directory.

Every file is written to a temporary name in its own directory, flushed to disk, then
renamed over its final name, so a reader (or a resumed sweep) sees either the old file or
the complete new one, never a half-written file; a reader that opened the old file keeps
reading it after the rename. ``directory_lock`` holds an OS-level lock (``flock``) on a
directory's ``.flatcli.lock`` for as long as a run writes there, so two runs never mix
their files; the kernel releases it when the process ends, however it ends.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import math
import os
import platform
import re
import socket
import stat
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

import flatcli
from flatcli.core.errors import FlatcliError
from flatcli.files import kind

if TYPE_CHECKING:  # pandas loads with the first DataFrame: a sweep writes Arrow tables only
    import pandas as pd

#: Key of the Parquet schema metadata holding flatcli's provenance (JSON).
PARQUET_META_KEY = b"flatcli"


def _read_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


@contextlib.contextmanager
def atomic_path(path: Path, syncer: Syncer | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (in its directory, so the rename is atomic);
    on success flush it to disk and rename it over ``path``. An OS error on the way names
    ``path`` (not the temporary file, and never no file at all).

    With a ``syncer`` the file is renamed at once and flushed to disk later, with others, by
    the syncer's thread (``Syncer``): the file is whole whenever its name exists (the rename
    follows the last write), but until the syncer has flushed it a crash of the machine (not
    of the process: the kernel keeps what was written) may lose it."""
    with naming_os_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp",
                                        dir=path.parent)
        os.close(fd)
    tmp = Path(tmp_name)
    try:
        with naming_os_errors(path, tmp):
            yield tmp
            if syncer is None:
                with tmp.open("rb+") as fh:
                    os.fsync(fh.fileno())
            tmp.chmod(0o666 & ~_UMASK)  # mkstemp makes 0600; give the file the usual mode
            os.replace(tmp, path)
        if syncer is None:
            fsync_directory(path.parent)
        else:
            syncer.add(path)
    finally:
        tmp.unlink(missing_ok=True)


class Syncer:
    """Flushes files to disk in a thread of its own, in groups: ``add`` a renamed file
    (``atomic_path(path, syncer)``); the thread fsyncs every file added while it was busy,
    then their directories, once each (a group commit: one directory flush for many files,
    and none on the caller's time). ``close`` waits until every file added is on disk and
    raises the first OS error the thread met (naming the file).

    Chunk files of a sweep go through one (``montecarlo.runner``): a process killed at any
    moment loses nothing it wrote (the kernel has it), a machine that crashes may lose the
    chunks not yet flushed, or leave them damaged, and a resume's checks compute those again
    (``montecarlo.directory.verified_chunks``); the final tables and the manifest are flushed
    before they count (``atomic_path`` without a syncer)."""

    def __init__(self) -> None:
        import threading

        self._pending: list[Path] = []
        self._busy = False
        self._closed = False
        self._error: OSError | None = None
        self._changed = threading.Condition()
        self._thread: threading.Thread | None = None
        #: Files flushed, and seconds the thread spent flushing them.
        self.synced = 0
        self.seconds = 0.0

    def add(self, path: Path) -> None:
        import threading

        with self._changed:
            if self._closed:
                raise RuntimeError("Syncer: closed")
            self._pending.append(path)
            if self._thread is None:  # started with the first file: after the workers forked
                thread = threading.Thread(target=self._run, name="flatcli-sync", daemon=True)
                thread.start()
                self._thread = thread  # (not before: Ctrl-C may end start() early)
            self._changed.notify_all()

    def _run(self) -> None:
        while True:
            with self._changed:
                while not self._pending and not self._closed:
                    self._changed.wait()
                if not self._pending:
                    return
                group, self._pending = self._pending, []
                self._busy = True
            started = time.perf_counter()
            try:
                for path in group:
                    with naming_os_errors(path):
                        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
                        try:
                            os.fsync(fd)
                        finally:
                            os.close(fd)
                for directory in dict.fromkeys(p.parent for p in group):
                    fsync_directory(directory)
            except OSError as exc:
                with self._changed:
                    if self._error is None:
                        self._error = exc
            with self._changed:
                self.synced += len(group)
                self.seconds += time.perf_counter() - started
                self._busy = False
                self._changed.notify_all()

    def close(self) -> None:
        """Wait until every file added is flushed; raise the first OS error met."""
        with self._changed:
            self._closed = True
            self._changed.notify_all()
            thread = self._thread
        if thread is not None and thread.ident is not None:
            thread.join()
        if self._error is not None:
            raise self._error


@contextlib.contextmanager
def naming_os_errors(path: Path, tmp: Path | None = None) -> Iterator[None]:
    """Re-raise an OS error that names no file (or the temporary file ``tmp``) as one that
    names ``path``: what the user asked for, and what the one line of the CLI shows."""
    try:
        yield
    except OSError as exc:
        if exc.filename is not None and (tmp is None or exc.filename != str(tmp)):
            raise
        reason = exc.strerror or (str(exc).splitlines() or [type(exc).__name__])[0]
        raise OSError(exc.errno, reason, str(path)) from None


def fsync_directory(directory: Path) -> None:
    """Make a rename in ``directory`` durable (where the file system allows it)."""
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:  # pragma: no cover - a file system without directory handles
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - e.g. some network file systems
        pass
    finally:
        os.close(fd)


def write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def to_jsonable(value: Any) -> Any:
    """JSON-ready copy: numpy scalars and arrays as Python values; nan (not applicable) as
    null; inf and -inf as the strings "inf" and "-inf".

    JSON has no inf. The only infinite values flatcli writes are spec values whose inf means
    "no limit" (``track.rate_limit``, ``plan.optimize.angle_limit``, ...): null there would
    read as "not set" (which a nullable key means something else by), and "inf" is how TOML
    spells it and what the spec's canonical JSON (its digest) has always held. Measured values
    are never inf (a trial stops before its state leaves the divergence bound); a metric that
    does not apply is nan, hence null.
    """
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, float) and math.isinf(value):
        return str(value)
    return value


def top_sorted(value: Any) -> Any:
    """A mapping with its own keys sorted (stable, diffable records) and every mapping inside
    it in its own order: a spec's ``[sweep.grid]`` is enumerated in the order its keys are
    written, so a record that sorted them would hand back another grid (another cell under
    each index)."""
    if isinstance(value, Mapping):
        return {k: value[k] for k in sorted(value)}
    return value


def write_json(path: Path, obj: Any) -> None:
    """Pretty JSON, its top-level keys sorted, every table inside in its own order
    (``top_sorted``; nan as null, inf as "inf": ``to_jsonable``)."""
    write_text(path, json.dumps(top_sorted(to_jsonable(obj)), indent=2) + "\n")


def write_parquet(path: Path, frame: pd.DataFrame, provenance: Mapping[str, Any]) -> None:
    """Write a DataFrame as Parquet, with ``provenance`` as JSON in the schema metadata (nan as
    null, units from ``frame.attrs["units"]``: ``arrow_table``)."""
    write_table(path, arrow_table(frame), provenance)


def write_table(path: Path, table: pa.Table, provenance: Mapping[str, Any],
                syncer: Syncer | None = None) -> None:
    """Write an Arrow table as Parquet, with ``provenance`` as JSON in the schema metadata
    (``atomic_path``; flushed to disk now, or by ``syncer``). Dictionary encoding only for
    text columns (``parquet_options``)."""
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                           **provenance_metadata(provenance)})
    with atomic_path(path, syncer) as tmp:
        pq.write_table(table, tmp, **parquet_options(table.schema))


def parquet_options(schema: pa.Schema) -> dict[str, Any]:
    """How flatcli writes Parquet: dictionary-encoded text columns only. A dictionary of a
    float column (distinct values, nearly all of them) costs 5x the encoding time and makes
    the file larger; a text column (statuses, reasons) repeats a few values."""
    text = [f.name for f in schema if pa.types.is_string(f.type) or pa.types.is_large_string(
        f.type)]
    return {"use_dictionary": text}


def provenance_metadata(provenance: Mapping[str, Any]) -> dict[bytes, bytes]:
    """Parquet schema metadata holding ``provenance`` as JSON under ``PARQUET_META_KEY``."""
    return {PARQUET_META_KEY: json.dumps(top_sorted(to_jsonable(provenance))).encode()}


def table_checksum(table: pa.Table) -> str:
    """SHA-256 of a table's content: column names, types, nulls and values, in order.

    It depends on what the table holds, not on how a file stores it, so it is the same for
    a table and for that table written to Parquet and read back, and differs when any
    value, null or name differs.
    """
    from flatcli.arrow import null_mask, to_numpy  # (pyarrow's own to_numpy loads pandas)

    digest = hashlib.sha256()
    for name, column in zip(table.column_names, table.columns, strict=True):
        array = column.combine_chunks() if column.num_chunks != 1 else column.chunk(0)
        digest.update(f"{name}\0{_type_text(array.type)}\0{len(array)}\0{array.null_count}\0"
                      .encode())
        if array.null_count:
            digest.update(null_mask(array).tobytes())
        if pa.types.is_integer(array.type) or pa.types.is_floating(array.type) \
                or pa.types.is_boolean(array.type):
            digest.update(np.ascontiguousarray(to_numpy(array)).tobytes())  # nulls as 0
        else:
            digest.update(json.dumps(array.to_pylist(), default=str).encode())
    return digest.hexdigest()


def _type_text(kind: pa.DataType) -> str:
    """A type as text without the names Parquet gives a list's items ("item" in Arrow,
    "element" once read back), so that a table and its Parquet copy read the same."""
    if pa.types.is_list(kind) or pa.types.is_large_list(kind):
        return f"list<{_type_text(kind.value_type)}>"
    return str(kind)


def read_provenance(path: Path) -> dict[str, Any]:
    """The provenance a Parquet file was written with ({} if none)."""
    meta = pq.read_schema(path).metadata or {}
    raw = meta.get(PARQUET_META_KEY)
    return json.loads(raw) if raw else {}


def git_state() -> dict[str, Any]:
    """The git commit of flatcli's source tree (if a checkout), and whether it is dirty."""
    source = Path(flatcli.__file__).resolve().parent

    def run(*args: str) -> str:
        return subprocess.run(
            ["git", *args], capture_output=True, text=True, timeout=5, check=True, cwd=source
        ).stdout.strip()

    try:
        commit = run("rev-parse", "HEAD")
        dirty = bool(run("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit, "dirty": dirty}


def versions() -> dict[str, str]:
    """The versions of Python and of the libraries flatcli runs on; scipy's and pandas' from
    their installed metadata, so that a sweep need not load them to say which it has."""
    import numba

    return {
        "flatcli": flatcli.__version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": _installed("scipy"),
        "numba": numba.__version__,
        "pandas": _installed("pandas"),
        "pyarrow": pa.__version__,
    }


def _installed(name: str) -> str:
    """A library's version: its module's if it is loaded, else its installed metadata's."""
    module = sys.modules.get(name)
    if module is not None:
        return str(module.__version__)
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:  # pragma: no cover - a broken installation
        return "not installed"


def peak_memory_mib() -> float:
    """This process's own peak resident memory [MiB]: VmHWM of /proc/self/status (Linux),
    the peak of this process's address space since it started (or was forked).

    Not ``getrusage``'s ru_maxrss: Linux keeps that across exec, so a process started by a
    large one (``make bench`` starting ``flatcli sweep``) reports at least its parent's peak.
    Elsewhere ru_maxrss is all there is. A forked worker's VmHWM counts the pages it shares
    with its parent since the fork, as its resident memory does."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):  # pragma: no cover - not Linux
        pass
    import resource  # pragma: no cover

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # pragma: no cover


def run_record(command: str, spec_tree: Mapping[str, Any], **extra: Any) -> dict[str, Any]:
    """What a run directory's run.json holds: the resolved spec, versions, git, time, host."""
    return {
        "command": command,
        "argv": sys.argv,
        "spec": spec_tree,
        "versions": versions(),
        "git": git_state(),
        "time": datetime.now(UTC).isoformat(timespec="seconds"),
        "host": socket.gethostname(),
        "platform": platform.platform(),
        **extra,
    }


# ---------------------------------------------------------------------------------------
# Nulls and units of the Parquet tables.

#: Key of an Arrow field's metadata holding its column's unit (``flatcli.units``).
UNIT_KEY = b"unit"


def arrow_table(frame: pd.DataFrame) -> pa.Table:
    """An Arrow table of a DataFrame: nan as null (not applicable), and the units of
    ``frame.attrs["units"]`` ({column: unit}, if any) as field metadata (``with_units``)."""
    table = pa.Table.from_pandas(frame, preserve_index=False)  # nan -> null
    return with_units(table, frame.attrs.get("units", {}))


def null_where_nan(values: Any) -> pa.Array:
    """A float column as Arrow, nan (not applicable) as null."""
    from flatcli.arrow import numbers

    return numbers(values)


def with_units(table: pa.Table, units: Mapping[str, str]) -> pa.Table:
    """``table`` with ``units[name]`` under ``UNIT_KEY`` in the metadata of each named field
    (other fields as they were)."""
    fields = []
    for f in table.schema:
        if f.name in units:
            f = f.with_metadata({**(f.metadata or {}), UNIT_KEY: units[f.name].encode()})
        fields.append(f)
    # the same columns under a schema that differs in metadata only (Table.cast would load
    # pyarrow.compute, which a sweep has no other use for)
    return pa.Table.from_arrays(table.columns, schema=pa.schema(fields,
                                                                metadata=table.schema.metadata))


def column_units(path: Path) -> dict[str, str]:
    """{column: unit} of a Parquet file's columns that carry one."""
    return {f.name: f.metadata[UNIT_KEY].decode() for f in pq.read_schema(path)
            if f.metadata and UNIT_KEY in f.metadata}


# ---------------------------------------------------------------------------------------
# Output directories: usable, and one writer per directory.

def check_output_dir(directory: Path, option: str = "--out") -> None:
    """Refuse (FlatcliError) an output directory that cannot be made or written, before any
    work: one that is a file or lies under one, a name longer than the file system allows,
    a directory without write permission, a read-only file system."""
    path = directory.absolute()
    probe = path
    while not os.path.lexists(probe):
        probe = probe.parent
    if not probe.is_dir():
        what = "exists and is not a directory" if probe == path else f"{probe} is not a directory"
        raise FlatcliError(f"{option} {directory}: {what}")
    try:
        longest = os.pathconf(probe, "PC_NAME_MAX")
    except (OSError, ValueError):  # pragma: no cover - a file system that does not say
        longest = 255
    for part in path.relative_to(probe).parts:
        if len(os.fsencode(part)) > longest:
            raise FlatcliError(f"{option}: the name {part[:20]}... has {len(os.fsencode(part))} "
                               f"bytes, more than the {longest} the file system allows")
    if not os.access(probe, os.W_OK | os.X_OK):
        try:
            readonly = bool(os.statvfs(probe).f_flag & os.ST_RDONLY)
        except OSError:  # pragma: no cover
            readonly = False
        why = "the file system is read-only" if readonly else "no permission to write there"
        raise FlatcliError(f"{option} {directory}: cannot write in {probe}: {why}")


# ---------------------------------------------------------------------------------------
# One writer per output directory.

#: The lock file of an output directory (it holds the writer's pid and host).
LOCK_NAME = ".flatcli.lock"
#: Held briefly by a shard of a sweep while it reads and writes the directory's manifest
#: (``shard_locks``), so that shards starting together agree on one spec.
SETUP_LOCK_NAME = ".flatcli.setup.lock"
#: Held by the one run of each shard (``shard_lock_name``).
SHARD_LOCK = re.compile(r"\.flatcli\.shard-[0-9]{1,9}-of-[0-9]{1,9}\.lock")
#: What a shard writes into the directory's lock (``_holder`` reads it).
SHARDS_MARK = "shards"
#: How long a shard waits for another shard's set-up (a second or so each) [s].
SETUP_WAIT = 600.0
#: How long a shard waits for the directory's lock when another run holds it alone: a shard
#: that has finished its chunks holds it while it checks whether it is the last (and, if it
#: is and the study is whole, writes the final tables), so a shard starting at that moment
#: waits instead of being refused as if a sweep without shards were writing there [s].
SHARD_WAIT = 30.0


def shard_lock_name(index: int, count: int) -> str:
    """The lock file of shard ``index`` of ``count`` (1-based)."""
    return f".flatcli.shard-{index}-of-{count}.lock"


class DirectoryBusyError(FlatcliError):
    """Another run holds the directory's lock (a usage error: exit status 2)."""


#: Locks this process holds: resolved path of the lock file -> [fd, depth, shared].
_HELD: dict[str, list[int]] = {}


def _missing_ancestors(directory: Path) -> list[Path]:
    """``directory`` and its ancestors that do not exist yet, deepest first."""
    missing = []
    path = directory.absolute()
    while not os.path.lexists(path):
        missing.append(path)
        if path.parent == path:  # pragma: no cover - the root always exists
            break
        path = path.parent
    return missing


def _holder(fd: int) -> str:
    """Who holds the lock, as its holder wrote it ("pid 123", "pid 123 on host", or the
    shards of a sweep), waiting briefly for a new holder to write."""
    for _ in range(20):
        text = os.pread(fd, 200, 0).decode("utf-8", "replace").split()
        if text:
            shards = text[0] == SHARDS_MARK
            if shards:
                text = text[1:] or ["unknown"]
            pid = text[0]
            host = text[1] if len(text) > 1 else ""
            who = f"pid {pid}" + (f" on {host}" if host and host != socket.gethostname()
                                  else "")
            return f"shards of a sweep, one of them {who}" if shards else who
        time.sleep(0.05)
    return "pid unknown"


def _acquire(directory: Path, name: str = LOCK_NAME, shared: bool = False,
             wait: float = 0.0, busy: str | None = None) -> int:
    """An open descriptor of ``directory/name`` holding its ``flock`` (shared or exclusive),
    waiting up to ``wait`` seconds for it; DirectoryBusyError (``busy``, or the standard
    line naming the holder) if it cannot be had."""
    path = directory / name
    deadline = time.monotonic() + wait
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW
                         | os.O_NONBLOCK, 0o644)
        except FileNotFoundError:  # a refused run removed the directory it had created
            directory.mkdir(parents=True, exist_ok=True)
            continue
        except OSError as exc:
            if exc.errno not in (errno.ELOOP, errno.EISDIR, errno.ENXIO):
                raise
            raise FlatcliError(f"{path} is {kind(path)}, not flatcli's lock file; remove it "
                               "yourself, or use another --out") from None
        if not stat.S_ISREG(os.fstat(fd).st_mode):  # a FIFO, a device: never flatcli's
            os.close(fd)
            raise FlatcliError(f"{path} is {kind(path)}, not flatcli's lock file; remove it "
                               "yourself, or use another --out")
        try:
            fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                os.close(fd)
                raise
            if time.monotonic() < deadline:
                os.close(fd)
                time.sleep(0.05)
                continue
            holder = _holder(fd)
            os.close(fd)
            raise DirectoryBusyError(
                (busy or "{directory} is being written by another flatcli run ({holder}); "
                 "wait for it to finish, or use another --out").format(
                    directory=directory, holder=holder)
            ) from None
        # the file may have been removed (by a run that created the directory and wrote
        # nothing, or by the last holder as it ended) between our open and our lock: then
        # lock the new one
        try:
            now = os.stat(path, follow_symlinks=False)
        except FileNotFoundError:
            os.close(fd)
            continue
        mine = os.fstat(fd)
        if (mine.st_dev, mine.st_ino) != (now.st_dev, now.st_ino):
            os.close(fd)
            continue
        if not shared:  # (a shard writes its line once it holds its own lock too)
            _write_holder(fd)
        return fd


def _write_holder(fd: int, shards: bool = False) -> None:
    """Write who holds a lock into it, for a refused run to name (``_holder``)."""
    line = f"{SHARDS_MARK + ' ' if shards else ''}{os.getpid()} {socket.gethostname()}\n"
    os.ftruncate(fd, 0)
    os.pwrite(fd, line.encode(), 0)


@contextlib.contextmanager
def directory_lock(directory: Path, shared: bool = False) -> Iterator[None]:
    """Hold ``directory``'s lock for the block: the one writer there (``DirectoryBusyError``,
    naming the holder's pid, if another process holds it).

    ``shared``: held together with other shared holders (the shards of one sweep,
    ``shard_locks``), never with an exclusive one. The directory is created if need be; if
    the block leaves nothing in a directory it created, the directory is removed again (a
    refused run writes nothing). The lock file is removed when the block ends if this run
    created it (one left by a killed run stays, harmless: the kernel released its lock); a
    shared holder removes it only when no other holder is left. Nested use in one process is
    allowed (in the mode held first). The lock is an ``flock`` on ``.flatcli.lock``, released
    by the kernel when the process ends, even by kill -9.
    """
    with _lock(directory, LOCK_NAME, shared):
        yield


@contextlib.contextmanager
def _lock(directory: Path, name: str, shared: bool = False, wait: float = 0.0,
          busy: str | None = None, remove: bool = False) -> Iterator[int]:
    """Hold ``directory/name``'s lock for the block (see ``directory_lock``); yields its
    descriptor. ``remove``: remove the lock file when the block ends whoever created it (a
    lock file of a killed run's goes then too)."""
    key = os.path.realpath(directory / name)
    held = _HELD.get(key)
    if held is not None:
        held[1] += 1
        try:
            yield held[0]
        finally:
            held[1] -= 1
        return
    created = _missing_ancestors(directory)
    directory.mkdir(parents=True, exist_ok=True)
    new_lock = not os.path.lexists(directory / name)
    try:
        fd = _acquire(directory, name, shared, wait, busy)
    except BaseException:
        _remove_empty(created)
        raise
    _HELD[key] = [fd, 1, int(shared)]
    try:
        yield fd
    finally:
        del _HELD[key]
        try:
            last = new_lock or remove
            if shared:  # the last holder removes it (a waiting run re-checks the file)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    last = True
                except OSError:
                    last = False
            if last:  # a run leaves no lock file behind (a waiting run re-checks it)
                (directory / name).unlink()
            if created and not any(directory.iterdir()):
                _remove_empty(created)
        except OSError:  # pragma: no cover - best effort; the lock is released below
            pass
        os.close(fd)


class ShardLocks:
    """What ``shard_locks`` yields: ``setup()``, the lock that serialises the shards' reading
    and writing of the manifest (a context manager), and ``running()``, which writes this
    shard's pid into the directory's lock once its set-up has passed (a run refused there
    names one of the shards that are running, not one that was refused)."""

    def __init__(self, directory: Path, fd: int) -> None:
        self._directory, self._fd = directory, fd

    def setup(self) -> contextlib.AbstractContextManager[int]:
        return _lock(self._directory, SETUP_LOCK_NAME, wait=SETUP_WAIT, remove=True,
                     busy=f"{{directory}}: another shard's set-up held its lock for "
                          f"{SETUP_WAIT:g} s ({{holder}})")

    def running(self) -> None:
        _write_holder(self._fd, shards=True)  # (over another shard's line: one of them)


@contextlib.contextmanager
def shard_locks(directory: Path, index: int, count: int) -> Iterator[ShardLocks]:
    """Hold what a shard of a sweep holds while it runs: the directory's lock, shared with
    the other shards (so no other run writes there meanwhile; held alone by another run, it
    is waited for up to ``SHARD_WAIT``: a finishing shard's check), and its own shard's lock
    (so each shard runs once at a time: DirectoryBusyError otherwise)."""
    with _lock(directory, LOCK_NAME, shared=True, wait=SHARD_WAIT) as fd, _lock(
            directory, shard_lock_name(index, count), remove=True,
            busy=f"{{directory}}: shard {index}/{count} is being run by another flatcli run "
                 "({holder}); wait for it to finish"):
        yield ShardLocks(directory, fd)


def _remove_empty(created: list[Path]) -> None:
    for path in created:  # deepest first
        try:
            path.rmdir()
        except OSError:
            return


def forget_inherited_locks() -> None:
    """In a forked child: close the lock descriptors inherited from the parent, so that the
    lock is released when the parent ends, whatever the child does."""
    for fd, *_ in _HELD.values():
        with contextlib.suppress(OSError):
            os.close(fd)
    _HELD.clear()
