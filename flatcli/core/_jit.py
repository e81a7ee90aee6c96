"""One source for the physics, two ways to run it; the compiled kernels and their cache.

The formulas of the core are written once, as plain functions of floats that also broadcast
over numpy arrays. ``jitable`` marks such a function so that numba can inline it into the
compiled closed-loop kernel (``loop.kernels``), while Python callers keep calling it on arrays.

numba caches compiled kernels on disk, but only checks the file that holds the kernel for
changes, not the files of the functions it inlined. So the cache directory is keyed by a
hash of every module of the core, its folders' included: a change anywhere in the core
compiles afresh, never reuses a stale kernel. The cache lives in
``$XDG_CACHE_HOME/flatcli/numba/<hash>`` (default ``~/.cache``), or in
``$NUMBA_CACHE_DIR/flatcli-<hash>`` when the user sets ``NUMBA_CACHE_DIR``; if that cannot
be written, in ``<temporary directory>/flatcli-numba-<uid>/<hash>``; if no directory can be
written, kernels are compiled in every process and not cached. Never in the package's own
``__pycache__`` (numba's fallback), where a stale kernel would be found again. flatcli's
kernels find it through their own cache (``KernelCache``): ``numba.config`` stays the user's.

Importing the core changes nothing else in the process (no LLVM option, no numba class
replaced, no module put into ``sys.modules``): what flatcli's own processes change is
``_owned``'s, installed by ``own_process``; elsewhere kernels are compiled by a child process
flatcli owns (``compile_in_child``). docs/development.md, *Speed tricks stay home*.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import subprocess
import sys
import tempfile
import threading
import uuid
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar, cast

import numba
import numpy as np
from numba.core import caching
from numba.core.compiler import Compiler
from numba.core.dispatcher import Dispatcher
from numba.extending import register_jitable
from numpy.typing import NDArray

from flatcli.core import OWN_PROCESS_VARIABLE

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


#: Where the compiled kernels are cached (``cache_dir``), or None: compiled in every process.
CACHE_DIRECTORY = cache_dir(core_source_hash())
#: Whether compiled kernels are cached on disk.
CACHING = CACHE_DIRECTORY is not None


@dataclass
class Ownership:
    """What ``own_process`` turned on in this process (nothing on import): kernels compiled
    and saved here (``owned``), registration deferred (``defer``), a kernel's cached load
    ``(cache, sig, target context, numba's load)`` (``load``; None: numba's), a call before
    numba sets up a compile (``before_compile``)."""

    owned: bool = False
    defer: bool = False
    load: Callable[..., Any] | None = None
    before_compile: Callable[[], object] | None = None


#: This process's ``Ownership``.
OWNERSHIP = Ownership()


def own_process() -> None:
    """Make this process flatcli's own: numba and llvmlite tuned for its kernels (``_owned``),
    kernels compiled here and saved. Idempotent; never called on ``import flatcli``."""
    if OWNERSHIP.owned:
        return
    from flatcli.core import _owned

    _owned.install(OWNERSHIP, CACHING)

#: ``jitable`` functions not yet registered with numba (``Ownership.defer``), with numba's
#: ``inline`` option for each.
_PENDING: list[tuple[Callable[..., Any], str]] = []
_PENDING_LOCK = threading.Lock()


def register_pending() -> int:
    """Register with numba every ``jitable`` function marked since the last call; how many."""
    with _PENDING_LOCK:
        functions = list(_PENDING)
        _PENDING.clear()
    for fn, inline in functions:
        register_jitable(inline=inline)(fn)
    return len(functions)


def jitable(fn: F, inline: str = "never") -> F:
    """Mark a float/array function as callable from compiled kernels; behaviour is unchanged
    (registered with numba now, or before numba's first compile where ``Ownership.defer``)."""
    if OWNERSHIP.defer:
        with _PENDING_LOCK:
            _PENDING.append((fn, inline))
        return fn
    return register_jitable(inline=inline)(fn)


def inlined(fn: F) -> F:
    """``jitable``, its body inlined into its callers by numba (a part's function that takes
    whole records, which a call would pass by value, word by word: ``loop.base``)."""
    return jitable(fn, "always")


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


class KernelCompiler(Compiler):
    """numba's compiler for flatcli's kernels: the functions marked since the last compile
    are registered first (``Ownership.defer``), and ``Ownership.before_compile`` runs."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if _PENDING:
            register_pending()
        if OWNERSHIP.before_compile is not None:
            OWNERSHIP.before_compile()
        super().__init__(*args, **kwargs)  # type: ignore[no-untyped-call]


class _KernelLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
    """A kernel's cache files, in ``CACHE_DIRECTORY`` (a folder per source folder, as
    numba names them)."""

    def __init__(self, py_func: Callable[..., Any], py_file: str) -> None:
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        subpath = self.get_suitable_cache_subpath(py_file)  # type: ignore[no-untyped-call]
        self._cache_path = str(Path(str(CACHE_DIRECTORY)) / subpath)

    def get_cache_path(self) -> str:
        return self._cache_path


class _KernelCacheImpl(caching.CompileResultCacheImpl):
    _locator_classes = [_KernelLocator]  # noqa: RUF012 - numba's own class attribute


class _RepairingIndexFile(caching.IndexDataCacheFile):
    """numba's index of a kernel's cache entries, where an index that cannot be read counts
    as absent: removed, so numba compiles the kernel once and writes a fresh index.

    numba reads a kernel's index before it loads the kernel and again before it saves one it
    compiled (``_load_index``), and only a missing index counts as empty: a damaged one (a
    full disk, a copy cut short, a stray write) raised UnpicklingError or ValueError after
    every full recompile, so every track and sweep failed until the user deleted the cache.
    Only flatcli's kernels' indexes (in ``CACHE_DIRECTORY``) are read through this class; a
    user's own numba functions keep numba's."""

    def _load_index(self) -> Any:
        try:
            return super()._load_index()  # type: ignore[no-untyped-call]
        except Exception:  # whatever unpickling a damaged index raises
            Path(self._index_path).unlink(missing_ok=True)
            return {}


class KernelCache(caching.FunctionCache):
    """The on-disk cache of one kernel, in ``CACHE_DIRECTORY``. Only a process flatcli owns
    writes it; elsewhere a kernel it lacks is compiled by one (``compile_in_child``) and read
    back, or, if that fails, compiled here and not cached: no kernel compiled without
    flatcli's inliner threshold is ever cached for its own processes to load."""

    _impl_class = _KernelCacheImpl

    def __init__(self, py_func: Callable[..., Any]) -> None:
        super().__init__(py_func)  # type: ignore[no-untyped-call]
        self._cache_file.__class__ = _RepairingIndexFile  # the same fields, the repair added

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        if OWNERSHIP.load is not None:
            return OWNERSHIP.load(self, sig, target_context, self._numba_load)
        found = self._numba_load(sig, target_context)
        if found is None and not OWNERSHIP.owned and compile_in_child(self._py_func, sig):
            found = self._numba_load(sig, target_context)
        return found

    def _numba_load(self, sig: Any, target_context: Any) -> Any:
        """numba's own load; an entry that cannot be read (a truncated file: numba raises
        UnpicklingError) is a miss, so the kernel is compiled again and its entry rewritten."""
        try:
            return super().load_overload(sig, target_context)  # type: ignore[no-untyped-call]
        except Exception:  # whatever numba's reading of a bad entry raises
            return None

    def save_overload(self, sig: Any, data: Any) -> None:
        if OWNERSHIP.owned:
            super().save_overload(sig, data)  # type: ignore[no-untyped-call]


#: The module ``compile_in_child`` runs (``python -m``).
CHILD_MODULE = "flatcli.core._compile"


def compile_in_child(py_func: Callable[..., Any], sig: Any) -> bool:
    """Compile the kernel ``py_func`` for the argument types ``sig`` into the cache in a child
    process flatcli owns (``python -m flatcli.core._compile``); whether it did (not for a
    kernel made inside a function, types that do not pickle, or a child that fails: warned).
    """
    module, name = py_func.__module__, py_func.__qualname__
    if "<" in name or not sys.executable:
        return False
    try:
        payload = pickle.dumps((module, name, sig))
    except (pickle.PicklingError, TypeError, AttributeError):
        return False
    # The child imports what this process imported: its path is this one's, and ``-P`` keeps
    # ``-m`` from putting the working directory first (a checkout one stands in would win).
    path = os.pathsep.join(p or os.getcwd() for p in sys.path)
    try:
        done = subprocess.run([sys.executable, "-P", "-m", CHILD_MODULE], input=payload,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, check=False,
                              env={**os.environ, "PYTHONPATH": path, OWN_PROCESS_VARIABLE: "1"})
    except OSError as exc:
        warnings.warn(f"flatcli: cannot start a process to compile {name} ({exc}); compiled "
                      "here without flatcli's inliner setting (slower)", RuntimeWarning,
                      stacklevel=2)
        return False
    if done.returncode != 0:
        said = [line for line in done.stderr.decode(errors="replace").splitlines()
                if line.strip()]
        warnings.warn(f"flatcli: compiling {name} in a child process failed "
                      f"({said[-1] if said else done.returncode}); compiled here without "
                      "flatcli's inliner setting (slower)", RuntimeWarning, stacklevel=2)
        return False
    return True


#: Every kernel made in this process, by (module, qualified name): how the child of
#: ``compile_in_child`` finds one (a kernel ``compile_kernels`` generated too).
KERNELS_BY_NAME: dict[tuple[str, str], Any] = {}


def _dispatcher(fn: F, runtime: bool) -> F:
    """``fn`` compiled by numba on first call: nopython, no GIL, IEEE semantics (no
    fastmath), numba's runtime or not, cached in ``CACHE_DIRECTORY`` (``KernelCache``)."""
    options: dict[str, Any] = {} if runtime else {"_nrt": False}  # numba's stubs lack it
    dispatcher = numba.njit(nogil=True, error_model="numpy", pipeline_class=KernelCompiler,
                            **options)(fn)
    KERNELS_BY_NAME[fn.__module__, fn.__qualname__] = dispatcher
    if CACHING and isinstance(dispatcher, Dispatcher):
        try:
            cache: Any = KernelCache(fn)
        except RuntimeError:  # no source file to key it by (code given to python -c)
            return cast(F, dispatcher)
        setattr(dispatcher, "_cache", cache)  # noqa: B010 - numba's enable_caching: its locators
    return cast(F, dispatcher)


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
    return _dispatcher(fn, runtime=False)


def allocating_kernel(fn: F) -> F:
    """``kernel`` with numba's runtime: for kernels that allocate or return arrays (batch
    helpers called once per batch, not per step)."""
    return _dispatcher(fn, runtime=True)



def named_kernel(name: str, module: str) -> Callable[[F], F]:
    """``kernel`` for a function a factory makes, as ``module.name``: numba caches a kernel by
    its module and qualified name, and links its code by them, so each must be its own
    (``loop.kernels.compile_kernels``)."""

    def mark(fn: F) -> F:
        fn.__name__ = fn.__qualname__ = name
        fn.__module__ = module
        return kernel(fn)

    return mark

if os.environ.get(OWN_PROCESS_VARIABLE) == "1":
    own_process()
