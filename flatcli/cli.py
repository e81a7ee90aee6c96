"""The ``flatcli`` command line: each command a thin wrapper over the Python API
(``flatcli.api``).

Every user error (a bad spec, option or file, an infeasible request) ends as one line on
stderr, ``error: ...``, with exit status 2, no traceback, and no output written. Options that
several commands take are declared once, below, as decorators (as pip-tools does).

Only click is imported up front: numpy, numba, scipy and pandas load inside the command that
needs them, so ``flatcli --help``, ``--version`` and shell completion answer at once.
"""

from __future__ import annotations

import contextlib
import shlex
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

import click

from flatcli import __version__

if TYPE_CHECKING:  # the core loads numba: imported where a command needs it
    from flatcli.core.model import FlatnessCheck, RobotParams

F = TypeVar("F", bound=Callable[..., Any])

EXIT_USAGE = 2
RESUME_HINT = "finished chunks are kept in {}/trials; run the same command again to resume"
#: ``flatcli.core.optimize.OBJECTIVES`` and ``flatcli.executors.EXECUTORS``, spelled out here
#: so that ``--help`` need not import the numerical core (tests/test_cli.py checks they agree).
OBJECTIVES = ("energy", "peak_rate", "effort", "margin")
EXECUTORS = ("local", "dask")


def fail(message: str) -> NoReturn:
    click.echo(f"error: {message}", err=True)
    sys.exit(EXIT_USAGE)


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn domain errors into one line and exit status 2."""
    from flatcli.core.model import FlatcliError  # the core loads with the command's work

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
               help: str = "Output directory [default: a new runs/<name>/<time>-<id>/, "
                           "linked as runs/<name>/latest].") -> Callable[[F], F]:
    return click.option("--out", type=click.Path(path_type=Path, file_okay=False),
                        default=default, show_default=default is not None, help=help)


def quiet_option(help: str = "Print nothing but errors.") -> Callable[[F], F]:
    return click.option("-q", "--quiet", is_flag=True, help=help)


def workers_option(help: str = "Worker processes [default: one per core].") -> Callable[[F], F]:
    return click.option("--workers", type=int, help=help)


def plot_option(help: str) -> Callable[[F], F]:
    return click.option("--plot", is_flag=True, help=help)


def force_option(help: str) -> Callable[[F], F]:
    return click.option("--force", is_flag=True, help=help)


def executor_option(fn: F) -> F:
    return click.option(
        "--executor", type=click.Choice(list(EXECUTORS)), default=EXECUTORS[0],
        show_default=True, help="Run chunks on this machine or on a Dask cluster.")(fn)


def optimize_option(fn: F) -> F:
    return click.option(
        "--optimize", "objective", type=click.Choice(list(OBJECTIVES)),
        help="Optimise the plan (shorthand for --set plan.optimize.objective=...).",
    )(fn)


def spec_options(fn: F) -> F:
    """SPEC argument, --set, --out, --force, -q: shared by the commands that run one spec."""
    for decorator in (quiet_option(), force_option(
            "Write into an --out directory that holds another run (its files are replaced)."),
            out_option(), set_option(), spec_argument()):
        fn = decorator(fn)
    return fn


def overrides(sets: tuple[str, ...], objective: str | None = None) -> list[str]:
    """The ``--set`` items of a command line (``--optimize`` is one more)."""
    extra = [] if objective is None else [f"plan.optimize.objective={objective}"]
    return [*sets, *extra]


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
def plan(spec: Path | None, sets: tuple[str, ...], out: Path | None, force: bool, quiet: bool,
         objective: str | None, plot: bool) -> None:
    """Plan a point-to-point maneuver through the flat outputs; write plan.parquet."""
    from flatcli import api

    with user_errors():
        s = api.load_spec(spec, overrides(sets, objective))
        target = api.output_target("plan", s, out, force)  # refused before any work
        result = api.plan(s)
        directory = result.save(target, plot=plot)
    say(quiet, result.text())
    say(quiet, f"wrote {directory}/plan.parquet" + (" and plan.png" if plot else ""))


@main.command()
@spec_options
@optimize_option
@plot_option("Also write track.png.")
def track(spec: Path | None, sets: tuple[str, ...], out: Path | None, force: bool,
          quiet: bool, objective: str | None, plot: bool) -> None:
    """Track the plan in closed loop from a perturbed initial state; write track.parquet."""
    from flatcli import api

    with user_errors():
        s = api.load_spec(spec, overrides(sets, objective))
        target = api.output_target("track", s, out, force)  # refused before any work
        result = api.track(s, quiet=quiet)
        directory = result.save(target, plot=plot)
    say(quiet, result.text())
    say(quiet, f"wrote {directory}/" + ", ".join(result.files))


@main.command()
@spec_argument()
@set_option()
def design(spec: Path | None, sets: tuple[str, ...]) -> None:
    """Check whether the paper's flat outputs apply to a design; print its coefficients.

    Exit status 0 when they apply (flatcli can plan for it), 1 when they do not.
    """
    from flatcli import api
    from flatcli.core.model import constraint_coefficients, flatness_check
    from flatcli.experiment import checked, plant_from, robot_from
    from flatcli.report import table

    with user_errors():
        s = api.load_spec(spec, sets)
        robot = robot_from(s)
        plant = plant_from(s)
    check = flatness_check(robot)
    if robot.n_joints == 2:
        k = constraint_coefficients(robot.links, checked(s.robot.model))
        rows = [[name, float(v)] for name, v in zip(k._fields, k, strict=True)]
        click.echo(f"robot {s.name!r}, {s.robot.model} coefficients [kg^2 m^2]:")
        click.echo(table(["coefficient", "value"], rows, 6))
    else:
        click.echo(chain_constants(s.name, robot))
    click.echo(design_verdict("robot", check, robot.n_joints))
    if plant != robot:
        click.echo(design_verdict("plant", flatness_check(plant), plant.n_joints))
    sys.exit(0 if check.is_flat else 1)


def chain_constants(name: str, robot: RobotParams) -> str:
    """The constants of an N-link robot's momentum: the barycentric matrix K [kg m^2] (H =
    sum_ab (K_ab cos(psi_a - psi_b) + I_a delta_ab) psi_a' psi_b') and I_N."""
    from flatcli.core.chainplan import ChainModel
    from flatcli.report import table

    model = ChainModel.of(robot)
    n = model.n_joints
    rows = [[f"K_{a}b", *model.K[a]] for a in range(n + 1)]
    head = f"robot {name!r}, {n} joints: barycentric matrix K [kg m^2] (row a, column b)"
    return "\n".join([head, table(["", *(f"b = {b}" for b in range(n + 1))], rows, 6),
                      f"K_10 = {model.K[1, 0]:.6g} kg m^2, I{n} = {model.inertia[n]:.6g} kg m^2"])


def design_verdict(what: str, check: FlatnessCheck, joints: int = 2) -> str:
    """One line: do the paper's flat outputs (or their N-link generalisation) apply, and if
    not, is the design still flat."""
    if check.is_flat and joints == 2:
        return (f"{what}: flat with the paper's outputs (d2 = 0, c0 a1 != 0); singular where "
                "sin th1 = 0 or th1' = 0")
    if check.is_flat:
        return (f"{what}: flat with the outputs y_j = th_j (j < {joints}), y{joints} = th0 + "
                f"I{joints} th{joints} / h_0(q) (d{joints} = 0, K_10 != 0); singular where "
                "dh_0/dt = 0")
    if check.unsupported:
        return f"{what}: flatcli cannot plan for it: {check.message()}"
    if check.controllable:
        return f"{what}: flat, but the paper's outputs do not apply: {check.message()}"
    return f"{what}: not flat: {check.message()}"


@main.command()
@spec_argument()
@set_option()
@workers_option("Worker processes the estimate assumes [default: one per core].")
@executor_option
@quiet_option("No compile notice.")
def check(spec: Path | None, sets: tuple[str, ...], workers: int | None, executor: str,
          quiet: bool) -> None:
    """What a sweep of SPEC would do, without doing it: the resolved spec, the cells and
    their grid values, trials, chunks, a time and memory estimate from a short calibration,
    and warnings. Writes nothing."""
    from flatcli import api

    with user_errors():
        report = api.check(spec, sets, workers=workers, executor=executor, quiet=quiet)
    click.echo(report.text())


@main.command()
@spec_argument(required=True)
@click.option("--out", type=click.Path(path_type=Path, file_okay=False),
              help="Output directory [default: runs/<name>/].")
@workers_option()
@set_option()
@quiet_option("No progress and no tables.")
@click.option("--fail-fast", is_flag=True,
              help="Stop at the first trial that raises or diverges (exit status 1).")
@force_option("Start over in a directory holding another sweep.")
@executor_option
@click.option("--scheduler", metavar="ADDRESS",
              help="Dask scheduler address (tcp://host:8786), or 'local' for a LocalCluster.")
@click.option("--rerun", "rerun", type=int, metavar="TRIAL",
              help="Re-run one finished trial alone (as flatcli track) and compare.")
@click.option("--print-spec", is_flag=True, help="With --rerun: print that trial's track spec.")
@click.option("--dry-run", is_flag=True,
              help="Show what the sweep would do (as flatcli check) and write nothing.")
@plot_option("Also write the summary figures.")
def sweep(spec: Path, out: Path | None, workers: int | None, sets: tuple[str, ...],
          quiet: bool, fail_fast: bool, force: bool, executor: str, scheduler: str | None,
          rerun: int | None, print_spec: bool, dry_run: bool, plot: bool) -> None:
    """Run a Monte Carlo sweep from a TOML spec with a [sweep] table (resumable)."""
    from flatcli import api
    from flatcli.executors import WorkerLostError
    from flatcli.spec import spec_toml
    from flatcli.sweep import FailFastError, rerun_and_compare, trial_spec

    with user_errors():
        s = api.load_spec(spec, sets)
        directory = out if out is not None else Path("runs") / s.name
        if dry_run:
            if rerun is not None or print_spec:
                fail("--dry-run: not with --rerun or --print-spec")
            click.echo(api.check(s, workers=workers, executor=executor, quiet=quiet).text())
            return
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
            done = api.sweep(s, directory, workers=workers, executor=executor,
                             scheduler=scheduler, force=force, fail_fast=fail_fast, quiet=quiet)
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
        done.plot()
    say(quiet, done.summary_text)
    say(quiet, f"{done.state.total} trials ({done.simulated} simulated now) in "
               f"{done.wall_seconds:.1f} s; wrote {directory}/trials.parquet, summary.md")


@main.command()
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@plot_option("Also write the summary figures (a finished sweep only).")
def summarize(directory: Path, plot: bool) -> None:
    """Print a sweep's summary tables again (and --plot its figures).

    Of an interrupted sweep: the tables of its finished trials, and how much is missing.
    """
    from flatcli import api

    with user_errors():
        if not (directory / "sweep.json").exists():
            summary_md = directory / "summary.md"
            if not summary_md.exists():
                fail(f"{summary_md} not found: not a sweep directory")
            click.echo(summary_md.read_text(), nl=False)
            return
        result = api.load(directory)
        assert isinstance(result, api.SweepResult)
        if plot and not result.complete:
            fail(f"--plot: {result.state.missing_text()}; the figures need every trial "
                 "(run the sweep again to finish it)")
        click.echo(result.summary_text)
        if plot:
            paths = result.plot()
            click.echo("wrote " + ", ".join(str(p) for p in paths))


@main.command()
@click.argument("directory", required=False, default=Path("runs"),
                type=click.Path(path_type=Path, file_okay=False))
@click.option("--compare", nargs=2, type=click.Path(path_type=Path, file_okay=False),
              metavar="A B", help="Show the spec keys (and key metrics) two runs differ in.")
def runs(directory: Path, compare: tuple[Path, Path] | None) -> None:
    """List the runs below DIRECTORY [default: runs]: command, name, time, status and key
    metrics (plan, track, sweep, reproduce)."""
    from flatcli.runs import RunDirectoryError, compare_runs, runs_table

    if compare:
        try:
            click.echo(compare_runs(*compare))
        except RunDirectoryError as exc:
            fail(str(exc))
        return
    if not directory.is_dir():
        fail(f"{directory}: no such directory")
    click.echo(runs_table(directory))


@main.command()
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@click.option("--csv", "as_csv", is_flag=True, help="Write CSV files (the one format so far).")
@out_option(help="Write the files here [default: beside the tables].")
def export(directory: Path, as_csv: bool, out: Path | None) -> None:
    """Write a run's or sweep's Parquet tables in another format (--csv)."""
    if not as_csv:
        fail("export: choose a format: --csv")
    from flatcli.export import export_csv

    with user_errors():
        paths = export_csv(directory, out)
    click.echo("wrote " + ", ".join(str(p) for p in paths))


@main.command()
@out_option(Path("runs/paper"), "Output directory.")
@click.option("--montecarlo", "montecarlo", type=click.Path(path_type=Path, dir_okay=False),
              help="Sweep spec of the Monte Carlo study [default: paper_montecarlo.toml, "
                   "shipped with flatcli].")
@click.option("--no-montecarlo", is_flag=True, help="Skip the Monte Carlo study.")
@workers_option("Worker processes for the study.")
@set_option("Override a key of the studies' specs (Monte Carlo, actuators), repeatable.")
@quiet_option()
def reproduce(out: Path, montecarlo: Path | None, no_montecarlo: bool, workers: int | None,
              sets: tuple[str, ...], quiet: bool) -> None:
    """The paper's figures 2-4 and numbers, and the Monte Carlo study, with REPORT.md."""
    from flatcli.reproduce import STUDY_SPEC
    from flatcli.reproduce import reproduce as run

    words = ["flatcli", "reproduce", "--out", str(out)]
    words += [] if montecarlo is None else ["--montecarlo", str(montecarlo)]
    words += ["--no-montecarlo"] if no_montecarlo else []
    words += [] if workers is None else ["--workers", str(workers)]
    words += [w for item in sets for w in ("--set", item)]
    words += ["-q"] if quiet else []
    with user_errors():
        study = None if no_montecarlo else (montecarlo or STUDY_SPEC)
        path = run(out, study, quiet, workers, sets, command=shlex.join(words))
    if not quiet:
        click.echo(path.read_text())


if __name__ == "__main__":
    main()
