"""One-line mutants of flatcli's guarantees under misuse, and whether the tests catch each.

    python -m benchmarks.mutants [--out runs/mutants] [--only ID ...] [--list] [--work DIR]

Each mutant is one plausible one-line bug: a file, the exact text of one line (or part of
it), its replacement, the kind of guarantee it breaks (docs/failures.md) and the tests that
pin that guarantee. The runner copies the package, the tests and what they read into a work
directory once, applies each mutant to that copy alone (the checkout is never touched), runs
the mutant's tests against the copy in a fresh interpreter (``PYTHONPATH`` points at the
copy, checked before the first run), then restores the file, its content and its time stamp
(so numba's on-disk cache of the copy stays valid between mutants). Every set of tests
is first run on the unmutated copy and must pass there. A mutant is *killed*
when its tests fail or time out, *survives* when they pass; a mutant whose text is not found
exactly once is *stale* (the code changed: update the list). Writes ``OUT/mutants.md`` and
``OUT/mutants.json``; the exit status is 1 if the kill rate is below ``TARGET``.

The first run compiles the copy's kernels (numba caches by source path): a few minutes; later
runs reuse the copy and its cache.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from flatcli.report.tables import table

#: What the tests of the copy need beside the package.
COPIED = ("flatcli", "tests", "benchmarks", "configs", "docs", "pyproject.toml",
          "README.md")
#: The kill rate the issue asks for.
TARGET = 0.9
#: Longest run of one mutant's tests [s] (a mutant that makes a read block is caught by the
#: tests' own timeouts well before).
TIMEOUT = 900.0


@dataclass(frozen=True)
class Mutant:
    """One one-line edit: in ``path``, ``old`` (found exactly once) becomes ``new``."""

    ident: str
    kind: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]  # pytest arguments: test files, optionally "-k", an expression


def _m(ident: str, kind: str, path: str, old: str, new: str, *tests: str) -> Mutant:
    return Mutant(ident, kind, path, old, new, tests)


SWEEP_DIR = "tests/test_montecarlo_directory.py"
DIRECTORY = "flatcli/montecarlo/directory.py"
CLI = "tests/test_cli.py"

MUTANTS = (
    # a manifest's names reach outside the directory
    _m("manifest-search", "manifest names", DIRECTORY,
       "if not RECORDED.fullmatch(name):", "if not RECORDED.search(name):", SWEEP_DIR),
    _m("manifest-chunk-any-cell", "manifest names", DIRECTORY,
       "if not (name.startswith(prefix) and _CHUNK.fullmatch(name)):",
       "if not _CHUNK.search(name):", SWEEP_DIR),
    _m("inside-no-parent-check", "manifest names", "flatcli/files.py",
       'parent = real_directory(directory, "/".join(parts[:-1]) or ".")',
       "parent = directory", "tests/test_files.py", SWEEP_DIR),
    _m("record-any-name", "manifest names", DIRECTORY,
       "if RECORDED.fullmatch(name) and is_regular(directory / name):", "if True:", SWEEP_DIR),
    _m("manifest-trials-one-past", "id space", DIRECTORY,
       'if not _count(data.get("trials_per_cell"), ID_STRIDE)',
       'if not _count(data.get("trials_per_cell"), ID_STRIDE + 1)', SWEEP_DIR),
    # a link, directory or FIFO named like flatcli's file is taken as flatcli's
    _m("foreign-not-regular", "symlink or directory as flatcli's", DIRECTORY,
       "elif stat.S_ISREG(mode) and (name in owned or",
       "elif not stat.S_ISDIR(mode) and (name in owned or", SWEEP_DIR),
    _m("clear-any-entry", "symlink or directory as flatcli's", DIRECTORY,
       "if path is not None and is_regular(path):",
       "if path is not None and os.path.lexists(path) and not path.is_dir():", SWEEP_DIR),
    _m("real-directory-follows-links", "symlink or directory as flatcli's", "flatcli/files.py",
       'if kind(path) != "a directory":', "if not path.is_dir():", "tests/test_files.py",
       SWEEP_DIR),
    _m("sweep-non-regular-unchecked", "non-regular files", DIRECTORY,
       "return not_regular(directory, [*FINAL_FILES, *sorted(present)])", "return []",
       SWEEP_DIR),
    _m("claim-non-regular-unchecked", "non-regular files", "flatcli/rundirs.py",
       "blocked = not_regular(out, RUN_FILES)", "blocked: list[str] = []", "tests/test_rundirs.py"),
    _m("read-blocks-on-fifo", "non-regular files", "flatcli/files.py",
       "os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC",
       "os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC", "tests/test_files.py"),
    _m("read-any-non-directory", "non-regular files", "flatcli/files.py",
       "if not stat.S_ISREG(info.st_mode):", "if stat.S_ISDIR(info.st_mode):",
       "tests/test_files.py", "tests/test_rundirs.py"),
    _m("chunk-opened-blindly", "non-regular files", DIRECTORY,
       "if not is_regular(path):  # never opened: a FIFO would block", "if False:", SWEEP_DIR),
    _m("state-opens-fifo", "non-regular files", "flatcli/rundirs.py",
       "if not is_regular(path):  # never opened: a FIFO would block", "if False:", SWEEP_DIR),
    _m("lock-any-file", "non-regular files", "flatcli/storage.py",
       "if not stat.S_ISREG(os.fstat(fd).st_mode):", "if False:", "tests/test_storage.py"),
    _m("rerun-through-link", "non-regular files", "flatcli/montecarlo/rerun.py",
       "if blocked:  # never written through: a link would lead out of the sweep's directory",
       "if False:", "tests/test_montecarlo_rerun.py"),
    # atomic writes
    _m("fsync-dropped", "fsync dropped", "flatcli/storage.py",
       "os.fsync(fh.fileno())", "fh.flush()", "tests/test_storage.py"),
    _m("directory-fsync-dropped", "fsync dropped", "flatcli/storage.py",
       "        _fsync_directory(path.parent)", "        pass", "tests/test_storage.py"),
    _m("temp-in-system-tmp", "temporary file outside the target's directory",
       "flatcli/storage.py", "dir=path.parent)", "dir=None)", "tests/test_storage.py"),
    _m("os-error-names-temp", "every OS error names its file", "flatcli/storage.py",
       "if exc.filename is not None and (tmp is None or exc.filename != str(tmp)):",
       "if True:", "tests/test_storage.py"),
    # the checksum
    _m("checksum-no-null-mask", "checksum ignoring the null mask", "flatcli/storage.py",
       "digest.update(np.asarray(array.is_null().to_numpy(zero_copy_only=False)).tobytes())",
       "pass", "tests/test_storage.py"),
    # --out checked for reading, or not before the work
    _m("out-read-permission", "--out checks read, not write", "flatcli/storage.py",
       "if not os.access(probe, os.W_OK | os.X_OK):",
       "if not os.access(probe, os.R_OK | os.X_OK):", "tests/test_storage.py",
       f"{CLI}::test_an_unwritable_out_is_refused_before_any_work"),
    _m("out-unchecked-without-out", "--out checks read, not write", "flatcli/api.py",
       '    check_output_dir(target.path, "--out" if out is not None else "the run directory")',
       "    pass", CLI, "-k", "unwritable"),
    _m("lock-makes-out-first", "--out checks read, not write", "flatcli/api.py",
       "    check_output_dir(Path(out))\n", "    pass\n", CLI, "-k", "unwritable"),
    # one writer per directory
    _m("plan-track-no-lock", "one writer per directory", "flatcli/api.py",
       "    return directory_lock(Path(out))", "    return contextlib.nullcontext()", CLI, "-k",
       "another_run_writes"),
    # name
    _m("name-dot-dot", "name", "flatcli/spec/keys.py",
       'or value.startswith("."):', 'or value == ".":', "tests/test_spec_keys.py"),
    _m("name-c0-only", "name", "flatcli/spec/keys.py",
       'UNPRINTABLE = ("Cc", "Cf", "Zl", "Zp")', 'UNPRINTABLE = ("Cc",)',
       "tests/test_spec_keys.py"),
    # the id space, the memory of the chunks in flight, the in-flight window
    _m("trials-one-past-id-space", "id space", "flatcli/spec/limits.py",
       "if sweep.trials > ID_STRIDE:", "if sweep.trials > ID_STRIDE + 1:",
       "tests/test_spec_limits.py"),
    _m("chunk-memory-one-worker", "chunk memory not times workers", "flatcli/spec/limits.py",
       "2 * cores() * chunk * chunk_trial_bytes(joints)", "2 * chunk * chunk_trial_bytes(joints)",
       "tests/test_spec_limits.py"),
    _m("workers-memory-one-worker", "chunk memory not times workers", "flatcli/spec/limits.py",
       'require_memory(f"--workers {workers}", workers * per_worker,',
       'require_memory(f"--workers {workers}", per_worker,', "tests/test_spec_limits.py"),
    _m("window-unbounded", "unbounded in-flight window", "flatcli/executors.py",
       "window = 2 * self.workers", "window = 10**6", "tests/test_executors.py"),
    # chunk size
    _m("chunk-rounds-down", "chunk size rounding", "flatcli/montecarlo/layout.py",
       "math.ceil(per_cell / CHUNKS_PER_CELL)", "per_cell // CHUNKS_PER_CELL",
       "tests/test_montecarlo_layout.py"),
    _m("chunk-may-exceed-cell", "chunk size rounding", "flatcli/montecarlo/layout.py",
       "return min(per_cell, max(CHUNK_MIN,", "return max(1, max(CHUNK_MIN,",
       "tests/test_montecarlo_layout.py"),
    # check's calibration and warnings
    _m("calibration-one-short", "check off by one", "flatcli/preflight.py",
       "k = min(lay.trials_per_cell, 1 + math.ceil(CALIBRATION_TRIALS / n))",
       "k = min(lay.trials_per_cell, math.ceil(CALIBRATION_TRIALS / n))",
       "tests/test_preflight.py"),
    _m("busy-one-past", "check off by one", "flatcli/preflight.py",
       "report.load >= report.cores", "report.load > report.cores", "tests/test_preflight.py"),
    # the singular set
    _m("zero-margin-no-crossing", "margin exactly 0 not a crossing",
       "flatcli/core/loop/integrate.py",
       "return (a > 0.0) != (b > 0.0) or b == 0.0", "return (a > 0.0) != (b > 0.0)",
       "tests/test_integrate.py"),
    # spec rules
    _m("grid-key-twice", "spec rules", "flatcli/spec/sweeps.py",
       "            if key in setters:", "            if key in setters and False:",
       "tests/test_spec_sweeps.py"),
    _m("torque-any-finite", "spec rules", "flatcli/spec/sweeps.py",
       "if not all(math.isfinite(v) for v in limits):",
       "if not any(math.isfinite(v) for v in limits):", "tests/test_spec_sweeps.py"),
    _m("rtol-any-positive", "sizes", "flatcli/spec/schema.py",
       '"cannot be met)", ge=MIN_RTOL)', '"cannot be met)", gt=0)',
       "tests/test_spec_limits.py"),
    _m("step-budget-underestimated", "sizes", "flatcli/spec/limits.py",
       'track.max_steps * SECONDS_PER_ATTEMPT, "lower track.max_steps")',
       'track.max_steps * SECONDS_PER_ATTEMPT / 1e3, "lower track.max_steps")',
       "tests/test_spec_limits.py"),
    _m("joints-one-past", "sizes", "flatcli/spec/limits.py",
       "if joints > MAX_JOINTS:", "if joints > MAX_JOINTS + 1:", "tests/test_spec_limits.py"),
    _m("joints-checked-late", "sizes", "flatcli/spec/build.py",
       "    check_joints(spec.joints)  # before anything costs O(N^3)", "    pass",
       "tests/test_spec_limits.py"),
    # run records
    _m("record-time-trusted", "runs trusts run.json", "flatcli/rundirs.py",
       '    if "time" in record and _parse_time(record["time"]) is None:', "    if False:",
       "tests/test_rundirs.py"),
    _m("record-read-unbounded", "runs trusts run.json", "flatcli/rundirs.py",
       "value = json.loads(read_bounded(path, MAX_RECORD_BYTES))",
       "value = json.loads(path.read_text())", "tests/test_rundirs.py"),
    # output hygiene
    _m("closed-stdout-late", "output hygiene", "flatcli/cli.py",
       "    if not quiet and sys.stdout is None:", "    if False:", CLI, "-k", "closed_stdout"),
    _m("stdout-error-unnamed", "output hygiene", "flatcli/cli.py",
       "            if exc.filename is None:", "            if False:",
       f"{CLI}::test_a_closed_stdout_is_one_line_and_exit_1",
       f"{CLI}::test_a_failing_last_flush_of_stdout_names_it"),
    _m("export-unrecorded", "output hygiene", "flatcli/export.py",
       "            record_outputs(sweep, written)", "            pass", "tests/test_export.py",
       f"{CLI}::test_exported_csv_files_do_not_block_force"),
)


def copy_tree(source: Path, work: Path) -> None:
    """The package, the tests and what they read, into ``work`` (time stamps kept)."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".pytest_cache")
    for name in COPIED:
        path = source / name
        if path.is_dir():
            shutil.copytree(path, work / name, ignore=ignore)
        elif path.exists():
            shutil.copy2(path, work / name)


def environment(work: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(work), "PYTHONDONTWRITEBYTECODE": "1"}


def check_copy_is_imported(work: Path) -> None:
    """The copy's flatcli is the one its tests import (not the checkout's editable one)."""
    found = subprocess.run([sys.executable, "-c", "import flatcli; print(flatcli.__file__)"],
                           cwd=work, env=environment(work), capture_output=True, text=True,
                           check=True).stdout.strip()
    if not Path(found).resolve().is_relative_to(work.resolve()):
        raise SystemExit(f"the tests would import {found}, not the copy in {work}")


def run_tests(work: Path, tests: tuple[str, ...]) -> tuple[bool, float, str]:
    """Whether the tests pass against the copy as it is now, their wall time, last line."""
    began = time.perf_counter()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *tests],
            cwd=work, env=environment(work), capture_output=True, text=True, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        return False, time.perf_counter() - began, f"timed out after {TIMEOUT:.0f} s"
    lines = [line for line in done.stdout.splitlines() if line.strip()]
    return done.returncode == 0, time.perf_counter() - began, (lines or [""])[-1]


@dataclass
class Outcome:
    ident: str
    kind: str
    status: str  # "killed", "survived", "stale"
    seconds: float
    detail: str


def run_mutant(work: Path, mutant: Mutant) -> Outcome:
    path = work / mutant.path
    text = path.read_text()
    count = text.count(mutant.old)
    if count != 1:
        return Outcome(mutant.ident, mutant.kind, "stale", 0.0,
                       f"{mutant.old!r} found {count} times in {mutant.path}")
    stamp = path.stat()
    path.write_text(text.replace(mutant.old, mutant.new))
    try:
        passed, seconds, last = run_tests(work, mutant.tests)
    finally:
        path.write_text(text)
        os.utime(path, ns=(stamp.st_atime_ns, stamp.st_mtime_ns))
    return Outcome(mutant.ident, mutant.kind, "survived" if passed else "killed", seconds, last)


def report(outcomes: list[Outcome]) -> tuple[str, float]:
    counted = [o for o in outcomes if o.status != "stale"]
    killed = sum(o.status == "killed" for o in counted)
    rate = killed / len(counted) if counted else 0.0
    lines = [f"# Mutants: {killed} of {len(counted)} killed ({100 * rate:.0f} %)", "",
             table(["mutant", "kind", "status", "s", "tests' last line"],
                   [[o.ident, o.kind, o.status, round(o.seconds), o.detail[:90]]
                    for o in outcomes], align=False)]
    stale = [o.ident for o in outcomes if o.status == "stale"]
    if stale:
        lines += ["", f"stale (not applied, not counted): {', '.join(stale)}"]
    return "\n".join(lines), rate


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.mutants", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("runs/mutants"))
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "flatcli-mutants")
    parser.add_argument("--only", nargs="+", metavar="ID", help="run these mutants only")
    parser.add_argument("--list", action="store_true", help="list the mutants and stop")
    args = parser.parse_args(argv)
    chosen = [m for m in MUTANTS if not args.only or m.ident in args.only]
    if args.list:
        for m in chosen:
            print(f"{m.ident:30} {m.kind:45} {m.path}")
        return 0
    source = Path(__file__).resolve().parents[1]
    work = args.work.resolve()
    copy_tree(source, work)
    check_copy_is_imported(work)
    for tests in dict.fromkeys(m.tests for m in chosen):  # each set passes unmutated
        passed, seconds, last = run_tests(work, tests)
        print(f"baseline {seconds:6.1f} s  {' '.join(tests)}: {last}", flush=True)
        if not passed:
            raise SystemExit(f"the unmutated copy fails {' '.join(tests)}: {last}")
    outcomes = []
    for mutant in chosen:
        outcome = run_mutant(work, mutant)
        outcomes.append(outcome)
        print(f"{outcome.status:8} {outcome.seconds:6.1f} s  {mutant.ident}  ({mutant.kind})",
              flush=True)
    text, rate = report(outcomes)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "mutants.md").write_text(text + "\n")
    (args.out / "mutants.json").write_text(json.dumps(
        {"rate": rate, "mutants": [asdict(m) for m in chosen],
         "outcomes": [asdict(o) for o in outcomes]}, indent=2) + "\n")
    print(text)
    return 0 if rate >= TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
