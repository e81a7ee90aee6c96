"""flatcli: flatness-based planning, feedback control and Monte Carlo studies of planar
free-floating space robots (Franch, Agrawal, Oh, Fattah, IROS 2003)."""

import os
from importlib.metadata import PackageNotFoundError, version

# flatcli's matrices are small: threaded BLAS only adds overhead (SLSQP runs 3-5x slower on
# two cores) and oversubscribes the cores a sweep's worker processes already fill. Set
# before numpy is first imported; a user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

try:
    __version__ = version("flatcli")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0+unknown"
