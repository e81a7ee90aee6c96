"""One source for the physics, two ways to run it.

The formulas of the core are written once, as plain functions of floats that also broadcast
over numpy arrays. ``jitable`` marks such a function so that numba can inline it into the
compiled closed-loop kernel (``simulate``), while Python callers keep calling it on arrays.

numba caches compiled kernels on disk, but only checks the file that holds the kernel for
changes, not the files of the functions it inlined. So the cache directory is keyed by a
hash of every source file of the core: a change anywhere in the core compiles afresh, never
reuses a stale kernel. A user's own ``NUMBA_CACHE_DIR`` is respected.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numba.extending import register_jitable
from numpy.typing import NDArray

F = TypeVar("F", bound=Callable[..., Any])

#: A float, or an array of any batch shape (...): the kernels see floats, Python callers arrays.
Real = float | NDArray[np.float64]

_CORE_DIR = Path(__file__).resolve().parent


def core_source_hash() -> str:
    """Hash of the source of every module of the core [12 hex digits]."""
    digest = hashlib.sha256()
    for path in sorted(_CORE_DIR.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    digest.update(numba.__version__.encode())
    return digest.hexdigest()[:12]


def _configure_cache() -> None:
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    setattr(numba.config, "CACHE_DIR", str(base / "flatcli" / "numba" / core_source_hash()))  # noqa: B010


_configure_cache()


def jitable(fn: F) -> F:
    """Mark a float/array function as callable from compiled kernels; behaviour is unchanged."""
    return register_jitable(fn)


def kernel(fn: F) -> F:
    """Compile a kernel: no Python objects, IEEE semantics (no fastmath), cached on disk."""
    return cast(F, numba.njit(cache=True, nogil=True, error_model="numpy")(fn))
