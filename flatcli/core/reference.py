"""The reference integrator ("dop853"): scipy's ``solve_ivp`` (DOP853) on any robot and plant,
one trial at a time, with the stopping rules of the compiled integrators as terminal events
(the divergence bound, the controller's margin changing sign); its right-hand sides and
observers are the compiled ones of ``kernels``, so only the integration differs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core.integrate import STALL_MARGIN
from flatcli.core.kernels import Grid, Kernels, Results, Settings, TrialArrays
from flatcli.core.metrics import Event, Metric, Status

Array = NDArray[np.float64]

#: Tolerances of the reference integrator.
REFERENCE_RTOL = 1e-10
REFERENCE_ATOL = 1e-12


def reference_trial(scenario: Any, trials: Any, kernels: Kernels, shared: Any,
                    arrays: TrialArrays, grid: Grid, settings: Settings, i: int,
                    results: Results) -> None:
    """Trial i by solve_ivp (DOP853), with terminal events on the divergence bound and on the
    controller's margin changing sign; its metrics from the same observer as the kernels,
    written into row i of ``results`` (``scenario``, ``trials``: ``simulate.Scenario`` and
    ``simulate.Trials``)."""
    initial_of, rhs_at, observe_trace, record_trace = kernels.single
    n_joints = scenario.n_joints
    n = scenario.n_steps
    times = scenario.times
    nx = kernels.ops.state(n_joints)
    size = nx + kernels.ops.aux(n_joints)
    buffers = kernels.buffers(n_joints, grid.ref.shape[1])
    noise = trials.noise_table(i, n)
    bound = settings.bound
    start = np.empty(nx)
    initial_of(shared, arrays, i, grid, buffers, start)
    out = np.empty(size)
    evaluations = [0]

    def full(t: float, x: Array, noise_row: Array) -> Array:
        evaluations[0] += 1
        rhs_at(shared, arrays, i, grid, buffers, t, np.ascontiguousarray(x), noise_row, out)
        return out

    def rhs(t: float, x: Array, noise_row: Array) -> Array:
        return full(t, x, noise_row)[:nx].copy()

    def blowup(t: float, x: Array, noise_row: Array) -> float:
        return float(bound - np.max(np.abs(x)))

    def crossing(t: float, x: Array, noise_row: Array) -> float:
        return float(full(t, x, noise_row)[nx])  # the controller's signed margin

    blowup.terminal = True  # type: ignore[attr-defined]
    crossing.terminal = True  # type: ignore[attr-defined]
    states = np.full((n + 1, nx), math.nan)
    states[0] = start
    stopped, when = int(Event.NONE), math.nan
    steps = 0
    # without noise one integration over the whole grid; with noise one per interval, so the
    # solver never steps across a jump of the measured angles
    segments = [(0, n)] if not np.any(noise) else [(s, s + 1) for s in range(n)]
    x = start
    for begin, stop in segments:
        with np.errstate(all="ignore"):
            sol = solve_ivp(rhs, (times[begin], times[stop]), x, method="DOP853",
                            t_eval=times[begin: stop + 1], rtol=REFERENCE_RTOL,
                            atol=REFERENCE_ATOL, args=(noise[begin],),
                            events=[blowup, crossing], dense_output=True)
        steps += len(sol.sol.ts) - 1 if sol.sol is not None else 0
        got = sol.y.T
        states[begin: begin + len(got)] = got
        if sol.status == 1:  # a terminal event; crossing the singular set takes precedence
            if len(sol.t_events[1]):
                stopped, when = int(Event.CROSSED), float(sol.t_events[1][0])
            else:
                stopped, when = int(Event.BOUND), float(sol.t_events[0][0])
            break
        if sol.status == -1 or len(got) < stop - begin + 1:  # the solver gave up
            last_x = sol.y[:, -1] if sol.y.size else x
            t_last = float(sol.t[-1]) if sol.t.size else float(times[begin])
            near = abs(crossing(t_last, last_x, noise[begin])) < STALL_MARGIN
            stopped = int(Event.STALLED if near else Event.STEP_FLOOR)
            when = t_last
            break
        x = got[-1]
    finite = np.isfinite(states).all(axis=1) & (np.abs(states) <= bound).all(axis=1)
    last = int(np.argmin(finite)) - 1 if not finite.all() else n
    if stopped == int(Event.NONE) and last < n:
        stopped, when = int(Event.BOUND), float(times[last + 1])
    rates = np.full((n + 1, size), math.nan)
    sample = np.empty(size)
    for j in range(last + 1):
        # the rates the plant applies at sample j: the plan's flag tabulated there (row 2 j
        # of grid.ref, as the kernels observe it) and the noise of its interval
        rhs_at(shared, arrays, i, grid, buffers, -(2.0 * j + 1.0),
               np.ascontiguousarray(states[j]), noise[min(j, n - 1)], sample)
        rates[j] = sample
    first = observe_trace(shared, arrays, i, grid, settings, buffers, states, rates, last,
                          stopped == int(Event.NONE), results.metrics[i])
    results.metrics[i, Metric.STEPS] = steps
    results.metrics[i, Metric.RHS_EVALUATIONS] = evaluations[0]
    code = Status.SINGULAR if first >= 0 else Status.OK
    if stopped != int(Event.NONE):
        code = Event(stopped).status
    results.status[i] = int(code)
    results.event[i] = stopped
    if stopped != int(Event.NONE):
        results.event_time[i] = when
    elif first >= 0:
        results.event_time[i] = first * settings.dt
    if settings.record:
        trace = results.trace[i]
        trace[:] = math.nan
        record_trace(states, rates, last, trace)
