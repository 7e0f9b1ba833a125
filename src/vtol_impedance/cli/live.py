"""``vtol-impedance live``: the wrench estimate (and the outer loop offboard) over MAVLink."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .common import DEFAULT_OUT, _numbers


def cmd_live(args: argparse.Namespace) -> int:
    """The estimator (and with --control the outer loop) on a vehicle over MAVLink; see docs/guide/live.md."""
    import json as _json

    from ..errors import InputError
    from ..estimator.momentum import EstimatorParams
    from ..live import ControlSettings, EstimatorSettings, LiveSettings, run_live

    control = None
    only_with_control = {
        "--comply": args.comply, "--impedance": args.impedance, "--kp": args.kp, "--dp": args.dp,
        "--fence": args.fence, "--max-speed": args.max_speed, "--tilt-max": args.tilt_max,
        "--tilt-rate": args.tilt_rate, "--watchdog": args.watchdog, "--on-loss": args.on_loss,
        "--handshake-timeout": args.handshake_timeout, "--arm": args.arm or None,
        "--set-guid-options": args.set_guid_options or None,
    }  # fmt: skip
    if args.control is None:
        given = [k for k, v in only_with_control.items() if v is not None]
        if given:
            raise InputError(f"{', '.join(given)} appl{'y' if len(given) > 1 else 'ies'} with --control only")
    else:
        fence = _numbers(args.fence, "--fence", 2)
        comply = _numbers(args.comply, "--comply", 3)
        if comply is None:
            comply = (1.0, 1.0, 0.0) if args.control == "comply" else (0.0, 0.0, 0.0)
        kw = {
            "impedance": _numbers(args.impedance, "--impedance", 3),
            "Kp": args.kp,
            "Dp": args.dp,
            "tilt_max_deg": args.tilt_max,
            "tilt_rate_max_deg_s": args.tilt_rate,
            "max_speed_m_s": args.max_speed,
            "watchdog_s": args.watchdog,
            "on_loss": args.on_loss,
            "handshake_timeout_s": args.handshake_timeout,
        }
        if fence is not None:
            kw["fence_radius_m"], kw["fence_height_m"] = fence
        control = ControlSettings(  # what is not given keeps ControlSettings' default (one place for them)
            variant=args.control, comply=comply, arm=args.arm, set_guid_options=args.set_guid_options,
            **{k: v for k, v in kw.items() if v is not None},
        )  # fmt: skip
    est = EstimatorSettings(
        rate_hz=args.rate, max_gap_s=args.max_gap, backend=args.backend,
        params=EstimatorParams(wn=args.wn, zeta=args.zeta, rotor_tau=args.rotor_tau),
    )  # fmt: skip
    inertia = None
    if args.inertia is not None:
        inertia = _numbers(args.inertia, "--inertia", 3)
    settings = LiveSettings(
        connect=args.connect, autopilot=args.autopilot, system=args.system, vehicle=args.vehicle, mass=args.mass,
        inertia=inertia, hover_thrust=args.hover_thrust, max_thrust=args.max_thrust,
        rotor_constant=args.rotor_constant, estimator=est, duration=args.duration, out=args.out,
        send_back=args.send_back, display=args.display, connect_timeout_s=args.connect_timeout,
        stream_timeout_s=args.stream_timeout, control=control,
    )  # fmt: skip
    if args.backend == "compiled":  # compile (first use) or load the kernels now, not while the link runs
        _warm_live_kernels(quiet=args.display == "none")
    res = run_live(settings, warn=lambda text: print(f"warning: {text}", file=sys.stderr))
    s = res.summary
    print(f"live session ended: {res.end}; {res.ticks} estimates", file=sys.stderr)
    if s.get("control"):  # the hand-over's own line: the same words as the screen and live.json
        print(f"control: {s['control']['text']} (exit code {res.exit_code})", file=sys.stderr)
    if res.folder is not None:
        print(f"recorded to {res.folder} (flight.tlog, estimate.csv, live.json)", file=sys.stderr)
    if args.json:
        print(_json.dumps(s, indent=1, default=str))
    return res.exit_code


def _warm_live_kernels(quiet: bool) -> None:
    """One estimator sample on the compiled kernels: the first use after an install or an upgrade compiles
    them (tens of seconds), which must happen before the session's clocks (connect timeout, duration) run."""
    import numpy as np

    from ..compiled import kernels_cached
    from ..runtime import Estimator

    if not quiet and not kernels_cached():
        print("compiling the estimator's kernels (first use only, cached on disk) ...", file=sys.stderr)
    z = np.zeros(3)
    Estimator(1.0, [0.01, 0.01, 0.02], 0.02).step(z, z, 9.81, z, omega_B=z)


def register(sub: Any) -> None:
    """Add the 'live' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser(
        "live",
        help="the wrench estimate live from a vehicle over MAVLink (and with --control the outer impedance loop)",
        description="Connects over MAVLink (pymavlink addresses), asks for the streams the estimator needs, shows the "
        "estimated external force and moment on one steady screen, and records the flight (flight.tlog, "
        "estimate.csv, live.json) in a run folder. With --control it flies the outer loop offboard "
        "(SET_ATTITUDE_TARGET) with a handshake, fence, limits and a watchdog. See docs/guide/live.md.",
    )
    sp.add_argument("--connect", required=True, metavar="ADDRESS",
                    help="udpin:HOST:PORT (listen, e.g. udpin:127.0.0.1:14550), udpout:HOST:PORT, tcp:HOST:PORT, "
                    "or a serial device /dev/ttyUSB0,57600")  # fmt: skip
    sp.add_argument("--system", type=int, default=None, help="the vehicle's system id (default: the first heard)")
    sp.add_argument("--autopilot", default="auto", choices=["auto", "px4", "ardupilot"],
                    help="its message set (default: from its heartbeat)")  # fmt: skip
    sp.add_argument("--vehicle", default="pelican", help="preset or vehicle .toml: nominal mass, inertia, rotors")
    sp.add_argument("--mass", type=float, default=None, help="nominal mass, kg (overrides --vehicle)")
    sp.add_argument("--inertia", default=None, metavar="IXX,IYY,IZZ", help="nominal inertia, kg m^2")
    g = sp.add_argument_group("thrust in newtons")
    g.add_argument("--hover-thrust", type=float, default=None,
                   help="normalised hover thrust (default: the vehicle's MPC_THR_HOVER / MOT_THST_HOVER)")  # fmt: skip
    g.add_argument("--max-thrust", type=float, default=None, help="total thrust at full throttle, N")
    g.add_argument("--rotor-constant", type=float, default=None, metavar="KF",
                   help="N s^2/rad^2: use the ESCs' rotor speeds (f = KF omega^2)")  # fmt: skip
    g = sp.add_argument_group("estimator")
    g.add_argument("--rate", type=float, default=50.0, help="estimator rate and requested stream rate, Hz (50)")
    g.add_argument("--wn", type=float, default=10.0, help="bandwidth of eq. (10), rad/s (paper: 10)")
    g.add_argument("--zeta", type=float, default=1.0, help="damping of eq. (10) (paper: 1)")
    g.add_argument("--rotor-tau", type=float, default=0.0, help="rotor time constant the commands pass through, s")
    g.add_argument("--max-gap", type=float, default=0.25, help="a longer gap in a stream restarts the estimator, s")
    g.add_argument("--backend", choices=["compiled", "numpy"], default="compiled")
    g = sp.add_argument_group("offboard control")
    g.add_argument("--control", nargs="?", const="pdc", default=None, choices=["pdc", "comply"],
                   help="fly the outer loop: pdc (reject: PD + estimate) or comply (yield on --comply)")  # fmt: skip
    g.add_argument("--comply", default=None, metavar="X,Y,Z", help="comply fraction per world axis (comply: 1,1,0)")
    g.add_argument("--impedance", default=None, metavar="M,D,K", help="comply's M_d kg, D_d N s/m, K_d N/m (2,6,5)")
    g.add_argument("--kp", type=float, default=None, help="position stiffness Kp, N/m (4; the paper's 16 is too "
                   "fast for an autopilot's attitude interface, docs/guide/live.md)")  # fmt: skip
    g.add_argument("--dp", type=float, default=None, help="position damping Dp, N s/m (5; paper: 12)")
    g.add_argument("--fence", default=None, metavar="R,H", help="fence around the hold point: radius, height (1,0.5) m")
    g.add_argument("--max-speed", type=float, default=None, help="speed fence, m/s (1.5)")
    g.add_argument("--tilt-max", type=float, default=None, help="largest roll/pitch set-point, deg (20)")
    g.add_argument("--tilt-rate", type=float, default=None, help="largest roll/pitch set-point rate, deg/s (180)")
    g.add_argument("--watchdog", type=float, default=None, help="no telemetry tick for this long hands back, s (0.25)")
    g.add_argument("--on-loss", default=None, choices=["hold", "land"], help="what the watchdog hands back to (hold)")
    g.add_argument("--handshake-timeout", type=float, default=None, help="each handshake step's time limit, s (3)")
    g.add_argument("--arm", action="store_true", help="arm a disarmed vehicle (else it must be armed and flying)")
    g.add_argument("--set-guid-options", action="store_true",
                   help="ArduCopter: set GUID_OPTIONS bit 3 (SET_ATTITUDE_TARGET thrust as thrust, not a climb rate) "
                   "for the session, restored at the end (else a clear bit refuses --control)")  # fmt: skip
    sp.add_argument("--duration", type=float, default=None, help="end after this many seconds (default: Ctrl-C)")
    sp.add_argument("--out", default=None, help=f"run folder (default: {DEFAULT_OUT}/live-<date>-<time>)")
    sp.add_argument("--send-back", action="store_true",
                    help="send the estimate as NAMED_VALUE_FLOAT fx..tz and DEBUG_VECT f_hat_W (10 Hz)")  # fmt: skip
    sp.add_argument("--display", default="auto", choices=["auto", "tty", "plain", "none"],
                    help="steady screen (tty), a line every 2 s (plain) or none; auto: tty on a terminal")  # fmt: skip
    sp.add_argument("--connect-timeout", type=float, default=10.0, help="wait this long for a heartbeat, s")
    sp.add_argument("--stream-timeout", type=float, default=3.0, help="wait this long for the streams, s")
    sp.add_argument("--json", action="store_true", help="print the session summary (live.json) on stdout")
    sp.set_defaults(func=cmd_live)
