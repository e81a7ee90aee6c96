"""What a controller that acts at sample instants hands the loop factory (``loop.compose``).

Such a controller wraps an inner law (the flat law, or the as-built law): between its
samples the inner law runs with the controller's held values added where its input enters
(``Ops.additive``); at each sample instant the controller measures what the inner law's
design is about (``Ops.measure``) and updates what it holds. Its module gives one
``SampledPart``: Python to make a trial's scratch from the design (once per plan), and
compiled functions the loop calls, allocating nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class SampledPart:
    """A sampled controller's parts (``mpc.PART``).

    name : its ``track.controller`` value (it names the compiled kernels)
    scratch : scratch(design) -> a trial's mutable record (Python, once per batch), with
        (at least) the fields ``s0`` (S,), where the loop writes the errors measured at a
        sample, and ``held`` (N,), what the inner law's input gets added (a kernel runs
        without numba's runtime: the loop reads them as fields, no function returns them)
    reset : reset(scratch), compiled: a trial (or its twin) starts
    period : period(design) -> int, compiled: output steps between samples (>= 1)
    step : step(design, scratch, k), compiled: sample k's update of ``held``, from the
        errors in ``s0``
    extras : extras(scratch, row), compiled: the trial's ``columns`` into row (E,)
    columns : the per-trial columns it reports (metrics beside the loop's)
    counts : those of ``columns`` that are counts (written as integers)
    design : design(scenario) -> its design record (Python, once per plan; ``scenario`` a
        ``loop.simulate.Scenario``: its plan, law, plant, dt, limits and settings)
    gains : gains(scenario) -> the inner flat law's ``control.Gains`` (None: the
        scenario's own, track.kp and track.kv)
    """

    name: str
    scratch: Callable[[Any], Any]
    reset: Callable[..., None]
    period: Callable[..., int]
    step: Callable[..., None]
    extras: Callable[..., None]
    columns: tuple[str, ...]
    counts: tuple[str, ...] = ()
    design: Callable[[Any], Any] | None = None
    gains: Callable[[Any], Any] | None = None


@dataclass(frozen=True)
class LawPart:
    """A base law's parts (``flat.LAW``, ``asbuilt.LAW``), composed with a plant by
    ``loop.base.base_ops``; compiled unless said. Its commands are joint rates r (N,); it
    has N - 1 states of its own (integrators: the trace shows them as u_1..u_N-1) or none
    (the trace shows the plant's commands r_1..r_N-1 there).

    name : the ``track.controller`` value its kernels are named by
    shared : shared(model, gains, rate_limit, servo_is_plant, robot) -> what every trial
        shares (Python, once per plan; a record with ``rate_limit`` [rad/s])
    scratch : scratch(n) -> its buffers for N joints (Python, once per batch)
    make : make(shared, scratch) -> a trial's law record
    joints : joints(law) -> N
    states : states(n) -> its states' count (N - 1 or 0)
    servo : servo(shared, offset) -> (K, inertia, cos, sin, is_plant, lag_shortcut): the
        robot a dynamic plant's rate servo believes (``plants.dynamic.make``), for a plant
        whose last link is turned by ``offset`` [rad]
    command : command(law, measured, rates, z, ref, r, z_dot) -> its signed margin: at the
        measured angles (N + 1,) [rad] (the true ones plus the sensor's noise), the plant's
        joint rates (N + 1,) or none, its states z and the plan's flag ``ref`` at t, the
        commands into r (N,) [rad/s] and its states' rates into z_dot
    start : start(law, initial, z0): its states at t = 0 from the trial's ``initial`` (2 N,)
    start_rates : start_rates(law, initial, ref, r): the commands at t = 0 a plant with rate
        states starts from (the servo in equilibrium)
    trig : trig(law) -> (cs, sn): the trigonometry of the angles it last evaluated (valid
        where ``shares_trig``: after ``command`` without noise, after ``observed``; the
        paper's law: cos th1, sin th1 as floats, after ``command``)
    observed : observed(law, obs, j, theta, z, f, at) -> (squared error of its outputs
        [rad^2], margin [rad/s], singular threshold [rad/s]) at output sample j of the true
        state; ``obs`` = (theta_ref, ref, threshold) as the kernels pass it; f the loop's
        derivative there, the plant's aux values from f[at] (a law that knows its plant may
        read them: ``paper``)
    additive : additive(law, ref, dv, out): ``out`` = ``ref`` with dv (N,) added where its
        input enters (``kernels.Ops.additive``)
    measure : measure(law, measured, rates, z, ref, s0): the errors its design is about
        into s0 (``kernels.Ops.measure``)
    shares_trig : ``trig`` holds the true angles' trigonometry where said (the plant reuses it)
    bounded : its commands are bounded everywhere (no singular set: its margin never changes
        sign), else the plant's limits say (``kernels.Ops.bounded``)
    """

    name: str
    shared: Callable[..., Any]
    scratch: Callable[[int], Any]
    make: Callable[..., Any]
    joints: Callable[..., int]
    states: Callable[[int], int]
    servo: Callable[..., Any]
    command: Callable[..., float]
    start: Callable[..., None]
    start_rates: Callable[..., None]
    trig: Callable[..., Any]
    observed: Callable[..., tuple[float, float, float]]
    additive: Callable[..., None]
    measure: Callable[..., None]
    shares_trig: bool
    bounded: bool
