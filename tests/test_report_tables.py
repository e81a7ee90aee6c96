"""Markdown tables (flatcli/report/tables.py)."""

from __future__ import annotations

import math

from flatcli.report.tables import fmt, table


def test_fmt_is_compact_and_marks_missing_values() -> None:
    assert fmt(0.5) == "0.5"
    assert fmt(1.23456789e-7) == "1.23e-07"
    assert fmt(math.nan) == "-"
    assert fmt(math.inf) == "inf"
    assert fmt(3) == "3"
    assert fmt(True) == "true"
    assert fmt("x") == "x"


def test_table_aligns_numbers_right_and_text_left() -> None:
    text = table(["name", "value"], [["a", 1.5], ["long name", 100.0]])
    lines = text.splitlines()
    assert lines[0] == "| name      | value |"
    assert lines[1] == "|-----------|------:|"
    assert lines[3] == "| long name |   100 |"
    assert len({len(line) for line in lines}) == 1


def test_compact_table_keeps_rows_short_and_escapes_pipes() -> None:
    text = table(["key", "n"], [["a|b", 1], ["c", 22]], align=False)
    assert text.splitlines() == ["| key | n |", "|---|---:|", "| a\\|b | 1 |", "| c | 22 |"]
    assert table(["x"], [["p|q"]]).splitlines()[2] == "| p\\|q |"
