"""Per-trial random draws (flatcli/montecarlo/draws.py)."""

from __future__ import annotations

from statistics import NormalDist

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.special import ndtri

from flatcli.experiment import plan_from
from flatcli.montecarlo import (
    N_VARIATES,
    PERTURB_SLOTS,
    draw_perturbations,
    layout,
    nominal_values,
    run_chunk,
)
from flatcli.montecarlo.draws import (
    invalid_plants,
    invalid_servos,
    perturb_slots,
    perturbation_columns,
    variates,
)
from flatcli.spec import perturbations, resolve


def test_perturbation_draws_are_independent_of_each_other_and_well_distributed() -> None:
    base = {"initial": {"dist": "normal", "std": 0.1},
            "mass": {"dist": "uniform", "low": -0.2, "high": 0.1, "relative": True}}
    spec = resolve({"sweep": {"perturb": base}})
    nominal = nominal_values(spec, plan_from(spec))
    ids = list(range(4000))
    drawn = perturbations(spec.sweep)
    both = draw_perturbations(drawn, nominal, 5, ids)
    alone = draw_perturbations({"mass": drawn["mass"]}, nominal, 5, ids)
    np.testing.assert_array_equal(both["mass"], alone["mass"])
    # relative uniform: m (1 + U(-0.2, 0.1)) with m = 1
    assert both["mass"].min() >= 0.8 and both["mass"].max() <= 1.1
    assert abs(both["mass"].mean() - 0.95) < 0.01  # mean of U(0.8, 1.1); 3 sigma ~ 0.008
    # normal: initial + N(0, 0.1^2) per component
    deviation = both["initial"] - nominal["initial"]
    assert np.allclose(deviation.std(axis=0), 0.1, rtol=0.05)
    assert np.allclose(deviation.mean(axis=0), 0.0, atol=0.006)
    # the draw of a trial depends on its id only
    again = draw_perturbations(drawn, nominal, 5, [17, 3])
    np.testing.assert_array_equal(again["initial"], both["initial"][[17, 3]])
    assert len(PERTURB_SLOTS) == 10


def test_slots_are_fixed_positions_per_component() -> None:
    # the layout every sweep written so far drew with: changing it changes every trial
    assert PERTURB_SLOTS == {"initial": (0, 1, 2), "initial_rate": (3,), "mass": (4, 5, 6),
                             "inertia": (7, 8, 9), "length": (10, 11, 12),
                             "com": (13, 14, 15), "momentum": (16,),
                             "servo_bandwidth": (17,), "torque_limit": (18,),
                             "end_effector": (19, 20)}
    assert N_VARIATES == 21


def test_the_servo_slots_leave_every_earlier_draw_unchanged() -> None:
    """Before the servo targets existed a trial drew 17 variates; now 19. The first 17 are
    numpy's same numbers (a Generator fills random(n) in order), so every perturbation a sweep
    drew before draws the same value now: checked against numpy directly."""
    spec = resolve({"sweep": {"perturb": {
        "mass": {"dist": "uniform", "low": -0.1, "high": 0.1, "relative": True},
        "momentum": {"dist": "normal", "std": 1e-3},
        "servo_bandwidth": {"dist": "uniform", "low": 10.0, "high": 20.0}}}})
    nominal = nominal_values(spec, plan_from(spec))
    drawn = draw_perturbations(perturbations(spec.sweep), nominal, 2003, [0, 5, 999])
    for row, trial in enumerate([0, 5, 999]):
        seq = np.random.SeedSequence(2003, spawn_key=(trial, 0))
        old = np.random.default_rng(seq).random(17)  # what the 17-variate layout drew
        np.testing.assert_array_equal(drawn["mass"][row], 1.0 * (1 + (-0.1 + 0.2 * old[4:7])))
        np.testing.assert_array_equal(drawn["momentum"][row], 1e-3 * ndtri(old[16]))
        u = np.random.default_rng(seq).random(19)[17]
        np.testing.assert_array_equal(drawn["servo_bandwidth"][row], 100.0 + (10.0 + 10.0 * u))


def test_an_invalid_servo_gets_the_message_of_its_spec_key() -> None:
    servo = np.array([[100.0, np.inf], [-5.0, 1.0], [10.0, -0.5], [np.nan, 1.0]])
    assert invalid_servos(servo) == [
        "",
        "plant.servo_bandwidth: must be > 0 rad/s, got -5",
        "plant.torque_limit: must be >= 0 N m, got -0.5",
        "plant.servo_bandwidth: expected a finite number [rad/s], got nan",
    ]


def test_an_invalid_plant_gets_the_message_of_its_spec_key() -> None:
    good = np.array([1.0, 1, 1, 0.05, 0.05, 0.05, 0.2, 0.2, 0.2, 0.1, 0.1, 0.0])
    links = np.stack([good, good, good, good])
    links[1, 2] = -0.25  # mass[2]
    links[2, 7] = 0.0  # length[1]
    links[3, 10] = np.nan  # com[1]
    assert invalid_plants(links) == [
        "",
        "plant.mass[2]: must be > 0 kg, got -0.25",
        "plant.length[1]: must be > 0 m, got 0",
        "plant.com[1]: expected a finite number [m], got nan",
    ]


def test_a_robot_of_n_joints_lays_out_its_own_variates() -> None:
    """The README's rule for N joints: the quantities in order, N + 1 per link quantity,
    N - 1 initial rates; for N = 2 it is PERTURB_SLOTS."""
    assert perturb_slots(2) == PERTURB_SLOTS and variates(2) == N_VARIATES
    slots = perturb_slots(4)
    assert slots["initial"] == (0, 1, 2, 3, 4) and slots["initial_rate"] == (5, 6, 7)
    assert slots["mass"] == (8, 9, 10, 11, 12) and slots["com"] == (23, 24, 25, 26, 27)
    assert slots["momentum"] == (28,) and slots["torque_limit"] == (30,)
    assert slots["end_effector"] == (31, 32)  # two coordinates whatever N
    assert variates(4) == 33 == 4 * 5 + 5 + 3 + 3 + 2
    assert perturbation_columns("initial_rate", 4) == ["initial_rate_1", "initial_rate_2",
                                                       "initial_rate_3"]
    assert perturbation_columns("initial_rate") == ["initial_rate"]
    assert perturbation_columns("length", 4)[-1] == "length_4"


def numpy_uniforms(seed: int, trial: int) -> NDArray[np.float64]:
    """The README's contract, computed here with numpy alone: trial ``trial``'s 21 uniform
    variates (a robot of N = 2 joints) come from default_rng(SeedSequence(seed,
    spawn_key=(trial, 0)))."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(trial, 0))).random(21)


def test_perturbation_draws_are_numpys_stream_of_each_trial() -> None:
    perturb = {
        "initial": {"dist": "normal", "std": [0.05, 0.02, 0.01], "mean": 0.003},
        "initial_rate": {"dist": "uniform", "low": -0.02, "high": 0.03},
        "mass": {"dist": "uniform", "low": -0.05, "high": 0.05, "relative": True},
        "length": {"dist": "normal", "std": 0.001},
        "momentum": {"dist": "normal", "std": 1e-3},
    }
    spec = resolve({"sweep": {"perturb": perturb}})
    nominal = nominal_values(spec, plan_from(spec))
    seed = 2003
    ids = [0, 1, 7, 10**9 + 3, 4_294_967_295 * 10**9 + 999_999_999]  # up to the largest id
    drawn = draw_perturbations(perturbations(spec.sweep), nominal, seed, ids)
    inverse = NormalDist().inv_cdf  # the standard library's, not scipy's ndtri
    for row, trial in enumerate(ids):
        u = numpy_uniforms(seed, trial)
        # README: slots initial 0-2, initial_rate 3, mass 4-6, length 10-12, momentum 16
        expected_initial = nominal["initial"] + 0.003 + np.array(
            [0.05, 0.02, 0.01]) * np.array([inverse(u[j]) for j in (0, 1, 2)])
        np.testing.assert_allclose(drawn["initial"][row], expected_initial, rtol=1e-13)
        assert drawn["initial_rate"][row, 0] == nominal["initial_rate"][0] + (
            -0.02 + (0.03 - -0.02) * u[3])
        np.testing.assert_array_equal(drawn["mass"][row],
                                      nominal["mass"] * (1 + (-0.05 + 0.1 * u[4:7])))
        np.testing.assert_allclose(drawn["length"][row], nominal["length"] + 0.001 * np.array(
            [inverse(u[j]) for j in (10, 11, 12)]), rtol=1e-13)
        assert drawn["momentum"][row, 0] == pytest.approx(1e-3 * inverse(u[16]), rel=1e-12)


def test_a_sweeps_trials_carry_the_draws_of_their_ids() -> None:
    spec = resolve({"track": {"dt": 0.004}, "sweep": {"trials": 3, "seed": 5, "perturb": {
        "initial_rate": {"dist": "uniform", "low": -0.01, "high": 0.02}},
        "grid": {"track.sensor_noise": [0.0, 0.001]}}})
    lay = layout(spec)
    for chunk in lay.chunks():
        cell = lay.cells[chunk.cell]
        rate = nominal_values(cell.spec, cell.scenario.plan)["initial_rate"][0]  # ~0.1
        frame = run_chunk(cell, chunk).table.to_pandas()
        assert len(frame) == 3
        for trial, value in zip(frame["trial"], frame["initial_rate"], strict=True):
            # README: low + (high - low) u, added to the plan's own th1'(0)
            assert value == rate + (-0.01 + (0.02 - -0.01) * numpy_uniforms(5, int(trial))[3])


@pytest.mark.parametrize(
    ("name", "table", "reason"),
    [
        ("inertia", {"dist": "uniform", "low": -1.0, "high": -1.0, "relative": True},
         r"^plant\.inertia\[0\]: must be > 0 kg m\^2, got 0$"),
        ("inertia", {"dist": "uniform", "low": -0.5, "high": -0.4},
         r"^plant\.inertia\[0\]: must be > 0 kg m\^2, got -0\.\d+$"),
        ("length", {"dist": "uniform", "low": -1.0, "high": -1.0, "relative": True},
         r"^plant\.length\[0\]: must be > 0 m, got 0$"),
        ("length", {"dist": "uniform", "low": -2.5, "high": -1.5, "relative": True},
         r"^plant\.length\[0\]: must be > 0 m, got -0\.\d+$"),
    ],
)
def test_zero_or_negative_perturbed_inertia_or_length_is_an_error_trial(
        name: str, table: dict[str, object], reason: str) -> None:
    spec = resolve({"track": {"dt": 0.004}, "sweep": {"trials": 4, "perturb": {name: table}}})
    lay = layout(spec)
    frame = run_chunk(lay.cells[0], next(lay.chunks())).table.to_pandas()
    assert (frame["status"] == "error").all()
    assert frame["reason"].str.match(reason).all(), frame["reason"].tolist()
    assert frame["err_y_rms"].isna().all()


def test_a_zero_std_is_accepted_and_draws_the_nominal_values() -> None:
    spec = resolve({"track": {"dt": 0.004}, "sweep": {"trials": 4, "perturb": {
        "initial": {"dist": "normal", "std": 0.0},
        "mass": {"dist": "normal", "std": [0.0, 0.0, 0.0], "relative": True}}}})
    lay = layout(spec)
    frame = run_chunk(lay.cells[0], next(lay.chunks())).table.to_pandas()
    assert (frame[["initial_0", "initial_1", "initial_2"]].to_numpy()
            == np.array(spec.track.initial)).all()
    assert (frame[["mass_0", "mass_1", "mass_2"]].to_numpy() == 1.0).all()
    assert (frame["status"] != "error").all()
    assert frame["err_y_rms"].nunique() == 1  # identical trials


@pytest.mark.parametrize("seed", [0, 2003, 2**32 + 5, 2**70 + 3])
def test_a_chunks_variates_are_numpys_streams_bit_for_bit(seed: int) -> None:
    """flatcli.montecarlo.streams against the referee it replaces: numpy's own
    default_rng(SeedSequence(seed, spawn_key=(trial, slot))).random(count), one trial at a
    time; trial ids of one and of two 32-bit words, both slots, any count."""
    from flatcli.experiment import trial_stream
    from flatcli.montecarlo.streams import uniform_variates

    trials = [0, 1, 2, 99, 2**32 - 1, 2**33 + 7, 12_345_678_901_234, 2**63 - 1]
    for slot, count in ((0, 21), (1, 3), (0, 1)):
        ours = uniform_variates(seed, trials, slot, count)
        theirs = np.array([trial_stream(seed, t, slot).random(count) for t in trials])
        assert ours.shape == (len(trials), count)
        assert np.array_equal(ours, theirs), (slot, count)
    assert uniform_variates(seed, [], 0, 5).shape == (0, 5)
