"""Reference trajectories for the flat outputs (position and yaw) with their derivatives.

A :class:`Trajectory` is a sequence of segments (hold, minimum-jerk move, circle) played one after
another; yaw is a planned piecewise-constant profile (steps are passed to the controller as they are,
which is how the yaw-step stress test asks the allocation for more than the rotors can give).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, as_finite, positive
from .signals import Reference


def _smooth5(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk blend ``10 s^3 - 15 s^4 + 6 s^5`` on [0, 1] and its first two derivatives in s."""
    s = np.clip(s, 0.0, 1.0)
    return (
        s**3 * (10 - 15 * s + 6 * s * s),
        30 * s * s * (1 - s) ** 2,
        60 * s * (1 - s) * (1 - 2 * s),
    )


@dataclass(frozen=True)
class Hold:
    """Stay at ``p_W`` for ``duration`` seconds."""

    p_W: tuple[float, float, float]
    duration: float

    def start(self) -> np.ndarray:
        return np.asarray(self.p_W, dtype=float)

    end = start

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        z = np.zeros(3)
        return self.start(), z, z


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

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        T = self.duration
        s, ds, dds = _smooth5(np.asarray(tau / T))
        d = self.end() - self.start()
        return self.start() + s * d, ds / T * d, dds / (T * T) * d


@dataclass(frozen=True)
class Circle:
    """Circle in the horizontal plane, entered and left at ``start_W`` with a smooth speed ramp.

    The tangential speed ramps from 0 to ``speed`` in ``ramp`` seconds (minimum-jerk profile), holds,
    and ramps back to 0 so that exactly ``laps`` turns are flown. The centre is ``radius`` metres from
    ``start_W`` along ``-x``; the circle is flown counter-clockwise seen from above (NED: x north, y east).
    """

    start_W: tuple[float, float, float]
    radius: float = 1.0
    speed: float = 0.5
    laps: float = 2.0
    ramp: float = 2.0

    def __post_init__(self) -> None:
        positive("circle radius", self.radius)
        positive("circle speed", self.speed)
        positive("circle laps", self.laps)
        positive("circle ramp", self.ramp, allow_zero=True)
        w = self.speed / self.radius
        if w * self.ramp > 2 * np.pi * self.laps:
            raise InputError("circle ramp is too long for the number of laps at this speed")

    @property
    def _w(self) -> float:
        return self.speed / self.radius

    @property
    def duration(self) -> float:
        # Each ramp covers half the angle it would at full speed.
        return 2 * np.pi * self.laps / self._w + self.ramp

    def start(self) -> np.ndarray:
        return np.asarray(self.start_W, dtype=float)

    end = start

    def _angle(self, tau: float) -> tuple[float, float, float]:
        w, Tr, T = self._w, self.ramp, self.duration
        if Tr == 0:
            return w * tau, w, 0.0
        if tau < Tr:
            # integral of the min-jerk speed profile s(u) from 0 to tau
            u = tau / Tr
            integ = Tr * (2.5 * u**4 - 3 * u**5 + u**6)
            s, ds, _ = _smooth5(np.asarray(u))
            return w * integ, w * float(s), w * float(ds) / Tr
        if tau <= T - Tr:
            return w * (Tr / 2 + (tau - Tr)), w, 0.0
        a_end = 2 * np.pi * self.laps
        th, thd, thdd = self._angle_rampdown(T - tau)
        return a_end - th, thd, thdd

    def _angle_rampdown(self, rem: float) -> tuple[float, float, float]:
        # mirror of the ramp-up, measured from the end
        w, Tr = self._w, self.ramp
        u = max(rem, 0.0) / Tr
        integ = Tr * (2.5 * u**4 - 3 * u**5 + u**6)
        s, ds, _ = _smooth5(np.asarray(u))
        return w * integ, w * float(s), -w * float(ds) / Tr

    def sample(self, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        th, thd, thdd = self._angle(tau)
        R = self.radius
        c = self.start() - np.array([R, 0.0, 0.0])
        cs, sn = np.cos(th), np.sin(th)
        p = c + R * np.array([cs, sn, 0.0])
        v = R * thd * np.array([-sn, cs, 0.0])
        a = R * thdd * np.array([-sn, cs, 0.0]) - R * thd * thd * np.array([cs, sn, 0.0])
        return p, v, a


Segment = Hold | MinJerk | Circle


@dataclass(frozen=True)
class Trajectory:
    """Segments played back to back from t = 0, then holding the last point; yaw steps ``(t, psi)``."""

    segments: tuple[Segment, ...]
    yaw0: float = 0.0
    yaw_steps: tuple[tuple[float, float], ...] = ()
    _t0: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.segments:
            raise InputError("a trajectory needs at least one segment")
        durations = [float(positive("segment duration", s.duration, allow_zero=True)) for s in self.segments]
        for a, b in zip(self.segments[:-1], self.segments[1:], strict=True):
            if not np.allclose(a.end(), b.start(), atol=1e-9):
                raise InputError(f"trajectory segments do not join: {a.end()} then {b.start()}")
        as_finite("yaw0", self.yaw0)
        object.__setattr__(self, "_t0", np.concatenate([[0.0], np.cumsum(durations)]))

    @property
    def duration(self) -> float:
        return float(self._t0[-1])

    def phase_times(self) -> np.ndarray:
        """Start time of each segment and the end time of the last, s."""
        return self._t0.copy()

    def sample(self, t: float) -> Reference:
        i = int(np.searchsorted(self._t0, t, side="right") - 1)
        if i >= len(self.segments):
            p = self.segments[-1].end()
            z = np.zeros(3)
            p_, v_, a_ = p, z, z
        else:
            p_, v_, a_ = self.segments[max(i, 0)].sample(max(t - self._t0[max(i, 0)], 0.0))
        psi = self.yaw0
        for ts, val in self.yaw_steps:
            if t >= ts:
                psi = val
        return Reference(p_, v_, a_, np.asarray(psi), np.asarray(0.0), np.asarray(0.0))
