"""The small search specs the design-search tests share, and how they run them."""

from pathlib import Path

from click.testing import CliRunner

from flatcli.cli import main

#: The paper's robot with its link 2 as a bare link (0.5 kg, centre 0.1 m along it) and a
#: 0.5 kg counterweight 0.1 m behind joint 2: together exactly the paper's link 2 (1 kg,
#: 0.0433 + 0.5 (0.1)^2 + 0.5 (0.1)^2 = 0.0533 kg m^2, centre on the joint). Built with its
#: counterweight 1 mm off the joint; tracked with the swapped gains from 20 mrad errors.
ROBOT = """
[robot]
mass = [1.0, 1.0, 0.5]
inertia = [0.0533, 0.0533, 0.0433]
com = [0.1, 0.1, 0.1]
[plant]
com = [0.1, 0.1, 0.001]
"""

#: A small but real search: 3 variables, 24 trials per candidate, 3 generations of 8.
SPEC = f"""
name = "small_search"
{ROBOT}
[track]
initial = [1.8, 1.0, 0.0]
initial_rate = 0.1
kp = [100, 110]
kv = [10, 13]
[sweep]
trials = 24
seed = 5
chunk = 10
[sweep.perturb]
initial = {{ dist = "normal", std = 0.02 }}
initial_rate = {{ dist = "normal", std = 0.01 }}
[search]
candidates = 24
population = 8
[search.vary]
"robot.mass[1]" = {{ relative = 0.3 }}
"robot.length[1]" = {{ relative = 0.3 }}
"counterweight.distance" = [0.07, 0.13]
[search.counterweight]
distance = 0.1
"""


def write_spec(tmp_path: Path, text: str = SPEC, name: str = "search.toml") -> Path:
    """A spec file in tmp_path (created if need be)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / name
    path.write_text(text)
    return path


def search(*args: str) -> tuple[int, str]:
    """``flatcli search ARGS`` through click's CliRunner: exit code and output."""
    result = CliRunner().invoke(main, ["search", *args])
    return result.exit_code, result.output
