"""Shards of one study (``flatcli sweep --shard K/N``, flatcli/montecarlo/layout.py ``Shard``
and runner.py): several processes (machines, array jobs) writing one study's directory at
once without stepping on each other, resumable, and merged by the last one to the very bytes
of a local run (the referee: the same spec swept by one process, compared byte for byte)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from small_sweep import SPEC, sweep, write_spec

from flatcli.core.errors import FlatcliError
from flatcli.montecarlo import layout
from flatcli.montecarlo.layout import Shard
from flatcli.spec import resolve
from flatcli.storage import LOCK_NAME, SETUP_LOCK_NAME

#: Long enough for a second process to start while the first still runs: 2 x 400 trials in
#: 40 chunks of 20.
LONG = SPEC.replace("trials = 60", "trials = 400").replace("chunk = 25", "chunk = 20")
FINAL = ("trials.parquet", "summary.parquet", "summary.md")


def command(spec: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out", str(out),
            "--workers", "1", *extra]


def started(spec: Path, out: Path, *extra: str) -> subprocess.Popen[str]:
    """A sweep in another process, once it has written a chunk file (so it holds its locks
    and has work left)."""
    process = subprocess.Popen(command(spec, out, *extra), stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 180
    while not (out / "trials").is_dir() or not list((out / "trials").glob("chunk-*.parquet")):
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail("the sweep ended before it could be disturbed; make it longer: "
                        + (process.communicate()[1] or ""))
        time.sleep(0.01)
    return process


def finished(process: subprocess.Popen[str]) -> str:
    out, err = process.communicate(timeout=600)
    assert process.returncode == 0, err
    return out + err


@pytest.fixture(scope="module")
def local(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """LONG swept by one local run: the referee of every merged study."""
    base = tmp_path_factory.mktemp("local")
    code, out = sweep(str(write_spec(base, LONG)), "--out", str(base / "out"), "-q",
                      "--workers", "1")
    assert code == 0, out
    return base / "out"


def assert_same_study(directory: Path, reference: Path) -> None:
    for name in FINAL:
        assert (directory / name).read_bytes() == (reference / name).read_bytes(), name
    assert not (directory / "trials").exists()  # each result once on disk
    assert not os.path.lexists(directory / LOCK_NAME)
    assert not [p.name for p in directory.iterdir() if p.name.startswith(".flatcli")]


@settings(deadline=None, max_examples=40)
@given(st.integers(1, 40), st.integers(1, 120))
def test_the_shards_of_a_study_cover_its_chunks_once(count: int, trials: int) -> None:
    lay = layout(resolve({"track": {"dt": 0.01}, "sweep": {
        "trials": trials, "chunk": 7, "perturb": {"initial": {"dist": "normal", "std": 0.01}},
        "grid": {"track.sensor_noise": [0.0, 0.001]}}}))
    parts = [Shard(k, count).chunks(lay) for k in range(1, count + 1)]
    names = [c.name for part in parts for c in part]
    assert sorted(names) == sorted(c.name for c in lay.chunks())  # all, once each
    sizes = [len(part) for part in parts]
    assert max(sizes) - min(sizes) <= 1  # round robin


@pytest.mark.parametrize("text", ["0/4", "5/4", "1/0", "2", "a/b", "1/4/2", "-1/4", ""])
def test_a_shard_that_is_not_k_of_n_is_refused(text: str) -> None:
    with pytest.raises(FlatcliError, match=r"^--shard: expected K/N"):
        Shard.parse(text)


def test_two_shards_at_once_merge_to_the_bytes_of_one_local_run(tmp_path: Path,
                                                                local: Path) -> None:
    spec = write_spec(tmp_path, LONG)
    out = tmp_path / "study"
    first = started(spec, out, "--shard", "1/2")
    os.kill(first.pid, signal.SIGSTOP)  # both running at once, whatever the machine's speed
    try:
        second = subprocess.Popen(command(spec, out, "--shard", "2/2"),
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        second_text = finished(second)  # its chunks done while the first still runs
    finally:
        os.kill(first.pid, signal.SIGCONT)
    texts = [finished(first), second_text]
    # one of them (the last to finish) wrote the final tables, the other its chunks only
    assert sum("trials.parquet, summary.md" in t for t in texts) == 1, texts
    assert sum("its chunks are done" in t for t in texts) == 1, texts
    assert_same_study(out, local)


def test_a_killed_shard_resumes_and_the_study_merges_to_the_same_bytes(
        tmp_path: Path, local: Path) -> None:
    spec = write_spec(tmp_path, LONG)
    out = tmp_path / "study"
    victim = started(spec, out, "--shard", "1/2")
    os.kill(victim.pid, signal.SIGKILL)
    victim.communicate(timeout=60)
    code, text = sweep(str(spec), "--out", str(out), "--workers", "1", "--shard", "2/2")
    assert code == 0, text
    assert "no other shard is running: run the missing shards again" in text
    assert not (out / "trials.parquet").exists()
    code, text = sweep(str(spec), "--out", str(out), "--workers", "1", "--shard", "1/2")
    assert code == 0, text
    assert "resuming with" in text  # the killed shard's finished chunks were kept
    assert "wrote" in text and "trials.parquet" in text
    assert_same_study(out, local)


def test_a_study_of_shards_is_finished_by_the_sweep_without_shards(tmp_path: Path,
                                                                   local: Path) -> None:
    spec = write_spec(tmp_path, LONG)
    out = tmp_path / "study"
    code, text = sweep(str(spec), "--out", str(out), "--workers", "1", "--shard", "2/3")
    assert code == 0 and "no other shard is running" in text, text
    code, text = sweep(str(spec), "--out", str(out), "-q", "--workers", "1")
    assert code == 0, text
    assert_same_study(out, local)


def test_what_would_step_on_a_running_shard_is_refused_in_one_line(tmp_path: Path,
                                                                   local: Path) -> None:
    spec = write_spec(tmp_path, LONG)
    other = write_spec(tmp_path, LONG.replace("seed = 11", "seed = 12"), "other.toml")
    out = tmp_path / "study"
    running = started(spec, out, "--shard", "1/2")
    try:
        refusals = {
            "the same shard": sweep(str(spec), "--out", str(out), "--shard", "1/2"),
            "another spec": sweep(str(other), "--out", str(out), "--shard", "2/2"),
            "a run without shards": sweep(str(spec), "--out", str(out)),
            "--force": sweep(str(spec), "--out", str(out), "--force"),
        }
        assert running.poll() is None, "the shard ended before the refusals; make it longer"
    finally:
        text = finished(running)
    for what, (code, line) in refusals.items():
        assert code == 2 and line.startswith("error: ") and line.count("\n") == 1, (what, line)
    assert f"shard 1/2 is being run by another flatcli run (pid {running.pid})" in \
        refusals["the same shard"][1]
    assert "holds a sweep of a different spec (keys that differ: sweep.seed (11 -> 12))" in \
        refusals["another spec"][1]
    for what in ("a run without shards", "--force"):
        assert f"is being written by another flatcli run (shards of a sweep, one of them pid " \
               f"{running.pid})" in refusals[what][1], refusals[what][1]
    assert "no other shard is running" in text
    code, line = sweep(str(spec), "--out", str(out), "--shard", "1/2", "--force")
    assert code == 2 and line.startswith("error: --force: not with --shard"), line
    code, line = sweep(str(spec), "--out", str(out), "--shard", "0/2")
    assert code == 2 and line.startswith("error: --shard: expected K/N"), line
    code, text = sweep(str(spec), "--out", str(out), "--workers", "1", "--shard", "2/2")
    assert code == 0, text
    assert_same_study(out, local)


def test_a_shard_starting_while_another_checks_whether_it_is_last_waits(
        tmp_path: Path) -> None:
    """A shard that has finished its chunks holds the directory's lock alone for a moment (is
    it the last? then it writes the final tables): a shard starting then waits for it
    (``SHARD_WAIT``) instead of being refused as if a sweep without shards ran there; held
    longer, the refusal names the holder. (Here this process holds the lock alone.)"""
    from flatcli import storage

    out = tmp_path / "study"
    # another process holds the lock alone for 1.5 s: the shard's lock is had once released
    code = ("import sys, time\nfrom pathlib import Path\nfrom flatcli import storage\n"
            "with storage.directory_lock(Path(sys.argv[1])):\n"
            "    print('held', flush=True)\n    time.sleep(float(sys.argv[2]))\n")
    holder = subprocess.Popen([sys.executable, "-c", code, str(out), "1.5"],
                              stdout=subprocess.PIPE, text=True)
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    begun = time.monotonic()
    with storage.shard_locks(out, 1, 2):
        waited = time.monotonic() - begun
    holder.communicate(timeout=60)
    assert waited > 0.5  # it waited for the holder rather than being refused at once
    holder = subprocess.Popen([sys.executable, "-c", code, str(out), "60"],
                              stdout=subprocess.PIPE, text=True)
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(storage, "SHARD_WAIT", 0.3)
            busy = f"being written by another flatcli run \\(pid {holder.pid}"
            with pytest.raises(storage.DirectoryBusyError, match=busy), \
                    storage.shard_locks(out, 1, 2):
                pass
    finally:
        holder.kill()
        holder.communicate(timeout=60)


def test_a_shard_waits_for_another_shards_set_up(tmp_path: Path, local: Path) -> None:
    """Shards starting together agree on one manifest: the set-up lock serialises them (here
    held by this process while the shard starts: it waits, then runs)."""
    from flatcli.storage import _lock

    spec = write_spec(tmp_path, LONG)
    out = tmp_path / "study"
    with _lock(out, SETUP_LOCK_NAME):
        process = subprocess.Popen(command(spec, out, "--shard", "1/1"),
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(3.0)
        assert process.poll() is None and not (out / "sweep.json").exists()
    finished(process)
    assert_same_study(out, local)
