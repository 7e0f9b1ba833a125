"""What each autopilot streams over MAVLink, what the estimator takes from each message, and in which units.

The estimator of eqs. (6)-(13) needs the attitude ``eta`` and the body rates ``omega_B`` (for ``eta_dot``,
eq. (1c)), the world velocity ``v_W`` and the collective thrust ``u`` held over each period; the moment
channel also needs the body torque ``tau_B``. Over MAVLink they come from these messages (fields read by
name; NED world, FRD body, as MAVLink defines them):

=========  ==============================================  ==========================================
role       message (fields)                                 becomes
=========  ==============================================  ==========================================
attitude   ``ATTITUDE`` (roll, pitch, yaw, rollspeed, ...)  ``eta`` (rad, ZYX), ``omega_B`` (rad/s)
           or ``ATTITUDE_QUATERNION`` (q1..q4, rates)
velocity   ``LOCAL_POSITION_NED`` (x, y, z, vx, vy, vz)     ``p_W`` (m), ``v_W`` (m/s)
           or ``ODOMETRY`` (velocity in its child frame)
thrust     ``ATTITUDE_TARGET.thrust`` (0..1)                ``u = thrust * m g / hover`` (N) with the
                                                            hover thrust, or ``thrust * U_max``
outputs    ``SERVO_OUTPUT_RAW`` (servoN_raw, PWM us) or     rotor forces ``f_i = c_i * unit`` with the
           ``ACTUATOR_OUTPUT_STATUS`` (actuator[])          same map; ``[u, tau_B] = E f`` (eq. (4));
                                                            ArduCopter's PWM through its thrust curve
                                                            (:mod:`~vtol_impedance.logs.ardupilot`)
rpm        ``ESC_STATUS.rpm`` (PX4) or                      ``f_i = k_f omega_i^2`` (N, rotor constant
           ``ESC_TELEMETRY_1_TO_4.rpm`` (ArduPilot)         ``k_f`` given); ``[u, tau_B] = E f``
=========  ==============================================  ==========================================

The moment needs ``tau_B``: PX4 from v1.14 streams no torque set-point over MAVLink (``ACTUATOR_CONTROL_TARGET``
was removed) and ArduPilot never did, so the moment comes from the actuator outputs or the rotor speeds
through the nominal mixer (4), or not at all (reported as NaN).

Times are the vehicle's (``time_boot_ms``, ``time_usec``); messages without one (``ESC_TELEMETRY_1_TO_4``)
take the latest vehicle time seen. Nothing here depends on the computer's clock, so a recording replays to
the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from ..conventions import G
from ..errors import InputError, scalar
from ..logs.ardupilot import MotorCurve
from ..model.kinematics import euler_from_rotation, quat_to_rotation
from ..model.vehicle import VehicleParams

#: Largest plausible PWM width (us) of an output and the range mapped to 0..1 (PX4 PWM_MAIN_MIN/MAX,
#: ArduPilot MOT_PWM_MIN/MAX defaults).
PWM_MIN_US = 1000.0
PWM_MAX_US = 2000.0
#: rpm -> rad/s
RPM = 2.0 * np.pi / 60.0


@dataclass(frozen=True)
class StreamSpec:
    """One MAVLink message as a source of a role, with the rates an autopilot sends it at.

    ``default_hz``: what the autopilot streams on a ground-station link without being asked (0: not at all);
    ``request``: whether ``live`` asks for it with ``MAV_CMD_SET_MESSAGE_INTERVAL`` (at the estimator's rate);
    ``lost_without``: what the estimate loses when it is missing; ``how``: how to get it on the vehicle.
    """

    message: str
    role: str
    default_hz: float
    request: bool
    lost_without: str
    how: str


@dataclass(frozen=True)
class AutopilotProfile:
    """How one autopilot family speaks: its ``MAV_AUTOPILOT`` id, streams, hover-thrust parameter and modes.

    Modes are ``(base_mode custom flag, custom_mode)`` values of the heartbeat; ``mode_command`` gives the
    ``MAV_CMD_DO_SET_MODE`` parameters (param2, param3) of a mode.
    """

    name: str
    mav_autopilot: int
    streams: tuple[StreamSpec, ...]
    hover_param: str
    modes: dict[str, int]
    mode_command: dict[str, tuple[float, float]]
    offboard: str
    hold: str
    land: str
    setpoint_timeout_s: float

    def mode_name(self, custom_mode: int) -> str:
        for k, v in self.modes.items():
            if v == custom_mode:
                return k
        return f"mode {custom_mode}"


def _px4_mode(main: int, sub: int = 0) -> int:
    """PX4's ``custom_mode``: main mode in bits 16-23, sub mode in bits 24-31."""
    return (main << 16) | (sub << 24)


_LOST_ATT = "everything: the estimate needs the attitude and the body rates"
_LOST_VEL = "everything: the force comes from the change of momentum m v_W"
_LOST_THRUST = "the force: without a thrust the estimate has no input (another thrust source can replace it)"
_LOST_OUT = "the moment (no torque without per-rotor commands); the thrust falls back to ATTITUDE_TARGET"
_LOST_RPM = "nothing if the outputs stream: the rotor speeds only replace commands by measured thrust"

#: What PX4 (v1.14 and later) streams, at which default rates, and what the estimate loses without each.
PX4 = AutopilotProfile(
    name="PX4",
    mav_autopilot=12,
    streams=(
        StreamSpec(
            "ATTITUDE",
            "attitude",
            15.0,
            True,
            _LOST_ATT,
            "mavlink stream -d <dev> -s ATTITUDE -r 50 (or MAV_CMD_SET_MESSAGE_INTERVAL)",
        ),
        StreamSpec("ATTITUDE_QUATERNION", "attitude", 10.0, False, "nothing while ATTITUDE streams", "as above"),
        StreamSpec(
            "LOCAL_POSITION_NED",
            "velocity",
            1.0,
            True,
            _LOST_VEL,
            "mavlink stream -d <dev> -s LOCAL_POSITION_NED -r 50; 1 Hz on a normal (ground station) link",
        ),
        StreamSpec(
            "ODOMETRY",
            "velocity",
            0.0,
            False,
            "nothing while LOCAL_POSITION_NED streams",
            "30 Hz on an onboard link (MAV_x_MODE = Onboard)",
        ),
        StreamSpec(
            "ATTITUDE_TARGET",
            "thrust",
            2.0,
            True,
            _LOST_THRUST,
            "normalised 0..1 and 2 Hz by default: request 50 Hz; needs MPC_THR_HOVER or --max-thrust",
        ),
        StreamSpec(
            "SERVO_OUTPUT_RAW",
            "outputs",
            1.0,
            True,
            _LOST_OUT,
            "1 Hz by default, request 50 Hz; PWM outputs (linear thrust: THR_MDL_FAC = 0)",
        ),
        StreamSpec(
            "ACTUATOR_OUTPUT_STATUS",
            "outputs",
            0.0,
            False,
            "nothing while SERVO_OUTPUT_RAW streams",
            "on request (MAVLink 2)",
        ),
        StreamSpec(
            "ESC_STATUS",
            "rpm",
            1.0,
            False,
            _LOST_RPM,
            "needs ESCs that report speed (DShot telemetry, UAVCAN); not in pymavlink 2.4's message set, "
            "so not read (a newer pymavlink with ESC_STATUS is used when present)",
        ),
    ),  # fmt: skip
    hover_param="MPC_THR_HOVER",
    modes={
        "MANUAL": _px4_mode(1),
        "ALTCTL": _px4_mode(2),
        "POSCTL": _px4_mode(3),
        "OFFBOARD": _px4_mode(6),
        "STABILIZED": _px4_mode(7),
        "AUTO_TAKEOFF": _px4_mode(4, 2),
        "AUTO_LOITER": _px4_mode(4, 3),
        "AUTO_LAND": _px4_mode(4, 6),
    },  # fmt: skip
    mode_command={
        "POSCTL": (3, 0),
        "OFFBOARD": (6, 0),
        "AUTO_TAKEOFF": (4, 2),
        "AUTO_LOITER": (4, 3),
        "AUTO_LAND": (4, 6),
    },  # fmt: skip
    offboard="OFFBOARD",
    hold="AUTO_LOITER",
    land="AUTO_LAND",
    setpoint_timeout_s=1.0,  # COM_OF_LOSS_T default
)

#: What ArduCopter (4.x) streams, through its SRn_* stream groups, and what the estimate loses without each.
ARDUPILOT = AutopilotProfile(
    name="ArduPilot",
    mav_autopilot=3,
    streams=(
        StreamSpec(
            "ATTITUDE",
            "attitude",
            4.0,
            True,
            _LOST_ATT,
            "SRn_EXTRA1 (stream group), or MAV_CMD_SET_MESSAGE_INTERVAL at 50 Hz",
        ),
        StreamSpec(
            "LOCAL_POSITION_NED",
            "velocity",
            4.0,
            True,
            _LOST_VEL,
            "SRn_POSITION, or MAV_CMD_SET_MESSAGE_INTERVAL at 50 Hz",
        ),
        StreamSpec(
            "ATTITUDE_TARGET",
            "thrust",
            0.0,
            True,
            _LOST_THRUST,
            "in no stream group: only on request (thrust = throttle in, 0..1; needs MOT_THST_HOVER)",
        ),
        StreamSpec(
            "SERVO_OUTPUT_RAW",
            "outputs",
            4.0,
            True,
            _LOST_OUT,
            "SRn_RC_CHAN; PWM read through ArduCopter's thrust curve (MOT_THST_EXPO, MOT_SPIN_MIN/MAX, "
            "MOT_PWM_MIN/MAX, MOT_BAT_VOLT_MAX/MIN with SYS_STATUS's voltage)",
        ),
        StreamSpec(
            "ESC_TELEMETRY_1_TO_4",
            "rpm",
            4.0,
            True,
            _LOST_RPM,
            "SRn_EXTRA3 with ESC telemetry (BLHeli/DShot); no timestamp field; needs --rotor-constant",
        ),
    ),  # fmt: skip
    hover_param="MOT_THST_HOVER",
    modes={
        "STABILIZE": 0,
        "ALT_HOLD": 2,
        "GUIDED": 4,
        "LOITER": 5,
        "RTL": 6,
        "LAND": 9,
        "POSHOLD": 16,
        "BRAKE": 17,
        "GUIDED_NOGPS": 20,
    },  # fmt: skip
    mode_command={
        "LOITER": (5, 0),
        "GUIDED_NOGPS": (20, 0),
        "LAND": (9, 0),
        "GUIDED": (4, 0),
        "BRAKE": (17, 0),
        "POSHOLD": (16, 0),
    },  # fmt: skip
    offboard="GUIDED_NOGPS",
    hold="LOITER",
    land="LAND",
    setpoint_timeout_s=3.0,  # GUID_TIMEOUT default
)

#: The autopilot profiles by name (``--autopilot``; found from the heartbeat otherwise).
PROFILES: dict[str, AutopilotProfile] = {"px4": PX4, "ardupilot": ARDUPILOT}
BY_MAV_AUTOPILOT = {p.mav_autopilot: p for p in PROFILES.values()}
#: Role -> messages that can give it, best first (the choice is made on the measured rates).
ROLE_SOURCES: dict[str, tuple[str, ...]] = {
    "attitude": ("ATTITUDE", "ATTITUDE_QUATERNION"),
    "velocity": ("LOCAL_POSITION_NED", "ODOMETRY"),
    "thrust": ("ATTITUDE_TARGET",),
    "outputs": ("SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS"),
    "rpm": ("ESC_STATUS", "ESC_TELEMETRY_1_TO_4"),
}
#: Roles the estimate cannot run without (they gate its ticks); the commands are held between samples.
GATING = ("attitude", "velocity")


def profile(name: str) -> AutopilotProfile:
    if name not in PROFILES:
        raise InputError(f"unknown autopilot {name!r}; choose one of {', '.join(PROFILES)}")
    return PROFILES[name]


# --------------------------------------------------------------------------- decoding


class Sample(NamedTuple):
    """One reading of a role at vehicle time ``t_us`` (microseconds since the vehicle booted)."""

    role: str
    t_us: int
    value: tuple


class VehicleClock:
    """The latest vehicle time seen and its jumps.

    A time more than ``back_s`` before the latest is a jump back (the vehicle rebooted, or its clock was
    reset); one more than ``ahead_s`` after it a jump ahead. :meth:`observe` reports either; the caller
    restarts what depends on continuity. ``time_usec`` fields of 32 bits wrap every 71.6 min: unwrapped
    near the latest time.
    """

    def __init__(self, back_s: float = 1.0, ahead_s: float = 10.0) -> None:
        self.latest_us: int | None = None
        self.back_us = int(back_s * 1e6)
        self.ahead_us = int(ahead_s * 1e6)

    def unwrap32(self, t_us: int) -> int:
        if self.latest_us is None:
            return t_us
        k = round((self.latest_us - t_us) / 2**32)
        return t_us + max(k, 0) * 2**32

    def observe(self, t_us: int) -> str | None:
        if self.latest_us is None:
            self.latest_us = t_us
            return None
        if t_us < self.latest_us - self.back_us:
            self.latest_us = t_us
            return "back"
        if t_us > self.latest_us + self.ahead_us:
            self.latest_us = t_us
            return "ahead"
        self.latest_us = max(self.latest_us, t_us)
        return None


def _time_us(msg: Any, clock: VehicleClock) -> int | None:
    d = msg.__dict__
    if "time_boot_ms" in d:
        return int(msg.time_boot_ms) * 1000
    if "time_usec" in d:
        t = int(msg.time_usec)
        return clock.unwrap32(t) if msg.get_type() == "SERVO_OUTPUT_RAW" else t
    return clock.latest_us


def _attitude(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    typ = msg.get_type()
    omega_B = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed], dtype=float)
    if typ == "ATTITUDE":
        eta = np.array([msg.roll, msg.pitch, msg.yaw], dtype=float)
    else:
        eta = euler_from_rotation(quat_to_rotation(np.array([msg.q1, msg.q2, msg.q3, msg.q4], dtype=float)))
    return eta, omega_B


#: MAV_FRAME values of ODOMETRY's child frame meaning the velocity is in the body frame.
_BODY_FRAMES = (8, 12)  # MAV_FRAME_BODY_NED (legacy meaning: body), MAV_FRAME_BODY_FRD


def _velocity(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    p_W = np.array([msg.x, msg.y, msg.z], dtype=float)
    v = np.array([msg.vx, msg.vy, msg.vz], dtype=float)
    if msg.get_type() == "ODOMETRY" and int(msg.child_frame_id) in _BODY_FRAMES:
        v = quat_to_rotation(np.asarray(msg.q, dtype=float)) @ v
    return p_W, v


# --------------------------------------------------------------------------- field checks

#: Bounds each decoded field must meet where it enters (MAVLink's documented range where it has one, else a
#: physical bound no vehicle this tool flies exceeds); a message with a field outside is rejected, counted per
#: field and named. Angles: MAVLink's -pi..pi (pitch -pi/2..pi/2) with float32 rounding room.
ANGLE_TOL_RAD = 1e-3
#: Body rates, rad/s: 4000 deg/s, twice the 2000 deg/s full scale of the usual flight-controller gyros.
RATE_MAX_RAD_S = 70.0
#: Position, m (the estimator's own bound on a measurement) and speed, m/s (above any multirotor's).
POSITION_MAX_M = 1e6
SPEED_MAX_M_S = 150.0
#: A quaternion is accepted when its norm is within this of 1 (float32 telemetry is unit to 1e-6).
QUAT_NORM_TOL = 0.05
#: An output's PWM pulse, us (servo and ESC pulses are 500..2500 us); 0 is an output not driven.
PWM_PULSE_US = (500.0, 2500.0)
#: Rotor speed, rpm (ESC_STATUS is signed, negative for reverse rotation, by MAVLink's definition).
RPM_MAX = 1e5


def _out_of(typ: str, name: str, value: Any, lo: float, hi: float, what: str) -> tuple[str, str] | None:
    v = np.atleast_1d(np.asarray(value, dtype=float))
    where = f"{typ}.{name}"
    bad = ~np.isfinite(v)
    if np.any(bad):
        return where, f"{v[bad][0]:g} is not finite"
    bad = (v < lo) | (v > hi)
    if np.any(bad):
        return where, f"{v[bad][0]:g} is outside {what}"
    return None


def _pwm_problem(typ: str, name: str, raw: np.ndarray) -> tuple[str, str] | None:
    lo, hi = PWM_PULSE_US
    driven = raw[raw != 0.0]
    return _out_of(typ, name, driven, lo, hi, f"a PWM pulse ({lo:g}..{hi:g} us, or 0: not driven)")


def field_problem(msg: Any, n_rotors: int) -> tuple[str, str] | None:
    """The first field of ``msg`` this tool reads that is out of its range: ``("MESSAGE.field", why)``, or
    ``None``. Ranges: the bounds above (module constants); fields not read are not checked."""
    typ = msg.get_type()
    checks: list[tuple[str, Any, float, float, str]] = []
    pi = np.pi + ANGLE_TOL_RAD
    if typ in ("ATTITUDE", "ATTITUDE_QUATERNION"):
        rate_rng = (-RATE_MAX_RAD_S, RATE_MAX_RAD_S, f"+-{RATE_MAX_RAD_S:g} rad/s (a gyro's range)")
        checks += [(n, getattr(msg, n), *rate_rng) for n in ("rollspeed", "pitchspeed", "yawspeed")]
    if typ == "ATTITUDE":
        checks += [("roll", msg.roll, -pi, pi, "MAVLink's -pi..pi rad"),
                   ("pitch", msg.pitch, -np.pi / 2 - ANGLE_TOL_RAD, np.pi / 2 + ANGLE_TOL_RAD,
                    "MAVLink's -pi/2..pi/2 rad"),
                   ("yaw", msg.yaw, -pi, pi, "MAVLink's -pi..pi rad")]  # fmt: skip
    if typ == "ATTITUDE_QUATERNION":
        q = np.array([msg.q1, msg.q2, msg.q3, msg.q4], dtype=float)
        checks.append(("q1..q4", q, -1.0 - QUAT_NORM_TOL, 1.0 + QUAT_NORM_TOL, "-1..1"))
        checks.append(("q norm", np.linalg.norm(q), 1 - QUAT_NORM_TOL, 1 + QUAT_NORM_TOL, f"1 +- {QUAT_NORM_TOL:g}"))
    if typ in ("LOCAL_POSITION_NED", "ODOMETRY"):
        p_rng = (-POSITION_MAX_M, POSITION_MAX_M, f"+-{POSITION_MAX_M:g} m")
        v_rng = (-SPEED_MAX_M_S, SPEED_MAX_M_S, f"+-{SPEED_MAX_M_S:g} m/s (faster than any multirotor)")
        checks += [(n, getattr(msg, n), *p_rng) for n in ("x", "y", "z")]
        checks += [(n, getattr(msg, n), *v_rng) for n in ("vx", "vy", "vz")]
        if typ == "ODOMETRY" and int(msg.child_frame_id) in _BODY_FRAMES:
            checks.append(("q norm", np.linalg.norm(np.asarray(msg.q, dtype=float)), 1 - QUAT_NORM_TOL,
                           1 + QUAT_NORM_TOL, f"1 +- {QUAT_NORM_TOL:g}"))  # fmt: skip
    if typ == "ATTITUDE_TARGET":
        checks.append(("thrust", msg.thrust, 0.0, 1.0, "MAVLink's 0..1 (normalised thrust)"))
    for name, value, lo, hi, what in checks:
        bad = _out_of(typ, name, value, lo, hi, what)
        if bad is not None:
            return bad
    if typ == "SERVO_OUTPUT_RAW":
        for i in range(n_rotors):
            bad = _pwm_problem(typ, f"servo{i + 1}_raw", np.array([getattr(msg, f"servo{i + 1}_raw")], dtype=float))
            if bad is not None:
                return bad
    if typ == "ACTUATOR_OUTPUT_STATUS":
        a = np.asarray(msg.actuator[:n_rotors], dtype=float)
        bad = _out_of(typ, "actuator", a, -np.inf, np.inf, "")
        if bad is None and not np.all(np.abs(a) <= 1.5):
            bad = _pwm_problem(typ, "actuator", a)
        return bad
    if typ in ("ESC_STATUS", "ESC_TELEMETRY_1_TO_4"):
        return _out_of(typ, "rpm", np.asarray(msg.rpm, dtype=float), -RPM_MAX, RPM_MAX, f"+-{RPM_MAX:g} rpm")
    return None


class Decoder:
    """Turns the chosen source messages into :class:`Sample` values; ``sources`` maps role -> message.

    ``curve``: ArduCopter's thrust curve, through which ``SERVO_OUTPUT_RAW`` PWM becomes rotor thrust (0..1 of
    the rotor's maximum), with the battery voltage of the latest ``SYS_STATUS`` when it compensates (outputs
    wait for the first voltage); without it, PWM 1000..2000 us is read as linear in thrust (PX4). ``channels``:
    the output channel (1-based) of each motor in order (ArduCopter's ``SERVOn_FUNCTION``), else 1..n."""

    def __init__(
        self,
        sources: dict[str, str],
        n_rotors: int,
        curve: MotorCurve | None = None,
        channels: tuple[int, ...] | None = None,
    ) -> None:
        self.sources = dict(sources)
        self.by_message = {m: r for r, m in self.sources.items() if m}
        self.n_rotors = n_rotors
        self.curve = curve
        self.channels = tuple(channels) if channels else tuple(range(1, n_rotors + 1))
        self._esc = np.full(max(n_rotors, 4), np.nan)
        self._volt: float | None = None
        #: rejected messages by ``MESSAGE.field``, the latest reason of each, and this call's (or None)
        self.rejected: dict[str, int] = {}
        self.why: dict[str, str] = {}
        self.last_rejected: str | None = None

    def _reject(self, where: str, why: str) -> None:
        self.rejected[where] = self.rejected.get(where, 0) + 1
        self.why[where] = why
        self.last_rejected = where

    def decode(self, msg: Any, clock: VehicleClock) -> tuple[Sample | None, str | None]:
        """``(sample or None, clock jump or None)`` for one message of the vehicle."""
        typ = msg.get_type()
        if typ == "SYS_STATUS" and self.curve is not None:
            mv = getattr(msg, "voltage_battery", 65535)
            if 0 < mv < 65535:  # UINT16_MAX: not known
                self._volt = mv * 1e-3
        role = self.by_message.get(typ)
        if role is None:
            return None, None
        t_us = _time_us(msg, clock)
        if t_us is None:
            return None, None
        jump = clock.observe(t_us) if typ != "ESC_TELEMETRY_1_TO_4" else None
        self.last_rejected = None
        try:
            bad = field_problem(msg, self.n_rotors)
            if bad is not None:
                self._reject(*bad)
                return None, jump
            value = self._value(role, msg)
        except (AttributeError, TypeError, ValueError, IndexError, np.linalg.LinAlgError) as exc:
            self._reject(typ, f"does not decode ({type(exc).__name__}: {exc})")
            return None, jump
        if value is None:
            return None, jump
        if not all(np.all(np.isfinite(np.asarray(v, dtype=float))) for v in value):
            self._reject(typ, "decodes to a value that is not finite")
            return None, jump
        return Sample(role, t_us, value), jump

    def _value(self, role: str, msg: Any) -> tuple | None:
        n = self.n_rotors
        if role == "attitude":
            return _attitude(msg)
        if role == "velocity":
            return _velocity(msg)
        if role == "thrust":
            return (float(msg.thrust),)
        if role == "outputs":
            if msg.get_type() == "SERVO_OUTPUT_RAW":
                raw = np.array([getattr(msg, f"servo{c}_raw", 0) for c in self.channels[:n]], dtype=float)
                if self.curve is not None:
                    if self.curve.compensates and self._volt is None:
                        return None
                    return (self.curve.thrust(raw, self._volt),)
            else:
                raw = np.asarray(msg.actuator[:n], dtype=float)
                if np.all(np.abs(raw) <= 1.5):  # normalised outputs, not PWM
                    return (np.clip(raw, 0.0, 1.0),)
            return (np.clip((raw - PWM_MIN_US) / (PWM_MAX_US - PWM_MIN_US), 0.0, 1.0),)
        if role == "rpm":
            if msg.get_type() == "ESC_STATUS":
                i0 = int(msg.index)
                if i0 >= len(self._esc):
                    return None
                k = min(4, len(self._esc) - i0)
                self._esc[i0 : i0 + k] = np.asarray(msg.rpm[:k], dtype=float)
                if i0 + k < n:  # wait for the block with the last motors
                    return None
                rpm = self._esc[:n].copy()
            else:
                rpm = np.asarray(msg.rpm[:n], dtype=float)
            return None if np.any(np.isnan(rpm)) else (np.abs(rpm),)
        return None


# --------------------------------------------------------------------------- commands in SI units


@dataclass(frozen=True)
class ThrustMap:
    """Normalised thrust, outputs and rotor speeds in newtons and newton metres.

    ``hover``: the autopilot's normalised hover thrust (``MPC_THR_HOVER``, ``MOT_THST_HOVER``): thrust ``t``
    (0..1) becomes ``u = t m g / hover`` (the thrust that held the *nominal* weight at hover: a payload the
    autopilot learnt into its hover thrust is absorbed, not estimated); or ``max_thrust`` (N): ``u = t U``.
    Outputs ``c_i`` (0..1 of a rotor's maximum thrust) become ``f_i = c_i u_full / n`` with the same full-scale
    thrust (``motor_curve``: ArduCopter's, through which the decoder reads the PWM of the channels
    ``motor_channels``); rotor speeds ``omega_i``
    (rad/s) ``f_i = k_f omega_i^2`` with ``rotor_constant`` ``k_f`` (N s^2/rad^2). ``[u, tau_B] = E f`` with the
    nominal vehicle's effectiveness (eq. (4)).
    """

    mass: float
    hover: float | None = None
    max_thrust: float | None = None
    rotor_constant: float | None = None
    E: np.ndarray = field(default_factory=lambda: np.zeros((4, 4)), repr=False)
    motor_curve: MotorCurve | None = None
    motor_channels: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "mass", scalar("mass", self.mass, lo=0.0, lo_open=True))
        if (self.hover is None) == (self.max_thrust is None):
            raise InputError(
                "a thrust map needs exactly one of the hover thrust (hover, 0..1) or the maximum thrust (max_thrust, N)"
            )
        if self.hover is not None:
            object.__setattr__(self, "hover", scalar("hover thrust", self.hover, lo=0.02, hi=1.0, lo_open=True))
        if self.max_thrust is not None:
            object.__setattr__(self, "max_thrust", scalar("max_thrust", self.max_thrust, lo=0.0, lo_open=True))
        if self.rotor_constant is not None:
            object.__setattr__(
                self, "rotor_constant", scalar("rotor_constant", self.rotor_constant, lo=0.0, lo_open=True)
            )

    @classmethod
    def for_vehicle(cls, vehicle: VehicleParams, mass: float, **kw: Any) -> ThrustMap:
        return cls(mass=mass, E=np.asarray(vehicle.geometry.E, dtype=float), **kw)

    @property
    def full_thrust(self) -> float:
        """Thrust at normalised 1, N."""
        return self.max_thrust if self.max_thrust is not None else self.mass * G / self.hover  # type: ignore[operator]

    def thrust(self, thrust_norm: float) -> float:
        return float(thrust_norm) * self.full_thrust

    def normalised(self, thrust_N: float) -> float:
        return float(np.clip(thrust_N / self.full_thrust, 0.0, 1.0))

    def wrench_from_outputs(self, c: np.ndarray) -> tuple[float, np.ndarray]:
        f = np.asarray(c, dtype=float) * self.full_thrust / self.E.shape[1]
        w = self.E @ f
        return float(w[0]), w[1:4]

    def wrench_from_rpm(self, rpm: np.ndarray) -> tuple[float, np.ndarray]:
        if self.rotor_constant is None:
            raise InputError("rotor speeds need the rotor constant k_f (--rotor-constant, N s^2/rad^2)")
        f = self.rotor_constant * (np.asarray(rpm, dtype=float) * RPM) ** 2
        w = self.E @ f
        return float(w[0]), w[1:4]

    def to_dict(self) -> dict[str, Any]:
        return {"mass": self.mass, "hover": self.hover, "max_thrust": self.max_thrust,
                "rotor_constant": self.rotor_constant, "full_thrust_N": self.full_thrust,
                "motor_curve": None if self.motor_curve is None else self.motor_curve.to_dict(),
                "motor_channels": None if self.motor_channels is None else list(self.motor_channels)}  # fmt: skip


def choose_sources(rates: dict[str, float], min_hz: float, use_rpm: bool) -> tuple[dict[str, str], list[str]]:
    """The message for each role from the measured rates (Hz by message name): the fastest of its sources at
    or above ``min_hz``; returns ``(sources, missing roles)``. The commands: the rotor speeds (with a rotor
    constant), else the outputs (thrust and torque), else ``ATTITUDE_TARGET`` (thrust only)."""
    sources: dict[str, str] = {}
    for role, msgs in ROLE_SOURCES.items():
        ok = [(rates.get(m, 0.0), -i, m) for i, m in enumerate(msgs) if rates.get(m, 0.0) >= min_hz]
        if ok:
            sources[role] = max(ok)[2]
    missing = [r for r in GATING if r not in sources]
    if not use_rpm:
        sources.pop("rpm", None)
    if not any(r in sources for r in ("thrust", "outputs", "rpm")):
        missing.append("thrust")
    return sources, missing


def command_role(sources: dict[str, str]) -> str:
    """Which role gives the commands: ``rpm``, ``outputs`` or ``thrust``."""
    for r in ("rpm", "outputs", "thrust"):
        if r in sources:
            return r
    raise InputError("no thrust source")
