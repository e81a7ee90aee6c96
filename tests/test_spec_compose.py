"""Specs that compose (flatcli/spec/compose.py): robot files picked by name or path, files
included relative to the file that includes them, and the order they merge in."""

from __future__ import annotations

from pathlib import Path

import pytest

from flatcli.spec import SpecError, load_spec, parse_set, resolve
from flatcli.spec.compose import MAX_FILES, ROBOTS, robot_names

#: flatcli/data/robots/chain4.toml's robot (base + 3 links), as written there.
CHAIN4_MASS = (2.0, 1.0, 1.0, 0.5)


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_the_shipped_robots_are_package_data() -> None:
    assert robot_names() == ["chain4", "chain6", "paper"]
    assert all((ROBOTS / f"{n}.toml").is_file() for n in robot_names())
    assert resolve({"robot": "paper"}).digest() == resolve({}).digest()  # the defaults


def test_a_robot_name_picks_its_file_and_the_spec_overrides_it(tmp_path: Path) -> None:
    spec = load_spec(write(tmp_path / "s.toml", 'robot = "chain4"\n[plan]\nduration = 3.0\n'))
    assert spec.joints == 3 and spec.robot.mass == CHAIN4_MASS
    assert spec.plan.duration == 3.0  # the spec's own key wins
    assert spec.track.kp == (25.0, 25.0, 25.0)  # the robot file's gains for its N
    # --robot (a robot override) replaces the file's choice
    assert load_spec(tmp_path / "s.toml", ["robot=chain6"]).joints == 5
    # a [robot] table of the spec still overrides the chosen file key by key
    spec = load_spec(write(tmp_path / "t.toml", "[robot]\nmodel = \"derived\"\n"
                                                "inertia = [0.1, 0.05, 0.05, 0.2]\n"),
                     ["robot=chain4"])
    assert spec.robot.inertia == (0.1, 0.05, 0.05, 0.2) and spec.robot.mass == CHAIN4_MASS


def test_a_users_robot_file_is_relative_to_the_spec(tmp_path: Path) -> None:
    write(tmp_path / "robots" / "mine.toml", "[robot]\nmass = [2.0, 1.0, 1.0]\n")
    spec = load_spec(write(tmp_path / "study" / "s.toml", 'robot = "../robots/mine.toml"\n'))
    assert spec.robot.mass == (2.0, 1.0, 1.0)
    assert resolve({"robot": str(tmp_path / "robots" / "mine.toml")}).robot.mass[0] == 2.0


def test_includes_merge_in_order_below_the_files_own_keys(tmp_path: Path) -> None:
    write(tmp_path / "parts" / "robot.toml", 'include = ["gains.toml"]\n'
          "[robot]\nmass = [2.0, 1.0, 1.0]\n[track]\nkp = [1.0, 2.0]\n")
    write(tmp_path / "parts" / "gains.toml", "[track]\nkp = [3.0, 4.0]\nkv = [5.0, 6.0]\n")
    write(tmp_path / "parts" / "noise.toml", "[track]\nsensor_noise = 0.001\nkv = [7.0, 8.0]\n")
    spec = load_spec(write(tmp_path / "s.toml", 'include = ["parts/robot.toml", '
                                                '"parts/noise.toml"]\n[track]\ndt = 0.002\n'),
                     ["track.kv=[9,10]"])
    assert spec.robot.mass == (2.0, 1.0, 1.0)
    assert spec.track.kp == (1.0, 2.0)  # robot.toml's own key above the file it includes
    assert spec.track.sensor_noise == 0.001 and spec.track.dt == 0.002
    assert spec.track.kv == (9.0, 10.0)  # --set last
    assert load_spec(tmp_path / "s.toml").track.kv == (7.0, 8.0)  # the later include wins


@pytest.mark.parametrize(("files", "message"), [
    ({"a.toml": 'include = ["b.toml"]', "b.toml": 'include = ["a.toml"]'},
     r"b\.toml: include 'a\.toml': include cycle .*a\.toml -> .*b\.toml -> .*a\.toml"),
    ({"a.toml": 'include = ["a.toml"]'}, r"include cycle .*a\.toml -> .*a\.toml"),
    ({"a.toml": 'include = ["missing.toml"]'},
     r"a\.toml: include 'missing\.toml': spec file not found: .*missing\.toml"),
    ({"a.toml": 'include = "b.toml"'}, r"a\.toml: include: expected a list of spec files"),
    ({"a.toml": 'robot = "chian4"'}, r"robot: unknown robot 'chian4'; shipped: chain4, "
                                     r"chain6, paper.*\(did you mean 'chain4'\?\)"),
    ({"a.toml": 'robot = "nowhere.toml"'}, r"robot 'nowhere\.toml': spec file not found"),
    ({"a.toml": 'include = ["b.toml"]', "b.toml": "[plan]\nduration = -1\n"},
     r"plan\.duration: must be > 0 s, got -1"),
])
def test_bad_compositions_are_one_line_naming_the_file(tmp_path: Path, files: dict[str, str],
                                                       message: str) -> None:
    for name, text in files.items():
        write(tmp_path / name, text + "\n")
    with pytest.raises(SpecError, match=message) as info:
        load_spec(tmp_path / "a.toml")
    assert "\n" not in str(info.value)


def test_the_number_of_files_is_bounded(tmp_path: Path) -> None:
    for i in range(MAX_FILES + 1):
        write(tmp_path / f"f{i}.toml", f'include = ["f{i + 1}.toml"]\n' if i < MAX_FILES else "")
    with pytest.raises(SpecError, match=f"more than {MAX_FILES} spec files"):
        load_spec(tmp_path / "f0.toml")


def test_include_is_for_files_not_for_set() -> None:
    with pytest.raises(SpecError, match="include: spec files are included by a spec file"):
        resolve({}, {"include": ["x.toml"]})


def test_a_spec_that_picks_a_robot_and_names_nothing_is_named_after_it(tmp_path: Path) -> None:
    write(tmp_path / "my_arm.toml", "[robot]\nmass = [2.0, 1.0, 1.0]\n")
    assert load_spec(None, ["robot=chain4"]).name == "chain4"
    assert load_spec(None, [f"robot='{tmp_path / 'my_arm.toml'}'"]).name == "my_arm"
    assert load_spec(write(tmp_path / "s.toml", 'robot = "my_arm.toml"\n')).name == "my_arm"
    # a robot chosen by an included file names it too; a name set anywhere wins
    write(tmp_path / "base.toml", 'robot = "chain6"\n')
    assert load_spec(write(tmp_path / "i.toml", 'include = ["base.toml"]\n')).name == "chain6"
    assert load_spec(write(tmp_path / "n.toml", 'name = "mine"\nrobot = "chain4"\n')).name == (
        "mine")
    assert load_spec(tmp_path / "s.toml", ["name=other"]).name == "other"
    # the top level's choice names it, whatever an include picked
    assert load_spec(write(tmp_path / "t.toml", 'robot = "chain4"\ninclude = ["base.toml"]\n')
                     ).name == "chain4"
    # the shipped paper robot is flatcli's defaults: the default name, not runs/paper/
    assert load_spec(None, ["robot=paper"]).name == "paper_example"
    # a stem that names no directory keeps the default name
    write(tmp_path / ".hidden.toml", "[robot]\nmass = [2.0, 1.0, 1.0]\n")
    assert load_spec(None, [f"robot='{tmp_path / '.hidden.toml'}'"]).name == "paper_example"


@pytest.mark.parametrize(("text", "message"), [
    ('include = ["loop_a.toml"]', r"a\.toml: include 'loop_a\.toml': cannot read spec file "
                                  r".*loop_a\.toml: a loop of symbolic links$"),
    ('robot = "loop_a.toml"', r"a\.toml: robot 'loop_a\.toml': cannot read spec file .*: a "
                              r"loop of symbolic links$"),
    ('include = ["x\\u0000y.toml"]', r"include 'x\\x00y\.toml': a file name must not contain "
                                    r"a NUL byte$"),
    ('robot = "x\\u0000y.toml"', r"robot: a file name must not contain a NUL byte$"),
    ('robot = "~nosuchuser_flatcli/x.toml"', r"robot: '~nosuchuser_flatcli/x\.toml': no home "
                                             r"directory of user 'nosuchuser_flatcli'$"),
    ('include = ["~nosuchuser_flatcli/x.toml"]', r"include '~nosuchuser_flatcli/x\.toml': no "
                                                 r"home directory of user"),
    ('robot = "../../nowhere/x"', r"a\.toml: robot '\.\./\.\./nowhere/x': spec file not "
                                  r"found: .*nowhere/x$"),
])
def test_misused_file_names_are_one_line_naming_the_key(tmp_path: Path, text: str,
                                                        message: str) -> None:
    """A link loop, a NUL byte, an unknown user's home and a missing robot file each end in
    one SpecError naming what chose the file (robot or include), never a traceback."""
    (tmp_path / "loop_a.toml").symlink_to(tmp_path / "loop_b.toml")
    (tmp_path / "loop_b.toml").symlink_to(tmp_path / "loop_a.toml")
    with pytest.raises(SpecError, match=message) as info:
        load_spec(write(tmp_path / "a.toml", text + "\n"))
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(("sets", "message"), [
    (["robot=../../nowhere/x"], r"^robot '\.\./\.\./nowhere/x': spec file not found"),
    (["robot='~nosuchuser_flatcli/x.toml'"], r"^robot: '~nosuchuser_flatcli/x\.toml': no home"),
    (['robot="x\\u0000y.toml"'], r"^robot: a file name must not contain a NUL byte$"),
])
def test_a_robot_file_chosen_on_the_command_line_is_named_robot(sets: list[str],
                                                                message: str) -> None:
    with pytest.raises(SpecError, match=message):
        load_spec(None, sets)


def test_a_file_unsets_what_its_robot_file_and_includes_gave(tmp_path: Path) -> None:
    write(tmp_path / "base.toml", "[plan]\nduration = 3.0\nsamples = 101\n[track]\ndt = 0.002\n")
    spec = load_spec(write(tmp_path / "s.toml", 'robot = "chain4"\ninclude = ["base.toml"]\n'
                                                'unset = ["plan.goal", "plan.duration", "track"]\n'
                                                "[plan]\nsamples = 51\n"),
                     ["task.end_effector=[0.1,0.3]"])
    assert spec.plan.duration == 2.0  # the default again (base.toml and chain4 set it)
    assert spec.plan.samples == 51  # the file's own keys come after its unset
    assert spec.track.dt == 1e-3  # a section: every key of it
    assert spec.plan.start == (0.0, 1.0, 0.3, 0.0)  # chain4's start is kept
    # chain4's goal is gone: on N = 3 with a target the goal stands at the start
    assert spec.plan.goal == spec.plan.start
    # unset in an included file removes what that file's own includes gave
    write(tmp_path / "inner.toml", 'include = ["base.toml"]\nunset = ["plan.samples"]\n')
    assert load_spec(write(tmp_path / "t.toml", 'include = ["inner.toml"]\n')).plan.samples == 201


def test_set_tilde_removes_a_key_where_it_stands_on_the_command_line() -> None:
    chain = ["robot=chain4", "task.end_effector=[0.1,0.3]"]
    assert load_spec(None, [*chain, "~plan.goal"]).plan.goal == (0.0, 1.0, 0.3, 0.0)
    assert load_spec(None, ["plan.duration=3", "~plan.duration"]).plan.duration == 2.0
    assert load_spec(None, ["~plan.duration", "plan.duration=3"]).plan.duration == 3.0
    # the last item wins, whatever came between
    assert load_spec(None, ["plan.duration=3", "~plan", "plan.duration=4"]).plan.duration == 4.0
    assert load_spec(None, ["plan.duration=3", "plan.duration=4", "~plan"]).plan.duration == 2.0
    # through the API: a "~KEY" key with the value None, on a spec or a dict
    assert resolve({"plan": {"duration": 3.0}}, {"~plan.duration": None}).plan.duration == 2.0
    spec = resolve({}, {"plan.duration": 3.0})
    assert spec.with_overrides({"~plan.duration": None}).plan.duration == 2.0


@pytest.mark.parametrize(("sets", "tree", "message"), [
    (["~plan.gaol"], {}, r"^--set ~plan\.gaol: 'plan\.gaol' is not a spec key or section "
                         r"\(did you mean 'plan\.goal'\?\)$"),
    (["~plan.goal=1"], {}, r"^--set ~plan\.goal: removes the key; it takes no value"),
    ([], {"unset": ["plan.nope"]}, r"^the spec: unset: 'plan\.nope' is not a spec key"),
    ([], {"unset": "plan.goal"}, r"^the spec: unset: expected a list of spec keys"),
    ([], {"unset": [1]}, r"^the spec: unset: expected a list of spec keys"),
])
def test_bad_unsets_are_one_line_naming_the_key(sets: list[str], tree: dict[str, object],
                                                message: str) -> None:
    with pytest.raises(SpecError, match=message):
        resolve(tree, parse_set(sets))


def test_unset_removes_the_key_and_its_section_only() -> None:
    """~plan.goal removes plan.goal, not plan.goal_rate (a key whose name starts the same);
    ~plan removes every key of [plan] and nothing of [plant]."""
    sets = ["plan.goal_rate=0.9", "plan.goal=[1.3,2.1,0.0]", "plant.momentum=0.001"]
    spec = load_spec(None, [*sets, "~plan.goal"])
    assert spec.plan.goal == (1.2, 2.0, 0.0) and spec.plan.goal_rate == 0.9
    spec = load_spec(None, [*sets, "~plan"])
    assert spec.plan.goal_rate == 0.5 and spec.plant.momentum == 0.001
