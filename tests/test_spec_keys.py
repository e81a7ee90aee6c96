"""One key's check (flatcli/spec/keys.py): kinds, bounds, lengths, and one-line messages."""

from __future__ import annotations

import math
from typing import Any

import pytest

from flatcli.spec.keys import Key, SpecError, suggest

MASS = Key("vector", (1.0, 1.0, 1.0), "masses", "kg", low=0, low_open=True, length=3)
LIMIT = Key("float", math.inf, "limit", "rad/s", low=0, low_open=True, allow_inf=True)
COUNT = Key("int", 1, "count", low=1)


@pytest.mark.parametrize(
    ("key", "value", "expected"),
    [
        (MASS, [1, 2, 3], (1.0, 2.0, 3.0)),
        (LIMIT, math.inf, math.inf),
        (LIMIT, 2, 2.0),
        (COUNT, 3, 3),
        (Key("bool", True, ""), False, False),
        (Key("choice", "a", "", choices=("a", "b")), "b", "b"),
        (Key("float", None, "", nullable=True), None, None),
    ],
)
def test_good_values_are_normalised(key: Key, value: Any, expected: Any) -> None:
    out = key.check("k", value)
    assert out == expected and type(out) is type(expected)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        (MASS, [1, 0, 1], "m[1]: must be > 0 kg, got 0"),
        (MASS, [1, 2], "m: expected a list of 3 numbers [kg], got [1, 2]"),
        (MASS, [1, math.nan, 1], "m[1]: expected a finite number [kg], got nan"),
        (LIMIT, 0, "m: must be > 0 rad/s, got 0"),
        (LIMIT, True, "m: expected a number [rad/s], got True"),
        (COUNT, 0, "m: must be >= 1, got 0"),
        (COUNT, 1.5, "m: expected an integer, got 1.5"),
        (Key("float", 1.0, ""), math.inf, "m: expected a finite number, got inf"),
        (Key("choice", "abc", "", choices=("abc", "xyz")), "abd",
         "m: expected one of ['abc', 'xyz'], got 'abd' (did you mean 'abc'?)"),
        (Key("str", "x", ""), "a/b", "m: must not contain '/'"),
        (Key("table", {}, ""), 3, "m: expected a table, got 3"),
    ],
)
def test_bad_values_are_one_line_naming_where(key: Key, value: Any, message: str) -> None:
    with pytest.raises(SpecError) as info:
        key.check("m", value)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_an_item_check_is_the_vector_check_of_that_item() -> None:
    with pytest.raises(SpecError) as whole:
        MASS.check("plant.mass", [1, -0.25, 1])
    with pytest.raises(SpecError) as item:
        MASS.check_item("plant.mass", 1, -0.25)
    assert str(whole.value) == str(item.value) == "plant.mass[1]: must be > 0 kg, got -0.25"


def test_bounds_text_and_suggestions() -> None:
    assert MASS.bounds_text() == "> 0"
    assert COUNT.bounds_text() == ">= 1"
    assert LIMIT.bounds_text() == "> 0 (inf: no limit)"
    assert suggest("track.kpp", ["track.kp", "plan.size"]) == " (did you mean 'track.kp'?)"
    assert suggest("zzz", ["track.kp"]) == ""


NAME = Key("str", "x", "")


@pytest.mark.parametrize("value", [
    "a\x00b", "a\tb", "a\nb", "a\x7fb", "a\x85b", "a\x9bb",  # C0, DEL, C1 (NEL, CSI)
    "a\u2028b", "a\u2029b",  # line and paragraph separators
    "a\u202eb", "a\u202ab", "a\u2066b", "a\u200eb",  # bidirectional controls
    "a\u200bb", "a\ufeffb", "a\u00adb",  # zero-width space, BOM, soft hyphen
])
def test_text_refuses_every_control_format_and_line_separator_character(value: str) -> None:
    with pytest.raises(SpecError) as info:
        NAME.check("name", value)
    text = str(info.value)
    code = next(f"U+{ord(c):04X}" for c in value if c not in "ab")
    assert text.startswith("name: must not contain control characters") and code in text
    assert text.isascii() and text.isprintable()  # the line itself shows no such character


@pytest.mark.parametrize("value", ["..", ".", ".hidden", "a/b", "a\\b", " ", ""])
def test_text_that_names_no_directory_of_its_own_is_refused(value: str) -> None:
    with pytest.raises(SpecError, match="name: "):
        NAME.check("name", value)


@pytest.mark.parametrize("value", ["a..b", "é", "日本語", "run-1.5", "a b"])
def test_printable_text_is_a_name(value: str) -> None:
    assert NAME.check("name", value) == value
