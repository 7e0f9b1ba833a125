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
* a gap longer than ``max_gap_s`` in any signal removes the grid points inside it, and the estimator
  restarts after it (``restart``); every such repair is listed in ``notes``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError, SingularityError
from ..model.kinematics import (
    check_euler_regular,
    euler_from_rotation,
    euler_rate_matrix_Q,
    quat_from_euler,
    quat_to_rotation,
)

#: Rate of the uniform grid a log is resampled onto, Hz (``--rate``).
DEFAULT_RATE_HZ = 100.0
#: A longer gap in any signal (s) removes the grid points inside it and restarts the estimator (``--max-gap``).
DEFAULT_MAX_GAP_S = 0.25
#: The longest resampled log: 50 million samples (about 6 days at 100 Hz, some GB of arrays).
MAX_SAMPLES = 50_000_000


@dataclass
class Signal:
    """One signal on its own clock: ``t (N,)`` in seconds, ``values (N, k)``, and where it came from."""

    name: str
    source: str
    t: np.ndarray
    values: np.ndarray
    hold: bool = False  # zero-order hold (a command) instead of interpolation


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
    thrust: Signal
    torque_B: Signal | None
    thrust_unit: str = "N"
    torque_unit: str = "N m"
    torque_per_unit: np.ndarray | None = None
    n_rotors: int | None = None
    hover_thrust: float | None = None  # normalised, from the log
    hover_source: str = ""
    notes: list[str] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)


@dataclass
class FlightLog:
    """Signals on one uniform grid (with holes where a gap was cut). World NED, body FRD, SI units."""

    t: np.ndarray
    v_W: np.ndarray
    eta: np.ndarray
    omega_B: np.ndarray
    eta_dot: np.ndarray
    thrust: np.ndarray  # as in the raw log (N or normalised) until converted
    tau_B: np.ndarray | None
    restart: np.ndarray
    rate_hz: float
    notes: list[str]
    raw: RawLog

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


def _gaps(t: np.ndarray, max_gap: float) -> list[tuple[float, float]]:
    i = np.flatnonzero(np.diff(t) > max_gap)
    return [(float(t[k]), float(t[k + 1])) for k in i]


def _interp(sig: Signal, grid: np.ndarray) -> np.ndarray:
    if sig.hold:
        idx = np.clip(np.searchsorted(sig.t, grid, side="right") - 1, 0, len(sig.t) - 1)
        return sig.values[idx]
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
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    t_start: float | None = None,
    t_end: float | None = None,
) -> FlightLog:
    """Clean every signal and bring them onto one grid at ``rate_hz`` (see the module docstring)."""
    if not (np.isfinite(rate_hz) and 1.0 <= rate_hz <= 10000.0):
        raise InputError(f"resampling rate must be within [1, 10000] Hz, got {rate_hz}")
    if not (np.isfinite(max_gap_s) and max_gap_s >= 2.0 / rate_hz):
        raise InputError(f"max gap must be at least two periods ({2.0 / rate_hz:g} s), got {max_gap_s}")
    notes = list(raw.notes)
    sigs = [raw.velocity_W, raw.attitude, raw.omega_B, raw.thrust] + ([raw.torque_B] if raw.torque_B else [])
    sigs = [clean(s, notes) for s in sigs]
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
    for s in sigs:
        for a, b in _gaps(s.t, max_gap_s):
            inside = (grid > a) & (grid < b)
            if a < hi and b > lo:
                notes.append(f"gap in {s.name} from {a:.3f} s to {b:.3f} s ({b - a:.3f} s): estimator restarted")
            keep &= ~inside
            after = np.searchsorted(grid, b, side="left")
            if after < len(grid):
                restart[after] = True
    if not keep.any():
        raise InputError("every sample falls inside a gap; nothing to estimate")
    grid, restart = grid[keep], restart[keep]
    restart[0] = True
    v_W = _interp(sigs[0], grid)
    eta = _interp_attitude(sigs[1], grid)
    omega_B = _interp(sigs[2], grid)
    thrust = _interp(sigs[3], grid)[:, 0]
    tau_B = _interp(sigs[4], grid) if raw.torque_B else None
    ct = np.abs(np.cos(eta[:, 1]))
    try:
        check_euler_regular(eta)
    except SingularityError as exc:
        k = int(np.argmin(ct))
        raise InputError(f"at t = {grid[k]:.3f} s: {exc}") from None
    eta_dot = np.linalg.solve(euler_rate_matrix_Q(eta), omega_B[..., None])[..., 0]
    return FlightLog(grid, v_W, eta, omega_B, eta_dot, thrust, tau_B, restart, float(rate_hz), notes, raw)
