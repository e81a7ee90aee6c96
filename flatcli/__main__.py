"""``python -m flatcli`` is the ``flatcli`` command."""

from flatcli.cli import run

run()
