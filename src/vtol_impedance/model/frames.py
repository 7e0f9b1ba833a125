"""Frame conventions of other tools (world ENU, body FLU, quaternions scalar first or last, either
direction), converted to the library's world NED and body FRD.

ENU to NED swaps x and y and flips z; FLU to FRD flips y and z. Both matrices are their own inverse, so
``R_NED_FRD = T_world R_source T_body`` and back ``R_source = T_world R_NED_FRD T_body``; a heading
(yaw) measured counter-clockwise from east in ENU is ``pi/2 - psi_NED``. Flight logs
(:mod:`vtol_impedance.logs.frames`) and the controller's inputs from another simulator
(:meth:`vtol_impedance.control.Measurement.from_frames`) both convert here.
"""

from __future__ import annotations

import numpy as np

from ..conventions import T_FRD_FLU, T_NED_ENU
from ..errors import InputError, _short
from .kinematics import euler_from_rotation, quat_to_rotation

WORLDS = ("ned", "enu")
BODIES = ("frd", "flu")
QUAT_ORDERS = ("wxyz", "xyzw")
QUAT_DIRECTIONS = ("body-to-world", "world-to-body")


def _choice(name: str, value: str, allowed: tuple[str, ...]) -> str:
    v = str(value).lower()
    if v not in allowed:
        raise InputError(f"{name} must be one of {', '.join(allowed)}, got {_short(value)}")
    return v


def world_matrix(world: str) -> np.ndarray:
    """``T`` with ``v_NED = T v_world``."""
    return T_NED_ENU if _choice("world frame", world, WORLDS) == "enu" else np.eye(3)


def body_matrix(body: str) -> np.ndarray:
    """``T`` with ``v_FRD = T v_body``."""
    return T_FRD_FLU if _choice("body frame", body, BODIES) == "flu" else np.eye(3)


def world_vector_to_ned(v: np.ndarray, world: str) -> np.ndarray:
    """A world-frame vector (velocity, force) ``(..., 3)`` in NED; a non-finite entry spoils its sample
    (marked missing later), quietly."""
    with np.errstate(invalid="ignore"):  # inf * 0 in the product: that sample is NaN, as it should be
        return np.asarray(v, dtype=float) @ world_matrix(world).T


def world_axes_to_ned(c: np.ndarray, world: str) -> np.ndarray:
    """Per-axis values ``(..., 3)`` of the world axes (comply fractions, gains: magnitudes with no sign)
    in NED order: ENU's ``[east, north, up]`` become ``[north, east, down]``, nothing flipped (a
    permutation, so a non-finite entry stays on its axis)."""
    return np.asarray(c, dtype=float)[..., np.argmax(np.abs(world_matrix(world)), axis=1)]


def body_vector_to_frd(v: np.ndarray, body: str) -> np.ndarray:
    """A body-frame vector (body rates, torque) ``(..., 3)`` in FRD (a non-finite entry: as
    :func:`world_vector_to_ned`)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(v, dtype=float) @ body_matrix(body).T


def rotation_to_ned_frd(R: np.ndarray, world: str, body: str) -> np.ndarray:
    """``R_NED_FRD`` from a source rotation ``R_world_body`` (body to world)."""
    return world_matrix(world) @ np.asarray(R, dtype=float) @ body_matrix(body)


def rotation_from_ned_frd(R: np.ndarray, world: str, body: str) -> np.ndarray:
    """The inverse of :func:`rotation_to_ned_frd` (for writing logs in another convention)."""
    return world_matrix(world) @ np.asarray(R, dtype=float) @ body_matrix(body)


def quaternion_rotation(q: np.ndarray, order: str = "wxyz", direction: str = "body-to-world") -> np.ndarray:
    """Body-to-world rotation matrices ``(N, 3, 3)`` of source quaternions ``(N, 4)`` (normalised here;
    a quaternion far from unit length is refused)."""
    q = np.asarray(q, dtype=float)
    if _choice("quaternion order", order, QUAT_ORDERS) == "xyzw":
        q = q[..., [3, 0, 1, 2]]
    norm = np.linalg.norm(q, axis=-1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > 0.05)
    if len(bad):
        where = "" if norm.ndim == 0 else f" at sample {bad[0]}"
        raise InputError(
            f"quaternion{where} has norm {np.ravel(norm)[bad[0]]:.3f}: not a unit quaternion "
            "(check the order: scalar first 'wxyz' or last 'xyzw')"
        )
    R = quat_to_rotation(q / norm[..., None])
    if _choice("quaternion direction", direction, QUAT_DIRECTIONS) == "world-to-body":
        R = np.swapaxes(R, -1, -2)
    return R


def eta_ned_frd(R_source: np.ndarray, world: str, body: str) -> np.ndarray:
    """ZYX Euler angles ``eta`` of the NED/FRD attitude, from source rotations."""
    return euler_from_rotation(rotation_to_ned_frd(R_source, world, body))


def world_vector_from_ned(v: np.ndarray, world: str) -> np.ndarray:
    """A world NED vector (an estimated force, a velocity) in ``world`` (the inverse of
    :func:`world_vector_to_ned`; the matrices are their own inverse)."""
    return world_vector_to_ned(v, world)


def body_vector_from_frd(v: np.ndarray, body: str) -> np.ndarray:
    """A body FRD vector (a moment) in ``body`` (the inverse of :func:`body_vector_to_frd`)."""
    return body_vector_to_frd(v, body)


def heading_to_ned(psi: np.ndarray | float, world: str) -> np.ndarray:
    """A yaw angle (rad) in the library's NED convention (clockwise from north seen from above) from
    ``world``'s: ENU measures counter-clockwise from east, ``psi_NED = pi/2 - psi_ENU``. Its rates go
    through :func:`heading_rate_to_ned`."""
    psi = np.asarray(psi, dtype=float)
    return np.pi / 2 - psi if _choice("world frame", world, WORLDS) == "enu" else psi


def heading_rate_to_ned(rate: np.ndarray | float, world: str) -> np.ndarray:
    """A yaw rate or acceleration in NED from ``world``'s (ENU: the opposite sign)."""
    rate = np.asarray(rate, dtype=float)
    return -rate if _choice("world frame", world, WORLDS) == "enu" else rate


__all__ = [
    "BODIES", "QUAT_DIRECTIONS", "QUAT_ORDERS", "WORLDS", "body_matrix", "body_vector_from_frd", "body_vector_to_frd",
    "eta_ned_frd", "heading_rate_to_ned", "heading_to_ned", "quaternion_rotation", "rotation_from_ned_frd",
    "rotation_to_ned_frd", "world_matrix", "world_vector_from_ned", "world_vector_to_ned",
]  # fmt: skip
