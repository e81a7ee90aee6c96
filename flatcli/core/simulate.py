"""Closed-loop simulation of the prolonged system: the planned reference, the controller, the plant.

The controller (``control.feedback``) believes the nominal model; the plant always obeys the
true physics (the derived constraint for its own parameters, d2 of any value, and its own
angular momentum H0). Per trial the plant state x = (th0, th1, th2, u1) evolves as

    th1' = sat(u1),  th2' = sat(u2),  th0' = (B th1' + C th2' + M H0) / A,  u1' = u1'

where (u1', u2) come from the controller at the measured angles th + noise, and sat clips a
joint rate to +-rate_limit (an actuator limit; infinite by default). Sensor noise is drawn
per grid step and held over that step.

Two integrators:

* ``"rk4"``: classical fixed-step Runge-Kutta over a batch of trials, compiled with numba.
  Each trial is integrated on its own by the same scalar code, so its result does not
  depend on which other trials share the batch (bit for bit).
* ``"dop853"``: scipy's ``solve_ivp`` (DOP853, rtol 1e-10, atol 1e-12 by default), one trial
  at a time, the reference the fixed step is checked against.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.integrate import solve_ivp

from flatcli.core._jit import Real, jitable, kernel
from flatcli.core.control import Gains, feedback_at
from flatcli.core.metrics import (
    N_METRICS,
    STATUS_DIVERGED,
    STATUS_OK,
    STATUS_SINGULAR,
    trace_metrics,
)
from flatcli.core.model import (
    Coefficients,
    FlatcliError,
    Links,
    base_rate_at,
    constraint_coefficients,
)
from flatcli.core.planning import FlatPlan

Array = NDArray[np.float64]
Integrator = Literal["rk4", "dop853"]
INTEGRATORS: tuple[Integrator, ...] = ("rk4", "dop853")

#: Columns of a trace: the prolonged state and the applied th2'.
TRACE_COLUMNS: tuple[str, ...] = ("theta0", "theta1", "theta2", "u1", "u2")

#: Tolerances of the reference integrator.
REFERENCE_RTOL = 1e-10
REFERENCE_ATOL = 1e-12


@jitable
def closed_loop(
    kc: Coefficients, gains: Gains, kp: Coefficients, total_mass: float, h0: float,
    rate_limit: float, x0: Real, x1: Real, x2: Real, x3: Real, ref: Sequence[Real] | Array,
    n0: Real, n1: Real, n2: Real,
) -> tuple[Real, Real, Real, Real, Real]:
    """Rates of the prolonged state under the feedback; also the applied th2'.

    Parameters
    ----------
    kc : Coefficients of the controller; gains : Gains
    kp : Coefficients of the plant (derived model); total_mass : plant M [kg]
    h0 : plant angular momentum [kg m^2/s]; rate_limit : joint-rate limit [rad/s] (inf: none)
    x0, x1, x2 : angles [rad]; x3 : u1 [rad/s], floats or arrays (...)
    ref : plan y1, y2, y1', y2', y1'', y2'' at this instant
    n0, n1, n2 : sensor noise on the three angles [rad]

    Returns
    -------
    th0', th1', th2' [rad/s], u1' [rad/s^2], applied u2 [rad/s]
    """
    m1 = x1 + n1
    return _closed_loop(kc, gains, kp, total_mass, h0, rate_limit, x3, ref, x0 + n0, m1, x2 + n2,
                        np.cos(m1), np.sin(m1), np.cos(x1), np.cos(x2), np.cos(x1 + x2))


@jitable
def _closed_loop(
    kc: Coefficients, gains: Gains, kp: Coefficients, total_mass: float, h0: float,
    rate_limit: float, x3: Real, ref: Sequence[Real] | Array, m0: Real, m1: Real, m2: Real,
    cm1: Real, sm1: Real, c1: Real, c2: Real, c12: Real,
) -> tuple[Real, Real, Real, Real, Real]:
    """``closed_loop`` given the measured angles m, cos and sin of m1, and the plant's cosines
    of th1, th2 and th1 + th2."""
    u1_dot, u2 = feedback_at(kc, gains, m0, m1, m2, x3, cm1, sm1, ref)
    w1 = np.minimum(np.maximum(x3, -rate_limit), rate_limit)
    w2 = np.minimum(np.maximum(u2, -rate_limit), rate_limit)
    w0 = base_rate_at(kp, total_mass, h0, c1, c2, c12, w1, w2)
    return w0, w1, w2, u1_dot, w2


# The kernel integrates each trial with one of three right-hand sides, chosen once per trial,
# so that the inner loop has no branches (a branch there costs ~30 %, measured). At every
# grid sample the integrator takes cos and sin of th1 and of th1 + th2 once: they serve the
# first RK4 stage and, stored in the trace, the metrics (momentum, flat outputs).

#: Trace columns: the prolonged state, the applied th2', and the sample's trigonometry.
TRACE_WIDTH = 9
COS1, SIN1, COS12, SIN12 = 5, 6, 7, 8


@jitable
def _rates_noisy(
    kc: Coefficients, gains: Gains, kp: Coefficients, total_mass: float, h0: float,
    rate_limit: float, x0: float, x1: float, x2: float, x3: float, ref: Array, n0: float,
    n1: float, n2: float, c1: float, s1: float, c12: float, s12: float,
) -> tuple[Real, Real, Real, Real, Real]:
    """Sensor noise: the controller measures other angles than the plant's (c1.. unused)."""
    return closed_loop(kc, gains, kp, total_mass, h0, rate_limit, x0, x1, x2, x3, ref,
                       n0, n1, n2)


@jitable
def _rates_exact(
    kc: Coefficients, gains: Gains, kp: Coefficients, total_mass: float, h0: float,
    rate_limit: float, x0: float, x1: float, x2: float, x3: float, ref: Array, n0: float,
    n1: float, n2: float, c1: float, s1: float, c12: float, s12: float,
) -> tuple[Real, Real, Real, Real, Real]:
    """No noise: controller and plant share c1 = cos th1, s1 = sin th1, c12 = cos(th1 + th2)."""
    return _closed_loop(kc, gains, kp, total_mass, h0, rate_limit, x3, ref, x0, x1, x2,
                        c1, s1, c1, np.cos(x2), c12)


@jitable
def _rates_exact_flat_plant(
    kc: Coefficients, gains: Gains, kp: Coefficients, total_mass: float, h0: float,
    rate_limit: float, x0: float, x1: float, x2: float, x3: float, ref: Array, n0: float,
    n1: float, n2: float, c1: float, s1: float, c12: float, s12: float,
) -> tuple[Real, Real, Real, Real, Real]:
    """No noise, plant with d2 = 0: its terms in cos th2 and cos(th1 + th2) vanish."""
    return _closed_loop(kc, gains, kp, total_mass, h0, rate_limit, x3, ref, x0, x1, x2,
                        c1, s1, c1, 0.0, 0.0)


def _trial_integrator(
    rates: Callable[..., tuple[Real, Real, Real, Real, Real]],
) -> Callable[..., tuple[int, bool]]:
    """RK4 of one trial over the grid with the right-hand side ``rates``, compiled inline.

    ``rates`` takes the state, the reference, the noise, and cos, sin of th1 and th1 + th2 of
    the state (exact at the first stage; the other stages compute their own).
    """

    @jitable
    def integrate(
        tr: Array, kc: Coefficients, gains: Gains, kp: Coefficients, M: float, H0: float,
        rate_limit: float, ref: Array, noise: Array, dt: float, bound: float,
    ) -> tuple[int, bool]:
        n = tr.shape[0] - 1
        half = 0.5 * dt
        sixth = dt / 6.0
        x0, x1, x2, x3 = tr[0, 0], tr[0, 1], tr[0, 2], tr[0, 3]
        n0 = n1 = n2 = 0.0
        for s in range(n + 1):
            c1, s1 = np.cos(x1), np.sin(x1)
            c12, s12 = np.cos(x1 + x2), np.sin(x1 + x2)
            tr[s, COS1], tr[s, SIN1], tr[s, COS12], tr[s, SIN12] = c1, s1, c12, s12
            if noise.shape[0]:
                j = min(s, n - 1)
                n0, n1, n2 = noise[j, 0], noise[j, 1], noise[j, 2]
            ra = ref[2 * s]
            # fmt: off
            a0, a1, a2, a3, u2 = rates(kc, gains, kp, M, H0, rate_limit,
                                       x0, x1, x2, x3, ra, n0, n1, n2, c1, s1, c12, s12)
            tr[s, 4] = u2
            if s == n:
                break
            rb, rc = ref[2 * s + 1], ref[2 * s + 2]
            y0, y1, y2, y3 = x0 + half * a0, x1 + half * a1, x2 + half * a2, x3 + half * a3
            b0, b1, b2, b3, _ = rates(kc, gains, kp, M, H0, rate_limit, y0, y1, y2, y3, rb,
                                      n0, n1, n2, np.cos(y1), np.sin(y1), np.cos(y1 + y2),
                                      0.0)
            y0, y1, y2, y3 = x0 + half * b0, x1 + half * b1, x2 + half * b2, x3 + half * b3
            c0_, c1_, c2_, c3_, _ = rates(kc, gains, kp, M, H0, rate_limit, y0, y1, y2, y3,
                                          rb, n0, n1, n2, np.cos(y1), np.sin(y1),
                                          np.cos(y1 + y2), 0.0)
            y0, y1, y2, y3 = x0 + dt * c0_, x1 + dt * c1_, x2 + dt * c2_, x3 + dt * c3_
            d0, d1, d2, d3, _ = rates(kc, gains, kp, M, H0, rate_limit, y0, y1, y2, y3, rc,
                                      n0, n1, n2, np.cos(y1), np.sin(y1), np.cos(y1 + y2),
                                      0.0)
            # fmt: on
            x0 = x0 + sixth * (a0 + 2.0 * b0 + 2.0 * c0_ + d0)
            x1 = x1 + sixth * (a1 + 2.0 * b1 + 2.0 * c1_ + d1)
            x2 = x2 + sixth * (a2 + 2.0 * b2 + 2.0 * c2_ + d2)
            x3 = x3 + sixth * (a3 + 2.0 * b3 + 2.0 * c3_ + d3)
            if not (abs(x0) <= bound and abs(x1) <= bound and abs(x2) <= bound
                    and abs(x3) <= bound):
                tr[s + 1:, :] = np.nan
                return s, True
            tr[s + 1, 0], tr[s + 1, 1], tr[s + 1, 2], tr[s + 1, 3] = x0, x1, x2, x3
        return n, False

    return integrate


_integrate_noisy = _trial_integrator(_rates_noisy)
_integrate_exact = _trial_integrator(_rates_exact)
_integrate_exact_flat_plant = _trial_integrator(_rates_exact_flat_plant)


# fmt: off
@jitable
def _links_row(a: Array, i: int) -> Links:
    return Links(a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5],
                 a[i, 6], a[i, 7], a[i, 8], a[i, 9], a[i, 10], a[i, 11])


@jitable
def _coefficients_row(a: Array, i: int) -> Coefficients:
    return Coefficients(a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5],
                        a[i, 6], a[i, 7], a[i, 8], a[i, 9], a[i, 10])
# fmt: on


@kernel
def _rk4_kernel(
    ref: Array,
    theta_ref: Array,
    plan_theta: Array,
    plan_theta_dot: Array,
    kc: Coefficients,
    gains: Gains,
    links: Array,
    plant_k: Array,
    h0: Array,
    initial: Array,
    noise: Array,
    dt: float,
    rate_limit: float,
    threshold: float,
    bound: float,
    record: bool,
    metrics: Array,
    status: NDArray[np.int64],
    event: NDArray[np.int64],
    trace: Array,
) -> None:
    """Integrate every trial with RK4 on the grid; write metrics, status and (maybe) traces.

    Shapes: ref (2n+1, 6); theta_ref (n+1, 3); plan_theta, plan_theta_dot (m, 3); links
    (N, 12); plant_k (N, 11); h0 (N,); initial (N, 4); noise (N, n, 3) or (N, 0, 3);
    metrics (N, N_METRICS); status, event (N,); trace (N, n+1, 5) if record.
    """
    n = theta_ref.shape[0] - 1
    has_noise = noise.shape[1] > 0
    scratch = np.empty((n + 1, TRACE_WIDTH))
    for i in range(links.shape[0]):
        tr = trace[i] if record else scratch
        p = _links_row(links, i)
        kp = _coefficients_row(plant_k, i)
        M = p.m0 + p.m1 + p.m2
        H0 = h0[i]
        tr[0, 0], tr[0, 1], tr[0, 2], tr[0, 3] = (initial[i, 0], initial[i, 1], initial[i, 2],
                                                  initial[i, 3])
        flat_plant = (kp.a2 == 0.0 and kp.a3 == 0.0 and kp.b2 == 0.0 and kp.b3 == 0.0
                      and kp.c2 == 0.0 and kp.c3 == 0.0)
        if has_noise:
            last, diverged = _integrate_noisy(tr, kc, gains, kp, M, H0, rate_limit, ref,
                                              noise[i], dt, bound)
        elif flat_plant:
            last, diverged = _integrate_exact_flat_plant(tr, kc, gains, kp, M, H0, rate_limit,
                                                         ref, noise[i], dt, bound)
        else:
            last, diverged = _integrate_exact(tr, kc, gains, kp, M, H0, rate_limit, ref,
                                              noise[i], dt, bound)
        if diverged:
            event[i] = last + 1
        first = trace_metrics(
            metrics[i],
            tr,
            last,
            diverged,
            ref,
            theta_ref,
            plan_theta,
            plan_theta_dot,
            kc,
            p,
            H0,
            dt,
            threshold,
        )
        if diverged:
            status[i] = STATUS_DIVERGED
        elif first >= 0:
            status[i] = STATUS_SINGULAR
            event[i] = first
        else:
            status[i] = STATUS_OK
            event[i] = -1


@kernel
def _trace_metrics_kernel(
    trace: Array,
    last: int,
    diverged: bool,
    ref: Array,
    theta_ref: Array,
    plan_theta: Array,
    plan_theta_dot: Array,
    kc: Coefficients,
    links_row: Array,
    h0: float,
    dt: float,
    threshold: float,
    out: Array,
) -> int:
    return trace_metrics(
        out,
        trace,
        last,
        diverged,
        ref,
        theta_ref,
        plan_theta,
        plan_theta_dot,
        kc,
        _links_row(links_row.reshape(1, 12), 0),
        h0,
        dt,
        threshold,
    )


@kernel
def _rates(
    x: Array,
    ref: Array,
    noise_row: Array,
    kc: Coefficients,
    gains: Gains,
    kp: Coefficients,
    total_mass: float,
    h0: float,
    rate_limit: float,
) -> Array:
    w0, w1, w2, u1_dot, _ = closed_loop(
        kc,
        gains,
        kp,
        total_mass,
        h0,
        rate_limit,
        x[0],
        x[1],
        x[2],
        x[3],
        ref,
        noise_row[0],
        noise_row[1],
        noise_row[2],
    )
    return np.array([w0, w1, w2, u1_dot])


@dataclass(frozen=True)
class Scenario:
    """What every trial of a batch shares: the plan, the controller and the time grid.

    Attributes
    ----------
    plan : FlatPlan, also the controller's model (its coefficients)
    gains : Gains
    dt : integration and sampling step [s]; must divide the plan's duration
    rate_limit : joint-rate limit [rad/s]; inf for none
    singular_threshold : margin below which a sample counts as a singularity hit [rad/s]
    divergence_bound : a state component beyond it (or non-finite) stops the trial
    plan_samples : size of the plan's own grid, on which ``plan_momentum_residual`` is taken
    """

    plan: FlatPlan
    gains: Gains
    dt: float
    rate_limit: float = math.inf
    singular_threshold: float = 1e-2
    divergence_bound: float = 1e4
    plan_samples: int = 201
    n_steps: int = field(init=False)

    def __post_init__(self) -> None:
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise FlatcliError(f"track.dt: must be > 0 s, got {self.dt}")
        steps = round(self.plan.duration / self.dt)
        if steps < 2 or not math.isclose(steps * self.dt, self.plan.duration, rel_tol=1e-9):
            raise FlatcliError(
                f"track.dt: must divide plan.duration = {self.plan.duration:g} s into at "
                f"least 2 steps, got {self.dt:g} s"
            )
        if not self.rate_limit > 0:
            raise FlatcliError(f"track.rate_limit: must be > 0 rad/s, got {self.rate_limit}")
        if not self.singular_threshold >= 0:
            raise FlatcliError("track.singular_threshold: must be >= 0 rad/s")
        if not self.divergence_bound > 0:
            raise FlatcliError("track.divergence_bound: must be > 0")
        object.__setattr__(self, "n_steps", steps)

    def prepared(self) -> Scenario:
        """This scenario with its reference tables computed (before shipping it to workers)."""
        _ = self.reference, self.theta_reference, self.plan_on_own_grid
        return self

    @property
    def times(self) -> Array:
        """(n + 1,) the grid t_j = j dt [s]."""
        return np.arange(self.n_steps + 1, dtype=float) * self.dt

    @cached_property
    def reference(self) -> Array:
        """(2 n + 1, 6) plan y1, y2, y1', y2', y1'', y2'' at half steps j dt / 2."""
        t = np.arange(2 * self.n_steps + 1, dtype=float) * (0.5 * self.dt)
        traj = self.plan.trajectory
        out = np.hstack([traj.derivative(t, 0), traj.derivative(t, 1), traj.derivative(t, 2)])
        return np.ascontiguousarray(out)

    @cached_property
    def theta_reference(self) -> Array:
        """(n + 1, 3) plan angles on the simulation grid [rad]."""
        return np.ascontiguousarray(self.plan.sample(self.times).theta)

    @cached_property
    def plan_on_own_grid(self) -> tuple[Array, Array]:
        """(plan_samples, 3) plan angles [rad] and their exact rates [rad/s]."""
        samples = self.plan.sample(self.plan.grid(self.plan_samples))
        return np.ascontiguousarray(samples.theta), np.ascontiguousarray(samples.theta_dot)


@dataclass(frozen=True)
class Trials:
    """What differs between trials: the plant and the initial state; N trials.

    Attributes
    ----------
    links : (N, 12) plant mass, inertia, length, com (see ``Links``)
    momentum : (N,) plant angular momentum H0 [kg m^2/s]
    initial : (N, 4) th0, th1, th2 [rad], u1 [rad/s] at t = 0
    noise : (N, n, 3) sensor noise per step on the three angles [rad], or None
    """

    links: Array
    momentum: Array
    initial: Array
    noise: Array | None = None

    def __post_init__(self) -> None:
        n = self.links.shape[0]
        if (
            self.links.shape != (n, 12)
            or self.momentum.shape != (n,)
            or (self.initial.shape != (n, 4))
        ):
            raise ValueError("Trials: links (N, 12), momentum (N,), initial (N, 4) expected")
        if self.noise is not None and (self.noise.ndim != 3 or self.noise.shape[0] != n):
            raise ValueError("Trials: noise (N, n, 3) expected")

    @property
    def count(self) -> int:
        return int(self.links.shape[0])

    def subset(self, index: slice | NDArray[np.intp]) -> Trials:
        return Trials(
            self.links[index],
            self.momentum[index],
            self.initial[index],
            None if self.noise is None else self.noise[index],
        )


@dataclass(frozen=True)
class Outcome:
    """Results of N trials.

    Attributes
    ----------
    metrics : (N, N_METRICS) in the order of ``metrics.METRIC_NAMES``
    status : (N,) STATUS_OK, STATUS_SINGULAR or STATUS_DIVERGED
    event_time : (N,) first singular hit or divergence time [s] (nan if none)
    trace : (N, n + 1, 5) th0, th1, th2, u1, applied u2 per grid sample, if recorded
    """

    metrics: Array
    status: NDArray[np.int64]
    event_time: Array
    trace: Array | None


def plant_coefficients(links: Array) -> Array:
    """(N, 11) derived constraint coefficients for (N, 12) plant parameters."""
    k = constraint_coefficients(Links(*np.asarray(links, dtype=float).T), "derived")
    return np.ascontiguousarray(np.stack(np.broadcast_arrays(*k), axis=-1))


def simulate(
    scenario: Scenario,
    trials: Trials,
    integrator: Integrator = "rk4",
    record: bool = False,
) -> Outcome:
    """Run N closed-loop trials of a scenario.

    Parameters
    ----------
    scenario : Scenario
    trials : Trials (N)
    integrator : "rk4" (compiled, fixed step dt) or "dop853" (solve_ivp reference)
    record : keep each trial's trace

    Returns
    -------
    Outcome
    """
    n = scenario.n_steps
    if trials.noise is not None and trials.noise.shape[1:] != (n, 3):
        raise ValueError(f"Trials: noise must be (N, {n}, 3) for this scenario")
    theta_ref = scenario.theta_reference
    plan_theta, plan_theta_dot = scenario.plan_on_own_grid
    N = trials.count
    metrics = np.empty((N, N_METRICS))
    status = np.zeros(N, dtype=np.int64)
    event = np.full(N, -1, dtype=np.int64)
    trace = np.empty((N, n + 1, TRACE_WIDTH)) if record else np.empty((0, 0, TRACE_WIDTH))
    kc = scenario.plan.coefficients
    kc = Coefficients(*(float(v) for v in kc))
    gains = Gains(*(float(v) for v in scenario.gains))
    plant_k = plant_coefficients(trials.links)
    noise = trials.noise if trials.noise is not None else np.zeros((N, 0, 3))
    if integrator == "rk4":
        _rk4_kernel(
            scenario.reference,
            theta_ref,
            plan_theta,
            plan_theta_dot,
            kc,
            gains,
            np.ascontiguousarray(trials.links, dtype=float),
            plant_k,
            np.ascontiguousarray(trials.momentum, dtype=float),
            np.ascontiguousarray(trials.initial, dtype=float),
            np.ascontiguousarray(noise, dtype=float),
            scenario.dt,
            scenario.rate_limit,
            scenario.singular_threshold,
            scenario.divergence_bound,
            record,
            metrics,
            status,
            event,
            trace,
        )
    elif integrator == "dop853":
        for i in range(N):
            tr = _reference_trace(scenario, trials, plant_k, kc, gains, i)
            last = int(np.flatnonzero(np.isfinite(tr[:, :4]).all(axis=1))[-1])
            diverged = last < n
            first = _trace_metrics_kernel(
                tr,
                last,
                diverged,
                scenario.reference,
                theta_ref,
                plan_theta,
                plan_theta_dot,
                kc,
                np.ascontiguousarray(trials.links[i], dtype=float),
                float(trials.momentum[i]),
                scenario.dt,
                scenario.singular_threshold,
                metrics[i],
            )
            if diverged:
                status[i], event[i] = STATUS_DIVERGED, last + 1
            elif first >= 0:
                status[i], event[i] = STATUS_SINGULAR, first
            if record:
                trace[i] = tr
    else:
        raise FlatcliError(
            f"track.integrator: expected one of {list(INTEGRATORS)}, got {integrator!r}"
        )
    event_time = np.where(event >= 0, event * scenario.dt, np.nan)
    return Outcome(metrics, status, event_time, trace[:, :, :5] if record else None)


def _reference_trace(
    scenario: Scenario, trials: Trials, plant_k: Array, kc: Coefficients, gains: Gains, i: int
) -> Array:
    """(n + 1, TRACE_WIDTH) trace of trial i by solve_ivp (DOP853); rows after a failure are
    nan."""
    n = scenario.n_steps
    times = scenario.times
    traj = scenario.plan.trajectory
    kp = Coefficients(*(float(v) for v in plant_k[i]))
    M = float(np.sum(trials.links[i, :3]))
    h0 = float(trials.momentum[i])
    noise = trials.noise[i] if trials.noise is not None else np.zeros((n, 3))
    bound = scenario.divergence_bound

    def rhs(t: float, x: Array, noise_row: Array) -> Array:
        ref = np.concatenate(
            [
                traj.derivative(np.array([t]), 0)[0],
                traj.derivative(np.array([t]), 1)[0],
                traj.derivative(np.array([t]), 2)[0],
            ]
        )
        return np.asarray(_rates(x, ref, noise_row, kc, gains, kp, M, h0, scenario.rate_limit))

    def blowup(t: float, x: Array, noise_row: Array) -> float:
        return float(bound - np.max(np.abs(x)))

    blowup.terminal = True  # type: ignore[attr-defined]
    trace = np.full((n + 1, TRACE_WIDTH), np.nan)
    trace[0, :4] = trials.initial[i]
    # Without noise one integration over the whole grid; with noise (held per step) one
    # integration per step, so the solver never steps across a jump of the measured angles.
    segments = [(0, n)] if trials.noise is None else [(s, s + 1) for s in range(n)]
    x = trials.initial[i].astype(float)
    for start, stop in segments:
        with np.errstate(all="ignore"):
            sol = solve_ivp(
                rhs,
                (times[start], times[stop]),
                x,
                method="DOP853",
                t_eval=times[start : stop + 1],
                rtol=REFERENCE_RTOL,
                atol=REFERENCE_ATOL,
                args=(noise[start],),
                events=blowup,
            )
        got = sol.y.T
        ok = np.isfinite(got).all(axis=1) & (np.abs(got) <= bound).all(axis=1)
        good = got[: int(np.argmin(ok)) if not ok.all() else len(got)]
        trace[start : start + len(good), :4] = good
        if len(good) < stop - start + 1 or sol.status == -1:
            break
        x = good[-1]
    # applied u2 at each valid sample, with the noise of the step that starts there
    valid = np.isfinite(trace[:, :4]).all(axis=1)
    rows = np.flatnonzero(valid)
    ref = scenario.reference[2 * rows].T
    held = noise[np.minimum(rows, n - 1)].T
    x0, x1, x2, x3 = trace[rows, :4].T
    with np.errstate(all="ignore"):
        th12 = x1 + x2
        trace[rows, COS1], trace[rows, SIN1] = np.cos(x1), np.sin(x1)
        trace[rows, COS12], trace[rows, SIN12] = np.cos(th12), np.sin(th12)
        trace[rows, 4] = closed_loop(
            kc,
            gains,
            kp,
            M,
            h0,
            scenario.rate_limit,
            x0,
            x1,
            x2,
            x3,
            ref,
            held[0],
            held[1],
            held[2],
        )[4]
    return trace
