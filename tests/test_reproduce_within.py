"""The section "Within the actuators" of make reproduce (flatcli/reproduce/within.py): its
cells by outcome from hand-made trial rows, its table and figure, and its study spec.

References: the counts recomputed here from the rows; the Wilson interval from its closed
form (Wilson, J. Am. Stat. Assoc. 22, 1927); the dynamic study's table and finding against
its trials.parquet, counted here row by row. End to end, the section is run by
tests/test_reproduce.py.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flatcli.reproduce import within
from flatcli.reproduce.sections import Context, Steps
from flatcli.reproduce.within import (
    CONTROLLER,
    LIMIT,
    STUDY,
    TORQUE,
    cell_rows,
    dynamic_spec,
    outcome_table,
    plot_fraction,
    torque_finding,
    torque_table,
)
from flatcli.spec import load_spec, resolve

Z95 = 1.959963984540054  # Phi^-1(0.975)


def wilson(k: int, n: int) -> tuple[float, float]:
    """Wilson's closed form: (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)."""
    p, z = k / n, Z95
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def trials_frame() -> pd.DataFrame:
    """Two limits x two controllers, 5 trials each: with no limit every trial reaches; at 4
    rad/s the paper's feedback misses 4 (error 2 rad) and loses 1, the MPC (re-planned)
    reaches 4 and misses 1, two of its trials needing slack."""
    rows = []
    for limit in (math.inf, 4.0):
        for controller in ("flat", "mpc"):
            for i in range(5):
                if limit == 4.0 and controller == "flat":
                    outcome = "lost" if i == 0 else "missed"
                    error = math.nan if i == 0 else 2.0 + i
                elif limit == 4.0:
                    outcome = "missed" if i == 4 else "reached"
                    error = 0.01 if i == 4 else 1e-9 * (i + 1)
                else:
                    outcome, error = "reached", 1e-5 * (i + 1)
                rows.append({
                    LIMIT: limit, CONTROLLER: controller, "outcome": outcome,
                    "err_theta_final": error,
                    "replanned": None if controller == "flat" else limit == 4.0,
                    "qp_infeasible": None if controller == "flat" else (
                        3 if limit == 4.0 and i >= 3 else 0),
                    "clipped_time": 0.0 if math.isinf(limit) else 0.1 * i,
                })
    return pd.DataFrame(rows)


def test_cells_are_counted_by_outcome_with_their_intervals() -> None:
    rows = cell_rows(trials_frame())
    assert list(zip(rows[LIMIT], rows[CONTROLLER], strict=True)) == [
        (math.inf, "flat"), (math.inf, "mpc"), (4.0, "flat"), (4.0, "mpc")]
    flat4 = rows.iloc[2]
    assert (flat4["trials"], flat4["reached"], flat4["missed"], flat4["lost"]) == (5, 0, 4, 1)
    assert flat4["median"] == pytest.approx(4.5)  # over the 4 that reached T: 3, 4, 5, 6
    assert flat4["replanned"] is None and pd.isna(flat4["slack_trials"])
    mpc4 = rows.iloc[3]
    assert (mpc4["reached"], mpc4["missed"], mpc4["slack_trials"]) == (4, 1, 2)
    assert mpc4["replanned"] is True and rows.iloc[1]["replanned"] is False
    assert mpc4["fraction"] == pytest.approx(0.8)
    low, high = wilson(4, 5)
    assert mpc4["low"] == pytest.approx(low, rel=1e-9)
    assert mpc4["high"] == pytest.approx(high, rel=1e-9)
    assert mpc4["clipped_max"] == pytest.approx(0.4)
    text = outcome_table(rows)
    assert "| 4 | MPC | re-planned | 4 of 5 | 80 % (" in text
    assert "| none | paper's feedback | - | 5 of 5 | 100 % (" in text


def test_the_figure_is_written(tmp_path: Path) -> None:
    path = tmp_path / "fig_within.png"
    plot_fraction(cell_rows(trials_frame()), 5, 0.002, 3.87, path)
    assert path.stat().st_size > 10_000


def test_the_study_compares_both_controllers_over_the_limits() -> None:
    spec = load_spec(STUDY)
    assert spec.sweep.grid[CONTROLLER] == ["flat", "mpc"]
    limits = spec.sweep.grid[LIMIT]
    assert math.isinf(limits[0]) and sorted(limits[1:], reverse=True) == limits[1:]
    assert spec.sweep.perturb["initial"]["std"] == 0.002


def torque_frame() -> pd.DataFrame:
    """Two torque limits x two controllers, 4 trials each, as the dynamic plant writes them:
    the paper's feedback misses every trial with no limit and at 1 N m is singular and lost
    in 3; the MPC reaches all with no limit and at 1 N m (re-planned) 2, its 2 others
    clipped and missed."""
    rows = []
    for limit in (math.inf, 1.0):
        for controller in ("flat", "mpc"):
            for i in range(4):
                if controller == "flat":
                    outcome = "lost" if limit == 1.0 and i < 3 else "missed"
                    status = "singular" if limit == 1.0 and i < 3 else "ok"
                    torque, clipped = (1.0, 50) if limit == 1.0 else (100.0 + i, 0)
                elif limit == 1.0:
                    outcome = "missed" if i >= 2 else "reached"
                    status = "ok"
                    torque, clipped = (1.0, 7) if i >= 2 else (0.5 + 0.1 * i, 0)
                else:
                    outcome, status, torque, clipped = "reached", "ok", 20.0 + i, 0
                rows.append({
                    TORQUE: limit, CONTROLLER: controller, "outcome": outcome,
                    "status": status, "err_theta_final": 1e-3 * (i + 1),
                    "replanned": None if controller == "flat" else limit == 1.0,
                    "qp_infeasible": None if controller == "flat" else 0,
                    "clipped_time": 0.0, "peak_torque": torque, "torque_saturated": clipped,
                })
    return pd.DataFrame(rows)


def test_the_torque_cells_say_where_the_mpc_falls_short() -> None:
    rows = cell_rows(torque_frame(), TORQUE)
    assert list(zip(rows[TORQUE], rows[CONTROLLER], strict=True)) == [
        (math.inf, "flat"), (math.inf, "mpc"), (1.0, "flat"), (1.0, "mpc")]
    flat1, mpc1 = rows.iloc[2], rows.iloc[3]
    assert (flat1["reached"], flat1["missed"], flat1["lost"], flat1["singular"]) == (0, 1, 3, 3)
    assert (mpc1["reached"], mpc1["missed"], mpc1["torque_clipped"]) == (2, 2, 2)
    assert mpc1["peak_torque"] == pytest.approx(np.median([0.5, 0.6, 1.0, 1.0]))
    assert rows.iloc[1]["peak_torque"] == pytest.approx(21.5)  # 20, 21, 22, 23
    text = torque_table(rows)
    assert "| 1 | MPC | re-planned | 2 of 4 | 50 % (" in text
    assert "| none | paper's feedback | - | 0 of 4 | 0 % (" in text
    finding = torque_finding(rows)
    low, high = wilson(2, 4)
    assert finding.startswith("With no torque limit the paper's feedback reaches 0 % (4 missed")
    assert ("at 1 N m the paper's feedback reaches 0 % (1 missed, 3 lost; 3 singular), the "
            f"MPC 50 % ({100 * low:.3g}-{100 * high:.3g} %)") in finding
    assert "at 2 of these 2 limits" not in finding and "of these 2 limits" in finding
    assert ("it cannot at 1 N m (2 of 4 reached; 2 of its trials had their torque clipped, 2 "
            "of the 2 not reached among them") in finding


def test_the_dynamic_study_is_checked_against_its_trials(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The section run on a small study (3 trials a cell; one rate limit; the dynamic plant
    at no torque limit and 1 N m): its dynamic table and finding against the trials'
    rows, counted here."""
    study_spec = within.study_spec
    monkeypatch.setattr(within, "study_spec", lambda context: study_spec(context).with_overrides(
        {"sweep.grid": {LIMIT: [math.inf], CONTROLLER: ["flat", "mpc"]}}))
    monkeypatch.setattr(within, "TORQUE_LIMITS", (math.inf, 1.0))
    context = Context(tmp_path, resolve({}), None, ("sweep.trials=3",), 1, Steps(quiet=True))
    outcome = within.run(context)
    report = "\n".join(outcome.lines)
    trials = pd.read_parquet(tmp_path / "within" / "dynamic" / "trials.parquet")
    assert len(trials) == 12 and set(trials["plant.torque_limit"]) == {math.inf, 1.0}
    for (key, controller), cell in trials.groupby(["plant.torque_limit", CONTROLLER]):
        limit = float(key)  # type: ignore[arg-type]
        n, k = len(cell), int((cell["outcome"] == "reached").sum())
        name = "MPC" if controller == "mpc" else "paper's feedback"
        plan = "-" if controller == "flat" else (
            "re-planned" if bool(cell["replanned"].iloc[0]) else "as planned")
        row = f"| {'none' if math.isinf(limit) else f'{limit:g}'} | {name} | {plan} | {k} of {n} |"
        assert row in report, row
        if controller == "flat" and k < n / 2:
            missed = int((cell["outcome"] == "missed").sum())
            lost = int((cell["outcome"] == "lost").sum())
            singular = int((cell["status"] == "singular").sum())
            mpc = trials[(trials["plant.torque_limit"] == limit) & (trials[CONTROLLER] == "mpc")]
            reached = int((mpc["outcome"] == "reached").sum())
            at = "ith no torque limit" if math.isinf(limit) else f"at {limit:g} N m"
            assert (f"{at} the paper's feedback reaches {100 * k / n:.3g} % ({missed} missed, "
                    f"{lost} lost; {singular} singular), the MPC "
                    f"{100 * reached / len(mpc):.3g} % ") in report
            if reached < 0.95 * len(mpc):
                clipped = int((mpc["torque_saturated"] > 0).sum())
                unreached = int(((mpc["torque_saturated"] > 0)
                                 & (mpc["outcome"] != "reached")).sum())
                assert (f"({reached} of {len(mpc)} reached; {clipped} of its trials had their "
                        f"torque clipped, {unreached} of the {len(mpc) - reached} not "
                        "reached among them") in report
    mpc1 = trials[(trials["plant.torque_limit"] == 1.0) & (trials[CONTROLLER] == "mpc")]
    assert bool(mpc1["replanned"].all())  # the cubic asks 32.6 N m
    assert any(line.startswith("dynamic plant, MPC within the torque limits: none N m ")
               for line in outcome.headline)


def test_the_dynamic_study_is_the_torque_benchmarks_settings() -> None:
    """dynamic_spec against benchmarks/mpc_torque.toml (the spec of docs/physics.md's
    table): the same plant, plan and perturbation."""
    bench = load_spec(Path(__file__).resolve().parents[1] / "benchmarks" / "mpc_torque.toml")
    spec = dynamic_spec(load_spec(STUDY))
    for key in ("model", "servo_bandwidth", "servo_model", "torque_limit"):
        assert getattr(spec.plant, key) == getattr(bench.plant, key), key
    assert spec.plan.basis == bench.plan.basis and spec.track.initial == bench.track.initial
    assert spec.sweep.perturb == bench.sweep.perturb
    assert spec.sweep.trials == 40 and spec.sweep.grid[TORQUE] == [math.inf, 30, 10, 3, 1]
    assert math.isinf(spec.track.rate_limit)
