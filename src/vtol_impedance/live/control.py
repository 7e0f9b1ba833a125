"""The outer impedance loop offboard: eqs. (16)-(20) with the estimate fed forward, sent as
``SET_ATTITUDE_TARGET`` while the autopilot keeps its own attitude loop, and the safety around it.

The loop (:class:`OuterLoop`) is the simulator's own position stage, :func:`~vtol_impedance.control.impedance.
position_step`: the estimator of eqs. (6)-(13), the position impedance (18a) with ``mu_bar = mu - f_hat/m``
(PD+C) or the programmable impedance of ``comply``, and eq. (16) solved in NED for the collective thrust and
the desired roll and pitch; then the second-order filter on the desired attitude (:func:`~vtol_impedance.
control.attitude_filter.filter_step`). Its estimator is fed the thrust the autopilot reports (the same held
commands as :class:`~.estimator.LiveEstimator`), not the thrust this tool asked for: before the mode switch
the autopilot flies, after it the two agree, so the estimate is continuous through the hand-over.

Safety (:class:`OffboardController`), every default stated with its reason in the README ("Live over
MAVLink"):

* **handshake, never skipped**: the vehicle must be armed (confirmed by its heartbeat; with ``arm`` the tool
  asks and waits for the confirmation); setpoints stream for ``engage_after_s`` (PX4 refuses OFFBOARD without
  them); the mode is requested with ``MAV_CMD_DO_SET_MODE`` and counts only once the heartbeat shows it; any
  step that does not happen within ``handshake_timeout_s`` stops the attempt with the reason, nothing changed;
* **fence**: leaving a cylinder of ``fence_radius_m`` and ``fence_height_m`` around the engagement point, or
  a speed above ``max_speed_m_s``, hands control back;
* **limits**: tilt at most ``tilt_max_deg`` (in eq. (16)), roll/pitch set-points slewed at most
  ``tilt_rate_max_deg_s``, thrust at most ``thrust_rate_max`` weights per second;
* **watchdog**: no estimator tick (telemetry stopped, stale, or its clock stuck) for ``watchdog_s`` hands
  control back (``on_loss``: ``hold`` or ``land``); the reaction time is ``watchdog_s`` plus one poll of the
  link (5 ms);
* **the pilot wins**: a heartbeat in any other mode than the offboard one ends control at once (no command
  is sent after it);
* **hand-back**: on Ctrl-C, at the end of ``--duration`` or on a safety stop the setpoints stop and the hold
  (or land) mode is requested until the heartbeat confirms it; without a link, the autopilot's own offboard
  loss failsafe (PX4 ``COM_OF_LOSS_T``, 1 s) takes over.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..control.attitude_filter import filter_step
from ..control.impedance import ControllerParams, compile_controllers, initial_controller_state, position_step
from ..control.signals import Measurement, Reference
from ..conventions import G
from ..errors import InputError, instance, per_axis, scalar
from ..model.kinematics import euler_rate_matrix_Q, quat_from_euler, wrap_angle
from .estimator import Tick
from .link import MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, MAV_RESULT, Link
from .streams import AutopilotProfile, ThrustMap

#: ``SET_ATTITUDE_TARGET.type_mask``: ignore the three body rates, use the attitude and the thrust.
TYPE_MASK_ATTITUDE_THRUST = 0b0000_0111
#: Seconds between repeats of a mode command that the heartbeat has not confirmed yet.
MODE_RESEND_S = 0.3


@dataclass(frozen=True)
class ControlSettings:
    """Offboard control: the controller and its safety limits (module docstring; README for the reasons).

    ``variant``: ``pdc`` (reject: PD + the estimate fed forward) or ``comply``; ``comply``: fraction per
    world axis (x, y, z) that yields with ``impedance`` = (M_d kg, D_d N s/m, K_d N/m); ``Kp`` (N/m) and
    ``Dp`` (N s/m): the position impedance (18a). Not the paper's 16 and 12: an autopilot's attitude interface
    takes attitude set-points without roll and pitch rate feed-forward (PX4 ignores the rates when an attitude
    is given), so the attitude lags its set-point by about ``2 zeta / wn_o`` (0.11 s for the simulated
    autopilot, more with PX4's default gains) and the paper's Dp/m = 10 1/s position loop oscillates and grows
    (measured on the simulated autopilot); 4 and 5 (Dp/m = 4.2 1/s) settle a 1 N step in about 3 s.
    """

    variant: str = "pdc"
    comply: tuple[float, float, float] = (0.0, 0.0, 0.0)
    impedance: tuple[float, float, float] = (2.0, 6.0, 5.0)
    Kp: float = 4.0
    Dp: float = 5.0
    tilt_max_deg: float = 20.0
    tilt_rate_max_deg_s: float = 180.0
    thrust_rate_max: float = 4.0
    fence_radius_m: float = 1.0
    fence_height_m: float = 0.5
    max_speed_m_s: float = 1.5
    watchdog_s: float = 0.25
    on_loss: str = "hold"
    handshake_timeout_s: float = 3.0
    engage_after_s: float = 0.5
    arm: bool = False

    def __post_init__(self) -> None:
        if self.variant not in ("pdc", "comply"):
            raise InputError(f"--control variant must be pdc (reject) or comply, got {self.variant!r}")
        if self.on_loss not in ("hold", "land"):
            raise InputError(f"--on-loss must be hold or land, got {self.on_loss!r}")
        c = per_axis("comply", self.comply)
        if c.shape != (3,) or np.any((c < 0) | (c > 1)):
            raise InputError(f"comply fractions must be 3 values in [0, 1], got {self.comply!r}")
        for name, lo, hi in (
            ("tilt_max_deg", 1.0, 45.0), ("tilt_rate_max_deg_s", 1.0, 2000.0), ("thrust_rate_max", 0.1, 100.0),
            ("fence_radius_m", 0.05, 1e3), ("fence_height_m", 0.05, 1e3), ("max_speed_m_s", 0.05, 50.0),
            ("watchdog_s", 0.02, 5.0), ("handshake_timeout_s", 0.1, 60.0), ("engage_after_s", 0.0, 10.0),
        ):  # fmt: skip
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=lo, hi=hi))
        for name in ("Kp", "Dp"):  # zero would leave the position to drift: no controller at all
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0, hi=1e4, lo_open=True))
        imp = tuple(self.impedance) if isinstance(self.impedance, list | tuple) else ()
        if len(imp) != 3 or not all(0.0 < scalar("--impedance", v) <= 1e6 for v in imp):
            raise InputError(f"--impedance is M_d kg, D_d N s/m, K_d N/m, each positive, got {self.impedance!r}")

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class OuterLoop:
    """Eqs. (16)-(20) for one vehicle: :func:`position_step` and the attitude filter, nothing else.

    :meth:`step` takes an estimator :class:`Tick` (measurements and the held commands from telemetry) and a
    reference, and returns the collective thrust (N), the filtered desired attitude ``eta_d`` (rad), the
    estimate it fed forward ``f_hat_W`` (N, world NED) and whether the tilt bound of eq. (16) acted.
    """

    def __init__(self, params: ControllerParams) -> None:
        self.params = instance("params", params, ControllerParams)
        self.P = compile_controllers(params)
        self.reset()

    def reset(self) -> None:
        self.S = initial_controller_state(self.P)

    def step(self, tick: Tick, ref: Reference) -> tuple[float, np.ndarray, np.ndarray, bool]:
        eta_dot = np.linalg.solve(euler_rate_matrix_Q(tick.eta), tick.omega_B)
        meas = Measurement(tick.p_W, tick.v_W, tick.eta, eta_dot)
        tau = np.zeros(3) if tick.tau_B is None else np.asarray(tick.tau_B, dtype=float)
        S = self.S._replace(thrust_prev=np.asarray(tick.thrust_N, dtype=float), tau_B_prev=tau)
        pos = position_step(self.P, S, meas, ref)
        filt, rp_d, _, _ = filter_step(self.P.filt, S.filt, pos.rp_d)
        self.S = S._replace(est=pos.est, filt=filt)
        eta_d = np.array([rp_d[0], rp_d[1], float(ref.psi)])
        return float(pos.thrust_request), eta_d, np.asarray(pos.f_hat_W, dtype=float), bool(pos.tilt_limited)


@dataclass
class Command:
    """One set-point as sent: ``thrust_N``, its normalised value, ``eta_d`` (rad) and the tick it answers."""

    t_us: int
    thrust_N: float
    thrust_norm: float
    eta_d: np.ndarray
    f_hat_W: np.ndarray
    p_ref_W: np.ndarray


class OffboardController:
    """The state machine of one offboard session (module docstring).

    States: ``preflight`` (checking arming), ``engaging`` (streaming set-points before the mode request),
    ``requesting`` (mode requested, waiting for the heartbeat), ``active``, and the ends ``handed_back``,
    ``yielded`` (the pilot changed mode), ``failed`` (a handshake step timed out).
    """

    TERMINAL = ("handed_back", "yielded", "failed")

    def __init__(
        self,
        settings: ControlSettings,
        loop: OuterLoop,
        profile: AutopilotProfile,
        thrust_map: ThrustMap,
        mass: float,
        rate_hz: float,
    ) -> None:
        self.s = instance("settings", settings, ControlSettings)
        instance("loop", loop, OuterLoop)
        instance("profile", profile, AutopilotProfile)
        instance("thrust_map", thrust_map, ThrustMap)
        mass = scalar("mass", mass, lo=0.0, lo_open=True)
        rate_hz = scalar("rate_hz", rate_hz, lo=0.0, lo_open=True)
        self.loop = loop
        self.profile = profile
        self.map = thrust_map
        self.mass = mass
        self.period = 1.0 / rate_hz
        self.state = "preflight"
        self.reason = ""
        self.events: list[tuple[float, str]] = []
        self.t_state = 0.0
        self.hold_W: np.ndarray | None = None
        self.psi_d = 0.0
        self.last: Command | None = None
        self.last_tick_wall: float | None = None
        self.commands_sent = 0
        self.handback: dict[str, Any] | None = None
        self._mode_sent = -1e9
        self._arm_sent = -1e9
        self._ack: str = ""
        self._rp_prev: np.ndarray | None = None
        self._u_prev: float | None = None
        self._wanted_mode: str | None = None
        self.max_error_m = 0.0
        self._segment: int | None = None

    def start(self, now: float) -> None:
        """Begin the handshake (the vehicle's heartbeat has been heard)."""
        self.t_state = now
        self.events.append((now, "control requested: checking that the vehicle is armed"))

    # ------------------------------------------------------------------ bookkeeping

    @property
    def sending(self) -> bool:
        return self.state in ("engaging", "requesting", "active")

    @property
    def done(self) -> bool:
        return self.state in self.TERMINAL and (self._wanted_mode is None)

    def _to(self, state: str, now: float, text: str) -> None:
        self.state = state
        self.t_state = now
        self.events.append((now, text))

    def status_lines(self, now: float) -> list[str]:
        s = self.s
        head = f"control: {self.state.upper()}"
        if self.state in self.TERMINAL:
            head += f" ({self.reason})"
        lines = [head + f"  [{s.variant}, fence {s.fence_radius_m:g} m x {s.fence_height_m:g} m, "
                        f"tilt <= {s.tilt_max_deg:g} deg, watchdog {s.watchdog_s:g} s, "
                        f"on loss {s.on_loss}]"]  # fmt: skip
        if self.last is not None and self.hold_W is not None:
            c = self.last
            lines.append(
                f"  set-point: thrust {c.thrust_N:6.2f} N ({c.thrust_norm:.3f}), roll {np.degrees(c.eta_d[0]):+5.1f} "
                f"pitch {np.degrees(c.eta_d[1]):+5.1f} yaw {np.degrees(c.eta_d[2]):+6.1f} deg; hold "
                f"[{self.hold_W[0]:+.2f} {self.hold_W[1]:+.2f} {self.hold_W[2]:+.2f}] m; sent {self.commands_sent}"
            )
        return lines

    # ------------------------------------------------------------------ inputs

    def on_ack(self, msg: Any) -> None:
        if int(msg.command) in (MAV_CMD_DO_SET_MODE, MAV_CMD_COMPONENT_ARM_DISARM):
            self._ack = MAV_RESULT.get(int(msg.result), f"result {msg.result}")

    def on_heartbeat(self, armed: bool, custom_mode: int, now: float, link: Link) -> None:
        mode = self.profile.mode_name(custom_mode)
        if self.state == "preflight" and armed:
            self._to("engaging", now, "armed (confirmed by the heartbeat): streaming set-points")
        elif self.state == "requesting" and mode == self.profile.offboard:
            self._to("active", now, f"{mode} confirmed by the heartbeat: control active")
        elif self.state == "active" and mode != self.profile.offboard:
            self.reason = f"the pilot (or the autopilot) switched to {mode}"
            self._to("yielded", now, self.reason + ": control yielded at once")
        elif self.state == "active" and not armed:
            self.reason = "the vehicle disarmed"
            self._to("yielded", now, self.reason)
        if self._wanted_mode is not None and mode == self._wanted_mode:
            self.events.append((now, f"{mode} confirmed by the heartbeat"))
            if self.handback is not None:
                self.handback["confirmed_s"] = now - self.handback["at"]
            self._wanted_mode = None

    def on_tick(self, tick: Tick, now: float, link: Link, target: tuple[int, int]) -> None:
        """One estimator tick: fence, the loop, limits, and the set-point (while sending)."""
        self.last_tick_wall = now
        if self._segment is not None and tick.segment != self._segment:  # the estimator restarted
            self._rp_prev = self._u_prev = None
            self.loop.reset()
            if self.state == "active":
                self._segment = tick.segment
                return self.hand_back("telemetry restarted (a gap or a jump of the vehicle's clock)", now, link, "hold")
        self._segment = tick.segment
        if self.hold_W is None:
            self.hold_W = np.asarray(tick.p_W, dtype=float).copy()
            self.psi_d = float(tick.eta[2])
        if self.state in self.TERMINAL or self.state == "preflight":
            return
        s = self.s
        e = tick.p_W - self.hold_W
        self.max_error_m = max(self.max_error_m, float(np.linalg.norm(e)))
        if self.state == "active":
            speed = float(np.linalg.norm(tick.v_W))
            if np.hypot(e[0], e[1]) > s.fence_radius_m or abs(e[2]) > s.fence_height_m:
                return self.hand_back(f"fence: {np.linalg.norm(e):.2f} m from the hold point", now, link, "hold")
            if speed > s.max_speed_m_s:
                return self.hand_back(f"speed fence: {speed:.2f} m/s > {s.max_speed_m_s:g}", now, link, "hold")
        ref = Reference(self.hold_W, psi=self.psi_d, comply=np.asarray(s.comply, dtype=float))
        thrust, eta_d, f_hat, _ = self.loop.step(tick, ref)
        # rate limits: roll/pitch slew and thrust slew (the tilt bound acted inside eq. (16))
        rp = eta_d[:2]
        if self._rp_prev is not None:
            step = np.radians(s.tilt_rate_max_deg_s) * self.period
            rp = self._rp_prev + np.clip(wrap_angle(rp - self._rp_prev), -step, step)
        tilt_max = np.radians(s.tilt_max_deg)
        rp = np.clip(rp, -tilt_max, tilt_max)
        if self._u_prev is not None:
            du = s.thrust_rate_max * self.mass * G * self.period
            thrust = float(np.clip(thrust, self._u_prev - du, self._u_prev + du))
        self._rp_prev, self._u_prev = rp, thrust
        eta_cmd = np.array([rp[0], rp[1], self.psi_d])
        norm = self.map.normalised(thrust)
        q = quat_from_euler(eta_cmd)
        link.send(
            link.mavlink.MAVLink_set_attitude_target_message(
                int(tick.t_us // 1000) % 2**32, target[0], target[1], TYPE_MASK_ATTITUDE_THRUST,
                [float(x) for x in q], 0.0, 0.0, 0.0, norm,
            )
        )  # fmt: skip
        self.commands_sent += 1
        self.last = Command(tick.t_us, thrust, norm, eta_cmd, f_hat, self.hold_W.copy())

    # ------------------------------------------------------------------ timing

    def check(self, now: float, link: Link, armed: bool) -> None:
        """Every loop of the session: handshake progress and timeouts, the watchdog, mode repeats."""
        s = self.s
        if self.state == "preflight":
            if armed:
                self._to("engaging", now, "armed (confirmed by the heartbeat): streaming set-points")
            elif not s.arm:
                return self.fail("the vehicle is disarmed: arm it and take off in a position mode, or pass --arm", now)
            elif now - self.t_state > s.handshake_timeout_s:
                return self.fail(
                    f"the vehicle did not arm within {s.handshake_timeout_s:g} s ({self._ack or 'no answer'})", now
                )
            elif now - self._arm_sent > MODE_RESEND_S:
                link.command_long(MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
                self._arm_sent = now
            return
        if self.sending:
            stale = self.last_tick_wall is None or now - self.last_tick_wall > s.watchdog_s
            if stale and (self.last_tick_wall is not None or now - self.t_state > s.watchdog_s):
                age = float("inf") if self.last_tick_wall is None else now - self.last_tick_wall
                if self.state == "active":
                    return self.hand_back(f"watchdog: no telemetry tick for {age:.3f} s", now, link, s.on_loss)
                return self.fail(f"telemetry stopped ({age:.3f} s) before control began", now)
        if self.state == "engaging" and now - self.t_state >= s.engage_after_s and self.commands_sent > 0:
            self._to("requesting", now, f"requesting {self.profile.offboard}")
            self._send_mode(self.profile.offboard, link, now)
        elif self.state == "requesting":
            if now - self.t_state > s.handshake_timeout_s:
                return self.fail(
                    f"the vehicle did not enter {self.profile.offboard} within {s.handshake_timeout_s:g} s "
                    f"({self._ack or 'no answer'}); set-points stopped, nothing else changed", now,
                )  # fmt: skip
            if now - self._mode_sent > MODE_RESEND_S:
                self._send_mode(self.profile.offboard, link, now)
        if self._wanted_mode is not None:
            if self.handback is not None and now - self.handback["at"] > s.handshake_timeout_s:
                self.events.append((now, f"{self._wanted_mode} not confirmed within {s.handshake_timeout_s:g} s: "
                                         "the autopilot's own offboard-loss failsafe takes over"))  # fmt: skip
                self._wanted_mode = None
            elif now - self._mode_sent > MODE_RESEND_S:
                self._send_mode(self._wanted_mode, link, now)

    def _send_mode(self, mode: str, link: Link, now: float) -> None:
        p2, p3 = self.profile.mode_command[mode]
        link.command_long(MAV_CMD_DO_SET_MODE, float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), p2, p3)
        self._mode_sent = now

    # ------------------------------------------------------------------ endings

    def fail(self, reason: str, now: float) -> None:
        self.reason = reason
        self._to("failed", now, reason)

    def hand_back(self, reason: str, now: float, link: Link, action: str = "hold") -> None:
        """Stop the set-points at once and ask for the hold (or land) mode until the heartbeat shows it."""
        if self.state in self.TERMINAL:
            return
        was_active = self.state == "active"
        self.reason = reason
        self._to("handed_back", now, f"{reason}: set-points stopped")
        if not was_active:
            return
        mode = self.profile.hold if action == "hold" else self.profile.land
        last = self.last_tick_wall
        self.handback = {"reason": reason, "mode": mode, "at": now,
                         "since_last_tick_s": None if last is None else now - last}  # fmt: skip
        self._wanted_mode = mode
        self._send_mode(mode, link, now)
