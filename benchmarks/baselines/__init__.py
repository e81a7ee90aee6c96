"""Baselines that ``make bench`` sets beside flatcli: what a user would pick instead.

Each baseline is an honest, competent implementation of the same task, written the way a
user of the tool in question would write it, so the ratios in the bench table mean
something:

* planning with python-control's ``flatsys`` (a ``FlatSystem`` for this robot):
  ``pc_point_to_point`` (the paper's cubic maneuver, which must come out identical to
  flatcli's), ``pc_optimal`` (input energy with trajectory constraints) and
  ``pc_obstacle_task`` (input energy among discs, the links' clearance at its time points);
* planning without flatness: ``shooting_plan``, an SLSQP shooting NLP over piecewise-constant
  joint rates;
* the closed loop of the paper (linearising feedback of the nominal d2 = 0 model, plant
  obeying the general reduced constraint), integrated with classical RK4 at a fixed step:
  ``compiled_closed_loop`` (a hand-written numba kernel, ``prange`` over trials),
  ``dopri_metrics`` (the same work as flatcli's default: adaptive Dormand-Prince with
  dense output and every metric at every output sample, hand-written in numba),
  ``numpy_batch_rk4`` (vectorised over trials) and ``solve_ivp_trials_per_second`` (one trial at a
  time, RK45);
* ``timed`` and ``machine_info`` for the table.

One module per baseline: ``problem`` (the shared maneuver and trials), ``timing``,
``pcflatsys``, ``quality``, ``shooting``, ``loop`` (the closed loop's shared inputs),
``compiled``, ``dopri``, ``numpy_batch``, ``ivp``; their public names are re-exported here.

Nothing here prints; every function returns its results. The closed-loop baselines share no
code with ``flatcli.core.loop.simulate``: the formulas are written out again below, so that
agreeing with flatcli to rounding is a check of both.
"""

from benchmarks.baselines.compiled import compiled_closed_loop, compiled_trials_per_second
from benchmarks.baselines.dopri import METRICS as DOPRI_METRICS
from benchmarks.baselines.dopri import (
    DopriInputs,
    dopri_inputs,
    dopri_metrics,
    dopri_trials_per_second,
    rhs_nanoseconds,
)
from benchmarks.baselines.ivp import IvpRun, solve_ivp_trials_per_second
from benchmarks.baselines.loop import LoopInputs, loop_inputs, plant_coefficients
from benchmarks.baselines.numpy_batch import numpy_batch_rk4, numpy_trials_per_second
from benchmarks.baselines.pcflatsys import (
    PcObstacleTask,
    PcOptimal,
    PcPlan,
    flat_states,
    matching_end_inputs,
    pc_flags,
    pc_obstacle_task,
    pc_optimal,
    pc_point_to_point,
    robot_flat_system,
)
from benchmarks.baselines.problem import (
    PAPER_MANEUVER,
    PAPER_TRACKING,
    PRINTED_GAINS,
    SWAPPED_GAINS,
    Maneuver,
    Tracking,
    paper_trials,
)
from benchmarks.baselines.quality import PlanQuality, flat_plan_quality, plan_quality
from benchmarks.baselines.shooting import ShootingPlan, shooting_plan
from benchmarks.baselines.timing import Throughput, Timing, machine_info, timed

__all__ = [
    "DOPRI_METRICS",
    "PAPER_MANEUVER",
    "PAPER_TRACKING",
    "PRINTED_GAINS",
    "SWAPPED_GAINS",
    "DopriInputs",
    "IvpRun",
    "LoopInputs",
    "Maneuver",
    "PcObstacleTask",
    "PcOptimal",
    "PcPlan",
    "PlanQuality",
    "ShootingPlan",
    "Throughput",
    "Timing",
    "Tracking",
    "compiled_closed_loop",
    "compiled_trials_per_second",
    "dopri_inputs",
    "dopri_metrics",
    "dopri_trials_per_second",
    "flat_plan_quality",
    "flat_states",
    "loop_inputs",
    "machine_info",
    "matching_end_inputs",
    "numpy_batch_rk4",
    "numpy_trials_per_second",
    "paper_trials",
    "pc_flags",
    "pc_obstacle_task",
    "pc_optimal",
    "pc_point_to_point",
    "plan_quality",
    "plant_coefficients",
    "rhs_nanoseconds",
    "robot_flat_system",
    "shooting_plan",
    "solve_ivp_trials_per_second",
    "timed",
]
