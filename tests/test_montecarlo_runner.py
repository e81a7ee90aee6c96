"""Running sweeps (flatcli/montecarlo/runner.py, end to end through the CLI): reproducible across
workers and chunkings, resumable after kill -9, failures kept, bad specs refused, one writer
per directory, no orphans, changed chunks recomputed, grid values added without recomputing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from small_sweep import SPEC, sweep, sweep_without_final_tables, write_spec

from flatcli.core import OWN_PROCESS_VARIABLE
from flatcli.montecarlo.layout import ID_STRIDE
from flatcli.storage import LOCK_NAME, read_provenance


def trials(directory: Path) -> pd.DataFrame:
    return pd.read_parquet(directory / "trials.parquet")


def test_results_identical_across_workers_and_chunk_sizes(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    runs = {
        "w1": ["--workers", "1"],
        "w2": ["--workers", "2", "--oversubscribe"],
        "w2c7": ["--workers", "2", "--oversubscribe", "--set", "sweep.chunk=7"],
        "w1c60": ["--workers", "1", "--set", "sweep.chunk=60"],
        # one chunk per cell, each computed in two pieces (the last chunks of a run: 2 workers)
        "w2c60": ["--workers", "2", "--oversubscribe", "--set", "sweep.chunk=60"],
    }
    frames = {}
    for name, extra in runs.items():
        code, out = sweep(str(spec), "--out", str(tmp_path / name), "-q", *extra)
        assert code == 0, out
        frames[name] = trials(tmp_path / name)
    reference = frames["w1"]
    assert len(reference) == 120
    assert (reference["trial"] % ID_STRIDE).tolist() == list(range(60)) * 2
    assert (reference.groupby("cell")["trial"].nunique() == 60).all()
    assert reference.groupby("cell")["trial"].apply(lambda t: (t // ID_STRIDE).nunique()).max() == 1
    assert (reference["status"] == "ok").mean() > 0.9
    for name, frame in frames.items():
        pd.testing.assert_frame_equal(frame, reference, check_exact=True, obj=name)
    # the same chunking gives the same file to the byte, whatever the workers: also where
    # each chunk was computed in pieces and joined (w2c60)
    for one, two in (("w1", "w2"), ("w1c60", "w2c60")):
        assert (tmp_path / one / "trials.parquet").read_bytes() == (
            tmp_path / two / "trials.parquet").read_bytes(), (one, two)
    assert not (tmp_path / "w1" / "trials").exists()  # each result once on disk


def test_a_killed_sweep_resumes_to_the_uninterrupted_result(tmp_path: Path) -> None:
    text = SPEC.replace("trials = 60", "trials = 1500").replace("chunk = 25", "chunk = 30")
    spec = write_spec(tmp_path, text)
    whole = tmp_path / "whole"
    assert sweep(str(spec), "--out", str(whole), "-q", "--workers", "2", "--oversubscribe")[0] == 0

    cut = tmp_path / "cut"
    command = [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out", str(cut),
               "-q", "--workers", "2", "--oversubscribe"]
    process = subprocess.Popen(command, start_new_session=True)
    deadline = time.monotonic() + 120
    chunks = cut / "trials"
    while time.monotonic() < deadline:
        if chunks.exists() and len(list(chunks.glob("chunk-*.parquet"))) >= 4:
            break
        if process.poll() is not None:
            pytest.fail("the sweep finished before it could be killed; make it longer")
        time.sleep(0.01)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    done_before = len(list(chunks.glob("chunk-*.parquet")))
    assert not (cut / "trials.parquet").exists(), "killed too late to test a resume"
    assert 0 < done_before < 100
    assert len(list(cut.glob(".trials.parquet.*.tmp"))) == 1  # trials.parquet, half written

    code, out = sweep(str(spec), "--out", str(cut), "--workers", "2", "--oversubscribe")
    assert code == 0, out
    assert f"resuming with {done_before * 30} done" in out
    pd.testing.assert_frame_equal(trials(cut), trials(whole), check_exact=True)
    assert not list(cut.glob(".*.tmp"))  # the killed run's temporary file is gone


def test_a_failing_trial_is_recorded_and_the_others_finish(tmp_path: Path) -> None:
    text = SPEC.replace(
        'mass = { dist = "uniform", low = -0.05, high = 0.05, relative = true }',
        'mass = { dist = "uniform", low = -1.6, high = 0.0, relative = true }',
    )
    spec = write_spec(tmp_path, text)
    code, out = sweep(str(spec), "--out", str(tmp_path / "d"), "-q")
    assert code == 0, out
    frame = trials(tmp_path / "d")
    failed = frame[frame["status"] == "error"]
    # mass * (1 + U(-1.6, 0)) <= 0 exactly when some link draws below -1: P = 1 - (0.6/1.6)^3
    assert 0 < len(failed) < len(frame)
    pattern = r"^plant\.mass\[\d\]: must be > 0 kg, got -?[\d.e-]+$"
    assert failed["reason"].str.contains(pattern).all()
    assert failed["err_y_rms"].isna().all()
    others = frame[frame["status"] != "error"]
    assert np.isfinite(others["err_y_rms"]).all()
    bad_mass = (frame[["mass_0", "mass_1", "mass_2"]] <= 0).any(axis=1)
    assert (bad_mass == (frame["status"] == "error")).all()


def test_fail_fast_stops_with_status_1_and_keeps_finished_chunks(tmp_path: Path) -> None:
    text = SPEC.replace(
        'mass = { dist = "uniform", low = -0.05, high = 0.05, relative = true }',
        'mass = { dist = "uniform", low = -1.6, high = 0.0, relative = true }',
    )
    spec = write_spec(tmp_path, text)
    code, out = sweep(str(spec), "--out", str(tmp_path / "d"), "-q", "--fail-fast",
                      "--workers", "1")
    assert code == 1
    assert "--fail-fast: trial" in out and "error: plant.mass[" in out
    assert not (tmp_path / "d" / "trials.parquet").exists()
    assert list((tmp_path / "d" / "trials").glob("chunk-*.parquet"))


def test_a_changed_spec_in_an_existing_directory_is_refused(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    out_dir = tmp_path / "d"
    assert sweep(str(spec), "--out", str(out_dir), "-q")[0] == 0
    before = (out_dir / "trials.parquet").read_bytes()
    code, out = sweep(str(spec), "--out", str(out_dir), "-q", "--set", "sweep.seed=12")
    assert code == 2
    assert out.startswith("error: ") and out.count("\n") == 1
    assert "holds a sweep of a different spec" in out and "--force" in out
    assert (out_dir / "trials.parquet").read_bytes() == before
    code, out = sweep(str(spec), "--out", str(out_dir), "-q", "--set", "sweep.seed=12",
                      "--force")
    assert code == 0, out
    assert (out_dir / "trials.parquet").read_bytes() != before


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("initial = {", "initiall = {"), "sweep.perturb.initiall: unknown perturbation"),
        (('initial = { dist = "normal"', 'initial = { dist = "gaussian"'),
         "sweep.perturb.initial.dist: expected one of"),
        (('"track.sensor_noise" = [0.0, 0.001]', '"track.sensor_noise" = []'),
         "expected a non-empty list"),
        (("trials = 60", "trials = -3"), "sweep.trials: must be >= 1, got -3"),
        (('"track.sensor_noise" = [0.0, 0.001]', '"track.sensor_nois" = [0.0]'),
         "not a spec key (did you mean 'track.sensor_noise'?)"),
        (('"track.sensor_noise" = [0.0, 0.001]', '"plan.start_rate" = [0.1, 0.0]'),
         "plan.start_rate: must be != 0"),
    ],
)
def test_bad_sweep_specs_exit_2_with_one_line_and_write_nothing(
    tmp_path: Path, edit: tuple[str, str], message: str
) -> None:
    assert edit[0] in SPEC
    spec = write_spec(tmp_path, SPEC.replace(*edit))
    code, out = sweep(str(spec), "--out", str(tmp_path / "d"), "-q")
    assert code == 2
    assert out.startswith("error: ") and out.count("\n") == 1, out
    assert message in out
    assert not (tmp_path / "d").exists()


def test_summary_matches_pandas_on_trials_parquet(tmp_path: Path) -> None:
    text = SPEC.replace('"track.sensor_noise" = [0.0, 0.001]',
                        '"track.sensor_noise" = [0.0, 0.001]\n"track.kp" = [[100, 110], [30, 30]]')
    spec = write_spec(tmp_path, text)
    assert sweep(str(spec), "--out", str(tmp_path / "d"), "-q")[0] == 0
    frame = trials(tmp_path / "d")
    summary = pd.read_parquet(tmp_path / "d" / "summary.parquet")
    assert len(summary) == 4
    # independent computation with pandas: the README's definitions
    for cell, group in frame.groupby("cell"):
        row = summary[summary["cell"] == cell].iloc[0]
        assert row["trials"] == len(group)
        for status in ("ok", "singular", "diverged", "error"):
            assert row[status] == (group["status"] == status).sum()
        done = group[group["status"].isin(["ok", "singular"])]
        # the errors over the verified resolved trials where the cell has any
        counted = done[done["verified"]] if done["verified"].any() else done
        assert row["statistics_of"] == ("verified" if done["verified"].any() else "unverified")
        for metric in ("err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final"):
            assert row[f"{metric}_median"] == pytest.approx(counted[metric].median(), rel=1e-12)
            assert row[f"{metric}_p95"] == pytest.approx(counted[metric].quantile(0.95),
                                                         rel=1e-12)
            assert row[f"{metric}_max"] == counted[metric].max()
        simulated = group[group["status"] != "error"]
        assert row["singular_fraction"] == pytest.approx((simulated["singular_hits"] > 0).mean())
        assert row["min_margin_median"] == pytest.approx(counted["min_margin"].median())
        assert row["momentum_drift_median"] == pytest.approx(counted["momentum_drift"].median())
        assert row["momentum_drift_max"] == counted["momentum_drift"].max()
        assert row["resolved"] == len(done)
        assert row["verified_trials"] + row["unverified_trials"] == len(done)
    assert summary["ok"].min() > 0  # every cell has statistics to check
    assert (tmp_path / "d" / "summary.md").read_text().count("| cell |") >= 4


def test_progress_lines_when_not_a_terminal(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    code, out = sweep(str(spec), "--out", str(tmp_path / "d"), "--workers", "1")
    assert code == 0
    assert "120/120 trials (100%)" in out and "trials/s" in out


def _children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(p) for p in path.read_text().split()] if path.exists() else []


def test_a_dead_worker_process_ends_the_sweep_cleanly_and_it_resumes(tmp_path: Path) -> None:
    text = SPEC.replace("trials = 60", "trials = 1500").replace("chunk = 25", "chunk = 30")
    spec = write_spec(tmp_path, text)
    out_dir = tmp_path / "d"
    command = [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out", str(out_dir),
               "-q", "--workers", "2", "--oversubscribe"]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        chunks = list((out_dir / "trials").glob("chunk-*.parquet")) if out_dir.exists() else []
        if len(chunks) >= 2 and _children(process.pid):
            break
        if process.poll() is not None:
            pytest.fail("the sweep finished before a worker could be killed; make it longer")
        time.sleep(0.01)
    os.kill(_children(process.pid)[0], signal.SIGKILL)  # as the out-of-memory killer would
    _, err = process.communicate(timeout=120)
    assert process.returncode == 1, err
    assert err.startswith("error: a worker process died") and err.count("\n") == 1, err
    assert "run the same command again to resume" in err
    assert not (out_dir / "trials.parquet").exists()
    code, out = sweep(str(spec), "--out", str(out_dir), "-q", "--workers", "2", "--oversubscribe")
    assert code == 0, out
    whole = tmp_path / "whole"
    assert sweep(str(spec), "--out", str(whole), "-q", "--workers", "1")[0] == 0
    pd.testing.assert_frame_equal(trials(out_dir), trials(whole), check_exact=True)


def _running_sweep(spec: Path, out: Path, *extra: str) -> subprocess.Popen[str]:
    """A long sweep in another process, once it has written a chunk."""
    command = [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out", str(out),
               "-q", *extra]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list((out / "trials").glob("chunk-*.parquet")) if out.exists() else True:
        if process.poll() is not None or time.monotonic() > deadline:
            pytest.fail("the sweep ended before it could be disturbed; make it longer")
        time.sleep(0.01)
    return process


def test_a_second_writer_is_refused_naming_the_first_ones_pid(tmp_path: Path) -> None:
    text = SPEC.replace("trials = 60", "trials = 1500").replace("chunk = 25", "chunk = 30")
    spec = write_spec(tmp_path, text)
    other = write_spec(tmp_path, text.replace("seed = 11", "seed = 12"), "other.toml")
    out_dir = tmp_path / "d"
    first = _running_sweep(spec, out_dir, "--workers", "1")
    try:
        for extra in ((), ("--force",)):
            code, out = sweep(str(other), "--out", str(out_dir), "-q", *extra)
            assert code == 2
            assert out == (f"error: {out_dir} is being written by another flatcli run (pid "
                           f"{first.pid}); wait for it to finish, or use another --out\n")
    finally:
        first.communicate(timeout=300)
    assert first.returncode == 0
    assert read_provenance(out_dir / "trials.parquet")["spec"]["sweep"]["seed"] == 11


def test_sigterm_is_ctrl_c_and_leaves_no_worker_behind(tmp_path: Path) -> None:
    text = SPEC.replace("trials = 60", "trials = 1500").replace("chunk = 25", "chunk = 30")
    spec = write_spec(tmp_path, text)
    out_dir = tmp_path / "d"
    process = _running_sweep(spec, out_dir, "--workers", "2", "--oversubscribe")
    workers = _children(process.pid)
    assert workers
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 128 + signal.SIGTERM
    assert err == (f"error: interrupted; finished chunks are kept in {out_dir}/trials; run the "
                   "same command again to resume\n")
    _gone(workers)


def _gone(pids: list[int], seconds: float = 30) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        alive = [p for p in pids if Path(f"/proc/{p}").exists()
                 and Path(f"/proc/{p}/stat").read_text().split()[2] != "Z"]
        if not alive:
            return
        time.sleep(0.1)
    pytest.fail(f"worker processes {alive} outlived their parent")


def test_workers_of_a_killed_sweep_do_not_outlive_it(tmp_path: Path) -> None:
    text = SPEC.replace("trials = 60", "trials = 1500").replace("chunk = 25", "chunk = 30")
    spec = write_spec(tmp_path, text)
    process = _running_sweep(spec, tmp_path / "d", "--workers", "2", "--oversubscribe")
    workers = _children(process.pid)
    assert workers
    os.kill(process.pid, signal.SIGKILL)  # only the main process: no process group kill
    process.communicate(timeout=60)
    _gone(workers)


def test_a_changed_chunk_is_computed_again_and_the_run_says_so(tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    out_dir = tmp_path / "d"
    assert sweep(str(spec), "--out", str(out_dir), "-q")[0] == 0
    whole = trials(out_dir)
    sweep_without_final_tables(str(spec), "--out", str(out_dir), "-q", "--force")
    chunk = sorted((out_dir / "trials").glob("chunk-*.parquet"))[2]
    table = pq.read_table(chunk)
    column = table.schema.get_field_index("err_y_rms")
    values = table.column(column).to_pylist()
    pq.write_table(table.set_column(column, "err_y_rms", pa.array([v * 2 for v in values])),
                   chunk)  # the metadata, checksum included, as it was
    code, out = sweep(str(spec), "--out", str(out_dir), "-q")
    assert code == 0, out
    assert out == (f"note: trials/{chunk.name}: its content does not match its checksum (the "
                   "file was changed); computing it again\n")
    pd.testing.assert_frame_equal(trials(out_dir), whole, check_exact=True)


def test_grid_values_added_or_removed_reuse_finished_cells_with_the_fresh_result(
        tmp_path: Path) -> None:
    three = SPEC.replace('"track.sensor_noise" = [0.0, 0.001]',
                         '"track.sensor_noise" = [0.0, 0.002, 0.001]')
    one = SPEC.replace('"track.sensor_noise" = [0.0, 0.001]', '"track.sensor_noise" = [0.001]')
    out_dir = tmp_path / "d"
    assert sweep(str(write_spec(tmp_path)), "--out", str(out_dir), "-q")[0] == 0
    assert not (out_dir / "trials").exists()  # the finished cells are in trials.parquet only
    code, out = sweep(str(write_spec(tmp_path, three, "three.toml")), "--out", str(out_dir))
    assert code == 0, out
    assert "sweep.grid.'track.sensor_noise'); 2 of the 3 cells were computed there before" in out
    assert "resuming with 120 done" in out and "(60 simulated now)" in out
    fresh = tmp_path / "fresh"
    assert sweep(str(tmp_path / "three.toml"), "--out", str(fresh), "-q")[0] == 0
    assert (out_dir / "trials.parquet").read_bytes() == (fresh / "trials.parquet").read_bytes()
    # and back to one value: nothing simulated, the same rows as a fresh run of it; the two
    # cells left out go back to chunk files (trials.parquet holds this grid's cells only)
    code, out = sweep(str(write_spec(tmp_path, one, "one.toml")), "--out", str(out_dir))
    assert code == 0 and "(0 simulated now)" in out, out
    alone = tmp_path / "alone"
    assert sweep(str(tmp_path / "one.toml"), "--out", str(alone), "-q")[0] == 0
    assert (out_dir / "trials.parquet").read_bytes() == (alone / "trials.parquet").read_bytes()
    assert len(list((out_dir / "trials").glob("chunk-*.parquet"))) == 6  # 2 cells x 3 chunks
    # and to all three again: nothing simulated, each result still once on disk
    code, out = sweep(str(tmp_path / "three.toml"), "--out", str(out_dir))
    assert code == 0 and "(0 simulated now)" in out, out
    assert (out_dir / "trials.parquet").read_bytes() == (fresh / "trials.parquet").read_bytes()
    assert not (out_dir / "trials").exists()


def test_force_twice_over_a_sweep_and_its_figures(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 10"))
    out_dir = tmp_path / "d"
    for _ in range(2):  # what make reproduce does: --force, then the figures
        code, out = sweep(str(spec), "--out", str(out_dir), "-q", "--force", "--plot")
        assert code == 0, out
    assert (out_dir / "sweep_errors.png").exists()


def test_a_list_valued_grid_key_out_of_alphabetical_order_is_extended_too(
        tmp_path: Path) -> None:
    """track.sensor_noise before plant.com (a list column, which Parquet reads back with
    other item names): the stored spec's grid keys are sorted, the file's are not; adding a
    value still reuses the finished cells and their chunks pass their checksums."""
    grid = ('"track.sensor_noise" = [0.0]\n'
            '"plant.com" = [[0.1, 0.1, 0.0], [0.1, 0.1, 0.001]]\n')
    base = SPEC.replace('"track.sensor_noise" = [0.0, 0.001]\n', grid)
    more = base.replace('[[0.1, 0.1, 0.0], [0.1, 0.1, 0.001]]',
                        '[[0.1, 0.1, 0.0], [0.1, 0.1, 0.001], [0.1, 0.1, 0.002]]')
    assert base != SPEC and more != base
    out_dir = tmp_path / "d"
    assert sweep(str(write_spec(tmp_path, base)), "--out", str(out_dir), "-q")[0] == 0
    code, out = sweep(str(write_spec(tmp_path, more, "more.toml")), "--out", str(out_dir))
    assert code == 0, out
    assert "2 of the 3 cells were computed there before" in out, out
    assert "(60 simulated now)" in out and "checksum" not in out, out


#: Libraries a sweep's processes never load unless a spec asks for them (normal draws load
#: scipy.special, an optimised plan scipy.optimize, a figure matplotlib).
UNASKED = ("pandas", "matplotlib", "scipy")

#: A sweep script: records, in the main process and in every worker after each chunk, which
#: of UNASKED's modules are loaded, and which of flatcli's optimiser's (a plan that is not
#: optimised needs none but the list of objectives' names, which the spec's schema offers;
#: workers fork from the main process).
_WATCHED_SWEEP = """
import json, os, sys
from pathlib import Path

import flatcli.montecarlo.runner as runner

out = Path(sys.argv[1])
def loaded():
    return sorted(m for m in sys.modules if m.split(".")[0] in {unasked!r}
                  or m.startswith("flatcli.core.optimize.")
                  and m != "flatcli.core.optimize.objectives")
real = runner.run_chunk
def watched(cell, chunk):
    result = real(cell, chunk)
    (out / f"modules-{{os.getpid()}}.json").write_text(json.dumps(loaded()))
    return result
runner.run_chunk = watched
from flatcli.cli import main
try:
    main(["sweep", sys.argv[2], "--out", str(out / "d"), "-q", "--workers", "2",
          "--oversubscribe"])
except SystemExit as exc:
    assert not exc.code, exc.code
(out / "modules-main.json").write_text(json.dumps(loaded()))
"""


def test_a_sweep_loads_neither_pandas_nor_matplotlib_nor_scipy_unless_asked(
        tmp_path: Path) -> None:
    """The light sweep path: the main process and its workers, through the command line, load
    no pandas, no matplotlib and none of scipy's modules but those numba itself loads when
    it loads a compiled function (its BLAS check): the referee is a process that only
    compiles and calls a function with numba. Not even scipy.linalg, which that check
    imports whole: its two extension modules are loaded alone (``_owned``, as in every
    process the ``flatcli`` program owns: ``FLATCLI_OWN_PROCESS=1``). Nor flatcli's own
    optimiser, whose package names its contents lazily."""
    text = SPEC.replace('initial = { dist = "normal", std = 0.02 }',
                        'initial = { dist = "uniform", low = -0.02, high = 0.02 }')
    assert text != SPEC
    spec = write_spec(tmp_path, text)
    subprocess.run([sys.executable, "-c", _WATCHED_SWEEP.format(unasked=UNASKED),
                    str(tmp_path), str(spec)], check=True, timeout=600,
                   env={**os.environ, OWN_PROCESS_VARIABLE: "1"})
    numba_alone = subprocess.run(
        [sys.executable, "-c", "import json, sys, numba\nnumba.njit(lambda x: x + 1)(1)\n"
         f"print(json.dumps([m for m in sys.modules if m.split('.')[0] in {UNASKED!r}]))"],
        capture_output=True, text=True, check=True).stdout
    allowed = set(json.loads(numba_alone))
    assert not {m for m in allowed if not m.startswith("scipy")}
    records = sorted(tmp_path.glob("modules-*.json"))
    assert len(records) >= 3  # the main process (its warm-up and its end) and a worker
    for record in records:
        loaded = set(json.loads(record.read_text()))
        assert loaded <= allowed, (record.name, sorted(loaded - allowed))
        assert "scipy.linalg" not in loaded, record.name  # numba's BLAS check, served alone
    assert trials(tmp_path / "d")["status"].isin(["ok", "singular"]).all()


def test_every_chunk_file_is_on_disk_before_the_final_tables(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunk files are flushed in groups by a thread of their own (storage.Syncer): every one
    is fsynced, and its directory after it, before the first final table is (the referee:
    the operating system's own fsync calls, recorded as they are made)."""
    flushed: list[str] = []
    real = os.fsync

    def recorded(fd: int) -> None:
        flushed.append(os.readlink(f"/proc/self/fd/{fd}"))
        real(fd)

    monkeypatch.setattr(os, "fsync", recorded)
    spec = write_spec(tmp_path)
    assert sweep(str(spec), "--out", str(tmp_path / "d"), "-q", "--workers", "1")[0] == 0
    trials_dir = str((tmp_path / "d").resolve() / "trials")
    chunks = sorted({p for p in flushed if Path(p).parent == Path(trials_dir)
                     and Path(p).name.startswith("chunk-")})
    assert len(chunks) == 6  # two cells of 60 trials, chunks of 25
    assert not os.path.exists(trials_dir)  # removed once trials.parquet holds them
    final = min(i for i, p in enumerate(flushed) if Path(p).name.startswith(".trials.parquet"))
    for chunk in chunks:
        assert chunk in flushed[:final], chunk
    last_chunk = max(flushed.index(c) for c in chunks)
    assert trials_dir in flushed[last_chunk:final]


@pytest.mark.parametrize("damage", ["empty", "cut"])
def test_a_chunk_a_machine_crash_left_unflushed_is_computed_again(tmp_path: Path,
                                                                  damage: str) -> None:
    """The window flushing in groups opens: a machine that crashes before a chunk file is
    flushed may leave it empty or cut short (the name renamed, its data not on disk); the
    resume computes it again and the result is the uninterrupted one."""
    spec = write_spec(tmp_path)
    whole = tmp_path / "whole"
    assert sweep(str(spec), "--out", str(whole), "-q")[0] == 0
    out_dir = tmp_path / "d"  # the crash came before the final tables
    sweep_without_final_tables(str(spec), "--out", str(out_dir), "-q")
    assert not (out_dir / "trials.parquet").exists()
    chunk = sorted((out_dir / "trials").glob("chunk-*.parquet"))[1]
    data = chunk.read_bytes()
    chunk.write_bytes(b"" if damage == "empty" else data[: len(data) // 2])
    code, out = sweep(str(spec), "--out", str(out_dir), "-q")
    assert code == 0, out
    assert f"trials/{chunk.name}: not a readable chunk file; computing it again" in out
    assert (out_dir / "trials.parquet").read_bytes() == (whole / "trials.parquet").read_bytes()


def test_a_box_sweep_is_identical_across_workers_and_chunk_sizes(tmp_path: Path) -> None:
    """sweep.perturb.end_effector plans a task per trial, in the workers: their plans (and
    so every column) are the same to the bit whichever worker and chunk ran the trial."""
    spec = tmp_path / "box.toml"
    spec.write_text(
        'name = "box"\n[plan]\nstart = [1.8, 1.0, 0.0]\nstart_rate = 0.2\ngoal_rate = 0.2\n'
        '[task]\nend_effector = [-0.25, 0.05]\nbase_attitude = 1.0\n'
        '[track]\ninitial = [1.8, 1.0, 0.0]\nkp = [100.0, 110.0]\nkv = [10.0, 13.0]\n'
        '[sweep]\ntrials = 24\nchunk = 12\nseed = 9\n'
        '[sweep.perturb.end_effector]\ndist = "uniform"\nlow = [-0.02, -0.02]\n'
        'high = [0.02, 0.02]\n')
    frames = {}
    for name, extra in {"w1": ["--workers", "1"],
                        "w2c5": ["--workers", "2", "--oversubscribe", "--set", "sweep.chunk=5"]
                        }.items():
        code, out = sweep(str(spec), "--out", str(tmp_path / name), "-q", *extra)
        assert code == 0, out
        frames[name] = trials(tmp_path / name)
    assert frames["w1"]["end_effector_0"].nunique() == 24
    assert (frames["w1"]["status"] == "ok").all()
    pd.testing.assert_frame_equal(frames["w2c5"], frames["w1"], check_exact=True)


def _same_files(directory: Path, reference: Path) -> None:
    for name in ("trials.parquet", "summary.parquet", "summary.md"):
        assert (directory / name).read_bytes() == (reference / name).read_bytes(), name
    assert not (directory / "trials").exists()  # each result once on disk
    # no temporary file left (the lock file of a killed run stays: docs/failures.md)
    assert not [p.name for p in directory.iterdir()
                if p.name.startswith(".") and p.name != LOCK_NAME]


def test_kill_9_at_random_moments_then_resume_gives_the_same_bytes(tmp_path: Path) -> None:
    """The attack: a sweep killed with SIGKILL (process group) at random moments, from its
    start-up to its final tables, then resumed; the referee is one uninterrupted run."""
    import random

    text = SPEC.replace("trials = 60", "trials = 600").replace("chunk = 25", "chunk = 30")
    spec = write_spec(tmp_path, text)
    whole = tmp_path / "whole"
    assert sweep(str(spec), "--out", str(whole), "-q", "--workers", "1")[0] == 0
    cut = tmp_path / "cut"
    command = [sys.executable, "-m", "flatcli.cli", "sweep", str(spec), "--out", str(cut),
               "-q", "--workers", "2", "--oversubscribe"]
    rng = random.Random(41)
    kills = 0
    for _ in range(10):
        process = subprocess.Popen(command, start_new_session=True, stderr=subprocess.DEVNULL)
        try:
            process.wait(timeout=rng.uniform(0.0, 3.0))
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
            kills += 1
            continue
        assert process.returncode == 0
    assert kills >= 3
    code, out = sweep(str(spec), "--out", str(cut), "-q", "--workers", "1")
    assert code == 0, out
    _same_files(cut, whole)


@pytest.mark.parametrize("where", ["before the summary", "while chunks are removed"])
def test_a_sweep_killed_after_trials_parquet_resumes_to_the_same_bytes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str) -> None:
    """The last moments: trials.parquet renamed into place with every chunk file still
    there (killed before the summary), or some chunk files removed and others not."""
    from flatcli.montecarlo import directory

    spec = write_spec(tmp_path)
    whole = tmp_path / "whole"
    assert sweep(str(spec), "--out", str(whole), "-q", "--workers", "1")[0] == 0
    real = directory.remove_merged_chunks

    def killed(*_: object, **__: object) -> object:
        raise KeyboardInterrupt

    def half(folder: Path, lay: object) -> int:
        for path in sorted((folder / "trials").glob("chunk-*.parquet"))[::2]:
            path.unlink()
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        if where == "before the summary":
            patch.setattr(directory, "summary_rows", killed)
        else:
            patch.setattr(directory, "remove_merged_chunks", half)
        code, _ = sweep(str(spec), "--out", str(tmp_path / "d"), "-q", "--workers", "1")
    assert code != 0  # (130, or 143 if this process met a SIGTERM before: interrupts.py)
    cut = tmp_path / "d"
    assert (cut / "trials.parquet").read_bytes() == (whole / "trials.parquet").read_bytes()
    assert list((cut / "trials").glob("chunk-*.parquet"))
    assert directory.remove_merged_chunks is real
    code, out = sweep(str(spec), "--out", str(cut), "-q", "--workers", "1")
    assert code == 0 and out == "", out
    _same_files(cut, whole)
