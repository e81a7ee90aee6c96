"""The start-up floor of a flatcli sweep process: what no flatcli process can do without.

``floor_seconds`` runs, in a fresh interpreter, a script that imports what a sweep's process
must (numpy, numba, pyarrow.parquet, click) and flatcli's numba set-up alone
(``flatcli.core._jit``: the cache directory and the light cache load), loads one tiny cached
kernel (``PROBE_SOURCE``, under a name of flatcli's so that the light load takes it), calls
it once and exits as flatcli does (``os._exit``). Everything a sweep does beyond that
(flatcli's own modules, the spec, the cells' plans, its kernels' loads, the trials, the
tables) is flatcli's distance from the floor.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

#: The module name the probe is loaded under (a flatcli function: the light load applies).
PROBE_NAME = "flatcli.floor_probe"

#: The floor's kernel: sum(x**2) of a 1-D array (any cached kernel would do). Written to a
#: file of its own, which no other process imports under another name (numba's cache entry
#: names the module that compiled it).
PROBE_SOURCE = '''import numba


@numba.njit(cache=True, nogil=True)
def sum_of_squares(x):
    total = 0.0
    for i in range(x.shape[0]):
        total += x[i] * x[i]
    return total
'''

_SCRIPT = """
import importlib.util, os, sys
import numpy as np, numba, pyarrow.parquet, click
import flatcli.core._jit
spec = importlib.util.spec_from_file_location({name!r}, {path!r})
probe = importlib.util.module_from_spec(spec)
sys.modules[{name!r}] = probe
spec.loader.exec_module(probe)
print(probe.sum_of_squares(np.ones(3)), flush=True)
{before_exit}
os._exit(0)
"""


def floor_script(directory: Path, before_exit: str = "") -> str:
    """The floor's script, its probe written to ``directory`` (kept as it is if unchanged,
    so that numba's cache entry of it stays valid)."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "floor_probe.py"
    if not path.exists() or path.read_text() != PROBE_SOURCE:
        path.write_text(PROBE_SOURCE)
    return _SCRIPT.format(name=PROBE_NAME, path=str(path), before_exit=before_exit)


def floor_seconds(directory: Path) -> float:
    """Wall time of one run of the floor's script in a fresh interpreter [s] (its first run
    with a new probe file compiles the probe: run it once before timing)."""
    script = floor_script(directory)
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", script], check=True, capture_output=True,
                         text=True).stdout
    seconds = time.perf_counter() - t0
    if out.strip() != "3.0":  # sum of the squares of three ones
        raise RuntimeError(f"the floor's probe printed {out!r}, not 3.0")
    return seconds
