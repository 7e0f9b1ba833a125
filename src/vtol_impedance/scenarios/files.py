"""Scenario files: a TOML document applied onto a registered scenario (``base = "case-a-payload"``) or a
new one. Here, above both :mod:`.spec` and :mod:`.registry`, so that neither imports the other."""

from __future__ import annotations

from pathlib import Path

from ..errors import ScenarioError, instance, path_like
from ..io import read_toml
from .registry import get
from .spec import ScenarioSpec, apply_mapping, set_value


def load_toml(path: str | Path, base: ScenarioSpec | None = None) -> ScenarioSpec:
    """Read a scenario file. ``base = "case-a-payload"`` at the top starts from a registered scenario."""
    path = path_like("path", path)
    if base is not None:
        instance("base", base, ScenarioSpec)
    data = read_toml(path, "scenario file", ScenarioError)
    base_name = data.pop("base", None)
    if base_name is not None:
        spec = get(base_name)
    elif base is not None:
        spec = base
    else:
        if "name" not in data:
            raise ScenarioError(f"{path}: give either 'base = \"<registered scenario>\"' or a 'name'")
        spec = ScenarioSpec(name=data["name"])
    dists = data.pop("disturbances", None)
    spec = apply_mapping(spec, data)
    if dists is not None:
        spec = set_value(spec, "disturbances", dists)
    return spec
