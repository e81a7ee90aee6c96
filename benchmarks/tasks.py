"""make bench: tasks among obstacles (issue 21), the goals measured.

* the capture task (``flatcli/data/capture.toml``: three discs, rest to rest, clearance proven
  over [0, T]) planned and verified through the public API, ``flatcli.plan`` and its metrics:
  the median of repeated calls against the goal of 10 ms;
* random tasks of the paper's robot from its start (a target in its annulus, a final base
  attitude, three discs 3 cm clear of the robot at its start), each planned through
  ``flatcli.plan``; every plan flatcli accepts re-checked on a grid 100x finer than its own
  (20,001 samples) by link kinematics written here in the complex plane (the centre of mass
  solved for, nothing taken from ``flatcli.core.kinematics``): violations counted, the goal
  is none.

python-control's flatsys with the same constraints at its time points is not run here (its
violations between points are not counted in this bench yet).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

TIMING = "Tasks (issue 21): the capture task through the public API"
RANDOM = "Tasks (issue 21): random tasks among three discs, re-checked 100x finer"
HEADERS = {
    TIMING: ["what", "value", "goal", "note"],
    RANDOM: ["tasks", "planned", "refused", "violations", "least margin [m]", "goal", "note"],
}
#: The grid of the re-check: 100 x the plan's own 200 intervals.
FINE = 100 * 200 + 1
#: The paper's robot (mass, length, com of its three links) and its start (Sec. VI).
PAPER = (np.ones(3), np.full(3, 0.2), np.array([0.1, 0.1, 0.0]))
START = np.array([1.8, 1.0, 0.0])

Array = NDArray[np.float64]


def link_clearance(mass: Array, length: Array, com: Array, theta: Array,
                   obstacles: Array) -> Array:
    """(n,) the least distance of any link segment from any disc's surface [m] at each row
    of theta (n, N + 1): joints placed in the complex plane from the links' definitions, the
    base's end moved so that the masses' centre is at the origin."""
    psi = np.cumsum(theta, axis=1)
    e = np.exp(1j * psi)
    rel = np.concatenate([np.zeros((len(theta), 1)), np.cumsum(length * e, axis=1)], axis=1)
    centres = rel[:, :-1] + com * e
    joints = rel - (np.sum(mass * centres, axis=1) / mass.sum())[:, None]
    a, b = joints[:, :-1], joints[:, 1:]
    out = np.full(len(theta), np.inf)
    for x, y, radius in obstacles:
        c = complex(x, y)
        d = b - a
        s = np.clip(((c - a) * np.conj(d)).real / np.maximum(np.abs(d) ** 2, 1e-300), 0, 1)
        out = np.minimum(out, (np.abs(a + s * d - c) - radius).min(axis=1))
    return out


def capture_timing(bench: Any) -> dict[str, Any]:
    import flatcli

    spec = "flatcli/data/capture.toml"
    assert flatcli.plan(spec).metrics  # warm: the spec, numba's caches
    times: list[float] = []
    for _ in range(15 if bench.quick else 41):
        started = time.perf_counter()
        p = flatcli.plan(spec)
        assert p.metrics  # the certificate and the task's metrics are part of the call
        times.append(time.perf_counter() - started)
    median = float(np.median(times))
    m = p.metrics
    bench.row(TIMING, "plan and prove the capture task (`flatcli.plan`, median)",
              f"{median * 1e3:.1f} ms", "<= 10 ms", f"{'met' if median <= 0.01 else 'not met'}:"
              f" {m['task_candidates']} candidates, the first {m['task_candidates'] - 1} refuted "
              f"at samples, the last proven on {m['certified_intervals']} intervals")
    out: dict[str, Any] = {"median_seconds": median, "times": times}
    return out


def random_tasks(bench: Any, count: int, seed: int = 21) -> dict[str, Any]:
    import flatcli
    from flatcli.core.model import FlatcliError

    rng = np.random.default_rng(seed)
    planned = refused = violations = 0
    least = math.inf
    reasons: dict[str, int] = {}
    started = time.perf_counter()
    for _ in range(count):
        radius = rng.uniform(0.12, 0.3)
        angle = rng.uniform(-math.pi, math.pi)
        discs: list[list[float]] = []
        while len(discs) < 3:  # three discs 3 cm clear of the robot at its start
            disc = [float(rng.uniform(-0.35, 0.35)), float(rng.uniform(-0.35, 0.35)),
                    float(rng.uniform(0.02, 0.05))]
            if link_clearance(*PAPER, START[None, :], np.array([disc]))[0] > 0.03:
                discs.append(disc)
        target = [radius * math.cos(angle), radius * math.sin(angle)]
        overrides: dict[str, Any] = {"task.end_effector": target,
                     "task.base_attitude": float(rng.uniform(0.6, 1.4)), "task.rest": True,
                     "task.obstacles": discs, "task.clearance": 0.01}
        try:
            p = flatcli.plan(overrides=overrides)
        except FlatcliError as exc:
            refused += 1
            key = str(exc).split(":")[0]
            reasons[key] = reasons.get(key, 0) + 1
            continue
        planned += 1
        assert p.plan is not None
        theta = p.plan.sample(np.linspace(0.0, p.plan.duration, FINE)).theta
        robot = p.plan.robot
        gap = link_clearance(np.asarray(robot.mass), np.asarray(robot.length),
                             np.asarray(robot.com), theta, np.asarray(discs))
        margin = float(gap.min()) - 0.01
        least = min(least, margin)
        violations += int(margin < 0)
    seconds = time.perf_counter() - started
    why = ", ".join(f"{n} {k}" for k, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
    bench.row(RANDOM, count, planned, refused, violations, f"{least:.3g}",
              "met" if violations == 0 else "not met",
              f"{seconds:.0f} s in all; refused by {why or 'nothing'}")
    return {"tasks": count, "planned": planned, "refused": refused, "violations": violations,
            "least_margin": least, "seconds": seconds, "refused_by": reasons}


def run_all(bench: Any) -> None:
    started = time.perf_counter()
    bench.raw["tasks"] = {
        "capture": capture_timing(bench),
        "random": random_tasks(bench, 40 if bench.quick else 1000),
        "seconds": time.perf_counter() - started,
    }
