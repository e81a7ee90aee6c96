"""A base law and a plant composed into one closed loop: ``base_ops(law, plant)`` makes the
``kernels.Ops`` of a (law, plant) pair from their parts (``controllers.parts.LawPart``,
``plants.part.PlantPart``), so that each law is written once (``controllers.flat``,
``controllers.asbuilt``) and each plant once (``plants.kinematic``, ``plants.dynamic``); the
paper's robot's closed form is a law and two plants too (``controllers.paper``,
``plants.paper``).

The loop's state is the plant's (the angles first) followed by the law's own states z; its
right-hand side writes the state's derivative, the law's signed margin, then the plant's
aux values:

    x = (plant state, z),   out = (plant's rates, z', margin, plant's aux)

At each evaluation the law computes its commands r (N,) at the measured angles (the plant's
angles plus the sensor's noise, and the joint rates where the plant has them) into the
plant's row, then the plant its rates under them; where the law already evaluated the
trigonometry of the true angles (``LawPart.shares_trig``, no noise) the plant reuses it. A
trace row is the state, then u_1..u_N-1 (the law's states, or the plant's commands of a
law without), then the plant's columns. The metrics observe the angles' error, the law's
outputs' error and margin, and the plant's momentum, rates, clipping and torques.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from flatcli.core._jit import jitable_variant, variant_tag
from flatcli.core.controllers.parts import LawPart
from flatcli.core.loop.kernels import Ops
from flatcli.core.loop.metrics import observe_clipped, observe_errors, observe_torque
from flatcli.core.plants.part import PlantPart


class BaseScratch(NamedTuple):
    """A batch's buffers: the law's and the plant's (their ``scratch(n)``), the measured
    angles (N + 1,)."""

    law: Any
    plant: Any
    measured: Any


class BaseLoop(NamedTuple):
    """One trial: the law's record and the plant's, the measured angles' row."""

    law: Any
    plant: Any
    measured: Any


def base_ops(law: LawPart, plant: PlantPart) -> Ops:
    """The ``Ops`` of ``law`` driving ``plant`` (module docstring)."""
    variant = jitable_variant(variant_tag(law.command, plant.rates))
    make_law, make_plant, servo = law.make, plant.make, law.servo
    joints, law_states, plant_state = law.joints, law.states, plant.state
    command, law_trig, shares = law.command, law.trig, law.shares_trig
    start_law, start_rates, rate_states = law.start, law.start_rates, plant.rate_states
    law_observed, plant_observed, torques = law.observed, plant.observed, plant.torques
    law_additive, law_measure = law.additive, law.measure
    io, plant_rates = plant.io, plant.rates
    start_plant, plant_record, plant_residual = plant.start, plant.record, plant.residual
    plant_bounded, always_bounded = plant.bounded, law.bounded

    @variant
    def make_loop(shared: Any, trials: Any, i: int, scratch: BaseScratch) -> BaseLoop:
        return BaseLoop(make_law(shared, scratch.law),
                        make_plant(trials, i, shared.rate_limit,
                                   servo(shared, trials.offset[i]), scratch.plant),
                        scratch.measured)

    @variant
    def bounded(loop: BaseLoop) -> bool:
        if always_bounded:
            return True
        return plant_bounded(loop.plant)

    @variant
    def initial_state(loop: BaseLoop, initial: Any, ref0: Any, x0: Any) -> None:
        n = joints(loop.law)
        ps = plant_state(n)
        start_law(loop.law, initial, x0[ps: ps + law_states(n)])
        r = io(loop.plant, x0)[0]
        if rate_states:
            start_rates(loop.law, initial, ref0, r)
        start_plant(loop.plant, initial, r, x0)

    def evaluator(full: bool) -> Any:
        """The right-hand side (``full``) or an integrator's stage, whose aux values nobody
        observes (the same derivative and margin, bit for bit: ``plants.dynamic``)."""

        @jitable_variant(variant_tag(law.command, plant.rates) + ("" if full else "_stage"))
        def rhs(loop: BaseLoop, x: Any, ref: Any, noise: Any, out: Any) -> None:
            n = joints(loop.law)
            nb = n + 1
            ps = plant_state(n)
            nx = ps + law_states(n)
            measured = loop.measured
            given = shares
            for i in range(nb):
                measured[i] = x[i] + noise[i]
                if noise[i] != 0.0:
                    given = False
            r, rates = io(loop.plant, x)
            margin = command(loop.law, measured, rates, x[ps:nx], ref, r, out[ps:nx])
            cs, sn = law_trig(loop.law)
            plant_rates(loop.plant, x, cs, sn, given, out, nx + 1, full)
            out[nx] = margin

        return rhs

    @variant
    def observe(loop: BaseLoop, obs: Any, acc: Any, j: int, x: Any, f: Any) -> None:
        theta_ref = obs[0]
        n = joints(loop.law)
        nb = n + 1
        ps = plant_state(n)
        nx = ps + law_states(n)
        et2 = 0.0
        for i in range(nb):
            d = x[i] - theta_ref[j, i]
            et2 += d * d
        ey2, margin, threshold = law_observed(loop.law, obs, j, x[:nb], x[ps:nx], f, nx + 1)
        cs, sn = law_trig(loop.law)
        h, h0, peak, clipped, torque, saturated = plant_observed(loop.plant, x, f, nx + 1, cs,
                                                                 sn, shares)
        observe_errors(acc, j, et2, ey2, margin, h, h0, peak, threshold)
        if torques:
            observe_torque(acc, torque, 0.0, saturated)
        observe_clipped(acc, j, clipped)

    @variant
    def record(loop: BaseLoop, trace: Any, j: int, nx: int, x: Any, f: Any) -> None:
        for i in range(nx):
            trace[j, i] = x[i]
        plant_record(loop.plant, trace, j, nx, x, f, nx + 1, law_states(joints(loop.law)) == 0)

    @variant
    def residual(loop: BaseLoop, trials: Any, i: int, plan_theta: Any, plan_theta_dot: Any
                 ) -> float:
        return plant_residual(loop.plant, trials, i, plan_theta,
                              plan_theta_dot)

    @variant
    def additive(loop: BaseLoop, ref: Any, dv: Any, out: Any) -> None:
        law_additive(loop.law, ref, dv, out)

    @variant
    def measure(loop: BaseLoop, x: Any, noise: Any, ref: Any, s0: Any) -> None:
        n = joints(loop.law)
        ps = plant_state(n)
        measured = loop.measured
        for i in range(n + 1):
            measured[i] = x[i] + noise[i]
        law_measure(loop.law, measured, io(loop.plant, x)[1], x[ps: ps + law_states(n)], ref,
                    s0)

    law_scratch, plant_scratch = law.scratch, plant.scratch

    def scratch(n: int) -> BaseScratch:
        return BaseScratch(law_scratch(n), plant_scratch(n), np.zeros(n + 1))

    def state(n: int) -> int:
        return plant.state(n) + law.states(n)

    def aux(n: int) -> int:
        return 1 + plant.aux(n)  # the margin first

    def width(n: int) -> int:
        return plant.state(n) + n - 1 + plant.columns(n)

    return Ops(make_loop, bounded, initial_state, evaluator(True), observe, record, residual,
               state, aux, width, scratch, evaluator(False) if torques else None,
               additive=additive, measure=measure)
