"""Reference trajectories for the flat outputs (position and yaw) with their derivatives.

A :class:`Trajectory` is a sequence of segments (hold, minimum-jerk move, circle, figure-eight) played one after
another; yaw is a planned piecewise-constant profile (steps are passed to the controller as they are,
which is how the yaw-step stress test asks the allocation for more than the rotors can give).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, as_finite, positive, scalar
from .signals import Reference, comply6


def _smooth5(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk blend ``10 s^3 - 15 s^4 + 6 s^5`` on [0, 1] and its first two derivatives in s."""
    s = np.clip(s, 0.0, 1.0)
    r = 1 - s
    s2 = s * s  # products, not powers: an array power is a pow() per element, ten times the time
    return s2 * s * (10 - 15 * s + 6 * s2), 30 * s2 * r * r, 60 * s * r * (1 - 2 * s)


@dataclass(frozen=True)
class Hold:
    """Stay at ``p_W`` for ``duration`` seconds."""

    p_W: tuple[float, float, float]
    duration: float

    def start(self) -> np.ndarray:
        return np.asarray(self.p_W, dtype=float)

    end = start

    def sample(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = np.shape(tau)[0]
        z = np.zeros((n, 3))
        return np.broadcast_to(self.start(), (n, 3)), z, z


@dataclass(frozen=True)
class MinJerk:
    """Rest-to-rest minimum-jerk move from ``p0_W`` to ``p1_W`` in ``duration`` seconds."""

    p0_W: tuple[float, float, float]
    p1_W: tuple[float, float, float]
    duration: float

    def start(self) -> np.ndarray:
        return np.asarray(self.p0_W, dtype=float)

    def end(self) -> np.ndarray:
        return np.asarray(self.p1_W, dtype=float)

    def sample(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        T = self.duration
        s, ds, dds = (v[:, None] for v in _smooth5(np.asarray(tau) / T))
        d = self.end() - self.start()
        return self.start() + s * d, ds / T * d, dds / (T * T) * d


class _Laps:
    """What the lapped segments share (:class:`Circle`, :class:`FigureEight`): ``laps`` turns of an angle
    at the rate ``_w`` (rad/s, from ``speed`` and the segment's size), with minimum-jerk ramps of ``ramp``
    seconds at both ends, entered and left at ``start_W``."""

    start_W: tuple[float, float, float]
    speed: float
    laps: float
    ramp: float

    @property
    def _w(self) -> float:
        raise NotImplementedError

    def _check_laps(self, what: str) -> None:
        positive(f"{what} speed", self.speed)
        positive(f"{what} laps", self.laps)
        positive(f"{what} ramp", self.ramp, allow_zero=True)
        if self._w * self.ramp > 2 * np.pi * self.laps:
            raise InputError(f"{what} ramp is too long for the number of laps at this speed")

    @property
    def duration(self) -> float:
        # Each ramp covers half the angle it would at full speed.
        return 2 * np.pi * self.laps / self._w + self.ramp

    def start(self) -> np.ndarray:
        return np.asarray(self.start_W, dtype=float)

    end = start

    def _angle(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Angle travelled and its two derivatives at times ``tau`` (array) into the segment."""
        return _ramped_angle(tau, self._w, self.ramp, self.duration, self.laps)


@dataclass(frozen=True)
class Circle(_Laps):
    """Circle in the horizontal plane, entered and left at ``start_W`` with a smooth speed ramp.

    The tangential speed ramps from 0 to ``speed`` in ``ramp`` seconds (minimum-jerk profile), holds,
    and ramps back to 0 so that exactly ``laps`` turns are flown. The centre is ``radius`` metres from
    ``start_W`` along ``-x``; the circle is flown clockwise seen from above (NED: x north, y east; from the
    start, north of the centre, towards the east: the sense of a positive NED yaw).
    """

    start_W: tuple[float, float, float]
    radius: float = 1.0
    speed: float = 0.5
    laps: float = 2.0
    ramp: float = 2.0

    def __post_init__(self) -> None:
        positive("circle radius", self.radius)
        self._check_laps("circle")

    @property
    def _w(self) -> float:
        return self.speed / self.radius

    def sample(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        th, thd, thdd = (v[:, None] for v in self._angle(tau))
        R = self.radius
        c = self.start() - np.array([R, 0.0, 0.0])
        cs, sn, z = np.cos(th), np.sin(th), np.zeros_like(th)
        radial = np.concatenate([cs, sn, z], -1)
        tangent = np.concatenate([-sn, cs, z], -1)
        return c + R * radial, R * thd * tangent, R * thdd * tangent - R * thd * thd * radial


@dataclass(frozen=True)
class FigureEight(_Laps):
    """A lemniscate of Gerono in the horizontal plane, centred on ``start_W`` and entered and left there.

    ``p(th) = start + a [sin th, sin th cos th, 0]`` with ``a = half_length``: two lobes along x (NED north),
    ``2 a`` long and ``a`` wide, crossing at the start. The parameter rate ramps from 0 to ``w`` in
    ``ramp`` seconds (the circle's minimum-jerk profile), holds and ramps back so that exactly ``laps``
    eights are flown; position, velocity and acceleration are analytic and continuous (what the
    controller uses). ``speed`` is the speed at the crossing, the fastest point: ``|dp/dth| = a sqrt(2)``
    there and ``a`` at the lobes' tips, so ``w = speed / (a sqrt(2))``; the curve is 6.097 ``a`` long, so
    the mean speed is 0.686 ``speed`` (6.097 / (2 pi sqrt(2))).
    """

    start_W: tuple[float, float, float]
    half_length: float = 1.0
    speed: float = 0.5
    laps: float = 2.0
    ramp: float = 2.0

    def __post_init__(self) -> None:
        positive("figure-eight half length", self.half_length)
        self._check_laps("figure-eight")

    @property
    def _w(self) -> float:
        return self.speed / (self.half_length * np.sqrt(2.0))

    def sample(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        th, thd, thdd = (v[:, None] for v in self._angle(tau))
        a = self.half_length
        s1, c1, s2, c2, z = np.sin(th), np.cos(th), np.sin(2 * th), np.cos(2 * th), np.zeros_like(th)
        p = np.concatenate([a * s1, 0.5 * a * s2, z], -1)  # sin th cos th = sin(2 th) / 2
        dp = np.concatenate([a * c1, a * c2, z], -1)  # d/dth
        ddp = np.concatenate([-a * s1, -2 * a * s2, z], -1)
        return self.start() + p, dp * thd, ddp * thd * thd + dp * thdd


def _ramped_angle(
    tau: np.ndarray, w: float, Tr: float, T: float, laps: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angle travelled at rate ``w`` with minimum-jerk ramps of ``Tr`` s at both ends of a segment of
    ``T`` s covering ``laps`` turns, and its two derivatives, at times ``tau`` (array) into the segment."""
    tau = np.asarray(tau, dtype=float)
    if Tr == 0:
        return w * tau, np.full_like(tau, w), np.zeros_like(tau)
    u_up = np.clip(tau / Tr, 0.0, 1.0)
    u_dn = np.clip((T - tau) / Tr, 0.0, 1.0)
    s_up, ds_up, _ = _smooth5(u_up)
    s_dn, ds_dn, _ = _smooth5(u_dn)
    integ = lambda u: Tr * (u * u) ** 2 * (2.5 - 3 * u + u * u)  # noqa: E731
    up, down = tau < Tr, tau > T - Tr
    th = np.where(up, w * integ(u_up), np.where(down, 2 * np.pi * laps - w * integ(u_dn), w * (Tr / 2 + (tau - Tr))))
    thd = np.where(up, w * s_up, np.where(down, w * s_dn, w))
    thdd = np.where(up, w * ds_up / Tr, np.where(down, -w * ds_dn / Tr, 0.0))
    return th, thd, thdd


Segment = Hold | MinJerk | Circle | FigureEight


@dataclass(frozen=True)
class Trajectory:
    """Segments played back to back from t = 0, then holding the last point; yaw steps ``(t, psi)``."""

    segments: tuple[Segment, ...]
    yaw0: float = 0.0
    yaw_steps: tuple[tuple[float, float], ...] = ()
    comply0: tuple[float, ...] = (0.0, 0.0, 0.0)  # x, y, z (and roll, pitch, yaw: 0 if not given)
    comply_switches: tuple[tuple[float, int, float], ...] = ()  # (time s, axis 0..5, fraction)
    blend_s: float = 0.5
    _t0: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.segments:
            raise InputError("a trajectory needs at least one segment")
        c0 = as_finite("comply0", self.comply0)
        if c0.shape not in ((3,), (6,)) or np.any((c0 < 0) | (c0 > 1)):
            raise InputError(
                f"comply0 must be 3 (x, y, z) or 6 (and roll, pitch, yaw) fractions in [0, 1], got {self.comply0!r}"
            )
        object.__setattr__(self, "comply0", tuple(float(c) for c in comply6(c0)))
        for sw in self.comply_switches:
            if len(sw) != 3 or not isinstance(sw[1], int | np.integer) or not 0 <= sw[1] <= 5 or not 0 <= sw[2] <= 1:
                raise InputError(f"a comply switch is (time s, axis 0..5, fraction 0..1), got {sw!r}")
            scalar("comply switch time", sw[0], lo=0.0)
        scalar("blend_s", self.blend_s, lo=0.0)
        durations = [scalar("segment duration", s.duration, lo=0.0) for s in self.segments]
        for a, b in zip(self.segments[:-1], self.segments[1:], strict=True):
            gap = np.abs(a.end() - b.start())
            if not np.all(gap <= 1e-9 + 1e-5 * np.abs(b.start())):  # np.allclose's test, without its overhead
                raise InputError(f"trajectory segments do not join: {a.end()} then {b.start()}")
        as_finite("yaw0", self.yaw0)
        object.__setattr__(self, "_t0", np.concatenate([[0.0], np.cumsum(durations)]))

    @property
    def duration(self) -> float:
        return float(self._t0[-1])

    def phase_times(self) -> np.ndarray:
        """Start time of each segment and the end time of the last, s."""
        return self._t0.copy()

    def comply_at(self, t: np.ndarray) -> np.ndarray:
        """The comply fraction per axis ``[x, y, z, roll, pitch, yaw]`` at the times ``t``, ``(N, 6)``: each
        switch moves an axis from
        its current fraction to the new one along a minimum-jerk blend of ``blend_s`` seconds."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.tile(np.asarray(self.comply0, dtype=float), (t.size, 1))
        for ts, axis, frac in sorted(self.comply_switches, key=lambda s: s[0]):
            before = out[:, axis].copy()
            if self.blend_s > 0:
                w = _smooth5((t - ts) / self.blend_s)[0]
            else:
                w = (t >= ts).astype(float)
            out[:, axis] = np.where(t >= ts, before + w * (frac - before), before)
        return out

    def sample_many(self, t: np.ndarray) -> np.ndarray:
        """Rows ``[p_W (3), v_W (3), a_W (3), psi, psi_dot, psi_ddot, comply (6)]`` at the times ``t``,
        shape ``(N, 18)``."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.zeros((t.size, 18))
        out[:, 12:18] = self.comply_at(t)
        seg = np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self.segments))
        ordered = t.size < 2 or bool(np.all(t[1:] >= t[:-1]))  # the usual case: a segment is a slice
        for i, segment in enumerate(self.segments):
            if ordered:
                m = slice(*np.searchsorted(seg, [i, i + 1]))
            else:
                m = seg == i
            if t[m].size:
                p, v, a = segment.sample(np.maximum(t[m] - self._t0[i], 0.0))
                out[m, 0:3], out[m, 3:6], out[m, 6:9] = p, v, a
        after = seg >= len(self.segments)
        out[after, 0:3] = self.segments[-1].end()
        out[:, 9] = self.yaw0
        for ts, val in self.yaw_steps:
            out[t >= ts, 9] = val
        return out

    def sample(self, t: float) -> Reference:
        """The reference at one time ``t``."""
        r = self.sample_many(np.array([t]))[0]
        return Reference(r[0:3], r[3:6], r[6:9], np.asarray(r[9]), np.asarray(r[10]), np.asarray(r[11]), r[12:15])
