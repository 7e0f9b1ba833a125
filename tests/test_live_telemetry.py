"""Live telemetry checked, streams that recover: a scripted vehicle drives a whole ``run_live`` session in
simulated time (no socket, no wall-clock wait: the result does not depend on the machine's load).

The scripted vehicle sends ATTITUDE, LOCAL_POSITION_NED and ATTITUDE_TARGET of a level vehicle at rest at
its hover thrust, at the rates it is asked for (``MAV_CMD_SET_MESSAGE_INTERVAL``), acknowledges commands and
answers the hover-thrust parameter; each test changes one thing (a field, its clock, a rate, the answers)
and checks what the session reports against what was scripted.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest

from vtol_impedance.conventions import G
from vtol_impedance.live import LiveError, LiveSettings, run_live
from vtol_impedance.live.estimator import EstimatorSettings
from vtol_impedance.live.link import SOURCE_COMPONENT, SOURCE_SYSTEM, Link, LinkStats, mavutil, parse_address
from vtol_impedance.live.session import PARAM_READ_WINDOW_S, POLL_S, Session
from vtol_impedance.live.streams import field_problem
from vtol_impedance.model.vehicle import load_preset

MU = mavutil()
MAV = MU.mavlink
HOVER = 0.5  # MPC_THR_HOVER the vehicle reports, and the thrust it flies at: u = m g


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class Vehicle:
    """A PX4-like vehicle on a scripted link: streams at set rates, acts on requests ``latency_s`` after they
    are sent, and its answers arrive ``latency_s`` later (one way each)."""

    def __init__(self, clock: Clock, **kw) -> None:
        self.clock = clock
        self.mav = MAV.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = MAV.MAVLink(None)
        self.rates = {"ATTITUDE": 15.0, "LOCAL_POSITION_NED": 1.0, "ATTITUDE_TARGET": 2.0, "ATTITUDE_QUATERNION": 0.0}
        self.rates.update(kw.pop("rates", {}))
        self.next_due = {m: 0.0 for m in self.rates}
        self.next_hb = 0.0
        self.latency_s = kw.pop("latency_s", 0.0)
        self.answer_param_on = kw.pop("answer_param_on", 1)  # answer the n-th PARAM_REQUEST_READ (0: never)
        self.field = kw.pop("field", {})  # message -> {field: value or f(k)} overrides
        self.vehicle_ms = kw.pop("vehicle_ms", lambda t: int(t * 1000))  # its clock
        self.events = kw.pop("events", [])  # (t, fn(vehicle))
        self.foreign_acks = kw.pop("foreign_acks", False)
        self.rates_locked = False  # True: requests no longer change the rates
        assert not kw, kw
        self.k = dict.fromkeys(self.rates, 0)
        self.pending: list[tuple[float, object]] = []  # (arrival time, msg) for us
        self.actions: list[tuple[float, object]] = []  # (time it acts, request)
        self.received: list[tuple[float, object]] = []  # (time sent, msg) from us

    # messages from the tool
    def write(self, buf: bytes) -> None:
        msg = self.parser.decode(bytearray(buf))
        self.received.append((self.clock.t, msg))
        self.actions.append((self.clock.t + self.latency_s, msg))

    def _act(self, msg) -> None:
        t = self.clock.t
        typ = msg.get_type()
        if typ == "COMMAND_LONG" and msg.target_system == 1:
            if msg.command == MAV.MAV_CMD_SET_MESSAGE_INTERVAL:
                name = MAV.mavlink_map[int(msg.param1)].msgname
                if name in self.rates and not self.rates_locked:
                    self.rates[name] = 0.0 if msg.param2 <= 0 else 1e6 / msg.param2
                    self.next_due[name] = t
            if self.foreign_acks:  # another station's ACK first: the same command, DENIED, to system 42
                self._send(MAV.MAVLink_command_ack_message(msg.command, 2, 0, 0, 42, 190), t + self.latency_s)
            self._send(MAV.MAVLink_command_ack_message(msg.command, 0, 0, 0, SOURCE_SYSTEM, SOURCE_COMPONENT),
                       t + self.latency_s)  # fmt: skip
        elif typ == "PARAM_REQUEST_READ":
            n = sum(1 for _, m in self.received if m.get_type() == "PARAM_REQUEST_READ")
            if self.answer_param_on and n >= self.answer_param_on:
                self._send(MAV.MAVLink_param_value_message(b"MPC_THR_HOVER", HOVER, 9, 1, 0), t + self.latency_s)

    def _send(self, m, at: float) -> None:
        buf = m.pack(self.mav)
        self.pending.append((at, self.parser.decode(bytearray(buf))))

    def _stream(self, name: str, t: float):
        k = self.k[name]
        self.k[name] += 1
        ms = self.vehicle_ms(t)
        f = {key: (v(k) if callable(v) else v) for key, v in self.field.get(name, {}).items()}
        if name == "ATTITUDE":
            return MAV.MAVLink_attitude_message(ms, f.get("roll", 0.0), 0.0, 0.0, 0.0, 0.0, 0.0)
        if name == "ATTITUDE_QUATERNION":
            return MAV.MAVLink_attitude_quaternion_message(ms, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        if name == "LOCAL_POSITION_NED":
            return MAV.MAVLink_local_position_ned_message(ms, 0.0, 0.0, -1.0, f.get("vx", 0.0), 0.0, 0.0)
        return MAV.MAVLink_attitude_target_message(ms, 0, [1, 0, 0, 0], 0, 0, 0, f.get("thrust", HOVER))

    def advance(self, t: float) -> list:
        """Everything that reaches the tool by time ``t``, in order."""
        for when, fn in list(self.events):
            if when <= t:
                fn(self)
                self.events.remove((when, fn))
        for when, msg in [a for a in self.actions if a[0] <= t]:
            self.actions.remove((when, msg))
            self._act(msg)
        while self.next_hb <= t:
            self._send(MAV.MAVLink_heartbeat_message(2, 12, 1, 3 << 16, 4, 3), self.next_hb)
            self.next_hb += 1.0
        for name, hz in self.rates.items():
            if hz <= 0:
                continue
            while self.next_due[name] <= t:
                self._send(self._stream(name, self.next_due[name]), self.next_due[name])
                self.next_due[name] += 1.0 / hz
        due = sorted((a for a in self.pending if a[0] <= t), key=lambda a: a[0])
        self.pending = [a for a in self.pending if a[0] > t]
        return [m for _, m in due]

    def sent(self, typ: str, after: float = -1.0) -> list:
        return [(t, m) for t, m in self.received if m.get_type() == typ and t > after]


class ScriptedLink(Link):
    """:class:`~vtol_impedance.live.link.Link` with the socket replaced by a :class:`Vehicle` and the clock by
    simulated time: each poll advances it by its timeout."""

    def __init__(self, vehicle: Vehicle, clock: Clock) -> None:
        self.address = parse_address("udpin:127.0.0.1:14550")
        self.mu = MU
        self.recorder = None
        self.peers = {}
        self.stats = LinkStats()
        self.target = None
        self._last_seq = None
        self.now = clock
        self.vehicle = vehicle

        class Conn:
            mav = MAV.MAVLink(None, srcSystem=SOURCE_SYSTEM, srcComponent=SOURCE_COMPONENT)
            write = staticmethod(vehicle.write)

            def close(self) -> None:
                pass

        self.conn = Conn()

    def poll(self, timeout, on_message=None, max_messages=2000) -> int:
        self.now.t += max(timeout, POLL_S)
        msgs = self.vehicle.advance(self.now.t)
        for msg in msgs:
            self._received(msg)
            if on_message is not None:
                on_message(msg)
        return len(msgs)


def patch_session(monkeypatch, folder, vehicle, clock: Clock) -> None:
    """Sessions opened from now on talk to ``vehicle`` over a :class:`ScriptedLink` on ``clock``'s time and
    record into ``folder``."""
    from vtol_impedance.io import RunFolder
    from vtol_impedance.live.link import TlogWriter

    def open_(self) -> None:
        self.folder = RunFolder(folder, command="live")
        self.tlog = TlogWriter(self.folder.path("flight.tlog"))
        self.link = ScriptedLink(vehicle, clock)
        self.link.recorder = self.tlog

    monkeypatch.setattr(Session, "now", lambda self: clock.t)
    monkeypatch.setattr(Session, "open", open_)


@pytest.fixture
def scripted(monkeypatch, tmp_path):
    """``fly(duration, **vehicle)`` runs one session against a scripted vehicle: ``(result, vehicle)``."""

    def fly(duration: float, display: str = "none", stream=None, **kw):
        clock = Clock()
        vehicle = Vehicle(clock, **kw)
        fly.vehicles.append(vehicle)
        patch_session(monkeypatch, tmp_path / "run", vehicle, clock)
        settings = LiveSettings("udpin:127.0.0.1:14550", display=display, duration=duration,
                                out=str(tmp_path / "run"), estimator=EstimatorSettings(backend="numpy"))  # fmt: skip
        return run_live(settings, stream=stream), vehicle

    fly.vehicles = []
    return fly


def estimate_rows(folder: Path) -> np.ndarray:
    lines = (folder / "estimate.csv").read_text().splitlines()
    return np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]]).reshape(-1, 18)


def events(res) -> str:
    return "\n".join(e["text"] for e in res.summary["events"])


# --------------------------------------------------------------------------- values checked


@pytest.mark.parametrize(
    "msg, words",
    [
        (MAV.MAVLink_attitude_message(0, math.nan, 0, 0, 0, 0, 0), ("ATTITUDE.roll", "not finite")),
        (MAV.MAVLink_attitude_message(0, 0, 1.7, 0, 0, 0, 0), ("ATTITUDE.pitch", "-pi/2..pi/2")),
        (MAV.MAVLink_attitude_message(0, 0, 0, 0, 0, 0, 100.0), ("ATTITUDE.yawspeed", "rad/s")),
        (MAV.MAVLink_attitude_quaternion_message(0, 0.5, 0.5, 0, 0, 0, 0, 0), ("q norm", "1 +- 0.05")),
        (MAV.MAVLink_local_position_ned_message(0, 0, 0, 0, 1e6, 0, 0), ("LOCAL_POSITION_NED.vx", "m/s")),
        (MAV.MAVLink_attitude_target_message(0, 0, [1, 0, 0, 0], 0, 0, 0, 50.0), ("thrust", "0..1")),
        (MAV.MAVLink_attitude_target_message(0, 0, [1, 0, 0, 0], 0, 0, 0, -0.1), ("thrust", "0..1")),
        (MAV.MAVLink_servo_output_raw_message(0, 0, 1500, 1500, 40000, 1500, 0, 0, 0, 0), ("servo3_raw", "PWM")),
        (MAV.MAVLink_esc_telemetry_1_to_4_message([0] * 4, [0] * 4, [0] * 4, [0] * 4, [0, 0, 0, 0], [0] * 4), None),
    ],
)
def test_each_field_is_checked_against_its_range_and_named(msg, words):
    got = field_problem(msg, 4)
    if words is None:
        assert got is None
    else:
        assert got is not None and all(w in " ".join(got) for w in words), got


@pytest.mark.parametrize(
    "msg",
    [
        MAV.MAVLink_attitude_message(0, math.pi, -math.pi / 2, -math.pi, 30.0, -30.0, 0.0),  # the range's ends
        MAV.MAVLink_attitude_target_message(0, 0, [1, 0, 0, 0], 0, 0, 0, 1.0),
        MAV.MAVLink_attitude_target_message(0, 0, [1, 0, 0, 0], 0, 0, 0, 0.0),
        MAV.MAVLink_servo_output_raw_message(0, 0, 1000, 2000, 0, 900, 0, 0, 0, 0),  # 0: an output not driven
        MAV.MAVLink_local_position_ned_message(0, 5e3, -5e3, -100.0, 60.0, -60.0, 20.0),  # a fast multirotor
    ],
)
def test_correct_values_at_their_limits_are_accepted(msg):
    assert field_problem(msg, 4) is None


def test_nan_attitude_is_named_and_the_run_exits_non_zero_with_the_reason(scripted):
    res, _ = scripted(5.0, field={"ATTITUDE": {"roll": math.nan}})
    assert res.ticks == 0 and res.exit_code == 4
    assert "ATTITUDE.roll" in res.end and "not finite" in res.end
    f = res.summary["rejected"]["fields"]["ATTITUDE.roll"]
    assert f["count"] > 50 and "not finite" in f["why"]
    assert "the attitude stream (ATTITUDE) is missing: no usable sample for 1 s: ATTITUDE.roll" in events(res)
    assert "attitude" in res.summary["missing_streams"]
    assert estimate_rows(res.folder).size == 0


def test_thrust_out_of_range_is_rejected_counted_and_never_shown(scripted):
    """Every fifth ATTITUDE_TARGET says thrust 50 (MAVLink: 0..1): those are rejected and counted, the others
    give the hover thrust m g of a vehicle at rest, so the estimate stays near zero (1,170 N before)."""
    out = io.StringIO()
    res, veh = scripted(6.0, display="plain", stream=out,
                        field={"ATTITUDE_TARGET": {"thrust": lambda k: 50.0 if k % 5 == 4 else HOVER}})  # fmt: skip
    assert res.exit_code == 0 and res.ticks > 100
    n_bad = veh.k["ATTITUDE_TARGET"] // 5
    count = res.summary["rejected"]["fields"]["ATTITUDE_TARGET.thrust"]["count"]
    assert 10 < count <= n_bad
    e = estimate_rows(res.folder)
    m = load_preset("pelican").mass
    np.testing.assert_allclose(e[:, 11], m * G, rtol=1e-9)  # thrust_N: only the good commands
    assert np.abs(e[:, 2:5]).max() < 0.5
    screen = out.getvalue()
    assert "rejected" in screen and "ATTITUDE_TARGET.thrust" in screen
    assert "ATTITUDE_TARGET.thrust rejected: 50 is outside MAVLink's 0..1" in events(res)


@pytest.mark.parametrize(
    "clock, words",
    [(lambda t: 1000, "does not advance"), (lambda t: int(1e6 - 1000 * t), "goes backwards")],
    ids=["frozen", "backwards"],
)
def test_a_frozen_or_backwards_vehicle_clock_is_named_and_exits_non_zero(scripted, clock, words):
    res, _ = scripted(5.0, vehicle_ms=clock)
    assert res.ticks == 0 and res.exit_code == 4
    assert words in res.end and "no estimate was produced" in res.end
    assert "missing" in events(res)


# --------------------------------------------------------------------------- streams that recover


def test_a_throttled_stream_is_asked_for_again_and_named(scripted):
    """Another ground station sets LOCAL_POSITION_NED to 1 Hz at 5 s: the session asks for 50 Hz again (the
    request is seen on the link) and says so; the vehicle obeys and the estimate runs again."""
    t_throttle = 5.0

    def throttle(v: Vehicle) -> None:
        v.rates["LOCAL_POSITION_NED"] = 1.0

    res, veh = scripted(11.0, events=[(t_throttle, throttle)])
    lpn = MAV.MAVLINK_MSG_ID_LOCAL_POSITION_NED
    again = [(t, m) for t, m in veh.sent("COMMAND_LONG", after=t_throttle)
             if m.command == MAV.MAV_CMD_SET_MESSAGE_INTERVAL and int(m.param1) == lpn]  # fmt: skip
    assert again and again[0][1].param2 == pytest.approx(1e6 / 50.0)
    assert t_throttle < again[0][0] < t_throttle + 3.0
    assert res.summary["stream_rerequests"]["LOCAL_POSITION_NED"] >= 1
    assert "LOCAL_POSITION_NED arrives at" in events(res) and "asked for 50 Hz again" in events(res)
    t = estimate_rows(res.folder)[:, 0]
    assert np.sum(t > t.max() - 1.0) >= 45  # a 50 Hz estimate again in the last second
    assert res.exit_code == 0


def test_the_probe_ranks_sources_after_the_requests_take_effect_on_a_slow_link(scripted):
    """0.9 s each way: ATTITUDE at 4 Hz until the request arrives, ATTITUDE_QUATERNION at 10 Hz unasked. A 1 s
    window from the request saw ATTITUDE at 4 * 0.9 + 50 * 0.1 = 8.6 Hz and chose the quaternion."""
    res, _ = scripted(8.0, latency_s=0.9, rates={"ATTITUDE": 4.0, "ATTITUDE_QUATERNION": 10.0})
    assert res.summary["estimator"]["sources"]["attitude"] == "ATTITUDE"
    att = next(s for s in res.summary["streams"] if s["message"] == "ATTITUDE")
    assert att["measured_probe_hz"] == pytest.approx(50.0, rel=0.1)


def test_the_hover_parameter_read_is_retried_with_back_off_and_succeeds_on_the_third_try(scripted):
    res, veh = scripted(5.0, answer_param_on=3)
    assert res.exit_code == 0 and res.summary["params"]["MPC_THR_HOVER"] == pytest.approx(HOVER)
    t = [t for t, _ in veh.sent("PARAM_REQUEST_READ")]
    assert len(t) == 3
    np.testing.assert_allclose(np.diff(t), [0.3, 0.6], atol=2 * POLL_S)  # the documented back-off


def test_an_unanswered_parameter_read_gives_up_after_the_documented_window(scripted):
    with pytest.raises(LiveError, match="MPC_THR_HOVER"):
        scripted(30.0, answer_param_on=0)
    t = np.array([t for t, _ in scripted.vehicles[-1].sent("PARAM_REQUEST_READ")])
    np.testing.assert_allclose(t - t[0], [0.0, 0.3, 0.9, 2.1, 4.1, 6.1], atol=3 * POLL_S)


def test_acks_for_another_station_are_ignored(scripted):
    """Each command is answered twice: DENIED to system 42 (another ground station), ACCEPTED to this tool;
    only ours is read."""
    res, veh = scripted(5.0, foreign_acks=True)
    n_cmd = len(veh.sent("COMMAND_LONG"))
    assert res.summary["acks_for_other_stations"] == n_cmd > 0
    assert res.exit_code == 0 and res.ticks > 50


def test_an_ack_is_matched_on_its_target(monkeypatch):
    clock = Clock()
    sess = Session(LiveSettings("udpin:127.0.0.1:14550", display="none", estimator=EstimatorSettings(backend="numpy")))
    sess.link = ScriptedLink(Vehicle(clock), clock)
    sess.target = sess.link.target = (1, 1)
    parser = MAV.MAVLink(None)
    mav = MAV.MAVLink(None, srcSystem=1, srcComponent=1)
    for target, ours in (((42, 190), False), ((SOURCE_SYSTEM, 7), False), ((SOURCE_SYSTEM, SOURCE_COMPONENT), True),
                         ((0, 0), True)):  # fmt: skip
        n = len(sess.acks)
        msg = parser.decode(bytearray(MAV.MAVLink_command_ack_message(176, 0, 0, 0, *target).pack(mav)))
        sess.on_message(msg)
        assert (len(sess.acks) == n + 1) is ours, target
    assert sess.acks_ignored == 2


def test_the_windows_are_as_documented():
    """The guide's request times of a parameter read are the ones the constants give."""
    from vtol_impedance.live.session import PARAM_FIRST_WAIT_S, PARAM_MAX_WAIT_S

    t, wait, times = 0.0, PARAM_FIRST_WAIT_S, []
    while t < PARAM_READ_WINDOW_S:
        times.append(t)
        t, wait = t + wait, min(2 * wait, PARAM_MAX_WAIT_S)
    text = ", ".join(f"{x:g}" for x in times[:-1]) + f" and {times[-1]:g} s"
    doc = (Path(__file__).resolve().parents[1] / "docs" / "guide" / "live.md").read_text(encoding="utf-8")
    doc = " ".join(doc.split())
    for words in (text, f"within a window of {PARAM_READ_WINDOW_S:g} s", "exit code 4", "ATTITUDE_TARGET.thrust"):
        assert words in doc, words


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"system": 1.5}, "system id"),
        ({"system": 0}, "system id"),
        ({"component": 300}, "component id"),
        ({"duration": 2.0, "events": ((5.0, "mode", "POSCTL"),)}, "time"),
        ({"events": ((-1.0, "mode", "POSCTL"),)}, "time"),
        ({"duration": 2.0, "inject_on": 3.0}, "before the end of the run"),
        ({"duration": 2.0, "impairments": {"latency_s": 5.0}}, "as long as the whole run"),
    ],
)
def test_simulated_autopilot_options_are_range_checked(kw, message):
    from vtol_impedance.errors import InputError
    from vtol_impedance.live.autopilot import Impairments, SimSettings

    if "impairments" in kw:
        kw = dict(kw, impairments=Impairments(**kw["impairments"]))
    with pytest.raises(InputError, match=message):
        SimSettings("udpout:127.0.0.1:9", **kw)
    ok = {k: v for k, v in kw.items() if k not in ("events", "inject_on", "impairments", "system", "component")}
    SimSettings("udpout:127.0.0.1:9", **ok)  # the rest of it is accepted


def test_a_stream_that_stops_is_reported_missing_and_back(scripted):
    """ATTITUDE_TARGET (the thrust) stops at 4 s, with re-requests ignored, and resumes at 7 s: missing after
    1 s without a sample (nothing arrived), named in live.json while it lasts, then back."""

    def stop(v: Vehicle) -> None:
        v.rates["ATTITUDE_TARGET"], v.rates_locked = 0.0, True

    def resume(v: Vehicle) -> None:
        v.rates["ATTITUDE_TARGET"], v.next_due["ATTITUDE_TARGET"] = 50.0, v.clock.t

    res, veh = scripted(9.0, events=[(4.0, stop), (7.0, resume)])
    text = events(res)
    assert "the thrust stream (ATTITUDE_TARGET) is missing: no usable sample for 1 s: nothing arrived" in text
    assert "the thrust stream (ATTITUDE_TARGET) is back" in text
    t_missing = next(e["t_s"] for e in res.summary["events"] if "is missing" in e["text"])
    assert 5.0 < t_missing < 5.0 + 0.05  # the last sample just before 4 s, plus the 1 s
    assert res.summary["missing_streams"] == {} and res.exit_code == 0
