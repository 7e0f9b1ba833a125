"""Scenarios: specification, registry, and the paper's case studies."""

from . import paper as _paper  # noqa: F401  (registers the paper's cases)
from .files import load_toml
from .paper import PAPER_CASES
from .registry import DEFAULT, Registry, get, names, register
from .simulate import simulate
from .spec import (
    ControlSpec,
    PayloadSpec,
    PlantSpec,
    ScenarioSpec,
    TrajectorySpec,
    apply_overrides,
    build,
    check,
    controller_params,
    set_value,
)
from .tracking import TrackingDesign, tracking_design

__all__ = [
    "DEFAULT",
    "PAPER_CASES",
    "ControlSpec",
    "PayloadSpec",
    "PlantSpec",
    "Registry",
    "ScenarioSpec",
    "TrajectorySpec",
    "apply_overrides",
    "build",
    "check",
    "controller_params",
    "get",
    "load_toml",
    "names",
    "register",
    "set_value",
    "simulate",
    "tracking_design",
    "TrackingDesign",
]
