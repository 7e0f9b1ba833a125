"""``vtol-impedance estimate``: the external wrench along a flight log."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from .common import DEFAULT_OUT, _floats


def _estimate_tables(est: Any, s: dict[str, Any]) -> list[tuple[str, list[str], list[list[str]]]]:
    tables = []
    for name, st in s["stats"].items():
        rows = [[k] + [f"{v:.4g}" for v in vals] for k, vals in st.items()]
        over = "in the air (the ground stretches left out)" if s.get("ground_samples_left_out") else "over the log"
        tables.append((f"Estimate {name} {over}", [name, "x", "y", "z"], rows))
    if est.bias is not None:
        rows = [[k] + [f"{v:.4g}" for v in est.bias[k]] for k in ("f_W_N", "tau_B_Nm") if k in est.bias]
        a, b = est.bias["segment_s"]
        tables.append((f"Bias: mean estimate over the quiet segment {a:g}-{b:g} s", ["", "x", "y", "z"], rows))
    choices = est.info.get("choices", [])
    if choices:
        tables.append(("What was chosen from the log", ["choice"], [[c] for c in choices]))
    conv = est.info.get("conventions")
    if conv and conv.get("evidence_chosen"):
        ev = conv["evidence_chosen"]
        rows = [[k, str(v)] for k, v in ev.items()] + [["mode", conv["mode"]], ["readings tried", str(conv["tried"])]]
        if conv.get("chosen"):
            rows.append(["conventions", ", ".join(f"{k} {v}" for k, v in conv["chosen"].items())])
        tables.append(("Conventions checked against physics", ["item", "value"], rows))
    gaps = est.info.get("gaps") or []
    if gaps:
        rows = []
        for g in gaps[:200]:
            bound = (
                f"{g['bound_f_N']:.3g} N (+{g['bound_f_per_N_change']:.2g} per N of change)" if "bound_f_N" in g else ""
            )
            rows.append(
                [g["signal"], f"{g['t0_s']:.3f}", f"{g['t1_s']:.3f}", f"{g['length_s']:.3f}", g["action"], bound]
            )
        caption = "Gaps: bridged (estimator state carried) or restart (the data stop)"
        if len(gaps) > 200:
            caption += f"; the first 200 of {len(gaps)}"
        tables.append((caption, ["signal", "from s", "to s", "length s", "action", "bound after it"], rows))
    skip = ("estimator", "inertia_kg_m2", "choices", "conventions", "gaps")
    info_rows = [[k, str(v)] for k, v in est.info.items() if k not in skip]
    tables.append(("How the log was read", ["item", "value"], info_rows))
    return tables


def cmd_estimate(args: argparse.Namespace) -> int:
    """Estimate the external wrench along a flight log (CSV, PX4 ULog, ArduPilot DataFlash, MAVLink tlog)."""
    from ..errors import InputError
    from ..estimator import EstimatorParams
    from ..io import RunFolder
    from ..logs import estimate_file, log_format
    from ..logs import samples as sample_logs

    if args.example is not None:
        if args.example == "list":
            print(sample_logs.listing())
            print(f"\ne.g. vtol-impedance estimate --example px4 --mass {sample_logs.MASS_KG}")
            return 0
        if args.log is not None:
            raise InputError("give a log file or --example NAME, not both")
        log = sample_logs.path(args.example)
        stem = args.example
    else:
        if args.log is None:
            raise InputError("give a log file (CSV, .ulg, .bin, .tlog) or --example NAME (--example list)")
        log = Path(args.log)
        if not log.is_file():
            from ..io import explain_path

            raise InputError(f"cannot read log file {log}: {explain_path(log) or 'not a regular file'}")
        stem = log.stem
    inertia: Any = _floats("--inertia", args.inertia, (3, 9))
    if inertia is not None and len(inertia) == 9:
        inertia = [inertia[0:3], inertia[3:6], inertia[6:9]]
    vehicle = None
    if args.vehicle:
        from ..model import load_preset

        vehicle = load_preset(args.vehicle)
    columns = {}
    for item in args.column:
        role, sep, name = item.partition("=")
        if not sep or not role or not name:
            raise InputError(f"--column takes ROLE=NAME, got {item!r}")
        columns[role.strip()] = name.strip()
    csv_flags = {
        "world": args.world, "body": args.body, "angle_unit": args.angle_unit, "quat_order": args.quat_order,
        "quat_direction": args.quat_direction, "time_unit": args.time_unit, "rate_unit": args.rate_unit,
        "velocity_world": args.velocity_world,
    }  # fmt: skip
    given = {k: v for k, v in csv_flags.items() if v is not None}
    read_options: dict[str, Any] = {"conventions": args.conventions}
    read_options.update({k: v for k, v in (("sysid", args.sysid), ("compid", args.compid)) if v is not None})
    if log_format(log) == "csv":
        read_options.update(given, columns=columns, rotor_speed_unit=args.rotor_speed_unit or "rpm")
    elif given or columns or args.rotor_speed_unit:
        flags = ", ".join(["--" + k.replace("_", "-") for k in given] + (["--column"] if columns else []))
        raise InputError(f"{flags or '--rotor-speed-unit'} appl{'y' if ',' in flags else 'ies'} to CSV logs; "
                         f"a {log_format(log)} log states its own frames and units")  # fmt: skip
    params = EstimatorParams(
        wn=args.wn, zeta=args.zeta, order=args.order, prototype=args.prototype, velocity_delay=args.velocity_delay,
        attitude_delay=args.attitude_delay, rotor_tau=args.rotor_tau,
    )  # fmt: skip
    est = estimate_file(
        log, args.mass, inertia, params,
        vehicle=vehicle,
        rate_hz=args.rate,
        max_gap_s=args.max_gap,
        t_start=args.start,
        t_end=args.end,
        read_options=read_options,
        zero_phase_too=args.zero_phase,
        quiet_segment=_floats("--quiet-segment", args.quiet_segment, 2),
        remove_bias=args.remove_bias,
        hover_thrust=args.hover_thrust,
        hover_segment=_floats("--hover-segment", args.hover_segment, 2),
        torque_scale=_floats("--torque-scale", args.torque_scale, (1, 3)),
        backend=args.backend,
        thrust_from=args.thrust_from,
        thrust_coefficient=args.thrust_coefficient,
        airframe=args.airframe,
        on_ground=args.on_ground,
        force=args.force,
    )  # fmt: skip
    out = Path(args.out) if args.out else _estimate_folder(stem, log)
    flight = est.flight
    with RunFolder(out, command="estimate") as folder:
        from ..analysis.report import write_html
        from ..logs.output import summary, write_estimate

        s = summary(est)
        write_estimate(est, folder.staging, s)
        figs = []
        if not args.no_plots:
            from ..analysis.log_plots import plot_log_inputs, plot_log_wrench

            figs = [
                plot_log_wrench(est, folder.path("wrench.png"), f"{log.name}: estimated external wrench"),
                plot_log_inputs(est, folder.path("inputs.png"), f"{log.name}: inputs at {flight.rate_hz:g} Hz"),
            ]
        notes = [f"WARNING: {w}" for w in est.warnings] + [
            "Force in world NED, moment in body FRD. The estimate contains everything the nominal model misses: "
            "a thrust-map or mass error appears as a constant force along the thrust axis (see the bias).",
            *est.notes,
        ]
        write_html(folder.staging, f"Wrench estimate: {log.name}", tables=_estimate_tables(est, s),
                   figures={"Figures": figs}, notes=notes, config=s["info"])  # fmt: skip
        final = folder.commit(s["info"])
    for w in est.warnings:
        print(f"WARNING: {w}", file=sys.stderr)
    if not args.quiet:
        for c in est.info.get("choices", []):
            print(f"chose: {c}", file=sys.stderr)
        for n in est.notes:
            print(f"note: {n}", file=sys.stderr)
        st = s["stats"]["f_W_N"]
        restarts = int(flight.restart.sum()) - 1
        bridged = sum(1 for g in flight.gaps if g["action"] == "bridged")
        print(f"{len(est.t)} samples at {flight.rate_hz:g} Hz, {est.info['segments']} segment(s) "
              f"({restarts} restart(s), {bridged} bridged dropout(s))")  # fmt: skip
        what = "ground reaction + external force" if est.info.get("on_ground") else "force"
        if s.get("ground_samples_left_out"):
            what += f" in the air ({s['ground_samples_left_out']} samples on the ground left out)"
        print(f"{what}, world NED [N]  mean " + " ".join(f"{v:+.3f}" for v in st["mean"]) + "   max |.| "
              + " ".join(f"{v:.3f}" for v in st["max_abs"]))  # fmt: skip
        sd = (est.info.get("hover_thrust") or {}).get("fz_sd_at_hover_N")
        if sd is not None:
            print(f"vertical force uncertainty from the fitted hover thrust: {sd:.3f} N (1 sd at hover; per sample "
                  "in the column fz_W_N_hover_sd)")  # fmt: skip
        if est.bias is not None:
            print("bias over the quiet segment [N]: " + " ".join(f"{v:+.4f}" for v in est.bias["f_W_N"]))
        verdict = est.info.get("verdict")
        if verdict is not None:
            print(f"verdict: {verdict['outcome']}" + (" (overridden with --force)" if verdict["forced"] else ""))
        print(f"results written to {final}", file=sys.stderr)
    return 0


def _estimate_folder(stem: str, log: Path) -> Path:
    """``results/estimate-<log name>``, or, when that folder holds the estimate of another file of the same
    name, ``results/estimate-<log name>+<hash of this file's path>``: a log never replaces another's."""
    import hashlib

    base = Path(DEFAULT_OUT) / f"estimate-{stem}"
    try:
        other = json.loads((base / "estimate.json").read_text())["info"]["file"]
    except (OSError, ValueError, KeyError, TypeError):
        return base  # no estimate there (or not ours: RunFolder refuses a foreign folder)
    here = Path(log).resolve()
    if Path(other).resolve() == here:
        return base
    return base.with_name(f"{base.name}+{hashlib.sha256(str(here).encode()).hexdigest()[:8]}")


def register(sub: Any) -> None:
    """Add the 'estimate' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser(
        "estimate",
        help="estimate the external wrench along a flight log (CSV, PX4 .ulg, ArduPilot .bin, MAVLink .tlog): "
        "series, figures, report",
        description="Runs the momentum-based estimator (eqs. (6)-(13)) on a flight log, after checking its "
        "conventions against physics. CSV columns: t_s, vx, vy, vz, roll, pitch, yaw (or q0..q3), wx, wy, wz, "
        "thrust_n (or thrust_norm), optional tx, ty, tz and rpm1..rpm8; see docs/guide/logs.md. --example list "
        "shows the sample logs that ship with the package.",
    )
    sp.add_argument("log", nargs="?", default=None, help="a .ulg (PX4), .bin (ArduPilot), .tlog (MAVLink) or .csv file")
    sp.add_argument("--example", default=None, metavar="NAME", help="a sample log that ships with the package "
                    "(--example list)")  # fmt: skip
    sp.add_argument(
        "--vehicle", default=None, help="preset name or vehicle .toml: nominal mass, inertia, rotor geometry"
    )
    sp.add_argument("--mass", type=float, default=None, help="nominal mass, kg (overrides --vehicle and the log)")
    sp.add_argument("--inertia", default=None, help="nominal inertia Ixx,Iyy,Izz or 9 values, kg m^2 (for the moment)")
    g = sp.add_argument_group("conventions (CSV; checked against physics for every format)")
    g.add_argument("--conventions", default="check", choices=["check", "auto", "unchecked"],
                   help="check the declared conventions against physics (default), choose them from the data "
                   "(auto), or skip that check (only that one: a thrust that does not carry the weight is still "
                   "refused; --on-ground for a log on the ground)")  # fmt: skip
    g.add_argument("--world", default=None, choices=["ned", "enu"], help="world frame of the attitude (and velocity)")
    g.add_argument("--velocity-world", default=None, choices=["ned", "enu"], help="world frame of the velocity")
    g.add_argument("--body", default=None, choices=["frd", "flu"], help="body frame of attitude, rates, torques")
    g.add_argument("--angle-unit", default=None, choices=["rad", "deg"], help="Euler angles (and rates)")
    g.add_argument("--rate-unit", default=None, choices=["rad", "deg"], help="body rates (default: --angle-unit)")
    g.add_argument("--quat-order", default=None, choices=["wxyz", "xyzw"], help="order of q0..q3")
    g.add_argument("--quat-direction", default=None, choices=["body-to-world", "world-to-body"])
    g.add_argument("--time-unit", default=None, choices=["s", "ms", "us", "ns"],
                   help="unit of the time column (default: s for t_s, us for timestamp_us)")  # fmt: skip
    g.add_argument("--rotor-speed-unit", default=None, choices=["rpm", "rad/s"], help="CSV rpm1..rpmN (default rpm)")
    g.add_argument("--column", action="append", default=[], metavar="ROLE=NAME",
                   help="read role ROLE (e.g. vx) from column NAME (repeatable); common other names (time, vel_x, "
                   "p/q/r...) are accepted without it (docs: 'CSV columns')")  # fmt: skip
    g = sp.add_argument_group("vehicle of a telemetry log (.tlog)")
    g.add_argument("--sysid", type=int, default=None, metavar="N",
                   help="MAVLink system id of the vehicle to estimate (needed when a tlog holds several)")  # fmt: skip
    g.add_argument("--compid", type=int, default=None, metavar="C",
                   help="its component id (default: the one that sent the most attitude messages)")  # fmt: skip
    g = sp.add_argument_group("time base")
    g.add_argument("--rate", type=float, default=100.0, help="resampling rate, Hz (default 100)")
    g.add_argument("--max-gap", type=float, default=None, metavar="S",
                   help="dropouts up to this long are bridged, longer ones restart the estimator (default: ten "
                   "periods of the log's slowest signal, within 0.5-5 s)")  # fmt: skip
    g.add_argument("--start", type=float, default=None, help="estimate from this time on, s")
    g.add_argument("--end", type=float, default=None, help="estimate up to this time, s")
    g = sp.add_argument_group("thrust and torque")
    g.add_argument("--airframe", default="auto", choices=["auto", "multirotor"],
                   help="auto: a log of a vehicle that is not a multirotor (fixed wing, helicopter, rover, boat, "
                   "submarine) is refused, a VTOL hybrid warned about; multirotor: take it as one anyway")  # fmt: skip
    g.add_argument("--thrust-from", default="auto", choices=["auto", "commands", "rotors"],
                   help="commands, or measured rotor speeds (no rotor lag); auto: rotor speeds when the log has "
                   "them at 20 Hz or more")  # fmt: skip
    g.add_argument("--thrust-coefficient", type=float, default=None, metavar="KT",
                   help="rotor thrust per speed squared, N/(rad/s)^2 (default: calibrated on the log)")  # fmt: skip
    g.add_argument("--hover-thrust", type=float, default=None,
                   help="normalised hover thrust (0..1); default: the log's estimate or its parameter (not at "
                   "the firmware default), else fitted on the hover windows found in the log (their spread "
                   "becomes the column fz_W_N_hover_sd), else refused (docs: 'The hover thrust')")  # fmt: skip
    g.add_argument("--hover-segment", default=None, metavar="T0,T1", help="fit the hover thrust on this hover")
    g.add_argument("--on-ground", action="store_true",
                   help="the vehicle stands on the ground (a bench test): the thrust is not checked against the "
                   "weight and the force is the ground reaction plus the external force")  # fmt: skip
    g.add_argument("--torque-scale", default=None, metavar="KX,KY,KZ",
                   help="N m per unit normalised torque (else from the log's rotor geometry)")  # fmt: skip
    g = sp.add_argument_group("estimator")
    g.add_argument("--wn", type=float, default=10.0, help="bandwidth, rad/s (paper: 10)")
    g.add_argument("--zeta", type=float, default=1.0, help="damping of eq. (10) (paper: 1)")
    g.add_argument("--order", type=int, default=2, help="filter order (2: eq. (10))")
    g.add_argument("--prototype", default="zeta", choices=["zeta", "binomial", "butterworth"])
    g.add_argument(
        "--velocity-delay",
        type=float,
        default=0.0,
        metavar="S",
        help="latency of the logged velocity against the commands, s (the estimator aligns to it; a PX4 log's "
        "timestamp_sample already does)",
    )
    g.add_argument(
        "--attitude-delay",
        type=float,
        default=0.0,
        metavar="S",
        help="latency of the logged attitude and rates against the commands, s",
    )
    g.add_argument(
        "--rotor-tau",
        type=float,
        default=0.0,
        metavar="S",
        help="rotor time constant: the commands pass through a first-order rotor model, s",
    )
    g.add_argument("--zero-phase", action="store_true", help="also the offline forward-backward estimate")
    g.add_argument("--quiet-segment", default=None, metavar="T0,T1", help="report the mean estimate here (bias)")
    g.add_argument("--remove-bias", action="store_true", help="subtract the quiet-segment bias")
    sp.add_argument("--backend", choices=["compiled", "numpy"], default="compiled")
    sp.add_argument("--force", action="store_true",
                    help="estimate even when the log's columns contradict physics (the verdict is refused); the "
                    "override is recorded in the results and printed")  # fmt: skip
    sp.add_argument("--out", default=None, help=f"results folder (default: {DEFAULT_OUT}/estimate-<log name>)")
    sp.add_argument("--no-plots", action="store_true", help="skip figures")
    sp.add_argument("--quiet", action="store_true", help="no notes or progress (warnings are still printed)")
    sp.set_defaults(func=cmd_estimate)
