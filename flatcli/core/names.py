"""The names and defaults the spec shows, written once, without numpy or numba.

Every enumeration a spec key or a command's option chooses from, and the core's defaults the
spec shows: the core imports them, ``flatcli.spec.schema`` builds its keys from them, and the
command line's ``--help`` and shell completion read them without the numerical libraries.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Literal

#: The paper's constraint coefficients (``robot.model``): as derived (correct), or the
#: appendix as printed.
Model = Literal["derived", "paper"]
MODELS: tuple[Model, ...] = ("derived", "paper")

#: How a maneuver is planned (``plan.method``): "flat" through the closed-form flat outputs
#: (``plan.planning``), "exact" (``plan.exact``), "auto" the first where the design has them
#: (``plan.exact.method_for``).
Method = Literal["auto", "flat", "exact"]
METHODS: tuple[Method, ...] = ("auto", "flat", "exact")

#: The objectives ``optimize_plan`` accepts (``plan.optimize.objective``).
Objective = Literal["energy", "peak_rate", "effort", "margin"]
OBJECTIVES: tuple[Objective, ...] = ("energy", "peak_rate", "effort", "margin")

#: The inverse-kinematics branch of the two-joint robot (``task.elbow``).
Elbow = Literal["auto", "up", "down"]
ELBOWS: tuple[Elbow, ...] = ("auto", "up", "down")

#: The plant models (``plant.model``): joints that follow their commanded rates exactly, or a
#: robot with inertia driven by joint torques through rate servos.
PlantModel = Literal["kinematic", "dynamic"]
PLANT_MODELS: tuple[PlantModel, ...] = ("kinematic", "dynamic")
#: What the dynamic plant's servo believes (``plant.servo_model``): the nominal robot, or the
#: plant itself.
ServoModel = Literal["robot", "plant"]
SERVO_MODELS: tuple[ServoModel, ...] = ("robot", "plant")
#: Default servo bandwidth [rad/s] (``plant.servo_bandwidth``).
DEFAULT_SERVO_BANDWIDTH = 100.0

#: The integrators (``track.integrator``).
Integrator = Literal["adaptive", "rk4", "dop853"]
INTEGRATORS: tuple[Integrator, ...] = ("adaptive", "rk4", "dop853")
#: The feedback laws (``track.controller``): the paper's linearising feedback on the flat
#: outputs of the nominal model (``controllers.control``), or the time-varying LQR of the
#: robot as built (``controllers.lqr``, ``controllers.asbuilt``), or model predictive control
#: wrapping either (the flat law on a flat plan, the as-built law on an exact one) with a
#: correction chosen at sample instants within the actuators' limits (``controllers.mpc``).
Controller = Literal["flat", "asbuilt", "mpc"]
CONTROLLERS: tuple[Controller, ...] = ("flat", "asbuilt", "mpc")
#: How an adaptive trial's error is estimated (``track.error_estimate``): by a twin at a
#: hundredth of its tolerances (``Scenario.twin``), or not at all.
ERROR_ESTIMATES: tuple[str, ...] = ("twin", "none")
#: Default tolerances of the adaptive integrator: 1e-6 rad or better at every output sample
#: of the paper's example, printed or swapped gains, against a DOP853 at rtol 1e-12
#: (tests/test_simulate.py measures it).
DEFAULT_RTOL = 5e-8
DEFAULT_ATOL = 1e-10
DEFAULT_MAX_STEPS = 100_000
#: The largest err_estimate of a verified trial [rad] (``Scenario.accuracy``).
DEFAULT_ACCURACY = 1e-6

#: Default weights of the as-built law, scaled by the plan's duration T [s]
#: (``controllers.lqr``): the bandwidth b = DEFAULT_BANDWIDTH_PERIODS / T [rad/s]
#: (``track.lqr_bandwidth``) and the terminal weight t_f = DEFAULT_TERMINAL_PERIODS T [s]
#: (``track.lqr_terminal``), which at the paper's T = 2 s are the former fixed defaults
#: DEFAULT_BANDWIDTH and DEFAULT_TERMINAL; and the running weight q_0 of the base's angle
#: error against a joint's (dimensionless, ``track.lqr_base``).
DEFAULT_BANDWIDTH_PERIODS = 10.0
DEFAULT_TERMINAL_PERIODS = 5e5
DEFAULT_BANDWIDTH = 5.0
DEFAULT_TERMINAL = 1e6
DEFAULT_BASE = 10.0

#: Default ``plan.rate_warning`` [rad/s]: a plan whose joints turn faster says so
#: (``plan.planning.rate_warning_text``).
RATE_WARNING = 50.0
#: Default ``track.goal_tolerance`` [rad] and ``task.goal_tolerance`` [m]: how close to its
#: goal a trial must end to be ``reached`` (``loop.outcome.judge``).
GOAL_TOLERANCE = 1e-3
TARGET_TOLERANCE = 1e-3

#: Flat-output bases of ``plan.basis``; "auto" picks one (``flatcli.experiment.basis_from``).
BASES = ("auto", "poly", "bspline")
#: File formats of ``figures.format`` (``--format``): one raster, two vector.
FIGURE_FORMATS = ("png", "pdf", "svg")
#: Where a sweep's chunks run (``--executor``): this machine's cores, or a Dask cluster.
EXECUTORS = ("local", "dask")


class Metric(IntEnum):
    """Column of a trial's metrics row (``Outcome.metrics``); names as in trials.parquet."""

    ERR_THETA_RMS = 0
    ERR_THETA_MAX = 1
    ERR_THETA_FINAL = 2
    ERR_Y_RMS = 3
    ERR_Y_MAX = 4
    ERR_Y_FINAL = 5
    SINGULAR_HITS = 6
    FIRST_HIT_TIME = 7
    MIN_MARGIN = 8
    MOMENTUM_DRIFT = 9
    PLAN_MOMENTUM_RESIDUAL = 10
    ERR_ESTIMATE = 11
    PEAK_RATE = 12
    PEAK_TORQUE = 13
    TORQUE_SATURATED = 14
    STEPS = 15
    RHS_EVALUATIONS = 16
    CROSSINGS = 17
    FIRST_CROSSING_TIME = 18
    CLIPPED_TIME = 19


#: The trial metrics' names, as in trials.parquet (``loop.metrics``).
METRIC_NAMES: tuple[str, ...] = tuple(m.name.lower() for m in Metric)
