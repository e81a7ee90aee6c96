"""``make reproduce``'s section "Robots as built": an imperfect counterweight planned exactly
and tracked by a feedback designed for it, against the paper's pipeline on the same robot.

Three studies, each run twice: by the *ideal-model* pipeline (the paper's: it believes
d2 = 0, plans flat, tracks with the linearising feedback, gains swapped: the reading that
converges) and by the *as-built* one (it knows where the counterweight is: an exact plan,
``exact``, and the time-varying LQR, ``lqr``), on the same plants:

* the goal (``flatcli/data/asbuilt_goal.toml``): d2 = 3 mm, the Monte Carlo study's
  initial-state errors (std 0.01, 0.05, 0.2 rad) and Fig. 4's start; both sweeps of it have
  the same grid, so their cells draw the same trials, compared one by one;
* the placement map: the counterweight d2 = 0..5 mm along link 2 and e2 = 0..5 mm across it;
* the mass map: the counterweight's mass off by -10..10 % at d2 = 3 mm (the as-built
  pipeline knows the placement, not the mass).

Each map cell is a small sweep of the Monte Carlo study's middle errors (``MAP_STD``); a
placement "keeps tracking" when its median final error is within ``TOLERANCE``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from flatcli.report import Progress, fmt, new_figure, save_figure, table
from flatcli.reproduce.sections import Context, Outcome, Section
from flatcli.spec import Spec, load_spec

#: The goal study's spec (package data; configs/ links to it).
GOAL_SPEC = Path(str(resources.files("flatcli") / "data" / "asbuilt_goal.toml"))
#: The section's directory, inside the output directory.
DIRECTORY = "asbuilt"
#: What turns the as-built pipeline of a spec into the ideal-model one.
IDEAL: dict[str, Any] = {"robot.com": [0.1, 0.1, 0.0], "robot.com_across": 0.0,
                         "plan.method": "flat", "track.controller": "flat",
                         "track.kp": [100.0, 110.0], "track.kv": [10.0, 13.0]}
PIPELINES = ("ideal", "asbuilt")
#: The paper's Fig. 4 start [rad].
FIG4 = (1.96, 0.8, -0.1)
#: The issue's goal: median final error [rad] and ratio to the ideal pipeline's.
GOAL_ERROR = 1e-4
GOAL_RATIO = 10.0
#: "Keeps tracking": median final error within this [rad].
TOLERANCE = 1e-3
#: The maps: counterweight placements [mm], mass errors [%], trials per cell, th(0) std.
ALONG_MM = (0.0, 0.5, 1.0, 2.0, 3.0, 5.0)
ACROSS_MM = (0.0, 1.0, 2.0, 3.0, 5.0)
MASS_PERCENT = (-10.0, -5.0, -2.0, 0.0, 2.0, 5.0, 10.0)
MAP_TRIALS = 64
MAP_STD = 0.05
#: ``--set`` items of ``make reproduce`` that apply to the goal study.
SHARED_SETS = ("sweep.trials=", "sweep.seed=")


def goal_spec(context: Context) -> Spec:
    """The goal study's spec with the --set items that apply (``SHARED_SETS``)."""
    spec = load_spec(GOAL_SPEC)
    for item in context.sets:
        if item.startswith(SHARED_SETS):
            key, _, value = item.partition("=")
            spec = spec.with_overrides({key: int(value)})
    return spec


def pipeline(spec: Spec, name: str) -> Spec:
    """``spec`` (an as-built pipeline) as the pipeline ``name``."""
    return spec.with_overrides(IDEAL) if name == "ideal" else spec


def _sweep(spec: Spec, directory: Path, context: Context) -> pd.DataFrame:
    from flatcli.sweep import run_sweep

    run_sweep(spec, directory, "local", context.workers, None, force=True,
              progress=Progress(spec.name, context.quiet))
    return pd.read_parquet(directory / "trials.parquet")


def goal_study(context: Context, out: Path) -> tuple[list[str], dict[str, Any]]:
    """Both pipelines on the goal's sweep and on Fig. 4's start: REPORT lines and numbers."""
    from flatcli.experiment import run_track

    base = goal_spec(context)
    trials = {}
    for name in PIPELINES:
        context.steps.step(f"goal: the {name} pipeline's sweep")
        spec = pipeline(base, name).with_overrides({"name": f"asbuilt_goal_{name}"})
        trials[name] = _sweep(spec, out / f"goal_{name}", context)
    key = "sweep.perturb.initial.std"
    joined = trials["ideal"].merge(trials["asbuilt"], on="trial", suffixes=("_ideal", "_as"))
    fig4 = {}
    for name in PIPELINES:
        spec = pipeline(base, name).with_overrides({"track.initial": list(FIG4)})
        fig4[name] = run_track(spec).metrics
    rows, numbers = [], {}
    for std, cell in joined.groupby(f"{key}_ideal"):
        resolved = cell[(cell["status_ideal"].isin(["ok", "singular"]))
                        & (cell["status_as"].isin(["ok", "singular"]))]
        ideal = cell["err_theta_final_ideal"].median()
        asb = cell["err_theta_final_as"].median()
        ratio = (resolved["err_theta_final_ideal"] / resolved["err_theta_final_as"]).median()
        lost = int((~cell["status_ideal"].isin(["ok", "singular"])).sum())
        lost_as = int((~cell["status_as"].isin(["ok", "singular"])).sum())
        met = asb <= GOAL_ERROR and ideal / asb >= GOAL_RATIO
        numbers[f"std {std:g}"] = {"ideal": ideal, "asbuilt": asb, "ratio": ratio, "met": met}
        rows.append([f"th(0) std {std:g} rad", len(cell), ideal, asb, ideal / asb, ratio,
                     f"{lost} / {lost_as}", "met" if met else "not met"])
    ideal4 = _number(fig4["ideal"]["err_theta_final"])
    as4 = _number(fig4["asbuilt"]["err_theta_final"])
    met4 = bool(as4 <= GOAL_ERROR and ideal4 / as4 >= GOAL_RATIO)
    numbers["fig4"] = {"ideal": ideal4, "asbuilt": as4, "met": met4}
    rows.insert(0, ["Fig. 4 start (1.96, 0.8, -0.1)", 1, ideal4, as4, ideal4 / as4, None, "-",
                    "met" if met4 else "not met"])
    pooled_as = joined["err_theta_final_as"].median()
    pooled_ideal = joined["err_theta_final_ideal"].median()
    numbers["pooled"] = {"ideal": pooled_ideal, "asbuilt": pooled_as}
    lines = [
        table(["trials", "n", "ideal: median err_theta_final [rad]",
               "as built: median [rad]", "ratio of medians", "median of per-trial ratios",
               "lost (ideal / as built)", f"goal (<= {GOAL_ERROR:g}, >= {GOAL_RATIO:g}x)"],
              rows, 3),
        "",
        f"Pooled over the three cells ({len(joined)} trials): median final error "
        f"{fmt(pooled_ideal, 3)} rad (ideal) against {fmt(pooled_as, 3)} rad (as built).",
    ]
    return lines, numbers


def _number(value: object) -> float:
    """A metric as a float (nan for a missing one)."""
    return float(value) if isinstance(value, int | float) else float("nan")


def _map_spec(base: Spec, name: str, grid: Mapping[str, Any]) -> Spec:
    """A map's sweep: the goal's spec at the middle errors, ``MAP_TRIALS`` per cell."""
    spec = pipeline(base, name)
    return spec.with_overrides({
        "name": f"asbuilt_map_{name}", "sweep.trials": MAP_TRIALS, "sweep.grid": dict(grid),
        "sweep.perturb": {"initial": {"dist": "normal", "std": MAP_STD},
                          "initial_rate": {"dist": "normal", "std": 0.01}}})


def placement_grid(name: str) -> dict[str, Any]:
    """The placement map's grid: one group entry per (along, across) placement; the
    as-built pipeline's robot is placed with its plant."""
    cells = []
    for d in ALONG_MM:
        for e in ACROSS_MM:
            cell: dict[str, Any] = {"label": f"d2 {d:g} mm, e2 {e:g} mm",
                                    "plant.com": [0.1, 0.1, d / 1000],
                                    "plant.com_across": e / 1000}
            if name == "asbuilt":
                cell |= {"robot.com": [0.1, 0.1, d / 1000], "robot.com_across": e / 1000}
            cells.append(cell)
    return {"placement": cells}


def mass_grid() -> dict[str, Any]:
    """The mass map's grid: the counterweighted link's mass, off by ``MASS_PERCENT``."""
    return {"plant.mass": [[1.0, 1.0, 1.0 + p / 100] for p in MASS_PERCENT]}


def maps(context: Context, out: Path) -> dict[str, pd.DataFrame]:
    """Median final errors per cell of both maps, both pipelines."""
    base = goal_spec(context)
    found: dict[str, pd.DataFrame] = {}
    for name in PIPELINES:
        context.steps.step(f"placement map: the {name} pipeline")
        spec = _map_spec(base, name, placement_grid(name))
        found[f"placement_{name}"] = _medians(_sweep(spec, out / f"placement_{name}", context),
                                              "placement")
        context.steps.step(f"mass map: the {name} pipeline")
        spec = _map_spec(base, name, mass_grid())
        found[f"mass_{name}"] = _medians(_sweep(spec, out / f"mass_{name}", context), "cell")
    return found


def _medians(trials: pd.DataFrame, by: str) -> pd.DataFrame:
    resolved = trials[trials["status"].isin(["ok", "singular"])]
    out = resolved.groupby(by, sort=False)["err_theta_final"].median().rename("median")
    lost = trials.groupby(by, sort=False)["status"].apply(
        lambda s: int((~s.isin(["ok", "singular"])).sum())).rename("lost")
    return pd.concat([out, lost], axis=1).reindex(trials[by].drop_duplicates())


def plot_maps(found: Mapping[str, pd.DataFrame], path: Path) -> None:
    """tolerance.png: log10 median final error over the placements, both pipelines, with
    the tolerance's contour; and against the mass error."""
    fig = new_figure(14, 4.4)
    axes = fig.subplots(1, 3)
    shape = (len(ALONG_MM), len(ACROSS_MM))
    levels = np.linspace(-8, 0, 17)
    for ax, name in zip(axes[:2], PIPELINES, strict=True):
        grid = np.log10(found[f"placement_{name}"]["median"].to_numpy(dtype=float)
                        .reshape(shape).clip(1e-8, 1))
        mesh = ax.contourf(ACROSS_MM, ALONG_MM, grid, levels=levels, cmap="viridis")
        ax.contour(ACROSS_MM, ALONG_MM, grid, levels=[np.log10(TOLERANCE)], colors="w",
                   linestyles="--")
        ax.set_xlabel("counterweight across link 2, e2 [mm]")
        ax.set_ylabel("counterweight along link 2, d2 [mm]")
        ax.set_title(f"{'ideal-model' if name == 'ideal' else 'as-built'} pipeline: log10 "
                     "median final error [rad]", fontsize=9)
        fig.colorbar(mesh, ax=ax)
    ax = axes[2]
    for name, style in zip(PIPELINES, ("o-", "s-"), strict=True):
        ax.semilogy(MASS_PERCENT, found[f"mass_{name}"]["median"].to_numpy(dtype=float), style,
                    label="ideal-model" if name == "ideal" else "as-built")
    ax.axhline(TOLERANCE, color="k", ls="--", lw=0.8, label=f"{TOLERANCE:g} rad")
    ax.set_xlabel("counterweight mass error [%] (d2 = 3 mm)")
    ax.set_ylabel("median final error [rad]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle(f"Tolerance maps: {MAP_TRIALS} trials per cell from th(0) errors of std "
                 f"{MAP_STD:g} rad; dashed: {TOLERANCE:g} rad", fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)


def _within(frame: pd.DataFrame) -> list[str]:
    return [str(label) for label, row in frame.iterrows() if row["median"] <= TOLERANCE]


def planning_seconds(repeats: int = 7) -> float:
    """The best of ``repeats`` wall times [s] of planning the goal's maneuver through the
    Python API (``flatcli.plan``: spec, exact plan, its samples and report)."""
    import flatcli

    overrides = {"robot.com": [0.1, 0.1, 0.003]}
    flatcli.plan(overrides=overrides)
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        flatcli.plan(overrides=overrides)
        best = min(best, time.perf_counter() - started)
    return best


def run(context: Context) -> Outcome:
    """The studies into OUT/asbuilt, the figure, and the section's lines."""
    import flatcli

    out = context.out / DIRECTORY
    goal_lines, numbers = goal_study(context, out)
    found = maps(context, out)
    context.steps.step("the figure")
    plot_maps(found, out / "tolerance.png")
    plan = flatcli.plan(overrides={"robot.com": [0.1, 0.1, 0.003]})
    flat = flatcli.plan()
    seconds = planning_seconds()
    kept = {name: _within(found[f"placement_{name}"]) for name in PIPELINES}
    mass_kept = {name: _within(found[f"mass_{name}"]) for name in PIPELINES}
    total = len(ALONG_MM) * len(ACROSS_MM)
    lines = [
        "",
        "## Robots as built: an imperfect counterweight planned exactly",
        "",
        "A counterweight a few millimetres off its joint leaves the robot controllable, hence "
        "flat, but without the paper's closed-form outputs. flatcli plans such a robot exactly "
        "(`plan.method = \"exact\"`: joint paths in quintic B-splines, th0 from the momentum "
        "constraint, the free coefficients solved so that th0(T) meets its goal with the "
        "least joint acceleration) and tracks it with a time-varying LQR of the driftless "
        "system designed on the robot as built (`track.controller = \"asbuilt\"`). The "
        f"exact plan of the maneuver at d2 = 3 mm keeps |H| at "
        f"{fmt(plan.metrics['max_abs_momentum'], 2)} kg m^2/s along it (full link "
        f"kinematics), needs an input energy of {fmt(plan.metrics['input_energy'], 4)} "
        f"rad^2/s against the paper's cubic's {fmt(flat.metrics['input_energy'], 4)}, and "
        f"took {seconds * 1e3:.0f} ms through the Python API (best of 7).",
        "",
        "**The goal** (issue 22): at d2 = 3 mm, from the paper's perturbations, the as-built "
        "pipeline's median final angle error (`err_theta_final`, all three angles, against "
        "the goal) at most 1e-4 rad and at least 10x below the ideal-model pipeline's on the "
        "same trials (both sweeps of `asbuilt_goal.toml` draw the same trials; files: "
        "`asbuilt/goal_*`):",
        "",
        *goal_lines,
        "",
        "**Tolerance map** (`asbuilt/tolerance.png`, `asbuilt/placement_*`, "
        f"`asbuilt/mass_*`; {MAP_TRIALS} trials per cell, th(0) errors of std {MAP_STD:g} "
        f"rad). With the ideal-model controller {len(kept['ideal'])} of {total} counterweight "
        f"placements (d2 along link 2 from 0 to 5 mm, e2 across it from 0 to 5 mm) keep the "
        f"median final error within {TOLERANCE:g} rad"
        + (f" ({', '.join(kept['ideal'])})" if kept["ideal"] else "")
        + f"; with the as-built controller, which knows the placement, {len(kept['asbuilt'])} "
        f"of {total} do. A counterweight whose mass is off by "
        f"{min(MASS_PERCENT):g}..{max(MASS_PERCENT):g} % (at d2 = 3 mm, the mass unknown to "
        f"both controllers) keeps {len(mass_kept['asbuilt'])} of {len(MASS_PERCENT)} mass "
        f"errors within it for the as-built pipeline and {len(mass_kept['ideal'])} for the "
        "ideal-model one. The paper's pipeline tolerates a placement error only where the "
        "plan it flies stays consistent with the plant's momentum: its reference is the "
        "plan of the robot it believes in; the as-built pipeline plans the robot it has, so "
        "the error it must correct is only what its model does not know. Its law has no "
        "integrator (nothing winds up against a rate or torque limit) and steers the error "
        "to zero at T with gains that grow like 1 / (T - t) near the end: the largest initial "
        "errors (std 0.2 rad) leave it with residuals of 1e-3 rad and more, because the base "
        "can be turned only through the joints' motion (a weakly controllable direction, "
        "whose correction a linear law about a fixed plan gets only to first order).",
        "",
        table(["placement", "ideal: median [rad]", "as built: median [rad]"],
              [[label, found["placement_ideal"]["median"].iloc[k],
                found["placement_asbuilt"]["median"].iloc[k]]
               for k, label in enumerate(found["placement_ideal"].index)], 3),
    ]
    goal = numbers["fig4"]
    headline = [
        f"d2 = 3 mm, Fig. 4's start: final error {fmt(goal['asbuilt'], 2)} rad as built "
        f"against {fmt(goal['ideal'], 2)} ideal; MC medians "
        + ", ".join(f"{k}: {fmt(v['asbuilt'], 2)} vs {fmt(v['ideal'], 2)}"
                    for k, v in numbers.items() if k.startswith("std"))
        + f"; {len(kept['asbuilt'])}/{total} placements within {TOLERANCE:g} rad as built, "
        f"{len(kept['ideal'])}/{total} ideal"]
    return Outcome(lines, headline, (f"{DIRECTORY}/**/*",))


def inputs(context: Context) -> dict[str, object]:
    """The goal study's resolved spec (with the --set items that apply) and the maps' grids."""
    return {"spec": goal_spec(context).tree, "along": ALONG_MM, "across": ACROSS_MM,
            "mass": MASS_PERCENT, "trials": MAP_TRIALS, "std": MAP_STD}


SECTION = Section("asbuilt", "robots as built: exact plans and the as-built feedback", inputs,
                  run, applies=lambda context: context.study)
