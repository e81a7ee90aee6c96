"""The table of compiled kernels, generated: one entry per (controller, model kind, plant).

The base laws' combinations (``BASE``: the flat law on the paper's closed form, on chains
and the as-built law, ``controllers.paper``, ``controllers.flat`` and ``controllers.asbuilt``,
each composed with the kinematic and the dynamic plant, ``plants``, by ``base.base_ops``) are
compiled here; every controller that acts at sample instants (``SAMPLED``:
a ``controllers.parts.SampledPart``) is composed with each of them by ``compose.sampled_ops``
and compiled here too, so a new sampled controller is its module plus one line in
``SAMPLED``. The kernels are made when this module is imported
(numba compiles each on its first call, or loads it from the cache; a compile child imports
this module to find one by name).
"""

from __future__ import annotations

from flatcli.core.controllers import asbuilt, flat, mpc, paper, python
from flatcli.core.controllers.parts import SampledPart
from flatcli.core.errors import FlatcliError
from flatcli.core.loop.base import base_ops
from flatcli.core.loop.compose import sampled_ops
from flatcli.core.loop.kernels import Kernels, chain_plant, compile_kernels
from flatcli.core.plants import dynamic, kinematic
from flatcli.core.plants import paper as paper_plants

#: The base laws' combinations, by (law, model kind, plant): their ``kernels.Ops``, how their
#: shared record and per-trial plant arrays are made ("command": the commands of a controller
#: written in Python, ``controllers.python``, given to the plant).
#: Each combination is a law's part and a plant's (``base.base_ops``): a new plant is its
#: module (a ``plants.part.PlantPart``) and a line per law here.
BASE = {
    ("flat", "paper", "kinematic"): (base_ops(paper.LAW, paper_plants.KINEMATIC),
                                     paper.paper_shared, paper_plants.plant_arrays),
    ("command", "paper", "kinematic"): (base_ops(paper.COMMAND, paper_plants.KINEMATIC),
                                        paper.paper_shared, paper_plants.plant_arrays),
    ("flat", "paper", "dynamic"): (base_ops(paper.LAW, paper_plants.DYNAMIC),
                                   paper.paper_shared, paper_plants.plant_arrays),
    ("flat", "chain", "kinematic"): (base_ops(flat.LAW, kinematic.PLANT), flat.LAW.shared,
                                     chain_plant),
    ("flat", "chain", "dynamic"): (base_ops(flat.LAW, dynamic.PLANT), flat.LAW.shared,
                                   chain_plant),
    ("asbuilt", "asbuilt", "kinematic"): (base_ops(asbuilt.LAW, kinematic.PLANT),
                                          asbuilt.LAW.shared, chain_plant),
    ("asbuilt", "asbuilt", "dynamic"): (base_ops(asbuilt.LAW, dynamic.PLANT),
                                        asbuilt.LAW.shared, chain_plant),
}

#: The controllers that act at sample instants, by ``track.controller``.
SAMPLED: dict[str, SampledPart] = {"mpc": mpc.PART, "python": python.PART}


#: Every sampled controller's per-trial columns (a sweep's trials.parquet holds them all, null
#: where a trial's controller has not that one), and those that are counts.
CONTROLLER_COLUMNS: tuple[str, ...] = tuple(dict.fromkeys(
    column for part in SAMPLED.values() for column in part.columns))
CONTROLLER_COUNTS: tuple[str, ...] = tuple(dict.fromkeys(
    column for part in SAMPLED.values() for column in part.counts))


def _generate() -> dict[tuple[str, str, str], Kernels]:
    # each kernel its own name: numba caches, and a compile child finds, a kernel by its name
    table = {(law, model, plant): compile_kernels(
        ops, f"{model}_{plant}" if law in ("flat", "asbuilt") else f"{law}_{model}_{plant}",
        shared, arrays, __name__) for (law, model, plant), (ops, shared, arrays) in BASE.items()}
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
