"""``vtol-impedance paper``: the paper's three case studies with PD, PID and PD+C."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from .common import _announce_compile, _backend, _load_spec, _run_folder, _seed, add_flight_options
from .flights import _finish, _preflight, _run_case_job, _run_parallel, _write_case, _write_margins, _write_mjcf


def cmd_paper(args: argparse.Namespace) -> int:
    from ..errors import InputError
    from ..io import RunFolder
    from ..scenarios import PAPER_CASES, check
    from ..scenarios.spec import PAPER_CONTROL

    if args.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {args.jobs}")
    tuning = [] if args.tuning == "design" else [f"{k}={json.dumps(v)}" for k, v in PAPER_CONTROL.items()]
    specs = [_load_spec(n, tuning + args.set, args.duration, args.ideal)[0] for n in PAPER_CASES]
    variants = ["pd", "pid", "pdc"]
    seed = _seed(args)
    for spec in specs:
        check(spec, variants)
    backend = _backend(args)
    t0 = time.perf_counter()
    tag = () if args.tuning == "paper" else (f"tuning={args.tuning}",)
    with RunFolder(_run_folder(args, "paper", tag), command="paper") as folder:
        margins = _preflight(specs, variants, args.quiet, args.verbose, paper_gains=args.tuning == "paper")
        _announce_compile(backend, args.quiet)
        if not args.quiet:
            print(f"flying {len(specs)} cases x {len(variants)} controllers ...", file=sys.stderr)
        jobs = min(args.jobs, len(specs))
        jobs_args = [(s, variants, seed, args.quiet, backend) for s in specs]
        results_list = _run_parallel(jobs_args, jobs) if jobs > 1 else [_run_case_job(a) for a in jobs_args]
        results: dict[str, Any] = {}
        figures: dict[str, list[Path]] = {}
        mtables: list[Any] = []
        for spec, res in zip(specs, results_list, strict=True):
            results[spec.name] = res
            figs = _write_case(res, folder, spec.name, not args.no_plots)
            mfiles, tabs = _write_margins(margins[spec.name], folder, spec.name, not args.no_plots)
            mtables += tabs
            if backend.startswith("mujoco"):
                _write_mjcf(spec, folder)
            figures[spec.name] = [p for p in figs + mfiles if p.suffix == ".png"]
        title = "Ruggiero et al. (ICRA 2014) case studies, simulated" + (
            " (the paper's controller)" if args.tuning == "paper" else " (this tool's robust defaults)"
        )
        found = _margin_findings(margins)
        why = [_PAPER_GAINS_NOTE] if found and args.tuning == "paper" else []
        final = _finish(folder, title, results, figures, args.quiet, mtables, why, found)
    if not args.quiet:
        print(f"wall time {time.perf_counter() - t0:.1f} s; the report: {final / 'report.html'}", file=sys.stderr)
    return 0


#: Why the paper's printed gains fall short of the margins, and what flies without them (its report).
_PAPER_GAINS_NOTE = (
    "As expected, the paper's printed gains (attitude 8 rad/s, estimator 10 rad/s, the estimate read at face "
    "value) fall short on a plant with sensor latency and rotor lag; 'vtol-impedance paper --tuning design' flies "
    "gains designed to meet the thresholds, with the same position impedance. Every finding:"
)


def _margin_findings(margins: dict[str, Any]) -> list[str]:
    """Every margin finding in full, one per case and controller that falls short (the report's list)."""
    from ..scenarios.margins import warnings_of

    return [f"{case}, {w}" for case, reports in margins.items() for w in warnings_of(reports)]


def register(sub: Any) -> None:
    """Add the 'paper' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser("paper", help="all three case studies with PD, PID and PD+C: figures, table, report")
    add_flight_options(sp)
    sp.add_argument(
        "--tuning",
        choices=["paper", "design"],
        default="paper",
        help="the paper's controller as printed (default: attitude 8 rad/s, estimator 10 rad/s, no timing "
        "alignment), or this tool's robust design (docs/guide/margins.md)",
    )
    sp.add_argument(
        "--jobs", type=int, default=1, help="parallel processes (the compiled backend is fast; plotting dominates)"
    )
    sp.add_argument(
        "--verbose",
        action="store_true",
        help="every margin finding before the flights (default: one line per case; all of them are in the report)",
    )
    sp.set_defaults(func=cmd_paper)
