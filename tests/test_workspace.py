"""Workspace maps (flatcli/core/plan/workspace.py, flatcli.workspace and flatcli workspace).

Referees, none of them the code under test: the full link kinematics written out below (each
body's centre of mass from its joint, the base placed so that the system's centre of mass is at
the origin); scipy's least_squares on it, started from several guesses, for targets the map
calls out of reach; the annulus of the virtual manipulator in closed form (its radii read off
the same link kinematics with the arm straight and folded back)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.optimize import least_squares

import flatcli
from flatcli.api import load_spec
from flatcli.core.errors import FlatcliError
from flatcli.core.plan.workspace import workspace_areas, workspace_map
from flatcli.core.robots.params import RobotParams
from flatcli.experiment import robot_from

PAPER = robot_from(load_spec())
START = np.array([1.8, 1.0, 0.0])  # the paper's maneuver starts here (Sec. VI)


def link_end(robot: RobotParams, theta: np.ndarray) -> np.ndarray:
    """(..., 2) the far end of the last link [m], from each body's geometry: joints
    O_k+1 = O_k + l_k e(psi_k), centres O_k + d_k e(psi_k), the base's end O_0 chosen so the
    masses' centre is at the origin."""
    psi = np.cumsum(theta, axis=-1)
    e = np.stack([np.cos(psi), np.sin(psi)], axis=-1)
    length = np.asarray(robot.length)[:, None]
    com = np.asarray(robot.com)[:, None]
    mass = np.asarray(robot.mass)
    joints = np.concatenate([np.zeros_like(e[..., :1, :]), np.cumsum(length * e, axis=-2)],
                            axis=-2)  # relative to O_0
    centres = joints[..., :-1, :] + com * e
    origin = -np.einsum("i,...ik->...k", mass, centres) / mass.sum()
    return np.asarray(origin + joints[..., -1, :])


def test_every_target_marked_reachable_is_reached_by_its_configuration() -> None:
    grid = np.linspace(-0.36, 0.36, 61)
    found = workspace_map(PAPER, START, (1.0, 1.4), grid, grid, 21)
    target = np.stack(np.meshgrid(grid, grid), axis=-1)
    for b in range(2):
        usable = found.usable[b]
        assert usable.sum() > 300  # a real part of the plane
        q = found.theta[b][usable]
        assert np.abs(link_end(PAPER, q) - target[usable]).max() < 1e-12
        assert np.isin(q[:, 0], found.attitudes).all()  # a sampled final base attitude
        assert ((q[:, 1] > 0) & (q[:, 1] < math.pi)).all()  # the start's side of sin th1 = 0
        assert (q[:, 2] > 0).all() if b == 0 else (q[:, 2] < 0).all()  # "up", "down"
        np.testing.assert_array_equal(found.margin[b][usable], np.abs(np.sin(q[:, 1])))
        assert np.isnan(found.margin[b][~usable]).all()


def test_targets_marked_out_of_reach_cannot_be_reached_at_any_sampled_attitude() -> None:
    grid = np.linspace(-0.36, 0.36, 25)
    found = workspace_map(PAPER, START, (1.0, 1.4), grid, grid, 5)
    rng = np.random.default_rng(3)
    for b, sign in enumerate((1.0, -1.0)):
        rows, cols = np.nonzero(~found.usable[b])
        picks = rng.choice(len(rows), size=25, replace=False)
        for i, j in zip(rows[picks], cols[picks], strict=True):
            r = np.array([grid[j], grid[i]])
            for th0 in found.attitudes:
                best = math.inf
                for g1 in (0.3, 1.5, 2.8):
                    for g2 in (0.5, 1.5, 2.8):
                        fit = least_squares(
                            lambda q, t0=th0, r=r: link_end(PAPER, np.array([t0, *q])) - r,
                            [g1, sign * g2],
                            bounds=([1e-9, 0.0 if sign > 0 else -math.pi],
                                    [math.pi - 1e-9, math.pi if sign > 0 else 0.0]))
                        best = min(best, float(np.linalg.norm(fit.fun)))
                assert best > 1e-6, (b, r, th0)


def test_a_free_attitude_reaches_the_whole_annulus_on_both_branches() -> None:
    outer = float(np.linalg.norm(link_end(PAPER, np.zeros(3))))  # the arm straight
    inner = float(np.linalg.norm(link_end(PAPER, np.array([0.0, 0.0, math.pi]))))
    grid = np.linspace(-0.35, 0.35, 281)
    found = workspace_map(PAPER, START, (START[0] - math.pi, START[0] + math.pi), grid, grid,
                          181)
    areas = workspace_areas(found, 0.1)
    annulus = math.pi * (outer**2 - inner**2)
    rim = 2 * math.pi * (outer + inner) * (grid[1] - grid[0])  # cells the edges cut
    assert abs(areas["reachable"] - annulus) < rim
    # with th0 free a branch's th1 can always be put on the start's side, but the attitudes
    # are samples: only cells at the rim may miss one branch
    assert areas["reachable"] - areas["both"] < rim / 10


def test_a_single_attitude_and_its_refusals() -> None:
    grid = np.linspace(-0.3, 0.3, 11)
    one = workspace_map(PAPER, START, (1.2, 1.2), grid, grid, 50)
    assert one.attitudes.tolist() == [1.2]
    for window, k, match in (((1.4, 1.0), 5, "--attitude"), ((0.0, 1.0), 0, "--attitudes"),
                             ((0.0, math.inf), 5, "--attitude")):
        with pytest.raises(FlatcliError, match=match):
            workspace_map(PAPER, START, window, grid, grid, k)
    chain = robot_from(load_spec(None, {"robot": "chain4"}))
    with pytest.raises(FlatcliError, match="this robot has N = 3 joints"):
        workspace_map(chain, np.zeros(5), (0.0, 1.0), grid, grid, 5)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "flatcli.cli", "workspace", *args],
                          capture_output=True, text=True)


def test_the_command_writes_its_table_record_and_figure_and_load_reads_them(
        tmp_path: Path) -> None:
    out = tmp_path / "w"
    done = _cli("--attitude", "1.0", "1.4", "--points", "41", "--attitudes", "9", "--out",
                str(out), "--tag", "map")
    assert done.returncode == 0, done.stderr
    assert "| reachable |" in done.stdout and f"wrote {out}/workspace.parquet" in done.stdout
    assert (out / "workspace.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = pq.read_table(out / "workspace.parquet")
    assert table.num_rows == 41 * 41
    assert table.schema.field("target_x").metadata[b"unit"] == b"m"
    assert table.schema.field("abs_sin_th1_up").metadata[b"unit"] == b"1"
    made = flatcli.workspace(attitude=(1.0, 1.4), points=41, attitudes=9)
    loaded = flatcli.load(out)
    assert isinstance(loaded, flatcli.WorkspaceResult) and loaded.tags == ["map"]
    np.testing.assert_array_equal(loaded.frame.to_numpy(dtype=float),
                                  made.frame.to_numpy(dtype=float))
    assert loaded.metrics["area_reachable"] == made.metrics["area_reachable"]
    assert loaded.plot() is not None  # drawn again from the table
    listed = flatcli.runs(tmp_path)
    assert listed["command"].tolist() == ["workspace"]
    assert listed["area_reachable"].tolist() == [made.metrics["area_reachable"]]
    record = json.loads((out / "run.json").read_text())
    record["metrics"]["start"] = "1.8"
    (out / "run.json").write_text(json.dumps(record))
    with pytest.raises(FlatcliError, match="not a workspace run's record"):
        flatcli.load(out)


def test_the_window_defaults_to_the_tasks_base_attitude_else_free() -> None:
    fixed = flatcli.workspace(overrides={"task.base_attitude": 1.3}, points=5, attitudes=7)
    assert fixed.metrics["attitude_low"] == fixed.metrics["attitude_high"] == 1.3
    free = flatcli.workspace(points=5, attitudes=7)
    assert free.metrics["attitude_low"] == pytest.approx(1.8 - math.pi)
    assert free.metrics["attitude_high"] == pytest.approx(1.8 + math.pi)


@pytest.mark.parametrize(("args", "names"), [
    (["--points", "1"], "--points"), (["--points", "5000"], "--points"),
    (["--attitude", "2", "1"], "--attitude"), (["--thin", "-1"], "--thin"),
    (["--extent", "0"], "--extent"), (["--robot", "chain4"], "this robot has N = 3 joints"),
    (["--points", "1001", "--attitudes", "20000"], "--points and --attitudes"),
    (["--attitude", "nan", "1"], "--attitude"),
])
def test_bad_options_are_one_line_and_write_nothing(tmp_path: Path, args: list[str],
                                                    names: str) -> None:
    done = _cli(*args, "--out", str(tmp_path / "w"))
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("error: ") and names in done.stderr
    assert not (tmp_path / "w" / "workspace.parquet").exists()


def test_a_workspace_map_leaves_the_names_latest_plan_or_track_run_alone(
        tmp_path: Path) -> None:
    """runs/<name>/latest is what flatcli.load("runs/<name>") and runs --compare read: the
    newest plan or track run. A workspace map after a plan goes to runs/<name>/workspace/
    with its own latest."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    plan = subprocess.run([sys.executable, "-m", "flatcli.cli", "plan"], cwd=tmp_path,
                          capture_output=True, text=True, env=env)
    assert plan.returncode == 0, plan.stderr
    planned = (tmp_path / "runs" / "paper_example" / "latest").resolve()
    done = subprocess.run([sys.executable, "-m", "flatcli.cli", "workspace", "--points", "11",
                           "--attitudes", "5"], cwd=tmp_path, capture_output=True, text=True,
                          env=env)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "runs" / "paper_example" / "latest").resolve() == planned
    mapped = (tmp_path / "runs" / "paper_example" / "workspace" / "latest").resolve()
    assert mapped.parent.name == "workspace" and (mapped / "workspace.parquet").is_file()
    assert isinstance(flatcli.load(tmp_path / "runs" / "paper_example"), flatcli.PlanResult)
    assert isinstance(flatcli.load(mapped), flatcli.WorkspaceResult)
