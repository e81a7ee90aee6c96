"""The notebooks of examples/ run from top to bottom (nbclient, a fresh Python kernel each),
on a few trials (FLATCLI_EXAMPLE_TRIALS), writing into a temporary directory
(FLATCLI_EXAMPLE_OUT); a cell that raises fails the test with the cell's error. Their own
checks (H along the plan, python-control against flatcli) are asserts inside them.

Cost: 32-35 s of the suite on this project's 2-core machine (9, 9 and 14 s per notebook:
a kernel's start and flatcli's import in each, two sweeps of 6 trials, one python-control
solve), with the closed-loop kernels already compiled by other tests."""

from __future__ import annotations

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NOTEBOOKS = sorted(EXAMPLES.glob("*.ipynb"))
#: Trials of each notebook's sweeps here (their default is 200).
TRIALS = 6
#: Seconds a cell may take (a cold numba cache compiles a kernel in one).
CELL_TIMEOUT = 600


def test_there_are_the_three_notebooks() -> None:
    assert [p.stem for p in NOTEBOOKS] == ["monte_carlo_study", "paper_in_ten_cells",
                                           "urdf_as_built"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_the_notebook_runs_from_top_to_bottom(path: Path, tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FLATCLI_EXAMPLE_OUT", str(tmp_path))
    monkeypatch.setenv("FLATCLI_EXAMPLE_TRIALS", str(TRIALS))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    book = nbformat.read(path, as_version=4)
    assert all(not c.get("outputs") for c in book.cells if c.cell_type == "code"), \
        "a notebook is committed without outputs"
    client = NotebookClient(book, timeout=CELL_TIMEOUT, kernel_name="python3",
                            resources={"metadata": {"path": str(EXAMPLES)}})
    client.execute()
    errors = [o for c in book.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "error"]
    assert errors == []
    assert not (EXAMPLES / "runs").exists()  # nothing written beside the notebooks
    assert os.listdir(tmp_path) or "sweep" not in path.read_text()
