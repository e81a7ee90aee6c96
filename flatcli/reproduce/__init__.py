"""``flatcli reproduce`` (``make reproduce``): the paper's Figs. 2-4 and numbers, and the studies.

Writes into one directory (``runs/paper`` from ``make reproduce``) the figures, the plans and
closed-loop runs as Parquet, the sweeps, and REPORT.md, whose every number is computed from
those runs. The report is made of sections (``SECTIONS``, one module each: ``paper``,
``optimized``, ``montecarlo``, ``actuators``, ``within``, ``chains``, ``asbuilt``,
``search``); a
section whose inputs and code have not changed since it was last computed into the directory
is reused, not computed again (``sections``), so a second ``make reproduce`` takes seconds. ``only``
computes some sections and keeps the others' last results; ``force`` computes again
whatever it runs.
"""

from __future__ import annotations

import time
from importlib import resources
from pathlib import Path

from flatcli import __version__
from flatcli.report.figures import FigureFile
from flatcli.reproduce import (
    actuators,
    asbuilt,
    capture,
    chains,
    montecarlo,
    optimized,
    paper,
    search,
    within,
)
from flatcli.reproduce.sections import Context, Result, Section, Steps, compute_or_reuse
from flatcli.reproduce.sections import stored_result as _stored
from flatcli.spec import load_spec, resolve
from flatcli.storage import directory_lock, run_record, write_json, write_text

#: The Monte Carlo study's spec, shipped with flatcli (package data; configs/ links to it).
STUDY_SPEC = Path(str(resources.files("flatcli") / "data" / "paper_montecarlo.toml"))

#: The report's sections, in its order.
SECTIONS: tuple[Section, ...] = (paper.SECTION, optimized.SECTION, montecarlo.SECTION,
                                 actuators.SECTION, within.SECTION, chains.SECTION,
                                 capture.SECTION, asbuilt.SECTION, search.SECTION)
SECTION_NAMES: tuple[str, ...] = tuple(s.name for s in SECTIONS)

INTRO = (
    "Every number below was computed by `make reproduce` (`flatcli reproduce`) from the runs "
    "in this directory. The robot is the paper's (m_i = 1 kg, l_i = 0.2 m, "
    "I_i = 0.0533 kg m^2, d0 = d1 = 0.1 m, d2 = 0); the maneuver goes from "
    "th = (1.8, 1, 0) to (1.2, 2, 0) rad in 2 s with th1'(0) = 0.1 and th1'(2) = 0.5 rad/s."
)


def check_inputs(out: Path, montecarlo: Path | None, workers: int | None,
                 sets: tuple[str, ...], only: tuple[str, ...] = ()) -> None:
    """Every input of ``reproduce``, checked before anything is written: the output
    directory, the study's spec with its --set items (every grid cell planned), --workers,
    --only."""
    from flatcli.core.errors import FlatcliError
    from flatcli.montecarlo import layout
    from flatcli.storage import check_output_dir

    for name in only:
        if name not in SECTION_NAMES:
            raise FlatcliError(f"--only: expected one of {', '.join(SECTION_NAMES)}, "
                               f"got {name!r}")
    for name in ("montecarlo", "within", "asbuilt", "search"):  # the sections that are studies
        if montecarlo is None and name in only:
            raise FlatcliError(f"--only {name}: the study is skipped by --no-montecarlo")
    check_output_dir(out)
    if workers is not None and workers < 1:
        raise FlatcliError(f"--workers: must be >= 1, got {workers}")
    if montecarlo is None:
        if sets:
            raise FlatcliError("--set: changes the Monte Carlo study, which --no-montecarlo "
                               "skips")
        return
    layout(load_spec(montecarlo, sets))


#: REPORT.md's last line: what to cite (``flatcli --cite``, CITATION.cff).
CITE_LINE = ("To cite: flatcli (this version) and the paper it reproduces, Franch, Agrawal, Oh, "
             "Fattah, IROS 2003, pp. 3053-3058; `flatcli --cite` prints both with BibTeX "
             "(CITATION.cff).")


def report_text(results: list[Result], missing: list[Section], command: str | None) -> str:
    """REPORT.md: the title, the headlines, every section's lines, and how it was made."""
    lines = ["# Reproducing Franch, Agrawal, Oh, Fattah (IROS 2003) with flatcli", "", INTRO, "",
             "## Headlines", ""]
    for result in results:
        lines += [f"- **{result.section.name}**: {text}" for text in result.headline]
    lines.append("")
    for result in results:
        lines += result.lines
        lines.append("")
    made = ", ".join(
        f"{r.section.name} ({'reused, computed ' + r.finished if r.reused else 'computed'} "
        f"in {r.seconds:.0f} s)" for r in results)
    lines += ["## How this report was made", "", f"Sections: {made}."]
    if missing:
        lines += ["", "Not in this report (never computed into this directory): "
                  + ", ".join(f"{s.name} (`flatcli reproduce --only {s.name}`)"
                              for s in missing) + "."]
    if command is not None:
        lines += ["", f"Made with `{command}` (flatcli {__version__})."]
    lines += ["", CITE_LINE]
    return "\n".join(lines) + "\n"


def reproduce(out: Path, montecarlo: Path | None, quiet: bool = False,
              workers: int | None = None, sets: tuple[str, ...] = (),
              command: str | None = None, only: tuple[str, ...] = (),
              force: bool = False, figures: FigureFile | None = None
              ) -> tuple[Path, list[Result]]:
    """Run everything ``make reproduce`` promises into ``out``; return REPORT.md's path and
    the sections' results (their headlines, whether each was reused).

    ``only``: compute these sections (reused if unchanged, unless ``force``) and keep the
    others' last valid results in the report; ``force``: compute again every section run.
    ``command``: the command line, recorded at the end of REPORT.md; ``figures``: the format
    and resolution of every figure (default png, 150 dots per inch).
    """
    started = time.perf_counter()
    check_inputs(out, montecarlo, workers, sets, only)
    steps = Steps(quiet)
    with directory_lock(out):
        context = Context(out, resolve({}), montecarlo, sets, workers, steps,
                          figures or FigureFile())
        wanted = [s for s in SECTIONS if s.wanted(context)]
        run = [s for s in wanted if not only or s.name in only]
        results: list[Result] = []
        missing: list[Section] = []
        for index, section in enumerate(run, 1):
            steps.section(index, len(run), section.title)
            results.append(compute_or_reuse(section, context, force))
        if only:
            kept = {r.section.name: r for r in results}
            for section in wanted:
                if section.name in kept:
                    continue
                stored = _stored(section, context)
                if stored is None:
                    missing.append(section)
                else:
                    kept[section.name] = stored
            results = [kept[s.name] for s in wanted if s.name in kept]
        path = out / "REPORT.md"
        write_text(path, report_text(results, missing, command))
        write_json(out / "run.json", run_record(
            "reproduce", context.base.tree, seconds=time.perf_counter() - started,
            sections={r.section.name: "reused" if r.reused else "computed" for r in results}))
    return path, results


__all__ = ["SECTIONS", "SECTION_NAMES", "STUDY_SPEC", "check_inputs", "reproduce"]
