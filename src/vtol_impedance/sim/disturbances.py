"""External disturbances as explicit plant inputs.

Each disturbance is a frozen dataclass. :meth:`prepare` draws whatever randomness it needs from a
seeded ``numpy.random.Generator`` once per run; the prepared object is then a deterministic function
``(t, p_W, v_W, R_WB) -> (f_W, tau_B)`` of time and the body-origin state, broadcast over a batch.
Forces act at the body origin, in the world frame; moments are in the body frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np
import scipy.linalg
import scipy.signal

from ..errors import InputError, as_finite, positive, scalar
from ..model.kinematics import cross

Vec3 = tuple[float, float, float]

#: Largest wind speed accepted, m/s (steady, gust peak, or turbulence 3 sigma): beyond any multirotor's
#: flight envelope (the strongest small multirotors are rated to about 20 m/s).
MAX_WIND_M_S = 50.0
#: Lowest band edge of band-limited noise, Hz. The filter settles over ``4 / f_lo`` s of padding drawn at
#: the plant rate (0.01 Hz: 400 s, 19 MB at 1 kHz; 1e-4 Hz needed 7.6 GB): a slower drift is a ramp or a
#: sinusoid, not noise.
MIN_NOISE_F_LO_HZ = 0.01


def check_band(name: str, band: Any) -> tuple[float, float]:
    """A noise band ``(f_lo, f_hi)`` in Hz: finite, ``MIN_NOISE_F_LO_HZ <= f_lo < f_hi`` (the upper
    bound, below the plant's Nyquist frequency, is checked when the plant rate is known)."""
    b = as_finite(name, band, (2,))
    if b.shape != (2,):
        raise InputError(f"{name} must be two frequencies (f_lo, f_hi) in Hz, got shape {b.shape}")
    lo, hi = float(b[0]), float(b[1])
    if not MIN_NOISE_F_LO_HZ <= lo < hi:
        raise InputError(
            f"{name} must satisfy {MIN_NOISE_F_LO_HZ:g} <= f_lo < f_hi Hz, got {lo:g}..{hi:g} (a drift slower than "
            f"{MIN_NOISE_F_LO_HZ:g} Hz is a ramp or a sinusoid)"
        )
    return lo, hi


Encoded = tuple[str, dict[str, Any], "np.ndarray | None"]


def pack_disturbances(items: Sequence[Disturbance]) -> tuple[np.ndarray, np.ndarray]:
    """``(records (D,) of compiled.layouts.DISTURBANCE, series (D, n, 6))`` of prepared disturbances, for the
    compiled plant (:func:`vtol_impedance.compiled.plant.add_disturbances`)."""
    from ..compiled.layouts import DISTURBANCE, KIND, fill

    enc = [d.encode() for d in items]
    out = np.zeros(len(enc), dtype=DISTURBANCE)
    series = np.zeros((len(enc), max([1] + [len(e[2]) for e in enc if e[2] is not None]), 6))
    for i, (kind, values, samples) in enumerate(enc):
        out["kind"][i] = KIND[kind]
        for name, value in values.items():
            fill(out[i : i + 1], name, value)
        if samples is not None:
            series[i, : len(samples)] = samples
            out["n_samples"][i] = len(samples)
    return out, series


class Disturbance:
    """Base class: constant-in-state, deterministic disturbances need no preparation."""

    kind: ClassVar[str] = ""
    #: Whether the wrench depends on the vehicle's state (position, velocity, attitude) and not on time
    #: alone: a plant that steps several times in one call must then evaluate it at every step.
    state_dependent: ClassVar[bool] = False

    def prepare(self, t_end: float, dt: float, rng: np.random.Generator) -> Disturbance:
        return self

    def check_start(self, p_W: np.ndarray) -> None:
        """Refuse a start the disturbance cannot begin from (a wall through the vehicle); default: any."""

    def starts_at(self) -> float:
        """When it first acts, s (a disturbance that starts after the flight ends is refused)."""
        return 0.0

    def __call__(self, t: float, p_W: np.ndarray, v_W: np.ndarray, R_WB: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def encode(self) -> Encoded:
        """``(kind, fields, series (n, 6) or None)`` for the compiled backend: the fields of
        :data:`vtol_impedance.compiled.layouts.DISTURBANCE` this kind uses (:mod:`vtol_impedance.compiled.plant`
        evaluates the same formulas)."""
        raise NotImplementedError(f"{type(self).__name__} has no compiled form")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind}
        for f in fields(self):  # type: ignore[arg-type]
            if f.init and not f.name.startswith("_"):
                v = getattr(self, f.name)
                out[f.name] = list(v) if isinstance(v, tuple) else v
        return out


def _vec(name: str, v: Any) -> Vec3:
    return tuple(float(a) for a in as_finite(name, v, (3,)))  # type: ignore[return-value]


def _const(shape_like: np.ndarray, f: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    shape = shape_like.shape
    return np.broadcast_to(f, shape), np.broadcast_to(tau, shape)


@dataclass(frozen=True)
class ConstantWrench(Disturbance):
    """A constant force (world) and moment (body); subclasses scale it by a time profile."""

    kind: ClassVar[str] = "constant"
    force_W: Vec3 = (0.0, 0.0, 0.0)
    torque_B: Vec3 = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "force_W", _vec("force_W", self.force_W))
        object.__setattr__(self, "torque_B", _vec("torque_B", self.torque_B))
        for f in fields(self):  # seconds from the flight's start: before it, nothing would act
            t = getattr(self, f.name)
            if f.name.startswith("t_") and not (f.name in ("t_off", "t_end") and t == float("inf")):  # never off
                scalar(f"{self.kind} {f.name} (s from the flight's start)", t, lo=0.0)

    def profile(self, t: float) -> float:
        """Scale of the wrench at time ``t``."""
        return 1.0

    def _timing(self) -> dict[str, float]:
        return {}

    def encode(self) -> Encoded:
        return self.kind, {"force_W": self.force_W, "torque_B": self.torque_B, **self._timing()}, None

    def __call__(self, t, p_W, v_W, R_WB):
        k = self.profile(t)
        return _const(p_W, k * np.asarray(self.force_W), k * np.asarray(self.torque_B))


@dataclass(frozen=True)
class StepWrench(ConstantWrench):
    """The constant wrench switched on at ``t_on`` and off at ``t_off``."""

    kind: ClassVar[str] = "step"
    t_on: float = 0.0
    t_off: float = float("inf")

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.t_off > self.t_on:
            raise InputError(f"step needs t_off > t_on, got t_on {self.t_on!r} s, t_off {self.t_off!r} s")

    def profile(self, t: float) -> float:
        return 1.0 if self.t_on <= t < self.t_off else 0.0

    def starts_at(self) -> float:
        return float(self.t_on)

    def _timing(self) -> dict[str, float]:
        return {"t_on": self.t_on, "t_off": self.t_off}


@dataclass(frozen=True)
class RampWrench(ConstantWrench):
    """Rises linearly from zero at ``t_start`` to the full wrench at ``t_end`` and holds."""

    kind: ClassVar[str] = "ramp"
    t_start: float = 0.0
    t_end: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        scalar("t_start", self.t_start)
        scalar("t_end", self.t_end)
        if not self.t_end > self.t_start:
            raise InputError(f"ramp needs t_end > t_start, got {self.t_start} .. {self.t_end}")

    def profile(self, t: float) -> float:
        return float(np.clip((t - self.t_start) / (self.t_end - self.t_start), 0.0, 1.0))

    def starts_at(self) -> float:
        return float(self.t_start)

    def _timing(self) -> dict[str, float]:
        return {"t_on": self.t_start, "t_off": self.t_end}


@dataclass(frozen=True)
class SinusoidWrench(ConstantWrench):
    """``amplitude * sin(2 pi freq_hz (t - t_on) + phase)`` from ``t_on``; ``force_W``/``torque_B`` are amplitudes."""

    kind: ClassVar[str] = "sinusoid"
    freq_hz: float = 1.0
    phase: float = 0.0
    t_on: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        scalar("freq_hz", self.freq_hz, lo=0.0, lo_open=True)
        scalar("phase", self.phase)

    def profile(self, t: float) -> float:
        return float(np.sin(2 * np.pi * self.freq_hz * (t - self.t_on) + self.phase)) if t >= self.t_on else 0.0

    def prepare(self, t_end: float, dt: float, rng: np.random.Generator) -> SinusoidWrench:
        """Refuse a frequency the plant's steps cannot carry: above a quarter of the plant rate the held
        samples alias it (at 1 kHz a 1 kHz sinusoid is zero at every step); a quarter itself, four samples a
        period, is the last carried."""
        if self.freq_hz > 0.25 / dt:
            raise InputError(
                f"sinusoid freq_hz = {self.freq_hz:g} Hz is above a quarter of the plant rate ({1.0 / dt:g} Hz): "
                "the plant's steps would alias it; raise plant_rate or lower the frequency"
            )
        return self

    def starts_at(self) -> float:
        return float(self.t_on)

    def _timing(self) -> dict[str, float]:
        return {"freq_hz": self.freq_hz, "phase": self.phase, "t_on": self.t_on}


@dataclass(frozen=True)
class Push(ConstantWrench):
    """An operator's push: a half-sine force pulse of peak ``force_W`` from ``t_on`` lasting ``duration``."""

    kind: ClassVar[str] = "push"
    t_on: float = 5.0
    duration: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        scalar("push duration", self.duration, lo=0.0, lo_open=True)

    def profile(self, t: float) -> float:
        s = (t - self.t_on) / self.duration
        return float(np.sin(np.pi * s)) if 0.0 <= s <= 1.0 else 0.0

    def _timing(self) -> dict[str, float]:
        return {"t_on": self.t_on, "duration": self.duration}

    def starts_at(self) -> float:
        return float(self.t_on)


def band_limited_noise(
    rng: np.random.Generator, n: int, dt: float, f_lo: float, f_hi: float, channels: int
) -> np.ndarray:
    """Zero-mean Gaussian noise with unit standard deviation, band-passed to [f_lo, f_hi] Hz, ``(n, channels)``."""
    nyq = 0.5 / dt
    f_lo, f_hi = check_band("noise band", (f_lo, f_hi))
    if not 0 < f_lo < f_hi < nyq:
        raise InputError(f"noise band must satisfy 0 < f_lo < f_hi < {nyq} Hz, got {f_lo}..{f_hi}")
    pad = int(4.0 / (f_lo * dt))  # let the filter settle
    white = rng.standard_normal((n + 2 * pad, channels))
    sos = scipy.signal.butter(2, [f_lo, f_hi], btype="bandpass", fs=1.0 / dt, output="sos")
    out = scipy.signal.sosfiltfilt(sos, white, axis=0)[pad : pad + n]
    std = out.std(axis=0)
    return out / np.where(std > 0, std, 1.0)


@dataclass(frozen=True)
class BandLimitedNoise(Disturbance):
    """Seeded Gaussian noise, band-limited to ``[f_lo, f_hi]`` Hz, with the given RMS per axis."""

    kind: ClassVar[str] = "noise"
    force_rms_W: Vec3 = (0.0, 0.0, 0.0)
    torque_rms_B: Vec3 = (0.0, 0.0, 0.0)
    f_lo: float = 0.5
    f_hi: float = 5.0
    _series: np.ndarray | None = field(default=None, repr=False, compare=False)
    _dt: float = field(default=0.0, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "force_rms_W", _vec("force_rms_W", self.force_rms_W))
        object.__setattr__(self, "torque_rms_B", _vec("torque_rms_B", self.torque_rms_B))
        lo, hi = check_band("noise band (f_lo, f_hi)", (self.f_lo, self.f_hi))
        object.__setattr__(self, "f_lo", lo)
        object.__setattr__(self, "f_hi", hi)

    def prepare(self, t_end: float, dt: float, rng: np.random.Generator) -> BandLimitedNoise:
        n = int(np.ceil(t_end / dt)) + 2
        unit = band_limited_noise(rng, n, dt, self.f_lo, self.f_hi, 6)
        series = unit * np.concatenate([self.force_rms_W, self.torque_rms_B])
        return replace(self, _series=series, _dt=dt)

    def encode(self) -> Encoded:
        if self._series is None:
            raise RuntimeError("BandLimitedNoise used before prepare()")
        return "series", {"sample_dt": self._dt}, self._series

    def __call__(self, t, p_W, v_W, R_WB):
        if self._series is None:
            raise RuntimeError("BandLimitedNoise used before prepare()")
        i = min(int(t / self._dt), len(self._series) - 1)
        s = self._series[i]
        return _const(p_W, s[:3], s[3:])


@dataclass(frozen=True)
class FanJet(Disturbance):
    """Air jet of a fan at ``position_W`` blowing along ``direction_W`` (case B of the paper).

    Force along the jet: ``mean_force * ref_distance / max(s, ref_distance/2) * exp(-r^2 / (2 width^2))
    * (1 + turbulence(t))`` where ``s`` is the distance along the jet and ``r`` off its axis.
    ``turbulence`` is seeded band-limited noise (``turbulence_band`` Hz) with RMS ``turbulence``
    (a fraction of the mean). The jet's centre of pressure sits ``cop_offset_B`` from the body origin,
    which gives the small moment the paper observes.
    """

    kind: ClassVar[str] = "fan"
    state_dependent: ClassVar[bool] = True
    position_W: Vec3 = (-0.15, 0.0, -1.0)
    direction_W: Vec3 = (1.0, 0.0, 0.0)
    mean_force: float = 0.7
    ref_distance: float = 0.15
    width: float = 0.2
    turbulence: float = 0.2
    turbulence_band: tuple[float, float] = (0.5, 5.0)
    cop_offset_B: Vec3 = (0.0, 0.0, -0.03)
    t_on: float = 0.0
    _gust: np.ndarray | None = field(default=None, repr=False, compare=False)
    _dt: float = field(default=0.0, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "position_W", _vec("position_W", self.position_W))
        d = np.asarray(_vec("direction_W", self.direction_W))
        if np.linalg.norm(d) == 0:
            raise InputError("fan direction_W must be non-zero")
        object.__setattr__(self, "direction_W", tuple(d / np.linalg.norm(d)))
        object.__setattr__(self, "cop_offset_B", _vec("cop_offset_B", self.cop_offset_B))
        scalar("fan mean_force", self.mean_force, lo=0.0)
        scalar("fan ref_distance", self.ref_distance, lo=0.0, lo_open=True)
        scalar("fan width", self.width, lo=0.0, lo_open=True)
        scalar("fan turbulence", self.turbulence, lo=0.0)
        object.__setattr__(self, "turbulence_band", check_band("fan turbulence_band", self.turbulence_band))
        scalar("fan t_on (s from the flight's start)", self.t_on, lo=0.0)

    def starts_at(self) -> float:
        return float(self.t_on)

    def prepare(self, t_end: float, dt: float, rng: np.random.Generator) -> FanJet:
        n = int(np.ceil(t_end / dt)) + 2
        gust = self.turbulence * band_limited_noise(rng, n, dt, *self.turbulence_band, 1)[:, 0]
        return replace(self, _gust=gust, _dt=dt)

    def encode(self) -> tuple[int, np.ndarray, np.ndarray | None]:
        fields = {
            "point_W": self.position_W,
            "normal_W": self.direction_W,
            "mean_force": self.mean_force,
            "ref_distance": self.ref_distance,
            "width": self.width,
            "cop_offset_B": self.cop_offset_B,
            "t_on": self.t_on,
            "sample_dt": self._dt,
        }
        series = None
        if self._gust is not None:
            series = np.zeros((len(self._gust), 6))
            series[:, 0] = self._gust
        return "fan", fields, series

    def __call__(self, t, p_W, v_W, R_WB):
        if t < self.t_on:
            z = np.zeros(np.shape(p_W))
            return z, z
        d = np.asarray(self.direction_W)
        rel = p_W - np.asarray(self.position_W)
        s = rel @ d
        r2 = np.sum(rel * rel, -1) - s * s
        gust = 0.0 if self._gust is None else self._gust[min(int(t / self._dt), len(self._gust) - 1)]
        mag = (
            self.mean_force
            * self.ref_distance
            / np.maximum(s, 0.5 * self.ref_distance)
            * np.exp(-r2 / (2 * self.width**2))
            * (1.0 + gust)
        )
        mag = np.where(s > 0, mag, 0.0)  # behind the fan there is no jet
        f_W = mag[..., None] * d
        f_B = np.einsum("...ji,...j->...i", R_WB, f_W)
        tau_B = cross(np.asarray(self.cop_offset_B), f_B)
        return f_W, tau_B


@dataclass(frozen=True)
class Wind(Disturbance):
    """Steady wind ``velocity_W`` acting through linear rotor drag: ``f = drag * velocity_W``.

    The plant's aerodynamic force (the vehicle's rotor drag, or ``plant.rotor_drag``) supplies the part due to
    the vehicle's motion.
    """

    kind: ClassVar[str] = "wind"
    velocity_W: Vec3 = (0.0, 0.0, 0.0)
    drag: float = 0.18

    def __post_init__(self) -> None:
        object.__setattr__(self, "velocity_W", _vec("velocity_W", self.velocity_W))
        scalar("wind drag", self.drag, lo=0.0)
        speed = float(np.linalg.norm(self.velocity_W))
        if speed > MAX_WIND_M_S:
            raise InputError(
                f"wind velocity_W of {speed:.4g} m/s is beyond any multirotor's flight envelope (at most "
                f"{MAX_WIND_M_S:g} m/s accepted)"
            )

    def encode(self) -> Encoded:
        return "constant", {"force_W": self.drag * np.asarray(self.velocity_W)}, None

    def __call__(self, t, p_W, v_W, R_WB):
        return _const(p_W, self.drag * np.asarray(self.velocity_W), np.zeros(3))


@dataclass(frozen=True)
class Wall(Disturbance):
    """A flat wall as a stiff spring-damper with Coulomb friction, touched by a sphere of ``radius`` around
    the body origin (a bumper, or the tip of a probe held level with it).

    The plane passes through ``position_W`` with ``normal_W`` pointing out of the wall, to the free side.
    With the gap ``g = (p - position_W) . n - radius``, a penetration ``-g > 0`` pushes back with
    ``F_n = max(stiffness (-g) - damping (v . n), 0)`` along ``n`` (a wall pushes, never pulls) and rubs with
    ``mu F_n`` against the sliding velocity (regularised below ``slip_speed``). The force acts at the
    contact point ``p - radius n``, which gives the moment about the origin.
    """

    kind: ClassVar[str] = "wall"
    state_dependent: ClassVar[bool] = True
    position_W: Vec3 = (1.0, 0.0, 0.0)
    normal_W: Vec3 = (-1.0, 0.0, 0.0)
    stiffness: float = 2000.0
    damping: float = 60.0
    friction: float = 0.3
    radius: float = 0.0
    slip_speed: float = 0.01

    def __post_init__(self) -> None:
        object.__setattr__(self, "position_W", _vec("wall position_W", self.position_W))
        n = np.asarray(_vec("wall normal_W", self.normal_W))
        if np.linalg.norm(n) == 0:
            raise InputError("wall normal_W must be non-zero")
        object.__setattr__(self, "normal_W", tuple(n / np.linalg.norm(n)))
        scalar("wall stiffness", self.stiffness, lo=0.0, lo_open=True)
        scalar("wall damping", self.damping, lo=0.0)
        scalar("wall friction", self.friction, lo=0.0)
        scalar("wall radius", self.radius, lo=0.0)
        scalar("wall slip_speed", self.slip_speed, lo=0.0, lo_open=True)

    def gap(self, p_W: np.ndarray) -> np.ndarray:
        """Distance from the contact sphere to the wall, m (negative: in contact)."""
        return (np.asarray(p_W) - np.asarray(self.position_W)) @ np.asarray(self.normal_W) - self.radius

    def check_start(self, p_W: np.ndarray) -> None:
        g = float(self.gap(p_W))
        if g < 0:
            raise InputError(
                f"the wall at {list(self.position_W)} (normal {list(self.normal_W)}) is inside the vehicle's start "
                f"position {np.asarray(p_W).tolist()}: the contact sphere of radius {self.radius} m overlaps it by "
                f"{-g:.3g} m; move the wall to the free side"
            )

    def encode(self) -> Encoded:
        fields = {"point_W": self.position_W, "normal_W": self.normal_W, "stiffness": self.stiffness,
                  "damping": self.damping, "friction": self.friction, "radius": self.radius,
                  "slip_speed": self.slip_speed}  # fmt: skip
        return "wall", fields, None

    def __call__(self, t, p_W, v_W, R_WB):
        n = np.asarray(self.normal_W)
        pen = -self.gap(p_W)
        vn = v_W @ n
        fn = np.where(pen > 0, np.maximum(self.stiffness * pen - self.damping * vn, 0.0), 0.0)
        vt = v_W - vn[..., None] * n
        speed = np.linalg.norm(vt, axis=-1)
        ft = -self.friction * (fn / np.maximum(speed, self.slip_speed))[..., None] * vt
        f_W = fn[..., None] * n + ft
        r_B = np.einsum("...ji,j->...i", R_WB, -self.radius * n)  # contact point from the origin, body frame
        f_B = np.einsum("...ji,...j->...i", R_WB, f_W)
        return f_W, cross(r_B, f_B)


#: MIL-F-8785C's low-altitude Dryden model holds below 1000 ft.
DRYDEN_MAX_ALTITUDE_M = 304.8


def dryden_filters(sigma_w: float, altitude: float) -> list[tuple[float, float, int]]:
    """``(sigma, L, order)`` of the u, v, w components of MIL-F-8785C's low-altitude Dryden model:
    ``L_w = h``, ``L_u = L_v = h / (0.177 + 0.000823 h)^1.2`` and ``sigma_u = sigma_v = sigma_w /
    (0.177 + 0.000823 h)^0.4`` with ``h`` in feet (converted here from metres, floored at 3 ft)."""
    h = max(altitude / 0.3048, 3.0)
    k = 0.177 + 0.000823 * h
    L_uv = h / k**1.2 * 0.3048
    L_w = h * 0.3048
    s_uv = sigma_w / k**0.4
    return [(s_uv, L_uv, 1), (s_uv, L_uv, 2), (sigma_w, L_w, 2)]


def dryden_series(
    rng: np.random.Generator, n: int, dt: float, sigma: float, length: float, airspeed: float, order: int
) -> np.ndarray:
    """A stationary Dryden component sampled every ``dt``: ``order`` 1 is the longitudinal form
    ``sigma sqrt(2L/(pi V)) / (1 + (L/V) s)``, 2 the lateral/vertical one ``sigma sqrt(L/(pi V)) (1 + sqrt(3)
    (L/V) s) / (1 + (L/V) s)^2``. Discretised exactly (Van Loan) from white noise of intensity pi (the
    spectra are one-sided) and run ten time constants before it is kept, so its variance is ``sigma^2``."""
    if sigma == 0:
        return np.zeros(n)
    T = length / airspeed
    if order == 1:
        A = np.array([[-1.0 / T]])
        B = np.array([[1.0]])
        C = np.array([[sigma * np.sqrt(2 * length / (np.pi * airspeed)) / T]])
    else:  # (1 + sqrt3 T s) / (1 + T s)^2 in controllable form
        A = np.array([[0.0, 1.0], [-1.0 / T**2, -2.0 / T]])
        B = np.array([[0.0], [1.0]])
        g = sigma * np.sqrt(length / (np.pi * airspeed)) / T**2
        C = np.array([[g, g * np.sqrt(3.0) * T]])
    m = A.shape[0]
    q = np.pi
    M = np.zeros((2 * m, 2 * m))
    M[:m, :m] = -A
    M[:m, m:] = q * B @ B.T
    M[m:, m:] = A.T
    E = scipy.linalg.expm(M * dt)
    Ad = E[m:, m:].T
    Qd = Ad @ E[:m, m:]
    lam, vec = np.linalg.eigh(0.5 * (Qd + Qd.T))
    Lq = vec * np.sqrt(np.maximum(lam, 0.0))  # Lq Lq^T = Qd
    pad = int(10.0 * T / dt) + 1  # ten time constants from rest: stationary to e^-20
    xi = rng.standard_normal((n + pad, m))
    out = np.zeros(n + pad)
    for j in range(m):
        num, den = scipy.signal.ss2tf(Ad, Lq[:, j : j + 1], C, np.zeros((1, 1)))
        out += scipy.signal.lfilter(num[0], den, xi[:, j])
    return out[pad:]


@dataclass(frozen=True)
class Gust(Disturbance):
    """Wind acting through rotor drag (``f = drag * v_wind``, as :class:`Wind`; the plant supplies ``-drag v``):
    a mean wind along ``direction_W``, a 1-cosine gust ``amplitude/2 (1 - cos(2 pi (t - start)/length))``
    over ``[start, start + length]``, and Dryden turbulence of MIL-F-8785C at ``altitude`` with vertical
    intensity ``sigma_w`` (m/s; 0: none) relative to an airspeed of ``max(mean_speed, 1 m/s)``: longitudinal
    along the wind, lateral across it, vertical along NED z."""

    kind: ClassVar[str] = "gust"
    direction_W: Vec3 = (1.0, 0.0, 0.0)
    mean_speed: float = 0.0
    amplitude: float = 3.0
    start: float = 10.0
    length: float = 2.0
    sigma_w: float = 0.0
    altitude: float = 1.0
    drag: float = 0.18
    _series: np.ndarray | None = field(default=None, repr=False, compare=False)
    _dt: float = field(default=0.0, repr=False, compare=False)

    def __post_init__(self) -> None:
        d = np.asarray(_vec("gust direction_W", self.direction_W))
        if np.linalg.norm(d[:2]) == 0:
            raise InputError("gust direction_W must have a horizontal component")
        object.__setattr__(self, "direction_W", tuple(d / np.linalg.norm(d)))
        for name in ("mean_speed", "amplitude", "start", "sigma_w", "drag"):
            positive(f"gust {name}", getattr(self, name), allow_zero=True)
        scalar("gust length", self.length, lo=0.0, lo_open=True)
        scalar("gust altitude", self.altitude, lo=0.0, hi=DRYDEN_MAX_ALTITUDE_M, lo_open=True)
        peak = self.mean_speed + self.amplitude + 3.0 * self.sigma_w
        if peak > MAX_WIND_M_S:
            raise InputError(
                f"gust wind of up to {peak:.4g} m/s (mean_speed + amplitude + 3 sigma_w) is beyond any multirotor's "
                f"flight envelope (at most {MAX_WIND_M_S:g} m/s accepted)"
            )

    def starts_at(self) -> float:
        return 0.0 if self.mean_speed > 0 or self.sigma_w > 0 else float(self.start)

    def wind_W(self, t: np.ndarray, turbulence: np.ndarray | None = None) -> np.ndarray:
        """Wind velocity (NED, m/s) at times ``t``; ``turbulence (N, 3)`` as ``[u, v, w]``."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        d = np.asarray(self.direction_W)
        s = np.clip((t - self.start) / self.length, 0.0, 1.0)
        inside = (t >= self.start) & (t <= self.start + self.length)
        speed = self.mean_speed + np.where(inside, 0.5 * self.amplitude * (1 - np.cos(2 * np.pi * s)), 0.0)
        w = speed[:, None] * d
        if turbulence is not None:
            horiz = np.array([d[0], d[1], 0.0]) / np.linalg.norm(d[:2])
            lateral = np.array([-horiz[1], horiz[0], 0.0])
            w = (
                w
                + turbulence[:, :1] * horiz
                + turbulence[:, 1:2] * lateral
                + turbulence[:, 2:3] * np.array([0, 0, 1.0])
            )
        return w

    def prepare(self, t_end: float, dt: float, rng: np.random.Generator) -> Gust:
        n = int(np.ceil(t_end / dt)) + 2
        V = max(self.mean_speed, 1.0)
        turb = np.zeros((n, 3))
        for i, (sig, L, order) in enumerate(dryden_filters(self.sigma_w, self.altitude)):
            turb[:, i] = dryden_series(rng, n, dt, sig, L, V, order)
        series = np.zeros((n, 6))
        series[:, :3] = self.drag * self.wind_W(np.arange(n) * dt, turb)
        return replace(self, _series=series, _dt=dt)

    def encode(self) -> Encoded:
        if self._series is None:
            raise RuntimeError("Gust used before prepare()")
        return "series", {"sample_dt": self._dt}, self._series  # a force series, as BandLimitedNoise

    def __call__(self, t, p_W, v_W, R_WB):
        if self._series is None:
            raise RuntimeError("Gust used before prepare()")
        s = self._series[min(int(t / self._dt), len(self._series) - 1)]
        return _const(p_W, s[:3], s[3:])


#: Disturbance classes by the ``kind`` a scenario file names them with (``[[disturbances]] kind = "fan"``).
KINDS: dict[str, type[Disturbance]] = {
    c.kind: c
    for c in (ConstantWrench, StepWrench, RampWrench, SinusoidWrench, Push, BandLimitedNoise, FanJet, Wind, Wall, Gust)
}


def from_dict(d: dict[str, Any]) -> Disturbance:
    """Build a disturbance from ``{"kind": ..., field: value}``, with clear errors on unknown kinds, keys and
    values of the wrong type or shape."""
    if not isinstance(d, dict):
        raise InputError(f"a disturbance is a table with a 'kind', got {d!r}")
    d = dict(d)
    kind = d.pop("kind", None)
    if kind not in KINDS:
        raise InputError(f"unknown disturbance kind {kind!r}; valid kinds: {', '.join(sorted(KINDS))}")
    cls = KINDS[kind]
    valid = [f.name for f in fields(cls) if f.init and not f.name.startswith("_")]  # type: ignore[arg-type]
    unknown = sorted(set(d) - set(valid))
    if unknown:
        raise InputError(f"unknown key(s) {unknown} for disturbance {kind!r}; valid keys: {', '.join(valid)}")
    defaults = {f.name: f.default for f in fields(cls) if f.init}  # type: ignore[arg-type]
    values = {}
    for k, v in d.items():
        where, default = f"disturbance {kind!r} {k}", defaults[k]
        if isinstance(default, float) and default == float("inf") and v == default:
            values[k] = v  # "never", as the default says
        elif isinstance(default, float):
            values[k] = scalar(where, v)
        elif isinstance(default, tuple):
            arr = as_finite(where, v)
            if arr.shape != (len(default),):
                raise InputError(f"{where} must be {len(default)} numbers, got {v!r}")
            values[k] = tuple(float(a) for a in arr)
        else:
            values[k] = v
    return cls(**values)


class DisturbanceSet:
    """Several prepared disturbances summed; callable as ``(t, p_W, v_W, R_WB) -> (f_W, tau_B)``."""

    def __init__(self, items: list[Disturbance]) -> None:
        self.items = items

    @property
    def state_dependent(self) -> bool:
        """Whether any member depends on the vehicle's state (see :attr:`Disturbance.state_dependent`)."""
        return any(d.state_dependent for d in self.items)

    def __call__(self, t: float, p_W: np.ndarray, v_W: np.ndarray, R_WB: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = np.zeros(np.shape(p_W))
        tau = np.zeros(np.shape(p_W))
        for d in self.items:
            fi, ti = d(t, p_W, v_W, R_WB)
            f = f + fi
            tau = tau + ti
        return f, tau
