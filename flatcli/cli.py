"""The ``flatcli`` command line: each command a few lines of wiring.

Every user error (a bad spec, option or file, an infeasible request) ends as one line on
stderr, ``error: ...``, with exit status 2, no traceback, and no output written. Options that
several commands take are declared once, below, as decorators (as pip-tools does).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import click

from flatcli import __version__
from flatcli.core.model import FlatcliError, constraint_coefficients, flatness_check
from flatcli.core.optimize import OBJECTIVES
from flatcli.executors import EXECUTORS
from flatcli.experiment import checked, plan_and_optimization, plant_from, robot_from, run_track
from flatcli.outputs import plan_frame, write_track
from flatcli.report import (
    Progress,
    metrics_text,
    optimization_summary,
    optimization_text,
    plan_summary,
    plan_text,
    plot_plan,
    plot_sweep,
    table,
)
from flatcli.spec import Spec, load_spec, spec_toml
from flatcli.storage import run_record, write_json, write_parquet

F = TypeVar("F", bound=Callable[..., Any])

EXIT_USAGE = 2
RESUME_HINT = "finished chunks are kept in {}/trials; run the same command again to resume"


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


# ---------------------------------------------------------------------------------------
# Options shared by several commands, each declared once.

def spec_argument(required: bool = False) -> Callable[[F], F]:
    return click.argument("spec", required=required, type=click.Path(path_type=Path))


def set_option(help: str = "Override a spec key (dotted; VALUE in TOML), repeatable."
               ) -> Callable[[F], F]:
    return click.option("--set", "sets", multiple=True, metavar="KEY=VALUE", help=help)


def out_option(default: Path | None = None,
               help: str = "Output directory [default: runs/<name>/].") -> Callable[[F], F]:
    return click.option("--out", type=click.Path(path_type=Path, file_okay=False),
                        default=default, show_default=default is not None, help=help)


def quiet_option(help: str = "Print nothing but errors.") -> Callable[[F], F]:
    return click.option("-q", "--quiet", is_flag=True, help=help)


def workers_option(help: str = "Worker processes [default: one per core].") -> Callable[[F], F]:
    return click.option("--workers", type=int, help=help)


def plot_option(help: str) -> Callable[[F], F]:
    return click.option("--plot", is_flag=True, help=help)


def optimize_option(fn: F) -> F:
    return click.option(
        "--optimize", "objective", type=click.Choice(list(OBJECTIVES)),
        help="Optimise the plan (shorthand for --set plan.optimize.objective=...).",
    )(fn)


def spec_options(fn: F) -> F:
    """SPEC argument, --set, --out, -q: shared by the commands that run one spec."""
    for decorator in (quiet_option(), out_option(), set_option(), spec_argument()):
        fn = decorator(fn)
    return fn


def load(spec: Path | None, sets: tuple[str, ...], objective: str | None = None) -> Spec:
    """The spec of a command line (``--optimize`` is one more ``--set``)."""
    extra = () if objective is None else (f"plan.optimize.objective={objective}",)
    return load_spec(spec, (*sets, *extra))


def out_dir(spec: Spec, out: Path | None) -> Path:
    return out if out is not None else Path("runs") / spec.name


def say(quiet: bool, text: str) -> None:
    if not quiet:
        click.echo(text)


# ---------------------------------------------------------------------------------------
# Commands.

@click.group(cls=Cli)
@click.version_option(__version__, prog_name="flatcli")
def main() -> None:
    """Flatness-based planning, feedback control and Monte Carlo studies of planar
    free-floating space robots (Franch, Agrawal, Oh, Fattah, IROS 2003).

    With no SPEC file a command runs the paper's example.
    """


@main.command()
@spec_options
@optimize_option
@plot_option("Also write plan.png.")
def plan(spec: Path | None, sets: tuple[str, ...], out: Path | None, quiet: bool,
         objective: str | None, plot: bool) -> None:
    """Plan a point-to-point maneuver through the flat outputs; write plan.parquet."""
    with user_errors():
        s = load(spec, sets, objective)
        planned, optimization = plan_and_optimization(s)
        samples = planned.sample(planned.grid(s.plan.samples))
    directory = out_dir(s, out)
    summary = plan_summary(planned, samples)
    opt = None if optimization is None else optimization_summary(
        optimization, str(s.plan.optimize.objective))
    record = run_record("plan", s.tree, summary=summary, optimization=opt)
    write_parquet(directory / "plan.parquet", plan_frame(samples), record)
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
@plot_option("Also write track.png.")
def track(spec: Path | None, sets: tuple[str, ...], out: Path | None, quiet: bool,
          objective: str | None, plot: bool) -> None:
    """Track the plan in closed loop from a perturbed initial state; write track.parquet."""
    with user_errors():
        s = load(spec, sets, objective)
        run = run_track(s)
    directory = out_dir(s, out)
    title = f"track {s.name!r}: kp = {s.track.kp}, kv = {s.track.kv}"
    names = write_track(directory, run, run_record("track", s.tree, metrics=run.metrics),
                        title if plot else None)
    say(quiet, metrics_text(s.name, run.metrics))
    say(quiet, f"wrote {directory}/" + ", ".join(names))


@main.command()
@spec_argument()
@set_option()
def design(spec: Path | None, sets: tuple[str, ...]) -> None:
    """Check whether a design is differentially flat; print its constraint coefficients.

    Exit status 0 when the robot is flat, 1 when it is not.
    """
    with user_errors():
        s = load(spec, sets)
        robot = robot_from(s)
        plant = plant_from(s)
    check = flatness_check(robot)
    k = constraint_coefficients(robot.links, checked(s.robot.model))
    rows = [[name, float(v)] for name, v in zip(k._fields, k, strict=True)]
    click.echo(f"robot {s.name!r}, {s.robot.model} coefficients [kg^2 m^2]:")
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
@spec_argument(required=True)
@out_option()
@workers_option()
@set_option()
@quiet_option("No progress and no tables.")
@click.option("--fail-fast", is_flag=True,
              help="Stop at the first trial that raises or diverges (exit status 1).")
@click.option("--force", is_flag=True, help="Start over in a directory holding another sweep.")
@click.option("--executor", type=click.Choice(list(EXECUTORS)), default=EXECUTORS[0],
              show_default=True, help="Run chunks on this machine or on a Dask cluster.")
@click.option("--scheduler", metavar="ADDRESS",
              help="Dask scheduler address (tcp://host:8786), or 'local' for a LocalCluster.")
@click.option("--rerun", "rerun", type=int, metavar="TRIAL",
              help="Re-run one finished trial alone (as flatcli track) and compare.")
@click.option("--print-spec", is_flag=True, help="With --rerun: print that trial's track spec.")
@plot_option("Also write the summary figures.")
def sweep(spec: Path, out: Path | None, workers: int | None, sets: tuple[str, ...],
          quiet: bool, fail_fast: bool, force: bool, executor: str, scheduler: str | None,
          rerun: int | None, print_spec: bool, plot: bool) -> None:
    """Run a Monte Carlo sweep from a TOML spec with a [sweep] table (resumable)."""
    from flatcli.executors import WorkerLostError
    from flatcli.sweep import FailFastError, rerun_and_compare, run_sweep, trial_spec

    with user_errors():
        s = load(spec, sets)
        directory = out_dir(s, out)
        if rerun is not None and print_spec:
            click.echo(spec_toml(trial_spec(s, directory, rerun)), nl=False)
            return
        if rerun is not None:
            result = rerun_and_compare(s, directory, rerun)
            say(quiet, result.text(s.name))
            if not result.modified and not result.reproduced:
                fail(f"--rerun: trial {rerun} did not reproduce")
            return
        if print_spec:
            fail("--print-spec: only with --rerun TRIAL")
        try:
            done = run_sweep(s, directory, executor, workers, scheduler, force, fail_fast,
                             Progress(s.name, quiet))
        except FailFastError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(1)
        except WorkerLostError as exc:
            click.echo(f"error: {exc}; {RESUME_HINT.format(directory)}", err=True)
            sys.exit(1)
        except KeyboardInterrupt:
            click.echo(f"error: interrupted; {RESUME_HINT.format(directory)}", err=True)
            sys.exit(130)
    if plot:
        plot_sweep(directory)
    say(quiet, done.summary_text)
    say(quiet, f"{done.layout.total} trials ({done.simulated} simulated now) in "
               f"{done.wall_seconds:.1f} s; wrote {directory}/trials.parquet, summary.md")


@main.command()
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@plot_option("Also write the summary figures.")
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
@out_option(Path("runs/paper"), "Output directory.")
@click.option("--montecarlo", "montecarlo", type=click.Path(path_type=Path),
              default=Path("configs/paper_montecarlo.toml"), show_default=True,
              help="Sweep spec of the Monte Carlo study.")
@click.option("--no-montecarlo", is_flag=True, help="Skip the Monte Carlo study.")
@workers_option("Worker processes for the study.")
@set_option("Override a key of the studies' specs (Monte Carlo, actuators), repeatable.")
@quiet_option()
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
