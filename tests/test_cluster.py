"""A sweep on SLURM jobs (flatcli/cluster.py, ``--scheduler slurm``): the settings flatcli
hands dask-jobqueue, the job script dask-jobqueue renders from them (the referee: dask-jobqueue
itself), and a whole sweep whose workers start from that job script. There is no SLURM here:
``sbatch`` and ``scancel`` are stand-ins that run the job script on this machine and stop it,
so everything from the job script on (dask-jobqueue's submission, the workers it starts, their
connection back, the cancellation) is the real path."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import dask
import pytest
from small_sweep import SPEC, sweep, write_spec

from flatcli.cluster import JOB_ENVIRONMENT, slurm_settings
from flatcli.core.errors import FlatcliError

SBATCH = """#!/usr/bin/env bash
# stand-in for SLURM's sbatch: copy the job script, run it here in a session of its own
set -e
id=$$
cp "$1" "$FAKE_SLURM/job-$id.sh"
setsid bash "$FAKE_SLURM/job-$id.sh" > "$FAKE_SLURM/job-$id.log" 2>&1 < /dev/null &
echo $! > "$FAKE_SLURM/job-$id.pid"
echo "Submitted batch job $id"
"""
SCANCEL = """#!/usr/bin/env bash
# stand-in for SLURM's scancel: stop each job's session
for id in "$@"; do
  kill -TERM -- "-$(cat "$FAKE_SLURM/job-$id.pid")" 2>/dev/null || true
  echo "$id" >> "$FAKE_SLURM/cancelled"
done
"""
REFUSING_SBATCH = """#!/usr/bin/env bash
echo "sbatch: error: Batch job submission failed: Invalid account or account/partition" >&2
exit 1
"""


def test_flatcli_hands_one_thread_per_process_and_keeps_the_sites_settings() -> None:
    site = {"jobqueue.slurm.cores": 4, "jobqueue.slurm.processes": 1,
            "jobqueue.slurm.queue": "short",
            "jobqueue.slurm.job-script-prologue": ["module load python"],
            "jobqueue.slurm.scheduler-options": {"interface": "ib0"}}
    with dask.config.set(site):
        settings, jobs = slurm_settings(10)
    assert jobs == 3  # 10 workers, 4 a job
    assert settings["cores"] == settings["processes"] == 4  # one thread each
    assert settings["memory"] == "4GiB"  # 1 GiB a worker, where the site says nothing
    assert settings["python"] == sys.executable
    assert settings["job_script_prologue"] == ["module load python", *JOB_ENVIRONMENT]
    assert settings["scheduler_options"] == {"dashboard_address": ":0", "interface": "ib0"}
    assert "queue" not in settings  # the site's, through dask-jobqueue's own configuration
    with dask.config.set({"jobqueue.slurm.cores": 2, "jobqueue.slurm.memory": "16GB"}):
        settings, jobs = slurm_settings(None)
    assert (jobs, settings["memory"]) == (1, "16GB")
    for bad in (0, 1.5, "4"):
        with dask.config.set({"jobqueue.slurm.cores": bad}), pytest.raises(
                FlatcliError, match=r"jobqueue\.slurm\.cores must be a whole number"):
            slurm_settings(2)


def test_the_job_script_dask_jobqueue_writes_from_them() -> None:
    from dask_jobqueue.slurm import SLURMCluster

    site = {"jobqueue.slurm.cores": 3, "jobqueue.slurm.queue": "short",
            "jobqueue.slurm.account": "robots", "jobqueue.slurm.walltime": "02:00:00"}
    with dask.config.set(site):
        settings, _ = slurm_settings(6)
        with SLURMCluster(**settings) as cluster:
            script = cluster.job_script()
    for line in ("#SBATCH -J flatcli-worker", "#SBATCH -p short", "#SBATCH -A robots",
                 "#SBATCH --cpus-per-task=3", "#SBATCH --mem=3G", "#SBATCH -t 02:00:00",
                 *JOB_ENVIRONMENT):
        assert line in script.splitlines(), line
    worker = script.splitlines()[-1]
    assert worker.startswith(f"{sys.executable} -m distributed.cli.dask_worker tcp://")
    assert "--nthreads 1" in worker and "--nworkers 3" in worker


@pytest.fixture
def fake_slurm(tmp_path: Path) -> dict[str, str]:
    """An environment whose sbatch and scancel are the stand-ins, jobs of one worker."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    for name, text in (("sbatch", SBATCH), ("scancel", SCANCEL)):
        path = bin_dir / name
        path.write_text(text)
        path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "FAKE_SLURM": str(jobs),
            "DASK_JOBQUEUE__SLURM__CORES": "1", "DASK_JOBQUEUE__SLURM__DEATH_TIMEOUT": "20"}


def _alive(pid: int) -> bool:
    try:
        os.killpg(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_a_sweep_on_slurm_jobs_writes_the_local_runs_bytes(
        tmp_path: Path, fake_slurm: dict[str, str]) -> None:
    spec = write_spec(tmp_path, SPEC)
    local = tmp_path / "local"
    assert sweep(str(spec), "--out", str(local), "-q", "--workers", "1")[0] == 0
    out = tmp_path / "slurm"
    jobs = Path(fake_slurm["FAKE_SLURM"])
    try:
        done = subprocess.run(
            [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out", str(out),
             "--executor", "dask", "--scheduler", "slurm", "--workers", "2"],
            env=fake_slurm, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        assert "waiting for SLURM to start the workers' jobs" in done.stderr
        assert "120 trials on dask at tcp://" in done.stderr and "2 worker threads" in done.stderr
        for name in ("trials.parquet", "summary.parquet", "summary.md"):
            assert (out / name).read_bytes() == (local / name).read_bytes(), name
        scripts = sorted(jobs.glob("job-*.sh"))
        assert len(scripts) == 2  # 2 workers, 1 a job
        # the jobs were cancelled when the sweep ended
        cancelled = (jobs / "cancelled").read_text().split()
        assert sorted(cancelled) == sorted(p.stem.removeprefix("job-") for p in scripts)
    finally:
        pids = [int(p.read_text()) for p in jobs.glob("job-*.pid")]
        deadline = time.monotonic() + 30
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        leftover = [p for p in pids if _alive(p)]
        for pid in leftover:
            os.killpg(pid, signal.SIGKILL)
    assert not leftover, "the workers' jobs outlived the sweep"


def test_no_sbatch_or_a_refused_job_is_one_line(tmp_path: Path,
                                                fake_slurm: dict[str, str]) -> None:
    spec = write_spec(tmp_path, SPEC)
    command = [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out",
               str(tmp_path / "d"), "--executor", "dask", "--scheduler", "slurm"]
    empty = tmp_path / "empty"
    empty.mkdir()
    python_only = f"{empty}:{Path(sys.executable).parent}:/usr/bin:/bin"
    no_sbatch = {**fake_slurm, "PATH": python_only}
    done = subprocess.run(command, env=no_sbatch, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr == ("error: --scheduler slurm: sbatch not found on PATH (run flatcli "
                           "where SLURM's commands are: a login node of the cluster)\n")
    (empty / "sbatch").write_text(REFUSING_SBATCH)
    (empty / "sbatch").chmod(0o755)
    done = subprocess.run(command, env=no_sbatch, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr == ("error: --scheduler slurm: sbatch refused the job (sbatch: error: "
                           "Batch job submission failed: Invalid account or "
                           "account/partition)\n"), done.stderr
    assert not (tmp_path / "d").exists()  # nothing written
