"""Tests of flatcli.core.optimize.api: ``optimize_plan`` on the paper's maneuver, and on a
chain of N >= 3 joints (the last section).

Reference values and where they come from:

* the paper's maneuver and cubic plan (Franch et al. 2003, Sec. VI; ``conftest``);
* the cubic's input energy 101.19 rad^2/s and peak |th2'| 48.8 rad/s at t = 0: as
  ``flatcli.core.plan.planning`` computes them for the paper's cubic (whose states and rates
  ``tests/test_planning.py`` checks against the full link kinematics); the optimiser's own
  starting guess must reproduce them;
* re-choosing only the cubic's end rates: a two-variable minimisation of
  ``Plan.input_energy`` of ``planning.plan_point_to_point`` by scipy's Nelder-Mead, done
  in the test (no optimiser code involved);
* the cubic's least margin sin(1) * 0.1 = 0.0841 rad/s, at t = 0 (the paper's end rate);
* the largest possible least margin, (cos th1(0) - cos th1(T)) / T = 0.4782 rad/s (the
  margin is -d(cos th1)/dt: this is its mean over [0, T]);
* the design target of the optimiser: an energy at most a third of the cubic's.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from optimize_support import (
    CHAIN_FINE,
    DURATION,
    EXACT_TOL,
    GOAL,
    START,
    base_inertia_h0,
    chain_ends,
    chain_energy,
    chain_margin,
    check_chain_plan,
    check_plan,
    fine,
    k10,
    optimize_chain,
    optimize_paper,
    peak_rate,
    signed_margin,
)
from scipy.optimize import minimize
from test_chainplan import example_chain

import flatcli.core.optimize as optimize
from flatcli.core.curves.basis import BSplineBasis, PolynomialBasis
from flatcli.core.errors import FlatcliError
from flatcli.core.optimize import OBJECTIVES, PlanLimits, optimize_plan
from flatcli.core.plan.planning import Plan, plan_chain, plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT

#: The optimiser's design target: the optimised energy is at most a third of the cubic's.
ENERGY_FRACTION = 1.0 / 3.0
#: The cubic's energy [rad^2/s] (see the module docstring).
CUBIC_ENERGY = 101.19
CUBIC_ENERGY_TOL = 0.01
#: The cubic's peak |th2'| [rad/s], at t = 0 (see the module docstring).
CUBIC_PEAK = 48.8
#: The cubic's least margin sin(1) * 0.1 [rad/s] (paper's start rate, at t = 0).
CUBIC_MARGIN = math.sin(1.0) * 0.1
#: The largest least margin on this maneuver, (cos 1 - cos 2) / 2 [rad/s].
MARGIN_CEILING = (math.cos(1.0) - math.cos(2.0)) / 2.0
#: The starting cubic rebuilt from its decision vector (pseudo-inverse plus null space):
#: observed 1.3e-12 relative in the energy.
REBUILT_TOL = 1e-9
#: Two optimisers of the same smooth two-variable problem (SLSQP to ftol 1e-10, Nelder-Mead
#: to fatol 1e-10): observed 3e-11 relative.
SAME_OPTIMUM_TOL = 1e-7


def test_public_names() -> None:
    """What other code imports from ``flatcli.core.optimize``."""
    assert set(optimize.__all__) >= {
        "DEFAULT_BSPLINE_DEGREE", "DEFAULT_BSPLINE_SIZE", "OBJECTIVES", "OptimizeResult",
        "PlanLimits", "default_basis", "flag_jacobian", "flag_quantities", "optimize_plan",
        "required_fold",
    }  # fmt: skip
    basis = optimize.default_basis(3.0)
    assert (basis.size, basis.degree, basis.duration) == (12, 5, 3.0)


# --- the design targets on the paper's maneuver ----------------------------------------


def test_energy_target(paper_plan: Plan) -> None:
    """Energy <= 1/3 of the cubic's, limits met, |H| ~ 0, margin above 0.02."""
    cubic = paper_plan.input_energy()
    assert cubic == pytest.approx(CUBIC_ENERGY, abs=CUBIC_ENERGY_TOL)
    result = optimize_paper()
    check_plan(result, PlanLimits())
    assert isinstance(result.plan.trajectory.basis, BSplineBasis)  # the default basis
    assert result.objective == pytest.approx(result.plan.input_energy(), rel=EXACT_TOL)
    # the cubic rebuilt through the affine coefficient map: equal up to amplified rounding
    assert result.initial_objective == pytest.approx(cubic, rel=REBUILT_TOL)
    assert result.objective <= ENERGY_FRACTION * cubic
    assert result.objective <= result.initial_objective
    # the optimum leans on the singularity margin (its end rates sit on it)
    assert any(a.startswith("min_margin") for a in result.active)


def test_effort_is_duration_times_energy() -> None:
    """Same optimum as "energy" at fixed T, reported as T x energy (on quintics: quick)."""
    basis = PolynomialBasis(5, 2.0)
    energy = optimize_paper(basis=basis)
    effort = optimize_paper(objective="effort", basis=basis)
    assert effort.objective == pytest.approx(2.0 * effort.plan.input_energy(), rel=EXACT_TOL)
    assert effort.plan.input_energy() == pytest.approx(energy.objective, rel=1e-6)


def test_rates_only_cubic_against_nelder_mead() -> None:
    """In the cubic basis only the end rates are free: the same optimum as Nelder-Mead on
    planning's cubic (the optimum is interior: its margin stays far above 0.02 rad/s)."""

    def energy(rates: np.ndarray) -> float:
        plan = plan_point_to_point(PAPER_ROBOT, START, GOAL, rates[0], rates[1], DURATION)
        return plan.input_energy()

    low = [0.02 / math.sin(1.0), 0.02 / math.sin(2.0)]
    reference = minimize(
        energy, [0.1, 0.5], method="Nelder-Mead", bounds=[(low[0], None), (low[1], None)],
        options={"xatol": 1e-8, "fatol": 1e-10},
    )  # fmt: skip
    result = optimize_paper(basis=PolynomialBasis(3, 2.0))
    assert result.objective == pytest.approx(reference.fun, rel=SAME_OPTIMUM_TOL)
    np.testing.assert_allclose([result.start_rate, result.goal_rate], reference.x, rtol=1e-3)
    assert np.min(signed_margin(fine(result.plan))) > 0.1


# --- each limit active and respected ----------------------------------------------------


@pytest.mark.parametrize(
    ("limits", "active"),
    [
        # th2 <= 2.8 rad, below the unconstrained optimum's 2.92 (and above the fold 2.672)
        (PlanLimits(angle_limit=(math.inf, math.inf, 2.8)), "angle_limit[2] on th2"),
        # |th'| <= 3.9 rad/s, below the unconstrained optimum's peak 4.09 rad/s
        (PlanLimits(rate_limit=3.9), "rate_limit on th2'"),
        # margin >= 0.2 rad/s, ten times the default
        (PlanLimits(min_margin=0.2), "min_margin"),
        # all at once, with a th0 bound as well
        (
            PlanLimits(angle_limit=(2.0, 2.5, 2.85), rate_limit=4.5, min_margin=0.05),
            "angle_limit[2] on th2",
        ),
    ],
    ids=["angle", "rate", "margin", "all"],
)
def test_limit_is_active_and_met(limits: PlanLimits, active: str) -> None:
    result = optimize_paper(limits=limits)
    check_plan(result, limits)
    assert any(a.startswith(active) for a in result.active), result.active
    # a binding limit costs energy, but still far less than the cubic's
    assert optimize_paper().objective <= result.objective <= ENERGY_FRACTION * CUBIC_ENERGY


def test_fixed_end_rates(paper_maneuver: Any, paper_plan: Plan) -> None:
    result = optimize_paper(free_rates=False)
    s = check_plan(result, PlanLimits())
    m = paper_maneuver
    assert (result.start_rate, result.goal_rate) == (m.start_rate, m.goal_rate)
    assert s.theta_dot[0, 1] == pytest.approx(m.start_rate, abs=EXACT_TOL)
    assert s.theta_dot[-1, 1] == pytest.approx(m.goal_rate, abs=EXACT_TOL)
    assert "fixed end rates" in result.active
    assert result.objective <= paper_plan.input_energy()
    assert result.objective >= optimize_paper().objective  # free rates can only do better


# --- the other objectives -------------------------------------------------------------


def test_peak_rate_objective() -> None:
    result = optimize_paper(objective="peak_rate")
    s = check_plan(result, PlanLimits())
    assert result.initial_objective == pytest.approx(CUBIC_PEAK, abs=0.05)
    assert result.objective == pytest.approx(peak_rate(s), rel=1e-3)
    # better than the cubic and than the least-energy plan, on its own measure
    assert result.objective < result.initial_objective / 10
    assert result.objective < peak_rate(fine(optimize_paper().plan))


def test_margin_objective() -> None:
    result = optimize_paper(objective="margin")
    s = check_plan(result, PlanLimits())
    assert result.initial_objective == pytest.approx(CUBIC_MARGIN, rel=1e-9)
    assert np.min(signed_margin(s)) == pytest.approx(result.objective, rel=1e-3)
    # the least margin can never exceed its mean; the optimum gets within 1 %
    assert 0.99 * MARGIN_CEILING <= result.objective <= MARGIN_CEILING


@pytest.mark.parametrize(
    "basis",
    [PolynomialBasis(7, 2.0), BSplineBasis(10, 2.0, 5)],
    ids=["poly7", "bspline10"],
)
def test_bases(paper_plan: Plan, basis: PolynomialBasis | BSplineBasis) -> None:
    """Each basis starts from the paper's cubic (it contains it) and reaches the target."""
    result = optimize_paper(basis=basis)
    check_plan(result, PlanLimits())
    assert result.plan.trajectory.basis is basis
    assert result.initial_objective == pytest.approx(paper_plan.input_energy(), rel=REBUILT_TOL)
    assert result.objective <= ENERGY_FRACTION * result.initial_objective


def test_never_worse_than_the_start() -> None:
    """Cut off after one iteration, the result is still no worse than the feasible cubic."""
    for objective in OBJECTIVES:
        result = optimize_paper(objective=objective, max_iter=1)
        if objective == "margin":
            assert result.objective >= result.initial_objective
        else:
            assert result.objective <= result.initial_objective


# --- infeasible and invalid requests ----------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"objective": "fast"}, r"plan\.optimize\.objective: expected one of"),
        ({"constraint_samples": 5}, r"plan\.optimize\.constraint_samples: must be >= 10"),
        ({"max_iter": 0}, r"plan\.optimize\.max_iter: must be >= 1"),
        ({"duration": 0.0}, r"plan\.duration: must be > 0 s"),
        ({"basis": PolynomialBasis(5, 3.0)}, r"its duration differs from plan\.duration"),
    ],
    ids=["objective", "samples", "max-iter", "duration", "basis"],
)
def test_invalid_arguments(kwargs: dict[str, Any], match: str) -> None:
    duration = kwargs.pop("duration", DURATION)
    with pytest.raises(FlatcliError, match=match) as info:
        optimize_plan(PAPER_ROBOT, START, GOAL, duration, **kwargs)
    assert "\n" not in str(info.value)


def test_infeasible_found_by_the_solver() -> None:
    """A rate limit above every up-front bound (2.672 rad/s, ``required_fold``) but below
    the least achievable peak: the error names that least peak, which the phase-1 solve
    (least violation) and the "peak_rate" objective must agree on.

    (Likewise th2 <= 2.675 rad, just above the fold bound: "the best plan found reaches
    |th2| = 2.676 rad"; left out here for time.)
    """
    limits = PlanLimits(rate_limit=3.0)
    with pytest.raises(FlatcliError) as info:
        optimize_plan(PAPER_ROBOT, START, GOAL, DURATION, limits=limits)
    message = str(info.value)
    assert "\n" not in message
    head = "plan.optimize.rate_limit = 3 rad/s cannot be met: the best plan found reaches |th2'| = "
    assert message.startswith(head)
    reached = float(message.removeprefix(head).split(" rad/s")[0])
    assert reached == pytest.approx(optimize_paper(objective="peak_rate").objective, abs=0.01)


# --- a chain of N >= 3 joints (the example chain of tests/test_chainplan.py) ------------
#
# Referees: the full link kinematics, differences and Simpson's rule on a dense sampling of
# the returned Plan (``optimize_support.check_chain_plan``, ``chain_energy``), the
# starting guess rebuilt by ``chainplan.plan_chain`` with the same end rates and basis, and
# the margin's mean (h_0(0) - h_0(T)) / (2 K_10 T), an upper bound of its least value (h_0
# from the link kinematics).

#: Limits the least-energy plan of the 3-joint chain breaks (it reaches |th3| = 13.8 rad and
#: |th3'| = 20.4 rad/s; |th1'| 3.0, |th2'| 4.5 rad/s): one rate limit per joint, N + 1 angles.
CHAIN_LIMITS = PlanLimits(angle_limit=(math.inf, math.inf, math.inf, 13.5),
                          rate_limit=(6.0, 6.0, 19.0))
#: Simpson's rule on 4001 samples against the optimiser's Gauss-Legendre energy.
CHAIN_ENERGY_RTOL = 1e-6


def test_chain_energy_under_per_joint_limits() -> None:
    """N = 3, least energy under a per-joint rate limit and an angle limit on th3: the plan
    meets them on a dense grid, conserves momentum, and beats the starting guess, which
    ``plan_chain`` rebuilds from the same end rates."""
    result = optimize_chain(3, limits=CHAIN_LIMITS)
    assert result.success, result.message
    s = check_chain_plan(result, 3, CHAIN_LIMITS)
    assert chain_energy(s) == pytest.approx(result.objective, rel=CHAIN_ENERGY_RTOL)
    # the rate limit on th3 binds
    assert np.max(np.abs(s.theta_dot[:, 3])) == pytest.approx(19.0, rel=1e-4)
    # the starting guess: min-acceleration plan of the same basis with the initial end rates
    start, goal = chain_ends(3)
    rates = [0.1, 0.1], [0.5, 0.5]
    guess = plan_chain(example_chain(3), start, goal, *rates, DURATION, optimize.default_basis(2.0))
    guess_energy = chain_energy(guess.sample(guess.grid(CHAIN_FINE)))
    assert result.initial_objective == pytest.approx(guess_energy, rel=CHAIN_ENERGY_RTOL)
    assert result.objective < guess_energy / 5


def test_chain_peak_rate() -> None:
    """N = 3: the least peak joint rate, as the dense sampling measures it, below the
    starting guess's."""
    result = optimize_chain(3, objective="peak_rate")
    assert result.success, result.message
    s = check_chain_plan(result, 3)
    assert float(np.max(np.abs(s.theta_dot[:, 1:]))) == pytest.approx(result.objective, rel=1e-3)
    assert result.objective < result.initial_objective / 5


def test_chain_margin_reaches_its_mean() -> None:
    """N = 3: the least margin can never exceed its mean over the maneuver; the optimum gets
    within Tuning.margin_tie of it, and the solve (two stages) converges."""
    result = optimize_chain(3, objective="margin")
    assert result.success, result.message
    s = check_chain_plan(result, 3)
    robot = example_chain(3)
    start, goal = chain_ends(3)
    h0 = base_inertia_h0(robot, np.vstack([start, goal]))
    ceiling = abs(h0[0] - h0[1]) / (2.0 * abs(k10(robot)) * DURATION)
    assert (1 - 2 * optimize.TUNING.margin_tie) * ceiling <= result.objective <= ceiling
    margin = chain_margin(robot, s.t, s.theta)
    assert float(np.min(np.sign(margin[0]) * margin)) == pytest.approx(result.objective, rel=1e-3)
    assert result.objective > result.initial_objective


def test_chain_of_four_is_never_worse_than_its_start() -> None:
    """N = 4, cut short (few samples and iterations): whatever the solver reached, the plan is
    a valid plan of the chain, no worse than the starting guess."""
    result = optimize_chain(4, constraint_samples=41, max_iter=60)
    s = check_chain_plan(result, 4)
    assert result.objective <= result.initial_objective
    assert len(result.start_rates) == len(result.goal_rates) == 3
    # the energy recomputed by Simpson's rule on the dense samples
    assert chain_energy(s) == pytest.approx(result.objective, rel=CHAIN_ENERGY_RTOL)
    # 60 iterations cannot converge on 38 decision variables: the result says so, and what
    # limited it
    assert not result.success
    assert "plan.optimize.max_iter = 60 iterations" in result.message
    assert "not a converged optimum" in result.message


def test_chain_of_four_energy_converges() -> None:
    """N = 4, least energy with the defaults: SLSQP alone crawls on this chain (iteration
    limit at 608.5 after 600 iterations); restarted in coordinates whitened by the energy's
    Gauss-Newton Hessian it converges. The plan conserves momentum and meets its ends on the
    dense grid, and its energy, recomputed by Simpson's rule, is the one reported, far below
    the starting guess's."""
    result = optimize_chain(4)
    assert result.success, result.message
    s = check_chain_plan(result, 4)
    assert chain_energy(s) == pytest.approx(result.objective, rel=CHAIN_ENERGY_RTOL)
    assert result.objective < result.initial_objective / 5


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"start": [0.0, 1.0, 0.3]}, r"^plan\.start: expected 4 angles"),
        ({"goal": [0.4, 2.0, 0.6, 0.0, 0.0]}, r"^plan\.goal: expected 4 angles"),
        ({"start_rate": [0.1, 0.1, 0.1]}, r"^plan\.start_rate: expected one number or 2"),
        ({"goal_rate": [[0.5, 0.5]]}, r"^plan\.goal_rate: expected one number or 2"),
        ({"model": "paper"}, r"^robot\.model: 'paper' .* three-link robot only"),
        ({"limits": PlanLimits(angle_limit=(3.0, 3.0, 3.0))},
         r"^plan\.optimize\.angle_limit: expected 4 numbers"),
        ({"limits": PlanLimits(rate_limit=(5.0, 5.0))},
         r"^plan\.optimize\.rate_limit: expected a number or 3"),
        # th1 must move 1 rad in 2 s
        ({"limits": PlanLimits(rate_limit=(0.4, 9.0, 9.0))},
         r"^plan\.optimize\.rate_limit\[0\] = 0\.4 rad/s cannot be met: th1 must move 1 rad"),
        ({"limits": PlanLimits(min_margin=5.0)},
         r"^plan\.optimize\.min_margin = 5 rad/s cannot be met: the margin"),
    ],
)
def test_chain_bad_input(kwargs: dict[str, Any], match: str) -> None:
    """One line naming the key, before any solve."""
    start, goal = chain_ends(3)
    args = {"start": start, "goal": goal, **kwargs}
    with pytest.raises(FlatcliError, match=match) as info:
        optimize_plan(example_chain(3), args.pop("start"), args.pop("goal"), DURATION, **args)
    assert "\n" not in str(info.value)


def test_chain_rate_limit_below_the_least_peak() -> None:
    """A rate limit below the least achievable peak rate (16.05 rad/s on this chain, the
    "peak_rate" optimum) is refused in one line naming rate_limit and the rate reached."""
    with pytest.raises(FlatcliError, match=r"^plan\.optimize\.rate_limit = 5 rad/s cannot be "
                       r"met: the best plan found reaches \|th\d'\| = [\d.]+ rad/s") as info:
        optimize_chain(3, limits=PlanLimits(rate_limit=5.0), constraint_samples=41, max_iter=60)
    assert "\n" not in str(info.value)


def test_the_package_names_each_of_its_contents_from_the_module_that_defines_it() -> None:
    """The package loads its modules on first use (PEP 562): every name in ``__all__`` is
    the very object its defining module holds (the referee: importlib, module by module, and
    the source text that defines it), and a name it does not have is an AttributeError."""
    import importlib
    import inspect

    for name in optimize.__all__:
        value = getattr(optimize, name)
        home = importlib.import_module(f"flatcli.core.optimize.{optimize._HOME[name]}")
        assert getattr(home, name) is value, name
        assert f"{name}" in inspect.getsource(home), name
    with pytest.raises(AttributeError, match="no_such_name"):
        optimize.no_such_name  # noqa: B018
