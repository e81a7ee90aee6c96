"""The numerical core: numpy/scipy (and numba for the compiled kernel) only.

No I/O, no printing, no click, pandas, pyarrow or matplotlib: the outer layers wire it up.
"""
