"""Figures of one plan and one closed-loop run, and what every figure shares: one style sheet
(``flatcli.mplstyle``, package data), the file a figure is written as (``FigureFile``:
``figures.format`` and ``figures.dpi``, ``--format``, ``--dpi``), print sizes, mathtext labels
with units, and titles that name the conditions of the run.

matplotlib's object API (no pyplot state, no display needed), imported on first use:
plotting is optional work. The style applies only while flatcli draws and saves
(``styled``): a user's own rcParams are never changed.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ParamSpec, TypeVar

import numpy as np
from numpy.typing import NDArray

from flatcli.core.names import DEFAULT_BANDWIDTH_PERIODS, DEFAULT_TERMINAL_PERIODS
from flatcli.storage import atomic_path

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from flatcli.spec import Spec

Array = NDArray[np.float64]
P = ParamSpec("P")
T = TypeVar("T")

#: The style sheet of every figure flatcli draws.
STYLE = Path(__file__).with_name("flatcli.mplstyle")
#: A journal page's two columns [in]: the width of flatcli's figures of a run.
PAGE_WIDTH = 7.2
#: The file formats a figure may be written as (``figures.format``).
FORMATS = ("png", "pdf", "svg")
#: No creation date in a vector file: the same figure gives the same bytes.
_METADATA: dict[str, dict[str, Any]] = {"pdf": {"CreationDate": None}, "svg": {"Date": None},
                                        "png": {}}


@dataclass(frozen=True)
class FigureFile:
    """How a figure is written: its format (png, pdf, svg) and a raster's resolution."""

    format: str = "png"
    dpi: int = 150

    @classmethod
    def of(cls, spec: Spec) -> FigureFile:
        """The spec's ``[figures]``."""
        return cls(spec.figures.format, spec.figures.dpi)

    @classmethod
    def of_tree(cls, tree: Mapping[str, Any]) -> FigureFile:
        """The ``[figures]`` of a spec tree read back from a run's files (defaults where a
        flatcli before ``[figures]`` wrote it)."""
        figures = tree.get("figures", {}) if isinstance(tree, Mapping) else {}
        default = cls()
        fmt = figures.get("format", default.format) if isinstance(figures, Mapping) else None
        dpi = figures.get("dpi", default.dpi) if isinstance(figures, Mapping) else None
        return cls(fmt if fmt in FORMATS else default.format,
                   dpi if isinstance(dpi, int) and not isinstance(dpi, bool) else default.dpi)

    def name(self, stem: str) -> str:
        """A figure's file name: ``plan.pdf``."""
        return f"{stem}.{self.format}"


@contextlib.contextmanager
def style() -> Iterator[None]:
    """flatcli's style sheet, for what is drawn and saved within."""
    import matplotlib

    with matplotlib.rc_context(fname=str(STYLE)):
        yield


def styled(fn: Callable[P, T]) -> Callable[P, T]:
    """A function that draws: it runs within ``style``."""
    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> T:
        with style():
            return fn(*args, **kwargs)

    return wrapper


def new_figure(width: float, height: float) -> Figure:
    """A matplotlib Figure (imported on first use: plotting is optional work)."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height))


def save_figure(fig: Figure, path: Path, file: FigureFile | None = None) -> Path:
    """Write a figure, atomically, in the format of its file name's suffix (png when it has
    none of ``FORMATS``) at ``file``'s resolution; its path."""
    fmt = path.suffix.lstrip(".") if path.suffix.lstrip(".") in FORMATS else "png"
    dpi = (file or FigureFile()).dpi
    # fontTools, subsetting the fonts a PDF embeds, warns about the timestamps matplotlib
    # leaves at 0 (a file without dates): not the user's concern
    fonts = logging.getLogger("fontTools")
    level = fonts.level
    fonts.setLevel(logging.ERROR)
    try:
        with style(), atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=fmt, metadata=_METADATA[fmt])
    finally:
        fonts.setLevel(level)
    return path


def finish_grid(fig: Figure, ax: Any, title: str, path: Path, legend_size: float = 6.5,
                file: FigureFile | None = None) -> None:
    """Legends on every panel of a grid of time plots (2 x 2, 2 x 3), t on the bottom row;
    title, layout, and the file."""
    with style():
        for a in ax.flat:
            if a.get_legend_handles_labels()[0]:
                a.legend(fontsize=legend_size)
        for a in ax[-1]:
            a.set_xlabel("$t$ [s]")
        fig.suptitle(title)
        fig.tight_layout()
        save_figure(fig, path, file)


@dataclass(frozen=True)
class Limits:
    """Thresholds and limits drawn as dashed lines on the figures of a plan or a run
    (None, or inf: not drawn; the title says "none" for inf)."""

    singular_threshold: float | None = None  # track.singular_threshold [rad/s]
    min_margin: float | None = None  # plan.optimize.min_margin [rad/s]
    #: track.rate_limit, or plan.optimize.rate_limit (one for every joint or one per joint)
    rate_limit: float | Sequence[float] | None = None  # [rad/s]
    angle_limit: Sequence[float] | None = None  # plan.optimize.angle_limit, per angle [rad]
    torque_limit: float | None = None  # plant.torque_limit [N m]

    @classmethod
    def of_plan(cls, spec: Spec, optimised: bool) -> Limits:
        """What a plan's figure draws: the singular threshold, and an optimised plan's
        limits."""
        if not optimised:
            return cls(singular_threshold=spec.track.singular_threshold)
        opt = spec.plan.optimize
        return cls(spec.track.singular_threshold, opt.min_margin, opt.rate_limit,
                   opt.angle_limit)

    @classmethod
    def of_track(cls, spec: Spec) -> Limits:
        """What a closed-loop run's figure draws: the singular threshold, the rate limit and
        (the dynamic plant) the torque limit."""
        dynamic = spec.plant.model == "dynamic"
        return cls(singular_threshold=spec.track.singular_threshold,
                   rate_limit=spec.track.rate_limit,
                   torque_limit=spec.plant.torque_limit if dynamic else None)


# ---------------------------------------------------------------------------------------
# Labels and titles.

def quantity(symbol: str, unit: str) -> str:
    """An axis label: a mathtext symbol and its unit in brackets (``$\\theta_1'$ [rad/s]``)."""
    return f"${symbol}$ [{unit}]" if unit else f"${symbol}$"


def unit_text(unit: str) -> str:
    """A unit as mathtext shows it: ``kg m^2/s`` as kg m$^2$/s."""
    return unit.replace("^2", "$^2$").replace("^3", "$^3$")


def limit_text(value: float, unit: str = "") -> str:
    """A limit for a title: "none" for inf (no limit)."""
    return "none" if math.isinf(value) else f"{value:g}{' ' + unit if unit else ''}"


def limit_line(ax: Any, value: float | None, label: str, unit: str, colour: str = "C3",
               symmetric: bool = False) -> None:
    """A dashed horizontal line at a finite threshold or limit (at +-value if
    ``symmetric``), labelled by its key's name (``rate_limit``: track.rate_limit on a run,
    plan.optimize.rate_limit on an optimised plan); none for None or inf (the title says
    "none")."""
    if value is None or not math.isfinite(value):
        return
    sign = r"$\pm$" if symmetric else ""
    text = f"{label} = {sign}{value:g} {unit_text(unit)}"
    if len(label) > 14:  # two lines: a legend no wider than a panel of a page's third
        text = f"{label}\n= {sign}{value:g} {unit_text(unit)}"
    ax.axhline(value, ls="--", lw=1.0, color=colour, label=text)
    if symmetric:
        ax.axhline(-value, ls="--", lw=1.0, color=colour)


def plan_title(spec: Spec, optimization: Mapping[str, Any] | None = None) -> str:
    """A plan figure's title: the run, the robot, the maneuver, and the optimiser's
    objective."""
    n = spec.joints
    robot = "the paper's robot" if n == 2 else f"a robot of {n} joints"
    line = (f"plan {spec.name!r}: {robot}, {spec.robot.model} model, "
            f"T = {spec.plan.duration:g} s")
    if optimization is not None:
        state = "" if optimization.get("success") else " (not converged)"
        line += f", optimised for {optimization.get('objective')}{state}"
    return line


def plant_text(spec: Spec) -> str:
    """The plant a run integrates, as a title names it."""
    plant = spec.plant
    if plant.model != "dynamic":
        return "kinematic plant"
    model = "the robot's model" if plant.servo_model == "robot" else "the plant's model"
    return f"dynamic plant (servo {plant.servo_bandwidth:g} rad/s, {model})"


def track_title(spec: Spec, metrics: Mapping[str, Any] | None = None) -> str:
    """A closed-loop run's title: the run, the plant, the sensor noise, the rate and torque
    limits, the gains (the as-built law's weights) and the status."""
    track, plant = spec.track, spec.plant
    torque = limit_text(plant.torque_limit, "N m") if plant.model == "dynamic" else \
        "n/a (no torques)"
    duration = float(spec.plan.duration)  # the as-built law's default weights scale with it
    bandwidth = (DEFAULT_BANDWIDTH_PERIODS / duration if track.lqr_bandwidth is None
                 else track.lqr_bandwidth)
    terminal = (DEFAULT_TERMINAL_PERIODS * duration if track.lqr_terminal is None
                else track.lqr_terminal)
    status = ""
    if metrics is not None and metrics.get("status"):
        status = f"; status {metrics['status']}"
        if metrics.get("event_time") is not None and metrics["status"] != "singular":
            status += f" at $t$ = {float(metrics['event_time']):.4g} s"
    law = (f"$k_p$ = {_numbers(track.kp)}, $k_v$ = {_numbers(track.kv)}"
           if track.controller != "asbuilt" else
           f"as-built LQR: $b$ = {bandwidth:g} rad/s, lqr_base = {track.lqr_base:g}, "
           f"lqr_terminal = {terminal:g} s")
    return (f"track {spec.name!r}: {plant_text(spec)}\n"
            f"sensor noise {limit_text(track.sensor_noise, 'rad')}, rate limit "
            f"{limit_text(track.rate_limit, 'rad/s')}, torque limit {torque}\n"
            f"{law}{status}")


def _numbers(values: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v:g}" for v in values) + ")"


def margin_label(joints: int, rate: str) -> str:
    """The singularity margin: abs(sin th1 * th1') on the paper's robot, the rate of change of
    the base's locked inertia beyond it (``rate``: the symbol of th1', e.g. ``u_1``)."""
    if joints == 2:
        return rf"$|\sin\theta_1\,{rate}|$"
    return r"$|\dot h_0|\,/\,(2|K_{10}|)$"


def _joints(cols: Mapping[str, Any]) -> int:
    """N, the joints of a plan's or a run's columns (theta0..thetaN)."""
    return sum(1 for name in cols if name.startswith("theta") and name[5:].isdigit()) - 1


def columns(frame: Any) -> dict[str, Array]:
    """A plan's or a run's table (a DataFrame, or a dict of arrays) as float arrays (null:
    nan, not drawn)."""
    if isinstance(frame, Mapping):
        return {str(k): np.asarray(v, dtype=np.float64) for k, v in frame.items()}
    return {str(k): frame[k].to_numpy(dtype=np.float64, na_value=np.nan) for k in frame.columns}


# ---------------------------------------------------------------------------------------
# A plan.

def plot_plan(frame: Any, path: Path, title: str, limits: Limits | None = None,
              file: FigureFile | None = None) -> Path:
    """A plan as one file (``plan_figure``)."""
    fig = plan_figure(frame, limits, title)
    return save_figure(fig, path, file)


@styled
def plan_figure(frame: Any, limits: Limits | None = None, title: str = "") -> Figure:
    """A plan's panels: flat outputs (the paper's Fig. 2), angles (Fig. 3), joint rates,
    the singularity margin (log axis: a plan never touches 0) with its thresholds, H from
    the full kinematics on a linear axis of its own (rounding for a correct plan), and the
    inputs u_j'. Limits, when given and finite, are dashed lines.

    ``frame``: plan.parquet's columns (a DataFrame, or a dict of arrays).
    """
    cols = columns(frame)
    lim = limits or Limits()
    fig = new_figure(PAGE_WIDTH, 4.6)
    ax = fig.subplots(2, 3, sharex=True)
    t = cols["t"]
    n = _joints(cols)
    for j in range(1, n + 1):
        ax[0, 0].plot(t, cols[f"y{j}"], color=f"C{j - 1}",
                      label=f"$y_{j} = \\theta_{j}$" if j < n else f"$y_{j}$")
    ax[0, 0].set_ylabel(quantity("y_j", "rad"))
    for i in range(n + 1):
        ax[0, 1].plot(t, cols[f"theta{i}"], color=f"C{i}", label=f"$\\theta_{i}$")
        ax[0, 2].plot(t, cols[f"theta{i}_dot"], color=f"C{i}", label=f"$\\theta_{i}'$")
        bound = None if lim.angle_limit is None else lim.angle_limit[i]
        limit_line(ax[0, 1], bound, f"angle_limit[{i}]", "rad",
                   colour=f"C{i}", symmetric=True)
    if isinstance(lim.rate_limit, Sequence):
        for j, bound in enumerate(lim.rate_limit, start=1):
            limit_line(ax[0, 2], bound, f"rate_limit[{j - 1}]", "rad/s",
                       colour=f"C{j}", symmetric=True)
    else:
        limit_line(ax[0, 2], lim.rate_limit, "rate_limit", "rad/s",
                   symmetric=True)
    ax[0, 1].set_ylabel(quantity(r"\theta_i", "rad"))
    ax[0, 2].set_ylabel(quantity(r"\theta_i'", "rad/s"))
    margin = cols["margin"]
    if np.any(np.isfinite(margin)):
        ax[1, 0].semilogy(t, margin, color="C6", label=margin_label(n, r"\theta_1'"))
        limit_line(ax[1, 0], lim.singular_threshold, "singular_threshold", "rad/s")
        limit_line(ax[1, 0], lim.min_margin, "min_margin", "rad/s", colour="C1")
        ax[1, 0].set_ylim(top=30 * float(np.nanmax(margin)))  # room for the legend above
    else:  # an exact plan (plan.method = "exact"): no flat outputs, no margin
        ax[1, 0].text(0.5, 0.5, "no singularity margin\n(exact plan: no flat outputs)",
                      ha="center", va="center", transform=ax[1, 0].transAxes)
        ax[1, 0].set_yticks([])
    ax[1, 0].set_ylabel("singularity margin [rad/s]")
    ax[1, 1].plot(t, cols["momentum"], color="C4", label="$H$ (full link kinematics)")
    ax[1, 1].set_ylabel(quantity("H", unit_text("kg m^2/s")))
    for j in range(1, n):
        ax[1, 2].plot(t, cols[f"u{j}_dot"], color=f"C{j}", label=f"$u_{j}' = \\theta_{j}''$")
    ax[1, 2].set_ylabel(quantity(r"u_j'", unit_text("rad/s^2")))
    _finish(fig, ax, title)
    return fig


def _finish(fig: Figure, ax: Any, title: str) -> None:
    """Legends where a panel has labelled lines, t on the bottom row, the title, the
    layout."""
    for a in ax.flat:
        if a.get_legend_handles_labels()[0]:
            a.legend(loc="best")
    for a in ax[-1]:
        a.set_xlabel("$t$ [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout(h_pad=0.6, w_pad=0.8)


# ---------------------------------------------------------------------------------------
# A closed-loop run.

def plot_track(frame: Any, path: Path, title: str, limits: Limits | None = None,
               file: FigureFile | None = None) -> Path:
    """A closed-loop run against its reference (the paper's Fig. 4) as one file
    (``track_figure``)."""
    fig = track_figure(frame, limits, title)
    return save_figure(fig, path, file)


def _dynamic(cols: Mapping[str, Array]) -> bool:
    """Whether a run's columns hold joint torques (the dynamic plant)."""
    return "tau1" in cols and bool(np.isfinite(cols["tau1"]).any())


@styled
def track_figure(frame: Any, limits: Limits | None = None, title: str = "") -> Figure:
    """A closed-loop run's panels: flat outputs, angles (each beside its reference, dashed),
    applied joint rates, tracking errors (log axis), the margin (log axis, with the singular
    threshold) and H from the full kinematics (linear axis); on the dynamic plant a third
    row: the joint torques (with the torque limit), the servos' rate errors (command minus
    applied rate) and the joints' mechanical power. Samples after a trial stopped are empty
    (nan) and not drawn; a dotted line marks the stop.

    ``frame``: track.parquet's columns (a DataFrame, or a dict of arrays).
    """
    cols = columns(frame)
    lim = limits or Limits()
    dynamic = _dynamic(cols)
    rows = 3 if dynamic else 2
    fig = new_figure(PAGE_WIDTH, 2.3 * rows)
    ax = fig.subplots(rows, 3, sharex=True)
    t = cols["t"]
    n = _joints(cols)
    for j in range(1, n + 1):
        ax[0, 0].plot(t, cols[f"y{j}"], color=f"C{j - 1}", label=f"$y_{j}$")
        ax[0, 0].plot(t, cols[f"y{j}_ref"], "--", color=f"C{j - 1}", lw=0.9)
    for i in range(n + 1):
        ax[0, 1].plot(t, cols[f"theta{i}"], color=f"C{i}", label=f"$\\theta_{i}$")
        ax[0, 1].plot(t, cols[f"theta{i}_ref"], "--", color=f"C{i}", lw=0.9)
    for a in (ax[0, 0], ax[0, 1]):
        a.plot([], [], "--", color="0.4", lw=0.9, label="plan (reference)")
    for i in range(1, n + 1):
        ax[0, 2].plot(t, cols[f"theta{i}_dot"], color=f"C{i}", label=f"$\\theta_{i}'$")
    assert not isinstance(lim.rate_limit, Sequence)  # track.rate_limit is one number
    limit_line(ax[0, 2], lim.rate_limit, "rate_limit", "rad/s", symmetric=True)
    ey = np.sqrt(sum((cols[f"y{j}"] - cols[f"y{j}_ref"]) ** 2 for j in range(1, n + 1)))
    eth = np.sqrt(sum((cols[f"theta{i}"] - cols[f"theta{i}_ref"]) ** 2 for i in range(n + 1)))
    ax[1, 0].semilogy(t, ey, color="C0", label=r"$\|y - y_\mathrm{ref}\|$")
    ax[1, 0].semilogy(t, eth, color="C1", label=r"$\|\theta - \theta_\mathrm{ref}\|$")
    margined = bool(np.any(np.isfinite(cols["margin"])))
    if margined:
        ax[1, 1].semilogy(t, cols["margin"], color="C6", label=margin_label(n, "u_1"))
        limit_line(ax[1, 1], lim.singular_threshold, "singular_threshold", "rad/s")
    else:  # the as-built law: no singular set, no margin recorded
        ax[1, 1].text(0.5, 0.5, "no singular set\n(as-built law)", ha="center", va="center",
                      transform=ax[1, 1].transAxes)
        ax[1, 1].set_yticks([])
    if "momentum" in cols:
        ax[1, 2].plot(t, cols["momentum"], color="C4", label="$H$ (full link kinematics)")
    ax[0, 0].set_ylabel(quantity("y_j", "rad"))
    ax[0, 1].set_ylabel(quantity(r"\theta_i", "rad"))
    ax[0, 2].set_ylabel("applied " + quantity(r"\theta_j'", "rad/s"))
    ax[1, 0].set_ylabel("tracking error [rad]")
    ax[1, 1].set_ylabel("singularity margin [rad/s]")
    ax[1, 2].set_ylabel(quantity("H", unit_text("kg m^2/s")))
    if dynamic:
        _actuator_row(ax[2], cols, n, lim)
    if margined:
        ax[1, 1].set_ylim(top=30 * float(np.nanmax(cols["margin"], initial=1.0)))  # legend
    valid = t[np.isfinite(cols["theta0"])]
    if len(valid) and valid[-1] < t[-1]:  # the trial stopped early: mark where, once
        for a in ax.flat:
            a.axvline(valid[-1], ls=":", lw=1.0, color="0.3")
        ax[0, 0].plot([], [], ":", lw=1.0, color="0.3",
                      label=f"stopped after $t$ = {valid[-1]:.4g} s")
    _finish(fig, ax, title)
    return fig


def _actuator_row(ax: Any, cols: Mapping[str, Array], n: int, lim: Limits) -> None:
    """The dynamic plant's actuators: joint torques tau_j with the torque limit, the servos'
    rate errors u_j - th_j' (command minus applied rate), and the joints' power tau_j th_j'."""
    t = cols["t"]
    for j in range(1, n + 1):
        tau, rate = cols[f"tau{j}"], cols[f"theta{j}_dot"]
        ax[0].plot(t, tau, color=f"C{j}", label=f"$\\tau_{j}$")
        ax[1].plot(t, cols[f"u{j}"] - rate, color=f"C{j}", label=f"$u_{j} - \\theta_{j}'$")
        ax[2].plot(t, tau * rate, color=f"C{j}", label=f"$\\tau_{j}\\,\\theta_{j}'$")
    limit_line(ax[0], lim.torque_limit, "torque_limit", "N m", symmetric=True)
    ax[0].set_ylabel(quantity(r"\tau_j", "N m"))
    ax[1].set_ylabel("servo rate error [rad/s]")
    ax[2].set_ylabel("joint power [W]")
