"""The schema (flatcli/spec/schema.py): records, their keys, enumerations from the core."""

from __future__ import annotations

from dataclasses import fields

import pytest

from flatcli.core.model import MODELS
from flatcli.core.optimize import OBJECTIVES
from flatcli.core.simulate import INTEGRATORS
from flatcli.spec import LINKS, SCHEMA, SECTIONS, Spec, SpecError, all_keys, lookup, resolve


def test_sections_are_the_toml_tables() -> None:
    assert list(SECTIONS) == ["", "robot", "plan", "plan.optimize", "track", "plant", "sweep"]
    assert list(SCHEMA) == list(SECTIONS)


def test_every_key_has_a_default_value_in_the_built_spec() -> None:
    values = resolve({}).values()
    assert sorted(values) == sorted(all_keys())
    for dotted in all_keys():
        key = lookup(dotted)
        expected = {} if key.kind == "table" else key.default
        assert values[dotted] == expected, dotted


def test_choices_come_from_the_core() -> None:
    assert lookup("robot.model").choices == MODELS
    assert lookup("plan.optimize.objective").choices == OBJECTIVES
    assert lookup("track.integrator").choices == INTEGRATORS


def test_per_link_vectors_hold_links_numbers() -> None:
    for dotted in ("robot.mass", "robot.com", "plan.start", "track.initial", "plant.com"):
        assert lookup(dotted).length == LINKS


def test_tree_mirrors_the_records_and_values_the_keys() -> None:
    spec = resolve({"track": {"dt": 0.002}})
    assert spec.tree["track"]["dt"] == spec.track.dt == 0.002
    assert spec.tree["plan"]["optimize"]["max_iter"] == spec.plan.optimize.max_iter
    assert spec.values()["plan.optimize.max_iter"] == 300
    assert [f.name for f in fields(Spec)] == list(spec.tree)


def test_unknown_keys_get_a_suggestion() -> None:
    expected = r"unknown key 'plan.optimise.objective' \(did you mean 'plan.optimize.objective'"
    with pytest.raises(SpecError, match=expected):
        lookup("plan.optimise.objective")
