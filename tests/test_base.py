"""Tests of flatcli.core.loop.base: a base law and a plant composed into one closed loop, here
with a plant that is not flatcli's (docs/development.md's example, tests/example_plant.py).

Referees, none of them the plant under test: the trace's own columns (the law's commands u_j
beside the rates the plant applied), and the angular momentum as the base's row of the
Lagrangian mass matrix times the applied rates (``referees.base_row_momentum``:
``dynamics.mass_matrix``, checked against a sympy Lagrangian in tests/test_dynamics.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from referees import base_row_momentum
from test_controllers_flat import example

from flatcli.core.controllers import flat
from flatcli.core.controllers.control import Gains
from flatcli.core.loop import simulate as simulate_module
from flatcli.core.loop.base import base_ops
from flatcli.core.loop.kernels import chain_plant, compile_kernels
from flatcli.core.loop.metrics import Metric, Status
from flatcli.core.loop.simulate import Scenario, Trials, simulate
from flatcli.core.plan.planning import plan_chain
from flatcli.core.robots.dynamics import make_chain


# the kernels of a plant made in a test live in its module (``compile_kernels``'s module),
# where a compile child finds them; made in the test they compile in this process
@pytest.mark.filterwarnings("ignore:flatcli. compiling chain_weak")
def test_a_new_plant_is_one_module_and_its_registration(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """docs/development.md's example plant, registered as the docs say (its kernels made by
    ``base_ops`` with the flat law, ``table.KERNELS``, ``PLANT_MODELS``), runs a chain of 3
    joints as plant "weak": at every output sample each joint j < N turns at 0.9 u_j, the
    flat law's command, clipped to the rate limit, and the base turns so that H stays 0 by
    the Lagrangian's momentum, with no rate limit and with one it meets; the trial ends
    where the kinematic plant's does not."""
    import example_plant

    from flatcli.core.loop import table

    root = Path(__file__).resolve().parents[1]
    printed = (root / "tests" / "example_plant.py").read_text().split('"""\n\n', 1)[1]
    assert printed.strip() in (root / "docs" / "development.md").read_text()  # as printed

    kernels = compile_kernels(base_ops(flat.LAW, example_plant.PLANT), "chain_weak",
                              flat.LAW.shared, chain_plant, "example_plant")
    monkeypatch.setitem(table.KERNELS, ("flat", "chain", "weak"), kernels)
    monkeypatch.setattr(simulate_module, "PLANT_MODELS",
                        (*simulate_module.PLANT_MODELS, "weak"))
    n = 3
    robot, start, goal = example(n)
    plan = plan_chain(robot, start, goal, np.full(n - 1, 0.3), np.full(n - 1, 0.5), 2.0)
    x0 = np.r_[start + 0.01, np.full(n - 1, 0.3)]
    trials = Trials(robot.as_array()[None], np.zeros(1), x0[None])
    chain = make_chain(robot.mass, robot.inertia, robot.length, robot.com)
    for limit in (np.inf, 40.0):
        weak, kin = (simulate(Scenario(plan, Gains((100.0,) * n, (20.0,) * n), 1e-3,
                                       rate_limit=limit, plant=plant), trials, "dop853",
                              record=True)
                     for plant in ("weak", "kinematic"))
        assert weak.status[0] == Status.OK and weak.trace is not None and kin.trace is not None
        columns, trace = weak.columns, weak.trace[0]
        theta = trace[:, [columns.index(f"theta{a}") for a in range(n + 1)]]
        rates = trace[:, [columns.index(f"theta{a}_dot") for a in range(n + 1)]]
        for j in range(1, n):
            u = trace[:, columns.index(f"u{j}")]
            np.testing.assert_allclose(rates[:, j], np.clip(0.9 * u, -limit, limit), rtol=0,
                                       atol=1e-12)
        assert np.abs(base_row_momentum(chain, theta, rates)).max() < 1e-12
        assert np.abs(weak.trace[0, -1, : n + 1] - kin.trace[0, -1, : n + 1]).max() > 1e-3
        # the flat law believes th_N' is its command: a motor 10 % weak is a model error
        # it does not absorb (0.59 rad off at T, measured), where the kinematic plant ends
        # 1.7e-7 rad (no limit) and 1.5e-4 rad (40 rad/s) off
        assert kin.metrics[0, Metric.ERR_THETA_FINAL] < 1e-3
        assert weak.metrics[0, Metric.ERR_THETA_FINAL] > 0.1
        if np.isfinite(limit):  # the limit was met and held
            assert np.abs(rates[:, 1:]).max() == pytest.approx(limit, abs=1e-12)
