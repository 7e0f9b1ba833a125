"""Vehicle model: kinematics (1), dynamics (3)-(8) and the rotor mixer (4)."""

from .dynamics import (
    body_moment_from_euler,
    coriolis_matrix_C,
    euler_moment_from_body,
    generalized_momentum,
    inertia_matrix_M,
    momentum_rate_known,
)
from .kinematics import (
    euler_rate_matrix_Q,
    euler_rate_matrix_Q_dot,
    euler_rate_matrix_T,
    rotation_zyx,
    skew,
)
from .mixer import THRUST_SHIFT_MAX, Allocation, allocate, mix, unmix
from .vehicle import (
    LAYOUTS,
    Rotor,
    RotorGeometry,
    VehicleParams,
    drag_factor_from_constants,
    effectiveness,
    f_max_from_motor,
    layout_positions,
    load_preset,
    preset_names,
    vehicle_from_dict,
)

__all__ = [
    "LAYOUTS",
    "THRUST_SHIFT_MAX",
    "Rotor",
    "RotorGeometry",
    "drag_factor_from_constants",
    "effectiveness",
    "f_max_from_motor",
    "layout_positions",
    "preset_names",
    "vehicle_from_dict",
    "Allocation",
    "VehicleParams",
    "allocate",
    "body_moment_from_euler",
    "coriolis_matrix_C",
    "euler_moment_from_body",
    "euler_rate_matrix_Q",
    "euler_rate_matrix_Q_dot",
    "euler_rate_matrix_T",
    "generalized_momentum",
    "inertia_matrix_M",
    "load_preset",
    "mix",
    "momentum_rate_known",
    "rotation_zyx",
    "skew",
    "unmix",
]
