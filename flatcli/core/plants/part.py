"""What a plant of an N-link chain hands the loop factory (``loop.base``): one record of its
functions, all with one signature per role, knowing nothing of the controller.

A plant's state starts with the angles th0..th_N (N + 1,); the controller's own states follow
it in the loop's state. The controller writes its joint-rate commands r (N,) into the row
``io(plant, x)[0]`` before ``rates`` reads them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from flatcli.core._jit import jitable
from flatcli.core.robots.chain import link_trig, turn_last

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PlantPart:
    """A plant's parts (``kinematic.PLANT``, ``dynamic.PLANT``); compiled unless said.

    name : its ``track.plant`` value
    scratch : scratch(n) -> its buffers for N joints (Python, once per batch)
    make : make(trials, i, rate_limit, servo, scratch) -> trial i's plant record
        (``kernels.TrialArrays``: its K, parameters, H0, servo bandwidth and torque limit,
        the turn of its last link; ``rate_limit`` [rad/s]; ``servo`` the controller's model
        of the robot as a rate servo sees it: (K, inertia, cos, sin of its last link's turn,
        whether it is the plant's own, whether the lag may skip the solve))
    state : state(n) -> its state's size (the angles first)
    aux : aux(n) -> the values ``rates`` writes at out[at:]
    columns : columns(n) -> its trace columns after the state and u_1..u_N-1
    io : io(plant, x) -> (the row (>= N,) the controller writes r into [rad/s], the joint
        rates (N + 1,) it measures in state x (empty: none))
    rates : rates(plant, x, cs, sn, given, out, at, torques): its state's derivative into
        out[:state] under the commands, its aux values into out[at:]; cs, sn (N + 1,) the
        trigonometry of its angles (``chain.link_trig``; the paper's plants: cos th1, sin th1)
        where ``given``; without
        ``torques`` (an integrator's stage) what nobody observes may be skipped
    start : start(plant, initial, r, x0): its state at t = 0 into x0[:state] from the trial's
        ``initial`` (2 N,) th(0), u(0) and the controller's commands r at t = 0
    observed : observed(plant, x, f, at, cs, sn, given) -> (H [kg m^2/s], H0, peak joint rate
        [rad/s], clipped, peak torque [N m], 1.0 if a torque was clipped) at state x with
        derivative f
    record : record(plant, trace, j, col, x, f, at, commands): trace row j from column col:
        with ``commands`` the commands r_1..r_N-1, then its ``columns``
    residual : residual(plant, trials, i, plan_theta, plan_theta_dot) -> the plan's
        max |H - H0| on this plant [kg m^2/s]
    bounded : bounded(plant) -> whether its actuators bound the right-hand side (a finite
        limit)
    rate_states : its state holds the joint rates (it starts from the controller's commands)
    torques : it has joint torques (observed, and an integrator's stage may skip them)
    """

    name: str
    scratch: Callable[[int], Any]
    make: Callable[..., Any]
    state: Callable[[int], int]
    aux: Callable[[int], int]
    columns: Callable[[int], int]
    io: Callable[..., tuple[Array, Array]]
    rates: Callable[..., None]
    start: Callable[..., None]
    observed: Callable[..., tuple[float, float, float, bool, float, float]]
    record: Callable[..., None]
    residual: Callable[..., float]
    bounded: Callable[..., bool]
    rate_states: bool
    torques: bool


@jitable
def plant_trig(theta: Array, cs: Array, sn: Array, given: bool, own_cs: Array,
               own_sn: Array, cos_p: float, sin_p: float) -> tuple[Array, Array]:
    """The plant's trigonometry at theta (N + 1,), its last link turned by (cos_p, sin_p):
    cs, sn where ``given`` (computed elsewhere at theta; a turned copy in own_cs, own_sn
    where it is turned), else computed into own_cs, own_sn."""
    if not given:
        link_trig(theta, own_cs, own_sn)
        turn_last(own_cs, own_sn, cos_p, sin_p)
        return own_cs, own_sn
    if sin_p == 0.0 and cos_p == 1.0:
        return cs, sn
    for a in range(cs.shape[0]):
        own_cs[a] = cs[a]
        own_sn[a] = sn[a]
    turn_last(own_cs, own_sn, cos_p, sin_p)
    return own_cs, own_sn
