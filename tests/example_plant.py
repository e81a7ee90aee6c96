"""The example plant of docs/development.md, *A new plant*, as written there (the kinematic
plant with motors 10 % weak): tests/test_base.py registers it and runs it."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from flatcli.core._jit import jitable
from flatcli.core.plants import kinematic
from flatcli.core.plants.part import plant_trig
from flatcli.core.robots.chain import momentum_weights_given

GAIN = 0.9  # each joint turns at 90 % of its command, then clipped to the rate limit

@jitable
def rates(plant: Any, x: np.ndarray, cs: np.ndarray, sn: np.ndarray, given: bool,
          out: np.ndarray, at: int, torques: bool) -> None:
    """th_j' = sat(GAIN r_j) into out[1..N]; th0' into out[0], from H = H0 (the plant's own
    momentum weights h: h_0 th0' + sum_j h_j th_j' = H0)."""
    rows = plant.rows  # the kinematic plant's scratch rows: r, h, cos, sin
    nb = rows.shape[1]
    pcs, psn = plant_trig(x[:nb], cs, sn, given, rows[2], rows[3], plant.cos_p, plant.sin_p)
    momentum_weights_given(plant.K, plant.inertia, pcs, psn, rows[1])
    base, limit = plant.h0, plant.rate_limit
    for j in range(1, nb):
        out[j] = min(max(GAIN * rows[0, j - 1], -limit), limit)
        base -= rows[1, j] * out[j]
    out[0] = base / rows[1, 0]

PLANT = replace(kinematic.PLANT, name="weak", rates=rates)
