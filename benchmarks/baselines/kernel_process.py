"""The same-work kernel as a whole process: what a small flatcli sweep's whole process is set
beside.

``kernel_process_seconds`` runs, in a fresh interpreter, what a user with the hand-written
kernel (``dopri``) would run to get the same metrics: import it (numba, its cached machine
code), build the paper's perturbed trials and their inputs, run the kernel on its threads,
and exit (``os._exit``, as flatcli does). Its wall time is the kernel's whole process;
``flatcli sweep`` of the same number of trials (``track.error_estimate = "none"``: one
solution per trial, as the kernel) against it is the front door's whole-process ratio for
small runs, where start-up is most of the time.

    python benchmarks/baselines/kernel_process.py TRIALS [THREADS]   (from the repository)
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

#: The trials' seed (``problem.paper_trials``), as the sweeps section's kernel uses.
SEED = 2003
#: Runs this file as the main module without importing its package (``python -m`` would run
#: ``benchmarks/baselines/__init__.py`` first: ``_package_alone``).
_BOOT = ("import runpy, sys; sys.path.insert(0, {root!r}); sys.argv[0] = {path!r}; "
         "runpy.run_path({path!r}, run_name='__main__')")


def _package_alone() -> None:
    """Make ``benchmarks.baselines``'s modules importable without its ``__init__``, which
    loads every baseline's libraries (python-control, scipy's optimisers, the other
    kernels): the kernel's user would load its own module only."""
    import types

    for name, path in (("benchmarks", Path(__file__).parent.parent),
                       ("benchmarks.baselines", Path(__file__).parent)):
        if name not in sys.modules:
            package = types.ModuleType(name)
            package.__path__ = [str(path)]
            sys.modules[name] = package


def run(trials: int, threads: int) -> int:
    """The kernel on ``trials`` of the paper's perturbed trials, ``threads`` threads; how
    many rows of metrics it gave."""
    from benchmarks.baselines.dopri import dopri_inputs, dopri_metrics
    from benchmarks.baselines.problem import PAPER_MANEUVER, paper_trials

    plan = PAPER_MANEUVER.cubic()
    batch = paper_trials(trials, seed=SEED)
    metrics = dopri_metrics(plan, batch, threads=threads, inputs=dopri_inputs(plan, batch))
    return int(metrics.shape[0])


def kernel_process_seconds(trials: int, threads: int = 2) -> float:
    """Wall time of one run of the kernel's whole process [s] (run it once first: its first
    run may compile the kernel)."""
    command = [sys.executable, "-c", _BOOT.format(root=str(Path(__file__).parent.parent.parent),
                                                  path=__file__), str(trials), str(threads)]
    t0 = time.perf_counter()
    out = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    seconds = time.perf_counter() - t0
    if out.strip() != str(trials):
        raise RuntimeError(f"the kernel's process printed {out!r}, not {trials}")
    return seconds


def main(argv: list[str]) -> None:
    _package_alone()
    trials = int(argv[0])
    threads = int(argv[1]) if len(argv) > 1 else 2
    print(run(trials, threads), flush=True)
    os._exit(0)


if __name__ == "__main__":
    if str(Path(__file__).resolve().parent.parent.parent) not in sys.path:
        sys.path.insert(0, str(Path(__file__).resolve().parent.parent.parent))
    main(sys.argv[1:])
