"""Design searches, the work of ``flatcli search`` and ``flatcli.search``: which robot design
(masses, inertias, lengths, centres, a counterweight) makes the closed loop most robust under a
Monte Carlo study (docs/search.md).

* ``design``: design variables -> a robot, its constraints, a candidate's spec;
* ``evaluate``: a candidate's trials -> outcomes, the reached fraction, the objective;
* ``directory``: the search's record and journal, resume;
* ``runner``: ``run_search``, scipy's differential evolution over batches of candidates;
* ``report``: search.parquet, the convergence figure, the best design's files, the summary.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pandas as pd


@dataclass(frozen=True)
class SearchResult:
    """A search's directory and what its run did: ``.table`` (search.parquet as a DataFrame:
    one row per candidate), ``.record`` (search.json), ``.best`` (the best candidate's
    record, or None), ``.summary_text`` (summary.md); ``.stop``, ``.wall_seconds``."""

    directory: Path
    record: dict[str, Any]
    summary_text: str

    @cached_property
    def table(self) -> pd.DataFrame:
        import pandas as pd

        return pd.read_parquet(self.directory / "search.parquet")

    @property
    def best(self) -> dict[str, Any] | None:
        best = self.record.get("best")
        return best if isinstance(best, dict) else None

    @property
    def stop(self) -> str:
        return str(self.record.get("stop", ""))

    @property
    def wall_seconds(self) -> float:
        return float(self.record.get("wall_seconds", float("nan")))


__all__ = ["SearchResult"]
