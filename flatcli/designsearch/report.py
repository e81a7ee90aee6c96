"""A search's results: search.parquet (one row per candidate), the best design's files, the
summary and the convergence figure.

search.parquet's rows are the candidates in the order the optimiser first asked for them; its
bytes depend on the rows and the spec only (no time, no host), so a search run with any number
of workers, or killed and resumed, writes the same file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from flatcli.arrow import flags, numbers, texts
from flatcli.core.robots.params import RobotParams
from flatcli.designsearch.design import CONSTRAINTS
from flatcli.designsearch.directory import (
    BEST_ROBOT,
    BEST_SPEC,
    BEST_URDF,
    FIGURE_STEM,
    SUMMARY,
    TABLE,
    remove_best,
    write_record,
)
from flatcli.designsearch.evaluate import EVALUATED, OUTCOMES
from flatcli.designsearch.runner import Row, SearchState
from flatcli.spec import Spec
from flatcli.spec.schema import SCHEMA
from flatcli.spec.toml import toml_key, toml_value
from flatcli.storage import versions, with_units, write_table, write_text
from flatcli.units import DIMENSIONLESS

#: The robot columns of search.parquet (the candidate's whole ``[robot]``).
ROBOT_COLUMNS = ("robot.mass", "robot.inertia", "robot.length", "robot.com", "robot.com_across")
#: Rows of the summary's table of the best candidates.
SHOWN = 10


def quantile_column(spec: Spec) -> str:
    """The name of the quantile's column: ``err_theta_final_q0.9``."""
    return f"{spec.search.metric}_q{spec.search.quantile:g}"


def best_row(rows: Sequence[Row]) -> Row | None:
    """The evaluated candidate of least objective (the first of equals), or None."""
    best: Row | None = None
    for row in rows:
        e = row.evaluation
        if e is None or e.status != EVALUATED:
            continue
        if best is None or e.objective < best.evaluation.objective:  # type: ignore[union-attr]
            best = row
    return best


def search_table(state: SearchState) -> pa.Table:
    """search.parquet: one row per candidate (docs/search.md lists the columns)."""
    spec, design, rows = state.spec, state.design, state.rows
    n = len(rows)
    cols: dict[str, Any] = {
        "candidate": numbers(np.arange(n), pa.int64()),
        "generation": numbers(np.array([r.generation for r in rows]), pa.int64()),
        "status": texts([r.evaluation.status if r.evaluation else "" for r in rows]),
        "reason": texts([r.evaluation.reason if r.evaluation else "" for r in rows]),
    }
    for j, name in enumerate(design.names):
        cols[name] = numbers(np.array([r.candidate.x[j] for r in rows]))
    robots = [r.candidate.robot for r in rows]
    missing = np.array([rb is None for rb in robots], dtype=bool)
    for column in ROBOT_COLUMNS:
        key = column.split(".")[1]
        values = [None if rb is None else getattr(rb, key) for rb in robots]
        if key == "com_across":
            cols[column] = numbers(np.array([math.nan if v is None else v for v in values]),
                                   null=missing)
        else:
            cols[column] = pa.array([None if v is None else list(v) for v in values],
                                    pa.list_(pa.float64()))
    cols["total_mass"] = numbers(np.array([math.nan if rb is None else rb.total_mass
                                           for rb in robots]), null=missing)
    if design.counterweight is not None:
        weights = [{} if r.candidate.robot is None else design.counterweight_of(
            np.array(r.candidate.x)) for r in rows]
        for key in ("mass", "x", "y"):
            cols[f"counterweight.{key}"] = numbers(
                np.array([w.get(key, math.nan) for w in weights]), null=missing)
    cols["verdict"] = texts([r.candidate.verdict or None for r in rows])
    cols["feasible"] = flags(np.array([r.candidate.feasible for r in rows], dtype=bool))
    for k, (name, _) in enumerate(CONSTRAINTS):
        violation = np.array([r.candidate.violations[k] for r in rows], dtype=float)
        cols[name] = numbers(np.where(np.isinf(violation), np.nan, violation),
                             null=np.isinf(violation))
    evaluations = [r.evaluation for r in rows]
    studied = np.array([e is not None and e.status == EVALUATED for e in evaluations])
    for name in ("trials", *OUTCOMES):
        counts = np.array([getattr(e, name) if e is not None else 0 for e in evaluations])
        cols[name] = numbers(counts, pa.int64(), ~studied)
    for name in ("reached_fraction", "reached_low", "reached_high"):
        shares = np.array([getattr(e, name) if e is not None and e.trials else math.nan
                           for e in evaluations], dtype=float)
        cols[name] = numbers(shares, null=~studied)
    cols[quantile_column(spec)] = numbers(
        np.array([e.quantile if e is not None else math.nan for e in evaluations]),
        null=~studied)
    energy = np.array([e.energy if e is not None else math.nan for e in evaluations])
    cols["plan_energy"] = numbers(energy, null=np.isnan(energy))
    objective = np.array([e.objective if e is not None else math.nan for e in evaluations])
    cols["objective"] = numbers(objective)
    running = np.full(n, math.nan)  # the least objective evaluated so far (nan before one)
    best: float | None = None
    for i, e in enumerate(evaluations):
        if studied[i] and e is not None:
            best = e.objective if best is None else min(best, e.objective)
        running[i] = math.nan if best is None else best
    cols["best_objective"] = numbers(running, null=np.isnan(running))
    return with_units(pa.table(cols), table_units(spec, design.names, cols))


def table_units(spec: Spec, names: Sequence[str], cols: Mapping[str, Any]) -> dict[str, str]:
    """{column: unit} of search.parquet."""
    units = {"trials": DIMENSIONLESS, **dict.fromkeys(OUTCOMES, DIMENSIONLESS),
             "reached_fraction": DIMENSIONLESS, "reached_low": DIMENSIONLESS,
             "reached_high": DIMENSIONLESS, "plan_energy": "rad^2/s",
             "total_mass": "kg", "objective": DIMENSIONLESS, "best_objective": DIMENSIONLESS,
             "counterweight.mass": "kg", "counterweight.x": "m", "counterweight.y": "m",
             **{name: unit or DIMENSIONLESS for name, unit in CONSTRAINTS}}
    for column in ROBOT_COLUMNS:
        units[column] = SCHEMA["robot"][column.split(".")[1]].unit
    for name in names:
        section, _, rest = name.partition(".")
        key = rest.split("[")[0]
        units[name] = (SCHEMA["robot"][key].unit if section == "robot"
                       else {"mass": "kg", "inertia": "kg m^2"}.get(key, "m"))
    from flatcli.units import unit_of

    units[quantile_column(spec)] = unit_of(spec.search.metric) or DIMENSIONLESS
    if spec.search.objective == "quantile" and spec.search.energy_weight == 0:
        units["objective"] = units[quantile_column(spec)]
        units["best_objective"] = units["objective"]
    return {k: v for k, v in units.items() if k in cols}


def provenance(spec: Spec, identity: str) -> dict[str, Any]:
    """What search.parquet's metadata holds: the search's identity, its spec, versions."""
    return {"identity": identity, "spec": spec.tree, "versions": versions()}


def write_table_now(state: SearchState, directory: Path, identity: str) -> None:
    """search.parquet as it stands (every generation writes it again, atomically)."""
    write_table(directory / TABLE, search_table(state), provenance(state.spec, identity))


def robot_text(spec: Spec, row: Row, robot: RobotParams, best: Spec, header: str) -> str:
    """best_robot.toml: a robot file (``robot = "best_robot.toml"``) with the candidate's
    ``[robot]`` and, where the search spec sets them, its as-built ``[plant]`` keys."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    lines += ["[robot]"]
    for key in ("mass", "inertia", "length", "com"):
        lines.append(f"{key} = {toml_value(list(getattr(robot, key)))}")
    lines.append(f"com_across = {toml_value(robot.com_across)}")
    lines.append(f"model = {toml_value(best.robot.model)}")
    plant = {k: getattr(best.plant, k) for k in ("mass", "inertia", "length", "com",
                                                "com_across")
             if getattr(spec.plant, k) is not None}
    if plant:
        lines += ["", "# the plant as built: the search spec's [plant] offsets kept", "[plant]"]
        for key, value in plant.items():
            text = toml_value(list(value) if isinstance(value, tuple) else value)
            lines.append(f"{toml_key(key)} = {text}")
    return "\n".join(lines) + "\n"


def outcome_text(row: Row) -> str:
    """'reached 412/500 = 0.824 (0.788-0.855)'."""
    e = row.evaluation
    if e is None or e.status != EVALUATED:
        return f"{e.status if e else 'not evaluated'}: {e.reason if e else ''}"
    return (f"reached {e.reached}/{e.trials} = {e.reached_fraction:.3g} "
            f"({e.reached_low:.3g}-{e.reached_high:.3g})")


def summary_text(state: SearchState, record: Mapping[str, Any]) -> str:
    """summary.md: what was searched, how it stopped, the best candidate against the spec's
    own design, and the best candidates."""
    from flatcli.report import table

    spec, design, rows = state.spec, state.design, state.rows
    search = spec.search
    best = best_row(rows)
    what = ("the 95 % Wilson lower bound of the fraction reached" if search.objective ==
            "reached" else f"the {search.quantile:g} quantile of {search.metric}")
    energy = (f" + {search.energy_weight:g} x plan energy / the spec's own"
              if search.energy_weight else "")
    stops = {"candidates": f"the budget of {search.candidates} candidates (search.candidates)",
             "seconds": f"search.seconds = {search.seconds:g} s at a generation boundary "
                        f"(set search.candidates = {len(rows)} to reproduce these rows "
                        "anywhere)",
             "converged": f"convergence (the population's objectives within search.tol = "
                          f"{search.tol:g})"}
    trials = spec.sweep.trials
    lines = [f"# Design search {spec.name!r}", "",
             f"{len(design.variables)} design variables ({', '.join(design.names)}); "
             f"objective: {what}{energy}, over {trials} trials per cell and candidate "
             f"(sweep.seed = {spec.sweep.seed}: the same draws for every candidate).",
             f"{len(rows)} candidates in {state.generation + 1} generations (the first "
             f"population and {state.generation} more); stopped by "
             f"{stops.get(state.stop, state.stop)}.",
             f"Feasible: {sum(r.candidate.feasible for r in rows)}; evaluated: "
             f"{sum(1 for r in rows if r.evaluation and r.evaluation.status == EVALUATED)}."]
    own = next((r for r in rows if design.baseline_inside and r.index == 0), None)
    if own is not None:
        lines.append(f"The spec's own design (candidate 0): {outcome_text(own)}.")
    if best is None:
        lines.append("No candidate was evaluated: no best design.")
    else:
        values = ", ".join(f"{n} = {v:.6g}" for n, v in zip(design.names, best.candidate.x,
                                                            strict=True))
        lines.append(f"Best: candidate {best.index} (generation {best.generation}): "
                     f"{outcome_text(best)}; {values}.")
    ranked = sorted((r for r in rows if r.evaluation and r.evaluation.status == EVALUATED),
                    key=lambda r: (r.evaluation.objective, r.index))  # type: ignore[union-attr]
    if ranked:
        body = [[r.index, r.generation, *(f"{v:.4g}" for v in r.candidate.x),
                 f"{r.evaluation.reached_fraction:.3f}",  # type: ignore[union-attr]
                 f"{r.evaluation.reached_low:.3f}-{r.evaluation.reached_high:.3f}",  # type: ignore[union-attr]
                 f"{r.evaluation.objective:.6g}"]  # type: ignore[union-attr]
                for r in ranked[:SHOWN]]
        lines += ["", f"## The best {min(SHOWN, len(ranked))} candidates", "",
                  table(["candidate", "generation", *design.names, "reached", "95 % interval",
                         "objective"], body)]
    lines += ["", f"Times: {record.get('wall_seconds', math.nan):.1f} s in all, "
                  f"{record.get('simulated_trials', 0)} trials simulated now, "
                  f"{record.get('resumed_candidates', 0)} candidates from the journal; "
                  f"{record.get('executor', '')}."]
    return "\n".join(lines) + "\n"


def convergence_figure(state: SearchState) -> Any:
    """How the search went, candidate by candidate in the order evaluated (colour: the
    generation): the objective and the best so far; the fraction reached and the best
    candidate's 95 % interval so far; the quantile of the metric (log scale)."""
    from matplotlib.figure import Figure

    from flatcli.report.figures import style

    table = search_table(state)
    spec = state.spec
    q_name = quantile_column(spec)
    frame = {name: table.column(name).to_numpy(zero_copy_only=False)
             for name in ("candidate", "generation", "objective", "best_objective",
                          "reached_fraction", "reached_low", "reached_high", "status", q_name)}
    ok = frame["status"] == EVALUATED
    x = frame["candidate"]
    best = _running_best_index(frame["objective"], ok)
    have = best >= 0
    with style():
        fig = Figure(figsize=(7.2, 6.4), layout="constrained")
        top, middle, bottom = fig.subplots(3, 1, sharex=True)
        kwargs = {"cmap": "viridis", "s": 9,
                  "vmin": 0, "vmax": max(1, int(frame["generation"].max(initial=0)))}
        generation = frame["generation"]
        points = top.scatter(x[ok], frame["objective"][ok], c=generation[ok],
                             label="candidate", **kwargs)
        top.step(x, frame["best_objective"], where="post", color="C3", label="best so far")
        if (~ok).any():
            level = np.nanmax(frame["objective"][ok]) if ok.any() else 0.0
            top.plot(x[~ok], np.full(int((~ok).sum()), level), "x", color="0.5", ms=4,
                     label="infeasible or error (drawn at the worst)")
        what = ("-(reached, 95 % lower bound) + tie-break" if spec.search.objective ==
                "reached" else f"{spec.search.metric} q{spec.search.quantile:g}")
        if spec.search.energy_weight:
            what += " + energy term"
        top.set_ylabel(f"objective\n{what}", fontsize=7)
        top.legend(loc="upper right")
        middle.scatter(x[ok], frame["reached_fraction"][ok], c=generation[ok], **kwargs)
        middle.fill_between(x[have], frame["reached_low"][best[have]],
                            frame["reached_high"][best[have]], step="post", color="C3",
                            alpha=0.25, label="best so far: 95 % interval")
        middle.set_ylim(-0.03, 1.03)
        middle.set_ylabel("fraction reached")
        middle.legend(loc="upper left")
        values = frame[q_name].astype(float)
        shown = ok & np.isfinite(values) & (values > 0)
        bottom.scatter(x[shown], values[shown], c=generation[shown], **kwargs)
        bottom.step(x[have], values[best[have]], where="post", color="C3",
                    label="best candidate so far")
        if shown.any():
            bottom.set_yscale("log")
        bottom.set_ylabel(f"{spec.search.metric}\nq{spec.search.quantile:g}", fontsize=7)
        bottom.set_xlabel("candidate (in the order evaluated)")
        bottom.legend(loc="upper right")
        bar = fig.colorbar(points, ax=[top, middle, bottom], pad=0.01, aspect=40)
        bar.set_label("generation")
        fig.suptitle(f"design search {spec.name!r}: {len(state.rows)} candidates of "
                     f"{spec.sweep.trials} trials per cell")
    return fig


def _running_best_index(objective: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """For each row, the index of the best evaluated row so far (-1 before the first)."""
    out = np.full(len(objective), -1)
    best, at = math.inf, -1
    for i in range(len(objective)):
        if ok[i] and (at < 0 or objective[i] < best):
            best, at = float(objective[i]), i
        out[i] = at
    return out


def write_results(state: SearchState, directory: Path, record: dict[str, Any],
                  identity: str) -> dict[str, Any]:
    """Everything a finished search writes: search.parquet, the best design's files, the
    summary, the figure, and search.json last (its status "finished")."""
    from flatcli.report.figures import FigureFile, save_figure
    from flatcli.spec import spec_toml
    from flatcli.urdf import write_urdf

    spec = state.spec
    write_table_now(state, directory, identity)
    best = best_row(state.rows)
    written = [TABLE]
    rebuilt = None if best is None else state.design.candidate(np.array(best.candidate.x))
    if best is not None and rebuilt is not None and rebuilt.spec is not None \
            and best.candidate.robot is not None:
        best_spec = rebuilt.spec.with_overrides({"name": f"{spec.name}_best"})
        header = (f"The best design of flatcli search {spec.name!r}: candidate {best.index}, "
                  f"{outcome_text(best)}.\nRe-measure it on fresh seeds with a sweep spec "
                  "that says robot = \"best_robot.toml\" (or: flatcli sweep best_spec.toml "
                  "--set sweep.seed=N).")
        write_text(directory / BEST_ROBOT, robot_text(spec, best, best.candidate.robot,
                                                      best_spec, header))
        write_urdf(best.candidate.robot, f"{spec.name}_best", directory / BEST_URDF)
        write_text(directory / BEST_SPEC, "# " + header.replace("\n", "\n# ") + "\n"
                   + spec_toml(best_spec, sweep=True))
        written += [BEST_ROBOT, BEST_URDF, BEST_SPEC]
        record["best"] = {"candidate": best.index, "design": dict(zip(
            state.design.names, best.candidate.x, strict=True)),
            **best.evaluation.to_json()}  # type: ignore[union-attr]
    else:
        remove_best(directory)
    file = FigureFile(spec.figures.format, spec.figures.dpi)
    fig = convergence_figure(state)
    save_figure(fig, directory / file.name(FIGURE_STEM), file)
    written.append(file.name(FIGURE_STEM))
    write_text(directory / SUMMARY, summary_text(state, record))
    written.append(SUMMARY)
    record["outputs"] = written
    write_record(directory, record)
    return record


__all__ = ["ROBOT_COLUMNS", "best_row", "convergence_figure", "quantile_column",
           "search_table", "summary_text", "write_results", "write_table_now"]
