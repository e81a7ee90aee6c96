"""What flatcli finds on disk (flatcli/files.py): only regular files are read, never through a
symbolic link, never beyond a bound, and no name leads out of its directory."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest

from flatcli.files import (
    UnreadableFileError,
    inside,
    is_regular,
    kind,
    not_regular,
    read_bounded,
    real_directory,
)


def entries(tmp_path: Path) -> dict[str, Path]:
    """One entry of each kind in tmp_path."""
    made = {"file": tmp_path / "file", "a directory": tmp_path / "dir",
            "a FIFO": tmp_path / "fifo", "a symbolic link": tmp_path / "link",
            "a socket": tmp_path / "sock"}
    made["file"].write_text("x")
    made["a directory"].mkdir()
    os.mkfifo(made["a FIFO"])
    made["a symbolic link"].symlink_to(made["file"])
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(made["a socket"]))
    server.close()
    return made


def test_kind_names_every_entry_without_following_links(tmp_path: Path) -> None:
    for what, path in entries(tmp_path).items():
        assert kind(path) == what
        assert is_regular(path) == (what == "file")
    assert kind(tmp_path / "missing") == "missing"
    assert kind(tmp_path / "file" / "below") == "missing"  # a parent is a file
    assert kind(Path("/dev/null")) == "a device"


@pytest.mark.timeout(20, method="thread")  # a FIFO opened blindly would block here forever
def test_only_a_regular_file_is_read(tmp_path: Path) -> None:
    made = entries(tmp_path)
    assert read_bounded(made["file"], 1) == b"x"
    for what in ("a directory", "a FIFO", "a symbolic link"):
        with pytest.raises(UnreadableFileError, match=f"is {what}, not a regular file"):
            read_bounded(made[what], 100)
    with pytest.raises(UnreadableFileError, match="is a device"):
        read_bounded(Path("/dev/zero"), 100)  # endless: refused unread
    with pytest.raises(UnreadableFileError, match="not found"):
        read_bounded(tmp_path / "missing", 100)


def test_a_file_beyond_the_bound_is_refused_unread(tmp_path: Path) -> None:
    path = tmp_path / "big"
    with path.open("wb") as fh:
        fh.truncate(1 << 30)  # sparse: nothing is stored, a read would still take 1 GiB
    with pytest.raises(UnreadableFileError, match=f"is {1 << 30} bytes, more than the 1000"):
        read_bounded(path, 1000)
    exact = tmp_path / "exact"
    exact.write_bytes(b"a" * 1000)
    assert len(read_bounded(exact, 1000)) == 1000
    with pytest.raises(UnreadableFileError, match="more than the 999"):
        read_bounded(exact, 999)


def test_an_unreadable_file_is_an_os_error_that_names_it(tmp_path: Path) -> None:
    error = UnreadableFileError(tmp_path / "run.json", "is a FIFO, not a regular file")
    assert isinstance(error, OSError) and error.filename == str(tmp_path / "run.json")
    assert str(error) == f"{tmp_path / 'run.json'}: is a FIFO, not a regular file"


def test_no_name_leads_out_of_its_directory(tmp_path: Path) -> None:
    outside = tmp_path / "outside"
    outside.mkdir()
    top = tmp_path / "top"
    (top / "sub").mkdir(parents=True)
    (top / "link").symlink_to(outside, target_is_directory=True)
    assert inside(top, "sub/run.json") == top / "sub" / "run.json"
    assert inside(top, "run.json") == top / "run.json"
    assert real_directory(top, "sub") == top / "sub"
    assert real_directory(top, ".") == top
    for name in ("../x", "sub/../../x", "/etc/passwd", "", "sub/", "./x", "sub//x", "..",
                 "link/x", "missing/x", "sub/.."):
        assert inside(top, name) is None, name
    for name in ("link", "..", "/tmp", "sub/../sub", "missing"):
        assert real_directory(top, name) is None, name


def test_not_regular_lists_what_stands_in_place_of_a_file(tmp_path: Path) -> None:
    entries(tmp_path)
    assert not_regular(tmp_path, ["file", "missing", "fifo", "dir", "link"]) == [
        "fifo (a FIFO)", "dir (a directory)", "link (a symbolic link)"]
