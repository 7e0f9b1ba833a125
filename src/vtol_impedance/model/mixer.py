"""Rotor mixer, eq. (4) of Ruggiero et al. (2014) for any multirotor, its inverse and a prioritised allocation.

With the effectiveness matrix ``E (4, n)`` of :func:`~vtol_impedance.model.vehicle.effectiveness`,
``[u, tau_B] = E f`` for rotor forces ``f (..., n)``; for the paper's '+' quadrotor this is eq. (4):
``u = sum f_i``, ``tau_phi = l (f2 - f4)``, ``tau_theta = l (f3 - f1)``, ``tau_psi = c (f1 - f2 + f3 - f4)``.
The inverse without limits is the pseudo-inverse ``E_pinv (n, 4)`` (the least-squares rotor forces).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import InputError, batched

#: Default bound on how far the allocator may move the collective thrust to make room for roll and
#: pitch, as a fraction of the (feasible) requested thrust.
THRUST_SHIFT_MAX = 0.25


def mix(f: np.ndarray, E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (4): rotor forces ``f (..., n)`` to total thrust ``u (...)`` and body torque ``tau_B (..., 3)``."""
    E = batched("E", E, (4, -1))
    f = batched("f", f, (-1,))
    if f.shape[-1] != E.shape[-1]:
        raise InputError(f"f has {f.shape[-1]} rotor forces but E {E.shape} has {E.shape[-1]} columns")
    w = np.einsum("...ij,...j->...i", E, f)
    return w[..., 0], w[..., 1:]  # eq. (4)


def moment_reach(E: np.ndarray, f_min: np.ndarray, f_max: np.ndarray) -> np.ndarray:
    """The largest body moment (N m, FRD) the rotors can give about each axis, either way: ``max |E_i f|`` over
    forces within their limits, for rows 1-3 of eq. (4)'s ``E (..., 4, n)``; ``(..., 3)``."""
    lo, hi = E[..., 1:, :] * f_min[..., None, :], E[..., 1:, :] * f_max[..., None, :]
    up, down = np.maximum(lo, hi).sum(-1), np.minimum(lo, hi).sum(-1)
    return np.maximum(up, -down)


def unmix(thrust: np.ndarray, tau_B: np.ndarray, E_pinv: np.ndarray) -> np.ndarray:
    """Inverse of eq. (4) without limits: ``(u, tau_B)`` to the least-squares rotor forces ``(..., n)``."""
    w = np.concatenate([batched("thrust", thrust)[..., None], batched("tau_B", tau_B, (3,))], -1)
    return np.einsum("...ij,...j->...i", batched("E_pinv", E_pinv, (-1, 4)), w)


class Allocation(NamedTuple):
    """Result of :func:`allocate`.

    ``f`` are the rotor forces sent to the motors; ``thrust`` and ``tau_B`` are what those forces
    produce (eq. (4) applied to ``f``), which differ from the request when ``saturated`` is True.
    What was given up: ``rp_scale`` (the roll/pitch torque was multiplied by it), ``yaw_scale`` (likewise
    yaw), ``thrust_shift`` (N, collective moved away from the request: clipped to what the rotors can
    give, plus the bounded shift that makes room for roll/pitch).
    """

    f: np.ndarray
    thrust: np.ndarray
    tau_B: np.ndarray
    saturated: np.ndarray
    yaw_scale: np.ndarray
    rp_scale: np.ndarray
    thrust_shift: np.ndarray


def _yaw_interval(base: np.ndarray, yw: np.ndarray, fmin: np.ndarray, fmax: np.ndarray):
    """Yaw scales ``a`` in ``[lo, hi]`` (with ``lo <= 1``, ``hi`` capped at 1) keeping ``base + a yw`` in range."""
    tol = 1e-12 * np.maximum(np.abs(fmax), 1.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        hi = np.where(yw > 0, (fmax + tol - base) / yw, np.where(yw < 0, (fmin - tol - base) / yw, np.inf))
        lo = np.where(yw > 0, (fmin - tol - base) / yw, np.where(yw < 0, (fmax + tol - base) / yw, -np.inf))
    flat_bad = ((yw == 0) & ((base < fmin - tol) | (base > fmax + tol))).any(-1)
    a_lo = np.maximum(lo.max(-1), 0.0)
    a_hi = np.minimum(hi.min(-1), 1.0)
    return np.where(flat_bad, np.inf, a_lo), a_hi


def allocate(
    thrust: np.ndarray,
    tau_B: np.ndarray,
    E: np.ndarray,
    E_pinv: np.ndarray,
    f_min: np.ndarray,
    f_max: np.ndarray,
    thrust_shift_max: float | np.ndarray = THRUST_SHIFT_MAX,
) -> Allocation:
    """Invert eq. (4) within rotor limits ``[f_min, f_max] (..., n)``, with priorities as flight stacks do.

    Priority, highest first: roll/pitch torque, collective thrust (within a bounded change), yaw torque.
    With ``p_u``, ``p_rp``, ``p_y`` the thrust, roll/pitch and yaw parts of the pseudo-inverse:

    1. The collective is clipped to what the rotors can give with equal shares, ``u_c``.
    2. Roll/pitch ``k p_rp`` is added with the largest ``k`` in [0, 1] for which a collective change
       ``|delta| <= thrust_shift_max * u_c`` keeps every rotor in range (solved exactly: each rotor pair
       bounds ``k`` linearly); then the smallest such ``|delta|`` is taken. The collective never moves
       by more than that bound, so a roll/pitch request can never multiply the thrust.
    3. Yaw ``a p_y`` is added with the largest ``a`` in [0, 1] that keeps every rotor in range.

    Before all that, if the full roll/pitch at the requested thrust fits with some yaw scale, the largest
    such yaw scale is used and nothing else changes (so a feasible request is met exactly).

    Within limits this equals :func:`unmix`. Works for any geometry whose thrust shares ``p_u`` are
    positive (checked when the vehicle is built), including non-square ones (hexarotor).
    """
    u = batched("thrust", thrust)
    tau_B = batched("tau_B", tau_B, (3,))
    Ep = batched("E_pinv", E_pinv, (-1, 4))
    if batched("E", E, (4, -1)).shape[-1] != Ep.shape[-2]:
        raise InputError(f"E {np.shape(E)} and E_pinv {Ep.shape} are not for the same rotors")
    fmin = batched("f_min", f_min, (Ep.shape[-2],))
    fmax = batched("f_max", f_max, (Ep.shape[-2],))
    if not isinstance(thrust_shift_max, np.ndarray) and not (
        isinstance(thrust_shift_max, float | int)
        and not isinstance(thrust_shift_max, bool)
        and 0 <= thrust_shift_max < np.inf
    ):
        raise InputError(f"thrust_shift_max must be a number >= 0, got {thrust_shift_max!r}")
    shape = np.broadcast_shapes(u.shape, tau_B.shape[:-1], Ep.shape[:-2], fmin.shape[:-1], np.shape(thrust_shift_max))
    n = Ep.shape[-2]
    pu = np.broadcast_to(Ep[..., :, 0], shape + (n,))
    rp = Ep[..., :, 1] * tau_B[..., 0, None] + Ep[..., :, 2] * tau_B[..., 1, None]
    yw = Ep[..., :, 3] * tau_B[..., 2, None]
    rp = np.broadcast_to(rp, shape + (n,))
    yw = np.broadcast_to(yw, shape + (n,))
    fmin = np.broadcast_to(fmin, shape + (n,))
    fmax = np.broadcast_to(fmax, shape + (n,))

    # 1. feasible collective with equal shares
    u_lo = (fmin / pu).max(-1)
    u_hi = (fmax / pu).min(-1)
    u_c = np.clip(u, u_lo, u_hi)
    dmax = np.asarray(thrust_shift_max, dtype=float) * u_c

    # 2. roll/pitch: rotor i needs a_i - k b_i <= delta <= c_i - k b_i, and |delta| <= dmax
    a = fmin / pu - u_c[..., None]
    c = fmax / pu - u_c[..., None]
    b = rp / pu
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        db = b[..., None, :] - b[..., :, None]  # [i, j] = b_j - b_i
        pair = np.where(db > 0, (c[..., None, :] - a[..., :, None]) / db, np.inf).min((-2, -1))
        lo_lim = np.where(b < 0, (dmax[..., None] - a) / -b, np.inf).min(-1)
        hi_lim = np.where(b > 0, (c + dmax[..., None]) / b, np.inf).min(-1)
    k = np.clip(np.minimum(np.minimum(pair, lo_lim), hi_lim), 0.0, 1.0)
    d_lo = np.maximum((a - k[..., None] * b).max(-1), -dmax)
    d_hi = np.minimum((c - k[..., None] * b).min(-1), dmax)
    delta = np.clip(0.0, d_lo, np.maximum(d_lo, d_hi))
    base = pu * (u_c + delta)[..., None] + k[..., None] * rp

    # 3. yaw with what is left
    ys = np.clip(_yaw_interval(base, yw, fmin, fmax)[1], 0.0, 1.0)

    # 0. but first: if the full roll/pitch at the requested thrust fits with some yaw, keep them (a
    #    feasible request is met exactly, and yaw may be what makes roll/pitch fit)
    base_keep = pu * u[..., None] + rp
    lo_keep, hi_keep = _yaw_interval(base_keep, yw, fmin, fmax)
    keep = (lo_keep <= hi_keep) & (hi_keep >= 0.0)
    k = np.where(keep, 1.0, k)
    ys = np.where(keep, np.clip(hi_keep, 0.0, 1.0), ys)
    delta = np.where(keep, u - u_c, delta)
    base = np.where(keep[..., None], base_keep, base)
    f = np.clip(base + ys[..., None] * yw, fmin, fmax)  # eq. (4) inverted within the limits

    u_out, tau_out = mix(f, E)  # eq. (4)
    shift = u_c + delta - u
    saturated = (k < 1.0 - 1e-9) | (ys < 1.0 - 1e-9) | (np.abs(shift) > 1e-9 * np.maximum(np.abs(u), 1.0))
    return Allocation(f, u_out, tau_out, saturated, ys, k, shift)
