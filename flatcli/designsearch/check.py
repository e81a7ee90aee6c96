"""``flatcli check SPEC`` (and ``flatcli search --dry-run``) for a search spec: what the search
would do and cost, nothing written.

The design variables with their bounds and the spec's own values, the constraints, the
objective, the optimiser's population and generations, the spec's own design judged against
the constraints, and a cost: the study of one candidate is the spec's own ``[sweep]``, so
``flatcli.preflight``'s calibration of the spec's own design (its first trials, in a worker
process) prices a trial, and the search costs its candidates' trials spread over the workers,
plus the planning of each candidate measured here.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from flatcli.designsearch.design import Design, violation_text
from flatcli.designsearch.runner import check_search, own_study
from flatcli.preflight import CheckReport, check_spec, closing_lines, duration_estimate
from flatcli.report import table
from flatcli.spec import Spec, spec_toml


@dataclass(frozen=True)
class SearchCheckReport:
    """What ``flatcli check`` prints for a search spec."""

    spec: Spec
    design: Design
    population: int
    generations: int
    own_reason: str
    sweep: CheckReport | None  # the spec's own design's study (None: it cannot be studied)
    planning_seconds: float  # laying out one candidate (planning its cells)

    @property
    def candidates(self) -> int:
        return self.population * (self.generations + 1)

    @property
    def estimate_seconds(self) -> float | None:
        """The search's wall time if every candidate is feasible [s]: its trials' CPU time
        over the workers, and each candidate's planning in the main process."""
        report = self.sweep
        if report is None or report.calibration is None:
            return None
        cal = report.calibration
        busy = max(1, min(report.workers, report.cores if report.executor == "local"
                          else report.workers))
        per_candidate = sum(cal.per_chunk + c.size * cal.per_trial for c in report.chunks)
        return self.candidates * (per_candidate / busy + self.planning_seconds)

    @property
    def warnings(self) -> tuple[str, ...]:
        """The calibrated study's warnings, but for idle workers on one candidate's chunks
        (a generation's candidates share the workers)."""
        if self.sweep is None:
            return ()
        return tuple(w for w in self.sweep.warnings if " would idle " not in w)

    def text(self) -> str:
        spec, design = self.spec, self.design
        search = spec.search
        lines = [f"search spec {spec.name!r}, resolved (every key; defaults filled in):", "",
                 spec_toml(spec, sweep=True, search=True).rstrip("\n"), ""]
        rows = [[v.name, f"{v.low:.6g}", f"{v.high:.6g}", f"{v.baseline:.6g}"]
                for v in design.variables]
        lines += [f"design variables ({len(rows)}):", "",
                  table(["variable", "low", "high", "the spec's own"], rows), ""]
        cw = design.counterweight
        if cw is not None:
            how = ("placed by the designer on the balancing ray (the link's centre on its "
                   "joint)" if cw.designer else "placed at x, y (the link's centre moves)")
            lines.append(f"counterweight on link {spec.joints}: {how}; [robot]'s link "
                         f"{spec.joints} is the bare link")
        lines.append(f"constraints: total mass <= {search.max_mass:g} kg; verdict at least "
                     f"{search.verdict}; last link's centre {search.centre}")
        what = ("the 95 % Wilson lower bound of the fraction reached (ties: the "
                f"{search.quantile:g} quantile of {search.metric})" if search.objective ==
                "reached" else f"the {search.quantile:g} quantile of {search.metric}")
        lines.append(f"objective: {what}" + (f" + {search.energy_weight:g} x plan energy / "
                                             "the spec's own" if search.energy_weight else ""))
        lines.append(f"optimiser: scipy's differential_evolution (best1bin, seed "
                     f"{search.seed}), {self.population} designs per generation, the first "
                     f"population and {self.generations} more: at most {self.candidates} "
                     f"candidates (search.candidates = {search.candidates})"
                     + (f", or search.seconds = {search.seconds:g} s" if search.seconds
                        < float("inf") else ""))
        own = design.candidate(design.baseline)
        judged = ("meets the constraints" if own.feasible else
                  f"breaks the constraints: {violation_text(own.violations, spec, own.verdict)}"
                  if own.robot is not None else f"cannot be built: {own.reason}")
        inside = ("candidate 0" if design.baseline_inside
                  else "outside the bounds, so not a candidate")
        lines.append(f"the spec's own design: {judged} ({inside}; verdict "
                     f"{own.verdict or '-'})")
        report = self.sweep
        if report is None:
            lines.append(f"its study cannot be laid out ({self.own_reason}): no estimate")
        else:
            lay = report.layout
            lines.append(f"each candidate: {lay.total} trials ({len(lay.cells)} cell"
                         f"{'s' if len(lay.cells) > 1 else ''} of {lay.trials_per_cell}, "
                         f"sweep.seed = {spec.sweep.seed}: the same draws for every candidate) "
                         f"in {len(report.chunks)} chunk{'s' if len(report.chunks) > 1 else ''};"
                         f" planning one takes {1e3 * self.planning_seconds:.0f} ms")
            cal = report.calibration
            total = self.estimate_seconds
            if cal is not None and total is not None:
                lines.append(f"calibration on the spec's own design: {cal.trials} trials, "
                             f"{1e3 * cal.per_trial:.3g} ms per trial")
                where = f"{report.workers} {report.executor} worker" + (
                    "s" if report.workers > 1 else "")
                lines.append(f"estimate on {where}: {duration_estimate(total)} for "
                             f"{self.candidates * lay.total} trials "
                             f"({self.candidates} candidates x {lay.total}), if every "
                             "candidate is feasible and costs what the spec's own design does")
        lines += closing_lines(self.warnings)
        return "\n".join(lines)


def check_search_spec(spec: Spec, workers: int | None = None, executor: str = "local",
                      calibrate: bool = True, quiet: bool = False) -> SearchCheckReport:
    """What a search of ``spec`` would do and cost (module docstring); SpecError if it cannot
    search."""
    design, population, generations = check_search(spec)
    began = time.perf_counter()
    own, lay, _, reason = own_study(spec, design)
    planning = time.perf_counter() - began
    sweep = None
    if lay is not None and own.spec is not None:
        sweep = check_spec(own.spec, workers=workers, executor=executor, calibrate=calibrate,
                           quiet=quiet)
    return SearchCheckReport(spec, design, population, generations, reason, sweep, planning)


__all__ = ["SearchCheckReport", "check_search_spec"]
