"""Simulator: true plant, disturbances, sensors, closed loop and results."""

from .disturbances import (
    KINDS as DISTURBANCE_KINDS,
)
from .disturbances import (
    BandLimitedNoise,
    ConstantWrench,
    Disturbance,
    FanJet,
    Push,
    RampWrench,
    SinusoidWrench,
    StepWrench,
    Wind,
)
from .loop import run_closed_loop
from .plant import PlantParams, compile_plants, plant_derivative, rk4_step
from .result import SIGNALS, Result
from .sensors import LatencyWarning, SensorParams

__all__ = [
    "DISTURBANCE_KINDS",
    "SIGNALS",
    "BandLimitedNoise",
    "ConstantWrench",
    "Disturbance",
    "FanJet",
    "LatencyWarning",
    "PlantParams",
    "Push",
    "RampWrench",
    "Result",
    "SensorParams",
    "SinusoidWrench",
    "StepWrench",
    "Wind",
    "compile_plants",
    "plant_derivative",
    "rk4_step",
    "run_closed_loop",
]
