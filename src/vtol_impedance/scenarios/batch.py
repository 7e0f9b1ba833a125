"""Populations of vehicles whose true plant, gains and noise seeds differ, for Monte-Carlo batches."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..control.impedance import ControllerParams
from ..errors import InputError
from ..sim.plant import PlantParams
from .spec import ScenarioSpec, build, controller_params


def population(
    spec: ScenarioSpec,
    n: int,
    seed: int = 0,
    variant: str = "pdc",
    payload_spread: float = 0.5,
    offset_spread_m: float = 0.01,
    inertia_spread: float = 0.1,
    gain_spread: float = 0.1,
) -> tuple[list[PlantParams], list[ControllerParams], list[int]]:
    """``n`` plants, controllers and seeds around a scenario, drawn from ``seed``.

    Payload mass varies by ``+-payload_spread`` (relative), its offset by ``+-offset_spread_m`` per axis,
    the inertia scale by ``+-inertia_spread``, and ``Kp``/``Dp`` by ``+-gain_spread`` (relative, uniform).
    """
    if n < 1:
        raise InputError(f"a population needs n >= 1, got {n}")
    rng = np.random.default_rng(seed)
    base_plant = build(spec).plant
    base_ctrl = controller_params(spec, variant)
    u = lambda size=None: rng.uniform(-1.0, 1.0, size)  # noqa: E731
    plants, ctrls = [], []
    for _ in range(n):
        plants.append(
            replace(
                base_plant,
                payload_mass=max(base_plant.payload_mass * (1 + payload_spread * u()), 0.0),
                payload_offset_B=tuple(np.asarray(base_plant.payload_offset_B) + offset_spread_m * u(3)),
                inertia_scale=tuple(np.broadcast_to(base_plant.inertia_scale, (3,)) * (1 + inertia_spread * u(3))),
            )
        )
        k = 1 + gain_spread * u()
        ctrls.append(
            replace(base_ctrl, gains=replace(base_ctrl.gains, Kp=base_ctrl.gains.Kp * k, Dp=base_ctrl.gains.Dp * k))
        )
    seeds = [int(s) for s in rng.integers(0, 2**31 - 1, n)]
    return plants, ctrls, seeds
