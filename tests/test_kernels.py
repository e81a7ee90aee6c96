"""The kernel factory (flatcli/core/loop/kernels.py): every (model, plant) combination's compiled
closures carry names of their own, the same in every process.

numba links a name that two loaded kernels share to one definition (its own rule: "the
mangled name *must* be unique, else the wrong function can be chosen at link time",
numba/core/funcdesc.py). A name is the module, the qualified name, the argument types and a
counter of the compiling process; a factory's closures share the first three, so two kernels
cached by different processes could share a name for two functions: the as-built kinematic
and dynamic batch loops did (``make_batch.<locals>.run_batch``, the same counter in both
cache files), and the second loaded from a warm cache ran the first's loop and ended
``unresolved``. The referee here is the names themselves, as numba reads them
(``__qualname__``), in this process and in a fresh one.

Checked once by hand, too slow for the suite (each process compiles a kernel afresh): two
processes with a fresh NUMBA_CACHE_DIR compile the as-built kinematic and the dynamic kernel,
numba's counter set alike (``FunctionIdentity._unique_ids``) so that both batch loops get
counter 100057; a third loads both. At aa61ed0 (names without tags) the kernel loaded second
ended ``unresolved`` with NaN states and the process crashed at exit; with the tags
(``run_batch_43fa272d960b``, ``run_batch_348688cd8449``) both trials ended ``ok`` with the
errors the compiling processes got (2026-12-02).
"""

from __future__ import annotations

import json
import subprocess
import sys

from flatcli.core.controllers import flat
from flatcli.core.loop import kernels
from flatcli.core.loop.base import base_ops
from flatcli.core.loop.integrate import make_trial_integrators
from flatcli.core.loop.table import BASE
from flatcli.core.plants import dynamic

COMBINATIONS = {
    "paper kinematic": BASE[("flat", "paper", "kinematic")][0],
    "paper dynamic": BASE[("flat", "paper", "dynamic")][0],
    "chain kinematic": BASE[("flat", "chain", "kinematic")][0],
    "chain dynamic": BASE[("flat", "chain", "dynamic")][0],
    "as-built kinematic": BASE[("asbuilt", "asbuilt", "kinematic")][0],
    "as-built dynamic": BASE[("asbuilt", "asbuilt", "dynamic")][0],
}


def closure_names(ops: kernels.Ops) -> list[str]:
    """The qualified names of every closure the factories make for ``ops``."""
    functions = [kernels.make_batch(ops), *kernels.make_single(ops),
                 *make_trial_integrators(ops.rhs, ops.observe, ops.record, ops.stage)]
    return [f.__qualname__ for f in functions]


def test_no_two_combinations_share_a_closure_name() -> None:
    seen: dict[str, str] = {}
    for label, ops in COMBINATIONS.items():
        names = closure_names(ops)
        assert len(set(names)) == len(names), label
        batch_tag = kernels.ops_tag(ops)
        integrator_tag = kernels.variant_tag(ops.rhs, ops.observe, ops.record,
                                              ops.stage or ops.rhs)
        assert all(name.endswith("_" + batch_tag) for name in names[:5]), names[:5]
        assert all(name.endswith("_" + integrator_tag) for name in names[5:]), names[5:]
        for name in names:
            assert name not in seen, (label, seen.get(name), name)
            seen[name] = label
    # the same combination made again is the same code under the same names
    assert closure_names(base_ops(flat.LAW, dynamic.PLANT)) == closure_names(
        COMBINATIONS["chain dynamic"])


def test_the_names_are_the_same_in_a_fresh_process() -> None:
    """A cached kernel is found again by a process that builds the same names: tags come
    from the functions' modules and names, not from anything that changes between runs."""
    code = ("import json; from tests.test_kernels import COMBINATIONS, closure_names; "
            "print(json.dumps({k: closure_names(v) for k, v in COMBINATIONS.items()}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=300).stdout
    assert json.loads(out.splitlines()[-1]) == {k: closure_names(v)
                                                for k, v in COMBINATIONS.items()}
