"""The rules of a search spec's tables (flatcli/spec/searches.py): variables, bounds, the
counterweight, and every refusal one line naming the key."""

from __future__ import annotations

import tomllib
from typing import Any

import pytest
from small_search import SPEC

from flatcli.spec import SpecError, resolve
from flatcli.spec.searches import counterweight_setup, search_variables


def spec_of(text: str = SPEC, **search: Any) -> Any:
    tree = tomllib.loads(text)
    tree["search"].update(search)
    return resolve(tree)


def test_variables_their_bounds_and_the_specs_own_values() -> None:
    spec = spec_of()
    names = [(v.name, v.section, v.key, v.index) for v in search_variables(spec)]
    assert names == [("robot.mass[1]", "robot", "mass", 1),
                     ("robot.length[1]", "robot", "length", 1),
                     ("counterweight.distance", "counterweight", "distance", None)]
    mass, length, distance = search_variables(spec)
    assert (mass.low, mass.high, mass.baseline) == pytest.approx((0.7, 1.3, 1.0))
    assert (length.low, length.high) == pytest.approx((0.14, 0.26))
    assert (distance.low, distance.high, distance.baseline) == (0.07, 0.13, 0.1)
    setup = counterweight_setup(spec.search)
    assert setup is not None and setup.designer and not setup.by_mass


def test_search_keys_enter_no_sweep_digest() -> None:
    """``flatcli sweep`` of a search spec is the sweep without [search]: same digest."""
    tree = tomllib.loads(SPEC)
    plain = {k: v for k, v in tree.items() if k != "search"}
    assert resolve(tree).digest() == resolve(plain).digest()
    other = spec_of(seed=9, candidates=5)
    assert other.digest() == resolve(plain).digest()


def test_a_plant_design_names_its_variables_after_the_plant() -> None:
    text = SPEC.replace('"robot.mass[1]"', '"plant.mass[1]"').replace(
        '"robot.length[1]"', '"plant.length[1]"')
    spec = spec_of(text, apply="plant")
    assert [v.section for v in search_variables(spec)][:2] == ["plant", "plant"]
    # the plant's own values: [plant] where set, [robot] elsewhere
    assert search_variables(spec)[0].baseline == 1.0


@pytest.mark.parametrize(("change", "message"), [
    ({"vary": {"robot.mas[1]": [0.5, 1.0]}},
     r"^search\.vary\.'robot\.mas\[1\]': not a design variable; allowed: .*did you mean"),
    ({"vary": {"robot.mass": [0.5, 1.0]}},
     r"not a design variable; .*give one element, e\.g\. robot\.mass\[1\]$"),
    ({"vary": {"robot.mass[3]": [0.5, 1.0]}},
     r"^search\.vary\.'robot\.mass\[3\]': the robot has links 0\.\.2 .*got index 3$"),
    ({"vary": {"robot.mass[1]": [1.0, 1.0]}}, r"low must be < high, got \[1, 1\]$"),
    ({"vary": {"robot.mass[1]": [0.0, 1.0]}}, r"robot\.mass must stay > 0, got low = 0$"),
    ({"vary": {"robot.com[0]": {"relative": 0.3}}, "counterweight": {}},
     None),  # d0 = 0.1: fine
    ({"vary": {"robot.com_across": {"relative": 0.3}}},
     r"relative bounds of a value that is 0 are \[0, 0\]; give \[low, high\]$"),
    ({"vary": {"robot.mass[1]": {"relative": -1}}}, r"\.relative: must be > 0, got -1$"),
    ({"vary": {"robot.mass[1]": {"rel": 0.1}}}, r"expected \[low, high\] or \{ relative = r \}"),
    ({"vary": {"robot.mass[1]": [0.5, "x"]}}, r"expected a finite number, got 'x'$"),
    ({"vary": {"plant.mass[1]": [0.5, 1.0]}},
     r"search\.apply = \"robot\" varies the robot: name it robot\.mass\[1\]"),
    ({"vary": {"counterweight.mass": [0.1, 1.0]}},
     r"^search\.counterweight\.mass: counterweight\.mass varies, so give its value"),
    ({"counterweight": {"distance": 0.1, "x": -0.1}},
     r"give its place either as distance .* or as mass, x and y, not both$"),
    ({"counterweight": {"distance": 0.1, "color": 1}},
     r"^search\.counterweight\.color: unknown; allowed: "),
    ({"counterweight": {"distance": -0.1}},
     r"^search\.counterweight\.distance: must be > 0, got -0\.1$"),
    ({"vary": {"counterweight.x": [-0.2, 0.0]}, "counterweight": {"mass": 0.5, "x": -0.1},
      "centre": "on_joint"},
     r"a counterweight placed at x, y leaves the link's centre off its joint"),
    ({"vary": {"counterweight.x": [-0.2, 0.0]}, "counterweight": {"distance": 0.1}},
     r"the designer places this counterweight on the balancing ray"),
    ({"vary": {}}, r"^search\.vary: a search needs at least one design variable"),
    ({"objective": "fastest"}, r"^search\.objective: "),
    ({"metric": "min_margin"}, r"^search\.metric: "),
    ({"candidates": 0}, r"^search\.candidates: "),
])
def test_bad_search_tables_are_refused_in_one_line(change: dict[str, Any],
                                                   message: str | None) -> None:
    if message is None:
        assert search_variables(spec_of(**change))
        return
    with pytest.raises(SpecError, match=message) as info:
        search_variables(spec_of(**change))
    assert "\n" not in str(info.value)


def test_on_joint_refuses_a_centre_it_cannot_keep() -> None:
    no_weight = SPEC.split("[search.counterweight]")[0].replace(
        '"counterweight.distance" = [0.07, 0.13]', "")
    with pytest.raises(SpecError, match=r"search\.centre = \"on_joint\": the spec's link 2 "
                                        r"centre is at \(0\.1, 0\) m, off its joint"):
        spec_of(no_weight, centre="on_joint")
    paper = no_weight.replace("com = [0.1, 0.1, 0.1]", "com = [0.1, 0.1, 0.0]").replace(
        "inertia = [0.0533, 0.0533, 0.0433]", "inertia = [0.0533, 0.0533, 0.0533]")
    with pytest.raises(SpecError, match=r"'robot\.com\[2\]': moves link 2's centre off its "
                                        r"joint"):
        spec_of(paper, centre="on_joint", vary={"robot.com[2]": [-0.01, 0.01]})


def test_a_grid_cannot_vary_search_keys() -> None:
    tree = tomllib.loads(SPEC)
    tree["sweep"]["grid"] = {"search.seed": [1, 2]}
    with pytest.raises(SpecError, match=r"cannot grid over 'search\.seed'"):
        resolve(tree)
