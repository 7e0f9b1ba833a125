"""A flight with a known external wrench, built from Newton-Euler rigid-body equations (not the paper's
Euler-Lagrange form that the estimator uses), for the log-estimation tests.

The attitude is prescribed analytically; the body rates come from ``R^T dR/dt`` by finite differences
of the rotation, the torque command from ``I w_dot + w x I w = tau_B + tau_ext_B``; the thrust command
is prescribed and the velocity integrated from ``m a = m g e3 - u R e3 + f_ext`` with a tight-tolerance
ODE solver. So the log's commands produce exactly the logged motion under the known wrench.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.integrate
import scipy.signal

from vtol_impedance.model.kinematics import rotation_zyx

G = 9.81
MASS = 1.2
INERTIA = np.diag([0.0135, 0.0137, 0.0247])
F_BIAS = np.array([0.3, -0.2, 0.5])
F_STEP = np.array([1.0, 0.0, 0.0])
T_F_STEP = 5.0
TAU_BIAS = np.array([0.02, -0.01, 0.005])
TAU_STEP = np.array([0.0, 0.03, 0.0])
T_TAU_STEP = 7.0


def eta_of(t):
    t = np.asarray(t, dtype=float)
    return np.stack([0.05 * np.sin(1.3 * t), 0.04 * np.sin(0.9 * t + 0.5), 0.3 * np.sin(0.2 * t)], -1)


def thrust_of(t):
    e = eta_of(t)
    return MASS * G * (1.0 + 0.05 * np.sin(0.7 * np.asarray(t))) / (np.cos(e[..., 0]) * np.cos(e[..., 1]))


def f_ext_of(t):
    t = np.asarray(t, dtype=float)
    return F_BIAS + F_STEP * (t >= T_F_STEP)[..., None]


def tau_ext_of(t):
    t = np.asarray(t, dtype=float)
    return TAU_BIAS + TAU_STEP * (t >= T_TAU_STEP)[..., None]


def omega_of(t, h=1e-6):
    R = rotation_zyx(eta_of(t))
    Rd = (rotation_zyx(eta_of(t + h)) - rotation_zyx(eta_of(t - h))) / (2 * h)
    W = np.swapaxes(R, -1, -2) @ Rd
    return np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], -1)


def torque_of(t, h=1e-5):
    w = omega_of(t)
    wd = (omega_of(t + h) - omega_of(t - h)) / (2 * h)
    Iw = w @ INERTIA.T
    return wd @ INERTIA.T + np.cross(w, Iw) - tau_ext_of(t)


def accel(t, v=None):
    R = rotation_zyx(eta_of(t))
    return G * np.array([0, 0, 1.0]) - np.asarray(thrust_of(t))[..., None] * R[..., :, 2] / MASS + f_ext_of(t) / MASS


@dataclass
class Flight:
    t: np.ndarray
    v_W: np.ndarray
    eta: np.ndarray
    omega_B: np.ndarray
    thrust: np.ndarray
    tau_B: np.ndarray
    f_ext_W: np.ndarray
    tau_ext_B: np.ndarray


def flight(duration: float = 12.0, rate: float = 250.0) -> Flight:
    t = np.arange(0.0, duration + 1e-9, 1.0 / rate)
    v = np.zeros((len(t), 3))
    v0 = np.zeros(3)
    edges = [0.0, T_F_STEP, duration + 1e-9]  # integrate across the step exactly
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        sel = (t >= a) & (t < b)
        sol = scipy.integrate.solve_ivp(lambda s, y: accel(s), (a, b), v0, rtol=1e-11, atol=1e-12, dense_output=True)
        v[sel] = sol.sol(t[sel]).T
        v0 = sol.sol(b - 1e-12) if b < duration else v0
    return Flight(t, v, eta_of(t), omega_of(t), thrust_of(t), torque_of(t), f_ext_of(t), tau_ext_of(t))


def g_response(t: np.ndarray, w_of, wn: float = 10.0, zeta: float = 1.0) -> np.ndarray:
    """The continuous-time G(s) of eq. (10) applied to the wrench ``w_of(time) -> (N, k)`` from rest at
    ``t[0]``, by scipy.signal.lsim on a fine time axis: what an ideal estimator would give."""
    fine = np.arange(t[0], t[-1] + 1e-9, 1e-4)
    w = w_of(fine)
    out = np.empty((len(t), w.shape[1]))
    sys = scipy.signal.lti([wn * wn], [1.0, 2 * zeta * wn, wn * wn])
    for j in range(w.shape[1]):
        _, y, _ = scipy.signal.lsim(sys, w[:, j], fine)
        out[:, j] = np.interp(t, fine, y)
    return out


@functools.cache
def _g_of_wrench_from_zero(which: str, wn: float, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    fine = np.arange(0.0, 12.5, 1e-4)
    w_of = f_ext_of if which == "f" else tau_ext_of
    return fine, g_response(fine, w_of, wn, zeta)


def g_of_true_wrench(t: np.ndarray, which: str = "f", wn: float = 10.0, zeta: float = 1.0) -> np.ndarray:
    """:func:`g_response` of the true force (``which="f"``) or body moment (``"tau"``) from rest at t = 0,
    computed once (lsim on a 0.1 ms grid) and interpolated at ``t`` (which must start near 0: an estimate
    starting later differs only in its first second)."""
    fine, y = _g_of_wrench_from_zero(which, float(wn), float(zeta))
    return np.stack([np.interp(t, fine, y[:, j]) for j in range(y.shape[1])], -1)
