"""Tests of flatcli.core.optimize.objectives: the objective vocabulary."""

from __future__ import annotations

from typing import get_args

from flatcli.core.optimize import OBJECTIVES, Objective
from flatcli.core.optimize.objectives import EPIGRAPH, Goal, better, maximised


def test_one_list_of_objectives() -> None:
    """The tuple the spec offers is the type the optimiser accepts; goals add phase 1."""
    assert get_args(Objective) == OBJECTIVES
    assert get_args(Goal) == (*OBJECTIVES, "violation")
    assert set(EPIGRAPH) == {"peak_rate", "margin", "violation"}


def test_direction() -> None:
    assert [g for g in get_args(Goal) if maximised(g)] == ["margin"]
    assert better("margin", 0.4, 0.3) and not better("margin", 0.3, 0.4)
    assert better("energy", 20.0, 21.0) and not better("peak_rate", 4.0, 3.9)
    assert better("energy", 20.0, 20.0)
