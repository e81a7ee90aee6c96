"""A controller written in plain Python, acting at sample instants around a compiled law.

A research controller is an object with (``PythonController``):

* ``sample`` [s]: its sample time (a multiple of track.dt that divides the duration);
* ``reset()``: a trial starts;
* ``step(k, t, errors) -> held``: at sample k (time t [s]) the errors the inner law's design is
  about, measured at the measured state (the flat law: e_j = y_j - y_jd and e_j' per flat
  output, (2 N,); the as-built law: th - th_r, then on the dynamic plant the joint rates'
  errors), returning the N values to hold until the next sample, added where the inner law's
  input enters (the flat law: to y_d'', so v_j = y_jd'' + dv_j + kv (..) + kp (..); the
  as-built law: to the joint-rate commands).

A controller with a ``command(t, theta, u, flag) -> (u_dot, rate)`` method instead acts at
every evaluation of the right-hand side, in place of the flat law on the paper's robot (the
kinematic plant; ``continuous``): given the measured angles theta (N + 1,) [rad], its
integrators u (N - 1,) [rad/s] (the commanded rates of joints 1..N-1, the prolonged state of
the flat law) and the plan's flat flag y, y', y'' (3 N,) at t, it returns their rates u_dot
(N - 1,) [rad/s^2] and the commanded rate of joint N [rad/s]. The plant (``plants.paper.
KINEMATIC``: rates clipped to the limit, the base from its momentum) and the rule
against wind-up (``control.unwound``) are compiled; each evaluation is a Python call.

A sampled controller runs where the MPC of ``mpc`` runs (``loop.compose``: the inner law,
the plant and the observer compiled), but its steps are Python calls. Either kind runs in the
scipy reference loop (DOP853 at rtol 1e-10, ``loop.reference``), one trial at a time: slower
than a compiled controller (27x for the MPC's step run as Python on a 10-sample trial,
tests/test_compose.py; more with more samples), for trying an idea, not for sweeps. ``PART``
is the sampled kind's ``SampledPart``: compiled no-ops around the Python calls the reference
makes. The MPC's step run by the Python interpreter gives the compiled MPC's trial to the bit
in that loop.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.controllers.parts import SampledPart
from flatcli.core.errors import FlatcliError

Array = NDArray[np.float64]


class PythonController(Protocol):
    """What ``flatcli.track(..., controller=obj)`` calls (module docstring)."""

    sample: float

    def reset(self) -> None: ...

    def step(self, k: int, t: float, errors: Array) -> Any: ...


class Design(NamedTuple):
    """The compiled loop's view of a Python controller: output steps per sample, the size S
    of the errors measured, the N values held."""

    every: int
    errors: int
    inputs: int


class Scratch(NamedTuple):
    """Where the loop writes the errors measured at a sample (S,) and reads what the
    controller holds (N,)."""

    s0: Array
    held: Array


def design(controller: Any, dt: float, duration: float, errors: int, inputs: int) -> Design:
    """A ``Design`` of ``controller`` (``errors``, ``inputs``: S and N); FlatcliError naming
    it unless its sample time is a multiple of dt that divides the duration and it has
    ``reset`` and ``step``."""
    sample = getattr(controller, "sample", None)
    if not (isinstance(sample, int | float) and sample > 0 and math.isfinite(sample)):
        raise FlatcliError(f"controller: its sample time must be a finite number > 0 s, got "
                           f"{sample!r}")
    every = round(sample / dt)
    steps = round(duration / dt)
    if every < 1 or not math.isclose(every * dt, sample, rel_tol=1e-9) or steps % every:
        raise FlatcliError(f"controller: its sample time {sample:g} s must be a multiple of "
                           f"track.dt = {dt:g} s that divides plan.duration = {duration:g} s")
    for name in ("reset", "step"):
        if not callable(getattr(controller, name, None)):
            raise FlatcliError(f"controller: {type(controller).__name__} has no method "
                               f"{name}() (flatcli.core.controllers.python)")
    return Design(int(every), int(errors), int(inputs))


def continuous(controller: Any) -> bool:
    """Whether a controller written in Python gives the law's commands at every evaluation
    (it has a ``command`` method) rather than acting at sample instants."""
    return controller is not None and callable(getattr(controller, "command", None))


def commands(value: Any, joints: int) -> Array:
    """What a controller's ``command`` returned, (u_dot (N - 1,), rate), as the (N,) floats
    u_dot..., rate (inf or nan pass, as the compiled law's do on the singular set);
    FlatcliError if they are not that many numbers."""
    try:
        u_dot, rate = value
        out = np.append(np.asarray(u_dot, dtype=float).reshape(-1), float(rate))
    except (TypeError, ValueError):
        out = np.empty(0)
    if out.shape != (joints,):
        raise FlatcliError(f"controller: command() must return (u_dot, rate): {joints - 1} "
                           f"rates of its integrators and one of joint {joints}, got "
                           f"{value!r}")
    return out


def scratch(d: Design) -> Scratch:
    """Fresh buffers for one trial."""
    return Scratch(np.zeros(d.errors), np.zeros(d.inputs))


@jitable
def reset(s: Scratch) -> None:
    """A trial starts: nothing held (the Python controller's own reset is called by the
    loop)."""
    s.held[:] = 0.0


@jitable
def period(d: Design) -> int:
    return d.every


@jitable
def step(d: Design, s: Scratch, k: int) -> None:
    """Nothing compiled: the reference loop calls the controller here."""


@jitable
def extras(s: Scratch, row: Array) -> None:
    """No columns of its own."""


def held_values(value: Any, inputs: int) -> Array:
    """What a controller's ``step`` returned, as (N,) finite floats; FlatcliError else."""
    held = np.asarray(value, dtype=float).reshape(-1)
    if held.shape != (inputs,) or not np.all(np.isfinite(held)):
        raise FlatcliError(f"controller: step() must return {inputs} finite numbers, got "
                           f"{value!r}")
    return held


def design_for(scenario: Any) -> Design:
    """The design of a ``loop.simulate.Scenario``'s Python controller (``python``): the
    errors are the flat law's (2 N) or the as-built law's (N + 1, 2 N + 1 on the dynamic
    plant), N values held."""
    n = scenario.n_joints
    errors = 2 * n if scenario.law == "flat" else (
        2 * n + 1 if scenario.plant == "dynamic" else n + 1)
    return design(scenario.python, scenario.dt, scenario.plan.duration, errors, n)


#: The Python controller's parts for the loop factory.
PART = SampledPart("python", scratch, reset, period, step, extras, (), (), design_for)
