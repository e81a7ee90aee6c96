"""Robots from and to URDF (flatcli/urdf.py, `robot = "arm.urdf"`, `flatcli export-robot`).

Referees, none of them flatcli's reader:

* tests/data/planar_arm.urdf, written by hand (x-z plane, an elbow axis reversed, parts on
  fixed joints, inertia tensors in rotated frames), worked out by hand in its header with the
  parallel-axis theorem: it is the robot of Franch, Agrawal, Oh, Fattah (IROS 2003), Sec. VI.
* the angular momentum about the system's centre of mass from the URDF's full 3-D link
  kinematics (``urdf_momentum``: this module's own reading of the XML with ElementTree, its
  own rotations, velocities by complex step of the link positions), against
  ``chain.chain_momentum`` of the robot read back, at random states: that checks every mass,
  inertia, length, centre of mass, axis sign and angle offset at once.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from flatcli.cli import main
from flatcli.core.errors import FlatcliError
from flatcli.core.robots.chain import chain_momentum
from flatcli.core.robots.params import PAPER_ROBOT, RobotParams, placed
from flatcli.urdf import read_urdf, urdf_robot, urdf_text

Array = NDArray[np.float64]
ROOT = Path(__file__).resolve().parents[1]
ARM = ROOT / "tests" / "data" / "planar_arm.urdf"
EXAMPLES = ROOT / "examples" / "robots"
#: Parameters read back from a file flatcli wrote, or worked out by hand [kg, kg m^2, m].
ROUND_TRIP_TOL = 1e-12
#: The momentum of the 3-D referee against the planar robot's [kg m^2/s] (rounding of a
#: few dozen products of order 1).
MOMENTUM_TOL = 1e-12
#: Complex-step size of the referee's velocities (exact to rounding, no difference taken).
STEP = 1e-30


# ---------------------------------------------------------------------------------------
# The referee: a URDF's angular momentum from its full 3-D kinematics


def _rot(rpy: str | None) -> NDArray[np.complex128]:
    r, p, y = (float(v) for v in (rpy or "0 0 0").split())
    cx, sx, cy, sy, cz, sz = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return (rz @ ry @ rx).astype(complex)


def _about(axis: Array, angle: complex) -> NDArray[np.complex128]:
    """Rodrigues' rotation by a (complex) angle about a unit axis."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def _xyz(node: ET.Element | None, attribute: str = "xyz") -> Array:
    text = None if node is None else node.get(attribute)
    return np.array([float(v) for v in (text or "0 0 0").split()])


def urdf_momentum(text: str, base_angle: float, base_rate: float, q: Array, q_dot: Array
                  ) -> float:
    """H . n [kg m^2/s] of a URDF robot whose root link turns by ``base_angle`` [rad] at
    ``base_rate`` [rad/s] about n (its first moving joint's axis in the root frame) while
    its moving joints, in the file's order from the root, are at q [rad] turning at q_dot
    [rad/s]: sum of R I R^T w + m (r - r_c) x (v - v_c) over every link with mass."""
    root = ET.fromstring(text)
    links = {link.get("name"): link for link in root.findall("link")}
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}  # type: ignore[union-attr]
    moving = []
    name = next(n for n in links if n not in joints)
    base = name
    order = [name]
    while True:  # the chain, for the joint order (fixed children visited below)
        nxt = [j for j in root.findall("joint") if j.find("parent").get("link") == name  # type: ignore[union-attr]
               and j.get("type") != "fixed"]
        if not nxt:
            break
        moving.append(nxt[0].get("name"))
        name = nxt[0].find("child").get("link")  # type: ignore[union-attr]
        order.append(name)
    first = next(j for j in root.findall("joint") if j.get("name") == moving[0])
    normal = (_rot(first.find("origin").get("rpy") if first.find("origin") is not None
                   else None).real @ _xyz(first.find("axis")))
    normal = normal / np.linalg.norm(normal)
    value = {m: (q[i] + 1j * STEP * q_dot[i]) for i, m in enumerate(moving)}
    turn = _about(normal, base_angle + 1j * STEP * base_rate)

    def frame(link: str) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
        if link == base:
            return turn, np.zeros(3, dtype=complex)
        joint = joints[link]
        R_p, p_p = frame(joint.find("parent").get("link"))  # type: ignore[union-attr]
        origin = joint.find("origin")
        R = _rot(None if origin is None else origin.get("rpy"))
        p = _xyz(origin)
        if joint.get("type") != "fixed":
            axis = _xyz(joint.find("axis"))
            R = R @ _about(axis / np.linalg.norm(axis), value[joint.get("name")])
        return R_p @ R, p_p + R_p @ p

    masses, places, speeds, spins = [], [], [], []
    for link_name, link in links.items():
        inertial = link.find("inertial")
        if inertial is None:
            continue
        R, p = frame(link_name)
        origin = inertial.find("origin")
        centre = p + R @ _xyz(origin)
        Ri = R @ _rot(None if origin is None else origin.get("rpy"))
        i = inertial.find("inertia")
        get = {k: float(i.get(k)) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}  # type: ignore[union-attr, arg-type]
        tensor = np.array([[get["ixx"], get["ixy"], get["ixz"]],
                           [get["ixy"], get["iyy"], get["iyz"]],
                           [get["ixz"], get["iyz"], get["izz"]]])
        R_dot = Ri.imag / STEP
        Rr = Ri.real
        omega_hat = R_dot @ Rr.T
        omega = np.array([omega_hat[2, 1], omega_hat[0, 2], omega_hat[1, 0]])
        masses.append(float(inertial.find("mass").get("value")))  # type: ignore[union-attr, arg-type]
        places.append(centre.real)
        speeds.append(centre.imag / STEP)
        spins.append(Rr @ tensor @ Rr.T @ omega)
    m = np.array(masses)
    r_c = (m[:, None] * np.array(places)).sum(0) / m.sum()
    v_c = (m[:, None] * np.array(speeds)).sum(0) / m.sum()
    total = sum(spins) + sum(mi * np.cross(r - r_c, v - v_c)
                             for mi, r, v in zip(m, places, speeds, strict=True))
    n_now = turn.real @ normal
    return float(total @ n_now)


def flatcli_momentum(robot: RobotParams, theta: Array, theta_dot: Array) -> float:
    equivalent, angles = placed(robot, theta)
    return float(chain_momentum(*(np.asarray(v, dtype=float) for v in (
        equivalent.mass, equivalent.inertia, equivalent.length, equivalent.com)),
        angles, theta_dot))


def _variants() -> dict[str, str]:
    """The hand-written arm, and the same arm changed where the reader must work: a bent
    zero pose (the elbow's origin turned in the plane: an angle offset), the whole arm in a
    tilted plane (the shoulder's origin rolled), a counterweight moved across the forearm
    (com_across), and a three-joint chain written by flatcli."""
    text = ARM.read_text()
    bent = text.replace('<origin xyz="0.2 0 0"/>\n    <axis xyz="0 -1 0"/>',
                        '<origin xyz="0.2 0 0" rpy="0 0.4 0"/>\n    <axis xyz="0 -1 0"/>')
    tilted = text.replace('<origin xyz="0.2 0 0" rpy="0 0 0"/>\n    <axis xyz="0 1 0"/>',
                          '<origin xyz="0.2 0 0" rpy="0.3 -0.2 0.5"/>\n    <axis xyz="0 1 0"/>')
    across = text.replace('<origin xyz="-0.05 0 0"/>', '<origin xyz="-0.05 0 0.01"/>')
    assert len({text, bent, tilted, across}) == 4  # every replacement took
    chain = urdf_text(RobotParams(mass=(2.0, 1.0, 0.7, 0.5), inertia=(0.1, 0.05, 0.04, 0.15),
                                  length=(0.3, 0.25, 0.2, 0.2), com=(0.1, 0.12, 0.08, 0.0)))
    return {"hand": text, "bent": bent, "tilted": tilted, "across": across, "chain": chain}


VARIANTS = _variants()


# ---------------------------------------------------------------------------------------
# Reading


def test_the_hand_written_arm_is_the_papers_robot_worked_out_by_hand() -> None:
    read = read_urdf(ARM)
    for field in ("mass", "inertia", "length", "com"):
        assert np.allclose(getattr(read.robot, field), getattr(PAPER_ROBOT, field),
                           rtol=0, atol=ROUND_TRIP_TOL), field
    assert read.robot.com_across == 0.0
    assert read.joints == ("shoulder", "elbow") and read.links == ("hub", "upper_arm",
                                                                     "forearm")
    assert read.tip == "tool" and read.axis_sign == (1, -1)
    assert read.angle_offset == pytest.approx((0.0, 0.0), abs=1e-15)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_the_robot_read_has_the_urdfs_momentum_from_its_full_3d_kinematics(
        variant: str) -> None:
    text = VARIANTS[variant]
    read = urdf_robot(text)
    rng = np.random.default_rng(7)
    n = read.robot.n_joints
    largest = 0.0
    for _ in range(5):
        q, q_dot = rng.uniform(-2, 2, n), rng.uniform(-1, 1, n)
        base, base_rate = rng.uniform(-3, 3), rng.uniform(-1, 1)
        sign = np.array(read.axis_sign, dtype=float)
        theta = np.concatenate([[base], np.array(read.angle_offset) + sign * q])
        theta_dot = np.concatenate([[base_rate], sign * q_dot])
        expected = urdf_momentum(text, base, base_rate, q, q_dot)
        largest = max(largest, abs(expected))
        assert flatcli_momentum(read.robot, theta, theta_dot) == pytest.approx(
            expected, rel=0, abs=MOMENTUM_TOL)
    assert largest > 1e-2  # states that move


def test_the_variants_read_as_they_were_changed() -> None:
    # flatcli's angles turn about n = the shoulder's axis, y, whatever a joint's own axis:
    # the elbow's frame pitched by 0.4 rad about y bends the forearm by +0.4 about n
    assert urdf_robot(VARIANTS["bent"]).angle_offset == pytest.approx((0.0, 0.4), abs=1e-14)
    across = urdf_robot(VARIANTS["across"]).robot
    # the counterweight (0.5 of 1 kg) 1 cm along z moves the forearm's centre 0.5 cm along
    # z; the side of increasing th_N is n x x = y x x = -z, so e_N = -0.005 m
    assert across.com_across == pytest.approx(-0.005, abs=1e-15)
    # the arm turned out of the root's x-z plane with the shoulder's frame: its two links are
    # the paper's still, the base (left in the root frame) is seen across a tilted plane
    tilted = urdf_robot(VARIANTS["tilted"]).robot
    for field in ("mass", "inertia", "length", "com"):
        assert np.allclose(getattr(tilted, field)[1:], getattr(PAPER_ROBOT, field)[1:],
                           rtol=0, atol=1e-12), field
    assert tilted.inertia[0] != pytest.approx(PAPER_ROBOT.inertia[0], abs=1e-6)


def test_the_shipped_urdf_examples_are_the_papers_robot_and_chain4() -> None:
    import tomllib

    chain4 = tomllib.loads((ROOT / "flatcli" / "data" / "robots" / "chain4.toml").read_text())
    expected = {"paper": PAPER_ROBOT, "chain4": RobotParams(**chain4["robot"])}
    for name, robot in expected.items():
        read = read_urdf(EXAMPLES / f"{name}.urdf").robot
        assert np.allclose(read.as_array(), robot.as_array(), rtol=0, atol=ROUND_TRIP_TOL)
        assert read.com_across == robot.com_across


# ---------------------------------------------------------------------------------------
# Writing: a round trip gives the same robot


LINK = st.floats(0.05, 5.0)


@st.composite
def robots(draw: st.DrawFn) -> RobotParams:
    n = draw(st.integers(2, 6))
    size = n + 1
    return RobotParams(
        mass=tuple(draw(LINK) for _ in range(size)),
        inertia=tuple(draw(st.floats(1e-4, 1.0)) for _ in range(size)),
        length=tuple(draw(st.floats(0.01, 2.0)) for _ in range(size)),
        com=tuple(draw(st.floats(-1.0, 1.0)) for _ in range(size)),
        com_across=draw(st.floats(-0.1, 0.1)))


@settings(max_examples=40, deadline=None)
@given(robots())
def test_a_round_trip_gives_the_same_robot(robot: RobotParams) -> None:
    read = urdf_robot(urdf_text(robot, "any")).robot
    assert np.allclose(read.as_array(), robot.as_array(), rtol=0, atol=ROUND_TRIP_TOL)
    assert read.com_across == pytest.approx(robot.com_across, abs=ROUND_TRIP_TOL)


# ---------------------------------------------------------------------------------------
# Refusals: one line naming the joint or element


def _arm(old: str, new: str) -> str:
    text = ARM.read_text()
    assert old in text
    return text.replace(old, new)


REFUSALS = {
    "prismatic": (_arm('name="elbow" type="continuous"', 'name="elbow" type="prismatic"'),
                  "joint 'elbow' is prismatic: flatcli's robots are planar chains of revolute"),
    "floating": (_arm('name="shoulder" type="revolute"', 'name="shoulder" type="floating"'),
                 "joint 'shoulder' is floating"),
    "axes": (_arm('<axis xyz="0 -1 0"/>', '<axis xyz="0 -1 0.2"/>'),
             "joint 'elbow': its axis (0, -0.9806, 0.1961) is 11.3 deg off joint 'shoulder'"),
    "branch": (_arm('<link name="tool"/>', '<link name="tool"/>\n<joint name="thumb" '
                    'type="revolute"><parent link="upper_arm"/><child link="gripper"/><axis '
                    'xyz="0 1 0"/><limit effort="1" velocity="1"/></joint><link '
                    'name="gripper"><inertial><mass value="0.1"/><inertia ixx="1" ixy="0" '
                    'ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>'),
               "link 'upper_arm' carries 2 moving joints ('elbow', 'thumb'): flatcli's "
               "robots are serial chains, no branches"),
    "xml": ("<robot name='x'><link name='a'></robot>", "not well-formed XML: mismatched tag"),
    "number": (_arm('<mass value="0.8"/>', '<mass value="heavy"/>'),
               "<mass value=\"heavy\"> of link 'hub' is not a number"),
    "missing mass": (_arm('<mass value="0.8"/>', '<mass/>'),
                     "<mass value> is missing in link 'hub'"),
    "no tip": (_arm('<link name="tool"/>', '').replace(
        '<joint name="tool_mount" type="fixed">\n    <parent link="forearm"/>\n    <child '
        'link="tool"/>\n    <origin xyz="0.2 0 0"/>\n  </joint>', ''),
        "link 'forearm' (the last) has no tip"),
    "massless": (_arm('<mass value="1.0"/>', '<mass value="0"/>'),
                 "link 'upper_arm' has no mass"),
    "across": (_arm('<origin xyz="0.1 0 0" rpy="1.5707963267948966 0 0"/>',
                    '<origin xyz="0.1 0 0.02" rpy="1.5707963267948966 0 0"/>'),
               "link 'upper_arm': its centre of mass lies -0.02 m across the line from joint "
               "'shoulder' to joint 'elbow'"),
    "one joint": (_arm('name="elbow" type="continuous"', 'name="elbow" type="fixed"'),
                  "1 revolute joint: flatcli's robots have a base and N >= 2 links"),
    "unknown link": (_arm('<child link="tool"/>', '<child link="tol"/>'),
                     "joint 'tool_mount': its child link 'tol' is not a <link>"),
}


@pytest.mark.parametrize("case", list(REFUSALS))
def test_a_urdf_flatcli_cannot_model_is_refused_naming_the_joint_or_element(case: str) -> None:
    text, message = REFUSALS[case]
    with pytest.raises(FlatcliError) as info:
        urdf_robot(text, "arm.urdf")
    assert str(info.value).startswith("arm.urdf: ") and "\n" not in str(info.value)
    assert message in str(info.value), str(info.value)


# ---------------------------------------------------------------------------------------
# The command line: robot = "arm.urdf", --robot arm.urdf, export-robot


def run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.output


def test_the_hand_written_arm_plans_as_the_papers_robot_does(tmp_path: Path) -> None:
    import pandas as pd

    code, out = run("plan", "--robot", str(ARM), "--out", str(tmp_path / "urdf"))
    assert code == 0, out
    code, out = run("plan", "--out", str(tmp_path / "paper"))
    assert code == 0, out
    urdf = pd.read_parquet(tmp_path / "urdf" / "plan.parquet")
    paper = pd.read_parquet(tmp_path / "paper" / "plan.parquet")
    columns = [c for c in paper.columns if c.startswith(("theta", "y"))]
    # the same robot up to the rounding of the hand derivation (5e-17 relative)
    assert np.allclose(urdf[columns], paper[columns], rtol=0, atol=1e-9)


def test_the_hand_written_arm_tracks_as_the_papers_robot_and_sweeps_from_a_spec(
        tmp_path: Path) -> None:
    import json

    import pandas as pd

    spec = tmp_path / "arm_study.toml"
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "arm.urdf").write_text(ARM.read_text())
    spec.write_text('name = "arm"\nrobot = "robots/arm.urdf"\n[sweep]\ntrials = 4\n'
                    '[sweep.perturb]\ninitial = { dist = "normal", std = 0.01 }\n')
    for args, out in (([str(spec)], "urdf"), ([], "paper")):
        code, text = run("track", *args, "--out", str(tmp_path / out), "--quiet")
        assert code == 0, text
    urdf, paper = (json.loads((tmp_path / d / "metrics.json").read_text())
                   for d in ("urdf", "paper"))
    for key, value in paper.items():  # the paper's printed gains: a poor track, the same one
        if isinstance(value, float):
            assert urdf[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
        else:
            assert urdf[key] == value, key
    code, text = run("sweep", str(spec), "--out", str(tmp_path / "sweep"), "--workers", "1",
                     "--quiet")
    assert code == 0, text
    trials = pd.read_parquet(tmp_path / "sweep" / "trials.parquet")
    assert len(trials) == 4 and set(trials["status"]) <= {"ok", "singular"}


@pytest.mark.parametrize("case", ["prismatic", "axes", "branch", "xml", "no tip"])
def test_a_bad_urdf_on_the_command_line_is_one_line_exit_2_and_nothing_written(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str) -> None:
    monkeypatch.chdir(tmp_path)
    text, message = REFUSALS[case]
    (tmp_path / "arm.urdf").write_text(text)
    for args in (["plan", "--robot", "arm.urdf"], ["export-robot", "--robot", "arm.urdf",
                                                    "--urdf", "--out", "x.urdf"]):
        code, out = run(*args)
        assert code == 2, out
        assert out.startswith("error: arm.urdf: ") and out.count("\n") == 1, out
        assert message in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arm.urdf"]


def test_a_missing_urdf_is_one_line_exit_2(tmp_path: Path) -> None:
    code, out = run("track", "--robot", str(tmp_path / "nowhere.urdf"))
    assert code == 2 and out == f"error: URDF file not found: {tmp_path / 'nowhere.urdf'}\n"


def test_a_urdf_given_as_the_spec_says_to_pass_it_as_the_robot(tmp_path: Path) -> None:
    code, out = run("plan", str(ARM), "--out", str(tmp_path / "p"))
    assert code == 2 and out.count("\n") == 1
    assert f"{ARM} is a URDF, a robot rather than a spec: pass it as --robot {ARM}" in out
    assert not (tmp_path / "p").exists()


def test_export_robot_writes_a_urdf_that_reads_back_as_the_specs_robot(tmp_path: Path) -> None:
    out = tmp_path / "chain4.urdf"
    code, text = run("export-robot", "--robot", "chain4", "--set", "robot.com_across=0.003",
                     "--urdf", "--out", str(out))
    assert code == 0 and text == f"wrote {out}\n", text
    import tomllib

    chain4 = tomllib.loads((ROOT / "flatcli" / "data" / "robots" / "chain4.toml").read_text())
    expected = RobotParams(**chain4["robot"], com_across=0.003)
    read = read_urdf(out).robot
    assert np.allclose(read.as_array(), expected.as_array(), rtol=0, atol=ROUND_TRIP_TOL)
    assert read.com_across == pytest.approx(0.003, abs=ROUND_TRIP_TOL)
    # standard output, and back in through --robot: the same file again
    code, printed = run("export-robot", "--robot", str(out), "--urdf", "--set", "name=chain4")
    assert code == 0 and urdf_robot(printed).robot == read
    code, message = run("export-robot", "--robot", "chain4")
    assert code == 2 and message == "error: export-robot: choose a format: --urdf\n"
