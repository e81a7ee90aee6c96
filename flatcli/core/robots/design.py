"""Is a design flat? The integrability of the momentum constraint, for any N.

With H = H0 = 0 the robot (base attitude th0, joints th1..thN: an (N + 1)-dimensional
configuration space) moves along the codimension-one distribution ker w of the constraint
one-form

    w = sum_i h_i(th) d th_i,        h_i = dH / d th_i'  [kg m^2],

with H from the full link kinematics (``chain.chain_momentum`` at unit rates; nothing here
uses the reduced formulas or the barycentric matrix). ker w is integrable (Frobenius) exactly
when the three-form

    w ^ dw = sum_{i<j<k} (h_i F_jk - h_j F_ik + h_k F_ij) d th_i ^ d th_j ^ d th_k,
    F_jk = dh_k/dth_j - dh_j/dth_k,

vanishes everywhere. Where it does not, ker w is bracket generating (its first brackets span
the whole tangent space), so the driftless system is controllable (Chow; Nagano-Sussmann for
this analytic system) and, being driftless of codimension one, flat (Martin & Rouchon 1995):
the design is flat whether or not its flat outputs are known in closed form.

The derivatives dh_i/dth_k are taken by complex step (exact to rounding: no difference is
formed) through ``chain.chain_momentum``, the link kinematics, which takes complex angles.
w ^ dw is evaluated at ``SAMPLES`` configurations drawn from a fixed seed (a trigonometric
polynomial that is not identically zero vanishes on a set of measure zero) and normalised by
J^2, J = ``chain.inertia_scale`` [kg m^2] (units of w ^ dw: kg^2 m^4 per rad^3).

A fact the tests check against a sympy derivation: in absolute angles psi,
dw = -2 sum_{a<b} K_ab sin(psi_a - psi_b) dpsi_a ^ dpsi_b, and the Fourier coefficient of
sin(psi_a - psi_b) in the (a, b, c) component of w ^ dw is -2 ((I_c + K_cc) K_ab - K_ac K_bc).
All of them vanish only if K_ab K_ac K_bc = prod (I + K_ii) or K_ab = K_ac = K_bc = 0 for
every triple, and the first is ruled out by |K_ab| <= sqrt(K_aa K_bb) with every I > 0.
So a design is integrable exactly when K is diagonal: every h_i is constant and
sum_i h_i th_i is conserved (``not_flat``); any non-zero coupling K_ab makes it controllable.

The three verdicts (``VERDICTS``):

* ``closed_form``: controllable, and the closed-form outputs apply (``model.flatness_check``:
  d_N = 0, I_N != 0, K_10 != 0; for N = 2 the paper's d2 = 0, c0 a1 != 0): flatcli plans it.
* ``flat``: controllable, but d_N != 0 or K_10 = 0: flat with outputs not known in closed
  form (for K_10 = 0, N >= 3, h_0 still varies but flatcli's planner normalises by K_10).
  ``plan.method = "flat"`` refuses it; "auto" (the default) and "exact" plan it exactly
  (``exact``).
* ``not_flat``: w ^ dw = 0 at every sample: the constraint integrates.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from flatcli.core.robots.chain import barycentric_matrix, chain_momentum, inertia_scale
from flatcli.core.robots.params import DESIGN_ZERO_TOL, RobotParams, flatness_check, placed

Array = NDArray[np.float64]
Verdict = Literal["closed_form", "flat", "not_flat"]
VERDICTS: tuple[Verdict, ...] = ("closed_form", "flat", "not_flat")

#: What each verdict means for flatcli, one clause each.
HEADLINES: dict[Verdict, str] = {
    "closed_form": "controllable, with closed-form flat outputs: flatcli plans it",
    "flat": "controllable, hence flat, with flat outputs not known in closed form",
    "not_flat": "the momentum constraint integrates: not controllable, not flat",
}
#: Relative tolerance on max |w ^ dw| / J^2 below which the constraint counts as integrable.
#: Rounding leaves <= 5e-16 on 300 random designs built integrable (N = 2..7), and random
#: controllable ones give >= 4e-4; a coupling K_12 / J = 6e-11 (the paper's robot with
#: l0 = d0 and d2 = 1e-9 l0) still gives 2e-11 (``tests/test_core_design.py``).
INTEGRABILITY_RTOL = 1e-12
#: Configurations at which w ^ dw is evaluated, and the seed they are drawn from.
SAMPLES = 64
SEED = 20031027
#: Imaginary step of the complex-step derivative [rad] (any tiny step: no cancellation).
COMPLEX_STEP = 1e-30


@dataclass(frozen=True)
class DesignVerdict:
    """Outcome of ``design_verdict``.

    Attributes
    ----------
    verdict : one of ``VERDICTS``
    reasons : one line each, the first the integrability test, then the closed-form
        conditions or the motion that is impossible
    wedge : max over samples and components of |w ^ dw| / J^2 [-]
    wedge_at : (N + 1,) configuration th0..thN where it was found [rad]
    wedge_component : (i, j, k), i < j < k, the component of w ^ dw found there
    tolerance : the relative tolerance it was compared with (``INTEGRABILITY_RTOL``)
    samples : how many configurations were evaluated
    scale : J [kg m^2] (``chain.inertia_scale``)
    k10 : K_10 [kg m^2], the coupling of base and link 1 (for N = 2, a1 = 2 M K_10)
    conserved : (N + 1,) the constant h_i [kg m^2] when every h_i is constant (then
        sum_i h_i th_i is conserved), else None
    """

    verdict: Verdict
    reasons: tuple[str, ...]
    wedge: float
    wedge_at: tuple[float, ...]
    wedge_component: tuple[int, int, int]
    tolerance: float
    samples: int
    scale: float
    k10: float
    conserved: tuple[float, ...] | None

    @property
    def headline(self) -> str:
        """What the verdict means, one short clause (``HEADLINES``)."""
        return HEADLINES[self.verdict]

    def numbers(self) -> str:
        """The K_10 test's numbers, one line."""
        return (f"K_10 = {self.k10:.6g} kg m^2, J = {self.scale:.6g} kg m^2: |K_10| / J = "
                f"{abs(self.k10) / self.scale:.3g} (counted as 0 at or below {DESIGN_ZERO_TOL:g})")

    @property
    def controllable(self) -> bool:
        """w ^ dw != 0 somewhere: controllable, hence flat (``closed_form`` or ``flat``)."""
        return self.verdict != "not_flat"


def _arrays(robot: RobotParams) -> tuple[Array, Array, Array, Array]:
    """mass, inertia, length, com of the robot's equivalent placement (``placement``: a
    centre of mass across the last link is its turn; the angles then shift by it)."""
    equivalent = robot.placement[0]
    return tuple(np.asarray(v, dtype=float)  # type: ignore[return-value]
                 for v in (equivalent.mass, equivalent.inertia, equivalent.length,
                           equivalent.com))


def constraint_form(robot: RobotParams, theta: Array) -> Array:
    """The one-form's coefficients h_i = dH/dth_i' from the full link kinematics.

    Parameters
    ----------
    robot : RobotParams with N joints
    theta : (..., N + 1) relative angles th0..thN [rad]

    Returns
    -------
    h : (..., N + 1) [kg m^2], ``chain.chain_momentum`` at the unit rates e_i (H is linear
        in the rates)
    """
    mass, inertia, length, com = _arrays(robot)
    theta = placed(robot, theta)[1]
    n = mass.shape[0]
    shape = (*theta.shape[:-1], n, n)  # (..., i, angle): th at the unit rates e_i
    return np.asarray(chain_momentum(mass, inertia, length, com,
                                     np.broadcast_to(theta[..., None, :], shape),
                                     np.broadcast_to(np.eye(n), shape)))


def form_slopes(robot: RobotParams, theta: Array) -> Array:
    """dh_i/dth_k by complex step through the link kinematics (exact to rounding).

    Parameters
    ----------
    robot : RobotParams with N joints
    theta : (..., N + 1) [rad]

    Returns
    -------
    slopes : (..., N + 1, N + 1) [kg m^2 / rad], slopes[..., i, k] = dh_i/dth_k
    """
    mass, inertia, length, com = _arrays(robot)
    theta = placed(robot, theta)[1]
    n = mass.shape[0]
    eye = np.eye(n)
    # (..., k, i, N + 1): th + i step e_k, at the unit rates e_i
    shifted = theta[..., None, None, :] + 1j * COMPLEX_STEP * eye[:, None, :]
    H = chain_momentum(mass, inertia, length, com, shifted, eye[None, :, :])
    return np.swapaxes(H.imag / COMPLEX_STEP, -1, -2)


def wedge_components(n_joints: int) -> tuple[tuple[int, int, int], ...]:
    """The index triples (i, j, k), i < j < k, of w ^ dw on N + 1 angles, in order."""
    return tuple(itertools.combinations(range(n_joints + 1), 3))


def wedge(robot: RobotParams, theta: Array) -> Array:
    """The components of w ^ dw at the configurations theta.

    Parameters
    ----------
    robot : RobotParams with N joints
    theta : (..., N + 1) [rad]

    Returns
    -------
    (..., C) [kg^2 m^4 / rad^3], C = (N + 1) N (N - 1) / 6, in the order of
    ``wedge_components``: h_i F_jk - h_j F_ik + h_k F_ij, F_jk = dh_k/dth_j - dh_j/dth_k
    """
    return _wedge_of(constraint_form(robot, theta), form_slopes(robot, theta))


def _wedge_of(h: Array, slopes: Array) -> Array:
    """``wedge`` from h (..., N + 1) and slopes (..., N + 1, N + 1)."""
    curl = np.swapaxes(slopes, -1, -2) - slopes  # F[..., j, k] = dh_k/dth_j - dh_j/dth_k
    out = [h[..., i] * curl[..., j, k] - h[..., j] * curl[..., i, k] + h[..., k] * curl[..., i, j]
           for i, j, k in wedge_components(h.shape[-1] - 1)]
    return np.stack(out, axis=-1)


def sample_configurations(n_joints: int, samples: int = SAMPLES, seed: int = SEED) -> Array:
    """(samples, N + 1) configurations, uniform in [-pi, pi) from a fixed seed [rad]."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-np.pi, np.pi, (samples, n_joints + 1))


def design_verdict(robot: RobotParams, samples: int = SAMPLES,
                   rtol: float = INTEGRABILITY_RTOL) -> DesignVerdict:
    """Decide whether a design is flat with closed-form outputs, flat, or not flat.

    Parameters
    ----------
    robot : RobotParams, any N >= 2
    samples : configurations at which w ^ dw is evaluated (``sample_configurations``)
    rtol : max |w ^ dw| / J^2 at or below which the constraint counts as integrable

    Returns
    -------
    DesignVerdict (module docstring: the criterion and the three verdicts)
    """
    n = robot.n_joints
    mass, inertia, length, com = _arrays(robot)
    scale = inertia_scale(mass, inertia, length, com)
    theta = sample_configurations(n, samples)
    h, slopes = constraint_form(robot, theta), form_slopes(robot, theta)
    values = np.abs(_wedge_of(h, slopes)) / scale**2
    where = np.unravel_index(int(np.argmax(values)), values.shape)
    top = float(values[where])
    at = tuple(float(v) for v in theta[where[0]])
    component = wedge_components(n)[int(where[1])]
    k10 = float(barycentric_matrix(mass, length, com)[1, 0])
    found = (f"max |w ^ dw| / J^2 = {top:.3g} over {samples} sampled configurations "
             f"(component {''.join(map(str, component))}, at th = "
             f"({', '.join(f'{v:.3g}' for v in at)}) rad; J = {scale:.4g} kg m^2, "
             f"tolerance {rtol:g})")
    base = DesignVerdict("not_flat", (), wedge=top, wedge_at=at, wedge_component=component,
                         tolerance=rtol, samples=samples, scale=scale, k10=k10, conserved=None)
    check = flatness_check(robot)
    if top <= rtol:
        weights = h.mean(axis=0) if np.abs(slopes).max() / scale <= rtol else None
        reasons = [f"w ^ dw = 0: {found}: ker w is integrable, the robot is not "
                   "controllable, hence not flat", _impossible(weights), *check.failures]
        return replace(base, reasons=tuple(reasons), conserved=None if weights is None
                       else tuple(float(v) for v in weights))
    controllable = (f"w ^ dw != 0: {found}: ker w is bracket generating, so the robot is "
                    "controllable and, driftless of codimension one, flat")
    if check.is_flat:
        return replace(base, verdict="closed_form",
                       reasons=(controllable, _closed_form(robot, k10)))
    plans = (f"the closed-form outputs need d{n} = 0 and K_10 != 0, so plan.method = \"flat\" "
             "refuses this design; plan.method = \"auto\" (the default) and \"exact\" plan it "
             "exactly (docs/asbuilt.md), and it can be simulated as the [plant] of a nominal "
             "robot that has them")
    return replace(base, verdict="flat", reasons=(controllable, *check.failures, plans))


def _closed_form(robot: RobotParams, k10: float) -> str:
    n = robot.n_joints
    if n == 2:
        return (f"d2 = 0 and c0 a1 != 0 (a1 = 2 M K_10 = {2 * robot.total_mass * k10:.4g} "
                "kg^2 m^2): the paper's flat outputs y1 = th1, y2 = th0 - c0 th2/(a0 + a1 "
                "cos th1) apply, singular where sin th1 = 0 or th1' = 0; flatcli plans it")
    return (f"d{n} = 0, I{n} != 0 and K_10 = {k10:.4g} kg m^2 != 0: the flat outputs y_j = "
            f"th_j (j < {n}), y{n} = th0 + I{n} th{n} / h_0(q) apply, singular where "
            "dh_0/dt = 0; flatcli plans it")


def _impossible(weights: Array | None) -> str:
    """The motion an integrable constraint forbids, one line."""
    if weights is None:  # not reached for RobotParams (module docstring): kept general
        return ("the base attitude th0 is a function of the joint angles on each leaf: "
                "cycling the joints cannot reorient the base")
    terms = " + ".join(f"{w:.4g} th{i}" for i, w in enumerate(weights)).replace("+ -", "- ")
    return (f"every h_i is constant (every coupling K_ab, a != b, is 0): {terms} [kg m^2 rad] "
            "is conserved, so th0 = const - (h_1 th1 + ...) / h_0 is fixed by the joint "
            "angles: joints that come back to their angles bring the base back to its "
            "attitude, so no maneuver reorients the base (a full turn of joint j turns it by "
            "-2 pi h_j / h_0)")
