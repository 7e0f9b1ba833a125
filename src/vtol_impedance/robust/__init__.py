"""Robustness by design: the closed loop linearised for any vehicle, its stability margins, and a design
rule for bandwidths that keep them."""

from .design import Design, DesignError, DesignWarning, Timing, design, designed_controller
from .linear import (
    LOOPS,
    MAX_LOOP_STATES,
    LinearLoop,
    LoopSizeError,
    OperatingPoint,
    TrimError,
    equivalent_rotor_tau,
    linearize,
    operating_point,
    rotor_lag_describing_function,
)
from .margins import LoopMargins, MarginReport, Thresholds, loop_margins, margins

__all__ = [
    "LOOPS",
    "Design",
    "DesignError",
    "DesignWarning",
    "Timing",
    "design",
    "designed_controller",
    "LoopMargins",
    "MarginReport",
    "Thresholds",
    "loop_margins",
    "margins",
    "LinearLoop",
    "OperatingPoint",
    "TrimError",
    "LoopSizeError",
    "MAX_LOOP_STATES",
    "equivalent_rotor_tau",
    "linearize",
    "operating_point",
    "rotor_lag_describing_function",
]
