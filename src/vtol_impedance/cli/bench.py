"""``vtol-impedance bench``: the speed of the compiled and NumPy executions; with ``--live``, the accuracy of
the live path."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import DEFAULT_OUT


def cmd_bench(args: argparse.Namespace) -> int:
    from ..bench import live_accuracy, live_table, run, table
    from ..errors import InputError

    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    if args.live:
        if args.quick or args.yardstick is not None or args.realistic is not None:
            raise InputError("--quick, --yardstick and --realistic apply to the speed benchmark, not with --live")
        out = Path(args.out if args.out is not None else f"{DEFAULT_OUT}/bench-live.json")
        seconds = 20.0 if args.live_seconds is None else args.live_seconds
        print(live_table(live_accuracy(out, seconds=seconds, log=log)))  # the table on stdout, as below
        return 0
    if args.live_seconds is not None:
        raise InputError("--live-seconds applies with --live only")
    out = Path(args.out if args.out is not None else f"{DEFAULT_OUT}/bench.json")
    res = run(out, quick=args.quick, log=log, compile_times=not args.quick, yardstick=args.yardstick,
              realistic=args.realistic)  # fmt: skip
    print(table(res))  # the table always, on stdout; --quiet silences the progress only
    return 0


def register(sub: Any) -> None:
    """Add the 'bench' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser("bench", help="speed of the compiled and NumPy backends; prints a table, writes JSON")
    sp.add_argument(
        "--out", default=None,
        help=f"JSON file (default: {DEFAULT_OUT}/bench.json, with --live {DEFAULT_OUT}/bench-live.json)",
    )  # fmt: skip
    sp.add_argument(
        "--quick", action="store_true", help="small sizes and short runs, no cold-compile measurement (a smoke test)"
    )
    sp.add_argument("--quiet", action="store_true", help="only the table (no progress)")
    sp.add_argument(
        "--yardstick", type=Path, default=None, metavar="NUMBA_LOOP_PY",
        help="also time the shared yardstick (its numba_loop.py) against this project, alternating rounds: "
        "one vehicle, a 10,000-vehicle batch, the controller step, and their ratios",
    )  # fmt: skip
    sp.add_argument(
        "--realistic", type=Path, default=None, metavar="DIR",
        help="the folder of the realistic-plant limit (plant_soa.c, built with gcc if present; default "
        "../shared/yardstick/realistic): a 4,000-vehicle batch on two threads is timed against it, as a ratio",
    )  # fmt: skip
    sp.add_argument(
        "--live", action="store_true",
        help="instead of the speeds: the accuracy of the live path, flying the simulated autopilot of each "
        "personality (PX4, ArduPilot) with a 1.0 N payload; prints the mean error and the p95 per axis",
    )  # fmt: skip
    sp.add_argument(
        "--live-seconds", type=float, default=None, metavar="S",
        help="seconds of estimate per personality with --live (default 20, at least 5; the set-up comes on top)",
    )  # fmt: skip
    sp.set_defaults(func=cmd_bench)
