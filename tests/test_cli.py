"""The command line end to end (click's CliRunner): outputs, summaries, and bad input."""

from __future__ import annotations

import errno
import io
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import click
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from flatcli.cli import main

#: y2'(0) and y2'(2) of the paper's example with the correct b1: README, *The physics, and the
#: paper's errata* (derived in tests/test_planning.py::test_boundary_values_of_y2_dot).
Y2_DOT_START = -0.066880
Y2_DOT_GOAL = -0.343458
PLAN_COLUMNS = ["t", "theta0", "theta1", "theta2", "theta0_dot", "theta1_dot", "theta2_dot",
                "u1_dot", "y1", "y2", "y1_dot", "y2_dot", "y1_ddot", "y2_ddot", "margin",
                "momentum"]
TRACK_COLUMNS = ["t", "theta0", "theta1", "theta2", "theta0_dot", "theta1_dot", "theta2_dot",
                 "theta0_ref", "theta1_ref", "theta2_ref", "u1", "u2", "y1", "y2", "y1_ref",
                 "y2_ref", "margin", "momentum", "tau1", "tau2"]
METRICS = ["err_theta_rms", "err_theta_max", "err_theta_final", "err_y_rms", "err_y_max",
           "err_y_final", "singular_hits", "first_hit_time", "min_margin", "momentum_drift",
           "plan_momentum_residual", "err_estimate", "peak_rate", "peak_torque",
           "torque_saturated", "steps", "rhs_evaluations", "crossings", "first_crossing_time",
           "clipped_time", "err_theta0_final", "err_theta1_final", "err_theta2_final",
           "status", "reason", "outcome", "outcome_reason", "event_time", "verified"]


def run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.output


def test_plan_writes_the_papers_plan(tmp_path: Path) -> None:
    code, out = run("plan", "--out", str(tmp_path / "p"), "--plot")
    assert code == 0, out
    frame = pd.read_parquet(tmp_path / "p" / "plan.parquet")
    assert set(PLAN_COLUMNS) <= set(frame.columns)
    assert len(frame) == 201
    assert frame["y2_dot"].iloc[0] == pytest.approx(Y2_DOT_START, abs=1e-6)
    assert frame["y2_dot"].iloc[-1] == pytest.approx(Y2_DOT_GOAL, abs=1e-6)
    assert frame["momentum"].abs().max() < 1e-12
    assert (tmp_path / "p" / "plan.png").stat().st_size > 10_000
    record = json.loads((tmp_path / "p" / "run.json").read_text())
    assert record["command"] == "plan"
    assert record["spec"]["plan"]["start"] == [1.8, 1.0, 0.0]
    assert {"flatcli", "numpy", "scipy"} <= set(record["versions"])
    assert "commit" in record["git"] and record["time"]
    assert "max abs(H) along the plan" in out and "wrote" in out


def test_plan_with_the_papers_coefficients(tmp_path: Path) -> None:
    code, out = run("plan", "--out", str(tmp_path / "p"), "--set", "robot.model=paper", "-q")
    assert code == 0 and out == ""
    frame = pd.read_parquet(tmp_path / "p" / "plan.parquet")
    # the paper's printed boundary values (Sec. VI) and its 1.39e-3 momentum residual (README,
    # *The physics, and the paper's errata*; tests/test_planning.py checks it on the core)
    assert round(frame["y2_dot"].iloc[0], 3) == -0.065
    assert round(frame["y2_dot"].iloc[-1], 4) == -0.3512
    assert frame["momentum"].abs().max() == pytest.approx(1.39e-3, rel=0.01)


def test_track_writes_trace_metrics_and_figure(tmp_path: Path) -> None:
    out_dir = tmp_path / "t"
    code, out = run("track", "--out", str(out_dir), "--plot")
    assert code == 0, out
    frame = pd.read_parquet(out_dir / "track.parquet")
    assert set(TRACK_COLUMNS) <= set(frame.columns)
    assert len(frame) == 2001
    metrics = json.loads((out_dir / "metrics.json").read_text())
    assert list(metrics) == sorted(METRICS)
    assert metrics["status"] == "ok"
    # with the gains as printed, y - y_ref at t = 2 is (-0.164, 0.105): README, *The physics,
    # and the paper's errata* (closed form: tests/test_control.py::test_closed_form_...)
    end = frame.iloc[-1]
    assert end["y1"] - end["y1_ref"] == pytest.approx(-0.164, abs=5e-4)
    assert end["y2"] - end["y2_ref"] == pytest.approx(0.105, abs=5e-4)
    assert metrics["err_y_final"] == pytest.approx(np.hypot(-0.1639, 0.1054), abs=1e-3)
    assert (out_dir / "track.png").exists()
    # the robot ends 0.19 rad off its goal: the headline says so before its status
    head = next(line for line in out.splitlines() if line.startswith("track '"))
    assert head.startswith("track 'paper_example': missed (at T ") and head.endswith("status ok")


def test_track_with_the_dynamic_plant(tmp_path: Path) -> None:
    """The paper's example on the robot with inertia (Fig. 4's start, gains as printed: the
    servo asks for ~580 N m in the first milliseconds): torques in the table and the metrics,
    clipped at the limit, momentum conserved by the integration."""
    out_dir = tmp_path / "d"
    code, out = run("track", "--set", "plant.model=dynamic", "--set",
                    "plant.torque_limit=500", "--out", str(out_dir))
    assert code == 0, out
    frame = pd.read_parquet(out_dir / "track.parquet")
    metrics = json.loads((out_dir / "metrics.json").read_text())
    assert metrics["status"] == "ok"
    assert metrics["peak_torque"] == 500.0 and metrics["torque_saturated"] > 0
    assert frame[["tau1", "tau2"]].abs().max().max() == 500.0
    assert metrics["momentum_drift"] < 1e-7  # observed 1.1e-8 (kinks where torque clips)
    assert "peak_torque" in out


def test_track_spec_file_and_sets_apply_in_order(tmp_path: Path) -> None:
    spec = tmp_path / "s.toml"
    spec.write_text('name = "mine"\n[track]\nkp = [1, 1]\n')
    code, out = run("track", str(spec), "--set", "track.kp=[100,110]",
                    "--set", "track.kv=[10,13]", "-q", "--out", str(tmp_path / "o"))
    assert code == 0, out
    record = json.loads((tmp_path / "o" / "run.json").read_text())
    assert record["spec"]["name"] == "mine"
    assert record["spec"]["track"]["kp"] == [100.0, 110.0]
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert metrics["err_y_final"] < 1e-4  # swapped gains: ~1e-5 (README, "The gains")


def test_every_run_without_out_gets_its_own_directory_and_latest_follows(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    code, out = run("plan", "--set", "name=demo")
    assert code == 0, out
    code, out = run("track", "--set", "name=demo")
    assert code == 0, out
    code, out = run("track", "--set", "name=demo", "--set", "track.kp=[100,110]")
    assert code == 0, out
    root = tmp_path / "runs" / "demo"
    dirs = sorted(p for p in root.iterdir() if not p.is_symlink())
    assert len(dirs) == 3
    assert [p.name for p in root.iterdir() if p.is_symlink()] == ["latest"]
    for d in dirs:
        assert re.fullmatch(r"\d{8}-\d{6}-[0-9a-f]{6}", d.name), d.name
    commands = {d.name: json.loads((d / "run.json").read_text())["command"] for d in dirs}
    assert sorted(commands.values()) == ["plan", "track", "track"]
    plan_dir = next(d for d in dirs if commands[d.name] == "plan")
    assert (plan_dir / "plan.parquet").exists() and not (plan_dir / "track.parquet").exists()
    latest = (root / "latest").resolve()
    assert json.loads((latest / "run.json").read_text())["spec"]["track"]["kp"] == [100, 110]
    assert f"wrote runs/demo/{latest.name}/track.parquet" in out  # printed on finish


def test_out_holding_a_different_run_is_refused_unless_force(tmp_path: Path) -> None:
    target = tmp_path / "o"
    assert run("plan", "--out", str(target), "-q")[0] == 0
    assert run("plan", "--out", str(target), "-q")[0] == 0  # the same run again: allowed
    before = (target / "plan.parquet").read_bytes()
    for args, what in ((["track"], "holds a plan run;"),
                       (["plan", "--set", "plan.duration=3"], "holds a plan run of a "
                                                               "different spec")):
        code, out = run(*args, "--out", str(target), "-q")
        assert code == 2 and out.startswith("error: --out") and out.count("\n") == 1, out
        assert what in out and "--force" in out
        assert (target / "plan.parquet").read_bytes() == before
        assert not (target / "track.parquet").exists()
    code, out = run("track", "--out", str(target), "-q", "--force")
    assert code == 0, out
    assert sorted(p.name for p in target.iterdir()) == ["metrics.json", "run.json",
                                                        "track.parquet"]


def verdict_block(out: str, what: str) -> list[str]:
    """The lines of ``flatcli design``'s verdict for ``what`` (robot or plant)."""
    return [line for line in out.splitlines() if line.lstrip().startswith(f"{what}: ")]


@pytest.mark.parametrize(
    ("sets", "verdict", "named"),
    [
        ([], "closed_form", "d2 = 0 and c0 a1 != 0"),
        # an imperfect counterweight: controllable, flat, but not with the paper's outputs
        (["robot.com=[0.1,0.1,0.002]"], "flat", "com[2] = d2 = 0.002 m"),
        # the audit's: l0 = d0 makes a1 = 0, but d2 != 0 keeps the robot controllable
        (["robot.com=[0.2,0.1,0.01]"], "flat", "l0 - d0 = 0 makes a1 = 2 M K_10 = 0"),
        # l0 = d0 and d2 = 0: every h_j constant
        (["robot.com=[0.2,0.1,0]"], "not_flat", "th2 [kg m^2 rad] is conserved"),
    ],
)
def test_design_gives_a_verdict_and_its_exit_status(sets: list[str], verdict: str,
                                                   named: str) -> None:
    """Exit 0 closed_form, 1 flat, 3 not_flat; one headline, one line per reason, the
    numbers; a flat design is never called not flat, nor an integrable one flat."""
    code, out = run("design", *(arg for s in sets for arg in ("--set", s)))
    assert code == {"closed_form": 0, "flat": 1, "not_flat": 3}[verdict], out
    assert "a1" in out and "c3" in out  # the coefficients, as before
    lines = verdict_block(out, "robot")
    assert lines[0].startswith(f"robot: {verdict}: ")
    assert all(line.startswith("  robot: ") for line in lines[1:])
    assert any(named in line for line in lines)
    assert "max |w ^ dw| / J^2 = " in out and "|K_10| / J = " in out
    if verdict == "not_flat":
        assert "hence flat" not in out and "reorients the base" in out
    else:
        assert "not flat" not in out and "not_flat" not in out


def test_design_exit_codes_cover_every_verdict() -> None:
    from flatcli.cli import DESIGN_EXIT
    from flatcli.core.robots.design import VERDICTS

    assert set(DESIGN_EXIT) == set(VERDICTS)
    assert sorted(DESIGN_EXIT.values()) == [0, 1, 3]  # 2 is bad input


def test_design_of_a_longer_chain_prints_its_barycentric_matrix() -> None:
    links = ["--set", "robot.mass=[2,1,1,0.6]", "--set", "robot.inertia=[0.08,0.03,0.03,0.2]",
             "--set", "robot.length=[0.3,0.25,0.25,0.25]", "--set", "plan.start=[0,1,0.3,0]",
             "--set", "plan.goal=[0.4,2,0.6,0]", "--set", "track.initial=[0,1,0.3,0]",
             "--set", "track.kp=[1,1,1]", "--set", "track.kv=[2,2,2]"]
    code, out = run("design", *links, "--set", "robot.com=[0.12,0.1,0.1,0]")
    assert code == 0 and "3 joints: barycentric matrix K" in out
    assert "robot: closed_form: " in out
    assert "the flat outputs y_j = th_j (j < 3), y3 = th0 + I3 th3 / h_0(q) apply" in out
    # K_10 = m0 (l0 - d0)(m1 d1 + (m2 + m3) l1) / M = 2 (0.18)(0.1 + 0.4) / 4.6, by hand
    assert f"K_10 = {2 * 0.18 * 0.5 / 4.6:.6g} kg m^2" in out
    code, out = run("design", *links, "--set", "robot.com=[0.12,0.1,0.1,0.01]")
    assert code == 1 and "robot: flat: " in out and "com[3] = d3 = 0.01 m" in out


def test_design_of_the_audits_chain4_is_not_flat_and_the_plant_gets_its_own_verdict() -> None:
    """chain4 with com = [0.3, -0.3, -0.1, 0]: every K_ab (a != b) vanishes, the constraint
    integrates (exit 3), and the conserved combination is printed; a plant that differs gets
    its own verdict, while the exit status stays the robot's."""
    spec = str(Path(__file__).parents[1] / "configs" / "chain4.toml")
    code, out = run("design", spec, "--set", "robot.com=[0.3,-0.3,-0.1,0]")
    assert code == 3 and "robot: not_flat: " in out
    # K diagonal, so h_j = sum_{b >= j} (I_b + K_bb): K_11 = 0.15, K_22 = 0.03, K_00 = K_33 = 0
    # (by hand: K_bb = sum_i m_i L_ib^2 - F_b^2 / M with F_b = 0), I = (0.1, 0.0533, 0.0533, 0.15)
    assert "0.5366 th0 + 0.4366 th1 + 0.2333 th2 + 0.15 th3" in out and "plant:" not in out
    code, out = run("design", spec, "--set", "plant.com=[0.1,0.1,0.1,0.01]")
    assert code == 0 and "robot: closed_form: " in out
    assert verdict_block(out, "plant")[0].startswith("plant: flat: ")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["plan", "--set", "plan.duraton=3"], "unknown key 'plan.duraton' (did you mean "
                                              "'plan.duration'?)"),
        (["plan", "--set", "track.kp=[1,2,3]"],
         "track.kp: expected 2 numbers (one per joint 1..N) for a robot of 2 joints"),
        (["track", "--set", "robot.mass=[1,-1,1]"], "robot.mass[1]: must be > 0 kg"),
        (["plan", "--set", "robot.com=[0.1,0.1,0.003]", "--set", "plan.method=\"flat\""],
         "the paper's flat outputs do not apply: com[2] = d2 = 0.003 m"),
        (["track", "--set", "robot.com=[0.1,0.1,0.003]"], "track.controller: \"flat\" tracks "
                                                          "the closed-form flat outputs"),
        (["plan", "--set", "plan.method=\"exactt\""], "plan.method: expected one of ['auto', "
                                                      "'flat', 'exact'], got 'exactt' (did you "
                                                      "mean 'exact'?)"),
        (["plan", "--set", "robot.com=[0.1,0.1,0.003]", "--set",
          "plan.optimize.rate_limit=3"], "plan.optimize.rate_limit: limits apply to flat plans "
                                         "only"),
        (["plan", "--set", "robot.com=[0.1,0.1,0.003]", "--set", "task.end_effector=[0.3,0.1]"],
         "plan.method: a [task] is planned through the closed-form flat outputs"),
        (["design", "--counterweight"], "--counterweight and --positions X1 Y1 X2 Y2 go "
                                        "together"),
        (["design", "--counterweight", "--positions", "0.1", "0", "0.2", "0", "--set",
          "robot.com=[0.1,0.1,0.05]"], "--positions: no allowed position lies on the ray"),
        (["plan", "--set", "plan.start_rate=0"], "plan.start_rate: must be != 0"),
        (["plan", "--set", "plan.start=[1.8,0,0]"], "plan.start[1] = 0 rad lies on the "
                                                    "singular set"),
        (["track", "--set", "track.dt=0.0007"], "track.dt: must divide plan.duration"),
        (["plan", "MISSING.toml"], "spec file not found: MISSING.toml"),
        (["track", "--set", "track.integrator=euler"], "track.integrator: expected one of"),
        (["track", "--set", "plant.model=dinamic"], "plant.model: expected one of "
                                                    "['kinematic', 'dynamic'], got 'dinamic' "
                                                    "(did you mean 'dynamic'?)"),
        (["track", "--set", "plant.servo_bandwidth=0"], "plant.servo_bandwidth: must be > 0 "
                                                        "rad/s, got 0"),
        (["track", "--set", "plant.torque_limit=-1"], "plant.torque_limit: must be >= 0 N m"),
        (["plan", "--bogus"], "No such option '--bogus'"),
        (["sweep"], "Missing argument 'SPEC'"),
        (["sweep", "MISSING.toml"], "spec file not found"),
        (["summarize", "nowhere"], "nowhere/summary.md not found"),
        (["design", "--set", "robot.inertia=[1e308,0.05,0.05]"], "robot.inertia[0]: must lie "
                                                                 "within +-1e+15"),
        (["plan", "--set", "plan.start_rate=1e308"], "plan.start_rate: must lie within"),
        (["plan", "--set", "plan.start_rate=1e14"], "plan: th1 may sweep up to 2e+14 rad"),
        (["track", "--set", "robot.mass=[1e-300,1e-300,1e-300]"], "robot.mass[0]: must be >="),
        (["plan", "--set", r'name="a\u0000b"'], "name: must not contain control characters"),
        (["plan", "--set", r'name="a\tb"'], "name: must not contain control characters"),
        (["plan", "--set", "plan.samples=3\nplan.duration=4"], "must be one line"),
        (["plan", "--set", "plan.samples=1000000000"], "plan.samples = 1000000000 would need"),
        (["track", "--set", "track.dt=1e-9"], "output steps would need"),
        (["plan", "/dev/zero"], "is not a regular file"),
        (["sweep", "MISSING.toml", "--rerun", str(10**23)],
         "'--rerun': expected a trial id (an integer from 0 to 2^63 - 1)"),
        (["rerun", "nowhere", "x1"], "expected a trial id"),
        (["plan", "--robot", "chian4"], "robot: unknown robot 'chian4'; shipped: chain4, "
                                        "chain6, paper"),
        (["plan", "--dpi", "5000"], "--dpi: must be at most 1200 dots/in, got 5000"),
        (["plan", "--format", "jpg"], "'--format': 'jpg' is not one of"),
        (["plan", "--tag", "a\x1bb"], "--tag: must not contain control"),
        (["plan", "--name", "../x"], "name: must not contain '/'"),
        (["summarize", "nowhere", "--x", "track.dt"], "--format, --dpi, --x, --hue: only "
                                                      "with --plot"),
        (["runs", "--filter", "status<ok"], "< compares numbers and times"),
        (["sweep", "flat.toml"], "sweep: 1000 identical trials (no [sweep.perturb] and no "
                                 "track.sensor_noise)"),
        (["sweep", "MISSING.toml", "--workers", "abc"], "'abc' is not a valid integer"),
        (["track", "--set", "robot.com=[0.1,0.1,0.003]", "--set", "track.controller=asbuilt",
          "--set", "track.lqr_bandwidth=1e12"], "track.lqr_bandwidth = 1e+12 rad/s"),
        (["plan", "--set", "task.end_effector=[-0.25,0.05]", "--set",
          "task.obstacles=[" + ",".join(f"[{2 + i / 100},0,0.001]" for i in range(1001)) + "]"],
         "task.obstacles: 1001 discs, more than the 1000"),
        (["sweep", "flat.toml", "--set", "sweep.grid={\"plan.goal_rate\" = ["
          + ",".join(str(0.5 + i / 1e4) for i in range(101)) + "], \"track.kp\" = ["
          + ",".join(f"[{100 + i}, 110]" for i in range(100)) + "]}"],
         "sweep.grid: 1.01e+04 cells (101 x 100), more than the 10000"),
        (["summarize", "nowhere", "--full", "--x", "track.dt"], "only with --plot"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: list[str], message: str
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "flat.toml").write_text('name = "flat"\n')  # no [sweep]: identical trials
    code, out = run(*args)
    assert code == 2, out
    assert out.startswith("error: ") and out.count("\n") == 1, out
    assert message in out
    assert "Traceback" not in out
    assert not (tmp_path / "runs").exists()


def test_unparsable_spec_file(tmp_path: Path) -> None:
    spec = tmp_path / "bad.toml"
    spec.write_text("[plan\n")
    code, out = run("plan", str(spec), "--out", str(tmp_path / "o"))
    assert code == 2 and "is not valid TOML" in out and out.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_version() -> None:
    code, out = run("--version")
    assert code == 0 and out.startswith("flatcli, version")


HEAVY = ("numpy", "numba", "scipy", "pandas", "pyarrow", "matplotlib")


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["sweep", "--help"]])
def test_help_version_and_completion_load_no_numerics(argv: list[str]) -> None:
    code = (
        "import sys\n"
        "from flatcli.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules), file=sys.stderr)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert done.stderr.strip().splitlines()[-1] == "[]"
    env = {**os.environ, "_FLATCLI_COMPLETE": "bash_complete", "COMP_WORDS": "flatcli sw",
           "COMP_CWORD": "1"}
    completion = subprocess.run(
        [sys.executable, "-c", code.replace(f"main({argv!r})", "main()")],
        capture_output=True, text=True, check=True, env=env)
    assert "plain,sweep" in completion.stdout
    assert completion.stderr.strip().splitlines()[-1] == "[]"


def test_summarize_plot_needs_a_finished_sweep(tmp_path: Path) -> None:
    (tmp_path / "summary.md").write_text("a summary\n")
    code, out = run("summarize", str(tmp_path), "--plot")
    assert code == 2 and out == f"error: --plot: {tmp_path}/summary.parquet not found: not a " \
                                "finished sweep directory\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.md"]


def test_the_output_directory_is_checked_before_any_work(tmp_path: Path) -> None:
    spec = tmp_path / "s.toml"
    spec.write_text("[sweep]\ntrials = 2\n")
    (tmp_path / "file").write_text("")
    code, out = run("sweep", str(spec), "--out", str(tmp_path / "file" / "d"), "-q")
    assert code == 2 and out.count("\n") == 1 and "file is not a directory" in out
    code, out = run("sweep", str(spec), "--out", str(tmp_path / ("n" * 300)), "-q")
    assert code == 2 and "more than the 255 the file system allows" in out
    code, out = run("plan", "--out", str(tmp_path / "file" / "d"), "-q")  # as for a sweep
    assert code == 2 and out.count("\n") == 1 and "file is not a directory" in out


@main.command("warn-demo", hidden=True)
def _warn_demo() -> None:
    """(tests only) a command whose numpy arithmetic overflows and divides by zero"""
    with np.errstate(all="warn"):
        np.log(np.zeros(1))
    np.float64(1e308) * 10
    click.echo("done")


def test_numpy_warnings_never_reach_a_successful_runs_stderr() -> None:
    result = CliRunner().invoke(main, ["warn-demo"])
    assert result.exit_code == 0
    assert result.output == "done\n"


def _cli(*args: str, **kwargs: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "flatcli.cli", *args], text=True,
                          capture_output=True, timeout=300, **kwargs)


def test_a_closed_stdout_is_one_line_and_exit_1(tmp_path: Path) -> None:
    command = [sys.executable, "-m", "flatcli.cli", "design"]
    reader, writer = os.pipe()
    os.close(reader)  # nobody reads: writing to stdout fails with EPIPE
    with open(os.devnull, "rb") as stdin:
        done = subprocess.run(command, stdout=writer, stderr=subprocess.PIPE, stdin=stdin,
                              text=True, timeout=300)
    os.close(writer)
    assert done.returncode == 1
    assert done.stderr == "error: standard output was closed (broken pipe)\n"
    with open("/dev/full", "w") as full:  # a full disk under stdout
        done = subprocess.run(command, stdout=full, stderr=subprocess.PIPE, text=True,
                              timeout=300)
    assert done.returncode == 1
    assert done.stderr == "error: standard output: No space left on device\n"  # names it


def test_sigterm_prints_the_line_ctrl_c_prints(tmp_path: Path) -> None:
    process = subprocess.Popen([sys.executable, "-c", (
        "import signal, sys, time, click\n"
        "from flatcli.cli import main\n"
        "@main.command('sleep')\n"
        "def sleep():\n"
        "    print('ready', flush=True); time.sleep(60)\n"
        "main()\n"), "sleep"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stdout is not None and process.stdout.readline() == "ready\n"
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert (process.returncode, err) == (128 + signal.SIGTERM, "error: interrupted\n")


# ---------------------------------------------------------------------------------------
# Misuse end to end (issue 23): one line, nothing outside touched, checks before the work.

TINY_SWEEP = """
name = "tiny"
[plan]
duration = 0.5
[track]
dt = 0.01
[sweep]
trials = 4
chunk = 2
[sweep.perturb]
initial = { dist = "normal", std = 0.01 }
"""


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A finished sweep (spec file, directory) the tests copy before misusing it."""
    root = tmp_path_factory.mktemp("tiny")
    spec = root / "tiny.toml"
    spec.write_text(TINY_SWEEP)
    code, out = run("sweep", str(spec), "--out", str(root / "d"), "-q", "--workers", "1")
    assert code == 0, out
    return spec, root / "d"


@pytest.mark.parametrize("where", ["files", "chunks"])
@pytest.mark.parametrize("name", ["../victim.txt", "../../victim.txt", "{victim}"])
def test_force_never_removes_a_file_outside_the_sweep_directory(
        tiny_sweep: tuple[Path, Path], tmp_path: Path, where: str, name: str) -> None:
    import shutil

    spec, finished = tiny_sweep
    directory = tmp_path / "a" / "d"
    shutil.copytree(finished, directory)
    victims = [tmp_path / "victim.txt", tmp_path / "a" / "victim.txt"]
    for victim in victims:
        victim.write_text("precious")
    manifest = json.loads((directory / "sweep.json").read_text())
    listed = name.format(victim=victims[0])
    if where == "files":
        manifest["files"].append(listed)
    else:
        manifest["cells"]["0"]["chunks"].append(listed)
    (directory / "sweep.json").write_text(json.dumps(manifest))
    before = sorted(str(p.relative_to(directory)) for p in directory.rglob("*"))
    code, out = run("sweep", str(spec), "--out", str(directory), "-q", "--force")
    assert code == 2 and out.count("\n") == 1 and "Traceback" not in out, out
    assert out.startswith(f"error: {directory}/sweep.json is not a flatcli sweep manifest")
    assert "nothing was removed" in out
    assert all(v.read_text() == "precious" for v in victims)
    assert sorted(str(p.relative_to(directory)) for p in directory.rglob("*")) == before


def test_exported_csv_files_do_not_block_force(tiny_sweep: tuple[Path, Path],
                                               tmp_path: Path) -> None:
    import shutil

    spec, finished = tiny_sweep
    directory = tmp_path / "d"
    shutil.copytree(finished, directory)
    assert run("export", str(directory), "--csv")[0] == 0
    assert run("sweep", str(spec), "--out", str(directory), "-q", "--rerun", "1")[0] == 0
    assert run("export", str(directory / "rerun-1"), "--csv")[0] == 0
    (directory / "notes.csv").write_text("mine")  # not flatcli's: still refused, by name
    code, out = run("sweep", str(spec), "--out", str(directory), "-q", "--force")
    assert code == 2 and "(notes.csv)" in out and "trials.csv" not in out, out
    (directory / "notes.csv").unlink()
    code, out = run("sweep", str(spec), "--out", str(directory), "-q", "--force")
    assert code == 0, out
    assert not (directory / "trials.csv").exists() and not (directory / "rerun-1").exists()


@pytest.mark.parametrize("command", ["plan", "track"])
def test_an_unwritable_out_is_refused_before_any_work(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, command: str) -> None:
    import flatcli.api
    import flatcli.experiment

    readable = tmp_path / "readable"  # as a directory of mode 0o555 is to a user
    readable.mkdir()
    access = os.access
    def denied(path: Any, mode: int, **kwargs: Any) -> bool:
        return False if Path(path) == readable and mode & os.W_OK else access(path, mode, **kwargs)

    monkeypatch.setattr(os, "access", denied)

    def computed(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("planned before the output was checked")

    monkeypatch.setattr(flatcli.experiment, "planned", computed)  # every plan's one way
    monkeypatch.setattr(flatcli.api, "run_track", computed)
    for out in (readable, readable / "run"):
        result = CliRunner().invoke(main, [command, "--out", str(out)])
        code, output = result.exit_code, result.output
        assert code == 2 and output.count("\n") == 1, (output, result.exception)
        assert f"--out {out}: cannot write in {readable}: no permission to write there" in output
    monkeypatch.chdir(readable)  # without --out: runs/ below an unwritable directory
    code, output = run(command)
    assert code == 2 and "the run directory runs/paper_example/" in output, output
    assert list(readable.iterdir()) == []


def _flatcli(*args: str, stdout: str, limit: int | None = None
             ) -> subprocess.CompletedProcess[str]:
    """flatcli in a subprocess whose standard output is closed (``>&-``) or a file, under an
    address-space limit [bytes] if given."""
    import resource

    def limited() -> None:
        if limit is not None:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    command = [sys.executable, "-m", "flatcli", *args]
    shell = ["sh", "-c", f'exec "$@" {stdout}', "sh", *command]
    return subprocess.run(shell, capture_output=False, stderr=subprocess.PIPE, text=True,
                          preexec_fn=limited, timeout=300)


def test_a_closed_stdout_is_one_line_and_exit_1_before_any_work(tmp_path: Path) -> None:
    done = _flatcli("plan", "--out", str(tmp_path / "p"), stdout=">&-")
    assert done.returncode == 1
    assert done.stderr == "error: standard output is closed: nothing could be printed " \
                          "(redirect it, e.g. > /dev/null)\n"
    assert not (tmp_path / "p").exists()  # refused before the work
    quiet = _flatcli("plan", "--out", str(tmp_path / "q"), "-q", stdout=">&-")
    assert quiet.returncode == 0 and quiet.stderr == "" and (tmp_path / "q").is_dir()


def _hold(directory: str, ready: Any, release: Any) -> None:
    from flatcli.storage import directory_lock

    with directory_lock(Path(directory)):
        ready.set()
        release.wait(60)


@pytest.mark.parametrize("command", ["plan", "track"])
def test_plan_and_track_refuse_a_directory_another_run_writes_before_any_work(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, command: str) -> None:
    import multiprocessing

    import flatcli.api
    import flatcli.experiment

    def computed(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("computed while another run writes there")

    monkeypatch.setattr(flatcli.experiment, "planned", computed)  # every plan's one way
    monkeypatch.setattr(flatcli.api, "run_track", computed)
    out = tmp_path / "o"
    context = multiprocessing.get_context("spawn")
    ready, release = context.Event(), context.Event()
    holder = context.Process(target=_hold, args=(str(out), ready, release))
    holder.start()
    try:
        assert ready.wait(60)
        result = CliRunner().invoke(main, [command, "--out", str(out), "-q"])
        assert result.exit_code == 2, (result.output, result.exception)
        assert result.output == (f"error: {out} is being written by another flatcli run (pid "
                                 f"{holder.pid}); wait for it to finish, or use another --out\n")
    finally:
        release.set()
        holder.join(60)
    assert not out.exists()  # the holder made it and left it empty: removed


@main.command("print-demo", hidden=True)
def _print_demo() -> None:
    """(tests only) a command that prints without flushing, as a library might"""
    print("left in the buffer")


class _FullStdout(io.StringIO):
    """A standard output whose disk is full: writes are buffered, the flush fails."""

    def flush(self) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")


def test_a_failing_last_flush_of_stdout_names_it(monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "stdout", _FullStdout())
    with pytest.raises(SystemExit) as stop:
        main(["print-demo"])
    assert stop.value.code == 1
    assert capsys.readouterr().err == "error: standard output: No space left on device\n"


# ---------------------------------------------------------------------------------------
# Issue 20: one --help, --cfg, figures' formats, names and tags, sweeps kept apart, rerun.

def test_help_is_one_convention_across_commands() -> None:
    from flatcli import cli

    visible = {n: c for n, c in main.commands.items() if not c.hidden}  # type: ignore[attr-defined]
    for name, command in visible.items():
        shared = [p.name for p in command.params if p.name in cli.OPTION_ORDER]
        assert shared == sorted(shared, key=cli.OPTION_ORDER.index), name
        quiet = [p for p in command.params if p.name == "quiet"]
        assert all(p.help == cli.QUIET_HELP for p in quiet), name
        code, out = run(name, "--help")
        assert code == 0 and "<=x<=" not in out and "9223372036854775807" not in out, name
    code, out = run("--help")
    commands = out.split("Commands:")[1]
    assert code == 0 and "..." not in commands  # no summary cut short
    assert all(f"  {name} " in commands for name in visible)


@pytest.mark.parametrize("command", ["plan", "track"])
def test_cfg_prints_the_resolved_spec_and_computes_nothing(
        command: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import tomllib

    from flatcli.spec import load_spec, resolve

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.toml").write_text('include = ["gains.toml"]\n[plan]\nduration = 3.0\n')
    (tmp_path / "gains.toml").write_text("[track]\nkp = [25.0, 25.0, 25.0]\n")
    code, out = run(command, "mine.toml", "--robot", "chain4", "--set", "track.dt=0.002",
                    "--cfg")
    assert code == 0, out
    assert list(tmp_path.iterdir()) == [tmp_path / "mine.toml", tmp_path / "gains.toml"] or \
        sorted(p.name for p in tmp_path.iterdir()) == ["gains.toml", "mine.toml"]
    printed = resolve(tomllib.loads(out))  # valid TOML, every key resolved
    expected = load_spec(tmp_path / "mine.toml", ["robot=chain4", "track.dt=0.002"])
    assert printed.digest() == expected.digest()
    assert printed.joints == 3 and printed.plan.duration == 3.0 and printed.track.dt == 0.002
    assert "[sweep]" not in out and "include" not in out


def test_a_plan_with_a_name_tags_and_a_pdf_figure(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    code, out = run("plan", "--name", "study1", "--tag", "draft", "--tag", "pdf", "--plot",
                    "--format", "pdf", "--dpi", "300")
    assert code == 0, out
    (directory,) = [p for p in (tmp_path / "runs" / "study1").iterdir() if p.name != "latest"]
    assert sorted(p.name for p in directory.iterdir()) == ["plan.parquet", "plan.pdf",
                                                           "run.json"]
    assert (directory / "plan.pdf").read_bytes()[:5] == b"%PDF-"
    record = json.loads((directory / "run.json").read_text())
    assert record["tags"] == ["draft", "pdf"] and record["spec"]["name"] == "study1"
    assert record["spec"]["figures"] == {"format": "pdf", "dpi": 300}
    assert "wrote " in out and "plan.pdf" in out
    # the same spec drawn as png is the same run: --out accepts it, --force replaces the pdf
    code, out = run("plan", "--name", "study1", "--plot", "--out", str(directory))
    assert code == 0 and (directory / "plan.png").exists(), out


def test_sweeps_and_plan_track_runs_are_kept_apart(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from small_sweep import SPEC, write_spec

    from flatcli import api

    monkeypatch.chdir(tmp_path)
    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 4"))
    code, out = run("track", str(spec), "-q")
    assert code == 0, out
    code, out = run("sweep", str(spec), "-q", "--workers", "1", "--tag", "nightly")
    assert code == 0, out
    assert (tmp_path / "runs" / "small" / "sweep" / "sweep.json").is_file()
    loaded = api.load("runs/small")  # the README's promise: its latest track run
    assert isinstance(loaded, api.TrackResult)
    sweep = api.load("runs/small/sweep")
    assert isinstance(sweep, api.SweepResult) and sweep.complete
    assert json.loads((tmp_path / "runs/small/sweep/run.json").read_text())["tags"] == [
        "nightly"]
    code, out = run("summarize", "runs/small")  # the name's sweep: its headline
    assert code == 0 and out.startswith("sweep 'small': 2 cells, ")
    assert "full tables: runs/small/sweep/summary.md (flatcli summarize " in out
    code, out = run("summarize", "runs/small", "--full")
    assert code == 0 and "### Trials by status" in out
    trial = int(pd.read_parquet(tmp_path / "runs/small/sweep/trials.parquet")["trial"][0])
    code, out = run("rerun", "runs/small", str(trial))  # no SPEC: the sweep's own
    assert code == 0, out
    assert "re-run alone:" in out and "NO" not in out
    assert (tmp_path / "runs/small/sweep" / f"rerun-{trial}" / "track.png").is_file()
    code, out = run("rerun", "runs/small", str(trial), "--print-spec")
    assert code == 0 and "[track]" in out and f"trial = {trial}" in out
    code, out = run("rerun", str(loaded.directory), "0")
    assert code == 2 and out.startswith("error: ") and "not a sweep" in out


def test_a_four_link_robot_plans_tracks_and_sweeps_with_only_robot_and_plan(
        tmp_path: Path) -> None:
    """Sized defaults end to end: no [track] table, so the plant starts on the plan (the
    plan itself is then the closed loop's exact solution: the error stays at the integrator's
    tolerance) with a double pole at -5 rad/s per output."""
    spec = tmp_path / "four.toml"
    spec.write_text(
        "[robot]\nmass = [2.0, 1.0, 1.0, 0.5]\ninertia = [0.1, 0.0533, 0.0533, 0.15]\n"
        "length = [0.3, 0.2, 0.2, 0.2]\ncom = [0.1, 0.1, 0.1, 0.0]\n"
        "[plan]\nstart = [0.0, 1.0, 0.3, 0.0]\ngoal = [-0.75, 2.0, 0.6, 0.0]\n"
        "start_rate = 0.3\n")
    for command in ("plan", "track"):
        code, out = run(command, str(spec), "--out", str(tmp_path / command))
        assert code == 0, out
    metrics = json.loads((tmp_path / "track" / "metrics.json").read_text())
    assert metrics["status"] == "ok" and metrics["err_theta_final"] < 1e-6
    spec.write_text(spec.read_text() + "[sweep]\ntrials = 3\n[sweep.perturb]\n"
                    "initial = { dist = \"normal\", std = 0.001 }\n")
    code, out = run("sweep", str(spec), "--out", str(tmp_path / "sweep"), "-q")
    assert code == 0, out
    trials = pd.read_parquet(tmp_path / "sweep" / "trials.parquet")
    assert len(trials) == 3 and set(trials["status"]) <= {"ok", "singular"}


@pytest.mark.parametrize("code", [None, 0, 3, 258, -1, True, "a message"])
def test_the_program_exits_with_the_status_the_interpreter_gives_systemexit(code: object,
                                                                              ) -> None:
    """``flatcli.cli.run`` ends the process itself (``os._exit``, no teardown): its exit status
    and stderr for ``SystemExit(code)`` are the interpreter's own (the referee: a plain
    ``python -c 'raise SystemExit(code)'``)."""
    python = subprocess.run([sys.executable, "-c", f"raise SystemExit({code!r})"],
                            capture_output=True, text=True, timeout=60)
    ours = subprocess.run([sys.executable, "-c", (
        "import flatcli.cli as c\n"
        "@c.main.command('end')\n"
        f"def end():\n    raise SystemExit({code!r})\n"
        "c.run()\n"), "end"], capture_output=True, text=True, timeout=300)
    assert (ours.returncode, ours.stderr) == (python.returncode, python.stderr)


def test_the_program_flushes_all_it_prints_and_waits_for_its_threads(tmp_path: Path) -> None:
    """What a command prints (buffered, to a file) and what a non-daemon thread it started
    writes after it returned are all there when ``run`` ends the process."""
    out = tmp_path / "out.txt"
    late = tmp_path / "late.txt"
    with out.open("w") as stdout:
        done = subprocess.run([sys.executable, "-c", (
            "import sys, threading, time, click\n"
            "import flatcli.cli as c\n"
            "@c.main.command('talk')\n"
            "def talk():\n"
            "    def later():\n"
            f"        time.sleep(0.5); open({str(late)!r}, 'w').write('late')\n"
            "    threading.Thread(target=later).start()\n"
            "    sys.stdout.write('x' * 100000)\n"
            "c.run()\n"), "talk"], stdout=stdout, stderr=subprocess.PIPE, text=True,
            timeout=300, env={**os.environ, "PYTHONUNBUFFERED": ""})
    assert done.returncode == 0 and done.stderr == ""
    assert out.read_text() == "x" * 100000
    assert late.read_text() == "late"


def test_the_program_under_a_profiler_ends_the_usual_way_so_the_profile_is_written(
        tmp_path: Path) -> None:
    """cProfile writes its file at the interpreter's teardown, which ``run`` otherwise skips."""
    profile = tmp_path / "version.prof"
    done = subprocess.run([sys.executable, "-m", "cProfile", "-o", str(profile), "-m", "flatcli",
                           "--version"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.startswith("flatcli, version")
    assert profile.stat().st_size > 0


@pytest.mark.parametrize(("text", "message"), [
    ('include = ["loop_a.toml"]', "include 'loop_a.toml': cannot read spec file"),
    ('robot = "loop_a.toml"', "robot 'loop_a.toml': cannot read spec file"),
    ('include = ["x\\u0000y.toml"]', "a file name must not contain a NUL byte"),
    ('robot = "~nosuchuser_flatcli/x.toml"', "robot: '~nosuchuser_flatcli/x.toml': no home"),
    ('robot = "../../x"', "robot '../../x': spec file not found"),
])
@pytest.mark.parametrize("command", ["plan", "track", "sweep", "design"])
def test_misused_robot_files_and_includes_are_one_line_exit_2(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, text: str, message: str,
        command: str) -> None:
    monkeypatch.chdir(tmp_path)
    Path("loop_a.toml").symlink_to("loop_b.toml")
    Path("loop_b.toml").symlink_to("loop_a.toml")
    Path("s.toml").write_text(text + "\n")
    code, out = run(command, "s.toml")
    assert code == 2 and out.startswith("error: ") and out.count("\n") == 1, out
    assert message in out and "Traceback" not in out
    assert not Path("runs").exists()


def test_summarize_checks_x_and_hue_before_it_prints_anything(tmp_path: Path) -> None:
    """A bad --x or --hue is the only line summarize prints (the summary is not printed
    first), exit 2, no figure written; with and without the sweep's manifest."""
    from small_sweep import SPEC, write_spec

    spec = write_spec(tmp_path, SPEC.replace("trials = 60", "trials = 4"))
    directory = tmp_path / "d"
    code, out = run("sweep", str(spec), "--out", str(directory), "-q")
    assert code == 0, out
    for args, message in ((["--x", "track.dt"], "--x: 'track.dt' is not a grid key"),
                          (["--hue", "track.sensor_noise", "--x", "track.sensor_noise"],
                           "is the --x key")):
        for manifest in (True, False):
            if not manifest:
                (directory / "sweep.json").rename(tmp_path / "sweep.json")
            code, out = run("summarize", str(directory), "--plot", *args)
            assert code == 2 and out.startswith("error: ") and out.count("\n") == 1, out
            assert message in out
            assert not list(directory.glob("sweep_*"))
            if not manifest:
                (tmp_path / "sweep.json").rename(directory / "sweep.json")
