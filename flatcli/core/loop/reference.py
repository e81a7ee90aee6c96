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

from flatcli.core.controllers.python import commands, continuous, held_values
from flatcli.core.loop.integrate import CROSS_STEP, STALL_MARGIN, plan_flag
from flatcli.core.loop.kernels import Grid, Kernels, Results, Settings, TrialArrays
from flatcli.core.loop.metrics import Event, Metric, Status

Array = NDArray[np.float64]

#: Tolerances of the reference integrator.
REFERENCE_RTOL = 1e-10
REFERENCE_ATOL = 1e-12
#: Crossings of the singular set a reference trial passes before it is unresolved (a margin
#: that keeps changing sign: chattering on the set).
MAX_CROSSINGS = 1000


def reference_trial(scenario: Any, trials: Any, kernels: Kernels, shared: Any,
                    arrays: TrialArrays, grid: Grid, settings: Settings, i: int,
                    results: Results) -> None:
    """Trial i by solve_ivp (DOP853), with terminal events on the divergence bound and on the
    controller's margin changing sign (passed where the actuators bound the plant: the
    integration starts again a step of ``integrate.CROSS_STEP`` T beyond the crossing, as
    the compiled integrators do); its metrics from the same observer as the kernels,
    written into row i of ``results`` (``scenario``, ``trials``: ``simulate.Scenario`` and
    ``simulate.Trials``).

    A controller acting at sample instants (``kernels.make_control_single``) starts afresh,
    the integration stops at each of its samples (as at each noise interval), it samples
    there (before the right-hand side is evaluated there), and the rates observed at an
    output sample are those under what it held then; its columns go to ``results.extra``.
    """
    from scipy.integrate import solve_ivp  # loaded for the reference only: a sweep needs none

    initial_of, rhs_at, observe_trace, record_trace = kernels.single[:4]
    sampled = kernels.ops.sampled
    n_joints = scenario.n_joints
    n = scenario.n_steps
    times = scenario.times
    nx = kernels.ops.state(n_joints)
    size = nx + kernels.ops.aux(n_joints)
    buffers = kernels.buffers(n_joints, grid.ref.shape[1], shared)
    noise = trials.noise_table(i, n)
    bound = settings.bound
    start = np.empty(nx)
    initial_of(shared, arrays, i, grid, buffers, start)
    period = 0
    python = scenario.python  # a controller written in Python (``controllers.python``)
    if sampled:
        control_start, sample_at, extras_at = kernels.single[4:7]
        period = control_start(shared, arrays, i, buffers)
    if python is not None and callable(getattr(python, "reset", None)):
        python.reset()
    command: Any = python if continuous(python) else None
    flag = np.empty(grid.ref.shape[1])
    out = np.empty(size)
    evaluations = [0]

    def commanded(t: float, ref: Array, x: Array, noise_row: Array) -> None:
        """The Python controller's commands at time t, the plan's flag ``ref`` and the
        measured state, into the law's scratch (``controllers.paper.given_command`` reads
        them)."""
        theta = x[: n_joints + 1] + noise_row
        buffers.scratch.law[:] = commands(command.command(
            t, theta, x[n_joints + 1: 2 * n_joints], ref.copy()), n_joints)

    def full(t: float, x: Array, noise_row: Array) -> Array:
        evaluations[0] += 1
        x = np.ascontiguousarray(x)
        if command is not None:
            plan_flag(grid.breaks, grid.local, t, flag)
            commanded(t, flag, x, noise_row)
        rhs_at(shared, arrays, i, grid, buffers, t, x, noise_row, out)
        return out

    def rhs(t: float, x: Array, noise_row: Array) -> Array:
        return full(t, x, noise_row)[:nx].copy()

    def blowup(t: float, x: Array, noise_row: Array) -> float:
        return float(bound - np.max(np.abs(x)))

    def crossing(t: float, x: Array, noise_row: Array) -> float:
        return float(full(t, x, noise_row)[nx])  # the controller's signed margin

    blowup.terminal = True  # type: ignore[attr-defined]
    crossing.terminal = True  # type: ignore[attr-defined]
    # the actuators bound the right-hand side at a crossing: pass it (restart beyond it)
    bounded = not math.isinf(scenario.rate_limit) or (
        scenario.plant == "dynamic" and not math.isinf(trials.servo_table()[i, 1]))
    states = np.full((n + 1, nx), math.nan)
    states[0] = start
    stopped, when = int(Event.NONE), math.nan
    steps = 0
    passed: list[float] = []
    rates = np.full((n + 1, size), math.nan)
    sample = np.empty(size)

    def observed_rates(first: int, end: int) -> None:
        """The rates the plant applies at samples first..end - 1: the plan's flag tabulated
        there (row 2 j of grid.ref, as the kernels observe it) and the noise of its
        interval."""
        for j in range(first, end):
            x_j = np.ascontiguousarray(states[j])
            if command is not None:
                commanded(float(times[j]), grid.ref[2 * j], x_j, noise[min(j, n - 1)])
            rhs_at(shared, arrays, i, grid, buffers, -(2.0 * j + 1.0), x_j,
                   noise[min(j, n - 1)], sample)
            rates[j] = sample

    # without noise one integration over the whole grid (or one per sample of a sampled
    # controller); with noise one per interval, so the solver never steps across a jump of
    # the measured angles or of what the controller holds
    if np.any(noise):
        segments = [(s, s + 1) for s in range(n)]
    elif period > 0:
        segments = [(s, min(s + period, n)) for s in range(0, n, period)]
    else:
        segments = [(0, n)]
    x = start
    for begin, stop in segments:
        if period > 0 and begin % period == 0:
            sample_at(shared, arrays, i, grid, buffers, np.ascontiguousarray(x),
                      noise[begin], begin)
            if python is not None:  # its step, on the errors the compiled loop measured
                part = buffers.scratch.part
                part.held[:] = held_values(python.step(begin // period, float(times[begin]),
                                                       part.s0.copy()), part.held.shape[0])
        t0, filled = float(times[begin]), begin  # samples up to ``filled`` are in states
        while stopped == int(Event.NONE):
            with np.errstate(all="ignore"):
                sol = solve_ivp(rhs, (t0, times[stop]), x, method="DOP853",
                                t_eval=times[filled: stop + 1], rtol=REFERENCE_RTOL,
                                atol=REFERENCE_ATOL, args=(noise[begin],),
                                events=[blowup, crossing], dense_output=True)
            steps += len(sol.sol.ts) - 1 if sol.sol is not None else 0
            got = sol.y.T
            if (len(got) and got.shape[0] and filled == begin and t0 == times[begin]) or len(got):
                states[filled: filled + len(got)] = got
            filled += len(got)
            if sol.status == 1 and len(sol.t_events[1]) and bounded \
                    and len(passed) < MAX_CROSSINGS:
                # the margin changed sign where the actuators bound the plant: count the
                # crossing, and start again just past it (the right-hand side jumps there)
                t_cross = float(sol.t_events[1][0])
                x_cross = np.asarray(sol.y_events[1][0], dtype=float)
                passed.append(t_cross)
                step = CROSS_STEP * float(times[-1])
                x = x_cross + step * rhs(t_cross + step, x_cross, noise[begin])
                t0 = t_cross + step
                while filled <= stop and times[filled] <= t0:  # samples inside the step
                    states[filled] = x_cross + (times[filled] - t_cross) * (x - x_cross) / step
                    filled += 1
                continue
            if sol.status == 1:  # a terminal event; crossing the singular set takes precedence
                if len(sol.t_events[1]):
                    stopped, when = int(Event.CROSSED), float(sol.t_events[1][0])
                    passed.append(when)
                else:
                    stopped, when = int(Event.BOUND), float(sol.t_events[0][0])
                break
            if sol.status == -1 or filled < stop + 1:  # the solver gave up
                last_x = sol.y[:, -1] if sol.y.size else x
                t_last = float(sol.t[-1]) if sol.t.size else t0
                near = abs(crossing(t_last, last_x, noise[begin])) < STALL_MARGIN
                stopped = int(Event.STALLED if near else Event.STEP_FLOOR)
                when = t_last
                break
            x = got[-1]
            break
        if sampled:  # under what the controller holds over this segment
            observed_rates(begin, min(filled, stop + 1 if stop == n else stop))
        if stopped != int(Event.NONE):
            break
    finite = np.isfinite(states).all(axis=1) & (np.abs(states) <= bound).all(axis=1)
    last = int(np.argmin(finite)) - 1 if not finite.all() else n
    if stopped == int(Event.NONE) and last < n:
        stopped, when = int(Event.BOUND), float(times[last + 1])
    if not sampled:
        observed_rates(0, last + 1)
    first_hit = observe_trace(shared, arrays, i, grid, settings, buffers, states, rates, last,
                              stopped == int(Event.NONE), np.asarray(passed, dtype=float),
                              results.metrics[i])
    results.metrics[i, Metric.STEPS] = steps
    if sampled:
        extras_at(shared, arrays, i, buffers, results.extra[i])
    results.metrics[i, Metric.RHS_EVALUATIONS] = evaluations[0]
    code = Status.OK if math.isnan(first_hit) else Status.SINGULAR
    if stopped != int(Event.NONE):
        code = Event(stopped).status
    results.status[i] = int(code)
    angles = results.final.shape[1]
    results.final[i] = states[n, :angles] if stopped == int(Event.NONE) else math.nan
    results.event[i] = stopped
    results.event_time[i] = when if stopped != int(Event.NONE) else first_hit
    if settings.record:
        trace = results.trace[i]
        trace[:] = math.nan
        record_trace(shared, arrays, i, buffers, states, rates, last, trace)
