"""Probe (issue 41, item 1): two more second solutions as a per-trial error estimate, measured
against DOP853 at rtol 1e-12 before anything is built.

* ``higher-order``: flatcli's own solution (the compiled Dormand-Prince 5(4) at the default
  tolerances, ``twin = 0``) against a twin by scipy's DOP853 (order 8) at ``--factors`` x
  the default rtol and atol: err_estimate = |angles(T) - twin's angles(T)|. Cost: the twin's
  right-hand sides over the compiled solution's (``Metric.RHS_EVALUATIONS``, its output
  samples included).
* ``extrapolation``: global extrapolation on the solution's own mesh. A Python Dormand-Prince
  5(4) with ``adaptive_trial``'s step control (``benchmarks.probes.local_error``'s) records
  its accepted step ends; the same method then runs again with fixed steps over every k-th of
  them (k in ``--merge``), and err_estimate = |angles difference| / (k^5 - 1), the global error
  of an order-5 method on a mesh k times as coarse being k^5 times as large where the steps are
  in the asymptotic regime. Cost: the coarse run's evaluations over the solution's (its 2,001
  output samples counted in, one evaluation each, as ``adaptive_trial`` observes them).

Trials: ``paper_trials(30, seed=7, spread=0.02, angle_spread=0.05)`` on the loops of
``benchmarks.integrators.twin_factors``; a trial is compared where the reference finishes
within its budget and the solution's final angle error is below 1e-3 rad (swapped gains make
some trials diverge: no estimate means anything there).

Measured 2026-12-06 (the table is in docs/performance.md, issue 41's item 1): the DOP853 twin
holds 3x on every loop at 0.01x (+54..121 % of one solution's right-hand sides; the
Dormand-Prince twin +86..174 %), and at 1x misses on the dynamic plant (23/30) and the rate
limit (26/30); extrapolation holds it on the printed loop alone (30/30 at k = 2 and 3, +25 and
+17 %; 9-23/30 on the dynamic plant, 3-5/30 with the rate limit).

k = 4 leaves the asymptotic regime on the printed loop itself (0/30: the coarse steps beyond
the method's stability).

Run from the repository root: ``python -m benchmarks.probes.twins higher-order dynamic`` or
``python -m benchmarks.probes.twins extrapolation printed --merge 2,3`` (10-60 s a loop).
"""

from __future__ import annotations

import argparse
import itertools
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from benchmarks.baselines import PAPER_MANEUVER, paper_trials
from benchmarks.integrators import PRINTED, SWAPPED
from benchmarks.probes.local_error import _A, _B, _C, _E
from flatcli.core.controllers.control import Gains
from flatcli.core.loop.metrics import Metric, Status
from flatcli.core.loop.simulate import (
    Scenario,
    Trials,
    closed_loop_rhs,
    closed_loop_start,
    simulate,
)
from flatcli.core.names import DEFAULT_ATOL, DEFAULT_RTOL

Array = NDArray[np.float64]
Rhs = Callable[[float, Array], Array]

#: The loops: gains and the Scenario's options.
LOOPS: dict[str, tuple[Gains, dict[str, object]]] = {
    "printed": (PRINTED, {}), "swapped": (SWAPPED, {}),
    "dynamic": (PRINTED, {"plant": "dynamic"}), "dynamic-swapped": (SWAPPED, {"plant": "dynamic"}),
    "limit": (PRINTED, {"rate_limit": 0.6})}
#: Right-hand sides a trial's reference (or Python solution) may take.
BUDGET = 400_000
#: A solution whose final angle error is this or more [rad] has diverged: not compared.
RESOLVED = 1e-3


class _OverBudgetError(Exception):
    pass


def budgeted(rhs: Rhs) -> tuple[Rhs, list[int]]:
    """rhs counting its calls (in the list), raising past ``BUDGET``."""
    calls = [0]

    def counted(t: float, x: Array) -> Array:
        calls[0] += 1
        if calls[0] > BUDGET:
            raise _OverBudgetError
        return np.asarray(rhs(t, x), dtype=float)

    return counted, calls


def dopri_stages(f: Rhs, t: float, x: Array, h: float, k0: Array) -> Array:
    """The Dormand-Prince step's first six stages (7, nx), k0 = f(t, x) given (5 evaluations)."""
    k = np.zeros((7, x.size))
    k[0] = k0
    for s in range(1, 6):
        k[s] = f(t + _C[s] * h, x + h * (_A[s, :s] @ k[:s]))
    return k


def adaptive(f: Rhs, duration: float, x0: Array) -> tuple[Array, Array, int]:
    """Dormand-Prince 5(4) at the default tolerances with ``adaptive_trial``'s step control:
    the final state, the accepted step ends (m,) [s] and the evaluations."""
    x, t, k1, h = x0.copy(), 0.0, f(0.0, x0), 1e-3
    mesh, rejected, evaluations = [0.0], False, 1
    while t < duration - 1e-14:
        h = min(h, duration - t)
        k = dopri_stages(f, t, x, h, k1)
        xn = x + h * (_B @ k[:6])
        k[6] = f(t + h, xn)
        evaluations += 6
        scale = DEFAULT_ATOL + DEFAULT_RTOL * np.maximum(abs(x), abs(xn))
        norm = float(np.sqrt(np.mean((h * (k.T @ _E) / scale) ** 2)))
        if not norm <= 1.0:
            h *= max(0.2, 0.9 * norm ** -0.2) if np.isfinite(norm) else 0.2
            rejected = True
            continue
        t, x, k1 = t + h, xn, k[6]
        mesh.append(t)
        grow = 10.0 if norm == 0.0 else min(10.0, 0.9 * norm ** -0.2)
        h *= min(1.0, grow) if rejected else grow
        rejected = False
    return x, np.array(mesh), evaluations


def fixed(f: Rhs, mesh: Array, x0: Array) -> tuple[Array, int]:
    """Dormand-Prince 5 with fixed steps over ``mesh`` (m,): the final state, evaluations."""
    x, k1, evaluations = x0.copy(), f(float(mesh[0]), x0), 1
    for a, b in itertools.pairwise(mesh):
        k = dopri_stages(f, float(a), x, float(b - a), k1)
        x = x + (b - a) * (_B @ k[:6])
        k1 = f(float(b), x)
        evaluations += 6
    return x, evaluations


def truth(f: Rhs, duration: float, x0: Array) -> Array | None:
    """The final angles by DOP853 at rtol 1e-12 (None past the budget or failing)."""
    counted, _ = budgeted(f)
    try:
        sol = solve_ivp(counted, (0.0, duration), x0, method="DOP853", rtol=1e-12, atol=1e-14)
    except _OverBudgetError:
        return None
    return np.asarray(sol.y[:3, -1]) if sol.status == 0 else None


def loop_trials(loop: str, count: int) -> tuple[Scenario, Trials]:
    """The loop's scenario (no twin) and its perturbed trials."""
    gains, options = LOOPS[loop]
    trials = paper_trials(count, seed=7, spread=0.02, angle_spread=0.05)
    return Scenario(PAPER_MANEUVER.cubic(), gains, 1e-3, twin=0.0,
                    **options).prepared(), trials  # type: ignore[arg-type]


def higher_order(loop: str, count: int, factors: list[float]) -> dict[float, list[tuple[float,
                                                                                          float]]]:
    """(estimate / true, twin's evaluations / solution's) of each compared trial, by factor."""
    scenario, trials = loop_trials(loop, count)
    duration = scenario.plan.duration
    out = simulate(scenario, trials, record=True)
    assert out.trace is not None
    found: dict[float, list[tuple[float, float]]] = {factor: [] for factor in factors}
    for i in range(count):
        if out.status[i] not in (Status.OK, Status.SINGULAR):
            continue
        rhs = closed_loop_rhs(scenario, trials, i)
        x0 = closed_loop_start(scenario, trials, i)
        with np.errstate(all="ignore"):
            true_angles = truth(rhs, duration, x0)
            if true_angles is None:
                continue
            solution = out.trace[i, -1, :3]
            true = float(np.linalg.norm(solution - true_angles))
            if not true < RESOLVED:
                continue
            for factor in factors:
                twin = solve_ivp(rhs, (0.0, duration), x0, method="DOP853",
                                 rtol=factor * DEFAULT_RTOL, atol=factor * DEFAULT_ATOL)
                estimate = float(np.linalg.norm(solution - twin.y[:3, -1]))
                found[factor].append((estimate / true, twin.nfev
                                      / float(out.metrics[i, Metric.RHS_EVALUATIONS])))
    return found


def extrapolation(loop: str, count: int, merges: list[int]) -> dict[float, list[tuple[float,
                                                                                         float]]]:
    """(estimate / true, coarse run's evaluations / solution's) of each compared trial, by k."""
    scenario, trials = loop_trials(loop, count)
    duration = scenario.plan.duration
    found: dict[float, list[tuple[float, float]]] = {float(k): [] for k in merges}
    samples = scenario.times.shape[0]
    for i in range(count):
        rhs, _ = budgeted(closed_loop_rhs(scenario, trials, i))
        x0 = closed_loop_start(scenario, trials, i)
        with np.errstate(all="ignore"):
            try:
                solution, mesh, evaluations = adaptive(rhs, duration, x0)
            except _OverBudgetError:
                continue
            true_angles = truth(rhs, duration, x0) if np.all(abs(solution) < 100) else None
            if true_angles is None:
                continue
            true = float(np.linalg.norm(solution[:3] - true_angles))
            if not true < RESOLVED:
                continue
            for k in merges:
                coarse = mesh[::k] if (mesh.shape[0] - 1) % k == 0 else np.append(mesh[::k],
                                                                                  mesh[-1])
                far, spent = fixed(rhs, coarse, x0)
                estimate = float(np.linalg.norm((far - solution)[:3])) / (k ** 5 - 1)
                found[float(k)].append((estimate / true, spent / (evaluations + samples)))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else "")
    parser.add_argument("method", choices=["higher-order", "extrapolation"])
    parser.add_argument("loop", choices=sorted(LOOPS))
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--factors", default="1,0.1,0.01",
                        help="higher-order: the twin's factors on rtol and atol")
    parser.add_argument("--merge", default="2,3", help="extrapolation: steps merged, k")
    a = parser.parse_args()
    if a.method == "higher-order":
        found = higher_order(a.loop, a.trials, [float(v) for v in a.factors.split(",")])
    else:
        found = extrapolation(a.loop, a.trials, [int(v) for v in a.merge.split(",")])
    for key, rows in found.items():
        if not rows:
            print(f"{a.loop} {a.method} {key:g}: no trial compared")
            continue
        ratio = np.array([r for r, _ in rows])
        cost = np.array([c for _, c in rows])
        within = int(np.sum((ratio >= 1 / 3) & (ratio <= 3)))
        print(f"{a.loop} {a.method} {key:g}: within 3x {within}/{len(rows)}; estimate/true"
              f" {ratio.min():.3g} - {np.median(ratio):.3g} - {ratio.max():.3g}; cost"
              f" +{100 * np.median(cost):.0f} % (max +{100 * cost.max():.0f} %)")


if __name__ == "__main__":
    main()
