"""``vtol-impedance run`` and ``compare``: one scenario with one or several controllers."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from .common import _announce_compile, _backend, _load_spec, _run_folder, _seed, add_flight_options
from .flights import _finish, _preflight, _run_case, _write_case, _write_margins, _write_mjcf


def cmd_run(args: argparse.Namespace, variants: list[str]) -> int:
    from ..io import RunFolder
    from ..scenarios import check
    from ..scenarios.spec import check_variants

    spec, tag = _load_spec(args.scenario, args.set, args.duration, args.ideal)
    variants = check_variants(variants, unique=True)
    seed = _seed(args)
    check(spec, variants)
    backend = _backend(args)
    t0 = time.perf_counter()
    with RunFolder(_run_folder(args, spec.name, tag), command=args.command) as folder:
        margins = _preflight([spec], variants, args.quiet)
        _announce_compile(backend, args.quiet)
        result = _run_case(spec, variants, seed, args.quiet, backend)
        if args.animate and not args.quiet:
            print("drawing the animation ...", file=sys.stderr)
        figs = _write_case(result, folder, spec.name, not args.no_plots, args.animate)
        mfiles, mtables = _write_margins(margins[spec.name], folder, spec.name, not args.no_plots)
        if backend.startswith("mujoco"):
            figs.append(_write_mjcf(spec, folder))
        _finish(
            folder,
            f"vtol-impedance: {spec.name}",
            {spec.name: result},
            {spec.name: [p for p in figs + mfiles if p.suffix in (".png", ".gif")]},
            args.quiet,
            mtables,
        )
    if not args.quiet:
        print(f"wall time {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


def register(sub: Any) -> None:
    """Add the 'run', 'compare' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser("run", help="one scenario with one controller")
    sp.add_argument("scenario", help="registered name (see 'list') or a .toml scenario file")
    sp.add_argument("--controller", default="pdc", choices=["pd", "pid", "pdc", "comply"])
    add_flight_options(sp)
    sp.add_argument("--animate", action="store_true", help="also write <scenario>.gif (3D, with the force arrows)")
    sp.set_defaults(func=lambda a: cmd_run(a, [a.controller]))
    sp = sub.add_parser("compare", help="one scenario with several controllers on the same disturbances")
    sp.add_argument("scenario", help="registered name (see 'list') or a .toml scenario file")
    sp.add_argument("--controllers", default="pd,pid,pdc", help="comma-separated (default: pd,pid,pdc)")
    add_flight_options(sp)
    sp.add_argument("--animate", action="store_true", help="also write <scenario>.gif (3D, with the force arrows)")
    sp.set_defaults(func=lambda a: cmd_run(a, [c.strip() for c in a.controllers.split(",") if c.strip()]))
