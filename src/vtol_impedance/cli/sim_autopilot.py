"""``vtol-impedance sim-autopilot``: a simulated autopilot behind a MAVLink endpoint."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .common import _load_spec, _numbers


def _sim_event(text: str) -> tuple[float, str, str]:
    from ..errors import InputError

    parts = str(text).split(",")
    try:
        if len(parts) != 3:
            raise ValueError
        return float(parts[0]), parts[1].strip(), parts[2].strip()
    except ValueError:
        raise InputError(
            f"--event is T,KIND,ARG (T simulated s; KIND mode, stop or clock), e.g. 8,mode,POSCTL; got {text!r}"
        ) from None


def cmd_sim_autopilot(args: argparse.Namespace) -> int:
    """A simulated autopilot (the project's simulator) behind a MAVLink endpoint."""
    import threading

    from ..live.autopilot import Impairments, SimAutopilot, SimSettings

    spec, _ = _load_spec(args.scenario, args.set, None, args.ideal)
    from ..errors import InputError

    inject_at = None
    if args.inject_at is not None:
        parts = str(args.inject_at).split(",")
        try:
            if len(parts) not in (1, 2):
                raise InputError("")
            inject_at = _numbers(args.inject_at, "--inject-at", len(parts))
        except InputError:
            raise InputError(
                f"--inject-at is T_ON or T_ON,T_OFF in simulated seconds (finite numbers), got {args.inject_at!r}"
            ) from None
    on, off = (inject_at[0], inject_at[1] if len(inject_at) > 1 else float("inf")) if inject_at else (0.0, float("inf"))
    settings = SimSettings(
        connect=args.connect, autopilot=args.autopilot, speed=args.speed, duration=args.duration,
        inject_force_W=_numbers(args.inject_force, "--inject-force", 3) or (0.0, 0.0, 0.0),
        inject_torque_B=_numbers(args.inject_torque, "--inject-torque", 3) or (0.0, 0.0, 0.0),
        inject_on=on, inject_off=off,
        impairments=Impairments(args.loss, args.duplicate, args.reorder, args.latency, args.seed or 0),
        no_streams=tuple(args.no_stream), events=tuple(_sim_event(e) for e in args.event), system=args.system,
        control_rate=args.control_rate,
        plant_rate=args.plant_rate,
    )  # fmt: skip
    sim = SimAutopilot(spec, settings)
    if not args.quiet:
        print(
            f"simulated {sim.profile.name} autopilot flying {spec.name} (system {settings.system}) on "
            f"{sim.address.text}, hovering at {sim.hold_W.tolist()} m NED in {sim.mode}; Ctrl-C to stop",
            file=sys.stderr,
        )
    if settings.duration is None and sim.dist.items and sim.series_end_s < 3600.0:
        print(
            f"note: the disturbances' random series are drawn for the first {sim.series_end_s:.0f} simulated s "
            f"at {settings.plant_rate:g} Hz and hold their last value after that (give --duration to size them)",
            file=sys.stderr,
        )
    done = threading.Event()
    out: dict[str, Any] = {}

    def fly() -> None:
        try:
            out["summary"] = sim.run()
        except BaseException as exc:  # reported by the main thread
            out["error"] = exc
        finally:
            done.set()

    th = threading.Thread(target=fly, name="sim-autopilot", daemon=True)
    th.start()
    try:
        while not done.wait(2.0):
            if not args.quiet:
                p = sim.history[-1][1] if sim.history else sim.hold_W
                print(f"  t {sim.t:7.1f} s  {sim.mode:<12} p_W [{p[0]:+.3f} {p[1]:+.3f} {p[2]:+.3f}] m  "
                      f"set-points {sim.stats['setpoints']}", file=sys.stderr)  # fmt: skip
    except KeyboardInterrupt:
        sim.stop()
        th.join(5.0)
    if "error" in out:
        raise out["error"]
    s = out.get("summary") or sim.summary()
    lat = s.get("setpoint_latency_ms")
    print(f"simulated {s['simulated_s']:.1f} s; final mode {s['mode']}; set-points received {s['setpoints']}"
          + (f", their age on arrival {lat['mean']:.1f} ms mean, {lat['max']:.1f} ms max" if lat else ""),
          file=sys.stderr)  # fmt: skip
    heard = s.get("heard") or {}
    print("heard: " + (", ".join(f"system/component {k} ({n} packets)" for k, n in heard.items()) or "nothing"),
          file=sys.stderr)  # fmt: skip
    if s["behind_real_time_s"] > 0:
        print(
            f"warning: the computer fell {s['behind_real_time_s']:.1f} s behind --speed {args.speed:g}", file=sys.stderr
        )
    if s["failure"] is not None:
        f = s["failure"]
        print(f"error: the simulated vehicle failed at {f['time']:.2f} s ({f['reason']}); the run stopped there",
              file=sys.stderr)  # fmt: skip
        return 1
    return 0


def register(sub: Any) -> None:
    """Add the 'sim-autopilot' sub-command(s) to ``sub`` (argparse's sub-parsers)."""
    sp = sub.add_parser(
        "sim-autopilot",
        help="a simulated autopilot (this simulator, PX4 or ArduPilot messages) behind a MAVLink endpoint",
        description="Flies a scenario's true vehicle and disturbances with its own position hold, streams what PX4 "
        "(or ArduCopter) would, answers what MAVSDK, MAVProxy and QGroundControl-like ground stations ask (home, "
        "global position, parameters, takeoff, land), flies SET_ATTITUDE_TARGET in OFFBOARD (ArduCopter GUIDED, "
        "GUIDED_NOGPS, thrust read as GUID_OPTIONS says) with its own attitude loop, and can inject a known "
        "wrench, packet loss, repeats, reordering and latency. Try 'live' against it; the guide lists what it "
        "refuses.",
    )
    sp.add_argument("scenario", help="registered name (see 'list') or a .toml scenario file, e.g. case-b-fan")
    sp.add_argument("--connect", required=True, metavar="ADDRESS",
                    help="where to send, e.g. udpout:127.0.0.1:14550 (where 'live' listens)")  # fmt: skip
    sp.add_argument("--autopilot", default="px4", choices=["px4", "ardupilot"],
                    help="whose messages, modes and parameters (ardupilot: ArduCopter)")  # fmt: skip
    sp.add_argument("--speed", type=float, default=1.0, help="simulated seconds per second (faster than real time)")
    sp.add_argument("--duration", type=float, default=None, help="simulated seconds (default: until Ctrl-C)")
    sp.add_argument("--inject-force", default=None, metavar="FX,FY,FZ", help="a known force, N, world NED")
    sp.add_argument("--inject-torque", default=None, metavar="TX,TY,TZ", help="a known moment, N m, body FRD")
    sp.add_argument("--inject-at", default=None, metavar="T_ON[,T_OFF]", help="when the injection acts, simulated s")
    sp.add_argument("--loss", type=float, default=0.0, help="probability a packet is lost (each way)")
    sp.add_argument("--duplicate", type=float, default=0.0, help="probability a packet is sent twice")
    sp.add_argument("--reorder", type=float, default=0.0, help="probability a packet swaps with the next")
    sp.add_argument("--latency", type=float, default=0.0, help="delay of every packet, s (each way)")
    sp.add_argument("--no-stream", action="append", default=[], metavar="MESSAGE",
                    help="a message this autopilot never sends (repeatable), e.g. LOCAL_POSITION_NED")  # fmt: skip
    sp.add_argument("--event", action="append", default=[], metavar="T,KIND,ARG",
                    help="at simulated time T: mode (a pilot switches to mode ARG, one it flies, e.g. 8,mode,POSCTL), "
                    "stop "
                    "(stream ARG stops, e.g. 6,stop,LOCAL_POSITION_NED) or clock (the clock jumps ARG s, "
                    "e.g. 5,clock,-100)")  # fmt: skip
    sp.add_argument("--system", type=int, default=1, help="its MAVLink system id")
    sp.add_argument("--control-rate", type=float, default=50.0, help="its own controller's rate, Hz")
    sp.add_argument("--plant-rate", type=float, default=100.0, help="the plant's RK4 rate, Hz")
    sp.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scenario value")
    sp.add_argument("--ideal", action="store_true", help="the ideal plant and sensors (no lag, no noise)")
    sp.add_argument("--seed", type=int, default=None, help="seed of the link's impairments")
    sp.add_argument("--quiet", action="store_true", help="no status lines")
    sp.set_defaults(func=cmd_sim_autopilot)
