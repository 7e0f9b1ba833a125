"""A simulated autopilot behind a MAVLink endpoint: the project's simulator flown by its own controller,
speaking PX4's or ArduCopter's MAVLink well enough for MAVSDK, MAVProxy and pymavlink ground stations.

What it is made of (nothing new about the physics):

* the plant: the scenario's true vehicle, integrated by :func:`vtol_impedance.sim.plant.rk4_step` with its
  disturbances (:mod:`vtol_impedance.sim.disturbances`, e.g. case B's fan) plus the wrench injected here
  (a :class:`~vtol_impedance.sim.disturbances.StepWrench`), on its spring-damper ground;
* the sensors: the scenario's :class:`~vtol_impedance.sim.sensors.SensorSuite` (noise and latency of what the
  autopilot's estimator reports). Everything it reports or flies on comes from these measurements, never from
  the true state;
* its own flight modes with the project's controller (the scenario's PD, no estimate): position hold
  (PX4 ``POSCTL``/``AUTO_LOITER``, ArduCopter ``LOITER``/``POSHOLD``/``BRAKE``, ``GUIDED`` without attitude
  targets), takeoff and landing run :func:`~vtol_impedance.control.impedance.controller_step`; attitude
  set-points (PX4 ``OFFBOARD``, ArduCopter ``GUIDED`` and ``GUIDED_NOGPS``) run only its attitude loop,
  :func:`~vtol_impedance.control.impedance.attitude_step`, on the received attitude.

**The thrust of a set-point.** PX4 flies ``SET_ATTITUDE_TARGET.thrust`` as normalised collective thrust
(0..1 of the rotors' maximum). ArduCopter reads it as its ``GUID_OPTIONS`` parameter says (default 0, as on
ArduCopter): with bit 3 (value 8, "SetAttitudeTarget interprets Thrust As Thrust") clear it is a climb-rate
demand, 0.5 holding the altitude, ``(t - 0.5) 2 WPNAV_SPEED_UP`` up above 0.5 and ``(0.5 - t) 2
WPNAV_SPEED_DN`` down below (cm/s), flown by its own altitude loop; with bit 3 set it is normalised thrust,
raised by the angle boost ``1 / cos(tilt target)`` (``ATC_ANGLE_BOOST``, on by default); the lean is limited
to ``ANGLE_MAX``. Set-points older than ``GUID_TIMEOUT`` (3 s) leave it in the mode, level, holding its
altitude (ArduPilot wiki, "Guided Mode", Guided Mode Options and ``GUID_TIMEOUT``,
https://ardupilot.org/copter/docs/ac2_guidedmode.html; ArduCopter ``GCS_MAVLINK_Copter::
handle_message_set_attitude_target`` and ``ModeGuided::angle_control_run``). PX4 leaves ``OFFBOARD`` for
``AUTO_LOITER`` when set-points are older than ``COM_OF_LOSS_T`` (1 s).

It starts hovering at the scenario's altitude above the origin, armed, in position hold (a pilot has taken
off), the origin being home at :data:`HOME_LAT_DEG`, :data:`HOME_LON_DEG`, :data:`HOME_ALT_M`. It streams at the
autopilot's default rates (:mod:`.streams`, plus ``GLOBAL_POSITION_INT``, ``EXTENDED_SYS_STATE``, ``SYS_STATUS``,
``VFR_HUD``) and at the rates asked with ``MAV_CMD_SET_MESSAGE_INTERVAL``, sends one message when asked with
``MAV_CMD_REQUEST_MESSAGE`` (``AUTOPILOT_VERSION`` and ``HOME_POSITION`` also with the older
``MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES`` and ``MAV_CMD_GET_HOME_POSITION``), answers arming, mode changes
(``MAV_CMD_DO_SET_MODE`` and ``SET_MODE``), ``MAV_CMD_NAV_TAKEOFF``, ``MAV_CMD_NAV_LAND`` (in ``COMMAND_LONG``
or ``COMMAND_INT``), the parameter protocol (:data:`PARAMETERS`: ``PARAM_REQUEST_LIST``, ``PARAM_REQUEST_READ``
by name or index, ``PARAM_SET`` answered by the value it holds) and ``TIMESYNC``, and sends a heartbeat at
1 Hz. Every other command is refused with ``COMMAND_ACK`` ``MAV_RESULT_UNSUPPORTED`` (a mode it does not fly:
``MAV_RESULT_DENIED``). As ArduCopter it drives its motors through ArduCopter's thrust curve with its
parameters (:class:`~vtol_impedance.logs.MotorCurve`); as PX4 its PWM is linear in thrust. The link can lose,
repeat, reorder and delay packets (:class:`Impairments`), both ways. ``speed`` runs the simulation faster than
real time (the vehicle's clock runs with it).
"""

from __future__ import annotations

import contextlib
import io
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..control.attitude_filter import FilterState
from ..control.impedance import (
    attitude_step,
    compile_controllers,
    controller_step,
    initial_controller_state,
    position_step,
)
from ..control.signals import Reference
from ..conventions import G
from ..errors import InputError, scalar
from ..logs.ardupilot import DEFAULTS as MOTOR_DEFAULTS
from ..logs.ardupilot import MotorCurve
from ..model.kinematics import euler_from_rotation, quat_from_euler, quat_to_rotation
from ..records import REASONS
from ..scenarios.spec import ScenarioSpec, build, controller_params
from ..sim.disturbances import DisturbanceSet, StepWrench
from ..sim.loop import check_vehicles
from ..sim.plant import OMEGA, ROTOR, apply_instant_rotors, compile_plants, initial_state, origin_kinematics, rk4_step
from ..sim.sensors import NoiseSource, SensorParams, SensorSuite
from .link import Address, LiveError, mavutil, parse_address
from .streams import RPM, AutopilotProfile, profile

#: The vehicle's clock at the start of the simulation, s (it booted this long before): vehicle time is
#: simulated time plus this.
BOOT_S = 1.0
#: Age of the newest set-point under which OFFBOARD may be entered (PX4 wants a set-point stream first).
OFFBOARD_READY_S = 0.5
#: Simulated seconds of disturbance series (turbulence, noise) a run without ``duration`` prepares: at
#: most an hour, and no more than :data:`SERIES_BUDGET_BYTES` at the plant rate (10 kHz: about 7 minutes).
#: After it the series hold their last value (said when the run starts).
OPEN_HORIZON_MAX_S = 3600.0
#: Memory the open-ended series may take: samples x 6 channels x 8 bytes, and the filter's temporaries.
SERIES_BUDGET_BYTES = 200e6
#: Rotor constant of the simulated ESCs, N s^2/rad^2 (7 N, a Pelican rotor's f_max, at about 9500 rpm).
ROTOR_CONSTANT = 7.0e-6
#: Messages this autopilot can send, by name (the others are refused when asked for).
SERVED = (
    "HEARTBEAT", "ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED", "ODOMETRY", "ATTITUDE_TARGET",
    "SERVO_OUTPUT_RAW", "ESC_STATUS", "ESC_TELEMETRY_1_TO_4", "VFR_HUD", "SYS_STATUS", "GLOBAL_POSITION_INT",
    "EXTENDED_SYS_STATE", "HOME_POSITION", "AUTOPILOT_VERSION",
)  # fmt: skip
#: Default rates (Hz) of the messages a ground station needs beside the estimator's (0: on request only).
DEFAULT_EXTRA_HZ = {"VFR_HUD": 4.0, "SYS_STATUS": 1.0, "GLOBAL_POSITION_INT": 5.0, "EXTENDED_SYS_STATE": 1.0,
                    "HOME_POSITION": 0.0, "AUTOPILOT_VERSION": 0.0}  # fmt: skip
#: Home, where the simulation's NED origin lies on the Earth (PX4's simulation site): ``GLOBAL_POSITION_INT``
#: and ``HOME_POSITION`` place the NED state around it on a flat Earth of radius :data:`EARTH_RADIUS_M` (the
#: curvature's error is below 0.1 mm within 1 km).
HOME_LAT_DEG = 47.397742
HOME_LON_DEG = 8.545594
HOME_ALT_M = 488.0
EARTH_RADIUS_M = 6378137.0
#: ``AUTOPILOT_VERSION.capabilities``: what is implemented (MAV_PROTOCOL_CAPABILITY_ PARAM_FLOAT 2,
#: SET_ATTITUDE_TARGET 64, MAVLINK2 8192) and the parameter encoding (PX4 PARAM_ENCODE_BYTEWISE 16: integers'
#: bytes in the float field; ArduPilot PARAM_ENCODE_C_CAST 131072: integers cast to float). Missions, position
#: set-points and ``COMMAND_INT`` beyond the commands listed in the module docstring are not implemented, so
#: not announced.
CAPABILITIES = {"PX4": 2 | 64 | 8192 | 16, "ArduPilot": 2 | 64 | 8192 | 131072}
#: ``AUTOPILOT_VERSION.flight_sw_version`` (major, minor, patch, FIRMWARE_VERSION_TYPE_OFFICIAL): the versions
#: whose messages and parameters :mod:`.streams` and :data:`PARAMETERS` follow.
FLIGHT_SW_VERSION = {"PX4": (1, 14, 0, 255), "ArduPilot": (4, 5, 0, 255)}
#: MAV_PARAM_TYPE of a parameter.
INT8, INT16, INT32, REAL32 = 2, 4, 6, 9
#: The parameters each personality holds: name -> (default, MAV_PARAM_TYPE, documented range, writable). The
#: hover thrust's default is the vehicle's (``None`` here); ArduCopter's motor parameters are
#: :data:`~vtol_impedance.logs.ardupilot.DEFAULTS`. A ``PARAM_SET`` outside the range, of a NaN, or of a
#: read-only parameter is refused: the value held is sent back unchanged.
PARAMETERS: dict[str, dict[str, tuple[float | None, int, tuple[float, float], bool]]] = {
    "PX4": {
        "MPC_THR_HOVER": (None, REAL32, (0.1, 0.8), True),
        "COM_OF_LOSS_T": (1.0, REAL32, (0.0, 60.0), True),
        "MIS_TAKEOFF_ALT": (2.5, REAL32, (0.0, 80.0), True),
        "MPC_TKO_SPEED": (1.5, REAL32, (1.0, 5.0), True),
        "MPC_LAND_SPEED": (0.7, REAL32, (0.6, 5.0), True),
    },
    "ArduPilot": {
        "MOT_THST_HOVER": (None, REAL32, (0.125, 0.6875), True),
        "MOT_THST_EXPO": (MOTOR_DEFAULTS["MOT_THST_EXPO"], REAL32, (-1.0, 1.0), True),
        "MOT_SPIN_MIN": (MOTOR_DEFAULTS["MOT_SPIN_MIN"], REAL32, (0.0, 0.3), True),
        "MOT_SPIN_MAX": (MOTOR_DEFAULTS["MOT_SPIN_MAX"], REAL32, (0.9, 1.0), True),
        "MOT_PWM_MIN": (MOTOR_DEFAULTS["MOT_PWM_MIN"], INT16, (0.0, 2000.0), True),
        "MOT_PWM_MAX": (MOTOR_DEFAULTS["MOT_PWM_MAX"], INT16, (0.0, 2000.0), True),
        "MOT_BAT_VOLT_MAX": (MOTOR_DEFAULTS["MOT_BAT_VOLT_MAX"], REAL32, (0.0, 100.0), False),
        "MOT_BAT_VOLT_MIN": (MOTOR_DEFAULTS["MOT_BAT_VOLT_MIN"], REAL32, (0.0, 100.0), False),
        "GUID_OPTIONS": (0.0, INT32, (0.0, 255.0), True),
        "GUID_TIMEOUT": (3.0, REAL32, (0.1, 5.0), True),
        "WPNAV_SPEED_UP": (250.0, REAL32, (10.0, 1000.0), True),
        "WPNAV_SPEED_DN": (150.0, REAL32, (10.0, 500.0), True),
        "LAND_SPEED": (50.0, INT16, (30.0, 200.0), True),
        "ANGLE_MAX": (3000.0, INT16, (1000.0, 8000.0), True),
        "ATC_ANGLE_BOOST": (1.0, INT8, (0.0, 1.0), True),
    },
}
#: ``GUID_OPTIONS`` bit 3 (value 8): ``SET_ATTITUDE_TARGET.thrust`` is thrust, not a climb rate.
GUID_THRUST_BIT = 8
#: What each mode does here, by personality: ``hold`` (position hold where entered), ``offboard``
#: (attitude set-points), ``guided`` (ArduCopter GUIDED: position hold, takeoff, or attitude set-points once
#: they arrive), ``takeoff``, ``land``. Other modes of the profiles are refused (``MAV_RESULT_DENIED``).
MODE_KINDS = {
    "PX4": {"POSCTL": "hold", "AUTO_LOITER": "hold", "OFFBOARD": "offboard", "AUTO_TAKEOFF": "takeoff",
            "AUTO_LAND": "land"},
    "ArduPilot": {"LOITER": "hold", "POSHOLD": "hold", "BRAKE": "hold", "GUIDED": "guided",
                  "GUIDED_NOGPS": "offboard", "LAND": "land"},
}  # fmt: skip
#: ``SYS_STATUS`` sensors present, enabled and healthy (they do not fail here): MAV_SYS_STATUS_SENSOR_ 3D_GYRO 1,
#: 3D_ACCEL 2, 3D_MAG 4, ABSOLUTE_PRESSURE 8, GPS 32, ANGULAR_RATE_CONTROL 1024, ATTITUDE_STABILIZATION 2048,
#: Z_ALTITUDE_CONTROL 8192, XY_POSITION_CONTROL 16384, MOTOR_OUTPUTS 32768, AHRS 2**21, PREARM_CHECK 2**28
#: (no RC receiver: none is simulated).
SENSORS_PRESENT = 1 | 2 | 4 | 8 | 32 | 1024 | 2048 | 8192 | 16384 | 32768 | 2**21 | 2**28
#: Below this height (m, sensed) with a vertical speed under :data:`LANDED_SPEED_M_S` the vehicle is landed.
LANDED_HEIGHT_M = 0.05
LANDED_SPEED_M_S = 0.1
#: Largest injected force and torque accepted: 85 and 34 times a Pelican's weight (11.8 N) and largest
#: roll moment (2.9 N m), far beyond a test of the estimator, still inside float64's comfort.
MAX_INJECT_FORCE_N = 1e3
MAX_INJECT_TORQUE_NM = 1e2
#: Largest scripted clock jump, s (about 11 days).
MAX_CLOCK_JUMP_S = 1e6


@dataclass(frozen=True)
class Impairments:
    """What the link does to packets, each way: drop with probability ``loss``, send twice with ``duplicate``,
    swap with the next with ``reorder``, and deliver ``latency_s`` late (wall-clock seconds); seeded."""

    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    latency_s: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate", "reorder"):
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0, hi=0.9))
        object.__setattr__(self, "latency_s", scalar("latency", self.latency_s, lo=0.0, hi=5.0))
        object.__setattr__(self, "seed", int(scalar("seed", self.seed, lo=0, hi=2**63 - 1, integer=True)))


#: The longest simulated flight of the simulated autopilot, in plant steps (its random disturbances are
#: drawn for the whole flight at the start).
MAX_SERIES_STEPS = 1e7


@dataclass(frozen=True)
class SimSettings:
    """The simulated autopilot: ``connect`` (its end of the link), ``autopilot`` (``px4`` or ``ardupilot``),
    ``speed`` (simulated seconds per wall second), ``duration`` (simulated s, None: until stopped),
    ``inject_force_W`` (N, world NED) and ``inject_torque_B`` (N m, body FRD) from ``inject_on`` to
    ``inject_off`` (simulated s), streams it never sends (``no_streams``), the rate of its own controller
    (``control_rate``, Hz: also the fastest stream it serves) and of the plant's RK4 steps (``plant_rate``,
    Hz; 100 Hz keeps one simulated second under a quarter of a core), its system id, and scripted
    ``events`` ``(T, kind, ARG)`` at simulated time T: ``mode`` (a pilot switches to mode ARG), ``stop`` (the
    stream ARG stops for good), ``clock`` (the reported clock jumps by ARG seconds)."""

    connect: str
    autopilot: str = "px4"
    speed: float = 1.0
    duration: float | None = None
    inject_force_W: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inject_torque_B: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inject_on: float = 0.0
    inject_off: float = float("inf")
    impairments: Impairments = field(default_factory=Impairments)
    no_streams: tuple[str, ...] = ()
    events: tuple[tuple[float, str, str], ...] = ()
    control_rate: float = 50.0
    plant_rate: float = 100.0
    system: int = 1
    component: int = 1
    seed: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "speed", scalar("speed", self.speed, lo=0.01, hi=100.0))
        if self.duration is not None:
            object.__setattr__(self, "duration", scalar("duration", self.duration, lo=0.0, lo_open=True))
        object.__setattr__(self, "plant_rate", scalar("plant rate", self.plant_rate, lo=10.0, hi=10000.0))
        if self.duration is not None and self.duration * self.plant_rate > MAX_SERIES_STEPS:
            # the random disturbances are drawn for the whole flight up front (about 46 bytes a step, measured:
            # 1e5 s at 100 Hz took 457 MB): a day at 100 Hz fits, 1e9 s asked for 745 GiB
            raise InputError(
                f"--duration {self.duration:g} s at the plant's {self.plant_rate:g} Hz is {self.duration * self.plant_rate:.3g} "
                f"steps, above {MAX_SERIES_STEPS:.0e} (about a day at 100 Hz): give a shorter --duration, or none (until "
                "Ctrl-C)"
            )
        object.__setattr__(self, "control_rate", scalar("control rate", self.control_rate, lo=10.0, hi=1000.0))
        wall_s = None if self.duration is None else self.duration / self.speed
        if wall_s is not None and self.impairments.latency_s >= wall_s:
            raise InputError(
                f"latency {self.impairments.latency_s:g} s is as long as the whole run ({self.duration:g} simulated s "
                f"at speed {self.speed:g} = {wall_s:g} s of wall time): no packet would arrive; give a longer "
                "--duration or a shorter --latency"
            )
        ratio = self.plant_rate / self.control_rate
        if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-9 * ratio:
            raise InputError(
                f"plant rate ({self.plant_rate:g} Hz) must be a whole multiple of the control rate "
                f"({self.control_rate:g} Hz), at least 1x"
            )
        profile(self.autopilot)
        for name in self.no_streams:
            if name not in SERVED:
                raise InputError(f"--no-stream {name}: not a message this autopilot sends ({', '.join(SERVED)})")
        for name, v, lim in (("inject force (N)", self.inject_force_W, MAX_INJECT_FORCE_N),
                             ("inject torque (N m)", self.inject_torque_B, MAX_INJECT_TORQUE_NM)):  # fmt: skip
            if len(v) != 3 or not all(abs(scalar(name, c)) <= lim for c in v):
                raise InputError(f"{name} must be 3 values within +-{lim:g}, got {v!r}")
        on = scalar("inject on (s)", self.inject_on, lo=0.0)
        if not (self.inject_off > on):  # infinite: never off
            raise InputError(f"the injection must end after it starts, got on {on:g} s, off {self.inject_off!r} s")
        for ev in self.events:
            if len(ev) != 3 or ev[1] not in ("mode", "stop", "clock") or not np.isfinite(float(ev[0])):
                raise InputError(f"an event is (T, mode|stop|clock, ARG), got {ev!r}")
            if ev[1] == "stop" and ev[2] not in SERVED:
                raise InputError(f"event {ev!r}: {ev[2]!r} is not a message this autopilot sends ({', '.join(SERVED)})")
            if ev[1] == "clock":
                try:
                    jump = float(ev[2])
                except ValueError:
                    jump = float("nan")
                if not abs(jump) <= MAX_CLOCK_JUMP_S:
                    raise InputError(f"event {ev!r}: a clock jump is a number of seconds within +-{MAX_CLOCK_JUMP_S:g}")
        object.__setattr__(self, "seed", int(scalar("seed", self.seed, lo=0, hi=2**63 - 1, integer=True)))
        # ids are whole numbers; scripted times lie inside the run (one after its end would silently not happen)
        object.__setattr__(self, "system", int(scalar("system id", self.system, lo=1, hi=254, integer=True)))
        object.__setattr__(self, "component", int(scalar("component id", self.component, lo=1, hi=255, integer=True)))
        end = float("inf") if self.duration is None else self.duration
        for ev in self.events:
            scalar(f"event {ev!r} time (simulated s)", ev[0], lo=0.0, hi=end)
        if self.inject_on >= end:
            raise InputError(
                f"inject on ({self.inject_on:g} s) must be before the end of the run ({end:g} simulated s)"
            )


def _param_id(raw: Any) -> str:
    """A ``param_id`` field as text (16 bytes, NUL-padded when shorter)."""
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes | bytearray) else str(raw)
    return text.split("\x00", 1)[0]


def _lat_lon(p_W: np.ndarray) -> tuple[int, int]:
    """Latitude and longitude (degE7) of the NED point ``p_W`` (m) around home, on a flat Earth."""
    lat = HOME_LAT_DEG + np.degrees(float(p_W[0]) / EARTH_RADIUS_M)
    lon = HOME_LON_DEG + np.degrees(float(p_W[1]) / (EARTH_RADIUS_M * np.cos(np.radians(HOME_LAT_DEG))))
    return int(round(lat * 1e7)), int(round(lon * 1e7))


class _Channel:
    """Outgoing (or incoming) packets through the impairments, released at their due wall time."""

    def __init__(self, imp: Impairments, rng: np.random.Generator) -> None:
        self.imp, self.rng = imp, rng
        self.queue: deque[tuple[float, Any]] = deque()
        self._held: Any = None
        self.counts = {"dropped": 0, "duplicated": 0, "reordered": 0}

    def put(self, item: Any, now: float) -> None:
        imp = self.imp
        if imp.loss and self.rng.random() < imp.loss:
            self.counts["dropped"] += 1
            return
        items = [item]
        if imp.duplicate and self.rng.random() < imp.duplicate:
            items.append(item)
            self.counts["duplicated"] += 1
        if self._held is not None:
            items.append(self._held)
            self._held = None
        elif imp.reorder and self.rng.random() < imp.reorder:
            self._held = items.pop(0)
            self.counts["reordered"] += 1
        for it in items:
            self.queue.append((now + imp.latency_s, it))

    def due(self, now: float) -> list[Any]:
        out = []
        while self.queue and self.queue[0][0] <= now:
            out.append(self.queue.popleft()[1])
        return out


class SimAutopilot:
    """The simulated autopilot (module docstring). :meth:`run` until ``duration`` or :meth:`stop`; the test
    hooks :meth:`pilot_mode`, :meth:`stop_stream` and :meth:`jump_clock` act as a pilot and as faults."""

    @staticmethod
    def open_horizon(dt: float, n_dist: int = 1) -> float:
        """Seconds of disturbance series prepared for a run until stopped, at the plant step ``dt`` (s), for
        ``n_dist`` disturbances (each at most six channels)."""
        return float(min(OPEN_HORIZON_MAX_S, SERIES_BUDGET_BYTES * dt / (6 * 8 * 4 * max(n_dist, 1))))

    def __init__(self, spec: ScenarioSpec, settings: SimSettings) -> None:
        self.spec, self.s = spec, settings
        self.profile: AutopilotProfile = profile(settings.autopilot)
        self.address: Address = parse_address(settings.connect)
        built = build(spec)
        self.built = built
        self.PA = compile_plants(built.plant)
        from dataclasses import replace

        cp = controller_params(replace(spec, control=replace(spec.control, rate=settings.control_rate)), "pd")
        self.CA = compile_controllers(cp)
        self.Ts = float(self.CA.Ts)
        self.n_sub = max(int(round(self.Ts * settings.plant_rate)), 1)
        self.dt = self.Ts / self.n_sub
        self.hold_W = np.array([0.0, 0.0, -float(spec.trajectory.altitude)])
        self.x = initial_state(self.PA, self.hold_W)
        sensors = SensorParams.ideal() if spec.ideal else built.sensors
        self.sensors = SensorSuite(sensors, self.PA, self.dt)
        self.sensors.push(self.x)
        self.noise = NoiseSource([spec.seed])
        # an open-ended run prepares its disturbance series for a bounded horizon (documented: they hold
        # their last value after it)
        horizon = (
            settings.duration if settings.duration is not None else self.open_horizon(self.dt, len(built.disturbances))
        ) + 5.0
        self.series_end_s = horizon
        rng = np.random.default_rng(np.random.SeedSequence([spec.seed, 1]))
        items = [d.prepare(horizon, self.dt, rng) for d in built.disturbances]
        if np.any(settings.inject_force_W) or np.any(settings.inject_torque_B):
            items.append(StepWrench(settings.inject_force_W, settings.inject_torque_B, settings.inject_on,
                                    settings.inject_off))  # fmt: skip
        self.dist = DisturbanceSet(items)
        self.CS = initial_controller_state(self.CA)
        g = built.plant.vehicle.geometry
        self.f_max = np.asarray(g.f_max, dtype=float)
        self.u_max = float(self.f_max.sum())
        self.hover = float((self.PA.mass + self.PA.pend_m) * G / self.u_max)
        # ArduCopter drives its motors through its thrust curve (its parameters); PX4's outputs are linear
        ardu = self.ardu = self.profile.mav_autopilot == 3
        self.motor_curve = MotorCurve.from_params(MOTOR_DEFAULTS) if ardu else None
        #: parameter values by name (the protocol's index is the position here) and their type, range, writability
        self.params: dict[str, float] = {}
        self.param_meta: dict[str, tuple[int, tuple[float, float], bool]] = {}
        for name, (default, ptype, rng_, writable) in PARAMETERS[self.profile.name].items():
            self.params[name] = self.hover if default is None else float(default)
            self.param_meta[name] = (ptype, rng_, writable)
        if ardu:  # a quadrotor's outputs 1..4 are its motors 1..4 (its wiring: read-only here)
            for i in range(1, len(self.f_max) + 1):
                self.params[f"SERVO{i}_FUNCTION"] = 32.0 + i
                self.param_meta[f"SERVO{i}_FUNCTION"] = (INT16, (0.0, 200.0), False)
        self.t = 0.0
        self.ticks = 0  # simulated time is ticks * Ts: no drift of a running sum
        self.clock_offset_s = BOOT_S
        self.mode = "POSCTL" if settings.autopilot == "px4" else "LOITER"
        self.kinds = MODE_KINDS[self.profile.name]
        self.armed = True
        self.landed = False
        self.setpoint: dict[str, Any] | None = None
        #: ArduCopter's altitude target of its climb-rate set-points (m NED, None: start from where it is),
        #: the takeoff's target (m NED) and GUIDED's sub-mode ("pos", "takeoff", "angle")
        self.z_ref: float | None = None
        self.takeoff_z: float | None = None
        self.guided_sub = "pos"
        self.psi_hold = 0.0
        self.throttle_in = 0.0  # ArduCopter's throttle before the angle boost (its ATTITUDE_TARGET.thrust)
        self.rates: dict[str, float] = {}
        for spec_ in self.profile.streams:
            if spec_.message in SERVED and hasattr(mavutil().mavlink, f"MAVLink_{spec_.message.lower()}_message"):
                self.rates[spec_.message] = spec_.default_hz
        self.rates.update(DEFAULT_EXTRA_HZ)
        self.rates["HEARTBEAT"] = 1.0
        self.next_due: dict[str, float] = {}
        self.stopped: set[str] = set(settings.no_streams)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._pending: list[tuple[str, Any]] = []
        # one generator per direction: what is lost on the way up does not depend on how much the vehicle sends
        seed = settings.impairments.seed
        self.down = _Channel(settings.impairments, np.random.default_rng(np.random.SeedSequence([seed, 0])))
        self.up = _Channel(settings.impairments, np.random.default_rng(np.random.SeedSequence([seed, 1])))
        self.last_out: Any = None
        self.history: deque[tuple[float, np.ndarray, np.ndarray, str]] = deque(maxlen=20000)
        self.stats: dict[str, Any] = {"setpoints": 0, "setpoint_latency_s": [], "modes": [(0.0, self.mode)],
                                      "requests": [], "behind_s": 0.0, "sent": 0, "setpoints_unused": 0,
                                      "commands": [], "params_set": [], "params_refused": [],
                                      "params_unknown": []}  # fmt: skip
        self._once: list[str] = []  # messages asked for once (MAV_CMD_REQUEST_MESSAGE), sent at the next tick
        #: packets received by (system, component): the ground stations (and routers) heard
        self.heard: dict[tuple[int, int], int] = {}
        self.conn: Any = None
        self.failure: dict[str, Any] | None = None  # the simulated vehicle's, when it diverged or crashed
        self._events = sorted((float(t), k, a) for t, k, a in settings.events)
        for _, kind, arg in self._events:
            if kind == "mode" and arg not in self.kinds:
                raise InputError(
                    f"event mode {arg!r} is not a mode the simulated {self.profile.name} flies "
                    f"({', '.join(self.kinds)})"
                )
        mav = mavutil().mavlink
        self._sendable = {n for n in SERVED if hasattr(mav, f"MAVLink_{n.lower()}_message")}

    # ------------------------------------------------------------------ hooks (thread-safe)

    def stop(self) -> None:
        self._stop.set()

    def pilot_mode(self, mode: str) -> None:
        """A pilot flips the mode switch."""
        with self._lock:
            self._pending.append(("mode", mode))

    def stop_stream(self, message: str) -> None:
        """The autopilot stops sending ``message`` (a fault)."""
        with self._lock:
            self._pending.append(("stop", message))

    def jump_clock(self, delta_s: float) -> None:
        """The reported clock jumps by ``delta_s`` (a fault, or a reboot when negative)."""
        with self._lock:
            self._pending.append(("jump", float(delta_s)))

    # ------------------------------------------------------------------ link

    def _open(self) -> None:
        mu = mavutil()
        a = self.address
        out, err = io.StringIO(), io.StringIO()
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                if a.kind == "serial":
                    self.conn = mu.mavlink_connection(a.device, baud=a.baud, source_system=self.s.system,
                                                      source_component=self.s.component)  # fmt: skip
                else:
                    self.conn = mu.mavlink_connection(a.text, source_system=self.s.system,
                                                      source_component=self.s.component)  # fmt: skip
        except Exception as exc:
            raise LiveError(f"cannot open {a.text}: {exc}") from None
        self.mav = self.conn.mav
        self.mavlink = mu.mavlink

    def _send(self, msg: Any, wall: float) -> None:
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.down.put(bytes(buf), wall)

    def _flush(self, wall: float) -> None:
        for buf in self.down.due(wall):
            with contextlib.suppress(OSError, ConnectionError):
                self.conn.write(buf)
            self.stats["sent"] += 1

    def _receive(self, wall: float) -> None:
        for _ in range(1000):
            try:
                m = self.conn.recv_msg()
            except (OSError, ConnectionError):
                break
            except Exception:
                continue
            if m is None:
                break
            if m.get_type() != "BAD_DATA":
                src = (m.get_srcSystem(), m.get_srcComponent())
                if src in self.heard or len(self.heard) < 64:  # bounded: a flood of ids is not kept
                    self.heard[src] = self.heard.get(src, 0) + 1
                self.up.put(m, wall)
        for m in self.up.due(wall):
            self._handle(m, wall)

    @property
    def boot_ms(self) -> int:
        return int(round((self.t + self.clock_offset_s) * 1000.0))

    def _ack(self, command: int, result: int, wall: float, target: tuple[int, int]) -> None:
        self._send(self.mavlink.MAVLink_command_ack_message(command, result, 0, 0, target[0], target[1]), wall)
        self.stats["commands"].append((self.t, int(command), int(result)))
        del self.stats["commands"][:-200]

    def _mine(self, m: Any) -> bool:
        """Whether a message is addressed to this vehicle (0: broadcast)."""
        ts = getattr(m, "target_system", self.s.system)
        tc = getattr(m, "target_component", self.s.component)
        return ts in (0, self.s.system) and tc in (0, self.s.component)

    def _handle(self, m: Any, wall: float) -> None:
        typ = m.get_type()
        src = (m.get_srcSystem(), m.get_srcComponent())
        if typ == "TIMESYNC" and m.tc1 == 0:
            self._send(self.mavlink.MAVLink_timesync_message(int(self.boot_ms * 1e6), int(m.ts1)), wall)
        elif not self._mine(m):
            return
        elif typ == "SET_ATTITUDE_TARGET":
            self._attitude_target(m)
        elif typ == "PARAM_REQUEST_READ":
            idx = int(m.param_index)
            names = list(self.params)
            name = names[idx] if 0 <= idx < len(names) else (None if idx >= 0 else _param_id(m.param_id))
            if name in self.params:
                self._param_value(name, wall)
            else:
                self.stats["params_unknown"].append(name if name is not None else idx)
                del self.stats["params_unknown"][:-50]
        elif typ == "PARAM_REQUEST_LIST":
            for name in list(self.params):
                self._param_value(name, wall)
        elif typ == "PARAM_SET":
            self._param_set(_param_id(m.param_id), float(m.param_value), wall)
        elif typ == "SET_MODE":  # the older message: as MAV_CMD_DO_SET_MODE, acknowledged with its message id
            custom = int(m.custom_mode)
            main, sub = (custom, 0) if self.ardu else ((custom >> 16) & 0xFF, (custom >> 24) & 0xFF)
            self._ack(11, self._mode_request(float(m.base_mode), float(main), float(sub)), wall, src)
        elif typ in ("COMMAND_LONG", "COMMAND_INT"):
            p = [float(m.param1), float(m.param2), float(m.param3), float(m.param4)]
            p += [float(m.param5), float(m.param6), float(m.param7)] if typ == "COMMAND_LONG" else \
                [float(m.x), float(m.y), float(m.z)]  # fmt: skip
            self._ack(int(m.command), self._command(int(m.command), p), wall, src)

    def _attitude_target(self, m: Any) -> None:
        """``SET_ATTITUDE_TARGET``: an attitude with a thrust. Set-points that leave out the attitude or the thrust
        (``type_mask`` bits 7, 6: rate set-points, thrust-less) are not flown (counted as unused), nor, as on
        ArduCopter, targets received outside its guided modes."""
        q = np.array(m.q, dtype=float)
        mask = int(getattr(m, "type_mask", 0))
        if self.ardu and self.kinds[self.mode] not in ("guided", "offboard"):  # ArduCopter: GUIDED* only
            self.stats["setpoints_unused"] += 1
            return
        if mask & (64 | 128) or not np.all(np.isfinite(q)) or not np.isfinite(m.thrust) or np.linalg.norm(q) < 0.5:
            self.stats["setpoints_unused"] += 1
            return
        eta = euler_from_rotation(quat_to_rotation(q / np.linalg.norm(q)))
        use_thrust = (not self.ardu) or bool(int(self.params.get("GUID_OPTIONS", 0)) & GUID_THRUST_BIT)
        self.setpoint = {"eta": eta, "t": self.t, "q": q, "raw": float(m.thrust), "use_thrust": use_thrust,
                         "norm": float(np.clip(m.thrust, 0.0, 1.0))}  # fmt: skip
        self.stats["setpoints"] += 1
        lat = (self.boot_ms - int(m.time_boot_ms)) * 1e-3
        if 0 <= lat < 10:
            self.stats["setpoint_latency_s"].append(lat)
            del self.stats["setpoint_latency_s"][:-5000]

    # ------------------------------------------------------------------ parameters

    def _param_value(self, name: str, wall: float) -> None:
        ptype = self.param_meta.get(name, (REAL32,))[0]
        value = self.params[name]
        if ptype != REAL32 and not self.ardu:  # PX4: an integer's bytes in the float field
            value = struct.unpack("<f", struct.pack("<i", int(round(value))))[0]
        names = list(self.params)
        self._send(self.mavlink.MAVLink_param_value_message(name.encode(), value, ptype, len(names),
                                                            names.index(name)), wall)  # fmt: skip

    def _param_set(self, name: str, value: float, wall: float) -> None:
        if name not in self.params:
            return  # as both autopilots: an unknown name is not answered
        ptype, (lo, hi), writable = self.param_meta.get(name, (REAL32, (-np.inf, np.inf), True))
        if ptype != REAL32 and not self.ardu:
            value = float(struct.unpack("<i", struct.pack("<f", value))[0])
        if ptype != REAL32 and np.isfinite(value):
            value = float(round(value))
        ok = writable and np.isfinite(value) and lo <= value <= hi
        if ok and name.startswith("MOT_") and name != "MOT_THST_HOVER":
            try:  # the motors follow the new curve, or the set is refused
                curve = MotorCurve.from_params({**MOTOR_DEFAULTS, **self.params, name: value})
            except InputError:
                ok = False
            else:
                self.motor_curve = curve
        if ok:
            self.params[name] = value
            self.stats["params_set"].append((self.t, name, value))
        else:
            self.stats["params_refused"].append((self.t, name, value))
        self._param_value(name, wall)  # the value held, changed or not

    # ------------------------------------------------------------------ commands

    def _command(self, cmd: int, p: list[float]) -> int:
        """The ``MAV_RESULT`` of one command (``p``: its seven parameters)."""
        mav = self.mavlink
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = self._message_name(p[0])
            if name is None or name in self.stopped or name not in self._sendable:
                return mav.MAV_RESULT_UNSUPPORTED
            us = p[1]
            if not np.isfinite(us):
                return mav.MAV_RESULT_DENIED
            if us < 0:
                self.rates[name] = 0.0
            elif us == 0:
                d = {s.message: s.default_hz for s in self.profile.streams}
                self.rates[name] = d.get(name, DEFAULT_EXTRA_HZ.get(name, 0.0))
            else:
                self.rates[name] = min(1e6 / us, 1.0 / self.Ts)
            self.next_due.pop(name, None)
            self.stats["requests"].append((name, self.rates[name]))
            return mav.MAV_RESULT_ACCEPTED
        if cmd in (mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
                   mav.MAV_CMD_GET_HOME_POSITION):  # fmt: skip
            name = {mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: "AUTOPILOT_VERSION",
                    mav.MAV_CMD_GET_HOME_POSITION: "HOME_POSITION"}.get(cmd) or self._message_name(p[0])  # fmt: skip
            if name is None or name in self.stopped or name not in self._sendable:
                return mav.MAV_RESULT_UNSUPPORTED
            self._once.append(name)
            return mav.MAV_RESULT_ACCEPTED
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] >= 0.5:
                self.armed = True
                return mav.MAV_RESULT_ACCEPTED
            if not self.landed and p[1] != 21196.0:  # an autopilot refuses to disarm in flight unless forced
                return mav.MAV_RESULT_DENIED
            self.armed = False
            return mav.MAV_RESULT_ACCEPTED
        if cmd == mav.MAV_CMD_DO_SET_MODE:
            return self._mode_request(p[0], p[1], p[2])
        if cmd == mav.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(p[6])
        if cmd == mav.MAV_CMD_NAV_LAND:
            if not self.armed or self.landed:
                return mav.MAV_RESULT_DENIED
            self._set_mode(self.profile.land)
            return mav.MAV_RESULT_ACCEPTED
        return mav.MAV_RESULT_UNSUPPORTED

    def _message_name(self, msg_id: float) -> str | None:
        mav = self.mavlink
        if not np.isfinite(msg_id) or int(msg_id) not in mav.mavlink_map:
            return None
        name = mav.mavlink_map[int(msg_id)].msgname
        return name if name in SERVED else None

    def _mode_request(self, base: float, p2: float, p3: float) -> int:
        """``MAV_CMD_DO_SET_MODE`` (base mode, custom mode; PX4: main mode, sub mode): the ``MAV_RESULT``."""
        mav = self.mavlink
        if not (np.isfinite(base) and int(base) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED and np.isfinite(p2)):
            return mav.MAV_RESULT_UNSUPPORTED
        if self.ardu:
            custom = int(p2)
        else:  # PX4: main mode, sub mode (NaN: none)
            custom = (int(p2) << 16) | ((int(p3) if np.isfinite(p3) else 0) << 24)
        names = [k for k, v in self.profile.modes.items() if v == custom]
        if not names:
            return mav.MAV_RESULT_UNSUPPORTED
        mode = names[0]
        kind = self.kinds.get(mode)
        if kind is None:  # a mode of the autopilot this simulation does not fly
            return mav.MAV_RESULT_DENIED
        if mode == self.profile.offboard and not self.ardu:  # PX4 wants a set-point stream first, and arming
            fresh = self.setpoint is not None and self.t - self.setpoint["t"] < OFFBOARD_READY_S
            if not (fresh and self.armed):
                return mav.MAV_RESULT_TEMPORARILY_REJECTED
        if kind == "takeoff":
            return self._takeoff(float("nan"))
        if kind == "land" and self.landed:
            return mav.MAV_RESULT_DENIED
        self._set_mode(mode)
        return mav.MAV_RESULT_ACCEPTED

    def _takeoff(self, alt: float) -> int:
        """``MAV_CMD_NAV_TAKEOFF`` with altitude ``alt`` (param 7; PX4: above mean sea level, NaN:
        ``MIS_TAKEOFF_ALT`` above home; ArduCopter: above home, in GUIDED only). Armed and landed only."""
        mav = self.mavlink
        if not self.armed or not self.landed:
            return mav.MAV_RESULT_DENIED
        if self.ardu:
            if self.kinds.get(self.mode) != "guided" or not (np.isfinite(alt) and 0.0 < alt <= 1000.0):
                return mav.MAV_RESULT_DENIED
            height = alt
        else:
            height = self.params["MIS_TAKEOFF_ALT"] if not np.isfinite(alt) else alt - HOME_ALT_M
            if not 0.0 < height <= 1000.0:
                return mav.MAV_RESULT_DENIED
            self._set_mode("AUTO_TAKEOFF")
        p = self.sensors.measure(np.zeros(12)).p_W
        self.hold_W = np.array([p[0], p[1], float(p[2])])
        self.takeoff_z = -float(height)
        self.guided_sub = "takeoff"
        self.landed = False
        return mav.MAV_RESULT_ACCEPTED

    def _set_mode(self, mode: str) -> None:
        if mode != self.mode:
            kind = self.kinds.get(mode)
            if kind in ("hold", "guided", "land"):  # hold (or land) where it is now, as the autopilot knows it
                self.hold_W = self.sensors.measure(np.zeros(12)).p_W.copy()
            if kind in ("offboard", "guided"):
                self.z_ref = None
                self.guided_sub = "pos"
                self.psi_hold = float(self.sensors.measure(np.zeros(12)).eta[2])
            if kind == "offboard" and self.ardu:  # GUIDED_NOGPS flies attitude targets only
                self.guided_sub = "angle"
            if self.ardu:  # ArduCopter reads attitude targets in its guided modes only: none carried over
                self.setpoint = None
            self.mode = mode
            self.stats["modes"].append((self.t, mode))
            self.next_due["HEARTBEAT"] = self.t  # autopilots announce a mode change at once
            self.next_due["EXTENDED_SYS_STATE"] = self.t

    def _airborne(self) -> bool:
        return bool(origin_kinematics(self.PA, self.x)[0][2] < -LANDED_HEIGHT_M)

    # ------------------------------------------------------------------ simulation

    def _control_tick(self) -> tuple[Any, np.ndarray]:
        noise = self.noise.block(1)[0, 0]
        meas = self.sensors.measure(noise)
        prof = self.profile
        kind = self.kinds[self.mode]
        sp = self.setpoint
        if not self.ardu and kind == "offboard":
            if sp is None or self.t - sp["t"] > self.params["COM_OF_LOSS_T"]:
                self._set_mode(prof.hold)
                kind = "hold"
        if self.ardu and kind == "guided" and sp is not None and self.guided_sub != "angle":
            self.guided_sub, self.z_ref = "angle", None  # an attitude target: GUIDED flies attitude from now on
        on_ground = float(meas.p_W[2]) > -LANDED_HEIGHT_M and abs(float(meas.v_W[2])) < LANDED_SPEED_M_S
        if not self.armed:
            self.landed = self.landed or on_ground
            return None, np.zeros_like(self.f_max)
        angle = kind == "offboard" or (kind == "guided" and self.guided_sub == "angle")
        if angle:
            return self._angle_tick(meas)
        takeoff = kind == "takeoff" or (kind == "guided" and self.guided_sub == "takeoff")
        if self.landed and not takeoff:  # armed on the ground: the motors idle until a takeoff
            return None, np.zeros_like(self.f_max)
        ref_W = self.hold_W.copy()
        if takeoff and self.takeoff_z is not None:
            speed = self.params["WPNAV_SPEED_UP"] * 0.01 if self.ardu else self.params["MPC_TKO_SPEED"]
            ref_W[2] = max(self.takeoff_z, float(meas.p_W[2]) - 0.5 * speed)  # half a second ahead, as landing
            if float(meas.p_W[2]) <= self.takeoff_z + 0.05:  # there: hold (PX4: in AUTO_LOITER)
                self.hold_W[2] = self.takeoff_z
                self.takeoff_z = None
                if self.ardu:
                    self.guided_sub = "pos"
                else:
                    self._set_mode(prof.hold)
                    self.hold_W[2] = ref_W[2] = float(meas.p_W[2])
        elif kind == "land":
            speed = self.params["LAND_SPEED"] * 0.01 if self.ardu else self.params["MPC_LAND_SPEED"]
            ref_W[2] = min(0.0, float(meas.p_W[2]) + speed * 0.5)  # half a second ahead
            if on_ground:  # touched down: disarm (both autopilots do, PX4 after COM_DISARM_LAND)
                self.armed, self.landed = False, True
                return None, np.zeros_like(self.f_max)
        self.CS, out = controller_step(self.CA, self.CS, meas, Reference(ref_W))
        return out, np.asarray(out.f_rotor, dtype=float)

    def _angle_tick(self, meas: Any) -> tuple[Any, np.ndarray]:
        """Attitude set-points (PX4 OFFBOARD; ArduCopter GUIDED, GUIDED_NOGPS) into the attitude loop, with the
        thrust as the autopilot reads it (module docstring)."""
        sp = self.setpoint
        fresh = sp is not None and self.t - sp["t"] <= (self.params["GUID_TIMEOUT"] if self.ardu else np.inf)
        psi = float(sp["eta"][2]) if fresh else self.psi_hold
        rp = np.asarray(sp["eta"][:2], dtype=float) if fresh else np.zeros(2)
        if fresh:
            self.psi_hold = psi
        use_thrust = bool(fresh and sp["use_thrust"])
        if self.ardu:  # the lean is limited to ANGLE_MAX (centidegrees)
            lean_max = np.radians(self.params["ANGLE_MAX"] * 0.01)
            total = float(np.hypot(*rp))
            if total > lean_max:
                rp = rp * lean_max / total
        if use_thrust:
            self.z_ref = None
            thrust = float(np.clip(sp["raw"], 0.0, 1.0)) * self.u_max
            self.throttle_in = thrust / self.u_max
            if self.ardu:
                thrust *= self._angle_boost(meas, rp)
            pos = position_step(self.CA, self.CS, meas, Reference(meas.p_W, meas.v_W, psi=psi))
            pos = pos._replace(thrust_request=np.asarray(thrust), rp_d=rp)
        else:  # ArduCopter's climb rate: its altitude loop (the PD's z axis) tracks a target moving at that rate
            climb = self._climb_rate(sp["raw"]) if fresh else 0.0
            if self.z_ref is None:
                self.z_ref = float(meas.p_W[2])
            self.z_ref -= climb * self.Ts
            p_ref = np.array([meas.p_W[0], meas.p_W[1], self.z_ref])
            v_ref = np.array([meas.v_W[0], meas.v_W[1], -climb])
            pos = position_step(self.CA, self.CS, meas, Reference(p_ref, v_ref, psi=psi))
            self.throttle_in = float(np.clip(pos.thrust_request / self.u_max, 0.0, 1.0))
            pos = pos._replace(thrust_request=pos.thrust_request * self._angle_boost(meas, rp), rp_d=rp)
        # the set-point goes straight into the attitude loop, as the autopilots' attitude interfaces do: the
        # filter on the desired attitude is held at it (its output is the set-point, with no rate)
        self.CS = self.CS._replace(filt=FilterState(rp.copy(), np.zeros(2), True))
        self.CS, out = attitude_step(self.CA, self.CS, meas, Reference(meas.p_W, psi=psi), pos)
        self.landed = False
        return out, np.asarray(out.f_rotor, dtype=float)

    def _climb_rate(self, thrust: float) -> float:
        """ArduCopter's climb rate (m/s, up) of a ``SET_ATTITUDE_TARGET.thrust`` with ``GUID_OPTIONS`` bit 3
        clear: 0.5 holds, above climbs at up to ``WPNAV_SPEED_UP``, below descends at up to ``WPNAV_SPEED_DN``."""
        t = float(np.clip(thrust, 0.0, 1.0))
        if t == 0.5:
            return 0.0
        if t > 0.5:
            return (t - 0.5) * 2.0 * self.params["WPNAV_SPEED_UP"] * 0.01
        return (0.5 - t) * 2.0 * -self.params["WPNAV_SPEED_DN"] * 0.01

    def _angle_boost(self, meas: Any, rp_d: np.ndarray) -> float:
        """ArduCopter's angle boost (``ATC_ANGLE_BOOST``): thrust over the cosine of the target's tilt (at most
        10x), faded out when the vehicle itself is past 84 deg (``10 cos(tilt)`` below 1)."""
        if not self.params.get("ATC_ANGLE_BOOST", 0.0):
            return 1.0
        cos_tilt = float(np.cos(meas.eta[0]) * np.cos(meas.eta[1]))
        cos_target = float(np.cos(rp_d[0]) * np.cos(rp_d[1]))
        return float(np.clip(10.0 * cos_tilt, 0.0, 1.0) / np.clip(cos_target, 0.1, 1.0))

    def _advance(self, f_cmd: np.ndarray) -> None:
        x = apply_instant_rotors(self.PA, self.x, f_cmd)  # a rotor without lag follows its command at once
        for j in range(self.n_sub):
            x = rk4_step(self.PA, x, f_cmd, self.t + j * self.dt, self.dt, self.dist)
            self.sensors.push(x)
        self.x = x
        self.ticks += 1
        self.t = self.ticks * self.Ts

    def _emit(self, out: Any, f_cmd: np.ndarray, wall: float) -> None:
        due = []
        for name, hz in self.rates.items():
            if hz <= 0 or name in self.stopped:
                continue
            nd = self.next_due.get(name, self.t)
            if self.t + 1e-9 >= nd:
                due.append(name)
                self.next_due[name] = max(nd + 1.0 / hz, self.t + 0.5 / hz)
        due += [n for n in self._once if n not in due]
        self._once = []
        if not due:
            return
        meas = self.sensors.measure(np.zeros(12))  # once per tick: what every message of this tick reports
        omega = self.sensors._ago(self.sensors.k_imu)[OMEGA]
        for name in due:
            msg = self._message(name, out, f_cmd, meas, omega)
            if msg is not None:
                self._send(msg, wall)

    def _message(self, name: str, out: Any, f_cmd: np.ndarray, meas: Any, omega: np.ndarray) -> Any:
        """One message of the vehicle now, from what its sensors measure (``meas``, ``omega``; never the true
        state)."""
        mav = self.mavlink
        p, v, eta = meas.p_W, meas.v_W, meas.eta
        ms = self.boot_ms % 2**32
        us = int(round((self.t + self.clock_offset_s) * 1e6))
        kind = self.kinds[self.mode]
        if name == "HEARTBEAT":
            return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, self.profile.mav_autopilot,
                                                 self._base_mode(kind), self.profile.modes[self.mode],
                                                 mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY,
                                                 3)  # fmt: skip
        if name == "ATTITUDE":
            return mav.MAVLink_attitude_message(ms, *eta, *omega)
        if name == "ATTITUDE_QUATERNION":
            return mav.MAVLink_attitude_quaternion_message(ms, *quat_from_euler(eta), *omega)
        if name == "LOCAL_POSITION_NED":
            return mav.MAVLink_local_position_ned_message(ms, *p, *v)
        if name == "ODOMETRY":
            q = quat_from_euler(eta)
            v_B = quat_to_rotation(q).T @ v
            return mav.MAVLink_odometry_message(us, mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_BODY_FRD, *p, q, *v_B,
                                                *omega, [float("nan")] * 21, [float("nan")] * 21)  # fmt: skip
        if name == "ATTITUDE_TARGET":
            sp = self.setpoint
            angle = kind == "offboard" or (kind == "guided" and self.guided_sub == "angle")
            if angle and sp is not None and out is not None:
                q, norm = sp["q"], (self.throttle_in if self.ardu else sp["norm"])
            else:
                q = quat_from_euler(out.eta_d) if out is not None else quat_from_euler(eta)
                norm = float(np.clip(out.thrust_request / self.u_max, 0, 1)) if out is not None else 0.0
            return mav.MAVLink_attitude_target_message(ms, 0, [float(c) for c in q], 0.0, 0.0, 0.0, norm)
        if name == "SERVO_OUTPUT_RAW":
            frac = np.clip(np.asarray(f_cmd) / self.f_max, 0.0, 1.0)
            width = self.motor_curve.pwm(frac) if self.motor_curve is not None else 1000.0 + 1000.0 * frac
            if not self.armed:  # disarmed outputs are not driven
                width = np.zeros_like(frac)
            pwm = ([int(round(w)) for w in width] + [0] * 16)[:16]
            return mav.MAVLink_servo_output_raw_message(us % 2**32, 0, *pwm)
        if name in ("ESC_STATUS", "ESC_TELEMETRY_1_TO_4"):
            f_act = np.clip(self.x[ROTOR], 0.0, None)
            rpm = [int(round(np.sqrt(f / ROTOR_CONSTANT) / RPM)) for f in f_act[:4]]
            if name == "ESC_STATUS":
                return mav.MAVLink_esc_status_message(0, us, rpm, [0.0] * 4, [0.0] * 4)
            return mav.MAVLink_esc_telemetry_1_to_4_message([0] * 4, [0] * 4, [0] * 4, [0] * 4, rpm, [0] * 4)
        if name == "VFR_HUD":
            thr = int(round(100 * float(np.sum(f_cmd)) / self.u_max))
            heading = int(round(np.degrees(eta[2]))) % 360
            return mav.MAVLink_vfr_hud_message(0.0, float(np.hypot(v[0], v[1])), heading, thr,
                                               float(HOME_ALT_M - p[2]), float(-v[2]))  # fmt: skip
        if name == "SYS_STATUS":
            present = SENSORS_PRESENT
            return mav.MAVLink_sys_status_message(present, present, present, 500, 12000, -1, -1, 0, 0, 0, 0, 0, 0)
        if name == "GLOBAL_POSITION_INT":
            lat, lon = _lat_lon(p)
            hdg = int(round(np.degrees(eta[2]) * 100.0)) % 36000
            vel = [int(np.clip(round(c * 100.0), -32767, 32767)) for c in v]
            return mav.MAVLink_global_position_int_message(ms, lat, lon, int(round((HOME_ALT_M - p[2]) * 1000.0)),
                                                           int(round(-p[2] * 1000.0)), *vel, hdg)  # fmt: skip
        if name == "HOME_POSITION":
            lat, lon = _lat_lon(np.zeros(3))
            return mav.MAVLink_home_position_message(lat, lon, int(round(HOME_ALT_M * 1000.0)), 0.0, 0.0, 0.0,
                                                     [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, us)  # fmt: skip
        if name == "EXTENDED_SYS_STATE":
            if self.landed or not self.armed and p[2] > -LANDED_HEIGHT_M:
                landed = mav.MAV_LANDED_STATE_ON_GROUND
            elif kind == "land":
                landed = mav.MAV_LANDED_STATE_LANDING
            elif kind == "takeoff" or (kind == "guided" and self.guided_sub == "takeoff"):
                landed = mav.MAV_LANDED_STATE_TAKEOFF
            else:
                landed = mav.MAV_LANDED_STATE_IN_AIR
            return mav.MAVLink_extended_sys_state_message(mav.MAV_VTOL_STATE_UNDEFINED, landed)
        if name == "AUTOPILOT_VERSION":
            major, minor, patch, typ = FLIGHT_SW_VERSION[self.profile.name]
            sw = (major << 24) | (minor << 16) | (patch << 8) | typ
            return mav.MAVLink_autopilot_version_message(CAPABILITIES[self.profile.name], sw, 0, 0, 0, [0] * 8,
                                                         [0] * 8, [0] * 8, 0, 0, self.s.system, [0] * 18)  # fmt: skip
        return None

    def _base_mode(self, kind: str) -> int:
        """The heartbeat's ``base_mode`` flags as each autopilot sets them: custom mode, armed, stabilised; PX4
        guided and auto (manual input in POSCTL), ArduCopter manual input and guided while its horizontal
        position controller runs."""
        mav = self.mavlink
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        base |= mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0
        if self.ardu:
            base |= mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            if kind in ("hold", "land", "takeoff") or (kind == "guided" and self.guided_sub != "angle"):
                base |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
        elif self.mode == "POSCTL":
            base |= mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | mav.MAV_MODE_FLAG_GUIDED_ENABLED
        else:
            base |= mav.MAV_MODE_FLAG_GUIDED_ENABLED | mav.MAV_MODE_FLAG_AUTO_ENABLED
        return base

    def _apply_pending(self) -> None:
        while self._events and self._events[0][0] <= self.t:
            _, kind, arg = self._events.pop(0)
            {"mode": self.pilot_mode, "stop": self.stop_stream, "clock": lambda a: self.jump_clock(float(a))}[kind](arg)
        with self._lock:
            pending, self._pending = self._pending, []
        for kind, arg in pending:
            if kind == "mode":
                self._set_mode(arg)
            elif kind == "stop":
                self.stopped.add(arg)
            elif kind == "jump":
                self.clock_offset_s += arg

    def run(self, ready: threading.Event | None = None) -> dict[str, Any]:
        """Fly until ``duration`` (simulated) or :meth:`stop`; returns the statistics."""
        self._open()
        wall0 = time.monotonic()
        if ready is not None:
            ready.set()
        try:
            while not self._stop.is_set():
                wall = time.monotonic()
                self._receive(wall)
                self._apply_pending()
                target = (wall - wall0) * self.s.speed
                behind = target - self.t
                if behind > 0.5:  # the computer is too slow for this speed: drop the backlog, say so
                    self.stats["behind_s"] += behind
                    wall0 += behind / self.s.speed
                n = 0
                while self.t + self.Ts <= (time.monotonic() - wall0) * self.s.speed and n < 20:
                    out, f_cmd = self._control_tick()
                    self.last_out = out
                    self._emit(out, f_cmd, time.monotonic())
                    self._advance(f_cmd)
                    code = int(check_vehicles(self.PA, self.x[None])[0])
                    if code:  # stop here: a diverged state is no vehicle to report on
                        self.failure = {"time": self.t, "reason": REASONS[code]}
                        self._stop.set()
                        break
                    p, v = origin_kinematics(self.PA, self.x)
                    self.history.append((self.t, p.copy(), v.copy(), self.mode))
                    n += 1
                    if self.s.duration is not None and self.t >= self.s.duration:
                        self._stop.set()
                        break
                self._flush(time.monotonic())
                nxt = wall0 + (self.t + self.Ts) / self.s.speed
                pause = min(max(nxt - time.monotonic(), 0.0), 0.005)
                if self.down.queue:
                    pause = min(pause, max(self.down.queue[0][0] - time.monotonic(), 0.0))
                fd = getattr(self.conn, "fd", None)
                if pause > 0:
                    if isinstance(fd, int) and fd >= 0:
                        import select

                        with contextlib.suppress(OSError, ValueError):
                            select.select([fd], [], [], pause)
                    else:
                        time.sleep(pause)
            self._flush(float("inf"))
        finally:
            with contextlib.suppress(Exception):
                self.conn.close()
        return self.summary()

    def summary(self) -> dict[str, Any]:
        lat = np.asarray(self.stats["setpoint_latency_s"], dtype=float)
        return {
            "autopilot": self.profile.name,
            "simulated_s": self.t,
            "failure": self.failure,
            "mode": self.mode,
            "modes": self.stats["modes"],
            "setpoints": self.stats["setpoints"],
            "setpoint_latency_ms": {"mean": float(lat.mean() * 1e3), "max": float(lat.max() * 1e3)}
            if lat.size
            else None,
            "stream_rates_hz": {k: v for k, v in self.rates.items() if v > 0 and k not in self.stopped},
            "hover_thrust": self.hover,
            "link": {"down": dict(self.down.counts), "up": dict(self.up.counts), "sent": self.stats["sent"]},
            "behind_real_time_s": self.stats["behind_s"],
            "heard": {f"{k[0]}/{k[1]}": n for k, n in self.heard.items()},
            "params_set": list(self.stats["params_set"]),
            "params_refused": list(self.stats["params_refused"]),
            "setpoints_unused": self.stats["setpoints_unused"],
        }
