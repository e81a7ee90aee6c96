"""``python -m flatcli.spec --markdown`` prints the spec tables; ``--update-readme PATH``
rewrites them in a document (docs/spec.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from flatcli.spec.markdown import markdown, sync_readme


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m flatcli.spec", description=__doc__)
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--markdown", action="store_true", help="print every spec table")
    group.add_argument("--update-readme", type=Path, metavar="PATH",
                       help="regenerate the spec-table blocks of a document (docs/spec.md) "
                            "in place")
    args = parser.parse_args(argv)
    if args.markdown:
        print(markdown())
    else:
        path: Path = args.update_readme
        path.write_text(sync_readme(path.read_text()))


if __name__ == "__main__":
    main()
