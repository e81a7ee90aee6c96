"""The compiled-code cache (flatcli/core/_jit.py): keyed by the core's source hash in every
configuration, never in the package's own directory."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from flatcli.core import _jit

PACKAGE = Path(_jit.__file__).resolve().parents[1]


def test_the_source_hash_changes_with_any_file_of_the_core(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    copy = tmp_path / "core"
    shutil.copytree(Path(_jit.__file__).parent, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(_jit, "_CORE_DIR", copy)
    before = _jit.core_source_hash()
    assert before == _jit.core_source_hash()
    # modules the kernels inline, in the core's folders, not the kernels' own file
    for module in ("loop/metrics.py", "models/chainflat.py", "robots/chain.py"):
        edited = copy / module
        edited.write_text(edited.read_text() + "\n# an edit\n")
        after = _jit.core_source_hash()
        assert after != before, module
        before = after
    (copy / "plants" / "kinematic.py").write_text("# a new module in a folder\n")
    assert _jit.core_source_hash() != before


def test_a_users_numba_cache_dir_gets_a_hash_subdirectory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert _jit.cache_dir("abc123") == tmp_path / "mine" / "flatcli-abc123"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _jit.cache_dir("abc123") == tmp_path / "xdg" / "flatcli" / "numba" / "abc123"


def test_an_unwritable_cache_falls_back_to_a_temporary_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")  # no directory can be made under a regular file
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocker / "cache"))
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(_jit.tempfile, "tempdir", None)  # read TMPDIR again
    found = _jit.cache_dir("abc123")
    assert found is not None and found.parent.parent == tmp_path / "tmp"
    assert found.name == "abc123"
    # nothing writable at all: no disk cache
    monkeypatch.setattr(_jit.tempfile, "gettempdir", lambda: str(blocker))
    assert _jit.cache_dir("abc123") is None
    for candidate in _jit.cache_candidates("abc123"):
        assert PACKAGE not in candidate.parents


def test_numba_uses_the_hash_keyed_directory_in_a_fresh_process(tmp_path: Path) -> None:
    code = ("import numba, flatcli.core.loop.simulate as s, flatcli.core._jit as j; "
            "print(numba.config.CACHE_DIR, j.CACHING, j.core_source_hash())")
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "n")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=300, check=True).stdout.split()
    assert out[1] == "True"
    assert out[0] == str(tmp_path / "n" / f"flatcli-{out[2]}")


_BLAS_PROBE = """
import json, sys
import numpy as np
{first}
import flatcli.core._jit as jit
import numba

@numba.njit
def products(a, b):
    return np.dot(a, b), np.linalg.solve(a, b)

rng = np.random.default_rng(7)
a = rng.standard_normal((4, 4)) + 4 * np.eye(4)
b = rng.standard_normal(4)
dot, solved = products(a, b)
print(json.dumps({{
    "linalg_loaded": "scipy.linalg" in sys.modules,
    "dot_error": float(np.max(np.abs(dot - a @ b))),
    "residual": float(np.max(np.abs(a @ solved - b))),
    "again": jit.load_numba_blas_alone(),
}}))
"""


@pytest.mark.parametrize("first", ["", "import scipy.linalg"])
def test_numba_finds_its_blas_without_scipy_linalg(first: str) -> None:
    """numba's BLAS check is served by the two extension modules loaded alone: a compiled
    np.dot and np.linalg.solve still run, against numpy's own product and the residual of
    the solve (the referee), and scipy.linalg is not imported unless someone else did."""
    out = subprocess.run([sys.executable, "-c", _BLAS_PROBE.format(first=first)],
                         capture_output=True, text=True, check=True, timeout=300).stdout
    probe = json.loads(out.splitlines()[-1])
    assert probe["linalg_loaded"] == bool(first)
    assert probe["dot_error"] < 1e-12
    assert probe["residual"] < 1e-12
    assert probe["again"] == []  # loaded once, or not at all where scipy.linalg was there


_WARM_BLAS_PROBE = """
import json, sys
import numpy as np
import flatcli.core._jit as jit
from flatcli.montecarlo import Chunk, layout, run_chunk
from flatcli.spec import resolve
cell = layout(resolve({"plan": {"duration": 1.0}, "track": {"dt": 0.01},
                       "sweep": {"trials": 2}})).cells[0]
statuses = run_chunk(cell, Chunk(0, 0, 2)).table.column("status").to_pylist()
before = [m for m in jit.NUMBA_BLAS_MODULES if m in sys.modules]
import numba

@numba.njit
def products(a, b):
    return np.dot(a, b), np.linalg.solve(a, b)

a = np.array([[4.0, 1.0], [1.0, 3.0]])
b = np.array([1.0, 2.0])
dot, solved = products(a, b)
print(json.dumps({
    "deferred": jit.DEFERRED,
    "statuses": statuses,
    "blas_before_compile": before,
    "blas_after_compile": [m for m in jit.NUMBA_BLAS_MODULES if m in sys.modules],
    "linalg_loaded": "scipy.linalg" in sys.modules,
    "residual": float(np.max(np.abs(a @ solved - b))),
    "dot_error": float(np.max(np.abs(dot - a @ b))),
}))
"""


def test_a_warm_process_loads_no_blas_until_numba_compiles() -> None:
    """A process that only loads flatcli's kernels from the cache (a sweep's chunk, twice: the
    second warm) never loads scipy's BLAS modules (about 4 ms); a compile afterwards loads
    them alone, before numba's BLAS check, and its np.dot and np.linalg.solve run (the
    referees: numpy's own product and the solve's residual)."""
    for _ in range(2):  # the first may compile (a cold cache): the second is warm
        out = subprocess.run([sys.executable, "-c", _WARM_BLAS_PROBE], capture_output=True,
                             text=True, check=True, timeout=600).stdout
    probe = json.loads(out.splitlines()[-1])
    if not probe["deferred"]:
        pytest.skip("numba's compile is not hooked here (another numba): loaded at import")
    assert probe["statuses"] == ["ok", "ok"]
    assert probe["blas_before_compile"] == []
    assert probe["blas_after_compile"] == list(_jit.NUMBA_BLAS_MODULES)
    assert not probe["linalg_loaded"]
    assert probe["residual"] < 1e-12 and probe["dot_error"] < 1e-12


def test_a_variant_is_named_by_its_tag() -> None:
    """``jitable_variant`` appends the combination's tag to the qualified name numba reads;
    the tag depends on the functions' modules and names only (the same for the same
    combination, different for another)."""

    def make(step: object) -> object:
        @_jit.jitable_variant(_jit.variant_tag(step))  # type: ignore[arg-type]
        def run(x: float) -> float:
            return x

        return run

    first, again, other = make(_jit.writable), make(_jit.writable), make(_jit.cache_dir)
    assert first.__qualname__ == again.__qualname__  # type: ignore[attr-defined]
    assert first.__qualname__ != other.__qualname__  # type: ignore[attr-defined]
    assert first.__qualname__.endswith(  # type: ignore[attr-defined]
        "_" + _jit.variant_tag(_jit.writable))
    assert len(_jit.variant_tag(_jit.writable)) == 12


_LOAD_PROBE = """
import hashlib, json, sys
import flatcli
import flatcli.core._jit as jit
frame = flatcli.track(quiet=True).frame  # the paper's maneuver and feedback (a cached kernel)
digest = hashlib.sha256(frame.to_numpy(dtype=float).tobytes()).hexdigest()
refreshed = sorted(m for m in ("numba.typed.typedlist", "numba.experimental.jitclass.base",
                               "numba.np.linalg") if m in sys.modules)
pending = len(jit._PENDING)  # jitable functions not registered: nothing was compiled
from numba.core.runtime.nrt import rtsys
runtime = rtsys._init  # the paper's kinematic loop never calls numba's runtime
import numba
import numpy as np

@numba.njit
def compiled_after(n):  # a fresh compile: a typed list, a string and a linear solve
    items = [float(i) for i in range(n)]
    a = np.eye(3) * 2.0
    return len(str(n)) + sum(items) + np.linalg.solve(a, np.ones(3))[0]

print(json.dumps({"light": jit.LIGHT_LOAD, "digest": digest, "refreshed": refreshed,
                  "compiled_after": compiled_after(4), "pending": pending, "runtime": runtime,
                  "pending_after_a_compile": len(jit._PENDING)}))
"""


def _fresh_process(code: str, env: dict[str, str], *args: str,
                   timeout: float = 600) -> dict[str, Any]:
    """Run ``code`` in a fresh Python with ``env`` added to this one's; its last line as JSON."""
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         check=True, timeout=timeout, env={**os.environ, **env}).stdout
    return dict(json.loads(out.splitlines()[-1]))


def _probe(env: dict[str, str]) -> dict[str, Any]:
    return _fresh_process(_LOAD_PROBE, env)


def test_a_cached_kernel_loads_without_numbas_compiler_and_computes_the_same_bits() -> None:
    """The light load (``load_cached_kernels_lightly``) against numba's own load
    (``FLATCLI_NUMBA_REFRESH=1``, the referee), each in a fresh process on this machine:
    the same track of the paper's maneuver to the bit; numba's compiler registries (typed
    lists, jitclass, linear algebra) not imported by the light load; and a function
    compiled afterwards in the same process (a list, a string, a solve: registries the
    light load skipped) still compiles and gives 1 + 6 + 0.5."""
    _probe({})  # the kernel compiled into the cache, if it was not there yet
    light, numba_own = _probe({}), _probe({"FLATCLI_NUMBA_REFRESH": "1"})
    assert light["light"] is True and numba_own["light"] is False
    assert light["digest"] == numba_own["digest"]
    assert light["refreshed"] == []
    assert numba_own["refreshed"] == ["numba.experimental.jitclass.base", "numba.np.linalg",
                                      "numba.typed.typedlist"]
    assert light["compiled_after"] == numba_own["compiled_after"] == 7.5
    # the core's jitable functions: registered with numba at the first compile, not before
    assert light["pending"] > 100 and light["pending_after_a_compile"] == 0
    assert numba_own["pending"] == 0  # numba's own load: registered when marked
    assert light["runtime"] is False and numba_own["runtime"] is True


def test_the_light_load_leaves_a_numba_it_was_not_read_against_alone(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Another numba release, or a ``Cache.load_overload`` that calls other names: numba's
    own load stays in place."""
    from numba.core import caching

    def other_load_overload(self: object, sig: object, target_context: object) -> None:
        target_context.refresh()  # type: ignore[attr-defined]
        return self.load(sig)  # type: ignore[attr-defined, no-any-return]

    monkeypatch.setattr(caching.Cache, "load_overload", other_load_overload)
    assert _jit.load_cached_kernels_lightly() is False
    assert caching.Cache.load_overload is other_load_overload

    def as_read(self: object, sig: object, target_context: object) -> object:
        target_context.refresh()  # type: ignore[attr-defined]
        with self._guard_against_spurious_io_errors():  # type: ignore[attr-defined]
            return self._load_overload(sig, target_context)  # type: ignore[attr-defined]

    monkeypatch.setattr(caching.Cache, "load_overload", as_read)
    monkeypatch.setattr(_jit.numba, "__version__", "0.70.0")
    assert _jit.load_cached_kernels_lightly() is False
    assert caching.Cache.load_overload is as_read
    monkeypatch.setenv("FLATCLI_NUMBA_REFRESH", "1")
    monkeypatch.setattr(_jit.numba, "__version__", "0.68.1")
    assert _jit.load_cached_kernels_lightly() is False
    monkeypatch.delenv("FLATCLI_NUMBA_REFRESH")
    assert _jit.load_cached_kernels_lightly() is True  # the body as read: replaced
    assert getattr(caching.Cache.load_overload, "_flatcli_light", False)


_USER_PROBE = """
import json, sys
sys.path.insert(0, sys.argv[1])
import flatcli.core._jit as jit
import userkern
value = userkern.twice_plus_one(3.0)
print(json.dumps({"light": jit.LIGHT_LOAD, "value": value,
                  "refreshed": "numba.np.linalg" in sys.modules,
                  "hits": sum(userkern.twice_plus_one.stats.cache_hits.values())}))
"""


def test_a_users_own_cached_function_loads_as_numba_loads_it(tmp_path: Path) -> None:
    """The light load is for flatcli's kernels only: a cached numba function of the user's,
    in a process that imported flatcli, is read from the cache by numba's own
    ``load_overload`` (its compiler set up first: numba.np.linalg imported, which the light
    load never imports), and gives 2 * 3 + 1."""
    (tmp_path / "userkern.py").write_text(
        "import numba\n\n@numba.njit(cache=True)\ndef twice_plus_one(x):\n    return 2 * x + 1\n")
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    compiled, loaded = (_fresh_process(_USER_PROBE, env, str(tmp_path), timeout=300)
                        for _ in range(2))
    assert compiled["hits"] == 0 and loaded["hits"] == 1  # the second read the cache
    assert loaded["light"] is True and loaded["refreshed"] is True
    assert compiled["value"] == loaded["value"] == 7.0


_COLD_PROBE = """
import json, sys
import numpy as np
import flatcli.core._jit as jit
from flatcli.core.robots.chain import barycentric_matrices, barycentric_matrix
rng = np.random.default_rng(5)
params = rng.uniform(0.05, 2.0, (20, 16))  # 20 chains of N = 3: mass, inertia, length, com
pending = sorted(f.__name__ for f in jit._PENDING)
compiled = barycentric_matrices(params)
same = all(barycentric_matrix(p[:4], p[8:12], p[12:]).tobytes() == compiled[i].tobytes()
           for i, p in enumerate(params))
from numba.core.runtime.nrt import rtsys
print(json.dumps({"deferred": jit.DEFERRED, "pending": pending, "left": len(jit._PENDING),
                  "same": same, "runtime": rtsys._init, "hits": sum(
                      barycentric_matrices.stats.cache_hits.values())}))
"""


def test_a_kernel_compiles_from_a_cold_cache_with_its_functions_registered_late(
        tmp_path: Path) -> None:
    """With registration deferred (``defer_registration``) a cold cache still compiles: the
    batch ``barycentric_matrices`` calls the jitable ``barycentric_matrix`` and
    ``lever_arms``, which numba can type only if they were registered before its compile
    began; its K is the Python function's to the bit (the referee), and nothing is left
    pending after the compile."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cold")}
    cold, warm = (_fresh_process(_COLD_PROBE, env) for _ in range(2))
    assert cold["deferred"] is True and cold["hits"] == 0
    assert {"barycentric_matrix", "lever_arms"} <= set(cold["pending"])
    assert cold["left"] == 0 and cold["same"] is True
    # loaded from the cache: an allocating kernel gets numba's runtime (without it, it crashes)
    assert warm["hits"] == 1 and warm["runtime"] is True and warm["same"] is True


def test_registration_is_not_deferred_where_numbas_compiler_is_not_as_read(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A ``CompilerBase.__init__`` that does not refresh the typing context: functions
    register when marked (``defer_registration`` declines and changes nothing)."""
    from numba.core import compiler

    def other_init(self: object, *args: object) -> None:
        self.args = args  # type: ignore[attr-defined]

    monkeypatch.setattr(compiler.CompilerBase, "__init__", other_init)
    assert _jit.defer_registration() is False
    assert compiler.CompilerBase.__init__ is other_init


def test_a_kernel_needs_the_runtime_when_its_machine_code_names_it() -> None:
    """``needs_runtime`` on numba's own cached data: the allocating ``barycentric_matrices``
    (np.empty: numba's runtime) needs it, the plain ``streams._variates`` does not; data laid
    out otherwise counts as needing it."""
    import numpy as np

    from flatcli.core.robots.chain import barycentric_matrices
    from flatcli.montecarlo.streams import _variates, uniform_variates

    barycentric_matrices(np.ones((1, 12)))
    uniform_variates(1, [0], 0, 2)

    def cached(dispatcher: object) -> object:
        cache = dispatcher._cache  # type: ignore[attr-defined]
        sig = dispatcher.signatures[0]  # type: ignore[attr-defined]
        codegen = dispatcher.targetctx.codegen()  # type: ignore[attr-defined]
        data = cache._cache_file.load(cache._index_key(sig, codegen))
        assert data is not None
        return data

    if not _jit.CACHING:
        pytest.skip("no writable cache directory")
    assert _jit.needs_runtime(cached(barycentric_matrices)) is True
    assert _jit.needs_runtime(cached(_variates)) is False
    assert _jit.needs_runtime((("k", "object", (b"call NRT_decref", b"")),)) is True
    assert _jit.needs_runtime((("k", "object", (b"plain code", b"")),)) is False
    assert _jit.needs_runtime((("k", "bitcode", b"plain code"),)) is True
    assert _jit.needs_runtime(None) is True


_STREAM_PROBE = """
import json
from flatcli.montecarlo.streams import _variates, uniform_variates
values = uniform_variates(2003, [0, 1, 2], 0, 4)
print(json.dumps({"values": values.tolist(), "hits": sum(_variates.stats.cache_hits.values())}))
"""


def test_a_cache_entry_that_cannot_be_read_is_compiled_again(tmp_path: Path) -> None:
    """A truncated kernel file in numba's cache (a full disk, a copy cut short): numba's own
    load raises UnpicklingError; the light load counts it as a miss, so the kernel compiles
    again and rewrites the entry. The numbers are those of the first, intact run."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "c")}

    def run() -> dict[str, Any]:
        return _fresh_process(_STREAM_PROBE, env)

    first = run()
    files = sorted((tmp_path / "c").rglob("*_variates*.nbc"))
    assert files and first["hits"] == 0
    for f in files:
        f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    again, warm = run(), run()
    assert again["hits"] == 0 and again["values"] == first["values"]
    assert warm["hits"] == 1 and warm["values"] == first["values"]  # rewritten whole
