"""Flight-log signals on their own clocks, cleaned, then resampled onto one uniform time base.

How a log becomes one time base (documented in the README, "Estimating from flight logs"):

* each signal is cleaned on its own clock: rows with a non-finite value are dropped (a NaN stretch becomes
  a gap), repeated timestamps keep the last row; a timestamp that goes backwards is an error, since it
  means concatenated or corrupted logs;
* the grid runs at ``rate_hz`` (default 100 Hz, the paper's control rate) over the span that every
  signal covers;
* velocity and body rates are interpolated linearly (error at most ``dt^2 / 8 * max|x''|`` for a signal
  sampled every ``dt``: 1.25e-3 * max|x''| at 10 Hz), attitude by normalised linear interpolation of the
  quaternion (sign made continuous first), the commands by zero-order hold (a controller output holds
  until the next one, which is what the vehicle flew);
* gaps. A *dropout* is a step between two samples of a signal longer than three of its typical periods
  (the median step). A dropout up to ``max_gap_s`` is **bridged**: the grid runs through it, the
  signal is interpolated linearly across it (commands too: across a dropout the held value is not what
  the vehicle flew), and the estimator carries its state. The momentum change across the gap is
  measured exactly (real samples at both ends); what the bridge cannot know is how the wrench and the
  thrust vector ``x = u R e3`` varied inside. The bridged residual is ``f + x_bridge(s) - mean(x)``
  instead of ``f``, so after a bridged gap of length ``T`` the estimate differs from an uninterrupted one
  by at most ``g_max (E + |dx| T / 4 + dW T / 2)``: ``g_max`` the peak of G's impulse response (``wn / e``
  for the paper's G), ``E <= T^3 / 12 (max|u''| + max|u| max|r''|)`` the impulse of the thrust vector the
  interpolation misses (thrust ``u``, thrust axis ``r = R e3``), ``dx`` the change of the thrust vector
  across the gap (the bridge spreads the impulse as a ramp) and ``dW`` the change of the external wrench
  inside it. A step longer than ``max_gap_s`` (dropout or not) means the data stop: the grid points
  inside are removed and the estimator **restarts** after it. By default ``max_gap_s`` comes from the
  log's own rates: ten periods of its slowest signal, at least 0.5 s, at most 5 s (an 8 Hz log bridges
  its normal 0.3-0.5 s dropouts). Every gap is listed in ``gaps`` and summarised in ``notes``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError, SingularityError, batched, instance, scalar
from ..model.kinematics import (
    check_euler_regular,
    euler_from_rotation,
    euler_rate_matrix_Q,
    quat_from_euler,
    quat_to_rotation,
)

#: Rate of the uniform grid a log is resampled onto, Hz (``--rate``).
DEFAULT_RATE_HZ = 100.0
#: The default ``max_gap_s``: this many periods of the log's slowest signal, within :data:`MAX_GAP_BOUNDS_S`.
MAX_GAP_PERIODS = 10.0
#: Bounds (s) of the default ``max_gap_s``.
MAX_GAP_BOUNDS_S = (0.5, 5.0)
#: A step between samples longer than this many typical periods is a dropout.
DROPOUT_PERIODS = 3.0
#: The fewest grid points an estimate is made on.
MIN_SAMPLES = 10
#: The longest resampled log: 5 million samples (about 14 hours at 100 Hz, longer than any battery flies).
#: Measured: an estimate holds about 0.7 kB per grid sample at its peak (a 2-hour log on a 100 Hz grid: 0.93 GB), so
#: this bounds it near 3.5 GB; the 50 million allowed before would have needed some 35 GB.
MAX_SAMPLES = 5_000_000


@dataclass
class Signal:
    """One signal on its own clock: ``t (N,)`` in seconds, ``values (N, k)``, and where it came from."""

    name: str
    source: str
    t: np.ndarray
    values: np.ndarray
    hold: bool = False  # zero-order hold (a command) instead of interpolation

    def __post_init__(self) -> None:  # types and shapes; NaN rows are a reader's to report, clean() drops them
        instance("name", self.name, str)
        instance("source", self.source, str)
        self.t = batched("t", self.t)
        self.values = batched("values", self.values)
        if self.t.ndim != 1 or self.values.ndim != 2 or self.values.shape[0] != self.t.shape[0]:
            raise InputError(
                f"signal {self.name}: t must be (N,) and values (N, k), "
                f"got t {self.t.shape}, values {self.values.shape}"
            )


@dataclass
class RawLog:
    """What a reader found, already in world NED / body FRD.

    ``attitude`` holds ZYX Euler angles ``eta`` (rad). ``thrust`` is collective thrust in newtons
    (``thrust_unit == "N"``) or normalised (``"normalized"``, 0..1, converted with a hover thrust).
    ``torque`` (optional) is in N m (``torque_unit == "N m"``) or normalised, converted with
    ``torque_per_unit`` (N m per unit normalised torque per newton of a rotor's full thrust).
    """

    velocity_W: Signal
    attitude: Signal
    omega_B: Signal
    thrust: Signal | None
    torque_B: Signal | None
    thrust_unit: str = "N"
    torque_unit: str = "N m"
    torque_per_unit: np.ndarray | None = None
    n_rotors: int | None = None
    hover_thrust: float | None = None  # normalised, a constant from the log (a parameter)
    hover_source: str = ""
    notes: list[str] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    # per-sample normalised hover thrust logged over the flight (an estimate that follows the battery)
    hover: Signal | None = None
    # measured rotor speeds, rad/s, one column per rotor (ESC telemetry, a simulator's rotor states)
    rotor_speed: Signal | None = None
    # rotor geometry from the log: ``(positions_B (n, 3) FRD m, yaw moment per newton (n,), with sign)``
    rotor_geometry: tuple[np.ndarray, np.ndarray] | None = None
    #: the log's parameters (PX4 and ArduPilot), by name
    params: dict[str, float] = field(default_factory=dict)
    # nominal mass and inertia found in the log's parameters, with where they came from
    mass: float | None = None
    inertia: np.ndarray | None = None
    vehicle_source: str = ""
    #: what the reader chose and why (the source of each signal), printed and kept in the report
    choices: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in ("velocity_W", "attitude", "omega_B"):
            instance(name, getattr(self, name), Signal)
        for name in ("thrust", "torque_B", "hover", "rotor_speed"):
            if getattr(self, name) is not None:
                instance(name, getattr(self, name), Signal)
        instance("thrust_unit", self.thrust_unit, str)
        instance("torque_unit", self.torque_unit, str)

    def signals(self) -> list[Signal]:
        """Every signal that goes onto the grid (the commands and rotor speeds present)."""
        out = [self.velocity_W, self.attitude, self.omega_B]
        out += [s for s in (self.thrust, self.torque_B, self.rotor_speed) if s is not None]
        return out


@dataclass
class FlightLog:
    """Signals on one uniform grid (with holes where a gap was cut). World NED, body FRD, SI units."""

    t: np.ndarray
    v_W: np.ndarray
    eta: np.ndarray
    omega_B: np.ndarray
    eta_dot: np.ndarray
    thrust: np.ndarray | None  # as in the raw log (N or normalised) until converted
    tau_B: np.ndarray | None
    restart: np.ndarray
    rate_hz: float
    notes: list[str]
    raw: RawLog
    # grid points inside a bridged dropout of any signal
    bridged: np.ndarray | None = None
    #: every dropout: ``{"signal", "t0_s", "t1_s", "length_s", "action": "bridged" | "restart"}``
    gaps: list[dict[str, Any]] = field(default_factory=list)
    max_gap_s: float = 0.0
    max_gap_source: str = ""
    hover: np.ndarray | None = None
    rotor_speed: np.ndarray | None = None

    @property
    def Ts(self) -> float:  # noqa: N802
        return 1.0 / self.rate_hz


def clean(sig: Signal, notes: list[str]) -> Signal:
    """Drop non-finite rows and repeated timestamps (reported), refuse time going backwards."""
    t = np.asarray(sig.t, dtype=float)
    v = np.asarray(sig.values, dtype=float).reshape(len(t), -1)
    if len(t) == 0:
        raise InputError(f"{sig.name} ({sig.source}) has no samples")
    bad_t = ~np.isfinite(t)
    if bad_t.any():
        raise InputError(f"{sig.name} ({sig.source}): timestamp at row {np.flatnonzero(bad_t)[0]} is not a number")
    back = np.flatnonzero(np.diff(t) < 0)
    if len(back):
        i = back[0]
        raise InputError(
            f"{sig.name} ({sig.source}): time goes backwards at row {i + 1} ({t[i]:.6f} s -> {t[i + 1]:.6f} s); "
            "the log is corrupted or several logs were joined"
        )
    finite = np.all(np.isfinite(v), axis=1)
    if not finite.all():
        notes.append(f"{sig.name}: dropped {int((~finite).sum())} row(s) with NaN or infinite values")
        t, v = t[finite], v[finite]
    dup = np.concatenate([np.diff(t) == 0, [False]])
    if dup.any():
        notes.append(f"{sig.name}: {int(dup.sum())} repeated timestamp(s), kept the last row of each")
        t, v = t[~dup], v[~dup]
    if len(t) < 2:
        raise InputError(f"{sig.name} ({sig.source}) has fewer than two valid samples")
    return Signal(sig.name, sig.source, t, v, sig.hold)


def typical_period(t: np.ndarray) -> float:
    """The median step between samples, s."""
    d = np.diff(t)
    d = d[d > 0]
    return float(np.median(d)) if len(d) else float("inf")


def default_max_gap(sigs: list[Signal]) -> tuple[float, str]:
    """``(max_gap_s, why)`` from the signals' typical periods (see the module docstring)."""
    if not isinstance(sigs, list | tuple) or not sigs or not all(isinstance(s, Signal) for s in sigs):
        raise InputError(f"sigs must be a non-empty list of Signal, got {sigs!r:.80}")
    periods = {s.name: typical_period(s.t) for s in sigs}
    slow = max(periods, key=periods.get)
    lo, hi = MAX_GAP_BOUNDS_S
    value = float(np.clip(MAX_GAP_PERIODS * periods[slow], lo, hi))
    why = (
        f"{value:.3g} s: {MAX_GAP_PERIODS:g} periods of the slowest signal ({slow} at {1.0 / periods[slow]:.3g} Hz), "
        f"within [{lo:g}, {hi:g}] s"
    )
    return value, why


def _dropouts(sig: Signal, rate_hz: float, max_gap_s: float) -> np.ndarray:
    """Indices ``i`` with ``t[i + 1] - t[i]`` a dropout of this signal (or longer than ``max_gap_s``)."""
    limit = max(DROPOUT_PERIODS * typical_period(sig.t), 2.0 / rate_hz)
    return np.flatnonzero(np.diff(sig.t) > min(limit, max_gap_s))


def _interp(sig: Signal, grid: np.ndarray, bridge: float = 0.0) -> np.ndarray:
    """Linear interpolation, or zero-order hold for commands; a command is interpolated linearly across a
    step longer than ``bridge`` (a bridged dropout) instead of held."""
    if sig.hold:
        idx = np.clip(np.searchsorted(sig.t, grid, side="right") - 1, 0, len(sig.t) - 1)
        out = sig.values[idx].copy()
        if bridge > 0:
            nxt = np.minimum(idx + 1, len(sig.t) - 1)
            step = sig.t[nxt] - sig.t[idx]
            lin = (step > bridge) & (nxt > idx)
            if lin.any():
                frac = ((grid[lin] - sig.t[idx[lin]]) / step[lin])[:, None]
                out[lin] = sig.values[idx[lin]] + frac * (sig.values[nxt[lin]] - sig.values[idx[lin]])
        return out
    return np.stack([np.interp(grid, sig.t, sig.values[:, j]) for j in range(sig.values.shape[1])], -1)


def _interp_attitude(sig: Signal, grid: np.ndarray) -> np.ndarray:
    q = quat_from_euler(sig.values)
    flip = np.cumprod(np.where(np.sum(q[1:] * q[:-1], -1) < 0, -1.0, 1.0))
    q[1:] *= flip[:, None]
    qi = np.stack([np.interp(grid, sig.t, q[:, j]) for j in range(4)], -1)
    qi /= np.linalg.norm(qi, axis=-1, keepdims=True)
    return euler_from_rotation(quat_to_rotation(qi))


def resample(
    raw: RawLog,
    rate_hz: float = DEFAULT_RATE_HZ,
    max_gap_s: float | None = None,
    t_start: float | None = None,
    t_end: float | None = None,
) -> FlightLog:
    """Clean every signal and bring them onto one grid at ``rate_hz`` (see the module docstring).

    ``max_gap_s``: dropouts up to this long are bridged, longer ones restart the estimator; ``None``
    (default): from the log's rates (:func:`default_max_gap`).
    """
    from ..errors import instance

    instance("raw", raw, RawLog)
    rate_hz = scalar("resampling rate (rate_hz, Hz)", rate_hz, lo=1.0, hi=10000.0)
    if max_gap_s is not None:
        max_gap_s = scalar("max gap (max_gap_s)", max_gap_s, lo=0.0, lo_open=True)
    if t_start is not None:
        t_start = scalar("t_start", t_start)
    if t_end is not None:
        t_end = scalar("t_end", t_end)
    if not (np.isfinite(rate_hz) and 1.0 <= rate_hz <= 10000.0):
        raise InputError(f"resampling rate must be within [1, 10000] Hz, got {rate_hz}")
    notes = list(raw.notes)
    sigs = [clean(s, notes) for s in raw.signals()]
    if max_gap_s is None:
        max_gap_s, gap_source = default_max_gap(sigs)
    else:
        if not (np.isfinite(max_gap_s) and max_gap_s >= 2.0 / rate_hz):
            raise InputError(f"max gap must be at least two periods ({2.0 / rate_hz:g} s), got {max_gap_s}")
        gap_source = f"{max_gap_s:g} s (given)"
    lo = max(s.t[0] for s in sigs)
    hi = min(s.t[-1] for s in sigs)
    if t_start is not None:
        lo = max(lo, t_start)
    if t_end is not None:
        hi = min(hi, t_end)
    if not hi - lo >= 2.0 / rate_hz:
        spans = ", ".join(f"{s.name} {s.t[0]:.3f}-{s.t[-1]:.3f} s" for s in sigs)
        window = "" if t_start is None and t_end is None else f" inside the window {t_start} to {t_end} s"
        raise InputError(f"the signals share no common time span{window} to estimate over (they cover: {spans})")
    n_grid = int(np.floor((hi - lo) * rate_hz + 1e-9)) + 1
    if n_grid > MAX_SAMPLES:
        raise InputError(
            f"{hi - lo:.6g} s at {rate_hz:g} Hz is {n_grid} samples, above {MAX_SAMPLES}: lower the rate or cut the "
            "log with a start and end time"
        )
    grid = lo + np.arange(n_grid) / rate_hz
    keep = np.ones(len(grid), bool)
    restart = np.zeros(len(grid), bool)
    bridged = np.zeros(len(grid), bool)
    gaps: list[dict[str, Any]] = []
    for s in sigs:
        n_bridged, longest = 0, 0.0
        for i in _dropouts(s, rate_hz, max_gap_s):
            a, b = float(s.t[i]), float(s.t[i + 1])
            if not (a < hi and b > lo):
                continue
            inside = (grid > a) & (grid < b)
            if b - a > max_gap_s:
                keep &= ~inside
                after = np.searchsorted(grid, b, side="left")
                if after < len(grid):
                    restart[after] = True
                gaps.append({"signal": s.name, "t0_s": a, "t1_s": b, "length_s": b - a, "action": "restart"})
                notes.append(f"gap in {s.name} from {a:.3f} s to {b:.3f} s ({b - a:.3f} s): the data stop, "
                             "estimator restarted")  # fmt: skip
            else:
                bridged |= inside
                n_bridged += 1
                longest = max(longest, b - a)
                gaps.append({"signal": s.name, "t0_s": a, "t1_s": b, "length_s": b - a, "action": "bridged"})
        if n_bridged:
            notes.append(
                f"{s.name}: {n_bridged} dropout(s) up to {longest:.3f} s bridged (estimator state carried; "
                f"max gap {max_gap_s:.3g} s)"
            )
    if keep.sum() < MIN_SAMPLES:
        raise InputError(
            f"no usable segment: every sample but {int(keep.sum())} falls inside a gap longer than the max gap "
            f"({max_gap_s:.3g} s, {gap_source}); nothing to estimate (a longer --max-gap bridges them)"
        )
    grid, restart, bridged = grid[keep], restart[keep], bridged[keep]
    restart[0] = True
    by_name = {s.name: s for s in sigs}

    def on_grid(sig: Signal | None) -> np.ndarray | None:
        if sig is None:
            return None
        s = by_name[sig.name]
        return _interp(s, grid, max(DROPOUT_PERIODS * typical_period(s.t), 2.0 / rate_hz))

    v_W = on_grid(raw.velocity_W)
    eta = _interp_attitude(by_name[raw.attitude.name], grid)
    omega_B = on_grid(raw.omega_B)
    thrust = on_grid(raw.thrust)
    thrust = None if thrust is None else thrust[:, 0]
    tau_B = on_grid(raw.torque_B)
    rotor_speed = on_grid(raw.rotor_speed)
    hover = None
    if raw.hover is not None:
        h = clean(raw.hover, notes)
        hover = np.interp(grid, h.t, h.values[:, 0])  # held at its first and last values outside its span
    ct = np.abs(np.cos(eta[:, 1]))
    try:
        check_euler_regular(eta)
    except SingularityError as exc:
        k = int(np.argmin(ct))
        raise InputError(f"at t = {grid[k]:.3f} s: {exc}") from None
    eta_dot = np.linalg.solve(euler_rate_matrix_Q(eta), omega_B[..., None])[..., 0]
    return FlightLog(
        grid, v_W, eta, omega_B, eta_dot, thrust, tau_B, restart, float(rate_hz), notes, raw,
        bridged=bridged, gaps=gaps, max_gap_s=float(max_gap_s), max_gap_source=gap_source, hover=hover,
        rotor_speed=rotor_speed,
    )  # fmt: skip
