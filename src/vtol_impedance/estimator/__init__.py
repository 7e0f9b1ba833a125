"""Momentum-based estimator of external generalized forces, eqs. (6)-(13)."""

from .momentum import (
    EstimatorBandwidthWarning,
    EstimatorDesign,
    EstimatorParams,
    EstimatorState,
    design,
    estimator_step,
    initial_state,
)

__all__ = [
    "EstimatorBandwidthWarning",
    "EstimatorDesign",
    "EstimatorParams",
    "EstimatorState",
    "design",
    "estimator_step",
    "initial_state",
]
