"""One source for the physics, two ways to run it.

The formulas of the core are written once, as plain functions of floats that also broadcast
over numpy arrays. ``jitable`` marks such a function so that numba can inline it into the
compiled closed-loop kernel (``kernels``), while Python callers keep calling it on arrays.

numba caches compiled kernels on disk, but only checks the file that holds the kernel for
changes, not the files of the functions it inlined. So the cache directory is keyed by a
hash of every source file of the core, in every configuration: a change anywhere in the core
compiles afresh, never reuses a stale kernel. The cache lives in
``$XDG_CACHE_HOME/flatcli/numba/<hash>`` (default ``~/.cache``), or in
``$NUMBA_CACHE_DIR/flatcli-<hash>`` when the user sets ``NUMBA_CACHE_DIR``; if that cannot
be written, in ``<temporary directory>/flatcli-numba-<uid>/<hash>``; if no directory can be
written, kernels are compiled in every process and not cached. Never in the package's own
``__pycache__`` (numba's fallback), where a stale kernel would be found again.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import os
import sys
import tempfile
import threading
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

#: The two extension modules numba's BLAS and LAPACK check imports (``numba.np.linalg``).
NUMBA_BLAS_MODULES = ("scipy.linalg.cython_blas", "scipy.linalg.cython_lapack")


def load_numba_blas_alone() -> list[str]:
    """Load scipy's ``cython_blas`` and ``cython_lapack`` without the rest of scipy.linalg.

    When numba sets up its compiler (before the first compiled call, cached kernels
    included) it checks that a BLAS exists with ``import scipy.linalg.cython_blas``, and
    Python imports a submodule's package first: all of ``scipy.linalg``, 0.1-0.2 s of
    every flatcli process for modules no kernel uses. The two extension modules are
    self-contained (numba reads their ``__pyx_capi__`` tables); loaded here by file into
    ``sys.modules``, numba's import finds them and scipy.linalg is not imported. Anything
    unexpected (scipy absent or laid out otherwise, scipy.linalg already imported, a module
    that fails to load) leaves the normal import to do its work. Returns the modules loaded
    (none when they are there already).

    Loading them costs about 4 ms (scipy's own OpenBLAS, numpy loaded), so it is done only
    where numba sets up its compiler: before a compile (``defer_registration``'s hook) and
    before numba's own cache load (the light load's fallback); a process that only loads
    flatcli's kernels from the cache never needs them (no cached kernel of flatcli calls
    BLAS or LAPACK).
    Without those hooks in place (``DEFERRED`` false) they are loaded when this module is.
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


import llvmlite.binding  # noqa: E402
import numba  # noqa: E402 - its import checks scipy's version only, not its BLAS
import numpy as np  # noqa: E402
from numba.extending import register_jitable  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

#: LLVM's inliner threshold for everything compiled in this process (LLVM's own default at
#: -O3: 275). numba compiles every ``jitable`` function on its own and calls it with each
#: array of its arguments spread into 7-11 words, a record of arrays into a hundred and
#: more: one right-hand side of the N-link dynamic plant made about 12 calls and pushed
#: some 500 words. At 275 LLVM inlined none of them; with this threshold it inlines them
#: into the right-hand side (which stays one function the integrators call), and the closed
#: loop ran 1.2-1.6x as fast (N = 3, 4, 6, both plants; the paper's loop 1.15-1.2x;
#: interleaved on one machine, 2026-12-03), the numbers bit for bit the same (inlining
#: does not change IEEE arithmetic; checked on 200 outcomes), compiling ~15 % longer.
INLINE_THRESHOLD = 5000
llvmlite.binding.set_option("flatcli", f"-inline-threshold={INLINE_THRESHOLD}")

F = TypeVar("F", bound=Callable[..., Any])

#: A float, or an array of any batch shape (...): the kernels see floats, Python callers arrays.
Real = float | NDArray[np.float64]

_CORE_DIR = Path(__file__).resolve().parent


def core_source_hash() -> str:
    """Hash of the source of every module of the core, its folders' included [12 hex
    digits]."""
    digest = hashlib.sha256()
    for path in sorted(_CORE_DIR.rglob("*.py")):
        digest.update(path.relative_to(_CORE_DIR).as_posix().encode())
        digest.update(path.read_bytes())
    digest.update(numba.__version__.encode())
    return digest.hexdigest()[:12]


def writable(directory: Path) -> bool:
    """Whether files can be created in ``directory`` (made if need be)."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
        probe = directory / f".probe-{uuid.uuid4().hex}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError:
        return False
    return True


def cache_candidates(source_hash: str) -> list[Path]:
    """Where the compiled kernels of the core with ``source_hash`` may be cached, in order
    of preference (each keyed by the hash)."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        first = Path(user) / f"flatcli-{source_hash}"
    else:
        home = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        first = Path(home) / "flatcli" / "numba" / source_hash
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return [first, Path(tempfile.gettempdir()) / f"flatcli-numba-{uid}" / source_hash]


def cache_dir(source_hash: str) -> Path | None:
    """The first writable directory of ``cache_candidates``, or None."""
    for candidate in cache_candidates(source_hash):
        if writable(candidate):
            return candidate
    return None


def _configure_cache() -> bool:
    """Point numba's cache at a hash-keyed writable directory; False if there is none."""
    directory = cache_dir(core_source_hash())
    if directory is None:
        return False
    setattr(numba.config, "CACHE_DIR", str(directory))  # noqa: B010
    return True


#: Whether compiled kernels are cached on disk (a writable hash-keyed directory exists).
CACHING = _configure_cache()


#: The numba releases whose ``Cache.load_overload`` ``load_cached_kernels_lightly`` was
#: read against (its body: ``target_context.refresh()``, then ``_load_overload`` under
#: ``_guard_against_spurious_io_errors``).
LIGHT_LOAD_NUMBA = ("0.68.",)
_LOAD_OVERLOAD_NAMES = ("refresh", "_guard_against_spurious_io_errors", "_load_overload")
#: What numba 0.68's ``Cache._load_overload`` reads, in order: the index key from the
#: codegen, the data from the cache file, the compile result rebuilt from it.
_READ_NAMES = ("_enabled", "_index_key", "codegen", "_cache_file", "load", "_impl", "rebuild")


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


def load_cached_kernels_lightly() -> bool:
    """Load a kernel from numba's on-disk cache without first setting up numba's compiler.

    Before it reads a cached kernel, numba 0.68 refreshes the CPU target
    (``Cache.load_overload`` calls ``target_context.refresh()``): it imports and registers
    the lowering of every feature numba compiles (numba.cpython.*, numba.np.linalg, arraymath,
    the typed containers, jitclass, third-party extensions' entry points), 0.2-0.25 s of
    the 0.26 s a sweep worker's first call of a cached kernel took. Loading machine code needs
    none of it, only numba's runtime (``rtsys.initialize``, which the refresh also does), so
    that is all this load does, and the runtime only for a kernel whose machine code calls it
    (``needs_runtime``: initialising it compiles the runtime's own module, 16-45 ms, which
    the paper's kinematic loop never calls); a compile still refreshes the target first
    (``CompilerBase.__init__``), and so does a lowering that finds no implementation
    (``BaseContext.get_function``). The numbers are the same to the bit (the same machine
    code runs). A cache entry that cannot be read (a truncated file: numba's own load
    raises UnpicklingError there) counts as a miss: the kernel is compiled again.

    This relies on numba's internals deliberately, and only where they are as read: a numba
    release of ``LIGHT_LOAD_NUMBA`` whose ``Cache.load_overload`` calls exactly the three
    names above and whose ``Cache._load_overload`` (which this load does in its own way)
    reads exactly ``_READ_NAMES``, a CPU target, and a function of flatcli's own (a
    notebook's cached numba functions beside flatcli load as numba loads them); anything
    else loads as numba does.
    ``FLATCLI_NUMBA_REFRESH=1`` turns it off. Returns whether the light load is in place.
    """
    if os.environ.get("FLATCLI_NUMBA_REFRESH") == "1":
        return False
    if not numba.__version__.startswith(LIGHT_LOAD_NUMBA):
        return False
    try:
        from numba.core import caching, cpu
        from numba.core.runtime.nrt import rtsys
    except ImportError:
        return False
    found = getattr(caching.Cache, "load_overload", None)
    if getattr(found, "_flatcli_light", False):
        return True
    code = getattr(found, "__code__", None)
    if found is None or code is None:
        return False
    original: Callable[..., Any] = found
    if code.co_names != _LOAD_OVERLOAD_NAMES or code.co_varnames[:3] != (
        "self",
        "sig",
        "target_context",
    ):
        return False
    if not callable(getattr(rtsys, "initialize", None)):
        return False
    read = getattr(getattr(caching.Cache, "_load_overload", None), "__code__", None)
    if read is None or read.co_names != _READ_NAMES:
        return False

    def load_overload(self: Any, sig: Any, target_context: Any) -> Any:
        if not (isinstance(target_context, cpu.CPUContext) and _flatcli_function(self)):
            load_numba_blas_alone()  # numba's own load refreshes the target: its BLAS check
            return original(self, sig, target_context)
        with self._guard_against_spurious_io_errors():
            if not self._enabled:
                return None
            codegen = target_context.codegen()  # type: ignore[no-untyped-call]
            try:
                data = self._cache_file.load(self._index_key(sig, codegen))
            except Exception:  # an entry that cannot be read (truncated, not a pickle): a
                return None  # miss, so numba compiles the kernel again and rewrites it
            if data is None:
                return None
            if needs_runtime(data):
                rtsys.initialize(target_context)
            return self._impl.rebuild(target_context, data)
        return None  # the guard swallowed an error: numba then compiles

    load_overload._flatcli_light = True  # type: ignore[attr-defined]
    load_overload.__doc__ = original.__doc__
    setattr(caching.Cache, "load_overload", load_overload)  # noqa: B010
    return True


def _flatcli_function(cache: Any) -> bool:
    """Whether a numba cache object caches one of flatcli's own functions."""
    module = getattr(getattr(cache, "_py_func", None), "__module__", None)
    return isinstance(module, str) and module.startswith("flatcli.")


#: Whether cached kernels load without numba's compiler set up (``load_cached_kernels_lightly``).
LIGHT_LOAD = CACHING and load_cached_kernels_lightly()


#: ``jitable`` functions not yet registered with numba (``DEFERRED``).
_PENDING: list[Callable[..., Any]] = []
_PENDING_LOCK = threading.Lock()


def register_pending() -> int:
    """Register with numba every ``jitable`` function marked since the last call; how many."""
    with _PENDING_LOCK:
        functions = list(_PENDING)
        _PENDING.clear()
    for fn in functions:
        register_jitable(fn)
    return len(functions)


def defer_registration() -> bool:
    """Register ``jitable`` functions with numba when numba first compiles, not when marked.

    numba's ``register_jitable`` builds a typing template per function, about 0.13 ms each:
    36 ms of every flatcli process for the ~270 functions of the core, which a process that
    only loads its kernels from the cache never types. ``CompilerBase.__init__``, where
    every compile of numba's begins (it refreshes the typing context, which is what takes the
    new templates in), registers the pending functions first. Only where numba's
    ``CompilerBase.__init__`` refreshes the typing context as read, and only with the light
    cache load (``LIGHT_LOAD``: numba 0.68, caching on); otherwise functions register when
    marked. Returns whether registration is deferred.
    """
    from numba.core import compiler

    base = getattr(compiler, "CompilerBase", None)
    found = getattr(base, "__init__", None)
    if getattr(found, "_flatcli_registers", False):
        return True
    code = getattr(found, "__code__", None)
    if base is None or found is None or code is None or "refresh" not in code.co_names:
        return False
    original: Callable[..., Any] = found

    def __init__(self: Any, *args: Any, **kwargs: Any) -> None:  # noqa: N807
        if _PENDING:
            register_pending()
        load_numba_blas_alone()  # the refresh below runs numba's BLAS check
        original(self, *args, **kwargs)

    __init__._flatcli_registers = True  # type: ignore[attr-defined]
    __init__.__doc__ = original.__doc__
    setattr(base, "__init__", __init__)  # noqa: B010
    return True


#: Whether ``jitable`` registers functions with numba at its first compile
#: (``defer_registration``) rather than when they are marked.
DEFERRED = LIGHT_LOAD and defer_registration()
if not DEFERRED:  # numba's refresh may come at any first call: its BLAS check served now
    load_numba_blas_alone()


def jitable(fn: F) -> F:
    """Mark a float/array function as callable from compiled kernels; behaviour is unchanged
    (registered with numba now, or before numba's first compile when ``DEFERRED``)."""
    if DEFERRED:
        with _PENDING_LOCK:
            _PENDING.append(fn)
        return fn
    return register_jitable(fn)


def variant_tag(*functions: Callable[..., Any]) -> str:
    """A name for one combination of functions that a factory closes over [12 hex digits]:
    the same in every process (from their modules and qualified names, not their ids)."""
    text = ";".join(f"{f.__module__}.{f.__qualname__}" for f in functions)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def jitable_variant(tag: str) -> Callable[[F], F]:
    """``jitable`` for a closure a factory makes once per combination (``variant_tag``).

    numba names a compiled function by its module, qualified name, argument types and a
    counter of the process that compiled it, and a process that loads two cached kernels
    links a name the two share to one definition. A factory's closures share the first
    three (``make_batch.<locals>.run_batch`` of the as-built kinematic and dynamic loops
    take the same types), so two kernels compiled by processes whose counters stood alike
    (forked sweep workers, two fresh processes) carried one name for two functions, and a
    process that loaded both ran one plant's batch loop for the other (found with the
    as-built kernels: the second kernel loaded gave NaN states, ``unresolved``, from a
    warm cache). The combination's tag in the qualified name makes the names differ.
    """

    def mark(fn: F) -> F:
        fn.__qualname__ = f"{fn.__qualname__}_{tag}"
        return jitable(fn)

    return mark


def kernel(fn: F) -> F:
    """Compile a kernel: no Python objects, IEEE semantics (no fastmath), cached on disk
    (``CACHING``), and without numba's runtime (no reference counting, no allocation).

    numba counts the references of every array a compiled function extracts from a record
    or slices, with an atomic operation per count; on the N-link loop, whose records hold a
    dozen arrays, that cost three times the arithmetic. A kernel instead takes every array
    it writes from its caller and allocates nothing (numba refuses ``np.empty`` and friends
    here at compile time); the numbers are the same to the bit. Kernels that must allocate
    use ``allocating_kernel``.
    """
    options: dict[str, Any] = {"_nrt": False}  # an option numba's type stubs do not list
    return cast(F, numba.njit(cache=CACHING, nogil=True, error_model="numpy", **options)(fn))


def allocating_kernel(fn: F) -> F:
    """``kernel`` with numba's runtime: for kernels that allocate or return arrays (batch
    helpers called once per batch, not per step)."""
    return cast(F, numba.njit(cache=CACHING, nogil=True, error_model="numpy")(fn))
