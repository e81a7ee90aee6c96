"""Workspace maps of the N = 2 robot: where its end effector can be put at the end of a
maneuver, on which elbow branch, and how far from the flat map's singular set, for final
base attitudes in a window.

A target r (2,) [m] (inertial frame, origin at the system's centre of mass) with final base
attitude th0 is reached by the configurations of ``inverse.two_link``: the two elbow
branches ("up": th2 in (0, pi), "down": th2 in (-pi, 0)) of the virtual manipulator, which
exist where |r - v_0 e(th0)| lies in [|v_1 - v_2|, v_1 + v_2]. A branch is *usable* from the
start if its th1 lies on the start's side of the singular set sin th1 = 0 (a flat plan's th1
cannot cross it, ``flatness``), as ``task.end_effector`` demands (``inverse.two_link_task``).

The map samples the window at ``attitudes`` equally spaced values of th0 (both ends
included): a target counts as usable on a branch if one sampled attitude makes it so, and
its ``margin`` is the largest |sin th1| over those attitudes, the configuration's part of the
flat map's margin |sin y1 y1'| (y1 = th1) at the goal. A target reachable only at attitudes
between two samples is not marked: the map's resolution in th0 is (hi - lo) / (attitudes - 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from flatcli.core.errors import FlatcliError
from flatcli.core.plan.inverse import nearest, two_link
from flatcli.core.robots.kinematics import virtual_links
from flatcli.core.robots.params import RobotParams

Array = NDArray[np.float64]
#: The branches, in the order of a map's first axis.
BRANCHES = ("up", "down")
#: Sampled attitudes of a window by default, and the most (memory is ny nx per sample).
DEFAULT_ATTITUDES = 181
MAX_ATTITUDES = 100_000
#: The most (target, attitude) pairs one map solves: about 100 s on one core (250 ns each).
MAX_PAIRS = 400_000_000


@dataclass(frozen=True)
class WorkspaceMap:
    """Where the end effector can be put (``workspace_map``).

    x (nx,), y (ny,) [m]: the grid of targets; attitudes (k,) [rad]: the sampled final base
    attitudes; margin (2, ny, nx) [-]: per branch (``BRANCHES``) the largest |sin th1| over the
    attitudes at which the branch is usable (nan where none is); theta (2, ny, nx, 3) [rad]: the
    configuration of that largest margin (nan where none; th1 the representative nearest the
    start's, th2 in [-pi, pi]).
    """

    x: Array
    y: Array
    attitudes: Array
    margin: Array
    theta: Array

    @property
    def usable(self) -> NDArray[np.bool_]:
        """(2, ny, nx) whether each branch reaches each target from the start."""
        return np.asarray(np.isfinite(self.margin))

    @property
    def best_margin(self) -> Array:
        """(ny, nx) the larger of the two branches' margins (nan where neither is usable)."""
        margin = np.where(self.usable, self.margin, -np.inf).max(axis=0)
        return np.asarray(np.where(np.isfinite(margin), margin, np.nan), dtype=float)

    @property
    def cell_area(self) -> float:
        """The area one grid point stands for [m^2]."""
        return float(_spacing(self.x) * _spacing(self.y))


def _spacing(values: Array) -> float:
    return float(values[1] - values[0]) if len(values) > 1 else 0.0


def workspace_map(robot: RobotParams, start: ArrayLike, window: tuple[float, float],
                  x: ArrayLike, y: ArrayLike, attitudes: int = DEFAULT_ATTITUDES
                  ) -> WorkspaceMap:
    """The map of targets (x[j], y[i]) an N = 2 robot starting at ``start`` (3,) [rad] can
    put its end effector on, for final base attitudes in ``window`` = (lo, hi) [rad].

    Raises
    ------
    FlatcliError: a robot of N != 2 joints, a window with hi < lo, fewer than 1 or more than
    ``MAX_ATTITUDES`` attitudes, or a grid of fewer than 2 points per axis.
    """
    if robot.n_joints != 2:
        raise FlatcliError(f"workspace: maps the N = 2 robot's elbow branches; this robot has "
                           f"N = {robot.n_joints} joints (an N >= 3 arm is redundant)")
    lo, hi = (float(w) for w in window)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
        raise FlatcliError(f"--attitude: expected LO <= HI, finite [rad], got {lo:g} {hi:g}")
    if not 1 <= attitudes <= MAX_ATTITUDES:
        raise FlatcliError(f"--attitudes: expected 1 to {MAX_ATTITUDES}, got {attitudes}")
    xs, ys = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    if xs.ndim != 1 or ys.ndim != 1 or len(xs) < 2 or len(ys) < 2:
        raise FlatcliError("workspace: the grid needs at least 2 points on each axis")
    pairs = len(xs) * len(ys) * attitudes
    if pairs > MAX_PAIRS:
        raise FlatcliError(f"--points and --attitudes: {len(xs)} x {len(ys)} targets at "
                           f"{attitudes} attitudes are {pairs:.3g} inverse kinematics, more "
                           f"than {MAX_PAIRS:.0e} (about 100 s); lower --points or --attitudes")
    if float(virtual_links(robot)[1]) == 0.0:
        two_link(robot, np.zeros(2), 0.0)  # raises its one-line reason
    ref = np.asarray(start, dtype=float)
    samples = np.linspace(lo, hi, attitudes) if hi > lo else np.array([lo])
    target = np.stack(np.meshgrid(xs, ys))  # (2, ny, nx)
    margin = np.full((2, len(ys), len(xs)), -np.inf)
    theta = np.full((2, len(ys), len(xs), 3), np.nan)
    side = math.floor(float(ref[1]) / math.pi)  # th1 must stay in (side pi, (side + 1) pi)
    for th0 in samples:
        for b, q in enumerate(two_link(robot, target, th0)):
            th1 = nearest(q[..., 1], ref[1])
            q = np.stack([q[..., 0], th1, q[..., 2]], axis=-1)
            m = np.where((th1 > side * math.pi) & (th1 < (side + 1) * math.pi),
                         np.abs(np.sin(th1)), np.nan)
            better = np.isfinite(m) & (m > margin[b])
            margin[b] = np.where(better, m, margin[b])
            theta[b] = np.where(better[..., None], q, theta[b])
    margin = np.where(np.isfinite(margin), margin, np.nan)
    return WorkspaceMap(xs, ys, samples, margin, theta)


def workspace_areas(found: WorkspaceMap, thin: float) -> dict[str, float]:
    """Areas of the map [m^2]: reachable on either branch, on both, on "up" only, on "down"
    only, and with a best margin under ``thin`` (reachable, but near sin th1 = 0)."""
    up, down = found.usable
    best = found.best_margin
    cell = found.cell_area
    return {
        "reachable": float((up | down).sum() * cell),
        "both": float((up & down).sum() * cell),
        "up_only": float((up & ~down).sum() * cell),
        "down_only": float((down & ~up).sum() * cell),
        "thin": float(((up | down) & (np.nan_to_num(best, nan=np.inf) < thin)).sum() * cell),
    }


__all__ = ["BRANCHES", "WorkspaceMap", "workspace_areas", "workspace_map"]
