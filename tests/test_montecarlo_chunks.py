"""One chunk of trials (flatcli/montecarlo/chunks.py): its rows, and what --fail-fast reads."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

from flatcli.core.loop.metrics import METRIC_NAMES
from flatcli.montecarlo import Chunk, ChunkResult, grid_cell_text, layout, run_chunk
from flatcli.montecarlo.chunks import grid_columns, verify_count
from flatcli.montecarlo.layout import work_pieces
from flatcli.spec import SpecError, resolve
from flatcli.storage import UNIT_KEY, table_checksum


def test_a_chunk_has_one_row_per_trial_with_draws_and_metrics_by_name() -> None:
    spec = resolve({"plan": {"duration": 1.0}, "track": {"dt": 0.01, "kp": [100, 110],
                                                         "kv": [20, 21]},
                    "sweep": {"trials": 4, "seed": 3, "grid": {"track.sensor_noise": [0.001]},
                              "perturb": {"initial_rate": {"dist": "normal", "std": 0.01}}}})
    cell = layout(spec).cells[0]
    result = run_chunk(cell, Chunk(0, 1, 4))
    frame = result.table.to_pandas()
    assert frame["trial"].tolist() == [1, 2, 3]
    assert frame["track.sensor_noise"].tolist() == [0.001] * 3
    assert {"initial_rate", *METRIC_NAMES, "status", "reason"} <= set(frame.columns)
    assert frame["singular_hits"].dtype == np.int64
    assert (frame["status"] == "ok").all() and result.first_failure() is None
    # a trial's row does not depend on the chunk it ran in
    alone = run_chunk(cell, Chunk(0, 2, 3)).table.to_pandas()
    assert alone.iloc[0].equals(frame.iloc[1])


def test_a_chunk_joined_from_pieces_is_the_whole_chunk() -> None:
    """The last chunks of a run are computed in pieces (layout.work_pieces): joined, they are
    the chunk computed whole, to the bit (the referee: run_chunk on the whole chunk), with
    sensor noise, a perturbed plant and the reference re-runs of sweep.verify in both."""
    spec = resolve({"plan": {"duration": 1.0}, "track": {"dt": 0.01, "kp": [100, 110],
                                                         "kv": [20, 21]},
                    "sweep": {"trials": 60, "seed": 5, "verify": 3,
                              "grid": {"track.sensor_noise": [0.001]},
                              "perturb": {"initial": {"dist": "normal", "std": 0.02},
                                          "mass": {"dist": "uniform", "low": -0.05,
                                                   "high": 0.05, "relative": True}}}})
    cell = layout(spec).cells[0]
    chunk = Chunk(0, cell.first_trial, cell.first_trial + 60)
    whole = run_chunk(cell, chunk)
    parts = [run_chunk(cell, piece) for _, piece in work_pieces([chunk], 2)]
    assert len(parts) == 2
    joined = ChunkResult.joined(parts)
    assert joined.table.equals(whole.table)
    assert joined.table.schema.equals(whole.table.schema, check_metadata=True)
    assert table_checksum(joined.table) == table_checksum(whole.table)
    # the checksum its file records, computed where the rows were made
    assert whole.checksum == joined.checksum == table_checksum(whole.table)
    assert all(p.checksum == table_checksum(p.table) for p in parts)
    assert all(column.num_chunks == 1 for column in joined.table.columns)
    assert joined.seconds == sum(p.seconds for p in parts)
    assert joined.peak_mib == max(p.peak_mib for p in parts)
    assert ChunkResult.joined([whole]) is whole


def test_a_dynamic_chunk_perturbs_the_servo_and_refuses_an_invalid_one() -> None:
    """Servo bandwidth and torque limit drawn per trial (columns of their own), torques in
    the metrics, and a drawn bandwidth <= 0 an ``error`` with the spec key's message."""
    spec = resolve({"plan": {"duration": 1.0}, "track": {"dt": 0.01, "kp": [100, 110],
                                                         "kv": [20, 21],
                                                         "initial": [1.8, 1.0, 0.0]},
                    "plant": {"model": "dynamic", "servo_bandwidth": 50.0,
                              "torque_limit": 20.0},
                    "sweep": {"trials": 6, "seed": 4, "perturb": {
                        "servo_bandwidth": {"dist": "uniform", "low": -1.2, "high": 0.5,
                                            "relative": True},
                        "torque_limit": {"dist": "uniform", "low": -10.0, "high": 30.0}}}})
    frame = run_chunk(layout(spec).cells[0], Chunk(0, 0, 6)).table.to_pandas()
    bad = frame["servo_bandwidth"] <= 0
    assert bad.any() and (~bad).any()
    assert (frame.loc[bad, "status"] == "error").all()
    assert frame.loc[bad, "reason"].str.startswith("plant.servo_bandwidth: must be > 0").all()
    good = frame[~bad]
    assert (good["status"] != "error").all()  # simulated (some diverge at these limits)
    assert good["torque_limit"].between(10.0, 50.0).all()
    assert (good["peak_torque"] <= good["torque_limit"]).all()
    assert good["peak_torque"].notna().all() and good["torque_saturated"].notna().all()


def test_first_failure_is_the_first_error_or_divergence() -> None:
    table = pa.table({"trial": [4, 5, 6], "status": ["ok", "diverged", "error"],
                      "reason": ["", "state beyond 1e4", "plant.mass[0]: must be > 0 kg"]})
    assert ChunkResult(table, 0.0).first_failure() == (5, "diverged: state beyond 1e4")


def test_grid_values_as_stored_in_a_column() -> None:
    assert grid_cell_text(3) == 3.0
    assert grid_cell_text([10, 13]) == "[10.0, 13.0]"
    assert grid_cell_text({"label": "swapped", "track.kp": [1, 2]}) == "swapped"
    assert grid_cell_text({"track.kp": [1, 2]}) == '{"track.kp": [1, 2]}'
    assert grid_cell_text("rk4") == "rk4"


#: Trials that fail in the ways a sweep records: u1(0) drawn around 0 (those started with the
#: wrong sign cross the singular set: diverged), masses scaled by 1 + U(-1.3, 0.3), some to
#: <= 0 kg (error).
FAILING = {
    "plan": {"duration": 1.0, "start": [1.8, 1.0, 0.0], "goal": [1.5, 1.5, 0.0]},
    "track": {"dt": 0.01, "initial": [1.8, 1.0, 0.0], "initial_rate": 0.1},
    "sweep": {"trials": 24, "seed": 5,
              "perturb": {"initial_rate": {"dist": "uniform", "low": -0.2, "high": 0.05},
                          "mass": {"dist": "uniform", "low": -1.3, "high": 0.3,
                                   "relative": True}},
              "grid": {"gains": [{"label": "swapped", "track.kp": [100, 110],
                                  "track.kv": [10, 13]}],
                       "plant.com": [[0.1, 0.1, 0.0]],
                       "track.integrator": ["adaptive", "rk4"]}},
}


def _rows(table: pa.Table, mask: list[bool], column: str) -> pa.Array:
    return pc.filter(table.column(column), pa.array(mask))


def test_not_applicable_is_null_never_nan_and_every_number_has_a_unit() -> None:
    lay = layout(resolve(FAILING))
    for cell in lay.cells:
        table = run_chunk(cell, Chunk(cell.index, cell.index * 24, cell.index * 24 + 24)).table
        status = table.column("status").to_pylist()
        assert {"ok", "diverged", "error"} <= set(status), status
        for field in table.schema:
            if pa.types.is_floating(field.type):
                assert not pc.any(pc.is_nan(table.column(field.name))).as_py(), field.name
            numeric = pa.types.is_floating(field.type) or pa.types.is_list(field.type) or (
                pa.types.is_integer(field.type) and field.name not in ("trial", "cell"))
            if numeric:  # a unit, or "1" for a pure number
                assert field.metadata and field.metadata.get(UNIT_KEY), field.name
        error = [s == "error" for s in status]
        for metric in (*METRIC_NAMES, "event_time"):  # an error trial never ran
            assert _rows(table, error, metric).null_count == sum(error), metric
        diverged = [s == "diverged" for s in status]
        for metric in ("err_theta_final", "err_y_final"):  # it never reached the end
            assert _rows(table, diverged, metric).null_count == sum(diverged)
        times = _rows(table, diverged, "event_time")  # when it stopped
        assert times.null_count == 0 and 0 < pc.min(times).as_py() <= 1.0
        ok = [s == "ok" for s in status]
        assert _rows(table, ok, "event_time").null_count == sum(ok)
        assert _rows(table, ok, "err_theta_final").null_count == 0
        simulated = [s != "error" for s in status]
        no_hit = [s and h == 0 for s, h in zip(simulated, table.column("singular_hits")
                                                .to_pylist(), strict=True)]
        assert _rows(table, no_hit, "first_hit_time").null_count == sum(no_hit)
        assert table.column("peak_torque").null_count == len(status)  # a kinematic plant
        # the adaptive integrator's only, of the trials that reached T (its twin's)
        reached = [s in ("ok", "singular") for s in status]
        estimates = _rows(table, reached, "err_estimate")
        expected_nulls = 0 if cell.spec.track.integrator == "adaptive" else sum(reached)
        assert estimates.null_count == expected_nulls
        assert _rows(table, diverged, "err_estimate").null_count == sum(diverged)
        # verified: reached T with error control and an estimate within track.accuracy
        verified = table.column("verified").to_pylist()
        assert all(not v for v, r in zip(verified, reached, strict=True) if not r)
        if cell.spec.track.integrator == "rk4":
            assert not any(verified)
        # the group's keys as columns of their own, lists as lists
        assert set(table.column("gains").to_pylist()) == {"swapped"}
        assert table.column("track.kp")[0].as_py() == [100.0, 110.0]
        assert table.column("track.kv")[0].as_py() == [10.0, 13.0]
        assert table.column("plant.com")[0].as_py() == [0.1, 0.1, 0.0]
        assert table.schema.field("plant.com").metadata[UNIT_KEY] == b"m"
        assert table.schema.field("track.kp").metadata[UNIT_KEY] == b"1/s^2"


def test_grid_columns_hold_what_each_cell_ran_with() -> None:
    spec = resolve({"sweep": {"perturb": {"initial": {"dist": "normal", "std": 0.1}},
                              "grid": {"sweep.perturb.initial.std": [0.01, 0.2],
                                       "g": [{"label": "a", "track.kp": [1, 2]},
                                             {"track.kv": [3, 4]}],
                                       "track.rate_limit": [5, float("inf")]}}})
    cells = layout(spec).cells
    columns = [grid_columns(c.values, c.spec) for c in cells]
    assert len(columns) == 8 and all(list(c) == list(columns[0]) for c in columns)
    first, last = columns[0], columns[-1]
    assert first["sweep.perturb.initial.std"] == (pa.float64(), 0.01)
    assert first["g"] == (pa.string(), "a")
    assert first["track.kp"] == (pa.list_(pa.float64()), [1.0, 2.0])
    assert first["track.kv"] == (pa.list_(pa.float64()), [100.0, 110.0])  # the spec's own
    assert last["g"] == (pa.string(), '{"track.kv": [3, 4]}')  # no label: its table
    assert last["track.kp"][1] == [10.0, 13.0] and last["track.kv"][1] == [3.0, 4.0]
    assert first["track.rate_limit"] == (pa.float64(), 5.0)
    assert last["track.rate_limit"] == (pa.float64(), float("inf"))  # inf: no limit


def test_a_chunk_of_a_three_joint_robot_perturbs_every_link() -> None:
    """N = 3: four links perturbed, two initial rates, columns named by link and joint; a
    drawn mass <= 0 is an error naming its link; the others run."""
    spec = resolve({
        "robot": {"mass": [2.0, 1.0, 1.0, 0.6], "inertia": [0.08, 0.03, 0.03, 0.2],
                  "length": [0.3, 0.25, 0.25, 0.25], "com": [0.12, 0.1, 0.1, 0.0]},
        "plan": {"start": [0.0, 1.0, 0.3, 0.0], "goal": [0.4, 2.0, 0.6, 0.0],
                 "start_rate": [0.3, 0.3], "goal_rate": 0.5},
        "track": {"initial": [0.0, 1.0, 0.3, 0.0], "kp": [100.0] * 3, "kv": [20.0] * 3,
                  "dt": 0.01},
        "sweep": {"trials": 8, "seed": 5, "perturb": {
            "initial": {"dist": "normal", "std": 0.01},
            "initial_rate": {"dist": "uniform", "low": -0.02, "high": [0.02, 0.0]},
            "mass": {"dist": "uniform", "low": [0, 0, 0, -1.5], "high": [0, 0, 0, 0.2]}}}})
    frame = run_chunk(layout(spec).cells[0], Chunk(0, 0, 8)).table.to_pandas()
    assert {f"initial_{i}" for i in range(4)} <= set(frame.columns)
    assert {"initial_rate_1", "initial_rate_2", "mass_3"} <= set(frame.columns)
    assert "initial_rate" not in frame.columns and "initial_4" not in frame.columns
    assert frame["initial_rate_2"].between(0.3 - 0.02, 0.3).all()  # plan.start_rate + draw
    assert (frame["mass_0"] == 2.0).all()  # a zero-width draw leaves link 0 as it is
    bad = frame["mass_3"] <= 0
    assert bad.any() and (~bad).any()
    assert frame.loc[bad, "reason"].str.startswith("plant.mass[3]: must be > 0 kg").all()
    assert (frame.loc[~bad, "status"] != "error").all()  # simulated (a light link diverges)
    assert frame.loc[frame["status"] == "ok", "err_y_final"].notna().all()


def test_a_grid_of_end_rates_is_a_number_column_or_a_list_column() -> None:
    """plan.goal_rate takes a number or one per inner joint: a grid of numbers stays float64
    (as before N links), a grid holding a list is list<float64> with a number spread over the
    joints, as the spec itself reads it."""
    numbers = resolve({"sweep": {"grid": {"plan.goal_rate": [0.4, 0.6]}}})
    cells = layout(numbers).cells
    assert [grid_columns(c.values, c.spec)["plan.goal_rate"] for c in cells] == [
        (pa.float64(), 0.4), (pa.float64(), 0.6)]
    mixed = resolve({
        "robot": {"mass": [2.0, 1.0, 1.0, 0.6], "inertia": [0.08, 0.03, 0.03, 0.2],
                  "length": [0.3, 0.25, 0.25, 0.25], "com": [0.12, 0.1, 0.1, 0.0]},
        "plan": {"start": [0.0, 1.0, 0.3, 0.0], "goal": [0.4, 2.0, 0.6, 0.0]},
        "track": {"initial": [0.0, 1.0, 0.3, 0.0], "kp": [100.0] * 3, "kv": [20.0] * 3},
        "sweep": {"grid": {"plan.goal_rate": [0.5, [0.4, 0.6]]}}})
    cells = layout(mixed).cells
    assert [grid_columns(c.values, c.spec)["plan.goal_rate"] for c in cells] == [
        (pa.list_(pa.float64()), [0.5, 0.5]), (pa.list_(pa.float64()), [0.4, 0.6])]


def test_verify_counts_a_fraction_rounded_up_or_a_whole_count() -> None:
    assert verify_count(0.0, 1000) == 0
    assert verify_count(0.01, 1000) == 10
    assert verify_count(0.001, 10) == 1  # a fraction checks at least one trial
    assert verify_count(0.5, 3) == 2
    assert verify_count(1.0, 1000) == 1  # from 1 on, a count
    assert verify_count(25.0, 1000) == 25
    assert verify_count(5000.0, 1000) == 1000


def test_sweep_verify_re_runs_the_first_trials_of_each_cell_with_dop853() -> None:
    """sweep.verify = 3: the first three trials of the cell (whatever chunk they fall in) carry
    reference_difference and reference_status; the others null. The referee is scipy's DOP853
    at rtol 1e-10 on the same right-hand side, run apart from the trial: the difference it
    reports is the trial's largest distance from it over the run (about 1e-7 rad at the
    default tolerances; RK4 at dt = 10 ms much larger)."""
    spec = resolve({"plan": FAILING["plan"], "track": {**FAILING["track"], "initial_rate": 0.1},
                    "sweep": {"trials": 6, "seed": 5, "verify": 3,
                              "perturb": {"initial": {"dist": "normal", "std": 0.01}},
                              "grid": {"track.integrator": ["adaptive", "rk4"]}}})
    lay = layout(spec)
    for cell in lay.cells:
        first = cell.first_trial
        tables = [run_chunk(cell, Chunk(cell.index, first + a, first + b)).table
                  for a, b in ((0, 2), (2, 6))]  # the checked trials span two chunks
        difference = [v for t in tables for v in t.column("reference_difference").to_pylist()]
        reference = [v for t in tables for v in t.column("reference_status").to_pylist()]
        status = [v for t in tables for v in t.column("status").to_pylist()]
        assert all(v is not None for v in difference[:3]) and difference[3:] == [None] * 3
        assert reference[:3] == status[:3] and reference[3:] == [None] * 3
        if cell.spec.track.integrator == "adaptive":
            assert max(difference[:3]) < 1e-6
        else:
            assert max(difference[:3]) > 1e-6  # RK4 at dt = 10 ms, which nothing verifies
        for t in tables:
            assert t.schema.field("reference_difference").metadata[UNIT_KEY] == b"rad"
        # trials of ids outside the cell's own (flatcli check's same draws in every cell:
        # ids 0, 1, 2) are never its first: none is re-run
        assert cell.key != 0
        other = run_chunk(cell, Chunk(cell.index, 0, 3)).table
        assert other.column("reference_status").to_pylist() == [None] * 3


#: A capture box (docs/tasks.md, "Task sweeps"): three targets near the paper's robot's
#: (-0.25, 0.05) m with the base at 1 rad at T, plants perturbed in their start and masses.
TASK_SWEEP = {
    "plan": {"duration": 2.0, "start": [1.8, 1.0, 0.0], "start_rate": 0.2, "goal_rate": 0.2},
    "task": {"end_effector": [-0.25, 0.05], "base_attitude": 1.0},
    "track": {"initial": [1.8, 1.0, 0.0], "kp": [100.0, 110.0], "kv": [10.0, 13.0]},
    "sweep": {"trials": 4, "seed": 4,
              "grid": {"task.end_effector": [[-0.26, 0.04], [-0.26, 0.06], [-0.25, 0.05]]},
              "perturb": {"initial": {"dist": "normal", "std": 0.002},
                          "mass": {"dist": "normal", "std": 0.0005}}},
}


def test_a_task_sweep_plans_every_target_and_bounds_the_end_effectors_final_error() -> None:
    """Referees: the links placed in the complex plane (tests/task_referees.py) for the
    plans' ends and for each trial re-run alone (flatcli track of its exact spec, the plant
    with the trial's masses): the true final distance from the target is within the bound."""
    from flatcli.api import track
    from flatcli.experiment import plant_from, robot_from
    from flatcli.montecarlo.rerun import rerun_spec
    from tests import task_referees as ref

    spec = resolve(TASK_SWEEP)
    lay = layout(spec)
    robot = robot_from(spec)
    for cell in lay.cells:  # each cell plans to its own target (they once shared cell 0's)
        plan = cell.scenario.plan
        end = plan.sample(np.array([plan.duration])).theta[-1]
        target = complex(*cell.spec.task.end_effector)
        assert abs(ref.end_effector(robot, end) - target) < 1e-9
        assert abs(end[0] - 1.0) < 1e-9
    checked_trials = 0
    for cell in lay.cells:
        rows = run_chunk(cell, Chunk(cell.index, cell.first_trial, cell.first_trial + 4)
                         ).table.to_pylist()
        for row in rows:
            assert row["status"] == "ok", row["reason"]
            alone = rerun_spec(lay, row)
            run = track(alone)
            theta = run.frame[["theta0", "theta1", "theta2"]].to_numpy()[-1]
            exact = abs(ref.end_effector(plant_from(alone), theta)
                        - complex(*cell.spec.task.end_effector))
            assert run.metrics["err_theta_final"] == row["err_theta_final"]
            assert exact <= row["ee_error_bound"] <= 20 * exact + 1e-4, (exact, row)
            assert row["ee_error_bound"] < 0.3  # the angle-error bound, not its 0.6 m cap
            checked_trials += 1
    assert checked_trials == 12


def test_a_task_sweep_with_ends_at_rest_runs_the_rest_law() -> None:
    """task.rest in a sweep (refused before 2026-12-06, when only flatcli track faded the
    feedback): each trial's row is flatcli track of its exact spec (``rerun_spec``) to the
    bit, and that run's final angles are the referee's (tests/rest_referee.py: the rest law
    by DOP853 at rtol 1e-11 on the full link kinematics, the trial's own plant and start)
    within 1e-6 rad (the adaptive integrator at its default rtol 5e-8)."""
    from flatcli.api import track
    from flatcli.core.controllers.control import Gains
    from flatcli.experiment import plant_from
    from flatcli.montecarlo.rerun import rerun_spec
    from tests.rest_referee import track_rest

    sweep = {k: v for k, v in TASK_SWEEP["sweep"].items() if k != "grid"}
    spec = resolve({**TASK_SWEEP, "task": {**TASK_SWEEP["task"], "rest": True},
                    "sweep": sweep})
    lay = layout(spec)
    (cell,) = lay.cells
    rows = run_chunk(cell, Chunk(0, 0, 4)).table.to_pylist()
    for row in rows:
        assert row["status"] == "ok", row["reason"]
        alone = rerun_spec(lay, row)
        run = track(alone)
        assert run.metrics["err_theta_final"] == row["err_theta_final"]
        theta = run.frame[["theta0", "theta1", "theta2"]].to_numpy()
        referee = track_rest(run.run.plan, Gains(alone.track.kp, alone.track.kv),
                             plant_from(alone), np.asarray(alone.track.initial),
                             run.run.scenario.times, alone.task.fade, alone.plant.momentum)
        assert referee.finished
        assert np.max(np.abs(theta[-1] - referee.theta[-1])) < 1e-6


#: A box of capture points: each trial draws its own target within 2 cm of the nominal one
#: (one corner out of reach: 0.3 m is the virtual manipulator's reach), and the start.
BOX_SWEEP = {
    **TASK_SWEEP,
    "sweep": {"trials": 10, "seed": 5,
              "perturb": {"initial": {"dist": "normal", "std": 0.002},
                          "end_effector": {"dist": "uniform", "low": [-0.02, -0.02],
                                           "high": [0.02, 0.02]}}},
}


def test_each_trial_of_a_box_sweep_plans_and_reaches_its_own_target() -> None:
    """sweep.perturb.end_effector: every trial plans its own task to its drawn target.
    Referees: the links placed in the complex plane (tests/task_referees.py) at each trial's
    final angles from flatcli track of its exact spec (``rerun_spec``, which takes the drawn
    target from the row): that re-run gives the same metrics to the bit, its true distance
    from the trial's own target is within the row's bound, and the targets are the uniform
    draws of the trial's stream (nominal + low + (high - low) u)."""
    from flatcli.api import track
    from flatcli.experiment import STREAM_PERTURB, plant_from
    from flatcli.montecarlo.draws import perturb_slots
    from flatcli.montecarlo.rerun import rerun_spec
    from flatcli.montecarlo.streams import uniform_variates
    from tests import task_referees as ref

    spec = resolve(BOX_SWEEP)
    lay = layout(spec)
    (cell,) = lay.cells
    rows = run_chunk(cell, Chunk(0, 0, 6)).table.to_pylist()
    slots = list(perturb_slots(2)["end_effector"])
    u = uniform_variates(5, list(range(6)), STREAM_PERTURB, len(
        [s for v in perturb_slots(2).values() for s in v]))[:, slots]
    nominal = np.array(TASK_SWEEP["task"]["end_effector"])
    targets = set()
    for row, draw in zip(rows, u, strict=True):
        target = np.array([row["end_effector_0"], row["end_effector_1"]])
        np.testing.assert_array_equal(target, nominal + (-0.02 + 0.04 * draw))
        targets.add(tuple(target))
        assert row["status"] == "ok", row["reason"]
        alone = rerun_spec(lay, row)
        assert list(alone.task.end_effector) == list(target)
        run = track(alone)
        for metric in ("err_theta_final", "err_theta_rms", "steps", "min_margin"):
            assert run.metrics[metric] == row[metric], metric
        theta = run.frame[["theta0", "theta1", "theta2"]].to_numpy()[-1]
        exact = abs(ref.end_effector(plant_from(alone), theta) - complex(*target))
        assert exact <= row["ee_error_bound"] <= 20 * exact + 1e-4, (exact, row)
    assert len(targets) == len(rows)  # a target per trial, not the cell's


def test_a_box_sweep_records_a_target_it_cannot_plan_and_goes_on() -> None:
    """A drawn target out of reach is an error trial with the planner's one-line reason; the
    others run. Reference: |target| > 0.3 m, the virtual manipulator's reach (sum |v_a| of
    the paper's robot: 1/30 + 0.1 + 0.2 m)."""
    far = {**BOX_SWEEP, "sweep": {**BOX_SWEEP["sweep"], "perturb": {
        "end_effector": {"dist": "uniform", "low": [-0.15, -0.15], "high": [0.15, 0.15]}}}}
    lay = layout(resolve(far))
    rows = run_chunk(lay.cells[0], Chunk(0, 0, 10)).table.to_pylist()
    out = [r for r in rows if np.hypot(r["end_effector_0"], r["end_effector_1"]) > 0.3 + 1e-9]
    assert out and len(out) < len(rows)
    for row in out:
        assert row["status"] == "error"
        assert row["reason"].startswith("task.end_effector: [") and "unreachable" in row["reason"]
        assert row["ee_error_bound"] is None
    assert any(r["status"] == "ok" for r in rows)


def test_a_target_perturbation_needs_a_target() -> None:
    spec = {k: v for k, v in BOX_SWEEP.items() if k != "task"}
    with pytest.raises(SpecError, match=r"sweep\.perturb\.end_effector: needs task\.end_effector"):
        resolve(spec)
