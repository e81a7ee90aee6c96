"""Figures of a task: a filmstrip of the robot among the obstacles, its animation, and the
map of where the end effector can be put (``workspace_figure``).

The links are drawn as segments between their joints (``core.kinematics.joint_positions``,
the system's centre of mass at the origin, marked +), the base thicker; obstacles as discs
with their clearance ring dashed; the end effector's path as a line and the target as x.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core.plan.workspace import WorkspaceMap
from flatcli.core.robots.kinematics import joint_positions
from flatcli.core.robots.params import RobotParams
from flatcli.report.figures import PAGE_WIDTH, new_figure, style, styled

Array = NDArray[np.float64]

#: Instants of the filmstrip.
FRAMES = 6


def _scene(ax: Any, robot: RobotParams, theta: Array, obstacles: Sequence[Sequence[float]],
           clearance: float, target: Sequence[float] | None) -> None:
    from matplotlib.patches import Circle

    points = joint_positions(robot, theta)
    for x, y, r in obstacles:
        ax.add_patch(Circle((x, y), r, color="0.6", alpha=0.7, lw=0))
        if clearance > 0:
            ax.add_patch(Circle((x, y), r + clearance, fill=False, ls="--", lw=0.6,
                                color="0.4"))
    ax.plot(points[:, -1, 0], points[:, -1, 1], color="C1", lw=0.8, label="end effector")
    if target is not None:
        ax.plot([target[0]], [target[1]], "x", color="C3", ms=6, label="target")
    ax.plot([0.0], [0.0], "+", color="k", ms=6, label="centre of mass")
    ax.set_aspect("equal")
    ax.set_xlabel("$x$ [m]")
    ax.set_ylabel("$y$ [m]")


def _links(ax: Any, points: Array, alpha: float, label: str | None = None) -> list[Any]:
    base = ax.plot(points[:2, 0], points[:2, 1], color="C0", lw=3.0, alpha=alpha,
                   solid_capstyle="round", label=label)
    arm = ax.plot(points[1:, 0], points[1:, 1], "o-", color="C0", lw=1.4, ms=2.5, alpha=alpha)
    return [*base, *arm]


@styled
def filmstrip_figure(robot: RobotParams, t: Array, theta: Array,
                     obstacles: Sequence[Sequence[float]] = (), clearance: float = 0.0,
                     target: Sequence[float] | None = None, title: str = "",
                     frames: int = FRAMES) -> Any:
    """The robot at ``frames`` instants (fading from the start to the goal), the obstacles
    and the end effector's path; t (n,) [s], theta (n, N + 1) [rad]."""
    fig = new_figure(PAGE_WIDTH / 2, PAGE_WIDTH / 2)
    ax = fig.subplots()
    _scene(ax, robot, theta, obstacles, clearance, target)
    points = joint_positions(robot, theta)
    picks = np.linspace(0, len(t) - 1, frames).round().astype(int)
    for k, i in enumerate(picks):
        alpha = 0.25 + 0.75 * k / max(frames - 1, 1)
        _links(ax, points[i], alpha, "links" if k == frames - 1 else None)
        ax.annotate(f"{t[i]:.2g} s", points[i, -1], fontsize=5, xytext=(2, 2),
                    textcoords="offset points")
    ax.legend(fontsize=5, loc="best")
    if title:
        ax.set_title(title, fontsize=7)
    fig.tight_layout()
    return fig


def animate(robot: RobotParams, t: Array, theta: Array, path: Path,
            obstacles: Sequence[Sequence[float]] = (), clearance: float = 0.0,
            target: Sequence[float] | None = None, fps: int = 25) -> Path:
    """The maneuver as a GIF (matplotlib's Pillow writer) at ``fps`` frames per second of
    maneuver time, from samples t (n,), theta (n, N + 1)."""
    from matplotlib.animation import FuncAnimation, PillowWriter

    with style():
        fig = new_figure(PAGE_WIDTH / 2, PAGE_WIDTH / 2)
        ax = fig.subplots()
        _scene(ax, robot, theta, obstacles, clearance, target)
        points = joint_positions(robot, theta)
        lines = _links(ax, points[0], 1.0)
        frames = np.unique(np.searchsorted(t, np.arange(0.0, float(t[-1]) + 1e-12, 1.0 / fps)))
        frames = np.minimum(frames, len(t) - 1)
        label = ax.text(0.02, 0.95, "", transform=ax.transAxes, fontsize=6)

        def draw(i: int) -> list[Any]:
            p = points[i]
            lines[0].set_data(p[:2, 0], p[:2, 1])
            lines[1].set_data(p[1:, 0], p[1:, 1])
            label.set_text(f"t = {t[i]:.2f} s")
            return [*lines, label]

        fig.tight_layout()
        movie = FuncAnimation(fig, draw, frames=list(frames), blit=False)
        movie.save(str(path), writer=PillowWriter(fps=fps))
    return path


#: Colours of a workspace map's regions: not reachable, "up" only, "down" only, both branches.
REGIONS = (("not reachable", "white"), ("elbow up only", "#9ecae1"),
           ("elbow down only", "#fdae6b"), ("both branches", "#a1d99b"))


@styled
def workspace_figure(found: WorkspaceMap, robot: RobotParams, start: Array, thin: float,
                     title: str = "", target: Sequence[float] | None = None,
                     obstacles: Sequence[Sequence[float]] = ()) -> Any:
    """Where the end effector can be put: each target coloured by the elbow branches that
    reach it from ``start`` (3,) [rad], the region where the best |sin th1| is under ``thin``
    hatched, the robot drawn at its start, the system's centre of mass marked +, and a task's
    ``target`` (x) and ``obstacles`` (discs x, y, radius [m]) if given."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Circle, Patch

    up, down = found.usable
    region = up.astype(int) + 2 * down.astype(int)  # 0 none, 1 up, 2 down, 3 both
    fig = new_figure(PAGE_WIDTH / 2, PAGE_WIDTH / 2 + 0.7)
    ax = fig.subplots()
    dx = float(found.x[1] - found.x[0])
    dy = float(found.y[1] - found.y[0])
    extent = (found.x[0] - dx / 2, found.x[-1] + dx / 2, found.y[0] - dy / 2, found.y[-1] + dy / 2)
    ax.imshow(region, origin="lower", extent=extent, interpolation="nearest",
              cmap=ListedColormap([c for _, c in REGIONS]), vmin=-0.5, vmax=3.5)
    best = np.nan_to_num(found.best_margin, nan=np.inf)
    low = ((up | down) & (best < thin)).astype(float)
    if low.any():
        ax.contourf(found.x, found.y, low, levels=[0.5, 1.5], colors="none", hatches=["////"])
    _links(ax, joint_positions(robot, start), 1.0, "start")
    ax.plot([0.0], [0.0], "+", color="k", ms=6)
    for x, y, r in obstacles:
        ax.add_patch(Circle((x, y), r, color="0.6", alpha=0.7, lw=0))
    if target is not None:
        ax.plot([target[0]], [target[1]], "x", color="C3", ms=6)
    handles = [Patch(facecolor=c, edgecolor="0.5", lw=0.4, label=name) for name, c in REGIONS]
    handles.append(Patch(facecolor="none", edgecolor="0.3", hatch="////",
                         label=f"|sin th1| < {thin:g}"))
    ax.legend(handles=handles, fontsize=5, loc="upper center", bbox_to_anchor=(0.5, -0.14),
              ncol=3, frameon=False)
    ax.grid(False)
    ax.set_aspect("equal")
    ax.set_xlabel("$x$ [m]")
    ax.set_ylabel("$y$ [m]")
    if title:
        ax.set_title(title, fontsize=7)
    fig.tight_layout()
    return fig


__all__ = ["animate", "filmstrip_figure", "workspace_figure"]
