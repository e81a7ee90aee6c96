"""``python -m flatcli.core._compile``, the child of ``_jit.compile_in_child``: compiles the
kernel named on its standard input (pickled module, qualified name and argument types) into
the cache, as a process flatcli owns."""

from __future__ import annotations

import importlib
import pickle
import sys
from typing import Any

from flatcli.core import _jit


def compile_from(stream: Any) -> None:
    """Compile the kernel named on ``stream`` into the cache (SystemExit if its module makes
    no kernel of that name: ``_jit.KERNELS_BY_NAME``)."""
    _jit.own_process()
    module, name, sig = pickle.load(stream)  # its types' classes import with their modules
    importlib.import_module(module)  # makes its kernels
    dispatcher: Any = _jit.KERNELS_BY_NAME.get((module, name))
    if dispatcher is None:
        raise SystemExit(f"{module}.{name} is not a compiled kernel")
    dispatcher.compile(sig)


if __name__ == "__main__":
    compile_from(sys.stdin.buffer)
