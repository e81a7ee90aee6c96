"""What flatcli changes in numba where it owns the process (flatcli/core/_owned.py): the
light load of cached kernels, registration deferred to the first compile, numba's BLAS
check served without scipy.linalg. Each probe runs in a fresh process that flatcli owns
(``FLATCLI_OWN_PROCESS=1``, as the ``flatcli`` program sets it)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from flatcli.core import OWN_PROCESS_VARIABLE, _jit, _owned

OWNED = {OWN_PROCESS_VARIABLE: "1"}


def _fresh_process(code: str, env: dict[str, str], *args: str,
                   timeout: float = 600) -> dict[str, Any]:
    """Run ``code`` in a fresh Python with ``env`` added to this one's; its last line as
    JSON."""
    base = {k: v for k, v in os.environ.items() if k != OWN_PROCESS_VARIABLE}
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         check=True, timeout=timeout, env={**base, **env}).stdout
    return dict(json.loads(out.splitlines()[-1]))


_BLAS_PROBE = """
import json, sys
import numpy as np
{first}
import flatcli.core._jit as jit
import flatcli.core._owned as owned
jit.own_process()

@jit.allocating_kernel  # compiled as flatcli compiles its kernels
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
    "again": owned.load_numba_blas_alone(),
}}))
"""


@pytest.mark.parametrize("first", ["", "import scipy.linalg"])
def test_numba_finds_its_blas_without_scipy_linalg(first: str) -> None:
    """numba's BLAS check is served by the two extension modules loaded alone: a kernel's
    np.dot and np.linalg.solve still run, against numpy's own product and the residual of
    the solve (the referee), and scipy.linalg is not imported unless someone else did."""
    probe = _fresh_process(_BLAS_PROBE.format(first=first), {}, timeout=300)
    assert probe["linalg_loaded"] == bool(first)
    assert probe["dot_error"] < 1e-12
    assert probe["residual"] < 1e-12
    assert probe["again"] == []  # loaded once, or not at all where scipy.linalg was there


_WARM_BLAS_PROBE = """
import json, sys
import numpy as np
import flatcli.core._jit as jit
from flatcli.core._owned import NUMBA_BLAS_MODULES
from flatcli.montecarlo import Chunk, layout, run_chunk
from flatcli.spec import resolve
cell = layout(resolve({"plan": {"duration": 1.0}, "track": {"dt": 0.01},
                       "sweep": {"trials": 2}})).cells[0]
statuses = run_chunk(cell, Chunk(0, 0, 2)).table.column("status").to_pylist()
before = [m for m in NUMBA_BLAS_MODULES if m in sys.modules]

@jit.allocating_kernel  # compiled as flatcli compiles its kernels
def products(a, b):
    return np.dot(a, b), np.linalg.solve(a, b)

a = np.array([[4.0, 1.0], [1.0, 3.0]])
b = np.array([1.0, 2.0])
dot, solved = products(a, b)
print(json.dumps({
    "deferred": jit.OWNERSHIP.defer,
    "statuses": statuses,
    "blas_before_compile": before,
    "blas_after_compile": [m for m in NUMBA_BLAS_MODULES if m in sys.modules],
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
        probe = _fresh_process(_WARM_BLAS_PROBE, OWNED)
    if not probe["deferred"]:
        pytest.skip("numba is not as the light load was read (another numba)")
    assert probe["statuses"] == ["ok", "ok"]
    assert probe["blas_before_compile"] == []
    assert probe["blas_after_compile"] == list(_owned.NUMBA_BLAS_MODULES)
    assert not probe["linalg_loaded"]
    assert probe["residual"] < 1e-12 and probe["dot_error"] < 1e-12


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
import numpy as np

@jit.allocating_kernel
def compiled_after(n):  # a fresh compile: a typed list, a string and a linear solve
    items = [float(i) for i in range(n)]
    a = np.eye(3) * 2.0
    return len(str(n)) + sum(items) + np.linalg.solve(a, np.ones(3))[0]

print(json.dumps({"light": jit.OWNERSHIP.load is not None, "digest": digest,
                  "refreshed": refreshed, "compiled_after": compiled_after(4),
                  "pending": pending, "runtime": runtime,
                  "pending_after_a_compile": len(jit._PENDING)}))
"""


def test_a_cached_kernel_loads_without_numbas_compiler_and_computes_the_same_bits() -> None:
    """The light load (``load_lightly``) against numba's own load (``FLATCLI_NUMBA_REFRESH=1``,
    the referee), each in a fresh process on this machine: the same track of the paper's
    maneuver to the bit; numba's compiler registries (typed lists, jitclass, linear algebra)
    not imported by the light load; and a kernel compiled afterwards in the same process
    (a list, a string, a solve: registries the light load skipped) still compiles, with
    the functions left pending registered first, and gives 1 + 6 + 0.5."""
    _fresh_process(_LOAD_PROBE, OWNED)  # the kernel compiled into the cache, if it was not
    light = _fresh_process(_LOAD_PROBE, OWNED)
    numba_own = _fresh_process(_LOAD_PROBE, {**OWNED, "FLATCLI_NUMBA_REFRESH": "1"})
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


def test_the_light_load_declines_a_numba_it_was_not_read_against(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Another numba release, or a ``Cache.load_overload`` that calls other names: the light
    load does not apply (numba's own load stays); ``FLATCLI_NUMBA_REFRESH=1`` declines it
    too. It never replaces numba's class: flatcli's kernels have their own cache."""
    from numba.core import caching

    found = caching.Cache.load_overload
    assert _owned.light_load_applies() is (not os.environ.get("FLATCLI_NUMBA_REFRESH"))

    def other_load_overload(self: object, sig: object, target_context: object) -> None:
        target_context.refresh()  # type: ignore[attr-defined]
        return self.load(sig)  # type: ignore[attr-defined, no-any-return]

    monkeypatch.setattr(caching.Cache, "load_overload", other_load_overload)
    assert _owned.light_load_applies() is False
    monkeypatch.setattr(caching.Cache, "load_overload", found)
    monkeypatch.setattr(_owned.numba, "__version__", "0.70.0")
    assert _owned.light_load_applies() is False
    monkeypatch.setattr(_owned.numba, "__version__", "0.68.1")
    monkeypatch.setenv("FLATCLI_NUMBA_REFRESH", "1")
    assert _owned.light_load_applies() is False
    monkeypatch.delenv("FLATCLI_NUMBA_REFRESH")
    assert _owned.light_load_applies() is True  # numba 0.68's body, as read
    assert caching.Cache.load_overload is found


_USER_PROBE = """
import json, sys
sys.path.insert(0, sys.argv[1])
import flatcli.core._jit as jit
import userkern
value = userkern.twice_plus_one(3.0)
print(json.dumps({"light": jit.OWNERSHIP.load is not None, "value": value,
                  "refreshed": "numba.np.linalg" in sys.modules,
                  "hits": sum(userkern.twice_plus_one.stats.cache_hits.values())}))
"""


def test_a_users_own_cached_function_loads_as_numba_loads_it(tmp_path: Path) -> None:
    """The light load is for flatcli's kernels only: a cached numba function of the user's,
    even in a process flatcli owns, is read from the cache by numba's own ``load_overload``
    (its compiler set up first: numba.np.linalg imported, which the light load never
    imports), and gives 2 * 3 + 1."""
    (tmp_path / "userkern.py").write_text(
        "import numba\n\n@numba.njit(cache=True)\ndef twice_plus_one(x):\n    return 2 * x + 1\n")
    env = {**OWNED, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
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
pending = sorted(f.__name__ for f, _ in jit._PENDING)
compiled = barycentric_matrices(params)
same = all(barycentric_matrix(p[:4], p[8:12], p[12:]).tobytes() == compiled[i].tobytes()
           for i, p in enumerate(params))
from numba.core.runtime.nrt import rtsys
print(json.dumps({"deferred": jit.OWNERSHIP.defer, "pending": pending,
                  "left": len(jit._PENDING), "same": same, "runtime": rtsys._init,
                  "hits": sum(barycentric_matrices.stats.cache_hits.values())}))
"""


def test_a_kernel_compiles_from_a_cold_cache_with_its_functions_registered_late(
        tmp_path: Path) -> None:
    """With registration deferred a cold cache still compiles: the batch
    ``barycentric_matrices`` calls the jitable ``barycentric_matrix`` and ``lever_arms``,
    which numba can type only if they were registered before its compile began
    (``_jit.KernelCompiler``); its K is the Python function's to the bit (the referee), and
    nothing is left pending after the compile."""
    env = {**OWNED, "NUMBA_CACHE_DIR": str(tmp_path / "cold")}
    cold, warm = (_fresh_process(_COLD_PROBE, env) for _ in range(2))
    assert cold["deferred"] is True and cold["hits"] == 0
    assert {"barycentric_matrix", "lever_arms"} <= set(cold["pending"])
    assert cold["left"] == 0 and cold["same"] is True
    # loaded from the cache: an allocating kernel gets numba's runtime (without it, it crashes)
    assert warm["hits"] == 1 and warm["runtime"] is True and warm["same"] is True


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
    assert _owned.needs_runtime(cached(barycentric_matrices)) is True
    assert _owned.needs_runtime(cached(_variates)) is False
    assert _owned.needs_runtime((("k", "object", (b"call NRT_decref", b"")),)) is True
    assert _owned.needs_runtime((("k", "object", (b"plain code", b"")),)) is False
    assert _owned.needs_runtime((("k", "bitcode", b"plain code"),)) is True
    assert _owned.needs_runtime(None) is True
