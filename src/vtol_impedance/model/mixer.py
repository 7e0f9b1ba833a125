"""Rotor mixer, eq. (4) of Ruggiero et al. (2014), its inverse and a prioritised allocation.

``u = sum f_i``, ``tau_phi = l (f2 - f4)``, ``tau_theta = l (f3 - f1)``,
``tau_psi = c (f1 - f2 + f3 - f4)``; rotor forces are ``(..., 4)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

_YAW_SIGNS = np.array([1.0, -1.0, 1.0, -1.0])


def mix(f: np.ndarray, arm_length: np.ndarray, drag_factor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (4): rotor forces ``f (..., 4)`` to total thrust ``u (...)`` and body torque ``tau_B (..., 3)``."""
    f = np.asarray(f, dtype=float)
    l = np.asarray(arm_length, dtype=float)
    c = np.asarray(drag_factor, dtype=float)
    u = f.sum(-1)
    tau_B = np.stack(
        [l * (f[..., 1] - f[..., 3]), l * (f[..., 2] - f[..., 0]), c * (f @ _YAW_SIGNS)],
        -1,
    )
    return u, tau_B


def unmix(thrust: np.ndarray, tau_B: np.ndarray, arm_length: np.ndarray, drag_factor: np.ndarray) -> np.ndarray:
    """Exact inverse of eq. (4), without limits: ``(u, tau_B)`` to rotor forces ``(..., 4)``."""
    u = np.asarray(thrust, dtype=float)
    tau_B = np.asarray(tau_B, dtype=float)
    l = np.asarray(arm_length, dtype=float)
    c = np.asarray(drag_factor, dtype=float)
    base = u[..., None] / 4.0
    rp = _roll_pitch_part(tau_B, l)
    yaw = (tau_B[..., 2] / (4.0 * c))[..., None] * _YAW_SIGNS
    return base + rp + yaw


def _roll_pitch_part(tau_B: np.ndarray, l: np.ndarray) -> np.ndarray:
    a = tau_B[..., 0] / (2.0 * l)
    b = tau_B[..., 1] / (2.0 * l)
    z = np.zeros_like(a)
    return np.stack([-b, a, b, -a], -1) + z[..., None]


class Allocation(NamedTuple):
    """Result of :func:`allocate`.

    ``f`` are the rotor forces sent to the motors; ``thrust`` and ``tau_B`` are what those forces
    produce (eq. (4) applied to ``f``), which differ from the request when ``saturated`` is True.
    ``yaw_scale``, ``thrust_shift`` and ``rp_scale`` say what was given up.
    """

    f: np.ndarray
    thrust: np.ndarray
    tau_B: np.ndarray
    saturated: np.ndarray
    yaw_scale: np.ndarray
    rp_scale: np.ndarray


def _yaw_interval(base: np.ndarray, yaw: np.ndarray, fmin_r: np.ndarray, fmax_r: np.ndarray):
    """Interval of yaw scales ``a`` in [0, 1] with ``fmin <= base + a yaw <= fmax`` on every rotor."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # tiny yaw shares: +-inf is right
        up = np.where(yaw > 0, (fmax_r - base) / yaw, np.where(yaw < 0, (fmin_r - base) / yaw, np.inf))
        lo = np.where(yaw > 0, (fmin_r - base) / yaw, np.where(yaw < 0, (fmax_r - base) / yaw, -np.inf))
    # a rotor without yaw share must already be within limits
    flat_bad = (yaw == 0) & ((base < fmin_r) | (base > fmax_r))
    a_lo = np.maximum(lo.max(-1), 0.0)
    a_hi = np.minimum(up.min(-1), 1.0)
    return a_lo, a_hi, (a_lo <= a_hi) & ~flat_bad.any(-1)


def allocate(
    thrust: np.ndarray,
    tau_B: np.ndarray,
    arm_length: np.ndarray,
    drag_factor: np.ndarray,
    f_max: np.ndarray,
    f_min: np.ndarray | float = 0.0,
) -> Allocation:
    """Invert eq. (4) within rotor limits ``[f_min, f_max]``, with priorities as flight stacks do.

    Priority, highest first: roll/pitch torque, total thrust, yaw torque.

    1. If the roll/pitch request alone spans more than ``f_max - f_min`` across rotors, it is scaled
       down to fit (``rp_scale < 1``).
    2. With the requested collective ``u/4``, the yaw part is scaled by the largest ``yaw_scale`` in
       ``[0, 1]`` that keeps every rotor in range.
    3. Only if no yaw scale makes collective + roll/pitch fit, the collective is moved to the nearest
       feasible value (thrust given up) and step 2 is repeated.

    Within limits this equals :func:`unmix`. ``saturated`` is True where anything was given up.
    """
    u = np.asarray(thrust, dtype=float)
    tau_B = np.asarray(tau_B, dtype=float)
    l = np.asarray(arm_length, dtype=float)
    c = np.asarray(drag_factor, dtype=float)
    fmax = np.asarray(f_max, dtype=float)
    fmin = np.asarray(f_min, dtype=float)
    # Round-off slack so that an exact solution on a limit counts as feasible.
    tol = 1e-12 * np.maximum(np.abs(fmax), 1.0)
    fmax_r = np.expand_dims(fmax + tol, -1)
    fmin_r = np.expand_dims(fmin - tol, -1)
    span = fmax - fmin

    rp = _roll_pitch_part(tau_B, l)
    rp_spread = rp.max(-1) - rp.min(-1)
    rp_scale = np.where(rp_spread > span, span / np.maximum(rp_spread, 1e-300), 1.0)
    rp = rp * rp_scale[..., None]
    yaw = (tau_B[..., 2] / (4.0 * c))[..., None] * _YAW_SIGNS

    # Thrust kept: the best yaw scale, if any makes the rotors fit.
    base_keep = u[..., None] / 4.0 + rp
    _, hi_keep, ok_keep = _yaw_interval(base_keep, yaw, fmin_r, fmax_r)
    # Thrust given up: nearest collective at which roll/pitch fit, then the best yaw scale.
    collective = np.clip(u / 4.0, fmin - rp.min(-1), fmax - rp.max(-1))
    base_move = collective[..., None] + rp
    _, hi_move, _ = _yaw_interval(base_move, yaw, fmin_r, fmax_r)

    base = np.where(ok_keep[..., None], base_keep, base_move)
    yaw_scale = np.clip(np.where(ok_keep, hi_keep, hi_move), 0.0, 1.0)
    f = np.clip(base + yaw_scale[..., None] * yaw, np.expand_dims(fmin, -1), np.expand_dims(fmax, -1))

    u_out, tau_out = mix(f, l, c)
    saturated = (rp_scale < 1.0) | ~ok_keep | (yaw_scale < 1.0 - 1e-9)
    return Allocation(f, u_out, tau_out, saturated, yaw_scale, rp_scale)
