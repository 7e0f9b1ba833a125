"""The table and figure of docs/guide/margins.md, "The widened robustness study", from the three sweeps.

    vtol-impedance sweep robustness-trajectories
    vtol-impedance sweep robustness-push
    vtol-impedance sweep robustness-wall
    python docs/make_robustness_widened.py [RESULTS_FOLDER]   # default: results

Prints the Markdown table (verdict against outcome per study and controller) and writes
docs/img/robustness-widened_verdict.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

from vtol_impedance.control.impedance import DISPLAY_NAMES
from vtol_impedance.sweeps.report import plot_verdict_outcome, summarise, verdict_outcome

STUDIES = ("robustness-trajectories", "robustness-push", "robustness-wall")


def main(results: Path) -> None:
    cols = {}
    for name in STUDIES:
        c = summarise(results / f"sweep-{name}")["cols"]
        if name == "robustness-trajectories":  # one row per trajectory: split the joint axis
            kind = c["trajectory.kind,trajectory.circle_speed"].astype(str)
            for k in ("circle", "figure-eight"):
                sel = [k in v for v in kind]
                cols[k] = {key: val[sel] for key, val in c.items()}
        else:
            cols[name.removeprefix("robustness-")] = c
    print(
        "| case | controller | flights | passes: settled / wobbled | thin: settled / wobbled "
        "| unstable: settled / wobbled | agree | false alarms | misses | vs thresholds: agree / FA / miss |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    total = {"cells": 0, "agree": 0, "false_alarm": 0, "miss": 0, "agree_t": 0, "false_alarm_t": 0, "miss_t": 0}
    for name, c in cols.items():
        for ctrl, a in verdict_outcome(c)["counts"].items():
            scoped = " (free flight only)" if a["scoped"] else ""
            print(
                f"| {name}{scoped} | {DISPLAY_NAMES.get(ctrl, ctrl)} | {a['cells']} "
                f"| {a['passes/settled']} / {a['passes/wobbled']} | {a['thin/settled']} / {a['thin/wobbled']} "
                f"| {a['unstable/settled']} / {a['unstable/wobbled']} | {a['agree']} | {a['false_alarm']} "
                f"| {a['miss']} | {a['agree_t']} / {a['false_alarm_t']} / {a['miss_t']} |"
            )
            for k in total:
                total[k] += a[k]
    print(
        f"| **all** | | {total['cells']} | | | | {total['agree']} | {total['false_alarm']} | {total['miss']} "
        f"| {total['agree_t']} / {total['false_alarm_t']} / {total['miss_t']} |"
    )
    out = Path(__file__).resolve().parent / "img" / "robustness-widened_verdict.png"
    plot_verdict_outcome(cols, out)
    print(f"wrote {out}", file=sys.stderr)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results"))
