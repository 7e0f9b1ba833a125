"""Stability margins of a scenario's controllers at its operating point (:mod:`vtol_impedance.robust`).

The operating point is a hover at the reference where the task window starts (its yaw and comply
fractions), on the scenario's true plant with its payload, inertia, rotor and sensor timing, under the
mean wrench of its disturbances over the task window evaluated there (at rest, level): a fan's steady
push, the payload's weight. What the disturbances do beyond their mean (turbulence, a push's duration,
a fan's or wall's dependence on position) is not in the linear model.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import InputError, scalar
from ..model.kinematics import rotation_zyx
from ..robust import MarginReport, Thresholds, linearize, margins
from .spec import Built, ScenarioSpec, checked

#: Times at which the disturbances are averaged over the task window.
N_AVERAGE = 64


def steady_wrench(built: Built, p_W: np.ndarray, psi: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean force (world, N) and moment (body, N m) of the disturbances over the task window, at rest at
    ``p_W`` with the level attitude of yaw ``psi``."""
    f, tau = np.zeros(3), np.zeros(3)
    if not built.disturbances:
        return f, tau
    t0, t1 = built.window
    times = np.linspace(t0, t1, N_AVERAGE) if t1 > t0 else np.array([t0])
    R = rotation_zyx(np.array([0.0, 0.0, psi]))
    prepared = [d.prepare(built.duration + 1.0, 1e-3, np.random.default_rng(0)) for d in built.disturbances]
    for t in times:
        for d in prepared:
            fd, td = d(float(t), p_W, np.zeros(3), R)
            f += np.asarray(fd, dtype=float) / len(times)
            tau += np.asarray(td, dtype=float) / len(times)
    return f, tau


def engaged_time(built: Built) -> float:
    """The first time in the task window at which the comply fractions (summed over the axes) reach their
    largest value there; the window's start when they never change in it. A scenario that switches
    comply on once airborne starts its window with comply off (the switch is blended over ``blend_s``)."""
    t0, t1 = built.window
    times = np.linspace(t0, t1, 1 + max(1, int(round((t1 - t0) / 0.01))))  # 10 ms: a blend is 0.5 s
    total = built.trajectory.comply_at(times).sum(axis=1)
    return float(times[int(np.argmax(total >= total.max() - 1e-9))])


def operating_point_of(built: Built, at: float | None = None) -> dict[str, Any]:
    """Where a scenario's margins are taken: the reference at the start of its task window, or at the
    time ``at`` (s; e.g. :func:`engaged_time`)."""
    t = built.window[0] if at is None else float(at)
    row = built.trajectory.sample_many(np.array([t]))[0]
    p, psi = row[0:3], float(row[9])
    f, tau = steady_wrench(built, p, psi)
    return {"p_W": p, "psi": psi, "comply": row[12:18], "force_W": f, "torque_B": tau}


def scenario_margins(
    spec: ScenarioSpec, variants: Sequence[str] = ("pd", "pid", "pdc"), at: float | str | None = None
) -> dict[str, MarginReport]:
    """Margins of each controller variant of ``spec`` (see the module docstring), at the start of the task
    window, at the time ``at`` (s) or, with ``at = "engaged"``, at :func:`engaged_time`."""
    from threadpoolctl import threadpool_limits

    built, ctrls = checked(spec, list(variants))
    if isinstance(at, str):
        if at != "engaged":
            raise InputError(f"at must be a time in s or 'engaged', got {at!r}")
        at = engaged_time(built)
    elif at is not None:
        at = scalar("at", at, lo=0.0)
    op = operating_point_of(built, at)
    out = {}
    with threadpool_limits(limits=1, user_api="blas"):  # the same numbers whatever the thread count
        for variant, ctrl in zip(variants, ctrls, strict=True):
            loop = linearize(ctrl, built.plant, built.sensors, plant_rate=spec.plant_rate, **op)
            out[variant] = margins(loop, label=variant)
    return out


#: What a compensating controller that falls short of the thresholds risks (said before it flies).
RISK = "compensating here can make the vehicle worse than PD"
#: The controllers that compensate the estimate (their shortfall carries :data:`RISK`).
COMPENSATING = ("pdc", "comply")


#: What the margin check says when every controller meets the thresholds (``vtol-impedance margins``).
MEETS = "every controller meets the thresholds"


def below_header(thresholds: Thresholds | None = None) -> str:
    """The first line of the pre-flight warning of the flying commands, naming ``thresholds``; the lines
    below it are ``"  <scenario>: "`` and :func:`summary_of`."""
    t = Thresholds() if thresholds is None else thresholds
    return (
        f"stability margins below the thresholds ({t.phase_deg:g} deg phase, {t.gain_db:g} dB gain, "
        f"damping {t.damping:g}) at the operating point:"
    )


def warnings_of(reports: dict[str, MarginReport], thresholds: Thresholds | None = None) -> list[str]:
    """One line per controller that falls short of ``thresholds``."""
    from ..control.impedance import DISPLAY_NAMES

    out = []
    for variant, r in reports.items():
        v = r.violations(thresholds)
        if v:
            risk = f" ({RISK})" if variant in COMPENSATING else ""
            out.append(f"{DISPLAY_NAMES.get(variant, variant)}: " + "; ".join(v) + risk)
    return out


def summary_of(reports: dict[str, MarginReport], thresholds: Thresholds | None = None) -> str:
    """:func:`warnings_of` in one line: the controllers that fall short of ``thresholds``, the worst one's
    shortfalls (unstable first, else the least phase margin; its phase margin in deg, gain margin in dB
    and least damping ratio where each falls short) and, when a compensating controller falls short,
    :data:`RISK`. ``""`` when every controller meets the thresholds."""
    from ..control.impedance import DISPLAY_NAMES

    t = Thresholds() if thresholds is None else thresholds
    short = {v: r for v, r in reports.items() if r.violations(t)}
    if not short:
        return ""
    name, worst = min(short.items(), key=lambda kv: (kv[1].stable, kv[1].summary()["pm_min_deg"]))
    s = worst.summary()
    if not worst.stable:
        what = [f"unstable, a closed-loop pole grows at {s['growth_rate']:.3g} 1/s"]
    else:
        what = [f"phase {s['pm_min_deg']:.1f} deg"] if s["pm_min_deg"] < t.phase_deg else []
        what += [f"gain {s['gm_min_db']:.1f} dB"] if s["gm_min_db"] < t.gain_db else []
        what += [f"damping {s['damping_min']:.2f}"] if s["damping_min"] < t.damping else []
    names = ", ".join(DISPLAY_NAMES.get(v, v) for v in short)
    line = f"{names} below (worst {DISPLAY_NAMES.get(name, name)}: {', '.join(what)})"
    return line + (f"; {RISK}" if any(v in COMPENSATING for v in short) else "")
