"""Write tests/data/kinematic_golden.npz: the kinematic plant's outcomes on a few trials.

Run once, at the commit named in the file (``commit``), before the dynamic plant was added
(issue 9), so that ``tests/test_plants_paper.py`` can check that the kinematic plant's results did
not change by a single bit. Regenerate it only when a change to the kinematic plant is meant
to change its numbers (and say so in that commit):

    .venv/bin/python tests/data/make_kinematic_golden.py
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from flatcli.core.controllers.control import Gains
from flatcli.core.loop.simulate import NoiseStreams, Scenario, Trials, simulate
from flatcli.core.plan.planning import plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT

HERE = Path(__file__).resolve().parent
#: Every TRACE_STRIDE-th output sample of each trace is kept (the metrics see them all).
TRACE_STRIDE = 10

#: The cases: (name, gains, rate limit [rad/s], noise std [rad], integrator).
CASES = (
    ("printed_adaptive", Gains((10.0, 13.0), (100.0, 110.0)), np.inf, 0.0, "adaptive"),
    ("swapped_adaptive_noise", Gains((100.0, 110.0), (10.0, 13.0)), np.inf, 1e-3, "adaptive"),
    ("swapped_rk4_limited", Gains((100.0, 110.0), (10.0, 13.0)), 20.0, 0.0, "rk4"),
    ("printed_dop853", Gains((10.0, 13.0), (100.0, 110.0)), np.inf, 0.0, "dop853"),
)


def golden_trials(count: int) -> Trials:
    """Perturbed plants (every parameter within +-2 %, d_i within +-2 mm), initial angles
    within 0.05 rad of the plan's start, u1(0) near 0.1, H0 within +-1e-4."""
    rng = np.random.default_rng(9)
    base = PAPER_ROBOT.as_array()
    links = base * (1 + rng.uniform(-0.02, 0.02, (count, 12)))
    links[:, 9:12] = base[9:12] + rng.uniform(-0.002, 0.002, (count, 3))
    initial = np.array([1.8, 1.0, 0.0, 0.1]) + np.c_[rng.normal(0, 0.05, (count, 3)),
                                                     rng.normal(0, 0.01, count)]
    return Trials(links, rng.uniform(-1e-4, 1e-4, count), initial)


def main() -> None:
    plan = plan_point_to_point(PAPER_ROBOT, np.array([1.8, 1.0, 0.0]),
                               np.array([1.2, 2.0, 0.0]), 0.1, 0.5, 2.0)
    out: dict[str, np.ndarray] = {}
    for name, gains, limit, std, integrator in CASES:
        count = 2 if integrator == "dop853" else 5
        trials = golden_trials(count)
        if std > 0:
            trials = Trials(trials.links, trials.momentum, trials.initial,
                            NoiseStreams(std, 7, np.arange(count, dtype=np.int64)))
        scenario = Scenario(plan, gains, 2e-3, rate_limit=limit)
        outcome = simulate(scenario, trials, integrator, record=True)  # type: ignore[arg-type]
        assert outcome.trace is not None
        out[f"{name}/metrics"] = outcome.metrics
        out[f"{name}/status"] = outcome.status
        out[f"{name}/event"] = outcome.event
        out[f"{name}/event_time"] = outcome.event_time
        out[f"{name}/trace"] = outcome.trace[:, ::TRACE_STRIDE]
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                            cwd=HERE, check=True).stdout.strip()
    out["commit"] = np.array(commit)
    np.savez_compressed(HERE / "kinematic_golden.npz", **out)
    print(f"wrote {HERE / 'kinematic_golden.npz'} at {commit}")


if __name__ == "__main__":
    main()
