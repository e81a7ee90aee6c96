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

from flatcli.core import OWN_PROCESS_VARIABLE, _jit

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


def _fresh_process(code: str, env: dict[str, str], *args: str, timeout: float = 600,
                   drop: tuple[str, ...] = ()) -> dict[str, Any]:
    """Run ``code`` in a fresh Python with ``env`` added to this one's (without
    ``FLATCLI_OWN_PROCESS`` unless ``env`` sets it, and without the variables ``drop``); its
    last line as JSON."""
    base = {k: v for k, v in os.environ.items() if k not in (OWN_PROCESS_VARIABLE, *drop)}
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         check=True, timeout=timeout, env={**base, **env}).stdout
    return dict(json.loads(out.splitlines()[-1]))


_CACHE_PROBE = """
import json, numba, flatcli.core.loop.simulate, flatcli.core._jit as j
print(json.dumps({"numba": numba.config.CACHE_DIR, "ours": str(j.CACHE_DIRECTORY),
                  "hash": j.core_source_hash()}))
"""


@pytest.mark.parametrize("users", [True, False])
def test_the_kernels_cache_is_hash_keyed_and_numbas_own_setting_stays_the_users(
        tmp_path: Path, users: bool) -> None:
    """In a fresh process the kernels' cache is the hash-keyed directory, and numba's own
    cache directory (where a user's ``cache=True`` functions go) is what the user set: their
    NUMBA_CACHE_DIR, or numba's default (none) without it."""
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "XDG_CACHE_HOME": ""}
    if users:
        env["NUMBA_CACHE_DIR"] = str(tmp_path / "n")
    out = _fresh_process(_CACHE_PROBE, env, timeout=300, drop=("NUMBA_CACHE_DIR",))
    if users:
        assert out["numba"] == str(tmp_path / "n")
        assert out["ours"] == str(tmp_path / "n" / f"flatcli-{out['hash']}")
    else:
        assert out["numba"] == ""
        assert out["ours"] == str(tmp_path / ".cache" / "flatcli" / "numba" / out["hash"])


_ASSEMBLY_PROBE = """
import hashlib, json, sys
exec(sys.argv[1])
import numba
terms = " + ".join(f"math.sin(x * {k}.0 + y) * math.cos(y - {k}.0)" for k in range(1, 30))
namespace = {}
exec(f"import math\\ndef helper(x, y):\\n    return {terms}\\n", namespace)
helper = numba.njit(namespace["helper"])

@numba.njit
def user(x, y):  # three calls of a helper whose inlining LLVM's threshold decides
    return helper(x, y) * helper(y, x) - helper(x + 1.0, y)

user(0.5, 0.25)
asm = user.inspect_asm(user.signatures[0])
print(json.dumps({"assembly": hashlib.sha256(asm.encode()).hexdigest(),
                  "calls": asm.count("call")}))
"""


def test_a_users_own_numba_code_compiles_the_same_with_flatcli_imported_and_used() -> None:
    """Issue 38: in a fresh process a user's @njit function compiles to the same assembly
    with and without ``import flatcli; flatcli.track()`` first. The referee that the probe
    can see a difference: the same function after flatcli's own-process tuning
    (``own_process``, LLVM's inliner threshold for the whole process) compiles otherwise."""
    alone = _fresh_process(_ASSEMBLY_PROBE, {}, "pass")
    after = _fresh_process(_ASSEMBLY_PROBE, {}, "import flatcli; flatcli.track(quiet=True)")
    owned = _fresh_process(_ASSEMBLY_PROBE, {}, "from flatcli.core._jit import own_process; "
                           "own_process()")
    assert after == alone
    assert owned["assembly"] != alone["assembly"]
    assert owned["calls"] > alone["calls"]  # the threshold inlined the helper's calls


_UNTOUCHED_PROBE = """
import json, sys
import llvmlite.binding
import numba
from numba.core import caching, compiler
options = []
real_set_option = llvmlite.binding.set_option
llvmlite.binding.set_option = lambda *a: (options.append(a), real_set_option(*a))
config = {k: repr(v) for k, v in vars(numba.config).items() if k.isupper()}
classes = (caching.Cache.load_overload, caching.Cache.save_overload,
           compiler.CompilerBase.__init__, compiler.Compiler.__init__)
import flatcli
imported = sorted(m for m in ("numpy", "numba.core.caching") if m in sys.modules)
result = flatcli.track(quiet=True)
import flatcli.core._jit as jit
print(json.dumps({
    "status": result.metrics["status"],
    "options": options,
    "config": {k: repr(v) for k, v in vars(numba.config).items() if k.isupper()} == config,
    "classes": classes == (caching.Cache.load_overload, caching.Cache.save_overload,
                           compiler.CompilerBase.__init__, compiler.Compiler.__init__),
    "blas_alone": "scipy.linalg.cython_blas" in sys.modules and "scipy.linalg" not in sys.modules,
    "owned": jit.OWNERSHIP.owned,
}))
"""


def test_import_flatcli_and_a_track_change_nothing_process_wide() -> None:
    """Issue 38: ``import flatcli`` and ``flatcli.track()`` set no LLVM option (llvmlite's
    set_option is watched), leave numba's configuration and the classes flatcli once
    replaced as they were, and load no scipy extension module by file (numba's BLAS
    check imports scipy.linalg the usual way, if at all); the process is not flatcli's own."""
    out = _fresh_process(_UNTOUCHED_PROBE, {})
    assert out["status"] == "ok"
    assert out["options"] == []
    assert out["config"] is True and out["classes"] is True
    assert out["blas_alone"] is False and out["owned"] is False


_STREAM_PROBE = """
import json
from flatcli.core import OWN_PROCESS_VARIABLE, _jit
from flatcli.montecarlo.streams import _variates, uniform_variates
values = uniform_variates(2003, [0, 1, 2], 0, 4)
stats = _variates.stats
print(json.dumps({"values": values.tolist(), "hits": sum(stats.cache_hits.values()),
                  "misses": sum(stats.cache_misses.values()), "owned": _jit.OWNERSHIP.owned}))
"""


@pytest.mark.parametrize("owned", [False, True])
def test_every_cached_kernel_was_compiled_by_a_process_flatcli_owns(
        tmp_path: Path, owned: bool) -> None:
    """A process flatcli does not own (a notebook, this test) never compiles a kernel into
    the cache itself: a child process flatcli owns compiles it, and the process reads it
    from the cache (a hit, no miss: the machine code every process then loads was compiled
    with flatcli's inliner threshold). A process flatcli owns (``FLATCLI_OWN_PROCESS=1``, as
    the program's) compiles it itself. A truncated cache entry (a full disk, a copy cut
    short) is a miss either way: compiled again and rewritten whole. The numbers are those
    of the first, intact run (the referee)."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "c")}
    if owned:
        env[OWN_PROCESS_VARIABLE] = "1"

    def run() -> dict[str, Any]:
        return _fresh_process(_STREAM_PROBE, env)

    first = run()
    assert first["owned"] is owned
    assert (first["hits"], first["misses"]) == ((0, 1) if owned else (1, 0))
    files = sorted((tmp_path / "c").rglob("*_variates*.nbc"))
    assert files
    for f in files:
        f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    again, warm = run(), run()
    assert again["values"] == warm["values"] == first["values"]
    assert (again["hits"], again["misses"]) == ((0, 1) if owned else (1, 0))
    assert (warm["hits"], warm["misses"]) == (1, 0)  # rewritten whole


def test_the_compile_child_imports_the_flatcli_its_parent_imported(tmp_path: Path) -> None:
    """A script that imports flatcli through ``PYTHONPATH`` while its working directory holds
    another ``flatcli`` (a checkout one stands in) gets its kernel compiled by a child that
    imports the parent's flatcli, not the directory's: the kernel is read from the cache (a
    hit, no miss), where before the child imported the other package, failed, and the
    kernel was compiled in the parent without flatcli's inliner setting (a miss). Referee:
    numba's own hit and miss counters, and the numbers of a run without the decoy."""
    decoy = tmp_path / "checkout" / "flatcli"
    decoy.mkdir(parents=True)
    (decoy / "__init__.py").write_text('raise ImportError("the decoy flatcli was imported")\n')
    script = tmp_path / "scripts" / "probe.py"
    script.parent.mkdir()
    script.write_text(_STREAM_PROBE)
    base = {k: v for k, v in os.environ.items() if k != OWN_PROCESS_VARIABLE}
    env = {**base, "NUMBA_CACHE_DIR": str(tmp_path / "c"), "PYTHONPATH": str(PACKAGE.parent)}
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          check=True, timeout=600, env=env, cwd=decoy.parent)
    out = json.loads(done.stdout.splitlines()[-1])
    assert "decoy" not in done.stderr
    assert out["owned"] is False
    assert (out["hits"], out["misses"]) == (1, 0)
    plain = _fresh_process(_STREAM_PROBE, {"NUMBA_CACHE_DIR": str(tmp_path / "c2")})
    assert out["values"] == plain["values"]


@pytest.mark.parametrize(("damage", "owned"), [("garbage", True), ("garbage", False),
                                               ("truncated", True), ("empty", False)])
def test_a_damaged_cache_index_is_compiled_again_once(tmp_path: Path, damage: str,
                                                      owned: bool) -> None:
    """A damaged index (``.nbi``) made numba raise (ValueError, UnpicklingError) when it
    saved the kernel it had compiled, on every run, until the cache was deleted: it is
    removed, the kernel compiled once and the index written whole, in a process flatcli owns
    and in one it does not (whose child compiles). Referee: the first, intact run's numbers
    and numba's own hit counter."""
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "c")}
    if owned:
        env[OWN_PROCESS_VARIABLE] = "1"

    def run() -> dict[str, Any]:
        return _fresh_process(_STREAM_PROBE, env)

    first = run()
    indexes = sorted((tmp_path / "c").rglob("*_variates*.nbi"))
    assert indexes
    for f in indexes:
        data = f.read_bytes()
        f.write_bytes({"garbage": bytes(range(7, 207)), "truncated": data[: len(data) // 2],
                       "empty": b""}[damage])
    again, warm = run(), run()
    assert again["values"] == first["values"]
    assert (again["hits"], again["misses"]) == ((0, 1) if owned else (1, 0))
    assert (warm["hits"], warm["misses"]) == (1, 0)  # the index written whole
    assert warm["values"] == first["values"]


def test_a_users_damaged_index_raises_as_numba_does(tmp_path: Path) -> None:
    """Only flatcli's kernels' indexes are repaired: numba's own index class still raises."""
    from numba.core import caching

    cache_file = caching.IndexDataCacheFile(str(tmp_path), "f", 0.0)
    (tmp_path / cache_file._index_name).write_bytes(b"\x80\x05garbage")
    with pytest.raises(Exception):  # noqa: B017 - whatever pickle raises
        cache_file._load_index()
    assert (tmp_path / cache_file._index_name).exists()


def test_a_kernel_compiled_here_is_not_cached_where_flatcli_does_not_own_the_process() -> None:
    """A kernel the child cannot compile (one made inside a function: not reachable by
    name) is compiled in this process, without flatcli's inliner threshold, and kept in
    memory only: nothing is written to the cache for flatcli's own processes to load."""
    if not _jit.CACHING or _jit.OWNERSHIP.owned:
        pytest.skip("needs a cache, and a process flatcli does not own")

    @_jit.kernel
    def triple_plus_two(x: float) -> float:
        return 3.0 * x + 2.0

    assert triple_plus_two(2.0) == 8.0
    stats = triple_plus_two.stats  # type: ignore[attr-defined]
    assert sum(stats.cache_misses.values()) == 1
    written = list(Path(stats.cache_path).glob("*triple_plus_two*"))
    assert written == []


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


