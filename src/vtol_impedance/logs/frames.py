"""Frame conventions of flight logs, converted in this one place to the library's world NED and body FRD.

Supported sources: world NED or ENU (``world``), body FRD or FLU (``body``), attitude as ZYX Euler
angles (roll, pitch, yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)``, rotating body vectors into the world) or as
a unit quaternion, scalar first (``wxyz``, PX4, Eigen's constructor) or last (``xyzw``, ROS, SciPy),
rotating body to world (PX4's ``vehicle_attitude.q``, ROS ``orientation``) or world to body.

ENU to NED swaps x and y and flips z; FLU to FRD flips y and z. Both matrices are their own inverse, so
``R_NED_FRD = T_world R_source T_body`` and back ``R_source = T_world R_NED_FRD T_body``.
"""

from __future__ import annotations

import numpy as np

from ..conventions import T_FRD_FLU, T_NED_ENU
from ..errors import InputError, _short
from ..model.kinematics import euler_from_rotation, quat_to_rotation, rotation_zyx

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
    """A world-frame vector (velocity, force) ``(..., 3)`` in NED."""
    return np.asarray(v, dtype=float) @ world_matrix(world).T


def body_vector_to_frd(v: np.ndarray, body: str) -> np.ndarray:
    """A body-frame vector (body rates, torque) ``(..., 3)`` in FRD."""
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
        raise InputError(
            f"quaternion at sample {bad[0]} has norm {norm[bad[0]]:.3f}: not a unit quaternion "
            "(check the column order flag: scalar first 'wxyz' or last 'xyzw')"
        )
    R = quat_to_rotation(q / norm[..., None])
    if _choice("quaternion direction", direction, QUAT_DIRECTIONS) == "world-to-body":
        R = np.swapaxes(R, -1, -2)
    return R


def euler_rotation(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body-to-world rotation of ZYX Euler angles (radians)."""
    return rotation_zyx(np.stack([roll, pitch, yaw], -1))


def eta_ned_frd(R_source: np.ndarray, world: str, body: str) -> np.ndarray:
    """ZYX Euler angles ``eta`` of the NED/FRD attitude, from source rotations."""
    return euler_from_rotation(rotation_to_ned_frd(R_source, world, body))
