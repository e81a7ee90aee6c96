"""Shared fixtures of the numerical-core tests: the paper's robot, plan, gains and scenario.

Sources of the values below:

* robot: Franch, Agrawal, Oh, Fattah (IROS 2003), Sec. VI; ``core.robots.params.PAPER_ROBOT``
  (m_i = 1 kg, l_i = 0.2 m, I_i = 0.0533 kg m^2, d0 = d1 = 0.1 m, d2 = 0).
* maneuver: paper, Sec. VI: th(0) = (1.8, 1, 0), th(2) = (1.2, 2, 0), th1'(0) = 0.1,
  th1'(2) = 0.5, T = 2 s, cubic flat outputs.
* feedback: paper, eqs. 39-42 and Fig. 4: th(0) = (1.96, 0.8, -0.1); gains as printed
  kv1 = 100, kp1 = 10, kv2 = 110, kp2 = 13, and with kv and kp swapped (README, *The physics,
  and the paper's errata*, "The gains"); u1(0) = y1d'(0) = 0.1, the plan's own rate (the
  paper does not give it; README, ``track.initial_rate``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import ArrayLike, NDArray

from flatcli.core.controllers.control import Gains
from flatcli.core.loop.simulate import Scenario, Trials
from flatcli.core.names import Model
from flatcli.core.plan.planning import Basis, Plan, plan_point_to_point
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Maneuver:
    """A point-to-point maneuver: configurations [rad], end rates th1' [rad/s], duration [s]."""

    start: tuple[float, float, float]
    goal: tuple[float, float, float]
    start_rate: float
    goal_rate: float
    duration: float


# Paper, Sec. VI.
PAPER_MANEUVER = Maneuver(
    start=(1.8, 1.0, 0.0), goal=(1.2, 2.0, 0.0), start_rate=0.1, goal_rate=0.5, duration=2.0
)
# Paper, eqs. 39-42 (gains as printed) and Fig. 4 (initial angles); u1(0) = y1d'(0).
PRINTED_GAINS = Gains((10.0, 13.0), (100.0, 110.0))
SWAPPED_GAINS = Gains((100.0, 110.0), (10.0, 13.0))
FIG4_INITIAL = (1.96, 0.8, -0.1, 0.1)
#: Simulation step of the paper scenario [s].
PAPER_DT = 1e-3


def make_plan(model: Model = "derived", basis: Basis | None = None) -> Plan:
    """The paper's maneuver planned for the paper's robot with the given model and basis."""
    m = PAPER_MANEUVER
    return plan_point_to_point(
        PAPER_ROBOT,
        np.array(m.start),
        np.array(m.goal),
        m.start_rate,
        m.goal_rate,
        m.duration,
        model,
        basis,
    )


def make_trials(
    initial: ArrayLike,
    plant: RobotParams | list[RobotParams] = PAPER_ROBOT,
    momentum: ArrayLike = 0.0,
    noise: Array | None = None,
) -> Trials:
    """Trials from initial states (N, 4) or (4,); plant(s) and H0 broadcast to N."""
    x = np.atleast_2d(np.asarray(initial, dtype=float))
    n = x.shape[0]
    plants = plant if isinstance(plant, list) else [plant] * n
    links = np.stack([p.as_array() for p in plants])
    h0 = np.broadcast_to(np.asarray(momentum, dtype=float), (n,)).copy()
    return Trials(links=links, momentum=h0, initial=x, noise=noise)


@pytest.fixture(scope="session", autouse=True)
def _no_inherited_terminal_size() -> Iterator[None]:
    """The commands see no COLUMNS or LINES from the shell or the runner (pytest-xdist sets
    COLUMNS=80 in its workers): a test of a table's width sets its own width."""
    with pytest.MonkeyPatch.context() as patch:
        patch.delenv("COLUMNS", raising=False)
        patch.delenv("LINES", raising=False)
        yield


@pytest.fixture(scope="session")
def paper_robot() -> RobotParams:
    return PAPER_ROBOT


@pytest.fixture(scope="session")
def paper_maneuver() -> Maneuver:
    return PAPER_MANEUVER


@pytest.fixture(scope="session")
def paper_plan() -> Plan:
    """The paper's cubic plan with the derived (correct) coefficients."""
    return make_plan("derived")


@pytest.fixture(scope="session")
def paper_plan_as_printed() -> Plan:
    """The paper's cubic plan with the coefficients as printed (``model="paper"``)."""
    return make_plan("paper")


@pytest.fixture(scope="session")
def plan_factory() -> Callable[..., Plan]:
    """``make_plan(model, basis)``: the paper's maneuver with another model or basis."""
    return make_plan


@pytest.fixture(params=["printed", "swapped"])
def paper_gains(request: pytest.FixtureRequest) -> Gains:
    """Both readings of the paper's gains (kv/kp as printed, and swapped)."""
    return PRINTED_GAINS if request.param == "printed" else SWAPPED_GAINS


@pytest.fixture(scope="session")
def replan() -> Plan:
    """The plan the MPC tracks at 4 rad/s: the paper's maneuver re-planned to the least peak
    joint rate (th2' at 3.5-3.75 rad/s for long stretches: the rate rows bind at many
    samples)."""
    from flatcli.api import load_spec
    from flatcli.experiment import tracked_plan

    plan, replanned = tracked_plan(load_spec(None, {"track.controller": "mpc",
                                                   "track.rate_limit": 4.0}))
    assert replanned
    return plan


@pytest.fixture(scope="session")
def printed_gains() -> Gains:
    return PRINTED_GAINS


@pytest.fixture(scope="session")
def swapped_gains() -> Gains:
    return SWAPPED_GAINS


@pytest.fixture(scope="session")
def fig4_initial() -> Array:
    """(4,) th0, th1, th2 [rad], u1 [rad/s] at t = 0 of the paper's feedback example."""
    return np.array(FIG4_INITIAL)


@pytest.fixture(scope="session")
def paper_scenario(paper_plan: Plan) -> Scenario:
    """The derived plan tracked with the printed gains at dt = 1 ms."""
    return Scenario(paper_plan, PRINTED_GAINS, PAPER_DT)


@pytest.fixture(scope="session")
def trials_factory() -> Callable[..., Trials]:
    """``make_trials(initial, plant=PAPER_ROBOT, momentum=0.0, noise=None)``."""
    return make_trials
