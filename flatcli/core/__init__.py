"""The numerical core: numpy/scipy (and numba for the compiled kernel) only.

No I/O, no printing, no click, pandas, pyarrow or matplotlib: the outer layers wire it up.
"""

#: Set to "1" in a process's environment, the core makes the process flatcli's own when it
#: is first imported (``_jit.own_process``): the ``flatcli`` program sets it for itself and
#: the processes it starts; a user may set it to have a notebook tuned the same way. Here,
#: not in ``_jit``, so that the program reads it without loading numba.
OWN_PROCESS_VARIABLE = "FLATCLI_OWN_PROCESS"
