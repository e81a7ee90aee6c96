"""What to cite (flatcli/citation.py, `flatcli --cite`, CITATION.cff): the two say the same,
the paper's details are those printed on its pages (shared/paper: IROS 2003, Las Vegas,
October 2003, pp. 3053-3058), and the version is flatcli's."""

from __future__ import annotations

from pathlib import Path

import yaml
from click.testing import CliRunner

import flatcli
from flatcli.citation import BIBTEX, PAPER, SOFTWARE
from flatcli.cli import main
from flatcli.reproduce import CITE_LINE

CFF = Path(__file__).resolve().parents[1] / "CITATION.cff"


def test_citation_cff_is_valid_cff_naming_the_software_and_the_paper() -> None:
    cff = yaml.safe_load(CFF.read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert {"message", "title", "authors", "version", "license"} <= set(cff)
    assert cff["version"] == flatcli.__version__ and cff["license"] == "MIT"
    (paper,) = cff["references"]
    assert paper["type"] == "conference-paper"
    assert [a["family-names"] for a in paper["authors"]] == ["Franch", "Agrawal", "Oh",
                                                             "Fattah"]
    assert (paper["year"], paper["month"], paper["start"], paper["end"]) == (2003, 10, 3053,
                                                                             3058)
    # the command says the same
    assert paper["title"] in PAPER and cff["title"] in SOFTWARE
    assert "3053--3058" in BIBTEX and flatcli.__version__ in BIBTEX


def test_cite_prints_both_at_once_and_report_md_says_what_to_cite() -> None:
    result = CliRunner().invoke(main, ["--cite"])
    assert result.exit_code == 0
    assert PAPER in result.output and SOFTWARE in result.output
    assert "@inproceedings{franch2003flat" in result.output
    assert "flatcli --cite" in CITE_LINE and "3053-3058" in CITE_LINE
