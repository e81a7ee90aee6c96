"""Design searches end to end (flatcli/designsearch/runner.py through the CLI): the same
search.parquet, bit for bit, with 1 and 2 workers, on Dask, after kill -9 and a resume, and
after a budget is raised; budgets; constraints; a search whose optimum is known in closed form;
the best candidate's study re-run as a plain sweep.

Referees: the files of another run (compared byte for byte, within one machine); the closed
form of a counterweight's balance, x* = -m d / m_c; the trials of ``flatcli sweep`` of the
written best_spec.toml, counted by the reached rule."""

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
import pytest
from small_search import SPEC, search, write_spec

from flatcli.designsearch.evaluate import trial_outcomes

#: A longer search to kill: 48 candidates of 60 trials.
LONG = SPEC.replace("trials = 24", "trials = 60").replace("candidates = 24", "candidates = 48")


def table(directory: Path) -> pd.DataFrame:
    return pd.read_parquet(directory / "search.parquet")


def record(directory: Path) -> dict[str, object]:
    return json.loads((directory / "search.json").read_text())


@pytest.fixture(scope="module")
def whole(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small search run once, on one worker."""
    base = tmp_path_factory.mktemp("whole")
    code, out = search(str(write_spec(base)), "--out", str(base / "w1"), "-q", "--workers", "1")
    assert code == 0, out
    assert out == ""  # -q: nothing but errors
    return base / "w1"


def test_a_search_writes_its_table_and_its_best_design(whole: Path) -> None:
    frame = table(whole)
    assert len(frame) == 24 and frame["candidate"].tolist() == list(range(24))
    assert frame["generation"].tolist() == [0] * 8 + [1] * 8 + [2] * 8
    assert (frame["status"] == "evaluated").all() and (frame["trials"] == 24).all()
    assert (frame[["reached", "collided", "missed", "lost"]].sum(axis=1) == 24).all()
    own = frame.iloc[0]  # the spec's own design, candidate 0
    assert (own["robot.mass[1]"], own["robot.length[1]"], own["counterweight.distance"]) == \
        (1.0, 0.2, 0.1)
    assert own["robot.mass"].tolist() == pytest.approx([1.0, 1.0, 1.0])
    best = frame.loc[frame["objective"].idxmin()]
    assert frame["best_objective"].iloc[-1] == best["objective"]
    rec = record(whole)
    assert rec["status"] == "finished" and rec["stop"] in ("candidates", "converged")
    assert rec["best"]["candidate"] == best["candidate"]  # type: ignore[index]
    robot = (whole / "best_robot.toml").read_text()
    assert "[robot]" in robot and "[plant]\ncom = [0.1, 0.1, 0.001]" in robot
    assert (whole / "best_robot.urdf").read_text().startswith("<?xml")
    assert (whole / "convergence.png").stat().st_size > 10_000


def test_identical_with_one_and_two_workers_and_on_dask(whole: Path, tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    code, out = search(str(spec), "--out", str(tmp_path / "w2"), "-q", "--workers", "2",
                       "--oversubscribe")
    assert code == 0, out
    code, out = search(str(spec), "--out", str(tmp_path / "dask"), "-q", "--executor", "dask",
                       "--scheduler", "local", "--workers", "2")
    assert code == 0, out
    for name in ("w2", "dask"):
        for file in ("search.parquet", "best_robot.toml", "best_spec.toml", "best_robot.urdf"):
            assert (tmp_path / name / file).read_bytes() == (whole / file).read_bytes(), \
                (name, file)


def test_a_killed_search_resumes_to_the_uninterrupted_result(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, LONG)
    code, out = search(str(spec), "--out", str(tmp_path / "whole"), "-q", "--workers", "2",
                       "--oversubscribe")
    assert code == 0, out
    cut = tmp_path / "cut"
    command = [sys.executable, "-m", "flatcli.cli", "search", str(spec), "--out", str(cut),
               "-q", "--workers", "2", "--oversubscribe"]
    process = subprocess.Popen(command, start_new_session=True)
    journal = cut / "journal.jsonl"
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:
        if journal.exists() and journal.read_text().count('"kind": "candidate"') >= 12:
            break
        if process.poll() is not None:
            pytest.fail("the search finished before it could be killed; make it longer")
        time.sleep(0.01)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    done = journal.read_text().count('"kind": "candidate"')
    assert 12 <= done < 48, "killed too late to test a resume"
    assert record(cut)["status"] == "running"
    code, out = search(str(spec), "--out", str(cut), "--workers", "2", "--oversubscribe")
    assert code == 0, out
    assert f"{done} candidates in the journal (resuming)" in out
    assert (cut / "search.parquet").read_bytes() == \
        (tmp_path / "whole" / "search.parquet").read_bytes()
    assert record(cut)["resumed_candidates"] >= done  # type: ignore[operator]


def test_a_larger_budget_continues_the_same_search(whole: Path, tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    out_dir = tmp_path / "grown"
    code, out = search(str(spec), "--out", str(out_dir), "-q", "--workers", "1",
                       "--set", "search.candidates=16")
    assert code == 0, out
    first = table(out_dir)
    assert len(first) == 16 and record(out_dir)["stop"] == "candidates"
    code, out = search(str(spec), "--out", str(out_dir), "-q", "--workers", "1")
    assert code == 0, out
    assert (out_dir / "search.parquet").read_bytes() == (whole / "search.parquet").read_bytes()
    pd.testing.assert_frame_equal(table(whole).iloc[:16], first, check_exact=True)
    assert record(out_dir)["resumed_candidates"] == 16


def test_a_time_budget_stops_at_a_generation_and_a_rerun_stops_there_too(
        whole: Path, tmp_path: Path) -> None:
    spec = write_spec(tmp_path)
    out_dir = tmp_path / "timed"
    code, out = search(str(spec), "--out", str(out_dir), "--workers", "1",
                       "--set", "search.seconds=1e-6")
    assert code == 0, out
    assert "stopped by search.seconds = 1e-06 s at a generation boundary (set " \
           "search.candidates = 16 to reproduce these rows anywhere)" in out
    rec = record(out_dir)
    assert rec["stop"] == "seconds" and rec["generations"] == 1
    pd.testing.assert_frame_equal(table(out_dir), table(whole).iloc[:16], check_exact=True)
    before = (out_dir / "search.parquet").read_bytes()
    code, out = search(str(spec), "--out", str(out_dir), "-q", "--workers", "1",
                       "--set", "search.seconds=1e-6")
    assert code == 0, out
    assert (out_dir / "search.parquet").read_bytes() == before
    assert record(out_dir)["simulated_trials"] == 0


def test_candidates_that_break_a_constraint_are_not_studied(tmp_path: Path) -> None:
    """search.max_mass = 3 kg: total mass 1 + m1 + 0.5 + 0.05 / distance kg (the designer's
    counterweight) must be <= 3; the spec's own design weighs 3 kg exactly."""
    spec = write_spec(tmp_path)
    code, out = search(str(spec), "--out", str(tmp_path / "c"), "-q", "--workers", "1",
                       "--set", "search.max_mass=3.0")
    assert code == 0, out
    frame = table(tmp_path / "c")
    mass = 1 + frame["robot.mass[1]"] + 0.5 + 0.05 / frame["counterweight.distance"]
    np.testing.assert_allclose(frame["total_mass"], mass, rtol=1e-12)
    heavy = frame["total_mass"] > 3.0
    assert heavy.any() and (~heavy).sum() > 8
    assert (frame.loc[heavy, "status"] == "infeasible").all()
    assert frame.loc[heavy, "trials"].isna().all()  # not simulated
    assert (frame.loc[heavy, "reason"].str.contains(r"> search\.max_mass 3 kg")).all()
    np.testing.assert_allclose(frame.loc[heavy, "mass_excess"],
                               frame.loc[heavy, "total_mass"] - 3.0, rtol=1e-12)
    assert (frame.loc[~heavy, "status"] == "evaluated").all()
    best = record(tmp_path / "c")["best"]
    assert frame.loc[best["candidate"], "total_mass"] <= 3.0  # type: ignore[index]
    assert record(tmp_path / "c")["simulated_trials"] == 24 * int((~heavy).sum())


#: A search whose optimum is known in closed form: the plant's link 2 is a bare link (0.5 kg,
#: centre 0.1 m along it, 0.0433 kg m^2) with 0.5 kg bolted at x along it; the controller
#: believes the paper's robot. The plan's momentum residual with the plant's parameters is 0
#: exactly when the plant is the paper's robot: the balance, x* = -m d / m_c = -0.1 m.
PLACEMENT = """
name = "placement"
[plant]
mass = [1.0, 1.0, 0.5]
inertia = [0.0533, 0.0533, 0.0433]
com = [0.1, 0.1, 0.1]
[track]
initial = [1.8, 1.0, 0.0]
initial_rate = 0.1
kp = [100, 110]
kv = [10, 13]
[sweep]
trials = 1
[search]
apply = "plant"
objective = "quantile"
metric = "plan_momentum_residual"
candidates = 150
population = 10
tol = 0
[search.vary]
"counterweight.x" = [-0.15, -0.05]
[search.counterweight]
mass = 0.5
x = -0.06
y = 0.0
"""


def test_a_counterweights_placement_is_found_where_its_link_balances(tmp_path: Path) -> None:
    spec = write_spec(tmp_path, PLACEMENT)
    code, out = search(str(spec), "--out", str(tmp_path / "p"), "-q", "--workers", "1")
    assert code == 0, out
    frame = table(tmp_path / "p")
    best = frame.loc[frame["objective"].idxmin()]
    balance = -0.5 * 0.1 / 0.5  # x* = -m d / m_c
    assert abs(best["counterweight.x"] - balance) < 1e-4  # within 0.1 mm
    assert abs(best["robot.com"][2]) < 0.5e-4  # the link's centre within 0.05 mm of its joint
    # the closed form is the optimum: nothing the search found is below its residual
    from flatcli.api import load_spec
    from flatcli.designsearch.design import Design
    from flatcli.designsearch.evaluate import judge, plan_energy
    from flatcli.montecarlo import layout, run_chunk

    design = Design.of(load_spec(spec))
    candidate = design.candidate(np.array([balance]))
    assert candidate.robot is not None and candidate.spec is not None
    assert candidate.robot.com[2] == pytest.approx(0.0, abs=1e-15)
    lay = layout(candidate.spec)
    cell = lay.cells[0]
    rows = run_chunk(cell, next(lay.chunks())).table
    at_balance = judge(design.spec, [rows], plan_energy(lay), 1.0)
    assert at_balance.objective < 1e-12 <= frame["objective"].min() + 1e-12


def test_the_best_candidate_reruns_as_a_plain_sweep(whole: Path, tmp_path: Path) -> None:
    """best_spec.toml with the search's sweep.seed: its trials are the search's (common
    random numbers), counted by the reached rule to the search's count."""
    from click.testing import CliRunner

    from flatcli.cli import main

    result = CliRunner().invoke(main, ["sweep", str(whole / "best_spec.toml"), "--out",
                                       str(tmp_path / "again"), "-q"])
    assert result.exit_code == 0, result.output
    import pyarrow.parquet as pq

    trials = pq.read_table(tmp_path / "again" / "trials.parquet")
    best = record(whole)["best"]
    assert int((trial_outcomes(trials) == "reached").sum()) == best["reached"]  # type: ignore[index]
    assert trials.num_rows == best["trials"]  # type: ignore[index]


def test_a_spec_without_a_search_and_a_dry_run(tmp_path: Path) -> None:
    plain = write_spec(tmp_path, SPEC.split("[search]")[0], "plain.toml")
    code, out = search(str(plain), "--out", str(tmp_path / "none"))
    assert code == 2
    assert out.startswith("error: search.vary: a search needs [search.vary]")
    assert out.count("\n") == 1 and not (tmp_path / "none").exists()
    code, out = search(str(write_spec(tmp_path)), "--dry-run", "--workers", "1",
                       "--out", str(tmp_path / "dry"))
    assert code == 0, out
    assert "design variables (3):" in out and "optimiser: scipy's differential_evolution" in out
    assert "at most 24 candidates" in out and "estimate on 1 local worker" in out
    assert out.rstrip().endswith("nothing written") and not (tmp_path / "dry").exists()


def test_a_search_of_another_robot_with_a_grid(tmp_path: Path) -> None:
    """chain4 (N = 3), a grid of two cells pooled per candidate, a quantile objective and a
    mass constraint that the spec's own design (4.5 kg) breaks."""
    text = """
name = "chain4_search"
robot = "chain4"
[sweep]
trials = 6
seed = 3
[sweep.perturb]
initial = { dist = "normal", std = 0.01 }
[sweep.grid]
"track.sensor_noise" = [0.0, 0.0005]
[search]
candidates = 20
population = 10
objective = "quantile"
max_mass = 4.3
[search.vary]
"robot.mass[1]" = { relative = 0.3 }
"robot.length[3]" = { relative = 0.2 }
"""
    code, out = search(str(write_spec(tmp_path, text)), "--out", str(tmp_path / "c4"), "-q",
                       "--workers", "1")
    assert code == 0, out
    frame = table(tmp_path / "c4")
    assert frame.loc[0, "status"] == "infeasible" and frame.loc[0, "total_mass"] == 4.5
    studied = frame[frame["status"] == "evaluated"]
    assert len(studied) and (studied["trials"] == 12).all()  # 2 cells x 6 trials
    assert (studied["total_mass"] <= 4.3).all()
    assert all(len(m) == 4 for m in frame["robot.mass"])
    np.testing.assert_array_equal(studied["objective"], studied["err_theta_final_q0.5"])
