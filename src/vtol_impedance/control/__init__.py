"""Hierarchical impedance controller, eqs. (14)-(20)."""

from .gains import Impedance, ImpedanceGains
from .impedance import (
    PAPER_KI,
    VARIANTS,
    ControllerArrays,
    ControllerParams,
    ControllerState,
    compile_controllers,
    controller_step,
    initial_controller_state,
)
from .signals import ControlOutput, Measurement, Reference
from .thrust import acceleration_from_thrust, thrust_and_attitude

__all__ = [
    "PAPER_KI",
    "VARIANTS",
    "ControlOutput",
    "ControllerArrays",
    "ControllerParams",
    "ControllerState",
    "Impedance",
    "ImpedanceGains",
    "Measurement",
    "Reference",
    "acceleration_from_thrust",
    "compile_controllers",
    "controller_step",
    "initial_controller_state",
    "thrust_and_attitude",
]
