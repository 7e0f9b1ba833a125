"""Vehicle parameters (nominal or true) and presets."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources
from typing import Any

import numpy as np

from ..conventions import G
from ..errors import InputError, as_finite, positive


def _inertia(value: Any) -> np.ndarray:
    arr = as_finite("inertia", value)
    if arr.shape == (3,):
        arr = np.diag(arr)
    if arr.shape != (3, 3):
        raise InputError(f"inertia must be a 3-vector (diagonal) or a 3x3 matrix, got shape {arr.shape}")
    if not np.allclose(arr, arr.T, atol=1e-12):
        raise InputError("inertia matrix must be symmetric")
    if np.any(np.linalg.eigvalsh(arr) <= 0):
        raise InputError(f"inertia matrix must be positive definite, eigenvalues {np.linalg.eigvalsh(arr)}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class VehicleParams:
    """Rigid-body and rotor parameters of a quadrotor in the '+' layout of eq. (4).

    Attributes
    ----------
    mass : kg.
    inertia : ``I_B``, 3x3 about the centre of mass in the body frame, kg m^2 (a 3-vector is a diagonal).
    arm_length : ``l`` of eq. (4b)-(4c), m.
    drag_factor : ``c`` of eq. (4d), N m per N.
    f_max, f_min : limits of each rotor force, N.
    name : label.
    """

    mass: float
    inertia: np.ndarray
    arm_length: float = 0.21
    drag_factor: float = 0.016
    f_max: float = 7.0
    f_min: float = 0.0
    name: str = "custom"

    def __post_init__(self) -> None:
        object.__setattr__(self, "mass", float(positive("mass", self.mass)))
        object.__setattr__(self, "inertia", _inertia(self.inertia))
        object.__setattr__(self, "arm_length", float(positive("arm_length", self.arm_length)))
        object.__setattr__(self, "drag_factor", float(positive("drag_factor", self.drag_factor)))
        object.__setattr__(self, "f_max", float(positive("f_max", self.f_max)))
        object.__setattr__(self, "f_min", float(positive("f_min", self.f_min, allow_zero=True)))
        if self.f_min >= self.f_max:
            raise InputError(f"f_min = {self.f_min} must be below f_max = {self.f_max}")

    @property
    def thrust_to_weight(self) -> float:
        """Maximum total thrust over nominal weight."""
        return 4.0 * self.f_max / (self.mass * G)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "mass": self.mass,
            "inertia": self.inertia.tolist(),
            "arm_length": self.arm_length,
            "drag_factor": self.drag_factor,
            "f_max": self.f_max,
            "f_min": self.f_min,
        }


def load_preset(name: str = "pelican") -> VehicleParams:
    """Load a vehicle preset shipped in ``vtol_impedance/presets/NAME.toml``."""
    files = resources.files("vtol_impedance") / "presets"
    available = sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".toml"))
    if name not in available:
        raise InputError(f"unknown vehicle preset {name!r}; available: {', '.join(available)}")
    data = tomllib.loads((files / f"{name}.toml").read_text())
    return VehicleParams(
        mass=data["mass"],
        inertia=data["inertia_diag"],
        arm_length=data["arm_length"],
        drag_factor=data["drag_factor"],
        f_max=data["f_max"],
        f_min=data.get("f_min", 0.0),
        name=data.get("name", name),
    )
