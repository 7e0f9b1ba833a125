"""``vtol-impedance bench``: the speed of the compiled and NumPy executions."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import DEFAULT_OUT


def cmd_bench(args: argparse.Namespace) -> int:
    from ..bench import run, table

    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    res = run(Path(args.out), quick=args.quick, log=log, compile_times=not args.quick, yardstick=args.yardstick)
    print(table(res))  # the table always, on stdout; --quiet silences the progress only
    return 0


def register(sub: Any) -> None:
    """Add the 'bench' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser("bench", help="speed of the compiled and NumPy backends; prints a table, writes JSON")
    sp.add_argument("--out", default=f"{DEFAULT_OUT}/bench.json", help=f"JSON file (default: {DEFAULT_OUT}/bench.json)")
    sp.add_argument(
        "--quick", action="store_true", help="small sizes and short runs, no cold-compile measurement (a smoke test)"
    )
    sp.add_argument("--quiet", action="store_true", help="only the table (no progress)")
    sp.add_argument(
        "--yardstick", type=Path, default=None, metavar="NUMBA_LOOP_PY",
        help="also time the shared yardstick (its numba_loop.py) against this project, alternating rounds: "
        "one vehicle, a 10,000-vehicle batch, the controller step, and their ratios",
    )  # fmt: skip
    sp.set_defaults(func=cmd_bench)
