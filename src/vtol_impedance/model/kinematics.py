"""Attitude kinematics, eq. (1) of Ruggiero et al. (2014).

All functions take arrays with arbitrary leading batch dimensions: ``eta`` is ``(..., 3)``
and matrices come back as ``(..., 3, 3)``.

References
----------
Ruggiero, Cacace, Sadeghian, Lippiello, "Impedance Control of VTOL UAVs with a Momentum-based
External Generalized Forces Estimator", ICRA 2014, eqs. (1a)-(1c).
"""

from __future__ import annotations

import numpy as np

from ..conventions import SINGULARITY_COS_EPS
from ..errors import SingularityError, batched


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``S(v)`` with ``S(v) w = v x w``; ``v`` is ``(..., 3)``."""
    v = batched("v", v, (3,))
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` over the last axis (a lighter ``np.cross`` for small batched vectors)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def rotation_zyx(eta: np.ndarray) -> np.ndarray:
    """Rotation ``R_WB = Rz(psi) Ry(theta) Rx(phi)`` from ZYX Euler angles ``eta = [phi, theta, psi]``."""
    eta = batched("eta", eta, (3,))
    c = np.cos(eta)
    s = np.sin(eta)
    cf, ct, cp = c[..., 0], c[..., 1], c[..., 2]
    sf, st, sp = s[..., 0], s[..., 1], s[..., 2]
    return np.stack(  # eq. (1a): R_WB
        [
            np.stack([cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf], -1),
            np.stack([sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf], -1),
            np.stack([-st, ct * sf, ct * cf], -1),
        ],
        -2,
    )


def check_euler_regular(eta: np.ndarray) -> None:
    """Raise :class:`SingularityError` if pitch is within the singular band around +-pi/2."""
    ct = np.abs(np.cos(np.asarray(eta, dtype=float)[..., 1]))
    if np.any(ct < SINGULARITY_COS_EPS):
        theta = np.asarray(eta)[..., 1][ct < SINGULARITY_COS_EPS].ravel()[0]
        raise SingularityError(
            f"pitch theta = {np.degrees(theta):.3f} deg is at the ZYX Euler singularity (+-90 deg); "
            "Q(eta) and M(eta) are not invertible there"
        )


def euler_rate_matrix_T(eta: np.ndarray) -> np.ndarray:
    """``T(eta)`` with ``omega_W = T(eta) eta_dot``, eq. (1b)."""
    eta = batched("eta", eta, (3,))
    ct, st = np.cos(eta[..., 1]), np.sin(eta[..., 1])
    cp, sp = np.cos(eta[..., 2]), np.sin(eta[..., 2])
    z, o = np.zeros_like(ct), np.ones_like(ct)
    return np.stack(
        [
            np.stack([cp * ct, -sp, z], -1),  # eq. (1b): T(eta)
            np.stack([sp * ct, cp, z], -1),
            np.stack([-st, z, o], -1),
        ],
        -2,
    )


def euler_rate_matrix_Q(eta: np.ndarray) -> np.ndarray:
    """``Q(eta) = R_WB^T T(eta)`` with ``omega_B = Q(eta) eta_dot``, eq. (1c)."""
    eta = batched("eta", eta, (3,))
    cf, sf = np.cos(eta[..., 0]), np.sin(eta[..., 0])
    ct, st = np.cos(eta[..., 1]), np.sin(eta[..., 1])
    z, o = np.zeros_like(cf), np.ones_like(cf)
    return np.stack(
        [
            np.stack([o, z, -st], -1),  # eq. (1c): Q(eta)
            np.stack([z, cf, sf * ct], -1),
            np.stack([z, -sf, cf * ct], -1),
        ],
        -2,
    )


def euler_rate_matrix_Q_dot(eta: np.ndarray, eta_dot: np.ndarray) -> np.ndarray:
    """Time derivative ``Q_dot(eta, eta_dot)`` of :func:`euler_rate_matrix_Q`."""
    eta = batched("eta", eta, (3,))
    eta_dot = batched("eta_dot", eta_dot, (3,))
    cf, sf = np.cos(eta[..., 0]), np.sin(eta[..., 0])
    ct, st = np.cos(eta[..., 1]), np.sin(eta[..., 1])
    df, dt = eta_dot[..., 0], eta_dot[..., 1]
    z = np.zeros_like(cf)
    return np.stack(
        [
            np.stack([z, z, -ct * dt], -1),  # d/dt of eq. (1c)
            np.stack([z, -sf * df, cf * ct * df - sf * st * dt], -1),
            np.stack([z, -cf * df, -sf * ct * df - cf * st * dt], -1),
        ],
        -2,
    )


def euler_from_rotation(R_WB: np.ndarray) -> np.ndarray:
    """ZYX Euler angles ``[phi, theta, psi]`` of ``R_WB`` (theta in [-pi/2, pi/2])."""
    R = np.asarray(R_WB, dtype=float)
    phi = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    theta = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    psi = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([phi, theta, psi], -1)


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrix ``R_WB`` of a unit quaternion ``q = [w, x, y, z]`` (body to world)."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def quat_from_euler(eta: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[w, x, y, z]`` (scalar first, rotating body to world, like ``R_WB``) of the ZYX
    Euler angles ``eta``."""
    eta = np.asarray(eta, dtype=float)
    h = 0.5 * eta
    cf, sf = np.cos(h[..., 0]), np.sin(h[..., 0])
    ct, st = np.cos(h[..., 1]), np.sin(h[..., 1])
    cp, sp = np.cos(h[..., 2]), np.sin(h[..., 2])
    return np.stack(
        [
            cp * ct * cf + sp * st * sf,
            cp * ct * sf - sp * st * cf,
            cp * st * cf + sp * ct * sf,
            sp * ct * cf - cp * st * sf,
        ],
        -1,
    )


def quat_derivative(q: np.ndarray, omega_B: np.ndarray) -> np.ndarray:
    """``q_dot = 0.5 q (x) [0, omega_B]`` for a body-to-world quaternion ``[w, x, y, z]``."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    p, r_, s = omega_B[..., 0], omega_B[..., 1], omega_B[..., 2]
    return 0.5 * np.stack(
        [
            -x * p - y * r_ - z * s,
            w * p + y * s - z * r_,
            w * r_ - x * s + z * p,
            w * s + x * r_ - y * p,
        ],
        -1,
    )


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap angles to ``[-pi, pi)``."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi
