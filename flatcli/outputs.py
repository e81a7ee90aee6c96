"""The files of ``plan`` and ``track`` runs: their Parquet tables, each built in one place.

``flatcli plan``, ``flatcli track``, ``flatcli sweep --rerun`` and ``flatcli reproduce`` all
write their tables through these functions, so a plan or a track table has the same columns
whichever command wrote it (docs/outputs.md lists them). Each frame carries its
columns' units in ``frame.attrs["units"]`` (``flatcli.units``), which ``write_parquet`` writes as
Arrow field metadata; a value that does not apply (a sample after a trial stopped) is null.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from flatcli.core.plan.planning import PlanSamples
from flatcli.core.robots.kinematics import base_position, end_effector
from flatcli.core.robots.params import RobotParams
from flatcli.experiment import TrackRun
from flatcli.report import FigureFile, Limits, plot_track
from flatcli.storage import write_json, write_parquet
from flatcli.units import units_of


def positions(robot: RobotParams, theta: Any) -> dict[str, Any]:
    """The end effector's and the base's positions (``ee_x``, ``ee_y``, ``base_x``,
    ``base_y`` [m]) at angles theta (n, N + 1), the system's centre of mass at the origin
    (``core.kinematics``)."""
    ee = end_effector(robot, theta)
    base = base_position(robot, theta)
    return {"ee_x": ee[:, 0], "ee_y": ee[:, 1], "base_x": base[:, 0], "base_y": base[:, 1]}


def plan_frame(samples: PlanSamples, robot: RobotParams | None = None) -> pd.DataFrame:
    """plan.parquet's rows: angles, rates, inputs, flat outputs, margin and H per sample
    (th0..thN, u1'..u(N-1)' and uN = thN', y1..yN on a robot of N joints), and with the
    ``robot`` the end effector's and base's positions (``positions``)."""
    n = samples.theta.shape[-1] - 1  # N joints
    columns: dict[str, Any] = {"t": samples.t}
    for i in range(n + 1):
        columns[f"theta{i}"] = samples.theta[:, i]
    for i in range(n + 1):
        columns[f"theta{i}_dot"] = samples.theta_dot[:, i]
    for j in range(1, n):
        columns[f"u{j}_dot"] = samples.u_dot[:, j - 1]
    columns[f"u{n}"] = samples.theta_dot[:, n]
    for name, arr in (("", samples.y), ("_dot", samples.y_dot), ("_ddot", samples.y_ddot)):
        for j in range(n):
            columns[f"y{j + 1}{name}"] = arr[:, j]
    columns["margin"] = samples.margin
    columns["momentum"] = samples.momentum
    if robot is not None:
        columns.update(positions(robot, samples.theta))
    frame = pd.DataFrame(columns)  # built at once: one block, no fragmentation warnings
    frame.attrs["units"] = units_of(frame.columns)
    return frame


def track_frame(run: TrackRun) -> pd.DataFrame:
    """track.parquet's rows (``TrackRun.columns``)."""
    frame = pd.DataFrame(run.columns)
    frame.attrs["units"] = units_of(frame.columns)
    return frame


def write_track(directory: Path, run: TrackRun, record: Mapping[str, Any],
                plot_title: str | None = None, file: FigureFile | None = None) -> list[str]:
    """track.parquet, metrics.json, run.json (and with a title the figure, ``track.png``
    or the format of ``file``, default the run spec's ``[figures]``); their names."""
    write_parquet(directory / "track.parquet", track_frame(run), record)
    write_json(directory / "metrics.json", run.metrics)
    write_json(directory / "run.json", record)
    names = ["track.parquet", "metrics.json"]
    if plot_title is not None:
        file = file or FigureFile.of(run.spec)
        plot_track(run.columns, directory / file.name("track"), plot_title,
                   track_limits(run), file)
        names.append(file.name("track"))
    return names


def track_limits(run: TrackRun) -> Limits:
    """The thresholds a track figure draws: the singular threshold, the rate limit and (on
    the dynamic plant) the torque limit."""
    return Limits.of_track(run.spec)
