"""Frame conventions of flight logs, converted in this one place to the library's world NED and body FRD.

Supported sources: world NED or ENU (``world``), body FRD or FLU (``body``), attitude as ZYX Euler
angles (roll, pitch, yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)``, rotating body vectors into the world) or as
a unit quaternion, scalar first (``wxyz``, PX4, Eigen's constructor) or last (``xyzw``, ROS, SciPy),
rotating body to world (PX4's ``vehicle_attitude.q``, ROS ``orientation``) or world to body.

ENU to NED swaps x and y and flips z; FLU to FRD flips y and z. Both matrices are their own inverse, so
``R_NED_FRD = T_world R_source T_body`` and back ``R_source = T_world R_NED_FRD T_body``.

:class:`Conventions` gathers everything a log may state differently (frames, quaternion layout, units
of angles, rates and time); :mod:`vtol_impedance.logs.checks` tests a declared set against physics and
can choose one from the data.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..model.frames import (  # noqa: F401  (the frame conversions, shared with the controller's inputs)
    BODIES,
    QUAT_DIRECTIONS,
    QUAT_ORDERS,
    WORLDS,
    _choice,
    body_matrix,
    body_vector_to_frd,
    eta_ned_frd,
    quaternion_rotation,
    rotation_from_ned_frd,
    rotation_to_ned_frd,
    world_matrix,
    world_vector_to_ned,
)  # fmt: skip
from ..model.kinematics import rotation_zyx

ANGLE_UNITS = ("rad", "deg")
#: Seconds per unit of a time column.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
ROTOR_SPEED_UNITS = {"rpm": 2.0 * np.pi / 60.0, "rad/s": 1.0}


@dataclass(frozen=True)
class Conventions:
    """How a log states its quantities; the library works in world NED, body FRD, radians and seconds.

    ``world`` is the world frame of the attitude (and of the velocity unless ``velocity_world`` is given),
    ``body`` the body frame of the attitude, rates and torques; ``angle_unit`` applies to Euler angles and
    ``rate_unit`` (default: ``angle_unit``) to body rates; ``quat_order`` and ``quat_direction`` to a
    quaternion attitude; ``time_unit`` to the time column. Each field has the command-line flag of
    :attr:`FLAGS`.
    """

    world: str = "ned"
    body: str = "frd"
    angle_unit: str = "rad"
    quat_order: str = "wxyz"
    quat_direction: str = "body-to-world"
    time_unit: str = "s"
    velocity_world: str | None = None
    rate_unit: str | None = None

    FLAGS = {
        "world": "--world",
        "body": "--body",
        "angle_unit": "--angle-unit",
        "quat_order": "--quat-order",
        "quat_direction": "--quat-direction",
        "time_unit": "--time-unit",
        "velocity_world": "--velocity-world",
        "rate_unit": "--rate-unit",
    }

    def __post_init__(self) -> None:
        object.__setattr__(self, "world", _choice("world frame (world)", self.world, WORLDS))
        object.__setattr__(self, "body", _choice("body frame (body)", self.body, BODIES))
        object.__setattr__(self, "angle_unit", _choice("angle unit (angle_unit)", self.angle_unit, ANGLE_UNITS))
        object.__setattr__(self, "quat_order", _choice("quaternion order (quat_order)", self.quat_order, QUAT_ORDERS))
        object.__setattr__(
            self,
            "quat_direction",
            _choice("quaternion direction (quat_direction)", self.quat_direction, QUAT_DIRECTIONS),
        )
        object.__setattr__(self, "time_unit", _choice("time unit (time_unit)", self.time_unit, tuple(TIME_UNITS)))
        vw = self.world if self.velocity_world is None else self.velocity_world
        object.__setattr__(self, "velocity_world", _choice("velocity world frame (velocity_world)", vw, WORLDS))
        ru = self.angle_unit if self.rate_unit is None else self.rate_unit
        object.__setattr__(self, "rate_unit", _choice("rate unit (rate_unit)", ru, ANGLE_UNITS))

    def to_dict(self) -> dict[str, str]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def differences(self, other: Conventions, relevant: tuple[str, ...] | None = None) -> dict[str, str]:
        """``{field: other's value}`` where ``other`` differs from ``self`` (among ``relevant`` fields)."""
        names = relevant or tuple(f.name for f in fields(self))
        return {n: getattr(other, n) for n in names if getattr(self, n) != getattr(other, n)}

    def as_flags(self, names: tuple[str, ...] | None = None) -> str:
        """The command-line flags that state these conventions (``names``: only those fields)."""
        names = names or tuple(self.FLAGS)
        return " ".join(f"{self.FLAGS[n]} {getattr(self, n)}" for n in names)


def euler_rotation(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body-to-world rotation of ZYX Euler angles (radians)."""
    return rotation_zyx(np.stack([roll, pitch, yaw], -1))
