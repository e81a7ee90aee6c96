"""The numerical core: numpy/scipy (and numba for the compiled kernel) only.

No I/O, no printing, no click, pandas, pyarrow or matplotlib: the outer layers wire it up.
"""

#: "1" in the environment: the core makes the process flatcli's own when first imported
#: (``_jit.own_process``). The ``flatcli`` program sets it (its children inherit it); a user
#: may. Here, not in ``_jit``, so that the program reads it without loading numba.
OWN_PROCESS_VARIABLE = "FLATCLI_OWN_PROCESS"
