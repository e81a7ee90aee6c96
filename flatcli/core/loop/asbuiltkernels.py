"""The as-built controller's compiled kernels: ``kernels.make_batch`` and ``make_single`` of
its two (model, plant) combinations, ("asbuilt", "kinematic") and ("asbuilt", "dynamic")
(``asbuiltloop``), any N. ``simulate`` looks them up in ``KERNELS`` beside the flat ones."""

from __future__ import annotations

from typing import Any

import numpy as np

from flatcli.core._jit import jitable, kernel
from flatcli.core.controllers.control import Gains
from flatcli.core.loop.asbuiltloop import (
    AsbuiltScratch,
    AsbuiltShared,
    asbuilt_loop,
    asbuilt_scratch,
    dynamic_aux,
    dynamic_initial,
    dynamic_rhs,
    kinematic_initial,
    kinematic_rhs,
    observe_dynamic,
    observe_kinematic,
    plan_residual,
    record_dynamic,
    record_kinematic,
)
from flatcli.core.loop.kernels import (
    Buffers,
    Grid,
    Kernels,
    Ops,
    Results,
    Settings,
    TrialArrays,
    chain_plant,
    make_batch,
    make_single,
)
from flatcli.core.plan.exact import constraint_of
from flatcli.core.robots.params import RobotParams

Array = np.ndarray[Any, np.dtype[np.float64]]


@jitable
def _loop(shared: AsbuiltShared, trials: TrialArrays, i: int, scratch: AsbuiltScratch
          ) -> Any:
    return asbuilt_loop(shared, trials.plant[i], trials.params[i], trials.offset[i],
                        trials.h0[i], trials.servo[i, 0], trials.servo[i, 1], scratch)


@jitable
def _residual(loop: Any, trials: TrialArrays, i: int, plan_theta: Array,
              plan_theta_dot: Array) -> float:
    return plan_residual(loop, plan_theta, plan_theta_dot)


@jitable
def _bounded(loop: Any) -> bool:
    """The as-built law has no singular set: its commands are bounded everywhere (finite
    gains about a finite plan), and its margin (1.0, ``asbuiltloop``) never changes sign,
    so no trial meets a crossing to stop at or to pass (``crossings`` is 0)."""
    return True


ASBUILT_KINEMATIC = Ops(_loop, _bounded, kinematic_initial, kinematic_rhs, observe_kinematic,
                        record_kinematic, _residual, lambda n: n + 1, lambda n: 1,
                        lambda n: 3 * n + 1, asbuilt_scratch)
ASBUILT_DYNAMIC = Ops(_loop, _bounded, dynamic_initial, dynamic_rhs, observe_dynamic,
                      record_dynamic, _residual, lambda n: 2 * n + 2, dynamic_aux,
                      lambda n: 4 * n + 2, asbuilt_scratch)

_kinematic_batch = make_batch(ASBUILT_KINEMATIC)
(_kinematic_initial, _kinematic_rhs, _kinematic_observe,
 _kinematic_record) = make_single(ASBUILT_KINEMATIC)
_dynamic_batch = make_batch(ASBUILT_DYNAMIC)
(_dynamic_initial, _dynamic_rhs, _dynamic_observe, _dynamic_record) = make_single(
    ASBUILT_DYNAMIC)


@kernel
def asbuilt_kinematic_batch(
    method: int, shared: AsbuiltShared, trials: TrialArrays, grid: Grid, settings: Settings,
    tables: Array, buffers: Buffers, results: Results,
) -> None:
    _kinematic_batch(method, shared, trials, grid, settings, tables, buffers, results)


@kernel
def asbuilt_kinematic_start(
    shared: AsbuiltShared, trials: TrialArrays, i: int, grid: Grid, buffers: Buffers,
    out: Array,
) -> None:
    _kinematic_initial(shared, trials, i, grid, buffers, out)


@kernel
def asbuilt_kinematic_derivative(
    shared: AsbuiltShared, trials: TrialArrays, i: int, grid: Grid, buffers: Buffers,
    t: float, x: Array, noise: Array, out: Array,
) -> None:
    _kinematic_rhs(shared, trials, i, grid, buffers, t, x, noise, out)


@kernel
def asbuilt_kinematic_metrics(
    shared: AsbuiltShared, trials: TrialArrays, i: int, grid: Grid, settings: Settings,
    buffers: Buffers, states: Array, rates: Array, last: int, complete: bool, crossings: Array,
    out: Array,
) -> float:
    return _kinematic_observe(shared, trials, i, grid, settings, buffers, states, rates, last,
                           complete, crossings, out)


@kernel
def asbuilt_kinematic_trace(states: Array, rates: Array, last: int, trace: Array) -> None:
    _kinematic_record(states, rates, last, trace)


@kernel
def asbuilt_dynamic_batch(
    method: int, shared: AsbuiltShared, trials: TrialArrays, grid: Grid, settings: Settings,
    tables: Array, buffers: Buffers, results: Results,
) -> None:
    _dynamic_batch(method, shared, trials, grid, settings, tables, buffers, results)


@kernel
def asbuilt_dynamic_start(
    shared: AsbuiltShared, trials: TrialArrays, i: int, grid: Grid, buffers: Buffers,
    out: Array,
) -> None:
    _dynamic_initial(shared, trials, i, grid, buffers, out)


@kernel
def asbuilt_dynamic_derivative(
    shared: AsbuiltShared, trials: TrialArrays, i: int, grid: Grid, buffers: Buffers,
    t: float, x: Array, noise: Array, out: Array,
) -> None:
    _dynamic_rhs(shared, trials, i, grid, buffers, t, x, noise, out)


@kernel
def asbuilt_dynamic_metrics(
    shared: AsbuiltShared, trials: TrialArrays, i: int, grid: Grid, settings: Settings,
    buffers: Buffers, states: Array, rates: Array, last: int, complete: bool, crossings: Array,
    out: Array,
) -> float:
    return _dynamic_observe(shared, trials, i, grid, settings, buffers, states, rates, last,
                           complete, crossings, out)


@kernel
def asbuilt_dynamic_trace(states: Array, rates: Array, last: int, trace: Array) -> None:
    _dynamic_record(states, rates, last, trace)


def asbuilt_shared(model: Any, gains: Gains, rate_limit: float, servo_is_plant: bool,
                   robot: RobotParams) -> AsbuiltShared:
    """What every trial shares: the controller's robot (``exact.Constraint`` of ``robot``,
    writable copies), the rate limit, the servo's model (``gains`` and ``model`` are the
    flat law's: the as-built law's gains are in the tracked flag)."""
    constraint = constraint_of(robot)
    return AsbuiltShared(np.array(constraint.K, dtype=float),
                         np.array(constraint.inertia, dtype=float),
                         float(np.cos(constraint.offset)), float(np.sin(constraint.offset)),
                         float(rate_limit), servo_is_plant)


#: The as-built kernels, by (model kind, plant model).
KERNELS: dict[tuple[str, str], Kernels] = {
    ("asbuilt", "kinematic"): Kernels(
        ASBUILT_KINEMATIC, asbuilt_kinematic_batch,
        (asbuilt_kinematic_start, asbuilt_kinematic_derivative, asbuilt_kinematic_metrics,
         asbuilt_kinematic_trace), asbuilt_shared, chain_plant),
    ("asbuilt", "dynamic"): Kernels(
        ASBUILT_DYNAMIC, asbuilt_dynamic_batch,
        (asbuilt_dynamic_start, asbuilt_dynamic_derivative, asbuilt_dynamic_metrics,
         asbuilt_dynamic_trace), asbuilt_shared, chain_plant),
}

__all__ = ["ASBUILT_DYNAMIC", "ASBUILT_KINEMATIC", "KERNELS", "asbuilt_shared"]
