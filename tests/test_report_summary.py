"""A sweep's per-cell statistics (flatcli/report/summary.py)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import binomtest

from flatcli.report.summary import summarize_trials, summary_markdown, wilson_interval


def test_summary_counts_and_statistics_on_a_handmade_frame() -> None:
    frame = pd.DataFrame({
        "cell": [0, 0, 0, 0, 1],
        "status": ["ok", "singular", "diverged", "error", "ok"],
        "singular_hits": [0, 3, 1, -1, 0],
        **{m: [1.0, 3.0, 100.0, np.nan, 2.0] for m in (
            "err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final", "min_margin",
            "momentum_drift", "plan_momentum_residual", "peak_rate", "err_estimate")},
    })
    summary = summarize_trials(frame, {0: {"g": "a"}, 1: {"g": "b"}})
    row = summary.iloc[0]
    assert (row["ok"], row["singular"], row["diverged"], row["error"]) == (1, 1, 1, 1)
    assert row["err_y_rms_median"] == 2.0  # ok and singular only: median(1, 3)
    assert row["err_y_rms_max"] == 3.0
    assert row["singular_fraction"] == 2 / 3  # of the three simulated trials
    assert row["min_margin_median"] == 2.0  # median(1, 3) of the resolved trials
    assert summary.iloc[1]["g"] == "b"


def test_wilson_interval_is_the_score_intervals_closed_form() -> None:
    # reference: Wilson (J. Am. Stat. Assoc. 22, 1927), written out here with numpy:
    # (p + z^2/2n -+ z sqrt(p (1 - p)/n + z^2/4n^2)) / (1 + z^2/n)
    z = 1.959963984540054  # Phi^-1(0.975)
    counts = [(1, 10), (3, 10), (1, 2000), (530, 2000), (1999, 2000)]
    k = np.array([c[0] for c in counts], dtype=float)
    n = np.array([c[1] for c in counts], dtype=float)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    low, high = wilson_interval(k.astype(int), n.astype(int))
    np.testing.assert_allclose(low, centre - half, rtol=1e-12)
    np.testing.assert_allclose(high, centre + half, rtol=1e-12)
    assert wilson_interval(3, 10)[0].shape == ()  # scalars in, scalars out


def test_wilson_interval_of_no_successes_in_closed_form() -> None:
    # k = 0: the score equation (p - 0)^2 = z^2 p (1 - p) / n gives p = z^2 / (n + z^2)
    z = 1.959963984540054  # Phi^-1(0.975), e.g. scipy.stats.norm.ppf(0.975)
    n = np.array([1, 20, 2000])
    low, high = wilson_interval(np.zeros(3), n)
    assert low.tolist() == [0.0, 0.0, 0.0]
    np.testing.assert_allclose(high, z * z / (n + z * z), rtol=1e-14)
    low, high = wilson_interval(n, n)  # k = n mirrors it
    np.testing.assert_allclose(low, n / (n + z * z), rtol=1e-14)
    assert high.tolist() == [1.0, 1.0, 1.0]
    assert np.isnan(wilson_interval(0, 0)).all()  # no trials: no interval


def test_statistics_leave_out_unresolved_trials_and_nulls() -> None:
    frame = pd.DataFrame({
        "cell": [0] * 6,
        "status": ["ok", "ok", "unresolved", "diverged", "error", "singular"],
        "singular_hits": pd.array([0, 0, 2, 1, None, 4], dtype="Int64"),
        "err_theta_rms": [1.0, 2.0, 50.0, 60.0, np.nan, 4.0],
        "err_estimate": [1e-7, np.nan, 1.0, 1.0, np.nan, 3e-7],  # nan: not applicable
        **{m: [1.0] * 6 for m in ("err_theta_final", "err_y_rms", "err_y_final", "min_margin",
                                  "momentum_drift", "plan_momentum_residual", "peak_rate")},
    })
    row = summarize_trials(frame, {0: {}}).iloc[0]
    assert (row["trials"], row["resolved"], row["simulated"]) == (6, 3, 5)
    assert row["err_theta_rms_median"] == 2.0  # median(1, 2, 4): not 50, 60
    assert row["err_theta_rms_max"] == 4.0
    assert row["err_estimate_max"] == 3e-7  # the nan is left out, not propagated
    assert row["singular_fraction"] == 3 / 5  # hits in the five simulated trials
    for status in ("diverged", "unresolved", "error"):
        assert row[f"{status}_fraction"] == 1 / 6
        ci = binomtest(1, 6).proportion_ci(0.95, method="wilson")
        assert row[f"{status}_fraction_low"] == pytest.approx(ci.low, rel=1e-12)
        assert row[f"{status}_fraction_high"] == pytest.approx(ci.high, rel=1e-12)


def test_summary_markdown_shows_shares_with_intervals() -> None:
    frame = pd.DataFrame({
        "cell": [0] * 4 + [1] * 4,
        "status": ["ok", "ok", "ok", "diverged", "ok", "ok", "ok", "ok"],
        "singular_hits": [0] * 8,
        **{m: [1.0] * 8 for m in (
            "err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final", "min_margin",
            "momentum_drift", "plan_momentum_residual", "peak_rate", "err_estimate")},
    })
    summary = summarize_trials(frame, {0: {"plant.com": [0.1, 0.1, 0.0]},
                                       1: {"plant.com": [0.1, 0.1, 0.005]}})
    text = summary_markdown(summary, ["plant.com"])
    assert "| [0.1, 0.1, 0.005] |" in text
    ci = binomtest(1, 4).proportion_ci(0.95, method="wilson")  # 1 of 4 diverged
    assert f"| 25 ({100 * ci.low:.2g}-{100 * ci.high:.2g}) " in text
    assert max(len(line) for line in text.splitlines()) <= 80


def test_verified_and_unverified_trials_are_never_averaged_together() -> None:
    """Cell 0 mixes two verified trials (errors 1, 2) with an unverified one (error 100): its
    statistics are the verified ones' alone. Cell 1 has only unverified trials: its
    statistics are theirs, and the cell says so (statistics_of; marked * in the tables)."""
    frame = pd.DataFrame({
        "cell": [0, 0, 0, 1, 1],
        "status": ["ok"] * 5,
        "singular_hits": [0] * 5,
        "verified": [True, True, False, False, False],
        **{m: [1.0, 2.0, 100.0, 3.0, 5.0] for m in (
            "err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final", "min_margin",
            "momentum_drift", "plan_momentum_residual", "peak_rate", "err_estimate")},
        "reference_difference": [1e-7, None, None, 4e-3, None],
        "reference_status": ["ok", None, None, "diverged", None],
    })
    summary = summarize_trials(frame, {0: {}, 1: {}}).set_index("cell")
    assert summary.loc[0, "err_theta_rms_max"] == 2.0  # never the unverified 100
    assert summary.loc[0, "err_theta_rms_median"] == 1.5
    assert summary.loc[1, "err_theta_rms_max"] == 5.0
    assert list(summary["statistics_of"]) == ["verified", "unverified"]
    assert list(summary["verified_trials"]) == [2, 0]
    assert list(summary["unverified_trials"]) == [1, 2]
    assert list(summary["reference_checked"]) == [1, 1]
    # cell 1's checked trial ended diverged under the reference: a mismatch, and no
    # difference to compare (a trial stopped at a crossing has no accuracy)
    assert summary.loc[0, "reference_difference_max"] == 1e-7
    assert math.isnan(summary.loc[1, "reference_difference_max"])
    assert list(summary["reference_status_mismatches"]) == [0, 1]
    text = summary_markdown(summary.reset_index(), [])
    assert "| 1*   |" in text and "| 0    |" in text
    assert "Checked against the reference" in text


def test_a_directory_without_the_accuracy_columns_has_no_verified_trials() -> None:
    """trials.parquet written before flatcli recorded ``verified``: nothing is claimed."""
    frame = pd.DataFrame({"cell": [0, 0], "status": ["ok", "ok"], "singular_hits": [0, 0],
                          **{m: [1.0, 2.0] for m in (
                              "err_theta_rms", "err_theta_final", "err_y_rms", "err_y_final",
                              "min_margin", "momentum_drift", "plan_momentum_residual",
                              "peak_rate", "err_estimate")}})
    summary = summarize_trials(frame, {0: {}})
    assert summary.loc[0, "statistics_of"] == "unverified"
    assert summary.loc[0, "verified_trials"] == 0 and summary.loc[0, "reference_checked"] == 0


def test_a_task_sweep_counts_trials_resolved_within_the_reach_tolerance() -> None:
    """ee_error_bound_within: resolved trials (ok, singular) whose ee_error_bound is within
    the tolerance, over all of the cell's trials; its interval the Wilson score interval of
    that count (scipy's binomtest(...).proportion_ci(method="wilson"))."""
    frame = pd.DataFrame({
        "cell": [0] * 5, "status": ["ok", "ok", "singular", "diverged", "ok"],
        "ee_error_bound": [1e-4, 2e-3, 5e-4, math.nan, 1e-3],
        **{m: [0.1] * 5 for m in ("err_theta_rms", "err_theta_final", "err_y_rms",
                                  "err_y_final", "min_margin", "momentum_drift",
                                  "plan_momentum_residual", "peak_rate", "err_estimate")},
        "singular_hits": [0, 0, 1, 0, 0]})
    row = summarize_trials(frame, {0: {}}, reach_tolerance=1e-3).iloc[0]
    assert row["ee_error_bound_within_fraction"] == 3 / 5  # 1e-4, 5e-4 and 1e-3 (at the tolerance)
    ci = binomtest(3, 5).proportion_ci(confidence_level=0.95, method="wilson")
    assert row["ee_error_bound_within_fraction_low"] == pytest.approx(ci.low, rel=1e-12)
    assert row["ee_error_bound_within_fraction_high"] == pytest.approx(ci.high, rel=1e-12)
    assert row["ee_error_bound_max"] == 2e-3 and row["ee_error_bound_median"] == 7.5e-4
    assert "### The task's target" in summary_markdown(
        summarize_trials(frame, {0: {}}, 1e-3), [])
    tighter = summarize_trials(frame, {0: {}}, reach_tolerance=2e-4).iloc[0]
    assert tighter["ee_error_bound_within_fraction"] == 1 / 5
    plain = summarize_trials(frame.drop(columns="ee_error_bound"), {0: {}}).iloc[0]
    assert "ee_error_bound_within_fraction" not in plain and "ee_error_bound_max" not in plain
    assert "reached_fraction" not in plain  # no outcome column: no outcomes


def test_outcomes_come_first_counted_over_all_trials_and_lost_ones_are_infinitely_wrong(
        ) -> None:
    """The headline columns on a handmade frame: counts per outcome, the fraction reached of
    ALL the cell's trials with scipy's Wilson interval (binomtest), and medians of the final
    errors over all trials with the trials that did not reach T as inf (numpy's median of
    the column with nan replaced by inf, written out here)."""
    base = {m: [0.1] * 6 for m in ("err_theta_rms", "err_y_rms", "err_y_final", "min_margin",
                                   "momentum_drift", "plan_momentum_residual", "peak_rate",
                                   "err_estimate")}
    frame = pd.DataFrame({
        "cell": [0] * 5 + [1], "status": ["ok", "ok", "singular", "diverged", "error", "ok"],
        "outcome": ["reached", "missed", "missed", "lost", "lost", "reached"],
        "err_theta_final": [1e-4, 2.0, 5.0, math.nan, math.nan, 3e-4],
        "singular_hits": [0, 0, 1, 0, 0, 0], **base})
    summary = summarize_trials(frame, {0: {"g": "a"}, 1: {"g": "b"}})
    columns = list(summary.columns)
    assert columns[columns.index("trials") + 1:][:4] == ["reached", "collided", "missed", "lost"]
    row = summary.iloc[0]
    assert (row["reached"], row["collided"], row["missed"], row["lost"]) == (1, 0, 2, 2)
    assert row["reached_fraction"] == 1 / 5 and row["lost_fraction"] == 2 / 5
    ci = binomtest(1, 5).proportion_ci(confidence_level=0.95, method="wilson")
    assert (row["reached_fraction_low"], row["reached_fraction_high"]) == (ci.low, ci.high)
    assert row["err_theta_final_median_all"] == 5.0  # median(1e-4, 2, 5, inf, inf)
    assert row["err_theta_final_median"] == 2.0  # the resolved trials' (1e-4, 2, 5)
    assert summary.iloc[1]["err_theta_final_median_all"] == 3e-4
    lost = summarize_trials(frame.assign(err_theta_final=[math.nan] * 3 + [1.0] * 3),
                            {0: {}, 1: {}}).iloc[0]
    assert lost["err_theta_final_median_all"] == math.inf  # 3 of 5 never reached T
    text = summary_markdown(summary, ["g"])
    assert text.index("### Outcomes") < text.index("### Trials by status")
    assert "ALL the cell's trials" in text and "infinitely wrong" in text


def _headline_rows(cells: int, errors: int = 0) -> list[dict[str, object]]:
    from flatcli.core.loop.metrics import STATUS_NAMES

    rows: list[dict[str, object]] = []
    for c in range(cells):
        counts = dict.fromkeys(STATUS_NAMES, 0)
        counts.update(ok=20 - c % 5 - (errors if c == 1 else 0), diverged=c % 5,
                      error=errors if c == 1 else 0)
        rows.append({"cell": c, "plant.com": [0.1, 0.1, 0.001 * c], "gains": "printed",
                     "track.kp": [10.0, 13.0], "trials": 20, **counts,
                     "err_y_final_median": 1e-3 * c})
    return rows


def test_the_headline_fits_one_screen_and_says_where_the_tables_are() -> None:
    """18 cells: every cell on one line (the varying grid component, the statuses any cell
    has), at most 24 lines and 100 columns; the footer names summary.md and --full."""
    from flatcli.report.summary import headline, totals_text

    rows = _headline_rows(18)
    text = headline(rows, ["plant.com", "gains", "track.kp"], f"sweep 's': {totals_text(rows)}",
                    "runs/s/sweep", grid={"plant.com": [], "gains": [
                        {"label": "printed", "track.kp": [10.0, 13.0]}]})
    lines = text.splitlines()
    assert lines[0] == ("sweep 's': 18 cells, 360 trials: ok 327, singular 0, diverged 33, "
                        "unresolved 0, error 0")
    assert lines[1].split("|")[1:-1] == [" cell ", " plant.com[2] ", " ok ", " diverged ",
                                         " err_y_final med resolved [rad] "]
    assert len(lines) == 1 + 2 + 18 + 2 and max(len(line) for line in lines) <= 100
    assert lines[-2:] == ["full tables: runs/s/sweep/summary.md (flatcli summarize runs/s/sweep "
                          "--full)", "every trial: runs/s/sweep/trials.parquet"]


def test_a_large_grid_shows_its_worst_cells_and_the_error_reasons() -> None:
    from flatcli.report.summary import HEADLINE_CELLS, headline

    rows = _headline_rows(400, errors=3)
    reasons = {"plan: the margin is zero": 2, "task.end_effector: unreachable": 1,
               "a": 1, "b": 1}
    text = headline(rows, ["plant.com"], "t", "d", reasons)
    lines = text.splitlines()
    shown = [int(line.split("|")[1]) for line in lines[3:3 + HEADLINE_CELLS]]
    assert len(shown) == HEADLINE_CELLS and shown == sorted(shown) and 1 in shown
    assert f"({HEADLINE_CELLS} of 400 cells shown: those with the most trials not ok)" in text
    assert "error (2 trials like this): plan: the margin is zero" in text
    assert "error (1 trial): task.end_effector: unreachable" in text
    assert "(1 more error reason in trials.parquet's reason column)" in text
    assert "| error |" in lines[1]  # a status any cell has is a column
    assert len(lines) <= 30


def test_the_headline_shows_outcome_counts_when_the_summary_has_them() -> None:
    """A summary with outcomes (``summarize_trials`` of trials with an outcome column): the
    headline's title is followed by the outcomes of all trials, counted here from the rows
    with scipy's binomtest Wilson interval; each cell's outcome counts come after its
    statuses (reached and missed; lost is its diverged, unresolved and error), counted here
    from the rows; its median final error of y is over all its trials with the lost ones as
    inf, and says so. A summary without outcomes keeps the median over the resolved trials,
    named so."""
    from flatcli.report.summary import headline

    base = {m: [0.1] * 6 for m in ("err_theta_rms", "err_theta_final", "err_y_rms",
                                   "min_margin", "momentum_drift", "plan_momentum_residual",
                                   "peak_rate", "err_estimate")}
    outcome = ["reached", "missed", "missed", "lost", "lost", "reached"]
    frame = pd.DataFrame({
        "cell": [0] * 5 + [1], "status": ["ok", "ok", "singular", "diverged", "error", "ok"],
        "outcome": outcome, "err_y_final": [1e-4, 2.0, 5.0, math.nan, math.nan, 3e-4],
        "singular_hits": [0, 0, 1, 0, 0, 0], **base})
    records = summarize_trials(frame, {0: {"g": "a"}, 1: {"g": "b"}}).to_dict("records")
    lines = headline(records, ["g"], "t", "d").splitlines()
    ci = binomtest(outcome.count("reached"), len(outcome)).proportion_ci(
        confidence_level=0.95, method="wilson")
    assert lines[1] == (f"outcomes: reached 2 of 6 trials ({100 * 2 / 6:.3g} %, 95 % interval "
                        f"{100 * ci.low:.2g}-{100 * ci.high:.2g} %), missed 2, lost 2")
    heads = [h.strip() for h in lines[2].split("|")[1:-1]]
    assert heads[heads.index("error") + 1:] == ["reached", "missed", "err_y_final med [rad]"]
    first = [c.strip() for c in lines[4].split("|")[1:-1]]
    assert first[heads.index("diverged"):] == ["1", "1", "1", "2", "5"]  # and error 1
    assert first[-1] == "5"  # median(1e-4, 2, 5, inf, inf)
    assert ("med: over all the cell's trials, a lost one (diverged, unresolved, error) as inf"
            in lines)
    old = headline(_headline_rows(2), [], "t", "d").splitlines()
    assert "err_y_final med resolved [rad]" in old[1] and "reached" not in old[1]


def test_error_reasons_that_differ_only_in_numbers_are_one_kind(tmp_path: Path) -> None:
    """Each trial's own target makes its reason's numbers differ: counted as one kind, shown
    as the first; ok trials and other reasons apart."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from flatcli.report.summary import error_reasons

    reasons = ["task.end_effector: [-0.3, 0.04] m is unreachable: 0.05 m beyond",
               "task.end_effector: [0.41, -1e-05] m is unreachable: 0.1 m beyond",
               "plan: the margin is zero at t = 0.3 s", None, ""]
    pq.write_table(pa.table({"status": ["error", "error", "error", "ok", "error"],
                             "reason": reasons}), tmp_path / "trials.parquet")
    assert error_reasons([tmp_path / "trials.parquet"]) == {
        reasons[0]: 2, reasons[2]: 1, "(no reason recorded)": 1}
