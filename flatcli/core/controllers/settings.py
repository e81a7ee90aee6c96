"""Controllers' settings, numba-free: frozen records whose fields generate their spec keys.

A controller's settings are a frozen dataclass validated when built; each field carries in
its metadata what its spec key shows (``setting``: one line of doc, the unit, the bounds the
spec checks before the record is built), so the spec's ``[track]`` table gains the keys
``<prefix><field>`` from the record alone (``flatcli.spec.keys.settings_keys``) and the
experiment builds the record from them (``settings_from``). This module imports nothing
compiled, so the spec and shell completion read it cheaply.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, TypeVar

from flatcli.core.errors import FlatcliError

T = TypeVar("T")


def setting(default: Any, doc: str, unit: str = "", *, kind: str = "float",
            gt: float | None = None, ge: float | None = None, le: float | None = None) -> Any:
    """A settings field: its default, and its spec key's doc, unit, kind ("float", "int",
    or "joints": one number per flat output, None for the controller's own default) and
    bounds (``gt``/``ge`` below, ``le`` above)."""
    return field(default=default, metadata={"setting": {"doc": doc, "unit": unit, "kind": kind,
                                                        "gt": gt, "ge": ge, "le": le}})


def settings_from(values: Any, cls: type[T], prefix: str) -> T:
    """A ``cls`` record from the attributes ``<prefix><field>`` of ``values`` (a spec
    section); a vector key's list becomes a tuple."""
    given = {}
    for f in fields(cls):  # type: ignore[arg-type]
        value = getattr(values, prefix + f.name)
        given[f.name] = tuple(value) if isinstance(value, list) else value
    return cls(**given)


@dataclass(frozen=True)
class MpcSettings:
    """The MPC's settings (``controllers.mpc``; spec ``track.mpc_*``).

    sample : the sample time [s] (a multiple of track.dt that divides plan.duration)
    horizon : samples predicted, H >= 2
    kp, kv : the inner flat law's gains per flat output [1/s^2, 1/s] (None: ``INNER_KP``,
        ``INNER_KV``); the as-built inner law is the LQR of ``track.lqr_*``
    weight_state : W's diagonal on the errors (the flat law: e and e' of each output)
    weight_input : r on the correction dv (> 0)
    margin : the singularity margin kept [rad/s] (0: none)
    backoff : the joint-rate limit is kept at R (1 - backoff): 3 % leaves the limits kept
        at the samples room for what they are not kept between them (on the paper's
        maneuver at 4 rad/s, 1000 trials of 2 mrad errors: 994 reached at 1 %, 994 at 2 %,
        998 at 3 %, 997 at 4 %)
    """

    sample: float = setting(0.1, "mpc: the sample time, a multiple of dt dividing the "
                            "duration", "s", gt=0)
    horizon: int = setting(20, "mpc: samples predicted", kind="int", ge=2, le=200)
    kp: tuple[float, ...] | None = setting(None, "mpc: the inner flat law's kp per flat output "
                                           "(default 1: a double pole at -1 rad/s)", "1/s^2",
                                           kind="joints")
    kv: tuple[float, ...] | None = setting(None, "mpc: the inner flat law's kv per flat output "
                                           "(default 2)", "1/s", kind="joints")
    weight_state: float = setting(0.0, "mpc: the weight of the errors at every sample", ge=0)
    weight_input: float = setting(1.0, "mpc: the weight of the correction dv", gt=0)
    margin: float = setting(0.05, "mpc: the singularity margin kept (0: none)", "rad/s", ge=0)
    backoff: float = setting(0.03, "mpc: the rate limit is kept at rate_limit (1 - backoff)",
                             ge=0, le=0.99)

    def __post_init__(self) -> None:
        if not (self.sample > 0 and math.isfinite(self.sample)):
            raise FlatcliError(f"track.mpc_sample: must be a finite number > 0 s, got "
                               f"{self.sample}")
        if not (isinstance(self.horizon, int) and 2 <= self.horizon <= 200):
            raise FlatcliError(f"track.mpc_horizon: must be an integer in [2, 200], got "
                               f"{self.horizon!r}")
        if not (self.weight_state >= 0 and math.isfinite(self.weight_state)):
            raise FlatcliError(f"track.mpc_weight_state: must be a finite number >= 0, got "
                               f"{self.weight_state}")
        if not (self.weight_input > 0 and math.isfinite(self.weight_input)):
            raise FlatcliError(f"track.mpc_weight_input: must be a finite number > 0, got "
                               f"{self.weight_input}")
        if not (self.margin >= 0 and math.isfinite(self.margin)):
            raise FlatcliError(f"track.mpc_margin: must be a finite number >= 0 rad/s, got "
                               f"{self.margin}")
        if not 0 <= self.backoff <= 0.99:
            raise FlatcliError(f"track.mpc_backoff: must be in [0, 0.99], got {self.backoff}")

    def check(self, dt: float, duration: float) -> None:
        """FlatcliError naming the key unless the sample time fits (``every``)."""
        self.every(dt, duration)

    def every(self, dt: float, duration: float) -> int:
        """Output steps per sample; FlatcliError naming the key unless the sample time is
        a multiple of dt that divides the duration."""
        every = round(self.sample / dt)
        steps = round(duration / dt)
        if every < 1 or not math.isclose(every * dt, self.sample, rel_tol=1e-9) or steps % every:
            raise FlatcliError(f"track.mpc_sample: {self.sample:g} s must be a multiple of "
                               f"track.dt = {dt:g} s that divides plan.duration = "
                               f"{duration:g} s")
        return every


#: Every controller's settings record and the prefix of its keys in ``[track]``, by
#: ``track.controller`` (read by the spec's schema, numba-free, and by the experiment).
SETTINGS: dict[str, tuple[type, str]] = {"mpc": (MpcSettings, "mpc_")}


def settings_of(values: Any) -> dict[str, Any]:
    """Every registered controller's settings record from a spec's ``[track]`` section."""
    return {name: settings_from(values, cls, prefix) for name, (cls, prefix) in
            SETTINGS.items()}
