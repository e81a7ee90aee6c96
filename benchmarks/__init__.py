"""Benchmarks of flatcli beside the tools users would pick instead (``make bench``)."""

# flatcli pins BLAS to one thread before numpy loads (see flatcli/__init__.py); importing it
# first gives the baselines the same setting, whatever the bench imports next.
import flatcli  # noqa: F401
