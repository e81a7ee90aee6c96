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
