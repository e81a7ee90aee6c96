"""Atomic writes, provenance, content checksums, and the one-writer lock of a directory."""

from __future__ import annotations

import errno
import json
import math
import multiprocessing
import os
import signal
import stat
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from flatcli.core.errors import FlatcliError
from flatcli.storage import (
    LOCK_NAME,
    UNIT_KEY,
    DirectoryBusyError,
    Syncer,
    atomic_path,
    check_output_dir,
    column_units,
    directory_lock,
    null_where_nan,
    read_provenance,
    run_record,
    table_checksum,
    to_jsonable,
    with_units,
    write_json,
    write_parquet,
    write_table,
    write_text,
)


def test_atomic_path_leaves_no_file_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "out.txt"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash mid-write")
    assert not target.exists()
    assert list((tmp_path / "sub").iterdir()) == []


def test_atomic_path_replaces_whole_file(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    write_text(target, "old")
    with atomic_path(target) as tmp:
        tmp.write_text("new")
        assert target.read_text() == "old"  # readers see the old file until the rename
    assert target.read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's 0600


def test_json_handles_numpy_and_non_finite(tmp_path: Path) -> None:
    path = tmp_path / "a.json"
    write_json(path, {"b": np.float64(1.5), "a": [np.int64(2), math.inf], "c": np.array([1.0]),
                      "d": np.float64(math.nan)})
    # nan (not applicable) is null; inf (a spec's "no limit") the string TOML spells it with
    assert json.loads(path.read_text()) == {"a": [2, "inf"], "b": 1.5, "c": [1.0], "d": None}
    assert "nan" not in path.read_text().lower()
    assert to_jsonable({"x": (1, math.nan, -math.inf)}) == {"x": [1, None, "-inf"]}


def test_parquet_nulls_for_nan_and_units_as_field_metadata(tmp_path: Path) -> None:
    frame = pd.DataFrame({"t": [0.0, 1.0], "err": [0.5, math.nan], "status": ["ok", "diverged"],
                          "com": [[0.1, 0.0], [0.1, 0.005]]})
    frame.attrs["units"] = {"t": "s", "err": "rad", "com": "m"}
    path = tmp_path / "x.parquet"
    write_parquet(path, frame, {"digest": "abc"})
    table = pq.read_table(path)
    assert table.column("err").null_count == 1
    assert not pc.any(pc.is_nan(table.column("err"))).as_py()
    assert pa.types.is_list(table.schema.field("com").type)
    assert column_units(path) == {"t": "s", "err": "rad", "com": "m"}
    assert read_provenance(path) == {"digest": "abc"}
    # a table built from arrays: nan -> null, units attached to the named fields only
    arrays = pa.table({"a": null_where_nan([1.0, math.nan]), "b": ["x", "y"]})
    table = with_units(arrays, {"a": "kg"})
    assert table.column("a").null_count == 1
    assert table.schema.field("a").metadata == {UNIT_KEY: b"kg"}
    assert table.schema.field("b").metadata is None


def test_parquet_round_trip_with_provenance(tmp_path: Path) -> None:
    frame = pd.DataFrame({"t": np.linspace(0, 1, 5), "status": ["ok"] * 5})
    path = tmp_path / "x.parquet"
    write_parquet(path, frame, {"digest": "abc", "spec": {"name": "x"}})
    pd.testing.assert_frame_equal(pd.read_parquet(path), frame)
    assert read_provenance(path) == {"digest": "abc", "spec": {"name": "x"}}


def test_run_record_has_versions_git_and_time() -> None:
    record = run_record("plan", {"name": "x"}, extra=1)
    assert record["command"] == "plan" and record["extra"] == 1
    assert {"flatcli", "numpy", "scipy", "numba"} <= set(record["versions"])
    assert set(record["git"]) == {"commit", "dirty"}
    assert record["time"].endswith("+00:00")


def test_a_reader_holding_the_old_file_still_reads_it_after_an_atomic_replace(
        tmp_path: Path) -> None:
    path = tmp_path / "t.parquet"
    old = pd.DataFrame({"x": np.arange(1000.0)})
    write_parquet(path, old, {"digest": "old"})
    reader = pq.ParquetFile(path)  # holds the file open, reads row groups on demand
    with path.open("rb") as raw:
        head = raw.read(4)
        write_parquet(path, pd.DataFrame({"x": -np.arange(10.0)}), {"digest": "new"})
        rest = raw.read()  # a file replaced in place would end (or change) under the reader
    pd.testing.assert_frame_equal(reader.read().to_pandas(), old)
    assert head + rest == _parquet_bytes(old, {"digest": "old"}, tmp_path)
    assert read_provenance(path) == {"digest": "new"}
    assert len(pd.read_parquet(path)) == 10


def _parquet_bytes(frame: pd.DataFrame, provenance: dict[str, str], tmp_path: Path) -> bytes:
    again = tmp_path / "again.parquet"
    write_parquet(again, frame, provenance)
    return again.read_bytes()


def test_table_checksum_follows_the_content_not_the_file() -> None:
    table = pa.table({"trial": pa.array([1, 2, 3]), "x": pa.array([0.5, None, np.nan]),
                      "status": pa.array(["ok", None, "error"]),
                      "com": pa.array([[0.1, 0.0], None, [0.2, 0.1]])})  # a grid list column
    buffer = pa.BufferOutputStream()
    pq.write_table(table.replace_schema_metadata({b"k": b"v"}), buffer)
    back = pq.read_table(pa.BufferReader(buffer.getvalue()))
    assert table_checksum(back) == table_checksum(table)
    assert table_checksum(table) == table_checksum(pa.concat_tables([table.slice(0, 1),
                                                                       table.slice(1)]))
    changes = [
        table.set_column(1, "x", pa.array([0.5, 0.0, np.nan])),  # a null became 0
        table.set_column(1, "x", pa.array([0.5000000000000001, None, np.nan])),  # one ulp
        table.set_column(2, "status", pa.array(["ok", None, "errors"])),
        table.rename_columns(["trial", "y", "status", "com"]),
        table.set_column(3, "com", pa.array([[0.1, 0.0], None, [0.2, 0.2]])),
        table.set_column(0, "trial", pa.array([1, 2, 3], type=pa.int32())),
        table.slice(0, 2),
    ]
    digests = {table_checksum(t) for t in [table, *changes]}
    assert len(digests) == len(changes) + 1


def _hold_lock(directory: str, ready: Any, release: Any) -> None:
    with directory_lock(Path(directory)):
        ready.set()
        release.wait(60)


def test_a_second_writer_is_refused_naming_the_holders_pid(tmp_path: Path) -> None:
    directory = tmp_path / "out"
    context = multiprocessing.get_context("spawn")
    ready, release = context.Event(), context.Event()
    holder = context.Process(target=_hold_lock, args=(str(directory), ready, release))
    holder.start()
    try:
        assert ready.wait(60)
        with pytest.raises(DirectoryBusyError, match=rf"being written by another flatcli run "
                                                     rf"\(pid {holder.pid}\)"), \
                directory_lock(directory):
            pass
    finally:
        release.set()
        holder.join(60)
    with directory_lock(directory), directory_lock(directory):  # nested in one process: fine
        (directory / "x").write_text("")
        assert (directory / LOCK_NAME).is_file()
    assert sorted(p.name for p in directory.iterdir()) == ["x"]  # the lock file went with it


def test_a_killed_holder_releases_the_lock(tmp_path: Path) -> None:
    directory = tmp_path / "out"
    context = multiprocessing.get_context("spawn")
    ready, release = context.Event(), context.Event()
    holder = context.Process(target=_hold_lock, args=(str(directory), ready, release))
    holder.start()
    assert ready.wait(60)
    os.kill(holder.pid, signal.SIGKILL)
    holder.join(60)
    with directory_lock(directory):
        assert (directory / LOCK_NAME).read_text().split()[0] == str(os.getpid())


def test_a_directory_made_for_a_lock_and_left_empty_is_removed(tmp_path: Path) -> None:
    directory = tmp_path / "a" / "b"
    with pytest.raises(RuntimeError), directory_lock(directory):
        raise RuntimeError("refused before writing anything")
    assert not (tmp_path / "a").exists()
    existing = tmp_path / "kept"
    existing.mkdir()
    with directory_lock(existing):
        pass
    assert existing.is_dir()


def test_unusable_output_directories_are_refused_up_front(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    with pytest.raises(FlatcliError, match="exists and is not a directory"):
        check_output_dir(tmp_path / "file")
    with pytest.raises(FlatcliError, match="file is not a directory"):
        check_output_dir(tmp_path / "file" / "sub")
    with pytest.raises(FlatcliError, match="more than the 255 the file system allows"):
        check_output_dir(tmp_path / ("x" * 300))
    check_output_dir(tmp_path / "new" / "deeper")
    assert not (tmp_path / "new").exists()  # nothing made


def test_the_temporary_file_is_beside_its_target(tmp_path: Path) -> None:
    # in the target's own directory: the rename is then atomic (one file system); a
    # temporary file in the system's temp directory could not be renamed atomically
    target = tmp_path / "sub" / "out.parquet"
    with atomic_path(target) as tmp:
        assert tmp.parent == target.parent and tmp.name.startswith(".out.parquet.")
        assert tmp.name.endswith(".tmp") and tmp.exists()
        tmp.write_text("x")
    assert target.read_text() == "x"


def test_the_file_is_flushed_to_disk_before_it_is_renamed(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    events: list[tuple[str, int]] = []
    fsync, replace = os.fsync, os.replace

    def logged_fsync(fd: int) -> None:
        info = os.fstat(fd)
        events.append(("fsync-dir" if stat.S_ISDIR(info.st_mode) else "fsync", info.st_ino))
        fsync(fd)

    def logged_replace(src: Any, dst: Any) -> None:
        events.append(("replace", os.stat(src).st_ino))
        replace(src, dst)

    monkeypatch.setattr(os, "fsync", logged_fsync)
    monkeypatch.setattr(os, "replace", logged_replace)
    target = tmp_path / "out.txt"
    write_text(target, "data")
    inode = target.stat().st_ino
    assert events[:2] == [("fsync", inode), ("replace", inode)]  # the data first, then the name
    assert events[2] == ("fsync-dir", tmp_path.stat().st_ino)  # and the rename made durable


def test_an_os_error_while_writing_names_the_target(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "plan.parquet"

    def failing_fsync(fd: int) -> None:
        raise OSError(errno.EIO, "Input/output error")  # no file named, as the kernel says it

    monkeypatch.setattr(os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="Input/output error") as caught:
        write_text(target, "x")
    assert caught.value.filename == str(target) and caught.value.errno == errno.EIO
    monkeypatch.undo()
    with pytest.raises(OSError) as caught, atomic_path(target) as tmp:
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert caught.value.filename == str(target)  # not the temporary name
    assert list(tmp_path.iterdir()) == []


def test_table_checksum_sees_where_the_nulls_are() -> None:
    # the same number of nulls and the same values once nulls are filled: only the mask differs
    a = pa.table({"x": pa.array([None, 0.0]), "n": pa.array([None, 0], type=pa.int64())})
    b = pa.table({"x": pa.array([0.0, None]), "n": pa.array([0, None], type=pa.int64())})
    assert table_checksum(a) != table_checksum(b)
    assert table_checksum(a.select(["n"])) != table_checksum(b.select(["n"]))
    flags = [pa.table({"f": pa.array(v, type=pa.bool_())}) for v in ([None, False], [False, None])]
    assert table_checksum(flags[0]) != table_checksum(flags[1])


def test_the_output_check_asks_for_write_permission(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    readable = tmp_path / "readable"
    readable.mkdir()
    access = os.access

    def no_write(path: Any, mode: int, **kwargs: Any) -> bool:  # a directory mode 0o555
        if Path(path) == readable and mode & os.W_OK:
            return False
        return access(path, mode, **kwargs)

    monkeypatch.setattr(os, "access", no_write)
    with pytest.raises(FlatcliError, match=r"cannot write in .*readable: no permission to "
                                           "write there"):
        check_output_dir(readable / "run")
    with pytest.raises(FlatcliError, match="no permission"):
        check_output_dir(readable)
    check_output_dir(tmp_path / "elsewhere")


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into any directory")
def test_a_directory_without_write_permission_is_refused(tmp_path: Path) -> None:
    readable = tmp_path / "readable"
    readable.mkdir(mode=0o555)
    with pytest.raises(FlatcliError, match="no permission to write there"):
        check_output_dir(readable / "run")


@pytest.mark.timeout(30, method="thread")  # a FIFO opened blindly would block
@pytest.mark.parametrize("what", ["a FIFO", "a directory", "a symbolic link"])
def test_a_lock_file_that_is_not_a_regular_file_is_refused(tmp_path: Path, what: str) -> None:
    lock = tmp_path / LOCK_NAME
    if what == "a FIFO":
        os.mkfifo(lock)
    elif what == "a directory":
        lock.mkdir()
    else:
        lock.symlink_to(tmp_path / "elsewhere")
    with pytest.raises(FlatcliError, match=f"is {what}, not flatcli's lock file"), \
            directory_lock(tmp_path):
        pass
    assert os.path.lexists(lock) and not (tmp_path / "elsewhere").exists()


def test_a_run_leaves_no_lock_file_behind(tmp_path: Path) -> None:
    (tmp_path / "mine.txt").write_text("")
    with pytest.raises(FlatcliError), directory_lock(tmp_path):
        raise FlatcliError("refused")
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]
    with directory_lock(tmp_path):
        assert (tmp_path / LOCK_NAME).read_text().split()[0] == str(os.getpid())
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]
    (tmp_path / LOCK_NAME).write_text("")  # left by a run killed with kill -9: kept, harmless
    with directory_lock(tmp_path):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == [LOCK_NAME, "mine.txt"]


def test_a_syncer_flushes_what_it_was_given_and_reports_a_failed_flush(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    table = pa.table({"a": [1.0, 2.0]})
    syncer = Syncer()
    for i in range(3):
        write_table(tmp_path / f"t{i}.parquet", table, {"i": i}, syncer)
        assert pq.read_table(tmp_path / f"t{i}.parquet").equals(table)  # whole at once
    syncer.close()
    assert syncer.synced == 3
    real = os.fsync

    def failing(fd: int) -> None:
        if os.readlink(f"/proc/self/fd/{fd}").endswith("bad.parquet"):
            raise OSError(errno.EIO, "Input/output error")
        real(fd)

    monkeypatch.setattr(os, "fsync", failing)
    syncer = Syncer()
    write_table(tmp_path / "bad.parquet", table, {}, syncer)
    with pytest.raises(OSError) as caught:
        syncer.close()
    assert caught.value.filename == str(tmp_path / "bad.parquet")
    assert caught.value.errno == errno.EIO


@pytest.mark.parametrize("started", [True, False])
def test_a_syncer_whose_thread_start_was_interrupted_still_closes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, started: bool) -> None:
    """Ctrl-C or SIGTERM (a KeyboardInterrupt) may end Thread.start() early, before or after
    the thread runs: the interrupted sweep then closes its syncer without an error of its
    own (it once raised RuntimeError: cannot join thread before it is started)."""
    import threading

    real = threading.Thread.start

    def interrupted(self: threading.Thread) -> None:
        if started:
            real(self)
        raise KeyboardInterrupt

    monkeypatch.setattr(threading.Thread, "start", interrupted)
    syncer = Syncer()
    with pytest.raises(KeyboardInterrupt):
        write_table(tmp_path / "t.parquet", pa.table({"a": [1.0]}), {}, syncer)
    monkeypatch.undo()
    syncer.close()
    assert pq.read_table(tmp_path / "t.parquet").num_rows == 1
