"""Thrust and desired roll/pitch from the virtual acceleration, eq. (16) solved in NED.

Eq. (16) reads ``mu_bar = mu - f_hat_ext_W / m = g_W - (u / m) R(eta_d) e3`` (world NED, z down).
With ``R e3 = [c_phi s_theta c_psi + s_phi s_psi, c_phi s_theta s_psi - s_phi c_psi, c_phi c_theta]``:

    u       = m sqrt(mu_bar_1^2 + mu_bar_2^2 + (g - mu_bar_3)^2)
    phi_d   = asin(m (mu_bar_2 cos psi_d - mu_bar_1 sin psi_d) / u)
    theta_d = atan2(-(mu_bar_1 cos psi_d + mu_bar_2 sin psi_d), g - mu_bar_3)

Eq. (20) as printed in the paper uses another sign convention (z up, opposite roll sign); these are
the NED forms that match eqs. (1)-(5).
"""

from __future__ import annotations

import numpy as np

from ..conventions import G
from ..errors import batched
from ..model.dynamics import thrust_direction_W

#: Default bound on the tilt of the thrust vector, rad (35 deg).
TILT_MAX_DEFAULT = float(np.radians(35.0))


def thrust_and_attitude(
    mu_bar: np.ndarray,
    psi_d: np.ndarray,
    mass: np.ndarray,
    tilt_max: float | np.ndarray = TILT_MAX_DEFAULT,
    min_lift_accel: float | np.ndarray = 0.2 * G,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Solve eq. (16) for ``u``, ``phi_d``, ``theta_d``.

    Two documented limits keep the answer physical: the vertical part ``g - mu_bar_3`` is kept at or
    above ``min_lift_accel`` (the rotors cannot pull down), and the tilt of the thrust vector is bounded
    by ``tilt_max`` by shortening the horizontal part of ``mu_bar``.

    Parameters
    ----------
    mu_bar : ndarray, shape (..., 3)
        ``mu - f_hat_ext_W / m``, the acceleration the thrust must give, world NED, m/s^2.
    psi_d : ndarray, shape (...)
        Desired yaw, rad.
    mass : ndarray, shape (...)
        Nominal mass, kg.
    tilt_max : float or ndarray
        Bound on the tilt of the thrust vector, rad (default 35 deg).
    min_lift_accel : float or ndarray
        Lower bound on the vertical part ``g - mu_bar_3``, m/s^2 (default 0.2 g).

    Returns
    -------
    thrust : ndarray, shape (...)
        Collective thrust ``u``, N.
    phi_d, theta_d : ndarray, shape (...)
        Desired roll and pitch, rad.
    limited : ndarray of bool, shape (...)
        True where either limit acted.

    References
    ----------
    Ruggiero et al. 2014, eqs. (16) and (20) (solved in NED; see :doc:`/equations`).
    """
    mu_bar = batched("mu_bar", mu_bar, (3,))
    psi_d = batched("psi_d", psi_d)
    mass = batched("mass", mass)
    tilt_max = batched("tilt_max", tilt_max)
    min_lift_accel = batched("min_lift_accel", min_lift_accel)
    vert = G - mu_bar[..., 2]
    vert_c = np.maximum(vert, min_lift_accel)
    horiz = mu_bar[..., :2]
    h_norm = np.linalg.norm(horiz, axis=-1)
    h_max = vert_c * np.tan(tilt_max)
    scale = np.where(h_norm > h_max, h_max / np.maximum(h_norm, 1e-300), 1.0)
    m1 = horiz[..., 0] * scale
    m2 = horiz[..., 1] * scale
    a = np.sqrt(m1 * m1 + m2 * m2 + vert_c * vert_c)  # eq. (20a): u = m a
    cp, sp = np.cos(psi_d), np.sin(psi_d)
    phi_d = np.arcsin(np.clip((m2 * cp - m1 * sp) / a, -1.0, 1.0))  # eq. (20b)
    theta_d = np.arctan2(-(m1 * cp + m2 * sp), vert_c)  # eq. (20c)
    limited = (vert < min_lift_accel) | (scale < 1.0)
    return mass * a, phi_d, theta_d, limited


def acceleration_from_thrust(thrust: np.ndarray, eta: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Forward eq. (16): ``g_W - (u / m) R(eta) e3`` (the acceleration the thrust gives, without f_ext)."""
    k = batched("thrust", thrust) / batched("mass", mass)
    return np.array([0.0, 0.0, G]) - k[..., None] * thrust_direction_W(eta)
