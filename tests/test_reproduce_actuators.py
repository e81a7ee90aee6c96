"""The actuators section of make reproduce (flatcli/actuators.py): its statistics, its
finding (a cell tracks when every trial reached: the outcomes of hand-made trial rows), and
the plans' demands.

References: statistics recomputed here with numpy from hand-made trial rows; the Wilson
interval from its closed form (Wilson, J. Am. Stat. Assoc. 22, 1927); the plan's exact rates
from ``Plan.sample`` (complex step through the inverse map, another route than
``plant.plan_motion``). End to end, the section is run by tests/test_reproduce.py.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from flatcli.experiment import plan_from
from flatcli.reproduce.actuators import (
    BANDWIDTH,
    LIMIT,
    MANEUVER,
    TRACKABLE_ERROR,
    bandwidth_law,
    cell_table,
    crossing_accounting,
    finding,
    limit_text,
    lost_interval,
    matrix_entry,
    plan_demands,
)
from flatcli.spec import resolve


def trials_frame() -> pd.DataFrame:
    """Two maneuvers x two bandwidths x two limits, 4 trials each, with known outcomes; under
    maneuver a's torque limit at 10 rad/s, trial 3 crossed the singular set and tumbled (final
    error 50 rad, not verified)."""
    rows = []
    rng = np.random.default_rng(1)
    for maneuver in ("a", "b"):
        for bandwidth in (10.0, 100.0):
            for limit in (math.inf, 5.0):
                for i in range(4):
                    lost = maneuver == "b" and limit == 5.0 and i == 0
                    tumbled = maneuver == "a" and limit == 5.0 and bandwidth == 10.0 and i == 3
                    error = 50.0 if tumbled else 0.05 / bandwidth * (1 + rng.uniform())
                    rows.append({
                        MANEUVER: maneuver, BANDWIDTH: bandwidth, LIMIT: limit,
                        "status": "diverged" if lost else ("singular" if i == 1 else "ok"),
                        "err_theta_final": math.nan if lost else error,
                        "peak_torque": 3.0 + i if math.isinf(limit) else min(3.0 + i, limit),
                        "torque_saturated": 0 if math.isinf(limit) or i < 2 else 7,
                        "momentum_drift": 1e-10 * (i + 1),
                        "crossings": 2 if tumbled else 0,
                        "first_crossing_time": 0.05 if tumbled else math.nan,
                        "err_estimate": 3e-3 if tumbled else 1e-9,
                        "verified": not (lost or tumbled),
                        # the outcome: within track.goal_tolerance (1e-3 rad) or not
                        "outcome": "lost" if lost else ("reached" if error <= 1e-3
                                                        else "missed"),
                    })
    return pd.DataFrame(rows)


def test_cell_statistics_are_over_the_right_trials() -> None:
    frame = trials_frame()
    cells = cell_table(frame)
    assert len(cells) == 8
    for _, cell in cells.iterrows():
        group = frame[(frame[MANEUVER] == cell[MANEUVER]) & (frame[BANDWIDTH] == cell[BANDWIDTH])
                      & (frame[LIMIT] == cell[LIMIT])]
        done = group[group["status"].isin(["ok", "singular"]) & group["verified"]]
        crossed = group["crossings"] > 0
        assert cell["trials"] == 4
        assert cell["crossed"] == crossed.mean()
        assert cell["tumbled"] == (crossed & (group["err_theta_final"] > TRACKABLE_ERROR)).mean()
        resolved = group[group["status"].isin(["ok", "singular"])]
        assert cell["unverified"] == 1 - resolved["verified"].mean()
        assert cell["lost"] == cell["diverged"] == (group["status"] == "diverged").mean()
        assert cell["unresolved"] == 0
        final = done["err_theta_final"].to_numpy()
        assert cell["err_final_median"] == np.median(final)
        assert cell["err_final_p95"] == np.quantile(final, 0.95)
        assert cell["peak_torque_median"] == np.median(done["peak_torque"])
        assert cell["saturated"] == (group["torque_saturated"] > 0).mean()
        assert cell["drift_max"] == done["momentum_drift"].max()
        reached = group["outcome"] == "reached"
        assert cell["reached"] == reached.mean() and cell["reached_count"] == reached.sum()
        assert cell["trackable"] == reached.all()  # every trial reached
        assert cell["counted"] == len(done) and cell["crossed_count"] == crossed.sum()
        # each number of the REPORT's matrix says over which trials it is
        entry = matrix_entry(cell)
        assert entry.startswith(f"{int(reached.sum())}/4 reached; p95 ")
        assert f" of {len(done)}" in entry
        assert ("/4 crossed" in entry) == bool(crossed.any())
    tumbling = cells[cells["tumbled"] > 0]
    assert len(tumbling) == 1 and tumbling.iloc[0]["err_final_p95"] < 1  # 50 rad left out
    assert matrix_entry(tumbling.iloc[0]).endswith("; 1/4 crossed")


def test_bandwidth_law_range_and_crossing_accounting() -> None:
    """error = c / b (closed form: the product error x b is c) from 20 rad/s up, ten times
    that below: the law's range starts at 20 rad/s; the accounting counts the tumbled trial
    of ``trials_frame`` and the diverged ones."""
    rows = []
    for b in (5.0, 10.0, 20.0, 50.0, 100.0):
        error = 0.6 / b * (1 if b >= 20 else 10)
        rows.append({MANEUVER: "m", BANDWIDTH: b, LIMIT: math.inf, "status": "ok",
                     "err_theta_final": error, "peak_torque": 1.0, "torque_saturated": 0,
                     "momentum_drift": 0.0, "crossings": 0, "verified": True})
    law = bandwidth_law(cell_table(pd.DataFrame(rows)))
    low, product, below = law["m"]
    assert low == 20.0 and product == pytest.approx(0.6) and below == pytest.approx(6.0)
    counts = crossing_accounting(trials_frame())
    assert counts["crossed"] == 1 and counts["recovered"] == 0 and counts["verified"] == 0
    assert counts["final_min"] == counts["final_max"] == 50.0 and counts["limits"] == [5.0]
    assert counts["diverged"] == 2 and counts["diverged_limits"] == [5.0]
    text = finding(cell_table(trials_frame()), {}, counts)
    assert "1 trials crossed the controller's singular set" in text
    assert "0 reached, 1 missed and 0 were lost (outcome)" in text
    assert "0 ended within 0.01 rad of the plan" in text


def test_finding_names_the_least_bandwidth_and_torque_that_track() -> None:
    cells = cell_table(trials_frame())
    text = finding(cells, {"a": ["a", 1.5, 2.5, 4.0]})
    # maneuver a: errors 5e-3-1e-2 at 10 rad/s (missed), 5e-4-1e-3 at 100 rad/s (reached)
    assert "every one of its trials reached" in text
    assert "the a plan (the plan itself needs 2.5 N m and 4 rad/s) is trackable from a " \
           "bandwidth of 100 rad/s" in text
    assert "the least torque limit that still tracks is 5 N m (at 100 rad/s)" in text
    # maneuver b loses a trial under the 5 N m limit
    assert "the b plan is trackable from a bandwidth of 100 rad/s" in text
    assert "and under none of the torque limits of the study" in text


def test_limit_text_and_wilson_interval() -> None:
    assert limit_text(math.inf) == "none" and limit_text(30.0) == "30"
    # Wilson's closed form: (p + z^2/2n +- z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)
    n, k, z = 25, 3, 1.959963984540054
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    low, high = lost_interval(k / n, n)
    assert low == pytest.approx(centre - half, rel=1e-9)
    assert high == pytest.approx(centre + half, rel=1e-9)


def test_plan_demands_of_the_cubic() -> None:
    """The cubic's peak joint rate is its exact th2'(0) (plan samples); the closed loop
    started on the plan finishes, its torque within reach of the plan's own."""
    base = resolve({})
    [row] = plan_demands(base, [("paper's cubic", {})])
    plan = plan_from(base)
    samples = plan.sample(plan.grid(4001))
    assert row[3] == pytest.approx(np.abs(samples.theta_dot[:, 1:]).max(), rel=1e-12)
    ideal = max(row[1], row[2])
    assert 0.5 * ideal < row[4] < 1.5 * ideal  # the servo lags: less than the plan's peak
    assert row[6] < 0.05  # final angle error on plan at 100 rad/s [rad]


def test_forgetting_the_study_removes_a_finished_kinematic_twin_and_its_folder(
        tmp_path: object) -> None:
    """The twin sweep under kinematic/ of an earlier run goes, folder and all, also now that
    a finished sweep leaves no trials/ folder (its chunks are in trials.parquet); a note of
    the user's there keeps it (and the sweep then refuses, naming it)."""
    from pathlib import Path

    from flatcli.montecarlo import run_sweep
    from flatcli.reproduce.actuators import forget_study
    from flatcli.spec import resolve

    root = Path(str(tmp_path))
    spec = resolve({"track": {"dt": 0.01}, "sweep": {
        "trials": 2, "perturb": {"initial": {"dist": "normal", "std": 0.01}}}})
    run_sweep(spec, root / "kinematic", workers=1)
    assert (root / "kinematic" / "trials.parquet").exists()
    assert not (root / "kinematic" / "trials").exists()
    forget_study(root)
    assert not (root / "kinematic").exists()
    run_sweep(spec, root / "kinematic", workers=1)
    (root / "kinematic" / "notes.txt").write_text("mine")
    forget_study(root)
    assert (root / "kinematic" / "notes.txt").read_text() == "mine"
    assert (root / "kinematic" / "trials.parquet").exists()
