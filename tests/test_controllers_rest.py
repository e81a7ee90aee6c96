"""The rest-to-rest law compiled (``flatcli.core.controllers.rest``: the flat law's feedback
faded in and out, run by the same kernels as the flat law) against its referee, the blended
law integrated by scipy's DOP853 at rtol 1e-11 on the full link kinematics
(``tests/rest_referee.py``), and its reference channels against the plan's own numbers."""

from __future__ import annotations

import numpy as np
import pytest

import flatcli
from flatcli.core.controllers import rest
from flatcli.core.controllers.control import Gains
from flatcli.experiment import plant_from
from tests.rest_referee import fade, track_rest

#: The paper's robot (capture.toml, started 2e-3 rad off the plan) and a chain of N = 3
#: (chain4, rest to rest, its own track.initial 1.2 rad off at worst).
CASES = {"paper": ("flatcli/data/capture.toml", {"track.initial": [1.802, 0.999, 0.001]}),
         "chain": ({"robot": "chain4", "task.rest": True}, {})}
#: The compiled trials' angles agree with the referee's within this [rad]: both integrators
#: at rtol 1e-10 or tighter; 5e-9 rad measured (2026-12-06) on trials whose error reaches
#: 0.6 rad (paper) and 1.2 rad (chain).
AGREE = 1e-7


@pytest.mark.parametrize("limit", [None, 4.0])
@pytest.mark.parametrize("case", sorted(CASES))
def test_the_compiled_rest_law_agrees_with_a_dop853_referee(case: str, limit: float | None
                                                            ) -> None:
    """Off the plan, without and with a rate limit that clips (0.7-1 s of 2 s): the adaptive
    integrator's trial (rtol 1e-10) is the referee's to 1e-7 rad at every output sample and
    at T (status ok, no crossing)."""
    source, overrides = CASES[case]
    sets: dict[str, object] = {**overrides, "track.rtol": 1e-10, "track.atol": 1e-12}
    if limit is not None:
        sets["track.rate_limit"] = limit
    result = flatcli.track(source, overrides=sets, quiet=True)
    run, spec, metrics = result.run, result.spec, result.metrics
    plan, n = run.plan, run.plan.n_joints
    assert metrics["status"] == "ok" and metrics["crossings"] == 0
    assert (metrics["clipped_time"] > 0.5) == (limit is not None)
    assert metrics["err_theta_max"] > 0.5  # far from the plan on the way
    trace, columns = run.outcome.trace[0], run.outcome.columns
    theta = trace[:, [columns.index(f"theta{i}") for i in range(n + 1)]]
    referee = track_rest(plan, Gains(spec.track.kp, spec.track.kv), plant_from(spec),
                         np.asarray(spec.track.initial)[: n + 1], run.scenario.times,
                         spec.task.fade, spec.plant.momentum, spec.track.rate_limit)
    assert referee.finished
    assert np.max(np.abs(theta - referee.theta)) < AGREE
    np.testing.assert_allclose(run.outcome.final[0], referee.theta[-1], rtol=0, atol=AGREE)


@pytest.mark.parametrize("fraction", [0.1, 0.2, 0.5])
def test_the_rest_reference_is_the_plans_own(fraction: float) -> None:
    """The channels the law reads: the flat outputs and their two derivatives to 1e-13 of
    ``RestPlan.derivative``; w to 1e-15 of the referee's fade, exactly 0 at t = 0 and 1 in
    the middle; th_N' where w < 1 within 3e-10 rad/s of ``RestPlan.sample`` (its own
    accuracy near the ends); the sign of the plan's margin."""
    for source in ("flatcli/data/capture.toml", {"robot": "chain4", "task.rest": True}):
        plan = flatcli.plan(source).plan
        curves = rest.reference(plan, fraction)
        T, n = plan.duration, plan.n_joints
        t = np.linspace(0.0, T, 4001)
        for order in range(3):
            np.testing.assert_allclose(curves.derivative(t, order)[:, :n],
                                       plan.derivative(t, order), rtol=0, atol=1e-13)
        values = curves.derivative(t, 0)
        w = values[:, n]
        np.testing.assert_allclose(w, [fade(x, T, fraction) for x in t], rtol=0, atol=1e-15)
        assert w[0] == 0.0 and np.all(w[(t > fraction * T) & (t < T - fraction * T)] == 1.0)
        inside = (w < 1) & (t > 0) & (t < T)
        rates = plan.sample(t[inside]).theta_dot[:, n]
        np.testing.assert_allclose(values[inside, n + 1], rates, rtol=0, atol=3e-10)
        margin = plan.sample(np.array([0.5 * T])).margin[0]
        assert np.all(values[:, n + 2] == np.sign(margin))


@pytest.mark.parametrize(("sets", "key"), [({"plant.model": "dynamic"}, r"plant\.model"),
                                           ({"track.controller": "mpc"}, r"track\.controller"),
                                           ({"track.controller": "asbuilt"},
                                            r"track\.controller")])
def test_a_rest_task_is_refused_where_the_rest_law_does_not_run(sets: dict[str, str],
                                                                key: str) -> None:
    """The dynamic plant (the law meets its singular set before T there) and the other
    controllers: one error naming the key, before any trial runs."""
    with pytest.raises(flatcli.FlatcliError, match=key):
        flatcli.track("flatcli/data/capture.toml", overrides=sets, quiet=True)
