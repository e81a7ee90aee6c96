"""Building specs (flatcli/spec/build.py): defaults are the paper's example, files and
overrides apply in order, the digest is stable, and bad input is one line naming the key."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
from pathlib import Path

import pytest

from flatcli.experiment import robot_from
from flatcli.spec import SpecError, build, load_spec, parse_set, read_toml, resolve
from flatcli.spec.limits import MAX_SPEC_BYTES

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_defaults_are_the_papers_example() -> None:
    # Franch et al. (2003), Sec. VI: robot, maneuver and Fig. 4's initial state and gains.
    spec = resolve({})
    assert spec.robot.mass == (1.0, 1.0, 1.0)
    assert spec.robot.inertia == (0.0533, 0.0533, 0.0533)
    assert spec.robot.length == (0.2, 0.2, 0.2)
    assert spec.robot.com == (0.1, 0.1, 0.0)
    assert spec.plan.start == (1.8, 1.0, 0.0)
    assert spec.plan.goal == (1.2, 2.0, 0.0)
    assert (spec.plan.start_rate, spec.plan.goal_rate) == (0.1, 0.5)
    assert spec.track.initial == (1.96, 0.8, -0.1)
    assert spec.track.kv == (100.0, 110.0)
    assert spec.track.kp == (10.0, 13.0)


def test_configs_paper_toml_equals_the_embedded_default() -> None:
    assert load_spec(CONFIGS / "paper.toml").digest() == resolve({}).digest()


def test_set_overrides_with_toml_values_and_bare_words(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('name = "x"\n[track]\nkp = [1, 2]\n')
    spec = load_spec(path, ["track.kp=[25,25]", "plan.duration=3", "robot.model=paper"])
    assert spec.track.kp == (25.0, 25.0)
    assert spec.plan.duration == 3.0
    assert spec.robot.model == "paper"
    assert spec.name == "x"


def test_inf_is_allowed_only_where_it_means_no_limit() -> None:
    assert resolve({}, {"track.rate_limit": math.inf}).track.rate_limit == math.inf
    with pytest.raises(SpecError, match=r"track\.dt"):
        resolve({}, {"track.dt": math.inf})


def test_digest_changes_with_any_value_and_not_with_key_order() -> None:
    a = resolve({"track": {"dt": 0.002, "kp": [1, 2]}})
    b = resolve({"track": {"kp": [1, 2], "dt": 0.002}})
    c = resolve({"track": {"kp": [1, 2], "dt": 0.001}})
    assert a.digest() == b.digest() != c.digest()


@pytest.mark.parametrize(
    ("user", "sets", "message"),
    [
        ({"track": {"kpp": 1}}, [], "unknown key 'track.kpp' (did you mean 'track.kp'?)"),
        ({"robott": {"mass": 1}}, [], "unknown key 'robott' (did you mean 'robot'?)"),
        ({"track": {"kp": [1, 2, 3]}}, [],
         "track.kp: expected 2 numbers (one per joint 1..N) for a robot of 2 joints"),
        ({"track": {"kp": "fast"}}, [], "track.kp: expected a list of N >= 2 numbers"),
        ({"robot": {"mass": [1, 0, 1]}}, [], "robot.mass[1]: must be > 0 kg, got 0"),
        ({"robot": {"inertia": [1, -1, 1]}}, [], "robot.inertia[1]: must be > 0"),
        ({"robot": {"model": "papr"}}, [], "did you mean 'paper'"),
        ({"plan": {"duration": -1}}, [], "plan.duration: must be > 0 s"),
        ({"plan": {"samples": 1.5}}, [], "plan.samples: expected an integer"),
        ({"track": {"dt": True}}, [], "track.dt: expected a number"),
        ({"robot": 3}, [], "robot: expected a [robot] table"),
        ({}, ["track.kp"], "--set: expected KEY=VALUE"),
        ({}, ["track.kp=[1,"], "--set track.kp: cannot read"),
        ({"name": "../evil"}, [], "name: must not contain '/'"),
    ],
)
def test_bad_input_is_one_line_naming_the_key(
    user: dict[str, object], sets: list[str], message: str
) -> None:
    with pytest.raises(SpecError) as info:
        resolve(user, parse_set(sets))
    text = str(info.value)
    assert message in text
    assert "\n" not in text


@pytest.mark.parametrize(
    ("sweep", "message"),
    [
        ({"perturb": {"masss": {"dist": "normal", "std": 0.1}}},
         "sweep.perturb.masss: unknown perturbation"),
        ({"perturb": {"mass": {"dist": "gauss", "std": 0.1}}},
         "sweep.perturb.mass.dist: expected one of ['normal', 'uniform']"),
        ({"perturb": {"mass": {"dist": "normal"}}}, "sweep.perturb.mass.std: required"),
        ({"perturb": {"mass": {"dist": "normal", "std": -1}}}, "std: must be >= 0"),
        ({"perturb": {"mass": {"dist": "uniform", "low": 1, "high": 0}}}, "low must be <= high"),
        ({"perturb": {"mass": {"dist": "normal", "std": 0.1, "sigma": 1}}},
         "sweep.perturb.mass.sigma: not a parameter"),
        ({"perturb": {"initial": {"dist": "normal", "std": 0.1, "relative": True}}},
         "only mass, inertia, length, com, servo_bandwidth, torque_limit can be relative"),
        ({"perturb": {"momentum": {"dist": "normal", "std": [1, 2, 3]}}},
         "sweep.perturb.momentum.std: expected a number"),
        ({"grid": {"track.kp": []}}, "expected a non-empty list"),
        ({"grid": {"track.kpp": [[1, 2]]}}, "not a spec key (did you mean 'track.kp'?)"),
        ({"grid": {"track.kp": [[1, 2, 3]]}},
         "track.kp: expected 2 numbers (one per joint 1..N) for a robot of 2 joints"),
        ({"grid": {"sweep.trials": [1, 2]}}, "cannot grid over 'sweep.trials'"),
        ({"grid": {"sweep.perturb.mass.std": [0.1]}}, "a perturbation grid key"),
        ({"grid": {"gains": [{"track.kpx": [1, 2]}]}}, "not a spec key"),
        ({"trials": -5}, "sweep.trials: must be >= 1, got -5"),
        ({"trials": 0}, "sweep.trials: must be >= 1"),
        ({"chunk": 0}, "sweep.chunk: must be >= 1"),
    ],
)
def test_bad_sweep_tables_are_one_line(sweep: dict[str, object], message: str) -> None:
    with pytest.raises(SpecError) as info:
        resolve({"sweep": sweep})
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_grid_groups_vary_keys_together() -> None:
    spec = resolve({"sweep": {"grid": {"gains": [
        {"label": "printed", "track.kp": [10, 13], "track.kv": [100, 110]},
        {"label": "swapped", "track.kp": [100, 110], "track.kv": [10, 13]},
    ]}}})
    assert len(spec.sweep.grid["gains"]) == 2


def test_missing_and_unparsable_files(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="spec file not found"):
        load_spec(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[track\nkp = 1")
    with pytest.raises(SpecError, match="not valid TOML"):
        load_spec(bad)
    with pytest.raises(SpecError, match="is a directory"):
        load_spec(tmp_path)


#: The paper's example as the canonical JSON of a spec, written out by hand: sorted keys, no
#: spaces, floats as Python writes them, inf as the string "inf", unset keys as null.
PAPER_CANONICAL = {
    "name": "paper_example",
    "plan": {"basis": "auto", "degree": None, "duration": 2.0, "goal": [1.2, 2.0, 0.0],
             "goal_rate": 0.5,
             "optimize": {"angle_limit": ["inf", "inf", "inf"], "constraint_samples": 201,
                          "free_rates": True, "max_iter": 300, "min_margin": 0.02,
                          "objective": None, "rate_limit": "inf"},
             "method": "auto", "rate_warning": 50.0, "samples": 201, "size": 12,
             "start": [1.8, 1.0, 0.0], "start_rate": 0.1},
    "plant": {"com": None, "com_across": None, "inertia": None, "length": None, "mass": None,
              "momentum": 0.0,
              "model": "kinematic", "servo_bandwidth": 100.0, "servo_model": "robot",
              "torque_limit": "inf"},
    "robot": {"com": [0.1, 0.1, 0.0], "com_across": 0.0, "inertia": [0.0533, 0.0533, 0.0533],
              "length": [0.2, 0.2, 0.2], "mass": [1.0, 1.0, 1.0], "model": "derived"},
    "sweep": {"chunk": None, "grid": {}, "perturb": {}, "seed": 0, "trials": 1000,
              "verify": 0.0},
    "task": {"base_attitude": None, "budget": 64, "clearance": 0.0, "elbow": "auto",
             "end_effector": None, "fade": 0.2, "goal_tolerance": 0.001, "obstacles": [],
             "rest": False, "start_end_effector": None},
    "track": {"accuracy": 1e-06, "atol": 1e-10, "controller": "flat",
              "divergence_bound": 10000.0, "dt": 0.001, "error_estimate": "twin",
              "goal_tolerance": 0.001,
              "initial": [1.96, 0.8, -0.1], "initial_rate": None, "integrator": "adaptive",
              "kp": [10.0, 13.0], "kv": [100.0, 110.0], "lqr_bandwidth": None, "lqr_base": 10.0,
              "lqr_terminal": None, "max_steps": 100000, "mpc_backoff": 0.03,
              "mpc_horizon": 20, "mpc_kp": None, "mpc_kv": None, "mpc_margin": 0.05,
              "mpc_sample": 0.1, "mpc_weight_input": 1.0, "mpc_weight_state": 0.0,
              "observe_every": 1, "rate_limit": "inf", "rtol": 5e-08, "seed": 0,
              "sensor_noise": 0.0, "singular_threshold": 0.01, "trial": 0},
}


def test_digest_is_sha256_of_the_canonical_json_written_by_hand() -> None:
    text = json.dumps(PAPER_CANONICAL, sort_keys=True, separators=(",", ":"))
    assert resolve({}).to_json() == text
    assert resolve({}).digest() == hashlib.sha256(text.encode()).hexdigest()


def test_with_overrides_validates_and_leaves_the_original_alone() -> None:
    base = resolve({})
    changed = base.with_overrides({"track.kp": [1, 2], "plan.degree": 5})
    assert changed.track.kp == (1.0, 2.0) and changed.plan.degree == 5
    assert base.track.kp == (10.0, 13.0) and base.plan.degree is None
    with pytest.raises(SpecError, match=r"plant\.mass\[1\]: must be > 0 kg, got -1"):
        base.with_overrides({"plant.mass": [1, -1, 1]})


def test_records_are_frozen() -> None:
    spec = resolve({})
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.track.dt = 0.5  # type: ignore[misc]


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"robot.inertia": [1e308, 0.05, 0.05]}, r"robot\.inertia\[0\]: must lie within "
                                                  r"\+-1e\+15 \[kg m\^2\], got 1e\+308"),
        ({"robot.com": [0.1, 0.1, 1e300]}, r"robot\.com\[2\]: must lie within"),
        ({"plan.start_rate": 1e308}, r"plan\.start_rate: must lie within"),
        ({"plan.start_rate": 10**30}, r"plan\.start_rate: integer out of range"),
        ({"robot.mass": [1e-300, 1, 1]}, r"robot\.mass\[0\]: must be >= 1e-12"),
        ({"plant.inertia": [1, 1, 1e-20]}, r"plant\.inertia\[2\]: must be >= 1e-12"),
        ({"name": "a\x00b"}, r"name: must not contain control characters"),
        ({"name": "x" * 201}, r"name: at most 200 bytes"),
        ({"name": "\u00e9" * 101}, r"name: at most 200 bytes \(it names a directory\), got 202"),
        ({"track.kp": [[[[[[[[[[1]]]]]]]]], 1]}, r"track\.kp: nested deeper than 8"),
        ({"sweep.seed": 2**64}, r"sweep\.seed: integer out of range"),
        ({"sweep.grid": {"sweep.perturb.initial.std": [0.01, [0.01, 0.02, 0.03]]},
          "sweep.perturb": {"initial": {"dist": "normal", "std": 0.01}}},
         r"sweep\.grid\.'sweep\.perturb\.initial\.std': mixes a list of 3 and a number"),
        ({"sweep.grid": {"g": [{"sweep.perturb.initial.std": 0.01},
                               {"sweep.perturb.initial.std": [0.01, 0.01, 0.01]}]},
          "sweep.perturb": {"initial": {"dist": "normal", "std": 0.01}}},
         r"group key 'sweep\.perturb\.initial\.std' mixes a list of 3 and a number"),
    ],
)
def test_values_that_would_overflow_or_break_a_column_are_refused(
    values: dict[str, object], message: str
) -> None:
    with pytest.raises(SpecError, match=message):
        build(values)


def test_the_largest_accepted_magnitudes_give_finite_coefficients() -> None:
    # the bound is chosen so that the products the constraint forms stay finite:
    # 1e15 in every mass, inertia, length and com is accepted, and every coefficient is
    # finite (computed by the core from the spec's robot)
    big = build({"robot.mass": [1e15] * 3, "robot.inertia": [1e15] * 3,
                 "robot.length": [1e15] * 3, "robot.com": [1e15, 1e15, 0.0]})
    small = build({"robot.mass": [1e-12] * 3, "robot.inertia": [1e-12] * 3,
                   "robot.length": [1e-12] * 3, "robot.com": [1e-12, 1e-12, 0.0]})
    for spec in (big, small):
        k = robot_from(spec).coefficients()
        assert all(math.isfinite(v) for v in k)
        assert k.c0 != 0 and k.a0 != 0


def test_set_values_are_one_line_and_one_value() -> None:
    for text in ('name="a\nb"', "plan.duration=2\nplan.samples=3", "plan.duration=2\rx=1"):
        with pytest.raises(SpecError, match="must be one line"):
            parse_set([text])
    with pytest.raises(SpecError, match="nested too deeply"):
        parse_set(["track.kp=" + "[" * 3000 + "]" * 3000])
    assert parse_set(["plan.duration = 3 # a comment"]) == {"plan.duration": 3}


def test_spec_files_that_are_not_small_regular_utf8_toml_are_refused(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # opening it for reading would block until a writer came
    cases = {
        fifo: "is not a regular file",
        Path("/dev/zero"): "is not a regular file",
        tmp_path: "is a directory",
    }
    big = tmp_path / "big.toml"
    big.write_text("# " + "x" * (MAX_SPEC_BYTES + 1))
    cases[big] = f"more than the {MAX_SPEC_BYTES} a spec may have"
    latin = tmp_path / "latin.toml"
    latin.write_bytes('name = "caf\u00e9"\n'.encode("latin-1"))
    cases[latin] = r"is not UTF-8 text \(byte 11\)"
    deep = tmp_path / "deep.toml"
    deep.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    cases[deep] = "TOML nested too deeply"
    for path, message in cases.items():
        with pytest.raises(SpecError, match=message):
            read_toml(path)
