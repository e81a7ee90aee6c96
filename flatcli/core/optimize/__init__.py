"""Optimised flat plans: choose the free end rates and free coefficients under limits.

The paper fixes the free end rates th1'(0) = 0.1 and th1'(T) = 0.5 rad/s by hand and uses
cubics. Here they, and every coefficient the boundary conditions leave free in a richer
basis, are decision variables of a smooth nonlinear programme solved by scipy's SLSQP. Only
the flat curve is optimised, so the plan is exactly momentum-consistent whatever the
optimiser does.

One concept per module, each importing only those above it:

=================  ==========================================================================
``tuning``         the optimiser's tuning constants, one frozen record (``Tuning``)
``quantities``     the limited quantities (angles, joint rates, margin) from the flat flag,
                   with exact derivatives by complex step
``objectives``     what can be minimised: energy, effort, peak rate, margin
``limits``         ``PlanLimits`` and the inequality rows that impose them pointwise
``affine``         the decision vector; coefficients and flat flag affine in it
``feasibility``    necessary conditions checked up front; ``required_fold``
``problem``        the nonlinear programme (objective, rows, exact Jacobians); ``Request``
``assessment``     a candidate measured on the fine check grid: feasible? what binds?
``solver``         SLSQP inside an exchange method for the semi-infinite constraints
``search``         which problems one call solves from where (multi-start, phase 1)
``api``            ``optimize_plan`` composed of named steps; ``OptimizeResult``
=================  ==========================================================================

Everything other code needs is importable from ``flatcli.core.optimize``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from flatcli.core.names import OBJECTIVES, Objective
    from flatcli.core.optimize.api import (
        DEFAULT_BSPLINE_DEGREE,
        DEFAULT_BSPLINE_SIZE,
        OptimizeResult,
        default_basis,
        optimize_plan,
    )
    from flatcli.core.optimize.feasibility import required_fold
    from flatcli.core.optimize.limits import PlanLimits
    from flatcli.core.optimize.quantities import flag_jacobian, flag_quantities
    from flatcli.core.optimize.tuning import TUNING, Tuning

#: Each public name and its module, loaded on first use (PEP 562): the spec's schema needs
#: ``OBJECTIVES``, a sweep without an optimised plan nothing else (scipy's SLSQP and the
#: nine modules above it stay unloaded).
_HOME = {
    "DEFAULT_BSPLINE_DEGREE": "api", "DEFAULT_BSPLINE_SIZE": "api", "OptimizeResult": "api",
    "default_basis": "api", "optimize_plan": "api", "required_fold": "feasibility",
    "PlanLimits": "limits", "OBJECTIVES": "objectives", "Objective": "objectives",
    "flag_jacobian": "quantities", "flag_quantities": "quantities", "TUNING": "tuning",
    "Tuning": "tuning",
}


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
    globals()[name] = value
    return value


__all__ = [
    "DEFAULT_BSPLINE_DEGREE",
    "DEFAULT_BSPLINE_SIZE",
    "OBJECTIVES",
    "TUNING",
    "Objective",
    "OptimizeResult",
    "PlanLimits",
    "Tuning",
    "default_basis",
    "flag_jacobian",
    "flag_quantities",
    "optimize_plan",
    "required_fold",
]
