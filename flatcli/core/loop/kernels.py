"""The compiled closed loop: one kernel factory, one kernel per (model, plant).

A closed loop is a base law's part (the controller and its model: the paper's closed form for
N = 2, a chain's, an as-built robot's) and a plant's part (kinematic or dynamic), composed by
``base.base_ops``. Each combination supplies the same few functions, its ``Ops``:

* ``make_loop(shared, trials, i, scratch)``: trial i's loop record (its plant, its H0, its
  servo; the controller's model and gains in ``shared``);
* ``bounded(loop)``: whether the actuators bound the right-hand side where the controller's
  margin changes sign (a finite rate limit, or a finite torque limit on the dynamic plant):
  then the integrators pass such a crossing, else the trial stops there;
* ``initial_state(loop, initial, ref0, x0)``: the state at t = 0 into x0;
* ``rhs``, ``observe``, ``record``: the right-hand side and what an output sample keeps
  (``integrate.make_trial_integrators`` compiles the integrators around them);
* ``residual(loop, trials, i, plan_theta, plan_theta_dot)``: the plan's momentum residual
  on the trial's plant.

``make_batch`` builds from them the batch runner every kernel is: trial after trial, RK4 or
the adaptive Dormand-Prince, metrics and status (``metrics.conclude_trial``); ``make_rhs``
and ``make_observer`` the single evaluations the scipy reference (``reference``) calls.
The kernels of each combination are those factories' functions, compiled once
(``compile_kernels``; ``table.KERNELS`` generates them all, by (controller, model, plant)).

Every buffer a kernel writes into is made by the caller (``Buffers``): the kernels run
without numba's reference counting (``_jit.kernel``), which on the N-link loop, whose
records hold arrays, costs more than the arithmetic.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable, jitable_variant, named_kernel, variant_tag
from flatcli.core.loop.integrate import (
    WORK_ROWS,
    make_trial_integrators,
    no_period,
    no_reset,
    no_sample,
    observed,
    plan_flag,
)
from flatcli.core.loop.metrics import (
    ACCUMULATOR_SIZE,
    Event,
    conclude_trial,
    finish_metrics,
    observe_crossing,
    reset_accumulator,
)
from flatcli.core.robots.chain import barycentric_matrices

Array = NDArray[np.float64]

#: The kernels' integrator codes.
RK4 = 0
ADAPTIVE = 1
EVENT_NONE = int(Event.NONE)


class Grid(NamedTuple):
    """The plan on the scenario's grids: ref (2 n + 1, 3 N) y, y', y'' at half steps;
    theta_ref (n + 1, N + 1) its angles on the output grid; breaks, local its piecewise
    polynomials (``integrate.plan_flag``); plan_theta, plan_theta_dot (p, N + 1) on its own
    grid (for the momentum residual)."""

    ref: Array
    theta_ref: Array
    breaks: Array
    local: Array
    plan_theta: Array
    plan_theta_dot: Array


class Settings(NamedTuple):
    """dt [s], the divergence bound, the singular threshold [rad/s], rtol, atol, the step
    budget, whether traces are kept, the twin's tolerance factor (0: no twin; see
    ``make_batch``), and which output samples the metrics observe: every ``every``-th one
    and the last (1: all; ``integrate.observed``)."""

    dt: float
    bound: float
    threshold: float
    rtol: float
    atol: float
    max_steps: int
    record: bool
    twin: float
    every: int = 1


class TrialArrays(NamedTuple):
    """What differs between trials (T of them): params (T, 4 (N + 1)) mass, inertia,
    length, com (of the plant's equivalent placement, ``model.RobotParams.placement``); h0
    (T,) [kg m^2/s]; servo (T, 2) bandwidth [rad/s], torque limit [N m]; initial (T, 2 N)
    th(0), u(0); plant (T, ...) the plant's constraint coefficients (the paper's robot,
    (T, 11)) or its barycentric matrix K (chains, (T, N + 1, N + 1)); offset (T,) the turn
    of its last link that placement adds [rad] (0: none)."""

    params: Array
    h0: Array
    servo: Array
    initial: Array
    plant: Array
    offset: Array


class Results(NamedTuple):
    """Written per trial: metrics (T, N_METRICS), status, event (T,), event_time (T,),
    trace (T, n + 1, width) if recorded (else (0, 0, width)), final (T, N + 1) the plant's
    angles th0..thN at t = T [rad] (nan where the trial stopped before T), and extra (T, E)
    the controller's own columns (``Ops.extra_columns``; E = 0 for a law without)."""

    metrics: Array
    status: NDArray[np.int64]
    event: NDArray[np.int64]
    event_time: Array
    trace: Array
    final: Array
    extra: Array


class Buffers(NamedTuple):
    """The kernels' scratch, made by the caller (``Kernels.buffers``): the integrator's work
    rows, the metrics' accumulator (and the twin's), the noise of the measured angles, two
    flags of the plan, the state at t = 0 and at the end, an empty trace, and the loop's own
    scratch (``Ops.scratch``)."""

    work: Array
    acc: Array
    twin_acc: Array
    noise: Array
    flag: Array
    flag_end: Array
    x0: Array
    final: Array
    no_trace: Array
    scratch: Any


@jitable
def no_extras(loop: Any, row: Array) -> None:
    """A law that reports no columns of its own (``Ops.extras``)."""


@dataclass(frozen=True)
class Ops:
    """The functions of one (model, plant) combination (module docstring), and its sizes:
    ``state(n)`` and ``aux(n)`` (what its right-hand side writes after the state's
    derivative, the margin first), ``width(n)`` (a trace row), ``scratch(n)`` (its loop's
    buffers; with ``needs_shared_scratch`` ``scratch(n, shared, flag_size)``); ``stage``
    (None: ``rhs``), the right-hand side of the integrators' stages, whose outputs after the
    margin nobody reads (``integrate.make_trial_integrators``).

    A controller acting at sample instants (``compose.sampled_ops``) adds ``reset``,
    ``period`` and ``sample`` (``integrate.make_trial_integrators``), and ``extras(loop,
    row)`` writing its ``extra_columns`` per trial. A law another can wrap declares
    ``additive(loop, ref, dv, out)`` (``out`` = its reference ``ref`` with dv (N,) added where
    its input enters: its command becomes its own plus dv) and ``measure(loop, x, noise, ref,
    s0)`` (the errors its design is about at the measured state, into ``s0``)."""

    make_loop: Callable[..., Any]
    bounded: Callable[..., bool]
    initial_state: Callable[..., None]
    rhs: Callable[..., None]
    observe: Callable[..., None]
    record: Callable[..., None]
    residual: Callable[..., float]
    state: Callable[[int], int]
    aux: Callable[[int], int]
    width: Callable[[int], int]
    scratch: Callable[..., Any]
    stage: Callable[..., None] | None = None
    reset: Callable[..., None] = no_reset
    period: Callable[..., int] = no_period
    sample: Callable[..., None] = no_sample
    extras: Callable[..., None] = no_extras
    extra_columns: tuple[str, ...] = ()
    extra_counts: tuple[str, ...] = ()
    additive: Callable[..., None] | None = None
    measure: Callable[..., None] | None = None
    needs_shared_scratch: bool = False

    @property
    def sampled(self) -> bool:
        """Whether a controller acts at sample instants (its hooks are not the defaults)."""
        return not (self.reset is no_reset and self.period is no_period
                    and self.sample is no_sample and self.extras is no_extras)


def ops_tag(ops: Ops) -> str:
    """``_jit.variant_tag`` of a combination's compiled functions."""
    hooks = (ops.reset, ops.period, ops.sample, ops.extras) if ops.sampled else ()
    return variant_tag(ops.make_loop, ops.bounded, ops.initial_state, ops.rhs, ops.observe,
                       ops.record, ops.residual, ops.stage or ops.rhs, *hooks)


def make_batch(ops: Ops) -> Callable[..., None]:
    """The batch runner of a combination: every trial integrated alone, in order.

    With ``settings.twin`` f in (0, 1) an adaptive trial that reaches T is integrated a second
    time, at its tolerances times f and without observing (a *twin*). The adaptive
    integrator's global error is about proportional to its tolerance, so the twin's error is
    about f times the trial's, the two final solutions differ by about (1 - f) times the
    trial's own error, and ``err_estimate`` is the Euclidean norm of the difference of their
    final angles divided by (1 - f) [rad] (docs, *Metrics*). A tighter twin, not a looser
    one: the estimate then rests on the twin being the better solution, not on the errors'
    proportionality, which near the default tolerances fails by up to 8x (a looser twin, and
    one at a tenth, each fell below the true error by more than 3x on 1 in 200 perturbed
    trials; one at a hundredth stayed within 0.70-1.36 of it on 595).
    """
    rk4_trial, adaptive_trial = make_trial_integrators(ops.rhs, ops.observe, ops.record,
                                                       ops.stage, ops.reset, ops.period,
                                                       ops.sample)
    make_loop, bounded, initial_state, residual = (ops.make_loop, ops.bounded,
                                                   ops.initial_state, ops.residual)
    extras = ops.extras
    variant = jitable_variant(ops_tag(ops))

    @variant
    def run_batch(method: int, shared: Any, trials: TrialArrays, grid: Grid,
                  settings: Settings, tables: Array, buffers: Buffers,
                  results: Results) -> None:
        n = grid.theta_ref.shape[0] - 1
        angles = grid.theta_ref.shape[1]
        obs = (grid.theta_ref, grid.ref, settings.threshold)
        x0 = buffers.x0
        work = buffers.work
        for i in range(trials.params.shape[0]):
            loop = make_loop(shared, trials, i, buffers.scratch)
            passes = bounded(loop)
            initial_state(loop, trials.initial[i], grid.ref[0], x0)
            acc = buffers.acc
            reset_accumulator(acc)
            tr = results.trace[i] if settings.record else buffers.no_trace
            estimate = math.nan
            at_end = results.final[i]
            if method == RK4:
                last, ev, t_ev, evaluations = rk4_trial(
                    loop, obs, x0, grid.ref, grid.breaks, grid.local, buffers.flag,
                    buffers.flag_end, settings.dt, n, settings.bound, passes, tables[i],
                    settings.record, tr, acc, work, buffers.noise, settings.every)
                steps = last
            else:
                last, ev, t_ev, steps, evaluations = adaptive_trial(
                    loop, obs, x0, grid.breaks, grid.local, settings.dt, n, settings.bound,
                    settings.rtol, settings.atol, settings.max_steps, tables[i],
                    settings.record, tr, acc, work, buffers.noise, buffers.flag, grid.ref,
                    passes, True, settings.every)
            extras(loop, results.extra[i])  # before a twin starts the controller afresh
            # the angles at T, where the trial got there (both integrators leave their last
            # state in integrate._X, the first work row); before the twin overwrites it
            for k in range(angles):
                at_end[k] = work[0, k] if ev == EVENT_NONE else math.nan
            if method != RK4 and ev == EVENT_NONE and settings.twin > 0.0:
                final = buffers.final
                for k in range(angles):
                    final[k] = work[0, k]  # the trial's end (integrate._X)
                reset_accumulator(buffers.twin_acc)
                _, twin_ev, _, _, twin_evaluations = adaptive_trial(
                    loop, obs, x0, grid.breaks, grid.local, settings.dt, n,
                    settings.bound, settings.rtol * settings.twin,
                    settings.atol * settings.twin, settings.max_steps, tables[i], False,
                    buffers.no_trace, buffers.twin_acc, work, buffers.noise, buffers.flag,
                    grid.ref, passes, False, 1)
                evaluations += twin_evaluations
                if twin_ev == EVENT_NONE:
                    gap = 0.0
                    for k in range(angles):
                        gap += (work[0, k] - final[k]) ** 2
                    estimate = math.sqrt(gap) / (1.0 - settings.twin)
            conclude_trial(i, residual(loop, trials, i, grid.plan_theta, grid.plan_theta_dot),
                           acc, last, n, ev, t_ev, estimate, steps, evaluations, settings.dt,
                           settings.record, tr, results.metrics, results.status,
                           results.event, results.event_time)

    return run_batch


def make_single(ops: Ops) -> tuple[Callable[..., None], Callable[..., None],
                                   Callable[..., float], Callable[..., None]]:
    """(initial_of, rhs_at, observe_trace, record_trace) of a combination, one trial i at a
    time (for the scipy reference): the state at t = 0 into ``out``; the state's derivative
    and the aux values at time t into ``out``; the metrics of a trace computed elsewhere
    (samples 0..last, and the times of the crossings it passed; returns the first singular
    hit's time, nan if none); the trace rows of those samples."""
    make_loop, initial_state, rhs, observe, residual, record = (
        ops.make_loop, ops.initial_state, ops.rhs, ops.observe, ops.residual, ops.record)
    variant = jitable_variant(ops_tag(ops))

    @variant
    def initial_of(shared: Any, trials: TrialArrays, i: int, grid: Grid, buffers: Buffers,
                   out: Array) -> None:
        loop = make_loop(shared, trials, i, buffers.scratch)
        initial_state(loop, trials.initial[i], grid.ref[0], out)

    @variant
    def rhs_at(shared: Any, trials: TrialArrays, i: int, grid: Grid, buffers: Buffers,
               t: float, x: Array, noise: Array, out: Array) -> None:
        """At time t, the plan's flag evaluated there (t < 0: row -t - 1 of grid.ref, the
        flag tabulated on the half-step grid, exactly as the kernels observe it)."""
        loop = make_loop(shared, trials, i, buffers.scratch)
        if t < 0.0:
            rhs(loop, x, grid.ref[int(-t) - 1], noise, out)
            return
        plan_flag(grid.breaks, grid.local, t, buffers.flag)
        rhs(loop, x, buffers.flag, noise, out)

    @variant
    def observe_trace(shared: Any, trials: TrialArrays, i: int, grid: Grid,
                      settings: Settings, buffers: Buffers, states: Array, rates: Array,
                      last: int, complete: bool, crossings: Array, out: Array) -> float:
        loop = make_loop(shared, trials, i, buffers.scratch)
        acc = buffers.acc
        reset_accumulator(acc)
        obs = (grid.theta_ref, grid.ref, settings.threshold)
        n = grid.theta_ref.shape[0] - 1
        for j in range(last + 1):
            if observed(j, n, settings.every):
                observe(loop, obs, acc, j, states[j], rates[j])
        for t in crossings:
            observe_crossing(acc, t)
        return finish_metrics(out, acc, complete, settings.dt,
                              residual(loop, trials, i, grid.plan_theta, grid.plan_theta_dot),
                              math.nan, 0, 0)

    @variant
    def record_trace(shared: Any, trials: TrialArrays, i: int, buffers: Buffers,
                     states: Array, rates: Array, last: int, trace: Array) -> None:
        loop = make_loop(shared, trials, i, buffers.scratch)
        nx = states.shape[1]
        for j in range(last + 1):
            record(loop, trace, j, nx, states[j], rates[j])

    return initial_of, rhs_at, observe_trace, record_trace


def make_control_single(ops: Ops) -> tuple[Callable[..., int], Callable[..., None],
                                           Callable[..., None]]:
    """(control_start, sample_at, extras_at) of a combination whose controller acts at
    sample instants (``Ops.sampled``), one trial i at a time (for the scipy reference):
    start its controller afresh and return its period p [output steps]; its sample at output
    sample j, state x and noise (before the right-hand side is evaluated there: ``rhs_at``
    then sees what it holds); its columns into ``row``. The controller's state lives in
    ``buffers.scratch`` between the calls."""
    make_loop, reset, period, sample, extras = (ops.make_loop, ops.reset, ops.period,
                                                ops.sample, ops.extras)
    variant = jitable_variant(ops_tag(ops))

    @variant
    def control_start(shared: Any, trials: TrialArrays, i: int, buffers: Buffers) -> int:
        loop = make_loop(shared, trials, i, buffers.scratch)
        reset(loop)
        return period(loop)

    @variant
    def sample_at(shared: Any, trials: TrialArrays, i: int, grid: Grid, buffers: Buffers,
                  x: Array, noise: Array, j: int) -> None:
        loop = make_loop(shared, trials, i, buffers.scratch)
        sample(loop, x, noise, grid.ref[2 * j], j)

    @variant
    def extras_at(shared: Any, trials: TrialArrays, i: int, buffers: Buffers,
                  row: Array) -> None:
        loop = make_loop(shared, trials, i, buffers.scratch)
        extras(loop, row)

    return control_start, sample_at, extras_at


def chain_plant(params: Array, plant: str) -> Array:
    """Per trial, the plant's barycentric matrix (T, N + 1, N + 1)."""
    return barycentric_matrices(params)


@dataclass(frozen=True)
class Kernels:
    """The compiled functions of one (model, plant) combination: its batch kernel and its
    single-trial kernels (initial state, right-hand side, observer of a trace, trace rows:
    ``make_single``; then, for a controller acting at sample instants, its start, sample and
    columns: ``make_control_single``), and how its shared record and per-trial plant arrays
    are made (a law's ``shared``, ``chain_plant``, ...)."""

    ops: Ops
    batch: Callable[..., None]
    single: tuple[Callable[..., Any], ...]
    shared: Callable[..., Any]
    plant: Callable[[Array, str], Array]

    def buffers(self, n: int, flag_size: int, shared: Any = None) -> Buffers:
        """Fresh buffers for a robot of N = ``n`` joints, a reference flag of ``flag_size``
        and the kernels' shared record ``shared`` (what a sampled controller's scratch is
        made from, ``Ops.needs_shared_scratch``)."""
        ops = self.ops
        scratch = (ops.scratch(n, shared, flag_size) if ops.needs_shared_scratch
                   else ops.scratch(n))
        nx = self.ops.state(n)
        width = nx + self.ops.aux(n)
        return Buffers(np.zeros((WORK_ROWS, width)), np.zeros(ACCUMULATOR_SIZE),
                       np.zeros(ACCUMULATOR_SIZE), np.zeros(n + 1), np.zeros(flag_size),
                       np.zeros(flag_size), np.zeros(nx), np.zeros(nx),
                       np.zeros((0, self.ops.width(n))), scratch)


def compile_kernels(ops: Ops, name: str, shared: Callable[..., Any],
                    plant: Callable[[Array, str], Array], module: str = __name__) -> Kernels:
    """The kernels of one combination, generated: ``make_batch``'s runner and ``make_single``'s
    functions compiled, named ``<name>_batch``, ``_start``, ``_derivative``, ``_metrics`` and
    ``_trace`` in ``module`` (the one that makes them: numba caches a kernel by its module and
    name, and links its code by them; a compile child imports that module to find it)."""
    names = ["batch", "start", "derivative", "metrics", "trace"]
    functions = [make_batch(ops), *make_single(ops)]
    if ops.sampled:
        names += ["control_start", "sample", "extras"]
        functions += make_control_single(ops)
    compiled: list[Callable[..., Any]] = [named_kernel(f"{name}_{part}", module)(fn)
                                          for part, fn in zip(names, functions, strict=True)]
    return Kernels(ops, compiled[0], tuple(compiled[1:]), shared, plant)
