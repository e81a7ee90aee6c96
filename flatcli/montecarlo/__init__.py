"""Monte Carlo sweeps, the work of ``flatcli.sweep`` and ``flatcli sweep``: grid cells x
random perturbations -> chunks of trials -> results.

* ``layout``: cells, their plans, chunks, from the spec alone;
* ``draws``: each trial's perturbations from its own random stream;
* ``chunks``: one chunk simulated into its rows (a worker's job);
* ``directory``: manifest, chunk files, resume, the final tables;
* ``runner``: ``run_sweep``, chunks through an executor into the directory;
* ``rerun``: one finished trial re-run alone (``flatcli sweep --rerun``).

A trial's result depends on its spec, its cell and its id only: not on the chunk size, the
number of workers, the executor, the order in which chunks finish, or a resume in between.
"""

from flatcli.montecarlo.chunks import ChunkResult, grid_cell_text, run_chunk
from flatcli.montecarlo.directory import MANIFEST, TRIALS_DIR, finish_sweep, recorded_digest
from flatcli.montecarlo.draws import (
    N_VARIATES,
    PERTURB_SLOTS,
    draw_perturbations,
    invalid_plants,
    nominal_values,
    perturbation_columns,
)
from flatcli.montecarlo.layout import Cell, Chunk, Layout, cell_spec, grid_label, layout
from flatcli.montecarlo.rerun import Rerun, rerun_and_compare, rerun_spec, trial_spec
from flatcli.montecarlo.runner import FailFastError, SweepResult, run_sweep

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

