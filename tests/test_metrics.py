"""Tests of flatcli.core.loop.metrics: every metric recomputed independently from a recorded trace.

The independent computation uses numpy only on the trace (norms, RMS, maxima), the public
flat map and margin, the plan sampled anew, and an angular momentum written here from the
inertial-frame positions of the link centres of mass (velocities by complex step of those
positions along the applied rates): not the kernel's fused loop, not ``model.momentum``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray

from flatcli.core.controllers.control import Gains
from flatcli.core.loop.metrics import (
    COUNT_METRICS,
    METRIC_NAMES,
    N_METRICS,
    STATUS_NAMES,
    Event,
    Metric,
    Status,
    describe_status,
    finish_metrics,
    observe_torque,
    reset_accumulator,
)
from flatcli.core.loop.simulate import Scenario, Trials, simulate
from flatcli.core.models.flatness import flat_outputs, singularity_margin
from flatcli.core.plan.planning import Plan
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams

Array = NDArray[np.float64]

#: Metrics vs the independent numpy computation: same quantities, other summation order.
METRIC_RTOL = 1e-10
METRIC_ATOL = 1e-15
#: momentum_drift: both sides are rounding of H, sums of terms up to I |rates| (observed
#: <= 3e-16 at rates of ~50 rad/s, 1.4e-12 at th2' = 1.7e5 rad/s before a pole), per rad/s.
DRIFT_ATOL_PER_RATE = 1e-16

PRINTED = Gains((10.0, 13.0), (100.0, 110.0))  # paper, eqs. 39-42
FIG4 = (1.96, 0.8, -0.1, 0.1)  # paper, Fig. 4; u1(0) = y1d'(0) of the plan


def inertial_momentum(robot: RobotParams, theta: Array, rates: Array) -> Array:
    """H about the system centre of mass [kg m^2/s] at states theta (n, 3) with rates (n, 3):
    centres of mass placed in the inertial frame from O0 = 0 (absolute angles th0,
    th0 + th1, th0 + th1 + th2), velocities by a complex step of those positions along the
    rates, H = sum m r x v + I w - M r_c x v_c."""
    m, inertia, length, d = (np.asarray(v) for v in (robot.mass, robot.inertia, robot.length,
                                                     robot.com))
    step = 1e-30

    def positions(th: NDArray[np.complex128]) -> NDArray[np.complex128]:
        a0, a1, a2 = th[:, 0], th[:, 0] + th[:, 1], th[:, 0] + th[:, 1] + th[:, 2]
        # x and y apart (not one complex number), so that the complex step is a derivative
        ex = [np.cos(a) for a in (a0, a1, a2)]
        ey = [np.sin(a) for a in (a0, a1, a2)]
        cx = [d[0] * ex[0], length[0] * ex[0] + d[1] * ex[1],
              length[0] * ex[0] + length[1] * ex[1] + d[2] * ex[2]]
        cy = [d[0] * ey[0], length[0] * ey[0] + d[1] * ey[1],
              length[0] * ey[0] + length[1] * ey[1] + d[2] * ey[2]]
        return np.stack([np.stack(cx, -1), np.stack(cy, -1)], -1)  # (n, 3 links, 2)

    r = positions(theta.astype(complex)).real
    v = positions(theta + 1j * step * rates).imag / step
    rc = np.einsum("i,nik->nk", m, r) / m.sum()
    vc = np.einsum("i,nik->nk", m, v) / m.sum()
    spin = inertia[0] * rates[:, 0] + inertia[1] * (rates[:, 0] + rates[:, 1]) + inertia[2] * (
        rates.sum(axis=1))
    orbital = np.einsum("i,ni->n", m, r[..., 0] * v[..., 1] - r[..., 1] * v[..., 0])
    return np.asarray(spin + orbital - m.sum() * (rc[:, 0] * vc[:, 1] - rc[:, 1] * vc[:, 0]))


@dataclass(frozen=True)
class Case:
    """One closed-loop run whose metrics are recomputed."""

    initial: tuple[float, float, float, float] = FIG4
    plant: RobotParams = PAPER_ROBOT
    h0: float = 0.0
    model: str = "derived"
    threshold: float = 1e-2
    bound: float = 1e4
    integrator: str = "adaptive"
    plan_samples: int = 201
    rate_limit: float = np.inf


CASES = {
    "nominal": Case(),
    "rk4": Case(integrator="rk4"),
    "dop853": Case(integrator="dop853"),
    # d2 = 5 mm and H0 != 0 in the plant, the printed coefficients in the controller
    "mismatch": Case(plant=PAPER_ROBOT.with_(com=(0.1, 0.1, 0.005)), h0=2e-3, model="paper",
                     plan_samples=57),
    # a threshold above the run's minimum margin (0.0717): hits without a crossing
    "hits": Case(threshold=0.1),
    # u1(0) against the plan's sign: driven into the singular set, stopped there
    "singular": Case(initial=(1.8, 1.0, 0.0, -0.1)),
    # th2 passes 3 rad: diverged mid-run, metrics up to the last valid sample
    "diverged": Case(bound=3.0),
    "diverged_rk4": Case(bound=3.0, integrator="rk4"),
    # clipped joint rates
    "limited": Case(rate_limit=0.3),
}  # fmt: skip


def expected_metrics(plan: Plan, scenario: Scenario, case: Case, trace: Array,
                     crossed_at: float) -> Array:
    """(N_METRICS,) from the trace, the plan and the plant, in the order of METRIC_NAMES
    (the integrators' own counters and error estimate are taken as reported). Crossings of
    the singular set are the sign changes of sin th1 * u1 between samples, and the one a
    trial stopped at (``crossed_at``, its event time; nan if it did not stop there); the
    time of one between samples is the later sample's (the test compares it within dt)."""
    valid = np.isfinite(trace[:, 0])
    count = int(np.argmin(valid)) if not valid.all() else len(valid)
    assert valid[:count].all() and not valid[count:].any()
    stopped = count < len(valid)
    x = trace[:count, :4]
    rates = trace[:count, 4:7]
    t = scenario.times[:count]
    dt = scenario.dt

    theta_ref = plan.sample(t).theta
    e_theta = np.linalg.norm(x[:, :3] - theta_ref, axis=1)
    y = np.array(flat_outputs(plan.coefficients, *x.T))[:2].T
    e_y = np.linalg.norm(y - plan.trajectory.derivative(t, 0), axis=1)
    margin = np.asarray(singularity_margin(x[:, 1], x[:, 3]))
    hits = np.flatnonzero(margin < case.threshold)
    signed = np.sin(x[:, 1]) * x[:, 3]
    flips = np.flatnonzero(np.sign(signed[1:]) != np.sign(signed[:-1])) + 1
    crossing_times = [*(flips * dt), *([] if np.isnan(crossed_at) else [crossed_at])]
    crossings = len(crossing_times)
    first_hit = min([*(hits[:1] * dt), *crossing_times], default=np.nan)
    drift = np.max(np.abs(inertial_momentum(case.plant, x[:, :3], rates) - case.h0))
    own = plan.sample(plan.grid(case.plan_samples))
    residual = np.max(np.abs(inertial_momentum(case.plant, own.theta, own.theta_dot) - case.h0))
    values = {
        "err_theta_rms": np.sqrt(np.mean(e_theta**2)),
        "err_theta_max": e_theta.max(),
        "err_theta_final": np.nan if stopped else e_theta[-1],
        "err_y_rms": np.sqrt(np.mean(e_y**2)),
        "err_y_max": e_y.max(),
        "err_y_final": np.nan if stopped else e_y[-1],
        "singular_hits": hits.size + crossings,
        "first_hit_time": first_hit,
        "min_margin": 0.0 if crossings else margin.min(),
        "momentum_drift": drift,
        "plan_momentum_residual": residual,
        "peak_rate": np.max(np.abs(rates[:, 1:])),
        "peak_torque": np.nan,  # the kinematic plant has no torques
        "torque_saturated": np.nan,
        "crossings": crossings,
        "first_crossing_time": crossing_times[0] if crossings else np.nan,
        # the trapezoidal rule (numpy's) over the samples of "a joint turned at the limit":
        # u1 beyond it (th1' = clip(u1)) or th2' at it (th2' = clip(u2))
        "clipped_time": float(np.trapezoid(
            ((np.abs(x[:, 3]) >= case.rate_limit)
             | (np.abs(rates[:, 2]) >= case.rate_limit)).astype(float), dx=dt)),
    }
    return np.array([values.get(name, np.nan) for name in METRIC_NAMES], dtype=float)


@pytest.mark.parametrize("name", list(CASES))
def test_metrics_equal_independent_computation(
    plan_factory: Callable[..., Plan], trials_factory: Callable[..., Trials], name: str
) -> None:
    case = CASES[name]
    plan = plan_factory(case.model)
    scenario = Scenario(
        plan,
        PRINTED,
        1e-3,
        singular_threshold=case.threshold,
        divergence_bound=case.bound,
        plan_samples=case.plan_samples,
        rate_limit=case.rate_limit,
    )
    outcome = simulate(
        scenario,
        trials_factory(case.initial, case.plant, case.h0),
        case.integrator,  # type: ignore[arg-type]
        record=True,
    )
    assert outcome.trace is not None
    got = outcome.metrics[0]
    crossed_at = float(outcome.event_time[0]) if outcome.event[0] == Event.CROSSED else np.nan
    expected = expected_metrics(plan, scenario, case, outcome.trace[0], crossed_at)
    for metric in Metric:
        if metric in (Metric.ERR_ESTIMATE, Metric.STEPS, Metric.RHS_EVALUATIONS):
            continue
        if metric in (Metric.FIRST_HIT_TIME, Metric.FIRST_CROSSING_TIME):
            # a crossing between samples: within the interval before the sample after it
            np.testing.assert_allclose(got[metric], expected[metric], atol=scenario.dt,
                                       err_msg=metric.name)
            assert not got[metric] > expected[metric] + 1e-12, metric.name
            continue
        peak = float(np.nanmax(np.abs(outcome.trace[0, :, 4:7])))
        atol = DRIFT_ATOL_PER_RATE * max(peak, 100.0) if metric in (
            Metric.MOMENTUM_DRIFT, Metric.PLAN_MOMENTUM_RESIDUAL) else METRIC_ATOL
        np.testing.assert_allclose(got[metric], expected[metric], rtol=METRIC_RTOL, atol=atol,
                                   err_msg=metric.name)
    if name == "limited":  # the limit bites for a while (both sides of clipped_time)
        assert 0.05 < got[Metric.CLIPPED_TIME] <= plan.duration
    else:
        assert got[Metric.CLIPPED_TIME] == 0.0
    status = {"hits": Status.SINGULAR, "singular": Status.DIVERGED, "diverged": Status.DIVERGED,
              "diverged_rk4": Status.DIVERGED}.get(name, Status.OK)  # fmt: skip
    assert outcome.status[0] == status
    steps, evaluations = got[Metric.STEPS], got[Metric.RHS_EVALUATIONS]
    if case.integrator == "adaptive" and status in (Status.OK, Status.SINGULAR):
        assert 0 < got[Metric.ERR_ESTIMATE] < 1e-2  # the twin's estimate (test_simulate)
        assert 0 < 6 * steps < evaluations
    elif case.integrator == "adaptive":  # stopped early: no twin, no estimate
        assert np.isnan(got[Metric.ERR_ESTIMATE])
        assert 0 < 6 * steps < evaluations
    else:
        assert np.isnan(got[Metric.ERR_ESTIMATE])
    if case.integrator == "rk4" and status == Status.OK:
        assert (steps, evaluations) == (scenario.n_steps, 4 * scenario.n_steps + 1)


def test_inertial_momentum_is_the_full_kinematics() -> None:
    """The test's own H: zero for a robot at rest, I_total w for a rigid rotation (th1' =
    th2' = 0) about the centre of mass, and independent of th0."""
    robot = PAPER_ROBOT
    theta = np.array([[0.3, 1.0, -0.5]])
    assert inertial_momentum(robot, theta, np.zeros((1, 3)))[0] == 0.0
    w = 0.7
    # rigid rotation: H = w * (sum I_i + sum m_i |r_i - r_c|^2)
    m = np.asarray(robot.mass)
    a = np.cumsum(theta[0])
    ex, ey = np.cos(a), np.sin(a)
    lengths, d = robot.length, robot.com
    r = np.array([[d[0] * ex[0], d[0] * ey[0]],
                  [lengths[0] * ex[0] + d[1] * ex[1], lengths[0] * ey[0] + d[1] * ey[1]],
                  [lengths[0] * ex[0] + lengths[1] * ex[1] + d[2] * ex[2],
                   lengths[0] * ey[0] + lengths[1] * ey[1] + d[2] * ey[2]]])  # fmt: skip
    rc = m @ r / m.sum()
    expected = w * (sum(robot.inertia) + np.sum(m * np.sum((r - rc) ** 2, axis=1)))
    got = inertial_momentum(robot, theta, np.array([[w, 0.0, 0.0]]))[0]
    assert got == pytest.approx(expected, rel=1e-14)
    rates = np.array([[0.2, -0.4, 1.1]])
    turned = inertial_momentum(robot, theta + np.array([1.0, 0.0, 0.0]), rates)
    assert turned[0] == pytest.approx(inertial_momentum(robot, theta, rates)[0], rel=1e-13)


def test_metric_names_are_the_public_columns() -> None:
    assert METRIC_NAMES[: 11] == (
        "err_theta_rms", "err_theta_max", "err_theta_final", "err_y_rms", "err_y_max",
        "err_y_final", "singular_hits", "first_hit_time", "min_margin", "momentum_drift",
        "plan_momentum_residual",
    )  # fmt: skip
    assert {"err_estimate", "peak_rate", "peak_torque", "torque_saturated", "steps",
            "rhs_evaluations"} <= set(METRIC_NAMES)
    assert set(COUNT_METRICS) <= set(METRIC_NAMES)
    assert STATUS_NAMES == ("ok", "singular", "diverged", "unresolved", "error")


def test_torque_metrics_accumulate_only_where_a_plant_has_torques() -> None:
    """peak_torque = max abs(tau_i) and torque_saturated = the count of samples flagged;
    nan when no sample had torques (the kinematic plant)."""
    from flatcli.core.loop.metrics import ACCUMULATOR_SIZE

    acc = np.empty(ACCUMULATOR_SIZE)
    out = np.empty(N_METRICS)
    reset_accumulator(acc)
    finish_metrics(out, acc, True, 1e-3, 0.0, np.nan, 0, 0)
    assert np.isnan(out[Metric.PEAK_TORQUE]) and np.isnan(out[Metric.TORQUE_SATURATED])
    taus = [(0.5, -2.0, 0.0), (-3.5, 1.0, 1.0), (0.0, 0.0, 0.0), (3.0, -3.5, 1.0)]
    for tau1, tau2, saturated in taus:
        observe_torque(acc, tau1, tau2, saturated)
    finish_metrics(out, acc, True, 1e-3, 0.0, np.nan, 0, 0)
    assert out[Metric.PEAK_TORQUE] == 3.5
    assert out[Metric.TORQUE_SATURATED] == 2


def test_describe_status() -> None:
    metrics = np.full(N_METRICS, np.nan)
    metrics[Metric.SINGULAR_HITS] = 3
    metrics[Metric.FIRST_HIT_TIME] = 0.25
    metrics[Metric.MIN_MARGIN] = 1e-3
    metrics[Metric.STEPS] = 77
    none = int(Event.NONE)
    assert describe_status(Status.OK, none, np.nan, metrics, 0.01, 1e4) == ("ok", "")
    name, reason = describe_status(Status.SINGULAR, none, 0.25, metrics, 0.01, 1e4)
    assert name == "singular"
    assert "below 0.01" in reason and "3 samples" in reason and "t = 0.25 s" in reason
    assert "crossed" not in reason
    passed = metrics.copy()
    passed[Metric.SINGULAR_HITS] = 4  # 3 samples and a crossing between two
    passed[Metric.CROSSINGS] = 1
    passed[Metric.FIRST_CROSSING_TIME] = 0.125
    passed[Metric.FIRST_HIT_TIME] = 0.125
    passed[Metric.MIN_MARGIN] = 0.0
    name, reason = describe_status(Status.SINGULAR, none, 0.125, passed, 0.01, 1e4)
    assert name == "singular"
    assert "crossed the singular set 1 time, first at t = 0.125 s" in reason
    assert "actuators' limits kept the plant's rates bounded" in reason
    assert "3 samples" in reason and "min margin 0" in reason
    name, reason = describe_status(Status.DIVERGED, int(Event.BOUND), 1.5, metrics, 0.01, 1e4)
    assert name == "diverged" and "beyond 10000" in reason and "t = 1.5 s" in reason
    name, reason = describe_status(Status.DIVERGED, int(Event.CROSSED), 0.5, metrics, 0.01, 1e4)
    assert name == "diverged" and "crossed the singular set" in reason
    name, reason = describe_status(Status.DIVERGED, int(Event.STALLED), 0.5, metrics, 0.01, 1e4)
    assert name == "diverged" and "met the singular set" in reason
    name, reason = describe_status(Status.UNRESOLVED, int(Event.MAX_STEPS), 0.7, metrics, 0.01,
                                   1e4)
    assert name == "unresolved" and "track.max_steps" in reason and "77 steps" in reason
    name, reason = describe_status(Status.UNRESOLVED, int(Event.STEP_FLOOR), 0.7, metrics,
                                   0.01, 1e4)
    assert name == "unresolved" and "track.rtol" in reason
    for event in Event:
        assert (event.status in (Status.OK,)) == (event is Event.NONE)
