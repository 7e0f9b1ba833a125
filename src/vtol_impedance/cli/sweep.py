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
    from ..errors import InputError
    from ..io import check_folder_path
    from ..sweeps import from_dict, load, run_sweep, write_report
    from ..sweeps.budget import Progress, check_budget, sweep_seconds
    from ..sweeps.cluster import ChunkError, ClusterError
    from ..sweeps.run import METRICS

    if args.metric not in METRICS:  # checked before the flights, not after them in the report
        raise InputError(f"--metric must be one of {', '.join(METRICS)}, got {args.metric!r}")
    sweep = load(args.spec, check_points=False)
    check_folder_path(_sweep_out(args, sweep.name))  # before any work
    check_budget(sweep_seconds(sweep, args.backend, args.workers), f"sweep {sweep.name}", args.max_minutes, args.yes)
    checked = Progress(len(sweep.points), "points checked", not args.quiet)
    where = Path(args.spec) if Path(args.spec).suffix else None
    # every point checked (its controller designed), on the base already read: the files are read once, here
    sweep = from_dict(sweep.source, where, on_point=checked, base=sweep.base)
    if sweep.fast_estimator_points and not args.quiet:
        print(
            f"note: {len(sweep.fast_estimator_points)} of {len(sweep.points)} points put the estimator bandwidth "
            "near the sampling rate (|p| Ts > 0.5): measurement noise is barely filtered there",
            file=sys.stderr,
        )
    _preflight([sweep.base], sweep.controllers, args.quiet)  # the base point; every point's margins are in its rows
    t0 = time.perf_counter()
    out = _sweep_out(args, sweep.name)
    try:
        folder, computed = run_sweep(
            sweep, out, args.workers, args.scheduler, args.backend, args.restart, where,
            show_progress=not args.quiet, scheduler_file=args.scheduler_file, connect_timeout=args.connect_timeout,
            wait_workers=args.wait_workers, resume=resume_command(args, out),
        )  # fmt: skip
    except KeyboardInterrupt:  # what was kept and how to resume is said by run_sweep
        return 130
    except (ClusterError, ChunkError) as exc:  # a fault of the cluster or of chunks, not of the input
        if isinstance(exc, InputError):  # a scheduler that is not there: a wrong address (exit 2)
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 1
    wall = time.perf_counter() - t0
    if not args.no_report:
        write_report(folder, args.metric)
    if not args.quiet:
        flights = computed * sweep.chunk * len(sweep.controllers)
        print(f"{computed} chunk(s) computed in {wall:.1f} s (about {flights / max(wall, 1e-9):.1f} flights/s); "
              f"results in {folder}", file=sys.stderr)  # fmt: skip
    return 0


def resume_command(args: argparse.Namespace, out: Path) -> str:
    """The command that resumes this sweep: the same spec, folder, cluster, backend and bound (never
    --restart, which would discard the kept chunks)."""
    import shlex

    cmd = ["vtol-impedance", "sweep", str(args.spec), "--out", str(out)]
    for flag in ("workers", "scheduler", "scheduler_file", "connect_timeout", "wait_workers", "max_minutes"):
        value = getattr(args, flag, None)
        if value is not None:
            cmd += [f"--{flag.replace('_', '-')}", str(value)]
    if args.backend != "compiled":
        cmd += ["--backend", args.backend]
    if getattr(args, "yes", False):  # the resumed sweep is estimated whole again
        cmd.append("--yes")
    return shlex.join(cmd)


def cluster_flags(sp: argparse.ArgumentParser) -> None:
    """The flags that choose where the work runs (shared by ``sweep`` and ``tune``). The defaults named in
    the help are :data:`~vtol_impedance.sweeps.cluster.CONNECT_TIMEOUT_S` and ``WAIT_WORKERS_S`` (written
    out: ``--help`` imports no heavy module; a test keeps them equal)."""
    CONNECT_TIMEOUT_S, WAIT_WORKERS_S = 10.0, 60.0  # noqa: N806

    sp.add_argument("--workers", type=int, default=None, help="start a local Dask cluster with N worker processes")
    sp.add_argument("--scheduler", default=None, metavar="ADDRESS", help="use an existing Dask cluster")
    sp.add_argument("--scheduler-file", default=None, metavar="FILE",
                    help="use the Dask cluster named in FILE (dask scheduler --scheduler-file FILE)")  # fmt: skip
    sp.add_argument("--connect-timeout", type=float, default=None, metavar="S",
                    help=f"deadline for the scheduler to answer, s (default {CONNECT_TIMEOUT_S:g})")  # fmt: skip
    sp.add_argument("--wait-workers", type=float, default=None, metavar="S",
                    help=f"how long to wait for a first worker, s (default {WAIT_WORKERS_S:g})")  # fmt: skip


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
    cluster_flags(sp)
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
