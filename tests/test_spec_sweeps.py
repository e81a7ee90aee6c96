"""Rules of [sweep.perturb] and [sweep.grid] (flatcli/spec/sweeps.py)."""

from __future__ import annotations

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
