"""``vtol-impedance identify``: rotor drag, inflow damping and rotor time constant from a flight log."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def cmd_identify(args: argparse.Namespace) -> int:
    """Fit the vehicle's aerodynamic coefficients and rotor lag to a log; print them and a TOML snippet."""
    from ..errors import InputError
    from ..io import check_output_file, explain_path, write_text
    from ..logs import samples as sample_logs
    from ..logs.identify import identify_file

    if args.example is not None:
        if args.log is not None:
            raise InputError("give a log file or --example NAME, not both")
        log = sample_logs.path(args.example)
    else:
        if args.log is None:
            raise InputError("give a log file (CSV, .ulg, .bin, .tlog) or --example NAME (estimate --example list)")
        log = Path(args.log)
        if not log.is_file():
            raise InputError(f"cannot read log file {log}: {explain_path(log) or 'not a regular file'}")
    if args.out:  # before the fit: a device or a folder named as the output is refused, not replaced
        check_output_file(Path(args.out))
    from ..estimator import EstimatorParams

    read_options: dict[str, Any] = {"conventions": args.conventions}
    params = EstimatorParams(wn=args.wn, velocity_delay=args.velocity_delay, attitude_delay=args.attitude_delay)
    res = identify_file(
        log, vehicle=args.vehicle, mass=args.mass, t_start=args.start, t_end=args.end, read_options=read_options,
        hover_thrust=args.hover_thrust, force=args.force, params=params,
    )  # fmt: skip
    if args.json:
        print(json.dumps(res.to_dict(), indent=2))
    else:
        print(f"Identified from {log} ({res.samples} samples, {res.span_s[0]:.2f}-{res.span_s[1]:.2f} s)")
        for c in res.coefficients:
            print("  " + c.text())
        print(
            f"  fit: residual RMS {res.rms_residual_N:.3g} N, R^2 {res.r2:.3f}, effective samples {res.n_eff:.0f};"
            f" constant force {', '.join(f'{b:.3g}' for b in res.bias_W_N)} N (world NED x, y), thrust missing"
            f" {100 * res.thrust_loss:.2g} % of the command"
        )
        for n in res.notes:
            print("  note: " + n)
        print("\nVehicle TOML keys:\n" + res.toml_snippet())
    if args.out:
        out = Path(args.out)
        text = json.dumps(res.to_dict(), indent=2) + "\n" if out.suffix == ".json" else res.toml_snippet()
        write_text(out, text)
        if not args.json:
            print(f"written {out}")
    return 0


def register(sub: Any) -> None:
    """Add the 'identify' sub-command to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser(
        "identify",
        help="fit rotor drag, inflow damping and the rotor time constant to a flight log (95 %% intervals)",
        description="Least squares on the momentum estimator's residual along a flight log (thrust from the "
        "commands): rotor_drag (body x, y) and inflow_damping (body z) in N per m/s and the rotor time constant, "
        "each with a 95 %% interval, or 'not identifiable from this log' where the flight does not excite it. "
        "Prints the vehicle TOML keys to paste; see docs/guide/identify.md.",
    )
    sp.add_argument("log", nargs="?", default=None, help="a .ulg (PX4), .bin (ArduPilot), .tlog (MAVLink) or .csv file")
    sp.add_argument("--example", default=None, metavar="NAME", help="a sample log (vtol-impedance estimate --example "
                    "list)")  # fmt: skip
    sp.add_argument("--vehicle", default=None, help="preset name or vehicle .toml: nominal mass and rotor geometry")
    sp.add_argument("--mass", type=float, default=None, help="nominal mass, kg (overrides --vehicle and the log)")
    sp.add_argument("--conventions", default="check", choices=["check", "auto", "unchecked"],
                    help="as for estimate: check the log's conventions against physics (default)")  # fmt: skip
    sp.add_argument("--hover-thrust", type=float, default=None, help="normalised hover thrust (0..1), as for estimate")
    sp.add_argument("--velocity-delay", type=float, default=0.0, metavar="S",
                    help="latency of the logged velocity against the commands, s (left out, it is read as rotor "
                    "lag)")  # fmt: skip
    sp.add_argument("--attitude-delay", type=float, default=0.0, metavar="S",
                    help="latency of the logged attitude against the commands, s")  # fmt: skip
    sp.add_argument("--wn", type=float, default=10.0, help="estimator bandwidth, rad/s (default 10, as estimate)")
    sp.add_argument("--start", type=float, default=None, help="fit from this time on, s")
    sp.add_argument("--end", type=float, default=None, help="fit up to this time, s")
    sp.add_argument("--force", action="store_true", help="fit even when the log's verdict is refused")
    sp.add_argument("--json", action="store_true", help="print the fit as JSON")
    sp.add_argument("--out", default=None, metavar="FILE",
                    help="write the TOML snippet (or the JSON, for a .json name) atomically to FILE")  # fmt: skip
    sp.set_defaults(func=cmd_identify)
