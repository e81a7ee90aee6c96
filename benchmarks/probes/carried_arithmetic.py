"""Probe (issue 41, item 1): what the carried estimate of ``benchmarks.probes.local_error``
would cost compiled, in time rather than in right-hand sides.

Its evaluations (the carry's J e, one a step, and the order-6 fallbacks) were counted there:
+11.5 % of one solution's right-hand sides on the printed loop, +13.9 % on the dynamic plant.
But a right-hand side of the paper's loop takes about 100 ns, so the arithmetic around them
counts too. This times, compiled with numba, the arithmetic a step adds beside those
evaluations:

* the weights of two interpolatory quadratures (10 and 8 nodes: Bjorck & Pereyra's algorithm
  for the transposed Vandermonde system) and the two sums over the nodes' f (nx components);
* the degree-7 Hermite through the last four step ends (confluent divided differences) and its
  value at the step's output samples (``--samples``);
* the carry's update e <- e + h J e + le.

``plain`` divides where the algorithms do; ``tuned`` takes each distinct node difference's
reciprocal once a step (45 for the weights, 6 for the Hermite) and multiplies. It also times
flatcli's own trial (``simulate``, ``twin = 0``) per accepted step on the printed and dynamic
loops, which gives the budget: 15 % of a step's time, less the evaluations' share above.

Measured 2026-12-06 (AMD EPYC, one thread): see docs/performance.md, issue 41's item 1.

Run from the repository root: ``python -m benchmarks.probes.carried_arithmetic``.
"""

from __future__ import annotations

import argparse
import math
import time

import numba as nb
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@nb.njit(cache=False)
def _weights(z: Array, m: int, w: Array, tuned: bool, inv: Array) -> None:
    """Weights w[:m] of the interpolatory rule on nodes z[:m] (in units of the step) for the
    integral over [0, 1]: V^T w = (1, 1/2, ..., 1/m), Bjorck & Pereyra (Math. Comp. 24, 1970);
    ``tuned``: multiplied by the reciprocals inv[i, j] = 1 / (z[i] - z[j]) (i > j) given,
    else divided by the differences."""
    for k in range(m):
        w[k] = 1.0 / (k + 1)
    for k in range(m - 1):
        for i in range(m - 1, k, -1):
            w[i] -= z[k] * w[i - 1]
    for k in range(m - 2, -1, -1):
        for i in range(k + 1, m):
            if tuned:
                w[i] *= inv[i, i - k - 1]
            else:
                w[i] /= z[i] - z[i - k - 1]
        for i in range(k, m - 1):
            w[i] -= w[i + 1]


@nb.njit(cache=False)
def _hermite(ts: Array, xs: Array, fs: Array, nx: int, c: Array, zz: Array, tuned: bool,
             rec: Array) -> None:
    """Newton coefficients c (8, nx) of the degree-7 Hermite through xs, fs (4, nx) at ts (4,)
    (nodes zz (8,), each of ts twice); ``tuned``: the 6 distinct differences' reciprocals
    taken once into rec (4, 4), then multiplied."""
    for i in range(4):
        zz[2 * i] = ts[i]
        zz[2 * i + 1] = ts[i]
    if tuned:
        for a in range(4):
            for b in range(a):
                rec[a, b] = 1.0 / (ts[a] - ts[b])
    for comp in range(nx):
        for i in range(4):
            c[2 * i, comp] = xs[i, comp]
            c[2 * i + 1, comp] = xs[i, comp]
        for order in range(1, 8):
            for i in range(7, order - 1, -1):
                if order == 1 and i % 2 == 1:
                    c[i, comp] = fs[i // 2, comp]
                elif tuned:
                    c[i, comp] = (c[i, comp] - c[i - 1, comp]) * rec[i // 2, (i - order) // 2]
                else:
                    c[i, comp] = (c[i, comp] - c[i - 1, comp]) / (zz[i] - zz[i - order])


def _check() -> None:
    """The tuned weights and Hermite are the plain ones, and the Hermite interpolates."""
    z = np.array([0.0, 1.0, -0.3, -1.2, -2.0, 0.45, -3.1, 0.8, -4.0, -5.5])
    inv = np.zeros((10, 10))
    for i in range(10):
        for j in range(i):
            inv[i, j] = 1.0 / (z[i] - z[j])
    w_plain, w_tuned = np.empty(10), np.empty(10)
    _weights(z, 10, w_plain, False, inv)
    _weights(z, 10, w_tuned, True, inv)
    exact = np.array([1.0 / (k + 1) for k in range(10)])  # the rule integrates z^k exactly
    assert np.allclose(np.vander(z, 10, increasing=True).T @ w_plain, exact, atol=1e-9)
    assert np.allclose(w_plain, w_tuned, rtol=1e-12)
    ts = np.array([-2.1, -1.05, 0.0, 1.0])
    xs, fs = np.sin(ts)[:, None], np.cos(ts)[:, None]
    for tuned in (False, True):
        c, zz = np.empty((8, 1)), np.empty(8)
        _hermite(ts, xs, fs, 1, c, zz, tuned, np.zeros((4, 4)))
        value = c[7, 0]
        for i in range(6, -1, -1):
            value = value * (0.5 - zz[i]) + c[i, 0]
        assert abs(value - np.sin(0.5)) < 1e-4, value


@nb.njit(cache=False)
def carried_steps(steps: int, samples: int, tuned: bool, node_f: Array, xs: Array, fs: Array,
                  je: Array, x: Array) -> float:
    """The arithmetic of ``steps`` steps (see the module docstring) on made-up values (node_f
    (10, nx), xs and fs (4, nx), je and x (nx,)); returns a checksum (so that nothing is
    optimised away)."""
    nx = x.shape[0]
    z = np.empty(10)
    w10 = np.empty(10)
    w8 = np.empty(10)
    inv = np.zeros((10, 10))
    ts = np.array([-2.1, -1.05, 0.0, 1.0])
    c = np.empty((8, nx))
    zz = np.empty(8)
    rec = np.zeros((4, 4))
    point = np.empty(nx)
    le10 = np.empty(nx)
    le8 = np.empty(nx)
    e = np.zeros(nx)
    checksum = 0.0
    for s in range(steps):
        jitter = 1e-3 * (s % 7)
        z[0] = 0.0
        z[1] = 1.0
        for k in range(2, 10):
            z[k] = 1.0 - 1.1 * k + jitter * k
        ts[0] = -2.1 - jitter
        if tuned:
            for i in range(10):
                for j in range(i):
                    inv[i, j] = 1.0 / (z[i] - z[j])
        _weights(z, 10, w10, tuned, inv)
        _weights(z, 8, w8, tuned, inv)
        disagree = 0.0
        for i in range(nx):
            q10 = 0.0
            q8 = 0.0
            for k in range(10):
                q10 += w10[k] * node_f[k, i]
            for k in range(8):
                q8 += w8[k] * node_f[k, i]
            le10[i] = x[i] - q10
            le8[i] = x[i] - q8
            disagree += (le10[i] - le8[i]) ** 2
        _hermite(ts, xs, fs, nx, c, zz, tuned, rec)
        for j in range(samples):
            a = (j + 0.5) / samples + jitter
            for comp in range(nx):
                p = c[7, comp]
                for i in range(6, -1, -1):
                    p = p * (a - zz[i]) + c[i, comp]
                point[comp] = p
            checksum += point[0]
        size = 0.0
        for i in range(nx):
            e[i] = e[i] + 1e-3 * je[i] + 1e-9 * le10[i]
            size += e[i] * e[i]
        checksum += math.sqrt(size) + disagree
    return checksum


def kernel_per_step() -> dict[str, tuple[float, float, float]]:
    """flatcli's own trial, per accepted step: (ns a step, steps a trial, ns a right-hand
    side) on the printed and the dynamic loop (400 perturbed trials, ``twin = 0``)."""
    from benchmarks.baselines import PAPER_MANEUVER, paper_trials
    from benchmarks.integrators import PRINTED
    from flatcli.core.loop.metrics import Metric
    from flatcli.core.loop.simulate import Scenario, simulate

    found = {}
    for name, plant in (("printed", "kinematic"), ("dynamic", "dynamic")):
        scenario = Scenario(PAPER_MANEUVER.cubic(), PRINTED, 1e-3, twin=0.0,
                            plant=plant).prepared()  # type: ignore[arg-type]
        simulate(scenario, paper_trials(4, seed=1))
        trials = paper_trials(400, seed=7, spread=0.02, angle_spread=0.05)
        start = time.perf_counter()
        out = simulate(scenario, trials)
        spent = time.perf_counter() - start
        steps = float(out.metrics[:, Metric.STEPS].sum())
        rhs = float(out.metrics[:, Metric.RHS_EVALUATIONS].sum())
        found[name] = (spent / steps * 1e9, steps / 400, spent / rhs * 1e9)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else "")
    parser.add_argument("--samples", type=int, default=2,
                        help="output samples inside a step (the Hermite's values)")
    parser.add_argument("--steps", type=int, default=2_000_000)
    a = parser.parse_args()
    _check()
    for name, (per_step, steps, per_rhs) in kernel_per_step().items():
        print(f"flatcli, {name} loop: {per_step:.0f} ns a step ({steps:.0f} steps a trial,"
              f" {per_rhs:.0f} ns a right-hand side); 15 % of a step: {0.15 * per_step:.0f} ns")
    for tuned in (False, True):
        for nx in (4, 7):  # the paper's kinematic and dynamic loops' state sizes
            rng = np.random.default_rng(0)
            values = (rng.standard_normal((10, nx)), rng.standard_normal((4, nx)),
                      rng.standard_normal((4, nx)), rng.standard_normal(nx),
                      rng.standard_normal(nx))
            carried_steps(10, a.samples, tuned, *values)
            start = time.perf_counter()
            carried_steps(a.steps, a.samples, tuned, *values)
            spent = (time.perf_counter() - start) / a.steps * 1e9
            print(f"carried arithmetic, {'tuned' if tuned else 'plain'}, nx {nx},"
                  f" {a.samples} samples a step: {spent:.0f} ns a step")


if __name__ == "__main__":
    main()
