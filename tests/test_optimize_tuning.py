"""Tests of flatcli.core.optimize.tuning: the tuning record."""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

import pytest

from flatcli.core.errors import FlatcliError
from flatcli.core.optimize import TUNING, Tuning


def test_defaults_are_documented() -> None:
    """Every field is described in the class docstring, and the defaults validate."""
    doc = Tuning.__doc__ or ""
    for f in dataclasses.fields(Tuning):
        # an attribute line of the numpydoc "Attributes" section: "name :" or "a, name :"
        assert re.search(rf"^    (\w+, )*{f.name}(, \w+)* : \S", doc, re.MULTILINE), f.name
    assert Tuning() == TUNING
    with pytest.raises(dataclasses.FrozenInstanceError):
        TUNING.backoff = 0.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"exchange_rounds": 0}, "exchange_rounds"),
        ({"check_refinement": 2.5}, "check_refinement"),
        ({"backoff": -1e-7}, "backoff"),
        ({"solver_tol": math.nan}, "solver_tol"),
        ({"big": math.inf}, "big"),
        ({"margin_tie": 1.0}, "margin_tie"),
    ],
)
def test_invalid_values_are_refused(kwargs: dict[str, Any], field: str) -> None:
    with pytest.raises(FlatcliError, match=rf"^Tuning\.{field}: must be"):
        Tuning(**kwargs)
