"""Run a scenario with one or more controller variants on the same disturbance realisation."""

from __future__ import annotations

from collections.abc import Sequence

from ..errors import choice, function, instance, scalar
from ..sim.loop import BACKENDS, ProgressFn, run_closed_loop
from ..sim.result import Result
from .registry import get
from .spec import ScenarioSpec, check_variants, checked


def simulate(
    scenario: str | ScenarioSpec,
    variants: Sequence[str] = ("pd", "pid", "pdc"),
    seed: int | None = None,
    progress: ProgressFn | None = None,
    backend: str = "compiled",
    log: str | int = "full",
) -> Result:
    """Fly ``scenario`` once per controller variant (one batch, same seed, same disturbances).

    The result's ``config`` holds the full scenario, the task ``window`` used for metrics and the phases.
    ``backend`` and ``log`` are passed to :func:`~vtol_impedance.sim.loop.run_closed_loop`.
    """
    spec = get(scenario) if isinstance(scenario, str) else instance("scenario", scenario, ScenarioSpec)
    variants = check_variants(variants)
    seed = spec.seed if seed is None else scalar("seed", seed, lo=0, hi=2**63 - 1, integer=True)
    choice("backend", backend, BACKENDS)
    if progress is not None:
        function("progress", progress)
    b, ctrls = checked(spec, variants)
    return run_closed_loop(
        b.plant,
        ctrls,
        b.trajectory,
        b.duration,
        disturbances=b.disturbances,
        sensors=b.sensors,
        plant_rate=spec.plant_rate,
        seed=seed,
        labels=variants,
        start_W=b.start_W,
        progress=progress,
        config={"scenario": spec.to_dict(), "window": list(b.window), "phases": b.phases},
        backend=backend,
        log=log,
        window=b.window,
    )
