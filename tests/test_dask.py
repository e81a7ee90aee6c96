"""The Dask executor: the same chunks, files, resume and results (bit for bit) as the local
executor, on a LocalCluster of 2 worker processes, also when a worker is killed mid-sweep."""

from __future__ import annotations

import gc
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest
from dask.distributed import Client, LocalCluster, get_task_stream
from small_sweep import SPEC, sweep, sweep_without_final_tables, write_spec

import flatcli.executors
from flatcli.montecarlo.layout import ID_STRIDE

#: Long enough that a worker can be killed with most chunks still to run (seconds of work
#: after the first chunk is written, against milliseconds to kill): 2 x 500 trials in 50
#: chunks of 20.
LONG_TRIALS, LONG_CHUNK = 500, 20
LONG_SPEC = SPEC.replace("trials = 60", f"trials = {LONG_TRIALS}").replace(
    "chunk = 25", f"chunk = {LONG_CHUNK}"
)
LONG_CHUNKS = 2 * LONG_TRIALS // LONG_CHUNK

MISSING = ("error: --executor dask: dask.distributed is not installed; "
           "pip install 'flatcli[dask]'\n")


def chunk_files(directory: Path) -> list[str]:
    trials = directory / "trials"
    return sorted(p.name for p in trials.glob("chunk-*.parquet")) if trials.exists() else []


def assert_same_sweep(directory: Path, reference: Path) -> None:
    """The same trials.parquet to the byte (its rows, its chunks' list and checksums), the
    same summary.parquet and summary.md; no chunk file left (each result once on disk)."""
    assert chunk_files(directory) == chunk_files(reference) == []
    assert (directory / "trials.parquet").read_bytes() == (
        reference / "trials.parquet").read_bytes()
    for name in ("trials.parquet", "summary.parquet"):
        pd.testing.assert_frame_equal(pd.read_parquet(directory / name),
                                      pd.read_parquet(reference / name),
                                      check_exact=True, obj=name)
    assert (directory / "summary.md").read_text() == (reference / "summary.md").read_text()


@pytest.fixture(autouse=True)
def _clients_finalised_on_the_main_thread() -> Iterator[None]:
    """Dask clients a test left to the garbage collector are finalised here, on the main
    thread, before and after each test. Finalised on an event loop's thread instead (a
    periodic callback of an in-process worker), ``Client.__del__`` joins another loop's thread
    and that loop hangs: test_workers_that_all_leave_mid_sweep_end_it_with_one_line hung a
    fresh-clone CI on 2026-12-06 (py-spy: Worker.trigger_profile -> Client.__del__ ->
    Client.close -> LoopRunner.stop -> Thread.join), after passing four runs that day."""
    gc.collect()
    yield
    gc.collect()


@pytest.fixture(scope="module")
def cluster() -> Iterator[LocalCluster]:
    """The CI cluster: 2 single-threaded worker processes, each under a nanny."""
    logger = logging.getLogger("distributed")
    level = logger.level
    logger.setLevel(logging.ERROR)  # a killed worker is expected here, not worth a warning
    try:
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                          dashboard_address=None) as local_cluster:
            yield local_cluster
    finally:
        logger.setLevel(level)


@pytest.fixture(scope="module")
def client(cluster: LocalCluster) -> Iterator[Client]:
    with Client(cluster) as dask_client:
        dask_client.wait_for_workers(2, timeout=120)
        yield dask_client


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """SPEC swept by the local executor in this process (also compiles the kernel, so the
    Dask workers load it from numba's disk cache)."""
    base = tmp_path_factory.mktemp("reference")
    out = base / "out"
    code, text = sweep(str(write_spec(base)), "--out", str(out), "-q", "--workers", "1")
    assert code == 0, text
    return out


def test_a_dask_cluster_writes_the_local_executors_files_bit_for_bit(
    tmp_path: Path, client: Client, cluster: LocalCluster, reference: Path
) -> None:
    out = tmp_path / "dask"
    with get_task_stream(client) as stream:
        code, text = sweep(str(write_spec(tmp_path)), "--out", str(out), "--executor", "dask",
                           "--scheduler", cluster.scheduler_address)
    assert code == 0, text
    assert f"120 trials on dask at {cluster.scheduler_address}, 2 worker threads" in text
    # the 6 chunks ran on the cluster, on both workers
    tasks = [t for t in stream.data if str(t["key"]).startswith("run_chunk")]
    assert len(tasks) == 6
    assert {t["worker"] for t in tasks} == set(client.run(os.getpid))
    assert "resuming" not in text
    assert_same_sweep(out, reference)
    frame = pd.read_parquet(out / "trials.parquet")
    assert (frame["trial"] % ID_STRIDE).tolist() == list(range(60)) * 2  # i within each cell
    assert frame["trial"].is_unique
    assert (frame["status"] == "ok").mean() > 0.9


def test_scheduler_local_starts_its_own_cluster_with_the_same_result(
    tmp_path: Path, reference: Path
) -> None:
    out = tmp_path / "dask-local"
    code, text = sweep(str(write_spec(tmp_path)), "--out", str(out), "--executor", "dask",
                       "--scheduler", "local", "--workers", "1")
    assert code == 0, text
    assert "120 trials on dask at tcp://127.0.0.1:" in text
    assert_same_sweep(out, reference)


def test_a_local_sweep_with_lost_chunks_is_finished_by_dask_identically(
    tmp_path: Path, cluster: LocalCluster, reference: Path
) -> None:
    # What a local sweep killed mid-way leaves: some chunks written, one lost (never renamed
    # into place: only its temp file is there), one torn, and no final tables.
    out = tmp_path / "cut"
    sweep_without_final_tables(str(write_spec(tmp_path)), "--out", str(out), "-q",
                               "--workers", "1")
    trials = out / "trials"
    names = chunk_files(out)  # per cell: trials 0-24, 25-49, 50-59
    lost, torn = trials / names[1], trials / names[5]
    assert names[1].endswith("-000000025.parquet") and names[5].endswith("-000000050.parquet")
    lost.rename(trials / f".{lost.name}.x1y2z3.tmp")
    torn.write_bytes(torn.read_bytes()[:100])
    kept = {name: (trials / name).stat() for name in chunk_files(out) if name != torn.name}
    assert len(kept) == 4

    code, text = sweep(str(write_spec(tmp_path)), "--out", str(out), "--executor", "dask",
                       "--scheduler", cluster.scheduler_address)
    assert code == 0, text
    assert f"on dask at {cluster.scheduler_address}" in text
    assert "120 trials" in text and "resuming with 85 done" in text  # 120 - 25 - 10
    assert "(35 simulated now)" in text
    assert_same_sweep(out, reference)
    assert not trials.exists()  # the temporary file gone, and the chunks in trials.parquet


def test_a_worker_killed_mid_sweep_changes_nothing(
    tmp_path: Path, client: Client, cluster: LocalCluster
) -> None:
    spec = write_spec(tmp_path, LONG_SPEC)
    whole = tmp_path / "local"  # one worker: no fork of this process, which runs threads
    code, text = sweep(str(spec), "--out", str(whole), "-q", "--workers", "1")
    assert code == 0, text

    out = tmp_path / "dask"
    command = [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out", str(out),
               "-q", "--executor", "dask", "--scheduler", cluster.scheduler_address]
    log = tmp_path / "sweep.log"
    with log.open("w") as sink:
        process = subprocess.Popen(command, stdout=sink, stderr=subprocess.STDOUT)
    try:
        pids: dict[str, int] = client.run(os.getpid)
        assert len(pids) == 2
        # Wait until chunks are being written and a worker is busy with one, then kill it.
        victim = None
        deadline = time.monotonic() + 120
        while victim is None:
            assert time.monotonic() < deadline, "the sweep never got going"
            if process.poll() is not None:
                pytest.fail("the sweep finished before a worker could be killed; make it "
                            "longer\n" + log.read_text())
            if chunk_files(out):
                busy = [w for w, keys in client.processing().items() if keys and w in pids]
                victim = busy[0] if busy else None
            if victim is None:
                time.sleep(0.005)
        os.kill(pids[victim], signal.SIGKILL)
        written_at_kill = len(chunk_files(out))
        running_at_kill = process.poll() is None
        code = process.wait(timeout=180)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert code == 0, log.read_text()
    # the kill landed mid-way: the sweep was running, with chunks done and chunks to do
    assert running_at_kill
    assert 1 <= written_at_kill < LONG_CHUNKS
    # the nanny restarted the killed worker (a new process)
    client.wait_for_workers(2, timeout=120)
    now = client.run(os.getpid)
    assert pids[victim] not in now.values()
    # the result is complete and identical
    frame = pd.read_parquet(out / "trials.parquet")
    assert (frame["trial"] % ID_STRIDE).tolist() == list(range(LONG_TRIALS)) * 2
    assert_same_sweep(out, whole)


@pytest.mark.parametrize("scheduler", [[], ["--scheduler", "local"],
                                       ["--scheduler", "tcp://127.0.0.1:8786"]],
                         ids=["default", "local", "address"])
def test_without_dask_the_dask_executor_is_a_one_line_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, scheduler: list[str]
) -> None:
    # as if dask.distributed were not installed: importing it raises ImportError
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    with pytest.raises(ImportError):
        from dask.distributed import Client  # noqa: F401
    out = tmp_path / "d"
    code, text = sweep(str(write_spec(tmp_path)), "--out", str(out), "-q",
                       "--executor", "dask", *scheduler)
    assert code == 2
    assert text == MISSING
    assert not out.exists()


@pytest.mark.parametrize(
    ("address", "message"),
    [
        ("tcp://127.0.0.1:1", "cannot connect"),  # nothing listens there
        ("foo://127.0.0.1:8786", "unknown address scheme 'foo'"),
    ],
)
def test_a_bad_scheduler_address_is_a_one_line_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, address: str, message: str
) -> None:
    monkeypatch.setattr(flatcli.executors, "CONNECT_TIMEOUT", "1s")  # 10 s by default
    out = tmp_path / "d"
    code, text = sweep(str(write_spec(tmp_path)), "--out", str(out), "-q",
                       "--executor", "dask", "--scheduler", address)
    assert code == 2, text
    assert text.startswith(f"error: --scheduler {address}: ") and text.count("\n") == 1, text
    assert message in text
    assert not out.exists()


def test_a_scheduler_without_workers_is_a_one_line_error_not_a_hang(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FLATCLI_DASK_WORKER_TIMEOUT", "2")
    out = tmp_path / "d"
    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as empty:
        started = time.monotonic()
        code, text = sweep(str(write_spec(tmp_path)), "--out", str(out), "-q",
                           "--executor", "dask", "--scheduler", empty.scheduler_address)
    assert code == 2, text
    assert text == (f"error: --scheduler {empty.scheduler_address}: no worker joined within "
                    "2 s (WorkerStartTimeoutError); start workers (dask worker ADDRESS), or "
                    "use --executor local\n")
    assert time.monotonic() - started < 60
    assert not out.exists()


def test_workers_that_all_leave_mid_sweep_end_it_with_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FLATCLI_DASK_WORKER_TIMEOUT", "3")
    executor = None
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        executor = flatcli.executors.DaskExecutor(cluster.scheduler_address)
        results = executor.run(time.sleep, ((i, (0.2 * i,)) for i in range(20)))
        assert next(results)[0] == 0
        cluster.scale(0)  # every worker leaves; the tasks left can never run
        with pytest.raises(flatcli.executors.WorkerLostError,
                           match=r"^no Dask worker for 3 s at "):
            list(results)
        executor.close()


def test_a_cluster_of_separate_processes_as_over_ssh_writes_the_local_bytes(
        tmp_path: Path, reference: Path) -> None:
    """What docs/cluster.md tells a user to start on other machines over SSH: a scheduler
    and a worker host, each a process of its own started by Dask's command line (here on
    this machine), and the sweep pointed at the scheduler's address."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    address_file = tmp_path / "scheduler.json"
    scheduler = subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", "0", "--dashboard-address", ":0", "--scheduler-file", str(address_file)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    worker = None
    try:
        deadline = time.monotonic() + 120
        while not address_file.exists() or not address_file.read_text().strip():
            assert time.monotonic() < deadline and scheduler.poll() is None
            time.sleep(0.1)
        worker = subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file",
             str(address_file), "--nworkers", "2", "--nthreads", "1", "--no-dashboard"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True)
        import json

        address = json.loads(address_file.read_text())["address"]
        with Client(address, timeout="30s") as watcher:
            watcher.wait_for_workers(2, timeout=120)  # both up, as a user would see first
        out = tmp_path / "ssh"
        code, text = sweep(str(write_spec(tmp_path)), "--out", str(out), "--executor", "dask",
                           "--scheduler", address)
        assert code == 0, text
        assert f"120 trials on dask at {address}, 2 worker threads" in text
        assert_same_sweep(out, reference)
    finally:
        for process in (worker, scheduler):
            if process is not None and process.poll() is None:
                os.killpg(process.pid, signal.SIGTERM)
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    os.killpg(process.pid, signal.SIGKILL)
                    process.wait()


def test_the_cluster_flatcli_starts_runs_its_workers_as_flatclis_own() -> None:
    """--scheduler local: worker processes forked from flatcli's (its modules already
    loaded), one BLAS thread, and Dask's own work beside a chunk's cut down (no profiler, a
    tick and memory monitor every second: flatcli.executors.CLUSTER_CONFIG)."""

    from flatcli.executors import CLUSTER_CONFIG, DaskExecutor

    def settings() -> dict[str, object]:
        import sys

        import dask

        return {"flatcli loaded": "flatcli.montecarlo.chunks" in sys.modules,
                "threads": os.environ.get("OPENBLAS_NUM_THREADS"),
                **{key: dask.config.get(key) for key in CLUSTER_CONFIG}}

    import flatcli.montecarlo.chunks  # noqa: F401  (what a sweep's process has loaded)

    executor = DaskExecutor("local", 2)
    try:
        found = executor._client.run(settings)
    finally:
        executor.close()
    assert len(found) == 2
    for worker in found.values():
        assert worker["flatcli loaded"] and worker["threads"] == "1", worker
        assert {k: worker[k] for k in CLUSTER_CONFIG} == CLUSTER_CONFIG
