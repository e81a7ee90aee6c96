"""Keys a spec sets that no trial reads (flatcli/spec/unread.py): named in one warning line
each, where the run's own numbers show the key does nothing (the referee: the same trial run
with and without the key gives the same metrics, and with the reading controller other ones)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import flatcli
from flatcli.spec import load_spec
from flatcli.spec.unread import READERS, controllers_used, unread_keys


def _warned(*sets: str) -> list[str]:
    return unread_keys(load_spec(None, sets))


def test_the_paper_example_and_its_controllers_warn_of_nothing() -> None:
    assert _warned() == []
    for controller in ("flat", "mpc"):
        assert _warned(f'track.controller="{controller}"') == []
    assert _warned('robot="chain4"', 'track.controller="mpc"') == []


@pytest.mark.parametrize(("sets", "key"), [
    (("track.mpc_horizon=5",), "track.mpc_horizon"),
    (("track.lqr_base=3",), "track.lqr_base"),
    (('track.controller="mpc"', "track.kp=[1.0, 2.0]"), "track.kp"),
    (('track.controller="mpc"', "track.kv=[3.0, 4.0]"), "track.kv"),
])
def test_a_setting_of_another_controller_is_named(sets: tuple[str, ...], key: str) -> None:
    lines = _warned(*sets)
    assert len(lines) == 1
    assert lines[0].startswith(f"warning: {key} is set but no trial reads it")


def test_a_setting_its_controller_reads_is_not_named() -> None:
    assert _warned('track.controller="mpc"', "track.mpc_horizon=5") == []
    assert _warned('track.controller="mpc"', "track.lqr_base=3") == []  # an exact plan's
    assert _warned("track.kp=[1.0, 2.0]") == []


def test_a_sweep_grid_counts_every_controller_it_runs() -> None:
    both = load_spec(None, ['sweep.grid={"track.controller" = ["flat", "mpc"]}',
                            "track.mpc_horizon=5", "track.kp=[1.0, 2.0]"])
    assert controllers_used(both) == {"flat", "mpc"}
    assert unread_keys(both) == []
    varied = load_spec(None, ['sweep.grid={"track.mpc_horizon" = [5, 10]}'])
    assert [w.split(" is set")[0] for w in unread_keys(varied)] == [
        "warning: track.mpc_horizon"]  # a grid over it runs identical cells


def test_every_owned_key_exists() -> None:
    from flatcli.spec.schema import SCHEMA

    track = SCHEMA["track"]
    for owned in READERS:
        assert any(name == owned or (owned.endswith("_") and name.startswith(owned))
                   for name in track), owned


def test_the_warning_is_true_the_run_does_not_read_the_key() -> None:
    """The referee: the trial with the named key set gives the metrics of the trial without
    it; the controller that reads it gives other ones (the warning names a key that does
    nothing, and only such a key)."""
    from flatcli.spec.build import parse_set

    def metrics(*sets: str) -> dict[str, Any]:
        result = flatcli.track(None, parse_set(sets), quiet=True)
        return {k: v for k, v in result.metrics.items() if isinstance(v, float)}

    plain = metrics()
    np.testing.assert_equal(metrics("track.mpc_horizon=5"), plain)  # nan equals nan
    said = flatcli.track(None, parse_set(["track.mpc_horizon=5"]), quiet=True).warnings
    assert said[0].startswith("warning: track.mpc_horizon is set")  # flatcli track prints it
    mpc = metrics('track.controller="mpc"')
    np.testing.assert_equal(metrics('track.controller="mpc"', "track.kp=[1.0, 2.0]"), mpc)
    assert metrics("track.kp=[1.0, 2.0]") != plain
    assert metrics('track.controller="mpc"', "track.mpc_horizon=5") != mpc


def test_a_torque_limit_drawn_per_trial_under_the_mpc_is_named() -> None:
    """The MPC on the dynamic plant re-plans for the cell's plant.torque_limit
    (experiment.mpc_reference, called once per cell by the sweep's layout): a limit drawn per
    trial is named in one line; with the paper's feedback, on the kinematic plant or with no
    draw there is nothing to name; a grid with a dynamic cell names it once."""
    from flatcli.spec.unread import unseen_draws

    draw = 'sweep.perturb={torque_limit={dist="uniform", low=-5.0, high=5.0}}'
    dynamic = ('plant.model="dynamic"', "plant.torque_limit=10.0")
    lines = unseen_draws(load_spec(None, ('track.controller="mpc"', *dynamic, draw)))
    assert len(lines) == 1 and "sweep.perturb.torque_limit" in lines[0]
    assert unseen_draws(load_spec(None, ('track.controller="flat"', *dynamic, draw))) == []
    assert unseen_draws(load_spec(None, ('track.controller="mpc"', *dynamic))) == []
    assert unseen_draws(load_spec(None, ('track.controller="mpc"', draw,
                                         "plant.torque_limit=10.0"))) == []
    grid = 'sweep.grid={"plant.model"=["kinematic", "dynamic"]}'
    assert len(unseen_draws(load_spec(None, ('track.controller="mpc"', draw, grid,
                                             "plant.torque_limit=10.0")))) == 1
