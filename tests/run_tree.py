"""A directory of runs the run and catalog tests share: two plans and a track of one name, a
finished and an interrupted sweep; and a plan record as flatcli writes one."""

import json
from pathlib import Path

from click.testing import CliRunner
from small_sweep import sweep_without_final_tables, write_spec

from flatcli.cli import main
from flatcli.rundirs import stamp

#: A plan's run.json, as flatcli writes one (its values of the types it writes).
GOOD_PLAN = {"command": "plan", "time": "2026-01-02T03:04:05+00:00", "digest": "d",
             "spec": {"name": "x"}, "summary": {"input_energy": 1.5, "min_margin": None},
             "optimization": None}


def cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.output


def make_tree(root: Path) -> Path:
    """runs/ under ``root``: paper_example/<stamp> x 3 (two plans, a track), small (a
    finished sweep), cut (the same, interrupted: one chunk of 25 lost)."""
    for args in (["plan"], ["plan", "--set", "plan.duration=3"],
                 ["track", "--set", "track.kp=[100,110]", "--set", "track.kv=[10,13]"]):
        code, out = cli(*args, "-q", "--out", str(root / "paper_example" / stamp()))
        assert code == 0, out
    spec = write_spec(root.parent / "specs")
    code, out = cli("sweep", str(spec), "--out", str(root / "small"), "-q", "--workers", "1")
    assert code == 0, out
    code, out = sweep_without_final_tables(str(spec), "--out", str(root / "cut"), "-q",
                                           "--workers", "1")
    assert code != 0, out  # (interrupted, as a kill before the final tables)
    manifest = json.loads((root / "cut" / "sweep.json").read_text())
    first = manifest["cells"][manifest["grid_cells"][0]]["chunks"][0]  # cell 0's first chunk
    (root / "cut" / "trials" / first).unlink()
    return root


