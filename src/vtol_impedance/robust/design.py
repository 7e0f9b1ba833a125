"""Bandwidths chosen so that the closed loop keeps its margins: the attitude loop, the attitude filter
and the estimator, for a given vehicle, position impedance and timing.

The rule (each step measured with :func:`~vtol_impedance.robust.margins.margins` on the linearised loop)
-------------------------------------------------------------------------------------------------------
The position impedance ``Kp``, ``Dp`` is the user's (it is what the vehicle should feel like); what is
chosen is everything that has to be fast enough *under* it. The design never sees the true plant: it
judges every candidate on a set of plants around the nominal vehicle, :data:`PLANT_SET` (true inertia
0.8x and 1.3x the nominal, a payload of 0 or 30 % of the mass, the nominal rotor time constant split
2:1 between spin-down and spin-up, no drag), with the latencies the controller assumes.

1. **Roll and pitch** (``wn_o``, ``zeta_o = 1``) and the **attitude filter** (``attitude_filter_wn``): the
   pair with the largest worst-case phase margin of PD (no estimate involved) over the roll and pitch
   torque and reference loops. ``wn_o`` is searched in multiples of ``Dp / m`` (the position loop's
   speed), 1 to 3; the filter at 1, 1.25 or 1.5 times ``wn_o``. The paper's 8 rad/s attitude loop sits
   below its own ``Dp / m = 10 1/s`` position loop, which is why its margin is thin.
2. **Yaw** (``wn_o_yaw``): the paper's choice, twice the position loop's natural frequency
   ``2 sqrt(Kp / m)``, kept below the roll/pitch bandwidth.
3. **Estimator** (``estimator_wn``, ``zeta = 1``, aligned to the latencies and the rotor model): the largest
   of 15, 12, 10, 8, 6, 5, 4 rad/s for which PD+C is stable on every plant of the set and loses at most
   :data:`COMPENSATION_COST_DEG` of phase margin and 0.02 of damping against PD on each: compensation may
   cost a little robustness, never the loop.

If even the best candidate leaves PD unstable, no bandwidth can help: :class:`DesignError` names the
latency and rotor lag and the largest position damping ``Dp`` the loop can take.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..control.gains import ImpedanceGains
from ..control.impedance import ControllerParams
from ..errors import InputError, choice, per_axis, scalar
from ..estimator.momentum import EstimatorParams
from ..io import source_digest
from ..model.vehicle import VehicleParams
from ..sim.plant import PlantParams
from ..sim.sensors import SensorParams
from .linear import LoopSizeError, TrimError, linearize
from .margins import MarginReport, Thresholds, margins

#: Plants the design must hold on: (true inertia / nominal, payload / nominal mass).
PLANT_SET: tuple[tuple[float, float], ...] = ((1.3, 0.0), (0.8, 0.3), (1.3, 0.3), (0.8, 0.0))
#: Phase margin PD+C may lose against PD on any plant of the set, deg.
COMPENSATION_COST_DEG = 5.0
#: Estimator bandwidths tried, rad/s: from the paper's 10 up while they pass, else down.
ESTIMATOR_WN = (4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0)
#: Roll/pitch bandwidths tried, in multiples of Dp/m (coarse, then +-0.25 around the best), and the
#: filter-to-attitude ratios tried at the best.
ATTITUDE_RATIOS = (1.25, 1.75, 2.25, 2.75)
FILTER_RATIOS = (1.0, 1.25, 1.5)
_RP_LOOPS = ("roll torque", "pitch torque", "roll reference", "pitch reference")


class DesignError(InputError):
    """No bandwidth keeps the loop stable with this latency and rotor lag."""


class DesignWarning(UserWarning):
    """A design that holds the loop stable but short of a margin threshold somewhere in its plant set."""


@dataclass(frozen=True)
class Timing:
    """What the controller assumes about its vehicle's timing: sensor latencies (s) and the rotors'
    first-order time constant (s). In the simulator the latencies default to the sensor model's (a real
    system reads them off its timestamps); the rotor time constant is the vehicle's nominal one."""

    velocity_delay: float = 0.02
    attitude_delay: float = 0.002
    rotor_tau: float = 0.019

    def __post_init__(self) -> None:
        for name in ("velocity_delay", "attitude_delay", "rotor_tau"):
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0, hi=1.0))


@dataclass(frozen=True)
class Design:
    """Chosen bandwidths (rad/s) and the margins that chose them (worst over :data:`PLANT_SET`)."""

    wn_o: float
    wn_o_yaw: float
    attitude_filter_wn: float
    estimator_wn: float
    timing: Timing
    worst_pd: dict[str, float] = field(default_factory=dict)
    worst_pdc: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def gains(self, vehicle: VehicleParams, Kp: Any, Dp: Any, Ki: Any = 0.0) -> ImpedanceGains:
        """Impedance gains with this design's attitude bandwidths (``zeta_o = 1``) on ``vehicle``."""
        I = np.diag(vehicle.inertia)  # noqa: E741
        w = np.array([self.wn_o, self.wn_o, self.wn_o_yaw])
        return ImpedanceGains(Kp=Kp, Dp=Dp, Ko=w**2 * I, Do=2.0 * w * I, Ki=Ki)

    def estimator(self) -> EstimatorParams:
        """The estimator of this design: second order, ``zeta = 1``, aligned to the timing."""
        t = self.timing
        return EstimatorParams(
            wn=self.estimator_wn, zeta=1.0, velocity_delay=t.velocity_delay, attitude_delay=t.attitude_delay,
            rotor_tau=t.rotor_tau,
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        return {
            "wn_o": self.wn_o,
            "wn_o_yaw": self.wn_o_yaw,
            "attitude_filter_wn": self.attitude_filter_wn,
            "estimator_wn": self.estimator_wn,
            "timing": {k: getattr(self.timing, k) for k in ("velocity_delay", "attitude_delay", "rotor_tau")},
            "worst_pd": self.worst_pd,
            "worst_pdc": self.worst_pdc,
            "notes": list(self.notes),
        }


def _plant(vehicle: VehicleParams, inertia: float, payload: float, rotor_tau: float) -> PlantParams:
    return PlantParams(
        vehicle, payload_mass=payload * vehicle.mass, inertia_scale=(inertia,) * 3,
        rotor_tau_up=2.0 / 3.0 * rotor_tau, rotor_tau_down=4.0 / 3.0 * rotor_tau, rotor_drag=0.0, ground=False,
    )  # fmt: skip


def _sensors(t: Timing) -> SensorParams:
    return SensorParams(0.0, 0.0, t.velocity_delay, 0.0, 0.0, t.attitude_delay)


def _report(ctrl: ControllerParams, plant: PlantParams, t: Timing, loops: tuple[str, ...] | None) -> MarginReport:
    try:
        return margins(linearize(ctrl, plant, _sensors(t)), loops=loops)
    except TrimError as exc:
        raise DesignError(f"the design's plant set cannot hover: {exc}") from exc
    except LoopSizeError as exc:
        raise DesignError(f"no design: {exc}") from exc


def _violations_of(worst: dict[str, float], t: Thresholds) -> list[str]:
    out = []
    if not worst["stable"]:
        out.append(f"unstable, growth {worst['growth_rate']:.3g} 1/s")
    else:
        if worst["pm_min_deg"] < t.phase_deg:
            out.append(f"phase margin {worst['pm_min_deg']:.1f} deg < {t.phase_deg:g}")
        if worst["gm_min_db"] < t.gain_db:
            out.append(f"gain margin {worst['gm_min_db']:.1f} dB < {t.gain_db:g}")
        if worst["damping_min"] < t.damping:
            out.append(f"damping {worst['damping_min']:.2f} < {t.damping:g}")
    return out


def _worst(reports: list[MarginReport]) -> dict[str, float]:
    sums = [r.summary() for r in reports]
    out = {k: min(s[k] for s in sums) for k in sums[0]}
    out["growth_rate"] = max(s["growth_rate"] for s in sums)
    out["ms_max"] = max(s["ms_max"] for s in sums)
    return out


def design(
    vehicle: VehicleParams,
    Kp: Any,
    Dp: Any,
    rate: float = 100.0,
    timing: Timing | None = None,
) -> Design:
    """Bandwidths for ``vehicle`` (nominal) under the position impedance ``Kp`` (N/m), ``Dp`` (N s/m) at the
    control ``rate`` (Hz) with ``timing``, by the rule of the module docstring. Cached per argument set."""
    if not isinstance(vehicle, VehicleParams):
        raise InputError(f"vehicle must be a VehicleParams, got {type(vehicle).__name__}")
    timing = Timing() if timing is None else timing
    if not isinstance(timing, Timing):
        raise InputError(f"timing must be a Timing, got {type(timing).__name__}")
    kp = tuple(float(v) for v in per_axis("Kp", Kp, lo=0.0, lo_open=True))
    dp = tuple(float(v) for v in per_axis("Dp", Dp, lo=0.0, lo_open=True))
    rate = scalar("rate", rate, lo=0.0, lo_open=True)
    key = json.dumps(
        [vehicle.to_dict(), kp, dp, rate, timing.velocity_delay, timing.attitude_delay, timing.rotor_tau, code_key()],
        sort_keys=True, default=str,
    )  # fmt: skip
    found = _design_cached(key, vehicle, kp, dp, rate, timing)
    if isinstance(found, str):  # no bandwidth keeps the loop stable: remembered as a design is
        raise DesignError(found)
    return found


_PACKAGE = Path(__file__).resolve().parent.parent
#: The code a design depends on: the rule, the linearisation and margins, and every model they call.
DESIGN_SOURCES: tuple[Path, ...] = tuple(
    sorted(p for sub in ("robust", "control", "estimator", "model", "sim") for p in (_PACKAGE / sub).glob("*.py"))
) + (_PACKAGE / "conventions.py", _PACKAGE / "compiled" / "algebra.py")  # the frequency responses


def code_key() -> str:
    """The code version of a cached design: :func:`~vtol_impedance.io.source_digest` of
    :data:`DESIGN_SOURCES` and the package version, so that no design cached on disk outlives the code
    that computed it (an edit, an upgrade)."""
    from .. import __version__

    return _code_key(DESIGN_SOURCES, __version__)


@functools.lru_cache(maxsize=8)
def _code_key(sources: tuple[Path, ...], version: str) -> str:
    return source_digest(sources)


def cache_dir() -> Path | None:
    """Where designs are kept between runs (``VTOL_IMPEDANCE_CACHE``, else ``~/.cache/vtol-impedance``;
    ``VTOL_IMPEDANCE_CACHE=off`` keeps none)."""
    where = os.environ.get("VTOL_IMPEDANCE_CACHE")
    if where == "off":
        return None
    base = Path(where) if where else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "vtol-impedance"
    return base / "designs"


@functools.lru_cache(maxsize=64)
def _design_cached(key: str, vehicle: VehicleParams, kp: tuple, dp: tuple, rate: float, t: Timing) -> Design | str:
    """:func:`_design_search` remembered in memory and on disk (one small JSON file per argument set,
    written atomically; an unreadable file is recomputed). No design is remembered too, as the
    :class:`DesignError` message (a str): its search is the longest, and a tuning meets the same gains
    again (the corners checked, the warm-up, the trials)."""
    folder = cache_dir()
    path = None if folder is None else folder / f"{hashlib.sha256(key.encode()).hexdigest()[:32]}.json"
    if path is not None and path.is_file():
        try:
            d = json.loads(path.read_text())
            if "no_design" in d:
                return str(d["no_design"])
            return Design(d["wn_o"], d["wn_o_yaw"], d["attitude_filter_wn"], d["estimator_wn"], t,
                          d["worst_pd"], d["worst_pdc"], tuple(d["notes"]))  # fmt: skip
        except (OSError, ValueError, KeyError, TypeError):
            pass
    try:
        result: Design | str = _design_search(vehicle, kp, dp, rate, t)
    except DesignError as exc:
        result = str(exc)
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(json.dumps({"no_design": result} if isinstance(result, str) else result.to_dict()))
            os.replace(tmp, path)
        except OSError:  # a read-only home: no cache, same answer
            pass
    return result


def _design_search(vehicle: VehicleParams, kp: tuple, dp: tuple, rate: float, t: Timing) -> Design:
    Ts = 1.0 / rate
    wn_yaw_rule = 2.0 * np.sqrt(kp[2] / vehicle.mass)
    plants = [_plant(vehicle, i, p, t.rotor_tau) for i, p in PLANT_SET]

    def controller(variant: str, wn_o: float, wn_f: float, wn_e: float) -> ControllerParams:
        return _controller(vehicle, kp, dp, Ts, t, variant, wn_o, wn_f, wn_e)

    # 1. roll/pitch and the filter, judged on PD over the plant set's extremes: coarse, then refined
    extremes = [plants[0], plants[1]]
    score, wn_o, wn_f = _attitude_search(vehicle, kp, dp, Ts, t, extremes, ATTITUDE_RATIOS, (1.25,))
    if score is not None:
        r = wn_o / (max(dp[0], dp[1]) / vehicle.mass)
        fine = _attitude_search(vehicle, kp, dp, Ts, t, extremes, (r - 0.25, r, r + 0.25), FILTER_RATIOS)
        if fine[0] is not None and fine[0] > score:
            score, wn_o, wn_f = fine
    if score is None:
        raise DesignError(_unstabilisable(vehicle, kp, dp, Ts, t, extremes))
    wn_yaw = min(wn_yaw_rule, wn_o)

    # 3. the fastest estimator that keeps the thresholds and costs little against PD on every plant
    thresholds = Thresholds()
    pd_reports = [_report(controller("pd", wn_o, wn_f, _pd_estimator(Ts)), p, t, None) for p in plants]
    pd = [r.summary() for r in pd_reports]
    results: dict[float, tuple[bool, dict[str, float]]] = {}

    def passes(wn_e: float) -> bool:
        if wn_e not in results:
            reports = [_report(controller("pdc", wn_o, wn_f, wn_e), p, t, None) for p in plants]
            ok = all(
                r.stable
                and not r.violations(thresholds)
                and r.summary()["pm_min_deg"] >= s["pm_min_deg"] - COMPENSATION_COST_DEG
                for r, s in zip(reports, pd, strict=True)
            )
            results[wn_e] = (ok, _worst(reports))
        return results[wn_e][0]

    usable = [w for w in ESTIMATOR_WN if w * Ts <= 0.5]
    i = usable.index(10.0) if 10.0 in usable else len(usable) - 1
    step = 1 if passes(usable[i]) else -1
    while 0 <= i + step < len(usable) and passes(usable[i + step]) == (step > 0):
        i += step
    if step < 0:
        i = i + step if i + step >= 0 else 0  # the first that passed going down (or the slowest)
    chosen = usable[i]
    passes(chosen)
    worst_pdc = results[chosen][1]
    notes: list[str] = []
    if not results[chosen][0]:
        notes.append(
            f"even a {chosen:g} rad/s estimator falls short on some plant of the design set ("
            + "; ".join(
                _violations_of(worst_pdc, thresholds)
                or [f"it costs more than {COMPENSATION_COST_DEG:g} deg of phase margin against PD"]
            )
            + "): PD+C may be worse than PD there"
        )
    if _violations_of(_worst(pd_reports), thresholds):
        notes.append(
            "the position loop itself is thin with this timing (" + "; ".join(_violations_of(_worst(pd_reports),
            thresholds)) + "): a softer position impedance (lower Dp, Kp) would gain margin"
        )  # fmt: skip
    worst_pd = _worst(pd_reports)
    return Design(float(wn_o), float(wn_yaw), float(wn_f), float(chosen), t, worst_pd, worst_pdc, tuple(notes))


def _controller(
    vehicle: VehicleParams, kp: tuple, dp: tuple, Ts: float, t: Timing, variant: str, wn_o: float, wn_f: float,
    wn_e: float,
) -> ControllerParams:  # fmt: skip
    d = Design(wn_o, min(2.0 * np.sqrt(kp[2] / vehicle.mass), wn_o), wn_f, wn_e, t)
    return ControllerParams(
        vehicle=vehicle, gains=d.gains(vehicle, kp, dp), variant=variant, estimator=d.estimator(), Ts=Ts,
        attitude_filter_wn=wn_f,
    )  # fmt: skip


def _pd_estimator(Ts: float) -> float:
    """The estimator bandwidth of PD candidates (never fed forward): the paper's 10 rad/s, or less at a
    slow control rate (a bandwidth near the sampling rate would warn about a loop it does not affect)."""
    return min(10.0, 0.5 / Ts)


def _attitude_search(
    vehicle: VehicleParams, kp: tuple, dp: tuple, Ts: float, t: Timing, plants: list[PlantParams],
    ratios: tuple[float, ...], filters: tuple[float, ...],
) -> tuple[float | None, float, float]:  # fmt: skip
    """Step 1: the roll/pitch bandwidth and filter with the largest worst-case PD phase margin over
    ``plants``; ``None`` as the score when no candidate is stable on all of them."""
    speed = max(dp[0], dp[1]) / vehicle.mass  # the lateral position loop's rate, 1/s
    nyquist = 0.45 * np.pi / Ts  # keep every bandwidth well below it
    best: tuple[float | None, float, float] = (None, 0.0, 0.0)
    for r in ratios:
        for f in filters:
            wn_o, wn_f = r * speed, f * r * speed
            if wn_f >= nyquist:
                continue
            ctrl = _controller(vehicle, kp, dp, Ts, t, "pd", wn_o, wn_f, _pd_estimator(Ts))
            w = _worst([_report(ctrl, p, t, _RP_LOOPS) for p in plants])
            if w["stable"] and (best[0] is None or w["pm_min_deg"] > best[0]):
                best = (w["pm_min_deg"], wn_o, wn_f)
    return best


def _unstabilisable(
    vehicle: VehicleParams, kp: tuple, dp: tuple, Ts: float, t: Timing, plants: list[PlantParams]
) -> str:
    """The message when no attitude bandwidth stabilises PD: name the timing and the largest ``Dp``
    (with ``Kp`` scaled to keep the position loop's damping) for which one does, judged as step 1 judges
    (the same ``plants`` and candidates), printed rounded down: the numbers it gives pass."""
    m = vehicle.mass
    lo, hi = 0.0, 1.0
    for _ in range(7):
        k = 0.5 * (lo + hi)
        score, _, _ = _attitude_search(
            vehicle, tuple(k * k * v for v in kp), tuple(k * v for v in dp), Ts, t, plants, ATTITUDE_RATIOS, (1.25,)
        )  # fmt: skip
        lo, hi = (k, hi) if score is not None else (lo, k)
    where = (
        f"Dp must come down to {_down(lo * max(dp[0], dp[1]))} N s/m or less (Kp to "
        f"{_down(lo * lo * max(kp[0], kp[1]))} N/m)"
        if lo > 0
        else "no position gain does"
    )
    return (
        f"no attitude bandwidth keeps the position loop stable at a {1.0 / Ts:.3g} Hz control rate with "
        f"{1e3 * t.velocity_delay:.0f} ms of position latency and a {1e3 * t.rotor_tau:.0f} ms rotor lag at "
        f"Dp/m = {max(dp[0], dp[1]) / m:.3g} 1/s: {where}, or the rate must rise or the latency or the rotor lag "
        "shrink"
    )


def designed_controller(
    vehicle: VehicleParams, variant: str, Kp: Any, Dp: Any, rate: float = 100.0, timing: Timing | None = None,
    Ki: Any = 0.0, **kw: Any,
) -> ControllerParams:  # fmt: skip
    """A :class:`ControllerParams` with the bandwidths of :func:`design` (the robust default).

    ``timing`` is what the controller assumes about the vehicle it will fly; unset it is :class:`Timing`'s
    default, the paper's Pelican in this simulator (20 ms position latency, 2 ms attitude latency, a 19 ms
    rotor time constant). The bandwidths depend on it: give your vehicle's. Each note of the design (a
    margin short of its threshold on the design's plant set, so that PD+C may be worse than PD there) is
    issued as a :class:`DesignWarning` before the controller is returned; the :class:`DesignError` of a
    loop no bandwidth can hold names the gains that can."""
    from ..control.impedance import VARIANTS

    choice("variant", variant, sorted(VARIANTS))
    per_axis("Ki", Ki, lo=0.0)
    d = design(vehicle, Kp, Dp, rate, timing)
    for note in d.notes:
        warnings.warn(f"designed_controller: {note}", DesignWarning, stacklevel=2)
    base = ControllerParams(
        vehicle=vehicle,
        gains=d.gains(vehicle, Kp, Dp, Ki),
        variant=variant,
        estimator=d.estimator(),
        Ts=1.0 / rate,
        attitude_filter_wn=d.attitude_filter_wn,
    )
    return replace(base, **kw) if kw else base


def _down(x: float) -> str:
    """``x`` to three significant digits, rounded towards zero."""
    e = 10.0 ** (np.floor(np.log10(x)) - 2) if x > 0 else 1.0
    return f"{np.floor(x / e) * e:.3g}"


__all__ = ["Design", "DesignError", "DesignWarning", "Timing", "design", "designed_controller"]
