"""Resource limits (flatcli/spec/limits.py): requests over the memory or time budget are
refused before any work, with the estimate and the key to change; requests that fit pass."""

from __future__ import annotations

import math

import pytest

from flatcli.spec import SpecError, limits, resolve
from flatcli.spec.limits import (
    BYTES_PER_CHUNK_TRIAL,
    BYTES_PER_PLAN_SAMPLE,
    BYTES_PER_TRACK_STEP,
    BYTES_PER_WORKER,
    ID_STRIDE,
    MAX_JOINTS,
    MIN_RTOL,
    SECONDS_PER_ATTEMPT,
    SECONDS_PER_CHAIN_SAMPLE,
    SECONDS_PER_STEP,
    check_sweep,
    check_track,
    check_workers,
    cores,
    memory_budget,
    plan_sample_bytes,
    plan_seconds,
    time_budget,
    track_seconds,
    track_step_bytes,
)


@pytest.fixture(autouse=True)
def budgets(monkeypatch: pytest.MonkeyPatch) -> None:
    """Budgets that do not depend on the machine the tests run on: 4 GiB, 30 days."""
    monkeypatch.setenv("FLATCLI_MEMORY_BUDGET", "4G")
    monkeypatch.setenv("FLATCLI_TIME_BUDGET", "30d")


@pytest.mark.parametrize(
    ("tree", "message"),
    [
        ({"plan": {"samples": 10**9}},
         r"plan\.samples = 1000000000 would need about 279 GiB of memory, more than the 4 GiB "
         r"budget .*lower plan\.samples"),
        ({"track": {"dt": 1e-9}}, r"2e\+09 output steps would need about 1\.46 TiB .*raise "
                                  r"track\.dt or lower plan\.duration"),
        ({"plan": {"duration": 1e6}}, r"1e\+09 output steps would need .*plan\.duration"),
        ({"sweep": {"trials": 10**12}}, r"sweep\.trials: at most 1e\+09 trials per cell"),
        ({"sweep": {"trials": 10**9}}, r"1e\+09 trials \(1000000000 x 1 cells\) would need about "
                                       r"186 GiB .*lower sweep\.trials"),
        ({"sweep": {"trials": 10**7, "grid": {"track.kp": [[1, 1], [2, 2], [3, 3]]}}},
         r"3e\+07 trials \(10000000 x 3 cells\) would need about 5\.59 GiB"),
        ({"track": {"dt": 1e-5}, "sweep": {"grid": {"plan.samples": list(range(10, 110)),
                                                    "track.kp": [[i, 1] for i in range(1, 101)]}}},
         r"sweep\.grid of 1e\+04 cells would need about .* use fewer grid values"),
        ({"plan": {"basis": "bspline", "size": 10**6}}, r"a flat-output basis of 1000000 terms"),
        ({"plan": {"degree": 10**6}}, r"a flat-output basis of 1000001 terms .*plan\.degree"),
        ({"plan": {"start_rate": 1e14}}, r"plan: th1 may sweep up to 2e\+14 rad .*at most 1e\+05"),
    ],
)
def test_requests_over_budget_are_refused_with_the_estimate_and_the_key(
    tree: dict[str, object], message: str
) -> None:
    with pytest.raises(SpecError, match=message):
        resolve(tree)


def test_a_sweep_over_the_time_budget_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLATCLI_TIME_BUDGET", "1h")
    resolve({"track": {"dt": 1e-5}, "sweep": {"trials": 10**4}})
    with pytest.raises(SpecError, match=r"1e\+06 trials of 2e\+05 output steps on \d+ cores "
                                        r"would take at least .* h, more than the 1 h budget"):
        resolve({"track": {"dt": 1e-5}, "sweep": {"trials": 10**6}})


def test_the_estimates_are_the_measured_rates() -> None:
    # plan.samples: refused just above budget / rate, accepted below it
    fits = int(4 * 2**30 / BYTES_PER_PLAN_SAMPLE)
    resolve({"plan": {"samples": fits - 1}})
    with pytest.raises(SpecError, match=r"plan\.samples"):
        resolve({"plan": {"samples": fits + 1000}})
    # output steps: duration / dt, at BYTES_PER_TRACK_STEP each
    steps = 4 * 2**30 / BYTES_PER_TRACK_STEP
    resolve({"plan": {"duration": 2.0}, "track": {"dt": 2.0 / 4e6}})  # 4e6 steps fit
    assert steps < 1e7
    with pytest.raises(SpecError, match="output steps"):
        resolve({"plan": {"duration": 2.0}, "track": {"dt": 2.0 / 1e7}})


def test_a_big_but_ordinary_study_fits() -> None:
    # the "ordinary-looking sweep", and the paper's study scaled to 10^5 trials a cell
    resolve({"track": {"dt": 1e-5, "sensor_noise": 1e-3}, "sweep": {"trials": 1000}})
    resolve({"sweep": {"trials": 100_000, "grid": {
        "track.sensor_noise": [0.0, 0.001, 0.01], "track.kp": [[10, 13], [100, 110]]}}})


def test_time_of_the_exact_cells_on_the_given_workers(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLATCLI_TIME_BUDGET", "1h")
    per_cell = 1e5 * (2e5 * SECONDS_PER_STEP + 1e-5)  # 1e5 trials of 2e5 steps, at best
    assert per_cell < 3600 < 40 * per_cell
    check_sweep([2e5], 10**5, 1000, 1)
    with pytest.raises(SpecError, match=r"4e\+06 trials on 1 workers would take at least "
                                        r".* use more --workers"):
        check_sweep([2e5] * 40, 10**5, 1000, 1)
    check_sweep([2e5] * 40, 10**5, 1000, 20)  # the same cells on 20 workers fit


def test_workers_beyond_the_cores_or_the_memory_are_refused() -> None:
    check_workers(cores(), oversubscribe=False)
    with pytest.raises(SpecError, match=rf"--workers {cores() + 1}: more than the {cores()} "
                                        r"cores .* add --oversubscribe"):
        check_workers(cores() + 1, oversubscribe=False)
    check_workers(cores() + 1, oversubscribe=True)
    with pytest.raises(SpecError, match="must be >= 1"):
        check_workers(0, oversubscribe=True)
    with pytest.raises(SpecError, match=r"--workers 100000 would need about 9\.\d+ TiB"):
        check_sweep([2000.0], 100, 100, 100_000)


def test_budgets_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    assert memory_budget() == 4 * 2**30
    assert time_budget() == 30 * 86400
    monkeypatch.setenv("FLATCLI_MEMORY_BUDGET", "512M")
    monkeypatch.setenv("FLATCLI_TIME_BUDGET", "90")
    assert (memory_budget(), time_budget()) == (512 * 2**20, 90.0)
    monkeypatch.setenv("FLATCLI_MEMORY_BUDGET", "lots")
    with pytest.raises(SpecError, match="FLATCLI_MEMORY_BUDGET: expected a positive number"):
        memory_budget()
    monkeypatch.delenv("FLATCLI_MEMORY_BUDGET")
    assert 0 < memory_budget() < math.inf


def chain(joints: int) -> dict[str, object]:
    """A spec tree of a robot of ``joints`` joints (the chain family of benchmarks/chains.py:
    a heavy base, equal links, the last counterweighted onto its joint)."""
    n = joints
    return {"robot": {"mass": [3.0] + [1.0] * (n - 1) + [0.5],
                      "inertia": [0.2] + [0.0533] * (n - 1) + [0.15],
                      "length": [0.3] + [0.2] * n, "com": [0.1] * n + [0.0]},
            "plan": {"start": [0.0, 1.0] + [0.3] * (n - 2) + [0.0],
                     "goal": [-1.05, 2.0] + [0.6] * (n - 2) + [0.0],
                     "start_rate": 0.3, "goal_rate": 0.5},
            "track": {"initial": [0.02, 0.98] + [0.3] * (n - 2) + [0.0],
                      "kp": [25.0] * n, "kv": [10.0] * n}}


def test_sweep_trials_fill_the_id_space_of_a_cell_and_no_more(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # budgets that admit 1e9 trials, so that only the id space decides
    monkeypatch.setenv("FLATCLI_MEMORY_BUDGET", "1000T")
    monkeypatch.setenv("FLATCLI_TIME_BUDGET", "1000000d")
    resolve({"sweep": {"trials": ID_STRIDE, "chunk": 1000}})  # ids i = 0 .. 1e9 - 1: its own
    for trials in (ID_STRIDE + 1, ID_STRIDE + 2):
        with pytest.raises(SpecError, match=rf"sweep\.trials: at most 1e\+09 trials per cell .*"
                                            rf"got {trials}"):
            resolve({"sweep": {"trials": trials, "chunk": 1000}})


def test_the_chunks_in_flight_are_counted_on_every_worker(monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    monkeypatch.setattr(limits, "cores", lambda: 4)
    monkeypatch.setenv("FLATCLI_MEMORY_BUDGET", "1G")
    chunk = 500_000  # two chunks in flight: 0.47 GiB on one worker, 1.9 GiB on four
    assert 2 * chunk * BYTES_PER_CHUNK_TRIAL < 2**30 < 8 * chunk * BYTES_PER_CHUNK_TRIAL
    with pytest.raises(SpecError, match=r"sweep\.chunk = 500000 trials on 4 workers would need "
                                        r"about 1\.86 GiB .* lower sweep\.chunk"):
        resolve({"sweep": {"trials": chunk, "chunk": chunk}})
    resolve({"sweep": {"trials": chunk, "chunk": chunk // 4}})
    # the exact layout on the given workers: the same rows per worker, times the workers
    per_worker = BYTES_PER_WORKER + 2 * 100_000 * BYTES_PER_CHUNK_TRIAL
    monkeypatch.setenv("FLATCLI_MEMORY_BUDGET", str(int(2.5 * per_worker)))
    check_sweep([0.0], 10**5, 100_000, 2)
    with pytest.raises(SpecError, match=r"--workers 3 would need"):
        check_sweep([0.0], 10**5, 100_000, 3)


def test_a_relative_tolerance_float64_cannot_meet_is_refused() -> None:
    with pytest.raises(SpecError, match=r"track\.rtol: must be >= 2\.22045e-14, got 1e-15"):
        resolve({"track": {"rtol": 1e-15}})
    with pytest.raises(SpecError, match=r"track\.rtol: must be >= 2\.22045e-14, got 2\.2e-14"):
        resolve({"track": {"rtol": 2.2e-14}})
    assert resolve({"track": {"rtol": MIN_RTOL}}).track.rtol == MIN_RTOL
    with pytest.raises(SpecError, match=r"sweep\.grid cell|track\.rtol"):
        resolve({"sweep": {"grid": {"track.rtol": [1e-8, 1e-20]}}})


def test_the_step_budget_of_one_trial_is_in_the_time_estimate(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLATCLI_TIME_BUDGET", "1h")
    fits = int(3600 / SECONDS_PER_ATTEMPT)
    resolve({"track": {"max_steps": fits}})
    with pytest.raises(SpecError, match=r"track\.max_steps = 7\.2e\+09 attempted steps \(one "
                                        r"trial that cannot meet track\.rtol spends them all\) "
                                        r"would take at least 1 h.*lower track\.max_steps"):
        resolve({"track": {"max_steps": fits + 1000}})
    resolve({"track": {"max_steps": 10 * fits, "integrator": "rk4"}})  # no step control


def test_a_robot_of_more_joints_than_flatcli_takes_is_refused_before_its_check() -> None:
    resolve(chain(MAX_JOINTS))
    with pytest.raises(SpecError, match=rf"robot\.mass: {MAX_JOINTS + 2} links \("
                                        rf"{MAX_JOINTS + 1} joints\), more than the "
                                        rf"{MAX_JOINTS + 1} links \({MAX_JOINTS} joints\)"):
        resolve(chain(MAX_JOINTS + 1))
    # 3000 joints: refused at once, before the O(N^3) check would take hours
    with pytest.raises(SpecError, match=r"about \d.* h here.*at least \d.* days"):
        resolve(chain(3000))


def test_plan_and_track_time_grow_as_n_to_the_fourth(monkeypatch: pytest.MonkeyPatch) -> None:
    assert plan_seconds(2) == 0.0  # the paper's closed-form maps
    assert plan_seconds(20) == pytest.approx(16 * plan_seconds(10))
    spec = resolve(chain(30))
    steps = 2.0 / 1e-3
    assert track_seconds(spec) >= SECONDS_PER_CHAIN_SAMPLE * 30**4 * (steps + 1)
    monkeypatch.setenv("FLATCLI_TIME_BUDGET", "60")
    check_track(spec)  # at least 8 s
    monkeypatch.setenv("FLATCLI_TIME_BUDGET", "5")
    with pytest.raises(SpecError, match=r"tracking a robot of 30 joints over 2e\+03 output "
                                        r"steps .* would take at least 8\.\d+ s, more than the "
                                        r"5 s budget .*use fewer links"):
        check_track(spec)


def test_memory_per_row_grows_with_the_columns_of_n_joints() -> None:
    assert plan_sample_bytes(2) == BYTES_PER_PLAN_SAMPLE
    assert track_step_bytes(2) == BYTES_PER_TRACK_STEP
    assert plan_sample_bytes(10) == pytest.approx(BYTES_PER_PLAN_SAMPLE * 65 / 17)
    assert track_step_bytes(10) == pytest.approx(BYTES_PER_TRACK_STEP * 76 / 20)


def test_the_as_built_laws_design_is_priced_by_its_bandwidth() -> None:
    """track.lqr_bandwidth = 1e12 rad/s failed after 38 s naming track.lqr_terminal: the
    Riccati equation takes about 0.8 b T steps of at least a millisecond
    (tests/test_lqr.py checks the steps), so it is refused at once, naming the key."""
    as_built = {"robot.com": [0.1, 0.1, 0.003], "track.controller": "asbuilt"}
    with pytest.raises(SpecError, match=r"^track\.lqr_bandwidth = 1e\+12 rad/s .* would take "
                                        r"at least .* years.*lower track\.lqr_bandwidth"):
        resolve({}, {**as_built, "track.lqr_bandwidth": 1e12})
    spec = resolve({}, {**as_built, "track.lqr_bandwidth": 50.0})  # fits
    assert limits.riccati_seconds(spec) == pytest.approx(0.8 * 50 * 2.0 * 1e-3)
    assert track_seconds(spec) >= limits.riccati_seconds(spec)
    # the flat law designs nothing: its bandwidth key is not priced
    assert limits.riccati_seconds(resolve({}, {"track.lqr_bandwidth": 1e12})) == 0.0


def test_grid_cells_and_obstacles_are_bounded_before_any_work() -> None:
    """A grid of 10^4+ cells was checked and planned cell by cell before any limit (minutes,
    silently), 8x10^4 discs proven for 5 min at 2.4 GB: both are refused from the spec, in
    one line naming the key and the limit."""
    values = [0.5 + 1e-4 * i for i in range(101)]
    gains = [[100.0 + i, 110.0] for i in range(100)]
    with pytest.raises(SpecError, match=r"^sweep\.grid: 1\.01e\+04 cells \(101 x 100\), more "
                                        rf"than the {limits.MAX_GRID_CELLS} "):
        resolve({"sweep": {"grid": {"plan.goal_rate": values, "track.kp": gains}}})
    resolve({"sweep": {"grid": {"plan.goal_rate": values[:100], "track.kp": gains}}})  # 10^4
    far = [[2.0 + 0.01 * i, 0.0, 0.001] for i in range(limits.MAX_OBSTACLES + 1)]
    with pytest.raises(SpecError, match=rf"^task\.obstacles: {limits.MAX_OBSTACLES + 1} discs, "
                                        rf"more than the {limits.MAX_OBSTACLES} "):
        resolve({"task": {"end_effector": [-0.25, 0.05], "obstacles": far}})
    resolve({"task": {"end_effector": [-0.25, 0.05], "obstacles": far[:-1]}})
