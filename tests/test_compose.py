"""A sampled controller composed with an inner law and a plant (flatcli/core/loop/compose.py),
and the integrators' sample hooks (flatcli/core/loop/integrate.py): the MPC of
flatcli/core/controllers/mpc.py as ``track.controller = "mpc"``.

Referee: an independent closed loop in numpy and scipy. The flat outputs and the inputs that
make y'' = v come from the general N-link chain's maps (``ChainModel``, ``chainflat.inputs``)
for N = 2, not from the paper's closed form the kernels use; the base's rate from the link
kinematics' angular momentum (``params.momentum``), solved for th0'; the loop integrated by
DOP853 at rtol 1e-11 over each sample interval with the correction held, the correction
computed at each sample instant by the MPC's own step (its QP is refereed by
tests/test_mpc.py) from the errors measured there.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

import flatcli
from flatcli.core.controllers import mpc
from flatcli.core.controllers.control import Gains
from flatcli.core.errors import FlatcliError
from flatcli.core.loop.compose import sampled_ops
from flatcli.core.loop.metrics import Metric, Status
from flatcli.core.loop.simulate import Scenario, Trials, simulate
from flatcli.core.models.chainflat import inputs
from flatcli.core.models.flatmodel import ChainModel
from flatcli.core.robots.params import Links, momentum

Array = NDArray[np.float64]

#: The referee's and the compiled loop's tolerances, and how close their final angles must be
#: [rad] (they agreed to 7.7e-12 rad with and without the rate limit, 2026-12-05).
REFEREE_RTOL = 1e-11
KERNEL_RTOL = 1e-11
AGREE = 1e-9


@numba.njit(cache=False)
def _step(d, s, k):  # type: ignore[no-untyped-def]
    mpc.sample_step(d, s, k)


@pytest.fixture(scope="module")
def plan():  # type: ignore[no-untyped-def]
    return flatcli.plan().plan


def _initial(plan, errors: Array) -> Array:  # type: ignore[no-untyped-def]
    start = plan.sample(np.array([0.0]))
    return np.array([*start.theta[0], start.theta_dot[0][1]]) + np.r_[errors, 0.0]


def _sampled(plan, design, rhs, x: Array, ts: float, u_at: int,  # type: ignore[no-untyped-def]
             given: Array | None = None) -> tuple[Array, Array]:
    """The referees' loop in time: at each sample the flat outputs' errors (e_j, e_j') of the
    angles x[:N + 1] and the integrators x[u_at:u_at + N - 1] (y' from the commanded u, as the
    compiled loop measures) into the MPC's s0, its step (``_step``) on ``design``, then
    ``rhs(t, x, dv)`` by DOP853 at rtol ``REFEREE_RTOL`` over the sample with dv held (or
    ``given`` (K, N) held instead: a replay). Returns the final state and the corrections
    held (K, N)."""
    n = plan.n_joints
    model = ChainModel.of(plan.robot)
    scratch = mpc.scratch(design)
    mpc.reset(scratch)
    held = np.zeros((design.samples, n))
    for k in range(design.samples):
        t0 = k * ts
        y, y_dot, _ = model.outputs(x[None, : n + 1], x[None, u_at: u_at + n - 1])
        flag = plan.trajectory.flags(np.array([t0]))[0]
        scratch.s0[0: 2 * n: 2] = y[0] - flag[:n]
        scratch.s0[1: 2 * n: 2] = y_dot[0] - flag[n: 2 * n]
        _step(design, scratch, k)
        held[k] = scratch.held if given is None else given[k]
        sol = solve_ivp(rhs, (t0, t0 + ts), x, method="DOP853", rtol=REFEREE_RTOL,
                        atol=1e-13, args=(held[k].copy(),))
        assert sol.success
        x = sol.y[:, -1]
    return x, held


def _referee(plan, settings: mpc.MpcSettings, dt: float, limit: float, x0: Array,  # type: ignore[no-untyped-def]
             given: Array | None = None) -> tuple[Array, Array]:
    """The final angles (3,) and the corrections held (K, 2) of the referee loop (module
    docstring) on the kinematic plant of the nominal robot, H0 = 0; with ``given`` (K, 2)
    those corrections are held instead of the MPC's (a replay)."""
    model = ChainModel.of(plan.robot)
    links = Links(*(float(v) for v in plan.robot.links))
    design = mpc.flat_design(plan.model, plan.trajectory, plan.duration, dt, limit, settings)
    kp = np.full(2, mpc.INNER_KP)
    kv = np.full(2, mpc.INNER_KV)
    ts = design.every * dt

    def law(t: float, x: Array, dv: Array) -> tuple[float, float, float]:
        theta, u = x[:3], x[3:4]
        y, y_dot, _ = model.outputs(theta[None], u[None])
        flag = plan.trajectory.flags(np.array([t]))[0]
        v = flag[4:6] + dv + kv * (flag[2:4] - y_dot[0]) + kp * (flag[0:2] - y[0])
        u_dot = np.zeros(1)
        command = inputs(np.array(model.K), np.array(model.inertia), theta, u, v, u_dot)
        return float(u_dot[0]), float(x[3]), float(command)

    def rhs(t: float, x: Array, dv: Array) -> Array:
        u1_dot, u1, u2 = law(t, x, dv)
        w1 = min(max(u1, -limit), limit)
        w2 = min(max(u2, -limit), limit)
        if (u1 >= limit and u1_dot > 0) or (u1 <= -limit and u1_dot < 0):
            u1_dot = 0.0
        # H = H(0) + th0' (H(1) - H(0)) is linear in th0': H = 0
        h_zero = momentum(links, x[0], x[1], x[2], 0.0, w1, w2)
        h_one = momentum(links, x[0], x[1], x[2], 1.0, w1, w2)
        return np.array([-h_zero / (h_one - h_zero), w1, w2, u1_dot])

    x, held = _sampled(plan, design, rhs, x0.copy(), ts, 3, given)
    return x[:3], held


@pytest.mark.parametrize("limit", [math.inf, 40.0])
def test_the_compiled_mpc_loop_is_the_sampled_loop_integrated_by_scipy(plan, limit: float  # type: ignore[no-untyped-def]
                                                                        ) -> None:
    """Horizon 5 of 10 samples: the correction without (the first half) and with the goal
    in the horizon; 40 rad/s below the plan's 48.8 rad/s peak: the QP's rate rows bind."""
    settings = mpc.MpcSettings(sample=0.2, horizon=5)
    dt = 0.002
    x0 = _initial(plan, np.array([2e-3, -3e-3, 1e-3]))
    final, held = _referee(plan, settings, dt, limit, x0)
    assert np.abs(held).max() > 1e-3  # the correction acts (else this proves little)
    scenario = Scenario(plan, Gains((1.0, 1.0), (2.0, 2.0)), dt=dt, rate_limit=limit,
                        controller="mpc", settings={"mpc": settings}, rtol=KERNEL_RTOL,
                        atol=1e-13, twin=0.0)
    trials = Trials(plan.robot.as_array()[None], np.zeros(1), x0[None])
    out = simulate(scenario, trials, "adaptive", record=True)
    assert out.status[0] == Status.OK
    assert out.trace is not None
    np.testing.assert_allclose(out.trace[0, -1, :3], final, atol=AGREE, rtol=0)
    assert out.extra_columns == mpc.COLUMNS
    assert out.extra is not None and out.extra[0, 0] > 0  # QP iterations were counted
    assert out.extra[0, 1] == 0  # no sample needed the slack
    # the limits are kept at the samples only (mpc's docstring); on this maneuver at every
    # output sample too: no joint ever turned at the limit (39.58 rad/s, 2026-12-05)
    assert out.metrics[0, Metric.PEAK_RATE] < limit


def test_the_trace_holds_the_corrections_the_loop_applied(plan) -> None:  # type: ignore[no-untyped-def]
    """Replayed: the corrections dv1, dv2 of the compiled trial's trace at its sample
    instants, held over each sample by the referee loop (no MPC in it), end where the
    compiled trial ends."""
    settings = mpc.MpcSettings(sample=0.2, horizon=5)
    dt, limit = 0.002, 40.0
    x0 = _initial(plan, np.array([-2e-3, 1e-3, 3e-3]))
    scenario = Scenario(plan, Gains((1.0, 1.0), (2.0, 2.0)), dt=dt, rate_limit=limit,
                        controller="mpc", settings={"mpc": settings}, rtol=KERNEL_RTOL,
                        atol=1e-13, twin=0.0)
    out = simulate(scenario, Trials(plan.robot.as_array()[None], np.zeros(1), x0[None]),
                   "adaptive", record=True)
    assert out.trace is not None
    every = settings.every(dt, plan.duration)
    columns = [out.columns.index("dv1"), out.columns.index("dv2")]
    held = out.trace[0, :-1:every][:, columns]  # the rows at t_k = k sample
    assert np.abs(held).max() > 1e-3
    final, _ = _referee(plan, settings, dt, limit, x0, given=held)
    np.testing.assert_allclose(out.trace[0, -1, :3], final, atol=AGREE, rtol=0)


def test_rk4_samples_where_the_adaptive_integrator_stops(plan) -> None:  # type: ignore[no-untyped-def]
    """Both integrators sample at the same instants: at dt = 1 ms their final angles agree
    to RK4's error (the held corrections would differ by a sample's jump otherwise)."""
    settings = mpc.MpcSettings(sample=0.1, horizon=8)
    x0 = _initial(plan, np.array([1e-3, 2e-3, -1e-3]))
    scenario = Scenario(plan, Gains((1.0, 1.0), (2.0, 2.0)), dt=0.001, controller="mpc",
                        settings={"mpc": settings}, rtol=1e-11, atol=1e-13, twin=0.0)
    trials = Trials(plan.robot.as_array()[None], np.zeros(1), x0[None])
    adaptive = simulate(scenario, trials, "adaptive")
    rk4 = simulate(scenario, trials, "rk4")
    assert rk4.metrics[0, Metric.ERR_THETA_FINAL] == pytest.approx(
        adaptive.metrics[0, Metric.ERR_THETA_FINAL], abs=1e-8)
    assert adaptive.metrics[0, Metric.ERR_THETA_FINAL] < 1e-6  # the terminal condition


def test_a_sample_time_that_does_not_fit_names_the_key(plan) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(FlatcliError, match=r"track\.mpc_sample"):
        Scenario(plan, Gains((1.0, 1.0), (2.0, 2.0)), dt=0.001, controller="mpc",
                 settings={"mpc": mpc.MpcSettings(sample=0.3)})


@pytest.mark.parametrize("noise", [False, True])
def test_the_reference_integrator_runs_the_sampled_loop(plan, noise: bool) -> None:  # type: ignore[no-untyped-def]
    """DOP853 (``reference``) stops at the samples and samples there as the compiled
    integrators do: the same trial agrees with the adaptive one at rtol 1e-11 to 1e-9 rad at
    every output sample, and the controller's columns are written, with and without sensor
    noise (held per output interval)."""
    settings = mpc.MpcSettings(sample=0.1, horizon=6)
    x0 = _initial(plan, np.array([1e-3, -2e-3, 2e-3]))
    scenario = Scenario(plan, Gains((1.0, 1.0), (2.0, 2.0)), dt=0.01, rate_limit=40.0,
                        controller="mpc", settings={"mpc": settings}, rtol=1e-11,
                        atol=1e-13, twin=0.0)
    table = np.random.default_rng(4).normal(0.0, 1e-5, (1, scenario.n_steps, 3)) if noise \
        else None
    trials = Trials(plan.robot.as_array()[None], np.zeros(1), x0[None], table)
    ours = simulate(scenario, trials, "adaptive", record=True)
    reference = simulate(scenario, trials, "dop853", record=True)
    assert ours.trace is not None and reference.trace is not None
    assert reference.status[0] == Status.OK
    gap = np.abs(ours.trace[0, :, :3] - reference.trace[0, :, :3]).max()
    assert gap < 1e-9
    assert reference.extra is not None and ours.extra is not None
    assert reference.extra[0, 1] == ours.extra[0, 1] == 0  # infeasible samples
    assert reference.extra[0, 0] > 0


def test_every_generated_kernel_has_closure_names_of_its_own() -> None:
    """numba links a name two loaded kernels share to one definition (tests/test_kernels.py):
    each composed combination's closures carry their own tag, the same in every process."""
    from flatcli.core.loop import table
    from flatcli.core.loop.integrate import make_trial_integrators
    from flatcli.core.loop.kernels import make_batch, make_single

    seen: dict[str, tuple[str, str, str]] = {}
    for key, kernels in table.KERNELS.items():
        ops = kernels.ops
        functions = [make_batch(ops), *make_single(ops),
                     *make_trial_integrators(ops.rhs, ops.observe, ops.record, ops.stage,
                                             ops.reset, ops.period, ops.sample)]
        for name in (f.__qualname__ for f in functions):
            assert name not in seen, (key, seen.get(name), name)
            seen[name] = key
    assert {key[0] for key in table.KERNELS} == {"flat", "asbuilt", "command", "mpc", "python"}
    # and each kernel a name of its own: numba caches, and a compile child finds, one by its
    # name (two kernels of one name had the child compile the other and this process its own
    # without the inliner setting: the paper's loop ran at 0.92x)
    names = [f.__qualname__ for k in table.KERNELS.values() for f in (k.batch, *k.single)]
    assert len(names) == len(set(names))
    for sampled in ("mpc", "python"):  # around each of the 6 base combinations
        assert len([key for key in table.KERNELS if key[0] == sampled]) == 6


def test_the_spec_reaches_the_kernel_through_the_generated_keys() -> None:
    """track.controller = "mpc" and track.mpc_* from the API to the kernel: the MPC's
    terminal condition brings the paper's maneuver from Fig. 4's start (errors of 0.16 rad)
    to its goal, where the paper's law (printed gains) ends 0.29 rad off."""
    flat = flatcli.track(quiet=True)
    run = flatcli.track(overrides={"track.controller": "mpc", "track.mpc_sample": 0.05,
                                   "track.mpc_horizon": 10}, quiet=True)
    assert run.run.scenario.settings_for("mpc") == mpc.MpcSettings(sample=0.05, horizon=10)
    assert run.metrics["status"] == "ok"
    assert run.metrics["err_theta_final"] < 1e-6 < flat.metrics["err_theta_final"]


def test_a_bad_mpc_key_is_one_line_and_exit_status_2(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from click.testing import CliRunner

    from flatcli.cli import main

    for bad, named in (("track.mpc_horizon=1", "track.mpc_horizon"),
                       ("track.mpc_sample=0.3", "track.mpc_sample")):
        result = CliRunner().invoke(main, ["track", "--set", "track.controller=\"mpc\"",
                                           "--set", bad, "--out", str(tmp_path / "run")])
        assert result.exit_code == 2, result.output
        assert named in result.output and "Traceback" not in result.output
        assert not (tmp_path / "run").exists()  # no half-written output


class PythonMpc:
    """The MPC's sample step run by the Python interpreter (its compiled functions are plain
    Python functions too): a controller written in Python, as a researcher would pass one."""

    def __init__(self, design: mpc.Design, sample: float) -> None:
        self.design = design
        self.sample = sample
        self.scratch = mpc.scratch(design)

    def reset(self) -> None:
        mpc.reset(self.scratch)

    def step(self, k: int, t: float, errors: Array) -> Array:
        self.scratch.s0[:] = errors
        mpc.sample_step(self.design, self.scratch, k)
        return self.scratch.held.copy()


def test_a_controller_written_in_python_runs_in_the_same_loop(plan) -> None:  # type: ignore[no-untyped-def]
    """flatcli.track(..., controller=obj): the MPC's step as Python around the flat law with
    the MPC's inner gains equals the compiled MPC run by the same DOP853 loop, and the
    compiled MPC's adaptive trial to 1e-9 rad."""
    settings = mpc.MpcSettings(sample=0.2, horizon=4)
    # a limit the cubic (48.8 rad/s) keeps with the MPC's backoff: the MPC tracks the flat
    # law's plan (one beyond the limit kept would be re-planned for the MPC alone)
    common = {"track.dt": 0.01, "track.rate_limit": 51.0, "track.mpc_sample": 0.2,
              "track.mpc_horizon": 4}
    compiled = flatcli.track(overrides={**common, "track.controller": "mpc",
                                        "track.integrator": "dop853"}, quiet=True)
    adaptive = flatcli.track(overrides={**common, "track.controller": "mpc",
                                        "track.rtol": 1e-11, "track.atol": 1e-13}, quiet=True)
    assert compiled.metrics["replanned"] is False
    design = mpc.flat_design(plan.model, plan.trajectory, plan.duration, 0.01, 51.0, settings)
    ours = flatcli.track(overrides={**common, "track.kp": [1.0, 1.0], "track.kv": [2.0, 2.0]},
                         controller=PythonMpc(design, 0.2), quiet=True)
    angles = [f"theta{i}" for i in range(3)]
    theirs = compiled.frame[angles].to_numpy()
    assert np.abs(ours.frame[angles].to_numpy() - theirs).max() < 1e-12
    assert np.abs(ours.frame[angles].to_numpy() - adaptive.frame[angles].to_numpy()).max() < AGREE
    np.testing.assert_array_equal(ours.frame["dv1"], compiled.frame["dv1"])


@pytest.mark.parametrize("overrides", [{}, {"track.rate_limit": 3.0, "track.sensor_noise": 1e-4}])
def test_the_paper_law_written_in_python_is_the_compiled_one(plan, overrides) -> None:  # type: ignore[no-untyped-def]
    """docs/development.md's example (tests/example_command.py): the paper's flat law in plain
    Python, called at every evaluation through the DOP853 loop on the compiled plant, gives
    the compiled law's trial (control.feedback in controllers.paper.command, the same DOP853
    loop: the referee) to 1e-9 rad; with a rate limit that clips (the plant's clip and the
    rule against wind-up compiled) and sensor noise too."""
    from example_command import PaperLaw

    gains = {"track.kp": [10.0, 13.0], "track.kv": [100.0, 110.0], **overrides}
    compiled = flatcli.track(overrides={**gains, "track.integrator": "dop853"}, quiet=True)
    ours = flatcli.track(overrides=gains, quiet=True,
                         controller=PaperLaw(plan.model.coefficients, (10.0, 13.0),
                                             (100.0, 110.0)))
    root = Path(__file__).resolve().parents[1]
    printed = (root / "tests" / "example_command.py").read_text().split("import math")[1]
    assert printed in (root / "docs" / "development.md").read_text()  # as the docs print it
    angles = [f"theta{i}" for i in range(3)] + ["u1"]
    gap = np.abs(ours.frame[angles].to_numpy() - compiled.frame[angles].to_numpy()).max()
    assert gap < 1e-9
    assert ours.metrics["status"] == compiled.metrics["status"] == "ok"
    if "track.rate_limit" in overrides:
        assert compiled.metrics["clipped_time"] > 0.0  # the limit acted


def test_a_python_controller_that_breaks_the_interface_is_one_clear_error() -> None:
    class NoStep:
        sample = 0.1

        def reset(self) -> None:
            pass

    class WrongSize(NoStep):
        def step(self, k: int, t: float, errors: Array) -> Array:
            return np.zeros(3)

    with pytest.raises(FlatcliError, match=r"controller: NoStep has no method step"):
        flatcli.track(controller=NoStep(), quiet=True)
    with pytest.raises(FlatcliError, match=r"controller: step\(\) must return 2 finite"):
        flatcli.track(controller=WrongSize(), quiet=True)

    class Command:
        def command(self, t: float, theta: Array, u: Array, flag: Array) -> object:
            return (0.0, 0.0), 0.0

    with pytest.raises(FlatcliError, match=r"controller: command\(\) must return"):
        flatcli.track(controller=Command(), quiet=True)
    with pytest.raises(FlatcliError, match=r"controller: a controller with command\(\) runs"):
        flatcli.track(overrides={"plant.model": "dynamic"}, controller=Command(), quiet=True)


def test_a_sweep_writes_the_mpc_columns_null_for_the_other_law(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """trials.parquet has qp_iterations, qp_infeasible (integers) and qp_slack_max for every
    trial, null where the trial's controller is not the MPC; the DOP853 re-run of
    sweep.verify runs the MPC too and agrees with the adaptive trial."""
    spec = {"name": "mpc_sweep",
            "track": {"dt": 0.01, "mpc_sample": 0.2, "mpc_horizon": 4, "kp": [1.0, 1.0],
                      "kv": [2.0, 2.0]},
            "sweep": {"trials": 3, "seed": 1, "verify": 1,
                      "grid": {"track.controller": ["flat", "mpc"]},
                      "perturb": {"initial": {"dist": "normal", "std": 0.002}}}}
    trials = flatcli.sweep(spec, tmp_path / "s", workers=1, quiet=True).trials
    columns = list(mpc.COLUMNS)
    ours = trials[trials["track.controller"] == "mpc"]
    other = trials[trials["track.controller"] == "flat"]
    assert len(ours) == len(other) == 3
    assert ours[columns].notna().all().all() and (ours["qp_iterations"] > 0).all()
    assert other[columns].isna().all().all()
    schema = pq.read_schema(tmp_path / "s" / "trials.parquet")
    assert schema.field("qp_iterations").type == schema.field("qp_infeasible").type == pa.int64()
    checked = ours["reference_difference"].dropna()
    assert len(checked) == 1 and float(checked.iloc[0]) < 1e-6


# registered in loop/table.py (not here) the kernels are made when that module is imported,
# where a compile child finds them; made in the test they compile in this process
@pytest.mark.filterwarnings("ignore:flatcli. compiling nudge_paper_kinematic")
def test_a_new_controller_is_one_module_and_its_registration(plan, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """docs/development.md's example (tests/example_controller.py, as printed there),
    registered as the docs say (``table.SAMPLED``, its kernels generated by the same
    factory, ``CONTROLLERS``), runs as track.controller = "nudge": at every sample it holds
    dv_j = -4 e_j, e_j = y_j - y_jd; for the paper's robot y1 = th1, so the trace's dv1 at
    each sample instant is -4 (th1 - th1 of the plan) there, read from the trace's own
    angles."""
    import example_controller as nudge

    from flatcli.core.loop import simulate as simulate_module
    from flatcli.core.loop import table
    from flatcli.core.loop.kernels import compile_kernels

    base = table.BASE[("flat", "paper", "kinematic")]
    ops = sampled_ops(base[0], nudge.PART)
    kernels = compile_kernels(ops, "nudge_paper_kinematic", base[1], base[2],
                              "example_controller")
    monkeypatch.setitem(table.SAMPLED, "nudge", nudge.PART)
    monkeypatch.setitem(table.KERNELS, ("nudge", "paper", "kinematic"), kernels)
    monkeypatch.setattr(simulate_module, "CONTROLLERS", (*simulate_module.CONTROLLERS, "nudge"))
    scenario = Scenario(plan, Gains((1.0, 1.0), (2.0, 2.0)), dt=0.01, controller="nudge")
    x0 = _initial(plan, np.array([2e-3, -3e-3, 1e-3]))
    out = simulate(scenario, Trials(plan.robot.as_array()[None], np.zeros(1), x0[None]), "rk4",
                   record=True)
    assert out.status[0] == Status.OK and out.trace is not None
    every = round(0.1 / 0.01)
    rows = out.trace[0, :-1:every]
    th1 = rows[:, out.columns.index("theta1")]
    th1_plan = plan.sample(np.arange(len(rows)) * 0.1).theta[:, 1]
    dv1 = rows[:, out.columns.index("dv1")]
    np.testing.assert_allclose(dv1, -4.0 * (th1 - th1_plan), rtol=0, atol=1e-12)
    assert np.abs(dv1).max() > 1e-3


def _lagged_referee(plan, settings: mpc.MpcSettings, dt: float, bandwidth: float,  # type: ignore[no-untyped-def]
                    x0: Array, limit: float = math.inf) -> Array:
    """The final angles (3,) of the flat-law MPC on a robot whose joint rates w lag the
    commanded ones r clipped at ``limit`` as a first-order servo, w' = bandwidth (sat(r) -
    w) (what the dynamic plant does when the servo's model is the plant and no torque is
    clipped: plants.paper's docstring), w(0) = sat(r(0)); the law's integrator u1 held while
    clipped and pushed further out; the base from H = 0 at the actual rates; the law
    measures y' from its own commanded u1 (as the compiled loop does). The referee's own
    loop (the chain's maps, DOP853 at rtol 1e-11), the MPC's step at each sample on the
    design with the offsets the MPC computes (``mpc.tracked_offsets``)."""
    model = ChainModel.of(plan.robot)
    links = Links(*(float(v) for v in plan.robot.links))
    offsets = mpc.tracked_offsets(plan, dt, settings, bandwidth, limit)
    design = mpc.flat_design(plan.model, plan.trajectory, plan.duration, dt, limit,
                             settings, offsets)
    kp = np.asarray(settings.kp, dtype=float)
    kv = np.asarray(settings.kv, dtype=float)
    ts = design.every * dt

    def command(t: float, x: Array, dv: Array) -> tuple[float, float]:
        theta, u = x[:3], x[3:4]
        y, y_dot, _ = model.outputs(theta[None], u[None])
        flag = plan.trajectory.flags(np.array([t]))[0]
        v = flag[4:6] + dv + kv * (flag[2:4] - y_dot[0]) + kp * (flag[0:2] - y[0])
        u_dot = np.zeros(1)
        u2 = inputs(np.array(model.K), np.array(model.inertia), theta, u, v, u_dot)
        return float(u_dot[0]), float(u2)

    def rhs(t: float, x: Array, dv: Array) -> Array:
        u1_dot, u2 = command(t, x, dv)
        if (x[3] >= limit and u1_dot > 0.0) or (x[3] <= -limit and u1_dot < 0.0):
            u1_dot = 0.0
        r1, r2 = np.clip([x[3], u2], -limit, limit)
        h_zero = momentum(links, x[0], x[1], x[2], 0.0, x[4], x[5])
        h_one = momentum(links, x[0], x[1], x[2], 1.0, x[4], x[5])
        return np.array([-h_zero / (h_one - h_zero), x[4], x[5], u1_dot,
                         bandwidth * (r1 - x[4]), bandwidth * (r2 - x[5])])

    r0 = np.clip([x0[3], command(0.0, np.r_[x0, 0.0, 0.0], np.zeros(2))[1]], -limit, limit)
    x, _ = _sampled(plan, design, rhs, np.r_[x0, r0], ts, 3)
    return x[:3]


def _dynamic_final(plan, settings: mpc.MpcSettings, dt: float, bandwidth: float,  # type: ignore[no-untyped-def]
                   x0: Array, rate_limit: float = math.inf, torque_limit: float = math.inf,
                   integrator: str = "adaptive", **extra: Any) -> Array:
    """The final angles (N + 1,) of one compiled MPC trial on the dynamic plant (the servo's
    model the plant, bandwidth ``bandwidth`` [rad/s], the joint torques clipped at
    ``torque_limit``) from ``x0``, the loop at rtol ``KERNEL_RTOL``; it must end ``ok``."""
    n = plan.n_joints
    scenario = Scenario(plan, Gains((1.0,) * n, (2.0,) * n), dt=dt, controller="mpc",
                        settings={"mpc": settings}, rate_limit=rate_limit, rtol=KERNEL_RTOL,
                        atol=1e-13, twin=0.0, plant="dynamic", servo_model="plant",
                        servo_bandwidth=bandwidth, **extra)
    trials = Trials(plan.robot.as_array()[None], np.zeros(1), x0[None],
                    servo=np.array([[bandwidth, torque_limit]]))
    out = simulate(scenario, trials, integrator, record=True)  # type: ignore[arg-type]
    assert out.status[0] == Status.OK
    assert out.trace is not None
    return np.asarray(out.trace[0, -1, : n + 1])


def test_the_dynamic_mpc_is_the_lagged_loop_integrated_by_scipy(plan) -> None:  # type: ignore[no-untyped-def]
    """The flat-law MPC on the dynamic plant (its servo's model the plant, no torque limit:
    each joint rate a first-order lag of bandwidth 100 rad/s) ends where the referee's
    lagged loop ends (``_lagged_referee``), within the goal's 1e-3 rad (the inner gains of
    docs/physics.md's dynamic MPC: poles at -4 rad/s)."""
    settings = mpc.MpcSettings(sample=0.2, horizon=5, kp=(16.0, 16.0), kv=(8.0, 8.0))
    dt, bandwidth = 0.002, 100.0
    x0 = _initial(plan, np.array([2e-3, -3e-3, 1e-3]))
    final = _lagged_referee(plan, settings, dt, bandwidth, x0)
    np.testing.assert_allclose(_dynamic_final(plan, settings, dt, bandwidth, x0), final,
                               atol=1e-6, rtol=0)
    goal = plan.sample(np.array([plan.duration])).theta[0]
    assert np.abs(final - goal).max() < 1e-3


def test_the_dynamic_mpc_reaches_the_goal_within_4_rad_s(replan, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """At 4 rad/s on the dynamic plant (servo 100 rad/s, its model the plant, no torque
    limit) the MPC on its least-peak-rate re-plan, from th(0) 2 mrad off, ends where the
    referee's lagged loop with the rates clipped ends (``_lagged_referee``) and there within
    the goal's 1e-3 rad. The re-plan ends on its margin bound, where an error of the flat
    outputs moves th2 about 1,000 times as much: with the offsets of the path with dv = 0
    alone (``mpc.servo_offsets``) the referee's loop ends more than 3e-3 rad off
    (docs/physics.md, "On the dynamic plant")."""
    settings = mpc.MpcSettings(kp=(16.0, 16.0), kv=(8.0, 8.0))
    dt, bandwidth, limit = 0.002, 100.0, 4.0
    x0 = _initial(replan, np.array([2e-3, -1e-3, 1.5e-3]))
    final = _lagged_referee(replan, settings, dt, bandwidth, x0, limit)
    np.testing.assert_allclose(_dynamic_final(replan, settings, dt, bandwidth, x0, limit),
                               final, atol=1e-6, rtol=0)
    goal = replan.sample(np.array([replan.duration])).theta[0]
    assert np.abs(final - goal).max() < 1e-3
    monkeypatch.setattr(mpc, "OFFSET_PASSES", 0)  # the offsets of the path with dv = 0
    assert np.abs(_lagged_referee(replan, settings, dt, bandwidth, x0, limit) - goal).max() > 3e-3


def _dynamic_referee(plan, settings: mpc.MpcSettings, dt: float, bandwidth: float,  # type: ignore[no-untyped-def]
                     x0: Array, torque_limit: float) -> tuple[Array, float]:
    """The final angles (3,) of the flat-law MPC on the free-floating robot with inertia, and
    the largest servo torque abs(tau_j) it asks before clipping [N m] (over every evaluation,
    rejected trial steps included: an upper bound of the path's). The referee's own loop: the
    state (q, q', u1); M(q) and C(q, q') q' from sympy's Lagrangian of the links' positions
    (tests/test_dynamics.py::lagrangian); the computed-torque rate servo of docs/physics.md
    with the plant as its model, a = b (r - qj'), tau = clip(Mhat a + chat, +-limit); q''
    from M q'' + C q' = (0, tau); H = 0 at the start; DOP853 at rtol 1e-11 over each sample,
    the MPC's step at each sample (as ``_lagged_referee``)."""
    from tests.test_dynamics import lagrangian

    f_M, f_C = lagrangian(3)
    r = plan.robot
    body = tuple(np.asarray(v, dtype=float) for v in (r.mass, r.inertia, r.length, r.com))
    model = ChainModel.of(plan.robot)
    offsets = mpc.tracked_offsets(plan, dt, settings, bandwidth, math.inf)
    design = mpc.flat_design(plan.model, plan.trajectory, plan.duration, dt, math.inf,
                             settings, offsets)
    kp = np.asarray(settings.kp, dtype=float)
    kv = np.asarray(settings.kv, dtype=float)
    ts = design.every * dt
    asked = [0.0]

    def command(t: float, theta: Array, u1: float, dv: Array) -> tuple[float, float]:
        u = np.array([u1])
        y, y_dot, _ = model.outputs(theta[None], u[None])
        flag = plan.trajectory.flags(np.array([t]))[0]
        v = flag[4:6] + dv + kv * (flag[2:4] - y_dot[0]) + kp * (flag[0:2] - y[0])
        u_dot = np.zeros(1)
        u2 = inputs(np.array(model.K), np.array(model.inertia), theta, u, v, u_dot)
        return float(u_dot[0]), float(u2)

    def rhs(t: float, x: Array, dv: Array) -> Array:
        q, w, u1 = x[:3], x[3:6], x[6]
        u1_dot, u2 = command(t, q, u1, dv)
        M = np.asarray(f_M(q, w, *body), dtype=float)
        c = np.asarray(f_C(q, w, *body), dtype=float).ravel()
        m_hat = M[1:, 1:] - np.outer(M[1:, 0], M[0, 1:]) / M[0, 0]
        c_hat = c[1:] - M[1:, 0] * c[0] / M[0, 0]
        tau = m_hat @ (bandwidth * (np.array([u1, u2]) - w[1:])) + c_hat
        asked[0] = max(asked[0], float(np.abs(tau).max()))
        tau = np.clip(tau, -torque_limit, torque_limit)
        return np.r_[w, np.linalg.solve(M, np.r_[0.0, tau] - c), u1_dot]

    w = np.array([0.0, x0[3], command(0.0, x0[:3], x0[3], np.zeros(2))[1]])
    M0 = np.asarray(f_M(x0[:3], w, *body), dtype=float)
    w[0] = -(M0[0, 1:] @ w[1:]) / M0[0, 0]  # H = 0
    x, _ = _sampled(plan, design, rhs, np.r_[x0[:3], w, x0[3]], ts, 6)
    return x[:3], asked[0]


def test_the_dynamic_mpc_keeps_10_n_m_on_its_replan() -> None:
    """At a 10 N m torque limit (below the cubic's 32.6 N m) the MPC tracks the re-plan of
    largest margin (``experiment.mpc_reference``); from th(0) 2 mrad off its trial on the
    dynamic plant (servo 100 rad/s, its model the plant) ends where the referee's full
    dynamics with the torque clipped end (``_dynamic_referee``), to 1e-6 rad, within the
    goal's 1e-3 rad (2.5e-5), the servo never asking 1 N m (0.40: nothing clipped). The other
    side: the same start on the cubic asks the servo 15.4 N m in the referee."""
    from flatcli.api import load_spec
    from flatcli.experiment import plan_from, tracked_plan

    spec = load_spec(None, ("track.controller=\"mpc\"", "plant.model=\"dynamic\"",
                            "plant.torque_limit=10.0"))
    replan, replanned = tracked_plan(spec)
    assert replanned
    settings = mpc.MpcSettings(kp=(16.0, 16.0), kv=(8.0, 8.0))
    dt, bandwidth, limit = 0.002, 100.0, 10.0
    x0 = _initial(replan, np.array([2e-3, -1e-3, 1.5e-3]))
    final, asked = _dynamic_referee(replan, settings, dt, bandwidth, x0, limit)
    assert asked < 1.0  # 0.40 N m
    np.testing.assert_allclose(_dynamic_final(replan, settings, dt, bandwidth, x0,
                                              torque_limit=limit), final, atol=1e-6, rtol=0)
    goal = replan.sample(np.array([replan.duration])).theta[0]
    assert np.abs(final - goal).max() < 1e-3
    cubic = plan_from(spec)
    _, asked = _dynamic_referee(cubic, settings, dt, bandwidth,
                                _initial(cubic, np.array([2e-3, -1e-3, 1.5e-3])), math.inf)
    assert asked > limit


def _lagged_chain_referee(plan, settings: mpc.MpcSettings, dt: float, bandwidth: float,  # type: ignore[no-untyped-def]
                          x0: Array, offsets: Array | None = None) -> Array:
    """The final angles (N + 1,) of the flat-law MPC on a chain of N joints whose joint rates
    w lag the commanded ones r as a first-order servo, w' = bandwidth (r - w), w(0) = r(0)
    (the dynamic plant with the servo's model right and no torque clipped), no rate limit;
    the base from H = 0 by the base's row of the Lagrangian mass matrix (``dynamics.
    mass_matrix``, checked against sympy in tests/test_dynamics.py: h_0 th0' = -sum_j M_0j
    w_j), not the momentum weights flatcli's loops use; the law on the chain's maps, y'
    measured from its commanded u (as the loop measures). DOP853 at rtol 1e-11 between the
    samples, the MPC's step at each on the design with ``offsets`` (default: the MPC's own,
    ``mpc.tracked_offsets``)."""
    from flatcli.core.robots.dynamics import make_chain, mass_matrix

    n = plan.n_joints
    robot = plan.robot
    chain = make_chain(robot.mass, robot.inertia, robot.length, robot.com)
    model = ChainModel.of(robot)
    K, inertia = np.array(model.K), np.array(model.inertia)
    if offsets is None:
        offsets = mpc.tracked_offsets(plan, dt, settings, bandwidth, math.inf)
    design = mpc.flat_design(plan.model, plan.trajectory, plan.duration, dt, math.inf,
                             settings, offsets)
    kp = np.asarray(settings.kp, dtype=float)
    kv = np.asarray(settings.kv, dtype=float)
    ts = design.every * dt

    def errors(t: float, x: Array) -> tuple[Array, Array, Array]:
        y, y_dot, _ = model.outputs(x[None, : n + 1], x[None, n + 1: 2 * n])
        flag = plan.trajectory.flags(np.array([t]))[0]
        return y[0] - flag[:n], y_dot[0] - flag[n: 2 * n], flag

    def command(t: float, x: Array, dv: Array) -> Array:
        e, e_dot, flag = errors(t, x)
        v = flag[2 * n:] + dv - kv * e_dot - kp * e
        u_dot = np.zeros(n - 1)
        last = inputs(K, inertia, x[: n + 1], x[n + 1: 2 * n], v, u_dot)
        return np.r_[u_dot, x[n + 1: 2 * n], last]  # u', then the commands r (N,)

    def rhs(t: float, x: Array, dv: Array) -> Array:
        out = command(t, x, dv)
        u_dot, r, w = out[: n - 1], out[n - 1:], x[2 * n:]
        row = mass_matrix(chain, x[: n + 1])[0]
        return np.r_[-(row[1:] @ w) / row[0], w, u_dot, bandwidth * (r - w)]

    x, _ = _sampled(plan, design, rhs, np.r_[x0, command(0.0, x0, np.zeros(n))[n - 1:]], ts,
                    n + 1)
    return x[: n + 1]


def test_the_dynamic_mpc_of_a_chain_is_its_lagged_loop_integrated_by_scipy() -> None:
    """A chain of 3 joints (tests/test_controllers_flat.py's) on the dynamic plant (servo
    100 rad/s, its model the plant, no torque limit): the flat-law MPC ends where the
    referee's lagged chain ends (``_lagged_chain_referee``: the base from the Lagrangian's
    momentum) to 1e-6 rad (3.7e-13, measured), and there within the goal's 1e-3 rad (2.1e-5);
    with no servo offsets in its design (as before 2026-12-06 for N > 2) the referee's loop
    ends beyond 1e-3 rad (0.015)."""
    from test_controllers_flat import example

    from flatcli.core.plan.planning import plan_chain

    n = 3
    robot, start, goal = example(n)
    chain_plan = plan_chain(robot, start, goal, np.full(n - 1, 0.3), np.full(n - 1, 0.5), 2.0)
    settings = mpc.MpcSettings(sample=0.2, horizon=5, kp=(16.0,) * n, kv=(8.0,) * n)
    dt, bandwidth = 0.002, 100.0
    x0 = np.r_[start + np.array([2e-3, -3e-3, 1e-3, 2e-3]), np.full(n - 1, 0.3)]
    final = _lagged_chain_referee(chain_plan, settings, dt, bandwidth, x0)
    end = chain_plan.sample(np.array([chain_plan.duration])).theta[0]
    np.testing.assert_allclose(_dynamic_final(chain_plan, settings, dt, bandwidth, x0,
                                              integrator="dop853"), final, atol=1e-6, rtol=0)
    assert np.abs(final - end).max() < 1e-3
    samples = round(chain_plan.duration / dt) // settings.every(dt, chain_plan.duration)
    none = _lagged_chain_referee(chain_plan, settings, dt, bandwidth, x0,
                                 np.zeros((samples, 2 * n)))
    assert np.abs(none - end).max() > 1e-3


def test_the_kinematic_design_carries_no_offset(plan) -> None:  # type: ignore[no-untyped-def]
    """On the kinematic plant the design is the one without the servo's offset: no constant
    state, the same tables (so the same numbers to the bit)."""
    settings = mpc.MpcSettings(sample=0.2, horizon=5)
    scenario = Scenario(plan, Gains((1.0, 1.0), (2.0, 2.0)), dt=0.002, controller="mpc",
                        settings={"mpc": settings})
    d = mpc.design_for(scenario)
    assert d.offset == 0 and d.A.shape[1:] == (4, 4)


def test_the_warm_started_mpc_ends_where_the_cold_one_does(replan) -> None:  # type: ignore[no-untyped-def]
    """The MPC's QPs started from the last sample's active set (the design's default) and
    from the unconstrained minimiser (``warm_start = 0``) have the same minimisers (each QP
    is strictly convex; tests/test_qp.py checks the warm start against quadprog): the same
    trials end at the same angles, to the QPs' rounding (the referee: the cold loop, itself
    refereed by scipy above). On the re-plan for 4 rad/s (``replan``) the rate rows bind at
    many samples, so the guesses matter; every applied joint rate at every recorded output
    sample is within the limit in both."""
    plan = replan
    settings = mpc.MpcSettings()  # sample 0.1 s, horizon 20
    dt, limit = 0.002, 4.0
    rng = np.random.default_rng(40)
    x0 = np.array([_initial(plan, rng.uniform(-2e-3, 2e-3, 3)) for _ in range(3)])
    trials = Trials(np.repeat(plan.robot.as_array()[None], 3, axis=0), np.zeros(3), x0)
    outs = []
    for warm in (1, 0):
        scenario = Scenario(plan, Gains((1.0, 1.0), (2.0, 2.0)), dt=dt, rate_limit=limit,
                            controller="mpc", settings={"mpc": settings},
                            rtol=KERNEL_RTOL, atol=1e-13, twin=0.0)
        # the design with its warm start switched (a frozen scenario caches it here)
        scenario.__dict__["sampled_design"] = scenario.sampled_design._replace(
            warm_start=warm)
        out = simulate(scenario, trials, "adaptive", record=True)
        assert out.trace is not None and out.extra is not None
        assert np.all(out.status == Status.OK)
        assert np.all(out.extra[:, 1] == 0)  # no sample needed the slack
        rates = out.trace[:, :, [out.columns.index("theta1_dot"),
                                 out.columns.index("theta2_dot")]]
        # never clipped by the plant (which would hold them at the limit exactly)
        assert np.nanmax(np.abs(rates)) < limit
        assert np.nanmax(np.abs(rates)) > 0.9 * limit  # the limit binds
        outs.append(out)
    warm_out, cold_out = outs
    assert warm_out.extra is not None and cold_out.extra is not None
    # the warm start's own use is tested in tests/test_mpc.py: the iterations here are equal
    # (a right guess costs one factor update a bound, as adding it cold does)
    assert np.all(warm_out.extra[:, 0] > 0)
    np.testing.assert_allclose(warm_out.trace[:, -1, :3], cold_out.trace[:, -1, :3],
                               atol=1e-10, rtol=0)


def test_on_a_torque_replan_the_inner_poles_slow_and_1_n_m_is_kept() -> None:
    """At a 1 N m torque limit the MPC tracks the re-plan of largest margin and, with no rate
    limit, its inner poles default to -2 rad/s (``mpc.TORQUE_INNER_KP``,
    ``Scenario.torque_replanned``): from a start 2.7 mrad off (a trial the poles at -4 rad/s
    lost in docs/physics.md's table) the referee's full dynamics with the torque clipped
    (``_dynamic_referee``) end within the goal's 1e-3 rad, and the compiled trial there to
    1e-6 rad; with the poles at -4 rad/s the referee ends beyond 1e-2 rad (the torque its
    inner law asks clipped). The other side: with no limit, at 100 N m (the cubic kept) and
    with a rate limit the inner poles stay at -4 rad/s."""
    from flatcli.api import load_spec
    from flatcli.experiment import scenario_from, tracked_plan

    def scenario_of(*sets: str) -> Scenario:
        spec = load_spec(None, ("track.controller=\"mpc\"", "plant.model=\"dynamic\"", *sets))
        plan, replanned = tracked_plan(spec)
        return scenario_from(spec, plan, replanned)

    for sets in ((), ("plant.torque_limit=100.0",),
                 ("plant.torque_limit=1.0", "track.rate_limit=10.0")):
        assert mpc.inner_gains(scenario_of(*sets)).kp == (mpc.DYNAMIC_INNER_KP,) * 2
    scenario = scenario_of("plant.torque_limit=1.0")
    assert scenario.torque_replanned
    assert mpc.inner_gains(scenario) == Gains((4.0, 4.0), (4.0, 4.0))
    replan = scenario.plan
    dt, bandwidth, limit = 0.002, 100.0, 1.0
    x0 = _initial(replan, np.array([-2.722e-3, -1.69e-3, -2.501e-3]))
    goal = replan.sample(np.array([replan.duration])).theta[0]
    fast = mpc.MpcSettings(kp=(16.0, 16.0), kv=(8.0, 8.0))
    final, _ = _dynamic_referee(replan, fast, dt, bandwidth, x0, limit)
    assert np.abs(final - goal).max() > 1e-2
    slow = mpc.MpcSettings(kp=(4.0, 4.0), kv=(4.0, 4.0))
    final, _ = _dynamic_referee(replan, slow, dt, bandwidth, x0, limit)
    assert np.abs(final - goal).max() < 1e-3
    np.testing.assert_allclose(_dynamic_final(replan, slow, dt, bandwidth, x0, torque_limit=limit,
                                              torque_replanned=True), final, atol=1e-6, rtol=0)


def _torque_case(limit: float, *sets: str) -> Scenario:
    """The paper's cubic on the dynamic plant at ``limit`` [N m] with the MPC, as a sweep
    makes its scenario (the re-plan within the limit, ``Scenario.torque_kept`` its limit
    (1 - backoff), so the design has the torque rows: ``mpc.servo_torques``)."""
    from flatcli.api import load_spec
    from flatcli.experiment import scenario_from, tracked_plan

    spec = load_spec(None, ("track.controller=\"mpc\"", "plant.model=\"dynamic\"",
                            f"plant.torque_limit={limit!r}", *sets))
    plan, replanned = tracked_plan(spec)
    return scenario_from(spec, plan, replanned)


def test_the_torque_rows_are_the_torques_the_dynamic_plant_applies() -> None:
    """Referee: the joint torques the compiled dynamic plant applied (its computed-torque
    servo, Mhat b (r - w) + chat on the lagging joint rates, trace columns tau1, tau2; the
    robot's dynamics checked against sympy's Lagrangian in tests/test_dynamics.py), not the
    flat map's inverse dynamics the rows are made of (``mpc.servo_torques``). The MPC's
    design at 0.5 N m (the rows at 0.485), the trial 2.7 mrad off and its torque not
    clipped (limit inf), b = 100 rad/s. At each sample t_k (k >= 1; t = 0 starts the servo
    off the plan): the torques' jump between the output steps either side of t_k is the
    rows' J_k (dv_k - dv_k-1) to 5 % of the largest (measured 1.2 %; jumps up to 0.2 N m),
    and the torque just before t_k+1 is the rows' linearised torque at the measured
    (s_k+1, dv_k) within 0.03 N m (measured 0.023, what the rows leave out is of order
    1/b: 0.003 at b = 1000), where the plan's own torque there misses it by 0.14 N m."""
    scenario = _torque_case(0.5)
    plan = scenario.plan
    scenario = dataclasses.replace(scenario, rtol=KERNEL_RTOL, atol=1e-13, twin=0.0)
    x0 = _initial(plan, np.array([-2.7e-3, -1.7e-3, -2.5e-3]))
    out = simulate(scenario, Trials(plan.robot.as_array()[None], np.zeros(1), x0[None],
                                    servo=np.array([[scenario.servo_bandwidth, math.inf]])),
                   "adaptive", record=True)
    assert out.status[0] == Status.OK and out.trace is not None
    d = mpc.design_for(scenario)
    n, every, samples = 2, d.every, d.samples
    assert d.held == n and d.value.shape[1] == 2 * n + 1  # rates, margin, the torques
    trace = out.trace[0]
    tau = trace[:, [out.columns.index(f"tau{j}") for j in (1, 2)]]
    dv = trace[:, [out.columns.index(f"dv{j}") for j in (1, 2)]]
    model = ChainModel.of(plan.robot)
    y, y_dot, _ = model.outputs(trace[:, :3], trace[:, [out.columns.index("u1")]])
    flag = plan.trajectory.flags(np.arange(trace.shape[0]) * scenario.dt)
    s = np.empty((trace.shape[0], 2 * n))
    s[:, 0::2], s[:, 1::2] = y - flag[:, :n], y_dot - flag[:, n: 2 * n]
    held = dv[np.arange(samples) * every]  # dv_k, held over [t_k, t_k+1)
    rows = slice(n + 1, 2 * n + 1)
    jumps, predicted, ends, plan_miss = [], [], [], []
    for k in range(1, samples):
        jumps.append(tau[k * every] - tau[k * every - 1])
        predicted.append(d.slope_v[k, rows] @ (held[k] - held[k - 1]))
        z = np.r_[s[(k + 1) * every], held[k], 1.0]  # errors, the held dv, the constant
        linear = (d.value[k + 1, rows] + d.slope_s[k + 1, rows] @ z
                  + d.slope_v[k + 1, rows] @ held[k])
        ends.append(tau[(k + 1) * every - 1] - linear)
        plan_miss.append(tau[(k + 1) * every - 1] - d.value[k + 1, rows])
    largest = np.abs(predicted).max()
    assert largest > 0.1
    assert np.abs(np.subtract(jumps, predicted)).max() < 0.05 * largest
    assert np.abs(ends).max() < 0.03
    assert np.abs(plan_miss).max() > 0.1


def test_the_torque_rows_bring_a_trial_the_inner_law_loses_to_the_goal() -> None:
    """At 0.5 N m (b = 100 rad/s) a trial of benchmarks/mpc_torque.toml's seed 2004 cell:
    with the torque rows (the scenario a sweep makes) it ends within the goal's 1e-3 rad
    (6.9e-5 in the sweep) and its torque sits at the limit for fewer output steps after the
    first sample; without them (``Scenario.torque_kept`` inf: the design before the rows)
    the jumps of the servo's torque at the samples are clipped and it ends beyond it
    (4.2e-3). The other side: at 100 N m the rows are in the design and never bind."""
    scenario = _torque_case(0.5)
    plan = scenario.plan
    x0 = _initial(plan, np.array([-0.004583078163799215, -0.0019435195356534152,
                                  0.0007853084512301434]))
    goal = plan.sample(np.array([plan.duration])).theta[0]
    errors, saturated = [], []
    for kept in (scenario.torque_kept, math.inf):
        case = dataclasses.replace(scenario, torque_kept=kept)
        out = simulate(case, Trials(plan.robot.as_array()[None], np.zeros(1), x0[None],
                                    servo=np.array([[case.servo_bandwidth, 0.5]])),
                       "adaptive", record=True)
        assert out.trace is not None
        tau = out.trace[0][:, [out.columns.index(f"tau{j}") for j in (1, 2)]]
        errors.append(np.abs(out.trace[0, -1, :3] - goal).max())
        saturated.append(int((np.abs(tau[mpc.design_for(case).every:]).max(axis=1)
                              >= 0.5 * (1 - 1e-9)).sum()))
    assert errors[0] < 1e-3 < errors[1]
    assert saturated[0] < saturated[1]
    high = mpc.design_for(_torque_case(100.0))
    assert high.value.shape[1] == 5 and high.held == 2
