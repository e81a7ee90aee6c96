"""What to cite: flatcli itself and the paper it reproduces (``flatcli --cite``; the same as
CITATION.cff at the repository's root, which tests/test_citation.py checks)."""

from __future__ import annotations

from flatcli import __version__

#: The paper whose results flatcli reproduces and extends (its proceedings' pages).
PAPER = ("J. Franch, S. K. Agrawal, S. Oh, A. Fattah, \"Design of Differentially Flat Planar "
         "Space Robots: A Step Forward in their Planning and Control\", Proceedings of the "
         "2003 IEEE/RSJ International Conference on Intelligent Robots and Systems (IROS "
         "2003), Las Vegas, Nevada, October 2003, pp. 3053-3058.")
#: The software, with the version in use.
SOFTWARE = (f"The flatcli developers, \"flatcli: flatness-based planning, feedback control and "
            f"Monte Carlo studies of planar free-floating space robots\", software, version "
            f"{__version__}, MIT license.")
#: Both, as BibTeX.
BIBTEX = f"""@inproceedings{{franch2003flat,
  author    = {{Franch, Jaume and Agrawal, Sunil K. and Oh, S. and Fattah, Abbas}},
  title     = {{Design of Differentially Flat Planar Space Robots: A Step Forward in their
               Planning and Control}},
  booktitle = {{Proceedings of the 2003 IEEE/RSJ International Conference on Intelligent
               Robots and Systems (IROS 2003)}},
  address   = {{Las Vegas, Nevada}},
  month     = oct,
  year      = {{2003}},
  pages     = {{3053--3058}},
  publisher = {{IEEE}}
}}
@software{{flatcli,
  author  = {{{{The flatcli developers}}}},
  title   = {{flatcli: flatness-based planning, feedback control and Monte Carlo studies
             of planar free-floating space robots}},
  version = {{{__version__}}},
  license = {{MIT}}
}}"""


def citation_text() -> str:
    """What ``flatcli --cite`` prints: the two references, then BibTeX."""
    return (f"If you use flatcli, please cite the software and the paper it reproduces:\n\n"
            f"  {SOFTWARE}\n\n  {PAPER}\n\nBibTeX:\n\n{BIBTEX}\n")
