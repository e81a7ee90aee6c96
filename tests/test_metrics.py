"""Tests of flatcli.core.metrics: every metric recomputed independently from a recorded trace.

The independent computation uses numpy only on the trace (norms, RMS, numpy.gradient with
edge_order=2 for the rates), the public flat map and margin, the plan sampled anew, and the
full-kinematics ``momentum``; the kernel's fused loop is not consulted.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray

from flatcli.core.control import Gains
from flatcli.core.flatness import flat_outputs, singularity_margin
from flatcli.core.metrics import (
    METRIC_NAMES,
    N_METRICS,
    STATUS_DIVERGED,
    STATUS_NAMES,
    STATUS_OK,
    STATUS_SINGULAR,
    describe_status,
    trace_rates,
)
from flatcli.core.model import PAPER_ROBOT, RobotParams, momentum
from flatcli.core.planning import FlatPlan
from flatcli.core.simulate import Scenario, Trials, simulate

Array = NDArray[np.float64]

#: Metrics vs the independent numpy computation: same quantities, other summation order.
METRIC_RTOL = 1e-10
METRIC_ATOL = 1e-15
#: momentum_drift: the difference quotients carry rounding ~eps |th| / dt ~ 1e-12 rad/s at
#: dt = 1 ms, rounded differently by numpy (divide by 2 dt) and the kernel (multiply by
#: 0.5 / dt); times coefficients h_j <~ 0.1 kg m^2 (observed differences <= 3e-14 kg m^2/s).
DRIFT_ATOL = 1e-12

PRINTED = Gains(kp1=10.0, kp2=13.0, kv1=100.0, kv2=110.0)  # paper, eqs. 39-42
FIG4 = (1.96, 0.8, -0.1, 0.1)  # paper, Fig. 4 (u1(0) from the physics note)


@dataclass(frozen=True)
class Case:
    """One closed-loop run whose metrics are recomputed."""

    initial: tuple[float, float, float, float] = FIG4
    plant: RobotParams = PAPER_ROBOT
    h0: float = 0.0
    model: str = "derived"
    threshold: float = 1e-2
    bound: float = 1e4
    integrator: str = "rk4"
    plan_samples: int = 201


CASES = {
    "nominal": Case(),
    # d2 = 5 mm and H0 != 0 in the plant, the printed coefficients in the controller
    "mismatch": Case(plant=PAPER_ROBOT.with_(com=(0.1, 0.1, 0.005)), h0=2e-3, model="paper",
                     plan_samples=57),
    # a threshold above the run's minimum margin (0.0717): hits without a singular crossing
    "hits": Case(threshold=0.1),
    # u1(0) against the plan's sign: driven through the singular set
    "singular": Case(initial=(1.8, 1.0, 0.0, -0.1)),
    # th2 passes 3 rad: diverged mid-run, metrics up to the last valid sample
    "diverged": Case(bound=3.0),
    "dop853": Case(integrator="dop853"),
}  # fmt: skip


def expected_metrics(plan: FlatPlan, scenario: Scenario, case: Case, trace: Array) -> Array:
    """(N_METRICS,) from the trace, the plan and the plant, in the order of METRIC_NAMES."""
    valid = np.isfinite(trace[:, :4]).all(axis=1)
    count = int(np.argmin(valid)) if not valid.all() else len(valid)
    assert valid[:count].all() and not valid[count:].any()
    diverged = count < len(valid)
    x = trace[:count, :4]
    t = scenario.times[:count]
    dt = scenario.dt

    theta_ref = plan.sample(t).theta
    e_theta = np.linalg.norm(x[:, :3] - theta_ref, axis=1)
    y = np.array(flat_outputs(plan.coefficients, *x.T))[:2].T
    e_y = np.linalg.norm(y - plan.trajectory.derivative(t, 0), axis=1)
    margin = np.asarray(singularity_margin(x[:, 1], x[:, 3]))
    hits = np.flatnonzero(margin < case.threshold)
    if count >= 3:
        rates = np.gradient(x[:, :3], dt, axis=0, edge_order=2)
        drift = np.max(np.abs(momentum(case.plant.links, *x[:, :3].T, *rates.T) - case.h0))
    else:
        drift = np.nan
    own = plan.sample(plan.grid(case.plan_samples))
    residual = np.max(np.abs(momentum(case.plant.links, *own.theta.T, *own.theta_dot.T) - case.h0))
    values = {
        "err_theta_rms": np.sqrt(np.mean(e_theta**2)),
        "err_theta_max": e_theta.max(),
        "err_theta_final": np.nan if diverged else e_theta[-1],
        "err_y_rms": np.sqrt(np.mean(e_y**2)),
        "err_y_max": e_y.max(),
        "err_y_final": np.nan if diverged else e_y[-1],
        "singular_hits": hits.size,
        "first_hit_time": hits[0] * dt if hits.size else np.nan,
        "min_margin": margin.min(),
        "momentum_drift": drift,
        "plan_momentum_residual": residual,
    }
    assert set(values) == set(METRIC_NAMES)
    return np.array([values[name] for name in METRIC_NAMES], dtype=float)


@pytest.mark.parametrize("name", list(CASES))
def test_metrics_equal_independent_computation(
    plan_factory: Callable[..., FlatPlan], trials_factory: Callable[..., Trials], name: str
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
    )
    outcome = simulate(
        scenario,
        trials_factory(case.initial, case.plant, case.h0),
        case.integrator,  # type: ignore[arg-type]
        record=True,
    )
    assert outcome.trace is not None
    got = outcome.metrics[0]
    expected = expected_metrics(plan, scenario, case, outcome.trace[0])
    for i, metric in enumerate(METRIC_NAMES):
        atol = DRIFT_ATOL if metric == "momentum_drift" else METRIC_ATOL
        np.testing.assert_allclose(got[i], expected[i], rtol=METRIC_RTOL, atol=atol, err_msg=metric)
    status = {
        "nominal": STATUS_OK, "mismatch": STATUS_OK, "hits": STATUS_SINGULAR,
        "singular": STATUS_SINGULAR, "diverged": STATUS_DIVERGED, "dop853": STATUS_OK,
    }[name]  # fmt: skip
    assert outcome.status[0] == status
    if name in ("hits", "singular"):
        assert expected[METRIC_NAMES.index("singular_hits")] > 0


def test_trace_rates_are_numpy_gradient_of_second_order() -> None:
    """trace_rates at every row of a random trace = numpy.gradient(edge_order=2)."""
    rng = np.random.default_rng(5)
    trace = rng.normal(size=(9, 5))
    dt = 0.01
    last = 7  # rows beyond last are ignored (a diverged run)
    expected = np.gradient(trace[: last + 1, :3], dt, axis=0, edge_order=2)
    got = np.array([trace_rates(trace, j, last, 0.5 / dt) for j in range(last + 1)])
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-12)


def test_describe_status() -> None:
    metrics = np.full(N_METRICS, np.nan)
    metrics[METRIC_NAMES.index("singular_hits")] = 3
    metrics[METRIC_NAMES.index("first_hit_time")] = 0.25
    metrics[METRIC_NAMES.index("min_margin")] = 1e-3
    assert describe_status(STATUS_OK, np.nan, metrics, 0.01, 1e4) == ("ok", "")
    name, reason = describe_status(STATUS_SINGULAR, 0.25, metrics, 0.01, 1e4)
    assert name == "singular"
    assert "below 0.01" in reason and "3 samples" in reason and "t = 0.25 s" in reason
    name, reason = describe_status(STATUS_DIVERGED, 1.5, metrics, 0.01, 1e4)
    assert name == "diverged"
    assert "beyond 10000" in reason and "t = 1.5 s" in reason
    assert [STATUS_NAMES[c] for c in (STATUS_OK, STATUS_SINGULAR, STATUS_DIVERGED)] == [
        "ok",
        "singular",
        "diverged",
    ]
