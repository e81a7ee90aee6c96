"""What people read: terminal tables, sweep summaries and figures (PNG, PDF or SVG).

* ``tables``: aligned Markdown tables (``fmt``, ``table``);
* ``runs``: the terminal summaries of a plan, an optimised plan and a closed-loop run;
* ``summary``: a sweep's per-cell statistics (summary.parquet, summary.md);
* ``figures``: plan and track figures, and what every figure shares (the style sheet
  ``flatcli.mplstyle``, the file format and resolution, labels and titles);
* ``sweep_figures``: the figures of a finished sweep.

A sweep's progress bar lives in ``flatcli.progress`` (re-exported here as ``Progress``).
Each name loads its module on first use, so importing one module does not load the others.
"""

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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
        task_text,
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

#: Each public name and the module it lives in, loaded on first use (PEP 562): a sweep reads
#: its tables and summaries without loading the figures' code.
_LAZY = {
    "COMPLETED": "flatcli.report.summary",
    "ERROR_METRICS": "flatcli.report.summary",
    "FigureFile": "flatcli.report.figures",
    "Limits": "flatcli.report.figures",
    "Progress": "flatcli.progress",
    "cell_text": "flatcli.report.summary",
    "finish_grid": "flatcli.report.figures",
    "fmt": "flatcli.report.tables",
    "metrics_text": "flatcli.report.runs",
    "new_figure": "flatcli.report.figures",
    "optimization_summary": "flatcli.report.runs",
    "optimization_text": "flatcli.report.runs",
    "task_text": "flatcli.report.runs",
    "plan_figure": "flatcli.report.figures",
    "plan_summary": "flatcli.report.runs",
    "plan_text": "flatcli.report.runs",
    "plan_title": "flatcli.report.figures",
    "plot_plan": "flatcli.report.figures",
    "plot_sweep": "flatcli.report.sweep_figures",
    "plot_track": "flatcli.report.figures",
    "save_figure": "flatcli.report.figures",
    "short_key": "flatcli.report.summary",
    "style": "flatcli.report.figures",
    "styled": "flatcli.report.figures",
    "summarize_trials": "flatcli.report.summary",
    "summary_markdown": "flatcli.report.summary",
    "sweep_figures": "flatcli.report.sweep_figures",
    "table": "flatcli.report.tables",
    "track_figure": "flatcli.report.figures",
    "track_title": "flatcli.report.figures",
}

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
    "task_text",
    "track_figure",
    "track_title",
]


def __getattr__(name: str) -> Any:
    """Load a public name's module on first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'flatcli.report' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
