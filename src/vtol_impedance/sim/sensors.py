"""Sensor models: motion capture (position, velocity) and IMU (attitude, body rates).

Each sensor reads the true state some time ago (latency, an integer number of plant steps: a latency
between two steps flies rounded to the nearest, with a :class:`LatencyWarning`) and adds
seeded Gaussian noise (:class:`NoiseSource`). The controller receives Euler rates computed from the measured gyro rate,
``eta_dot = Q(eta)^{-1} omega_B``, as on the real vehicle.
"""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..control.signals import Measurement
from ..errors import scalar
from ..model.kinematics import euler_from_rotation, euler_rate_matrix_Q, quat_to_rotation
from .plant import OMEGA, QUAT, PlantArrays, origin_kinematics

#: Longest sensor latency accepted, s.
MAX_DELAY_S = 1.0


@dataclass(frozen=True)
class SensorParams:
    """Noise standard deviations and latencies. Defaults: OptiTrack over WiFi and a MEMS IMU.

    ``pos_noise`` [m], ``vel_noise`` [m/s], ``mocap_delay`` [s]; ``att_noise`` [rad] per Euler angle,
    ``gyro_noise`` [rad/s] per axis, ``imu_delay`` [s]. Delays are at most :data:`MAX_DELAY_S`.
    """

    pos_noise: float = 3e-4
    vel_noise: float = 0.003
    mocap_delay: float = 0.02
    att_noise: float = 3e-3
    gyro_noise: float = 0.01
    imu_delay: float = 0.002

    def __post_init__(self) -> None:
        for name in ("pos_noise", "vel_noise", "att_noise", "gyro_noise"):
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0))
        for name in ("mocap_delay", "imu_delay"):  # bounded: the loop keeps that much state history
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0, hi=MAX_DELAY_S))

    @classmethod
    def ideal(cls) -> SensorParams:
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


class LatencyWarning(UserWarning):
    """A sensor latency is not a whole number of plant steps: it flies rounded to the nearest step (the
    plant's state exists only at its steps); the result's config records the values flown."""


def latency_steps(params: SensorParams, dt_plant: float) -> tuple[int, int]:
    """The motion-capture and IMU latencies in plant steps of ``dt_plant`` s, rounded to the nearest."""
    return int(round(params.mocap_delay / dt_plant)), int(round(params.imu_delay / dt_plant))


def rounded_latencies(params: SensorParams, dt_plant: float) -> dict[str, float]:
    """The latencies that are not whole plant steps, by name, with the value they fly at (s)."""
    out = {}
    for name, k in zip(("mocap_delay", "imu_delay"), latency_steps(params, dt_plant), strict=True):
        if abs(k * dt_plant - getattr(params, name)) > 1e-6 * dt_plant:
            out[name] = k * dt_plant
    return out


class SensorSuite:
    """Keeps a short history of plant states to serve delayed, noisy measurements."""

    def __init__(self, params: SensorParams, plant: PlantArrays, dt_plant: float) -> None:
        self.params = params
        self.plant = plant
        self.k_mocap, self.k_imu = latency_steps(params, dt_plant)
        moved = rounded_latencies(params, dt_plant)
        if moved:
            warnings.warn(
                LatencyWarning(
                    ", ".join(f"sensors.{n} = {getattr(params, n):g} s flies as {v:g} s" for n, v in moved.items())
                    + f": a latency is a whole number of plant steps ({dt_plant * 1e3:g} ms)"
                ),
                stacklevel=2,
            )
        self.history: deque[np.ndarray] = deque(maxlen=max(self.k_mocap, self.k_imu) + 1)

    def push(self, x: np.ndarray) -> None:
        """Record the plant state after each plant step (and once at the start)."""
        self.history.append(x)

    def _ago(self, k: int) -> np.ndarray:
        return self.history[max(len(self.history) - 1 - k, 0)]

    def delayed(self) -> tuple[np.ndarray, np.ndarray]:
        """The plant states the motion capture and the IMU read now (``mocap_delay``, ``imu_delay`` ago)."""
        return self._ago(self.k_mocap), self._ago(self.k_imu)

    def measure(self, noise: np.ndarray) -> Measurement:
        """Measurement from the delayed states plus ``sigma * noise``; ``noise (..., 12)`` are standard
        normals ordered ``[position (3), velocity (3), attitude (3), gyro (3)]``."""
        return measurement(self.plant, *self.delayed(), self.sigma, noise)

    @property
    def sigma(self) -> np.ndarray:
        """``[pos, vel, att, gyro]`` standard deviations, the scale of each noise group."""
        p = self.params
        return np.array([p.pos_noise, p.vel_noise, p.att_noise, p.gyro_noise])


class NoiseSource:
    """Standard-normal sensor noise, one seeded stream per vehicle, drawn in blocks of control ticks.

    A vehicle's numbers depend only on its own seed, so a batch sees exactly what single runs see. The
    generators are made on the first draw: the compiled engines draw the same streams from the seeds
    (:func:`vtol_impedance.compiled.noise.generator_states`).
    """

    def __init__(self, seeds: list[int]) -> None:
        self.seeds = [int(s) for s in seeds]
        self._gens: list[np.random.Generator] | None = None

    @property
    def gens(self) -> list[np.random.Generator]:
        """One ``default_rng(SeedSequence([seed, 0]))`` per vehicle."""
        if self._gens is None:
            self._gens = [np.random.default_rng(np.random.SeedSequence([s, 0])) for s in self.seeds]
        return self._gens

    def block(self, n: int) -> np.ndarray:
        """``(B, n, 12)`` standard normals."""
        out = np.empty((len(self.gens), n, 12))
        for b, g in enumerate(self.gens):
            g.standard_normal(out=out[b])
        return out


def measurement(
    plant: PlantArrays,
    x_mocap: np.ndarray,
    x_imu: np.ndarray,
    sigma: np.ndarray | None = None,
    noise: np.ndarray | None = None,
) -> Measurement:
    """What the sensors report: the body origin's position and velocity from the plant state ``x_mocap``
    (motion capture), the attitude and the Euler rates ``Q(eta)^{-1} omega_B`` from ``x_imu`` (IMU), plus
    ``sigma [pos, vel, att, gyro] * noise (..., 12)`` when given (noise-free otherwise)."""
    p_o, v_o = origin_kinematics(plant, x_mocap)
    eta = euler_from_rotation(quat_to_rotation(x_imu[..., QUAT]))
    omega = x_imu[..., OMEGA]
    if noise is not None:
        s = np.zeros(4) if sigma is None else sigma
        p_o = p_o + s[0] * noise[..., 0:3]
        v_o = v_o + s[1] * noise[..., 3:6]
        eta = eta + s[2] * noise[..., 6:9]
        omega = omega + s[3] * noise[..., 9:12]
    eta_dot = np.linalg.solve(euler_rate_matrix_Q(eta), omega[..., None])[..., 0]
    return Measurement(p_o, v_o, eta, eta_dot)
