"""A spec written back as TOML (flatcli/spec/toml.py) reads back as the same spec."""

from __future__ import annotations

import math
import tomllib

from flatcli.spec import resolve, spec_toml
from flatcli.spec.toml import toml_key, toml_value


def test_values_round_trip_exactly() -> None:
    assert toml_value(0.1 + 0.2) == "0.30000000000000004"
    assert toml_value(math.inf) == "inf" and toml_value(-math.inf) == "-inf"
    assert toml_value((1.0, True)) == "[1.0, true]"
    assert toml_value('say "x"') == '"say \\"x\\""'
    assert toml_key("plant.com") == '"plant.com"' and toml_key("kp") == "kp"


def test_any_text_is_written_as_valid_toml() -> None:
    # json.dumps writes a character beyond the BMP as a surrogate pair ("\\ud83d\\ude00"),
    # which TOML refuses; a DEL and a backslash need TOML's own escapes
    for text in ["rocket \U0001F680", "tab\there", "del\x7f", "back\\slash", 'quote "q"',
                 "line\nbreak", "é"]:
        assert tomllib.loads(f"v = {toml_value(text)}")["v"] == text
        key = toml_key(text)
        assert tomllib.loads(f"{key} = 1") == {text: 1}


def test_a_spec_round_trips_through_its_toml_without_the_sweep() -> None:
    spec = resolve({"name": "r", "plant": {"com": [0.1, 0.1, 0.001]},
                    "plan": {"optimize": {"objective": "energy", "rate_limit": 5.0}},
                    "sweep": {"trials": 3}})
    text = spec_toml(spec)
    assert "[sweep]" not in text and "degree" not in text  # unset keys stay unset
    assert "\n[plan.optimize]\nobjective = \"energy\"" in text
    again = resolve(tomllib.loads(text), {"sweep.trials": 3})
    assert again.digest() == spec.digest()


def test_a_sweep_round_trips_with_its_tables_and_notes() -> None:
    spec = resolve({"sweep": {"trials": 3, "perturb": {"initial": {"dist": "normal",
                                                                    "std": 0.01}},
                              "grid": {"gains": [{"label": "printed \U0001F680",
                                                  "track.kp": [10, 13]}],
                                       "plant.com": [[0.1, 0.1, 0.0], [0.1, 0.1, 0.002]]}}})
    text = spec_toml(spec, sweep=True, values={"sweep.chunk": 3},
                     notes={"sweep.chunk": "the default"})
    assert "chunk = 3  # the default" in text
    assert '"plant.com" = [[0.1, 0.1, 0.0], [0.1, 0.1, 0.002]]' in text
    again = tomllib.loads(text)
    assert again["sweep"]["grid"] == spec.tree["sweep"]["grid"]
    assert resolve({**again, "sweep": {**again["sweep"], "chunk": None}}).digest() == \
        spec.digest()
