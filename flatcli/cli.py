"""The ``flatcli`` command line: each command a few lines of wiring.

Every user error (a bad spec, option or file, an infeasible request) ends as one line on
stderr, ``error: ...``, with exit status 2, no traceback, and no output written. A runtime
failure (an OS error while writing, a lost worker, no memory) is one line with exit status
1; Ctrl-C and SIGTERM print the same line (exit status 128 + the signal's number). numpy's
floating-point warnings never reach the terminal: the metrics and statuses say what went
wrong. Options that several commands take are declared once, below, as decorators (as
pip-tools does).
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import click
import numpy as np

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
from flatcli.spec.limits import require_finite_plan
from flatcli.storage import run_record, write_json, write_parquet

F = TypeVar("F", bound=Callable[..., Any])

EXIT_USAGE = 2
EXIT_RUNTIME = 1
RESUME_HINT = "finished chunks are kept in {}/trials; run the same command again to resume"
#: The signal that interrupted the run (SIGINT: Ctrl-C, or SIGTERM).
_INTERRUPT = {"signal": int(signal.SIGINT)}


def fail(message: str) -> NoReturn:
    click.echo(f"error: {message}", err=True)
    sys.exit(EXIT_USAGE)


def interrupted_status() -> int:
    """The exit status of an interrupted run: 128 + the signal's number."""
    return 128 + _INTERRUPT["signal"]


def _terminate(signum: int, frame: Any) -> None:
    """SIGTERM: stop as Ctrl-C does (finished work kept, one line, no traceback)."""
    _INTERRUPT["signal"] = signum
    raise KeyboardInterrupt


def os_error_text(exc: OSError) -> str:
    """One line for an OS error: what failed, on which file, and why."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if isinstance(exc, BrokenPipeError) or exc.errno == errno.EPIPE:
        return "standard output was closed (broken pipe)"
    where = f"{exc.filename}: " if exc.filename is not None else ""
    return f"{where}{reason}".replace("\n", " ")


class _Stop(BaseException):
    """Carries a one-line error and its exit status past click's own handlers."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.message = message
        self.status = status


def _silence_stdout() -> None:
    """After stdout failed: point it at /dev/null so the interpreter's final flush is quiet."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn domain errors into one line and exit status 2."""
    try:
        yield
    except FlatcliError as exc:
        fail(str(exc))


class Cli(click.Group):
    """A group whose usage errors, OS errors and interruptions are one line too."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            raise _Stop("interrupted", interrupted_status()) from None
        except OSError as exc:
            raise _Stop(os_error_text(exc), EXIT_RUNTIME) from None
        except MemoryError:
            raise _Stop("out of memory (lower the sizes of the spec)", EXIT_RUNTIME) from None
        except Exception as exc:
            if type(exc).__module__.startswith("pyarrow"):  # a damaged or foreign data file
                first = (str(exc).splitlines() or [type(exc).__name__])[0]
                raise _Stop(f"cannot read a data file: {first}", EXIT_RUNTIME) from None
            raise

    def main(self, *args: Any, **kwargs: Any) -> Any:
        kwargs["standalone_mode"] = False
        kwargs.setdefault("prog_name", "flatcli")
        previous = None
        if threading.current_thread() is threading.main_thread():
            previous = signal.signal(signal.SIGTERM, _terminate)
        try:
            with np.errstate(all="ignore"), warnings.catch_warnings():
                if not sys.warnoptions:
                    warnings.simplefilter("ignore", RuntimeWarning)
                result = super().main(*args, **kwargs)
                if sys.stdout is not None:
                    sys.stdout.flush()
                return result
        except _Stop as stop:
            if stop.status == EXIT_RUNTIME and "broken pipe" in stop.message:
                _silence_stdout()
            click.echo(f"error: {stop.message}", err=True)
            sys.exit(stop.status)
        except OSError as exc:  # writing the last lines to stdout
            _silence_stdout()
            click.echo(f"error: {os_error_text(exc)}", err=True)
            sys.exit(EXIT_RUNTIME)
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)
        except click.exceptions.Abort:
            click.echo("error: interrupted", err=True)
            sys.exit(interrupted_status())
        except click.ClickException as exc:
            hint = ""
            ctx = getattr(exc, "ctx", None)
            if ctx is not None:
                hint = f" (see '{ctx.command_path} --help')"
            message = " ".join(exc.format_message().split())
            click.echo(f"error: {message}{hint}", err=True)
            sys.exit(exc.exit_code)
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)


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
        require_finite_plan({"theta": samples.theta, "theta_dot": samples.theta_dot,
                             "u1_dot": samples.u1_dot, "y": samples.y})
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
        require_finite_plan({"the reference": run.scenario.reference,
                             "theta": run.scenario.theta_reference})
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
@click.option("--rerun", "rerun", type=click.IntRange(0, 2**63 - 1), metavar="TRIAL",
              help="Re-run one finished trial alone (as flatcli track) and compare.")
@click.option("--print-spec", is_flag=True, help="With --rerun: print that trial's track spec.")
@click.option("--oversubscribe", is_flag=True,
              help="Allow more --workers than this machine's cores.")
@plot_option("Also write the summary figures.")
def sweep(spec: Path, out: Path | None, workers: int | None, sets: tuple[str, ...],
          quiet: bool, fail_fast: bool, force: bool, executor: str, scheduler: str | None,
          rerun: int | None, print_spec: bool, oversubscribe: bool, plot: bool) -> None:
    """Run a Monte Carlo sweep from a TOML spec with a [sweep] table (resumable)."""
    from flatcli.executors import WorkerLostError
    from flatcli.storage import check_output_dir, directory_lock
    from flatcli.sweep import FailFastError, rerun_and_compare, run_sweep, trial_spec
    from flatcli.sweep.directory import record_outputs

    with user_errors():
        s = load(spec, sets)
        directory = out_dir(s, out)
        check_output_dir(directory)
        if rerun is not None and print_spec:
            click.echo(spec_toml(trial_spec(s, directory, rerun)), nl=False)
            return
        if rerun is not None:
            if not (directory / "trials.parquet").is_file():
                fail(f"--rerun: {directory / 'trials.parquet'} not found; run the sweep first")
            with directory_lock(directory):
                result = rerun_and_compare(s, directory, rerun)
                record_outputs(directory, result.target.iterdir())
            say(quiet, result.text(s.name))
            if not result.modified and not result.reproduced:
                fail(f"--rerun: trial {rerun} did not reproduce")
            return
        if print_spec:
            fail("--print-spec: only with --rerun TRIAL")
        try:
            with directory_lock(directory):
                done = run_sweep(s, directory, executor, workers, scheduler, force, fail_fast,
                                 Progress(s.name, quiet), oversubscribe=oversubscribe)
                if plot:
                    record_outputs(directory, plot_sweep(directory))
        except FailFastError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(EXIT_RUNTIME)
        except WorkerLostError as exc:
            click.echo(f"error: {exc}; {RESUME_HINT.format(directory)}", err=True)
            sys.exit(EXIT_RUNTIME)
        except OSError as exc:
            kept = os.path.isdir(directory / "trials")
            hint = f"; {RESUME_HINT.format(directory)}" if kept else ""
            click.echo(f"error: {os_error_text(exc)}{hint}", err=True)
            sys.exit(EXIT_RUNTIME)
        except KeyboardInterrupt:
            click.echo(f"error: interrupted; {RESUME_HINT.format(directory)}", err=True)
            sys.exit(interrupted_status())
    say(quiet, done.summary_text)
    say(quiet, f"{done.layout.total} trials ({done.simulated} simulated now) in "
               f"{done.wall_seconds:.1f} s; wrote {directory}/trials.parquet, summary.md")


@main.command()
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@plot_option("Also write the summary figures.")
def summarize(directory: Path, plot: bool) -> None:
    """Print a finished sweep's summary tables again (and --plot its figures)."""
    summary_md = directory / "summary.md"
    if not summary_md.is_file():
        fail(f"{summary_md} not found: not a finished sweep directory")
    if plot:
        for name in ("summary.parquet", "trials.parquet"):
            if not (directory / name).is_file():
                fail(f"--plot: {directory / name} not found: not a finished sweep directory")
    click.echo(summary_md.read_text(encoding="utf-8", errors="replace"), nl=False)
    if plot:
        from flatcli.storage import directory_lock
        from flatcli.sweep.directory import record_outputs

        with user_errors(), directory_lock(directory):
            paths = plot_sweep(directory)
            record_outputs(directory, paths)
        click.echo("wrote " + ", ".join(str(p) for p in paths))


@main.command()
@out_option(Path("runs/paper"), "Output directory.")
@click.option("--montecarlo", "montecarlo", type=click.Path(path_type=Path),
              default=Path("configs/paper_montecarlo.toml"), show_default=True,
              help="Sweep spec of the Monte Carlo study.")
@click.option("--no-montecarlo", is_flag=True, help="Skip the Monte Carlo study.")
@workers_option("Worker processes for the study.")
@set_option("Override a key of the study's spec, repeatable.")
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
