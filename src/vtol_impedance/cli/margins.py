"""``vtol-impedance margins``: the stability margins of a scenario's controllers."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .common import DEFAULT_OUT, _load_spec, _run_folder
from .flights import _write_margins


def cmd_margins(args: argparse.Namespace) -> int:
    """Stability margins of a scenario's controllers at its operating point: table, figures, report."""
    from ..analysis.margin_plots import text_margins
    from ..analysis.report import write_html
    from ..io import RunFolder
    from ..scenarios import check
    from ..scenarios.margins import MEETS, scenario_margins, warnings_of
    from ..scenarios.spec import check_variants

    spec, tag = _load_spec(args.scenario, args.set, None, args.ideal)
    variants = check_variants([c.strip() for c in args.controllers.split(",") if c.strip()], unique=True)
    check(spec, variants)
    out = _run_folder(args, f"margins-{spec.name}", tag)
    with RunFolder(out, command="margins") as folder:
        if not args.quiet:
            print(f"linearising {spec.name} for {', '.join(variants)} ...", file=sys.stderr)
        reports = scenario_margins(spec, variants)
        files, tables = _write_margins(reports, folder, spec.name, not args.no_plots)
        warn = warnings_of(reports)
        notes = [
            "Each loop is broken with the others closed; L is closed by 1 + L. Gain margins up and down: a loop "
            "around a double integrator also destabilises when its gain falls. An unstable closed loop shows no "
            "margins.",
            "Operating point: hover at the reference where the task window starts, on the true plant, under the "
            "disturbances' mean wrench there (module vtol_impedance.scenarios.margins).",
        ] + ([f"Below the thresholds: {w}" for w in warn] or [f"{MEETS[0].upper()}{MEETS[1:]}."])
        write_html(folder.staging, f"Stability margins: {spec.name}", tables=tables,
                   figures={spec.name: [p for p in files if p.suffix == ".png"]}, notes=notes,
                   config={"scenario": spec.to_dict()}, seed=spec.seed)  # fmt: skip
        final = folder.commit({"scenario": spec.to_dict()}, seed=spec.seed)
    print(text_margins(reports))
    for w in warn:
        print(f"below the thresholds: {w}")
    if not warn:
        print(MEETS)
    if not args.quiet:
        print(f"results written to {final}", file=sys.stderr)
    return 0


def register(sub: Any) -> None:
    """Add the 'margins' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser(
        "margins",
        help="stability margins of a scenario's controllers (the sampled loop linearised): table, Bode, "
        "Nyquist, poles, report",
        description="Linearises the closed loop the simulator flies at the scenario's operating point (hover at the "
        "task's reference, true plant, sensor latencies, rotor lag) and reports per loop the phase, gain and delay "
        "margins and the sensitivity peak, and the closed-loop poles; see docs/guide/margins.md.",
    )
    sp.add_argument("scenario", help="registered name (see 'list') or a .toml scenario file")
    sp.add_argument("--controllers", default="pd,pid,pdc", help="comma-separated (default: pd,pid,pdc)")
    sp.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scenario value")
    sp.add_argument("--ideal", action="store_true", help="the ideal plant and sensors (no lag, no latency)")
    sp.add_argument("--out", default=None, help=f"results folder (default: {DEFAULT_OUT}/margins-<scenario>)")
    sp.add_argument("--no-plots", action="store_true", help="skip figures")
    sp.add_argument("--quiet", action="store_true", help="no progress output")
    sp.set_defaults(func=cmd_margins)
