"""The optimiser's tuning constants, in one frozen record.

None of these changes the problem being solved (the limits, the objective, the plan's
physics); they steer how SLSQP and the exchange rounds get there, and how strictly the
result is checked. Tolerances "relative" are fractions of max(1, |limit|) (or of
max(1, |epigraph variable|) for the "peak_rate" and "margin" objectives), so that they mean
the same for a limit of 0.02 rad/s and one of 50 rad/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from flatcli.core.errors import FlatcliError


@dataclass(frozen=True)
class Tuning:
    """How the optimiser searches and checks (the defaults are ``TUNING``).

    Attributes
    ----------
    solver_tol : SLSQP's ``ftol`` on the objective divided by its starting value [-]
    exchange_rounds : rounds of the exchange method per solve (solve, re-check on the check
        grid, add the times where a limit is missed) [-]
    check_refinement : the check grid has this many times as many intervals as the constraint
        grid [-]
    backoff : limits are imposed tightened by this relative amount, so that the solver's own
        tolerance cannot show up as a violation [-]
    feasibility_tol : a plan is feasible when no limit is exceeded on the check grid by more
        than this relative amount [-]
    active_tol : a limit counts as active where its slack (as imposed) is below this relative
        amount [-]
    screen : angle, rate and peak-rate rows with more relative slack than this are left out
        of a solve (the exchange rounds restore any that end up violated) [-]
    epigraph_tol : epigraph rows ("peak_rate", "margin") are refined where the check grid
        exceeds them by more than this relative amount [-]
    tighten_cap : an exchange round tightens a violated limit by at most this relative
        amount (a larger excess comes from a screened-out row, not from between samples) [-]
    reject_floor, round_reject : a round whose plan violates a limit by more than
        ``reject_floor`` (relative) and ``round_reject`` times more than the least violating
        plan so far is discarded: the solver went astray [-]
    restart_tol : ... and the next round starts from that round's best iterate that missed
        no row of the constraint grid by more than this relative amount [-]
    margin_tie : the "margin" objective's second stage keeps the least margin within this
        fraction of the best one found [-]
    end_rate_clearance : a free end rate guess below the margin's minimum min_margin /
        |sin th1| is raised to (1 + this) times that minimum [-]
    big : stand-in for non-finite values the solver would see at a trial point on the
        singular set (values of the quantities [rad, rad/s]; their gradients become 0)
    scale_floor : floor of the objective's normalising value (energy [rad^2/s], effort
        [rad^2], peak rate or margin [rad/s]), so a zero objective never divides by 0
    gradient_floor : floor of a constraint row's gradient norm when rows are normalised
        (units of the row per unit of the decision vector)
    polish_restarts, polish_iter : when the last exchange round of an energy or effort solve
        on a chain of N >= 3 joints does not converge, SLSQP is restarted from the best plan
        up to ``polish_restarts`` times, for at most ``polish_iter`` iterations each, in
        coordinates whitened by the Gauss-Newton Hessian of the energy at the restart point
        (``solver``) [-]
    polish_floor : eigenvalues of that Hessian are floored at this fraction of the largest
        before whitening [-]
    """

    solver_tol: float = 1e-10
    exchange_rounds: int = 6
    check_refinement: int = 10
    backoff: float = 1e-7
    feasibility_tol: float = 1e-9
    active_tol: float = 1e-5
    screen: float = 0.5
    epigraph_tol: float = 1e-4
    tighten_cap: float = 1e-3
    reject_floor: float = 1e-2
    round_reject: float = 100.0
    restart_tol: float = 1e-4
    margin_tie: float = 1e-3
    end_rate_clearance: float = 1e-3
    big: float = 1e6
    scale_floor: float = 1e-12
    gradient_floor: float = 1e-8
    polish_restarts: int = 40
    polish_iter: int = 50
    polish_floor: float = 1e-9

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type == "int":
                if not isinstance(value, int) or value < 1:
                    raise FlatcliError(f"Tuning.{f.name}: must be an integer >= 1, got {value!r}")
            elif not (math.isfinite(value) and value > 0):
                raise FlatcliError(f"Tuning.{f.name}: must be finite and > 0, got {value!r}")
        if self.margin_tie >= 1:
            raise FlatcliError(f"Tuning.margin_tie: must be < 1, got {self.margin_tie!r}")


#: The tuning ``optimize_plan`` uses unless told otherwise.
TUNING = Tuning()

__all__ = ["TUNING", "Tuning"]
