"""flatcli's Python API: what the command line does, as functions returning objects.

    >>> import flatcli
    >>> p = flatcli.plan(overrides={"plan.duration": 3.0})
    >>> p.frame            # plan.parquet's rows, a pandas DataFrame
    >>> p.metrics          # its headline numbers, a dict
    >>> t = flatcli.track(overrides={"track.kp": [100, 110], "track.kv": [10, 13]})
    >>> t.metrics["err_y_final"], t.frame["margin"].min()
    >>> s = flatcli.sweep("configs/paper_montecarlo.toml", "runs/study", workers=2)
    >>> s.summary, s.trials, s.metrics
    >>> flatcli.load("runs/paper_example/latest").frame

``plan`` and ``track`` compute in memory and write nothing until ``.save()``; ``sweep``
writes its directory as ``flatcli sweep`` does (resumable). Every command of the CLI is a
thin wrapper over these functions, so a result is the same whichever way it was made.

A spec is a TOML file's path, a dict (nested as in TOML, or dotted keys), a ``Spec``, or
None (the paper's example); ``overrides`` are dotted keys and values
(``{"track.kp": [100, 110]}``) or ``--set`` strings (``["track.kp=[100,110]"]``). Bad input
raises ``flatcli.FlatcliError`` (``SpecError``) with the same one line the CLI prints.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from collections.abc import Iterable, Iterator, Mapping
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from flatcli.core.errors import FlatcliError
from flatcli.core.plan.planning import Plan, PlanSamples
from flatcli.core.plan.workspace import BRANCHES, DEFAULT_ATTITUDES, WorkspaceMap
from flatcli.experiment import TrackRun as TrackRun  # the type of TrackResult.run
from flatcli.experiment import plan_from, run_track
from flatcli.files import is_regular, kind, read_text
from flatcli.progress import compile_notices, planner_text, spec_kernel_text
from flatcli.report import (
    FigureFile,
    Limits,
    metrics_text,
    optimization_summary,
    optimization_text,
    plan_figure,
    plan_summary,
    plan_text,
    plan_title,
    save_figure,
    task_text,
    track_figure,
    track_title,
)
from flatcli.rundirs import (
    RECORD,
    ROOT,
    SWEEP_DIR,
    SWEEP_MANIFEST,
    RunDirectoryError,
    SweepState,
    Target,
    chunk_frames,
    claim,
    partial_summary,
    read_json,
    sweep_state,
)
from flatcli.spec import Spec, parse_set, read_toml, resolve
from flatcli.storage import (
    check_output_dir,
    directory_lock,
    run_record,
    write_json,
    write_parquet,
)
from flatcli.threads import computes

if TYPE_CHECKING:  # pandas loads with the first DataFrame, never in a sweep's processes
    import pandas as pd
    from matplotlib.figure import Figure

    from flatcli.core.optimize import OptimizeResult
    from flatcli.designsearch import SearchResult
    from flatcli.designsearch.check import SearchCheckReport
    from flatcli.preflight import CheckReport
    from flatcli.trajectory import Trajectory

SpecLike = str | os.PathLike[str] | Mapping[str, Any] | Spec | None
#: The most targets per axis of ``workspace`` (memory: about 130 bytes per target).
MAX_WORKSPACE_POINTS = 1001
Overrides = Mapping[str, Any] | Iterable[str] | None

def load_spec(spec: SpecLike = None, overrides: Overrides = None) -> Spec:
    """A validated spec from a file, a dict or a Spec, with overrides applied in order."""
    if overrides is None:
        extra: dict[str, Any] = {}
    elif isinstance(overrides, Mapping):
        extra = dict(overrides)
    elif isinstance(overrides, str):
        extra = parse_set([overrides])
    else:
        extra = parse_set(overrides)
    if spec is None:
        return _resolved({}, extra)
    if isinstance(spec, Spec):
        return spec.with_overrides(extra) if extra else spec
    if isinstance(spec, Mapping):
        return _resolved(spec, extra)
    if isinstance(spec, str | os.PathLike):
        path = Path(spec)
        return resolve(read_toml(path), extra, base=path.parent, source=path)
    raise TypeError(f"spec: expected a path, a dict, a Spec or None, got {type(spec).__name__}")


#: Specs validated from dicts (and overrides), by their content: a Spec is immutable, so one
#: validated once is the same when asked for again (``_resolved``).
_RESOLVED: dict[Any, Spec] = {}
RESOLVED_CACHE_SIZE = 256


def _resolved(user: Mapping[str, Any], extra: dict[str, Any]) -> Spec:
    """``resolve(user, extra)``, remembered for dicts of plain values (str, int, float, bool,
    None, lists, tuples and dicts of them): validating a spec costs more than planning the
    paper's maneuver. Anything else (a file's robot, an array) is validated every time."""
    try:
        key = (_frozen(user), _frozen(extra))
    except TypeError:
        return resolve(user, extra)
    found = _RESOLVED.get(key)
    if found is None:
        found = resolve(user, extra)  # a bad spec raises: nothing is remembered
        if len(_RESOLVED) >= RESOLVED_CACHE_SIZE:
            _RESOLVED.pop(next(iter(_RESOLVED)))
        _RESOLVED[key] = found
    return found


def _frozen(value: Any) -> Any:
    """A hashable copy of a spec's plain values that keeps their types apart (1, 1.0, True
    and [1] are four keys); TypeError for anything else."""
    if isinstance(value, Mapping):
        if not all(isinstance(k, str) for k in value):
            raise TypeError("a spec's keys are strings")
        return ("dict", tuple(sorted((k, _frozen(v)) for k, v in value.items())))
    if isinstance(value, list | tuple):
        return (type(value).__name__, tuple(_frozen(v) for v in value))
    if value is None or type(value) in (str, int, float, bool):
        return (type(value).__name__, value)
    raise TypeError(f"not a plain value: {type(value).__name__}")


def _output(out: str | os.PathLike[str] | Target | None, command: str, spec: Spec,
            force: bool, root: str | os.PathLike[str]) -> Target:
    if isinstance(out, Target):
        return out
    try:
        target = claim(None if out is None else Path(out), command, spec.name, spec.digest(),
                       force, Path(root))
    except RunDirectoryError as exc:
        raise FlatcliError(str(exc)) from None
    check_output_dir(target.path, "--out" if out is not None else "the run directory")
    return target


def output_target(command: str, spec: Spec, out: str | os.PathLike[str] | None = None,
                  force: bool = False, root: str | os.PathLike[str] = ROOT) -> Target:
    """Where a ``command`` run of ``spec`` will be saved: ``out``, or a new directory
    ``root/<name>/<stamp>/``; FlatcliError if ``out`` holds a different run (``force``
    replaces it), or cannot be made or written. The CLI asks before computing (holding
    ``output_lock``), so a refusal costs nothing."""
    return _output(out, command, spec, force, root)


def output_lock(out: str | os.PathLike[str] | None) -> contextlib.AbstractContextManager[None]:
    """The lock of the directory ``out`` a plan or track run writes into (none for a new
    directory of its own, which no other run can choose): held from the check of ``out``
    to the run's last file, so two runs never mix their files there (FlatcliError naming
    the other run's pid). ``out`` is checked first (it can be made and written), so the
    lock never makes a directory that cannot be written."""
    if out is None:
        return contextlib.nullcontext()
    check_output_dir(Path(out))
    return directory_lock(Path(out))


def duration_note(spec: Spec, command: str) -> str | None:
    """A line for stderr before a long ``command`` ("plan" or "track") run starts: the least
    time it takes (``flatcli.spec.limits``), if that is more than ``NOTICE_SECONDS``."""
    from flatcli.spec.limits import NOTICE_SECONDS, plan_seconds, time_text, track_seconds

    seconds = track_seconds(spec) if command == "track" else plan_seconds(spec.joints)
    if seconds < NOTICE_SECONDS:
        return None
    return (f"note: this {command} run of a robot of {spec.joints} joints takes at least "
            f"{time_text(seconds)} (the N-link flat maps cost O(N^4) per point)")


@contextlib.contextmanager
def _saving(out: str | os.PathLike[str] | Target | None, command: str, spec: Spec,
            force: bool, root: str | os.PathLike[str]) -> Iterator[Path]:
    """The directory a run's files go into, under its lock (``output_lock``): checked
    (``output_target``), made, and for a new directory linked as ``latest`` afterwards."""
    given = None if isinstance(out, Target) else out
    with output_lock(given):
        target = _output(out, command, spec, force, root)
        directory = target.open()
        with directory_lock(directory):  # already held, unless a Target came from elsewhere
            yield directory
        target.finish(directory)


# ---------------------------------------------------------------------------------------
# Results.

class Run:
    """A run: its directory (None until saved) and its record (run.json)."""

    command = ""

    def __init__(self, directory: Path | None = None,
                 record: Mapping[str, Any] | None = None) -> None:
        self.directory = directory
        self.record: dict[str, Any] = dict(record or {})
        self.files: list[str] = []  # the files save() wrote
        recorded = self.record.get("tags", [])
        #: Labels of the run (``--tag``), saved in run.json; ``flatcli runs --filter`` finds
        #: runs by them.
        self.tags: list[str] = [str(t) for t in recorded] if isinstance(recorded, list) else []

    def table(self, name: str) -> pd.DataFrame:
        """``<name>.parquet`` of the run's directory as a DataFrame."""
        if self.directory is None:
            raise FlatcliError(f"this {self.command or 'run'} is not saved; call .save() first")
        if not _table(self.directory, f"{name}.parquet"):
            raise FlatcliError(f"{self.directory / f'{name}.parquet'} not found")
        import pandas as pd

        return pd.read_parquet(self.directory / f"{name}.parquet")

    def __repr__(self) -> str:
        where = f" in {self.directory}" if self.directory is not None else " (not saved)"
        name = self.record.get("spec", {}).get("name", "")
        return f"<flatcli {self.command or 'run'} {name!r}{where}>"


class PlanResult(Run):
    """A planned maneuver: ``.frame`` (plan.parquet's rows), ``.metrics`` (its headline
    numbers), ``.optimization`` (the optimiser's report, or None), ``.spec``; ``.plan``
    and ``.samples`` (the core's objects) when computed here, not loaded."""

    command = "plan"

    def __init__(self, spec: Spec | None, frame: pd.DataFrame | None,
                 metrics: Mapping[str, Any] | None,
                 optimization: Mapping[str, Any] | None = None, plan: Plan | None = None,
                 samples: PlanSamples | None = None, directory: Path | None = None,
                 record: Mapping[str, Any] | None = None) -> None:
        super().__init__(directory, record)
        if (frame is None or metrics is None) and (plan is None or samples is None):
            raise ValueError("PlanResult: a frame and metrics, or the plan and its samples")
        self._spec = spec
        self._frame = frame
        self._metrics = None if metrics is None else dict(metrics)
        self.optimization = None if optimization is None else dict(optimization)
        self.plan = plan
        self.samples = samples

    @property
    def frame(self) -> pd.DataFrame:
        """plan.parquet's rows (a DataFrame, made from the samples on first use)."""
        if self._frame is None:
            from flatcli.outputs import plan_frame

            assert self.samples is not None
            self._frame = plan_frame(self.samples,
                                     None if self.plan is None else self.plan.robot)
        return self._frame

    @property
    def metrics(self) -> dict[str, Any]:
        """The plan's headline numbers (``report.plan_summary``, made on first use)."""
        if self._metrics is None:
            assert self.plan is not None and self.samples is not None
            self._metrics = plan_summary(self.plan, self.samples)
        return self._metrics

    @cached_property
    def spec(self) -> Spec:
        return self._spec if self._spec is not None else spec_of(self.record)

    @cached_property
    def trajectory(self) -> Trajectory:
        """The maneuver as a function of time (``flatcli.trajectory.Trajectory``):
        ``p.trajectory(t)`` gives its states, rates, inputs and flat outputs at any t in
        [0, T]; a loaded plan is planned again from its spec (the same plan: planning is
        deterministic)."""
        from flatcli.trajectory import Trajectory

        return Trajectory(self.plan if self.plan is not None else
                          plan_from(self.spec))

    @property
    def warnings(self) -> list[str]:
        """One line each (``flatcli plan`` prints them on stderr): the plan's fastest joint
        beyond ``plan.rate_warning`` on its samples (none for a loaded plan)."""
        if self.samples is None:
            return []
        from flatcli.core.plan.planning import rate_warning_text

        text = rate_warning_text(self.samples, self.spec.plan.rate_warning)
        return [text] if text else []

    def text(self) -> str:
        """What ``flatcli plan`` prints."""
        if self.plan is None or self.samples is None:
            return metrics_text(self.spec.name, {"status": "ok", **self.metrics})
        text = plan_text(self.spec.name, self.plan, self.samples)
        if self.optimization is not None:
            text += "\n\n" + optimization_text(self.optimization)
        if self.metrics is not None and "task_candidates" in self.metrics:
            text += "\n\n" + task_text(self.metrics)
        return text

    def plot(self) -> Figure:
        """The plan's figure (a matplotlib Figure, drawn in flatcli's style): flat outputs,
        angles, joint rates, the singularity margin, H and the inputs, with the limits of an
        optimised plan; its title names the run, the robot and the objective. A loaded plan
        is drawn from its plan.parquet."""
        return plan_figure(self.frame, Limits.of_plan(self.spec, self.optimization is not None),
                           plan_title(self.spec, self.optimization))

    def save(self, out: str | os.PathLike[str] | Target | None = None, *, force: bool = False,
             plot: bool = False, root: str | os.PathLike[str] = ROOT) -> Path:
        """Write plan.parquet and run.json (and with ``plot`` the figure, plan.png or the
        format of the spec's ``[figures]``) into ``out``, or a new directory
        ``root/<name>/<stamp>/``; return the directory."""
        spec = self.spec
        record = run_record("plan", spec.tree, digest=spec.digest(), summary=self.metrics,
                            optimization=self.optimization, **_tags(self.tags))
        file = FigureFile.of(spec)
        with _saving(out, "plan", spec, force, root) as directory:
            write_parquet(directory / "plan.parquet", self.frame, record)
            write_json(directory / RECORD, record)
            self.files = ["plan.parquet", RECORD]
            if plot:
                save_figure(self.plot(), directory / file.name("plan"), file)
                self.files.append(file.name("plan"))
                if _has_task(spec):
                    save_figure(self.filmstrip(), directory / file.name("filmstrip"), file)
                    self.files.append(file.name("filmstrip"))
        self.directory, self.record = directory, record
        return directory

    def filmstrip(self) -> Figure:
        """The robot at a few instants among the task's obstacles, with the end effector's
        path and target (``report.task_figures.filmstrip_figure``)."""
        from flatcli.experiment import robot_from
        from flatcli.report.task_figures import filmstrip_figure

        s = self.spec
        theta = self.frame[[f"theta{i}" for i in range(s.joints + 1)]].to_numpy()
        fig: Figure = filmstrip_figure(robot_from(s), self.frame["t"].to_numpy(), theta,
                                       s.task.obstacles, s.task.clearance, s.task.end_effector,
                                       plan_title(s, self.optimization))
        return fig

    def animate(self, path: str | os.PathLike[str]) -> Path:
        """The maneuver as a GIF at ``path`` (matplotlib's Pillow writer): the links, the
        obstacles, the end effector's path."""
        import numpy as np

        from flatcli.experiment import robot_from
        from flatcli.report.task_figures import animate

        s = self.spec
        times = self.frame["t"].to_numpy()
        fine = np.linspace(0.0, float(times[-1]), max(len(times), int(25 * times[-1]) + 1))
        plan_ = self.plan if self.plan is not None else plan_from(s)
        theta = plan_.sample(fine).theta
        return animate(robot_from(s), fine, theta, Path(path), s.task.obstacles,
                       s.task.clearance, s.task.end_effector)


class TrackResult(Run):
    """A closed-loop run: ``.frame`` (track.parquet's rows), ``.metrics`` (metrics.json),
    ``.spec``; ``.run`` (plan, scenario and outcome) when computed here, not loaded."""

    command = "track"

    def __init__(self, spec: Spec | None, frame: pd.DataFrame, metrics: Mapping[str, Any],
                 run: TrackRun | None = None, directory: Path | None = None,
                 record: Mapping[str, Any] | None = None) -> None:
        super().__init__(directory, record)
        self._spec = spec
        self.frame = frame
        self.metrics = dict(metrics)
        self.run = run

    @cached_property
    def spec(self) -> Spec:
        return self._spec if self._spec is not None else spec_of(self.record)

    @cached_property
    def trajectory(self) -> Trajectory:
        """The reference the run tracked, as a function of time (``PlanResult.trajectory``)."""
        from flatcli.trajectory import Trajectory

        return Trajectory(self.run.plan if self.run is not None else
                          plan_from(self.spec))

    @property
    def warnings(self) -> list[str]:
        """One line each (``flatcli track`` prints them on stderr): the plan's fastest joint
        beyond ``plan.rate_warning`` (none for a loaded run)."""
        return [] if self.run is None else self.run.warnings

    def text(self) -> str:
        """What ``flatcli track`` prints."""
        return metrics_text(self.spec.name, self.metrics)

    def plot(self) -> Figure:
        """The run's figure (a matplotlib Figure, drawn in flatcli's style): flat outputs and
        angles beside the plan's, applied joint rates, tracking errors, the margin and H; on
        the dynamic plant also the joint torques, the servos' rate errors and the joints'
        power. Its title names the plant, the sensor noise, the rate and torque limits, the
        gains and the status. A loaded run is drawn from its track.parquet."""
        return track_figure(self.frame, Limits.of_track(self.spec),
                            track_title(self.spec, self.metrics))

    def save(self, out: str | os.PathLike[str] | Target | None = None, *, force: bool = False,
             plot: bool = False, root: str | os.PathLike[str] = ROOT) -> Path:
        """Write track.parquet, metrics.json and run.json (and with ``plot`` the figure,
        track.png or the format of the spec's ``[figures]``) into ``out``, or a new directory
        ``root/<name>/<stamp>/``; return the directory."""
        if self.run is None:
            raise FlatcliError("save: only a run computed here can be saved")
        spec = self.spec
        record = run_record("track", spec.tree, digest=spec.digest(), metrics=self.metrics,
                            **_tags(self.tags))
        title = track_title(spec, self.metrics)
        from flatcli.outputs import write_track

        with _saving(out, "track", spec, force, root) as directory:
            self.files = write_track(directory, self.run, record, title if plot else None)
        self.directory, self.record = directory, record
        return directory


class WorkspaceResult(Run):
    """Where an N = 2 robot can put its end effector at the end of a maneuver
    (``flatcli.workspace``): ``.frame`` (workspace.parquet's rows, one per target of the grid),
    ``.metrics`` (areas [m^2] by elbow branch, the attitude window, the threshold ``thin``),
    ``.spec``; ``.map`` (the core's ``WorkspaceMap``) when computed here."""

    command = "workspace"

    def __init__(self, spec: Spec, frame: pd.DataFrame, metrics: Mapping[str, Any],
                 found: WorkspaceMap | None = None, directory: Path | None = None,
                 record: Mapping[str, Any] | None = None) -> None:
        super().__init__(directory, record)
        self.spec = spec
        self.frame = frame
        self.metrics = dict(metrics)
        self.map = found

    def text(self) -> str:
        """What ``flatcli workspace`` prints: the window and the areas."""
        from flatcli.report import table

        m = self.metrics
        rows = [[name.replace("_", " "), m[f"area_{name}"], m[f"area_{name}"] / m["area_grid"]]
                for name in ("reachable", "both", "up_only", "down_only", "thin")]
        lo, hi = m["attitude_low"], m["attitude_high"]
        window = f"th0(T) = {lo:g} rad" if lo == hi else f"th0(T) in [{lo:g}, {hi:g}] rad " \
            f"({m['attitudes']} attitudes)"
        return (f"workspace of {self.spec.name!r} from th(0) = "
                f"({', '.join(f'{v:g}' for v in m['start'])}) rad, {window}, "
                f"{m['points']} x {m['points']} targets; thin: |sin th1| < {m['thin']:g}\n"
                + table(["region", "area [m^2]", "fraction of the grid"], rows, 4))

    def plot(self) -> Figure:
        """The map (``report.task_figures.workspace_figure``): targets coloured by the branches
        that reach them, the thin region hatched, the robot at its start."""
        import numpy as np

        from flatcli.core.plan.workspace import WorkspaceMap
        from flatcli.experiment import robot_from
        from flatcli.report.task_figures import workspace_figure

        found = self.map
        if found is None:  # loaded: the map from its table
            f = self.frame
            xs, ys = np.unique(f["target_x"].to_numpy()), np.unique(f["target_y"].to_numpy())
            shape = (len(ys), len(xs))
            margin = np.stack([f[f"abs_sin_th1_{b}"].to_numpy(dtype=float).reshape(shape)
                               for b in BRANCHES])
            theta = np.stack([np.stack([f[f"theta{i}_{b}"].to_numpy(dtype=float).reshape(shape)
                                        for i in range(3)], axis=-1) for b in BRANCHES])
            found = WorkspaceMap(xs, ys, np.linspace(self.metrics["attitude_low"],
                                                     self.metrics["attitude_high"],
                                                     int(self.metrics["attitudes"])),
                                 margin, theta)
        m = self.metrics
        task = self.spec.task
        fig: Figure = workspace_figure(found, robot_from(self.spec), np.asarray(m["start"]),
                                       float(m["thin"]), f"{self.spec.name}: where the end "
                                       "effector can be put", task.end_effector, task.obstacles)
        return fig

    def save(self, out: str | os.PathLike[str] | Target | None = None, *, force: bool = False,
             plot: bool = True, root: str | os.PathLike[str] = ROOT) -> Path:
        """Write workspace.parquet and run.json (and with ``plot`` the figure, workspace.png or
        the format of the spec's ``[figures]``) into ``out``, or a new directory
        ``root/<name>/<stamp>/``; return the directory."""
        spec = self.spec
        record = run_record("workspace", spec.tree, digest=spec.digest(), metrics=self.metrics,
                            **_tags(self.tags))
        file = FigureFile.of(spec)
        with _saving(out, "workspace", spec, force, root) as directory:
            write_parquet(directory / "workspace.parquet", self.frame, record)
            write_json(directory / RECORD, record)
            self.files = ["workspace.parquet", RECORD]
            if plot:
                save_figure(self.plot(), directory / file.name("workspace"), file)
                self.files.append(file.name("workspace"))
        self.directory, self.record = directory, record
        return directory


class SweepResult(Run):
    """A sweep's directory, finished or interrupted: ``.trials`` (one row per finished
    trial), ``.summary`` (per-cell statistics), ``.metrics`` (trials by status),
    ``.complete``; ``.simulated`` and ``.wall_seconds`` when run here."""

    command = "sweep"

    def __init__(self, state: SweepState, simulated: int | None = None,
                 wall_seconds: float | None = None, summary_text: str | None = None,
                 headline_text: str | None = None) -> None:
        super().__init__(state.directory, read_json(state.directory / RECORD)
                         if state.complete else {"command": "sweep",
                                                 "spec": state.manifest.get("spec", {})})
        self.state = state
        self.simulated = simulated
        self.wall_seconds = wall_seconds
        self._summary_text = summary_text
        #: what the run here did, as the runner reports it (``montecarlo.SweepResult``; of a
        #: shard: whether it wrote the final tables, what is missing)
        self.outcome: Any = None
        self._headline_text = headline_text

    @property
    def complete(self) -> bool:
        return self.state.complete

    @cached_property
    def spec(self) -> Spec:
        """The sweep's spec, its grid in the order the sweep enumerated it (a record of an
        older flatcli sorted the grid's keys: ``layout.grid_in_recorded_order``)."""
        from flatcli.montecarlo.layout import grid_in_recorded_order

        grid_cells = self.state.manifest.get("grid_cells")
        return grid_in_recorded_order(spec_of(self.state.manifest),
                                      grid_cells if isinstance(grid_cells, list) else None)

    @cached_property
    def trials(self) -> pd.DataFrame:
        """trials.parquet (of a partial sweep: its finished chunks, in the same order: cells
        in the grid's order, trials in order)."""
        if self.complete:
            return self.table("trials")
        if not self.state.chunk_files and not self.state.stored:
            import pandas as pd

            return pd.DataFrame()
        frame: pd.DataFrame = chunk_frames(self.state)
        return frame

    @cached_property
    def _partial(self) -> tuple[pd.DataFrame, str]:
        frame, text = partial_summary(self.state)
        return frame, text

    @cached_property
    def summary(self) -> pd.DataFrame:
        """summary.parquet (of a partial sweep: computed from its finished trials)."""
        return self.table("summary") if self.complete else self._partial[0]

    @property
    def summary_text(self) -> str:
        """summary.md (of a partial sweep: headed by how much is missing)."""
        if self._summary_text is not None:
            return self._summary_text
        assert self.directory is not None
        if self.complete and is_regular(self.directory / "summary.md"):
            return read_text(self.directory / "summary.md").rstrip("\n")
        return self._partial[1]

    @property
    def headline_text(self) -> str:
        """The summary in one screen (what ``flatcli sweep`` and ``summarize`` print): per
        cell its varying grid values, trials by status and median final error, the most
        frequent error reasons, and where the full tables are (``summary_text``)."""
        from flatcli.report.summary import error_reasons, grid_columns_of, headline, totals_text

        if self._headline_text is not None:
            return self._headline_text
        assert self.directory is not None
        records = [{str(k): v for k, v in r.items()} for r in self.summary.to_dict("records")]
        if self.complete:
            title = f"sweep {self.spec.name!r}: {totals_text(records)}"
            files = [self.directory / "trials.parquet"]
        else:
            title = (f"{self.state.missing_text()}; the finished trials: "
                     f"{totals_text(records) if records else 'none'} (run the same flatcli "
                     "sweep command again to finish it)")
            files = list(self.state.chunk_files)
        errors = sum(int(r["error"]) for r in records)
        return headline(records, grid_columns_of(records), title, str(self.directory),
                        error_reasons(files) if errors else None,
                        grid=self.spec.sweep.grid)

    @property
    def metrics(self) -> dict[str, int]:
        """Trials in all, finished, and finished by status."""
        from flatcli.core.loop.metrics import STATUS_NAMES

        if self.complete:
            counts = self.record.get("status_counts", {})
        else:
            counts = {str(k): int(v) for k, v in self.trials["status"].value_counts().items()} \
                if len(self.trials) else {}
        return {"trials": self.state.total, "finished": self.state.done,
                **{s: int(counts.get(s, 0)) for s in STATUS_NAMES}}

    def _finished(self) -> Path:
        if not self.complete:
            raise FlatcliError(f"--plot: {self.state.missing_text()}; the figures need "
                               "every trial (run the sweep again to finish it)")
        assert self.directory is not None
        return self.directory

    def figures(self, x: str | None = None, hue: str | None = None) -> dict[str, Figure]:
        """The summary figures of a finished sweep, by name ("errors", "singular",
        "margin", "momentum": ``sweep_<name>`` files), as matplotlib Figures; ``x`` and
        ``hue``: the grid keys of sweep_singular's x axis and colours (``plot``)."""
        from flatcli.report.sweep_figures import sweep_figures

        return sweep_figures(self._finished(), x=x, hue=hue)

    def plot(self, which: str = "singular", *, x: str | None = None,
             hue: str | None = None) -> Figure:
        """One summary figure of a finished sweep as a matplotlib Figure: "singular" (the
        final error, singular hits and failures against the grid key ``x``, one line per
        value of ``hue`` and of the other grid keys), "errors", "margin" or "momentum" (per
        cell). FlatcliError naming a key that is not one of the sweep's grid keys."""
        from flatcli.report.sweep_figures import FIGURE_NAMES, sweep_figure

        if which not in FIGURE_NAMES:
            raise FlatcliError(f"plot: expected one of {list(FIGURE_NAMES)}, got {which!r}")
        return sweep_figure(self._finished(), which, x=x, hue=hue)

    def save_figures(self, fmt: str | None = None, dpi: int | None = None,
                     x: str | None = None, hue: str | None = None) -> list[Path]:
        """Write the summary figures (``sweep_<name>.png``, or ``fmt``; default the sweep
        spec's ``[figures]``) into the sweep's directory and record them in its manifest;
        their paths."""
        from flatcli.montecarlo.directory import record_outputs
        from flatcli.report import plot_sweep

        directory = self._finished()
        spec_file = FigureFile.of(self.spec)
        file = FigureFile(fmt or spec_file.format, dpi or spec_file.dpi)
        with directory_lock(directory):  # flatcli's files: --force may remove them
            paths = plot_sweep(directory, file, x=x, hue=hue)
            record_outputs(directory, paths)
        return paths


def _has_task(spec: Spec) -> bool:
    t = spec.task
    return t.end_effector is not None or t.rest or bool(t.obstacles) or (
        t.start_end_effector is not None)


def _tags(tags: Iterable[str]) -> dict[str, Any]:
    """The ``tags`` of a run record (none: no key, as before tags existed)."""
    from flatcli.rundirs import check_tags

    chosen = check_tags(tags)
    return {"tags": chosen} if chosen else {}


def spec_of(record: Mapping[str, Any]) -> Spec:
    """The Spec a run.json or sweep.json holds (non-finite numbers come back from JSON's
    strings)."""
    tree = record.get("spec")
    if not isinstance(tree, Mapping):
        raise FlatcliError("the run's record holds no spec")
    return resolve(_floats(tree))


def _floats(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: (v if k == "name" else _floats(v)) for k, v in value.items()}
    if isinstance(value, list):
        return [_floats(v) for v in value]
    if value in ("inf", "-inf", "nan"):
        return float(value)
    return value


# ---------------------------------------------------------------------------------------
# The functions.

@computes
def plan(spec: SpecLike = None, overrides: Overrides = None, *,
         quiet: bool = True) -> PlanResult:
    """Plan the spec's maneuver (optimised when ``plan.optimize.objective`` is set).

    Returns a PlanResult (``.frame``, ``.metrics``, ``.optimization``); nothing is written
    until ``.save()``. Not ``quiet`` (as ``flatcli plan``): a planner numba compiles first
    (the N-link chain's maps, on a cold cache) is announced on stderr.
    """
    from flatcli.experiment import planned as plan_of
    from flatcli.experiment import task_metrics
    from flatcli.spec.limits import require_finite_plan

    s = load_spec(spec, overrides)
    with contextlib.nullcontext() if quiet else compile_notices(planner_text(s), quiet):
        made, optimization, task = plan_of(s)
    samples = made.sample(made.grid(s.plan.samples))
    require_finite_plan({"theta": samples.theta, "theta_dot": samples.theta_dot,
                         "u_dot": samples.u_dot, "y": samples.y})
    opt = None if optimization is None else _optimization(optimization, s)
    if task is None:
        return PlanResult(s, None, None, opt, made, samples)  # frame and metrics on first use
    metrics: dict[str, Any] = dict(plan_summary(made, samples))
    metrics.update({k: v for k, v in task_metrics(s, samples.theta).items()
                    if k != "ee_error_max"})
    if task.certificate is not None:
        bound = float(task.certificate.lower_bound)
        metrics["clearance_bound"] = bound if math.isfinite(bound) else None
        metrics["certified_intervals"] = task.certificate.intervals
    metrics["task_candidates"] = task.candidates
    metrics["rate_factor"] = None if s.task.rest else float(task.shape)
    metrics["rest_skew"] = float(task.shape) if s.task.rest else None
    return PlanResult(s, None, metrics, opt, made, samples)  # the frame on first use


class PlanBatch:
    """M maneuvers of one robot planned at once (``plan_many``): ``.plan`` (the core's
    ``Plan``, its coefficients (M, N, size)), ``len()``, ``[i]`` (maneuver i as a
    ``PlanResult``: the same plan, samples, frame and metrics to the bit as ``flatcli.plan``
    makes of the spec with maneuver i's start, goal and end rates, which is its ``.spec``),
    and, computed on first use, ``.samples`` (on the spec's ``plan.samples`` grid, arrays
    (M, n, ...); FlatcliError naming a maneuver whose samples are not finite) and
    ``.metrics`` (``PlanResult.metrics`` of every maneuver, each an (M,) array)."""

    #: Maneuvers sampled at a time (the arrays of a block stay in the processor's caches).
    BLOCK = 64

    def __init__(self, spec: Spec, plan: Plan, ends: dict[str, Any]) -> None:
        self.spec = spec
        self.plan = plan
        self._ends = ends

    def __len__(self) -> int:
        return int(self.plan.trajectory.coefficients.shape[0])

    def _part(self, index: int | slice) -> Plan:
        """Maneuver ``index`` (or a block of them) as a core ``Plan``."""
        import numpy as np

        from flatcli.core.curves.basis import FlatTrajectory
        from flatcli.core.plan.planning import Plan as CorePlan

        plan = self.plan
        coefficients = np.ascontiguousarray(plan.trajectory.coefficients[index])
        return CorePlan(plan.robot, plan.model, FlatTrajectory(plan.trajectory.basis,
                                                               coefficients), plan.duration)

    def __getitem__(self, i: int) -> PlanResult:
        from flatcli.spec.limits import require_finite_plan

        if not -len(self) <= i < len(self):
            raise IndexError(f"maneuver {i} of {len(self)}")
        i %= len(self)
        one = self._part(i)
        samples = one.sample(one.grid(self.spec.plan.samples))
        require_finite_plan(_finite_columns(samples))
        overrides = {f"plan.{name}": _plain(values[i]) for name, values in self._ends.items()}
        return PlanResult(self.spec.with_overrides(overrides), None, None, None, one, samples)

    @cached_property
    def samples(self) -> PlanSamples:
        """Every maneuver on the spec's ``plan.samples`` grid (``PlanSamples``, arrays
        (M, n, ...)), sampled ``BLOCK`` maneuvers at a time."""
        import dataclasses

        import numpy as np

        from flatcli.spec.limits import require_finite_plan

        parts = []
        for first in range(0, len(self), self.BLOCK):
            block = self._part(slice(first, first + self.BLOCK))
            part = block.sample(block.grid(self.spec.plan.samples))
            try:
                require_finite_plan(_finite_columns(part))
            except FlatcliError:
                columns = _finite_columns(part)
                bad = min(int(np.flatnonzero(~np.isfinite(v).reshape(len(v), -1).all(axis=1))[0])
                          for v in columns.values() if not np.isfinite(v).all())
                raise FlatcliError(f"plan_many: maneuver {first + bad}: its samples are not "
                                   "finite (the spec's magnitudes overflow the flat map)"
                                   ) from None
            parts.append(part)
        fields = [f.name for f in dataclasses.fields(PlanSamples)]
        return PlanSamples(**{f: parts[0].t if f == "t" else
                              np.concatenate([getattr(p, f) for p in parts]) for f in fields})

    @cached_property
    def metrics(self) -> dict[str, Any]:
        """Per maneuver (arrays (M,)): max_abs_momentum, min_margin, min_margin_time,
        max_abs_theta{i}, peak_rate{i} and input_energy, as ``PlanResult.metrics``
        (``report.plan_summary``) computes them one maneuver at a time."""
        import numpy as np

        from flatcli.core.curves.basis import composite_gauss_legendre
        from flatcli.core.plan.planning import ENERGY_ORDER, ENERGY_PIECES

        s = self.samples
        out: dict[str, Any] = {
            "max_abs_momentum": np.max(np.abs(s.momentum), axis=-1),
            "min_margin": np.min(s.margin, axis=-1),
            "min_margin_time": s.t[np.argmin(s.margin, axis=-1)],
        }
        for i in range(s.theta.shape[-1]):
            out[f"max_abs_theta{i}"] = np.max(np.abs(s.theta[..., i]), axis=-1)
        for i in range(s.theta.shape[-1]):
            out[f"peak_rate{i}"] = np.max(np.abs(s.theta_dot[..., i]), axis=-1)
        t, weights = composite_gauss_legendre(self.plan.duration, ENERGY_PIECES, ENERGY_ORDER)
        energy = np.empty(len(self))
        for first in range(0, len(self), self.BLOCK):
            rates = self._part(slice(first, first + self.BLOCK)).sample(t).theta_dot
            squares = np.sum(rates[..., 1:] ** 2, axis=-1)
            for k, row in enumerate(squares):  # one dot product each, as Plan.input_energy
                energy[first + k] = float(weights @ row)
        out["input_energy"] = energy
        return out

    def __repr__(self) -> str:
        return f"<flatcli plans: {len(self)} maneuvers of {self.spec.name!r}>"


def _finite_columns(samples: PlanSamples) -> dict[str, Any]:
    """The sampled values a plan must have finite (``spec.limits.require_finite_plan``)."""
    return {"theta": samples.theta, "theta_dot": samples.theta_dot, "u_dot": samples.u_dot,
            "y": samples.y}


def _plain(value: Any) -> Any:
    """A numpy value of a batch as the plain value a spec holds."""
    return value.tolist() if hasattr(value, "tolist") else value


#: The spec keys ``plan_many`` takes as arrays (one row per maneuver) and their widths for a
#: robot of N joints.
MANY_KEYS = ("start", "goal", "start_rate", "goal_rate")


@computes
def plan_many(spec: SpecLike = None, overrides: Overrides = None, *, start: Any = None,
              goal: Any = None, start_rate: Any = None, goal_rate: Any = None) -> PlanBatch:
    """Plan M maneuvers of the spec's robot at once: ``start``, ``goal`` (M, N + 1) [rad] and
    ``start_rate``, ``goal_rate`` (M,) or (M, N - 1) [rad/s] (each None: the spec's, for
    every maneuver; one row or one number: the same for all). Everything else (the robot,
    ``plan.duration``, the model and basis, ``plan.samples``) is the spec's.

    Maneuver i is the plan ``flatcli.plan`` makes of the spec with those four keys set to
    row i, to the bit (``PlanBatch[i]``), at a small part of the cost: one vectorised solve
    for all M; their samples and metrics are computed when first asked for (``.samples``,
    ``.metrics``). Bad input raises FlatcliError naming the argument (and the maneuver, for
    one that meets the singular set); optimised plans (``plan.optimize.objective``) and
    robots of more than 2 joints plan one at a time (``flatcli.plan``).
    """
    import numpy as np

    from flatcli.core.plan.planning import plan_point_to_point
    from flatcli.experiment import robot_from

    s = load_spec(spec, overrides)
    if s.plan.optimize.objective is not None:
        raise FlatcliError("plan_many: plan.optimize.objective is set: optimised plans are "
                           "planned one at a time (flatcli.plan)")
    if s.joints != 2:
        raise FlatcliError(f"plan_many: the robot has {s.joints} joints; batches are planned "
                           "for the paper's robot (2 joints), others one at a time "
                           "(flatcli.plan)")
    given = {"start": start, "goal": goal, "start_rate": start_rate, "goal_rate": goal_rate}
    ends: dict[str, Any] = {}
    counts: dict[str, int] = {}
    for name in MANY_KEYS:
        value = given[name] if given[name] is not None else getattr(s.plan, name)
        try:
            array = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise FlatcliError(f"plan_many: {name}: expected numbers, got "
                               f"{type(value).__name__}") from None
        width = 3 if name in ("start", "goal") else 1
        batch_ndim = 2 if width > 1 else 1  # the dimensions of one row per maneuver
        if width == 1 and array.ndim == 2 and array.shape[1] == 1:
            array = array[:, 0]
        if array.ndim > batch_ndim or (width > 1 and array.shape[-1:] != (3,)):
            shape = "(M, 3) or (3,)" if width > 1 else "(M,), (M, 1) or one number"
            raise FlatcliError(f"plan_many: {name}: expected shape {shape} for a robot of 2 "
                               f"joints, got {array.shape}")
        bad = np.flatnonzero(~np.isfinite(array.reshape(-1, width)).all(axis=1))
        if bad.size:
            where = f" (maneuver {int(bad[0])})" if array.ndim == batch_ndim else ""
            raise FlatcliError(f"plan_many: {name}: not finite{where}")
        if array.ndim == batch_ndim:
            counts[name] = array.shape[0]
        ends[name] = array
    if len(set(counts.values())) > 1:
        raise FlatcliError("plan_many: start, goal, start_rate and goal_rate: different numbers "
                           f"of maneuvers ({', '.join(f'{k} {v}' for k, v in counts.items())})")
    count = next(iter(counts.values()), 1)
    if count < 1:
        raise FlatcliError("plan_many: no maneuvers (M = 0)")
    ends = {name: np.ascontiguousarray(np.broadcast_to(
        a, (count, 3) if name in ("start", "goal") else (count,))) for name, a in ends.items()}
    robot = robot_from(s)
    model = checked_model(s)
    basis = basis_of(s)

    def planned(index: Any) -> Plan:
        return plan_point_to_point(robot, ends["start"][index], ends["goal"][index],
                                   ends["start_rate"][index], ends["goal_rate"][index],
                                   s.plan.duration, model, basis)

    try:
        batch = planned(slice(None))
    except FlatcliError:  # which maneuver: each alone, until one says
        for i in range(count):
            try:
                planned(i)
            except FlatcliError as exc:
                raise FlatcliError(f"plan_many: maneuver {i}: {exc}") from None
        raise
    return PlanBatch(s, batch, ends)


def checked_model(spec: Spec) -> Any:
    """The planning model a spec names (``robot.model``)."""
    from flatcli.experiment import checked

    return checked(spec.robot.model)


def basis_of(spec: Spec) -> Any:
    """The flat-output basis a spec names (``experiment.basis_from``)."""
    from flatcli.experiment import basis_from

    return basis_from(spec)


def _optimization(result: OptimizeResult, spec: Spec) -> dict[str, Any]:
    return optimization_summary(result, str(spec.plan.optimize.objective))


@computes
def track(spec: SpecLike = None, overrides: Overrides = None, *,
          quiet: bool = False, controller: Any = None) -> TrackResult:
    """Plan, then simulate the closed loop of the spec's ``[track]`` on its ``[plant]``.

    Returns a TrackResult (``.frame``, ``.metrics``); nothing is written until ``.save()``.
    On a cold numba cache says on stderr, unless quiet, that its kernel compiles (once),
    how long that should take, and how far it is (``progress.compile_notices``).

    ``controller``: your own controller, written in Python, acting at its sample instants
    around the law ``track.controller`` names ("flat": add to y''; "asbuilt": add to the
    joint-rate commands): an object with ``sample`` [s], ``reset()`` and ``step(k, t,
    errors) -> held`` (``flatcli.core.controllers.python``). The plant, the inner law and
    the metrics stay compiled, but its steps are Python calls between scipy's DOP853
    segments (the run is DOP853's whatever ``track.integrator`` says): slower than a
    compiled controller (the MPC's step in Python on the paper's maneuver, dt 0.01 s, 10
    samples: 0.11 s a trial against 0.004 s for the compiled MPC's adaptive trial, 27x; the
    cost grows with the samples and the step's own work). Or an object with ``command(t,
    theta, u, flag) -> (u_dot, rate)``, called at every evaluation in place of the flat law
    (the paper's robot, kinematic plant; docs/development.md has the paper's law written so:
    1.1 s for the paper's maneuver, 0.05 s compiled).
    """
    from flatcli.outputs import track_frame
    from flatcli.spec.limits import require_finite_plan

    s = load_spec(spec, overrides)
    with compile_notices(spec_kernel_text(s), quiet):  # the planner's and the loop's
        run = run_track(s, controller=controller)
    require_finite_plan({"the reference": run.scenario.reference,
                         "theta": run.scenario.theta_reference})
    return TrackResult(s, track_frame(run), run.metrics, run)


@computes
def sweep(spec: SpecLike, out: str | os.PathLike[str] | None = None, *,
          overrides: Overrides = None, workers: int | None = None, executor: str = "local",
          scheduler: str | None = None, force: bool = False, fail_fast: bool = False,
          quiet: bool = False, oversubscribe: bool = False,
          tags: Iterable[str] = (), shard: str | None = None) -> SweepResult:
    """Run (or resume) a Monte Carlo sweep into ``out`` (default ``runs/<name>/sweep/``,
    apart from the plan and track runs of that name).

    A spec whose trials would all be the same (no ``[sweep.perturb]``, no grid, no sensor
    noise) is refused: it would repeat one track run ``sweep.trials`` times; with a grid but
    identical trials in each cell a note says so.

    ``workers``: processes (default one per core); ``executor``: "local" or "dask"
    (``scheduler``: an address or "local"); ``force``: start over in a directory holding
    another sweep (removing only the files flatcli wrote there); ``fail_fast``: stop at the
    first trial that errors or diverges; ``oversubscribe``: allow more workers than cores.
    Shows a progress bar on stderr unless quiet. ``tags``: labels of the sweep (run.json).
    Returns the SweepResult of the directory. One run writes into a directory at a time
    (FlatcliError naming the other run's pid), except the shards of one study: ``shard``
    "K/N" computes shard K of N (``montecarlo.layout.Shard``) beside the others, possibly
    on other machines sharing the directory; the last to finish writes the final tables
    (docs/cluster.md). A shard's result is ``.complete`` only if it did.
    """
    from flatcli.montecarlo import run_sweep
    from flatcli.montecarlo.layout import Shard
    from flatcli.report import Progress
    from flatcli.rundirs import check_tags, sweep_directory
    from flatcli.spec.sweeps import identical_trials

    s = load_spec(spec, overrides)
    chosen = check_tags(tags)
    same = identical_trials(s)
    if same is not None and not s.sweep.grid and s.sweep.trials > 1:
        raise FlatcliError(f"sweep: {s.sweep.trials} identical trials ({same}): the sweep "
                           "would repeat one track run; add a [sweep] table with "
                           "[sweep.perturb] or [sweep.grid] (or track.sensor_noise), set "
                           "sweep.trials = 1, or run flatcli track")
    if same is not None and s.sweep.trials > 1 and not quiet:
        print(f"note: the {s.sweep.trials} trials of each cell are identical ({same})",
              file=sys.stderr)
    part = Shard.parse(shard) if shard is not None else None
    directory = Path(out) if out is not None else sweep_directory(s.name)
    check_output_dir(directory)
    # (a shard takes the directory's lock itself: shared, then alone if it is the last)
    with directory_lock(directory) if part is None else contextlib.nullcontext():
        done = run_sweep(s, directory, executor, workers, scheduler, force, fail_fast,
                         Progress(s.name, quiet), oversubscribe=oversubscribe, tags=chosen,
                         shard=part)
        state = sweep_state(directory)
    assert state is not None
    result = SweepResult(state, done.simulated, done.wall_seconds, done.summary_text,
                         done.headline or None)
    result.outcome = done
    return result


def search(spec: SpecLike, out: str | os.PathLike[str] | None = None, *,
           overrides: Overrides = None, workers: int | None = None, executor: str = "local",
           scheduler: str | None = None, force: bool = False, quiet: bool = False,
           oversubscribe: bool = False, command: str = "") -> SearchResult:
    """Run (or resume) the design search of a spec with a ``[search]`` table into ``out``
    (default ``runs/<name>/search/``): scipy's differential evolution over the design
    variables of ``[search.vary]``, each candidate studied by the spec's own ``[sweep]``
    (common random numbers), generation by generation on every core (or Dask); writes
    search.parquet, summary.md, the convergence figure and the best design as
    best_robot.toml, best_robot.urdf and best_spec.toml (docs/search.md). Running it again
    resumes it (the same search.parquet, bit for bit); a larger ``search.candidates``
    continues it. Progress on stderr unless quiet."""
    from flatcli.designsearch import SearchResult
    from flatcli.designsearch.directory import identity
    from flatcli.designsearch.progress import SearchProgress
    from flatcli.designsearch.report import write_results, write_table_now
    from flatcli.designsearch.runner import SearchState, run_search

    s = load_spec(spec, overrides)
    directory = Path(out) if out is not None else ROOT / s.name / "search"
    check_output_dir(directory)
    digest = identity(s)
    progress = SearchProgress(s.name, quiet)

    def generation(state: SearchState) -> None:
        write_table_now(state, directory, digest)  # the rows so far, for a reader
        progress.on_generation(state)

    record: dict[str, Any] = {}

    def finish(state: SearchState, where: Path, items: dict[str, Any]) -> None:
        record.update(write_results(state, where, items, digest))

    try:
        run_search(s, directory, executor, workers, scheduler, force, oversubscribe,
                   command or " ".join(sys.argv), on_generation=generation,
                   on_candidate=progress.on_candidate, on_start=progress.on_start,
                   finish=finish, quiet=quiet)
    finally:
        progress.close()
    from flatcli.designsearch.directory import SUMMARY

    return SearchResult(directory, record, read_text(directory / SUMMARY).rstrip("\n"))


@computes
def check(spec: SpecLike, overrides: Overrides = None, *, workers: int | None = None,
          executor: str = "local", calibrate: bool = True, quiet: bool = False,
          what: str = "auto") -> CheckReport | SearchCheckReport:
    """What a sweep of this spec would do, without doing it: cells, trials, chunks, a time
    and memory estimate from a short calibration, and warnings (``flatcli.preflight``); for
    a spec with ``[search.vary]`` (``what`` "auto"; or "search"), what its design search would
    do and cost (``flatcli.designsearch.check``). Writes nothing. Returns a CheckReport
    (``.text()``, ``.cells``, ``.warnings``) or a SearchCheckReport (``.text()``,
    ``.estimate_seconds``)."""
    from flatcli.preflight import check_spec

    if what not in ("auto", "sweep", "search"):
        raise FlatcliError(f"check: what must be 'auto', 'sweep' or 'search', got {what!r}")
    s = load_spec(spec, overrides)
    if what == "search" or (what == "auto" and s.search.vary):
        from flatcli.designsearch.check import check_search_spec

        return check_search_spec(s, workers=workers, executor=executor, calibrate=calibrate,
                                 quiet=quiet)
    return check_spec(s, workers=workers, executor=executor, calibrate=calibrate, quiet=quiet)


def workspace(spec: SpecLike = None, overrides: Overrides = None, *,
              attitude: tuple[float, float] | None = None, attitudes: int = DEFAULT_ATTITUDES,
              points: int = 201, extent: float | None = None, thin: float = 0.1
              ) -> WorkspaceResult:
    """Map where the spec's N = 2 robot can put its end effector at the end of a maneuver
    from its start (``plan.start``, or ``task.start_end_effector``), for final base attitudes
    in ``attitude`` = (lo, hi) [rad] (default: ``task.base_attitude`` if set, else free:
    th0(0) +- pi) sampled at ``attitudes`` values, on a ``points`` x ``points`` grid of
    targets over [-extent, extent]^2 [m] (default: 5 % beyond the arm's reach).

    Columns: ``target_x``, ``target_y`` [m]; ``up``, ``down``, ``reachable`` (usable on that
    branch, either); ``abs_sin_th1_up``/``_down`` (the largest |sin th1| over the window,
    nan where not usable) and ``abs_sin_th1`` (the larger); ``theta0_up`` .. ``theta2_down``
    [rad], the configuration of that largest margin. Nothing is written until ``.save()``.
    """
    import math
    from dataclasses import replace

    import numpy as np
    import pandas as pd

    from flatcli.core.plan.task import task_ends
    from flatcli.core.plan.workspace import workspace_areas, workspace_map
    from flatcli.core.robots.kinematics import reach
    from flatcli.experiment import robot_from, task_from
    from flatcli.units import units_of

    s = load_spec(spec, overrides)
    robot = robot_from(s)  # an N != 2 robot is refused by workspace_map
    if not 2 <= points <= MAX_WORKSPACE_POINTS:
        raise FlatcliError(f"--points: expected 2 to {MAX_WORKSPACE_POINTS}, got {points}")
    if not (math.isfinite(thin) and thin >= 0):
        raise FlatcliError(f"--thin: expected a number >= 0, got {thin:g}")
    task = task_from(s)
    start = np.asarray(s.plan.start, dtype=float)
    if task.start_end_effector is not None:
        plain = replace(task, end_effector=None, rest=False, obstacles=())
        start = task_ends(robot, plain, start, s.plan.goal, False, True)[0][0]
    if attitude is None:
        a = task.base_attitude
        attitude = (a, a) if a is not None else (start[0] - math.pi, start[0] + math.pi)
    span = 1.05 * reach(robot)[1] if extent is None else float(extent)
    if not (math.isfinite(span) and span > 0):
        raise FlatcliError(f"--extent: expected a positive length [m], got {span:g}")
    grid = np.linspace(-span, span, points)
    found = workspace_map(robot, start, attitude, grid, grid, attitudes)
    areas = workspace_areas(found, thin)
    columns: dict[str, Any] = {"target_x": np.tile(grid, points),
                               "target_y": np.repeat(grid, points)}
    usable = found.usable
    for b, name in enumerate(BRANCHES):
        columns[name] = usable[b].ravel()
    columns["reachable"] = usable.any(axis=0).ravel()
    columns["abs_sin_th1"] = found.best_margin.ravel()
    for b, name in enumerate(BRANCHES):
        columns[f"abs_sin_th1_{name}"] = found.margin[b].ravel()
        for i in range(3):
            columns[f"theta{i}_{name}"] = found.theta[b, ..., i].ravel()
    frame = pd.DataFrame(columns)
    frame.attrs["units"] = units_of(frame.columns)
    metrics: dict[str, Any] = {f"area_{k}": v for k, v in areas.items()}
    metrics.update(area_grid=found.cell_area * points**2, start=[float(v) for v in start],
                   attitude_low=float(found.attitudes[0]),
                   attitude_high=float(found.attitudes[-1]),
                   attitudes=len(found.attitudes), points=points, extent=span, thin=thin)
    return WorkspaceResult(s, frame, metrics, found)


def load(directory: str | os.PathLike[str]) -> Run:
    """The run a directory holds: a PlanResult, TrackResult (also ``sweep --rerun``) or
    SweepResult (finished or not); other runs (``reproduce``) as a plain Run.

    A directory of runs of one name (``runs/<name>``) loads its ``latest`` plan or track run,
    or, if it has none, its sweep (``runs/<name>/sweep``).
    """
    import pandas as pd

    from flatcli.montecarlo.directory import read_manifest

    path = Path(directory)
    if kind(path / SWEEP_MANIFEST) == "missing" and kind(path / RECORD) == "missing" and \
            not (path / "latest").is_dir() and kind(path / SWEEP_DIR / SWEEP_MANIFEST) != \
            "missing":
        path = path / SWEEP_DIR
    if kind(path / SWEEP_MANIFEST) != "missing":
        read_manifest(path)  # SpecError saying what is wrong with it
        state = sweep_state(path)
        if state is None:
            raise FlatcliError(f"{path}/{SWEEP_MANIFEST} is unreadable")
        return SweepResult(state)
    if kind(path / RECORD) == "missing" and (path / "latest").is_dir():
        return load(path / "latest")
    record = read_json(path / RECORD)
    if record is None:
        if kind(path / RECORD) != "missing":
            raise FlatcliError(f"{path / RECORD} is unreadable (not a regular file of JSON, "
                               "or too large)")
        raise FlatcliError(f"{path} holds no flatcli run (no run.json or sweep.json)")
    command = str(record.get("command"))
    summary, optimization = record.get("summary", {}), record.get("optimization")
    if _table(path, "plan.parquet") and command == "plan":
        return PlanResult(None, pd.read_parquet(path / "plan.parquet"),
                          summary if isinstance(summary, dict) else {},
                          optimization if isinstance(optimization, dict) else None,
                          directory=path, record=record)
    if _table(path, "track.parquet"):
        recorded = record.get("metrics", {})
        metrics = read_json(path / "metrics.json") or (
            recorded if isinstance(recorded, dict) else {})
        return TrackResult(None, pd.read_parquet(path / "track.parquet"), metrics,
                           directory=path, record=record)
    if _table(path, "workspace.parquet") and command == "workspace":
        return WorkspaceResult(spec_of(record), pd.read_parquet(path / "workspace.parquet"),
                               _workspace_metrics(record, path), directory=path, record=record)
    run = Run(path, record)
    run.command = command
    return run


#: What a workspace run's record holds beside its areas (``WorkspaceResult.metrics``).
_WORKSPACE_NUMBERS = ("attitude_low", "attitude_high", "attitudes", "points", "extent", "thin")


def _workspace_metrics(record: Mapping[str, Any], path: Path) -> dict[str, Any]:
    """A workspace run's recorded metrics, checked (a record on disk is not trusted)."""
    metrics = record.get("metrics")
    start = metrics.get("start") if isinstance(metrics, dict) else None
    ok = isinstance(metrics, dict) and isinstance(start, list) and len(start) == 3 and all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in start) and all(
        isinstance(metrics.get(k), int | float) and not isinstance(metrics.get(k), bool)
        for k in _WORKSPACE_NUMBERS)
    if not ok:
        raise FlatcliError(f"{path / RECORD}: not a workspace run's record (its metrics need "
                           f"start (3 numbers) and {', '.join(_WORKSPACE_NUMBERS)})")
    return dict(metrics)  # type: ignore[arg-type]


def sweep_dir_of(directory: str | os.PathLike[str]) -> Path:
    """A sweep's directory from what a user names: the sweep's own, or its name's
    (``runs/<name>``, whose sweep is ``runs/<name>/sweep``)."""
    path = Path(directory)
    if kind(path / SWEEP_MANIFEST) == "missing" and kind(path / SWEEP_DIR / SWEEP_MANIFEST) != \
            "missing":
        return path / SWEEP_DIR
    return path


def runs(root: str | os.PathLike[str] = ROOT, filters: Iterable[str] = (),
         sort: str | None = None, reverse: bool = False) -> pd.DataFrame:
    """The runs below ``root`` as a DataFrame, one row per run (as ``flatcli runs``, and
    like ``mlflow.search_runs``): ``run`` (its directory below root), ``path``, ``command``,
    ``name``, ``time``, ``status``, ``tags``, then every number of the runs' records (a track
    run's metrics, a plan's summary, a sweep's trials by status) and every key of their
    resolved specs, dotted (``plant.model``, ``track.kp``).

    ``filters``: ``--filter`` conditions ("status=ok", "plant.model=dynamic",
    "err_y_final<1e-3", "tag=baseline"); ``sort``: a column (runs without it last).

        >>> df = flatcli.runs(filters=["plant.model=dynamic"])
        >>> df[df["time"] > "2026-11-20"].sort_values("err_y_final")
    """
    from flatcli.catalog import Filter, rows_below, runs_frame, select

    path = Path(root)
    if not path.is_dir():
        raise FlatcliError(f"{path}: no such directory")
    rows = select(rows_below(path), [Filter.parse(f) for f in filters], sort, reverse)
    frame: pd.DataFrame = runs_frame(rows)
    return frame


def _table(directory: Path, name: str) -> bool:
    """Whether a run's directory holds the table ``name`` (FlatcliError if something else
    than a regular file stands there: it is never opened, a FIFO would block)."""
    what = kind(directory / name)
    if what not in ("missing", "file"):
        raise FlatcliError(f"{directory / name} is {what}, not a table flatcli wrote")
    return what == "file"
