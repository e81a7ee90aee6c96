"""Per-trial random draws (flatcli/sweep/draws.py)."""

from __future__ import annotations

import numpy as np
from scipy.special import ndtri

from flatcli.experiment import plan_from
from flatcli.spec import perturbations, resolve
from flatcli.sweep import N_VARIATES, PERTURB_SLOTS, draw_perturbations, nominal_values
from flatcli.sweep.draws import (
    invalid_plants,
    invalid_servos,
    perturb_slots,
    perturbation_columns,
    variates,
)


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
    assert len(PERTURB_SLOTS) == 9


def test_slots_are_fixed_positions_per_component() -> None:
    # the layout every sweep written so far drew with: changing it changes every trial
    assert PERTURB_SLOTS == {"initial": (0, 1, 2), "initial_rate": (3,), "mass": (4, 5, 6),
                             "inertia": (7, 8, 9), "length": (10, 11, 12),
                             "com": (13, 14, 15), "momentum": (16,),
                             "servo_bandwidth": (17,), "torque_limit": (18,)}
    assert N_VARIATES == 19


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
    assert variates(4) == 31 == 4 * 5 + 5 + 3 + 3
    assert perturbation_columns("initial_rate", 4) == ["initial_rate_1", "initial_rate_2",
                                                       "initial_rate_3"]
    assert perturbation_columns("initial_rate") == ["initial_rate"]
    assert perturbation_columns("length", 4)[-1] == "length_4"
