"""A controller that acts at sample instants, composed with an inner law and a plant.

``sampled_ops(inner, part)`` makes the ``kernels.Ops`` of a loop in which a sampled
controller (``controllers.parts.SampledPart``: the MPC of ``controllers.mpc``) wraps the
inner law of an existing (model, plant) combination ``inner`` (the flat law on the paper's
robot or a chain, the as-built law; kinematic or dynamic plant):

* between samples the inner combination's right-hand side runs unchanged, given its
  reference with the controller's held values added where the inner law's input enters
  (``inner.additive``: the flat law's y'', the as-built law's joint-rate commands), so the
  inner law's command becomes its own plus those values (no copy of the law here);
* at each sample instant (every ``part.period(design)`` output steps; the integrators stop
  there, ``integrate.make_trial_integrators``) the inner combination measures the errors its
  law's design is about at the measured state (``inner.measure``) and the controller updates
  what it holds (``part.step``);
* each trial (and its twin) starts from a fresh controller (``part.reset``); after the trial
  the controller's per-trial columns are written (``part.extras``, ``Results.extra``);
* the right-hand side writes what the controller holds (N values: the held dv) after the
  inner combination's aux values, and a trace row gains them after the inner row's columns
  (``simulate.trace_columns``: dv1..dvN), so a test can replay the controller's decisions.

The plant, its observer, trace and momentum residual are the inner combination's: the
metrics are about the plan, not the shifted reference.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable_variant, variant_tag
from flatcli.core.controllers.parts import SampledPart
from flatcli.core.loop.kernels import Ops

Array = NDArray[np.float64]


class SampledShared(NamedTuple):
    """What every trial shares: the inner combination's shared record and the controller's
    design (once per plan)."""

    inner: Any
    design: Any


class SampledScratch(NamedTuple):
    """A batch's buffers: the inner loop's, the controller's trial scratch, and the shifted
    reference (the plan's flag with the held values added)."""

    inner: Any
    part: Any
    shifted: Array


class SampledLoop(NamedTuple):
    """One trial: the inner loop record, the design, the controller's scratch, the shifted
    reference's buffer."""

    inner: Any
    design: Any
    part: Any
    shifted: Array


def sampled_ops(inner: Ops, part: SampledPart) -> Ops:
    """The ``Ops`` of ``part`` wrapping ``inner`` (module docstring); ``inner`` must declare
    ``additive`` and ``measure``."""
    if inner.additive is None or inner.measure is None:
        raise ValueError(f"{part.name}: the inner loop declares no additive input or "
                         "measurement to wrap")
    variant = jitable_variant(variant_tag(*_functions(inner), part.step, part.reset))
    make_inner, bounded_inner, initial_inner = inner.make_loop, inner.bounded, inner.initial_state
    rhs_inner, stage_inner = inner.rhs, inner.stage or inner.rhs
    observe_inner, residual_inner, record_inner = inner.observe, inner.residual, inner.record
    state, aux_inner, width_inner = inner.state, inner.aux, inner.width
    additive, measure = inner.additive, inner.measure
    reset_part, period_part = part.reset, part.period
    step_part, extras_part = part.step, part.extras

    @variant
    def make_loop(shared: SampledShared, trials: Any, i: int,
                  scratch: SampledScratch) -> SampledLoop:
        return SampledLoop(make_inner(shared.inner, trials, i, scratch.inner), shared.design,
                           scratch.part, scratch.shifted)

    @variant
    def bounded(loop: SampledLoop) -> bool:
        return bounded_inner(loop.inner)

    @variant
    def initial_state(loop: SampledLoop, initial: Array, ref0: Array, x0: Array) -> None:
        initial_inner(loop.inner, initial, ref0, x0)

    @variant
    def rhs(loop: SampledLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
        held = loop.part.held
        additive(loop.inner, ref, held, loop.shifted)
        rhs_inner(loop.inner, x, loop.shifted, noise, out)
        end = out.shape[0] - held.shape[0]
        for v in range(held.shape[0]):  # after the inner loop's aux values: what it holds
            out[end + v] = held[v]

    @variant
    def stage(loop: SampledLoop, x: Array, ref: Array, noise: Array, out: Array) -> None:
        additive(loop.inner, ref, loop.part.held, loop.shifted)
        stage_inner(loop.inner, x, loop.shifted, noise, out)

    @variant
    def observe(loop: SampledLoop, obs: Any, acc: Array, j: int, x: Array, f: Array) -> None:
        observe_inner(loop.inner, obs, acc, j, x, f)

    @variant
    def record(loop: SampledLoop, trace: Array, j: int, nx: int, x: Array, f: Array) -> None:
        record_inner(loop.inner, trace, j, nx, x, f)
        held = loop.part.held.shape[0]
        end, written = trace.shape[1] - held, f.shape[0] - held
        for v in range(held):  # the held values the right-hand side wrote last in f
            trace[j, end + v] = f[written + v]

    @variant
    def residual(loop: SampledLoop, trials: Any, i: int, plan_theta: Array,
                 plan_theta_dot: Array) -> float:
        return residual_inner(loop.inner, trials, i, plan_theta,
                              plan_theta_dot)

    @variant
    def reset(loop: SampledLoop) -> None:
        reset_part(loop.part)

    @variant
    def period(loop: SampledLoop) -> int:
        return period_part(loop.design)

    @variant
    def sample(loop: SampledLoop, x: Array, noise: Array, ref: Array, j: int) -> None:
        measure(loop.inner, x, noise, ref, loop.part.s0)
        step_part(loop.design, loop.part, j // period_part(loop.design))

    @variant
    def extras(loop: SampledLoop, row: Array) -> None:
        extras_part(loop.part, row)

    scratch_inner, make_part = inner.scratch, part.scratch

    def scratch(n: int, shared: SampledShared | None = None, flag_size: int = 0
                ) -> SampledScratch:
        if shared is None:
            raise ValueError(f"{part.name}: a trial's scratch needs the plan's design")
        return SampledScratch(scratch_inner(n), make_part(shared.design), np.zeros(flag_size))

    def aux(n: int) -> int:
        return aux_inner(n) + n  # and what the controller holds, one per joint

    def width(n: int) -> int:
        return width_inner(n) + n

    return Ops(make_loop, bounded, initial_state, rhs, observe, record, residual,
               state, aux, width, scratch, stage, reset=reset, period=period,
               sample=sample, extras=extras, extra_columns=part.columns,
               extra_counts=part.counts,
               needs_shared_scratch=True)


def _functions(ops: Ops) -> tuple[Any, ...]:
    """The compiled functions of a combination that name its wrapped variant."""
    return (ops.make_loop, ops.rhs, ops.observe, ops.record, ops.residual,
            ops.stage or ops.rhs, ops.measure, ops.additive)


__all__ = ["SampledLoop", "SampledScratch", "SampledShared", "sampled_ops"]
