"""A cluster flatcli starts for a sweep: Dask workers as SLURM jobs (``--scheduler slurm``).

flatcli hands dask-jobqueue's ``SLURMCluster`` the settings its work needs and leaves the
site's own to dask-jobqueue's configuration (``~/.config/dask/jobqueue.yaml``, or
``DASK_JOBQUEUE__SLURM__*`` variables: queue, account, walltime, interface, ...). What
flatcli sets (``slurm_settings``):

* one thread per worker process (``processes = cores``): a trial is one compiled loop,
  and the GIL makes threads of one process no faster;
* one BLAS and OpenMP thread in each (its variables exported by the job script), Dask's
  statistical profiler off (it samples the task's thread every 10 ms), its event loop's
  tick and memory monitor every second, as flatcli's own workers run;
* the job's memory, if the configuration does not say: ``MEMORY_PER_WORKER`` per worker
  process (a sweep's worker peaks near 100 MiB on the paper's robot);
* the Python that runs flatcli (a shared file system holds its environment), and the job
  name ``flatcli-worker``;
* as many jobs as ``--workers`` needs (default: one job of ``cores`` workers).

The jobs are cancelled (``scancel``) when the sweep ends, however it ends but by kill -9.
"""

from __future__ import annotations

import math
import shutil
import sys
import time
from typing import Any

from flatcli.core.errors import FlatcliError

#: The ``--scheduler`` that starts SLURM jobs.
SLURM = "slurm"
#: A worker process's memory where dask-jobqueue's configuration gives none.
MEMORY_PER_WORKER_GIB = 1
#: What a worker's job exports: one thread in each numerical library
#: (``flatcli.threads.THREAD_VARIABLES``), and Dask's own work beside a chunk's cut down
#: (``flatcli.executors.WORKER_SETTINGS``: no profiler, a slower tick and memory monitor).
JOB_ENVIRONMENT = ("export FLATCLI_OWN_PROCESS=1", "export OPENBLAS_NUM_THREADS=1",
                   "export OMP_NUM_THREADS=1",
                   "export MKL_NUM_THREADS=1",
                   "export DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False",
                   "export DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL=1s",
                   "export DASK_DISTRIBUTED__WORKER__MEMORY__MONITOR_INTERVAL=1s")
#: How long sbatch may take to accept the jobs [s].
SUBMIT_SECONDS = 120.0
#: How long a sweep waits for the first SLURM job to start its workers (a queue may hold
#: them) [s], unless FLATCLI_DASK_WORKER_TIMEOUT says.
SLURM_WORKER_TIMEOUT = 3600.0


def slurm_settings(workers: int | None) -> tuple[dict[str, Any], int]:
    """The keyword arguments flatcli hands ``dask_jobqueue.SLURMCluster``, and the number of
    jobs for ``workers`` worker processes (None: one job), from dask's configuration of
    ``jobqueue.slurm`` as it stands (FlatcliError naming a setting flatcli cannot use)."""
    import dask

    def setting(name: str, default: Any = None) -> Any:
        value = dask.config.get(f"jobqueue.slurm.{name}", default)
        return default if value is None else value

    cores = setting("cores", 1)
    if not isinstance(cores, int) or isinstance(cores, bool) or cores < 1:
        raise FlatcliError(f"--scheduler slurm: dask's jobqueue.slurm.cores must be a whole "
                           f"number >= 1 (the worker processes of one job), got {cores!r}")
    wanted = cores if workers is None else workers
    if wanted < 1:
        raise FlatcliError(f"--workers: must be >= 1, got {wanted}")
    memory = setting("memory", f"{MEMORY_PER_WORKER_GIB * cores}GiB")
    prologue = [*setting("job-script-prologue", []), *JOB_ENVIRONMENT]
    scheduler = {"dashboard_address": ":0", **setting("scheduler-options", {})}
    return {
        "cores": cores,
        "processes": cores,  # one thread each
        "memory": memory,
        "python": sys.executable,
        "job_name": "flatcli-worker",
        "job_script_prologue": prologue,
        "scheduler_options": scheduler,
    }, math.ceil(wanted / cores)


def slurm_cluster(workers: int | None) -> tuple[Any, int]:
    """A ``dask_jobqueue.SLURMCluster`` of ``slurm_settings``, its jobs submitted, and the
    worker processes they will start (FlatcliError, the cluster closed, if sbatch is not
    there or refuses a job)."""
    try:
        from dask_jobqueue.slurm import SLURMCluster, SLURMJob
    except ImportError:
        raise FlatcliError("--scheduler slurm: dask-jobqueue is not installed; "
                           "pip install 'flatcli[slurm]'") from None
    from distributed.core import Status

    settings, jobs = slurm_settings(workers)
    if shutil.which("sbatch") is None:
        raise FlatcliError("--scheduler slurm: sbatch not found on PATH (run flatcli where "
                           "SLURM's commands are: a login node of the cluster)")
    refused: list[str] = []

    class Job(SLURMJob):
        """dask-jobqueue's SLURM job, whose refused submission is kept for the user, the
        job marked failed (raised in Dask's event loop, the refusal would be logged there
        as a traceback, and the cluster would wait for its workers forever)."""

        async def start(self) -> None:
            try:
                await super().start()
            except RuntimeError as exc:  # dask-jobqueue: sbatch's exit status and output
                lines = [line for line in str(exc).splitlines() if line.strip()]
                refused.append(lines[-1] if lines else "no reason given")
                self.status = Status.failed

    try:
        cluster = SLURMCluster(job_cls=Job, **settings)  # type: ignore[arg-type]
    except (ValueError, TypeError) as exc:  # a setting dask-jobqueue refuses
        raise FlatcliError(f"--scheduler slurm: {str(exc).splitlines()[0]}") from None
    try:
        cluster.scale(jobs=jobs)
        deadline = time.monotonic() + SUBMIT_SECONDS
        while not refused and time.monotonic() < deadline and not (
                len(cluster.workers) == jobs
                and all(getattr(w, "job_id", None) for w in cluster.workers.values())):
            time.sleep(0.05)
        if refused:
            raise FlatcliError(f"--scheduler slurm: sbatch refused the job "
                               f"({refused[0][:160]})")
    except BaseException:
        cluster.close()
        raise
    return cluster, jobs * int(settings["cores"])
