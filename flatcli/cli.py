"""The ``flatcli`` command line: each command a thin wrapper over the Python API
(``flatcli.api``).

Every user error (a bad spec, option or file, an infeasible request) ends as one line on
stderr, ``error: ...``, with exit status 2, no traceback, and no output written. A runtime
failure (an OS error while writing, a lost worker, no memory) is one line with exit status
1; Ctrl-C and SIGTERM print the same line (exit status 128 + the signal's number). numpy's
floating-point warnings never reach the terminal: the metrics and statuses say what went
wrong. Options that several commands take are declared once, below, as decorators (as
pip-tools does).

Only click is imported up front: numpy, numba, scipy and pandas load inside the command that
needs them, so ``flatcli --help``, ``--version`` and shell completion answer at once.
"""

from __future__ import annotations

import sys

try:  # too little memory to load even these (ulimit -v): one line, not a traceback
    import contextlib
    import errno
    import os
    import shlex
    import signal
    import threading
    import warnings
    from collections.abc import Callable, Iterator
    from pathlib import Path
    from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

    import click

    from flatcli import __version__
    from flatcli.core import OWN_PROCESS_VARIABLE
    from flatcli.core.names import EXECUTORS, FIGURE_FORMATS, OBJECTIVES
    from flatcli.interrupts import last_signal, raise_interrupt
    from flatcli.startup import library_error_text, probe_libraries, while_importing
    from flatcli.threads import THREAD_VARIABLES

    # The command line is flatcli's own process: one BLAS thread (flatcli.threads), set
    # before numpy first loads; a user's own setting wins.
    for _var in THREAD_VARIABLES:
        os.environ.setdefault(_var, "1")
except (ImportError, MemoryError) as _exc:  # pragma: no cover - exercised in a subprocess
    sys.stderr.write(f"error: cannot start flatcli: {type(_exc).__name__} while loading its "
                     "modules; out of memory? (a limit such as ulimit -v, or a container's)\n")
    raise SystemExit(1) from None

if TYPE_CHECKING:  # the core loads numba: imported where a command needs it
    from flatcli.core.robots.design import DesignVerdict
    from flatcli.core.robots.params import RobotParams

F = TypeVar("F", bound=Callable[..., Any])

EXIT_USAGE = 2
EXIT_RUNTIME = 1
#: How an OS error on the standard output names its "file".
STDOUT = "standard output"
#: ``flatcli design``'s exit status per verdict of ``core.robots.design.VERDICTS`` (bad input
#: is EXIT_USAGE, 2): 0 closed-form outputs, 1 flat without them, 3 not flat.
DESIGN_EXIT = {"closed_form": 0, "flat": 1, "not_flat": 3}
RESUME_HINT = "finished chunks are kept in {}/trials; run the same command again to resume"


def fail(message: str) -> NoReturn:
    click.echo(f"error: {message}", err=True)
    sys.exit(EXIT_USAGE)


def interrupted_status() -> int:
    """The exit status of an interrupted run: 128 + the signal's number."""
    return 128 + last_signal()


def os_error_text(exc: OSError) -> str:
    """One line for an OS error: what failed, on which file, and why."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if isinstance(exc, BrokenPipeError) or exc.errno == errno.EPIPE:
        return "standard output was closed (broken pipe)"
    if exc.filename == STDOUT and exc.errno == errno.EBADF:
        return "standard output is closed: nothing could be printed (redirect it, e.g. > /dev/null)"
    where = f"{exc.filename}: " if exc.filename is not None else ""
    return f"{where}{reason}".replace("\n", " ")


class _Stop(BaseException):
    """Carries a one-line error and its exit status past click's own handlers."""

    def __init__(self, message: str, status: int, hard: bool = False) -> None:
        super().__init__(message)
        self.message = message
        self.status = status
        self.hard = hard  # exit at once: a half-loaded library may crash the interpreter's exit


def _silence_stdout() -> None:
    """After stdout failed: point it at /dev/null so the interpreter's final flush is quiet."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn domain errors into one line and exit status 2; numpy's floating-point errors
    are silent inside (the metrics and statuses say what went wrong)."""
    import numpy as np

    from flatcli.core.errors import FlatcliError

    try:
        with np.errstate(all="ignore"):
            yield
    except FlatcliError as exc:
        fail(str(exc))


class Cli(click.Group):
    """A group whose usage errors, OS errors and interruptions are one line too."""

    def invoke(self, ctx: click.Context) -> Any:
        problem = probe_libraries()
        if problem is not None:
            raise _Stop(problem, EXIT_RUNTIME)
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            raise _Stop("interrupted", interrupted_status()) from None
        except ImportError as exc:
            raise _Stop(library_error_text(exc), EXIT_RUNTIME, hard=True) from None
        except (OSError, MemoryError) as exc:
            if while_importing(exc):
                raise _Stop(library_error_text(exc), EXIT_RUNTIME, hard=True) from None
            if isinstance(exc, MemoryError):
                raise _Stop("out of memory (lower the sizes of the spec)", EXIT_RUNTIME) from None
            raise _Stop(os_error_text(exc), EXIT_RUNTIME) from None
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
            previous = signal.signal(signal.SIGTERM, raise_interrupt)  # as Ctrl-C
        try:
            with warnings.catch_warnings():  # numpy's errstate: ``user_errors``
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
            if stop.hard:
                with contextlib.suppress(OSError, ValueError, AttributeError):
                    sys.stderr.flush()
                os._exit(stop.status)
            executors = sys.modules.get("flatcli.executors")  # an aborted pool's stuck thread
            if executors is not None:
                executors.leave(stop.status)
            sys.exit(stop.status)
        except OSError as exc:  # writing the last lines to stdout
            _silence_stdout()
            if exc.filename is None:
                exc.filename = STDOUT
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


def run() -> NoReturn:
    """The ``flatcli`` program (its console script, ``python -m flatcli``): the command, then
    the end of the process without the interpreter's teardown.

    A command has closed, flushed and renamed everything it writes before it returns; what
    the interpreter would still do is wait for threads, run the ``atexit`` handlers (of
    multiprocessing, dask, logging) and then free every module and object, which with numba's
    compiler and a kernel loaded takes 0.3-0.4 s of each command here (``benchmarks.run``'s
    start-up figures). The first two are done here as the interpreter does them; the third
    is skipped (``os._exit``). A bug's traceback ends the process the usual way, and so does
    every command under a profiler or a tracer (``python -m cProfile``, coverage), which
    write their files at the teardown.
    """
    # the program is flatcli's own process, and so are the processes it starts: numba tuned
    # for its kernels (flatcli.core._jit.own_process) when the core is first imported
    os.environ[OWN_PROCESS_VARIABLE] = "1"
    try:
        main.main()
        status = 0
    except SystemExit as exc:
        status = exit_status(exc.code)
    if sys.getprofile() is not None or sys.gettrace() is not None:
        sys.exit(status)
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    import atexit

    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            stream.flush()
    os._exit(status)


def exit_status(code: object) -> int:
    """The exit status ``SystemExit(code)`` gives, as the interpreter computes it (a message
    is printed on stderr and gives 1)."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code & 0xFF  # as the system truncates it
    with contextlib.suppress(OSError, ValueError, AttributeError):
        sys.stderr.write(f"{code}\n")
    return 1


# ---------------------------------------------------------------------------------------
# Options shared by several commands, each declared once, and listed by every command in one
# order (``OPTION_ORDER``; tests/test_cli.py checks it).

#: The order shared options take in every command's --help (by their parameter names).
OPTION_ORDER = ("robot", "sets", "name", "tags", "objective", "out", "force", "plot", "fmt",
                "dpi", "x", "hue", "cfg", "workers", "oversubscribe", "executor", "scheduler",
                "quiet")
#: The one meaning of -q in every command.
QUIET_HELP = "Print nothing but errors (the exit status says how it went)."


class TrialId(click.ParamType[int, Any]):
    """A sweep trial's id: an integer from 0 (``trial = key * 1e9 + i``), without click's
    range text in --help."""

    name = "TRIAL"

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> int:
        try:
            number = int(value)
        except (TypeError, ValueError):
            self.fail(f"expected a trial id (an integer >= 0), got {value!r}", param, ctx)
        if not 0 <= number <= 2**63 - 1:
            self.fail(f"expected a trial id (an integer from 0 to 2^63 - 1), got {value!r}",
                      param, ctx)
        return number


def spec_argument(required: bool = False) -> Callable[[F], F]:
    return click.argument("spec", required=required, type=click.Path(path_type=Path))


def robot_option(fn: F) -> F:
    from flatcli.completion import complete_robot

    return click.option(
        "--robot", metavar="NAME|FILE", shell_complete=complete_robot,
        help="The robot: a shipped robot file (chain4, chain6, paper), your own FILE.toml, or "
             "a URDF (FILE.urdf: a planar chain, its root link the free base), under the "
             "spec's own keys (shorthand for --set robot=...).")(fn)


def set_option(help: str = "Override a spec key (dotted; VALUE in TOML), or remove one with "
                             "~KEY (it takes its default again), repeatable."
               ) -> Callable[[F], F]:
    from flatcli.completion import complete_set

    return click.option("--set", "sets", multiple=True, metavar="KEY=VALUE", help=help,
                        shell_complete=complete_set)


def name_option(fn: F) -> F:
    return click.option("--name", metavar="NAME",
                        help="Name the run (shorthand for --set name=NAME): its directory is "
                             "runs/<name>/.")(fn)


def tag_option(fn: F) -> F:
    return click.option("--tag", "tags", multiple=True, metavar="TAG",
                        help="Label the run, repeatable (flatcli runs --filter tag=TAG).")(fn)


def out_option(default: Path | None = None,
               help: str = "Output directory [default: a new runs/<name>/<time>-<id>/, "
                           "linked as runs/<name>/latest].") -> Callable[[F], F]:
    return click.option("--out", type=click.Path(path_type=Path, file_okay=False),
                        default=default, show_default=default is not None, help=help)


def quiet_option(fn: F) -> F:
    return click.option("-q", "--quiet", is_flag=True, help=QUIET_HELP)(fn)


def workers_option(help: str = "Worker processes [default: one per core].") -> Callable[[F], F]:
    return click.option("--workers", type=int, help=help)


def plot_option(help: str) -> Callable[[F], F]:
    return click.option("--plot", is_flag=True, help=help)


def force_option(help: str) -> Callable[[F], F]:
    return click.option("--force", is_flag=True, help=help)


def figure_options(fn: F) -> F:
    """--format and --dpi: how figures are written (``[figures]``)."""
    fn = click.option("--dpi", type=int, metavar="N",
                      help="Resolution of raster figures, 50 to 1200 dots per inch "
                           "(figures.dpi) [default: 150].")(fn)
    return click.option("--format", "fmt", type=click.Choice(list(FIGURE_FORMATS)),
                        help="File format of the figures: png, or pdf and svg for print "
                             "(figures.format) [default: png].")(fn)


def cfg_option(fn: F) -> F:
    return click.option("--cfg", is_flag=True,
                        help="Print the resolved spec (TOML: robot file, includes and --set "
                             "applied) and exit; nothing is computed or written.")(fn)


def executor_option(fn: F) -> F:
    return click.option(
        "--executor", type=click.Choice(list(EXECUTORS)), default=EXECUTORS[0],
        show_default=True, help="Run chunks on this machine or on a Dask cluster.")(fn)


def optimize_option(fn: F) -> F:
    return click.option(
        "--optimize", "objective", type=click.Choice(list(OBJECTIVES)),
        help="Optimise the plan (shorthand for --set plan.optimize.objective=...).",
    )(fn)


def spec_overrides(sets: tuple[str, ...], *, robot: str | None = None,
                   name: str | None = None, objective: str | None = None,
                   fmt: str | None = None, dpi: int | None = None) -> dict[str, Any]:
    """The overrides of a command line: its ``--set`` items in order, then the options that
    are shorthands for one (``--robot``, ``--name``, ``--optimize``, ``--format``, ``--dpi``).
    SpecError (one line) for a bad one."""
    from flatcli.spec import parse_set

    out = parse_set(sets)
    for key, value in (("robot", robot), ("name", name),
                       ("plan.optimize.objective", objective), ("figures.format", fmt)):
        if value is not None:
            out[key] = value
    if dpi is not None:
        out["figures.dpi"] = checked_dpi(dpi)
    return out


def checked_dpi(dpi: int) -> int:
    """``--dpi`` checked as ``figures.dpi`` is (SpecError naming --dpi)."""
    from flatcli.spec import lookup

    return int(lookup("figures.dpi").check("--dpi", dpi))


def show(text: str, nl: bool = True) -> None:
    """Print a command's report on standard output. A closed standard output (``>&-``: Python
    then has none) or a failing one (a full disk, ``/dev/full``) is an OS error naming it:
    one line on stderr, exit status 1 (a closed pipe: ``os_error_text``)."""
    if sys.stdout is None:
        raise OSError(errno.EBADF, "closed", STDOUT)
    try:
        click.echo(text, nl=nl)
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), STDOUT) from None


def require_stdout(quiet: bool = False) -> None:
    """Before a command's work: its report could not be printed (standard output closed),
    so refuse now (exit status 1) rather than after the work."""
    if not quiet and sys.stdout is None:
        raise OSError(errno.EBADF, "closed", STDOUT)


def say(quiet: bool, text: str) -> None:
    if not quiet:
        show(text)


# ---------------------------------------------------------------------------------------
# Commands.

def print_citation(ctx: click.Context, param: click.Parameter, value: bool) -> None:
    """``--cite``: what to cite (CITATION.cff), printed at once like --version."""
    if not value or ctx.resilient_parsing:
        return
    from flatcli.citation import citation_text

    show(citation_text(), nl=False)
    ctx.exit()


@click.group(cls=Cli)
@click.version_option(__version__, prog_name="flatcli")
@click.option("--cite", is_flag=True, expose_value=False, is_eager=True,
              callback=print_citation,
              help="Print how to cite flatcli and the paper it reproduces, and exit.")
def main() -> None:
    """Flatness-based planning, feedback control and Monte Carlo studies of planar
    free-floating space robots (Franch, Agrawal, Oh, Fattah, IROS 2003).

    With no SPEC file a command runs the paper's example.
    """


def run_options(fn: F) -> F:
    """The options of ``plan`` and ``track``, in ``OPTION_ORDER``."""
    for decorator in reversed((
            spec_argument(), robot_option, set_option(), name_option, tag_option,
            optimize_option, out_option(), force_option(
                "Write into an --out directory that holds another run (its files are "
                "replaced)."),
            plot_option("Also draw the figure (plan.png, track.png; --format)."),
            figure_options, cfg_option, quiet_option)):
        fn = decorator(fn)
    return fn


def run_one(command: str, spec: Path | None, robot: str | None, sets: tuple[str, ...],
            name: str | None, tags: tuple[str, ...], objective: str | None, out: Path | None,
            force: bool, plot: bool, fmt: str | None, dpi: int | None, cfg: bool,
            quiet: bool, animate: bool = False) -> None:
    """``flatcli plan`` and ``flatcli track``: everything checked before any work (the spec,
    the tags, ``--out``), then the run, then its files."""
    from flatcli import api
    from flatcli.rundirs import check_tags
    from flatcli.spec import spec_toml

    require_stdout(quiet and not cfg)
    with user_errors():
        s = api.load_spec(spec, spec_overrides(sets, robot=robot, name=name,
                                               objective=objective, fmt=fmt, dpi=dpi))
        if cfg:
            show(spec_toml(s), nl=False)
            return
        chosen = check_tags(tags)
        with api.output_lock(out):  # one writer from the check to the last file
            target = api.output_target(command, s, out, force)  # refused before any work
            note = api.duration_note(s, command)
            if note is not None and not quiet:
                click.echo(note, err=True)
            result: api.PlanResult | api.TrackResult = (
                api.plan(s, quiet=quiet) if command == "plan" else api.track(s, quiet=quiet))
            if not quiet:
                for warning in result.warnings:
                    click.echo(warning, err=True)
            result.tags = chosen
            directory = result.save(target, plot=plot)
            if animate and isinstance(result, api.PlanResult):
                result.animate(directory / "plan.gif")
                result.files.append("plan.gif")
    say(quiet, result.text())
    say(quiet, f"wrote {directory}/" + ", ".join(result.files))


@main.command(short_help="Plan a maneuver through the flat outputs.")
@run_options
@click.option("--animate", is_flag=True,
              help="Also write the maneuver as plan.gif (the links, obstacles and the end "
                   "effector's path; matplotlib's Pillow writer).")
def plan(spec: Path | None, robot: str | None, sets: tuple[str, ...], name: str | None,
         tags: tuple[str, ...], objective: str | None, out: Path | None, force: bool,
         plot: bool, fmt: str | None, dpi: int | None, cfg: bool, quiet: bool,
         animate: bool) -> None:
    """Plan a point-to-point maneuver through the flat outputs; write plan.parquet and
    run.json (and with --plot the figure, with a [task] its filmstrip; --animate a GIF)."""
    run_one("plan", spec, robot, sets, name, tags, objective, out, force, plot, fmt, dpi, cfg,
            quiet, animate)


@main.command(short_help="Plan, then track the plan in closed loop.")
@run_options
def track(spec: Path | None, robot: str | None, sets: tuple[str, ...], name: str | None,
          tags: tuple[str, ...], objective: str | None, out: Path | None, force: bool,
          plot: bool, fmt: str | None, dpi: int | None, cfg: bool, quiet: bool) -> None:
    """Track the plan in closed loop from a perturbed initial state; write track.parquet,
    metrics.json and run.json (and with --plot the figure)."""
    run_one("track", spec, robot, sets, name, tags, objective, out, force, plot, fmt, dpi,
            cfg, quiet)


@main.command(short_help="Map where the end effector can be put (N = 2).")
@spec_argument()
@robot_option
@set_option()
@name_option
@tag_option
@click.option("--attitude", nargs=2, type=float, metavar="LO HI",
              help="Window of the final base attitude th0(T) [rad] [default: task.base_attitude "
                   "if set, else free: th0(0) +- pi].")
@click.option("--attitudes", type=int, default=181, show_default=True, metavar="K",
              help="Attitudes sampled over the window (both ends included).")
@click.option("--points", type=int, default=201, show_default=True, metavar="N",
              help="Targets per axis of the square grid (2 to 1001).")
@click.option("--extent", type=float, metavar="M",
              help="Half width of the grid [m] [default: 5 % beyond the arm's reach].")
@click.option("--thin", type=float, default=0.1, show_default=True, metavar="S",
              help="Mark targets whose best |sin th1| is under S (near the flat map's "
                   "singular set).")
@out_option()
@force_option("Write into an --out directory that holds another run (its files are replaced).")
@figure_options
@quiet_option
def workspace(spec: Path | None, robot: str | None, sets: tuple[str, ...], name: str | None,
              tags: tuple[str, ...], attitude: tuple[float, float] | None, attitudes: int,
              points: int, extent: float | None, thin: float, out: Path | None, force: bool,
              fmt: str | None, dpi: int | None, quiet: bool) -> None:
    """Map, for an N = 2 robot starting at plan.start, where its end effector can be put at
    the end of a maneuver: each target of a grid by the elbow branches that reach it with th1
    on the start's side of sin th1 = 0, for final base attitudes in a window, and how far from
    that singular set (|sin th1|). Writes workspace.parquet, run.json and the figure
    (workspace.png, or --format)."""
    from flatcli import api
    from flatcli.rundirs import check_tags

    require_stdout(quiet)
    with user_errors():
        s = api.load_spec(spec, spec_overrides(sets, robot=robot, name=name, fmt=fmt, dpi=dpi))
        chosen = check_tags(tags)
        with api.output_lock(out):
            target = api.output_target("workspace", s, out, force)  # refused before any work
            result = api.workspace(s, attitude=attitude, attitudes=attitudes, points=points,
                                   extent=extent, thin=thin)
            result.tags = chosen
            directory = result.save(target)
    say(quiet, result.text())
    say(quiet, f"wrote {directory}/" + ", ".join(result.files))


@main.command(short_help="Is the design flat? Its verdict and reasons.")
@spec_argument()
@robot_option
@set_option()
@click.option("--counterweight", is_flag=True,
              help="Design the last link's counterweight instead: the spec's last link is "
                   "the bare link; needs --positions.")
@click.option("--positions", nargs=4, type=float, metavar="X1 Y1 X2 Y2",
              help="--counterweight: the segment of allowed positions in the last link's "
                   "frame [m] (x along the link from its joint, y across).")
@click.option("--counterweight-inertia", "own_inertia", type=float, default=0.0,
              show_default=True, help="--counterweight: its inertia about its own centre "
                                      "[kg m^2].")
def design(spec: Path | None, robot: str | None, sets: tuple[str, ...], counterweight: bool,
           positions: tuple[float, float, float, float] | None, own_inertia: float) -> None:
    """Is the design flat, and do the closed-form flat outputs apply? Prints its constraint
    coefficients (N = 2) or barycentric matrix (N >= 3) and the verdict with its reasons.

    Exit status (the robot's verdict): 0 closed_form (flatcli plans it), 1 flat (outputs not
    known in closed form), 3 not_flat (the constraint integrates), 2 bad input. With
    --counterweight: the least-mass and least-inertia counterweights that put the last link's
    centre of mass on its joint, each design's verdict and plan energy (exit status 0).
    """
    from flatcli import api
    from flatcli.core.robots.design import design_verdict
    from flatcli.core.robots.params import constraint_coefficients
    from flatcli.experiment import checked, plant_from, robot_from
    from flatcli.report import table

    if counterweight or positions is not None:
        if not counterweight or positions is None:
            fail("--counterweight and --positions X1 Y1 X2 Y2 go together")
        from flatcli.designer import counterweight_options, counterweight_text

        segment = [positions[:2], positions[2:]]
        with user_errors():
            s = api.load_spec(spec, spec_overrides(sets, robot=robot))
            options = counterweight_options(s, segment, own_inertia)
        show(counterweight_text(s, segment, options))
        return
    with user_errors():
        s = api.load_spec(spec, spec_overrides(sets, robot=robot))
        nominal = robot_from(s)
        plant = plant_from(s)
    if nominal.n_joints == 2:
        k = constraint_coefficients(nominal.links, checked(s.robot.model))
        rows = [[name, float(v)] for name, v in zip(k._fields, k, strict=True)]
        show(f"robot {s.name!r}, {s.robot.model} coefficients [kg^2 m^2]:")
        show(table(["coefficient", "value"], rows, 6))
    else:
        show(chain_constants(s.name, nominal))
    verdict = design_verdict(nominal)
    show(verdict_lines("robot", verdict))
    if plant != nominal:
        show(verdict_lines("plant", design_verdict(plant)))
    sys.exit(DESIGN_EXIT[verdict.verdict])


def chain_constants(name: str, robot: RobotParams) -> str:
    """The constants of an N-link robot's momentum: the barycentric matrix K [kg m^2] (H =
    sum_ab (K_ab cos(psi_a - psi_b) + I_a delta_ab) psi_a' psi_b') and I_N."""
    from flatcli.core.models.flatmodel import ChainModel
    from flatcli.report import table

    model = ChainModel.of(robot)
    n = model.n_joints
    rows = [[f"K_{a}b", *model.K[a]] for a in range(n + 1)]
    head = f"robot {name!r}, {n} joints: barycentric matrix K [kg m^2] (row a, column b)"
    return "\n".join([head, table(["", *(f"b = {b}" for b in range(n + 1))], rows, 6),
                      f"K_10 = {model.K[1, 0]:.6g} kg m^2, I{n} = {model.inertia[n]:.6g} kg m^2"])


def verdict_lines(what: str, verdict: DesignVerdict) -> str:
    """``what: <verdict>: <headline>``, then one indented line per reason and the numbers of
    the K_10 test."""
    lines = [f"{what}: {verdict.verdict}: {verdict.headline}"]
    lines += [f"  {what}: {reason}" for reason in verdict.reasons]
    lines.append(f"  {what}: {verdict.numbers()}")
    return "\n".join(lines)


@main.command(short_help="What a sweep of SPEC would do (a dry run).")
@spec_argument()
@robot_option
@set_option()
@workers_option("Worker processes the estimate assumes [default: one per core].")
@executor_option
@quiet_option
def check(spec: Path | None, robot: str | None, sets: tuple[str, ...], workers: int | None,
          executor: str, quiet: bool) -> None:
    """What a sweep of SPEC would do, without doing it: the resolved spec, the cells and
    their grid values, trials, chunks, a time and memory estimate from a short calibration,
    and warnings; for a spec with a [search] table, what its design search would do and
    cost. Writes nothing; with -q only the exit status says whether SPEC is valid."""
    from flatcli import api

    require_stdout(quiet)

    with user_errors():
        report = api.check(spec, spec_overrides(sets, robot=robot), workers=workers,
                           executor=executor, quiet=quiet)
    say(quiet, report.text())


@main.command(short_help="Run a Monte Carlo sweep (resumable).")
@spec_argument(required=True)
@robot_option
@set_option()
@name_option
@tag_option
@out_option(help="Output directory [default: runs/<name>/sweep/].")
@force_option("Start over in a directory holding another sweep.")
@plot_option("Also write the summary figures (sweep_*.png; --format).")
@figure_options
@workers_option()
@click.option("--oversubscribe", is_flag=True,
              help="Allow more --workers than this machine's cores.")
@executor_option
@click.option("--scheduler", metavar="ADDRESS",
              help="Dask scheduler address (tcp://host:8786), 'local' for a LocalCluster, or "
                   "'slurm' to start workers as SLURM jobs (dask-jobqueue).")
@click.option("--shard", metavar="K/N",
              help="Compute shard K of N of the study (machines or array jobs sharing --out); "
                   "the last shard to finish writes the final tables.")
@click.option("--fail-fast", is_flag=True,
              help="Stop at the first trial that raises or diverges (exit status 1).")
@click.option("--rerun", "rerun", type=TrialId(),
              help="Re-run one finished trial alone (as flatcli track) and compare "
                   "(flatcli rerun DIR TRIAL needs no SPEC).")
@click.option("--print-spec", is_flag=True, help="With --rerun: print that trial's track spec.")
@click.option("--dry-run", is_flag=True,
              help="Show what the sweep would do (as flatcli check) and write nothing.")
@quiet_option
def sweep(spec: Path, robot: str | None, sets: tuple[str, ...], name: str | None,
          tags: tuple[str, ...], out: Path | None, force: bool, plot: bool, fmt: str | None,
          dpi: int | None, workers: int | None, oversubscribe: bool, executor: str,
          scheduler: str | None, shard: str | None, fail_fast: bool, rerun: int | None,
          print_spec: bool, dry_run: bool, quiet: bool) -> None:
    """Run a Monte Carlo sweep from a TOML spec with a [sweep] table, into
    runs/<name>/sweep/ (or --out); running the same command again resumes it."""
    require_stdout(quiet)
    from flatcli import api
    from flatcli.executors import WorkerLostError, leave
    from flatcli.montecarlo import FailFastError
    from flatcli.rundirs import check_tags, sweep_directory
    from flatcli.storage import check_output_dir, directory_lock

    with user_errors():
        s = api.load_spec(spec, spec_overrides(sets, robot=robot, name=name, fmt=fmt,
                                               dpi=dpi))
        directory = out if out is not None else sweep_directory(s.name)
        if shard is not None and (rerun is not None or dry_run):
            fail("--shard: not with --rerun or --dry-run")
        if dry_run:
            if rerun is not None or print_spec:
                fail("--dry-run: not with --rerun or --print-spec")
            say(quiet, api.check(s, workers=workers, executor=executor, quiet=quiet,
                                 what="sweep").text())
            return
        if print_spec and rerun is None:
            fail("--print-spec: only with --rerun TRIAL")
        if rerun is not None:
            rerun_trial(s, directory, rerun, print_spec, quiet)
            return
        chosen = check_tags(tags)
        check_output_dir(directory)
        try:
            # (a shard takes the directory's lock itself: with the other shards, then alone)
            with directory_lock(directory) if shard is None else contextlib.nullcontext():
                done = api.sweep(s, directory, workers=workers, executor=executor,
                                 scheduler=scheduler, force=force, fail_fast=fail_fast,
                                 quiet=quiet, oversubscribe=oversubscribe, tags=chosen,
                                 shard=shard)
                if plot and done.complete:
                    done.save_figures()
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
            leave(interrupted_status())
    if not done.complete:  # a shard whose study is not whole yet
        say(quiet, shard_text(shard or "", done, directory))
        return
    say(quiet, done.headline_text)
    say(quiet, f"{done.state.total} trials ({done.simulated} simulated now) in "
               f"{done.wall_seconds:.1f} s; wrote {directory}/trials.parquet, summary.md")


#: What a search interrupted or failed says: where its work is and how to go on.
SEARCH_HINT = ("the evaluated candidates are kept in {}/journal.jsonl; run the same command "
               "again to resume")


@main.command(short_help="Search the robot's design against a Monte Carlo study.")
@spec_argument(required=True)
@robot_option
@set_option()
@name_option
@out_option(help="Output directory [default: runs/<name>/search/].")
@force_option("Start over in a directory holding another search.")
@figure_options
@workers_option()
@click.option("--oversubscribe", is_flag=True,
              help="Allow more --workers than this machine's cores.")
@executor_option
@click.option("--scheduler", metavar="ADDRESS",
              help="Dask scheduler address (tcp://host:8786), or 'local' for a LocalCluster.")
@click.option("--dry-run", is_flag=True,
              help="Show what the search would do and cost (as flatcli check) and write "
                   "nothing.")
@quiet_option
def search(spec: Path, robot: str | None, sets: tuple[str, ...], name: str | None,
           out: Path | None, force: bool, fmt: str | None, dpi: int | None,
           workers: int | None, oversubscribe: bool, executor: str, scheduler: str | None,
           dry_run: bool, quiet: bool) -> None:
    """Search the design variables of SPEC's [search] table (masses, inertias, lengths,
    centres, a counterweight) for the design whose Monte Carlo study ([sweep], the same draws
    for every candidate) goes best, into runs/<name>/search/ (or --out): search.parquet, the
    convergence figure, best_robot.toml and .urdf. Running the same command again resumes it
    (docs/search.md)."""
    require_stdout(quiet)
    from flatcli import api
    from flatcli.executors import WorkerLostError, leave

    with user_errors():
        s = api.load_spec(spec, spec_overrides(sets, robot=robot, name=name, fmt=fmt, dpi=dpi))
        if dry_run:
            say(quiet, api.check(s, workers=workers, executor=executor, quiet=quiet,
                                 what="search").text())
            return
        directory = out if out is not None else Path("runs") / s.name / "search"
        try:
            done = api.search(s, directory, workers=workers, executor=executor,
                              scheduler=scheduler, force=force, quiet=quiet,
                              oversubscribe=oversubscribe,
                              command=shlex.join(["flatcli", *sys.argv[1:]]))
        except WorkerLostError as exc:
            click.echo(f"error: {exc}; {SEARCH_HINT.format(directory)}", err=True)
            sys.exit(EXIT_RUNTIME)
        except OSError as exc:
            click.echo(f"error: {os_error_text(exc)}; {SEARCH_HINT.format(directory)}",
                       err=True)
            sys.exit(EXIT_RUNTIME)
        except KeyboardInterrupt:
            click.echo(f"error: interrupted; {SEARCH_HINT.format(directory)}", err=True)
            leave(interrupted_status())
    say(quiet, done.summary_text)
    say(quiet, f"wrote {directory}/search.parquet, summary.md, best_robot.toml, "
               "best_robot.urdf")
def shard_text(shard: str, done: Any, directory: Path) -> str:
    """What a shard that did not write the study's final tables says of it."""
    state, outcome = done.state, done.outcome
    head = (f"shard {shard}: its chunks are done ({done.simulated} trials simulated now, in "
            f"{done.wall_seconds:.1f} s); the study has {state.done} of {state.total} trials")
    if outcome is not None and outcome.running:
        return (f"{head}; other shards are still running: the last one to finish writes "
                f"{directory}/trials.parquet")
    return (f"{head} and no other shard is running: run the missing shards again (the same "
            "command resumes a shard), or the sweep without --shard")


def rerun_trial(s: Any, directory: Path, trial: int, print_spec: bool, quiet: bool) -> None:
    """``sweep --rerun`` and ``rerun``: one finished trial of the sweep ``s`` in ``directory``
    re-run alone (``rerun-TRIAL/``) and compared with its row (exit status 2 if it does not
    reproduce), or with ``print_spec`` its track spec printed."""
    from flatcli.montecarlo import rerun_and_compare, trial_spec
    from flatcli.montecarlo.directory import record_outputs
    from flatcli.montecarlo.rerun import trials_table
    from flatcli.spec import spec_toml
    from flatcli.storage import check_output_dir, directory_lock

    check_output_dir(directory)
    if print_spec:
        show(spec_toml(trial_spec(s, directory, trial)), nl=False)
        return
    trials_table(directory)  # there, and a regular file
    with directory_lock(directory):
        result = rerun_and_compare(s, directory, trial)
        record_outputs(directory, result.target.iterdir())
    say(quiet, result.text(s.name))
    if not result.modified and not result.reproduced:
        fail(f"--rerun: trial {trial} did not reproduce")


@main.command(short_help="Re-run one trial of a sweep alone, and compare.")
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@click.argument("trial", type=TrialId())
@click.option("--print-spec", is_flag=True, help="Print the trial's track spec and exit.")
@figure_options
@quiet_option
def rerun(directory: Path, trial: int, print_spec: bool, fmt: str | None, dpi: int | None,
          quiet: bool) -> None:
    """Re-run trial TRIAL of the sweep in DIRECTORY alone, as flatcli track, from the spec the
    sweep recorded (no SPEC to pass again), into DIRECTORY/rerun-TRIAL/, and check that every
    metric reproduces (exit status 2 if not)."""
    require_stdout(quiet)
    from flatcli import api

    with user_errors():
        found = api.load(api.sweep_dir_of(directory))
        if not isinstance(found, api.SweepResult):
            fail(f"{directory}: holds a {found.command or 'run'}, not a sweep")
        s = found.spec.with_overrides(spec_overrides((), fmt=fmt, dpi=dpi)) if (
            fmt is not None or dpi is not None) else found.spec
        rerun_trial(s, found.state.directory, trial, print_spec, quiet)


@main.command(short_help="A sweep's summary again; --full its tables, --plot its figures.")
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@click.option("--full", is_flag=True,
              help="Print every table of summary.md, not the one-screen headline.")
@plot_option("Also write the summary figures (a finished sweep only).")
@figure_options
@click.option("--x", "x", metavar="KEY",
              help="With --plot: the grid key sweep_singular's x axis shows, or `outcome` "
                   "(each cell split by its trials' outcome) [default: the perturbation "
                   "size, or the first numeric grid key].")
@click.option("--hue", "hue", metavar="KEY",
              help="With --plot: the grid key whose values get a colour each (the other grid "
                   "keys a line style), or `outcome`.")
@quiet_option
def summarize(directory: Path, full: bool, plot: bool, fmt: str | None, dpi: int | None,
              x: str | None, hue: str | None, quiet: bool) -> None:
    """Print a sweep's summary again: one screen (per cell its grid values, trials by status,
    median final error; the error reasons; where the full tables are), or with --full every
    table of summary.md; --plot writes its figures, against any grid key with --x, --hue.

    Of an interrupted sweep: the finished trials, and how much is missing.
    DIRECTORY may be a sweep's or its name's (runs/<name>, whose sweep/ it reads).
    """
    from flatcli import api
    from flatcli.files import is_regular, kind, read_text
    from flatcli.report import FigureFile
    from flatcli.report.sweep_figures import check_axes

    require_stdout(quiet)
    with user_errors():
        if not plot and (fmt is not None or dpi is not None or x is not None or hue is not None):
            fail("--format, --dpi, --x, --hue: only with --plot")
        directory = api.sweep_dir_of(directory)
        dpi = None if dpi is None else checked_dpi(dpi)
        if kind(directory / "sweep.json") == "missing":
            summary_md = directory / "summary.md"
            if not is_regular(summary_md):
                what = kind(summary_md)
                fail(f"{summary_md} not found: not a sweep directory" if what == "missing" else
                     f"{summary_md} is {what}, not flatcli's summary")
            if plot:  # a sweep directory without its manifest: its final tables
                for name in ("summary.parquet", "trials.parquet"):
                    if not is_regular(directory / name):
                        fail(f"--plot: {directory / name} not found: not a finished sweep "
                             "directory")
                check_axes(directory, x, hue)  # before anything is printed
            say(quiet, read_text(summary_md).rstrip("\n"))
            if plot:
                from flatcli.report import plot_sweep
                from flatcli.storage import directory_lock

                file = FigureFile(fmt or "png", dpi or FigureFile().dpi)
                with directory_lock(directory):
                    paths = plot_sweep(directory, file, x=x, hue=hue)
                say(quiet, "wrote " + ", ".join(str(p) for p in paths))
            return
        result = api.load(directory)
        assert isinstance(result, api.SweepResult)
        if plot and not result.complete:
            fail(f"--plot: {result.state.missing_text()}; the figures need every trial "
                 "(run the sweep again to finish it)")
        if plot:
            check_axes(directory, x, hue)  # before anything is printed
        say(quiet, result.summary_text if full else result.headline_text)
        if plot:
            paths = result.save_figures(fmt=fmt, dpi=dpi, x=x, hue=hue)
            say(quiet, "wrote " + ", ".join(str(p) for p in paths))


@main.command(short_help="List, filter, sort and compare runs.")
@click.argument("directories", nargs=-1, type=click.Path(path_type=Path, file_okay=False))
@click.option("--filter", "filters", multiple=True, metavar="KEY[OP]VALUE",
              help="Only runs where KEY OP VALUE holds, repeatable (all must hold): OP is one "
                   "of = != < <= > >= ~ (contains); KEY a field (command, name, status, "
                   "time, tag), a metric (err_y_final) or a spec key (plant.model).")
@click.option("--sort", "sort", metavar="KEY", help="Order the runs by KEY (runs without it "
                                                    "last) [default: time].")
@click.option("--reverse", is_flag=True, help="With --sort: largest first.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the runs as JSON: every metric and the resolved spec of each.")
@click.option("--compare", is_flag=True,
              help="Compare the runs given (two or more): the spec keys they differ in, their "
                   "key metrics side by side.")
def runs(directories: tuple[Path, ...], filters: tuple[str, ...], sort: str | None,
         reverse: bool, as_json: bool, compare: bool) -> None:
    """List the runs below DIRECTORIES [default: runs]: command, name, time, status, tags and
    key metrics (plan, track, sweep, reproduce), in a table as wide as the terminal.

    With --compare, DIRECTORIES are the runs to compare (runs/<name>: its latest run).
    """
    import shutil

    from flatcli.catalog import Filter, compare_runs, rows_below, runs_json, runs_table, select
    from flatcli.rundirs import RunDirectoryError

    with user_errors():
        if compare:
            if filters or sort or as_json:
                fail("--compare: not with --filter, --sort or --json")
            try:
                show(compare_runs(*directories))
            except RunDirectoryError as exc:
                fail(str(exc))
            return
        chosen = [Filter.parse(f) for f in filters]
        roots = list(directories) or [Path("runs")]
        for root in roots:
            if not root.is_dir():
                fail(f"{root}: no such directory")
        rows = [row for root in roots for row in rows_below(root)]
        rows = select(rows, chosen, sort, reverse)
        if as_json:
            show(runs_json(rows))
            return
        if not rows and (filters or len(roots) == 1):
            show(f"no runs in {roots[0]}" if not filters else "no runs match")
            return
        width = shutil.get_terminal_size().columns if (
            sys.stdout is not None and sys.stdout.isatty()) or "COLUMNS" in os.environ \
            else None
        show(runs_table(roots[0], rows, width))


@main.command(short_help="A run's or sweep's tables as CSV or MATLAB files.")
@click.argument("directory", type=click.Path(path_type=Path, file_okay=False))
@click.option("--csv", "as_csv", is_flag=True, help="Write CSV files.")
@click.option("--mat", "as_mat", is_flag=True,
              help="Write MATLAB files (.mat: the columns, their units and a description).")
@out_option(help="Write the files here [default: beside the tables].")
def export(directory: Path, as_csv: bool, as_mat: bool, out: Path | None) -> None:
    """Write a run's or sweep's Parquet tables in other formats (--csv, --mat, or both)."""
    if not (as_csv or as_mat):
        fail("export: choose a format: --csv, --mat (or both)")
    from flatcli.export import export_csv, export_mat

    paths = []
    with user_errors():
        if as_csv:
            paths += export_csv(directory, out)
        if as_mat:
            paths += export_mat(directory, out)
    show("wrote " + ", ".join(str(p) for p in paths))


@main.command("export-robot", short_help="A spec's robot as a URDF file.")
@spec_argument()
@robot_option
@set_option()
@click.option("--urdf", "as_urdf", is_flag=True,
              help="Write URDF (the one format so far): a planar chain in the x-y plane, the "
                   "root link its free base.")
@click.option("--out", "out", type=click.Path(path_type=Path, dir_okay=False), metavar="FILE",
              help="Write the URDF to FILE [default: standard output].")
def export_robot(spec: Path | None, robot: str | None, sets: tuple[str, ...], as_urdf: bool,
                 out: Path | None) -> None:
    """Write the robot of SPEC (with --robot and --set applied) in another format (--urdf);
    reading the file back (robot = "FILE.urdf") gives the same robot."""
    if not as_urdf:
        fail("export-robot: choose a format: --urdf")
    from flatcli.experiment import robot_from
    from flatcli.spec.build import resolve_robot
    from flatcli.spec.tree import read_toml
    from flatcli.urdf import write_urdf

    require_stdout(out is not None)
    with user_errors():
        overrides = spec_overrides(sets, robot=robot)
        s = resolve_robot({}, overrides) if spec is None else resolve_robot(
            read_toml(spec), overrides, base=spec.parent, source=spec)
        text = write_urdf(robot_from(s), s.name, out)
    if out is None:
        show(text, nl=False)
    else:
        show(f"wrote {out}")


#: The sections of ``flatcli reproduce`` (``flatcli.reproduce.SECTION_NAMES``; the CLI does
#: not import the numerical libraries to list them).
REPRODUCE_SECTIONS = ("paper", "optimized", "montecarlo", "actuators", "within", "chains",
                      "capture", "asbuilt", "search")


@main.command(short_help="The paper's figures and numbers, and the studies.")
@set_option("Override a key of the studies' specs (Monte Carlo, actuators), repeatable.")
@out_option(Path("runs/paper"), "Output directory.")
@click.option("--montecarlo", "montecarlo", type=click.Path(path_type=Path, dir_okay=False),
              help="Sweep spec of the Monte Carlo study [default: paper_montecarlo.toml, "
                   "shipped with flatcli].")
@click.option("--no-montecarlo", is_flag=True, help="Skip the Monte Carlo studies.")
@click.option("--only", "only", multiple=True, type=click.Choice(REPRODUCE_SECTIONS),
              help="Compute only this section (repeatable); the report keeps the others' "
                   "last results.")
@click.option("--force", is_flag=True,
              help="Compute every section run again, even if its inputs and code are "
                   "unchanged since it was last computed here.")
@figure_options
@workers_option("Worker processes for the studies.")
@quiet_option
def reproduce(sets: tuple[str, ...], out: Path, montecarlo: Path | None, no_montecarlo: bool,
              only: tuple[str, ...], force: bool, fmt: str | None, dpi: int | None,
              workers: int | None, quiet: bool) -> None:
    """The paper's figures 2-4 and numbers, and the Monte Carlo studies, with REPORT.md.

    A section whose inputs and code are unchanged since it was last computed into the
    directory is reused (and says so); the headlines and the report's path are printed.
    """
    require_stdout(quiet)
    from flatcli.reproduce import STUDY_SPEC
    from flatcli.reproduce import reproduce as run

    words = ["flatcli", "reproduce", "--out", str(out)]
    words += [] if montecarlo is None else ["--montecarlo", str(montecarlo)]
    words += ["--no-montecarlo"] if no_montecarlo else []
    words += [w for name in only for w in ("--only", name)]
    words += ["--force"] if force else []
    words += [] if fmt is None else ["--format", fmt]
    words += [] if dpi is None else ["--dpi", str(dpi)]
    words += [] if workers is None else ["--workers", str(workers)]
    words += [w for item in sets for w in ("--set", item)]
    words += ["-q"] if quiet else []
    with user_errors():
        from flatcli.report import FigureFile

        file = FigureFile(fmt or "png", FigureFile().dpi if dpi is None else checked_dpi(dpi))
        study = None if no_montecarlo else (montecarlo or STUDY_SPEC)
        path, results = run(out, study, quiet, workers, sets, command=shlex.join(words),
                            only=only, force=force, figures=file)
    if quiet:
        return
    reused = sum(r.reused for r in results)
    show(f"\n{path}: {len(results)} sections ({len(results) - reused} computed, "
         f"{reused} reused)")
    for result in results:
        for text in result.headline:
            show(f"- {result.section.name}: {text}")


if __name__ == "__main__":
    run()
