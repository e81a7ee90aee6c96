"""Probe (issue 41, item 1): a per-trial global-error estimate carried along the trajectory,
prototyped in Python on flatcli's real closed loops and measured against DOP853 at rtol 1e-12.

Inside flatcli's reference path (``simulate(..., integrator="dop853")``) ``solve_ivp`` is
intercepted: for each trial integrated in one piece (no crossing of the singular set, no
noise) it runs a Python Dormand-Prince 5(4) with flatcli's default tolerances and a step-size
controller like ``adaptive_trial``'s (safety 0.9, growth within [0.2, 10], none after a
rejection), on the compiled right-hand side, and estimates the global error e of the angles:

* each accepted step's order-5 local error le = x_n+1 - x_n - Q, Q an interpolatory quadrature
  of f over the step with ``--nodes`` nodes: the step's ends, f at the output samples inside it
  (flatcli evaluates f there for its metrics anyway: counted in one solution's cost), placed on
  a degree-7 Hermite through the last 4 step ends, and older nodes (``--lookback`` steps, span
  < ``--span`` h, nodes >= 0.05 h apart); (``adaptive_trial`` observes the samples on its
  order-4 dense output: built there, such an estimate would observe the Hermite's states
  instead, changing those metrics in the last digits, or pay one evaluation a sample);
* steps with fewer than ``--extra`` samples inside get f at extra points (paid) to reach it;
* a fallback (one 7-stage Butcher RK6 step from x_n, 6 evaluations; or Richardson, two half
  steps, 11) where the quadrature has too few nodes, where |le| > ``--guard`` |embedded
  error|, and on steps with < 2 samples before ``--early`` s; where two quadratures (all nodes,
  and without the 2 oldest) differ by more than ``--agree`` |le| (floor 0.3 x the mean |le| of
  the last 10 steps), two RK6 half steps (13 evaluations);
* with a rate limit (``--loop limit``), a step whose stages, ends or samples do not all have
  the same joints clipped is split where the clipping changes (bisection on the dense output,
  6 evaluations, then two DOPRI sub-steps: 11), and older nodes are dropped there (f has a
  kink: no polynomial estimate sees it);
* e <- e + h J e + le after each step, J e by one forward difference at the step's end.

``--mode exact`` replaces every local error by the exact one (DOP853 at rtol 1e-13 over the
step: free here, not counted), to test the carrying alone. The true error is the DOPRI's final
angles against DOP853 (rtol 1e-12, atol 1e-14) on the same right-hand side; trials whose true
error is 1e-3 rad or more (diverged) are left out as unresolved. Cost: the evaluations the
estimate adds (extra points, fallbacks, splits, J e) over one solution's (samples included).

Run from the repository root, e.g. ``python -m benchmarks.probes.local_error dynamic``
(30-90 s a loop; loops: printed, swapped, dynamic, limit (0.6 rad/s), chain4, chain4-dynamic).

Measured 2026-12-06 with the defaults (30 trials; swapped with ``--trials 45``: 29-30 of them
resolved and in one piece), within 3x of the true error / resolved trials, cost median (max):

| loop | seed 7 | seed 11 | seed 13 | cost |
|---|---|---|---|---|
| printed gains | 30/30 (0.81-1.04) | 30/30 | 30/30 | +11.5 % (12.4) |
| swapped gains | 26/29 (0.15-7.3) | 29/29 | 28/30 | +8.8 % (64: near-singular passages) |
| dynamic plant | 29/30 (0.35-19.5) | 29/30 | 28/30 | +13.9 % (14.9) |
| rate limit 0.6 rad/s | 30/30 (0.61-2.71) | 30/30 | 30/30 | +14.0 % (15.2) |
| chain N = 4, kinematic | 30/30 (1.05-1.07) | | | +5.9 % |
| chain N = 4, dynamic | 16/30 (0.03-5.8) | | | +10.5 % |

With ``--mode exact`` (the carrying alone): dynamic 30/30 (0.72-1.61), chain4-dynamic 30/30
(0.44-0.90), swapped 28/29 (the miss: a trial whose final error, 7.8e-11, is 1/250 of the
median). What fails is the local error where the servo or the gains are stiff for the step
(true local errors 20-100x below the embedded estimate; quadrature and one RK6 step both off
by 0.3-6x there, RK6 on every step of chain4-dynamic gives 18/30), which matters on trials
whose final error is 10-250x below the loop's median (the estimate's own error is 7-9 % of the
median true error): the goal's 3x band on every trial asks for local errors accurate to ~1 %.
The carry's J e (one evaluation a step) is 11.7 % of the dynamic plant's solution by itself.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.integrate as si
from numpy.typing import NDArray
from scipy.integrate._ivp.rk import RK45

from flatcli.core.names import DEFAULT_ATOL, DEFAULT_RTOL

Array = NDArray[np.float64]
Rhs = Callable[[float, Array], Array]

_SOLVE_IVP = si.solve_ivp
_C, _A, _B, _E, _P = RK45.C, RK45.A, RK45.B, RK45.E, RK45.P
#: Butcher's 7-stage order-6 method (Butcher, Numerical Methods for ODEs, 2008, Sec. 325)
_C6 = np.array([0, 1 / 3, 2 / 3, 1 / 3, 1 / 2, 1 / 2, 1])
_A6 = np.zeros((7, 7))
_A6[1, :1] = [1 / 3]
_A6[2, :2] = [0, 2 / 3]
_A6[3, :3] = [1 / 12, 1 / 3, -1 / 12]
_A6[4, :4] = [-1 / 16, 9 / 8, -3 / 16, -3 / 8]
_A6[5, :5] = [0, 9 / 8, -3 / 8, -3 / 4, 1 / 2]
_A6[6, :6] = [9 / 44, -9 / 11, 63 / 44, 18 / 11, 0, -16 / 11]
_B6 = np.array([11 / 120, 0, 27 / 40, 27 / 40, -4 / 15, -4 / 15, 11 / 120])
#: The loops: (gains swapped, plant, rate limit [rad/s])
LOOPS: dict[str, tuple[bool, Literal["kinematic", "dynamic"], float]] = {
    "printed": (False, "kinematic", math.inf), "swapped": (True, "kinematic", math.inf),
    "dynamic": (False, "dynamic", math.inf), "limit": (False, "kinematic", 0.6)}


@dataclass
class Options:
    """The estimate's settings (see the module docstring)."""

    mode: str = "quadrature"
    nodes: int = 10
    lookback: int = 6
    span: float = 12.0
    guard: float = 1.0
    extra: int = 2
    agree: float = 1.0
    early: float = 0.0
    fallback: str = "rk6"
    kink: bool = True
    rate_limit: float = math.inf
    rate_rows: tuple[int, ...] = ()


@dataclass
class Count:
    """Right-hand-side evaluations of one trial: the solution's (samples included) and each
    part of the estimate's."""

    solution: int = 1
    extra: int = 0
    fallback: int = 0
    split: int = 0
    carry: int = 0
    steps: int = 0

    def added(self) -> int:
        return self.extra + self.fallback + self.split + self.carry


@dataclass
class Trial:
    """One trial's estimate / true final angle error, the true error [rad], its counts."""

    ratio: float
    true: float
    count: Count = field(default_factory=Count)


def quadrature_weights(nodes: Array) -> Array:
    """Weights (m,) of the interpolatory rule on nodes (m,) (in units of the step) for the
    integral over [0, 1]."""
    m = nodes.shape[0]
    return np.asarray(np.linalg.solve(np.vander(nodes, m, increasing=True).T,
                                      1.0 / np.arange(1, m + 1)), dtype=float)


def hermite(ts: Array, xs: Array, fs: Array, t: float) -> Array:
    """The Hermite polynomial through values xs (m, nx) and derivatives fs (m, nx) at ts (m,)
    (all scaled to the step), at t."""
    deg = 2 * ts.shape[0]
    k = np.arange(deg)
    rows = np.vstack([ts[:, None] ** k, np.where(k > 0, k * ts[:, None] ** np.maximum(k - 1, 0),
                                                 0.0)])
    coef = np.linalg.solve(rows, np.vstack([xs, fs]))
    return np.asarray(t ** k @ coef, dtype=float)


def dopri_step(f: Rhs, t: float, x: Array, h: float, k0: Array) -> Array:
    """One Dormand-Prince 5 step (5 evaluations: k0 = f(t, x) given)."""
    k = np.zeros((7, x.size))
    k[0] = k0
    for s in range(1, 6):
        k[s] = f(t + _C[s] * h, x + h * (_A[s, :s] @ k[:s]))
    return np.asarray(x + h * (_B @ k[:6]), dtype=float)


def rk6_step(f: Rhs, t: float, x: Array, h: float, k0: Array) -> Array:
    """One step of Butcher's RK6 (6 evaluations: k0 = f(t, x) given)."""
    k = np.zeros((7, x.size))
    k[0] = k0
    for s in range(1, 7):
        k[s] = f(t + _C6[s] * h, x + h * (_A6[s, :s] @ k[:s]))
    return np.asarray(x + h * (_B6 @ k), dtype=float)


def exact_local(f: Rhs, t: float, x: Array, h: float) -> Array:
    """The exact flow from (t, x) over h (DOP853 at rtol 1e-13, atol 1e-16)."""
    sol = _SOLVE_IVP(f, (t, t + h), x, method="DOP853", rtol=1e-13, atol=1e-16)
    return np.asarray(sol.y[:, -1], dtype=float)


def estimate(f: Rhs, t0: float, t_end: float, x0: Array, samples: Array, o: Options
             ) -> tuple[Array, Array, Count]:
    """The DOPRI's final state, the estimate of its global error (nx,) and the counts."""
    x = np.array(x0, dtype=float)
    t, k1, h = t0, f(t0, x), 1e-3
    e = np.zeros_like(x)
    count = Count()
    pool: list[tuple[float, Array]] = []  # (time, f) nodes of earlier steps
    ends: list[float] = []
    hist: list[tuple[float, Array, Array]] = []  # (t, x, f) at earlier step starts
    sizes: list[float] = []
    lookback = t0
    rejected = False

    def clipped(v: Array) -> tuple[bool, ...]:
        return tuple(abs(v[j]) >= o.rate_limit for j in o.rate_rows)

    while t < t_end - 1e-14:
        h = min(h, t_end - t)
        k = np.zeros((7, x.size))
        k[0] = k1
        for s in range(1, 6):
            k[s] = f(t + _C[s] * h, x + h * (_A[s, :s] @ k[:s]))
        xn = x + h * (_B @ k[:6])
        k[6] = f(t + h, xn)
        count.solution += 6
        err = h * (k.T @ _E)
        norm = float(np.sqrt(np.mean((err / (DEFAULT_ATOL + DEFAULT_RTOL * np.maximum(
            abs(x), abs(xn)))) ** 2)))
        if norm > 1:
            h *= max(0.2, 0.9 * norm ** -0.2)
            rejected = True
            continue
        inside = samples[(samples > t + 1e-12) & (samples < t + h - 1e-12)]
        free = inside.shape[0]
        times = list(inside)
        while len(times) < o.extra:  # extra points, each in the widest gap
            grid = np.sort(np.array([t, t + h, *times]))
            i = int(np.argmax(np.diff(grid)))
            times.append(0.5 * (grid[i] + grid[i + 1]))
        times.sort()
        q = k.T @ _P
        smooth = len(hist) >= 2 and hist[-2][0] >= lookback - 1e-15
        points = []
        for s_t in times:
            a = (s_t - t) / h
            if smooth:
                ts = (np.array([hist[-2][0], hist[-1][0], t, t + h]) - t) / h
                xs = np.array([hist[-2][1], hist[-1][1], x, xn])
                fs = h * np.array([hist[-2][2], hist[-1][2], k[0], k[6]])
                points.append(hermite(ts, xs, fs, a))
            else:
                points.append(x + h * (q @ np.array([a, a * a, a ** 3, a ** 4])))
        values = [f(s_t, p) for s_t, p in zip(times, points, strict=True)]
        count.solution += free
        count.extra += len(times) - free
        kink = o.kink and bool(o.rate_rows) and len(
            {clipped(v) for v in [*k, *values]}) > 1
        if kink:  # split where the clipping changes
            before, after = clipped(k[0]), clipped(k[6])
            cuts = [0.25, 0.5, 0.75]
            if before != after:
                lo, hi = 0.0, 1.0
                for _ in range(6):
                    mid = 0.5 * (lo + hi)
                    state = x + h * (q @ np.array([mid, mid ** 2, mid ** 3, mid ** 4]))
                    if clipped(f(t + mid * h, state)) == before:
                        lo = mid
                    else:
                        hi = mid
                count.split += 6
                cuts = [0.5 * (lo + hi)]
            xx, tt, kk = x, t, k[0]
            for a in [*cuts, 1.0]:
                xx = dopri_step(f, tt, xx, t + a * h - tt, kk)
                tt = t + a * h
                kk = f(tt, xx)
                count.split += 6
            count.split -= 1  # the last sub-step's end is not needed
            le = xn - xx
            pool, ends, hist, lookback = [], [], [], t + h
        else:
            le, fallback = local_error(f, t, x, xn, h, k, err, times, values, pool, lookback,
                                       free, sizes[-10:], o)
            count.fallback += fallback
        if o.mode == "exact":
            le = xn - exact_local(f, t, x, h)
        if not kink:
            pool.append((t, k[0].copy()))
            pool.extend(zip(times, values, strict=True))
            ends.append(t)
            lookback = max(lookback, ends[-o.lookback] if len(ends) >= o.lookback else t0)
            hist.append((t, x.copy(), k[0].copy()))
        size = float(np.linalg.norm(e))
        if size > 0:
            d = 1e-7 * max(1.0, float(np.linalg.norm(xn))) / size
            e = e + h * (f(t + h, xn + d * e) - k[6]) / d
            count.carry += 1
        e = e + le
        sizes.append(float(np.linalg.norm(le)))
        t, x, k1 = t + h, xn, k[6]
        count.steps += 1
        grow = 10.0 if norm == 0 else min(10.0, 0.9 * norm ** -0.2)
        h *= min(1.0, grow) if rejected else grow
        rejected = False
    return x, e, count


def local_error(f: Rhs, t: float, x: Array, xn: Array, h: float, k: Array, err: Array,
                times: list[float], values: list[Array], pool: list[tuple[float, Array]],
                lookback: float, free: int, recent: list[float], o: Options
                ) -> tuple[Array, int]:
    """A smooth step's local error (nx,) and the evaluations its fallback took; ``recent``
    the sizes of the last steps' local errors."""
    node_t, node_f = [t, t + h], [k[0], k[6]]
    for s_t, s_f in zip(times, values, strict=True):
        if min(abs(s_t - c) for c in node_t) >= 0.05 * h:
            node_t.append(s_t)
            node_f.append(s_f)
    for s_t, s_f in reversed(pool):
        if s_t < lookback or len(node_t) >= o.nodes:
            break
        if min(abs(s_t - c) for c in node_t) >= 0.05 * h:
            node_t.append(s_t)
            node_f.append(s_f)
    fallback = o.fallback
    if len(node_t) >= o.nodes and max(node_t) - min(node_t) < o.span * h:
        def rule(m: int) -> Array:
            w = quadrature_weights((np.array(node_t[:m]) - t) / h) * h
            return np.asarray(xn - x - sum(wi * fi for wi, fi in zip(w, node_f[:m],
                                                                       strict=True)))
        le = rule(len(node_t))
        size = float(np.linalg.norm(le))
        scale = max(size, 0.3 * float(np.mean(recent)) if recent else 0.0)
        if size > o.guard * float(np.linalg.norm(err)):
            pass  # the embedded estimate is the smaller: one RK6 step
        elif o.agree > 0 and float(np.linalg.norm(le - rule(len(node_t) - 2))) > o.agree * scale:
            fallback = "rk6x2"
        elif not (free < 2 and t < o.early):
            return le, 0
    if fallback == "richardson":
        half = dopri_step(f, t, x, h / 2, k[0])
        full = dopri_step(f, t + h / 2, half, h / 2, f(t + h / 2, half))
        return (xn - full) * 32 / 31, 11
    if fallback == "rk6x2":
        half = rk6_step(f, t, x, h / 2, k[0])
        return xn - rk6_step(f, t + h / 2, half, h / 2, f(t + h / 2, half)), 13
    return xn - rk6_step(f, t, x, h, k[0]), 6


def run(loop: str, trials: int, seed: int, o: Options) -> list[Trial]:
    """The estimate on each trial of one loop that integrates in one piece (the chain's
    trials are benchmarks/chains.py's, whatever the seed)."""
    from benchmarks.baselines.problem import (
        PAPER_MANEUVER,
        PRINTED_GAINS,
        SWAPPED_GAINS,
        paper_trials,
    )
    from flatcli.core.loop.simulate import Scenario, simulate

    if loop.startswith("chain4"):  # benchmarks/chains.py's chain of 4 joints
        from dataclasses import replace

        from benchmarks.chains import scenario_and_trials

        scenario, batch = scenario_and_trials(4, trials, "dynamic" if "dynamic" in loop
                                              else "kinematic")
        scenario, limit = replace(scenario, twin=0.0), math.inf
    else:
        swapped, plant, limit = LOOPS[loop]
        scenario = Scenario(PAPER_MANEUVER.cubic(), SWAPPED_GAINS if swapped else
                            PRINTED_GAINS, 1e-3, twin=0.0, plant=plant,
                            rate_limit=limit).prepared()
        batch = paper_trials(trials, seed=seed, spread=0.02, angle_spread=0.05)
    angles = scenario.n_joints + 1
    o.rate_limit = limit
    o.rate_rows = tuple(range(1, angles)) if math.isfinite(limit) else ()
    found: list[Trial] = []

    def hooked(fun: Any, span: tuple[float, float], y0: Array, *args: Any, **kw: Any) -> Any:
        sol = _SOLVE_IVP(fun, span, y0, *args, **kw)
        samples = kw.get("t_eval")
        if samples is not None and len(samples) > 100 and sol.status == 0:
            extra = kw.get("args", ())

            def g(t: float, x: Array) -> Array:
                return np.asarray(fun(t, x, *extra), dtype=float)

            x, e, count = estimate(g, span[0], span[1], np.asarray(y0, dtype=float),
                                   np.asarray(samples, dtype=float), o)
            true = _SOLVE_IVP(g, span, y0, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
            wrong = float(np.linalg.norm((x - true)[:angles]))
            found.append(Trial(float(np.linalg.norm(e[:angles])) / wrong, wrong, count))
        return sol

    si.solve_ivp = hooked
    try:
        simulate(scenario, batch, integrator="dop853")
    finally:
        si.solve_ivp = _SOLVE_IVP
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else "")
    parser.add_argument("loop", choices=[*sorted(LOOPS), "chain4", "chain4-dynamic"])
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--mode", choices=["quadrature", "exact"], default="quadrature")
    parser.add_argument("--nodes", type=int, default=10)
    parser.add_argument("--lookback", type=int, default=6)
    parser.add_argument("--span", type=float, default=12.0)
    parser.add_argument("--guard", type=float, default=1.0)
    parser.add_argument("--extra", type=int, default=2)
    parser.add_argument("--agree", type=float, default=1.0)
    parser.add_argument("--early", type=float, default=0.0)
    parser.add_argument("--fallback", choices=["rk6", "richardson"], default="rk6")
    parser.add_argument("--no-kink", dest="kink", action="store_false")
    a = parser.parse_args()
    o = Options(a.mode, a.nodes, a.lookback, a.span, a.guard, a.extra, a.agree, a.early,
                a.fallback, a.kink)
    found = run(a.loop, a.trials, a.seed, o)
    resolved = [r for r in found if r.true < 1e-3]
    ratio = np.array([r.ratio for r in resolved])
    cost = np.array([r.count.added() / r.count.solution for r in resolved])
    within = int(np.sum((ratio >= 1 / 3) & (ratio <= 3)))
    print(f"{a.loop} seed {a.seed}: {len(found)} trials in one piece, {len(resolved)} resolved;"
          f" within 3x {within}/{len(resolved)}; estimate/true {ratio.min():.3g} -"
          f" {np.median(ratio):.3g} - {ratio.max():.3g}; cost +{100 * np.median(cost):.1f} %"
          f" (max +{100 * cost.max():.1f} %)")
    typical = float(np.median([r.true for r in resolved]))
    off = np.array([abs(r.ratio - 1.0) * r.true for r in resolved]) / typical
    print(f"  |estimate - true| / median true error: median {np.median(off):.2g}, max"
          f" {off.max():.2g} (median true {typical:.2g} rad)")
    for r in resolved:
        if not 1 / 3 <= r.ratio <= 3:
            print(f"  outside: estimate/true {r.ratio:.3g}, true {r.true:.3g} rad")


if __name__ == "__main__":
    main()
