"""flatcli: flatness-based planning, feedback control and Monte Carlo studies of planar
free-floating space robots (Franch, Agrawal, Oh, Fattah, IROS 2003).

The Python API (``flatcli.api``; each command of the CLI is a thin wrapper over it)::

    import flatcli
    p = flatcli.plan(overrides={"plan.duration": 3.0})    # p.frame, p.metrics, p.save()
    b = flatcli.plan_many(start=starts, goal=goals)       # M maneuvers at once: b[i], b.metrics
    t = flatcli.track("my.toml")                          # t.frame, t.metrics
    s = flatcli.sweep("study.toml", "runs/study", workers=2)  # s.trials, s.summary
    r = flatcli.load("runs/paper_example/latest")
    flatcli.check("study.toml").text()                    # what a sweep would do
    d = flatcli.search("design.toml", workers=2)          # d.table, d.best: a design search
    df = flatcli.runs(filters=["plant.model=dynamic"])    # the runs as a DataFrame
    w = flatcli.workspace(attitude=(1.0, 1.4))            # where the end effector can go
    sys = flatcli.flatsystem()                            # a python-control FlatSystem
    u = flatcli.read_urdf("arm.urdf")                     # u.robot: a robot from URDF

``import flatcli`` stays light (no numpy, numba, scipy or pandas): the API loads on first
use (PEP 562 module ``__getattr__``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

# No thread-count variables are set here: flatcli limits the numerical libraries' threads in
# its own work only (flatcli.threads), so a notebook's numpy keeps its threads.

#: flatcli's version: the one place it is written (pyproject.toml reads it from here, and the
#: installed package's metadata says the same: tests/test_api.py). A constant, not
#: ``importlib.metadata.version``: that import and the search of sys.path for the
#: distribution cost about 20 ms at the start of every flatcli process, --help included.
__version__ = "0.1.0"

if TYPE_CHECKING:
    from flatcli.api import (
        PlanBatch,
        PlanResult,
        Run,
        SweepResult,
        TrackResult,
        WorkspaceResult,
        check,
        load,
        load_spec,
        plan,
        plan_many,
        runs,
        search,
        sweep,
        track,
        workspace,
    )
    from flatcli.core.errors import FlatcliError
    from flatcli.designsearch import SearchResult
    from flatcli.pycontrol import flatsystem
    from flatcli.spec import Spec, SpecError
    from flatcli.urdf import read_urdf

#: Public names and the module each one lives in (loaded on first use).
_LAZY = {
    "plan": "flatcli.api",
    "plan_many": "flatcli.api",
    "track": "flatcli.api",
    "workspace": "flatcli.api",
    "sweep": "flatcli.api",
    "search": "flatcli.api",
    "SearchResult": "flatcli.designsearch",
    "check": "flatcli.api",
    "load": "flatcli.api",
    "load_spec": "flatcli.api",
    "runs": "flatcli.api",
    "Run": "flatcli.api",
    "PlanResult": "flatcli.api",
    "PlanBatch": "flatcli.api",
    "TrackResult": "flatcli.api",
    "WorkspaceResult": "flatcli.api",
    "SweepResult": "flatcli.api",
    "FlatcliError": "flatcli.core.errors",
    "Spec": "flatcli.spec",
    "SpecError": "flatcli.spec",
    "flatsystem": "flatcli.pycontrol",
    "read_urdf": "flatcli.urdf",
}

__all__ = [
    "FlatcliError",
    "PlanBatch",
    "PlanResult",
    "Run",
    "SearchResult",
    "Spec",
    "SpecError",
    "SweepResult",
    "TrackResult",
    "WorkspaceResult",
    "__version__",
    "check",
    "flatsystem",
    "load",
    "load_spec",
    "plan",
    "plan_many",
    "read_urdf",
    "runs",
    "search",
    "sweep",
    "track",
    "workspace",
]


def __getattr__(name: str) -> Any:
    """Load a public name's module on first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'flatcli' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    # cached here; importing the subpackage flatcli.sweep (or the module flatcli.runs) later
    # rebinds the name to it, and calling it runs the function too
    # (flatcli/montecarlo/__init__.py, flatcli/rundirs.py)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
