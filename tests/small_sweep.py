"""The small sweep spec the sweep and Dask tests share, and how they run it."""

from pathlib import Path

from click.testing import CliRunner

from flatcli.cli import main

#: A small but real study: two cells, perturbations of the initial state and the plant.
SPEC = """
name = "small"
[plan]
duration = 1.0
start = [1.8, 1.0, 0.0]
goal = [1.5, 1.5, 0.0]
[track]
initial = [1.8, 1.0, 0.0]
dt = 0.002
kp = [100, 110]
kv = [20, 21]
[sweep]
trials = 60
seed = 11
chunk = 25
[sweep.perturb]
initial = { dist = "normal", std = 0.02 }
initial_rate = { dist = "uniform", low = -0.01, high = 0.01 }
mass = { dist = "uniform", low = -0.05, high = 0.05, relative = true }
com = { dist = "uniform", low = [0, 0, 0], high = [0, 0, 0.002] }
[sweep.grid]
"track.sensor_noise" = [0.0, 0.001]
"""


def write_spec(tmp_path: Path, text: str = SPEC, name: str = "spec.toml") -> Path:
    """A spec file in tmp_path (created if need be)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / name
    path.write_text(text)
    return path


def sweep(*args: str) -> tuple[int, str]:
    """``flatcli sweep ARGS`` through click's CliRunner: exit code and output."""
    result = CliRunner().invoke(main, ["sweep", *args])
    return result.exit_code, result.output


def sweep_without_final_tables(*args: str) -> tuple[int, str]:
    """``flatcli sweep ARGS`` stopped where a kill -9 after its last chunk and before its
    final tables would stop it: every chunk file written and flushed, no trials.parquet,
    summary or run.json (a finished sweep keeps its rows in trials.parquet only)."""
    import pytest

    from flatcli.montecarlo import runner

    def killed(*_: object, **__: object) -> str:
        raise KeyboardInterrupt

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(runner, "finish_sweep", killed)
        return sweep(*args)
