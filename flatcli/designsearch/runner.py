"""Running (or resuming) a design search: scipy's differential evolution, each generation's
candidates studied together on every core (or Dask), every candidate in the journal.

**The optimiser.** ``scipy.optimize.differential_evolution`` (Storn and Price 1997; scipy's
implementation, with Lampinen's feasibility rules for constraints): derivative-free and
population-based, which suits an objective that is a count of trials (piecewise constant in the
design) and a handful of bounded variables; scipy is already flatcli's dependency and its
solver is seeded. It runs with ``vectorized=True`` and ``updating="deferred"``, so it hands a
whole generation to one call: the constraints of every trial vector first (``register``), then
the objective of the feasible ones (``objective``), which this module evaluates as one batch of
chunks through an executor. ``polish`` is off (a gradient method on a count is no use). The
first population is a Latin hypercube drawn from ``search.seed``, whose first member is the
spec's own design when it lies within the bounds; mutation (0.5, 1) with dithering,
recombination 0.7, strategy best1bin (scipy's defaults).

**Reproducible.** A candidate's evaluation depends on its design and the spec only (its trials'
rows are those of a sweep, which depend on their ids only: ``flatcli.montecarlo``), the solver
on the evaluations and its seed: so the sequence of candidates, and search.parquet, are the same
whatever the number of workers or the executor. They do not depend on the budget either: a
budget only says where the sequence stops.

**Resumable.** A run replays the search from its start; every candidate already in the
journal is answered from it (``flatcli.designsearch.directory``), the others are computed. So
a search killed at any moment and run again writes the same search.parquet as one never
interrupted, and a finished search run again with a larger ``search.candidates`` continues it.

**Budgets.** ``search.candidates``: whole generations, as many as fit (the first population
counts). ``search.seconds``: the search stops at the first generation boundary (after the first
generation at the earliest) where its computing time so far reaches it. That time is recorded in
the journal at every boundary, so a resumed search stops where the first run did; the rows are
then the first rows of the unbounded search, and the result says so (``stop``: the number of
candidates that reproduces them on any machine).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from numpy.typing import NDArray

from flatcli.core.errors import FlatcliError
from flatcli.designsearch.design import CONSTRAINTS, Candidate, Design
from flatcli.designsearch.directory import (
    Journal,
    design_key,
    identity,
    open_directory,
    write_record,
)
from flatcli.designsearch.evaluate import (
    ERROR,
    INFEASIBLE,
    Evaluation,
    failed,
    judge,
    plan_energy,
    slim_chunk,
)
from flatcli.executors import Executor, default_workers, make_executor
from flatcli.interrupts import check, deferred, interruptible
from flatcli.montecarlo.layout import Chunk, Layout, layout, work_pieces
from flatcli.spec import Spec, SpecError
from flatcli.spec.limits import check_workers
from flatcli.spec.sweeps import identical_trials
from flatcli.storage import directory_lock, run_record

Array = NDArray[np.float64]

#: Designs per generation when ``search.population`` is not set: this many per variable, and
#: at least ``MIN_POPULATION``.
PER_VARIABLE = 5
MIN_POPULATION = 10
#: scipy's defaults, written out: they are part of what the search is.
STRATEGY = "best1bin"
MUTATION = (0.5, 1.0)
RECOMBINATION = 0.7


def population_size(spec: Spec, variables: int) -> int:
    """Designs per generation."""
    return spec.search.population or max(MIN_POPULATION, PER_VARIABLE * variables)


def generations(spec: Spec, population: int) -> int:
    """Generations after the first population that fit ``search.candidates`` (SpecError if
    not even the first does)."""
    budget = spec.search.candidates
    if budget < population:
        raise SpecError(f"search.candidates: {budget} is fewer than one generation of "
                        f"{population} designs (search.population); give at least "
                        f"{population}")
    return budget // population - 1


def first_population(design: Design, size: int, seed: int) -> Array:
    """(size, n) a Latin hypercube over the bounds drawn from ``seed``; its first member the
    spec's own design when that lies within the bounds."""
    from scipy.stats import qmc

    n = len(design.variables)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
    unit = qmc.LatinHypercube(d=n, rng=rng).random(size)
    low, high = (np.array(b) for b in zip(*design.bounds, strict=True))
    points: Array = low + unit * (high - low)
    if design.baseline_inside:
        points[0] = design.baseline
    return points


@dataclass
class Row:
    """One candidate of the search, in the order the optimiser first asked for it."""

    index: int
    generation: int
    candidate: Candidate
    evaluation: Evaluation | None = None
    resumed: bool = False


@dataclass
class SearchState:
    """Everything one run of a search knows and does (module docstring)."""

    spec: Spec
    design: Design
    journal: Journal
    executor: Executor | None
    own_energy: float
    on_generation: Callable[[SearchState], None] = lambda state: None
    on_candidate: Callable[[SearchState, Row], None] = lambda state, row: None
    rows: list[Row] = field(default_factory=list)
    by_key: dict[str, Row] = field(default_factory=dict)
    generation: int = 0  # generations finished after the first population
    first_done: bool = False  # the first population has been evaluated
    seconds: float = 0.0  # the search's computing time at the last generation boundary
    stop: str = ""
    simulated_trials: int = 0
    _base: float = 0.0
    _origin: float = field(default_factory=time.perf_counter)

    # -- the optimiser's two calls -------------------------------------------------------

    def register(self, x: Any) -> Array:
        """The constraint function: (M, S) violations of the designs ``x`` (n, S) (or (M,) of
        one design (n,)); a design met for the first time becomes a row."""
        points = np.asarray(x, dtype=float)
        single = points.ndim == 1
        columns = points[:, None] if single else points
        out = np.empty((len(CONSTRAINTS), columns.shape[1]))
        for j in range(columns.shape[1]):
            out[:, j] = self._row(columns[:, j]).candidate.violations
        return out[:, 0] if single else out

    def objective(self, x: Any) -> Array:
        """The objective of the designs ``x`` (n, S), computed together (cached ones from the
        journal)."""
        points = np.asarray(x, dtype=float)
        rows = [self._row(points[:, j]) for j in range(points.shape[1])]
        self._evaluate([r for r in rows if r.evaluation is None])
        self.first_done = True
        return np.array([r.evaluation.objective for r in rows if r.evaluation is not None])

    def generation_done(self, intermediate_result: Any = None) -> bool:
        """The optimiser's callback after each generation: record it, tell, and say whether
        the time budget stops the search here."""
        self.generation += 1
        g = self.generation
        recorded = self.journal.generations.get(g)
        if recorded is not None:  # replayed: its time as the first run measured it
            self.seconds = recorded
            self._base, self._origin = recorded, time.perf_counter()
        else:
            self.seconds = self._base + (time.perf_counter() - self._origin)
            self.journal.add_generation(g, self.seconds)
        self.on_generation(self)
        check()
        if self.seconds >= self.spec.search.seconds:
            self.stop = "seconds"
            return True
        return False

    # -- rows and evaluations --------------------------------------------------------------

    def _row(self, x: Array) -> Row:
        key = design_key(x)
        row = self.by_key.get(key)
        if row is not None:
            return row
        candidate = self.design.candidate(x)
        # the generation it is a trial vector of (0: the first population)
        row = Row(len(self.rows), self.generation + (1 if self.first_done else 0), candidate)
        if not candidate.feasible:
            status = INFEASIBLE if candidate.robot is not None else ERROR
            row.evaluation = failed(self.spec, status, candidate.reason)
        self.rows.append(row)
        self.by_key[key] = row
        return row

    def _evaluate(self, rows: Sequence[Row]) -> None:
        """Evaluate ``rows`` (feasible candidates): from the journal, or their studies'
        chunks through the executor as one batch."""
        fresh: list[tuple[Row, Layout, float]] = []
        for row in rows:
            key = design_key(row.candidate.x)
            known = self.journal.evaluations.get(key)
            if known is not None:
                row.evaluation, row.resumed = known, True
                row.candidate = replace(row.candidate, spec=None)  # done with it: memory
                self.on_candidate(self, row)
                continue
            spec = row.candidate.spec
            assert spec is not None
            try:
                lay = layout(spec, self.executor.workers if self.executor else None)
                energy = plan_energy(lay)
            except FlatcliError as exc:
                self._finish(row, failed(self.spec, ERROR, str(exc)))
                continue
            fresh.append((row, lay, energy))
        if not fresh:
            return
        assert self.executor is not None
        metric = self.spec.search.metric
        tagged = [(i, chunk) for i, (_, lay, _) in enumerate(fresh) for chunk in lay.chunks()]
        need = {i: lay.total for i, (_, lay, _) in enumerate(fresh)}
        parts: dict[int, list[tuple[int, pa.Table]]] = {i: [] for i in need}
        for (i, piece), table in self.executor.run(
                slim_chunk, _tasks(tagged, self.executor.workers, fresh, metric)):
            parts[i].append((piece.start, table))
            self.simulated_trials += table.num_rows
            need[i] -= table.num_rows
            if need[i] == 0:
                row, _, energy = fresh[i]
                tables = [t for _, t in sorted(parts.pop(i), key=lambda p: p[0])]
                self._finish(row, judge(self.spec, tables, energy, self.own_energy))

    def _finish(self, row: Row, evaluation: Evaluation) -> None:
        row.evaluation = evaluation
        row.candidate = replace(row.candidate, spec=None)  # a long search keeps no specs
        self.journal.add_candidate(design_key(row.candidate.x), evaluation)
        self.on_candidate(self, row)


def _tasks(tagged: Sequence[tuple[int, Chunk]], workers: int,
           fresh: Sequence[tuple[Row, Layout, float]], metric: str
           ) -> Iterator[tuple[tuple[int, Chunk], tuple[Any, ...]]]:
    """The generation's chunks in order, each of the last ``workers`` in pieces
    (``layout.work_pieces``: the idle workers take pieces of them)."""
    tail = max(len(tagged) - workers, 0) if workers > 1 else len(tagged)
    for k, (i, chunk) in enumerate(tagged):
        lay = fresh[i][1]
        pieces = [(chunk, chunk)] if k < tail else work_pieces([chunk], 2)
        for _, piece in pieces:
            yield (i, piece), (lay.cells[piece.cell], piece, metric)


@dataclass(frozen=True)
class SearchOutcome:
    """What a finished run of a search did: its state (rows, stop), the optimiser's result,
    where it was written, and its times [s]."""

    directory: Path
    state: SearchState
    message: str
    resumed: int  # candidates answered from the journal
    wall_seconds: float
    setup_seconds: float


def warm_up(lay: Layout, quiet: bool = True) -> None:
    """Simulate one trial, so the compiled kernel is loaded before the workers fork; a kernel
    numba compiles is announced unless quiet (``progress.compile_notices``)."""
    from flatcli.progress import compile_notices, kernel_text

    cell = lay.cells[0]
    with compile_notices(kernel_text(cell.scenario), quiet):
        slim_chunk(cell, Chunk(cell.index, cell.first_trial, cell.first_trial + 1),
                   "err_theta_final")


def check_search(spec: Spec) -> tuple[Design, int, int]:
    """The design space, population and generations of a search spec (SpecError, nothing
    run, if it cannot search)."""
    if not spec.search.vary:
        raise SpecError("search.vary: a search needs [search.vary] with at least one design "
                        "variable, e.g. \"robot.mass[1]\" = { relative = 0.3 } "
                        "(docs/search.md)")
    design = Design.of(spec)
    same = identical_trials(spec)
    if same is not None and spec.sweep.trials > 1:
        raise SpecError(f"search: every candidate would run {spec.sweep.trials} identical "
                        f"trials ({same}); add [sweep.perturb] (or track.sensor_noise), or set "
                        "sweep.trials = 1")
    size = population_size(spec, len(design.variables))
    return design, size, generations(spec, size)


def own_study(spec: Spec, design: Design) -> tuple[Candidate, Layout | None, float, str]:
    """The spec's own design as a candidate, its layout (None if it cannot be studied:
    ``reason``) and its plan's energy (nan then)."""
    own = design.candidate(design.baseline)
    if own.spec is None:
        return own, None, math.nan, own.reason
    try:
        lay = layout(own.spec)
        return own, lay, plan_energy(lay), ""
    except FlatcliError as exc:
        return own, None, math.nan, str(exc)


def run_search(spec: Spec, directory: Path, executor_kind: str = "local",
               workers: int | None = None, scheduler: str | None = None, force: bool = False,
               oversubscribe: bool = False, command: str = "",
               on_generation: Callable[[SearchState], None] | None = None,
               on_candidate: Callable[[SearchState, Row], None] | None = None,
               on_start: Callable[[SearchState, int, int, str], None] | None = None,
               finish: Callable[[SearchState, Path, dict[str, Any]], None] | None = None,
               quiet: bool = True) -> SearchOutcome:
    """Run (or resume) the search of ``spec`` into ``directory`` (module docstring).

    Everything that can be refused is refused before a byte is written. ``on_start`` (state,
    population, generations, executor description), ``on_generation`` and ``on_candidate``
    report progress; ``finish`` writes the results (``flatcli.designsearch.report``) with the run's
    record items.
    """
    from scipy.optimize import NonlinearConstraint, differential_evolution

    started = time.perf_counter()
    design, size, gens = check_search(spec)
    if executor_kind == "local" or scheduler == "local":
        check_workers(workers if workers is not None else default_workers(), oversubscribe)
    _, own_layout, own_energy, own_reason = own_study(spec, design)
    if spec.search.energy_weight > 0 and not (own_energy > 0):
        why = own_reason or "zero"
        raise SpecError(f"search.energy_weight: the secondary term is relative to the spec's "
                        f"own design's plan energy, which is not available ({why}); set "
                        "search.energy_weight = 0")
    population = first_population(design, size, spec.search.seed)
    digest = identity(spec)
    with directory_lock(directory):
        opened = open_directory(directory, spec, force)
        directory.mkdir(parents=True, exist_ok=True)
        record = run_record("search", spec.tree, identity=digest, status="running",
                            command_line=command)
        write_record(directory, record)
        if own_layout is not None and executor_kind == "local" and (
                len(opened.journal.evaluations) < spec.search.candidates):
            with interruptible():
                warm_up(own_layout, quiet)  # forked workers inherit the loaded kernel
        executor = make_executor(executor_kind, workers, scheduler)
        state = SearchState(spec, design, opened.journal, executor, own_energy,
                            on_generation or (lambda s: None),
                            on_candidate or (lambda s, r: None))
        setup = time.perf_counter() - started
        if on_start is not None:
            on_start(state, size, gens, executor.description)
        rng = np.random.default_rng(np.random.SeedSequence(spec.search.seed, spawn_key=(0,)))
        constraint = NonlinearConstraint(state.register, -np.inf, 0.0)
        with deferred():
            try:
                result = differential_evolution(
                    state.objective, design.bounds, strategy=STRATEGY, maxiter=gens,
                    tol=spec.search.tol, atol=0.0, mutation=MUTATION,
                    recombination=RECOMBINATION, rng=rng, callback=state.generation_done,
                    polish=False, init=population, updating="deferred", vectorized=True,
                    constraints=constraint,
                    x0=design.baseline if design.baseline_inside else None)
            except BaseException:
                executor.close(abort=True)
                raise
            executor.close()
        if not state.stop:
            converged = result.message == "Optimization terminated successfully."
            state.stop = "converged" if converged else "candidates"
        resumed = sum(r.resumed for r in state.rows)
        wall = time.perf_counter() - started
        timings = {"setup_seconds": setup, "wall_seconds": wall,
                   "search_seconds": state.seconds, "simulated_trials": state.simulated_trials,
                   "resumed_candidates": resumed, "workers": executor.workers,
                   "executor": executor.description, "stop": state.stop,
                   "generations": state.generation, "message": str(result.message)}
        if finish is not None:
            finish(state, directory, {**record, "status": "finished", **timings})
    return SearchOutcome(directory, state, str(result.message), resumed, wall, setup)


__all__ = ["MUTATION", "RECOMBINATION", "STRATEGY", "Row", "SearchOutcome", "SearchState",
           "check_search", "first_population", "generations", "own_study", "population_size",
           "run_search"]
