"""Conventions checked against physics before estimating.

A wrong convention (a quaternion read in the wrong order or direction, degrees read as radians, ENU read
as NED, milliseconds read as seconds) gives an estimate that looks plausible and is wrong. Three
physical facts hold in every flight, whatever the wrench, and each convention error breaks at least one:

* **kinematics**: the logged body rates are the attitude's rate of change, ``[w_B]x = R^T dR/dt`` (both
  averaged over 0.5 s). The score ``kin`` is the RMS of their difference over the sum of their RMS (0:
  they agree; about 1: opposite, as from a mirrored attitude, unrelated, or off by a large factor). The
  per-axis gain tells a scale error: about 1000 for milliseconds read as seconds, 57.3 for deg/s read as
  rad/s, -1 for a mirrored attitude.
* **gravity**: the thrust axis points along the specific force ``g e3 - a`` that the velocity shows, up
  to the external force (a few degrees): ``tilt`` is the median angle between them; an upside-down or
  tumbling attitude (a quaternion read in the wrong order, degrees read as radians) gives tens of
  degrees. The fitted thrust gain ``k`` of ``a = g e3 - k u R e3`` must be positive.
* **dynamics**: the acceleration follows thrust and attitude, ``a = g e3 - k u R e3 + f/m``: the measured
  acceleration and the one thrust and attitude predict must correlate positively, horizontally and
  vertically (their fast parts, a 10 s moving average removed so that a slow external force does not
  count; ``dyn = 1 - correlation``, 0 to 2). A mirrored tilt or a velocity in the wrong world frame
  gives a negative correlation; angles 57 times too small none. Where the vehicle only rejects a
  disturbance (it tilts against a force and does not move) the correlation says little, and a flight
  without enough acceleration leaves it out.

Plus the time base: every signal's rate must be plausible for a flight log (0.5 Hz to 20 kHz). The score
sums these (``Evidence.score``) with two priors that only rank readings: body rates whose RMS is below
0.003 rad/s (no flying vehicle is that still: radians read as degrees) and mixed frames or units (the
velocity in another world frame than the attitude, the rates in another unit than the angles).

A log is scored under its declared conventions and, where the reader can re-read it under others (a
CSV file), under every combination of the conventions that apply to it. The declared set passes when no
other set fits clearly better; otherwise the error names the difference, its most likely cause and the
flags that fix it. ``--conventions auto`` takes the best set, keeping the declared value of any convention
the data cannot decide (for instance the world frame of a log with no horizontal acceleration), and
reports what it chose. Separately :func:`check_thrust_signal` refuses a thrust column of zeros or one held
constant and treats a stretch the logger froze as a dropout (idle thrust on the ground, saturation, and a
thrust quantised to a few hundred levels, such as MAVLink's whole-percent throttle, repeat values honestly
and are left alone).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..conventions import G
from ..errors import InputError
from ..model.kinematics import quat_from_euler, quat_to_rotation
from .frames import ANGLE_UNITS, BODIES, QUAT_DIRECTIONS, QUAT_ORDERS, TIME_UNITS, WORLDS, Conventions
from .timeseries import DROPOUT_PERIODS, RawLog, Signal, clean, typical_period

MODES = ("check", "auto", "unchecked")
EVAL_RATE_HZ = 50.0
EVAL_MAX_SAMPLES = 20000
HP_WINDOW_S = 10.0
SMOOTH_S = 0.5
OMEGA_FLOOR = 1e-4  # rad/s: keeps the kinematic score defined for a log with no rotation at all
ACCEL_FLOOR = 0.05  # m/s^2: likewise for the dynamic score
RATE_RANGE_HZ = (0.5, 20000.0)
#: The kinematic score needs the attitude to move this much (RMS rate of change, rad/s).
KIN_MOTION = 0.02
#: A flying multirotor's body rates have at least this RMS (gyro noise and vibration alone), rad/s.
MIN_FLIGHT_RATE = 0.003
#: The dynamic score needs this much fast acceleration (RMS, m/s^2) to say anything.
DYN_MOTION = 0.03

CAUSES = {
    ("quat_direction", "world-to-body"): "the attitude looks mirrored (is the quaternion world-to-body?)",
    ("quat_direction", "body-to-world"): "the attitude looks mirrored (is the quaternion body-to-world?)",
    ("quat_order", "xyzw"): "the quaternion looks scalar-last (x, y, z, w), read as scalar-first",
    ("quat_order", "wxyz"): "the quaternion looks scalar-first (w, x, y, z), read as scalar-last",
    ("angle_unit", "deg"): "the angles look like degrees read as radians",
    ("angle_unit", "rad"): "the angles look like radians read as degrees",
    ("rate_unit", "deg"): "the body rates look like deg/s read as rad/s",
    ("rate_unit", "rad"): "the body rates look like rad/s read as deg/s",
    ("time_unit", "s"): "time looks like seconds",
    ("time_unit", "ms"): "time looks like milliseconds",
    ("time_unit", "us"): "time looks like microseconds",
    ("time_unit", "ns"): "time looks like nanoseconds",
    ("world", "enu"): "the attitude's world frame looks ENU (z up), read as NED",
    ("world", "ned"): "the attitude's world frame looks NED (z down), read as ENU",
    ("velocity_world", "enu"): "the velocity looks ENU (z up), read as NED",
    ("velocity_world", "ned"): "the velocity looks NED (z down), read as ENU",
    ("body", "flu"): "the body frame looks FLU (z up), read as FRD",
    ("body", "frd"): "the body frame looks FRD (z down), read as FLU",
}
CHOICES = {
    "world": WORLDS,
    "velocity_world": WORLDS,
    "body": BODIES,
    "angle_unit": ANGLE_UNITS,
    "rate_unit": ANGLE_UNITS,
    "quat_order": QUAT_ORDERS,
    "quat_direction": QUAT_DIRECTIONS,
    "time_unit": tuple(TIME_UNITS),
}


@dataclass
class Evidence:
    """How well one reading of a log agrees with physics (module docstring)."""

    kin: float
    kin_gain: np.ndarray
    kin_motion: float
    rate_rms: float
    tilt_rad: float
    thrust_gain: float
    dyn: np.ndarray  # horizontal, vertical
    dyn_motion: np.ndarray
    rates_hz: dict[str, float]
    time_ok: bool
    span_s: float = 0.0  # first to last time stamp of the signals
    jump: tuple[float, float] = (0.0, 0.0)  # the longest step between two samples of a signal, and where, s
    #: per body axis: the kinematic relative residual and the axis's RMS rate, rad/s (the whole score is
    #: dominated by the axis that turns most: a fast yaw hides roll and pitch rates of another quantity)
    kin_axis: np.ndarray = field(default_factory=lambda: np.zeros(3))
    kin_axis_motion: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: the dropouts left no stretch of a second to check (the scores are then not measured)
    no_stretch: bool = False

    @property
    def measured(self) -> bool:
        """Whether the reading left enough of a flight to score (read in milliseconds, a 40 s log at 10 Hz
        lasts 0.04 s: nothing to score is not a perfect fit)."""
        return bool(np.isfinite(self.kin))

    @property
    def score(self) -> float:
        """Lower is better: about 0.2-0.8 for a consistent log, several units for a contradiction."""
        s = 0.0 if self.time_ok else 100.0
        if self.kin_motion > KIN_MOTION:
            s += self.kin
        if self.rate_rms < MIN_FLIGHT_RATE:
            s += 3.0
        for d, m in zip(self.dyn, self.dyn_motion, strict=True):
            if m > DYN_MOTION:
                s += float(d)
        s += self.tilt_rad / 0.15
        if not self.thrust_gain > 0:
            s += 10.0
        return float(s)

    def symptoms(self) -> list[str]:
        """What contradicts physics, in words."""
        out = []
        if not self.time_ok:
            rates = ", ".join(f"{k} {v:.3g} Hz" for k, v in self.rates_hz.items())
            if all(RATE_RANGE_HZ[0] <= r <= RATE_RANGE_HZ[1] for r in self.rates_hz.values()):
                step, at = self.jump
                out.append(
                    f"the time stamps span {self.span_s:.3g} s ({self.span_s / 86400:.3g} days), no flight's length, "
                    f"although the signals run at flight rates ({rates}): they jump by {step:.3g} s at "
                    f"t = {at:.6g} s (a clock reset, or logs joined); split the file there (or estimate one part "
                    "with --start/--end and --conventions unchecked, the conventions then unchecked)"
                )
            else:
                out.append(f"the time base is implausible for a flight log (signal rates {rates})")
        if self.rate_rms < MIN_FLIGHT_RATE:
            out.append(
                f"the body rates never exceed a few thousandths of a rad/s (RMS {self.rate_rms:.2g} rad/s): no flying "
                "vehicle is that still"
            )
        if self.kin_motion > KIN_MOTION and self.kin > 0.5:
            g = ", ".join(f"{x:.3g}" for x in self.kin_gain)
            out.append(
                f"the body rates disagree with the attitude's rate of change (relative residual {self.kin:.2f}; "
                f"gain per axis {g}, 1 expected)"
            )
        if self.tilt_rad > 0.35 or not self.thrust_gain > 0:
            out.append(
                f"the thrust axis is {np.degrees(self.tilt_rad):.0f} deg away from the specific force the velocity "
                "shows (a few degrees expected)"
            )
        for d, m, where in zip(self.dyn, self.dyn_motion, ("horizontal", "vertical"), strict=True):
            if m > DYN_MOTION and d > 1.3:
                out.append(
                    f"the {where} acceleration runs against the one thrust and attitude predict (correlation "
                    f"{1 - d:+.2f}; near +1 expected)"
                )
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "kinematic_residual": round(self.kin, 4),
            "kinematic_gain": [round(float(x), 4) for x in self.kin_gain],
            "tilt_deg": round(float(np.degrees(self.tilt_rad)), 3),
            "acceleration_correlation": [round(1.0 - float(x), 4) for x in self.dyn],
            "score": round(self.score, 4),
        }


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over ``n`` samples along axis 0 (shrinking at the ends)."""
    if n <= 1:
        return x
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), 0)
    i = np.arange(len(x))
    a = np.clip(i - n // 2, 0, len(x))
    b = np.clip(i + (n - n // 2), 0, len(x))
    return (c[b] - c[a]) / (b - a).reshape((-1,) + (1,) * (x.ndim - 1))


def _windows(sigs: list[Signal], lo: float, hi: float, rate: float) -> list[np.ndarray]:
    """Evaluation grids: the whole span, or the most dynamic stretches of a long log."""
    n = int((hi - lo) * rate)
    if n <= EVAL_MAX_SAMPLES:
        return [lo + np.arange(max(n, 2)) / rate]
    chunk = 40.0
    starts = np.arange(lo, hi - chunk, chunk)
    v = sigs[0]
    act = []
    for s0 in starts:
        sel = (v.t >= s0) & (v.t < s0 + chunk)
        act.append(float(np.std(v.values[sel], 0).sum()) if sel.sum() > 2 else 0.0)
    best = np.argsort(act)[::-1][: max(1, int(EVAL_MAX_SAMPLES / (chunk * rate)))]
    return [s0 + np.arange(int(chunk * rate)) / rate for s0 in np.sort(starts[best])]


def _split_at_dropouts(grids: list[np.ndarray], sigs: list[Signal], rate: float) -> list[np.ndarray]:
    """The grids cut where a signal drops out (a step over :data:`~.timeseries.DROPOUT_PERIODS` of its
    typical period, as the resampler counts a dropout, and longer than the checks' own averaging,
    :data:`SMOOTH_S`): interpolating across one invents a motion that contradicts the other signals, and a
    correct log with a gap in an agile stretch would read as a wrong column. Pieces shorter than a second
    are left out."""
    cuts = []
    for s in sigs:
        if len(s.t) > 1:
            d = np.diff(s.t)
            k = np.flatnonzero(d > max(DROPOUT_PERIODS * typical_period(s.t), SMOOTH_S))
            cuts.extend(zip(s.t[k], s.t[k + 1], strict=True))
    if not cuts:
        return grids
    out = []
    for g in grids:
        bad = np.zeros(len(g), dtype=bool)
        for a, b in cuts:
            bad |= (g > a) & (g < b)
        edges = np.flatnonzero(np.diff(np.concatenate([[1], bad.astype(np.int8), [1]])))  # starts, ends of good runs
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a >= max(rate, 3):
                out.append(g[a:b])
    return out


#: A body-rate sample further than this many robust standard deviations (1.4826 MAD over 7 samples) from its
#: neighbours' median, and more than :data:`SPIKE_FLOOR` rad/s, while both its neighbours are not, is a
#: glitch (a garbled sample): the checks take the median there. Only in a gyro logged at
#: :data:`SPIKE_MIN_RATE_HZ` or faster, where no turn lasts a single sample (at 10 Hz a real 0.3 s yaw turn
#: spans three samples, and a flip can span one).
SPIKE_SIGMAS = 8.0
SPIKE_FLOOR = 0.5
SPIKE_MIN_RATE_HZ = 100.0


def _despiked(t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values (N, k)`` sampled at ``t`` with isolated one-sample glitches replaced by their neighbours'
    median (:data:`SPIKE_SIGMAS`); unchanged below :data:`SPIKE_MIN_RATE_HZ`."""
    import scipy.ndimage

    if len(values) < 7 or 1.0 / typical_period(t) < SPIKE_MIN_RATE_HZ:
        return values
    med = scipy.ndimage.median_filter(values, size=(7, 1), mode="nearest")
    dev = np.abs(values - med)
    mad = scipy.ndimage.median_filter(dev, size=(7, 1), mode="nearest")
    out = dev > np.maximum(SPIKE_SIGMAS * 1.4826 * mad, SPIKE_FLOOR)
    alone = out.copy()
    alone[1:] &= ~out[:-1]
    alone[:-1] &= ~out[1:]
    return np.where(alone, med, values)


def _interval_means(t: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The mean of the signal ``values (N, k)`` (linear between its samples ``t``) over each interval of
    ``grid``: ``(len(grid) - 1, k)``. What the attitude's change over the interval integrates, and a filter
    with a null at every multiple of the grid's rate: a gyro sampled at single points aliased its rotors'
    vibration near 100 or 150 Hz to almost 0 Hz on the 50 Hz grid, which no averaging removed (a correct
    log with 0.2 rad/s at 100.3 Hz scored 0.54 on the kinematic test)."""
    area = np.concatenate([np.zeros((1, values.shape[1])),
                           np.cumsum(0.5 * (values[1:] + values[:-1]) * np.diff(t)[:, None], 0)])  # fmt: skip
    at = np.stack([np.interp(grid, t, area[:, j]) for j in range(values.shape[1])], -1)
    return np.diff(at, axis=0) / np.diff(grid)[:, None]


def _drag_part(sf: np.ndarray, ub: np.ndarray, v: np.ndarray, air: np.ndarray) -> np.ndarray:
    """Minus the drag's share of the specific force ``sf = g e3 - a`` (world NED, m/s^2), to be added to it
    before the thrust axis is compared with it: ``sf = k ub - f/m`` with ``-f/m = D_j v_j + D2_j |v| v_j`` per
    axis, fitted jointly with ``k`` by least squares on the airborne samples; an axis whose fit pushes along
    its velocity (no drag does) keeps none. In steady fast flight the thrust tilts against the drag while the
    specific force stays vertical: a correct agile log with drag of a third of its weight read 18 degrees
    between them and was taken for angles in degrees. A wrong column gives an error in phase with the
    acceleration, which a force in phase with the velocity cannot take."""
    if air.sum() < 10 or not np.any(v[air]):
        return np.zeros_like(sf)
    q = np.linalg.norm(v, axis=-1, keepdims=True) * v
    n = int(air.sum())
    X = np.zeros((3 * n, 7))
    X[:, 0] = ub[air].ravel()
    for j in range(3):
        X[j::3, 1 + j] = v[air, j]
        X[j::3, 4 + j] = q[air, j]
    coef = np.linalg.lstsq(X, sf[air].ravel(), rcond=None)[0]
    share = coef[1:4] * v + coef[4:7] * q  # -f / m: sf = k ub + share
    opposes = np.sum(share[air] * v[air], 0) > 0  # share . v > 0: the force f opposes the velocity
    return np.where(opposes, -share, 0.0)


def evidence(raw: RawLog) -> Evidence:
    """Score one reading of a log (world NED / body FRD, SI) against physics (module docstring)."""
    from ..errors import instance

    instance("raw", raw, RawLog)
    notes: list[str] = []
    thrust_sig = raw.thrust
    if thrust_sig is None and raw.rotor_speed is not None:  # rotor speeds only: thrust ~ sum of squares
        rs = raw.rotor_speed
        thrust_sig = Signal("thrust", "rotor speeds", rs.t, np.sum(rs.values**2, -1, keepdims=True), True)
    sigs = [clean(s, notes) for s in (raw.velocity_W, raw.attitude, raw.omega_B, thrust_sig)]
    rates = {s.name: 1.0 / typical_period(s.t) for s in sigs}
    span = max(s.t[-1] for s in sigs) - min(s.t[0] for s in sigs)
    steps = [(float(np.max(np.diff(s.t))), float(s.t[np.argmax(np.diff(s.t))])) for s in sigs if len(s.t) > 1]
    jump = max(steps, default=(0.0, 0.0))
    time_ok = all(RATE_RANGE_HZ[0] <= r <= RATE_RANGE_HZ[1] for r in rates.values()) and span < 10 * 86400
    lo = max(s.t[0] for s in sigs)
    hi = min(s.t[-1] for s in sigs)
    slow = 1.0 / min(rates.values())
    rate = float(min(EVAL_RATE_HZ, max(4.0 / slow, 5.0)))
    if not time_ok or not hi - lo > 10.0 / rate:
        nan = float("nan")
        return Evidence(
            nan, np.full(3, nan), 0.0, 1.0, 0.0, 1.0, np.full(2, nan), np.zeros(2), rates, time_ok, span, jump
        )
    smooth = max(2, int(round(max(SMOOTH_S, 2.5 * slow) * rate)))
    hp = max(3, int(round(HP_WINDOW_S * rate)))
    w_att_all, w_log_all, ub_all, sf_all, a_hp_all, e_parts, v_all = [], [], [], [], [], [], []
    vel, att, omg, thr = sigs
    q_att = quat_from_euler(att.values)
    flip = np.cumprod(np.where(np.sum(q_att[1:] * q_att[:-1], -1) < 0, -1.0, 1.0))
    q_att[1:] *= flip[:, None]
    dt = 1.0 / rate
    grids = _split_at_dropouts(_windows(sigs, lo, hi, rate), sigs, rate)
    w_clean = _despiked(omg.t, omg.values)  # a glitch counts once in a sum over intervals; no point sample hid it
    if not grids:
        nan = float("nan")
        return Evidence(nan, np.full(3, nan), 0.0, 1.0, 0.0, 1.0, np.full(2, nan), np.zeros(2), rates, time_ok, span,
                        jump, no_stretch=True)  # fmt: skip
    for grid in grids:
        q = np.stack([np.interp(grid, att.t, q_att[:, j]) for j in range(4)], -1)
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
        R = quat_to_rotation(q)
        rel = np.einsum("nji,njk->nik", R[:-1], R[1:])  # R_k^T R_{k+1} = I + [w]x dt
        w_att = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], -1)
        w_log = _interval_means(omg.t, w_clean, grid)
        w_att_all.append(_moving_average(w_att / (2.0 * dt), smooth))
        w_log_all.append(_moving_average(w_log, smooth))
        v = np.stack([np.interp(grid, vel.t, vel.values[:, j]) for j in range(3)], -1)
        a = _moving_average(np.gradient(v, dt, axis=0), smooth)
        v_all.append(_moving_average(v, smooth))
        idx = np.clip(np.searchsorted(thr.t, grid, side="right") - 1, 0, len(thr.t) - 1)
        u = _moving_average(thr.values[idx, 0], smooth)
        ub_all.append(u[:, None] * R[:, :, 2])
        sf_all.append(np.array([0.0, 0.0, G]) - a)
        a_hp_all.append(a - _moving_average(a, hp))
    rms = lambda x: float(np.sqrt(np.mean(np.sum(x**2, -1))))  # noqa: E731
    w_att, w_log = np.concatenate(w_att_all), np.concatenate(w_log_all)
    kin = rms(w_log - w_att) / (rms(w_log) + rms(w_att) + OMEGA_FLOOR)
    # logged over attitude-derived rate, per axis: regressing the derived rate (the noisier one) on the logged
    kin_gain = np.sum(w_log * w_log, 0) / np.where(np.abs(g := np.sum(w_log * w_att, 0)) > 1e-300, g, 1e-300)
    kin_motion = max(rms(w_att), rms(w_log))
    ub = np.concatenate(ub_all)
    sf = np.concatenate(sf_all)
    k = float(np.sum(sf * ub) / max(np.sum(ub * ub), 1e-300))
    un = np.linalg.norm(ub, axis=-1)
    air = un > 0.3 * np.percentile(un, 95)
    sf_thrust = sf + _drag_part(sf, ub, np.concatenate(v_all), air)  # what the thrust alone must give
    cosang = np.sum(sf_thrust * ub, -1) / np.maximum(np.linalg.norm(sf_thrust, axis=-1) * un, 1e-300)
    tilt = float(np.median(np.arccos(np.clip(cosang[air], -1, 1)))) if air.any() else 0.0
    for ubw in ub_all:  # the acceleration thrust and attitude predict, fast part
        m = -k * ubw
        e_parts.append(m - _moving_average(m, hp))
    a_hp = np.concatenate(a_hp_all)
    m_hp = np.concatenate(e_parts)
    dyn_motion = np.array([rms(a_hp[:, :2]), rms(a_hp[:, 2:])])
    dyn = np.empty(2)
    for i, sl in enumerate((slice(0, 2), slice(2, 3))):
        a_i, m_i = a_hp[:, sl].ravel(), m_hp[:, sl].ravel()
        floor = ACCEL_FLOOR * np.sqrt(len(a_i))
        dyn[i] = 1.0 - float(a_i @ m_i) / (np.linalg.norm(a_i) * np.linalg.norm(m_i) + floor**2 / 4 + 1e-300)
    r_log, r_att = np.sqrt(np.mean(w_log**2, 0)), np.sqrt(np.mean(w_att**2, 0))
    kin_axis = np.sqrt(np.mean((w_log - w_att) ** 2, 0)) / (r_log + r_att + OMEGA_FLOOR)
    return Evidence(kin, kin_gain, kin_motion, rms(w_log), tilt, k, dyn, dyn_motion, rates, time_ok, span, jump,
                    kin_axis, np.maximum(r_log, r_att))  # fmt: skip


def _strong_symptoms(ev: Evidence) -> bool:
    """A contradiction no flight explains, whatever its wrench (the body-rate prior of the score is a
    preference between readings, not a contradiction)."""
    return (
        not ev.time_ok or ev.tilt_rad > 0.5 or not ev.thrust_gain > 0 or (ev.kin_motion > KIN_MOTION and ev.kin > 0.6)
    )


@dataclass
class ConventionReport:
    """What the convention check found: the declared and chosen conventions, their evidence, which
    conventions the data decide, and the notes for the report."""

    mode: str
    declared: Conventions | None
    chosen: Conventions | None
    evidence_declared: Evidence | None
    evidence_chosen: Evidence | None
    undetermined: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    tried: int = 0

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"mode": self.mode, "tried": self.tried}
        if self.declared is not None:
            out["declared"] = self.declared.to_dict()
        if self.chosen is not None:
            out["chosen"] = self.chosen.to_dict()
        if self.evidence_declared is not None:
            out["evidence_declared"] = self.evidence_declared.to_dict()
        if self.evidence_chosen is not None:
            out["evidence_chosen"] = self.evidence_chosen.to_dict()
        out["undetermined"] = self.undetermined
        return out


def candidates(declared: Conventions, relevant: tuple[str, ...]) -> list[Conventions]:
    """Every combination of the ``relevant`` conventions (the others as declared)."""
    out = []
    for values in itertools.product(*(CHOICES[f] for f in relevant)):
        out.append(Conventions(**{**declared.to_dict(), **dict(zip(relevant, values, strict=True))}))
    return out


class ImplausibleTime(Exception):
    """Raised by a re-reader when a candidate time unit gives implausible sample rates (skipped early)."""


def time_plausible(t_s: np.ndarray) -> bool:
    """Whether a time column (seconds) has a plausible flight-log sample rate."""
    r = 1.0 / typical_period(np.asarray(t_s, dtype=float))
    return bool(RATE_RANGE_HZ[0] <= r <= RATE_RANGE_HZ[1])


def prior(c: Conventions, relevant: tuple[str, ...]) -> float:
    """A small penalty for mixed frames or units (velocity and attitude in different world frames, angles
    and rates in different units): rare in real logs, so an equal fit prefers the unmixed reading."""
    p = 0.0
    if "velocity_world" in relevant and c.velocity_world != c.world:
        p += 0.3
    if "angle_unit" in relevant and "rate_unit" in relevant and c.rate_unit != c.angle_unit:
        p += 0.3
    return p


def _rates_plausible(raw: RawLog) -> bool:
    for s in (raw.velocity_W, raw.attitude, raw.omega_B):
        r = 1.0 / typical_period(s.t)
        if not RATE_RANGE_HZ[0] <= r <= RATE_RANGE_HZ[1]:
            return False
    return True


def _describe(c: Conventions, names: tuple[str, ...]) -> str:
    return c.as_flags(names)


def _minimal_flags(declared: Conventions, diff: dict[str, str]) -> list[str]:
    """The flags to give: ``--angle-unit`` also sets the rates' unit and ``--world`` the velocity's frame when
    they were tied in the declared conventions."""
    names = list(diff)
    for lead, follow in (("angle_unit", "rate_unit"), ("world", "velocity_world")):
        tied = getattr(declared, lead) == getattr(declared, follow)
        if lead in diff and follow in diff and diff[lead] == diff[follow] and tied:
            names.remove(follow)
    return names


def _causes(diff: dict[str, str]) -> list[str]:
    """Each difference in words; angles and rates in the same unit, or world and velocity in the same frame,
    as one cause."""
    diff = dict(diff)
    out = []
    if diff.get("angle_unit") and diff.get("angle_unit") == diff.get("rate_unit"):
        unit = diff.pop("angle_unit")
        diff.pop("rate_unit")
        other = "radians" if unit == "deg" else "degrees"
        out.append(f"the angles and rates look like {'degrees' if unit == 'deg' else 'radians'} read as {other}")
    if diff.get("world") and diff.get("world") == diff.get("velocity_world"):
        frame = diff.pop("world")
        diff.pop("velocity_world")
        out.append(f"the log's world frame looks {frame.upper()}, read as {'NED' if frame == 'enu' else 'ENU'}")
    out += [CAUSES.get((k, v), f"{k} looks like {v}") for k, v in diff.items()]
    return out


def check_conventions(
    raw: RawLog,
    mode: str = "check",
    declared: Conventions | None = None,
    reread: Callable[[Conventions], RawLog] | None = None,
    relevant: tuple[str, ...] = (),
) -> tuple[RawLog, ConventionReport]:
    """Test the log ``raw`` (read under ``declared``) against physics; ``reread`` reads it under other
    conventions (``relevant`` fields). Returns the log to use and the report; raises
    :class:`~vtol_impedance.errors.InputError` on a contradiction (module docstring)."""
    from ..errors import choice, instance

    instance("raw", raw, RawLog)
    choice("mode", mode, MODES)
    if declared is not None:
        instance("declared", declared, Conventions)
    if mode not in MODES:
        raise InputError(f"conventions mode must be one of {', '.join(MODES)}, got {mode!r}")
    if mode == "unchecked":
        rep = ConventionReport(mode, declared, declared, None, None)
        rep.notes.append("conventions not checked against physics (--conventions unchecked)")
        return raw, rep
    ev0 = evidence(raw)
    escape = " (--conventions unchecked estimates anyway)"
    if reread is None or declared is None:
        rep = ConventionReport(mode, declared, declared, ev0, ev0, tried=1)
        if _strong_symptoms(ev0):
            raise InputError(
                "the log contradicts physics: " + "; ".join(ev0.symptoms()) + ". Its format fixes the frames and "
                "units, so the data themselves are suspect (a converted or edited log?)" + escape
            )
        rep.notes.append(
            f"conventions fixed by the format ({raw.meta.get('format', 'log')}); checked against physics: consistent"
        )
        return raw, rep
    scored: list[tuple[float, Conventions, Evidence | None]] = []
    for c in candidates(declared, relevant):
        if c == declared:
            scored.append((ev0.score + prior(c, relevant), c, ev0))
            continue
        try:
            r = reread(c)
        except InputError:
            continue
        except ImplausibleTime:
            scored.append((100.0 + ev0.score, c, None))
            continue
        if not _rates_plausible(r):
            scored.append((100.0 + ev0.score, c, None))
            continue
        ev = evidence(r)
        scored.append((ev.score + prior(c, relevant), c, ev))
    if any(e is not None and e.measured for _, _, e in scored):  # nothing to score is no fit: never preferred
        scored = [(s, c, e) if e is None or e.measured else (100.0 + s, c, e) for s, c, e in scored]
    scored.sort(key=lambda x: x[0])
    best_score = scored[0][0]
    margin = max(0.3, 0.15 * best_score)
    near = [(s, c, e) for s, c, e in scored if s <= best_score + margin]
    undetermined = [f for f in relevant if len({getattr(c, f) for _, c, _ in near}) > 1]
    rep = ConventionReport(mode, declared, declared, ev0, ev0, undetermined=undetermined, tried=len(scored))
    declared_ok = any(c == declared for _, c, _ in near)
    if mode == "check":
        if declared_ok:
            if undetermined:
                rep.notes.append(
                    "conventions checked against physics; the data cannot confirm "
                    + ", ".join(f"{f} ({getattr(declared, f)} declared)" for f in undetermined)
                    + " (too little motion to tell)"
                )
            else:
                rep.notes.append("conventions checked against physics: the declared ones fit best")
            if _strong_symptoms(ev0):
                raise InputError(
                    "the log contradicts physics under every convention tried: " + "; ".join(ev0.symptoms()) + escape
                )
            return raw, rep
        best = scored[0]
        diff = declared.differences(best[1], relevant)
        causes = "; ".join(_causes(diff))
        flags = best[1].as_flags(tuple(_minimal_flags(declared, diff)))
        raise InputError(
            f"the log contradicts physics under the declared conventions ({_describe(declared, relevant)}): "
            + "; ".join(ev0.symptoms() or [f"it fits much worse (score {ev0.score:.2f}) than another reading"
                                            if ev0.measured else "it leaves nothing long enough to score"])
            + f". Most likely: {causes}. With {flags} the data agree (score {best[0]:.2f} against {ev0.score:.2f}): "
            f"give {flags}, or --conventions auto to choose from the data" + escape
        )
    # auto: the best reading; on a near tie, the one closer to the declared
    s_c, chosen, ev_c = min(near, key=lambda x: x[0] + 0.05 * len(declared.differences(x[1], relevant)))
    if ev_c is None or _strong_symptoms(ev_c):
        raise InputError(
            "no convention tried makes the log agree with physics; the best reading "
            f"({_describe(chosen, relevant)}) still shows: " + "; ".join((ev_c or ev0).symptoms()) + escape
        )
    rep.chosen, rep.evidence_chosen = chosen, ev_c
    diff = declared.differences(chosen, relevant)
    decided = [f for f in relevant if f not in undetermined]
    text = "conventions chosen from the data (--conventions auto): " + _describe(chosen, relevant)
    if diff:
        text += "; changed from the declared: " + chosen.as_flags(tuple(diff))
    if decided:
        text += "; decided by the data: " + ", ".join(decided)
    rep.notes.append(text)
    if undetermined:
        rep.warnings.append(
            "the data cannot decide "
            + ", ".join(f"{f} (took {getattr(chosen, f)})" for f in undetermined)
            + ": the flight has too little motion of the kind that tells them apart; state them with "
            + " ".join(Conventions.FLAGS[f] for f in undetermined)
            + " if they are not what the log uses"
        )
    return (raw if chosen == declared else reread(chosen)), rep


#: A stretch of repeated thrust is the vehicle's own steady state, not a frozen logger, when over it the logged
#: velocity departs from a straight line in time (a constant acceleration) by at most this, m/s, and every
#: body rate varies by at most :data:`STEADY_RATE_RAD_S`: what only a noise-free log (a simulator's) holds;
#: a real IMU's noise alone is a thousand times more.
STEADY_VELOCITY_M_S = 1e-6
STEADY_RATE_RAD_S = 1e-6
#: ... and only in a log whose velocity is noise-free elsewhere: the RMS of its third differences below this,
#: m/s (white noise of sigma gives 4.5 sigma; a smooth flight at 100 Hz with a snap of 100 m/s^4 gives 1e-4).
STEADY_NOISE_M_S = 1e-4


def _steady(motion: tuple[Signal, Signal] | None, t0: float, t1: float) -> bool:
    """Whether the logged velocity and body rates ``motion`` hold still (:data:`STEADY_VELOCITY_M_S`) over
    ``[t0, t1]``, with at least three samples of each there, in a log whose velocity is smooth elsewhere
    (noise-free: a simulator's)."""
    if motion is None:
        return False
    v, w = motion
    iv = (v.t >= t0) & (v.t <= t1)
    iw = (w.t >= t0) & (w.t <= t1)
    if iv.sum() < 3 or iw.sum() < 3:
        return False
    tv, vv, ww = v.t[iv], v.values[iv], w.values[iw]
    if not (np.all(np.isfinite(vv)) and np.all(np.isfinite(ww))):
        return False
    # and noise-free elsewhere: a logger that froze every column repeats a noisy log's whole row. White noise
    # of sigma gives third differences of 4.5 sigma (a real velocity: 1e-3 m/s and more); a smooth flight
    # sampled at 100 Hz well under STEADY_NOISE_M_S
    parts = [p for p in (v.values[v.t < t0], v.values[v.t > t1]) if len(p) >= 4]
    d3 = np.concatenate([np.diff(p, 3, axis=0) for p in parts]) if parts else np.zeros((0, 3))
    if len(d3) < 10 or not np.sqrt(np.mean(d3**2)) < STEADY_NOISE_M_S:
        return False
    A = np.column_stack([np.ones_like(tv), tv - tv[0]])
    resid = vv - A @ np.linalg.lstsq(A, vv, rcond=None)[0]
    return bool(np.max(np.abs(resid)) <= STEADY_VELOCITY_M_S and np.max(np.ptp(ww, axis=0)) <= STEADY_RATE_RAD_S)


def check_thrust_signal(
    sig: Signal | None, notes: list[str], motion: tuple[Signal, Signal] | None = None
) -> Signal | None:
    """Refuse a thrust column of zeros or one constant throughout; a stretch of at least 1 s (and 10
    samples) where the logger repeated the same value, below the column's maximum (not saturated) and above
    a fifth of its usual level (not idle on the ground), becomes a dropout (its repeated rows are dropped;
    the resampler bridges or restarts); at either end of the log, under half the usual level, it is the
    vehicle idling before take-off or after landing, kept. With ``motion = (velocity_W, omega_B)``, a
    stretch over which the vehicle's logged motion is as steady as its thrust (:func:`_steady`: a noise-free
    log's hover or straight flight) is kept too, with a note."""
    if sig is None:
        return None
    v = np.asarray(sig.values, dtype=float)[:, 0]
    finite = np.isfinite(v)
    if not finite.any():
        raise InputError(f"the thrust ({sig.source}) has no finite value")
    vf = v[finite]
    if np.all(vf == 0):
        raise InputError(
            f"the thrust ({sig.source}) is zero throughout: the vehicle never flew in this log (disarmed, on the "
            "ground), or the logger did not record it; give another thrust column, or rotor speeds (CSV "
            "rpm1..rpmN, ESC telemetry) to take the thrust from"
        )
    if np.ptp(vf) <= 1e-9 * max(1.0, float(np.max(np.abs(vf)))):
        raise InputError(
            f"the thrust ({sig.source}) holds the value {vf[0]:.6g} throughout the log: the logger held it, it is "
            "not what the vehicle flew; give another thrust column or rotor speeds"
        )
    t = np.asarray(sig.t, dtype=float)
    hi = float(np.max(vf))
    lo = max(float(np.min(vf)), 0.2 * float(np.percentile(np.abs(vf), 95)))  # idle on the ground repeats honestly
    levels = np.unique(vf)
    if len(levels) <= 200 and np.min(np.diff(levels)) >= 1e-3 * (hi - lo):
        return sig  # a coarsely quantised thrust (whole percent) repeats its values honestly
    same = np.concatenate([[False], (v[1:] == v[:-1]) & finite[1:]])
    drop = np.zeros(len(v), bool)
    i = 0
    n = len(v)
    while i < n:
        if not same[i]:
            i += 1
            continue
        j = i
        while j < n and same[j]:
            j += 1
        start = i - 1  # the run is v[start .. j-1]
        # at either end of the log and under half the usual level: idling before take-off or after landing
        idle = (start == 0 or j == n) and v[start] < 0.5 * float(np.percentile(np.abs(vf), 95))
        frozen = j - start >= 10 and t[j - 1] - t[start] >= 1.0 and lo < v[start] < hi and not idle
        if frozen and _steady(motion, t[start], t[j - 1]):
            notes.append(
                f"thrust ({sig.source}) repeats {v[start]:.6g} from {t[start]:.3f} s to {t[j - 1]:.3f} s, and the "
                "logged velocity and body rates are as steady there (a noise-free log): kept as the vehicle's "
                "steady state"
            )
        elif frozen:
            drop[start + 1 : j] = True  # keep the run's first row: the step to the next fresh value is a gap
            notes.append(
                f"thrust ({sig.source}) repeats {v[start]:.6g} from {t[start]:.3f} s to {t[j - 1]:.3f} s "
                f"({j - start} samples) while it varies elsewhere: the logger froze it; treated as a dropout"
            )
        i = j
    if drop.any():
        return Signal(sig.name, sig.source, t[~drop], sig.values[~drop], sig.hold)
    return sig
