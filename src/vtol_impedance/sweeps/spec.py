"""Sweep specifications: a base scenario, fixed overrides, axes over any scenario value, controllers and
seeds; resolved into a fixed list of flight units before any work starts. Every flight row also carries
the controller's stability margins at the point (``margins = true``, the default; about 0.3 s per point
and controller, once per point whatever the seeds).

A sweep file (TOML)::

    name = "rate-vs-bandwidth"            # also the default output folder: results/sweep-<name>
    base = "case-b-fan"                   # a registered scenario or a scenario file (relative to this file)
    controllers = ["pd", "pdc"]           # every point is flown with each, on the same noise
    seeds = 3                             # repetitions per point (sensor noise, turbulence)
    seed = 2026                           # the sweep seed
    mode = "grid"                         # grid (all combinations), zip (axes side by side), random
    samples = 40                          # random mode: how many points
    chunk = 8                             # units (point x seed) per chunk of work
    traces = 0                            # keep every K-th control tick of |e_p| and the estimate (0: none)
    measures = false                      # also the flight outcome of an interaction (settling, push, wall)
    margins_at = "window"                 # margins at the task window's start, or "engaged" (comply on)
    [set]                                 # fixed overrides of the base
    duration = 20.0
    [axes]
    "control.rate" = [20, 50, 100, 200, 500]                       # values
    "control.estimator_wn" = {min = 2.0, max = 40.0, n = 8, log = true}   # a range
    "payload.offset_B[0]" = {min = 0.0, max = 0.05, n = 6}         # one component of a vector value
    "plant.rotor_tau_up,plant.rotor_tau_down" = [[0.01, 0.02], [0.02, 0.04]]   # keys that move together

A range gives ``n`` values (grid, zip) or the interval to draw from (random, log-uniform with
``log = true``); a list is used as is (grid, zip) or drawn from (random).

A *unit* is one point flown with every controller under one seed: one batch of the engine, sharing the
disturbance realisation and the sensor noise, as ``simulate`` does. Its seed is derived from the sweep
seed and the unit's indices only (``SeedSequence(seed, spawn_key=(point, repeat))``), so the results do
not depend on how the units are cut into chunks or spread over workers.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

from ..control.impedance import VARIANTS
from ..errors import InputError, ScenarioError, check_keys, flag, instance, path_like, scalar
from ..estimator.momentum import EstimatorBandwidthWarning
from ..io import read_toml
from ..scenarios import get, load_toml, set_value
from ..scenarios.spec import ScenarioSpec, _dotted, check, check_name, keys_overlap

MODES = ("grid", "zip", "random")
KEYS = ("name", "description", "base", "controllers", "seeds", "seed", "mode", "samples", "chunk", "traces",
        "max_flights", "margins", "margins_at", "measures", "set", "axes")  # fmt: skip
#: Where a sweep takes each point's margins (``margins_at``): the start of the task window (as the
#: ``margins`` command), or where the comply fractions first reach their largest value in the window
#: (a scenario that switches comply on once airborne would otherwise be checked with comply off).
MARGINS_AT = ("window", "engaged")
MAX_FLIGHTS = 200_000
#: Most points one sweep file lists, whatever ``max_flights`` says: its points are built as one list before
#: any other check (9 million took 1.9 GB and 39 s before the 10-minute budget refused them); split a
#: larger study into several sweeps.
MAX_POINTS = 1_000_000


def set_param(spec: ScenarioSpec, key: str, value: Any) -> ScenarioSpec:
    """``set_value`` (which takes one component of a vector value, ``payload.offset_B[0]``) plus joint
    keys: ``"plant.rotor_tau_up,plant.rotor_tau_down"`` set from a list of as many values."""
    instance("spec", spec, ScenarioSpec)
    instance("key", key, str)
    if "," in key:
        keys = [k.strip() for k in key.split(",")]
        if not isinstance(value, list | tuple) or len(value) != len(keys):
            raise ScenarioError(f"{key}: a joint axis takes {len(keys)} values per point, got {value!r}")
        for k, v in zip(keys, value, strict=True):
            spec = set_param(spec, k, v)
        return spec
    return set_value(spec, key, value)


@dataclass(frozen=True)
class Axis:
    """One axis of a sweep: the scenario value ``key`` (``"control.rate"``, ``"payload.offset_B[0]"``) and
    either explicit ``values`` or a range ``lo`` .. ``hi`` with ``n`` values (geometric with ``log``);
    random sweeps draw from the range. :meth:`grid` lists the values, :meth:`draw` draws one."""

    key: str
    values: tuple[Any, ...] | None = None  # explicit values
    lo: float | None = None
    hi: float | None = None
    n: int | None = None
    log: bool = False

    def __post_init__(self) -> None:
        instance("key", self.key, str)
        flag("log", self.log)
        if self.values is None and (self.lo is None or self.hi is None):
            raise InputError(f"axis {self.key!r}: give values, or a range lo .. hi")
        if self.lo is not None:
            scalar("lo", self.lo, lo=0.0 if self.log else None, lo_open=self.log)
        if self.hi is not None:
            scalar("hi", self.hi, lo=0.0 if self.log else None, lo_open=self.log)
        if self.n is not None:
            scalar("n", self.n, lo=1, integer=True)

    def grid(self) -> list[Any]:
        """The axis's values in grid and zip mode."""
        if self.values is not None:
            return list(self.values)
        assert self.lo is not None and self.hi is not None and self.n is not None
        if self.log:
            return [float(v) for v in np.geomspace(self.lo, self.hi, self.n)]
        return [float(v) for v in np.linspace(self.lo, self.hi, self.n)]

    def draw(self, rng: np.random.Generator) -> Any:
        """One value drawn with ``rng`` (random mode): uniform over the range (in log with ``log``) or one of
        the values."""
        if self.values is not None:
            return self.values[int(rng.integers(len(self.values)))]
        assert self.lo is not None and self.hi is not None
        if self.log:
            return float(math.exp(rng.uniform(math.log(self.lo), math.log(self.hi))))
        return float(rng.uniform(self.lo, self.hi))


def _axis(key: str, raw: Any, mode: str) -> Axis:
    if isinstance(raw, list):
        if not raw:
            raise InputError(f"axis {key!r} is empty: give at least one value")
        return Axis(key, values=tuple(raw))
    if isinstance(raw, dict):
        check_keys(f"axis {key!r}", raw, ("min", "max", "n", "log"))
        if "min" not in raw or "max" not in raw:
            raise InputError(f"axis {key!r}: a range needs min and max, got {raw}")
        log = raw.get("log", False)
        if not isinstance(log, bool):
            raise InputError(f"axis {key!r}: log must be true or false, got {log!r}")
        lo = scalar(f"axis {key!r} min", raw["min"])
        hi = scalar(f"axis {key!r} max", raw["max"])
        if not lo <= hi:
            raise InputError(f"axis {key!r}: min {lo} is above max {hi}")
        if log and lo <= 0:
            raise InputError(f"axis {key!r}: a log range needs min > 0, got {lo}")
        n = raw.get("n")
        if mode != "random":
            if n is None:
                raise InputError(f"axis {key!r}: a range in {mode} mode needs n (how many values)")
            n = int(scalar(f"axis {key!r} n", n, lo=1, hi=10_000, integer=True))
        return Axis(key, lo=float(lo), hi=float(hi), n=n, log=log)
    raise InputError(f"axis {key!r} must be a list of values or a range table {{min, max, n}}, got {raw!r}")


@dataclass(frozen=True)
class Unit:
    """One point flown with every controller under one seed."""

    index: int
    point: int
    repeat: int
    seed: int


@dataclass
class Sweep:
    """A resolved sweep: the base scenario with its fixed overrides, the points, the units."""

    name: str
    description: str
    base: ScenarioSpec
    controllers: list[str]
    axes: list[Axis]
    points: list[dict[str, Any]]
    seeds: int
    seed: int
    chunk: int
    traces: int
    source: dict[str, Any] = field(default_factory=dict)
    margins: bool = True  # margin columns in every flight row
    margins_at: str = "window"  # see MARGINS_AT
    measures: bool = False  # outcome columns (settling, push, wall contact): flights logged decimated
    fast_estimator_points: list[int] = field(default_factory=list)  # |p| Ts > 0.5: noise barely filtered
    #: The base's vehicle file (``vehicle = "my_quad.toml"``) as read here: ``{"path": ..., "text": ...}``;
    #: a worker flies this text, and its content is part of the hash.
    vehicle_file: dict[str, str] = field(default_factory=dict)

    @property
    def units(self) -> list[Unit]:
        return [
            Unit(i * self.seeds + r, i, r, unit_seed(self.seed, i, r))
            for i in range(len(self.points))
            for r in range(self.seeds)
        ]

    @property
    def n_flights(self) -> int:
        return len(self.points) * self.seeds * len(self.controllers)

    @property
    def n_chunks(self) -> int:
        return -(-len(self.points) * self.seeds // self.chunk)

    def chunk_units(self, k: int) -> list[Unit]:
        """The units of chunk ``k`` (the same as ``units[k * chunk : (k + 1) * chunk]``, without the others)."""
        n = len(self.points) * self.seeds
        return [
            Unit(i, i // self.seeds, i % self.seeds, unit_seed(self.seed, i // self.seeds, i % self.seeds))
            for i in range(k * self.chunk, min(n, (k + 1) * self.chunk))
        ]

    def task(self, k: int) -> Sweep:
        """What chunk ``k``'s task carries to a worker: this resolved sweep (the base scenario's values, not
        a file name) with only that chunk's points (``None`` for the others) and without its source text,
        so that a task's size does not grow with the sweep."""
        keep = {u.point for u in self.chunk_units(k)}
        points = [p if i in keep else None for i, p in enumerate(self.points)]
        return replace(self, points=points, source={})  # type: ignore[arg-type]

    def point_spec(self, i: int) -> ScenarioSpec:
        spec = self.base
        for key, value in self.points[i].items():
            spec = set_param(spec, key, value)
        return spec

    def to_dict(self) -> dict[str, Any]:
        """Everything that determines the results (hashed for resuming)."""
        return (
            {
                "name": self.name,
                "description": self.description,
                "base": self.base.to_dict(),
                "controllers": self.controllers,
                "axes": [a.key for a in self.axes],
                "points": self.points,
                "seeds": self.seeds,
                "seed": self.seed,
                "chunk": self.chunk,
                "traces": self.traces,
                "margins": self.margins,
            }
            | ({"vehicle_file": _vehicle_content(self.vehicle_file)} if self.vehicle_file else {})
            | ({"margins_at": self.margins_at} if self.margins_at != "window" else {})
            | ({"measures": True} if self.measures else {})
        )  # absent at their defaults: older folders resume

    def digest(self) -> str:
        """The content hash: SHA-256 of :meth:`to_dict`, the resolved scenario (a base file's content, not
        its path) and every point, seed and option; recorded in ``sweep.json`` and in every chunk."""
        return hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True, default=str).encode()).hexdigest()


def changes(old: Any, new: Any, path: str = "", limit: int = 5) -> list[str]:
    """What differs between two resolved sweep descriptions (:meth:`Sweep.to_dict`), as
    ``"base.payload.mass: 0.1 -> 0.3"`` lines (the first ``limit``), for a refusal that names the change."""
    out: list[str] = []

    def walk(a: Any, b: Any, where: str) -> None:
        if len(out) >= limit:
            return
        if isinstance(a, dict) and isinstance(b, dict):
            for k in list(a) + [k for k in b if k not in a]:
                walk(a.get(k, "(absent)"), b.get(k, "(absent)"), f"{where}.{k}" if where else str(k))
        elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
            for i, (x, y) in enumerate(zip(a, b, strict=True)):
                walk(x, y, f"{where}[{i}]")
        elif json.dumps(a, sort_keys=True, default=str) != json.dumps(b, sort_keys=True, default=str):
            short = lambda v: t if len(t := json.dumps(v, default=str)) <= 60 else t[:57] + "..."  # noqa: E731
            out.append(f"{where or '(whole)'}: {short(a)} -> {short(b)}")

    walk(old, new, path)
    return out


def unit_seed(sweep_seed: int, point: int, repeat: int) -> int:
    """The seed of a unit: from the sweep seed and the unit's indices only."""
    for name, v in (("sweep_seed", sweep_seed), ("point", point), ("repeat", repeat)):
        scalar(name, v, lo=0, hi=2**63 - 1, integer=True)
    s = np.random.SeedSequence(int(sweep_seed), spawn_key=(int(point), int(repeat)))
    hi, lo = (int(x) for x in s.generate_state(2, np.uint32))
    return ((hi << 32) | lo) & (2**63 - 1)


def _base(data: dict[str, Any], where: Path | None) -> ScenarioSpec:
    base = data.get("base")
    if not isinstance(base, str) or not base:
        raise InputError('a sweep needs base = "<registered scenario>" or a scenario .toml path')
    if base.endswith(".toml"):
        path = Path(base)
        if not path.is_absolute() and where is not None:
            path = where.parent / path
        return load_toml(path)
    return get(base)


def from_dict(
    data: dict[str, Any], where: Path | None = None, check_points: bool = True,
    on_point: Callable[[int], None] | None = None, base: ScenarioSpec | None = None,
) -> Sweep:  # fmt: skip
    """Validate a sweep description and resolve its points (see the module docstring); ``on_point(1)``
    is called after each point is checked (progress: a check designs the point's controller). ``base``,
    when given, is the already resolved base scenario (its file is then not read again)."""
    instance("data", data, dict)
    check_keys("sweep", data, KEYS)
    name = check_name(data.get("name", "sweep"))
    base = _base(data, where) if base is None else instance("base", base, ScenarioSpec)
    fixed = data.get("set", {})
    if not isinstance(fixed, dict):
        raise InputError(f"[set] must be a table of scenario values, got {fixed!r}")
    for key, value in _dotted(fixed).items():
        if key == "seed":
            raise InputError("[set] seed: the sweep sets each flight's seed itself (from 'seed' and 'seeds')")
        base = set_param(base, key, value)
    ctrls = data.get("controllers", ["pdc"])
    if isinstance(ctrls, str):
        ctrls = [ctrls]
    if (
        not isinstance(ctrls, list)
        or not ctrls
        or any(not isinstance(c, str) or c not in VARIANTS for c in ctrls)
        or len(set(ctrls)) != len(ctrls)
    ):
        raise InputError(f"controllers must be a list of distinct names from {', '.join(VARIANTS)}, got {ctrls!r}")
    mode = data.get("mode", "grid")
    if mode not in MODES:
        raise InputError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    seeds = int(scalar("seeds", data.get("seeds", 1), lo=1, hi=10_000, integer=True))
    seed = int(scalar("seed", data.get("seed", 0), lo=0, hi=2**63 - 1, integer=True))
    chunk = int(scalar("chunk", data.get("chunk", 8), lo=1, hi=100_000, integer=True))
    traces = int(scalar("traces", data.get("traces", 0), lo=0, hi=1_000_000, integer=True))
    max_flights = int(scalar("max_flights", data.get("max_flights", MAX_FLIGHTS), lo=1, integer=True))
    margins = data.get("margins", True)
    if not isinstance(margins, bool):
        raise InputError(f"margins must be true or false, got {margins!r}")
    margins_at = data.get("margins_at", "window")
    if margins_at not in MARGINS_AT:
        raise InputError(f"margins_at must be one of {', '.join(MARGINS_AT)}, got {margins_at!r}")
    measures = data.get("measures", False)
    if not isinstance(measures, bool):
        raise InputError(f"measures must be true or false, got {measures!r}")
    raw_axes = data.get("axes", {})
    if not isinstance(raw_axes, dict) or not raw_axes:
        raise InputError("a sweep needs [axes]: at least one scenario value to vary")
    axes = [_axis(k, v, mode) for k, v in raw_axes.items()]
    distinct_keys({"axis": axes}, fixed)
    for a in axes:
        if "seed" in (k.strip() for k in a.key.split(",")):
            raise InputError(
                f"axis {a.key!r}: the sweep sets each flight's seed itself (from 'seed' and 'seeds'), so seed "
                "cannot be an axis; raise 'seeds' for more repeats"
            )
    for a in axes:  # unknown keys fail here, before any flight
        set_param(base, a.key, a.grid()[0] if mode != "random" else a.draw(np.random.default_rng(0)))
    if mode == "grid":
        n_points = int(np.prod([len(a.grid()) for a in axes], dtype=float))
    elif mode == "zip":
        n_points = len(axes[0].grid())
    else:
        n_points = int(scalar("samples", data.get("samples", 0), lo=1, hi=MAX_POINTS, integer=True))
    n_flights = n_points * seeds * len(ctrls)
    if n_points > MAX_POINTS:
        raise InputError(
            f"the sweep has {n_points} points, above the {MAX_POINTS} one sweep file can list (each is built "
            "and checked before the first flight); split it into several sweeps"
        )
    if n_flights > max_flights:  # before the points are built: a huge grid is refused, not allocated
        raise InputError(
            f"the sweep has {n_flights} flights ({n_points} points x {seeds} seeds x {len(ctrls)} "
            f"controllers), above max_flights = {max_flights}; raise max_flights in the sweep file if this is meant"
        )
    if mode == "grid":
        points = [dict(zip([a.key for a in axes], combo, strict=True)) for combo in product(*(a.grid() for a in axes))]
    elif mode == "zip":
        lengths = {a.key: len(a.grid()) for a in axes}
        if len(set(lengths.values())) != 1:
            raise InputError(f"zip mode needs axes of equal length, got {lengths}")
        points = [
            dict(zip([a.key for a in axes], combo, strict=True))
            for combo in zip(*(a.grid() for a in axes), strict=True)
        ]
    else:
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2**31,)))
        points = [{a.key: a.draw(rng) for a in axes} for _ in range(n_points)]
    description = instance("description", data.get("description", ""), str)
    sweep = Sweep(name, description, base, list(ctrls), axes, points, seeds, seed, chunk, traces,
                  source=data, margins=margins, margins_at=margins_at, measures=measures,
                  vehicle_file=_read_vehicle(base.vehicle))  # fmt: skip
    if check_points:
        for i in range(len(points)):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", EstimatorBandwidthWarning)
                try:
                    check(sweep.point_spec(i), ctrls)
                except InputError as exc:  # keeps its kind (a DesignError is a property of the gains)
                    raise type(exc)(f"point {i} ({_fmt_point(points[i])}): {exc}") from None
            if any(issubclass(w.category, EstimatorBandwidthWarning) for w in caught):
                sweep.fast_estimator_points.append(i)
            if on_point is not None:
                on_point(1)
    return sweep


def _read_vehicle(vehicle: str) -> dict[str, str]:
    """The base's vehicle file, read once here (a preset name: nothing to read)."""
    if not vehicle.endswith(".toml"):
        return {}
    try:
        return {"path": vehicle, "text": Path(vehicle).read_text(encoding="utf-8-sig")}
    except OSError as exc:
        raise InputError(f"cannot read the vehicle file {vehicle}: {exc.strerror or exc}") from None


def _vehicle_content(vehicle_file: dict[str, str]) -> dict[str, Any]:
    """A vehicle file's path and parsed values (what the hash covers, and what a refusal names)."""
    import tomllib

    try:
        values: Any = tomllib.loads(vehicle_file["text"])
    except tomllib.TOMLDecodeError:
        values = vehicle_file["text"]
    return {"path": vehicle_file["path"], "values": values}


def _fmt_point(p: dict[str, Any]) -> str:
    return ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}" for k, v in p.items())


def distinct_keys(groups: dict[str, list[Axis]], fixed: Any = None) -> None:
    """Every scenario value set in one place only, among ``fixed`` (the ``[set]`` table) and the axes of
    ``groups`` (joint axes count each of their keys): a second place would silently override the first
    (two axes over one key label flights by values they never flew)."""
    seen: dict[str, str] = {}

    def overlap(k: str) -> str | None:
        """A key set before that ``k`` would override or lose: itself, or a vector and one of its entries;
        but an axis over one entry of a vector ``[set]`` gives whole is that vector with the entry varied."""
        for s in seen:
            if keys_overlap(s, k) and (s == k or not (seen[s] == "[set]" and "[" not in s)):
                return s
        return None

    if isinstance(fixed, dict):
        seen.update({k: "[set]" for k in _dotted(fixed)})
    for group, axes in groups.items():
        for a in axes:
            for k in (x.strip() for x in a.key.split(",")):
                other = overlap(k)
                if other is not None:
                    also = "" if other == k else f" (as {other!r})"
                    raise InputError(
                        f"{group} {a.key!r} sets {k!r}, which {seen[other]} sets too{also}: set each value in one "
                        "place (one would silently override the other)"
                    )
                seen[k] = f"{group} {a.key!r}"


def load(path_or_name: str | Path, check_points: bool = True, on_point: Callable[[int], None] | None = None) -> Sweep:
    """A sweep file, or the name of a built-in study (see :func:`builtin_names`); ``check_points=False``
    skips checking every point's scenario (which designs the controllers: work, see ``sweeps.budget``)."""
    path_like("path_or_name", path_or_name)
    path = Path(path_or_name)
    if not path.suffix and not os.path.lexists(path):  # a link loop is a path, named as such below
        path = _BUILTIN / f"{path_or_name}.toml"
        if not path.exists():
            raise InputError(f"unknown sweep {path_or_name!r}; built-in studies: {', '.join(builtin_names())}")
    data = read_toml(path, "sweep file")
    return from_dict(data, where=path, check_points=check_points, on_point=on_point)


_BUILTIN = Path(__file__).resolve().parent / "studies"


def builtin_names() -> list[str]:
    """Names of the studies shipped with the package (``vtol-impedance sweep NAME``)."""
    return sorted(p.stem for p in _BUILTIN.glob("*.toml"))
