"""The names of what the optimiser can minimise (all over the plan's [0, T]).

* ``"energy"``: integral of th1'^2 + th2'^2 [rad^2/s], on the composite Gauss-Legendre rule
  of ``planning.Plan.input_energy``.
* ``"effort"``: T times the energy [rad^2]: invariant under time scaling (stretching a plan
  by a factor c divides the energy by c and multiplies T by c). At fixed T a constant
  multiple of the energy: same optimum.
* ``"peak_rate"``: max of |th1'| and |th2'| [rad/s], as an epigraph variable s with
  s >= +-th1', s >= +-th2' at every grid time.
* ``"margin"``: the least signed margin [rad/s], maximised (epigraph: margin >= s).

Internally a problem may also minimise ``"violation"`` (phase 1 for a request no plan seems
to meet): the largest relative excess over the angle and rate limits, as an epigraph
variable.
"""

from __future__ import annotations

from typing import Literal

from flatcli.core.names import OBJECTIVES, Objective

#: What a ``Problem`` minimises: an objective, or the largest relative limit violation.
Goal = Literal["energy", "peak_rate", "effort", "margin", "violation"]
#: Goals with an epigraph variable s, the last decision variable.
EPIGRAPH: tuple[Goal, ...] = ("peak_rate", "margin", "violation")


def maximised(goal: Goal) -> bool:
    """Whether larger values of ``goal`` are better (only the margin)."""
    return goal == "margin"


def better(goal: Goal, a: float, b: float) -> bool:
    """Whether value ``a`` of ``goal`` is at least as good as value ``b``."""
    return a >= b if maximised(goal) else a <= b


__all__ = ["EPIGRAPH", "OBJECTIVES", "Goal", "Objective", "better", "maximised"]
