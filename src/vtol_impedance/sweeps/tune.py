"""Gain tuning with optuna over a population of plants and disturbances, on the sweep's execution.

A tuning file (TOML)::

    name = "tune-case-b"
    base = "case-b-fan"
    controller = "pdc"
    trials = 40
    seed = 7
    population = 6                 # plants flown by every trial (the same ones: common random numbers)
    [set]                          # fixed overrides of the base
    trajectory.hover_duration = 10.0
    [search]                       # ranges of the gains searched (any scenario value)
    "control.Kp" = {min = 4.0, max = 40.0, log = true}
    "control.estimator_wn" = {min = 2.0, max = 30.0, log = true}
    [spread]                       # how the population's true plants differ (drawn once from the seed)
    "payload.mass" = {min = 0.0, max = 0.25}
    [cost]
    metric = "rms_ep_cm"           # per flight, over the task window
    saturation_weight = 0.1        # added per % of the window spent at a limit
    failure_penalty = 1000.0       # replaces the metric of a flight that failed
    min_phase_margin_deg = 20.0    # optional constraint: the stability margins of every member's loop
    margin_penalty = 1000.0        # added for a member whose loop is unstable or below that phase margin

Cost of a trial = mean over the population of ``metric + saturation_weight * sat_pct`` (or
``failure_penalty`` for a failed flight), plus ``margin_penalty`` for every member whose linearised loop
(:mod:`vtol_impedance.robust`) is unstable or keeps less than ``min_phase_margin_deg`` (only computed when
that constraint is set: about 0.3 s per member and trial). The best gains are written as a scenario file
(``best.toml``) that ``vtol-impedance run`` flies directly.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..control.impedance import VARIANTS
from ..errors import InputError, check_keys, instance, scalar
from ..io import read_toml
from ..robust.design import DesignError
from ..scenarios.spec import _INDEXED, _dotted, check_name, get_value
from .budget import Progress, minutes
from .run import METRICS, Executor, warm_up
from .spec import Axis, _axis, distinct_keys, from_dict

KEYS = ("name", "description", "base", "controller", "trials", "seed", "population", "set", "search", "spread", "cost")
COST_KEYS = ("metric", "saturation_weight", "failure_penalty", "min_phase_margin_deg", "margin_penalty")


def _optuna():
    try:
        import optuna
    except ImportError:
        raise InputError("tuning needs optuna: pip install 'vtol-impedance[tune]'") from None
    optuna.logging.set_verbosity(optuna.logging.ERROR)  # a failed trial is reported once, by us, without a traceback
    return optuna


def optimize(
    search: list[Axis], objective: Callable[[dict[str, float]], float], trials: int, seed: int,
    callback: Callable[[int, dict[str, float], float], None] | None = None,
) -> tuple[dict[str, float], float, list[tuple[dict[str, float], float]]]:  # fmt: skip
    """Minimise ``objective(params)`` over ranges ``search`` with optuna's TPE sampler (seeded, so the same
    call gives the same trials); returns the best parameters, their cost and every trial."""
    optuna = _optuna()
    study = optuna.create_study(direction="minimize", sampler=optuna.samplers.TPESampler(seed=seed))
    history: list[tuple[dict[str, float], float]] = []

    def wrapped(trial) -> float:
        params = {}
        for a in search:
            if a.values is not None:
                params[a.key] = trial.suggest_categorical(a.key, list(a.values))
            else:
                params[a.key] = trial.suggest_float(a.key, a.lo, a.hi, log=a.log)
        value = float(objective(params))
        if not math.isfinite(value):
            value = float("inf")
        history.append((params, value))
        if callback:
            callback(len(history), params, value)
        return value

    study.optimize(wrapped, n_trials=trials)
    return dict(study.best_params), float(study.best_value), history


@dataclass
class Tuning:
    name: str
    description: str
    data: dict[str, Any]
    where: Path | None
    controller: str
    trials: int
    seed: int
    population: int
    search: list[Axis]
    spread: list[Axis]
    metric: str
    saturation_weight: float
    failure_penalty: float
    min_phase_margin_deg: float = 0.0
    margin_penalty: float = 1000.0
    base: Any = None  # the base scenario, resolved once (a base file is read here, never by a worker)

    def __post_init__(self) -> None:
        if self.base is None:
            from .spec import _base

            self.base = _base(self.data, self.where)

    def base_spec(self) -> Any:
        """The scenario every trial starts from: the base with the fixed overrides."""
        from .spec import set_param

        spec = self.base
        for k, v in _dotted(self.data.get("set", {})).items():
            spec = set_param(spec, k, v)
        return spec

    def trial_sweep(self, params: dict[str, float]) -> dict[str, Any]:
        """The sweep description flying ``params`` on the whole population (one point per member)."""
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(2**30,)))
        members = [{a.key: a.draw(rng) for a in self.spread} for _ in range(self.population)]
        fixed = dict(_dotted(self.data.get("set", {})))
        fixed.update(params)
        if self.spread:  # one point per member, one seed each
            axes, seeds = {a.key: [m[a.key] for m in members] for a in self.spread}, 1
        else:  # the members differ only by their noise: one point, a seed each (an axis of the one duration)
            axes, seeds = {"duration": [fixed.pop("duration", self.base_spec().duration)]}, self.population
        return {
            "name": self.name, "base": self.data["base"], "controllers": [self.controller], "seeds": seeds,
            "seed": self.seed, "mode": "zip", "chunk": 1, "set": fixed, "axes": axes,
            "margins": self.min_phase_margin_deg > 0.0,
        }  # fmt: skip


def load_tuning(path: str | Path, check_corners: bool = True) -> Tuning:
    """A tuning file (module docstring); see :func:`tuning_from_dict` for ``check_corners``."""
    path = Path(path)
    data = read_toml(path, "tuning file")
    return tuning_from_dict(data, path, check_corners)


def tuning_from_dict(data: dict[str, Any], where: Path | None = None, check_corners: bool = True) -> Tuning:
    """Validate a tuning description; ``check_corners=False`` skips checking the search box's corners as
    scenarios (which designs their controllers: work, see ``sweeps.budget``)."""
    check_keys("tuning", data, KEYS)
    search_raw = data.get("search")
    if not isinstance(search_raw, dict) or not search_raw:
        raise InputError("a tuning needs [search]: the gains to search, as ranges {min, max, log}")
    search = [_axis(k, v, "random") for k, v in search_raw.items()]
    spread_raw = data.get("spread", {})
    if not isinstance(spread_raw, dict):
        raise InputError(f"[spread] must be a table of ranges, got {spread_raw!r}")
    spread = [_axis(k, v, "random") for k, v in spread_raw.items()]
    distinct_keys({"[search]": search, "[spread]": spread}, data.get("set", {}))
    cost = data.get("cost", {})
    check_keys("[cost]", cost, COST_KEYS)
    metric = cost.get("metric", "rms_ep_cm")
    if metric not in METRICS:
        raise InputError(f"cost metric must be one of {', '.join(METRICS)}, got {metric!r}")
    controller = data.get("controller", "pdc")
    if not isinstance(controller, str):  # one controller is tuned at a time
        raise InputError(f"controller is one of {', '.join(sorted(VARIANTS))} (one per tuning), got {controller!r}")
    t = Tuning(
        name=check_name(data.get("name", "tune")),
        description=instance("description", data.get("description", ""), str), data=data, where=where,
        controller=controller,
        trials=int(scalar("trials", data.get("trials", 30), lo=1, hi=100_000, integer=True)),
        seed=int(scalar("seed", data.get("seed", 0), lo=0, hi=2**63 - 1, integer=True)),
        population=int(scalar("population", data.get("population", 4), lo=1, hi=10_000, integer=True)),
        search=search, spread=spread, metric=metric,
        saturation_weight=float(scalar("saturation_weight", cost.get("saturation_weight", 0.0), lo=0.0)),
        failure_penalty=float(scalar("failure_penalty", cost.get("failure_penalty", 1000.0), lo=0.0)),
        min_phase_margin_deg=float(scalar("min_phase_margin_deg", cost.get("min_phase_margin_deg", 0.0), lo=0.0,
                                          hi=90.0)),
        margin_penalty=float(scalar("margin_penalty", cost.get("margin_penalty", 1000.0), lo=0.0)),
    )  # fmt: skip
    # every corner of the search box, and every listed value, must be a valid scenario: checked now (gains
    # that no attitude bandwidth keeps stable are valid input: such a trial fails and the search moves on)
    lo = {a.key: a.lo if a.values is None else a.values[0] for a in search}
    hi = {a.key: a.hi if a.values is None else a.values[-1] for a in search}
    # and a point inside every range, which a key taking whole numbers refuses (a range draws real numbers)
    inside = {a.key: (a.lo + 0.37 * (a.hi - a.lo) if a.values is None else a.values[0]) for a in search}
    corners = [lo, hi, inside, *({**lo, a.key: v} for a in search for v in a.values or ())]
    for point in corners if check_corners else []:
        try:
            from_dict(t.trial_sweep(point), where, base=t.base)
        except DesignError:
            pass
        except InputError as exc:
            if point is not inside:
                raise
            raise InputError(
                f"{exc} (a [search] range draws real numbers: give a key that takes whole numbers its values as a "
                "list, values = [...])"
            ) from None
    return t


def _input_error(message: str) -> bool:
    """Whether a chunk's failure (``"TypeName: message"``, as :class:`~.cluster.ChunkError` lists it) was the
    input's own error (:class:`~vtol_impedance.errors.InputError` or a subclass), not the machine's."""
    names, todo = set(), [InputError]
    while todo:
        c = todo.pop()
        names.add(c.__name__)
        todo.extend(c.__subclasses__())
    return message.split(":", 1)[0] in names


def bound_notes(t: Tuning, best: dict[str, Any]) -> list[str]:
    """A note for each best value within 1 % of its search range's end (log scale for log ranges): the
    optimum may lie beyond it."""
    notes = []
    for a in t.search:
        if a.values is not None or a.lo is None or a.hi is None or a.hi <= a.lo:
            continue
        v = float(best[a.key])
        lo, hi, x = (math.log(a.lo), math.log(a.hi), math.log(max(v, 1e-300))) if a.log else (a.lo, a.hi, v)
        frac = (x - lo) / (hi - lo)
        if frac <= 0.01 or frac >= 0.99:
            end = "min" if frac <= 0.01 else "max"
            notes.append(
                f"the best {a.key} = {v:.4g} sits on the search range's {end} ({a.lo:g}..{a.hi:g}): the optimum may "
                "lie beyond it; widen the range"
            )
    return notes


def trial_cost(t: Tuning, rows: dict[str, list]) -> tuple[float, dict[str, float]]:
    vals = np.asarray(rows[t.metric], dtype=float)
    sat = np.asarray(rows["sat_pct"], dtype=float)
    failed = np.asarray(rows["diverged"], dtype=bool) | ~np.isfinite(vals)
    per = np.where(failed, t.failure_penalty, vals + t.saturation_weight * np.nan_to_num(sat))
    parts = {"metric_mean": float(np.nanmean(np.where(failed, np.nan, vals))) if (~failed).any() else float("nan"),
             "failed": int(failed.sum())}  # fmt: skip
    if t.min_phase_margin_deg > 0.0:
        stable = np.asarray(rows["margin_stable"], dtype=float) > 0.5
        pm = np.asarray(rows["pm_min_deg"], dtype=float)
        short = ~stable | ~(pm >= t.min_phase_margin_deg)
        per = per + np.where(short, t.margin_penalty, 0.0)
        parts["below_margin"] = int(short.sum())
    return float(per.mean()), parts


def tune(
    t: Tuning, workers: int | None = None, scheduler: str | None = None, trials: int | None = None,
    backend: str = "compiled", log: Callable[[str], None] = lambda m: None, scheduler_file: str | Path | None = None,
    connect_timeout: float | None = None, wait_workers: float | None = None,
) -> dict[str, Any]:  # fmt: skip
    """Search the gains; returns the best parameters, cost and every trial with its cost components. Where
    the flights run: ``workers``, ``scheduler``, ``scheduler_file``, ``connect_timeout``, ``wait_workers``
    as for :class:`~vtol_impedance.sweeps.cluster.Executor`."""
    from . import cluster

    n_trials = t.trials if trials is None else int(scalar("--trials", trials, lo=1, hi=100_000, integer=True))
    records: list[dict[str, Any]] = []
    try:
        lower = {a.key: a.grid()[0] if a.values else a.lo for a in t.search}
        warm_up(from_dict(t.trial_sweep(lower), t.where, base=t.base), backend)
    except DesignError:
        pass  # the lower corner has no robust design: the first trial that has one compiles
    executor = Executor(
        workers, scheduler, scheduler_file,
        cluster.CONNECT_TIMEOUT_S if connect_timeout is None else connect_timeout,
        cluster.WAIT_WORKERS_S if wait_workers is None else wait_workers, log=log,
    )  # fmt: skip
    if executor.note:
        log(f"note: {executor.note}")
    with executor as ex:
        if ex.distributed:
            ex.warm_workers(from_dict(t.trial_sweep(lower), t.where, check_points=False, base=t.base), backend)

        def objective(params: dict[str, float]) -> float:
            desc = t.trial_sweep(params)
            sweep = from_dict(desc, t.where, check_points=False, base=t.base)
            rows: dict[str, list] = {}
            try:  # no retries: a trial that fails (no robust design) fails on every try
                for _, r, _ in ex.map_chunks(sweep, list(range(sweep.n_chunks)), backend, retries=0):
                    for k, v in r.items():
                        rows.setdefault(k, []).extend(v)
            except (InputError, cluster.ChunkError) as exc:  # a DesignError among the first
                # gains no bandwidth keeps stable on some plant, or values valid alone that no scenario takes
                # together (a filter too fast for a control rate, inside the box whose corners were checked):
                # a failed trial, not a stop after the work has begun. On Dask the input's error comes back
                # named in a ChunkError; any other failure there still stops the tuning.
                if isinstance(exc, cluster.ChunkError) and not all(_input_error(f[2]) for f in exc.failures):
                    raise
                cost = float(t.failure_penalty)
                why = str(exc).split(": ", 1)[-1] if isinstance(exc, DesignError) else f"invalid: {exc}"
                records.append({**params, "cost": cost, "metric_mean": float("nan"), "failed": sweep.n_flights,
                                "no_design": why[:200]})  # fmt: skip
                return cost
            cost, parts = trial_cost(t, rows)
            records.append({**params, "cost": cost, **parts, "no_design": ""})
            return cost

        clock = Progress(n_trials, "trials", enabled=False)  # measures the time left; the line is ours

        def progress(i: int, params: dict[str, float], value: float) -> None:
            best = min(r["cost"] for r in records)
            clock()
            log(f"  trial {i}/{n_trials}: cost {value:.4g} (best {best:.4g}), {minutes(clock.left_s())} left")

        best, value, _ = optimize(t.search, objective, n_trials, t.seed, progress)
    return {"best": best, "cost": value, "trials": records}


def best_scenario_toml(t: Tuning, best: dict[str, Any]) -> str:
    """A scenario file: the base, the fixed overrides and the best values (vectors written whole)."""
    from .spec import set_param

    spec = t.base_spec()
    fixed = _dotted(t.data.get("set", {}))
    for k, v in best.items():
        spec = set_param(spec, k, v)
    keys = []
    for k in [*fixed, *best]:
        m = _INDEXED.match(k)
        keys.append(m["key"] if m else k)
    base = t.data["base"]
    if base.endswith(".toml") and t.where is not None and not Path(base).is_absolute():
        base = str((t.where.parent / base).resolve())
    lines = [f"# best gains of tuning {t.name!r}, written by vtol-impedance tune", f"base = {json.dumps(base)}",
             f"name = {json.dumps(t.name + '-best-v1')}"]  # fmt: skip
    for k in dict.fromkeys(keys):
        lines.append(f"{k} = {json.dumps(get_value(spec, k))}")
    return "\n".join(lines) + "\n"


def trials_csv(records: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    if records:
        w = csv.DictWriter(buf, fieldnames=list(dict.fromkeys(k for r in records for k in r)))
        w.writeheader()
        w.writerows(records)
    return buf.getvalue()
