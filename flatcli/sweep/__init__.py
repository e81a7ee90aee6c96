"""Monte Carlo sweeps: grid cells x random perturbations -> chunks of trials -> results.

* ``layout``: cells, their plans, chunks, from the spec alone;
* ``draws``: each trial's perturbations from its own random stream;
* ``chunks``: one chunk simulated into its rows (a worker's job);
* ``directory``: manifest, chunk files, resume, the final tables;
* ``runner``: ``run_sweep``, chunks through an executor into the directory;
* ``rerun``: one finished trial re-run alone (``flatcli sweep --rerun``).

A trial's result depends on its spec, its cell and its id only: not on the chunk size, the
number of workers, the executor, the order in which chunks finish, or a resume in between.
"""

import sys
import types
from typing import Any

from flatcli.sweep.chunks import ChunkResult, grid_cell_text, run_chunk
from flatcli.sweep.directory import MANIFEST, TRIALS_DIR, finish_sweep, recorded_digest
from flatcli.sweep.draws import (
    N_VARIATES,
    PERTURB_SLOTS,
    draw_perturbations,
    invalid_plants,
    nominal_values,
    perturbation_columns,
)
from flatcli.sweep.layout import Cell, Chunk, Layout, cell_spec, grid_label, layout
from flatcli.sweep.rerun import Rerun, rerun_and_compare, rerun_spec, trial_spec
from flatcli.sweep.runner import FailFastError, SweepResult, run_sweep

__all__ = [
    "MANIFEST",
    "N_VARIATES",
    "PERTURB_SLOTS",
    "TRIALS_DIR",
    "Cell",
    "Chunk",
    "ChunkResult",
    "FailFastError",
    "Layout",
    "Rerun",
    "SweepResult",
    "cell_spec",
    "draw_perturbations",
    "finish_sweep",
    "grid_cell_text",
    "grid_label",
    "invalid_plants",
    "layout",
    "nominal_values",
    "perturbation_columns",
    "recorded_digest",
    "rerun_and_compare",
    "rerun_spec",
    "run_chunk",
    "run_sweep",
    "trial_spec",
]


class _CallablePackage(types.ModuleType):
    """``flatcli.sweep`` names both this package and the API function ``flatcli.api.sweep``
    (``flatcli.sweep(spec, out, workers=...)``); once the package is imported its name is
    bound to it, so calling the package runs a sweep."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        from flatcli.api import sweep

        return sweep(*args, **kwargs)


sys.modules[__name__].__class__ = _CallablePackage
