"""Every safety action of ``live --control`` made to act, and the decoding of every message ``live`` reads.

The control tests fly a whole ``run_live`` session against a scripted vehicle in simulated time (no socket, no
wall-clock wait: the result does not depend on the machine's load). The vehicle is PX4-like or ArduCopter-like:
armed, in its position mode, streaming ATTITUDE, LOCAL_POSITION_NED and ATTITUDE_TARGET at 50 Hz; it enters the
mode asked by ``MAV_CMD_DO_SET_MODE`` and shows it in its next heartbeat. Once in the offboard mode it follows a
scripted path (position and velocity as functions of the time since it entered), whatever it is sent.

Each test judges what is observable on the wire, as the vehicle recorded it: when the ``SET_ATTITUDE_TARGET``
set-points stop, the thrust and attitude they carry, and the ``DO_SET_MODE`` that asks for the hold (or land)
mode with the autopilot's own mode numbers (PX4: custom main mode 4 AUTO with sub mode 3 LOITER or 6 LAND;
ArduCopter: 5 LOITER, 9 LAND). The expected times and limits are computed here from the settings and the path,
not read from the code.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from test_live_telemetry import Clock, patch_session

from vtol_impedance.live import ControlSettings, LiveSettings, run_live
from vtol_impedance.live.estimator import EstimatorSettings
from vtol_impedance.live.link import SOURCE_COMPONENT, SOURCE_SYSTEM, mavutil
from vtol_impedance.live.session import POLL_S
from vtol_impedance.live.streams import Decoder, VehicleClock
from vtol_impedance.logs.ardupilot import MotorCurve

MU = mavutil()
MAV = MU.mavlink
HOVER = 0.5  # the hover thrust the vehicle reports (MPC_THR_HOVER / MOT_THST_HOVER)
RATE = 50.0  # Hz: the streams and the estimator's ticks
PERIOD = 1.0 / RATE
P0 = np.array([0.0, 0.0, -1.0])  # where the vehicle hovers before the hand-over (NED, m)

# the autopilots' mode numbers, from their documentation (PX4 px4_custom_mode.h; ArduCopter's mode list)
PX4_MODES = {"POSCTL": (3, 0), "OFFBOARD": (6, 0), "AUTO_LOITER": (4, 3), "AUTO_LAND": (4, 6)}
APM_MODES = {"LOITER": (5, 0), "GUIDED_NOGPS": (20, 0), "LAND": (9, 0)}


def _at_rest(t: float) -> tuple[np.ndarray, np.ndarray]:
    return P0.copy(), np.zeros(3)


class Flyer:
    """A scripted vehicle that can be flown: modes, arming, streams, parameters (module docstring).

    ``path(t)``: position and velocity (NED) ``t`` seconds after it entered the offboard mode; ``silent_after``:
    seconds into the offboard mode after which every stream stops (the heartbeat goes on)."""

    def __init__(self, clock: Clock, autopilot: str = "px4", path=_at_rest, silent_after: float | None = None):
        self.clock = clock
        self.px4 = autopilot == "px4"
        self.modes = PX4_MODES if self.px4 else APM_MODES
        self.mode = self.modes["POSCTL" if self.px4 else "LOITER"]
        self.offboard = self.modes["OFFBOARD" if self.px4 else "GUIDED_NOGPS"]
        self.params = {"MPC_THR_HOVER": HOVER} if self.px4 else {"MOT_THST_HOVER": HOVER, "GUID_OPTIONS": 8.0}
        self.path, self.silent_after = path, silent_after
        self.mav = MAV.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = MAV.MAVLink(None)
        self.t_offboard: float | None = None
        self.thrust = HOVER  # ATTITUDE_TARGET: the set-point's thrust in the offboard mode, else the hover
        self.next_hb = 0.0
        self.next_stream = 0.0
        self.pending: list[tuple[float, object]] = []
        self.received: list[tuple[float, object]] = []

    def write(self, buf: bytes) -> None:
        msg = self.parser.decode(bytearray(buf))
        t = self.clock.t
        self.received.append((t, msg))
        typ = msg.get_type()
        if typ == "COMMAND_LONG" and msg.target_system == 1:
            if msg.command == MAV.MAV_CMD_DO_SET_MODE:
                self.mode = (int(msg.param2), int(msg.param3) if self.px4 else 0)
                if self.mode == self.offboard and self.t_offboard is None:
                    self.t_offboard = t
            self._send(MAV.MAVLink_command_ack_message(msg.command, 0, 0, 0, SOURCE_SYSTEM, SOURCE_COMPONENT))
        elif typ == "PARAM_REQUEST_READ":
            name = msg.param_id.decode() if isinstance(msg.param_id, bytes) else msg.param_id
            name = name.rstrip("\x00")
            if name in self.params:
                self._send(MAV.MAVLink_param_value_message(name.encode(), self.params[name], 9, 1, 0))
        elif typ == "PARAM_SET":
            name = (msg.param_id.decode() if isinstance(msg.param_id, bytes) else msg.param_id).rstrip("\x00")
            self.params[name] = float(msg.param_value)
            self._send(MAV.MAVLink_param_value_message(name.encode(), self.params[name], 9, 1, 0))
        elif typ == "SET_ATTITUDE_TARGET" and self.mode == self.offboard:
            self.thrust = float(msg.thrust)

    def _send(self, m) -> None:
        self.pending.append(self.parser.decode(bytearray(m.pack(self.mav))))

    def custom_mode(self) -> int:
        main, sub = self.mode
        return (main << 16) | (sub << 24) if self.px4 else main

    def state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        return _at_rest(t) if self.t_offboard is None or t < self.t_offboard else self.path(t - self.t_offboard)

    def advance(self, t: float) -> list:
        while self.next_hb <= t:
            self._send(MAV.MAVLink_heartbeat_message(2, 12 if self.px4 else 3, 1 | 128, self.custom_mode(), 4, 3))
            self.next_hb += 1.0
        while self.next_stream <= t:
            ts = self.next_stream
            self.next_stream += PERIOD
            quiet = self.t_offboard is not None and self.silent_after is not None
            if quiet and ts >= self.t_offboard + self.silent_after:
                continue
            ms = int(round(ts * 1000)) + 1000
            p, v = self.state(ts)
            self._send(MAV.MAVLink_attitude_message(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
            self._send(MAV.MAVLink_local_position_ned_message(ms, *p, *v))
            thrust = self.thrust if self.mode == self.offboard else HOVER
            self._send(MAV.MAVLink_attitude_target_message(ms, 0, [1, 0, 0, 0], 0, 0, 0, thrust))
        out, self.pending = self.pending, []
        return out

    # what the tool sent
    def setpoints(self) -> list[tuple[float, object]]:
        return [(t, m) for t, m in self.received if m.get_type() == "SET_ATTITUDE_TARGET"]

    def mode_requests(self) -> list[tuple[float, tuple[int, int]]]:
        return [(t, (int(m.param2), int(m.param3) if self.px4 else 0)) for t, m in self.received
                if m.get_type() == "COMMAND_LONG" and m.command == MAV.MAV_CMD_DO_SET_MODE]  # fmt: skip


@pytest.fixture
def fly(monkeypatch, tmp_path):
    """``fly(control, duration, **vehicle)``: one controlled session against a :class:`Flyer`."""

    def run(control: ControlSettings, duration: float, **kw) -> tuple[object, Flyer]:
        clock = Clock()
        vehicle = Flyer(clock, **kw)
        patch_session(monkeypatch, tmp_path / "run", vehicle, clock)
        settings = LiveSettings("udpin:127.0.0.1:14550", display="none", duration=duration, out=str(tmp_path / "run"),
                                estimator=EstimatorSettings(backend="numpy"), control=control)  # fmt: skip
        return run_live(settings), vehicle

    return run


def _engaged(veh: Flyer) -> float:
    assert veh.t_offboard is not None, "the hand-over never reached the offboard mode"
    return veh.t_offboard


def _stopped_and_asked(veh: Flyer, mode: tuple[int, int]) -> tuple[float, float]:
    """(time of the last set-point, time of the first request of ``mode`` after the hand-over); asserts none
    was sent after that request and the vehicle ended in ``mode``."""
    t_off = _engaged(veh)
    asked = [t for t, m in veh.mode_requests() if m == mode and t > t_off]
    assert asked, f"mode {mode} was never requested; requests: {veh.mode_requests()}"
    sp = [t for t, _ in veh.setpoints()]
    assert sp and sp[-1] <= asked[0], "a set-point was sent after the hold was requested"
    assert veh.mode == mode
    return sp[-1], asked[0]


# --------------------------------------------------------------------------- the fence, each axis, both signs

SPEED = 0.5  # m/s: below the speed fence (1.5 m/s), so only the position fence can act


@pytest.mark.parametrize(
    "direction, limit",
    [((1, 0, 0), 1.0), ((-1, 0, 0), 1.0), ((0, 1, 0), 1.0), ((0, -1, 0), 1.0), ((0, 0, 1), 0.5), ((0, 0, -1), 0.5),
     ((math.sqrt(0.5), -math.sqrt(0.5), 0), 1.0)],
    ids=["+x", "-x", "+y", "-y", "+z down", "-z up", "diagonal"],
)  # fmt: skip
def test_the_fence_hands_back_when_the_vehicle_leaves_it_on_each_axis(fly, direction, limit):
    """Drifting at 0.5 m/s from the hold point, the vehicle leaves the cylinder (radius 1 m, half-height 0.5 m)
    at ``limit / 0.5`` s; the set-points flow until then and stop within two ticks after, with the hold asked.
    The diagonal leaves the cylinder at 1 m from its axis, where a box check would still hold."""
    d = np.array(direction, dtype=float)

    def path(t: float):
        return P0 + d * SPEED * t, d * SPEED

    res, veh = fly(ControlSettings(fence_radius_m=1.0, fence_height_m=0.5), 9.0, path=path)
    t_cross = _engaged(veh) + limit / SPEED
    t_last, t_hold = _stopped_and_asked(veh, PX4_MODES["AUTO_LOITER"])
    assert t_cross - PERIOD <= t_last <= t_cross + 2 * PERIOD
    assert t_hold - t_last < 2 * PERIOD
    assert res.exit_code == 3 and "fence" in res.summary["control"]["reason"]


def test_the_speed_fence_hands_back_above_its_speed_and_not_below(fly):
    """1.41 m/s back and forth (below 1.5 m/s, inside the fence) for 2 s, then (1.1, 0, 1.1) m/s: 1.56 m/s,
    each component below 1.5. The set-points flow through the first part and stop within two ticks of the
    second, well before the position fence (0.5 m down at 1.1 m/s: 0.45 s later)."""
    t_fast = 2.0

    def path(t: float):
        if t < t_fast:
            k = math.floor(t / 0.25)
            sign = 1.0 if k % 2 == 0 else -1.0
            s = (t - 0.25 * k) if k % 2 == 0 else 0.25 - (t - 0.25 * k)  # a triangle 0..0.25 m
            return P0 + np.array([s, 0.0, s]), sign * np.array([1.0, 0.0, 1.0])
        return P0 + 1.1 * (t - t_fast) * np.array([1.0, 0.0, 1.0]), np.array([1.1, 0.0, 1.1])

    res, veh = fly(ControlSettings(max_speed_m_s=1.5), 9.0, path=path)
    t_switch = _engaged(veh) + t_fast
    t_last, _ = _stopped_and_asked(veh, PX4_MODES["AUTO_LOITER"])
    assert t_switch - PERIOD <= t_last <= t_switch + 2 * PERIOD
    assert "speed" in res.summary["control"]["reason"]


# --------------------------------------------------------------------------- the slew limits and the tilt bound


def _euler(q) -> tuple[float, float]:
    """Roll and pitch (rad, ZYX) of a quaternion w, x, y, z (the textbook formulas)."""
    w, x, y, z = (float(c) for c in q)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    return roll, pitch


def test_set_points_step_by_at_most_the_slew_limits_and_stay_within_the_tilt_bound(fly):
    """The hold point jumps 0.6 m in x and y and 0.3 m down, then to the opposite corner: the loop asks for a
    tilt beyond the bound and a thrust step far above the slew. Limits computed from the settings: thrust
    ``thrust_rate_max`` weights per second is ``thrust_rate_max * hover`` in normalised thrust per second
    (normalised thrust = N / (m g / hover)); roll and pitch ``tilt_rate_max_deg_s`` each; the tilt (roll and
    pitch together) at most ``tilt_max_deg``. Each limit must be reached (it acted) and never exceeded, the
    slews in both directions."""
    c = ControlSettings(thrust_rate_max=1.0, tilt_rate_max_deg_s=20.0, tilt_max_deg=10.0)
    corner = np.array([0.6, 0.6, 0.3])

    def path(t: float):
        if t < 1.0:
            return P0.copy(), np.zeros(3)
        return (P0 + corner if t < 3.5 else P0 - corner), np.zeros(3)

    res, veh = fly(c, 7.0, path=path)
    t_on = _engaged(veh)
    sp = [(m.time_boot_ms, m) for t, m in veh.setpoints() if t >= t_on]
    t = np.array([ms for ms, _ in sp]) * 1e-3
    thrust = np.array([m.thrust for _, m in sp])
    rp = np.array([_euler(m.q) for _, m in sp])
    dt = np.diff(t)
    assert len(sp) > 200 and np.all(dt > 0)
    du_max = c.thrust_rate_max * HOVER * dt  # normalised thrust per step
    dth_max = math.radians(c.tilt_rate_max_deg_s) * dt
    du, dth = np.diff(thrust), np.abs(np.diff(rp, axis=0))
    assert np.all(np.abs(du) <= du_max + 1e-6)
    assert np.all(dth <= dth_max[:, None] + 1e-6)
    assert np.any(du >= 0.99 * du_max) and np.any(du <= -0.99 * du_max), "the thrust slew never acted both ways"
    for k in (0, 1):
        assert np.any(np.diff(rp[:, k]) >= 0.99 * dth_max) and np.any(np.diff(rp[:, k]) <= -0.99 * dth_max)
    # the tilt: the body z axis's angle from the vertical, cos = 1 - 2 (x^2 + y^2) of the quaternion
    tilt = np.array([math.acos(min(1.0, 1 - 2 * (m.q[1] ** 2 + m.q[2] ** 2))) for _, m in sp])
    bound = math.radians(c.tilt_max_deg)
    assert np.all(tilt <= bound + 1e-5)
    assert tilt.max() >= bound - 1e-4, "the tilt bound never acted"
    assert res.exit_code == 0, res.end


# --------------------------------------------------------------------------- the watchdog: hold and land


@pytest.mark.parametrize(
    "autopilot, on_loss, mode",
    [("px4", "hold", PX4_MODES["AUTO_LOITER"]), ("px4", "land", PX4_MODES["AUTO_LAND"]),
     ("ardupilot", "land", APM_MODES["LAND"])],
)  # fmt: skip
def test_the_watchdog_asks_for_the_loss_action_when_telemetry_stops(fly, autopilot, on_loss, mode):
    """Every stream stops 1.5 s into the offboard mode (the heartbeat goes on): ``watchdog_s`` after the last
    sample arrived, the mode of ``on_loss`` is asked for with the autopilot's own number, and kept asked until
    the heartbeat shows it."""
    c = ControlSettings(watchdog_s=0.25, on_loss=on_loss)
    res, veh = fly(c, 9.0, autopilot=autopilot, silent_after=1.5)
    t_on = _engaged(veh)
    t_silent = t_on + 1.5  # the first sample not sent
    t_last_sample = math.ceil((t_silent - 1e-9) / PERIOD) * PERIOD - PERIOD
    _, t_asked = _stopped_and_asked(veh, mode)
    assert t_last_sample + c.watchdog_s <= t_asked <= t_last_sample + c.watchdog_s + 2 * POLL_S + 1e-9
    assert res.exit_code == 3 and "watchdog" in res.summary["control"]["reason"]


# --------------------------------------------------------------------------- decoding, against hand computation


def _decode(msg, sources: dict[str, str], n: int = 4, curve: MotorCurve | None = None, channels=None):
    dec = Decoder(sources, n, curve, channels)
    sample, _ = dec.decode(msg, VehicleClock())
    assert sample is not None, dec.why
    return sample.value


def _packed(m):
    """A message as it arrives: packed and parsed (float32 fields rounded as on the wire)."""
    mav = MAV.MAVLink(None, srcSystem=1, srcComponent=1)
    return MAV.MAVLink(None).decode(bytearray(m.pack(mav)))


def test_attitude_and_its_quaternion_give_the_angles_and_the_body_rates():
    roll, pitch, yaw = 0.1, -0.2, 0.3
    eta, omega = _decode(_packed(MAV.MAVLink_attitude_message(5, roll, pitch, yaw, 0.4, -0.5, 0.6)),
                         {"attitude": "ATTITUDE"})  # fmt: skip
    np.testing.assert_allclose(eta, [roll, pitch, yaw], atol=1e-7)
    np.testing.assert_allclose(omega, [0.4, -0.5, 0.6], atol=1e-7)
    # ZYX: q = q_z(yaw) q_y(pitch) q_x(roll), written out
    cr, sr, cp, sp, cy, sy = (f(a / 2) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    q = [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
         cr * cp * sy - sr * sp * cy]  # fmt: skip
    eta, omega = _decode(_packed(MAV.MAVLink_attitude_quaternion_message(5, *q, 0.4, -0.5, 0.6)),
                         {"attitude": "ATTITUDE_QUATERNION"})  # fmt: skip
    np.testing.assert_allclose(eta, [roll, pitch, yaw], atol=1e-6)
    np.testing.assert_allclose(omega, [0.4, -0.5, 0.6], atol=1e-7)


def test_local_position_ned_gives_position_and_velocity_as_sent():
    p, v = _decode(_packed(MAV.MAVLink_local_position_ned_message(5, 1.5, -2.5, -3.0, 0.25, -0.5, 0.75)),
                   {"velocity": "LOCAL_POSITION_NED"})  # fmt: skip
    np.testing.assert_allclose(p, [1.5, -2.5, -3.0])
    np.testing.assert_allclose(v, [0.25, -0.5, 0.75])


@pytest.mark.parametrize(
    "q, child, v_ned",
    [
        # yaw 90 deg: body x (forward) points east, body y (right) south; v_B (1, 2, 3) -> (-2, 1, 3)
        ((math.sqrt(0.5), 0, 0, math.sqrt(0.5)), 12, (-2.0, 1.0, 3.0)),
        ((math.sqrt(0.5), 0, 0, math.sqrt(0.5)), 8, (-2.0, 1.0, 3.0)),
        # roll 90 deg: body y (right) points down, body z (down) west; (1, 2, 3) -> (1, -3, 2)
        ((math.sqrt(0.5), math.sqrt(0.5), 0, 0), 12, (1.0, -3.0, 2.0)),
        # pitch 90 deg nose up: body x points up, body z north; (1, 2, 3) -> (3, 2, -1)
        ((math.sqrt(0.5), 0, math.sqrt(0.5), 0), 12, (3.0, 2.0, -1.0)),
        # velocity already in the local NED frame (MAV_FRAME_LOCAL_NED): as sent, whatever the attitude
        ((math.sqrt(0.5), 0, 0, math.sqrt(0.5)), 1, (1.0, 2.0, 3.0)),
    ],
    ids=["yaw90-FRD", "yaw90-BODY_NED", "roll90", "pitch90", "local-frame"],
)
def test_odometry_body_frame_velocity_is_rotated_to_ned(q, child, v_ned):
    msg = _packed(MAV.MAVLink_odometry_message(5_000, 1, child, 0.5, -0.5, -2.0, list(q), 1.0, 2.0, 3.0, 0, 0, 0,
                                               [math.nan] * 21, [math.nan] * 21))  # fmt: skip
    p, v = _decode(msg, {"velocity": "ODOMETRY"})
    np.testing.assert_allclose(p, [0.5, -0.5, -2.0])
    np.testing.assert_allclose(v, v_ned, atol=1e-6)


def test_attitude_target_thrust_is_the_normalised_thrust():
    (u,) = _decode(_packed(MAV.MAVLink_attitude_target_message(5, 0, [1, 0, 0, 0], 0, 0, 0, 0.625)),
                   {"thrust": "ATTITUDE_TARGET"})  # fmt: skip
    assert u == 0.625


def test_servo_output_raw_is_linear_on_px4_and_through_the_thrust_curve_on_arducopter():
    msg = _packed(MAV.MAVLink_servo_output_raw_message(5_000, 0, 1000, 1250, 1500, 2000, 1100, 0, 0, 0))
    (c,) = _decode(msg, {"outputs": "SERVO_OUTPUT_RAW"})
    np.testing.assert_allclose(c, [0.0, 0.25, 0.5, 1.0])
    # motors on channels 5, 3, 2, 4 (SERVOn_FUNCTION): their PWM in that order
    (c,) = _decode(msg, {"outputs": "SERVO_OUTPUT_RAW"}, channels=(5, 3, 2, 4))
    np.testing.assert_allclose(c, [0.1, 0.5, 0.25, 1.0])
    # ArduCopter's defaults (expo 0.65, spin 0.15..0.95, PWM 1000..2000): 1550 us is y = (0.55 - 0.15) / 0.8 = 0.5,
    # thrust 0.65 * 0.25 + 0.35 * 0.5 = 0.3375; 1150 us (spin min) 0; 1950 us (spin max) 1; 1350 us y = 0.25
    msg = _packed(MAV.MAVLink_servo_output_raw_message(5_000, 0, 1550, 1150, 1950, 1350, 0, 0, 0, 0))
    (c,) = _decode(msg, {"outputs": "SERVO_OUTPUT_RAW"}, curve=MotorCurve())
    np.testing.assert_allclose(c, [0.3375, 0.0, 1.0, 0.65 * 0.0625 + 0.35 * 0.25], atol=1e-12)


def test_actuator_output_status_normalised_or_pwm():
    (c,) = _decode(_packed(MAV.MAVLink_actuator_output_status_message(5_000, 15, [0.2, 0.4, 0.6, 0.8] + [0] * 28)),
                   {"outputs": "ACTUATOR_OUTPUT_STATUS"})  # fmt: skip
    np.testing.assert_allclose(c, [0.2, 0.4, 0.6, 0.8], atol=1e-7)
    (c,) = _decode(_packed(MAV.MAVLink_actuator_output_status_message(5_000, 15, [1100, 1300, 1700, 1900] + [0] * 28)),
                   {"outputs": "ACTUATOR_OUTPUT_STATUS"})  # fmt: skip
    np.testing.assert_allclose(c, [0.1, 0.3, 0.7, 0.9], atol=1e-7)


class _EscStatus(SimpleNamespace):
    """ESC_STATUS (id 291) as MAVLink defines it: pymavlink 2.4's set lacks it, so built by hand."""

    def get_type(self) -> str:
        return "ESC_STATUS"


def test_esc_status_rpm_in_blocks_of_four_and_esc_telemetry():
    sources = {"rpm": "ESC_STATUS"}
    (rpm,) = _decode(_EscStatus(time_usec=5_000, index=0, rpm=[1000, -2000, 3000, 4000], voltage=[0.0] * 4,
                                current=[0.0] * 4), sources)  # fmt: skip
    np.testing.assert_allclose(rpm, [1000, 2000, 3000, 4000])  # signed: negative is reverse rotation
    # a hexacopter: rotors 5 and 6 come in the block at index 4; nothing before it arrives
    dec = Decoder(sources, 6)
    clock = VehicleClock()
    s, _ = dec.decode(_EscStatus(time_usec=5_000, index=0, rpm=[1, 2, 3, 4], voltage=[0.0] * 4, current=[0.0] * 4),
                      clock)  # fmt: skip
    assert s is None
    s, _ = dec.decode(_EscStatus(time_usec=5_100, index=4, rpm=[5, 6, 0, 0], voltage=[0.0] * 4, current=[0.0] * 4),
                      clock)  # fmt: skip
    np.testing.assert_allclose(s.value[0], [1, 2, 3, 4, 5, 6])
    msg = _packed(MAV.MAVLink_esc_telemetry_1_to_4_message([0] * 4, [0] * 4, [0] * 4, [0] * 4, [900, 950, 1000, 1050],
                                                           [0] * 4))  # fmt: skip
    dec = Decoder({"rpm": "ESC_TELEMETRY_1_TO_4"}, 4)
    clock = VehicleClock()
    dec.decode(_packed(MAV.MAVLink_attitude_message(7, 0, 0, 0, 0, 0, 0)), clock)  # no time field: the latest
    clock.observe(7_000)
    s, _ = dec.decode(msg, clock)
    assert s.t_us == 7_000
    np.testing.assert_allclose(s.value[0], [900, 950, 1000, 1050])
