"""A spec written back as TOML (flatcli/spec/toml.py) reads back as the same spec."""

from __future__ import annotations

import math
import tomllib

from flatcli.spec import resolve, spec_toml
from flatcli.spec.toml import toml_value


def test_values_round_trip_exactly() -> None:
    assert toml_value(0.1 + 0.2) == "0.30000000000000004"
    assert toml_value(math.inf) == "inf" and toml_value(-math.inf) == "-inf"
    assert toml_value((1.0, True)) == "[1.0, true]"
    assert toml_value('say "x"') == '"say \\"x\\""'


def test_a_spec_round_trips_through_its_toml_without_the_sweep() -> None:
    spec = resolve({"name": "r", "plant": {"com": [0.1, 0.1, 0.001]},
                    "plan": {"optimize": {"objective": "energy", "rate_limit": 5.0}},
                    "sweep": {"trials": 3}})
    text = spec_toml(spec)
    assert "[sweep]" not in text and "degree" not in text  # unset keys stay unset
    assert "\n[plan.optimize]\nobjective = \"energy\"" in text
    again = resolve(tomllib.loads(text), {"sweep.trials": 3})
    assert again.digest() == spec.digest()
