"""External disturbances as explicit plant inputs.

Each disturbance is a frozen dataclass. :meth:`prepare` draws whatever randomness it needs from a
seeded ``numpy.random.Generator`` once per run; the prepared object is then a deterministic function
``(t, p_W, v_W, R_WB) -> (f_W, tau_B)`` of time and the body-origin state, broadcast over a batch.
Forces act at the body origin, in the world frame; moments are in the body frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np
import scipy.signal

from ..errors import InputError, as_finite, positive, scalar
from ..model.kinematics import cross

Vec3 = tuple[float, float, float]

#: Codes and parameter-vector length of the compiled encoding (see ``Disturbance.encode``).
CODE = {"constant": 0, "step": 1, "ramp": 2, "sinusoid": 3, "push": 4, "noise": 5, "fan": 6}
ENC_PARAMS = 16


def _enc(*values: float) -> np.ndarray:
    out = np.zeros(ENC_PARAMS)
    out[: len(values)] = values
    return out


class Disturbance:
    """Base class: constant-in-state, deterministic disturbances need no preparation."""

    kind: ClassVar[str] = ""

    def prepare(self, t_end: float, dt: float, rng: np.random.Generator) -> Disturbance:
        return self

    def __call__(self, t: float, p_W: np.ndarray, v_W: np.ndarray, R_WB: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def encode(self) -> tuple[int, np.ndarray, np.ndarray | None]:
        """``(code, params (ENC_PARAMS,), series (n, 6) or None)`` for the compiled backend
        (:mod:`vtol_impedance.compiled.plant` evaluates the same formulas)."""
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

    def profile(self, t: float) -> float:
        """Scale of the wrench at time ``t``."""
        return 1.0

    def _timing(self) -> tuple[float, ...]:
        return ()

    def encode(self) -> tuple[int, np.ndarray, np.ndarray | None]:
        return CODE[self.kind], _enc(*self.force_W, *self.torque_B, *self._timing()), None

    def __call__(self, t, p_W, v_W, R_WB):
        k = self.profile(t)
        return _const(p_W, k * np.asarray(self.force_W), k * np.asarray(self.torque_B))


@dataclass(frozen=True)
class StepWrench(ConstantWrench):
    """The constant wrench switched on at ``t_on`` and off at ``t_off``."""

    kind: ClassVar[str] = "step"
    t_on: float = 0.0
    t_off: float = float("inf")

    def profile(self, t: float) -> float:
        return 1.0 if self.t_on <= t < self.t_off else 0.0

    def _timing(self) -> tuple[float, ...]:
        return (self.t_on, self.t_off)


@dataclass(frozen=True)
class RampWrench(ConstantWrench):
    """Rises linearly from zero at ``t_start`` to the full wrench at ``t_end`` and holds."""

    kind: ClassVar[str] = "ramp"
    t_start: float = 0.0
    t_end: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.t_end > self.t_start:
            raise InputError(f"ramp needs t_end > t_start, got {self.t_start} .. {self.t_end}")

    def profile(self, t: float) -> float:
        return float(np.clip((t - self.t_start) / (self.t_end - self.t_start), 0.0, 1.0))

    def _timing(self) -> tuple[float, ...]:
        return (self.t_start, self.t_end)


@dataclass(frozen=True)
class SinusoidWrench(ConstantWrench):
    """``amplitude * sin(2 pi freq_hz (t - t_on) + phase)`` from ``t_on``; ``force_W``/``torque_B`` are amplitudes."""

    kind: ClassVar[str] = "sinusoid"
    freq_hz: float = 1.0
    phase: float = 0.0
    t_on: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        positive("freq_hz", self.freq_hz)

    def profile(self, t: float) -> float:
        return float(np.sin(2 * np.pi * self.freq_hz * (t - self.t_on) + self.phase)) if t >= self.t_on else 0.0

    def _timing(self) -> tuple[float, ...]:
        return (self.freq_hz, self.phase, self.t_on)


@dataclass(frozen=True)
class Push(ConstantWrench):
    """An operator's push: a half-sine force pulse of peak ``force_W`` from ``t_on`` lasting ``duration``."""

    kind: ClassVar[str] = "push"
    t_on: float = 5.0
    duration: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        positive("push duration", self.duration)

    def profile(self, t: float) -> float:
        s = (t - self.t_on) / self.duration
        return float(np.sin(np.pi * s)) if 0.0 <= s <= 1.0 else 0.0

    def _timing(self) -> tuple[float, ...]:
        return (self.t_on, self.duration)


def band_limited_noise(
    rng: np.random.Generator, n: int, dt: float, f_lo: float, f_hi: float, channels: int
) -> np.ndarray:
    """Zero-mean Gaussian noise with unit standard deviation, band-passed to [f_lo, f_hi] Hz, ``(n, channels)``."""
    nyq = 0.5 / dt
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

    def prepare(self, t_end: float, dt: float, rng: np.random.Generator) -> BandLimitedNoise:
        n = int(np.ceil(t_end / dt)) + 2
        unit = band_limited_noise(rng, n, dt, self.f_lo, self.f_hi, 6)
        series = unit * np.concatenate([self.force_rms_W, self.torque_rms_B])
        return replace(self, _series=series, _dt=dt)

    def encode(self) -> tuple[int, np.ndarray, np.ndarray | None]:
        if self._series is None:
            raise RuntimeError("BandLimitedNoise used before prepare()")
        return CODE["noise"], _enc(self._dt), self._series

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
        positive("fan mean_force", self.mean_force, allow_zero=True)
        positive("fan ref_distance", self.ref_distance)
        positive("fan width", self.width)
        positive("fan turbulence", self.turbulence, allow_zero=True)
        object.__setattr__(self, "turbulence_band", tuple(float(b) for b in self.turbulence_band))

    def prepare(self, t_end: float, dt: float, rng: np.random.Generator) -> FanJet:
        n = int(np.ceil(t_end / dt)) + 2
        gust = self.turbulence * band_limited_noise(rng, n, dt, *self.turbulence_band, 1)[:, 0]
        return replace(self, _gust=gust, _dt=dt)

    def encode(self) -> tuple[int, np.ndarray, np.ndarray | None]:
        params = _enc(
            *self.position_W,
            *self.direction_W,
            self.mean_force,
            self.ref_distance,
            self.width,
            *self.cop_offset_B,
            self.t_on,
            self._dt,
        )
        series = None
        if self._gust is not None:
            series = np.zeros((len(self._gust), 6))
            series[:, 0] = self._gust
        return CODE["fan"], params, series

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

    The plant's own ``rotor_drag * v`` term supplies the part due to the vehicle's motion.
    """

    kind: ClassVar[str] = "wind"
    velocity_W: Vec3 = (0.0, 0.0, 0.0)
    drag: float = 0.18

    def __post_init__(self) -> None:
        object.__setattr__(self, "velocity_W", _vec("velocity_W", self.velocity_W))
        positive("wind drag", self.drag, allow_zero=True)

    def encode(self) -> tuple[int, np.ndarray, np.ndarray | None]:
        return CODE["constant"], _enc(*(self.drag * np.asarray(self.velocity_W)), 0.0, 0.0, 0.0), None

    def __call__(self, t, p_W, v_W, R_WB):
        return _const(p_W, self.drag * np.asarray(self.velocity_W), np.zeros(3))


KINDS: dict[str, type[Disturbance]] = {
    c.kind: c for c in (ConstantWrench, StepWrench, RampWrench, SinusoidWrench, Push, BandLimitedNoise, FanJet, Wind)
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

    def __call__(self, t: float, p_W: np.ndarray, v_W: np.ndarray, R_WB: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = np.zeros(np.shape(p_W))
        tau = np.zeros(np.shape(p_W))
        for d in self.items:
            fi, ti = d(t, p_W, v_W, R_WB)
            f = f + fi
            tau = tau + ti
        return f, tau
