"""Scenario specification: plain, typed, frozen sections that map one-to-one onto TOML tables.

A scenario says what is flown (trajectory), what the true vehicle is (payload, plant effects, sensors),
what pushes on it (disturbances) and how it is controlled (gains, rates). ``ideal = true`` removes every
effect the controller does not model except the payload *mass* and the listed disturbances, for checks
against analytic numbers.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import re
import tomllib
import typing
import warnings
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np

from ..control.gains import Impedance, ImpedanceGains
from ..control.impedance import ATTITUDE_FILTER_WN, PAPER_KI, VARIANTS, ControllerParams, compile_controllers
from ..control.reference import Circle, FigureEight, Hold, MinJerk, Trajectory
from ..errors import InputError, ScenarioError, as_finite, flag, instance, scalar
from ..estimator.momentum import EstimatorParams
from ..model.mixer import THRUST_SHIFT_MAX
from ..model.vehicle import load_preset
from ..robust.design import DesignError, Timing, design
from ..sim.disturbances import Disturbance, from_dict
from ..sim.plant import PlantParams
from ..sim.sensors import SensorParams

Vec3 = tuple[float, float, float]


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _check_fields(obj: Any) -> None:
    """Refuse a section's value of the wrong type (or a number outside the range its ``_positive`` and
    ``_nonneg`` fields name), naming the field: a spec is checked where it is made, not mid-run."""
    pos, nonneg = getattr(obj, "_positive", ()), getattr(obj, "_nonneg", ())
    for f in fields(obj):
        hint, v, name = _hints(type(obj))[f.name], getattr(obj, f.name), f.name
        if hint is bool:
            flag(name, v)
        elif hint is str:
            instance(name, v, str)
        elif hint is int:
            scalar(name, v, lo=0 if name in nonneg else None, integer=True)
        elif hint in (float, float | None) or hint in (Vec3, float | Vec3):
            if v is None and hint is not float:
                continue
            arr = as_finite(name, v)
            shapes = {float: ((),), float | None: ((),), Vec3: ((3,),)}.get(hint, ((), (3,)))
            if arr.shape not in shapes:
                raise InputError(
                    f"{name} must be {' or '.join('one number' if s == () else '3 numbers' for s in shapes)}, got {v!r}"
                )
            if name in pos and not np.all(arr > 0):
                raise InputError(f"{name} must be > 0, got {v!r}")
            if name in nonneg and not np.all(arr >= 0):
                raise InputError(f"{name} must be >= 0, got {v!r}")
        elif dataclasses.is_dataclass(hint):
            instance(name, v, hint)


@dataclass(frozen=True)
class TrajectorySpec:
    """Take-off, the task (hover, circle or figure-eight), optional landing. Times in s, distances in m.

    ``kind = "figure-eight"`` flies a lemniscate of Gerono (:class:`~vtol_impedance.control.reference.FigureEight`)
    with the circle's fields: ``circle_radius`` its half length along x (it is half as wide), ``circle_speed``
    its speed at the crossing (the fastest point; the mean is 0.686 of it), ``circle_laps`` how many eights,
    ``circle_ramp`` the speed ramps.

    The run starts on the ground (z = 0) or, with ``start_on_ground = false``, hovering at the altitude.
    ``yaw_step_time < 0`` disables the yaw step.
    """

    kind: str = "hover"
    altitude: float = 1.0
    start_on_ground: bool = True
    takeoff_at: float = 1.0
    takeoff_duration: float = 4.0
    hover_duration: float = 25.0
    circle_radius: float = 1.0
    circle_speed: float = 0.5
    circle_laps: float = 2.0
    circle_ramp: float = 2.0
    settle_duration: float = 3.0
    land: bool = False
    land_duration: float = 4.0
    land_hold: float = 2.0
    yaw: float = 0.0
    yaw_step_time: float = -1.0
    yaw_step_angle: float = 0.5
    move_offset: Vec3 = (0.0, 0.0, 0.0)  # after the hover: a minimum-jerk move by this much (NED, m)
    move_duration: float = 3.0
    move_hold: float = 5.0  # then hold there, s

    _positive: ClassVar[tuple[str, ...]] = ("takeoff_duration", "circle_radius", "land_duration", "move_duration")
    _nonneg: ClassVar[tuple[str, ...]] = ("takeoff_at", "hover_duration", "settle_duration", "land_hold", "move_hold")

    def __post_init__(self) -> None:
        _check_fields(self)


@dataclass(frozen=True)
class PayloadSpec:
    """An unmodelled payload: true mass (kg) at ``offset_B`` (m, FRD) from the body origin."""

    mass: float = 0.110
    offset_B: Vec3 = (0.01, 0.0, 0.03)

    _nonneg: ClassVar[tuple[str, ...]] = ("mass",)

    def __post_init__(self) -> None:
        _check_fields(self)


#: The isotropic linear drag (N per m/s) a scenario flies when the vehicle describes none (DESIGN.md, section 4).
ROTOR_DRAG_STAND_IN = 0.18


@dataclass(frozen=True)
class PlantSpec:
    """True-plant effects the controller does not know (see :class:`~vtol_impedance.sim.plant.PlantParams`).

    ``rotor_drag`` (N per m/s, isotropic) left at ``None`` (``"auto"`` in a file or ``--set``) flies the
    vehicle's own rotor drag and inflow damping when its description gives them, else the stand-in
    :data:`ROTOR_DRAG_STAND_IN`; a number replaces them, and is refused for a vehicle that describes its own.
    """

    inertia_scale: Vec3 = (1.15, 1.15, 0.9)
    arm_length_scale: float = 1.0
    drag_factor_scale: float = 1.1
    rotor_tau_up: float = 0.0125
    rotor_tau_down: float = 0.025
    rotor_drag: float | None = None
    rotor_limits: bool = True
    ground: bool = True
    pendulum_mass: float = 0.0  # kg on a rigid link hung from the centre of mass (0: none)
    pendulum_length: float = 0.5  # m

    _positive: ClassVar[tuple[str, ...]] = ("inertia_scale", "arm_length_scale", "drag_factor_scale", "pendulum_length")
    _nonneg: ClassVar[tuple[str, ...]] = ("rotor_tau_up", "rotor_tau_down", "rotor_drag", "pendulum_mass")

    def __post_init__(self) -> None:
        _check_fields(self)


@dataclass(frozen=True)
class ControlSpec:
    """Controller and estimator settings.

    The position impedance (``Kp``, ``Dp``, and ``Ki`` for PID) and the rate are the paper's (Sec. VI.A-B).
    The bandwidths left at ``None`` (``"design"`` in a file or ``--set``) are chosen by
    :func:`vtol_impedance.robust.design` for the nominal vehicle, the position impedance and the timing
    the controller assumes, so that the margins hold (README, "Stability margins"); a number sets one by
    hand. :data:`PAPER_CONTROL` is the paper's own choice (``vtol-impedance paper`` flies it).

    ``wn_o``, ``wn_o_yaw``: attitude bandwidths (roll/pitch, yaw), rad/s, ``zeta_o`` their damping;
    ``estimator_wn``: the estimator's bandwidth (rad/s), and of its moment channels too unless
    ``estimator_wn_moment`` sets theirs (the moment estimate is fed forward inside the attitude loop,
    whose margin a fast one costs; the force estimate is what rejects a gust: :mod:`.tracking`);
    ``estimator_timing``: align the estimator to the latencies the controller assumes and pass its
    commands through the rotor model (:mod:`vtol_impedance.estimator.momentum`, "Timing");
    ``reference_timing``: compare the measured position and velocity with the reference of the instant
    they were measured (``velocity_delay`` ago; the feed-forward acceleration is today's), so that a
    trajectory is not tracked a latency late (``ControllerParams.reference_delay``; margins unchanged);
    ``velocity_delay``, ``attitude_delay``: those latencies (s; ``None``: the sensor model's, as a real
    system reads them off its timestamps); ``rotor_tau``: the rotors' nominal time constant (s), what the
    controller assumes (the true plant's are ``plant.rotor_tau_up``/``down``).
    """

    rate: float = 100.0
    Kp: float | Vec3 = 16.0
    Dp: float | Vec3 = 12.0
    Ki: float | Vec3 = PAPER_KI
    wn_o: float | None = None
    wn_o_yaw: float | None = None
    zeta_o: float = 1.0
    estimator_wn: float | None = None
    estimator_wn_moment: float | None = None
    estimator_zeta: float = 1.0
    estimator_order: int = 2
    estimator_prototype: str = "zeta"
    estimator_timing: bool = True
    reference_timing: bool = False
    attitude_filter_wn: float | None = None
    velocity_delay: float | None = None
    attitude_delay: float | None = None
    rotor_tau: float = 0.019
    tilt_max_deg: float = 35.0
    integral_limit: float = 3.0
    thrust_shift_max: float = THRUST_SHIFT_MAX

    _positive: ClassVar[tuple[str, ...]] = (
        "rate", "Kp", "Dp", "zeta_o", "estimator_zeta", "tilt_max_deg", "wn_o", "wn_o_yaw", "estimator_wn",
        "attitude_filter_wn", "estimator_wn_moment",
    )  # fmt: skip
    _nonneg: ClassVar[tuple[str, ...]] = (
        "Ki", "rotor_tau", "integral_limit", "thrust_shift_max", "estimator_order", "velocity_delay", "attitude_delay",
    )  # fmt: skip

    def __post_init__(self) -> None:
        _check_fields(self)


#: The paper's controller (Sec. VI.A; the attitude filter's bandwidth, which the paper does not give, is
#: this project's earlier default): what ``vtol-impedance paper`` flies, as ``--set`` assignments.
PAPER_CONTROL: dict[str, Any] = {
    "control.wn_o": 8.0,
    "control.wn_o_yaw": 8.0,
    "control.attitude_filter_wn": ATTITUDE_FILTER_WN,
    "control.estimator_wn": 10.0,
    "control.estimator_timing": False,
}
#: Control settings chosen by the design when left at ``None``.
DESIGNED = ("wn_o", "wn_o_yaw", "attitude_filter_wn", "estimator_wn")


AXES = ("x", "y", "z", "roll", "pitch", "yaw")
BEHAVIOURS = {"reject": 0.0, "comply": 1.0}


@dataclass(frozen=True)
class InteractionSpec:
    """Impedance of the ``comply`` controller per world axis (``M`` kg, ``D`` N s/m, ``K`` N/m) and per
    Euler angle (``M_o`` kg m^2, ``D_o`` N m s/rad, ``K_o`` N m/rad) and its behaviour: ``comply`` and
    ``comply_attitude`` give the initial fraction per world axis and per Euler angle (1 yields with the
    impedance, 0 rejects like PD+C), ``switches`` changes them in flight, ``[[time_s, axis, "comply"|
    "reject"], ...]`` with axis one of x, y, z, roll, pitch, yaw, each ramped over ``blend_s`` seconds so
    that the commands never jump."""

    M: float | Vec3 = 2.0
    D: float | Vec3 = 6.0
    K: float | Vec3 = 5.0
    M_o: float | Vec3 = 0.01
    D_o: float | Vec3 = 0.04
    K_o: float | Vec3 = 0.04
    comply: Vec3 = (1.0, 1.0, 1.0)
    comply_attitude: Vec3 = (0.0, 0.0, 0.0)
    switches: tuple[tuple[float, str, str], ...] = ()
    blend_s: float = 0.5

    _positive: ClassVar[tuple[str, ...]] = ("M", "M_o")
    _nonneg: ClassVar[tuple[str, ...]] = ("D", "K", "D_o", "K_o", "blend_s")

    def __post_init__(self) -> None:
        _check_fields(self)


def _real(value: Any) -> float | None:
    """``value`` as a finite float when it is a real number (not a boolean), else None (an integer beyond
    any float, 10**400, included: NumPy could not even test it)."""
    if not isinstance(value, numbers.Real) or isinstance(value, bool | np.bool_):  # NumPy's numbers are Real
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def parse_switches(value: Any) -> tuple[tuple[float, str, str], ...]:
    """Validate ``[[time_s, axis, behaviour], ...]`` naming what is wrong."""
    if not isinstance(value, list | tuple):
        raise ScenarioError(f"interaction.switches must be a list of [time_s, axis, behaviour], got {value!r}")
    out = []
    for sw in value:
        if not isinstance(sw, list | tuple) or len(sw) != 3:
            raise ScenarioError(f"an interaction switch is [time_s, axis, behaviour], got {sw!r}")
        t, axis, beh = sw
        t_s = _real(t)
        if t_s is None or t_s < 0:
            raise ScenarioError(f"interaction switch time must be a finite number >= 0 s, got {str(t)[:40]}")
        if axis not in AXES:
            raise ScenarioError(
                f"interaction switch axis {axis!r} does not exist; the axes are x, y, z (world NED) and roll, "
                "pitch, yaw (Euler angles)"
            )
        if beh not in BEHAVIOURS:
            raise ScenarioError(f"interaction switch behaviour {beh!r} is not one of {', '.join(BEHAVIOURS)}")
        out.append((t_s, str(axis), str(beh)))
    return tuple(out)


@dataclass(frozen=True)
class ScenarioSpec:
    """A scenario: everything a flight needs but the controller variant, as plain values.

    ``name`` carries a version (``case-a-payload-v1``); ``vehicle`` is a preset name or a vehicle
    ``.toml``; ``ideal`` removes every unmodelled effect except the payload mass and the listed
    disturbances; ``duration`` (s) 0 flies the trajectory's own length; ``plant_rate`` (Hz) is the RK4
    rate. The sections :class:`TrajectorySpec`, :class:`PayloadSpec`, :class:`PlantSpec`,
    ``sensors`` (:class:`~vtol_impedance.sim.SensorParams`), :class:`ControlSpec` and ``interaction``
    (what the ``comply`` variant does) are the tables of a scenario file; ``disturbances`` are its
    ``[[disturbances]]`` tables, each with a ``kind`` of :data:`vtol_impedance.sim.DISTURBANCE_KINDS`.
    Build one from a file with :func:`load_toml`, change it with :func:`set_value`, fly it with
    :func:`~vtol_impedance.scenarios.simulate`.
    """

    name: str
    description: str = ""
    vehicle: str = "pelican"
    ideal: bool = False
    seed: int = 0
    plant_rate: float = 1000.0
    duration: float = 0.0  # 0: the trajectory's own length
    trajectory: TrajectorySpec = field(default_factory=TrajectorySpec)
    payload: PayloadSpec = field(default_factory=PayloadSpec)
    plant: PlantSpec = field(default_factory=PlantSpec)
    sensors: SensorParams = field(default_factory=SensorParams)
    control: ControlSpec = field(default_factory=ControlSpec)
    interaction: InteractionSpec = field(default_factory=InteractionSpec)
    disturbances: tuple[dict[str, Any], ...] = ()

    _positive: ClassVar[tuple[str, ...]] = ("plant_rate",)
    _nonneg: ClassVar[tuple[str, ...]] = ("duration", "seed")

    def __post_init__(self) -> None:
        _check_fields(self)
        check_name(self.name)
        if not all(isinstance(d, dict) for d in self.disturbances):
            raise ScenarioError("disturbances must be a list of tables with a 'kind'")
        object.__setattr__(self, "disturbances", tuple(dict(d) for d in self.disturbances))
        for d in self.disturbances:
            from_dict(d)  # validates kinds and keys now, not mid-run

    def to_dict(self) -> dict[str, Any]:
        return _to_plain(self)


def _to_plain(v: Any) -> Any:
    """Plain dicts, lists and Python numbers (as ``dataclasses.asdict`` with tuples as lists, in one pass)."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {f.name: _to_plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
    if isinstance(v, dict):
        return {k: _to_plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_to_plain(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


# --------------------------------------------------------------------------- building


@dataclass(frozen=True)
class Built:
    """Everything :func:`~vtol_impedance.sim.loop.run_closed_loop` needs, derived from a spec."""

    plant: PlantParams
    trajectory: Trajectory
    disturbances: tuple[Disturbance, ...]
    sensors: SensorParams
    duration: float
    window: tuple[float, float]
    phases: dict[str, float]
    start_W: np.ndarray


#: The trajectory kinds (``trajectory.kind``): the task after take-off.
KINDS = ("hover", "circle", "figure-eight")


def build_trajectory(ts: TrajectorySpec) -> tuple[Trajectory, tuple[float, float], dict[str, float]]:
    """The reference of a scenario, its task window (for metrics) and named phase times."""
    if ts.kind not in KINDS:
        raise InputError(f"trajectory.kind must be one of {', '.join(KINDS)}, got {ts.kind!r}")
    hover = (0.0, 0.0, -float(ts.altitude))
    ground = (0.0, 0.0, 0.0)
    segs: list[Any] = []
    phases: dict[str, float] = {}
    t = 0.0
    if ts.start_on_ground:
        segs += [Hold(ground, ts.takeoff_at), MinJerk(ground, hover, ts.takeoff_duration)]
        t += ts.takeoff_at + ts.takeoff_duration
        phases["takeoff"] = ts.takeoff_at
    phases["hover"] = t
    segs.append(Hold(hover, ts.hover_duration))
    t += ts.hover_duration
    if np.any(np.asarray(ts.move_offset) != 0.0):
        target = tuple(float(a + b) for a, b in zip(hover, ts.move_offset, strict=True))
        segs += [MinJerk(hover, target, ts.move_duration), Hold(target, ts.move_hold)]
        phases["move"] = t
        t += ts.move_duration + ts.move_hold
        hover = target
    if ts.kind == "hover":
        window = (phases["hover"], t)
    else:
        shape = Circle if ts.kind == "circle" else FigureEight
        c = shape(hover, ts.circle_radius, ts.circle_speed, ts.circle_laps, ts.circle_ramp)
        segs.append(c)
        phases[ts.kind] = t
        window = (t, t + c.duration)
        t += c.duration
        segs.append(Hold(hover, ts.settle_duration))
        t += ts.settle_duration
    if ts.land:
        ground = (hover[0], hover[1], 0.0)
        segs += [MinJerk(hover, ground, ts.land_duration), Hold(ground, ts.land_hold)]
        phases["land"] = t
        t += ts.land_duration + ts.land_hold
    steps = ((ts.yaw_step_time, ts.yaw + ts.yaw_step_angle),) if ts.yaw_step_time >= 0 else ()
    return Trajectory(tuple(segs), yaw0=ts.yaw, yaw_steps=steps), window, phases


def build(spec: ScenarioSpec) -> Built:
    """Turn a spec into plant, trajectory, disturbances and sensors (the controller is built separately)."""
    instance("spec", spec, ScenarioSpec)
    vehicle = load_preset(spec.vehicle)
    traj, window, phases = build_trajectory(spec.trajectory)
    duration = spec.duration if spec.duration > 0 else traj.duration
    window = (min(window[0], duration), min(window[1], duration))
    ps, pl = spec.plant, spec.payload
    true_vehicle = vehicle if ps.rotor_limits else vehicle.with_rotor_limits(f_max=1e6)
    if spec.ideal:
        plant = PlantParams(
            true_vehicle.without_aero(), payload_mass=pl.mass, rotor_tau_up=0.0, rotor_tau_down=0.0, ground=ps.ground,
            pendulum_mass=ps.pendulum_mass, pendulum_length=ps.pendulum_length,
        )  # fmt: skip
        sensors = SensorParams.ideal()
    else:
        effects = {k: v for k, v in dataclasses.asdict(ps).items() if k != "rotor_limits"}
        if ps.rotor_drag is None:  # the vehicle's own, or the stand-in for a vehicle that describes none
            effects["rotor_drag"] = 0.0 if any(vehicle.linear_drag_B) else ROTOR_DRAG_STAND_IN
        plant = PlantParams(true_vehicle, payload_mass=pl.mass, payload_offset_B=pl.offset_B, **effects)
        sensors = spec.sensors
    start = np.array([0.0, 0.0, 0.0 if spec.trajectory.start_on_ground else -spec.trajectory.altitude])
    dists = tuple(from_dict(d) for d in spec.disturbances)
    it = spec.interaction
    switches = tuple((t, AXES.index(axis), BEHAVIOURS[beh]) for t, axis, beh in it.switches)
    comply0 = tuple(float(c) for c in (*it.comply, *it.comply_attitude))
    traj = replace(traj, comply0=comply0, comply_switches=switches, blend_s=it.blend_s)
    return Built(plant, traj, dists, sensors, float(duration), window, phases, start)


def assumed_timing(spec: ScenarioSpec) -> Timing:
    """The latencies and rotor time constant the scenario's controller assumes (``control.velocity_delay``,
    ``attitude_delay`` or, unset, the sensor model's; ``control.rotor_tau``)."""
    c, sens = spec.control, (SensorParams.ideal() if spec.ideal else spec.sensors)
    return Timing(
        sens.mocap_delay if c.velocity_delay is None else c.velocity_delay,
        sens.imu_delay if c.attitude_delay is None else c.attitude_delay,
        c.rotor_tau,
    )


def resolved_control(spec: ScenarioSpec) -> ControlSpec:
    """``spec.control`` with every designed bandwidth filled in (:func:`vtol_impedance.robust.design`)."""
    c = spec.control
    if all(getattr(c, k) is not None for k in DESIGNED):
        return c
    try:
        d = design(load_preset(spec.vehicle), c.Kp, c.Dp, c.rate, assumed_timing(spec))
    except DesignError as exc:  # stays a DesignError: a property of the gains (a tuning counts it as a failed trial)
        raise DesignError(
            f"{exc} (to fly it anyway, set control.wn_o, control.wn_o_yaw, control.attitude_filter_wn and "
            "control.estimator_wn by hand)"
        ) from None
    chosen = {"wn_o": d.wn_o, "wn_o_yaw": d.wn_o_yaw, "attitude_filter_wn": d.attitude_filter_wn,
              "estimator_wn": d.estimator_wn}  # fmt: skip
    return replace(c, **{k: v for k, v in chosen.items() if getattr(c, k) is None})


def controller_params(spec: ScenarioSpec, variant: str) -> ControllerParams:
    """The nominal controller of a scenario: the preset vehicle, never the true plant."""
    instance("spec", spec, ScenarioSpec)
    check_variants(variant)
    c = resolved_control(spec)
    vehicle = load_preset(spec.vehicle)
    w = np.array([c.wn_o, c.wn_o, c.wn_o_yaw])
    I = np.diag(vehicle.inertia)  # noqa: E741
    gains = ImpedanceGains(
        Kp=c.Kp, Dp=c.Dp, Ko=w**2 * I, Do=2.0 * c.zeta_o * w * I, Ki=c.Ki if variant == "pid" else 0.0
    )
    t = assumed_timing(spec)
    est = EstimatorParams(
        wn=[c.estimator_wn] * 3 + [c.estimator_wn if c.estimator_wn_moment is None else c.estimator_wn_moment] * 3,
        zeta=c.estimator_zeta,
        order=int(c.estimator_order),
        prototype=c.estimator_prototype,
        velocity_delay=t.velocity_delay if c.estimator_timing else 0.0,
        attitude_delay=t.attitude_delay if c.estimator_timing else 0.0,
        rotor_tau=t.rotor_tau if c.estimator_timing else 0.0,
    )
    return ControllerParams(
        vehicle=vehicle,
        gains=gains,
        variant=variant,
        estimator=est,
        Ts=1.0 / c.rate,
        tilt_max=float(np.radians(c.tilt_max_deg)),
        attitude_filter_wn=c.attitude_filter_wn,
        integral_limit=c.integral_limit,
        thrust_shift_max=c.thrust_shift_max,
        impedance=Impedance(**{k: getattr(spec.interaction, k) for k in ("M", "D", "K", "M_o", "D_o", "K_o")}),
        reference_delay=t.velocity_delay if c.reference_timing else 0.0,
    )


def check(spec: ScenarioSpec, variants: tuple[str, ...] | list[str] = ("pdc",)) -> Built:
    """Every check that needs more than one value, before any work: rates, duration, the controllers."""
    built, ctrls = checked(spec, variants)
    compile_controllers(ctrls)  # the estimator's bandwidth against the control period
    return built


def check_variants(variants: Any, unique: bool = False) -> list[str]:
    """``variants`` as a list of known controller names, or a clear error; ``unique``: each once (the
    command line's comparisons: a repeat is the same flight twice under one label; the API allows copies,
    a batch of identical vehicles)."""
    if not isinstance(variants, str | list | tuple):
        raise InputError(f"variants must be a controller name or a list of them, got {variants!r}")
    variants = [variants] if isinstance(variants, str) else list(variants)
    bad = [v for v in variants if not isinstance(v, str) or v not in VARIANTS]
    if bad or not variants:
        raise InputError(
            f"unknown controller variant(s) in variants: {bad or variants}; choose from {sorted(VARIANTS)}"
        )
    twice = sorted({v for v in variants if variants.count(v) > 1})
    if unique and twice:
        raise InputError(f"controller variant(s) {twice} given more than once; each is flown once per run")
    return variants


def checked(spec: ScenarioSpec, variants: tuple[str, ...] | list[str]) -> tuple[Built, list[ControllerParams]]:
    """:func:`check` without the controller design, returning what a run needs: the built scenario and one
    controller per variant (the run designs them once)."""
    if not isinstance(spec, ScenarioSpec):
        raise ScenarioError(f"spec must be a ScenarioSpec or a registered name, got {type(spec).__name__}")
    rate, plant_rate = spec.control.rate, spec.plant_rate
    ratio = plant_rate / rate
    if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ScenarioError(
            f"plant_rate ({plant_rate:g} Hz) must be a whole multiple of control.rate ({rate:g} Hz), at least 1x"
        )
    b = build(spec)
    if b.duration < 1.0 / rate:
        raise ScenarioError(f"duration {b.duration:g} s is shorter than one control period (1/{rate:g} Hz)")
    late = [f"the {raw['kind']} disturbance at {d.starts_at():g} s" for d, raw in zip(b.disturbances,
            spec.disturbances, strict=True) if d.starts_at() >= b.duration]  # fmt: skip
    late += [f"the interaction switch at {t:g} s ({axis} to {beh})" for t, axis, beh in spec.interaction.switches
             if t >= b.duration]  # fmt: skip
    if spec.trajectory.yaw_step_time >= b.duration:
        late.append(f"the yaw step at {spec.trajectory.yaw_step_time:g} s")
    if late:  # a shortened run (--duration) does this on purpose: say it, do not refuse it
        warnings.warn(
            f"{'; '.join(late)}: after the flight ends ({b.duration:g} s), never happening in this run",
            ScenarioWarning,
            stacklevel=2,
        )
    for d in b.disturbances:
        d.check_start(b.start_W)
    return b, [controller_params(spec, v) for v in variants]


class ScenarioWarning(UserWarning):
    """Something in a scenario will not happen as written (an event after the end of the flight)."""


# --------------------------------------------------------------------------- overrides and TOML


#: Allowed ranges of scenario values: dotted key -> (low, high, low excluded). Keys not listed here are
#: only checked for type (and finiteness); vectors are checked element by element.
RANGES: dict[str, tuple[float, float, bool]] = {
    "duration": (0.0, 1e6, False),  # 0: the trajectory's own length
    "plant_rate": (0.0, 1e6, True),
    "seed": (0, 2**63 - 1, False),
    "trajectory.altitude": (0.0, 1e4, True),
    "trajectory.takeoff_at": (0.0, 1e6, False),
    "trajectory.takeoff_duration": (0.0, 1e6, True),
    "trajectory.hover_duration": (0.0, 1e6, False),
    "trajectory.circle_radius": (0.0, 1e4, True),
    "trajectory.circle_speed": (0.0, 100.0, True),
    "trajectory.circle_laps": (0.0, 1e4, True),
    "trajectory.circle_ramp": (0.0, 1e6, False),
    "trajectory.settle_duration": (0.0, 1e6, False),
    "trajectory.land_duration": (0.0, 1e6, True),
    "trajectory.land_hold": (0.0, 1e6, False),
    "trajectory.yaw": (-100.0, 100.0, False),
    "trajectory.yaw_step_time": (-1e6, 1e6, False),
    "trajectory.yaw_step_angle": (-100.0, 100.0, False),
    "payload.mass": (0.0, 1e3, False),
    "payload.offset_B": (-10.0, 10.0, False),
    "plant.inertia_scale": (0.0, 100.0, True),
    "plant.arm_length_scale": (0.0, 100.0, True),
    "plant.drag_factor_scale": (0.0, 100.0, True),
    "plant.rotor_tau_up": (0.0, 10.0, False),
    "plant.rotor_tau_down": (0.0, 10.0, False),
    "plant.rotor_drag": (0.0, 1e3, False),
    "plant.pendulum_mass": (0.0, 1e3, False),
    "plant.pendulum_length": (0.0, 100.0, True),
    "sensors.pos_noise": (0.0, 1e3, False),
    "sensors.vel_noise": (0.0, 1e3, False),
    "sensors.att_noise": (0.0, 10.0, False),
    "sensors.gyro_noise": (0.0, 1e3, False),
    "sensors.mocap_delay": (0.0, 1.0, False),
    "sensors.imu_delay": (0.0, 1.0, False),
    "control.rate": (0.0, 1e5, True),
    "control.Kp": (0.0, 1e6, True),
    "control.Dp": (0.0, 1e6, True),
    "control.Ki": (0.0, 1e6, False),
    "control.wn_o": (0.0, 1e4, True),
    "control.wn_o_yaw": (0.0, 1e4, True),
    "control.velocity_delay": (0.0, 1.0, False),
    "control.attitude_delay": (0.0, 1.0, False),
    "control.rotor_tau": (0.0, 1.0, False),
    "control.zeta_o": (0.0, 100.0, True),
    "control.estimator_wn": (0.0, 1e5, True),
    "control.estimator_wn_moment": (0.0, 1e5, True),
    "control.estimator_zeta": (0.0, 100.0, True),
    "control.estimator_order": (1, 8, False),
    "control.attitude_filter_wn": (0.0, 1e5, True),
    "control.tilt_max_deg": (0.0, 89.0, True),
    "control.integral_limit": (0.0, 1e6, True),
    "control.thrust_shift_max": (0.0, 1.0, False),
    "interaction.M": (0.0, 1e6, True),
    "interaction.D": (0.0, 1e6, True),
    "interaction.K": (0.0, 1e6, True),
    "interaction.M_o": (0.0, 1e6, True),
    "interaction.D_o": (0.0, 1e6, True),
    "interaction.K_o": (0.0, 1e6, True),
    "interaction.comply": (0.0, 1.0, False),
    "interaction.comply_attitude": (0.0, 1.0, False),
    "interaction.blend_s": (0.0, 100.0, False),
    "trajectory.move_offset": (-1e4, 1e4, False),
    "trajectory.move_duration": (0.0, 1e6, True),
    "trajectory.move_hold": (0.0, 1e6, False),
}
_GAIN_KEYS = (
    "control.Kp", "control.Dp", "control.Ki", "interaction.M", "interaction.D", "interaction.K", "interaction.M_o",
    "interaction.D_o", "interaction.K_o",
)  # fmt: skip
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,99}$")


def check_name(name: Any) -> str:
    """A scenario name is also a file name: letters, digits and ``. _ + -``, at most 100 characters."""
    if not isinstance(name, str) or not _NAME.match(name) or ".." in name:
        raise ScenarioError(
            f"scenario name must be 1-100 letters, digits or '._+-' (it names the result files), got {name!r}"
        )
    return name


def _check_range(path: str, value: Any) -> None:
    key = re.sub(r"\[\d+\]$", "", path)
    if key not in RANGES:
        return
    lo, hi, lo_open = RANGES[key]
    if value is None:  # "design" / "auto"
        return
    for v in value if isinstance(value, tuple) else (value,):
        if v < lo or v > hi or (lo_open and v == lo):
            rng = f"{'(' if lo_open else '['}{lo}, {hi}]"
            raise ScenarioError(f"{path} must be in {rng}, got {v!r}")


def _gain_value(path: str, value: Any) -> Any:
    """A gain may be a scalar, 3 values, or a diagonal 3x3 matrix (as eq. (18) writes it)."""
    if isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) for r in value):
        if not all(_real(v) is not None for r in value for v in r):  # no true for a 1, no 10**400
            raise ScenarioError(f"{path} must be finite numbers, got {value!r}")
        try:
            mat = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"{path} must be numbers, got {value!r}") from None
        if mat.shape != (3, 3) or np.any(mat - np.diag(np.diag(mat))):
            raise ScenarioError(f"{path} must be a scalar, 3 values or a diagonal 3x3 matrix, got {value!r}")
        return [float(v) for v in np.diag(mat)]
    return value


#: Keys whose default ``None`` means "chosen for you" (designed, or from the sensor model); ``"design"`` or
#: ``"auto"`` sets them back to that.
_OPTIONAL = {"control.wn_o", "control.wn_o_yaw", "control.attitude_filter_wn", "control.estimator_wn",
             "control.estimator_wn_moment",
             "control.velocity_delay", "control.attitude_delay", "plant.rotor_drag"}  # fmt: skip


def _coerce(path: str, current: Any, value: Any) -> Any:
    """Convert ``value`` to the type of ``current`` or raise a clear error."""
    if isinstance(value, np.generic | np.ndarray):  # NumPy's numbers (a sweep's, a user's) as Python's
        value = value.tolist()
    if path in _OPTIONAL:
        if isinstance(value, str) and value in ("design", "auto"):
            return None
        current = 0.0  # otherwise a number
    if isinstance(current, bool):
        if isinstance(value, bool):
            return value
        raise ScenarioError(f"{path} expects true/false, got {value!r}")
    if isinstance(current, int) and not isinstance(current, bool):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ScenarioError(f"{path} expects an integer, got {value!r}")
    if isinstance(current, float):
        if path in _GAIN_KEYS and isinstance(value, list | tuple) and len(value) == 3:
            return tuple(float(_coerce(f"{path}[{i}]", 0.0, v)) for i, v in enumerate(value))
        if isinstance(value, int | float) and not isinstance(value, bool):
            number = _real(value)  # an integer of 2**64 or more is a Python int NumPy cannot test
            if number is None:
                raise ScenarioError(f"{path} must be a finite number, got {str(value)[:40]}")
            return number
        raise ScenarioError(f"{path} expects a number, got {value!r}")
    if isinstance(current, str):
        if isinstance(value, str):
            return value
        raise ScenarioError(f"{path} expects a string, got {value!r}")
    if isinstance(current, tuple) and current and not isinstance(current[0], dict):
        if isinstance(value, int | float) and not isinstance(value, bool):
            value = [value] * len(current)
        if not isinstance(value, list | tuple) or len(value) != len(current):
            raise ScenarioError(f"{path} expects {len(current)} values, got {value!r}")
        return tuple(_coerce(f"{path}[{i}]", c, v) for i, (c, v) in enumerate(zip(current, value, strict=True)))
    return value


def _section_keys(obj: Any) -> list[str]:
    return [f.name for f in fields(obj)]


#: A key naming one component of a vector value: ``payload.offset_B[0]``.
_INDEXED = re.compile(r"^(?P<key>[A-Za-z_][\w.]*)\[(?P<i>\d)\]$")


def get_value(spec: ScenarioSpec, key: str) -> Any:
    """The value at the dotted ``key`` of ``spec``, as plain data (:meth:`ScenarioSpec.to_dict`)."""
    obj: Any = spec.to_dict()
    for part in key.split("."):
        if isinstance(obj, list) and part.isdigit() and int(part) < len(obj):
            obj = obj[int(part)]
        elif isinstance(obj, dict) and part in obj:
            obj = obj[part]
        else:
            raise ScenarioError(f"unknown key {key!r}")
    return obj


def keys_overlap(a: str, b: str) -> bool:
    """Whether the dotted keys ``a`` and ``b`` (as :func:`set_value` takes them) set one value: the same key,
    or a vector and one of its entries (``payload.offset_B`` and ``payload.offset_B[0]``); two entries of one
    vector are two values."""
    if a == b:
        return True
    return a.split("[", 1)[0] == b.split("[", 1)[0] and ("[" not in a or "[" not in b)


def _dotted(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A scenario's plain data (``to_dict``) by the dotted keys :func:`set_value` takes (``control.Kp``);
    lists and the disturbances kept whole."""
    out: dict[str, Any] = {}
    for k, v in data.items():
        if isinstance(v, dict):
            out.update(_dotted(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def set_value(spec: ScenarioSpec, key: str, value: Any) -> ScenarioSpec:
    """Return a copy of ``spec`` with the dotted ``key`` (``payload.mass``, ``disturbances.0.mean_force``, or
    one component of a vector value, ``payload.offset_B[0]``) set."""
    instance("spec", spec, ScenarioSpec)
    if not isinstance(key, str) or not key:
        raise ScenarioError(f"a scenario key is a dotted name such as 'payload.mass', got {key!r}")
    m = _INDEXED.match(key)
    if m is not None:
        current = get_value(spec, m["key"])
        if isinstance(current, int | float) and m["key"] in _GAIN_KEYS:
            current = [current] * 3  # a scalar gain taken per axis
        if not isinstance(current, list) or int(m["i"]) >= len(current):
            raise ScenarioError(f"{key}: {m['key']} is not a vector with a component {m['i']}")
        new = list(current)
        new[int(m["i"])] = value
        return set_value(spec, m["key"], new)
    return _set(spec, key.split("."), value, key)


def _set(obj: Any, parts: list[str], value: Any, full: str) -> Any:
    head, rest = parts[0], parts[1:]
    if isinstance(obj, tuple):  # the disturbances list
        if not obj:
            raise ScenarioError(
                f"{full}: this scenario has no disturbances; add them as [[disturbances]] tables in a scenario file"
            )
        if not (head.isascii() and head.isdigit() and int(head) < len(obj)):  # "-1" or "+0" would address another
            raise ScenarioError(f"{full}: there are {len(obj)} disturbances; use an index 0..{len(obj) - 1}")
        i = int(head)
        item = obj[i]
        if not rest:
            raise ScenarioError(f"{full}: name a field of disturbance {i}, e.g. disturbances.{i}.kind")
        new = dict(item)
        if len(rest) != 1:
            raise ScenarioError(f"{full}: disturbance fields are not nested")
        new[rest[0]] = value
        from_dict(new)  # validates the key
        return obj[:i] + (new,) + obj[i + 1 :]
    if not dataclasses.is_dataclass(obj):
        raise ScenarioError(f"{full}: {head!r} cannot be set inside a value")
    valid = _section_keys(obj)
    if head not in valid:
        raise ScenarioError(f"unknown key {full!r}: {head!r} is not one of {', '.join(valid)}")
    current = getattr(obj, head)
    if rest:
        if not dataclasses.is_dataclass(current) and head != "disturbances":  # a value, not a section
            key = full[: len(full) - len(".".join(rest)) - 1]
            hint = f"; set one entry with {key}[i], e.g. {key}[0]" if isinstance(current, tuple) else ""
            if key == "interaction.switches":
                hint = "; give the whole list, interaction.switches=[[time_s, axis, behaviour], ...]"
            raise ScenarioError(f"{full}: {key} is a value, not a section{hint}")
        return replace(obj, **{head: _set(current, rest, value, full)})
    if dataclasses.is_dataclass(current):
        raise ScenarioError(f"{full} is a section; set one of its keys: {', '.join(_section_keys(current))}")
    if head == "disturbances":
        if not isinstance(value, list | tuple) or not all(isinstance(d, dict) for d in value):
            raise ScenarioError("disturbances must be a list of tables with a 'kind'")
        return replace(obj, disturbances=tuple(value))
    if full == "interaction.switches":
        return replace(obj, switches=parse_switches(value))
    if full in _GAIN_KEYS or (isinstance(current, tuple) and full.startswith("control.")):
        value = _gain_value(full, value)
    if head == "name":
        value = check_name(value)
    if head == "vehicle":
        if not isinstance(value, str):
            raise ScenarioError(f"vehicle expects a preset name or a .toml path, got {value!r}")
        load_preset(value)  # validates now
    coerced = _coerce(full, current, value)
    _check_range(full, coerced)
    try:
        return replace(obj, **{head: coerced})
    except InputError as exc:
        raise ScenarioError(f"{full}: {exc}") from exc


def parse_value(text: str) -> Any:
    """Parse a command-line value as TOML (``0.2``, ``true``, ``[1, 2, 3]``), else keep it as a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
    except RecursionError:
        raise InputError(f"value {text[:40]!r}... nests arrays or tables too deeply to read") from None


def apply_overrides(spec: ScenarioSpec, assignments: list[str] | tuple[str, ...]) -> ScenarioSpec:
    """Apply ``key=value`` strings, as given to ``--set``."""
    instance("spec", spec, ScenarioSpec)
    if not isinstance(assignments, list | tuple) or not all(isinstance(a, str) for a in assignments):
        raise InputError(f"assignments must be a list of 'key=value' strings, got {assignments!r:.80}")
    for a in assignments:
        if "=" not in a:
            raise ScenarioError(f"--set expects key=value, got {a!r}")
        k, v = a.split("=", 1)
        spec = set_value(spec, k.strip(), parse_value(v.strip()))
    return spec


def apply_mapping(spec: ScenarioSpec, data: dict[str, Any], prefix: str = "") -> ScenarioSpec:
    """Apply a nested mapping (a parsed TOML document) onto ``spec``."""
    for k, v in data.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and not v:  # an empty table sets nothing: a section may be empty, a value not
            current: Any = spec
            for part in key.split("."):
                if not (dataclasses.is_dataclass(current) and part in _section_keys(current)):
                    return set_value(spec, key, v)  # not a key of this scenario: named as such
                current = getattr(current, part)
            if not dataclasses.is_dataclass(current):
                raise ScenarioError(f"{key} is given an empty table {{}}, which sets nothing; give its value")
        if isinstance(v, dict):
            spec = apply_mapping(spec, v, key + ".")
        else:
            spec = set_value(spec, key, v)
    return spec
