"""What flatcli changes in numba and llvmlite where it owns the process, never on ``import
flatcli`` (``_jit.own_process`` installs it: docs/development.md, *Speed tricks stay home*).

Four changes for speed, none changing a number: LLVM's inliner threshold for the process
(``INLINE_THRESHOLD``); a cached kernel read without numba's compiler set up
(``load_lightly``); ``jitable`` functions registered at numba's first compile; numba's BLAS
check served without scipy.linalg (``load_numba_blas_alone``). The last three rely on numba
0.68's internals as read, and check that they are so; otherwise numba's own way stays.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import llvmlite.binding
import numba

#: LLVM's inliner threshold for everything compiled in flatcli's processes (LLVM's default at
#: -O3: 250, which inlined none of the dozen calls of a right-hand side, each passing its
#: arrays spread into 7-11 words): it inlines them, and the closed loop ran 1.2-1.6x as fast,
#: the numbers bit for bit the same (docs/development.md, docs/performance.md).
INLINE_THRESHOLD = 5000

#: The two extension modules numba's BLAS and LAPACK check imports (``numba.np.linalg``).
NUMBA_BLAS_MODULES = ("scipy.linalg.cython_blas", "scipy.linalg.cython_lapack")
#: The numba releases whose ``Cache.load_overload`` ``load_lightly`` was read against (its
#: body: ``target_context.refresh()``, then ``_load_overload`` under
#: ``_guard_against_spurious_io_errors``).
LIGHT_LOAD_NUMBA = ("0.68.",)
_LOAD_OVERLOAD_NAMES = ("refresh", "_guard_against_spurious_io_errors", "_load_overload")
#: What numba 0.68's ``Cache._load_overload`` reads, in order: the index key from the
#: codegen, the data from the cache file, the compile result rebuilt from it.
_READ_NAMES = ("_enabled", "_index_key", "codegen", "_cache_file", "load", "_impl", "rebuild")


def install(ownership: Any, caching: bool) -> None:
    """Turn the four changes on in this process, recording them in ``ownership`` (a
    ``_jit.Ownership``): the inliner threshold always; with numba 0.68 and a cache
    (``caching``), the light load, deferred registration and the BLAS modules loaded before a
    compile; otherwise the BLAS modules now (numba's refresh may come at any first call)."""
    llvmlite.binding.set_option("flatcli", f"-inline-threshold={INLINE_THRESHOLD}")
    ownership.owned = True
    if caching and light_load_applies():
        ownership.load = load_lightly
        ownership.defer = True
        ownership.before_compile = load_numba_blas_alone  # a compile runs numba's BLAS check
    else:
        load_numba_blas_alone()


def light_load_applies() -> bool:
    """Whether numba is as ``load_lightly`` was read: a release of ``LIGHT_LOAD_NUMBA``
    whose ``Cache.load_overload`` calls exactly the three names above and whose
    ``Cache._load_overload`` reads exactly ``_READ_NAMES``. ``FLATCLI_NUMBA_REFRESH=1``
    says no."""
    if os.environ.get("FLATCLI_NUMBA_REFRESH") == "1":
        return False
    if not numba.__version__.startswith(LIGHT_LOAD_NUMBA):
        return False
    try:
        from numba.core import caching
        from numba.core.runtime.nrt import rtsys
    except ImportError:
        return False
    code = getattr(getattr(caching.Cache, "load_overload", None), "__code__", None)
    if code is None or code.co_names != _LOAD_OVERLOAD_NAMES or code.co_varnames[:3] != (
            "self", "sig", "target_context"):
        return False
    read = getattr(getattr(caching.Cache, "_load_overload", None), "__code__", None)
    return (read is not None and read.co_names == _READ_NAMES
            and callable(getattr(rtsys, "initialize", None)))


def needs_runtime(data: Any) -> bool:
    """Whether a kernel's cached data (numba 0.68's ``CompileResult._reduce``: library state
    first, ``(name, "object", (object code, bitcode))``) may call numba's runtime: its object
    code names one of the runtime's symbols (NRT_*, nrt_*, _nrt_*: how every call into the
    runtime is linked). Anything not laid out so counts as needing it."""
    try:
        _name, kind, (object_code, _bitcode) = data[0]
    except (TypeError, ValueError, IndexError):
        return True
    return kind != "object" or not isinstance(object_code, bytes) or b"nrt_" in object_code.lower()


def load_lightly(cache: Any, sig: Any, target_context: Any,
                 numba_load: Callable[[Any, Any], Any]) -> Any:
    """Read a kernel from numba's on-disk cache without first setting up numba's compiler.

    Before it reads a cached kernel, numba 0.68 refreshes the CPU target: it imports and
    registers the lowering of everything numba compiles, 0.2-0.25 s of the 0.26 s a sweep
    worker's first call of a cached kernel took. Loading machine code needs only numba's
    runtime, and that only for a kernel whose machine code calls it (``needs_runtime``: its
    initialisation compiles the runtime's own module, 16-45 ms); a compile still refreshes
    the target first. The same machine code runs: the numbers are the same to the bit. An
    entry that cannot be read (truncated) is a miss: compiled again. Anything but numba's
    CPU target loads as numba does (``numba_load``).
    """
    from numba.core import cpu
    from numba.core.runtime.nrt import rtsys

    if not isinstance(target_context, cpu.CPUContext):
        load_numba_blas_alone()  # numba's own load refreshes the target: its BLAS check
        return numba_load(sig, target_context)
    with cache._guard_against_spurious_io_errors():
        if not cache._enabled:
            return None
        codegen = target_context.codegen()  # type: ignore[no-untyped-call]
        try:
            data = cache._cache_file.load(cache._index_key(sig, codegen))
        except Exception:  # an entry that cannot be read (truncated, not a pickle): a
            return None  # miss, so numba compiles the kernel again and rewrites it
        if data is None:
            return None
        if needs_runtime(data):
            rtsys.initialize(target_context)
        return cache._impl.rebuild(target_context, data)
    return None  # the guard swallowed an error: numba then compiles


def load_numba_blas_alone() -> list[str]:
    """Load scipy's ``cython_blas`` and ``cython_lapack`` without the rest of scipy.linalg.

    When numba sets up its compiler it checks that a BLAS exists with ``import
    scipy.linalg.cython_blas``, which imports all of ``scipy.linalg`` first (0.1-0.2 s) for
    modules no kernel uses. The two extension modules are self-contained; loaded here by file
    into ``sys.modules``, numba's import finds them. Anything unexpected (scipy absent or laid
    out otherwise, scipy.linalg imported already, a module that fails to load) leaves the
    normal import to do its work. Loading them costs about 4 ms, so it is done only where
    numba sets up its compiler: before a compile and before numba's own cache load. Returns
    the modules loaded.
    """
    if "scipy.linalg" in sys.modules or all(n in sys.modules for n in NUMBA_BLAS_MODULES):
        return []
    try:
        spec = importlib.util.find_spec("scipy")
    except (ImportError, ValueError):
        return []
    if spec is None or not spec.submodule_search_locations:
        return []
    linalg = Path(next(iter(spec.submodule_search_locations))) / "linalg"
    loaded: list[str] = []
    for name in NUMBA_BLAS_MODULES:
        if name in sys.modules:
            continue
        stem = name.rsplit(".", 1)[1]
        files = [linalg / (stem + suffix) for suffix in importlib.machinery.EXTENSION_SUFFIXES]
        path = next((f for f in files if f.is_file()), None)
        if path is None:
            return loaded
        loader = importlib.machinery.ExtensionFileLoader(name, str(path))
        module_spec = importlib.util.spec_from_file_location(name, path, loader=loader)
        if module_spec is None:
            return loaded
        try:
            module = importlib.util.module_from_spec(module_spec)
            sys.modules[name] = module
            loader.exec_module(module)
        except Exception:  # any failure: numba's own import then runs
            sys.modules.pop(name, None)
            return loaded
        loaded.append(name)
    return loaded
