"""Progress of a running search on stderr: a line when it starts, a bar of candidates on a
terminal, a line per generation (best so far, time), nothing when quiet."""

from __future__ import annotations

import sys
from typing import Any, TextIO

from flatcli.designsearch.evaluate import EVALUATED
from flatcli.designsearch.runner import Row, SearchState


class SearchProgress:
    """The callbacks ``run_search`` reports to (``on_start``, ``on_candidate``,
    ``on_generation``) and ``close``."""

    def __init__(self, name: str, quiet: bool = False, stream: TextIO | None = None) -> None:
        self.name = name
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self._bar: Any = None
        self._budget = 0

    def on_start(self, state: SearchState, population: int, generations: int,
                 description: str) -> None:
        spec = state.spec
        self._budget = population * (generations + 1)
        if self.quiet:
            return
        cells = 1
        for values in spec.sweep.grid.values():
            cells *= len(values)
        known = len(state.journal.evaluations)
        resumed = f"; {known} candidates in the journal (resuming)" if known else ""
        print(f"search {self.name!r}: up to {self._budget} candidates ({population} per "
              f"generation: the first population and {generations} more) x "
              f"{spec.sweep.trials * cells} trials each, on {description}{resumed}",
              file=self.stream, flush=True)
        if self.stream.isatty():
            from tqdm import tqdm

            self._bar = tqdm(total=self._budget, unit="candidate", file=self.stream,
                             dynamic_ncols=True, leave=False)

    def on_candidate(self, state: SearchState, row: Row) -> None:
        if self._bar is not None:
            self._bar.n = min(len(state.rows), self._budget)
            self._bar.refresh()

    def on_generation(self, state: SearchState) -> None:
        if self.quiet:
            return
        from flatcli.designsearch.report import best_row, outcome_text

        best = best_row(state.rows)
        evaluated = sum(1 for r in state.rows if r.evaluation is not None
                        and r.evaluation.status == EVALUATED)
        where = ("none evaluated" if best is None else
                 f"best: candidate {best.index}, {outcome_text(best)}, objective "
                 f"{best.evaluation.objective:.6g}")  # type: ignore[union-attr]
        line = (f"  generation {state.generation}: {len(state.rows)} candidates "
                f"({evaluated} evaluated); {where}; {state.seconds:.1f} s")
        if self._bar is not None:
            self._bar.n = min(len(state.rows), self._budget)
            self._bar.write(line, file=self.stream)
            self._bar.refresh()
        else:
            print(line, file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


__all__ = ["SearchProgress"]
