"""The continuous-time proof (flatcli/core/plan/clearance.py): tests that fail when a bound
is wrong.

Referees, none of them the code under test: the links placed in the complex plane from
their definitions (tests/task_referees.py); each plan sampled densely on random time
intervals (hypothesis) through its own maps, which the bounds must contain; the distance of
a point from a segment written out in complex numbers; random points of random boxes.
Every constraint (obstacles and their radii, task.clearance, each angle and rate limit, the
margin) is shown to change the verdict on both sides of its value; NaN and empty bounds are
never proven; the proof's budget is exact to the interval; a violation at either end of
[0, T] is found.

(tests/test_tasks_core.py has the end-to-end checks: a disc planted between two samples, a
proven plan re-checked 100x finer, a disc beside a slanted link.)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.plan import clearance as cl
from flatcli.core.plan.clearance import Constraints, certify, point_slack, sampled_slack
from flatcli.core.plan.intervals import Interval
from flatcli.core.plan.planning import Plan, plan_point_to_point
from flatcli.core.plan.rest import plan_rest_to_rest
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams
from tests import task_referees as ref

Array = NDArray[np.float64]

START = np.array([1.8, 1.0, 0.0])  # the paper's maneuver, Sec. VI
GOAL = np.array([1.2, 2.0, 0.0])
CHAIN4 = RobotParams(mass=(2.0, 1.0, 1.0, 0.5), inertia=(0.1, 0.0533, 0.0533, 0.15),
                     length=(0.3, 0.2, 0.2, 0.2), com=(0.1, 0.1, 0.1, 0.0))  # robots/chain4
CHAIN5 = RobotParams(mass=(3.0, 1.2, 0.8, 0.6, 0.4), inertia=(0.15, 0.04, 0.03, 0.03, 0.2),
                     length=(0.4, 0.25, 0.2, 0.2, 0.15), com=(0.15, 0.12, 0.1, 0.1, 0.0))
#: Samples of the plan's own maps are rounded too: the bounds hold them to this [rad, rad/s,
#: m] (a hundred roundings of terms of size up to 1e3).
SAMPLE_TOL = 1e-9


def _plans() -> dict[str, Plan]:
    chain_start = np.array([0.0, 1.0, 0.3, 0.0])
    chain_goal = np.array([-0.75, 2.0, 0.6, 0.0])
    five_start = np.array([0.3, 0.8, 0.5, 0.4, 0.0])
    five_goal = np.array([0.1, 1.3, 0.9, 0.7, 0.0])
    return {
        "paper": plan_point_to_point(PAPER_ROBOT, START, GOAL, 0.1, 0.5, 2.0),
        "paper rest": plan_rest_to_rest(PAPER_ROBOT, START, GOAL, 2.0, skew=0.3),
        "chain4": plan_point_to_point(CHAIN4, chain_start, chain_goal, [0.3, 0.3], [0.5, 0.5],
                                      2.0),
        "chain4 rest": plan_rest_to_rest(CHAIN4, chain_start, chain_goal, 2.0),
        "chain5 rest": plan_rest_to_rest(CHAIN5, five_start, five_goal, 1.5, skew=-0.3),
    }


PLANS = _plans()


@settings(deadline=None, max_examples=60)
@given(name=st.sampled_from(sorted(PLANS)), start=st.floats(0.0, 1.0),
       width=st.sampled_from([1.0, 0.25, 1e-2, 1e-4, 1e-7]))
def test_the_bounds_contain_the_plan_on_any_interval(name: str, start: float,
                                                      width: float) -> None:
    """Angles, rates and the signed margin of 41 samples of a random time interval (the
    ends included: a rest plan's 0/0 limits there) lie within their bounds, for the paper's
    robot and chains of 3 and 4 joints, rest or not."""
    plan = PLANS[name]
    breaks, local = plan.trajectory.piecewise()
    piece = min(int(start * (len(breaks) - 1)), len(breaks) - 2)
    lo = min(start, 1.0 - width) if width < 1.0 else 0.0
    hi = lo + width
    widths = np.diff(breaks)[[piece]]
    with np.errstate(all="ignore"):
        theta, rates, margin = cl._bounds(plan, local[[piece]], widths, np.array([lo]),
                                          np.array([hi]))
    t = breaks[piece] + widths[0] * np.linspace(lo, hi, 41)
    if name.endswith("rest"):  # the maps are 0/0 at rest: eps / t off near the ends, so
        # samples within 1e-4 T of them are not a referee (the ends use their limits)
        near = np.minimum(t, plan.duration - t)
        t = t[(near == 0) | (near > 1e-4 * plan.duration)]
    s = plan.sample(t)
    sigma = plan.signed_margin(t) if not name.endswith("rest") else None
    for a in range(plan.n_joints + 1):
        for values, bound in ((s.theta[:, a], theta[a]), (s.theta_dot[:, a], rates[a])):
            finite = np.isfinite(values)
            assert np.all(values[finite] >= bound.lo[0] - SAMPLE_TOL), (name, a)
            assert np.all(values[finite] <= bound.hi[0] + SAMPLE_TOL), (name, a)
    if sigma is not None:
        assert np.all(sigma >= margin.lo[0] - SAMPLE_TOL) and np.all(
            sigma <= margin.hi[0] + SAMPLE_TOL)


@pytest.mark.parametrize("name", sorted(PLANS))
def test_the_bounds_shrink_to_the_plan(name: str) -> None:
    """On intervals 1e-6 of a piece wide every angle's bound is within 1e-3 rad of the
    angle (first-order convergence: a bound that is sound only by being wide never proves)."""
    plan = PLANS[name]
    breaks, local = plan.trajectory.piecewise()
    centres = np.linspace(0.05, 0.95, 7)
    lo, hi = centres - 5e-7, centres + 5e-7
    piece = np.zeros(len(centres), dtype=int)
    theta, _, _ = cl._bounds(plan, local[piece], np.diff(breaks)[piece], lo, hi)
    s = plan.sample(breaks[0] + np.diff(breaks)[0] * centres)
    for a in range(plan.n_joints + 1):
        assert np.all(theta[a].hi - theta[a].lo < 1e-3), (name, a)
        assert np.all(np.abs(s.theta[:, a] - 0.5 * (theta[a].lo + theta[a].hi)) < 1e-3)


@settings(deadline=None, max_examples=300)
@given(ax=st.floats(-1, 1), ay=st.floats(-1, 1), bx=st.floats(-1, 1), by=st.floats(-1, 1),
       ra=st.tuples(st.floats(0, 0.2), st.floats(0, 0.2)),
       rb=st.tuples(st.floats(0, 0.2), st.floats(0, 0.2)), u=st.floats(0, 1),
       v=st.floats(0, 1), w=st.floats(0, 1), z=st.floats(0, 1), cx=st.floats(-1.5, 1.5),
       cy=st.floats(-1.5, 1.5))
def test_a_segments_distance_bound_is_below_every_segment_in_the_boxes(
        ax: float, ay: float, bx: float, by: float, ra: tuple[float, float],
        rb: tuple[float, float], u: float, v: float, w: float, z: float, cx: float,
        cy: float) -> None:
    """Two boxes (centres a, b, half sizes ra, rb), a segment p q with p in box a and q in
    box b (random corners' mix), a point c: both bounds of the proof (the distance to the
    joints' box hull, the segment bound) are at most c's distance from p q (the referee's
    complex-plane distance)."""
    box_a = (Interval(np.array([ax - ra[0]]), np.array([ax + ra[0]])),
             Interval(np.array([ay - ra[1]]), np.array([ay + ra[1]])))
    box_b = (Interval(np.array([bx - rb[0]]), np.array([bx + rb[0]])),
             Interval(np.array([by - rb[1]]), np.array([by + rb[1]])))
    p = complex(ax + (2 * u - 1) * ra[0], ay + (2 * v - 1) * ra[1])
    q = complex(bx + (2 * w - 1) * rb[0], by + (2 * z - 1) * rb[1])
    c = complex(cx, cy)
    truth = ref.segment_distance(p, q, c)
    centre = np.array([cx, cy])
    segment = float(cl._segment_distance_bound(box_a, box_b, centre)[0])
    hull = (box_a[0].hull(box_b[0]), box_a[1].hull(box_b[1]))
    boxed = float(cl._box_distance(hull, centre)[0])
    assert segment <= truth + 1e-15 and boxed <= truth + 1e-15
    # both exact (to rounding) for boxes shrunk to points
    if ra == (0.0, 0.0) and rb == (0.0, 0.0):
        assert truth - segment < 1e-12


def test_the_joint_boxes_hold_the_referees_joints() -> None:
    """Joint boxes from angle intervals contain the joints the referee places from any
    angles inside them (random intervals, 200 samples each), for N = 2, 3, 4."""
    rng = np.random.default_rng(5)
    for robot, plan in ((PAPER_ROBOT, PLANS["paper"]), (CHAIN4, PLANS["chain4"]),
                        (CHAIN5, PLANS["chain5 rest"])):
        n = robot.n_joints + 1
        lo = rng.uniform(-3, 3, (20, n))
        hi = lo + rng.uniform(0, 0.3, (20, n))
        theta = [Interval(lo[:, a], hi[:, a]) for a in range(n)]
        boxes = cl._joint_boxes(plan, theta)
        inside = lo[:, None, :] + (hi - lo)[:, None, :] * rng.uniform(0, 1, (20, 200, n))
        z = ref.joints(robot, inside)  # (20, 200, N + 2)
        for k, (bx, by) in enumerate(boxes):
            assert np.all(z[..., k].real >= bx.lo[:, None] - 1e-15)
            assert np.all(z[..., k].real <= bx.hi[:, None] + 1e-15)
            assert np.all(z[..., k].imag >= by.lo[:, None] - 1e-15)
            assert np.all(z[..., k].imag <= by.hi[:, None] + 1e-15)


def _dense(plan: Plan, obstacles: Array, samples: int = 20001) -> float:
    s = plan.sample(np.linspace(0.0, plan.duration, samples))
    return float(ref.link_clearance(plan.robot, s.theta, obstacles).min())


@pytest.mark.parametrize("name", ["paper rest", "chain4", "chain4 rest"])
def test_task_clearance_and_the_radius_each_decide_the_verdict(name: str) -> None:
    """A disc at a known distance d from the links (the referee's dense minimum): proven
    clear with task.clearance below d, refuted above it; the radius moves d the same way.
    A proof that ignored either would say ok on both sides."""
    plan = PLANS[name]
    coarse = plan.sample(np.linspace(0.0, plan.duration, 401)).theta
    grid = np.array([[x, y, 0.0] for x in np.arange(-0.6, 0.61, 0.05)
                     for y in np.arange(-0.6, 0.61, 0.05)])
    near = cl.clearances(plan, grid, coarse).min(axis=(0, 1))  # (only to choose a point)
    x, y, _ = grid[int(np.flatnonzero((near > 0.03) & (near < 0.08))[0])]
    tip = complex(x, y)  # a point 3 to 8 cm from the links' sweep
    point = np.array([[tip.real, tip.imag, 1e-9]])
    d = _dense(plan, point)
    assert 0.01 < d < 0.2
    ok = certify(plan, Constraints(point, 0.9 * d))
    assert ok.ok and ok.lower_bound <= d
    bad = certify(plan, Constraints(point, 1.1 * d))
    assert not bad.ok and "within task.clearance of obstacle 0" in bad.reason
    assert _dense(plan, point) - 1.1 * d < 0  # the refusal is true
    assert certify(plan, Constraints(np.array([[tip.real, tip.imag, 0.9 * d]]), 0.0)).ok
    assert not certify(plan, Constraints(np.array([[tip.real, tip.imag, 1.1 * d]]), 0.0)).ok


@pytest.mark.parametrize("where", [0.003, 0.997])
def test_a_violation_at_either_end_of_the_maneuver_is_found(where: float) -> None:
    """A disc that only the first (last) 0.6 % of [0, T] touches: every piece of [0, T] is
    examined, the first and the last included."""
    plan = PLANS["paper"]
    t = where * plan.duration
    z = ref.joints(PAPER_ROBOT, plan.sample(np.array([t])).theta)[0]
    disc = np.array([[z[-1].real, z[-1].imag, 1e-3]])
    cert = certify(plan, Constraints(disc, 0.0))
    assert not cert.ok
    assert ref.link_clearance(PAPER_ROBOT, plan.sample(np.array([cert.time])).theta,
                              disc)[0] < 0


def test_each_limit_decides_the_verdict_on_both_sides() -> None:
    """Every angle limit (th0, th1, th2), every rate limit (th1', th2') and the margin's
    minimum, set 0.1 % beyond and within the plan's dense extreme: proven, then refuted
    naming that limit."""
    plan = PLANS["paper"]
    fine = plan.sample(np.linspace(0.0, plan.duration, 20001))
    none = np.zeros((0, 3))
    inf = math.inf
    for a in range(3):
        peak = float(np.abs(fine.theta[:, a]).max())
        limit = np.full(3, inf)
        limit[a] = 1.001 * peak
        assert certify(plan, Constraints(none, 0.0, limit)).ok
        limit[a] = 0.999 * peak
        cert = certify(plan, Constraints(none, 0.0, limit))
        assert not cert.ok and f"abs th{a} beyond its angle limit" in cert.reason
    for j in (1, 2):
        peak = float(np.abs(fine.theta_dot[:, j]).max())
        rate = np.full(2, inf)
        rate[j - 1] = 1.001 * peak
        assert certify(plan, Constraints(none, 0.0, None, rate)).ok
        rate[j - 1] = 0.999 * peak
        cert = certify(plan, Constraints(none, 0.0, None, rate))
        assert not cert.ok and f"abs th{j}' beyond its rate limit" in cert.reason
    least = float(fine.margin.min())
    assert certify(plan, Constraints(none, 0.0, min_margin=0.999 * least)).ok
    cert = certify(plan, Constraints(none, 0.0, min_margin=1.001 * least))
    assert not cert.ok and "the margin below its minimum" in cert.reason


def test_a_chains_limits_decide_the_verdict_too() -> None:
    plan = PLANS["chain4"]
    fine = plan.sample(np.linspace(0.0, plan.duration, 20001))
    inf = math.inf
    peak = float(np.abs(fine.theta[:, 3]).max())
    rate = float(np.abs(fine.theta_dot[:, 3]).max())
    none = np.zeros((0, 3))
    assert certify(plan, Constraints(none, 0.0, np.array([inf, inf, inf, 1.001 * peak]),
                                     np.array([inf, inf, 1.001 * rate]))).ok
    assert not certify(plan, Constraints(none, 0.0, np.array([inf, inf, inf, 0.999 * peak]))).ok
    assert not certify(plan, Constraints(none, 0.0, None,
                                         np.array([inf, inf, 0.999 * rate]))).ok


def _broken(kind: str) -> Any:
    def bounds(plan: Plan, local: Array, width: Array, s_lo: Array, s_hi: Array) -> Any:
        n = len(s_lo)
        good = Interval(np.zeros(n), np.zeros(n))
        bad = (Interval(np.full(n, math.nan), np.full(n, math.nan)) if kind == "nan"
               else Interval(np.ones(n), np.zeros(n)))
        return [bad, good, good], [good, good, good], good
    return bounds


@pytest.mark.parametrize("kind", ["nan", "empty"])
def test_nan_and_empty_bounds_are_never_proven(kind: str, monkeypatch: pytest.MonkeyPatch
                                               ) -> None:
    """Bounds with a NaN end, or empty (lo > hi), prove nothing: the check goes on halving
    (and gives up), never says ok. (Real bounds are never empty; NaN comes from inf - inf
    next to the singular set.)"""
    monkeypatch.setattr(cl, "_bounds", _broken(kind))
    far = np.array([[10.0, 10.0, 0.1]])
    cert = certify(PLANS["paper"], Constraints(far, 0.0), max_intervals=2000)
    assert not cert.ok
    worst, _ = cl._slack(PLANS["paper"], Constraints(far, 0.0), *_broken(kind)(
        None, None, None, np.zeros(3), np.ones(3)))  # type: ignore[arg-type]
    assert np.all(worst == -math.inf)


def test_the_interval_budget_is_exact() -> None:
    """A far disc is proven on the 64 starting pieces: a budget of 64 intervals proves it,
    63 does not (and says so)."""
    plan = PLANS["paper"]
    far = Constraints(np.array([[5.0, 5.0, 0.1]]), 0.0)
    done = certify(plan, far)
    assert done.ok and done.intervals == cl.START_PIECES
    assert certify(plan, far, max_intervals=cl.START_PIECES).ok
    short = certify(plan, far, max_intervals=cl.START_PIECES - 1)
    assert not short.ok and f"not proven within {cl.START_PIECES - 1} intervals" in short.reason


def test_an_undecided_touch_is_not_proven() -> None:
    """A disc 1e-6 m beyond task.clearance at its nearest (clearance = the dense minimum less
    1e-6 m): provable only on intervals far shorter than a min_width of 1e-3 T, so the check
    says undecided near the touch, at once (no counterexample exists), never ok."""
    plan = PLANS["paper rest"]
    z = ref.joints(PAPER_ROBOT, plan.sample(np.array([0.8])).theta)[0]
    point = np.array([[z[-1].real + 0.03, z[-1].imag, 1e-9]])
    d = _dense(plan, point, 200001)
    cert = certify(plan, Constraints(point, d - 1e-6), min_width=1e-3)
    assert not cert.ok and cert.reason.startswith("undecided within 0.001 T of t = ")
    assert cert.intervals < 10 * cl.START_PIECES * 10


def test_the_lower_bound_is_below_the_truth_and_above_the_clearance() -> None:
    plan = PLANS["chain4 rest"]
    obstacles = np.array([[0.3, 0.25, 0.03], [-0.3, 0.3, 0.04]])
    cert = certify(plan, Constraints(obstacles, 0.005))
    truth = _dense(plan, obstacles)
    assert cert.ok and 0.005 <= cert.lower_bound <= truth


def test_constraints_are_validated() -> None:
    for obstacles in ([[0.0, 0.0, 0.0]], [[0.0, 0.0, -1.0]], [[math.nan, 0.0, 1.0]],
                      [[0.0, math.inf, 1.0]]):
        with pytest.raises(FlatcliError, match=r"^task\.obstacles"):
            Constraints(np.array(obstacles))
    for clearance in (-1e-9, math.nan, math.inf):
        with pytest.raises(FlatcliError, match=r"^task\.clearance"):
            Constraints(np.zeros((0, 3)), clearance)


def test_the_samples_screen_names_a_violation_and_a_nan_as_one() -> None:
    """sampled_slack and point_slack: a NaN state counts as a violation (-inf), not as
    clear; the slack at a sample is the referee's clearance less task.clearance."""
    plan = PLANS["paper"]
    disc = np.array([[0.25, 0.2, 0.05]])
    got = sampled_slack([plan], Constraints(disc, 0.01), 65)
    s = plan.sample(np.linspace(0.0, plan.duration, 65))
    assert got[0] == pytest.approx(ref.link_clearance(PAPER_ROBOT, s.theta, disc).min() - 0.01,
                                   abs=1e-12)
    worst, what = point_slack(plan, Constraints(disc, 0.01), np.array([0.5]))
    assert worst[0] == pytest.approx(ref.link_clearance(
        PAPER_ROBOT, plan.sample(np.array([0.5])).theta, disc)[0] - 0.01, abs=1e-12)
    assert what[0].startswith("link ")


def test_an_exact_plan_is_refused_in_one_line() -> None:
    from flatcli.core.plan.exact import plan_exact

    built = RobotParams(com=(0.1, 0.1, 0.003))
    plan = plan_exact(built, START, GOAL, 0.1, 0.5, 2.0)
    with pytest.raises(FlatcliError, match=r"^task\.obstacles: continuous-time checks need"):
        certify(plan, Constraints(np.array([[1.0, 1.0, 0.1]])))


def test_a_nan_state_at_a_sample_screens_the_candidate_out(monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """A candidate whose states are NaN at a sample (its maps overflowed) has slack -inf at
    the samples, as a violation: the screen never passes what it cannot evaluate."""
    plan = PLANS["paper"]
    real = type(plan).states_of

    def nan_states(plans: Any, t: Array) -> Any:
        theta, theta_dot, margin = real(plans, t)
        theta = theta.copy()
        theta[..., 3, :] = math.nan
        return theta, theta_dot, margin

    monkeypatch.setattr(type(plan), "states_of", staticmethod(nan_states))
    disc = np.array([[5.0, 5.0, 0.1]])
    assert sampled_slack([plan], Constraints(disc, 0.0), 65).tolist() == [-math.inf]
