"""One live session: connect, find the vehicle, ask for the streams, estimate, show, record, and (with
``control``) fly the outer loop, then write the run folder.

Order of a session (each step bounded in time, each failure a :class:`~.link.LiveError` naming the cause):

1. parse the address and open the link; send this tool's heartbeat at 1 Hz;
2. wait for a vehicle's heartbeat (``connect_timeout_s``); lock onto it (or onto ``system``); any other
   system heard is listed and ignored (in ``control``, a second vehicle before the hand-over is refused);
3. ask for the streams with ``MAV_CMD_SET_MESSAGE_INTERVAL`` at the estimator's rate, read the hover thrust
   parameter, exchange ``TIMESYNC`` for the link's latency, and measure what arrives for ``probe_s`` (up to
   ``stream_timeout_s`` when something is missing); choose the source of each role; a missing one is an
   error listing it with the way to get it; ArduCopter's motor outputs need its thrust-curve parameters
   (:meth:`Session.motor_outputs_or_refuse`), else they are refused by name;
4. run: every vehicle message goes to the :class:`~.estimator.LiveEstimator`; each tick is written to
   ``estimate.csv``, shown, optionally sent back (``NAMED_VALUE_FLOAT`` ``fx``..``tz``, ``DEBUG_VECT``
   ``f_hat_W``) and, with ``control``, handed to the :class:`~.control.OffboardController`;
5. end at ``duration``, on Ctrl-C, when control ends, or on a fatal error; hand control back; write
   ``live.json`` and commit the run folder (``flight.tlog``, ``estimate.csv``, ``control.csv``).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO, Any

import numpy as np

from ..errors import InputError, instance, scalar
from ..io import RunFolder, check_folder_path
from ..logs.ardupilot import CURVE_PARAMS, MotorCurve, motor_channels
from ..model.vehicle import check_inertia, load_preset
from .control import ControlSettings, OffboardController, OuterLoop
from .display import Screen, StreamRow, View
from .estimator import CSV_COLUMNS, EstimatorSettings, LiveEstimator, csv_row
from .link import (
    MAV_CMD_SET_MESSAGE_INTERVAL,
    Link,
    LiveError,
    TlogWriter,
    parse_address,
)
from .streams import (
    BY_MAV_AUTOPILOT,
    GATING,
    ROLE_SOURCES,
    AutopilotProfile,
    ThrustMap,
    choose_sources,
    command_role,
    profile,
)

#: Seconds between this tool's heartbeats and TIMESYNC requests.
HEARTBEAT_S = 1.0
TIMESYNC_S = 0.5
#: Longest silence of the vehicle's heartbeat before the link counts as lost (and streams are asked again
#: when it comes back: an autopilot that rebooted forgot them).
LINK_LOST_S = 3.0
#: Send-back rate (NAMED_VALUE_FLOAT, DEBUG_VECT), Hz: enough for a ground station's plot, little bandwidth.
SEND_BACK_HZ = 10.0
#: After the first vehicle's heartbeat, listen this long for others (heartbeats come at 1 Hz).
LISTEN_S = 1.1
POLL_S = 0.005
#: Most messages handled per poll of the running session: the hand-over's checks (the mode request, its
#: timeouts, the watchdog, the hold's repeats) run between polls, so a backlog (a busy computer) delays them
#: by at most this many messages (half a second of the four 50 Hz streams), not by the 2000 a poll may read.
POLL_MAX_MESSAGES = 100
#: A stream of the estimate with no usable sample for this long is reported missing, with the reason.
STREAM_MISSING_S = 1.0
#: Window (s) over which a used stream's rate is measured while the session runs.
RATE_WINDOW_S = 2.0
#: A used stream below this fraction of the rate asked for (or of the rate the probe measured, when the
#: vehicle never reached the asked one: a slow radio is not a change) is asked for again.
RATE_LOW_FRACTION = 0.5
#: Seconds after the last request before a stream is asked for again; the wait then doubles while it stays
#: low, up to :data:`REREQUEST_MAX_S` (an autopilot that cannot send faster is not flooded).
REREQUEST_FIRST_S = 2.0
#: Longest wait (s) between two requests of a stream that stays low.
REREQUEST_MAX_S = 30.0
#: A parameter read is retried with back-off: first after :data:`PARAM_FIRST_WAIT_S`, the wait doubling up to
#: :data:`PARAM_MAX_WAIT_S`, for at most :data:`PARAM_READ_WINDOW_S` in all (6 requests: at 0, 0.3, 0.9, 2.1,
#: 4.1 and 6.1 s): a radio that drops a few packets in a row, or a round trip of a second, still reads it.
PARAM_FIRST_WAIT_S = 0.3
PARAM_MAX_WAIT_S = 2.0
PARAM_READ_WINDOW_S = 8.0
#: Fewest samples of a stream in the probe to rank it (a rate from two or three arrivals is noise).
PROBE_MIN_SAMPLES = 5
#: Exit code of a session that produced no estimate at all (the reason is its ``end``).
EXIT_NO_ESTIMATE = 4
#: ArduCopter's guided-mode options and the bit that makes ``SET_ATTITUDE_TARGET.thrust`` a thrust (bit 3, value
#: 8, "SetAttitudeTarget interprets Thrust As Thrust"; else a climb rate).
GUID_OPTIONS = "GUID_OPTIONS"
THRUST_AS_THRUST = 8
#: ``MAV_PARAM_TYPE_INT32``: the type of ``GUID_OPTIONS`` when the vehicle has not said.
MAV_PARAM_TYPE_INT32 = 6


@dataclass(frozen=True)
class LiveSettings:
    """Everything a session needs (see :mod:`vtol_impedance.live` and the README, "Live over MAVLink")."""

    connect: str
    autopilot: str = "auto"
    system: int | None = None
    vehicle: str = "pelican"
    mass: float | None = None
    inertia: tuple[float, ...] | None = None
    hover_thrust: float | None = None
    max_thrust: float | None = None
    rotor_constant: float | None = None
    estimator: EstimatorSettings = field(default_factory=EstimatorSettings)
    duration: float | None = None
    out: str | None = None
    send_back: bool = False
    display: str = "auto"
    connect_timeout_s: float = 10.0
    probe_s: float = 1.0
    stream_timeout_s: float = 3.0
    min_stream_hz: float = 5.0
    control: ControlSettings | None = None

    def __post_init__(self) -> None:
        instance("estimator", self.estimator, EstimatorSettings)
        if self.control is not None:
            instance("control", self.control, ControlSettings)
        parse_address(self.connect)
        if self.autopilot != "auto":
            profile(self.autopilot)
        if self.duration is not None:
            object.__setattr__(self, "duration", scalar("--duration", self.duration, lo=0.0, lo_open=True, hi=1e6))
        # the flag as typed on the command line, and the field as given in Python
        flags = {"connect_timeout_s": "--connect-timeout (connect_timeout_s)",
                 "stream_timeout_s": "--stream-timeout (stream_timeout_s)"}  # fmt: skip
        for name in ("connect_timeout_s", "probe_s", "stream_timeout_s", "min_stream_hz"):
            object.__setattr__(self, name, scalar(flags.get(name, name), getattr(self, name), lo=0.0, lo_open=True,
                                                  hi=3600.0))  # fmt: skip
        if self.out is not None:  # before the link: a session must not wait for a vehicle to learn this
            check_folder_path(self.out)
        if self.hover_thrust is not None and self.max_thrust is not None:
            raise InputError("give --hover-thrust or --max-thrust, not both")
        # the vehicle's numbers are checked here, before the link: after it they would end a live session
        for name, attr, lo, hi in (("--mass (kg)", "mass", 0.0, 1e4), ("--hover-thrust", "hover_thrust", 0.0, 1.0),
                                   ("--max-thrust (N)", "max_thrust", 0.0, 1e6),
                                   ("--rotor-constant (N s^2/rad^2)", "rotor_constant", 0.0, 1.0)):  # fmt: skip
            if getattr(self, attr) is not None:
                object.__setattr__(self, attr, scalar(name, getattr(self, attr), lo=lo, hi=hi, lo_open=True))
        if self.hover_thrust is not None and not self.hover_thrust < 1.0:
            raise InputError(
                f"--hover-thrust is the normalised thrust that holds the vehicle, below 1, got {self.hover_thrust}"
            )
        if self.inertia is not None:
            check_inertia(self.inertia)
        if self.display not in ("auto", "tty", "plain", "none"):
            raise InputError(f"--display must be auto, tty, plain or none, got {self.display!r}")
        if self.system is not None and not 1 <= int(self.system) <= 255:
            raise InputError(f"--system must be in 1..255, got {self.system}")


@dataclass
class LiveResult:
    """What a session did: its run folder, how it ended and the summary written to ``live.json``."""

    folder: Path | None
    end: str
    exit_code: int
    summary: dict[str, Any]
    ticks: int = 0


class _Latency:
    """TIMESYNC round trips: latency = RTT / 2, and the vehicle clock's offset to ``time.monotonic``."""

    def __init__(self) -> None:
        self.rtt_s: list[float] = []
        self.offset_s: float | None = None
        self.ages_s: list[float] = []

    def on_reply(self, ts1_ns: int, tc1_ns: int, now: float) -> None:
        sent = ts1_ns * 1e-9
        rtt = now - sent
        if not 0 <= rtt < 10:
            return
        self.rtt_s.append(rtt)
        del self.rtt_s[:-200]
        off = tc1_ns * 1e-9 - (sent + now) / 2.0  # vehicle clock minus ours
        # the latest exchange with an ordinary round trip (a slow one says little about the offset)
        if self.offset_s is None or rtt <= 2.0 * float(np.median(self.rtt_s)) + 1e-3:
            self.offset_s = off

    @property
    def latency_s(self) -> float | None:
        return float(np.median(self.rtt_s)) / 2.0 if self.rtt_s else None

    def age(self, t_vehicle_s: float, now: float) -> float | None:
        if self.offset_s is None:
            return None
        return now + self.offset_s - t_vehicle_s

    def note_age(self, age: float | None) -> None:
        if age is not None and -1.0 < age < 10.0:
            self.ages_s.append(age)
            del self.ages_s[:-2000]


class Session:
    """The running session (module docstring). Use :func:`run_live`."""

    def __init__(self, settings: LiveSettings, stream: IO[str] | None = None, warn: Any = None) -> None:
        self.s = settings
        self.address = parse_address(settings.connect)
        self.vehicle = load_preset(settings.vehicle)
        self.mass = float(settings.mass) if settings.mass is not None else float(self.vehicle.mass)
        inertia = self.vehicle.inertia if settings.inertia is None else np.asarray(settings.inertia, dtype=float)
        self.inertia_B = np.diag(inertia) if np.ndim(inertia) == 1 else np.asarray(inertia, dtype=float)
        self.screen = Screen(settings.display, stream)
        self.warn = warn or (lambda text: None)
        self.t0 = self.now()
        self.link: Link | None = None
        self.folder: RunFolder | None = None
        self.tlog: TlogWriter | None = None
        self.est: LiveEstimator | None = None
        self.ctrl: OffboardController | None = None
        self.profile: AutopilotProfile | None = None
        self.target: tuple[int, int] | None = None
        self.params: dict[str, float] = {}
        self.param_types: dict[str, int] = {}
        self.guid_options: dict[str, Any] | None = None  # what --control did with ArduCopter's GUID_OPTIONS
        self.motor_curve: MotorCurve | None = None
        self.motor_channels: tuple[int, ...] | None = None
        self.acks: list[tuple[int, str]] = []
        self.latency = _Latency()
        self.events: list[tuple[float, str]] = []
        self.others: dict[int, str] = {}
        self.requested: dict[str, float] = {}
        self.probe_rates: dict[str, float] = {}
        self.sources: dict[str, str] = {}
        self.ticks = 0
        self.first_frame_us = 0
        self._csv: IO[str] | None = None
        self._ctrl_csv: IO[str] | None = None
        self._last_hb_sent = -1e9
        self._last_ts_sent = -1e9
        self._last_send_back = -1e9
        self._last_vehicle_hb: float | None = None
        self._link_lost = False
        self.reconnects = 0
        self.margin_warnings: list[str] = []
        self.proc_s: list[float] = []
        self.end = ""
        # streams: when each role last gave a usable sample, why the latest one was not, which are missing
        self.usable_at: dict[str, float] = {}
        self.unusable: dict[str, str] = {}
        self.missing: dict[str, str] = {}
        self.requested_at: dict[str, float] = {}
        self.rerequests: dict[str, int] = {}
        self._rerequest_wait: dict[str, float] = {}
        self.acks_ignored = 0
        self._est_t0 = 0.0
        self._interval_acks = 0
        self.param_requests: dict[str, list[float]] = {}  # parameter -> request times (s into the session)
        self.written: dict[str, Any] = {}
        self._guid_restore: int | None = None
        self._guid_to_set: int | None = None
        self._warm_up()

    def _warm_up(self) -> None:
        """Load what takes seconds (the compiled kernels, the controller design) before the link opens, so
        that no telemetry waits in the socket while it loads."""
        from ..runtime import Estimator

        e = self.s.estimator
        Estimator(self.mass, self.inertia_B, 1.0 / e.rate_hz, e.params, backend=e.backend).step(
            np.zeros(3), np.zeros(3), self.mass * 9.81, np.zeros(3), omega_B=np.zeros(3)
        )
        self.designed = None
        if self.s.control is not None:
            from ..scenarios.margins import scenario_margins  # noqa: F401  (imports the linear model)
            from ..scenarios.spec import ScenarioSpec, resolved_control

            self.designed = resolved_control(ScenarioSpec(name="live-v1", vehicle=self.s.vehicle))

    # ------------------------------------------------------------------ helpers

    def now(self) -> float:
        return time.monotonic()

    def event(self, text: str) -> None:
        self.events.append((self.now() - self.t0, text))

    def pump(self, seconds: float) -> None:
        """Process the link for ``seconds`` (setup steps)."""
        end = self.now() + seconds
        while True:
            self._housekeeping()
            self.link.poll(POLL_S, self.on_message)  # type: ignore[union-attr]
            if self.now() >= end:
                return

    def _housekeeping(self) -> None:
        now = self.now()
        link = self.link
        assert link is not None
        if now - self._last_hb_sent >= HEARTBEAT_S:
            mav = link.mavlink
            link.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                                    mav.MAV_STATE_ACTIVE, 3))  # fmt: skip
            self._last_hb_sent = now
        if self.target is not None and now - self._last_ts_sent >= TIMESYNC_S:
            link.send(link.mavlink.MAVLink_timesync_message(0, int(now * 1e9)))
            self._last_ts_sent = now

    # ------------------------------------------------------------------ messages

    def on_message(self, msg: Any) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        typ = msg.get_type()
        now = self.now()
        link = self.link
        assert link is not None
        if typ == "HEARTBEAT" and src != self.target:
            peer = link.peers.get(src)
            if peer is not None and peer.is_vehicle and self.target is not None and src[0] != self.target[0]:
                if src[0] not in self.others:
                    name = BY_MAV_AUTOPILOT.get(peer.autopilot)
                    self.others[src[0]] = f"system {src[0]} ({name.name if name else f'autopilot {peer.autopilot}'})"
                    self.event(f"another vehicle on the link: {self.others[src[0]]}; its messages are ignored")
            return
        if src != self.target:
            return
        if typ == "HEARTBEAT":
            self._last_vehicle_hb = now
            if self._link_lost:
                self._link_lost = False
                self.reconnects += 1
                self.event("the vehicle is back: asking for the streams again")
                self.usable_at = {r: now for r in self.usable_at}  # no "missing" for the outage itself
                self.request_streams()
            if self.ctrl is not None:
                peer = link.peers[src]
                self.ctrl.on_heartbeat(peer.armed, peer.custom_mode, now, link)
        elif typ == "COMMAND_ACK":
            from .link import MAV_RESULT

            if not link.ack_is_ours(msg):  # answers another station's command: not ours to act on
                self.acks_ignored += 1
                return
            if int(msg.command) == MAV_CMD_SET_MESSAGE_INTERVAL:
                self._interval_acks += 1
            self.acks.append((int(msg.command), MAV_RESULT.get(int(msg.result), str(msg.result))))
            del self.acks[:-200]
            if self.ctrl is not None:
                self.ctrl.on_ack(msg)
        elif typ == "TIMESYNC":
            if msg.tc1 != 0:
                self.latency.on_reply(int(msg.ts1), int(msg.tc1), now)
            else:  # the vehicle syncs to us: answer
                link.send(link.mavlink.MAVLink_timesync_message(int(now * 1e9), int(msg.ts1)))
        elif typ == "PARAM_VALUE":
            pid = msg.param_id.decode() if isinstance(msg.param_id, bytes) else str(msg.param_id)
            self.params[pid.rstrip("\x00")] = float(msg.param_value)
            self.param_types[pid.rstrip("\x00")] = int(msg.param_type)
        if self.est is None:
            return
        t_arrive = now
        ticks = self._feed(msg, typ, now)
        if typ == "ATTITUDE" or typ == self.sources.get("attitude"):
            t_v = getattr(msg, "time_boot_ms", None)
            if t_v is not None:
                self.latency.note_age(self.latency.age(t_v * 1e-3, now))
        for tick in ticks:
            self.ticks += 1
            self._csv.write(",".join(format(v, ".10g") for v in csv_row(tick)) + "\n")  # type: ignore[union-attr]
            if self.ctrl is not None:
                age = self.latency.age(tick.t_us * 1e-6, self.now())
                if self.ctrl.state == "engaged" and age is not None and age > self.ctrl.s.watchdog_s:
                    self.ctrl.hand_back(f"watchdog: telemetry {age:.3f} s old (stale)", self.now(), link,
                                        self.ctrl.s.on_loss)  # fmt: skip
                before = self.ctrl.commands_sent
                self.ctrl.on_tick(tick, self.now(), link, self.target)
                if self.ctrl.commands_sent > before:
                    self.proc_s.append(self.now() - t_arrive)
                    del self.proc_s[:-2000]
                    c = self.ctrl.last
                    self._ctrl_csv.write(",".join(format(v, ".10g") for v in (  # type: ignore[union-attr]
                        c.t_us * 1e-6, *tick.p_W, *c.p_ref_W, c.thrust_N, c.thrust_norm, *c.eta_d, *c.f_hat_W,
                    )) + f",{self.ctrl.state}\n")  # fmt: skip
            if self.s.send_back and now - self._last_send_back >= 1.0 / SEND_BACK_HZ:
                self._send_back(tick)
                self._last_send_back = now

    def _feed(self, msg: Any, typ: str, now: float) -> list[Any]:
        """Feed the estimator and note, per role, whether the message gave a usable sample, or why not."""
        est = self.est
        assert est is not None
        role = est.decoder.by_message.get(typ)
        if role is None:
            return est.feed(msg)
        c0 = dict(est.counts)
        ticks = est.feed(msg)
        d = est.decoder
        if d.last_rejected is not None:
            where = d.last_rejected
            if d.rejected[where] == 1:
                self.event(f"{where} rejected: {d.why[where]} (each rejection counted in live.json)")
            self.unusable[role] = f"{where} {d.why[where]}"
        elif est.counts["repeated"] > c0["repeated"]:
            self.unusable[role] = f"{typ}'s vehicle time does not advance (a frozen clock?)"
        elif est.counts["late"] > c0["late"]:
            self.unusable[role] = f"{typ}'s vehicle time goes backwards"
        elif est.counts["samples"] > c0["samples"]:
            self.usable_at[role] = now
            self.unusable.pop(role, None)  # a reason given later is about what happens then
            if role in self.missing:
                del self.missing[role]
                self.event(f"the {role} stream ({typ}) is back")
        return ticks

    def watch_streams(self, now: float) -> None:
        """Report a stream missing after :data:`STREAM_MISSING_S` without a usable sample (with the reason), and
        ask again for a used stream arriving below :data:`RATE_LOW_FRACTION` of its requested rate."""
        est, link = self.est, self.link
        if est is None or link is None or self._link_lost:
            return
        for role, msg in self.sources.items():
            if role not in est.buffers or role in self.missing:
                continue
            if now - self.usable_at.get(role, self._est_t0) > STREAM_MISSING_S:
                why = self.unusable.get(role, "nothing arrived")
                self.missing[role] = why
                self.event(f"the {role} stream ({msg}) is missing: no usable sample for {STREAM_MISSING_S:g} s: {why}")
        for msg in set(self.sources.values()):
            hz = self.requested.get(msg)
            wait = self._rerequest_wait.get(msg, REREQUEST_FIRST_S)
            if not hz or now - self.requested_at.get(msg, self._est_t0) < max(wait, RATE_WINDOW_S):
                continue
            measured = link.stats.rate(msg, now, RATE_WINDOW_S)
            # against what the vehicle showed it can send (a link or autopilot slower than asked is not a change)
            expected = min(hz, self.probe_rates.get(msg) or hz)
            if measured >= RATE_LOW_FRACTION * expected:
                self._rerequest_wait.pop(msg, None)
                continue
            mid = link.message_id(msg)
            if mid is None:
                continue
            link.command_long(MAV_CMD_SET_MESSAGE_INTERVAL, float(mid), 1e6 / hz)
            self.requested_at[msg] = now
            self.rerequests[msg] = self.rerequests.get(msg, 0) + 1
            self._rerequest_wait[msg] = min(2.0 * wait, REREQUEST_MAX_S)
            self.event(f"{msg} arrives at {measured:.1f} Hz, under half the {expected:.3g} Hz it came at (asked: "
                       f"{hz:g} Hz; another ground station lowered it?): asked for {hz:g} Hz again")  # fmt: skip

    def no_estimate_reason(self) -> str:
        """Why a session produced no tick: each stream's latest problem, the clock's jumps."""
        why_by_role = {**self.missing, **self.unusable}
        parts = [f"{role} ({self.sources.get(role, '?')}): {why}" for role, why in sorted(why_by_role.items())]
        est = self.est
        if est is not None and est.counts["clock_jumps"]:
            parts.append(f"the vehicle clock jumped {est.counts['clock_jumps']} times")
        if not parts:
            parts.append("the streams gave no sample for the estimate")
        return "no estimate was produced: " + "; ".join(parts)

    def _send_back(self, tick: Any) -> None:
        link = self.link
        mav = link.mavlink  # type: ignore[union-attr]
        ms = int(tick.t_us // 1000) % 2**32
        values = [*tick.f_hat_W, *tick.tau_hat_B]
        for name, v in zip((b"fx", b"fy", b"fz", b"tx", b"ty", b"tz"), values, strict=True):
            if np.isfinite(v):
                link.send(mav.MAVLink_named_value_float_message(ms, name, float(v)))  # type: ignore[union-attr]
        link.send(mav.MAVLink_debug_vect_message(b"f_hat_W", int(tick.t_us), *map(float, tick.f_hat_W)))  # type: ignore[union-attr]

    # ------------------------------------------------------------------ setup

    def open(self) -> None:
        s = self.s
        out = Path(s.out) if s.out else Path("results") / _dt.datetime.now().strftime("live-%Y%m%d-%H%M%S")
        self.folder = RunFolder(out, command="live")
        self.tlog = TlogWriter(self.folder.path("flight.tlog"))
        self.link = Link(self.address, s.connect_timeout_s)
        self.link.recorder = self.tlog

    def find_vehicle(self) -> None:
        """The vehicle to work with: ``system`` if given, else the only one heard. A heartbeat comes once a
        second, so after the first one the link is listened to for :data:`LISTEN_S` more to hear the others:
        with several, ``control`` is refused (which one?) and monitoring takes the one sending the most."""
        s = self.s
        link = self.link
        assert link is not None
        end = self.now() + s.connect_timeout_s
        listen_until = None
        while self.now() < end and (listen_until is None or self.now() < listen_until):
            self._housekeeping()
            link.poll(POLL_S)
            found = [p for p in link.vehicles() if s.system is None or p.system == s.system]
            if found and listen_until is None:
                listen_until = self.now() + (0.0 if s.system is not None else LISTEN_S)
        found = [p for p in link.vehicles() if s.system is None or p.system == s.system]
        if not found:
            heard = ", ".join(
                f"system {p.system} (autopilot {p.autopilot}, type {p.mav_type})" for p in link.peers.values()
            )
            what = f"only {heard}, no vehicle" if heard else "nothing"
            if s.system is not None and link.vehicles():
                what = "vehicles " + ", ".join(str(p.system) for p in link.vehicles()) + f", not system {s.system}"
            hint = (
                "is the vehicle (or 'vtol-impedance sim-autopilot') sending to this port?"
                if self.address.listens
                else "is the address right and the vehicle listening there?"
            )
            raise LiveError(
                f"no heartbeat from a vehicle on {self.address.text} within {s.connect_timeout_s:g} s (heard {what}); "
                + hint
            )
        systems = sorted({p.system for p in found})
        if len(systems) > 1 and s.control is not None:
            raise LiveError(
                f"more than one vehicle on the link (systems {', '.join(map(str, systems))}): choose the one to "
                "control with --system"
            )
        counts = link.stats.by_source
        peer = max(found, key=lambda p: (counts.get((p.system, p.component), 0), -p.system))
        self.target = (peer.system, peer.component)
        link.target = self.target
        self._last_vehicle_hb = peer.last_heartbeat
        peer = link.peers[self.target]
        if s.autopilot != "auto":
            self.profile = profile(s.autopilot)
        else:
            self.profile = BY_MAV_AUTOPILOT.get(peer.autopilot)
            if self.profile is None:
                raise LiveError(
                    f"system {peer.system} runs autopilot type {peer.autopilot} (MAV_AUTOPILOT), neither PX4 (12) nor "
                    "ArduPilot (3): say which messages it speaks with --autopilot px4 or --autopilot ardupilot"
                )
        others = [p.system for p in link.vehicles() if p.system != self.target[0]]
        for o in others:
            self.others[o] = f"system {o}"
        self.event(f"vehicle: system {peer.system} component {peer.component}, {self.profile.name}")

    def request_streams(self) -> None:
        link = self.link
        assert link is not None and self.profile is not None
        hz = self.s.estimator.rate_hz
        used = set(self.sources.values())
        self._interval_acks = 0
        for spec in self.profile.streams:
            if not spec.request or (spec.role == "rpm" and self.s.rotor_constant is None):
                continue
            if used and spec.message not in used:  # asking again (a reconnection): only what is used
                continue
            mid = link.message_id(spec.message)
            if mid is None:
                continue
            link.command_long(MAV_CMD_SET_MESSAGE_INTERVAL, float(mid), 1e6 / hz)
            self.requested[spec.message] = hz
            self.requested_at[spec.message] = self.now()

    def release_unused(self) -> None:
        """Give back the streams asked for but not used (interval 0: the autopilot's default): less traffic."""
        link = self.link
        assert link is not None
        used = set(self.sources.values())
        for name in [m for m in self.requested if m not in used]:
            mid = link.message_id(name)
            if mid is not None:
                link.command_long(MAV_CMD_SET_MESSAGE_INTERVAL, float(mid), 0.0)
            del self.requested[name]

    def read_param(self, name: str) -> float | None:
        """One parameter of the vehicle (``PARAM_REQUEST_READ``), retried with back-off: requests at 0, 0.3,
        0.9, 2.1, 4.1 and 6.1 s (:data:`PARAM_FIRST_WAIT_S` doubling up to :data:`PARAM_MAX_WAIT_S`) within
        :data:`PARAM_READ_WINDOW_S`; ``None`` (and an event) when unanswered."""
        link = self.link
        assert link is not None and self.target is not None
        t_next = self.now()  # the schedule is kept from the first request: no poll's lateness accumulates
        t_end = t_next + PARAM_READ_WINDOW_S
        wait = PARAM_FIRST_WAIT_S
        sent = self.param_requests.setdefault(name, [])
        while name not in self.params and self.now() < t_end:
            link.send(
                link.mavlink.MAVLink_param_request_read_message(self.target[0], self.target[1], name.encode(), -1)
            )
            sent.append(self.now() - self.t0)
            t_next = min(t_next + wait, t_end)
            while name not in self.params and self.now() < t_next:
                self.pump(POLL_S)
            wait = min(2.0 * wait, PARAM_MAX_WAIT_S)
        if name not in self.params:
            self.event(f"{name} not read: {len(sent)} requests over {PARAM_READ_WINDOW_S:g} s unanswered")
        return self.params.get(name)

    def read_params(self, names: list[str] | tuple[str, ...]) -> None:
        """Ask for the parameters of ``names`` not yet known, up to 4 times 0.4 s apart (answers land in
        ``self.params``)."""
        link = self.link
        assert link is not None and self.target is not None
        for _ in range(4):
            todo = [n for n in names if n not in self.params]
            if not todo:
                return
            for name in todo:
                link.send(
                    link.mavlink.MAVLink_param_request_read_message(self.target[0], self.target[1], name.encode(), -1)
                )
            self.pump(0.4)

    def motor_outputs_or_refuse(self, sources: dict[str, str]) -> dict[str, str]:
        """ArduCopter's ``SERVO_OUTPUT_RAW``, when it is the thrust source, is read through its thrust curve
        (:class:`~vtol_impedance.logs.ardupilot.MotorCurve`) from the vehicle's parameters; when one is not
        answered the outputs are refused, naming it, and the thrust comes from ``ATTITUDE_TARGET`` (or, when
        that does not arrive either, the session stops with the reason)."""
        assert self.profile is not None
        if self.profile.mav_autopilot != 3 or command_role(sources) != "outputs":
            return sources
        if sources["outputs"] != "SERVO_OUTPUT_RAW":
            return sources
        self.read_params([*CURVE_PARAMS, *(f"SERVO{c}_FUNCTION" for c in range(1, 9))])
        more = ["MOT_BAT_VOLT_MIN"] if self.params.get("MOT_BAT_VOLT_MAX", 0.0) > 0.0 else []
        if not 0 < self.params.get("MOT_PWM_MIN", 1.0) < self.params.get("MOT_PWM_MAX", 2.0):
            more += ["RC3_MIN", "RC3_MAX"]  # ArduCopter's PWM range when MOT_PWM_MIN/MAX are unset
        self.read_params(more)
        try:
            self.motor_curve = MotorCurve.from_params(self.params)
        except InputError as exc:
            rest = {r: m for r, m in sources.items() if r != "outputs"}
            if "thrust" not in rest:
                raise LiveError(f"{exc}, and no other thrust source (ATTITUDE_TARGET) arrives") from None
            self.event(f"motor outputs refused: {exc}; thrust from {rest['thrust']} (no moment)")
            return rest
        n = self.vehicle.n_rotors
        chans = motor_channels(self.params, 8)
        if chans is not None and len(chans) == n:
            self.motor_channels = tuple(chans)
            where = f"motors on channels {', '.join(map(str, chans))} (SERVOn_FUNCTION)"
        else:
            where = f"motors taken as channels 1..{n}: SERVO1..8_FUNCTION name {len(chans or [])} motor(s)"
        self.event(f"SERVO_OUTPUT_RAW read through ArduCopter's thrust curve: {self.motor_curve.describe()}; {where}")
        return sources

    def write_param(self, name: str, value: float) -> float | None:
        """Set one parameter (``PARAM_SET`` with the type the vehicle reported, retried on the schedule of
        :meth:`read_param` until its ``PARAM_VALUE`` echo shows ``value``), then read it back with
        :meth:`read_param`: the value read, or ``None``."""
        link = self.link
        assert link is not None and self.target is not None
        ptype = self.param_types.get(name, MAV_PARAM_TYPE_INT32)
        self.params.pop(name, None)
        t_next = self.now()
        t_end = t_next + PARAM_READ_WINDOW_S
        wait = PARAM_FIRST_WAIT_S
        sent = self.param_requests.setdefault(f"{name} (set)", [])
        while self.params.get(name) != float(value) and self.now() < t_end:
            link.send(link.mavlink.MAVLink_param_set_message(self.target[0], self.target[1], name.encode(),
                                                            float(value), ptype))  # fmt: skip
            sent.append(self.now() - self.t0)
            t_next = min(t_next + wait, t_end)
            while self.params.get(name) != float(value) and self.now() < t_next:
                self.pump(POLL_S)
            wait = min(2.0 * wait, PARAM_MAX_WAIT_S)
        self.params.pop(name, None)  # the echo is not the read-back
        return self.read_param(name)

    def guided_thrust_or_refuse(self) -> None:
        """ArduCopter (GUIDED, GUIDED_NOGPS) reads ``SET_ATTITUDE_TARGET.thrust`` as a climb rate (0.5 holds the
        altitude, 0 and 1 descend and climb at ``WPNAV_SPEED_DN/UP``) unless ``GUID_OPTIONS`` bit 3 (value 8,
        "SetAttitudeTarget interprets Thrust As Thrust") is set: read it; with the bit clear, refuse (before
        anything is sent) or, with ``set_guid_options``, note it for :meth:`apply_guid_options` (the other bits
        kept; restored at the end by :meth:`restore_guid_options`). PX4 reads the thrust as thrust."""
        c = self.s.control
        assert c is not None and self.profile is not None
        if self.profile.mav_autopilot != 3:
            return
        flag = f"bit 3 (value {THRUST_AS_THRUST}, 'SetAttitudeTarget interprets Thrust As Thrust')"
        value = self.read_param(GUID_OPTIONS)
        if value is None:
            raise LiveError(
                f"--control refused before anything was sent: {GUID_OPTIONS} could not be read "
                f"({len(self.param_requests.get(GUID_OPTIONS, []))} requests over {PARAM_READ_WINDOW_S:g} s "
                f"unanswered); its {flag} decides whether ArduCopter reads SET_ATTITUDE_TARGET.thrust as a thrust "
                "or as a climb rate"
            )
        bits = int(value)
        self.guid_options = {"read": bits, "thrust_as_thrust": bool(bits & THRUST_AS_THRUST), "set": None,
                             "restored": None}  # fmt: skip
        if bits & THRUST_AS_THRUST:
            self.event(f"{GUID_OPTIONS} = {bits}: {flag} set, SET_ATTITUDE_TARGET.thrust is a thrust")
            return
        if not c.set_guid_options:
            raise LiveError(
                f"--control refused before anything was sent: {GUID_OPTIONS} is {bits}, its {flag} is clear, so "
                "ArduCopter would read SET_ATTITUDE_TARGET.thrust as a climb rate (0.5 = hold the altitude), not "
                f"the thrust this controller sends; set {GUID_OPTIONS} to {bits | THRUST_AS_THRUST} on the vehicle, "
                "or pass --set-guid-options to set it for this session and restore it at the end"
            )
        self._guid_to_set = bits | THRUST_AS_THRUST

    def apply_guid_options(self) -> None:
        """With ``set_guid_options``, after every other check: set ``GUID_OPTIONS`` bit 3 (the value read with
        the bit added), read it back, and from then on restore the value read on every exit."""
        want = self._guid_to_set
        if want is None or self.guid_options is None:
            return
        bits = self.guid_options["read"]
        flag = f"bit 3 (value {THRUST_AS_THRUST}, 'SetAttitudeTarget interprets Thrust As Thrust')"
        self._guid_restore = bits  # from here on every exit restores it
        got = self.write_param(GUID_OPTIONS, want)
        self.guid_options["set"] = want
        self.guid_options["read_back"] = got
        if got is None or int(got) != want:
            raise LiveError(
                f"--control refused before anything was sent: {GUID_OPTIONS} was set to {want} ({bits} with {flag}) "
                f"but reads back as {got if got is None else int(got)}"
            )
        self.event(f"{GUID_OPTIONS} set to {want} ({bits} with {flag}; read back): restored to {bits} at the end")

    def restore_guid_options(self) -> None:
        """Put back the ``GUID_OPTIONS`` value read before :meth:`apply_guid_options` changed it (every exit
        path of :func:`run_live`), read back; a failure is an event and a warning, never silent."""
        bits = getattr(self, "_guid_restore", None)
        if bits is None or self.link is None or self.guid_options is None:
            return
        self._guid_restore = None
        got = self.write_param(GUID_OPTIONS, bits)
        ok = got is not None and int(got) == bits
        self.guid_options["restored"] = bits if ok else None
        self.guid_options["restore_read_back"] = got
        text = f"{GUID_OPTIONS} restored to {bits} (read back)"
        if not ok:
            text = f"{GUID_OPTIONS} NOT restored: it reads {got} on the vehicle, set it back to {bits} by hand"
        self.event(text)
        if not ok:
            self.warn(text)

    def read_hover(self) -> float | None:
        assert self.profile is not None
        return self.read_param(self.profile.hover_param)

    def probe(self) -> None:
        s = self.s
        link = self.link
        assert link is not None
        # the asked rates start once the vehicle has the requests: wait for its first acknowledgement (a round
        # trip; bounded; one lost ACK of several does not stall it) so that the window does not rank the
        # default rates on a slow link, then rate each stream from its first arrival in the window (a stream
        # that starts late is not diluted by the wait)
        t_ack_end = self.now() + s.stream_timeout_s
        while self._interval_acks == 0 and self.requested and self.now() < t_ack_end:
            self.pump(POLL_S)
        since = self.now()
        self.pump(s.probe_s)
        while True:
            now = self.now()
            el = now - since
            rates = {m: link.stats.rate_since(m, since, now, PROBE_MIN_SAMPLES) for m in list(link.stats.arrivals)}
            sources, missing = choose_sources(rates, s.min_stream_hz, s.rotor_constant is not None)
            if not missing or el >= s.stream_timeout_s:
                break
            self.pump(0.25)
        self.probe_rates = rates
        if missing:
            assert self.profile is not None
            lines = []
            for role in missing:
                msgs = ROLE_SOURCES["thrust"] + ROLE_SOURCES["outputs"] if role == "thrust" else ROLE_SOURCES[role]
                got = ", ".join(f"{m} {rates.get(m, 0.0):.1f} Hz" for m in msgs)
                how = next(
                    (sp.how for sp in self.profile.streams if sp.role in (role, "outputs") and sp.message in msgs), ""
                )
                lines.append(
                    f"{role}: needs {' or '.join(msgs)} at {s.min_stream_hz:g} Hz or more (received: {got}); {how}"
                )
            have = ", ".join(f"{k} {v:.1f} Hz" for k, v in sorted(rates.items()) if v > 0) or "nothing but heartbeats"
            raise LiveError(
                f"the vehicle does not send the streams the estimate needs (asked for at {s.estimator.rate_hz:g} Hz, "
                f"waited {el:.1f} s):\n  " + "\n  ".join(lines) + f"\n  it sends: {have}"
            )
        sources = self.motor_outputs_or_refuse(sources)
        keep = command_role(sources)
        self.sources = {r: m for r, m in sources.items() if r in GATING or r == keep}
        self.release_unused()
        for role in GATING:
            hz = rates.get(sources[role], 0.0)
            if hz < 0.8 * s.estimator.rate_hz:
                self.event(f"{sources[role]} arrives at {hz:.1f} Hz, under the estimator's {s.estimator.rate_hz:g} Hz: "
                           "samples are held (less bandwidth)")  # fmt: skip

    def thrust_map(self) -> ThrustMap:
        s = self.s
        role = command_role(self.sources)
        if role == "rpm":
            kw: dict[str, Any] = {"rotor_constant": s.rotor_constant}
            kw["max_thrust"] = s.max_thrust or float(np.sum(self.vehicle.geometry.f_max))
            if s.hover_thrust is not None:
                kw = {"rotor_constant": s.rotor_constant, "hover": s.hover_thrust}
            return ThrustMap.for_vehicle(self.vehicle, self.mass, **kw)
        kw = {"motor_curve": self.motor_curve, "motor_channels": self.motor_channels} if role == "outputs" else {}
        if s.max_thrust is not None:
            return ThrustMap.for_vehicle(self.vehicle, self.mass, max_thrust=s.max_thrust, **kw)
        hover = s.hover_thrust if s.hover_thrust is not None else self.read_hover()
        if hover is None:
            raise LiveError(
                f"the thrust is normalised (0..1) and the vehicle did not report {self.profile.hover_param}: give "  # type: ignore[union-attr]
                "--hover-thrust (the normalised hover thrust) or --max-thrust (N at full throttle)"
            )
        if not 0.02 < hover < 1.0:
            raise LiveError(f"hover thrust {hover:g} is outside (0.02, 1): give --hover-thrust or --max-thrust")
        return ThrustMap.for_vehicle(self.vehicle, self.mass, hover=hover, **kw)

    def start_estimator(self, tmap: ThrustMap) -> None:
        self.map = tmap
        n = self.vehicle.n_rotors
        self.est = LiveEstimator(self.mass, self.inertia_B, tmap, self.sources, n, self.s.estimator)
        self._est_t0 = self.now()
        assert self.tlog is not None and self.folder is not None
        self.first_frame_us = self.tlog.last_us + 1
        self._csv = open(self.folder.path("estimate.csv"), "w", encoding="utf-8")  # noqa: SIM115
        self._csv.write(",".join(CSV_COLUMNS) + "\n")

    # ------------------------------------------------------------------ control

    def live_spec(self, loop_latency_s: float) -> Any:
        """The scenario the margin check and the outer loop are built from: this vehicle hovering, the
        outer loop's latency as the delay of position and velocity, the attitude loop onboard (2 ms)."""
        from ..scenarios.spec import (
            InteractionSpec,
            PayloadSpec,
            ScenarioSpec,
            TrajectorySpec,
            resolved_control,
        )
        from ..sim.sensors import SensorParams

        c = self.s.control
        assert c is not None
        designed = self.designed or resolved_control(ScenarioSpec(name="live-v1", vehicle=self.s.vehicle))
        p = self.s.estimator.params
        ctrl = replace(
            designed, rate=self.s.estimator.rate_hz, Kp=c.Kp, Dp=c.Dp, estimator_wn=float(p.wn[0]),
            estimator_zeta=float(p.zeta[0]), estimator_order=int(p.order), estimator_prototype=p.prototype,
            estimator_timing=False, tilt_max_deg=c.tilt_max_deg,
        )  # fmt: skip
        M, D, K = c.impedance
        return ScenarioSpec(
            name="live-v1", vehicle=self.s.vehicle, payload=PayloadSpec(mass=0.0, offset_B=(0.0, 0.0, 0.0)),
            trajectory=TrajectorySpec(kind="hover", start_on_ground=False, hover_duration=10.0),
            sensors=SensorParams(0.0, 0.0, loop_latency_s, 0.0, 0.0, 0.002), control=ctrl,
            interaction=InteractionSpec(M=M, D=D, K=K, comply=tuple(float(x) for x in c.comply)),
        )  # fmt: skip

    def start_control(self) -> None:
        """Check what must hold before anything is sent (one vehicle, a latency the margin check can model,
        ArduCopter's ``GUID_OPTIONS``), run the margin check, and start the :class:`~.control.
        OffboardController`. A refusal is a :class:`~.link.LiveError` naming the reason."""
        from ..robust import LoopSizeError, TrimError
        from ..scenarios.margins import scenario_margins, warnings_of
        from ..scenarios.spec import controller_params
        from ..sim.sensors import MAX_DELAY_S

        c = self.s.control
        assert c is not None and self.profile is not None
        if self.others and self.s.system is None:
            raise LiveError(
                f"more than one vehicle on the link (system {self.target[0]} and {', '.join(self.others.values())}): "  # type: ignore[index]
                "choose the one to control with --system"
            )
        lat = self.latency.latency_s
        age = float(np.median(self.latency.ages_s)) if self.latency.ages_s else None
        # the outer loop's delay: a sample's age when it arrives (TIMESYNC offset), the time to compute, and the
        # set-point's way back (half the round trip); without TIMESYNC, one round trip
        proc = 2e-3
        loop_latency = (age + proc + (lat or 0.0)) if age is not None else 2.0 * (lat or 0.0) + proc
        self.loop_latency_assumed_s = loop_latency
        back_ms = (lat or 0.0) * 1e3
        parts = f"twice the {back_ms:.0f} ms one-way latency"
        if age is not None:
            parts = f"telemetry {age * 1e3:.0f} ms old on arrival, {proc * 1e3:.0f} ms computing, {back_ms:.0f} ms back"
        refused = (f"--control refused before anything was sent: the outer loop's latency over this link is "
                   f"{loop_latency * 1e3:.0f} ms ({parts}), ")  # fmt: skip
        hint = "; fly --control over a faster link (a companion computer on the vehicle's serial port)"
        if loop_latency > MAX_DELAY_S:
            raise LiveError(refused + f"more than the {MAX_DELAY_S:g} s the stability-margin check models" + hint)
        self.guided_thrust_or_refuse()  # reads only: a refusal changes nothing on the vehicle
        spec = self.live_spec(loop_latency)
        try:
            reports = scenario_margins(spec, [c.variant])
            self.margin_warnings = warnings_of(reports)
            self.margins = {k: r.summary() for k, r in reports.items()}
        except LoopSizeError as exc:
            raise LiveError(refused + f"more than the stability-margin check can model ({exc})" + hint) from None
        except TrimError as exc:
            self.margin_warnings = [f"no margins ({exc})"]
            self.margins = {}
        for w in self.margin_warnings:
            text = (f"stability margins with the link's latency ({loop_latency * 1e3:.0f} ms in the outer loop) are "
                    f"below the thresholds before the loop closes: {w}")  # fmt: skip
            self.warn(text)
            self.event(text)
        params = controller_params(spec, c.variant)
        loop = OuterLoop(params)
        self.apply_guid_options()
        self.ctrl = OffboardController(c, loop, self.profile, self.map, self.mass, self.s.estimator.rate_hz)
        self.ctrl.start(self.now())
        self._ctrl_csv = open(self.folder.path("control.csv"), "w", encoding="utf-8")  # type: ignore[union-attr]  # noqa: SIM115
        self._ctrl_csv.write(
            "t_s,x_W_m,y_W_m,z_W_m,x_ref_W_m,y_ref_W_m,z_ref_W_m,thrust_cmd_N,thrust_cmd_norm,roll_d_rad,pitch_d_rad,"
            "yaw_d_rad,fx_hat_W_N,fy_hat_W_N,fz_hat_W_N,state\n"
        )

    # ------------------------------------------------------------------ run

    def view(self) -> View:
        link = self.link
        now = self.now()
        v = View(self.address.text, elapsed_s=now - self.t0)
        if link is None:
            return v
        if self.target is not None and self.profile is not None:
            peer = link.peers.get(self.target)
            v.vehicle = f"{self.profile.name} system {self.target[0]}"
            if peer is not None:
                v.mode = f"{self.profile.mode_name(peer.custom_mode)} {'armed' if peer.armed else 'disarmed'}"
                if now - peer.last_heartbeat > LINK_LOST_S:
                    v.mode += f"  NO HEARTBEAT for {now - peer.last_heartbeat:.0f} s"
        est = self.est
        if est is not None and est.last is not None:
            v.t_vehicle_s = est.last.t_us * 1e-6
            v.f_hat_W, v.tau_hat_B, v.segment = est.last.f_hat_W, est.last.tau_hat_B, est.last.segment
            age = self.latency.age(v.t_vehicle_s, now)
            v.tick_age_s = age
        used = set(self.sources.values())
        if self.profile is not None:
            for sp in self.profile.streams:
                measured = link.stats.rate(sp.message, now)
                if sp.message in used or sp.message in self.requested or measured > 0:
                    v.streams.append(StreamRow(sp.message, sp.role, self.requested.get(sp.message), measured,
                                               sp.message in used))  # fmt: skip
        lat = self.latency.latency_s
        v.latency_ms = None if lat is None else lat * 1e3
        v.telemetry_age_ms = float(np.median(self.latency.ages_s[-100:])) * 1e3 if self.latency.ages_s else None
        counts = dict(est.counts) if est is not None else {}
        counts.update(lost=link.stats.lost, duplicates=link.stats.duplicates, bad_data=link.stats.bad_data)
        if est is not None:
            counts["rejected"] = counts.get("rejected", 0) + sum(est.decoder.rejected.values())
            v.rejected = dict(est.decoder.rejected)
        v.counts = counts
        v.missing = [f"{role}: {why}" for role, why in self.missing.items()]
        v.others = list(self.others.values())
        e = self.s.estimator
        v.estimator = (f"eqs. (6)-(13), {e.rate_hz:g} Hz, wn {float(e.params.wn[0]):g} rad/s, zeta "
                       f"{float(e.params.zeta[0]):g}, order {e.params.order}")  # fmt: skip
        if est is not None:
            role = est.command
            if role == "thrust":
                v.commands = f"thrust from {self.sources['thrust']} (x {self.map.full_thrust:.2f} N); no moment"
            elif role == "outputs":
                v.commands = (f"thrust and moment from {self.sources['outputs']} through the mixer (full "
                              f"{self.map.full_thrust:.2f} N)")  # fmt: skip
            else:
                v.commands = f"thrust and moment from {self.sources['rpm']} (k_f {self.map.rotor_constant:g})"
        if self.ctrl is not None:
            v.control = self.ctrl.status_lines(now)
        if self.tlog is not None:
            v.recording = f"{self.folder.final} ({self.tlog.frames} packets)"  # type: ignore[union-attr]
        v.events = [f"{t:6.1f} s {text}" for t, text in self._all_events()[-4:]]
        return v

    def _all_events(self) -> list[tuple[float, str]]:
        ev = list(self.events)
        if self.est is not None:
            ev += [(self.now() - self.t0, text) for _, text in list(self.est.events)[-3:]]
        if self.ctrl is not None:
            ev += [(t - self.t0, text) for t, text in self.ctrl.events]
        return sorted(ev, key=lambda e: e[0])

    def loop(self, stop: Any) -> str:
        s = self.s
        link = self.link
        assert link is not None
        while True:
            now = self.now()
            if stop is not None and stop.is_set():
                return "stopped"
            if s.duration is not None and now - self.t0 >= s.duration:
                return "duration reached"
            self._housekeeping()
            link.poll(POLL_S, self.on_message, POLL_MAX_MESSAGES)
            now = self.now()
            if self._last_vehicle_hb is not None and now - self._last_vehicle_hb > LINK_LOST_S and not self._link_lost:
                self._link_lost = True
                self.event(f"no heartbeat from the vehicle for {LINK_LOST_S:g} s: link lost, waiting for it")
                if self.ctrl is not None:
                    self.ctrl.hand_back(f"link lost: no heartbeat from the vehicle for {LINK_LOST_S:g} s", now, link,
                                        self.ctrl.s.on_loss)  # fmt: skip
            self.watch_streams(now)
            if self.ctrl is not None:
                peer = link.peers.get(self.target)  # type: ignore[arg-type]
                self.ctrl.check(now, link, bool(peer and peer.armed))
                if self.ctrl.done:
                    return f"control ended: {self.ctrl.reason}"
            if self.screen.due(now):
                self.screen.draw(self.view(), now)

    def finish_control(self, reason: str, cause: str = "end") -> None:
        """End control with ``reason`` (a cause of :data:`~.control.CAUSES`) unless it already ended, and wait,
        bounded, for the hand-back: after a mode request the hold is requested and repeated until a heartbeat
        confirms it or its window passes (:class:`~.control.OffboardController`). A second
        interrupt cuts the wait short: the state is then ``lost``, never ``handed_back``."""
        ctrl, link = self.ctrl, self.link
        if ctrl is None or link is None:
            return
        ctrl.hand_back(reason, self.now(), link, "hold", cause=cause)
        end = self.now() + ctrl.handback_window_s + 0.5
        try:
            while not ctrl.done and self.now() < end:
                self._housekeeping()
                link.poll(POLL_S, self.on_message, POLL_MAX_MESSAGES)
                peer = link.peers.get(self.target)  # type: ignore[arg-type]
                ctrl.check(self.now(), link, bool(peer and peer.armed))
        except KeyboardInterrupt:
            ctrl.abandon("a second interrupt cut short the wait for the hold's confirmation", self.now())
        ctrl.abandon(f"not confirmed by a heartbeat within {ctrl.handback_window_s:g} s", self.now())

    def summary(self) -> dict[str, Any]:
        link = self.link
        now = self.now()
        duration = now - self.t0
        streams = []
        if self.profile is not None and link is not None:
            used = set(self.sources.values())
            for sp in self.profile.streams:
                streams.append({
                    "message": sp.message, "role": sp.role, "default_hz": sp.default_hz,
                    "requested_hz": self.requested.get(sp.message),
                    "measured_probe_hz": self.probe_rates.get(sp.message, 0.0),
                    "measured_session_hz": link.stats.by_type.get(sp.message, 0) / max(duration, 1e-9),
                    "used": sp.message in used, "lost_without": sp.lost_without, "how": sp.how,
                })  # fmt: skip
        out: dict[str, Any] = {
            "tool": "vtol-impedance live",
            "address": self.address.text,
            "started_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "duration_s": duration,
            "end": self.end,
            "vehicle": {
                "system_component": list(self.target) if self.target else None,
                "autopilot": self.profile.name if self.profile else None,
                "preset": self.s.vehicle,
                "mass": self.mass,
                "inertia_B": self.inertia_B.tolist(),
            },
            "streams": streams,
            "params": self.params,
            "others": list(self.others.values()),
            "events": [{"t_s": t, "text": text} for t, text in self._all_events()],
            "reconnects": self.reconnects,
            "rejected": self._rejected(),
            "missing_streams": dict(self.missing),
            "stream_rerequests": dict(self.rerequests),
            "acks_for_other_stations": self.acks_ignored,
            "param_requests_s": self.param_requests,
        }
        if self.est is not None:
            out["estimator"] = {
                "mass": self.mass, "inertia_B": self.inertia_B.tolist(), "thrust_map": self.map.to_dict(),
                "effectiveness": self.map.E.tolist(), "sources": self.sources, "n_rotors": self.vehicle.n_rotors,
                "settings": self.s.estimator.to_dict(), "first_frame_us": self.first_frame_us,
                "counts": dict(self.est.counts), "ticks": self.ticks,
            }  # fmt: skip
        if link is not None:
            lat = self.latency
            out["link"] = {
                "latency_ms": None if lat.latency_s is None else lat.latency_s * 1e3,
                "rtt_ms": {"median": float(np.median(lat.rtt_s)) * 1e3, "max": float(np.max(lat.rtt_s)) * 1e3}
                if lat.rtt_s else None,
                "telemetry_age_ms": {"median": float(np.median(lat.ages_s)) * 1e3,
                                     "max": float(np.max(lat.ages_s)) * 1e3}
                if lat.ages_s else None,
                "received": link.stats.received, "sent": link.stats.sent, "lost": link.stats.lost,
                "duplicates": link.stats.duplicates, "damaged": link.stats.bad_data,
            }  # fmt: skip
        if self.ctrl is not None:
            c = self.ctrl
            lat = self.latency
            proc = float(np.median(self.proc_s)) if self.proc_s else None
            age = float(np.median(lat.ages_s)) if lat.ages_s else None
            loop = None if proc is None or age is None or lat.latency_s is None else age + proc + lat.latency_s
            out["control"] = {
                "settings": c.s.to_dict(), **c.record(),
                "commands_sent": c.commands_sent, "max_error_m": c.max_error_m, "guid_options": self.guid_options,
                "events": [{"t_s": t - self.t0, "text": x} for t, x in c.events],
                "margin_warnings": self.margin_warnings, "margins": getattr(self, "margins", {}),
                "loop_latency_assumed_ms": getattr(self, "loop_latency_assumed_s", 0.0) * 1e3,
                "loop_latency_ms": None if loop is None else loop * 1e3,
                "processing_ms": None if proc is None else proc * 1e3,
            }  # fmt: skip
        return out

    def _rejected(self) -> dict[str, Any]:
        """Rejections: by ``MESSAGE.field`` where the field is decoded (count, latest reason), and by the
        estimator (a sample it refused as a whole)."""
        if self.est is None:
            return {"fields": {}, "by_estimator": 0}
        d = self.est.decoder
        return {"fields": {k: {"count": n, "why": d.why[k]} for k, n in d.rejected.items()},
                "by_estimator": self.est.counts["rejected"]}  # fmt: skip

    def close(self, commit: bool) -> Path | None:
        if self.ctrl is not None and self.link is not None and self.screen.mode == "tty":
            with contextlib.suppress(Exception):  # the last screen shows how control ended, as live.json says
                self.screen.draw(self.view(), self.now())
        for fh in (self._csv, self._ctrl_csv):
            if fh is not None:
                fh.close()
        if self.tlog is not None:
            self.tlog.close()
        final = None
        if self.folder is not None:
            if commit:
                summary = self.written = self.summary()
                from ..io import write_text

                write_text(self.folder.path("live.json"), json.dumps(summary, indent=1, default=str))
                final = self.folder.commit({"live": {k: summary.get(k) for k in ("address", "vehicle", "estimator")}})
            self.folder.close()
        if self.link is not None:
            self.link.close()
        self.screen.close()
        return final


def run_live(settings: LiveSettings, stop: Any = None, stream: IO[str] | None = None, warn: Any = None) -> LiveResult:
    """Run one session (module docstring). ``stop``: a ``threading.Event`` that ends it; ``stream``: where the
    display goes (stdout by default); ``warn``: called with each warning's text (the margin check, the
    hand-over's end after an error, a parameter not restored).

    Exit codes in the result, from the hand-over's state (:attr:`~.control.OffboardController.exit_code`)
    with ``control``: 0 the session ended normally (duration, Ctrl-C or a signal, ``stop``, the pilot took
    over) and a heartbeat confirmed the hand-back (or none was needed); 3 control ended by a safety check
    (watchdog, fence, link loss) or a failed handshake, or the hold was not confirmed (``lost``); 4 the
    session produced no estimate at all (its ``end`` says why: each stream's problem). A setup failure
    raises :class:`~.link.LiveError` and writes no run folder; an error while flying hands control back
    first and says how it ended through ``warn``."""
    instance("settings", settings, LiveSettings)
    sess = Session(settings, stream, warn)
    code = 0
    try:
        sess.open()
        sess.find_vehicle()
        sess.request_streams()
        sess.probe()
        sess.start_estimator(sess.thrust_map())
        if settings.control is not None:
            sess.pump(0.3)  # a few ticks first: the hold point and the latency
            sess.start_control()
        try:
            end = sess.loop(stop)
        except KeyboardInterrupt:
            end = "stopped by Ctrl-C"
        except BaseException as exc:  # never leave the vehicle with a dead offboard controller
            with contextlib.suppress(BaseException):
                sess.finish_control(f"error: {exc}", cause="error")
            if sess.ctrl is not None:
                sess.warn(f"control: {sess.ctrl.describe()}")
            raise
        sess.end = end
        sess.finish_control(end, cause="end")
        if sess.ctrl is not None:
            code = sess.ctrl.exit_code
        if sess.ticks == 0:  # nothing estimated: say why, never exit 0
            sess.end = f"{end}; {sess.no_estimate_reason()}"
            sess.event(sess.no_estimate_reason())
            code = code or EXIT_NO_ESTIMATE
    except BaseException:
        with contextlib.suppress(BaseException):
            sess.restore_guid_options()
        sess.close(commit=False)
        raise
    try:
        sess.restore_guid_options()
    except KeyboardInterrupt:  # a second Ctrl-C: say what is left on the vehicle, write the record anyway
        text = f"{GUID_OPTIONS} not restored (interrupted): set it back to {sess.guid_options['read']} by hand"  # type: ignore[index]
        sess.event(text)
        sess.warn(text)
    final = sess.close(commit=True)
    return LiveResult(final, sess.end, code, sess.written, sess.ticks)
