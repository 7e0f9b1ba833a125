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
  step that does not happen within ``handshake_timeout_s`` stops the attempt with the reason (after the mode
  request: with a hold request, as every end, since the request may still be in flight);
* **fence**: leaving a cylinder of ``fence_radius_m`` and ``fence_height_m`` around the engagement point, or
  a speed above ``max_speed_m_s``, hands control back;
* **limits**: tilt at most ``tilt_max_deg`` (in eq. (16)), roll/pitch set-points slewed at most
  ``tilt_rate_max_deg_s``, thrust at most ``thrust_rate_max`` weights per second;
* **watchdog**: no estimator tick (telemetry stopped, stale, or its clock stuck) for ``watchdog_s`` hands
  control back (``on_loss``: ``hold`` or ``land``); the reaction time is ``watchdog_s`` plus one poll of the
  link (5 ms);
* **the pilot wins**: a heartbeat in any other mode than the offboard one ends control at once (no command
  is sent after it);
* **hand-back**: one state machine (``probing``, ``requesting``, ``engaged``, ``handing_back``, then
  ``handed_back`` or ``lost``) on every exit: once a mode request has been sent, any end (Ctrl-C or a
  signal, ``--duration``, a handshake timeout, link loss, the watchdog, the fence, an exception) stops the
  setpoints and requests the hold (or land) mode, repeated with back-off, until a heartbeat confirms it or
  ``handshake_timeout_s`` (at least 3 s) passes (``lost``: the autopilot's own offboard-loss failsafe, PX4
  ``COM_OF_LOSS_T`` or ArduCopter ``GUID_TIMEOUT``, takes over). The screen, the exit code and ``live.json``
  come from it.
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
    ``arm``: arm a disarmed vehicle; ``set_guid_options``: on ArduCopter, set ``GUID_OPTIONS`` bit 3 (thrust as
    thrust) for the session and restore it at the end (without it, a clear bit refuses ``--control``).
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
    set_guid_options: bool = False

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


#: The states of the hand-over (:class:`OffboardController`), in order; the last two end it.
STATES = {
    "probing": "checking that the vehicle is armed, then streaming set-points before the mode request",
    "requesting": "the offboard mode requested, not yet confirmed by a heartbeat",
    "engaged": "the offboard mode confirmed by a heartbeat: this tool flies the outer loop",
    "handing_back": "set-points stopped, the hold (or land) mode requested and repeated, not yet confirmed",
    "handed_back": "a heartbeat confirmed the vehicle out of the offboard mode (in the hold asked for, or in the "
    "pilot's mode), or no mode request was ever sent (nothing to hand back)",
    "lost": "the hold not confirmed within handback_window_s (or the link is gone): the autopilot's own "
    "offboard-loss failsafe takes over",
}
#: How a hand-over ended (``handback["outcome"]``).
OUTCOMES = {
    "confirmed": "the hold (or land) mode asked for, confirmed by a heartbeat",
    "pilot": "a heartbeat showed another mode than the offboard one: the pilot's (or the autopilot's) choice, "
    "never overridden",
    "not_needed": "no mode request was ever sent: nothing to hand back",
    "not_confirmed": "the hold was not confirmed within the bounded time (state lost)",
}
#: What ended control (``cause``): the user's end (``--duration``, Ctrl-C or a signal, the stop event), the
#: pilot (a mode switch, a disarm), a safety check (watchdog, fence, speed, telemetry restart), the handshake
#: (not armed, a step timed out), an exception. The exit code follows from the state and this.
CAUSES = ("end", "pilot", "safety", "handshake", "error")
#: ``MAV_RESULT_IN_PROGRESS``: an acknowledgement that is not the command's answer yet.
MAV_RESULT_IN_PROGRESS = 5
#: Longest wait (s) between repeats of the hold request: it starts at :data:`MODE_RESEND_S` and doubles.
MODE_RESEND_MAX_S = 1.0
#: Shortest wait (s) for the hold's confirmation (``handshake_timeout_s`` when longer): a short handshake
#: timeout on a slow link must not cut the hand-back short.
HANDBACK_MIN_S = 3.0
#: What each autopilot does on its own when the set-points stop and no hold was confirmed.
FAILSAFE = {
    "PX4": "PX4's offboard-loss failsafe takes over (COM_OF_LOSS_T, 1 s by default, then COM_OBL_RC_ACT: "
    "position mode by default)",
    "ArduPilot": "ArduCopter's GUID_TIMEOUT takes over (3 s by default): it levels the vehicle and holds its "
    "altitude in GUIDED_NOGPS, without holding position",
}


class OffboardController:
    """The state machine of one offboard session (module docstring): the one source of the screen's control
    line (:meth:`describe`), the exit code (:attr:`exit_code`) and ``live.json``'s ``control`` (:meth:`record`).

    States (:data:`STATES`): ``probing`` (arming checked, then set-points streamed before the mode request),
    ``requesting``, ``engaged``, ``handing_back``, and the ends ``handed_back`` and ``lost``. Every end after
    a mode request was sent (:meth:`hand_back`, whatever its cause) asks for the hold (or land) mode and
    repeats it (:data:`MODE_RESEND_S` doubling to :data:`MODE_RESEND_MAX_S`) until a heartbeat shows it or
    ``handback_window_s`` passes (``lost``). A heartbeat counts only once no offboard request can still be
    in flight (as many answers to ``DO_SET_MODE`` as offboard requests): a heartbeat older than the request
    would confirm nothing. ``handed_back`` is never claimed without that heartbeat, except when no
    mode request was ever sent (outcome ``not_needed``).
    """

    TERMINAL = ("handed_back", "lost")

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
        self.state = "probing"
        self.reason = ""
        self.cause: str | None = None
        self.events: list[tuple[float, str]] = []
        self.t_state = 0.0
        self.hold_W: np.ndarray | None = None
        self.psi_d = 0.0
        self.last: Command | None = None
        self.last_tick_wall: float | None = None
        self.commands_sent = 0
        self.handback: dict[str, Any] | None = None
        self.mode_seen: tuple[str, float] | None = None  # the latest heartbeat's mode and when it came
        self.offboard_requests = 0
        self.mode_acks = 0
        self._armed = False
        self._t_armed = 0.0
        self._mode_sent = -1e9
        self._arm_sent = -1e9
        self._ack: str = ""
        self._acks_needed = 0
        self._resend_wait = MODE_RESEND_S
        self._next_hold = 0.0
        self._rp_prev: np.ndarray | None = None
        self._u_prev: float | None = None
        self.max_error_m = 0.0
        self._segment: int | None = None

    def start(self, now: float) -> None:
        """Begin the handshake (the vehicle's heartbeat has been heard)."""
        self.t_state = now
        self.events.append((now, "control requested: checking that the vehicle is armed"))

    # ------------------------------------------------------------------ bookkeeping

    @property
    def sending(self) -> bool:
        """Whether set-points are being sent (armed and probing, requesting, engaged)."""
        return (self.state == "probing" and self._armed) or self.state in ("requesting", "engaged")

    @property
    def done(self) -> bool:
        return self.state in self.TERMINAL

    @property
    def handback_window_s(self) -> float:
        """How long (s) the hold is requested before the hand-back counts as ``lost``."""
        return max(self.s.handshake_timeout_s, HANDBACK_MIN_S)

    @property
    def mode_requested(self) -> bool:
        """Whether the offboard mode was ever requested (from then on every end asks for the hold)."""
        return self.offboard_requests > 0

    @property
    def exit_code(self) -> int:
        """0 when a heartbeat confirmed the hand-back (or none was needed) after the user's end or the pilot's
        switch; 3 after a safety stop or a failed handshake, and whenever the state is not ``handed_back``."""
        if self.state == "handed_back" and self.cause in ("end", "pilot"):
            return 0
        return 3

    def _to(self, state: str, now: float, text: str) -> None:
        self.state = state
        self.t_state = now
        self.events.append((now, text))

    def describe(self) -> str:
        """The control line of the screen and of the command's last words, from the state alone."""
        st = self.state.upper().replace("_", " ")
        off = self.profile.offboard
        if self.state == "probing":
            return f"{st} ({'streaming set-points before the mode request' if self._armed else 'checking arming'})"
        if self.state == "requesting":
            return f"{st} {off} (sent {self.offboard_requests}x, not yet confirmed by a heartbeat)"
        if self.state == "engaged":
            return f"{st} ({off} confirmed by the heartbeat)"
        hb = self.handback or {}
        head = f"{st} ({self.reason})"
        if self.state == "handing_back":
            return f"{head}: {hb['mode']} requested {hb['requests']}x, not yet confirmed by a heartbeat"
        if self.state == "lost":
            return f"{head}: {hb.get('lost', '')}"
        outcome = hb.get("outcome")
        if outcome == "not_needed":
            return f"{head}: no mode request was sent, nothing to hand back"
        if outcome == "pilot":
            return (f"{head}: the heartbeat shows {hb['confirmed_mode']} (the pilot's or the autopilot's choice); "
                    "no command sent after it")  # fmt: skip
        return f"{head}: {hb['mode']} confirmed by the heartbeat {hb['confirmed_s']:.3f} s after the request"

    def record(self) -> dict[str, Any]:
        """``live.json``'s account of the hand-over: the state, its cause, the exit code and the line shown."""
        return {"state": self.state, "reason": self.reason, "cause": self.cause, "exit_code": self.exit_code,
                "text": self.describe(), "handback": self.handback, "offboard_requests": self.offboard_requests,
                "mode_acks": self.mode_acks, "last_ack": self._ack or None}  # fmt: skip

    def status_lines(self, now: float) -> list[str]:
        s = self.s
        lines = [f"control: {self.describe()}  [{s.variant}, fence {s.fence_radius_m:g} m x {s.fence_height_m:g} m, "
                 f"tilt <= {s.tilt_max_deg:g} deg, watchdog {s.watchdog_s:g} s, on loss {s.on_loss}]"]  # fmt: skip
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
        cmd, result = int(msg.command), int(msg.result)
        if cmd in (MAV_CMD_DO_SET_MODE, MAV_CMD_COMPONENT_ARM_DISARM):
            self._ack = MAV_RESULT.get(result, f"result {result}")
        if cmd == MAV_CMD_DO_SET_MODE and result != MAV_RESULT_IN_PROGRESS:
            self.mode_acks += 1

    def _settled(self) -> bool:
        """Whether no offboard request can still be in flight: as many ``DO_SET_MODE`` answers as offboard
        requests (in order on the link, an answer to a later hold request also answers for them). No time
        makes up for an answer: a slow link (seconds behind) delivers heartbeats older than the request."""
        return self.mode_acks >= self._acks_needed

    def on_heartbeat(self, armed: bool, custom_mode: int, now: float, link: Link) -> None:
        mode = self.profile.mode_name(custom_mode)
        self.mode_seen = (mode, now)
        off = self.profile.offboard
        if self.state == "probing" and armed and not self._armed:
            self._armed, self._t_armed = True, now
            self.events.append((now, "armed (confirmed by the heartbeat): streaming set-points"))
        elif self.state == "requesting" and mode == off:
            self._to("engaged", now, f"{mode} confirmed by the heartbeat: control engaged")
        elif self.state == "engaged" and mode != off:
            self.reason, self.cause = f"the pilot (or the autopilot) switched to {mode}", "pilot"
            self.handback = {"reason": self.reason, "mode": None, "at": now, "requests": 0, "outcome": "pilot",
                             "confirmed_mode": mode, "confirmed_s": 0.0,
                             "since_last_tick_s": self._since_tick(now)}  # fmt: skip
            self._to("handed_back", now, self.reason + ": control yielded at once, no command sent after it")
        elif self.state == "engaged" and not armed:
            self.hand_back("the vehicle disarmed", now, link, "hold", cause="pilot")
        elif self.state == "handing_back" and self._settled() and mode != off:
            hb = self.handback
            assert hb is not None
            hb["confirmed_mode"], hb["confirmed_s"] = mode, now - hb["at"]
            if mode == hb["mode"]:
                hb["outcome"] = "confirmed"
                self._to("handed_back", now, f"{mode} confirmed by the heartbeat {hb['confirmed_s']:.3f} s after the "
                                             "request")  # fmt: skip
            else:  # the pilot (or the autopilot's own failsafe) chose: never fight it
                hb["outcome"] = "pilot"
                self._to("handed_back", now, f"the heartbeat shows {mode}, not the {hb['mode']} asked for (the "
                                             "pilot's or the autopilot's choice): no more requests")  # fmt: skip

    def on_tick(self, tick: Tick, now: float, link: Link, target: tuple[int, int]) -> None:
        """One estimator tick: fence, the loop, limits, and the set-point (while sending)."""
        self.last_tick_wall = now
        if self._segment is not None and tick.segment != self._segment:  # the estimator restarted
            self._rp_prev = self._u_prev = None
            self.loop.reset()
            if self.state == "engaged":
                self._segment = tick.segment
                return self.hand_back("telemetry restarted (a gap or a jump of the vehicle's clock)", now, link, "hold")
        self._segment = tick.segment
        if self.hold_W is None:
            self.hold_W = np.asarray(tick.p_W, dtype=float).copy()
            self.psi_d = float(tick.eta[2])
        if not self.sending:
            return
        s = self.s
        e = tick.p_W - self.hold_W
        self.max_error_m = max(self.max_error_m, float(np.linalg.norm(e)))
        if self.state == "engaged":
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
        """Every loop of the session: handshake progress and timeouts, the watchdog, the hold's repeats."""
        s = self.s
        if self.state == "probing" and not self._armed:
            if armed:
                self._armed, self._t_armed = True, now
                self.events.append((now, "armed (confirmed by the heartbeat): streaming set-points"))
            elif not s.arm:
                return self.hand_back("the vehicle is disarmed: arm it and take off in a position mode, or pass --arm",
                                      now, link, cause="handshake")  # fmt: skip
            elif now - self.t_state > s.handshake_timeout_s:
                return self.hand_back(f"the vehicle did not arm within {s.handshake_timeout_s:g} s "
                                      f"({self._ack or 'no answer'})", now, link, cause="handshake")  # fmt: skip
            elif now - self._arm_sent > MODE_RESEND_S:
                link.command_long(MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
                self._arm_sent = now
            return
        if self.sending:
            since = self._t_armed if self.state == "probing" else self.t_state
            stale = self.last_tick_wall is None or now - self.last_tick_wall > s.watchdog_s
            if stale and (self.last_tick_wall is not None or now - since > s.watchdog_s):
                age = float("inf") if self.last_tick_wall is None else now - self.last_tick_wall
                if self.state == "engaged":
                    return self.hand_back(f"watchdog: no telemetry tick for {age:.3f} s", now, link, s.on_loss)
                return self.hand_back(f"telemetry stopped ({age:.3f} s) before control began", now, link,
                                      cause="handshake")  # fmt: skip
        off = self.profile.offboard
        if self.state == "probing" and now - self._t_armed >= s.engage_after_s and self.commands_sent > 0:
            self._to("requesting", now, f"requesting {off}")
            self._send_mode(off, link, now)
        elif self.state == "requesting":
            if now - self.t_state > s.handshake_timeout_s:
                return self.hand_back(f"the vehicle did not enter {off} within {s.handshake_timeout_s:g} s "
                                      f"({self._ack or 'no answer'})", now, link, cause="handshake")  # fmt: skip
            if now - self._mode_sent > MODE_RESEND_S:
                self._send_mode(off, link, now)
        elif self.state == "handing_back":
            hb = self.handback
            assert hb is not None
            if now - hb["at"] > self.handback_window_s:
                self._lose(f"not confirmed by a heartbeat within {self.handback_window_s:g} s", now)
            elif now >= self._next_hold:  # on a schedule kept from the first request: no poll's lateness adds up
                self._send_mode(hb["mode"], link, now)
                self._resend_wait = min(2.0 * self._resend_wait, MODE_RESEND_MAX_S)
                self._next_hold += self._resend_wait

    def _send_mode(self, mode: str, link: Link, now: float) -> None:
        p2, p3 = self.profile.mode_command[mode]
        link.command_long(MAV_CMD_DO_SET_MODE, float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), p2, p3)
        self._mode_sent = now
        if mode == self.profile.offboard:
            self.offboard_requests += 1
        elif self.handback is not None:
            self.handback["requests"] += 1

    def _since_tick(self, now: float) -> float | None:
        return None if self.last_tick_wall is None else now - self.last_tick_wall

    # ------------------------------------------------------------------ endings

    def hand_back(self, reason: str, now: float, link: Link, action: str = "hold", cause: str = "safety") -> None:
        """End control, whatever the cause (one of :data:`CAUSES`): the set-points stop at once; after a mode
        request the hold (``action="land"``: land) mode is requested, then repeated by :meth:`check` until a
        heartbeat confirms it or :attr:`handback_window_s` passes. The first cause is kept: a second one (a
        Ctrl-C while handing back) changes nothing."""
        if self.state in self.TERMINAL or self.state == "handing_back":
            return
        if cause not in CAUSES:
            raise InputError(f"cause must be one of {', '.join(CAUSES)}, got {cause!r}")
        self.reason, self.cause = reason, cause
        stopped = ": set-points stopped" if self.commands_sent else ""
        if not self.mode_requested:
            self.handback = {"reason": reason, "mode": None, "at": now, "requests": 0, "outcome": "not_needed",
                             "since_last_tick_s": self._since_tick(now)}  # fmt: skip
            self._to("handed_back", now, f"{reason}{stopped}; no mode request was sent, nothing to hand back")
            return
        mode = self.profile.hold if action == "hold" else self.profile.land
        self.handback = {"reason": reason, "mode": mode, "at": now, "requests": 0, "outcome": None,
                         "confirmed_mode": None, "confirmed_s": None,
                         "since_last_tick_s": self._since_tick(now)}  # fmt: skip
        self._acks_needed = self.offboard_requests  # each offboard request answered: none still in flight
        self._to("handing_back", now, f"{reason}{stopped}; {mode} requested until a heartbeat confirms it")
        self._resend_wait = MODE_RESEND_S
        self._next_hold = now + MODE_RESEND_S
        self._send_mode(mode, link, now)

    def _lose(self, why: str, now: float) -> None:
        hb = self.handback
        assert hb is not None
        seen = "no heartbeat heard"
        if self.mode_seen is not None:
            seen = f"the last heartbeat ({now - self.mode_seen[1]:.1f} s ago) showed {self.mode_seen[0]}"
        if self.mode_acks < self._acks_needed:  # a heartbeat could not count: say why
            seen += f"; {self.mode_acks} of {self._acks_needed} offboard requests answered"
        hb["outcome"] = "not_confirmed"
        hb["lost"] = (f"{hb['mode']} {why} ({hb['requests']} requests; {seen}): "
                      f"{FAILSAFE.get(self.profile.name, 'the autopilot failsafe takes over')}")  # fmt: skip
        self._to("lost", now, hb["lost"])

    def abandon(self, why: str, now: float) -> None:
        """End the wait for the hand-back now (a second interrupt, the session's own end): ``lost`` unless a
        heartbeat already confirmed it or nothing needed handing back."""
        if self.state in self.TERMINAL:
            return
        if self.state != "handing_back":
            self.hand_back(why, now, _NoLink(), cause="error")
            if self.state in self.TERMINAL:
                return
        self._lose(why, now)


class _NoLink:
    """Stands for a link that can no longer send (the hold request of :meth:`OffboardController.abandon`)."""

    def command_long(self, *args: Any) -> None:
        pass
