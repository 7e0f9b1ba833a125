"""A simulated autopilot behind a MAVLink endpoint: the project's simulator flown by its own controller,
streaming what PX4 (or ArduPilot) would, honouring ``SET_ATTITUDE_TARGET`` with its own attitude loop.

What it is made of (nothing new about the physics):

* the plant: the scenario's true vehicle, integrated by :func:`vtol_impedance.sim.plant.rk4_step` with its
  disturbances (:mod:`vtol_impedance.sim.disturbances`, e.g. case B's fan) plus the wrench injected here
  (a :class:`~vtol_impedance.sim.disturbances.StepWrench`);
* the sensors: the scenario's :class:`~vtol_impedance.sim.sensors.SensorSuite` (noise and latency of what the
  autopilot's estimator reports);
* its own flight modes with the project's controller (the scenario's PD, no estimate): position hold
  (``POSCTL``/``AUTO_LOITER``, ArduPilot ``LOITER``) and landing run :func:`~vtol_impedance.control.impedance.
  controller_step`; ``OFFBOARD`` (ArduPilot ``GUIDED_NOGPS``) runs only its attitude loop,
  :func:`~vtol_impedance.control.impedance.attitude_step`, on the received thrust and attitude. Set-points
  older than the autopilot's timeout (PX4 ``COM_OF_LOSS_T`` 1 s, ArduPilot ``GUID_TIMEOUT`` 3 s) send it
  back to position hold.

It starts hovering at the scenario's altitude above the origin, armed, in position hold (a pilot has taken
off), streams at the autopilot's default rates (:mod:`.streams`) and at the rates asked with
``MAV_CMD_SET_MESSAGE_INTERVAL``, answers ``COMMAND_LONG`` (arm, mode, message interval), ``PARAM_REQUEST_READ``
(the hover thrust; as ArduCopter, its motor parameters too) and ``TIMESYNC``, and sends a heartbeat at 1 Hz.
As ArduCopter it drives its motors through ArduCopter's thrust curve with the default parameters
(:class:`~vtol_impedance.logs.MotorCurve`); as PX4 its PWM is linear in thrust. The link can lose, repeat, reorder and
delay packets (:class:`Impairments`), both ways. ``speed`` runs the simulation faster than real time (the
vehicle's clock runs with it).
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..control.attitude_filter import FilterState
from ..control.impedance import (
    PositionStage,
    attitude_step,
    compile_controllers,
    controller_step,
    initial_controller_state,
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
#: Descent speed of the landing mode, m/s.
LAND_SPEED_M_S = 0.5
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
    "SERVO_OUTPUT_RAW", "ESC_STATUS", "ESC_TELEMETRY_1_TO_4", "VFR_HUD", "SYS_STATUS",
)  # fmt: skip
DEFAULT_EXTRA_HZ = {"VFR_HUD": 4.0, "SYS_STATUS": 1.0}
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
        # ArduCopter drives its motors through its thrust curve (its default parameters); PX4's outputs are linear
        ardu = self.profile.mav_autopilot == 3
        self.motor_curve = MotorCurve.from_params(MOTOR_DEFAULTS) if ardu else None
        self.params = {self.profile.hover_param: self.hover, **(MOTOR_DEFAULTS if ardu else {})}
        if ardu:  # a quadrotor's outputs 1..4 are its motors 1..4
            self.params.update({f"SERVO{i}_FUNCTION": 32.0 + i for i in range(1, len(self.f_max) + 1)})
        self.t = 0.0
        self.ticks = 0  # simulated time is ticks * Ts: no drift of a running sum
        self.clock_offset_s = BOOT_S
        self.mode = "POSCTL" if settings.autopilot == "px4" else "LOITER"
        self.armed = True
        self.setpoint: dict[str, Any] | None = None
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
        self.rng = np.random.default_rng(settings.impairments.seed)
        self.down = _Channel(settings.impairments, self.rng)
        self.up = _Channel(settings.impairments, self.rng)
        self.last_out: Any = None
        self.history: deque[tuple[float, np.ndarray, np.ndarray, str]] = deque(maxlen=20000)
        self.stats: dict[str, Any] = {"setpoints": 0, "setpoint_latency_s": [], "modes": [(0.0, self.mode)],
                                      "requests": [], "behind_s": 0.0, "sent": 0}  # fmt: skip
        self.conn: Any = None
        self.failure: dict[str, Any] | None = None  # the simulated vehicle's, when it diverged or crashed
        self._events = sorted((float(t), k, a) for t, k, a in settings.events)
        for _, kind, arg in self._events:
            if kind == "mode" and arg not in self.profile.modes:
                raise InputError(
                    f"event mode {arg!r} is not a {self.profile.name} mode ({', '.join(self.profile.modes)})"
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
                self.up.put(m, wall)
        for m in self.up.due(wall):
            self._handle(m, wall)

    @property
    def boot_ms(self) -> int:
        return int(round((self.t + self.clock_offset_s) * 1000.0))

    def _ack(self, command: int, result: int, wall: float, target: tuple[int, int]) -> None:
        self._send(self.mavlink.MAVLink_command_ack_message(command, result, 0, 0, target[0], target[1]), wall)

    def _handle(self, m: Any, wall: float) -> None:
        typ = m.get_type()
        src = (m.get_srcSystem(), m.get_srcComponent())
        mine = getattr(m, "target_system", self.s.system) in (0, self.s.system)
        if typ == "TIMESYNC" and m.tc1 == 0:
            self._send(self.mavlink.MAVLink_timesync_message(int(self.boot_ms * 1e6), int(m.ts1)), wall)
        elif typ == "SET_ATTITUDE_TARGET" and mine:
            q = np.array(m.q, dtype=float)
            if np.linalg.norm(q) < 0.5 or not np.all(np.isfinite(q)) or not np.isfinite(m.thrust):
                return
            eta = euler_from_rotation(quat_to_rotation(q / np.linalg.norm(q)))
            self.setpoint = {"eta": eta, "thrust": float(np.clip(m.thrust, 0.0, 1.0)) * self.u_max, "t": self.t,
                             "q": q, "norm": float(np.clip(m.thrust, 0.0, 1.0))}  # fmt: skip
            self.stats["setpoints"] += 1
            lat = (self.boot_ms - int(m.time_boot_ms)) * 1e-3
            if 0 <= lat < 10:
                self.stats["setpoint_latency_s"].append(lat)
                del self.stats["setpoint_latency_s"][:-5000]
        elif typ == "PARAM_REQUEST_READ" and mine:
            pid = m.param_id.decode() if isinstance(m.param_id, bytes) else str(m.param_id)
            pid = pid.rstrip("\x00")
            if pid in self.params:
                self._send(self.mavlink.MAVLink_param_value_message(pid.encode(), self.params[pid], 9, 1, 0), wall)
        elif typ == "COMMAND_LONG" and mine:
            self._command(m, wall, src)

    def _command(self, m: Any, wall: float, src: tuple[int, int]) -> None:
        cmd = int(m.command)
        mav = self.mavlink
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = mav.mavlink_map[int(m.param1)].msgname if int(m.param1) in mav.mavlink_map else None
            if name is None or name not in SERVED or name in self.stopped or name not in self._sendable:
                return self._ack(cmd, mav.MAV_RESULT_UNSUPPORTED, wall, src)
            us = float(m.param2)
            if us < 0:
                self.rates[name] = 0.0
            elif us == 0:
                d = {s.message: s.default_hz for s in self.profile.streams}
                self.rates[name] = d.get(name, DEFAULT_EXTRA_HZ.get(name, 0.0))
            else:
                self.rates[name] = min(1e6 / us, 1.0 / self.Ts)
            self.next_due.pop(name, None)
            self.stats["requests"].append((name, self.rates[name]))
            return self._ack(cmd, mav.MAV_RESULT_ACCEPTED, wall, src)
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if m.param1 < 0.5 and self._airborne():  # an autopilot refuses to disarm in flight
                return self._ack(cmd, mav.MAV_RESULT_DENIED, wall, src)
            self.armed = bool(m.param1 >= 0.5)
            return self._ack(cmd, mav.MAV_RESULT_ACCEPTED, wall, src)
        if cmd == mav.MAV_CMD_DO_SET_MODE:
            key = (float(m.param2), float(m.param3))
            names = [k for k, v in self.profile.mode_command.items() if (float(v[0]), float(v[1])) == key]
            if not names:
                return self._ack(cmd, mav.MAV_RESULT_UNSUPPORTED, wall, src)
            mode = names[0]
            if mode == self.profile.offboard:
                fresh = self.setpoint is not None and self.t - self.setpoint["t"] < OFFBOARD_READY_S
                if not (fresh and self.armed):
                    return self._ack(cmd, mav.MAV_RESULT_TEMPORARILY_REJECTED, wall, src)
            self._set_mode(mode)
            return self._ack(cmd, mav.MAV_RESULT_ACCEPTED, wall, src)
        return self._ack(cmd, mav.MAV_RESULT_UNSUPPORTED, wall, src)

    def _set_mode(self, mode: str) -> None:
        if mode != self.mode:
            if mode in (self.profile.hold, "POSCTL", "LOITER"):
                self.hold_W = origin_kinematics(self.PA, self.x)[0].copy()
            self.mode = mode
            self.stats["modes"].append((self.t, mode))
            self.next_due["HEARTBEAT"] = self.t  # autopilots announce a mode change at once

    def _airborne(self) -> bool:
        return bool(origin_kinematics(self.PA, self.x)[0][2] < -0.05)

    # ------------------------------------------------------------------ simulation

    def _control_tick(self) -> tuple[Any, np.ndarray]:
        noise = self.noise.block(1)[0, 0]
        meas = self.sensors.measure(noise)
        prof = self.profile
        sp = self.setpoint
        if self.mode == prof.offboard:
            if sp is None or self.t - sp["t"] > prof.setpoint_timeout_s:
                self._set_mode(prof.hold)
        if not self.armed:
            out = None
            f_cmd = np.zeros_like(self.f_max)
        elif self.mode == prof.offboard and sp is not None:
            ref = Reference(self.hold_W, psi=np.asarray(sp["eta"][2]))
            # the set-point goes straight into the attitude loop, as PX4's offboard attitude mode does: the
            # filter on the desired attitude is held at it (its output is the set-point, with no rate)
            rp = np.asarray(sp["eta"][:2], dtype=float)
            self.CS = self.CS._replace(filt=FilterState(rp.copy(), np.zeros(2), True))
            z3 = np.zeros(3)
            pos = PositionStage(self.CS.est, z3, z3, np.asarray(sp["thrust"]), np.asarray(sp["eta"][:2]),
                                np.asarray(False), z3, z3)  # fmt: skip
            self.CS, out = attitude_step(self.CA, self.CS, meas, ref, pos)
            f_cmd = out.f_rotor
        else:
            ref_W = self.hold_W.copy()
            if self.mode == prof.land:
                ref_W[2] = min(0.0, float(meas.p_W[2]) + LAND_SPEED_M_S * 0.5)
                if not self._airborne() and abs(float(meas.v_W[2])) < 0.1:
                    self.armed = False
            self.CS, out = controller_step(self.CA, self.CS, meas, Reference(ref_W))
            f_cmd = out.f_rotor
        return out, np.asarray(f_cmd, dtype=float)

    def _advance(self, f_cmd: np.ndarray) -> None:
        x = apply_instant_rotors(self.PA, self.x, f_cmd)  # a rotor without lag follows its command at once
        for j in range(self.n_sub):
            x = rk4_step(self.PA, x, f_cmd, self.t + j * self.dt, self.dt, self.dist)
            self.sensors.push(x)
        self.x = x
        self.ticks += 1
        self.t = self.ticks * self.Ts

    def _emit(self, out: Any, f_cmd: np.ndarray, wall: float) -> None:
        mav = self.mavlink
        due = []
        for name, hz in self.rates.items():
            if hz <= 0 or name in self.stopped:
                continue
            nd = self.next_due.get(name, self.t)
            if self.t + 1e-9 >= nd:
                due.append(name)
                self.next_due[name] = max(nd + 1.0 / hz, self.t + 0.5 / hz)
        if not due:
            return
        meas = self.sensors.measure(np.zeros(12))
        p, v, eta = meas.p_W, meas.v_W, meas.eta
        omega = self.sensors._ago(self.sensors.k_imu)[OMEGA]
        ms = self.boot_ms % 2**32
        us = int(round((self.t + self.clock_offset_s) * 1e6))
        for name in due:
            if name == "HEARTBEAT":
                base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
                msg = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, self.profile.mav_autopilot, base,
                                                    self.profile.modes[self.mode], mav.MAV_STATE_ACTIVE, 3)  # fmt: skip
            elif name == "ATTITUDE":
                msg = mav.MAVLink_attitude_message(ms, *eta, *omega)
            elif name == "ATTITUDE_QUATERNION":
                q = quat_from_euler(eta)
                msg = mav.MAVLink_attitude_quaternion_message(ms, *q, *omega)
            elif name == "LOCAL_POSITION_NED":
                msg = mav.MAVLink_local_position_ned_message(ms, *p, *v)
            elif name == "ODOMETRY":
                q = quat_from_euler(eta)
                v_B = quat_to_rotation(q).T @ v
                msg = mav.MAVLink_odometry_message(us, mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_BODY_FRD, *p, q, *v_B,
                                                   *omega, [float("nan")] * 21, [float("nan")] * 21)  # fmt: skip
            elif name == "ATTITUDE_TARGET":
                if self.mode == self.profile.offboard and self.setpoint is not None:
                    q, norm = self.setpoint["q"], self.setpoint["norm"]
                else:
                    q = quat_from_euler(out.eta_d) if out is not None else quat_from_euler(eta)
                    norm = float(np.clip(out.thrust_request / self.u_max, 0, 1)) if out is not None else 0.0
                msg = mav.MAVLink_attitude_target_message(ms, 0, [float(c) for c in q], 0.0, 0.0, 0.0, norm)
            elif name == "SERVO_OUTPUT_RAW":
                frac = np.clip(np.asarray(f_cmd) / self.f_max, 0.0, 1.0)
                width = self.motor_curve.pwm(frac) if self.motor_curve is not None else 1000.0 + 1000.0 * frac
                pwm = ([int(round(w)) for w in width] + [0] * 16)[:16]
                msg = mav.MAVLink_servo_output_raw_message(us % 2**32, 0, *pwm)
            elif name in ("ESC_STATUS", "ESC_TELEMETRY_1_TO_4"):
                f_act = np.clip(self.x[ROTOR], 0.0, None)
                rpm = [int(round(np.sqrt(f / ROTOR_CONSTANT) / RPM)) for f in f_act[:4]]
                if name == "ESC_STATUS":
                    msg = mav.MAVLink_esc_status_message(0, us, rpm, [0.0] * 4, [0.0] * 4)
                else:
                    msg = mav.MAVLink_esc_telemetry_1_to_4_message([0] * 4, [0] * 4, [0] * 4, [0] * 4, rpm, [0] * 4)
            elif name == "VFR_HUD":
                thr = int(round(100 * float(np.sum(f_cmd)) / self.u_max))
                msg = mav.MAVLink_vfr_hud_message(0.0, float(np.hypot(v[0], v[1])), 0, thr, float(-p[2]), float(-v[2]))
            elif name == "SYS_STATUS":
                msg = mav.MAVLink_sys_status_message(0, 0, 0, 500, 12000, -1, -1, 0, 0, 0, 0, 0, 0)
            else:
                continue
            self._send(msg, wall)

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
        }
