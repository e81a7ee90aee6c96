"""The table of compiled kernels, generated: one entry per (controller, model kind, plant).

The base laws' combinations are written once each (``kernels``: the flat law on the paper's
closed form and on chains; ``asbuiltkernels``: the as-built law); every controller that acts
at sample instants (``SAMPLED``: a ``controllers.parts.SampledPart``) is composed with each
of them by ``compose.sampled_ops`` and compiled here, so a new sampled controller is its
module plus one line in ``SAMPLED``. The kernels are made when this module is imported
(numba compiles each on its first call, or loads it from the cache; a compile child imports
this module to find one by name).
"""

from __future__ import annotations

from flatcli.core.controllers import mpc, python
from flatcli.core.controllers.parts import SampledPart
from flatcli.core.errors import FlatcliError
from flatcli.core.loop.asbuiltkernels import KERNELS as ASBUILT_KERNELS
from flatcli.core.loop.compose import sampled_ops
from flatcli.core.loop.kernels import KERNELS as FLAT_KERNELS
from flatcli.core.loop.kernels import Kernels, compile_kernels

#: The controllers that act at sample instants, by ``track.controller``.
SAMPLED: dict[str, SampledPart] = {"mpc": mpc.PART, "python": python.PART}


#: Every sampled controller's per-trial columns (a sweep's trials.parquet holds them all, null
#: where a trial's controller has not that one), and those that are counts.
CONTROLLER_COLUMNS: tuple[str, ...] = tuple(dict.fromkeys(
    column for part in SAMPLED.values() for column in part.columns))
CONTROLLER_COUNTS: tuple[str, ...] = tuple(dict.fromkeys(
    column for part in SAMPLED.values() for column in part.counts))


def _base() -> dict[tuple[str, str, str], Kernels]:
    table = {("flat", model, plant): k for (model, plant), k in FLAT_KERNELS.items()}
    table.update({("asbuilt", model, plant): k for (model, plant), k in ASBUILT_KERNELS.items()})
    return table


def _generate() -> dict[tuple[str, str, str], Kernels]:
    table = _base()
    for name, part in SAMPLED.items():
        for (law, model, plant), base in list(table.items()):
            if law not in ("flat", "asbuilt"):
                continue
            ops = sampled_ops(base.ops, part)
            table[(name, model, plant)] = compile_kernels(ops, f"{name}_{model}_{plant}",
                                                          base.shared, base.plant, __name__)
    return table


#: Every kernel, by (controller, model kind, plant): model kind "paper" (the paper's closed
#: form, N = 2), "chain" (N links) or "asbuilt" (the exact model of a robot as built).
KERNELS: dict[tuple[str, str, str], Kernels] = _generate()


def kernels_for(controller: str, model: str, plant: str) -> Kernels:
    """The kernels of a combination; FlatcliError naming track.controller if there are none."""
    found = KERNELS.get((controller, model, plant))
    if found is None:
        raise FlatcliError(f"track.controller: {controller!r} has no kernel for the {model} "
                           f"model on the {plant} plant")
    return found
