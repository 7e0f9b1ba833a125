"""Bounded work: an estimate of a sweep's or a tuning's duration before any work, a refusal above
:data:`MAX_MINUTES` unless confirmed, and progress with the time left while it runs.

The estimate is a sum of measured per-cell costs (:data:`VEHICLE_SECONDS_PER_S`, :data:`MARGIN_S`,
:data:`DESIGN_S`), measured on the reference machine of ``docs/guide/sweeps.md`` and rounded towards the
slow side; once the work runs, :class:`Progress` replaces it by the rate it measures.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from typing import IO, Any

from ..errors import InputError

#: The longest a sweep or tuning runs without being confirmed (``--yes`` or ``--max-minutes``), minutes.
#: The longest shipped study (``robustness``: 640 flights, 320 margin points) is estimated at about 3
#: minutes on the reference machine, so 10 leaves it room on a slower one; more than that unattended
#: should be a choice, not a surprise.
MAX_MINUTES = 10.0
#: Simulated vehicle-seconds per wall second, one process: compiled batch of a few vehicles (measured
#: 2,500 for case A; 1,000 kept) and the NumPy reference (measured 0.5; 0.4 kept).
VEHICLE_SECONDS_PER_S = {"compiled": 1000.0, "numpy": 0.4}
#: Margin check of one point for one controller (linearise, poles, loop margins), s (measured 0.13).
MARGIN_S = 0.2
#: One robust design (``vtol_impedance.robust.design``) not yet cached, s (measured about 5).
DESIGN_S = 6.0
#: Checking one point's scenario before the work (its design aside), s (measured 0.006).
CHECK_S = 0.01
#: Scenario values a robust design depends on: a sweep varying one designs at every point.
_DESIGN_INPUTS = ("control.Kp", "control.Dp", "control.rate", "control.rotor_tau", "control.velocity_delay",
                  "control.attitude_delay", "vehicle", "sensors.mocap_delay", "sensors.imu_delay")  # fmt: skip


class WorkBoundError(InputError):
    """The estimated duration exceeds the bound and was not confirmed."""


def flight_seconds(spec: Any) -> float:
    """Simulated length of one flight of ``spec``, s (its ``duration``, or its trajectory's)."""
    from ..scenarios.spec import build_trajectory

    return float(spec.duration) if spec.duration > 0 else float(build_trajectory(spec.trajectory)[0].duration)


def _design_keys(spec: Any, keys: list[str]) -> list[str]:
    """Those of ``keys`` (axis keys, ``"a,b"`` for a joint axis) a robust design of ``spec`` depends on
    (none when every designed bandwidth is set by hand)."""
    from ..scenarios.spec import DESIGNED

    if all(getattr(spec.control, k) is not None for k in DESIGNED):
        return []
    return [k for k in keys if any(part.strip().startswith(_DESIGN_INPUTS) for part in k.split(","))]


def _rate(backend: str) -> float:
    if backend not in VEHICLE_SECONDS_PER_S:
        raise InputError(f"backend must be one of {', '.join(VEHICLE_SECONDS_PER_S)}, got {backend!r}")
    return VEHICLE_SECONDS_PER_S[backend]


def sweep_seconds(sweep: Any, backend: str = "compiled", workers: int | None = None) -> float:
    """Estimated wall time of ``sweep``, s: its flights, margin checks and designs at the per-cell costs,
    shared by ``workers`` processes (one when None; no more than this machine's cores, as the local cluster
    caps them: ``--workers 1000`` got past the bound before)."""
    n = len(sweep.points)
    sample = [sweep.point_spec(i) for i in sorted({0, n // 2, n - 1})]  # duration may be an axis
    per_flight = sum(flight_seconds(s) for s in sample) / len(sample)
    total = sweep.n_flights * per_flight / _rate(backend)
    total += n * CHECK_S
    if sweep.margins:
        total += n * len(sweep.controllers) * MARGIN_S
    by = _design_keys(sample[0], [a.key for a in sweep.axes])  # one design per distinct combination
    total += len({json.dumps([p[k] for k in by], default=str) for p in sweep.points}) * DESIGN_S
    return total / _sharing(workers)


def tuning_seconds(t: Any, trials: int, backend: str = "compiled", workers: int | None = None) -> float:
    """Estimated wall time of a tuning of ``trials`` trials, s (each flies the population once), shared as in
    :func:`sweep_seconds`."""
    spec = t.base_spec()
    per_trial = t.population * flight_seconds(spec) / _rate(backend)
    if t.min_phase_margin_deg > 0.0:
        per_trial += t.population * MARGIN_S
    checks = 0.0
    if _design_keys(spec, [a.key for a in t.search]):
        per_trial += DESIGN_S
        checks = 3 * DESIGN_S  # the search box's corners, checked before the first trial
    return checks + trials * per_trial / _sharing(workers)


def _sharing(workers: int | None) -> int:
    """How many processes share the work: ``workers`` capped at this machine's cores (one when None)."""
    import os

    return max(1, min(workers or 1, os.cpu_count() or 1))


def minutes(seconds: float) -> str:
    """``seconds`` as a short duration: ``45 s``, ``12 min``, ``3.5 h``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def check_budget(seconds: float, what: str, max_minutes: float | None = None, yes: bool = False) -> None:
    """Refuse, before any work, ``what`` estimated at ``seconds`` when it exceeds ``max_minutes`` (default
    :data:`MAX_MINUTES`), unless ``yes``: :class:`WorkBoundError` names the estimate, the bound and how to go on."""
    if max_minutes is not None and not (max_minutes > 0 and max_minutes != float("inf")):
        raise InputError(f"--max-minutes must be a positive number of minutes, got {max_minutes}")
    bound = MAX_MINUTES if max_minutes is None else float(max_minutes)
    if yes or seconds <= bound * 60.0:
        return
    raise WorkBoundError(
        f"{what} is estimated at {minutes(seconds)}, over the bound of {bound:g} min (docs: sweeps, 'Bounded "
        f"work'); confirm with --yes or --max-minutes {seconds / 60 * 1.5:.0f}, or make it smaller (fewer axis "
        "values, seeds or trials; --workers N shares it)"
    )


class Progress:
    """Flights done, the rate and the time left, on stderr: an updating line on a terminal, else a line
    every ``every_s`` seconds (and at the end). ``clock`` is injectable for tests."""

    def __init__(
        self, total: int, what: str = "flights", enabled: bool = True, every_s: float = 5.0,
        stream: IO[str] | None = None, clock: Callable[[], float] = time.perf_counter,
    ) -> None:  # fmt: skip
        self.total, self.what, self.enabled, self.every_s = total, what, enabled, every_s
        self.stream = stream if stream is not None else sys.stderr
        self.clock = clock
        self.tty = self.stream.isatty()
        self.done = 0
        self.start()

    def start(self) -> None:
        """Start (or restart) the clock: after a compile, so that the rate is the work's."""
        self.t0 = self.last = self.clock()

    def left_s(self) -> float:
        """Seconds left at the rate measured so far (inf before the first)."""
        el = self.clock() - self.t0
        return float("inf") if self.done == 0 else (self.total - self.done) * el / self.done

    def __call__(self, n: int = 1) -> None:
        self.done = min(self.total, self.done + n)
        if not self.enabled:
            return
        now = self.clock()
        end = self.done >= self.total
        if not (self.tty or end or now - self.last >= self.every_s):
            return
        self.last = now
        el = now - self.t0
        rate = self.done / max(el, 1e-9)
        msg = f"  {self.what} {self.done}/{self.total}  {rate:7.1f}/s  {minutes(self.left_s())} left"
        self.stream.write(("\r" + msg + ("\n" if end else "")) if self.tty else msg + "\n")
        self.stream.flush()
