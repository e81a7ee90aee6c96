"""Tests of the counterweight designer (flatcli.core.robots.counterweight, flatcli.designer and
``flatcli design --counterweight``).

Referees: the centre of mass and the inertia about the joint from their definitions
((m r + m_c p) / (m + m_c), parallel axes); a brute-force search over the allowed segment;
the Python API planning the resulting design (its input energy) and judging it
(``design_verdict``).
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

import flatcli
from flatcli.cli import main
from flatcli.core.errors import FlatcliError
from flatcli.core.robots.counterweight import apply, design_counterweight
from flatcli.core.robots.design import design_verdict
from flatcli.core.robots.params import RobotParams

#: Balancing to rounding.
ROUNDING = 1e-12


def _balance(m: float, r: np.ndarray, mc: float, p: np.ndarray) -> np.ndarray:
    return (m * r + mc * p) / (m + mc)


@pytest.mark.parametrize("segment", [[[-0.1, 0.0], [-0.02, 0.0]],   # along the axis, behind
                                     [[-0.2, -0.05], [0.0, -0.05]],  # across it, crossing
                                     [[-0.05, 0.1], [-0.05, -0.1]]])
def test_least_mass_and_least_inertia_balance_the_link(segment: list[list[float]]) -> None:
    """Referee: the centre of mass (definition) is on the joint; brute force over 2001
    points of the segment: no balancing point needs less mass or adds less inertia."""
    m, inertia, d, e = 0.5, 0.01, 0.05, 0.02 if segment[0][1] != 0 else 0.0
    light, compact = design_counterweight(m, inertia, d, e, segment)
    r = np.array([d, e])
    for cw in (light, compact):
        p = np.array([cw.x, cw.y])
        np.testing.assert_allclose(_balance(m, r, cw.mass, p), 0.0, atol=ROUNDING)
        want = inertia + m * (r @ r) + cw.mass * (p @ p)
        assert cw.link_inertia == pytest.approx(want, rel=1e-12)
        assert cw.link_mass == pytest.approx(m + cw.mass)
    a, b = np.asarray(segment)
    points = a + np.linspace(0, 1, 2001)[:, None] * (b - a)
    unit = -r / np.linalg.norm(r)
    along = points @ unit
    off = np.abs(points @ np.array([-unit[1], unit[0]]))
    ok = (off <= 1e-3 * np.abs(points).max()) & (along > 0)
    masses = m * np.linalg.norm(r) / along[ok]
    added = masses * along[ok] ** 2
    assert light.mass <= masses.min() * (1 + 1e-2)
    assert compact.mass * compact.distance**2 <= added.min() * (1 + 1e-2)


def test_a_segment_off_the_ray_is_refused() -> None:
    with pytest.raises(FlatcliError, match=r"^--positions: no allowed position lies on the ray"):
        design_counterweight(0.5, 0.01, 0.05, 0.0, [[0.1, 0.0], [0.2, 0.0]])
    with pytest.raises(FlatcliError, match=r"needs no counterweight"):
        design_counterweight(0.5, 0.01, 0.0, 0.0, [[-0.1, 0.0], [-0.2, 0.0]])


def test_cli_reports_each_design_its_verdict_and_plan_energy() -> None:
    """Referee: the API planning each resulting robot, and design_verdict of it."""
    sets = ["--set", "robot.com=[0.1,0.1,0.05]", "--set", "robot.mass=[1,1,0.5]"]
    result = CliRunner().invoke(main, ["design", "--counterweight", "--positions", "-0.1",
                                       "0", "-0.02", "0", *sets])
    assert result.exit_code == 0, result.output
    bare = RobotParams(mass=(1, 1, 0.5), com=(0.1, 0.1, 0.05))
    for label, cw in zip(("least mass", "least inertia"),
                         design_counterweight(0.5, 0.0533, 0.05, 0.0, [[-0.1, 0], [-0.02, 0]]),
                         strict=True):
        robot = apply(bare, cw)
        assert design_verdict(robot).verdict == "closed_form"
        energy = flatcli.plan(overrides={"robot.mass": list(robot.mass),
                                         "robot.inertia": list(robot.inertia),
                                         "robot.com": list(robot.com)}).metrics["input_energy"]
        row = next(line for line in result.output.splitlines() if line.startswith(f"| {label}"))
        assert "closed_form" in row and f"{energy:.6g}" in row
