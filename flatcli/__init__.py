"""flatcli: flatness-based planning, feedback control and Monte Carlo studies of planar
free-floating space robots (Franch, Agrawal, Oh, Fattah, IROS 2003)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("flatcli")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0+unknown"
