"""The integrators' singular-set test (flatcli/core/loop/integrate.py): a margin that reaches zero
within a step is a crossing, exactly as one that changes sign."""

from __future__ import annotations

import pytest

from flatcli.core.loop.integrate import _C2, _C3, _C4, _C5, _first_flip, _flipped


@pytest.mark.parametrize(("a", "b", "crossed"), [
    (0.5, -0.5, True), (-0.5, 0.5, True),  # a change of sign
    (0.5, 0.0, True), (-0.5, 0.0, True), (0.5, -0.0, True),  # exactly zero: on the set
    (0.5, 0.25, False), (-0.5, -1e-300, False),  # the same side, however close
])
def test_a_margin_that_reaches_zero_is_a_crossing(a: float, b: float, crossed: bool) -> None:
    assert _flipped(a, b) is crossed


def test_the_first_stage_on_the_singular_set_is_found() -> None:
    assert _first_flip(1.0, 0.5, 0.4, 0.3, 0.2, 0.1) == -1.0
    assert _first_flip(1.0, 0.5, 0.0, 0.3, 0.2, 0.1) == _C3  # zero at the third stage
    assert _first_flip(-1.0, 0.0, -0.5, -0.5, -0.5, -0.5) == _C2
    assert _first_flip(1.0, 0.5, 0.4, 0.0, -0.2, 0.1) == _C4
    assert _first_flip(1.0, 0.5, 0.4, 0.3, 0.0, 0.1) == _C5
    assert _first_flip(1.0, 0.5, 0.4, 0.3, 0.2, 0.0) == 1.0
