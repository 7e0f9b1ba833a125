"""The offboard hand-over on every exit path, in simulated time (no socket, no wall clock: the result does not
depend on the machine's load).

Two levels:

* **every cause at every 10 ms**: an :class:`~vtol_impedance.live.control.OffboardController` against a scripted
  autopilot (PX4 and ArduPilot: their mode numbers, hold and offboard modes, a processing delay before a mode
  command takes effect and is acknowledged, a link latency each way, a heartbeat at 1 Hz and on each mode
  change), driven as the session drives it (its polling, ``check`` each loop, and the session's own
  :meth:`~vtol_impedance.live.session.Session.finish_control` at the end). Each exit cause is injected at each
  10 ms of the hand-over; after the tool stops, the vehicle processes what is still in flight. Asserted against
  the vehicle's own mode (not the controller's belief): never in the offboard mode without a hold request
  after the last set-point; ``handed_back`` only when the vehicle really ends out of the offboard mode (and,
  for "nothing to hand back", never received a mode request); the exit code as the causes define it.
* **whole sessions** (``run_live`` against a scripted vehicle): the bugs the trials found (a signal 50 ms after
  the autopilot accepted OFFBOARD, a handshake timeout with the request in flight, ``--duration`` while it is
  pending, a changed system id), ArduCopter's ``GUID_OPTIONS``, and the latency beyond the margin check; the
  screen, the command's last line, ``live.json`` and the exit code agree.
"""

from __future__ import annotations

import copy
import io
import json
from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import numpy as np
import pytest
from test_live_telemetry import Clock, Vehicle, patch_session

from vtol_impedance.live import ControlSettings, LiveError, LiveSettings, control, run_live
from vtol_impedance.live.control import MODE_RESEND_MAX_S, MODE_RESEND_S, OffboardController, OuterLoop
from vtol_impedance.live.estimator import EstimatorSettings, Tick
from vtol_impedance.live.link import SOURCE_COMPONENT, SOURCE_SYSTEM, Peer, mavutil
from vtol_impedance.live.session import POLL_S, Session
from vtol_impedance.live.streams import ARDUPILOT, PX4, ThrustMap
from vtol_impedance.model.vehicle import load_preset

MU = mavutil()
MAV = MU.mavlink
DO_SET_MODE = 176
ARM_FLAG = 128
PILOT_MODE = {"PX4": ("POSCTL", "ALTCTL"), "ArduPilot": ("LOITER", "ALT_HOLD")}  # flying in, switched to
VEHICLE = load_preset("pelican")


# --------------------------------------------------------------------------- the controller, every cause


class FlatLoop(OuterLoop):
    """The outer loop replaced by a level hover set-point: the hand-over does not depend on what is flown,
    and the exhaustive runs stay fast."""

    def __init__(self) -> None:  # no controller to compile
        pass

    def reset(self) -> None:
        pass

    def step(self, tick, ref):
        return VEHICLE.mass * 9.81, np.zeros(3), np.zeros(3), False


@dataclass
class Autopilot:
    """A scripted autopilot: a command arrives ``latency`` after it is sent, takes effect ``proc`` later (the
    mode changes, the acknowledgement and a heartbeat leave together, as PX4 and ArduCopter announce a mode
    change), and its answers arrive ``latency`` later. Offboard is refused (temporarily) without a set-point in
    the last 0.5 s, as PX4 does. No failsafe of its own: a vehicle left in offboard stays there, so the test
    sees it."""

    profile: object
    clock: Clock
    latency: float = 0.02
    proc: float = 0.03
    mode: str = ""
    dead_from: float = np.inf  # the link carries nothing (either way) from this time
    fence_at: float = np.inf  # telemetry shows the vehicle 2 m off from this time
    ticks_stop: float = np.inf  # telemetry stops (the watchdog's cause)
    hb_period: float = 1.0
    drop_holds: int = 0  # the first hold (or land) requests the link loses
    inbox: list = field(default_factory=list)  # (time it takes effect, kind, payload)
    outbox: list = field(default_factory=list)  # (arrival time at the tool, kind, payload)
    log: list = field(default_factory=list)  # (time received, kind, payload) from the tool
    modes: list = field(default_factory=list)  # (time, mode)
    next_hb: float = 0.0
    next_tick: float = 0.0
    last_sp: float = -np.inf

    def __post_init__(self) -> None:
        self.mode = self.mode or PILOT_MODE[self.profile.name][0]
        self.modes.append((0.0, self.mode))

    def receive(self, kind: str, payload, t: float) -> None:
        if t >= self.dead_from:
            return
        if kind == "MODE" and self.drop_holds and payload != tuple(map(float, self.profile.mode_command[
                self.profile.offboard])):  # fmt: skip
            self.drop_holds -= 1
            return
        self.inbox.append((t + self.latency, kind, payload))

    def _send(self, kind: str, payload, t: float) -> None:
        if t < self.dead_from:
            self.outbox.append((t + self.latency, kind, payload))

    def _heartbeat(self, t: float) -> None:
        self._send("HEARTBEAT", self.profile.modes[self.mode], t)

    def set_mode(self, mode: str, t: float) -> None:
        if mode != self.mode:
            self.mode = mode
            self.modes.append((t, mode))
            self._heartbeat(t)

    def advance(self, t: float, telemetry: bool = True) -> list:
        for item in sorted([m for m in self.inbox if m[0] <= t], key=lambda m: m[0]):
            self.inbox.remove(item)
            when, kind, payload = item
            self.log.append((when - self.latency, kind, payload))
            if kind == "SET_ATTITUDE_TARGET":
                self.last_sp = when
            elif kind == "MODE":  # processed proc after it arrives
                self.inbox.append((when + self.proc, "MODE_DO", payload))
            elif kind == "MODE_DO":
                name = next(k for k, v in self.profile.mode_command.items() if tuple(map(float, v)) == payload)
                if name == self.profile.offboard and when - self.last_sp > 0.5 + self.proc:
                    self._send("ACK", 1, when)  # temporarily rejected
                else:
                    self.set_mode(name, when)
                    self._send("ACK", 0, when)
        while self.next_hb <= t:
            self._heartbeat(self.next_hb)
            self.next_hb += self.hb_period
        while telemetry and self.next_tick <= t:
            if self.next_tick < self.ticks_stop:
                off = 2.0 if self.next_tick >= self.fence_at else 0.0
                self._send("TICK", (self.next_tick, off), self.next_tick)
            self.next_tick += 0.02
        due = sorted([m for m in self.outbox if m[0] <= t], key=lambda m: m[0])
        self.outbox = [m for m in self.outbox if m[0] > t]
        return due


def hold_after_last_setpoint(sent: list, profile) -> bool:
    """Whether the tool sent a hold (or land) request after its last set-point (``sent``: what it sent)."""
    t_sp = max((t for t, k, _ in sent if k == "SET_ATTITUDE_TARGET"), default=-np.inf)
    wanted = {tuple(map(float, profile.mode_command[m])) for m in (profile.hold, profile.land)}
    return any(k == "MODE" and p in wanted and t >= t_sp for t, k, p in sent)


class FakeLink:
    """What the controller and ``finish_control`` use of a link, over an :class:`Autopilot`."""

    mavlink = MAV

    def __init__(self, ap: Autopilot, clock: Clock) -> None:
        self.ap, self.clock = ap, clock
        self.peers = {(1, 1): Peer(1, 1, ap.profile.mav_autopilot, 2, ARM_FLAG, ap.profile.modes[ap.mode])}
        self.sent: list = []  # (time, kind, payload)

    def send(self, msg) -> None:
        self.sent.append((self.clock.t, msg.get_type(), None))
        self.ap.receive(msg.get_type(), None, self.clock.t)

    def command_long(self, command: int, *params: float) -> None:
        key = (float(params[1]), float(params[2])) if command == DO_SET_MODE else None
        self.sent.append((self.clock.t, "MODE" if key else "COMMAND", key))
        if key:
            self.ap.receive("MODE", key, self.clock.t)

    def poll(self, timeout: float, on_message=None, max_messages: int = 2000) -> int:
        self.clock.t += max(timeout, POLL_S)
        msgs = self.ap.advance(self.clock.t)
        for _, kind, payload in msgs:
            if kind == "HEARTBEAT":
                self.peers[(1, 1)].custom_mode = payload
            on_message(SimpleNamespace(kind=kind, payload=payload))
        return len(msgs)


class MiniSession:
    """The session's side of the controller: message dispatch, as :class:`Session` does it."""

    def __init__(self, ctrl: OffboardController, link: FakeLink, clock: Clock) -> None:
        self.ctrl, self.link, self.clock, self.target = ctrl, link, clock, (1, 1)

    def now(self) -> float:
        return self.clock.t

    def _housekeeping(self) -> None:
        pass

    def on_message(self, m) -> None:
        now = self.clock.t
        if m.kind == "HEARTBEAT":
            peer = self.link.peers[(1, 1)]
            self.ctrl.on_heartbeat(peer.armed, peer.custom_mode, now, self.link)
        elif m.kind == "ACK":
            self.ctrl.on_ack(SimpleNamespace(command=DO_SET_MODE, result=m.payload))
        elif m.kind == "TICK":
            t, off = m.payload
            z = np.zeros(3)
            tick = Tick(int(t * 1e6), 0, np.array([off, 0.0, -1.0]), z, z, z, VEHICLE.mass * 9.81, None, z, z, z)
            self.ctrl.on_tick(tick, now, self.link, self.target)


CAUSES = {  # cause -> its kind (what the exit code follows)
    "signal": "end", "duration": "end", "exception": "error", "watchdog": "safety", "fence": "safety",
    "link_loss": "safety", "pilot": "pilot", "handshake_timeout": "handshake",
}  # fmt: skip


def step(ctrl, link, sess) -> None:
    """One loop of the session: poll the link (5 ms), then ``check``."""
    link.poll(POLL_S, sess.on_message)
    ctrl.check(link.clock.t, link, True)


def handovers(profile, cause: str, grid, timeout: float = 0.5, lead: float = 0.0, **vehicle):
    """For each time of ``grid`` (s on the simulated clock; control starts after ``lead`` s of telemetry),
    one hand-over with ``cause`` injected then: yields (controller, autopilot, link, exit code). The flight up
    to each time is flown once and copied (it is deterministic); from the copy the session's loop is mirrored
    (poll, ``check``, end when control ends or 0.4 s after the cause), then the session's own
    ``finish_control`` runs, then the vehicle processes what is still in flight (for 0.5 s)."""
    clock = Clock()
    ap = Autopilot(profile, clock, **vehicle)
    link = FakeLink(ap, clock)
    tmap = ThrustMap.for_vehicle(VEHICLE, VEHICLE.mass, hover=0.5)
    ctrl = OffboardController(ControlSettings(handshake_timeout_s=timeout), FlatLoop(), profile, tmap, VEHICLE.mass,
                              50.0)  # fmt: skip
    sess = MiniSession(ctrl, link, clock)
    while clock.t < lead - 1e-9:  # the session's setup: telemetry flows before control starts
        link.poll(POLL_S, lambda m: None)
    ctrl.start(clock.t)
    for t_cause in grid:
        while clock.t < t_cause - 1e-9:
            step(ctrl, link, sess)
        yield finish_copy(copy.deepcopy((clock, ap, link, ctrl, sess)), profile, cause)


def finish_copy(flight, profile, cause: str):
    clock, ap, link, ctrl, sess = flight
    t_cause = clock.t
    if cause == "link_loss":
        ap.dead_from = t_cause
    elif cause == "fence":
        ap.fence_at = t_cause
    elif cause == "watchdog":
        ap.ticks_stop = t_cause
    elif cause == "pilot":
        ap.set_mode(PILOT_MODE[profile.name][1], t_cause)
    elif cause == "handshake_timeout":  # it times out now (or 0.1 s, the least, after a later request)
        since = t_cause - ctrl.t_state if ctrl.state == "requesting" else 0.0
        ctrl.s = replace(ctrl.s, handshake_timeout_s=max(0.1, since))
    end = {"signal": "stopped by Ctrl-C", "exception": "error: planted", "duration": "duration reached"}.get(cause)
    t_end = t_cause + 0.4  # the watchdog acts 0.25 s after the last tick
    while end is None:
        if clock.t >= t_end:
            end = "duration reached"
            break
        step(ctrl, link, sess)
        if ctrl.done:
            end = f"control ended: {ctrl.reason}"
    Session.finish_control(sess, end, cause="error" if cause == "exception" else "end")
    t_stop = clock.t
    while clock.t < t_stop + 0.5:  # the vehicle goes on: what is in flight arrives and acts
        clock.t += POLL_S
        ap.advance(clock.t, telemetry=False)
    return ctrl, ap, link, ctrl.exit_code


#: probing (0, 0.2 s), then every 10 ms from 0.4 s: the request at 0.505 s (the first poll after 0.5 s of
#: set-points), its effect at 0.555 s (20 ms each way, 30 ms to act), its heartbeat at 0.575 s, engaged to 0.89 s
GRID = [0.0, 0.2] + [round(0.01 * k, 2) for k in range(40, 90)]


@pytest.mark.parametrize("profile", [PX4, ARDUPILOT], ids=["px4", "ardupilot"])
@pytest.mark.parametrize("cause", list(CAUSES))
def test_every_exit_cause_at_every_10_ms_ends_in_a_hold_request_or_a_true_hand_back(profile, cause, monkeypatch):
    """The property of the hand-over (module docstring), each cause at each 10 ms of :data:`GRID`. The hold's
    window is 0.5 s here (3 s in use; a confirmation takes 0.07 s): what is asserted does not depend on it,
    the run time does."""
    monkeypatch.setattr(control, "HANDBACK_MIN_S", 0.5)
    off = profile.offboard
    seen = set()
    for t_cause, (ctrl, ap, link, code) in zip(GRID, handovers(profile, cause, GRID), strict=True):
        where = f"{cause} at {t_cause:.2f} s: {ctrl.describe()}"
        seen.add((ctrl.state, (ctrl.handback or {}).get("outcome")))
        assert ctrl.state in ("handed_back", "lost"), where
        if ap.mode == off:  # left in offboard: only with a hold request after the last set-point, never "handed back"
            assert hold_after_last_setpoint(link.sent, profile), where
            assert ctrl.state == "lost", where
        mode_requests = [p for _, k, p in link.sent if k == "MODE"]  # sent (a dead link delivers nothing)
        if ctrl.state == "handed_back":
            outcome = ctrl.handback["outcome"]
            if outcome == "not_needed":
                assert not any(k == "MODE" for _, k, _ in link.sent), where
                assert all(m != off for _, m in ap.modes), where
            else:
                assert outcome in ("confirmed", "pilot") and ap.mode == ctrl.handback["confirmed_mode"], where
            if outcome == "confirmed":
                assert ap.mode in (profile.hold, profile.land), where
        if ctrl.mode_requested:  # every end after a mode request asked for the hold (the pilot's switch aside)
            hold = tuple(map(float, profile.mode_command[profile.hold]))
            assert hold in mode_requests or ctrl.handback["outcome"] == "pilot", where
        # no set-point after the hand-over began
        t_end = ctrl.handback["at"]
        assert all(t <= t_end + 1e-9 for t, k, _ in ap.log if k == "SET_ATTITUDE_TARGET"), where
        kind = CAUSES[cause]
        expected = 0 if ctrl.state == "handed_back" and ctrl.cause in ("end", "pilot") else 3
        assert code == expected, where
        if ctrl.state == "handed_back" and kind in ("end", "pilot") and ctrl.cause == kind:
            assert code == 0, where
        if kind in ("safety", "handshake", "error") and ctrl.cause == kind:
            assert code == 3, where
    # the grid reached each phase of the hand-over (else the property says little)
    if cause in ("signal", "duration", "exception"):
        assert {("handed_back", "not_needed"), ("handed_back", "confirmed")} <= seen, seen


def test_the_hold_request_is_repeated_with_back_off_until_a_bounded_time():
    """A vehicle that stops answering while engaged (the link dies at 0.8 s): the watchdog hands back, the hold
    is requested at 0, 0.3, 0.9, 1.9, 2.9 s (MODE_RESEND_S doubling to MODE_RESEND_MAX_S) and the state is
    ``lost`` 3 s after, naming PX4's own failsafe; exit code 3."""
    ((ctrl, ap, link, code),) = handovers(PX4, "link_loss", [0.8], timeout=3.0)
    t = np.array([t for t, k, p in link.sent if k == "MODE" and p == (4.0, 3.0)])
    expected, w, x = [0.0], MODE_RESEND_S, 0.0
    while x + w <= 3.0:
        x += w
        expected.append(x)
        w = min(2 * w, MODE_RESEND_MAX_S)
    np.testing.assert_allclose(t - t[0], expected, atol=2 * POLL_S)
    assert ctrl.state == "lost" and code == 3 and "COM_OF_LOSS_T" in ctrl.describe()
    assert ctrl.handback["outcome"] == "not_confirmed"


def test_a_heartbeat_older_than_the_mode_request_confirms_nothing(monkeypatch):
    """ArduCopter flying in LOITER (its hold mode), heartbeats at 10 Hz, and the link loses the first hold
    request. A stop between the GUIDED_NOGPS request and its effect: heartbeats still showing LOITER arrive
    after the hold request, but they were sent before the vehicle acted on the request. Taken as the
    confirmation, they would end the repeats and claim a hand-back while the vehicle then enters GUIDED_NOGPS."""
    monkeypatch.setattr(control, "HANDBACK_MIN_S", 0.5)
    grid = [round(0.505 + 0.005 * k, 3) for k in range(12)]  # the request at 0.505 s, its effect at 0.555 s
    for t, (ctrl, ap, _, code) in zip(grid, handovers(ARDUPILOT, "signal", grid, hb_period=0.1, drop_holds=1),
                                      strict=True):  # fmt: skip
        where = f"stop at {t:.3f} s: {ctrl.describe()}"
        assert ctrl.state == "handed_back" and ap.mode == "LOITER", where
        assert any(m == "GUIDED_NOGPS" for _, m in ap.modes), where  # the request did act
        assert ctrl.handback["requests"] >= 2 and code == 0, where  # the lost one, and the repeat that worked


# --------------------------------------------------------------------------- whole sessions


class ModeVehicle(Vehicle):
    """:class:`test_live_telemetry.Vehicle` (streams at the rates asked, ``latency_s`` each way) as an armed
    autopilot of ``profile`` flying in ``mode``: it acts on ``DO_SET_MODE`` ``proc_s`` after it arrives
    (acknowledged then; the heartbeat shows the mode at once, or with ``announce=False`` only at its next
    1 Hz beat), answers its hover parameter and, as ArduCopter, ``GUID_OPTIONS`` (``PARAM_SET`` echoed), and
    records when it entered each mode. ``sysid`` is its system id (an event can change it)."""

    def __init__(self, clock, profile=PX4, proc_s: float = 0.03, announce: bool = True, guid_options=None, **kw):
        super().__init__(clock, **kw)
        self.profile, self.proc_s, self.announce = profile, proc_s, announce
        self.mode = PILOT_MODE[profile.name][0]
        self.modes = [(0.0, self.mode)]
        self.guid_options = guid_options
        self.sysid = 1
        self.timers: list = []  # (time, fn)
        self.on_offboard_ack = None  # fn(arrival time of the ACK)
        self.on_mode = None  # fn(vehicle, mode, time) on each mode command acted on

    def _heartbeat(self, t: float) -> None:
        hb = MAV.MAVLink_heartbeat_message(2, self.profile.mav_autopilot, 128 | 1, self.profile.modes[self.mode], 4, 3)
        self._send(hb, t + self.latency_s)

    def _act(self, msg) -> None:
        t = self.clock.t
        typ = msg.get_type()
        if typ == "COMMAND_LONG" and msg.target_system == self.sysid and msg.command == DO_SET_MODE:
            key = (float(msg.param2), float(msg.param3))
            name = next(k for k, v in self.profile.mode_command.items() if tuple(map(float, v)) == key)

            def act(name=name, cmd=msg.command) -> None:
                now = self.clock.t
                if name != self.mode:
                    self.mode = name
                    self.modes.append((now, name))
                    if self.announce:
                        self._heartbeat(now)
                ack = MAV.MAVLink_command_ack_message(cmd, 0, 0, 0, SOURCE_SYSTEM, SOURCE_COMPONENT)
                self._send(ack, now + self.latency_s)
                if self.on_mode is not None:
                    self.on_mode(self, name, now)
                if name == self.profile.offboard and self.on_offboard_ack is not None:
                    self.on_offboard_ack(now + self.latency_s)
                    self.on_offboard_ack = None

            self.timers.append((t + self.proc_s, act))
        elif typ == "COMMAND_LONG" and msg.target_system == self.sysid:
            super()._act(msg)
        elif typ == "PARAM_REQUEST_READ" and msg.target_system == self.sysid:
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            if name == self.profile.hover_param:
                self._send(MAV.MAVLink_param_value_message(name.encode(), 0.5, 9, 1, 0), t + self.latency_s)
            elif name == "GUID_OPTIONS" and self.guid_options is not None:
                self._param_echo(t)
        elif typ == "PARAM_SET" and msg.target_system == self.sysid and self.guid_options is not None:
            self.guid_options = int(msg.param_value)
            self._param_echo(t)

    def _param_echo(self, t: float) -> None:
        self._send(MAV.MAVLink_param_value_message(b"GUID_OPTIONS", float(self.guid_options), 6, 1, 0),
                   t + self.latency_s)  # fmt: skip

    def advance(self, t: float) -> list:
        for when, fn in sorted([x for x in self.timers if x[0] <= t], key=lambda x: x[0]):
            self.timers.remove((when, fn))
            fn()
        for when, fn in list(self.events):
            if when <= t:
                self.events.remove((when, fn))
                fn(self)
        for when, msg in [a for a in self.actions if a[0] <= t]:
            self.actions.remove((when, msg))
            self._act(msg)
        while self.next_hb <= t:
            self._heartbeat(self.next_hb)
            self.next_hb += 1.0
        for name, hz in self.rates.items():
            while hz > 0 and self.next_due[name] <= t:
                self._send(self._stream(name, self.next_due[name]), self.next_due[name] + self.latency_s)
                self.next_due[name] += 1.0 / hz
        due = sorted((a for a in self.pending if a[0] <= t), key=lambda a: a[0])
        self.pending = [a for a in self.pending if a[0] > t]
        return [m for _, m in due]

    def change_system_id(self, sysid: int) -> None:
        self.sysid = sysid
        self.mav = MAV.MAVLink(None, srcSystem=sysid, srcComponent=1)

    def modes_sent(self, after: float = -1.0) -> list:
        """(time, mode) of each ``DO_SET_MODE`` the tool sent."""
        return [(t, _mode_of(self.profile, m)) for t, m in self.sent("COMMAND_LONG", after) if m.command == DO_SET_MODE]


def _mode_of(profile, m) -> str:
    key = (float(m.param2), float(m.param3))
    return next(k for k, v in profile.mode_command.items() if tuple(map(float, v)) == key)


@pytest.fixture
def session(monkeypatch, tmp_path):
    """``fly(duration, control=ControlSettings(...), **vehicle)`` runs ``run_live`` with ``--control`` against a
    :class:`ModeVehicle` in simulated time: ``(result, vehicle, screen text)``."""

    def patch(setup=None, **kw) -> ModeVehicle:
        clock = Clock()
        vehicle = fly.vehicle = ModeVehicle(clock, **kw)
        if setup is not None:
            setup(vehicle)
        fly.flights += 1  # each flight its own folder: a live recording is never replaced
        fly.out = tmp_path / ("run" if fly.flights == 1 else f"run-{fly.flights}")
        patch_session(monkeypatch, fly.out, vehicle, clock)
        return vehicle

    def fly(duration: float, control: ControlSettings | None = None, autopilot: str = "auto", rate=RATE, **kw):
        vehicle = patch(**kw)
        screen = io.StringIO()
        settings = LiveSettings("udpin:127.0.0.1:14550", display="tty", duration=duration, out=str(fly.out),
                                estimator=EstimatorSettings(backend="numpy", rate_hz=rate),
                                control=control or ControlSettings(),
                                autopilot=autopilot)  # fmt: skip
        res = run_live(settings, stream=screen)
        return res, vehicle, screen.getvalue()

    fly.patch = patch
    fly.flights = 0
    fly.out = tmp_path / "run"
    return fly


def last_control_line(screen: str) -> str:
    lines = [ln.replace("\x1b[K", "") for ln in screen.split("\n") if "control: " in ln]
    return lines[-1].split("control: ", 1)[1].split("  [", 1)[0]


def agree(res, screen: str) -> dict:
    """The screen's last control line, live.json's and the exit code: one account."""
    c = res.summary["control"]
    saved = json.loads((res.folder / "live.json").read_text())["control"]
    line = last_control_line(screen)  # the screen cuts its lines at 100 columns
    assert saved["text"] == c["text"] and c["text"].startswith(line) and len(line) > 40, (line, c["text"])
    assert saved["exit_code"] == res.exit_code == c["exit_code"]
    return c


RATE = 25.0  # the estimator's and the streams' (half the default: the same hand-over, half the run time)
RATES = {"ATTITUDE": RATE, "LOCAL_POSITION_NED": RATE, "ATTITUDE_TARGET": RATE}


def test_a_signal_50_ms_after_offboard_was_accepted_asks_for_the_hold(session):
    """The trial's SIGTERM: the autopilot accepted OFFBOARD, no heartbeat has shown it yet (the next one comes
    up to a second later), and the tool is stopped 50 ms after the ACK. Before: "handed_back", exit 0, no hold
    request, the vehicle left in OFFBOARD. Now: the hold is requested and confirmed, the vehicle in AUTO_LOITER."""
    t_stop = []

    def interrupt(v) -> None:
        raise KeyboardInterrupt  # what the CLI makes of SIGTERM

    def setup(v) -> None:
        def on_ack(t_ack: float) -> None:
            t_stop.append(t_ack + 0.05)
            v.events.append((t_ack + 0.05, interrupt))

        v.on_offboard_ack = on_ack

    res, veh, screen = session(20.0, setup=setup, announce=False, latency_s=0.01, rates=RATES)
    assert t_stop, "the autopilot never accepted OFFBOARD"
    entered = [t for t, m in veh.modes if m == "OFFBOARD"]
    assert entered and entered[0] < t_stop[0]
    holds = [t for t, m in veh.modes_sent() if m == "AUTO_LOITER"]
    assert holds and holds[0] >= t_stop[0] - 1e-9  # asked for after the stop
    assert veh.mode == "AUTO_LOITER" and res.end == "stopped by Ctrl-C"
    c = agree(res, screen)
    assert c["state"] == "handed_back" and c["handback"]["outcome"] == "confirmed" and res.exit_code == 0
    assert "HANDED BACK" in c["text"] and "AUTO_LOITER confirmed by the heartbeat" in c["text"]


def test_a_request_in_flight_is_followed_by_a_hold_when_the_handshake_times_out_or_the_duration_ends(session):
    """0.3 s each way. ``--handshake-timeout 0.1``: the tool gives up while its OFFBOARD request is in flight;
    the autopilot then enters OFFBOARD. Before: "set-points stopped, nothing else changed", exit 3, the vehicle
    left in OFFBOARD. Now the hold is requested after it and confirmed (the hold's wait is at least 3 s), exit
    3 (a failed handshake). The same flight again, ended by ``--duration`` 0.1 s after the request: exit 0."""
    slow = {"latency_s": 0.3, "rates": RATES, "proc_s": 0.03}
    res, veh, screen = session(30.0, control=ControlSettings(handshake_timeout_s=0.1), **slow)
    (t_req,) = [t for t, m in veh.modes_sent() if m == "OFFBOARD"]
    holds = [t for t, m in veh.modes_sent() if m == "AUTO_LOITER"]
    assert holds and holds[0] > t_req
    assert [m for _, m in veh.modes] == ["POSCTL", "OFFBOARD", "AUTO_LOITER"], veh.modes
    c = agree(res, screen)
    assert c["state"] == "handed_back" and c["cause"] == "handshake" and res.exit_code == 3
    assert "did not enter OFFBOARD within 0.1 s" in c["text"] and "AUTO_LOITER confirmed" in c["text"]
    # the same flight (deterministic) ended by --duration while the request is pending
    res, veh, screen = session(t_req + 0.1, **slow)
    assert [t for t, m in veh.modes_sent() if m == "OFFBOARD"] == [t_req]
    assert [m for _, m in veh.modes] == ["POSCTL", "OFFBOARD", "AUTO_LOITER"], veh.modes
    c = agree(res, screen)
    assert res.end == "duration reached" and c["state"] == "handed_back" and res.exit_code == 0
    assert c["handback"]["outcome"] == "confirmed" and c["cause"] == "end"


def test_after_a_system_id_change_every_account_says_lost(session, capsys):
    """The vehicle reboots with system id 2 one second after entering OFFBOARD: its telemetry and heartbeats
    now come from another system (listed, ignored); the watchdog hands back, the hold requests go unanswered.
    Before, the screen said "handed back" while live.json said "not confirmed within 3 s". Now the screen, the
    command's last line, live.json and the exit code all say lost."""
    from vtol_impedance.cli import main

    def reboot(v, mode, t) -> None:
        if mode == "OFFBOARD":
            v.events.append((t + 1.0, lambda v: v.change_system_id(2)))

    session.patch(setup=lambda v: setattr(v, "on_mode", reboot), rates=RATES)
    out = session.out
    code = main(["live", "--connect", "udpin:127.0.0.1:14550", "--control", "--duration", "30", "--display", "tty",
                 "--backend", "numpy", "--rate", str(RATE), "--out", str(out)])  # fmt: skip
    captured = capsys.readouterr()
    saved = json.loads((out / "live.json").read_text())
    c = saved["control"]
    assert code == 3 == c["exit_code"] and c["state"] == "lost" and c["handback"]["outcome"] == "not_confirmed"
    assert "watchdog" in c["reason"] and "AUTO_LOITER not confirmed by a heartbeat within 3 s" in c["text"]
    assert f"control: {c['text']} (exit code 3)" in captured.err
    line = last_control_line(captured.out)
    assert line.startswith("LOST") and c["text"].startswith(line)
    assert "HANDED BACK" not in line and any("system 2" in o for o in saved["others"])


def _nothing_flown(veh) -> None:
    sent = {m.get_type() for _, m in veh.received}
    assert "SET_ATTITUDE_TARGET" not in sent and "PARAM_SET" not in sent
    assert not veh.modes_sent()


def test_ardupilot_control_is_refused_before_anything_is_sent_while_guid_options_bit_3_is_clear(session):
    """ArduCopter reads SET_ATTITUDE_TARGET.thrust as a climb rate unless GUID_OPTIONS bit 3 (8) is set:
    GUID_OPTIONS = 1 is refused, naming the parameter, its value, the flag and the way out; nothing sent. An
    unanswered GUID_OPTIONS is refused naming it."""
    with pytest.raises(LiveError) as exc:
        session(30.0, profile=ARDUPILOT, guid_options=1, rates=RATES)
    text = str(exc.value)
    for words in ("GUID_OPTIONS is 1", "bit 3 (value 8", "SetAttitudeTarget interprets Thrust As Thrust",
                  "climb rate", "--set-guid-options", "refused before anything was sent"):  # fmt: skip
        assert words in text, words
    _nothing_flown(session.vehicle)
    with pytest.raises(LiveError, match="GUID_OPTIONS could not be read") as exc:
        session(30.0, profile=ARDUPILOT, guid_options=None, rates=RATES)
    _nothing_flown(session.vehicle)


def test_set_guid_options_sets_bit_3_keeping_the_others_and_restores_them_at_the_end(session):
    res, veh, screen = session(5.0, control=ControlSettings(set_guid_options=True), profile=ARDUPILOT,
                               guid_options=1, rates=RATES)  # fmt: skip
    values = [int(m.param_value) for _, m in veh.received if m.get_type() == "PARAM_SET"]
    assert values == [9, 1] and veh.guid_options == 1  # 1 | 8 for the session, then 1 again
    t_set, t_restore = [t for t, m in veh.received if m.get_type() == "PARAM_SET"]
    sp = [t for t, m in veh.received if m.get_type() == "SET_ATTITUDE_TARGET"]
    assert sp and t_set < sp[0] and sp[-1] < t_restore  # set before the first set-point, restored after the last
    c = agree(res, screen)
    assert c["guid_options"]["read"] == 1 and c["guid_options"]["set"] == 9 and c["guid_options"]["restored"] == 1
    assert [m for _, m in veh.modes] == ["LOITER", "GUIDED_NOGPS", "LOITER"] and res.exit_code == 0


def test_a_loop_latency_beyond_the_margin_model_refuses_control_before_anything_is_sent(session, monkeypatch):
    """At 50 Hz, 0.39 s each way (no TIMESYNC age: twice that plus 2 ms, 0.782 s in the outer loop) is 40
    control periods of delay, each a line of six states: 16 + 6 (40 + 1) = 262 > 250 states. Before: exit 2
    with "the linearised loop would have 322 states" where the guide said it warns; now a refusal naming the
    latency and its parts. 0.6 s each way (1.202 s) is beyond the 1 s the check models at all. Nothing sent."""
    from vtol_impedance.live import session as session_module

    fast = {"ATTITUDE": 50.0, "LOCAL_POSITION_NED": 50.0, "ATTITUDE_TARGET": 50.0}
    for one_way, words in ((0.39, ("782 ms", "262 states")), (0.6, ("1202 ms", "more than the 1 s"))):
        monkeypatch.setattr(session_module._Latency, "latency_s", property(lambda self, x=one_way: x))
        with pytest.raises(LiveError) as exc:
            session(30.0, rate=50.0, rates=fast)
        text = str(exc.value)
        assert "--control refused before anything was sent" in text and all(w in text for w in words), text
        _nothing_flown(session.vehicle)


def test_an_error_while_engaged_hands_back_first_and_says_how_it_ended(session, monkeypatch):
    """An exception in the session's loop (planted 0.5 s after the vehicle entered OFFBOARD): the hold is
    requested and confirmed before the error propagates, and the warning says so (no run folder: an error)."""
    warned = []

    def boom(v) -> None:
        raise RuntimeError("planted")

    def on_mode(v, mode, t) -> None:
        if mode == "OFFBOARD":
            v.events.append((t + 0.5, boom))

    vehicle = session.patch(setup=lambda v: setattr(v, "on_mode", on_mode), rates=RATES)
    est = EstimatorSettings(backend="numpy", rate_hz=RATE)
    settings = LiveSettings("udpin:127.0.0.1:14550", display="none", duration=30.0, out=str(session.out),
                            estimator=est, control=ControlSettings())  # fmt: skip
    with pytest.raises(RuntimeError, match="planted"):
        run_live(settings, warn=warned.append)
    assert [m for _, m in vehicle.modes] == ["POSCTL", "OFFBOARD", "AUTO_LOITER"]
    assert warned and warned[-1].startswith("control: HANDED BACK (error: planted): AUTO_LOITER confirmed")


def test_on_a_link_seconds_behind_no_time_stands_in_for_the_answer():
    """0.8 s each way, heartbeats at 10 Hz, the first hold request lost, control started after 1 s of
    telemetry, a stop at each 0.1 s from the request (1.505 s) on: heartbeats from before the request keep
    arriving for 1.6 s. Whatever the hand-over ends as,
    a claimed hand-back is the vehicle's real final mode, and a vehicle left in offboard was asked for the
    hold after the last set-point (the repeats stop only on a heartbeat sent after the requests were acted on)."""
    grid = [round(1.505 + 0.1 * k, 3) for k in range(16)]
    seen = set()
    for t, (ctrl, ap, link, _) in zip(grid, handovers(PX4, "signal", grid, timeout=3.0, lead=1.0, latency=0.8,
                                                      hb_period=0.1, drop_holds=1), strict=True):  # fmt: skip
        seen.add((ctrl.state, ctrl.handback["outcome"]))
        where = f"stop at {t:.3f} s: {ctrl.describe()}"
        if ctrl.state == "handed_back":
            assert ap.mode == (ctrl.handback.get("confirmed_mode") or ap.mode) and ap.mode != "OFFBOARD", where
        if ap.mode == "OFFBOARD":
            assert ctrl.state == "lost" and hold_after_last_setpoint(link.sent, PX4), where
    assert ("handed_back", "confirmed") in seen, seen  # the repeats do get through
