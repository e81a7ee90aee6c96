"""The example controller of docs/development.md, *A new controller*, as written there (a
sampled proportional correction of the flat outputs' errors): tests/test_compose.py
registers it and runs it."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from flatcli.core._jit import jitable
from flatcli.core.controllers.parts import SampledPart


class Design(NamedTuple):  # once per plan (Python): output steps per sample, gain [1/s^2], N
    every: int
    gain: float
    outputs: int

class Scratch(NamedTuple):  # one trial's: s0 (2 N,) e_j, e_j' measured; held (N,) dv
    s0: np.ndarray
    held: np.ndarray

def design(scenario: Any) -> Design:  # a 0.1 s sample
    return Design(round(0.1 / scenario.dt), 4.0, scenario.n_joints)

def scratch(d: Design) -> Scratch:
    return Scratch(np.zeros(2 * d.outputs), np.zeros(d.outputs))

@jitable
def reset(s: Scratch) -> None:
    s.held[:] = 0.0

@jitable
def period(d: Design) -> int:
    return d.every

@jitable
def step(d: Design, s: Scratch, k: int) -> None:  # dv_j = -gain e_j, held for a sample
    for j in range(s.held.shape[0]):
        s.held[j] = -d.gain * s.s0[2 * j]

@jitable
def extras(s: Scratch, row: np.ndarray) -> None:  # no columns of its own
    pass

PART = SampledPart("nudge", scratch, reset, period, step, extras, (), (), design)
