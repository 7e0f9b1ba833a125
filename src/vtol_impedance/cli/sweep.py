"""``vtol-impedance sweep`` and ``sweep-report``: parameter studies (resumable; optional Dask)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from .common import DEFAULT_OUT, _bound_flags, _default_out
from .flights import _preflight


def _sweep_out(args: argparse.Namespace, name: str) -> Path:
    return Path(args.out) if args.out else _default_out("sweep", name)


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run or resume a sweep, then write its summary."""
    from ..io import check_folder_path
    from ..sweeps import load, run_sweep, write_report
    from ..sweeps.budget import Progress, check_budget, sweep_seconds
    from ..sweeps.run import METRICS

    if args.metric not in METRICS:  # checked before the flights, not after them in the report
        from ..errors import InputError

        raise InputError(f"--metric must be one of {', '.join(METRICS)}, got {args.metric!r}")
    sweep = load(args.spec, check_points=False)
    check_folder_path(_sweep_out(args, sweep.name))  # before any work
    check_budget(sweep_seconds(sweep, args.backend, args.workers), f"sweep {sweep.name}", args.max_minutes, args.yes)
    checked = Progress(len(sweep.points), "points checked", not args.quiet)
    sweep = load(args.spec, on_point=checked)  # every point checked (its controller designed)
    where = Path(args.spec) if Path(args.spec).suffix else None
    if sweep.fast_estimator_points and not args.quiet:
        print(
            f"note: {len(sweep.fast_estimator_points)} of {len(sweep.points)} points put the estimator bandwidth "
            "near the sampling rate (|p| Ts > 0.5): measurement noise is barely filtered there",
            file=sys.stderr,
        )
    _preflight([sweep.base], sweep.controllers, args.quiet)  # the base point; every point's margins are in its rows
    t0 = time.perf_counter()
    folder, computed = run_sweep(
        sweep, _sweep_out(args, sweep.name), args.workers, args.scheduler, args.backend, args.restart, where,
        show_progress=not args.quiet,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    if not args.no_report:
        write_report(folder, args.metric)
    if not args.quiet:
        flights = computed * sweep.chunk * len(sweep.controllers)
        print(f"{computed} chunk(s) computed in {wall:.1f} s (about {flights / max(wall, 1e-9):.1f} flights/s); "
              f"results in {folder}", file=sys.stderr)  # fmt: skip
    return 0


def cmd_sweep_report(args: argparse.Namespace) -> int:
    from ..sweeps import write_report

    files = write_report(Path(args.folder), args.metric, args.x, args.y)
    if not args.quiet:
        print(f"wrote {len(files)} files to {args.folder}", file=sys.stderr)
    return 0


def register(sub: Any) -> None:
    """Add the 'sweep', 'sweep-report' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser(
        "sweep",
        help="a parameter study or Monte-Carlo over any scenario value (resumable; optional Dask)",
        description="Runs a sweep file (or a built-in study: rate-vs-bandwidth, payload-vs-offset) on the "
        "compiled batch engine, writes one Parquet file per chunk and a summary. Running the same command "
        "again after an interruption computes only the missing chunks.",
    )
    sp.add_argument("spec", help="a sweep .toml file or the name of a built-in study")
    sp.add_argument("--out", default=None, help=f"sweep folder (default: {DEFAULT_OUT}/sweep-<name>)")
    sp.add_argument("--workers", type=int, default=None, help="start a local Dask cluster with N worker processes")
    sp.add_argument("--scheduler", default=None, metavar="ADDRESS", help="use an existing Dask cluster")
    sp.add_argument("--restart", action="store_true", help="discard a different sweep found in the folder")
    sp.add_argument("--metric", default="rms_ep_cm", help="metric of the summary figures (default rms_ep_cm)")
    sp.add_argument("--no-report", action="store_true", help="only the data, no summary")
    sp.add_argument("--backend", choices=["compiled", "numpy"], default="compiled")
    sp.add_argument("--quiet", action="store_true", help="no progress output")
    _bound_flags(sp)
    sp.set_defaults(func=cmd_sweep)
    sp = sub.add_parser("sweep-report", help="summary figures, table and HTML report of a finished sweep folder")
    sp.add_argument("folder", help="a sweep folder")
    sp.add_argument("--metric", default="rms_ep_cm", help="metric (default rms_ep_cm)")
    sp.add_argument("--x", default=None, help="axis along x of the heat maps (default: the first axis)")
    sp.add_argument("--y", default=None, help="axis along y of the heat maps (default: the second axis)")
    sp.add_argument("--quiet", action="store_true")
    sp.set_defaults(func=cmd_sweep_report)
