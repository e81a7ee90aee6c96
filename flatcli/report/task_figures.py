"""Figures of a task: a filmstrip of the robot among the obstacles, and its animation.

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

from flatcli.core.kinematics import joint_positions
from flatcli.core.model import RobotParams
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


__all__ = ["animate", "filmstrip_figure"]
