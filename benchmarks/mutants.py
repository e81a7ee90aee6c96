"""One-line mutants of flatcli's guarantees under misuse, and whether the tests catch each.

    python -m benchmarks.mutants [--group misuse|proofs|all] [--out runs/mutants] [--only ID ...]
                                 [--list] [--work DIR]

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


IV = "flatcli/core/plan/intervals.py"
CL = "flatcli/core/plan/clearance.py"
RD = "flatcli/rundirs.py"
CP = "flatcli/spec/compose.py"
IN = "flatcli/interrupts.py"
T_IV = ("tests/test_intervals.py",)
T_CL = ("tests/test_clearance.py", *(f"tests/test_tasks_core.py::{name}" for name in (
    "test_a_violation_planted_between_two_samples_is_caught",
    "test_a_proven_plan_clears_on_a_grid_100x_finer",
    "test_limits_between_samples_are_proven_or_refuted",
    "test_candidates_screened_together_have_each_plans_own_least_slack",
    "test_a_disc_beside_a_slanted_link_inside_its_box_is_proven_clear")))
T_RD = ("tests/test_rundirs.py", "tests/test_workspace.py::"
        "test_a_workspace_map_leaves_the_names_latest_plan_or_track_run_alone")
T_CP = ("tests/test_spec_compose.py",)
T_IN = ("tests/test_interrupts.py",)

#: Mutants of the proof that obstacles are clear (intervals, clearance) and of the run
#: directories, composed specs and interrupts (issue 42): one-line bugs a reviewer could miss,
#: each expected to make its module's tests fail.
PROOF_MUTANTS = (
    # interval arithmetic
    _m("iv-no-outward-rounding", "interval bound", IV,
       "return np.nextafter(lo, -np.inf), np.nextafter(hi, np.inf)", "return lo, hi", *T_IV),
    _m("iv-mul-two-corners", "interval bound", IV,
       "np.fmax(np.fmax(a, b), np.fmax(c, d))))", "np.fmax(a, d)))", *T_IV),
    _m("iv-mul-nan-wins", "NaN", IV, "np.fmin(np.fmin(a, b), np.fmin(c, d)),",
       "np.minimum(np.minimum(a, b), np.minimum(c, d)),", *T_IV),
    _m("iv-reciprocal-zero-inside", "interval bound", IV,
       "safe = (self.lo > 0) | (self.hi < 0)", "safe = (self.lo >= 0) | (self.hi <= 0)", *T_IV),
    _m("iv-reciprocal-swapped", "interval bound", IV,
       "lo = np.where(safe, 1.0 / np.where(safe, self.hi, 1.0), -np.inf)",
       "lo = np.where(safe, 1.0 / np.where(safe, self.lo, 1.0), -np.inf)", *T_IV),
    _m("iv-square-no-straddle", "interval bound", IV,
       "lo = np.where(straddles, 0.0, np.minimum(a, b) ** 2)", "lo = np.minimum(a, b) ** 2",
       *T_IV),
    _m("iv-mignitude-no-straddle", "interval bound", IV,
       "return np.asarray(np.where(straddles, 0.0, np.minimum(np.abs(self.lo),",
       "return np.asarray(np.where(False, 0.0, np.minimum(np.abs(self.lo),", *T_IV),
    _m("iv-magnitude-one-end", "interval bound", IV,
       "return np.asarray(np.maximum(np.abs(self.lo), np.abs(self.hi)), dtype=float)",
       "return np.asarray(np.abs(self.hi), dtype=float)", *T_IV),
    _m("iv-hull-narrow", "interval bound", IV,
       "return Interval(np.minimum(self.lo, other.lo), np.maximum(self.hi, other.hi))",
       "return Interval(np.maximum(self.lo, other.lo), np.maximum(self.hi, other.hi))", *T_IV),
    _m("iv-cos-max-always", "interval bound (loose)", IV,
       "k_max = np.ceil(lo / (2.0 * math.pi))", "k_max = np.floor(lo / (2.0 * math.pi))",
       *T_IV),
    _m("iv-cos-min-missed", "interval bound", IV,
       "has_min = wide | (math.pi + 2.0 * math.pi * k_min <= hi)", "has_min = wide", *T_IV),
    _m("iv-cos-wide-4pi", "interval bound", IV, "wide = (hi - lo) >= 2.0 * math.pi",
       "wide = (hi - lo) >= 4.0 * math.pi", *T_IV),
    _m("iv-sin-shift-sign", "interval bound", IV, "return cos(x - math.pi / 2.0)",
       "return cos(x + math.pi / 2.0)", *T_IV),
    _m("iv-poly-no-pad", "rounding", IV,
       "pad = 8.0 * terms * np.finfo(float).eps * scale", "pad = 0.0 * scale", *T_IV),
    _m("iv-poly-first-order-only", "interval bound", IV,
       "spread = np.sum(np.abs(taylor[..., 1:]) * radius[..., 1:], axis=-1)",
       "spread = np.abs(taylor[..., 1]) * radius[..., 1]", *T_IV),
    _m("iv-poly-binomial-diagonal", "interval bound", IV,
       "weight = np.array([[math.comb(a, b) if a >= b else 0 for b in range(terms)]",
       "weight = np.array([[math.comb(a, b) if a > b else 0 for b in range(terms)]", *T_IV),
    _m("iv-poly-half-radius", "interval bound", IV, "r = 0.5 * (s_hi - s_lo)",
       "r = 0.25 * (s_hi - s_lo)", *T_IV),
    # the proof
    _m("cl-segment-min-reach", "unsound segment bound", CL,
       "return np.asarray(gap - np.maximum(ra, rb) - pad, dtype=float)",
       "return np.asarray(gap - np.minimum(ra, rb) - pad, dtype=float)", *T_CL),
    _m("cl-segment-no-reach", "unsound segment bound", CL,
       "return np.asarray(gap - np.maximum(ra, rb) - pad, dtype=float)",
       "return np.asarray(gap - pad, dtype=float)", *T_CL),
    _m("cl-box-distance-l1", "unsound box bound", CL,
       "return np.asarray(np.nextafter(np.hypot(dx, dy), -np.inf), dtype=float)",
       "return np.asarray(dx + dy, dtype=float)", *T_CL),
    _m("cl-clearance-ignored", "task.clearance ignored", CL,
       "worst = np.minimum(worst, clear - constraints.clearance)",
       "worst = np.minimum(worst, clear)", *T_CL),
    _m("cl-radius-ignored", "radius ignored", CL,
       "_segment_distance_bound(near, far, centre)) - radius",
       "_segment_distance_bound(near, far, centre))", *T_CL),
    _m("cl-nan-proven", "NaN counted as proven", CL,
       "worst = np.where(np.isnan(worst) | broken, -np.inf, worst)",
       "worst = np.nan_to_num(worst, nan=1.0)", *T_CL),
    _m("cl-empty-proven", "empty interval proven", CL,
       "broken |= ~(x.lo <= x.hi)  # nan compares false",
       "broken |= np.isnan(x.lo) | np.isnan(x.hi)", *T_CL),
    _m("cl-last-piece-skipped", "off by one", CL,
       "starts += [(i, a, b) for a, b in itertools.pairwise(edges)]",
       "starts += [(i, a, b) for a, b in itertools.pairwise(edges[:-1])]", *T_CL),
    _m("cl-first-half-dropped", "bisection", CL,
       "s_lo, s_hi = (np.column_stack([s_lo, mid]).ravel(),",
       "s_lo, s_hi = (np.column_stack([mid, mid]).ravel(),", *T_CL),
    _m("cl-budget-off-by-one", "off by one", CL, "if examined > max_intervals:",
       "if examined >= max_intervals:", *T_CL),
    _m("cl-undecided-unreported", "undecided", CL, "        if narrow.any():",
       "        if False:", *T_CL),
    _m("cl-lower-bound-max", "reported bound", CL,
       "lower = min(lower, float(np.min(clear[~open_])))",
       "lower = max(lower if math.isfinite(lower) else 0.0, float(np.max(clear[~open_])))",
       *T_CL),
    _m("cl-angle-limit-ignored", "a key without effect", CL,
       "worst = np.minimum(worst, lim - th.magnitude())", "worst = worst", *T_CL),
    _m("cl-rate-limit-other-joint", "a key without effect", CL,
       "lim = float(constraints.rate_limit[j - 1])",
       "lim = float(constraints.rate_limit[-j])", *T_CL),
    _m("cl-min-margin-magnitude", "interval bound", CL,
       "worst = np.minimum(worst, margin.mignitude() - constraints.min_margin)",
       "worst = np.minimum(worst, margin.magnitude() - constraints.min_margin)", *T_CL),
    _m("cl-counterexample-ignored", "counterexample", CL, "        if np.any(exact < 0):",
       "        if False:", *T_CL),
    _m("cl-paper-th0-sign", "interval bound", CL, "th0 = y2 + k.c0 * th2 / A",
       "th0 = y2 - k.c0 * th2 / A", *T_CL),
    _m("cl-chain-thN-sign", "interval bound", CL, "num = -1.0 * h0 * (S_hat + R * h0)",
       "num = h0 * (S_hat + R * h0)", *T_CL),
    _m("cl-chain-grad-half", "interval bound", CL,
       "acc = acc + (-2.0 * float(K[a, b])) * sn", "acc = acc + (-1.0 * float(K[a, b])) * sn",
       *T_CL),
    _m("cl-chain-angle-short", "off by one", CL, "for k in range(b + 2, a + 1):",
       "for k in range(b + 2, a):", *T_CL),
    _m("cl-chain-rest-no-derivative", "interval bound", CL,
       "d = c[i, 1:] * np.arange(1, deg + 1)", "d = c[i, 1:]", *T_CL),
    _m("cl-paper-rest-no-derivative", "interval bound", CL,
       "d = c[1:] * np.arange(1, deg + 1)", "d = c[1:]", *T_CL),
    _m("cl-joint-box-moment-sign", "interval bound", CL, "ox = ox - float(moments[a]) * cx",
       "ox = ox + float(moments[a]) * cx", *T_CL),
    _m("cl-chain-margin-sign", "interval bound", CL,
       "margin = D * (-1.0 / (2.0 * float(K[1, 0])))",
       "margin = D * (1.0 / (2.0 * float(K[1, 0])))", *T_CL),
    _m("cl-screen-nan-clear", "NaN counted as clear at samples", CL,
       "return np.asarray(np.where(np.isnan(worst), -np.inf, worst), dtype=float)",
       "return np.asarray(worst, dtype=float)", *T_CL),
    # run directories
    _m("rd-other-command-accepted", "runs mixed", RD, "        if previous != command:",
       "        if False:", *T_RD),
    _m("rd-other-spec-accepted", "runs mixed", RD,
       "        if recorded_digest(record) != digest:", "        if False:", *T_RD),
    _m("rd-stamp-not-random", "runs mixed", RD,
       'return f"{now:%Y%m%d-%H%M%S}-{secrets.token_hex(3)}"',
       'return f"{now:%Y%m%d-%H%M%S}-000000"', *T_RD),
    _m("rd-fresh-reused", "runs mixed", RD, "path.mkdir(parents=True, exist_ok=False)",
       "path.mkdir(parents=True, exist_ok=True)", *T_RD),
    _m("rd-latest-absolute", "latest", RD,
       "tmp.symlink_to(directory.name, target_is_directory=True)",
       "tmp.symlink_to(directory.resolve(), target_is_directory=True)", *T_RD),
    _m("rd-workspace-takes-latest", "latest", RD,
       "home = root / name / COMMAND_DIRS[command] if command in COMMAND_DIRS else root / name",
       "home = root / name", *T_RD),
    _m("rd-sweep-mixed-with-run", "runs mixed", RD,
       'if kind(out / SWEEP_MANIFEST) != "missing":  # even with --force: never mix with a '
       "sweep", "if False:", *T_RD),
    _m("rd-unreadable-record-accepted", "runs trusts run.json", RD,
       'if kind(out / RECORD) != "missing" and record is None:', "if False:", *T_RD),
    _m("rd-legacy-sweep-moved", "resume", RD,
       'if kind(legacy / SWEEP_MANIFEST) != "missing":', "if False:", *T_RD),
    _m("rd-missing-count", "partial sweep", RD, "missing = self.total - self.done",
       "missing = self.total", *T_RD),
    _m("rd-json-not-object", "runs trusts run.json", RD,
       "return value if isinstance(value, dict) else None", "return value", *T_RD),
    _m("rd-tags-repeated", "tags", RD, "        if tag not in out:", "        if True:", *T_RD),
    _m("rd-tags-one-past", "tags", RD, "if len(out) > MAX_TAGS:",
       "if len(out) > MAX_TAGS + 1:", *T_RD),
    # composed specs
    _m("cp-cycle-undetected", "include cycle", CP, "        if real in chain:",
       "        if False:", *T_CP),
    _m("cp-files-one-past", "off by one", CP, "if len(self.files) >= MAX_FILES:",
       "if len(self.files) > MAX_FILES:", *T_CP),
    _m("cp-includes-reversed", "merge order", CP, "        for name in include:",
       "        for name in reversed(include):", *T_CP),
    _m("cp-cli-robot-loses", "merge order", CP,
       "selection = chosen if selection is None else selection", "selection = chosen", *T_CP),
    _m("cp-relative-to-cwd", "relative names", CP,
       "return path if path.is_absolute() or base is None else base / path", "return path",
       *T_CP),
    _m("cp-unset-ignored", "unset", CP,
       'remove_key(out, dotted, f"{source}: unset")', "pass", *T_CP),
    _m("cp-unset-unknown-accepted", "unset", CP, "if not known or not dotted:",
       "if not dotted:", *T_CP),
    _m("cp-unset-prefix", "unset", CP,
       'if k == dotted or k.startswith(f"{dotted}.")]', "if k.startswith(dotted)]", *T_CP),
    _m("cp-named-after-paper", "robot's name", CP,
       'if "name" in out or self.robot is None or self.robot.stem == "paper":',
       'if "name" in out or self.robot is None:', *T_CP),
    _m("cp-name-overridden", "robot's name", CP,
       'if "name" in out or self.robot is None or self.robot.stem == "paper":',
       'if self.robot is None or self.robot.stem == "paper":', *T_CP),
    _m("cp-nul-accepted", "misuse", CP, '    if "\\0" in name:', "    if False:", *T_CP),
    _m("cp-home-unchecked", "misuse", CP,
       "    except RuntimeError:  # Python's \"Could not determine home directory\"",
       "    except KeyError:", *T_CP),
    _m("cp-loop-unchecked", "misuse", CP,
       "except (OSError, RuntimeError, ValueError):  # a link loop (RuntimeError before 3.13)",
       "except (OSError, ValueError):", *T_CP),
    _m("cp-error-not-named", "misuse", CP,
       'raise SpecError(str(exc) if where == str(path) else f"{where}: {exc}") from None',
       "raise SpecError(str(exc)) from None", *T_CP),
    # interrupts
    _m("int-check-raises-twice", "interrupts", IN,
       'if _state["pending"] is not None and not _state["raised"]:',
       'if _state["pending"] is not None:', *T_IN),
    _m("int-handlers-not-restored", "interrupts", IN, "            signal.signal(s, handler)",
       "            signal.signal(s, signal.SIG_DFL)", *T_IN),
    _m("int-raises-in-locks", "interrupts", IN, '    if _state["immediate"]:',
       "    if True:", *T_IN),
    _m("int-second-signal-interrupts", "interrupts", IN, '    if _state["raised"]:\n',
       "    if False:\n", *T_IN),
    _m("int-pending-lost-at-end", "interrupts", IN, "        yield\n        check()\n",
       "        yield\n", *T_IN),
    _m("int-critical-immediate", "interrupts", IN, '    _state["immediate"] = False',
       '    _state["immediate"] = True', *T_IN),
    _m("int-no-check-on-entry", "interrupts", IN,
       '    check()\n    was = _state["immediate"]\n    _state["immediate"] = True',
       '    was = _state["immediate"]\n    _state["immediate"] = True', *T_IN),
    _m("int-signal-forgotten", "interrupts", IN,
       'return int(_state["signal"] or signal.SIGINT)', "return int(signal.SIGINT)", *T_IN),
    _m("int-outer-pending-lost", "interrupts", IN,
       '_state.update(pending=outer["pending"], immediate=outer["immediate"],',
       '_state.update(pending=None, immediate=outer["immediate"],', *T_IN),
)
#: The groups ``--group`` picks.
GROUPS = {"misuse": MUTANTS, "proofs": PROOF_MUTANTS, "all": MUTANTS + PROOF_MUTANTS}


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
    parser.add_argument("--group", choices=sorted(GROUPS), default="misuse",
                        help="misuse (the guarantees under misuse), proofs (intervals, "
                             "clearance, run directories, composed specs, interrupts) or all")
    args = parser.parse_args(argv)
    chosen = [m for m in GROUPS[args.group] if not args.only or m.ident in args.only]
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
