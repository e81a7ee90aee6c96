"""Starting under a memory limit: the numerical libraries are loaded in a forked probe
first, so that a library that cannot be loaded ends the command in one line.

Under an address-space limit (``ulimit -v``, a container's) a shared object that fails to
map is an ImportError, a MemoryError or an OSError raised in the middle of an import, and
OpenBLAS, when it cannot map its buffers, either ends the process itself or retries forever.
Only another process can see the last two and end them: ``probe_libraries`` loads the
libraries in a child (30 s at most) before a command runs, and reports why they could not
be loaded. Without a limit nothing is probed. Standard library only: this runs before numpy
is imported, and must itself fit where numpy does not.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import resource
import signal
import sys
import time

#: The libraries every command loads, in the order they load.
LIBRARIES = ("numpy", "pandas", "pyarrow", "scipy.optimize", "numba")
#: How long loading them may take in the probe of ``probe_libraries`` [s] (about 2 s here).
PROBE_SECONDS = 30.0
#: Marks the probe's own line among what the libraries print.
PROBE_MARK = "flatcli-probe: "


def probe_libraries() -> str | None:
    """Under an address-space limit (``ulimit -v``), load the numerical libraries in a
    forked child first: the one line saying why they cannot be loaded, or None.

    A shared object that fails to map is an ImportError, but OpenBLAS, when it cannot map
    its buffers at load time, retries forever: only another process can see that and end
    it. Without a limit nothing is probed (and nothing costs anything).
    """
    soft = resource.getrlimit(resource.RLIMIT_AS)[0]
    if soft == resource.RLIM_INFINITY or "numpy" in sys.modules:
        return None
    read, write = os.pipe()
    try:
        pid = os.fork()
    except OSError:  # no memory even to fork: the command's own imports will say so
        os.close(read)
        os.close(write)
        return None
    if pid == 0:  # the child: load, report, end without the parent's clean-up
        os.close(read)
        status = 0
        try:
            os.dup2(write, 2)  # what a library prints itself (OpenBLAS) goes to the parent
            for name in LIBRARIES:
                importlib.import_module(name)
            _exercise_blas()
        except BaseException as exc:
            status = 1
            with contextlib.suppress(BaseException):
                os.write(write, f"\n{PROBE_MARK}{library_error_text(exc)}".encode()[:4000])
        os._exit(status)
    os.close(write)
    deadline = time.monotonic() + PROBE_SECONDS
    while not (ended := os.waitpid(pid, os.WNOHANG))[0]:
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            os.close(read)
            return (f"loading the numerical libraries did not end within {PROBE_SECONDS:.0f} s "
                    f"under the address-space limit of {soft / 2**20:.0f} MiB (ulimit -v; "
                    "OpenBLAS retries forever when it cannot map its buffers): raise that "
                    "limit")
        time.sleep(0.02)
    with os.fdopen(read, "rb") as pipe:
        said = pipe.read(1 << 16).decode("utf-8", "replace")
    if os.WIFEXITED(ended[1]) and os.WEXITSTATUS(ended[1]) == 0:
        return None
    if PROBE_MARK in said:
        return said.rpartition(PROBE_MARK)[2].strip()
    last = ([line.strip() for line in said.splitlines() if line.strip()] or [
        f"the process loading them ended with status {os.waitstatus_to_exitcode(ended[1])}"])[-1]
    return (f"cannot load the numerical libraries ({last[:160]}); this process may use at most "
            f"{soft / 2**20:.0f} MiB of address space (ulimit -v): raise that limit")


def _exercise_blas() -> None:
    """Make both copies of OpenBLAS (numpy's and scipy's) map their buffers, as a plan's
    first solve does: where they cannot, OpenBLAS ends the process itself."""
    import numpy as np
    import scipy.linalg

    a = np.eye(64) + np.ones((64, 64)) / 64
    np.linalg.solve(a, np.ones(64))
    scipy.linalg.lu_factor(a)


def while_importing(exc: BaseException) -> bool:
    """Whether ``exc`` was raised while a module was being imported (a library that failed
    to load, e.g. under a memory limit), not by a command's own work."""
    if "shared object" in str(exc):  # a library's own loader (llvmlite loads on first use)
        return True
    tb = exc.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        tb = tb.tb_next
    return False


def library_error_text(exc: BaseException) -> str:
    """One line for a library that could not be loaded: why, and the memory limit if any
    (a shared object that fails to map under ``ulimit -v`` is the usual cause)."""
    while exc.__cause__ is not None or exc.__context__ is not None:  # the first failure
        exc = exc.__cause__ or exc.__context__  # type: ignore[assignment]
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    why = f"{type(exc).__name__}: {lines[-1][:160]}" if lines else type(exc).__name__
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    hint = (f"; this process may use at most {limit / 2**20:.0f} MiB of address space "
            "(ulimit -v): raise that limit" if limit != resource.RLIM_INFINITY else
            "; out of memory, or a broken installation")
    return f"cannot load the numerical libraries ({why}){hint}"
