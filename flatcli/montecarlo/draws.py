"""The random part of a trial: perturbed initial states and plants, drawn per trial.

Every random number of trial ``i`` comes from its own stream
``SeedSequence(sweep.seed, spawn_key=(i, slot))`` (``flatcli.experiment.trial_stream``; drawn
for a chunk at once by ``flatcli.montecarlo.streams``, the same numbers), so a
trial's values do not depend on the chunk size, the number of workers, the executor, the
order in which chunks finish, or a resume in between.

Each trial draws ``N_VARIATES`` uniform variates from its perturbation stream, one fixed
position per perturbable component (``PERTURB_SLOTS``: the quantities of
``flatcli.spec.PERTURB_TARGETS`` in order, each as many as its spec key holds), and transforms
those it needs (uniform: low + (high - low) u; normal: mean + std Phi^-1(u)). So adding or
removing one perturbation never changes the values another one draws. A robot of N joints
has its own layout (``perturb_slots``): per-link quantities hold N + 1 components and
``initial_rate`` N - 1; for the paper's robot (N = 2) it is ``PERTURB_SLOTS``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from flatcli.core.plan.planning import Plan
from flatcli.experiment import STREAM_PERTURB, initial_rates, plant_from
from flatcli.montecarlo.streams import uniform_variates
from flatcli.spec import PERTURB_TARGETS, Perturbation, Spec, SpecError, lookup
from flatcli.spec.keys import MIN_JOINTS
from flatcli.spec.sweeps import size

Array = NDArray[np.float64]


def perturb_slots(joints: int = MIN_JOINTS) -> dict[str, tuple[int, ...]]:
    """Position of each perturbable component among a trial's uniform variates, for a robot
    of ``joints`` joints."""
    out: dict[str, tuple[int, ...]] = {}
    first = 0
    for name in PERTURB_TARGETS:
        out[name] = tuple(range(first, first + size(name, joints)))
        first += size(name, joints)
    return out


def variates(joints: int = MIN_JOINTS) -> int:
    """How many uniform variates a trial draws on a robot of ``joints`` joints."""
    return sum(len(s) for s in perturb_slots(joints).values())


#: Position of each perturbable component among a trial's uniform variates (N = 2).
PERTURB_SLOTS: dict[str, tuple[int, ...]] = perturb_slots()
N_VARIATES = variates()
#: The spec keys of a plant's parameters, in the order of a row of ``Trials.links``.
PLANT_KEYS = ("plant.mass", "plant.inertia", "plant.length", "plant.com")
#: The spec keys of a trial's servo, in the order of a row of ``Trials.servo``.
SERVO_KEYS = ("plant.servo_bandwidth", "plant.torque_limit")


def perturbation_columns(name: str, joints: int = MIN_JOINTS) -> list[str]:
    """Column names of the realised values of a perturbed quantity: ``name`` for one number,
    else ``name_i`` with i the link (``initial_rate``: the joint, 1..N-1)."""
    n = size(name, joints)
    if name == "initial_rate":
        return [name] if joints == MIN_JOINTS else [f"{name}_{j}" for j in range(1, joints)]
    return [name] if n == 1 else [f"{name}_{i}" for i in range(n)]


def draw_perturbations(
    perturb: Mapping[str, Perturbation], nominal: Mapping[str, Array], seed: int,
    trials: Sequence[int], joints: int = MIN_JOINTS,
) -> dict[str, Array]:
    """Realised values of every perturbed quantity for the given trial ids.

    Parameters
    ----------
    perturb : the sweep's perturbations (``flatcli.spec.perturbations``)
    nominal : nominal value of each perturbable quantity, (n,) with n its slot count
    seed : sweep.seed
    trials : trial ids (N)
    joints : the robot's joints (the layout of the variates, ``perturb_slots``)

    Returns
    -------
    {name: (N, n)} realised values
    """
    count = variates(joints)
    u = uniform_variates(seed, trials, STREAM_PERTURB, count)  # trial_stream's, to the bit
    out: dict[str, Array] = {}
    for name, slots in perturb_slots(joints).items():
        if name not in perturb:
            continue
        p = perturb[name]
        draws = u[:, list(slots)]
        if p.dist == "uniform":
            low = np.asarray(p.low, dtype=float)
            high = np.asarray(p.high, dtype=float)
            sample = low + (high - low) * draws
        else:
            std = np.asarray(p.std, dtype=float)
            mean = np.asarray(p.mean, dtype=float)
            from scipy.special import ndtri  # loaded when a normal perturbation asks for it

            sample = mean + std * ndtri(draws)
        base = nominal[name]
        out[name] = base * (1.0 + sample) if p.relative else base + sample
    return out


def nominal_values(spec: Spec, plan: Plan) -> dict[str, Array]:
    """Nominal value of every perturbable quantity of a (cell's) spec and its plan."""
    plant = plant_from(spec)
    return {
        "initial": np.asarray(spec.track.initial, dtype=float),
        "initial_rate": initial_rates(spec, plan),
        "mass": np.asarray(plant.mass),
        "inertia": np.asarray(plant.inertia),
        "length": np.asarray(plant.length),
        "com": np.asarray(plant.com),
        "momentum": np.array([spec.plant.momentum]),
        "servo_bandwidth": np.array([spec.plant.servo_bandwidth]),
        "torque_limit": np.array([spec.plant.torque_limit]),
        "end_effector": np.asarray(spec.task.end_effector if spec.task.end_effector is not None
                                   else (np.nan, np.nan), dtype=float),
    }


def invalid_plants(links: Array) -> list[str]:
    """For (N, 4 L) plants of L links (``PLANT_KEYS`` side by side): why each is not a valid
    plant, or '' if it is.

    A perturbed value is checked by its spec key (``flatcli.spec.keys.Key``), so the reason
    is the very line ``--set plant.mass=[...]`` with that value would print, e.g.
    ``plant.mass[2]: must be > 0 kg, got -0.106467``.
    """
    valid = np.ones(len(links), dtype=bool)
    count = links.shape[1] // len(PLANT_KEYS)
    for j, dotted in enumerate(PLANT_KEYS):
        key = lookup(dotted)
        block = links[:, j * count:(j + 1) * count]
        valid &= np.isfinite(block).all(axis=1)
        if key.low is not None:
            valid &= (block > key.low if key.low_open else block >= key.low).all(axis=1)
    reasons = [""] * len(links)
    for row in np.flatnonzero(~valid):
        reasons[row] = _reason(links[row])
    return reasons


def invalid_servos(servo: Array) -> list[str]:
    """For (N, 2) servos (``SERVO_KEYS`` side by side): why each is not a valid servo, or ''
    if it is; the reason is the line the same value in the spec would give."""
    bandwidth, torque = servo[:, 0], servo[:, 1]
    valid = (bandwidth > 0) & np.isfinite(bandwidth) & (torque >= 0)
    reasons = [""] * len(servo)
    for row in np.flatnonzero(~valid):
        for j, dotted in enumerate(SERVO_KEYS):
            try:
                lookup(dotted).check(dotted, float(servo[row, j]))
            except SpecError as exc:
                reasons[row] = str(exc)
                break
    return reasons


def _reason(values: Array) -> str:
    count = len(values) // len(PLANT_KEYS)
    for j, dotted in enumerate(PLANT_KEYS):
        key = lookup(dotted)
        for i in range(count):
            try:
                key.check_item(dotted, i, float(values[j * count + i]))
            except SpecError as exc:
                return str(exc)
    raise AssertionError("a plant flagged invalid passes every check")  # pragma: no cover
