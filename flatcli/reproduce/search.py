"""``make reproduce``'s section "Searching the design": ``flatcli search`` of the shipped
``flatcli/data/design_search.toml`` (the paper's robot, its counterweight 1 mm off joint 2 as
built, the swapped gains, 20 mrad errors), then the best design and the paper's re-measured by
plain sweeps on fresh seeds (``REMEASURE_SEED``), and both again with the counterweight off by
other amounts (``OFFSETS_MM``): how specific is the design to the offset it was searched for?

The re-measuring sweeps are what a user would run: a spec that says ``robot =
"best_robot.toml"`` (the file the search wrote) or ``robot = "paper"``, with the search spec's
``[track]``, ``[plant]`` offset and perturbations, and another ``sweep.seed``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from flatcli.report import fmt, table
from flatcli.reproduce.sections import Context, Outcome, Section, with_shared_sets
from flatcli.spec import Spec, load_spec
from flatcli.spec.toml import toml_key, toml_value

#: The search's spec (package data; configs/design_search.toml is the same file).
SEARCH_SPEC = Path(str(resources.files("flatcli") / "data" / "design_search.toml"))
#: The section's directory, inside the output directory.
DIRECTORY = "search"
#: The re-measurement: trials per sweep and their seed (not the search's).
REMEASURE_TRIALS = 2000
REMEASURE_SEED = 4002
#: Other as-built offsets of link 2's centre [mm] the two designs are measured at, and trials.
OFFSETS_MM = (-1.0, 0.0, 0.5, 1.0, 2.0)
OFFSET_TRIALS = 500
#: ``--set`` items of ``make reproduce`` that reach the search (as they reach the studies).
#: search.candidates, if not the spec's (None: the spec's).
BUDGET: int | None = None


def search_spec(context: Context) -> Spec:
    """The shipped search spec with the --set items that apply (``SHARED_SETS``)."""
    spec = with_shared_sets(load_spec(SEARCH_SPEC), context.sets)
    if BUDGET is not None:
        spec = spec.with_overrides({"search.candidates": BUDGET})
    return spec


def remeasure_text(spec: Spec, robot: str, offset: float, trials: int, seed: int,
                   plant_com: tuple[float, ...]) -> str:
    """A plain sweep spec of ``robot`` (a robot file or a shipped name) with the search
    spec's closed loop and perturbations, link 2's centre ``offset`` [m] off its joint as
    built, ``trials`` trials drawn from ``seed``."""
    com = [*plant_com[:-1], offset]
    lines = [f"# Re-measuring {robot} on fresh seeds (flatcli reproduce, section search)",
             'name = "remeasure"', f"robot = {toml_value(robot)}", "", "[plant]",
             f"com = {toml_value(com)}", "", "[track]"]
    for key in ("initial", "initial_rate", "kp", "kv"):
        value = getattr(spec.track, key)
        lines.append(f"{key} = {toml_value(list(value) if isinstance(value, tuple) else value)}")
    lines += ["", "[sweep]", f"trials = {trials}", f"seed = {seed}", "", "[sweep.perturb]"]
    for name, entry in spec.sweep.perturb.items():
        lines.append(f"{toml_key(name)} = {toml_value(entry)}")
    return "\n".join(lines) + "\n"


def measure(context: Context, text: str, path: Path) -> tuple[int, int, float]:
    """Run the sweep spec ``text`` (written to ``path``) into the directory beside it; the
    trials reached, all its trials, and the final error of its nominal trial (the spec as a
    track run: no initial error) [rad]."""
    from flatcli.designsearch.evaluate import trial_outcomes
    from flatcli.experiment import run_track
    from flatcli.montecarlo import run_sweep
    from flatcli.report import Progress

    path.write_text(text)
    spec = load_spec(path)
    directory = path.with_suffix("")
    run_sweep(spec, directory, "local", context.workers, None, force=True,
              progress=Progress(spec.name, True))
    trials = pq.read_table(directory / "trials.parquet")
    final = run_track(spec).metrics["err_theta_final"]
    nominal = float(final) if isinstance(final, int | float) else float("nan")
    return (int(np.count_nonzero(trial_outcomes(trials) == "reached")), trials.num_rows,
            nominal)


def interval_text(k: int, n: int, *_: float) -> str:
    """'k/n = p % (low-high %)', the 95 % Wilson interval."""
    from flatcli.report.summary import wilson_interval

    low, high = (float(v) for v in wilson_interval(k, n))
    return f"{k}/{n} = {100 * k / n:.1f} % ({100 * low:.1f}-{100 * high:.1f} %)"


def run(context: Context) -> Outcome:
    from flatcli import api

    spec = search_spec(context)
    out = context.out / DIRECTORY
    context.steps.step(f"{spec.name}: the search ({spec.search.candidates} candidates x "
                       f"{spec.sweep.trials} trials)")
    result = api.search(spec, out, workers=context.workers, force=True, quiet=context.quiet,
                        command="flatcli reproduce")
    record = result.record
    frame = result.table
    best = result.best
    own = frame.iloc[0]
    plant_com = spec.plant.com or spec.robot.com
    offset = plant_com[-1]
    measured: dict[str, dict[float, tuple[int, int, float]]] = {"paper": {}, "best": {}}
    robots = {"paper": "paper", "best": str((out / "best_robot.toml").resolve())}
    context.steps.step(f"re-measuring both designs: {REMEASURE_TRIALS} trials each on seed "
                       f"{REMEASURE_SEED}, and {OFFSET_TRIALS} at offsets {OFFSETS_MM} mm")
    for name, robot in robots.items():
        measured[name][offset] = measure(
            context, remeasure_text(spec, robot, offset, REMEASURE_TRIALS, REMEASURE_SEED,
                                    plant_com), out / f"remeasure_{name}.toml")
        for mm in OFFSETS_MM:
            if mm / 1000 == offset:
                continue
            measured[name][mm / 1000] = measure(
                context, remeasure_text(spec, robot, mm / 1000, OFFSET_TRIALS,
                                        REMEASURE_SEED + 1, plant_com),
                out / f"offset_{name}_{mm:g}mm.toml")
    from flatcli.report.summary import wilson_interval

    def bounds(measure: tuple[int, int, float]) -> tuple[float, float]:
        low, high = (float(v) for v in wilson_interval(*measure[:2]))
        return low, high

    apart = bounds(measured["best"][offset])[0] > bounds(measured["paper"][offset])[1]
    assert best is not None
    values = ", ".join(f"{k} = {fmt(v, 4)}" for k, v in best["design"].items())
    weight = frame.loc[best["candidate"]]
    variables = list(spec.search.vary)
    lines = [
        "", "## Searching the design", "",
        f"`flatcli search {SEARCH_SPEC.name}` (configs/design_search.toml): the paper's robot "
        f"with link 2 built from a bare link and a counterweight that the designer places "
        f"behind joint 2, tracked by the paper's law with the gains swapped from 20 mrad "
        f"errors of th(0) (std) and 0.01 rad/s of u1(0), its counterweight {1000 * offset:g} mm "
        f"off joint 2 as built (the Monte Carlo study's middle plant; the controller believes "
        f"it on the joint). Design variables, each within +-30 % of the paper's: "
        f"{', '.join(f'`{v}`' for v in variables)}; the counterweight's mass follows from "
        "its distance (the designer), so link 2's mass and inertia follow too. Objective: "
        "the 95 % Wilson lower bound of the fraction of trials reached (a trial reaches when "
        "it is resolved to the end with its final angles within 1 mrad; between equal counts "
        f"the median final error decides), each candidate over the same {spec.sweep.trials} "
        f"trials (sweep.seed = {spec.sweep.seed}: common random numbers). "
        f"{len(frame)} candidates in {record['generations'] + 1} generations of scipy's "
        f"differential evolution, {record['simulated_trials']} trials, in "
        f"{record['wall_seconds']:.0f} s on {record['executor']} (stopped by "
        f"{record['stop']}). Files: `search/` (search.parquet, summary.md, "
        f"best_robot.toml, best_robot.urdf, convergence.{context.figures.format}).",
        "",
        f"- The paper's design (candidate 0): reached {int(own['reached'])}/{int(own['trials'])}"
        f" (95 % interval {fmt(own['reached_low'], 3)}-{fmt(own['reached_high'], 3)}), median "
        f"final error {fmt(own[_median(frame)], 3)} rad.",
        f"- The best, candidate {best['candidate']} (generation "
        f"{int(weight['generation'])}): reached {best['reached']}/{best['trials']} "
        f"({fmt(best['reached_low'], 3)}-{fmt(best['reached_high'], 3)}), median final error "
        f"{fmt(best['quantile'], 3)} rad; {values}; link 2 {fmt(weight['robot.mass'][2], 4)} "
        f"kg with a {fmt(weight['counterweight.mass'], 4)} kg counterweight "
        f"{fmt(-weight['counterweight.x'], 4)} m behind joint 2, total mass "
        f"{fmt(weight['total_mass'], 4)} kg (the paper's 3 kg).",
        f"- Re-measured by plain `flatcli sweep`s of `robot = \"best_robot.toml\"` and of "
        f"`robot = \"paper\"` on fresh seeds (sweep.seed = {REMEASURE_SEED}, "
        f"{REMEASURE_TRIALS} trials each, the same offset): the paper's design reaches "
        f"{interval_text(*measured['paper'][offset])}, the best design "
        f"{interval_text(*measured['best'][offset])}: the 95 % intervals "
        + ("do not overlap." if apart else "overlap."),
        "",
        "How specific is the design to the offset it was searched for? Both designs with link "
        f"2's centre off its joint by other amounts ({OFFSET_TRIALS} trials each, sweep.seed = "
        f"{REMEASURE_SEED + 1}; at {1000 * offset:g} mm the re-measurement above), and the "
        "final angle error of the nominal trial (no initial error: the spec as `flatcli "
        "track` runs it):",
        "",
        table(["offset [mm]", "paper's design: reached", "final error [rad]",
               "best design: reached", "final error [rad]"],
              [[f"{1000 * d:g}", interval_text(*measured["paper"][d]),
                fmt(measured["paper"][d][2], 3), interval_text(*measured["best"][d]),
                fmt(measured["best"][d][2], 3)] for d in sorted(measured["paper"])]),
        "",
        "Without an offset both reach about as often as the paper's law allows on this "
        "maneuver: the trials it loses there are those whose th1' crosses zero early (the y1 "
        "loop, e1'' + kv1 e1' + kp1 e1 = 0, does not depend on the masses or lengths), so no "
        "design changes them. With the offset, the paper's design ends its nominal trial "
        f"{fmt(measured['paper'][offset][2], 3)} rad from the goal, the best design "
        f"{fmt(measured['best'][offset][2], 3)} rad: for the best design the final angle "
        "error an offset causes along this maneuver nearly vanishes over a range of offsets "
        "(the search found where its first-order effect cancels), which is why it keeps "
        "reaching. It is a property of this maneuver (its plan, its end rates, its gains) as "
        "much as of the design: read the table's other offsets before trusting it with a "
        "larger misplacement or another maneuver. `robot.length[2]` does not enter the "
        "dynamics (l_N): the search leaves it anywhere in its range.",
    ]
    headline = [f"the paper's design with its counterweight {1000 * offset:g} mm off reaches "
                f"its goal in {interval_text(*measured['paper'][offset])} of fresh trials, "
                f"the best of {len(frame)} searched designs in "
                f"{interval_text(*measured['best'][offset])}"
                + (" (95 % intervals apart)" if apart else " (intervals overlap)")]
    return Outcome(lines, headline, (f"{DIRECTORY}/**/*",))


def _median(frame: Any) -> str:
    """The column of the quantile of err_theta_final."""
    return str(next(c for c in frame.columns if c.startswith("err_theta_final_q")))


def inputs(context: Context) -> dict[str, object]:
    """The search's resolved spec and the re-measurement's sizes."""
    return {"spec": search_spec(context).tree, "remeasure": [REMEASURE_TRIALS,
                                                             REMEASURE_SEED],
            "offsets": OFFSETS_MM, "offset_trials": OFFSET_TRIALS}  # the budget is the spec's


SECTION = Section("search", "searching the design (flatcli search)", inputs, run,
                  applies=lambda context: context.study)
