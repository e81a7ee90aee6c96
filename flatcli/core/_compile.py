"""``python -m flatcli.core._compile``: the child process of ``_jit.compile_in_child``.

It reads the pickled ``(module, qualified name, argument types)`` of a kernel on its standard
input, and compiles that kernel into the cache, as a process flatcli owns (the parent sets
``_jit.OWN_PROCESS_VARIABLE``; ``own_process`` is called again here in case it did not).
"""

from __future__ import annotations

import importlib
import pickle
import sys
from typing import Any

from flatcli.core import _jit


def compile_from(stream: Any) -> None:
    """Compile the kernel named on ``stream`` into the cache (SystemExit if the name is not
    a compiled kernel)."""
    _jit.own_process()
    module, name, sig = pickle.load(stream)  # its types' classes import with their modules
    dispatcher: Any = getattr(importlib.import_module(module), name, None)
    if getattr(dispatcher, "py_func", None) is None:
        raise SystemExit(f"{module}.{name} is not a compiled kernel")
    dispatcher.compile(sig)


if __name__ == "__main__":
    compile_from(sys.stdin.buffer)
