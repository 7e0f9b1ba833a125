"""The estimator of eqs. (6)-(13) run online on MAVLink telemetry, and the same run offline on a recording.

Telemetry arrives asynchronously, each stream at its own rate, late, sometimes lost, duplicated or out of
order. :class:`LiveEstimator` turns it into the uniform sampling the estimator assumes (eq. (11) runs at a
fixed period ``Ts``):

* **clock**: the vehicle's (``time_boot_ms``, ``time_usec``), never the computer's; ticks fall on whole
  multiples of ``Ts`` of it. A jump of that clock (a reboot, a reset) restarts the estimator.
* **zero-order hold at the tick**: at tick ``t_k`` each measurement (attitude and rates, velocity) is its
  latest sample at or before ``t_k``; the command (thrust, outputs or rotor speeds) is its latest sample
  strictly before ``t_k``: the one that was held over the period that just ended, as eq. (8) wants.
* **ticks wait for the measurements**: a tick is computed once every measurement stream has reported at or
  after it (so a late packet of one stream does not hide behind another); commands never hold ticks back.
* **gaps**: two consecutive samples of a measurement more than ``max_gap_s`` apart, or a command older than
  ``command_stale_s``, restart the estimator (a new segment), as ``estimate --max-gap`` does.
* **late and repeated packets**: a sample not newer than the latest of its stream is dropped and counted.

Every decision depends only on the messages and their order, so feeding a recorded ``.tlog`` in file order
(:func:`replay`) reproduces the live estimate exactly: this one class is the live and the offline path.
Memory is bounded: each stream keeps the last :data:`RING` samples.
"""

from __future__ import annotations

import contextlib
import io
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..errors import InputError, SingularityError, choice, instance, path_like, scalar
from ..estimator.momentum import EstimatorParams
from ..logs.ardupilot import MotorCurve
from ..runtime import Estimator
from .streams import GATING, Decoder, Sample, ThrustMap, VehicleClock, command_role

#: Samples kept per stream (a ring buffer): 1.3 s at 50 Hz, far more than any tick waits for.
RING = 64
#: Events kept for the display and the run folder.
EVENTS_KEPT = 200


@dataclass(frozen=True)
class EstimatorSettings:
    """The online estimator: tick ``rate_hz`` (Hz), filter ``params`` (eq. (10), paper: wn = 10 rad/s,
    zeta = 1), the longest gap in a measurement stream before a restart (s), the oldest command used (s),
    and the backend (``compiled`` or ``numpy``, the same numbers)."""

    rate_hz: float = 50.0
    params: EstimatorParams = field(default_factory=EstimatorParams)
    max_gap_s: float = 0.25
    command_stale_s: float = 1.0
    backend: str = "compiled"

    def __post_init__(self) -> None:
        object.__setattr__(self, "rate_hz", scalar("rate_hz (estimator rate)", self.rate_hz, lo=1.0, hi=1000.0))
        object.__setattr__(self, "max_gap_s", scalar("max_gap_s", self.max_gap_s, lo=0.0, hi=10.0, lo_open=True))
        object.__setattr__(
            self, "command_stale_s", scalar("command_stale_s", self.command_stale_s, lo=0.0, lo_open=True)
        )
        if not isinstance(self.params, EstimatorParams):
            raise InputError(f"params must be an EstimatorParams, got {type(self.params).__name__}")
        choice("backend", self.backend, ("compiled", "numpy"))

    def to_dict(self) -> dict[str, Any]:
        return {"rate_hz": self.rate_hz, "params": self.params.to_dict(), "max_gap_s": self.max_gap_s,
                "command_stale_s": self.command_stale_s, "backend": self.backend}  # fmt: skip

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EstimatorSettings:
        p = dict(d["params"])
        p.pop("poles", None)
        wn = np.asarray(p.pop("wn"), dtype=float)
        zeta = np.asarray(p.pop("zeta"), dtype=float)
        return cls(d["rate_hz"], EstimatorParams(wn=wn, zeta=zeta, **p), d["max_gap_s"], d["command_stale_s"],
                   d.get("backend", "compiled"))  # fmt: skip


class Tick(NamedTuple):
    """One estimator sample at vehicle time ``t_us``: the held inputs and the estimate.

    ``p_W``, ``v_W`` (m, m/s, world NED), ``eta`` (rad, ZYX), ``omega_B`` (rad/s, body FRD), ``thrust_N`` and
    ``tau_B`` (N m, body FRD; ``None`` without per-rotor commands) held over the period that ended at
    ``t_us``; ``f_hat_W`` (N, world NED), ``tau_hat_eta`` (N m, Euler coordinates, eq. (5b)) and
    ``tau_hat_B`` (N m, body FRD; NaN without a torque). ``segment`` counts restarts.
    """

    t_us: int
    segment: int
    p_W: np.ndarray
    v_W: np.ndarray
    eta: np.ndarray
    omega_B: np.ndarray
    thrust_N: float
    tau_B: np.ndarray | None
    f_hat_W: np.ndarray
    tau_hat_eta: np.ndarray
    tau_hat_B: np.ndarray


CSV_COLUMNS = (
    "t_s", "segment", "fx_W_N", "fy_W_N", "fz_W_N", "taux_B_Nm", "tauy_B_Nm", "tauz_B_Nm", "taux_eta_Nm",
    "tauy_eta_Nm", "tauz_eta_Nm", "thrust_N", "vx_W_m_s", "vy_W_m_s", "vz_W_m_s", "roll_rad", "pitch_rad",
    "yaw_rad",
)  # fmt: skip


def csv_row(t: Tick) -> list[float]:
    return [t.t_us * 1e-6, t.segment, *t.f_hat_W, *t.tau_hat_B, *t.tau_hat_eta, t.thrust_N, *t.v_W, *t.eta]


class LiveEstimator:
    """Feed it the vehicle's messages in arrival order (:meth:`feed`); it returns the ticks they complete.

    ``sources`` maps each role to the message chosen for it (:func:`~.streams.choose_sources`), ``thrust_map``
    turns commands into newtons and newton metres, ``mass`` and ``inertia_B`` are the *nominal* vehicle's.
    """

    def __init__(
        self,
        mass: float,
        inertia_B: Any,
        thrust_map: ThrustMap,
        sources: dict[str, str],
        n_rotors: int,
        settings: EstimatorSettings | None = None,
    ) -> None:
        self.settings = EstimatorSettings() if settings is None else instance("settings", settings, EstimatorSettings)
        instance("thrust_map", thrust_map, ThrustMap)
        instance("sources", sources, dict)
        n_rotors = scalar("n_rotors", n_rotors, lo=1, integer=True)
        s = self.settings
        self.estimator = Estimator(mass, inertia_B, 1.0 / s.rate_hz, s.params, backend=s.backend)
        self.map = thrust_map
        self.sources = dict(sources)
        self.command = command_role(self.sources)
        self.decoder = Decoder(self.sources, n_rotors, thrust_map.motor_curve, thrust_map.motor_channels)
        self.clock = VehicleClock()
        self.period_us = int(round(1e6 / s.rate_hz))
        self.max_gap_us = int(round(s.max_gap_s * 1e6))
        self.stale_us = int(round(s.command_stale_s * 1e6))
        roles = set(GATING) | {self.command}
        self.buffers: dict[str, deque[tuple[int, tuple]]] = {r: deque(maxlen=RING) for r in roles}
        self.next_tick_us: int | None = None
        self.segment = -1
        self._fresh = True
        self.counts = {"samples": 0, "late": 0, "repeated": 0, "ticks": 0, "restarts": 0, "clock_jumps": 0,
                       "rejected": 0}  # fmt: skip
        self.events: deque[tuple[int, str]] = deque(maxlen=EVENTS_KEPT)
        self.last: Tick | None = None

    # ------------------------------------------------------------------ input

    def feed(self, msg: Any) -> list[Tick]:
        sample, jump = self.decoder.decode(msg, self.clock)
        if jump is not None:
            self.counts["clock_jumps"] += 1
            self._event(f"vehicle clock jumped {'back' if jump == 'back' else 'ahead'}: estimator restarted")
            for b in self.buffers.values():
                b.clear()
            self.next_tick_us = None
            self._restart()
        if sample is None:
            return []
        return self.push(sample)

    def push(self, sample: Sample) -> list[Tick]:
        buf = self.buffers.get(sample.role)
        if buf is None:
            return []
        if buf and sample.t_us <= buf[-1][0]:
            self.counts["repeated" if sample.t_us == buf[-1][0] else "late"] += 1
            return []
        buf.append((sample.t_us, sample.value))
        self.counts["samples"] += 1
        return self._advance()

    # ------------------------------------------------------------------ ticks

    def _event(self, text: str) -> None:
        self.events.append((self.clock.latest_us or 0, text))

    def _restart(self) -> None:
        self.estimator.reset()
        self._fresh = True

    def _advance(self) -> list[Tick]:
        if any(not self.buffers[r] for r in GATING):
            return []
        frontier = min(self.buffers[r][-1][0] for r in GATING)
        if self.next_tick_us is None:
            start = max(self.buffers[r][0][0] for r in GATING)
            self.next_tick_us = -(-start // self.period_us) * self.period_us
        out = []
        while self.next_tick_us <= frontier:
            t = self.next_tick_us
            self.next_tick_us += self.period_us
            tick = self._tick(t)
            if tick is not None:
                out.append(tick)
        return out

    @staticmethod
    def _around(buf: deque, t: int, strict: bool = False) -> tuple[tuple[int, tuple] | None, int | None]:
        """The latest sample at (or strictly before) ``t`` and the time of the one after it."""
        after = None
        for ts, val in reversed(buf):
            if ts < t or (ts == t and not strict):
                return (ts, val), after
            after = ts
        return None, after

    def _tick(self, t: int) -> Tick | None:
        held = {}
        for role in GATING:
            s, after = self._around(self.buffers[role], t)
            if s is None or (after is not None and after - s[0] > self.max_gap_us) or t - s[0] > self.max_gap_us:
                gap = (after - s[0]) * 1e-6 if s is not None and after is not None else float("nan")
                self._event(f"gap in the {role} stream ({gap:.3g} s): estimator restarted")
                self._restart()
                if after is not None:  # skip to where the stream resumed
                    self.next_tick_us = max(self.next_tick_us, -(-after // self.period_us) * self.period_us)
                return None
            held[role] = s[1]
        c, _ = self._around(self.buffers[self.command], t, strict=True)
        if c is None:
            return None
        if t - c[0] > self.stale_us:
            if not self._fresh:
                self._event(f"{self.sources[self.command]} older than {self.stale_us * 1e-6:g} s: estimator restarted")
            self._restart()
            return None
        eta, omega_B = held["attitude"]
        p_W, v_W = held["velocity"]
        if self.command == "thrust":
            thrust, tau_B = self.map.thrust(c[1][0]), None
        elif self.command == "outputs":
            thrust, tau_B = self.map.wrench_from_outputs(c[1][0])
        else:
            thrust, tau_B = self.map.wrench_from_rpm(c[1][0])
        if self._fresh:
            self.segment += 1
            self.counts["restarts"] += self.segment > 0
        try:
            out = self.estimator.step(v_W, eta, thrust, tau_B, omega_B=omega_B)
        except (InputError, SingularityError) as exc:
            self.counts["rejected"] += 1
            self._event(f"sample rejected ({exc}): estimator restarted")
            self._restart()
            return None
        self._fresh = False
        self.counts["ticks"] += 1
        tick = Tick(t, self.segment, p_W, v_W, eta, omega_B, thrust, tau_B, out.f_hat_W, out.tau_hat_eta,
                    out.tau_hat_B)  # fmt: skip
        self.last = tick
        return tick


# --------------------------------------------------------------------------- offline


def estimator_from_config(cfg: dict[str, Any]) -> LiveEstimator:
    """The :class:`LiveEstimator` a session used, from the ``estimator`` section of its ``live.json``."""
    e = cfg["estimator"]
    m = e["thrust_map"]
    curve = MotorCurve.from_dict(m["motor_curve"]) if m.get("motor_curve") else None
    chans = tuple(m["motor_channels"]) if m.get("motor_channels") else None
    tmap = ThrustMap(m["mass"], m["hover"], m["max_thrust"], m["rotor_constant"], np.asarray(e["effectiveness"]),
                     curve, chans)  # fmt: skip
    return LiveEstimator(e["mass"], np.asarray(e["inertia_B"]), tmap, e["sources"], int(e["n_rotors"]),
                         EstimatorSettings.from_dict(e["settings"]))  # fmt: skip


def replay(folder: str | Path, backend: str | None = None) -> tuple[list[Tick], LiveEstimator]:
    """Re-run a session's estimate from its run folder: ``flight.tlog`` read with pymavlink in file order,
    the messages of the vehicle from the first frame the live estimate saw, fed to the same
    :class:`LiveEstimator` built from ``live.json``."""
    import json

    from .link import mavutil

    folder = path_like("folder", folder)
    if backend is not None:
        choice("backend", backend, ("compiled", "numpy"))
    try:
        cfg = json.loads((folder / "live.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{folder} is not a live run folder (live.json: {exc})") from None
    if backend is not None:
        cfg["estimator"]["settings"]["backend"] = backend
    est = estimator_from_config(cfg)
    target = tuple(cfg["vehicle"]["system_component"])
    first_us = int(cfg["estimator"]["first_frame_us"])
    mu = mavutil()
    ticks: list[Tick] = []
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        log = mu.mavlink_connection(str(folder / "flight.tlog"))
        try:
            while True:
                m = log.recv_msg()
                if m is None:
                    break
                if m.get_type() == "BAD_DATA" or int(round(m._timestamp * 1e6)) < first_us:
                    continue
                if (m.get_srcSystem(), m.get_srcComponent()) != target:
                    continue
                ticks.extend(est.feed(m))
        finally:
            log.close()
    return ticks, est
