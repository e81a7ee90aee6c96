"""The ``flatcli`` command line: each command a few lines of wiring.

Every user error (a bad spec, option or file, an infeasible request) ends as one line on
stderr, ``error: ...``, with exit status 2, no traceback, and no output written.
"""

from __future__ import annotations

import contextlib
import json
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import click
import pandas as pd

from flatcli import __version__
from flatcli.core.model import FlatcliError, constraint_coefficients, flatness_check
from flatcli.core.optimize import OBJECTIVES
from flatcli.experiment import plan_and_optimization, plant_from, robot_from, run_track
from flatcli.report import (
    Progress,
    metrics_text,
    optimization_summary,
    optimization_text,
    plan_summary,
    plan_text,
    plot_plan,
    plot_sweep,
    plot_track,
    table,
)
from flatcli.spec import Spec, load_spec
from flatcli.storage import run_record, write_json, write_parquet

F = TypeVar("F", bound=Callable[..., Any])

EXIT_USAGE = 2


def fail(message: str) -> NoReturn:
    click.echo(f"error: {message}", err=True)
    sys.exit(EXIT_USAGE)


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn domain errors into one line and exit status 2."""
    try:
        yield
    except FlatcliError as exc:
        fail(str(exc))


class Cli(click.Group):
    """A group whose usage errors are one line too."""

    def main(self, *args: Any, **kwargs: Any) -> Any:
        kwargs["standalone_mode"] = False
        kwargs.setdefault("prog_name", "flatcli")
        try:
            return super().main(*args, **kwargs)
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)
        except click.exceptions.Abort:
            click.echo("error: interrupted", err=True)
            sys.exit(130)
        except click.ClickException as exc:
            hint = ""
            ctx = getattr(exc, "ctx", None)
            if ctx is not None:
                hint = f" (see '{ctx.command_path} --help')"
            click.echo(f"error: {exc.format_message()}{hint}", err=True)
            sys.exit(exc.exit_code)


def spec_options(fn: F) -> F:
    """SPEC argument, --set, --out, -q: shared by the commands that read a spec."""
    fn = click.option("-q", "--quiet", is_flag=True, help="Print nothing but errors.")(fn)
    fn = click.option(
        "--out",
        type=click.Path(path_type=Path, file_okay=False),
        help="Output directory [default: runs/<name>/].",
    )(fn)
    fn = click.option(
        "--set",
        "sets",
        multiple=True,
        metavar="KEY=VALUE",
        help="Override a spec key (dotted; VALUE in TOML), repeatable.",
    )(fn)
    return click.argument("spec", required=False, type=click.Path(path_type=Path, dir_okay=True))(
        fn
    )


def out_dir(spec: Spec, out: Path | None) -> Path:
    return out if out is not None else Path("runs") / spec.name


def say(quiet: bool, text: str) -> None:
    if not quiet:
        click.echo(text)


@click.group(cls=Cli)
@click.version_option(__version__, prog_name="flatcli")
def main() -> None:
    """Flatness-based planning, feedback control and Monte Carlo studies of planar
    free-floating space robots (Franch, Agrawal, Oh, Fattah, IROS 2003).

    With no SPEC file a command runs the paper's example.
    """


def optimize_option(fn: F) -> F:
    return click.option(
        "--optimize", "objective", type=click.Choice(list(OBJECTIVES)),
        help="Optimise the plan (shorthand for --set plan.optimize.objective=...).",
    )(fn)


def with_objective(sets: tuple[str, ...], objective: str | None) -> tuple[str, ...]:
    return sets if objective is None else (*sets, f"plan.optimize.objective={objective}")


@main.command()
@spec_options
@optimize_option
@click.option("--plot", is_flag=True, help="Also write plan.png.")
def plan(spec: Path | None, sets: tuple[str, ...], out: Path | None, quiet: bool,
         objective: str | None, plot: bool) -> None:
    """Plan a point-to-point maneuver through the flat outputs; write plan.parquet."""
    with user_errors():
        s = load_spec(spec, with_objective(sets, objective))
        planned, optimization = plan_and_optimization(s)
        samples = planned.sample(planned.grid(s.get("plan.samples")))
    frame = pd.DataFrame({"t": samples.t})
    for i in range(3):
        frame[f"theta{i}"] = samples.theta[:, i]
    for i in range(3):
        frame[f"theta{i}_dot"] = samples.theta_dot[:, i]
    frame["u1_dot"] = samples.u1_dot
    frame["u2"] = samples.u2
    for name, arr in (("", samples.y), ("_dot", samples.y_dot), ("_ddot", samples.y_ddot)):
        frame[f"y1{name}"] = arr[:, 0]
        frame[f"y2{name}"] = arr[:, 1]
    frame["margin"] = samples.margin
    frame["momentum"] = samples.momentum
    directory = out_dir(s, out)
    summary = plan_summary(planned, samples)
    opt = None if optimization is None else optimization_summary(
        optimization, s.get("plan.optimize.objective"))
    record = run_record("plan", s.tree, summary=summary, optimization=opt)
    write_parquet(directory / "plan.parquet", frame, record)
    write_json(directory / "run.json", record)
    if plot:
        plot_plan(samples, directory / "plan.png", f"plan {s.name!r} ({planned.model} model)")
    say(quiet, plan_text(s.name, planned, samples))
    if opt is not None:
        say(quiet, "\n" + optimization_text(opt))
    say(quiet, f"wrote {directory}/plan.parquet" + (" and plan.png" if plot else ""))


@main.command()
@spec_options
@optimize_option
@click.option("--plot", is_flag=True, help="Also write track.png.")
def track(spec: Path | None, sets: tuple[str, ...], out: Path | None, quiet: bool,
          objective: str | None, plot: bool) -> None:
    """Track the plan in closed loop from a perturbed initial state; write track.parquet."""
    with user_errors():
        s = load_spec(spec, with_objective(sets, objective))
        run = run_track(s)
    cols = run.columns
    metrics = run.metrics
    directory = out_dir(s, out)
    record = run_record("track", s.tree, metrics=metrics)
    write_parquet(directory / "track.parquet", pd.DataFrame(cols), record)
    write_json(directory / "metrics.json", metrics)
    write_json(directory / "run.json", record)
    if plot:
        plot_track(
            cols,
            directory / "track.png",
            f"track {s.name!r}: kp = {s.get('track.kp')}, kv = {s.get('track.kv')}",
        )
    say(quiet, metrics_text(s.name, metrics))
    say(quiet, f"wrote {directory}/track.parquet, metrics.json" + (", track.png" if plot else ""))


@main.command()
@click.argument("spec", required=False, type=click.Path(path_type=Path))
@click.option(
    "--set",
    "sets",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a spec key (dotted; VALUE in TOML), repeatable.",
)
def design(spec: Path | None, sets: tuple[str, ...]) -> None:
    """Check whether a design is differentially flat; print its constraint coefficients.

    Exit status 0 when the robot is flat, 1 when it is not.
    """
    with user_errors():
        s = load_spec(spec, sets)
        robot = robot_from(s)
        plant = plant_from(s)
    check = flatness_check(robot)
    model = s.get("robot.model")
    k = constraint_coefficients(robot.links, model)
    rows = [[name, float(v)] for name, v in zip(k._fields, k, strict=True)]
    click.echo(f"robot {s.name!r}, {model} coefficients [kg^2 m^2]:")
    click.echo(table(["coefficient", "value"], rows, 6))
    if check.is_flat:
        click.echo("flat: yes (d2 = 0, c0 a1 != 0); singular where sin th1 = 0 or th1' = 0")
    else:
        click.echo(f"flat: no: {check.message()}")
    if plant != robot:
        pc = flatness_check(plant)
        click.echo(f"plant: {'flat' if pc.is_flat else 'not flat: ' + pc.message()}")
    sys.exit(0 if check.is_flat else 1)


@main.command()
@click.argument("spec", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path, file_okay=False),
              help="Output directory [default: runs/<name>/].")
@click.option("--workers", type=int, help="Worker processes [default: one per core].")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a spec key (dotted; VALUE in TOML), repeatable.")
@click.option("-q", "--quiet", is_flag=True, help="No progress and no tables.")
@click.option("--fail-fast", is_flag=True,
              help="Stop at the first trial that raises or diverges (exit status 1).")
@click.option("--force", is_flag=True, help="Start over in a directory holding another sweep.")
@click.option("--executor", type=click.Choice(["local", "dask"]), default="local",
              show_default=True, help="Run chunks on this machine or on a Dask cluster.")
@click.option("--scheduler", metavar="ADDRESS",
              help="Dask scheduler address (tcp://host:8786), or 'local' for a LocalCluster.")
@click.option("--rerun", "rerun", type=int, metavar="TRIAL",
              help="Re-run one finished trial alone (as flatcli track) and compare.")
@click.option("--print-spec", is_flag=True, help="With --rerun: print that trial's track spec.")
@click.option("--plot", is_flag=True, help="Also write the summary figures.")
def sweep(spec: Path, out: Path | None, workers: int | None, sets: tuple[str, ...],
          quiet: bool, fail_fast: bool, force: bool, executor: str, scheduler: str | None,
          rerun: int | None, print_spec: bool, plot: bool) -> None:
    """Run a Monte Carlo sweep from a TOML spec with a [sweep] table (resumable)."""
    from flatcli.executors import WorkerLostError
    from flatcli.sweep import FailFastError, run_sweep

    with user_errors():
        s = load_spec(spec, sets, sweep=True)
        directory = out_dir(s, out)
        if rerun is not None:
            _rerun(s, directory, rerun, print_spec, quiet)
            return
        if print_spec:
            fail("--print-spec: only with --rerun TRIAL")
        try:
            result = run_sweep(s, directory, executor, workers, scheduler, force, fail_fast,
                               Progress(s.name, quiet))
        except FailFastError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(1)
        except WorkerLostError as exc:
            click.echo(f"error: {exc}; finished chunks are kept in {directory}/trials; "
                       "run the same command again to resume", err=True)
            sys.exit(1)
        except KeyboardInterrupt:
            click.echo(f"error: interrupted; finished chunks are kept in {directory}/trials; "
                       "run the same command again to resume", err=True)
            sys.exit(130)
    if plot:
        plot_sweep(directory)
    say(quiet, result.summary_text)
    say(quiet, f"{result.layout.total} trials ({result.simulated} simulated now) in "
               f"{result.wall_seconds:.1f} s; wrote {directory}/trials.parquet, summary.md")


def _rerun(s: Spec, directory: Path, trial: int, print_spec: bool, quiet: bool) -> None:
    from flatcli.sweep import layout, rerun_spec, spec_toml

    trials_path = directory / "trials.parquet"
    if not trials_path.exists():
        fail(f"--rerun: {trials_path} not found; run the sweep first")
    frame = pd.read_parquet(trials_path, filters=[("trial", "==", trial)])
    if frame.empty:
        fail(f"--rerun: no trial {trial} in {trials_path}")
    row = {str(k): v for k, v in frame.iloc[0].items()}
    if row["status"] == "error":
        fail(f"--rerun: trial {trial} did not simulate ({row['reason']})")
    track_spec = rerun_spec(layout(s), row)
    if print_spec:
        click.echo(spec_toml(track_spec), nl=False)
        return
    run = run_track(track_spec)
    metrics = run.metrics
    target = directory / f"rerun-{trial}"
    record = run_record("sweep --rerun", track_spec.tree, metrics=metrics, trial=trial)
    write_parquet(target / "track.parquet", pd.DataFrame(run.columns), record)
    write_json(target / "metrics.json", metrics)
    write_json(target / "run.json", record)
    plot_track(run.columns, target / "track.png", f"{s.name}: trial {trial}")
    rows = [[k, row[k], v, "yes" if _same(row[k], v) else "NO"]
            for k, v in metrics.items() if k != "reason"]
    modified = _sweep_digest(directory) != s.digest()
    say(quiet, f"trial {trial} of {s.name!r} re-run alone" + (
        " with a spec that differs from the sweep's (--set): differences are expected"
        if modified else ":"))
    say(quiet, table(["metric", "in trials.parquet", "re-run", "identical"], rows, 6))
    say(quiet, f"wrote {target}/track.parquet, metrics.json, track.png")
    if not modified and not all(r[3] == "yes" for r in rows):
        fail(f"--rerun: trial {trial} did not reproduce")


def _sweep_digest(directory: Path) -> str | None:
    from flatcli.sweep import MANIFEST

    try:
        return str(json.loads((directory / MANIFEST).read_text())["digest"])
    except (OSError, ValueError, KeyError):
        return None


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float | int) and isinstance(b, float | int):
        return (a == b) or (a != a and b != b)
    return bool(a == b)


@main.command()
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@click.option("--plot", is_flag=True, help="Also write the summary figures.")
def summarize(directory: Path, plot: bool) -> None:
    """Print a finished sweep's summary tables again (and --plot its figures)."""
    summary_md = directory / "summary.md"
    if not summary_md.exists():
        fail(f"{summary_md} not found: not a finished sweep directory")
    click.echo(summary_md.read_text(), nl=False)
    if plot:
        paths = plot_sweep(directory)
        click.echo("wrote " + ", ".join(str(p) for p in paths))


@main.command()
@click.option("--out", type=click.Path(path_type=Path, file_okay=False),
              default=Path("runs/paper"), show_default=True, help="Output directory.")
@click.option("--montecarlo", "montecarlo", type=click.Path(path_type=Path),
              default=Path("configs/paper_montecarlo.toml"), show_default=True,
              help="Sweep spec of the Monte Carlo study.")
@click.option("--no-montecarlo", is_flag=True, help="Skip the Monte Carlo study.")
@click.option("--workers", type=int, help="Worker processes for the study.")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a key of the study's spec, repeatable.")
@click.option("-q", "--quiet", is_flag=True, help="Print nothing but errors.")
def reproduce(out: Path, montecarlo: Path, no_montecarlo: bool, workers: int | None,
              sets: tuple[str, ...], quiet: bool) -> None:
    """The paper's Figs. 2-4 and numbers, and the Monte Carlo study, with REPORT.md."""
    from flatcli.reproduce import reproduce as run

    with user_errors():
        path = run(out, None if no_montecarlo else montecarlo, quiet, workers, sets)
    if not quiet:
        click.echo(path.read_text())


if __name__ == "__main__":
    main()
