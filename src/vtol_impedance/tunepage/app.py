"""What the tuning page computes, without HTTP: a tuning is a set of scenario values (the keys of
``--set``), applied to a base scenario by :func:`~vtol_impedance.scenarios.set_value`, so that a bad value
gets the same error as on the command line. From a tuning the page shows the stability margins of the
sampled loop (:func:`~vtol_impedance.scenarios.margins.scenario_margins`, the ``margins`` command's), the
pre-flight verdict in the words of the flying commands, and three short flights on the compiled engine
(:func:`~vtol_impedance.scenarios.simulate`): a step of the reference, an operator's push and a gust.
Nothing here is a copy of the physics or of the margin check: every number comes from those functions.

The margins of the two controllers take about 0.15 s each (the trim and the frequency responses are
NumPy code); they run in two worker processes at once while the flights run here, so that a change is
shown in about 0.2 s on two cores (docs/guide/tuning-page.md).
"""

from __future__ import annotations

import json
import math
import threading
import time
import warnings
from collections import OrderedDict
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..errors import InputError, ScenarioError, VtolImpedanceError, choice, instance, scalar
from ..io import quiet_worker, spawning_quietly
from ..robust import LOOPS
from ..scenarios import ScenarioSpec, check, get, set_value, simulate
from ..scenarios.spec import DESIGNED, _dotted, check_name, get_value, parse_value, resolved_control

#: What the page promises: a change shown within this many milliseconds (measured by the page).
BUDGET_MS = 200.0
#: The controllers the page can put beside PD: the paper's compensation, or the interaction impedance.
COMPENSATING = ("pdc", "comply")


@dataclass(frozen=True)
class Field:
    """One control of the page: the scenario ``key`` it sets (as ``--set`` names it), a label, the slider's
    range and step (the accepted range is the scenario's own, wider), the unit and the group it is shown in."""

    key: str
    label: str
    lo: float
    hi: float
    step: float
    unit: str
    group: str


def _axes(key: str, label: str, lo: float, hi: float, step: float, unit: str, group: str) -> list[Field]:
    return [Field(f"{key}[{i}]", f"{label} {a}", lo, hi, step, unit, group) for i, a in enumerate("xyz")]


_POS, _IMP, _BW, _TRUE = (
    "Position impedance (PD, PD+C)",
    "Interaction impedance (comply)",
    "Attitude and estimator",
    "The true vehicle (what the controller does not know)",
)
#: The page's controls, in the order shown.
FIELDS: tuple[Field, ...] = (
    *_axes("control.Kp", "Kp", 1.0, 60.0, 0.5, "N/m", _POS),
    *_axes("control.Dp", "Dp", 0.5, 40.0, 0.5, "N s/m", _POS),
    *_axes("interaction.M", "M", 0.2, 6.0, 0.1, "kg", _IMP),
    *_axes("interaction.D", "D", 0.0, 30.0, 0.5, "N s/m", _IMP),
    *_axes("interaction.K", "K", 0.0, 40.0, 0.5, "N/m", _IMP),
    Field("control.estimator_wn", "estimator bandwidth", 1.0, 40.0, 0.5, "rad/s", _BW),
    Field("control.estimator_order", "estimator order", 1.0, 4.0, 1.0, "", _BW),
    Field("control.wn_o", "attitude bandwidth roll/pitch", 4.0, 40.0, 0.5, "rad/s", _BW),
    Field("control.wn_o_yaw", "attitude bandwidth yaw", 2.0, 20.0, 0.5, "rad/s", _BW),
    Field("control.attitude_filter_wn", "attitude reference filter", 5.0, 60.0, 0.5, "rad/s", _BW),
    Field("control.rotor_tau", "rotor lag assumed", 0.0, 0.06, 0.001, "s", _BW),
    Field("plant.rotor_tau_up", "rotor lag up", 0.0, 0.06, 0.001, "s", _TRUE),
    Field("plant.rotor_tau_down", "rotor lag down", 0.0, 0.08, 0.001, "s", _TRUE),
    Field("sensors.mocap_delay", "position/velocity latency", 0.0, 0.06, 0.001, "s", _TRUE),
    Field("sensors.imu_delay", "attitude latency", 0.0, 0.02, 0.001, "s", _TRUE),
    Field("plant.inertia_scale[0]", "inertia roll (true / nominal)", 0.5, 1.5, 0.01, "", _TRUE),
    Field("plant.inertia_scale[1]", "inertia pitch (true / nominal)", 0.5, 1.5, 0.01, "", _TRUE),
    Field("plant.inertia_scale[2]", "inertia yaw (true / nominal)", 0.5, 1.5, 0.01, "", _TRUE),
    Field("payload.mass", "unmodelled payload", 0.0, 0.4, 0.005, "kg", _TRUE),
)
_KEYS = {f.key: f for f in FIELDS}

#: Evaluated tunings kept (the latest first), so that showing another loop or a second tab on the same
#: state flies nothing again.
CACHED = 16
#: The three flights (s): how long the vehicle hovers before the event, and the whole flight.
SETTLE_S, FLIGHT_S = 1.0, 3.5
#: The step of the reference (m along x), the push (N along x, s) and the gust (m/s along x, s).
STEP_M, PUSH_N, PUSH_S, GUST_M_S, GUST_S = 0.3, 2.0, 1.0, 5.0, 1.5


def _margins_job(spec: ScenarioSpec, variant: str) -> tuple[Any, float]:
    """The margins of one controller (run in a worker process) and the CPU time they took (s)."""
    from ..scenarios.margins import scenario_margins

    t0 = time.thread_time()
    return scenario_margins(spec, [variant])[variant], time.thread_time() - t0


def _finite(x: Any, decimals: int = 3) -> list[float | None]:
    """Numbers for JSON, rounded to ``decimals``; ``None`` for a non-finite value (JSON has no NaN)."""
    a = np.round(np.asarray(x, dtype=float), decimals)
    out = a.tolist()
    if not np.all(np.isfinite(a)):
        out = [v if math.isfinite(v) else None for v in out]
    return out


def _toml_value(v: Any) -> str:
    """A TOML value: JSON's numbers, strings, booleans and arrays are TOML's; ``None`` (a designed or
    automatic value) is ``"design"``."""
    return '"design"' if v is None else json.dumps(v)


class TunePage:
    """The tuning page's state and computations (the HTTP server is :func:`make_server`).

    Parameters
    ----------
    base : ScenarioSpec or str
        The scenario whose operating point the margins are taken at (its payload and mean disturbance) and
        whose vehicle, plant and sensors the flights keep (default: case A, hover with a payload).
    vehicle : str, optional
        A vehicle preset name or a vehicle ``.toml`` file flown instead of the base's.
    workers : int
        Worker processes for the margins (two: one per controller, at once); 0 computes them here.

    Notes
    -----
    The defaults shown are the base scenario's control with its designed bandwidths filled in
    (:func:`~vtol_impedance.scenarios.spec.resolved_control`): what ``vtol-impedance run`` flies.
    """

    def __init__(self, base: ScenarioSpec | str = "case-a-payload", vehicle: str | None = None, workers: int = 2):
        if isinstance(base, str):
            try:
                spec = get(base)
            except ScenarioError as exc:
                raise ScenarioError(f"base: {exc}") from None
        else:
            spec = instance("base", base, ScenarioSpec)
        if vehicle is not None:
            instance("vehicle", vehicle, str)
            if vehicle.endswith(".toml"):  # the scenario file it writes is flown from anywhere
                from pathlib import Path

                vehicle = str(Path(vehicle).resolve())
            spec = set_value(spec, "vehicle", vehicle)
        self.workers = int(scalar("workers", workers, lo=0, hi=8, integer=True))
        self.base_name = spec.name
        name = check_name(f"{spec.name}-tuned")
        control = resolved_control(spec)
        spec = replace(spec, name=name, control=control)
        self.base = spec
        self.defaults = {f.key: self._value(spec, f.key) for f in FIELDS}
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self._cache: OrderedDict[str, tuple[Any, dict[str, Any], list[str]]] = OrderedDict()

    @staticmethod
    def _value(spec: ScenarioSpec, key: str) -> float:
        plain, _, index = key.partition("[")
        v = get_value(spec, plain)
        if index:
            v = v[int(index[0])] if isinstance(v, list) else v
        return float(v)

    # ------------------------------------------------------------------ the tuning

    def spec_of(self, values: Mapping[str, Any]) -> ScenarioSpec:
        """The base scenario with ``values`` (``{key: number or text}``, text read as ``--set`` reads it)
        applied; a bad value raises the scenario's :class:`~vtol_impedance.errors.ScenarioError`, an
        unknown key an :class:`~vtol_impedance.errors.InputError`, each naming the key."""
        instance("values", values, Mapping)
        spec = self.base
        for key, value in values.items():
            if key not in _KEYS:
                raise InputError(f"values: unknown key {key!r}; the page sets {', '.join(_KEYS)}")
            v = parse_value(value.strip()) if isinstance(value, str) else value
            if key == "control.estimator_order" and isinstance(v, float) and v.is_integer():
                v = int(v)  # a slider's 2.0
            spec = set_value(spec, key, v)
        return spec

    def designed(self, values: Mapping[str, Any]) -> dict[str, Any]:
        """The bandwidths :func:`~vtol_impedance.robust.design` chooses for the tuning's position impedance
        and timing: ``{"values": {key: rad/s}, "notes": [what falls short on the design's plant set]}``."""
        from ..model.vehicle import load_preset
        from ..robust.design import design
        from ..scenarios.spec import assumed_timing

        spec = self.spec_of(values)
        c = spec.control
        d = design(load_preset(spec.vehicle), c.Kp, c.Dp, c.rate, assumed_timing(spec))
        return {"values": {f"control.{k}": float(getattr(d, k)) for k in DESIGNED}, "notes": list(d.notes)}

    def toml(self, values: Mapping[str, Any]) -> str:
        """The tuning as a scenario file that ``vtol-impedance run`` and ``compare`` fly: the registered base
        scenario and every value that differs from it (vectors and disturbances written whole); read back
        by :func:`~vtol_impedance.scenarios.load_toml` it is the page's scenario."""
        spec = self.spec_of(values)
        try:
            ref, head = get(self.base_name), [f"base = {json.dumps(self.base_name)}"]
        except ScenarioError:  # a scenario of the caller's own: written from the defaults
            ref, head = ScenarioSpec(name=spec.name), []
        new, old = _dotted(spec.to_dict()), _dotted(ref.to_dict())
        keys = dict.fromkeys([*(f.key.partition("[")[0] for f in FIELDS), *(k for k in new if new[k] != old.get(k))])
        keys.pop("disturbances", None)
        lines = ["# written by vtol-impedance tune-page; fly it with: vtol-impedance compare FILE --controllers pd,pdc",
                 *head, f"name = {json.dumps(spec.name)}"]  # fmt: skip
        lines += [f"{k} = {_toml_value(new[k])}" for k in keys if k != "name"]
        if new["disturbances"] != old["disturbances"]:
            for d in spec.to_dict()["disturbances"]:
                lines += ["", "[[disturbances]]", *(f"{k} = {_toml_value(v)}" for k, v in d.items())]
        return "\n".join(lines) + "\n"

    # ------------------------------------------------------------------ computing

    def open_pool(self) -> None:
        """Make the pool of worker processes (they start with the first job)."""
        if self.workers and self._pool is None:
            import multiprocessing

            self._pool = ProcessPoolExecutor(
                self.workers, mp_context=multiprocessing.get_context("spawn"), initializer=quiet_worker,
                initargs=(False,),  # started by request threads: a death signal would follow the thread
            )  # fmt: skip

    def start(self) -> None:
        """Start the worker processes and warm them and the compiled engine up (a first change is then
        as fast as the next)."""
        self.open_pool()
        self.evaluate({})

    def close(self, wait: bool = True) -> None:
        """Stop the worker processes: after their current job, or (``wait=False``) at once."""
        pool, self._pool = self._pool, None
        if pool is not None:
            if not wait:  # no shutdown API for running workers before Python 3.14
                for proc in list((getattr(pool, "_processes", None) or {}).values()):
                    proc.terminate()
            pool.shutdown(wait=True, cancel_futures=True)  # quick once terminated; frees the queues' locks

    def _submit(self, spec: ScenarioSpec, variants: list[str]) -> Callable[[], tuple[Any, list[float]]]:
        """Start the margins of ``variants`` (in the workers, at once) and return the wait for them: the
        reports per variant (or the error of a loop without margins) and the CPU time of each (s)."""
        pool = self._pool
        with spawning_quietly():  # a submit may start a worker
            futures: list[Future] = [pool.submit(_margins_job, spec, v) for v in variants] if pool is not None else []

        def result() -> tuple[dict[str, Any] | VtolImpedanceError, list[float]]:
            try:
                try:
                    jobs = [f.result() for f in futures] if pool is not None else None
                except BrokenProcessPool:  # a worker was killed: carry on here, slower but serving
                    self._pool = None
                    jobs = None
                    warnings.warn("a worker process of the margins died; they are computed in the server now",
                                  RuntimeWarning, stacklevel=1)  # fmt: skip
                if jobs is None:
                    jobs = [_margins_job(spec, v) for v in variants]
            except VtolImpedanceError as exc:  # no trim, a loop too large: the CLI says "no margins, ..."
                return exc, []
            return {v: r for v, (r, _) in zip(variants, jobs, strict=True)}, [cpu for _, cpu in jobs]

        return result

    def flight_specs(self, spec: ScenarioSpec) -> dict[str, ScenarioSpec]:
        """The three flights of a tuning: hovering, a reference step, a push and a gust along x."""
        s = spec
        for key, v in (("trajectory.start_on_ground", False), ("trajectory.yaw_step_time", -1.0),
                       ("trajectory.kind", "hover"), ("duration", FLIGHT_S), ("disturbances", [])):  # fmt: skip
            s = set_value(s, key, v)
        hover = set_value(s, "trajectory.hover_duration", FLIGHT_S)
        step = set_value(s, "trajectory.hover_duration", SETTLE_S)
        step = set_value(step, "trajectory.move_offset", [STEP_M, 0.0, 0.0])
        step = set_value(step, "trajectory.move_duration", 0.05)
        step = set_value(step, "trajectory.move_hold", FLIGHT_S)
        push = {"kind": "push", "force_W": [PUSH_N, 0.0, 0.0], "t_on": SETTLE_S, "duration": PUSH_S}
        gust = {"kind": "gust", "amplitude": GUST_M_S, "start": SETTLE_S, "length": GUST_S}
        return {
            "step": step,
            "push": set_value(hover, "disturbances", [push]),
            "gust": set_value(hover, "disturbances", [gust]),
        }

    def evaluate(self, values: Mapping[str, Any], compensating: str = "pdc", loop: str | None = None) -> dict[str, Any]:
        """Margins, verdict and flights of a tuning (``values`` as :meth:`spec_of` takes them) with PD and
        ``compensating`` (one of :data:`COMPENSATING`), as plain data for the page; the Bode and Nyquist
        curves are those of ``loop`` (one of :data:`~vtol_impedance.robust.LOOPS`; default: the loop of
        least phase margin of the compensating controller)."""
        from ..analysis.margin_plots import bode_curves, margin_rows, pole_rows
        from ..scenarios.margins import MEETS, below_header, summary_of

        t0 = time.perf_counter()
        choice("compensating", compensating, COMPENSATING)
        if loop is not None:
            choice("loop", loop, LOOPS)
        spec = self.spec_of(values)
        variants = ["pd", compensating]
        key = json.dumps([spec.to_dict(), variants], sort_keys=True, default=str)
        with self._lock:
            if key in self._cache:  # another loop shown, a second tab on the same state: nothing to fly
                self._cache.move_to_end(key)
                reports, flights, said = self._cache[key]
                cpu_flights, cpu_margins = 0.0, [0.0 for _ in variants]
            else:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    check(spec, variants)
                    margins = self._submit(spec, variants)  # in the workers while the flights fly here
                    cpu0 = time.thread_time()
                    flights = {name: self._fly(s, variants) for name, s in self.flight_specs(spec).items()}
                    cpu_flights = time.thread_time() - cpu0
                    reports, cpu_margins = margins()
                said = list(dict.fromkeys(str(w.message) for w in caught))
                self._cache[key] = (reports, flights, said)
                while len(self._cache) > CACHED:
                    self._cache.popitem(last=False)
        out: dict[str, Any] = {"flights": flights, "variants": variants}
        if isinstance(reports, VtolImpedanceError):
            out["verdict"] = f"{below_header()}\n  {spec.name}: no margins, {reports}"
            out["margins"] = None
        else:
            summary = summary_of(reports)
            out["verdict"] = f"{below_header()}\n  {spec.name}: {summary}" if summary else MEETS
            out["passes"] = not summary
            head, rows = margin_rows(reports)
            phead, prows = pole_rows(reports)
            worst = min(reports[compensating].loops.values(), key=lambda m: (m.phase_deg, m.name)).name
            shown = choice("loop", loop, LOOPS) if loop else worst
            curves = {}
            for variant, r in reports.items():
                m = r.loops[shown]
                mag_db, phase = bode_curves(m)
                k = slice(None, None, 2)  # every other frequency: smooth on the page, half the bytes
                curves[variant] = {
                    "omega": _finite(m.omega[k], 4), "mag_db": _finite(mag_db[k], 2), "phase_deg": _finite(phase[k], 1),
                    "re": _finite(m.response.real[k]), "im": _finite(m.response.imag[k]),
                    "pm": _finite([m.phase_deg], 2)[0], "wc": _finite([m.crossover])[0],
                }  # fmt: skip
            out["margins"] = {
                "table": [head, rows], "poles": [phead, prows], "loop": shown, "worst": worst, "loops": list(LOOPS),
                "curves": curves,
                "summary": {v: dict(zip(s := r.summary(), _finite(list(s.values()), 2), strict=True))
                            for v, r in reports.items()},
            }  # fmt: skip
        out["warnings"] = said
        out["server_ms"] = 1e3 * (time.perf_counter() - t0)
        out["cpu_ms"] = {"flights": 1e3 * cpu_flights, "margins": [1e3 * c for c in cpu_margins]}
        return out

    @staticmethod
    def _fly(spec: ScenarioSpec, variants: list[str]) -> dict[str, Any]:
        r = simulate(spec, variants, log="decimate:2")  # 50 Hz traces (the control ticks, every other)
        t0 = r.config["phases"].get("move", SETTLE_S)
        out: dict[str, Any] = {"t": _finite(r.t - t0, 2)}
        for i, v in enumerate(r.labels):
            e_cm = 100.0 * r.e_p[i, :, 0]
            out[v] = {"x_err_cm": _finite(e_cm, 2), "failure": r.failures[i] and r.failures[i]["reason"],
                                "f_hat_x": _finite(r["f_hat_W"][i, :, 0]),
                      "max_err_cm": _finite([np.nanmax(np.abs(e_cm[r.t >= t0]))], 2)[0]}  # fmt: skip
        return out


__all__ = ["BUDGET_MS", "COMPENSATING", "FIELDS", "Field", "TunePage"]
