"""``vtol-impedance design``: gains for a trajectory objective that keep the margins (docs/guide/margins.md)."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from typing import Any

from .common import _Progress


def cmd_design(args: argparse.Namespace) -> int:
    """Search the tuning that tracks the wind and circle cases best within the margins; print it against
    the printed gains, with the ``--set`` flags that fly it (and write them to ``--out``)."""
    from ..io import check_output_file, write_text
    from ..scenarios.tracking import CASES, tracking_design

    cases = list(CASES) if args.cases is None else [c.strip() for c in args.cases.split(",") if c.strip()]
    if not cases:
        from ..errors import InputError

        raise InputError(f"--cases {args.cases!r}: give one or more registered scenarios, comma-separated")
    if args.out:  # a file's folder that cannot be written is named before the search
        from pathlib import Path

        from ..errors import InputError

        try:
            check_output_file(Path(args.out))
        except InputError as exc:
            raise InputError(f"--out {args.out!r}: {exc} (give a file name for the tuning, a .toml file)") from None
    if not args.quiet:
        print(f"designing for {', '.join(cases)} on {args.vehicle}: 108 tunings, about 40 s ...", file=sys.stderr)
    bar = _Progress("tunings checked", not args.quiet)
    d = tracking_design(args.vehicle, cases, args.min_phase, args.min_gain, progress=lambda i, n: bar(i / n))

    def row(name: str, rms: dict[str, float], m: dict[str, float]) -> tuple[str, ...]:
        return (name, *(f"{rms[c]:.2f} mm" for c in cases), f"{m['pm_deg']:.1f} deg", f"{m['gm_db']:.1f} dB")

    rows = [("", *cases, "phase margin", "gain margin"), row("printed gains", d.printed_rms_mm, d.printed_margins),
            row("designed", d.rms_mm, d.margins)]  # fmt: skip
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    print(f"PD+C on {d.vehicle}, RMS |e_p| over each case's task window; margins: the worst over the cases "
          f"({d.feasible} of {d.checked} tunings keep {d.min_phase_deg:g} deg)")  # fmt: skip
    for r in rows:
        print("  " + "  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)))
    for note in d.notes:
        print(f"note: {note}")
    flags = " ".join(f"--set {k}={json.dumps(v).replace(' ', '')}" for k, v in d.settings.items())
    vehicle = shlex.quote(f"vehicle={args.vehicle}")  # the gains are this vehicle's, for the first case designed for
    print(f"fly it: vtol-impedance compare {cases[0]} --set {vehicle} {flags}")
    if args.out:
        lines = ["# written by vtol-impedance design: the tuning for a trajectory objective; use it as a scenario",
                 f"# file's settings (vtol-impedance run FILE) with a base scenario: base = \"{cases[0]}\"",
                 f"base = \"{cases[0]}\"", f"vehicle = {json.dumps(args.vehicle)}",
                 f"name = \"{cases[0]}-tracking\""]  # fmt: skip
        lines += [f"{k} = {json.dumps(v)}" for k, v in d.settings.items()]
        write_text(args.out, "\n".join(lines) + "\n")
        if not args.quiet:
            print(f"wrote {args.out}", file=sys.stderr)
    return 0


def register(sub: Any) -> None:
    """Add the 'design' sub-command to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser(
        "design",
        help="gains for a trajectory objective: the tuning that tracks wind and a circle best within the margins",
        description="Searches a grid of position impedances, attitude and estimator bandwidths (with the reference "
        "aligned to the latency and a slower moment estimate than force estimate) for the tuning whose PD+C tracks "
        "the wind (gust) and circle cases best while keeping --min-phase degrees of phase and --min-gain dB of gain "
        "margin at every case's operating point, and prints it against the paper's printed gains. See "
        "docs/guide/margins.md.",
    )
    sp.add_argument("vehicle", nargs="?", default="pelican", help="a vehicle preset or .toml file (default: pelican)")
    sp.add_argument(
        "--cases", default=None, help="registered scenarios to track, comma-separated (default: gust,case-c-circle)"
    )
    sp.add_argument("--min-phase", type=float, default=30.0, help="phase margin to keep, deg (default: 30)")
    sp.add_argument("--min-gain", type=float, default=3.0, help="gain margin to keep, dB (default: 3)")
    sp.add_argument("--out", default=None, help="write the tuning as a scenario file (TOML) here")
    sp.add_argument("--quiet", action="store_true", help="no progress output")
    sp.set_defaults(func=cmd_design)
