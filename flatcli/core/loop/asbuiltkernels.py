"""The as-built controller's compiled kernels: ``kernels.make_batch`` and ``make_single`` of
its two (model, plant) combinations, ("asbuilt", "kinematic") and ("asbuilt", "dynamic")
(``asbuiltloop``), any N. ``simulate`` looks them up in ``KERNELS`` beside the flat ones."""

from __future__ import annotations

from typing import Any

import numpy as np

from flatcli.core._jit import jitable
from flatcli.core.controllers.control import Gains
from flatcli.core.loop.asbuiltloop import (
    AsbuiltScratch,
    AsbuiltShared,
    additive,
    asbuilt_loop,
    asbuilt_scratch,
    dynamic_aux,
    dynamic_initial,
    dynamic_rhs,
    kinematic_initial,
    kinematic_rhs,
    measure,
    observe_dynamic,
    observe_kinematic,
    plan_residual,
    record_dynamic,
    record_kinematic,
)
from flatcli.core.loop.kernels import (
    Kernels,
    Ops,
    TrialArrays,
    chain_plant,
    compile_kernels,
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
                        lambda n: 3 * n + 1, asbuilt_scratch, additive=additive,
                        measure=measure)
ASBUILT_DYNAMIC = Ops(_loop, _bounded, dynamic_initial, dynamic_rhs, observe_dynamic,
                      record_dynamic, _residual, lambda n: 2 * n + 2, dynamic_aux,
                      lambda n: 4 * n + 2, asbuilt_scratch, additive=additive,
                      measure=measure)

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
    ("asbuilt", "kinematic"): compile_kernels(ASBUILT_KINEMATIC, "asbuilt_kinematic",
                                              asbuilt_shared, chain_plant, __name__),
    ("asbuilt", "dynamic"): compile_kernels(ASBUILT_DYNAMIC, "asbuilt_dynamic",
                                            asbuilt_shared, chain_plant, __name__),
}

__all__ = ["ASBUILT_DYNAMIC", "ASBUILT_KINEMATIC", "KERNELS", "asbuilt_shared"]
