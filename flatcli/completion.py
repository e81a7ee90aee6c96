"""Shell completion of ``--set`` keys and values and of ``--robot``, without the numerical
libraries (a shell asks on every Tab: it must answer at once).

The spec's keys are spelled out here (``SET_KEYS``, ``WORDS``) because the schema's home,
``flatcli.spec.schema``, takes its choices from the core, which loads numba;
``tests/test_completion.py`` checks they are the schema's. Turn completion on with
``eval "$(_FLATCLI_COMPLETE=bash_source flatcli)"`` (``zsh_source``, ``fish_source``).
"""

from __future__ import annotations

from importlib import resources
from typing import Any

#: Every dotted key of the spec (``flatcli.spec.all_keys()``).
SET_KEYS = (
    "name",
    "robot.mass", "robot.inertia", "robot.length", "robot.com", "robot.com_across",
    "robot.model",
    "plan.duration", "plan.start", "plan.goal", "plan.start_rate", "plan.goal_rate",
    "plan.samples", "plan.basis", "plan.degree", "plan.size", "plan.rate_warning",
    "plan.method",
    "plan.optimize.objective", "plan.optimize.angle_limit", "plan.optimize.rate_limit",
    "plan.optimize.min_margin", "plan.optimize.free_rates", "plan.optimize.constraint_samples",
    "plan.optimize.max_iter",
    "task.end_effector", "task.base_attitude", "task.start_end_effector", "task.rest",
    "task.obstacles", "task.clearance", "task.elbow", "task.fade", "task.goal_tolerance",
    "task.budget",
    "track.initial", "track.initial_rate", "track.kp", "track.kv", "track.dt",
    "track.integrator", "track.rtol", "track.atol", "track.max_steps",
    "track.error_estimate", "track.accuracy", "track.observe_every",
    "track.singular_threshold", "track.sensor_noise", "track.rate_limit",
    "track.goal_tolerance", "track.divergence_bound", "track.controller",
    "track.lqr_bandwidth", "track.lqr_base",
    "track.lqr_terminal", "track.seed", "track.trial",
    "plant.mass", "plant.inertia", "plant.length", "plant.com", "plant.com_across",
    "plant.momentum",
    "plant.model", "plant.servo_bandwidth", "plant.torque_limit", "plant.servo_model",
    "sweep.trials", "sweep.seed", "sweep.chunk", "sweep.verify", "sweep.perturb", "sweep.grid",
    "figures.format", "figures.dpi", "summary.reach_tolerance",
)
#: The words a key takes (its choices; true, false for a flag): completed after ``KEY=``.
WORDS = {
    "robot.model": ("derived", "paper"),
    "plan.basis": ("auto", "poly", "bspline"),
    "plan.method": ("auto", "flat", "exact"),
    "plan.optimize.objective": ("energy", "peak_rate", "effort", "margin"),
    "plan.optimize.free_rates": ("true", "false"),
    "task.rest": ("true", "false"),
    "task.elbow": ("auto", "up", "down"),
    "track.integrator": ("adaptive", "rk4", "dop853"),
    "track.error_estimate": ("twin", "none"),
    "track.controller": ("flat", "asbuilt"),
    "plant.model": ("kinematic", "dynamic"),
    "plant.servo_model": ("robot", "plant"),
    "figures.format": ("png", "pdf", "svg"),
}


def robot_names() -> list[str]:
    """The robot files shipped with flatcli (``flatcli.spec.compose.robot_names``)."""
    folder = resources.files("flatcli") / "data" / "robots"
    return sorted(p.name.removesuffix(".toml") for p in folder.iterdir()
                  if p.name.endswith(".toml"))


def set_items(incomplete: str) -> list[tuple[str, str]]:
    """Completions of a ``--set`` item: ``(value, help)``; a key with ``=`` appended, or after
    ``KEY=`` the key's words (a robot file's name for ``robot=``)."""
    key, sep, value = incomplete.partition("=")
    if sep:
        words = robot_names() if key == "robot" else WORDS.get(key, ())
        return [(f"{key}={w}", "") for w in words if w.startswith(value)]
    keys = [*SET_KEYS, "robot"]
    return [(f"{k}=", "robot file (chain4, ...)" if k == "robot" else "")
            for k in keys if k.startswith(incomplete)]


def complete_set(ctx: Any, param: Any, incomplete: str) -> list[Any]:
    """click's ``shell_complete`` of ``--set``: no space after ``KEY=``."""
    from click.shell_completion import CompletionItem

    return [CompletionItem(v, help=h or None) for v, h in set_items(incomplete)]


def complete_robot(ctx: Any, param: Any, incomplete: str) -> list[Any]:
    """click's ``shell_complete`` of ``--robot``: the shipped robots, or a file."""
    from click.shell_completion import CompletionItem

    if "/" in incomplete or incomplete.endswith((".toml", ".urdf")) or incomplete.startswith("."):
        return [CompletionItem(incomplete, type="file")]
    return [CompletionItem(n) for n in robot_names() if n.startswith(incomplete)]
