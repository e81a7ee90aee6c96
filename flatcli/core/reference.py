"""The reference integrator ("dop853"): scipy's ``solve_ivp`` (DOP853) on the paper's robot,
one trial at a time, with the stopping rules of the compiled integrators as terminal events
(the divergence bound, the controller's margin changing sign); its right-hand sides and
observers are the compiled ones of ``paperloop``, so only the integration differs.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core.control import Gains
from flatcli.core.integrate import STALL_MARGIN
from flatcli.core.metrics import Event, Status
from flatcli.core.model import Coefficients, Links
from flatcli.core.paperloop import (
    _dynamic_rhs_at,
    _dynamic_rhs_kernel,
    _dynamic_start,
    _is_flat,
    _kinematic_rhs_at,
    _kinematic_rhs_kernel,
    _make_dynamic_loop,
    _observe_dynamic_trace_kernel,
    _observe_trace_kernel,
    _plain,
)
from flatcli.core.plant import (
    AUX_R2,
    AUX_TAU1,
    AUX_TAU2,
    DYNAMIC_AUX,
    DYNAMIC_STATE,
    KINEMATIC_AUX,
    KINEMATIC_STATE,
    Loop,
)

if TYPE_CHECKING:  # simulate imports this module: for the type hints only
    from flatcli.core.simulate import Scenario, Trials

Array = NDArray[np.float64]

#: Tolerances of the reference integrator.
REFERENCE_RTOL = 1e-10
REFERENCE_ATOL = 1e-12


def _reference_trial(
    scenario: Scenario, trials: Trials, plant_k: Array, kc: Coefficients, gains: Gains, i: int,
    out: Array, status: NDArray[np.int64], event: NDArray[np.int64], event_time: Array,
    trace: Array | None,
) -> None:
    """Trial i by solve_ivp (DOP853), with terminal events on the divergence bound and on the
    controller's margin changing sign; its metrics from the same observer as the kernels."""
    n = scenario.n_steps
    times = scenario.times
    p = Links(*(float(v) for v in trials.links[i]))
    dynamic = scenario.plant == "dynamic"
    noise = trials.noise_table(i, n)
    bound = scenario.divergence_bound
    breaks, local = scenario.pieces
    loop: Any  # Loop or DynamicLoop, with the kernels below that take it
    rhs_at: Any
    rhs_full: Any
    if dynamic:
        bandwidth, torque_limit = trials.servo_table()[i]
        robot = Links(*(float(v) for v in scenario.plan.robot.links))
        loop = _make_dynamic_loop(kc, gains, p, robot, scenario.servo_model == "plant",
                                  float(trials.momentum[i]), float(scenario.rate_limit),
                                  float(bandwidth), float(torque_limit))
        nx, aux, u1_index = DYNAMIC_STATE, DYNAMIC_AUX, 6
        rhs_at, rhs_full = _dynamic_rhs_at, _dynamic_rhs_kernel
        start = np.asarray(_dynamic_start(loop, np.asarray(trials.initial[i], dtype=float),
                                          scenario.reference[0]))
    else:
        kq = _plain(Coefficients(*plant_k[i]))
        loop = Loop(kc, gains, kq, p, p.m0 + p.m1 + p.m2, float(trials.momentum[i]),
                    float(scenario.rate_limit), bool(_is_flat(kq)))
        nx, aux, u1_index = KINEMATIC_STATE, KINEMATIC_AUX, 3
        rhs_at, rhs_full = _kinematic_rhs_at, _kinematic_rhs_kernel
        start = np.asarray(trials.initial[i], dtype=float)

    def rhs(t: float, x: Array, noise_row: Array) -> Array:
        return np.asarray(rhs_at(loop, breaks, local, t, x, noise_row))

    def blowup(t: float, x: Array, noise_row: Array) -> float:
        return float(bound - np.max(np.abs(x)))

    def crossing(t: float, x: Array, noise_row: Array) -> float:
        return float(np.sin(x[1] + noise_row[1]) * x[u1_index])

    blowup.terminal = True  # type: ignore[attr-defined]
    crossing.terminal = True  # type: ignore[attr-defined]
    states = np.full((n + 1, nx), math.nan)
    states[0] = start
    stopped, when = int(Event.NONE), math.nan
    # without noise one integration over the whole grid; with noise one per interval, so the
    # solver never steps across a jump of the measured angles
    segments = [(0, n)] if not np.any(noise) else [(s, s + 1) for s in range(n)]
    x = start
    for begin, stop in segments:
        with np.errstate(all="ignore"):
            sol = solve_ivp(rhs, (times[begin], times[stop]), x, method="DOP853",
                            t_eval=times[begin: stop + 1], rtol=REFERENCE_RTOL,
                            atol=REFERENCE_ATOL, args=(noise[begin],),
                            events=[blowup, crossing])
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
            near = abs(crossing(float(sol.t[-1]) if sol.t.size else times[begin], last_x,
                                noise[begin])) < STALL_MARGIN
            stopped = int(Event.STALLED if near else Event.STEP_FLOOR)
            when = float(sol.t[-1]) if sol.t.size else float(times[begin])
            break
        x = got[-1]
    finite = np.isfinite(states).all(axis=1) & (np.abs(states) <= bound).all(axis=1)
    last = int(np.argmin(finite)) - 1 if not finite.all() else n
    if stopped == int(Event.NONE) and last < n:
        stopped, when = int(Event.BOUND), float(times[last + 1])
    rates = np.full((n + 1, nx + aux), math.nan)
    for j in range(last + 1):
        ref = scenario.reference[2 * j]
        rates[j] = rhs_full(loop, states[j], ref, noise[min(j, n - 1)])
    theta_ref = scenario.theta_reference
    plan_theta, plan_theta_dot = scenario.plan_on_own_grid
    observe = _observe_dynamic_trace_kernel if dynamic else _observe_trace_kernel
    first = observe(loop, theta_ref, scenario.reference, float(scenario.singular_threshold),
                    states, rates, last, stopped == int(Event.NONE), float(scenario.dt),
                    plan_theta, plan_theta_dot, out)
    code = Status.SINGULAR if first >= 0 else Status.OK
    if stopped != int(Event.NONE):
        code = Event(stopped).status
    status[i] = int(code)
    event[i] = stopped
    if stopped != int(Event.NONE):
        event_time[i] = when
    elif first >= 0:
        event_time[i] = first * scenario.dt
    if trace is not None:
        trace[:, :nx] = states
        trace[:, nx:] = rates[:, [AUX_TAU1, AUX_TAU2, AUX_R2]] if dynamic else rates[:, :3]
        trace[last + 1:] = math.nan
