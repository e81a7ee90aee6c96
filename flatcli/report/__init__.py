"""What people read: terminal tables, sweep summaries and figures (PNG, PDF or SVG).

* ``tables``: aligned Markdown tables (``fmt``, ``table``);
* ``runs``: the terminal summaries of a plan, an optimised plan and a closed-loop run;
* ``summary``: a sweep's per-cell statistics (summary.parquet, summary.md);
* ``figures``: plan and track figures, and what every figure shares (the style sheet
  ``flatcli.mplstyle``, the file format and resolution, labels and titles);
* ``sweep_figures``: the figures of a finished sweep.

A sweep's progress bar lives in ``flatcli.progress`` (re-exported here as ``Progress``).
"""

from flatcli.progress import Progress
from flatcli.report.figures import (
    FigureFile,
    Limits,
    finish_grid,
    new_figure,
    plan_figure,
    plan_title,
    plot_plan,
    plot_track,
    save_figure,
    style,
    styled,
    track_figure,
    track_title,
)
from flatcli.report.runs import (
    metrics_text,
    optimization_summary,
    optimization_text,
    plan_summary,
    plan_text,
)
from flatcli.report.summary import (
    COMPLETED,
    ERROR_METRICS,
    cell_text,
    short_key,
    summarize_trials,
    summary_markdown,
)
from flatcli.report.sweep_figures import plot_sweep, sweep_figures
from flatcli.report.tables import fmt, table

__all__ = [
    "COMPLETED",
    "ERROR_METRICS",
    "FigureFile",
    "Limits",
    "Progress",
    "cell_text",
    "finish_grid",
    "fmt",
    "metrics_text",
    "new_figure",
    "optimization_summary",
    "optimization_text",
    "plan_figure",
    "plan_summary",
    "plan_text",
    "plan_title",
    "plot_plan",
    "plot_sweep",
    "plot_track",
    "save_figure",
    "short_key",
    "style",
    "styled",
    "summarize_trials",
    "summary_markdown",
    "sweep_figures",
    "table",
    "track_figure",
    "track_title",
]
