"""Rules of [sweep.perturb] and [sweep.grid] (flatcli/spec/sweeps.py)."""

from __future__ import annotations

import math

import pytest

from flatcli.spec import Perturbation, SpecError, perturbation, perturbations, resolve
from flatcli.spec.sweeps import grid_overrides, is_perturbation_param, size


def test_a_perturbation_becomes_a_record_of_floats() -> None:
    assert perturbation("mass", {"dist": "uniform", "low": -1, "high": [0, 0, 1],
                                 "relative": True}) == Perturbation(
        "uniform", low=-1.0, high=(0.0, 0.0, 1.0), relative=True)
    assert perturbation("momentum", {"dist": "normal", "std": 2}) == Perturbation("normal", std=2.0)


def test_sizes_follow_the_perturbed_keys() -> None:
    assert size("initial") == 3 and size("initial_rate") == 1 and size("com") == 3
    with pytest.raises(SpecError, match=r"com\.low: expected a number or 3 numbers"):
        perturbation("com", {"dist": "uniform", "low": [0, 0], "high": 1})


def test_perturbations_of_a_spec_in_canonical_order() -> None:
    spec = resolve({"sweep": {"perturb": {"momentum": {"dist": "normal", "std": 1.0},
                                          "initial": {"dist": "normal", "std": 0.1}}}})
    assert list(perturbations(spec.sweep)) == ["initial", "momentum"]


def test_grid_values_are_checked_like_the_key_they_set() -> None:
    with pytest.raises(SpecError) as grid:
        resolve({"sweep": {"grid": {"plant.mass": [[1, 0, 1]]}}})
    with pytest.raises(SpecError) as direct:
        resolve({"plant": {"mass": [1, 0, 1]}})
    assert str(grid.value).endswith(str(direct.value))


def test_a_grid_group_sets_its_keys_and_a_cell_can_set_a_perturbation_parameter() -> None:
    group = {"label": "swapped", "track.kp": [100, 110]}
    assert grid_overrides("gains", group) == {"track.kp": [100, 110]}
    assert grid_overrides("track.dt", 0.002) == {"track.dt": 0.002}
    assert is_perturbation_param("sweep.perturb.initial.std")
    assert not is_perturbation_param("sweep.perturb.initial")
    spec = resolve({"sweep": {"perturb": {"initial": {"dist": "normal", "std": 0.1}}}})
    cell = spec.with_overrides({"sweep.perturb.initial.std": 0.5})
    assert cell.sweep.perturb["initial"] == {"dist": "normal", "std": 0.5}
    assert spec.sweep.perturb["initial"] == {"dist": "normal", "std": 0.1}


@pytest.mark.parametrize("grid", [
    {"track.kp": [[1, 2]], "gains": [{"track.kp": [10, 13], "track.kv": [100, 110]}]},
    {"gains": [{"track.kp": [10, 13]}], "track.kp": [[1, 2], [3, 4]]},  # either order
    {"a": [{"track.kv": [1, 2]}], "b": [{"label": "x", "track.kv": [3, 4]}]},  # two groups
    {"sweep.perturb.initial.std": [0.1], "g": [{"sweep.perturb.initial.std": 0.2}]},
])
def test_a_key_set_by_two_grid_entries_is_refused(grid: dict[str, object]) -> None:
    spec = {"sweep": {"perturb": {"initial": {"dist": "normal", "std": 0.1}}, "grid": grid}}
    with pytest.raises(SpecError, match=r"sweep\.grid: '[a-z.]+' is set both by the (grid key|"
                                        r"group) '\S+' and by the (grid key|group) '\S+'"):
        resolve(spec)


def test_keys_set_by_one_grid_entry_each_are_fine() -> None:
    spec = resolve({"sweep": {"grid": {
        "track.kp": [[1, 2], [3, 4]],
        "gains": [{"label": "a", "track.kv": [1, 2]}, {"label": "b", "track.kv": [3, 4]}]}}})
    assert list(spec.sweep.grid) == ["track.kp", "gains"]


TORQUE = {"plant": {"model": "dynamic"},
          "sweep": {"perturb": {"torque_limit": {"dist": "normal", "std": 0.5}}}}


def test_a_torque_limit_perturbation_needs_a_finite_torque_limit() -> None:
    with pytest.raises(SpecError, match=r"sweep\.perturb\.torque_limit: needs a finite "
                                        r"plant\.torque_limit, got inf"):
        resolve(TORQUE)
    relative = {**TORQUE, "sweep": {"perturb": {"torque_limit": {
        "dist": "uniform", "low": -0.1, "high": 0.1, "relative": True}}}}
    with pytest.raises(SpecError, match="needs a finite"):
        resolve(relative)
    assert resolve({**TORQUE, "plant": {"model": "dynamic", "torque_limit": 2.0}})
    with pytest.raises(SpecError, match=r"in every cell \(the grid key 'plant\.torque_limit'"):
        resolve({**TORQUE, "sweep": {**TORQUE["sweep"],
                                     "grid": {"plant.torque_limit": [1.0, math.inf]}}})
    with pytest.raises(SpecError, match=r"in every cell \(the group 'limits' sets it\)"):
        resolve({**TORQUE, "sweep": {**TORQUE["sweep"], "grid": {"limits": [
            {"plant.torque_limit": 1.0}, {"plant.torque_limit": math.inf}]}}})
    # every cell finite: fine, even though the spec's own value (the default) is inf
    spec = resolve({**TORQUE, "sweep": {**TORQUE["sweep"],
                                        "grid": {"plant.torque_limit": [1.0, 2.0]}}})
    assert math.isinf(spec.plant.torque_limit)


def test_a_group_label_refuses_control_characters() -> None:
    with pytest.raises(SpecError, match=r"label must not contain control characters.*U\+2028"):
        resolve({"sweep": {"grid": {"g": [{"label": "a\u2028b", "track.kp": [1, 2]}]}}})
