"""The closed loop written out again, independently of flatcli.core.loop.simulate: the plant's
coefficients and the inputs every closed-loop baseline shares."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from benchmarks.baselines.problem import Tracking
from flatcli.core.curves.basis import PolynomialBasis
from flatcli.core.loop.simulate import Trials
from flatcli.core.plan.planning import Plan

Array = NDArray[np.float64]

def plant_coefficients(links: Array) -> Array:
    """(N, 11) reduced-constraint coefficients of N plants, general d2.

    Order: a0, a1, a2, a3, b0, b1, b2, b3, c0, c2', c3 [kg^2 m^2]: the reduced momentum
    constraint of docs/physics.md (checked symbolically in tests/test_model.py).
    Written out here rather than taken from flatcli, so that the closed-loop baselines check it.

    Parameters
    ----------
    links : (N, 12) m0, m1, m2 [kg], I0, I1, I2 [kg m^2], l0, l1, l2, d0, d1, d2 [m]
    """
    m0, m1, m2, I0, I1, I2, l0, l1, _, d0, d1, d2 = np.asarray(links, dtype=float).T
    M = m0 + m1 + m2
    e0, e1 = l0 - d0, l1 - d1
    common = m1 * m2 * e1**2 + m0 * (m2 * l1**2 + m1 * d1**2) + m2 * d2**2 * (m0 + m1)
    k2 = m2 * d2 * (m0 * l1 + m1 * e1)
    k3 = m0 * m2 * d2 * e0
    arm = m0 * e0 * (m2 * l1 + m1 * d1)
    out = np.column_stack(
        [
            M * (I0 + I1 + I2) + m0 * (m1 + m2) * e0**2 + common,
            2 * arm,
            2 * k2,
            2 * k3,
            -(M * (I1 + I2) + common),
            -arm,
            -2 * k2,
            -k3,
            -(M * I2 + m2 * d2**2 * (m0 + m1)),
            -k2,
            -k3,
        ]
    )
    return np.ascontiguousarray(out)


@dataclass(frozen=True)
class LoopInputs:
    """Everything the closed-loop baselines need, as plain arrays.

    Attributes
    ----------
    reference : (2n + 1, 6) y1, y2, y1', y2', y1'', y2'' at t = j dt / 2, from the plan's
        polynomial coefficients (Horner)
    poly : (3, 2, deg + 1) coefficients in s = t/T of y, y', y'' [per s^order], for
        evaluation at any t
    duration : T [s]
    controller : (5,) a0, a1, b0, b1, c0 of the controller's model [kg^2 m^2]
    gains : (4,) kp1, kp2, kv1, kv2
    plant : (N, 11) plant coefficients; total_mass : (N,) [kg]; h0 : (N,) [kg m^2/s]
    initial : (N, 4); dt [s]; steps n; rate_limit [rad/s]
    """

    reference: Array
    poly: Array
    duration: float
    controller: Array
    gains: Array
    plant: Array
    total_mass: Array
    h0: Array
    initial: Array
    dt: float
    steps: int
    rate_limit: float


def loop_inputs(plan: Plan, tracking: Tracking, trials: Trials) -> LoopInputs:
    """Unpack a polynomial plan, a tracking setting and trials into ``LoopInputs``."""
    basis = plan.trajectory.basis
    if not isinstance(basis, PolynomialBasis):
        raise TypeError("closed-loop baselines: the plan must use a PolynomialBasis")
    T = plan.duration
    steps = round(T / tracking.dt)
    if not math.isclose(steps * tracking.dt, T, rel_tol=1e-9):
        raise ValueError("closed-loop baselines: dt must divide the plan's duration")
    c = np.asarray(plan.trajectory.coefficients, dtype=float)  # (2, deg + 1), in s = t/T
    P = np.polynomial.polynomial
    poly = np.zeros((3, 2, c.shape[1]))
    for order in range(3):
        d = P.polyder(c, order, axis=1) / T**order
        poly[order, :, : d.shape[1]] = d
    t = np.arange(2 * steps + 1, dtype=float) * (0.5 * tracking.dt)
    s = t / T
    reference = np.empty((t.size, 6))
    for order in range(3):
        for i in range(2):
            reference[:, 2 * order + i] = P.polyval(s, poly[order, i])
    k = plan.coefficients
    return LoopInputs(
        reference=reference,
        poly=poly,
        duration=T,
        controller=np.array([k.a0, k.a1, k.b0, k.b1, k.c0], dtype=float),
        gains=np.asarray(tracking.gains.paper(), dtype=float),
        plant=plant_coefficients(trials.links),
        total_mass=np.ascontiguousarray(trials.links[:, :3].sum(axis=1)),
        h0=np.ascontiguousarray(trials.momentum, dtype=float),
        initial=np.ascontiguousarray(trials.initial, dtype=float),
        dt=float(tracking.dt),
        steps=steps,
        rate_limit=float(tracking.rate_limit),
    )
