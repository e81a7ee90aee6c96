"""Keys a spec sets that no trial reads: a controller's settings under another controller.

``track.controller = "flat"`` reads ``track.kp`` and ``track.kv``; "asbuilt" reads the LQR's
``track.lqr_*``; "mpc" reads its own ``track.mpc_*`` and, around the as-built law (on an
exact plan), ``track.lqr_*`` too (its inner flat law's gains are ``track.mpc_kp``,
``track.mpc_kv``, not ``track.kp``). A user who sets ``track.mpc_horizon`` and forgets to
choose the MPC would otherwise get the flat law's numbers and believe them the MPC's; a
sweep whose grid varies such a key would run identical cells. ``unread_keys`` names them
(one warning line each); nothing is refused, since a spec may keep settings for later.

``unseen_draws`` names the one perturbation a controller does not see although the plant
does: a ``torque_limit`` drawn per trial under the MPC on the dynamic plant (the MPC re-plans
within the cell's ``plant.torque_limit``; each trial's plant clips at its own draw).
"""

from __future__ import annotations

from collections.abc import Iterator

from flatcli.spec.schema import SCHEMA, SpecRecord, find_key, sized_defaults

#: The controllers that read each ``[track]`` key a controller owns (by prefix or name).
READERS: dict[str, frozenset[str]] = {
    "kp": frozenset({"flat"}),
    "kv": frozenset({"flat"}),
    "lqr_": frozenset({"asbuilt", "mpc"}),
    "mpc_": frozenset({"mpc"}),
}


def _readers(name: str) -> frozenset[str] | None:
    """The controllers reading ``track.<name>``, or None for a key every controller reads."""
    for owned, readers in READERS.items():
        if name == owned or (owned.endswith("_") and name.startswith(owned)):
            return readers
    return None


def controllers_used(spec: SpecRecord) -> frozenset[str]:
    """The controllers the spec's trials run: ``track.controller``, or the values its sweep
    grid gives it."""
    grid = spec.sweep.grid.get("track.controller")
    return frozenset(str(v) for v in grid) if isinstance(grid, list) else frozenset(
        {spec.track.controller})


def _set_keys(spec: SpecRecord) -> Iterator[str]:
    """The controller-owned ``[track]`` keys whose value is not their default, or that the
    sweep grid varies."""
    sized = sized_defaults(spec) if spec.joints != 2 else {}
    for name in SCHEMA["track"]:
        if _readers(name) is None:
            continue
        dotted = f"track.{name}"
        key = find_key(dotted)
        default = sized.get(dotted, None if key is None else key.default)
        value = getattr(spec.track, name)
        if dotted in spec.sweep.grid or value != default:
            yield dotted


def unread_keys(spec: SpecRecord) -> list[str]:
    """One warning line per controller-owned key the spec sets that no trial's controller
    reads (``READERS``), e.g. ``track.mpc_horizon`` with ``track.controller = "flat"``."""
    used = controllers_used(spec)
    lines = []
    for dotted in _set_keys(spec):
        readers = _readers(dotted.removeprefix("track."))
        assert readers is not None
        if not readers & used:
            chosen = ", ".join(f'"{c}"' for c in sorted(used))
            wanted = " or ".join(f'"{c}"' for c in sorted(readers))
            lines.append(f"warning: {dotted} is set but no trial reads it: track.controller "
                         f"is {chosen} (it is read with {wanted})")
    return lines


def unseen_draws(spec: SpecRecord) -> list[str]:
    """One warning line where a sweep draws ``torque_limit`` per trial and the MPC runs on
    the dynamic plant: the MPC's re-plan within the torque limit (and its design) is made
    once per cell, for the cell's ``plant.torque_limit``; each trial's plant clips its
    torques at its own draw, which the MPC does not know (docs/physics.md, "Within the
    torque limit")."""
    if "mpc" not in controllers_used(spec) or "torque_limit" not in spec.sweep.perturb:
        return []
    grid = spec.sweep.grid.get("plant.model")
    models = {str(v) for v in grid} if isinstance(grid, list) else {spec.plant.model}
    if "dynamic" not in models:
        return []
    return ["warning: sweep.perturb.torque_limit: each trial's plant clips its torques at "
            "its own draw, but the MPC re-plans within the cell's plant.torque_limit only "
            "(docs/physics.md, \"Within the torque limit\")"]
