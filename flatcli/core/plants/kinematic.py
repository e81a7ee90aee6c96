"""The kinematic plant of an N-link chain: each joint turns at its commanded rate, clipped to
the rate limit, and the base turns as the plant's own angular momentum makes it. It takes
joint-rate commands and knows nothing of the controller that made them:

    th_j' = sat(r_j) (j = 1..N),   th0' = (H0 - sum_j h_j th_j') / h_0

with h the plant's momentum weights (``chain.momentum_weights_given``: its own K and
inertias, any d_N) and sat the clip to +-rate_limit (infinite: none). Its state is the angles
th0..th_N; it writes no aux values; its trace columns are th0'..th_N' (``PLANT``).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import inlined, jitable
from flatcli.core.plants.part import PlantPart, plant_trig
from flatcli.core.robots.chain import chain_momentum_given, momentum_weights_given, plan_residual

Array = NDArray[np.float64]

#: Rows of ``KinematicPlant.rows`` (each N + 1 long): the commands r, the weights h, the
#: plant's cos and sin (its own, or a turned copy of given ones).
_R, _H, _CS, _SN = range(4)
ROWS = 4


class KinematicPlant(NamedTuple):
    """One trial's kinematic plant: K (N + 1, N + 1) [kg m^2], inertias (N + 1,), parameters
    (4 (N + 1),) of its equivalent placement (H from the full kinematics), H0 [kg m^2/s], the
    rate limit [rad/s], cos and sin of its last link's turn, rows (ROWS, N + 1) scratch."""

    K: Array
    inertia: Array
    params: Array
    h0: float
    rate_limit: float
    cos_p: float
    sin_p: float
    rows: Array


def scratch(n: int) -> Array:
    """A kinematic plant's rows for N joints."""
    return np.zeros((ROWS, n + 1))


@jitable
def make(trials: Any, i: int, rate_limit: float, servo: Any, rows: Array) -> KinematicPlant:
    """Trial i's plant (``PlantPart.make``; no servo)."""
    p = trials.params[i]
    nb = rows.shape[1]
    offset = trials.offset[i]
    return KinematicPlant(trials.plant[i], p[nb: 2 * nb], p, trials.h0[i], rate_limit,
                          np.cos(offset), np.sin(offset), rows)


@jitable
def state(n: int) -> int:
    """th0..th_N."""
    return n + 1


def aux(n: int) -> int:
    return 0


def columns(n: int) -> int:
    """th0'..th_N' in a trace row."""
    return n + 1


@jitable
def io(plant: KinematicPlant, x: Array) -> tuple[Array, Array]:
    """Its commands' row; no joint rates in its state."""
    nb = plant.rows.shape[1]
    return plant.rows[_R], x[nb:nb]


@inlined
def rates(plant: KinematicPlant, x: Array, cs: Array, sn: Array, given: bool, out: Array,
          at: int, torques: bool) -> None:
    """th_j' = sat(r_j) into out[1..N], th0' from the plant's momentum into out[0]."""
    rows = plant.rows
    nb = rows.shape[1]
    pcs, psn = plant_trig(x[:nb], cs, sn, given, rows[_CS], rows[_SN], plant.cos_p,
                          plant.sin_p)
    h, r, limit = rows[_H], rows[_R], plant.rate_limit
    momentum_weights_given(plant.K, plant.inertia, pcs, psn, h)
    base = plant.h0
    for j in range(1, nb):
        rate = min(max(r[j - 1], -limit), limit)
        out[j] = rate
        base -= h[j] * rate
    out[0] = base / h[0]


@jitable
def start(plant: KinematicPlant, initial: Array, r: Array, x0: Array) -> None:
    """th(0)."""
    for a in range(plant.rows.shape[1]):
        x0[a] = initial[a]


@jitable
def observed(plant: KinematicPlant, x: Array, f: Array, at: int, cs: Array, sn: Array,
             given: bool) -> tuple[float, float, float, bool, float, float]:
    """H with the applied rates f[:N + 1], the largest of them; clipped where it is at the
    limit (the joints turn at their commands clipped: at it exactly where clipped); no
    torques (nan)."""
    rows = plant.rows
    nb = rows.shape[1]
    peak = 0.0
    for i in range(1, nb):
        peak = max(peak, abs(f[i]))
    pcs, psn = plant_trig(x[:nb], cs, sn, given, rows[_CS], rows[_SN], plant.cos_p,
                          plant.sin_p)
    h = chain_momentum_given(plant.params, pcs, psn, f[:nb])
    return h, plant.h0, peak, peak >= plant.rate_limit, math.nan, math.nan


@jitable
def record(plant: KinematicPlant, trace: Array, j: int, col: int, x: Array, f: Array,
           at: int, commands: bool) -> None:
    """[the applied rates of joints 1..N-1,] th0'..th_N'."""
    nb = plant.rows.shape[1]
    if commands:
        for i in range(1, nb - 1):
            trace[j, col + i - 1] = f[i]
        col += nb - 2
    for i in range(nb):
        trace[j, col + i] = f[i]


@jitable
def residual(plant: KinematicPlant, trials: Any, i: int, plan_theta: Array,
             plan_theta_dot: Array) -> float:
    return plan_residual(plan_theta, plan_theta_dot, plant.params, plant.h0,
                         plant.rows[_CS], plant.rows[_SN], plant.cos_p, plant.sin_p)


@jitable
def bounded(plant: KinematicPlant) -> bool:
    """The joint rates are clipped to a finite rate limit."""
    return not math.isinf(plant.rate_limit)


PLANT = PlantPart("kinematic", scratch, make, state, aux, columns, io, rates, start,
                  observed, record, residual, bounded, rate_states=False, torques=False)
