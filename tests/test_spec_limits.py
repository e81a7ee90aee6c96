"""Resource limits (flatcli/spec/limits.py): requests over the memory or time budget are
refused before any work, with the estimate and the key to change; requests that fit pass."""

from __future__ import annotations

import math

import pytest

from flatcli.spec import SpecError, resolve
from flatcli.spec.limits import (
    BYTES_PER_PLAN_SAMPLE,
    BYTES_PER_TRACK_STEP,
    SECONDS_PER_STEP,
    check_sweep,
    check_workers,
    cores,
    memory_budget,
    time_budget,
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
        ({"sweep": {"grid": {"plan.samples": list(range(10, 10010)),
                             "track.kp": [[i, 1] for i in range(1, 1001)]}}},
         r"sweep\.grid of 1e\+07 cells would need about .* use fewer grid values"),
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
