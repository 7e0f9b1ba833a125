"""``vtol-impedance tune``: gains searched by optuna over a population of plants."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import DEFAULT_OUT, _bound_flags, _default_out
from .flights import _preflight
from .sweep import cluster_flags


def cmd_tune(args: argparse.Namespace) -> int:
    """Search gains with optuna over a population of plants; write the best as a scenario file."""
    from ..analysis.plots import _save, plt
    from ..analysis.report import write_html
    from ..io import RunFolder, check_folder_path, write_text
    from ..sweeps.budget import check_budget, tuning_seconds
    from ..sweeps.tune import _optuna, best_scenario_toml, bound_notes, load_tuning, trials_csv, tune

    _optuna()  # a missing extra is said at once, before anything compiles
    if args.trials is not None:  # refused before the corners are designed (seconds each), as tune() would
        from ..errors import scalar

        scalar("--trials", args.trials, lo=1, hi=100_000, integer=True)
    t = load_tuning(args.spec, check_corners=False)
    out = check_folder_path(Path(args.out) if args.out else _default_out("tune", t.name))
    seconds = tuning_seconds(t, t.trials if args.trials is None else args.trials, args.backend, args.workers)
    check_budget(seconds, f"tuning {t.name}", args.max_minutes, args.yes)
    t = load_tuning(args.spec)  # the search box's corners checked (their controllers designed)
    _preflight([t.base_spec()], [t.controller], args.quiet)
    with RunFolder(out, command="tune") as folder:
        log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
        res = tune(t, args.workers, args.scheduler, args.trials, args.backend, log, scheduler_file=args.scheduler_file,
                   connect_timeout=args.connect_timeout, wait_workers=args.wait_workers)  # fmt: skip
        write_text(folder.path("trials.csv"), trials_csv(res["trials"]))
        best_row = min(res["trials"], key=lambda r: r["cost"])
        if best_row["failed"] or best_row.get("below_margin", 0):
            from ..errors import VtolImpedanceError

            margin = " and within the phase margin" if best_row.get("below_margin") else ""
            raise VtolImpedanceError(
                f"no trial flew every member of the population without failing{margin} (the best had "
                f"{best_row['failed']} failed flights): no best.toml is written; widen or move the search ranges, "
                "or soften the population"
            )
        toml_text = best_scenario_toml(t, res["best"])
        write_text(folder.path("best.toml"), toml_text)
        notes = bound_notes(t, res["best"])
        costs = [r["cost"] for r in res["trials"]]
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.plot(range(1, len(costs) + 1), costs, "o", ms=3, color="gray", label="trial")
        ax.plot(range(1, len(costs) + 1), [min(costs[: i + 1]) for i in range(len(costs))], color="tab:blue",
                label="best so far")  # fmt: skip
        ax.set_yscale("log")
        ax.set_xlabel("trial")
        ax.set_ylabel(f"cost ({t.metric} + penalties)")
        ax.grid(alpha=0.3)
        ax.legend()
        fig_path = _save(fig, folder.path("history.png"))
        keys = list(res["best"])
        fmt = lambda v: f"{v:.4g}" if isinstance(v, int | float) else str(v)  # noqa: E731
        rows = [[str(i + 1)] + [fmt(r[k]) for k in keys] + [fmt(r["cost"]), str(r["failed"])]
                for i, r in enumerate(res["trials"])]  # fmt: skip
        write_html(folder.staging, f"Tuning {t.name}", tables=[("Trials", ["trial", *keys, "cost", "failed"], rows)],
                   figures={"Search": [fig_path]},
                   notes=[f"Best cost {res['cost']:.4g}; best.toml:", toml_text, *notes],
                   config=t.data, seed=t.seed)  # fmt: skip
        final = folder.commit(t.data, seed=t.seed)
    print(toml_text, end="")
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    if not args.quiet:
        print(f"best cost {res['cost']:.4g}; results written to {final}", file=sys.stderr)
    return 0


def register(sub: Any) -> None:
    """Add the 'tune' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser("tune", help="search gains with optuna over a population of plants; best as a scenario file")
    sp.add_argument("spec", help="a tuning .toml file")
    sp.add_argument("--trials", type=int, default=None, help="number of trials (default: the file's)")
    sp.add_argument("--out", default=None, help=f"results folder (default: {DEFAULT_OUT}/tune-<name>)")
    cluster_flags(sp)
    sp.add_argument("--backend", choices=["compiled", "numpy"], default="compiled")
    sp.add_argument("--quiet", action="store_true")
    _bound_flags(sp)
    sp.set_defaults(func=cmd_tune)
