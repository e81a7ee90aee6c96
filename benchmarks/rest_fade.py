"""docs/tasks.md's table of the rest-to-rest closed loop, measured from today's code.

    .venv/bin/python -m benchmarks.rest_fade            # print the table
    .venv/bin/python -m benchmarks.rest_fade --update   # and write it into docs/tasks.md

The paper's robot, maneuver (1.8, 1, 0) -> (1.2, 2, 0) rad in T = 2 s at rest at both ends,
gains kp = (100, 110), kv = (10, 13), tracked by ``flatcli.track`` (``controllers.rest``: the
flat law's feedback faded in and out over ``task.fade`` x T; track.integrator "dop853", scipy's
DOP853 at rtol 1e-10 on the compiled right-hand side) from the plan's start
and from (1.82, 0.99, 0.01) rad. Per row: err_theta_max and err_theta_final (the run's
metrics), the end effector's distance at T from the plan's end effector at T, and the
largest abs th_i'(T) (the plant's rates when it should be at rest).
``tests/test_tasks.py::test_the_rest_fade_table_is_todays`` recomputes two rows and compares
them with docs/tasks.md, so the table cannot drift from the code.
"""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

#: The maneuver and gains of the table.
BASE: dict[str, Any] = {"task.rest": True, "plan.start": [1.8, 1.0, 0.0],
                        "plan.goal": [1.2, 2.0, 0.0], "plan.duration": 2.0,
                        "track.kp": [100.0, 110.0], "track.kv": [10.0, 13.0],
                        "track.integrator": "dop853"}
ON_PLAN = (1.8, 1.0, 0.0)
OFF_PLAN = (1.82, 0.99, 0.01)
#: The rows: (start, fade).
ROWS = ((ON_PLAN, 0.1), (ON_PLAN, 0.2), (OFF_PLAN, 0.1), (OFF_PLAN, 0.2), (OFF_PLAN, 0.3))
HEADER = ("| start | fade | err_theta_max [rad] | err_theta_final [rad] | ee error at T [m] | "
          "max abs th'(T) [rad/s] |")
BEGIN, END = "<!-- rest-fade-table -->", "<!-- end rest-fade-table -->"
DOC = Path(__file__).resolve().parents[1] / "docs" / "tasks.md"


def row(start: tuple[float, ...], fade: float) -> dict[str, float]:
    """One row's numbers (module docstring)."""
    import flatcli

    run = flatcli.track(overrides={**BASE, "track.initial": list(start), "task.fade": fade})
    plan = flatcli.plan(overrides=BASE).frame
    frame = run.frame
    ee = float(np.hypot(frame["ee_x"].iloc[-1] - plan["ee_x"].iloc[-1],
                        frame["ee_y"].iloc[-1] - plan["ee_y"].iloc[-1]))
    rates = frame[["theta0_dot", "theta1_dot", "theta2_dot"]].iloc[-1].to_numpy(dtype=float)
    return {"err_theta_max": float(run.metrics["err_theta_max"]),
            "err_theta_final": float(run.metrics["err_theta_final"]),
            "ee_error_at_T": ee, "rate_at_T": float(np.max(np.abs(rates)))}


def number(x: float) -> str:
    """Three significant digits, as the table writes them (so a test can tell 1 % apart)."""
    if x == 0 or not math.isfinite(x):
        return str(x)
    if 0.1 <= abs(x) < 100:
        return f"{x:.3g}"
    return f"{x:.2e}"


def label(start: tuple[float, ...]) -> str:
    return "on the plan" if start == ON_PLAN else "(" + ", ".join(f"{v:g}" for v in start) + ")"


def table(values: list[dict[str, float]]) -> str:
    lines = [HEADER, "|---|---|---|---|---|---|"]
    for (start, fade), v in zip(ROWS, values, strict=True):
        lines.append(f"| {label(start)} | {fade:g} | {number(v['err_theta_max'])} | "
                     f"{number(v['err_theta_final'])} | {number(v['ee_error_at_T'])} | "
                     f"{number(v['rate_at_T'])} |")
    return "\n".join(lines)


def documented() -> dict[tuple[str, float], list[float]]:
    """The table as docs/tasks.md has it: (start label, fade) -> its four numbers."""
    text = DOC.read_text()
    block = text.split(BEGIN, 1)[1].split(END, 1)[0]
    out = {}
    for line in block.strip().splitlines()[2:]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        out[(cells[0], float(cells[1]))] = [float(c) for c in cells[2:]]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--update", action="store_true", help="write it into docs/tasks.md")
    args = parser.parse_args()
    text = table([row(start, fade) for start, fade in ROWS])
    print(text)
    if args.update:
        doc = DOC.read_text()
        new = re.sub(rf"{re.escape(BEGIN)}.*?{re.escape(END)}",
                     lambda _: f"{BEGIN}\n{text}\n{END}", doc, flags=re.S)
        DOC.write_text(new)
        print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
