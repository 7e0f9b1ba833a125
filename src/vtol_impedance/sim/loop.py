"""Closed loop: true plant at the plant rate (fixed-step RK4), controller and estimator at the control rate.

Timing per control period ``Ts`` (ZOH): sensors are read, the controller computes rotor forces from the
estimate of the period that just ended, and the forces are held while the plant takes ``Ts / dt`` RK4
steps. Logged signals are sampled at the control instants.

Two backends run this loop. ``"compiled"`` (default) runs the numba kernels of
:mod:`vtol_impedance.compiled`, one thread-parallel iteration per vehicle; ``"numpy"`` runs the NumPy
functions of :mod:`vtol_impedance.model`, :mod:`.control`, :mod:`.estimator` and :mod:`.sim` on the whole
batch at once. They compute the same thing (parity tests), from the same random numbers.
"""

from __future__ import annotations

import gc
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ..control.impedance import (
    ControllerParams,
    compile_controllers,
    controller_step,
    initial_controller_state,
)
from ..control.reference import Trajectory
from ..control.signals import Reference
from ..conventions import E3, GRAVITY_W, G
from ..errors import InputError, as_finite, scalar
from ..model.dynamics import coriolis_matrix_C, inertia_matrix_M, matvec, transpose
from ..model.kinematics import (
    cross,
    euler_from_rotation,
    euler_rate_matrix_Q,
    euler_rate_matrix_Q_dot,
    quat_to_rotation,
)
from ..model.vehicle import warn_if_cannot_hover
from ..records import (
    CRASH_DEPTH_M,
    FAIL_CRASH,
    FAIL_FAR,
    FAIL_NAN,
    FAIL_TILT,
    LOG_ROW,
    MAX_DISTANCE_M,
    MAX_TILT_RAD,
    REASONS,
    SIGNALS,
    empty_log,
    rows_to_data,
)
from .disturbances import Disturbance, DisturbanceSet
from .plant import (
    OMEGA,
    QUAT,
    ROTOR,
    V_COM,
    PlantArrays,
    PlantParams,
    apply_instant_rotors,
    compile_plants,
    environment_wrench,
    initial_state,
    link_force,
    lowest_contact_depth,
    origin_kinematics,
    plant_derivative,
    rk4_step,
    rotor_wrench,
)
from .result import STEADY_TAIL_S, Result, compute_metrics, metrics_row, window_mask_of
from .sensors import NoiseSource, SensorParams, SensorSuite, latency_steps, rounded_latencies

#: Bytes of random numbers per block (NumPy backend).
BLOCK_BYTES = 50_000_000
#: Vehicle-ticks the compiled engine flies between two returns to Python (progress, interruption; 50 to
#: 5,000 ticks): about half a second of a batch on two cores. Each return writes the lanes' states back to
#: the records and reads them again: 4,000 case-A vehicles in chunks of 130 ticks spent 2.5 % of the
#: kernel's time there, in chunks of 375 about 1 %.
CHUNK_VEHICLE_TICKS = 1_500_000
#: Control ticks per block of random numbers in the NumPy backend.
BLOCK_TICKS = 200

#: ``"mujoco"``: the compiled controller flying MuJoCo's physics (:mod:`.mjplant`, the ``mujoco`` extra);
#: ``"mujoco-numpy"``: the NumPy controller on it (the reference the compiled one is tested against).
BACKENDS = ("compiled", "numpy", "mujoco", "mujoco-numpy")


@dataclass(frozen=True)
class Limits:
    """Bounds on one run, checked before it starts; a run beyond them is refused with the estimate.

    ``max_memory_gb``: memory the run's buffers may take (traces, state history, noise, disturbance
    series); ``max_plant_steps``: vehicles x plant steps (about 1e7 per second per core compiled).
    Defaults come from the environment variables ``VTOL_IMPEDANCE_MAX_MEMORY_GB`` (4) and
    ``VTOL_IMPEDANCE_MAX_PLANT_STEPS`` (2e10); pass ``limits=Limits(...)`` to override one run.
    """

    max_memory_gb: float = 4.0
    max_plant_steps: float = 2e10

    def __post_init__(self) -> None:
        for name in ("max_memory_gb", "max_plant_steps"):
            object.__setattr__(self, name, scalar(f"Limits.{name}", getattr(self, name), lo=0.0, lo_open=True))

    @classmethod
    def from_env(cls) -> Limits:
        import os

        out = {}
        for field_name, var in (
            ("max_memory_gb", "VTOL_IMPEDANCE_MAX_MEMORY_GB"),
            ("max_plant_steps", "VTOL_IMPEDANCE_MAX_PLANT_STEPS"),
        ):
            if var in os.environ:
                try:
                    out[field_name] = scalar(var, float(os.environ[var]), lo=0.0, lo_open=True)
                except ValueError:
                    raise InputError(f"{var} must be a positive number, got {os.environ[var]!r}") from None
        return cls(**out)


def estimate_run(
    B: int, N: int, n_sub: int, n_rotors: int, dec: int, history: int, n_dist: int, backend: str
) -> dict[str, float]:
    """Bytes and plant steps a run will need (the numbers :class:`Limits` are checked against)."""
    width = LOG_ROW.itemsize // 8
    compiled = backend in ("compiled", "mujoco")  # decimated logs, no noise blocks
    n_log = N if not compiled else ((N + dec - 1) // dec if dec else 0)
    mem = 8.0 * (
        B * n_log * width  # traces
        + B * history * (13 + n_rotors)  # sensor history
        + N * 12  # reference samples
        + n_dist * (N * n_sub + 2) * 6  # disturbance series at the plant rate
    )
    if not compiled:  # the compiled kernels draw their noise as they go
        mem = 2.0 * (mem + min(BLOCK_BYTES, 8.0 * B * N * 12))  # noise blocks, NumPy temporaries
    return {"memory_bytes": mem, "plant_steps": float(B) * N * n_sub}


def check_limits(estimate: dict[str, float], limits: Limits) -> None:
    gb = estimate["memory_bytes"] / 1e9
    if gb > limits.max_memory_gb:
        raise InputError(
            f"this run would need about {gb:.3g} GB of memory, above the limit of {limits.max_memory_gb:g} GB; "
            "shorten it, log less (log='metrics' or 'decimate:K'), fly fewer vehicles, or raise the limit "
            "(VTOL_IMPEDANCE_MAX_MEMORY_GB or Limits(max_memory_gb=...))"
        )
    if estimate["plant_steps"] > limits.max_plant_steps:
        raise InputError(
            f"this run would take {estimate['plant_steps']:.3g} vehicle plant steps, above the limit of "
            f"{limits.max_plant_steps:.3g} (about {limits.max_plant_steps / 1e7 / 60:.0f} min on one core); shorten "
            "it, lower plant_rate, or raise the limit (VTOL_IMPEDANCE_MAX_PLANT_STEPS or Limits(max_plant_steps=...))"
        )


ProgressFn = Callable[[float], None]


def _lumped_wrench(
    PA: PlantArrays,
    x: np.ndarray,
    a_o: np.ndarray,
    w_dot: np.ndarray,
    R: np.ndarray,
    eta: np.ndarray,
    thrust_prev: np.ndarray,
    tau_B_prev: np.ndarray,
    mass_nom: np.ndarray,
    I_nom: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """What the nominal model (5) misses, given the true motion: the estimator's target.

    ``f = m (a_o - g_W) + u R e3`` and ``tau_eta = M eta_ddot + C eta_dot - Q^T tau_B`` with nominal
    ``m``, ``I_B``, the true acceleration ``a_o`` of the body origin (world), the true ``w_dot_B`` and the
    command held over the period.
    """
    w = x[..., OMEGA]
    f = mass_nom[..., None] * (a_o - GRAVITY_W) + thrust_prev[..., None] * matvec(R, np.broadcast_to(E3, a_o.shape))
    Q = euler_rate_matrix_Q(eta)
    eta_dot = np.linalg.solve(Q, w[..., None])[..., 0]
    Qd = euler_rate_matrix_Q_dot(eta, eta_dot)
    eta_ddot = np.linalg.solve(Q, (w_dot - matvec(Qd, eta_dot))[..., None])[..., 0]
    tau = (
        matvec(inertia_matrix_M(eta, I_nom), eta_ddot)
        + matvec(coriolis_matrix_C(eta, eta_dot, I_nom), eta_dot)
        - matvec(transpose(Q), tau_B_prev)
    )
    return f, tau


class _BuiltinPlant:
    """The plant of :mod:`.plant` integrated by RK4: the NumPy backend's physics, with the interface
    :class:`.mjplant.MujocoPlant` shares (``x``, ``truth``, ``advance``, ``park``)."""

    def __init__(self, PA: PlantArrays, dist: DisturbanceSet, x0: np.ndarray) -> None:
        self.PA, self.dist, self.x = PA, dist, x0.copy()

    def truth(self, t: float, f_cmd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The body origin's acceleration (world), ``w_dot_B`` and the external force (world, at the
        origin, the pendulum's pull included) and moment (body) at the start of the period."""
        PA, x = self.PA, self.x
        x_dot = plant_derivative(PA, x, f_cmd, t, self.dist)
        R = quat_to_rotation(x[..., QUAT])
        w, w_dot, c = x[..., OMEGA], x_dot[..., OMEGA], PA.c_B
        a_o = x_dot[..., V_COM] - matvec(R, cross(w_dot, c) + cross(w, cross(w, c)))
        f_env, tau_env = environment_wrench(PA, t, x, R, self.dist)
        u = rotor_wrench(PA, x[..., ROTOR])[0]
        f_env = f_env + link_force(PA, x, -u[..., None] * R[..., :, 2] + f_env)[0]  # the pendulum's pull
        return a_o, w_dot, f_env, tau_env

    def advance(self, t: float, f_cmd: np.ndarray, n_sub: int, dt: float, push: Callable[[np.ndarray], None]) -> None:
        x = apply_instant_rotors(self.PA, self.x, f_cmd)
        for j in range(n_sub):
            x = rk4_step(self.PA, x, f_cmd, t + j * dt, dt, self.dist)
            push(x)
        self.x = x

    def park(self, alive: np.ndarray, x_park: np.ndarray) -> None:
        self.x = np.where(alive[:, None], self.x, x_park)


@dataclass
class _Setup:
    CA: Any
    PA: PlantArrays
    dist: DisturbanceSet
    sensors: SensorParams
    noise: NoiseSource
    refs: np.ndarray  # (N, 24): reference_rows
    x0: np.ndarray  # (B, state_size(n))
    Ts: float
    dt: float
    n_sub: int
    N: int
    dec: int  # log every dec-th tick; 0: metrics only
    window: tuple[float, float, float]


def _parse_log(log: str | int) -> int:
    if log == "full":
        return 1
    if log == "metrics":
        return 0
    if isinstance(log, int | np.integer) and not isinstance(log, bool | np.bool_) and log >= 1:
        return int(log)
    if isinstance(log, str) and log.startswith("decimate:"):
        digits = log.split(":", 1)[1]
        k = int(digits) if digits.isascii() and digits.isdigit() else 0  # not int(): it reads "5_0" and " 5"
        if k >= 1:
            return k
    raise InputError(f"log must be 'full', 'metrics', 'decimate:K' or a whole number K >= 1, got {log!r}")


def _window(window: tuple[float, float] | None, t_grid: np.ndarray) -> tuple[float, float, float]:
    """``[t0, t1, tail_start]`` of the metrics window, by the rule of :func:`.result.window_mask_of`."""
    inside = t_grid[window_mask_of(t_grid, window)]
    return float(inside[0]), float(inside[-1]), float(inside[-1] - STEADY_TAIL_S)


def run_closed_loop(
    plant: PlantParams | Sequence[PlantParams],
    controllers: Sequence[ControllerParams],
    trajectory: Trajectory,
    duration: float,
    disturbances: Sequence[Disturbance] = (),
    sensors: SensorParams | None = None,
    plant_rate: float = 1000.0,
    seed: int | Sequence[int] = 0,
    labels: Sequence[str] | None = None,
    start_W: np.ndarray | None = None,
    progress: ProgressFn | None = None,
    config: dict[str, Any] | None = None,
    backend: str = "compiled",
    log: str | int = "full",
    window: tuple[float, float] | None = None,
    limits: Limits | None = None,
) -> Result:
    """Fly ``B = len(controllers)`` vehicles through the same trajectory.

    Parameters
    ----------
    plant : PlantParams or sequence of PlantParams
        One true plant for all vehicles, or one per vehicle.
    controllers : ControllerParams or sequence of ControllerParams
        Nominal controllers, one per vehicle (they must share the control period).
    trajectory : Trajectory
        The reference; the run starts at ``start_W`` (default: the trajectory's first point).
    duration : float
        Flight time, s.
    disturbances : sequence of Disturbance
        Explicit external disturbances; one realisation, drawn from the first vehicle's seed, is shared
        by the batch.
    sensors : SensorParams, optional
        Noise and latency (default :class:`SensorParams`); use ``SensorParams.ideal()`` for none.
    plant_rate : float
        RK4 rate in Hz; ``plant_rate * Ts`` must be an integer.
    seed : int or sequence of int
        One seed for every vehicle (the same sensor noise, a fair comparison) or one per vehicle.
    labels : sequence of str, optional
        A name per vehicle (default: the controller variants).
    start_W : ndarray, shape (3,), optional
        Initial position of the body origin, world NED, m.
    progress : callable, optional
        Called with the fraction done.
    config : dict, optional
        Extra entries for the result's ``config``.
    backend : {"compiled", "numpy", "mujoco", "mujoco-numpy"}
        ``"compiled"`` (numba), ``"numpy"`` (the reference), ``"mujoco"`` (the compiled controller on
        MuJoCo's physics, an independent plant; needs the ``mujoco`` extra) or ``"mujoco-numpy"`` (the
        NumPy controller on MuJoCo: the same numbers, slower).
    log : str
        ``"full"`` (every control tick), ``"decimate:K"`` (every K-th), or ``"metrics"`` (no traces, only
        the per-vehicle metrics of ``window``; for large batches).
    window : tuple of float, optional
        Task window ``(t0, t1)`` in s for the metrics (default: the whole run).
    limits : Limits, optional
        Bounds on memory and work checked before the run (default ``Limits.from_env()``).

    Returns
    -------
    Result
        Arrays ``(B, N, ...)`` on the control ticks, the failures and the configuration.
    """
    if progress is not None and not callable(progress):
        raise InputError(f"progress must be callable, got {type(progress).__name__}")
    controllers, plants, disturbances, sensors, labels, seeds, duration, plant_rate = _checked_inputs(
        plant, controllers, trajectory, duration, disturbances, sensors, plant_rate, seed, labels, window, backend
    )
    # one pause for the whole run: a batch's thousands of small objects (generators, records, result rows),
    # whose allocation would otherwise set off full collections over them (4,000 vehicles: 0.2 s of a 2.6 s run)
    with _collector_paused():
        setup, lift = _prepare(
            controllers, plants, trajectory, duration, disturbances, sensors, plant_rate, seeds, start_W, backend,
            _parse_log(log), window, limits,
        )  # fmt: skip
        rows, metrics, failures = _fly(setup, backend, plants, progress)
        cfg = dict(config or {})
        cfg.update({"seed": seeds[0] if len(set(seeds)) == 1 else seeds, "backend": backend, "log": log,
                    "duration": duration, "plant_rate": plant_rate, "control_period": setup.Ts,
                    "labels": labels})  # fmt: skip
        cfg.update(_run_config(controllers, plants, disturbances, sensors))
        cfg.setdefault("window", list(setup.window[:2]))
        if np.any(lift > 0):
            cfg["start_lifted_m"] = lift.tolist()  # documented: a contact point started under the ground
        moved = rounded_latencies(sensors, setup.dt)
        if moved:
            cfg["sensor_delays_flown_s"] = moved  # documented: latencies flown at the nearest plant step
        t_grid = np.arange(setup.N) * setup.Ts
        t_log = t_grid[:: setup.dec] if setup.dec else t_grid[:0]
        data = rows_to_data(rows, setup.PA.spins.shape[-1]) if setup.dec else {}
        for i, m in enumerate(metrics):
            m["controller"] = labels[i]
    # a decimated run keeps the metrics taken at every tick: every K-th sample would give other numbers
    return Result(t_log, labels, data, cfg, failures, metrics if setup.dec != 1 else None)


def _warn_if_grounded(controllers: list[ControllerParams], plants: list[PlantParams]) -> None:
    """A :class:`~vtol_impedance.model.HoverWarning` for each nominal vehicle whose rotors cannot lift it, and one
    for the plants their payload and pendulum keep down (the heaviest named, with the count)."""
    for vehicle in {id(c.vehicle): c.vehicle for c in controllers}.values():
        warn_if_cannot_hover(vehicle, stacklevel=4)
    lift = {id(v): float(v.geometry.f_max.sum()) for v in {id(p.vehicle): p.vehicle for p in plants}.values()}
    grounded = [
        p for p in {id(p): p for p in plants}.values()
        if (p.payload_mass > 0 or p.pendulum_mass > 0) and lift[id(p.vehicle)] < (p.total_mass + p.pendulum_mass) * G
    ]  # fmt: skip
    if grounded:
        p = max(grounded, key=lambda q: q.total_mass + q.pendulum_mass)
        carrying = (f" with {p.payload_mass:g} kg of payload and a {p.pendulum_mass:g} kg pendulum (the heaviest of "
                    f"{len(grounded)} plant(s) of the flight that cannot hover)")  # fmt: skip
        warn_if_cannot_hover(p.vehicle, stacklevel=4, mass=p.total_mass + p.pendulum_mass, carrying=carrying)


def _checked_inputs(
    plant: Any, controllers: Any, trajectory: Any, duration: Any, disturbances: Any, sensors: Any, plant_rate: Any,
    seed: Any, labels: Any, window: Any, backend: Any,
) -> tuple[list[ControllerParams], list[PlantParams], list[Disturbance], SensorParams, list[str], list[int], float,
           float]:  # fmt: skip
    """The arguments of :func:`run_closed_loop`, checked before any work and normalised to one per vehicle."""
    if isinstance(controllers, ControllerParams):
        controllers = [controllers]
    if isinstance(controllers, str) or not hasattr(controllers, "__iter__"):
        raise InputError(f"controllers must be a sequence of ControllerParams, got {type(controllers).__name__}")
    if isinstance(plant, str) or not (isinstance(plant, PlantParams) or hasattr(plant, "__iter__")):
        raise InputError(f"plant must be a PlantParams or a sequence of them, got {type(plant).__name__}")
    for name, v in (("disturbances", disturbances), ("labels", labels)):
        if v is not None and (isinstance(v, str) or not hasattr(v, "__iter__")):
            raise InputError(f"{name} must be a sequence, got {type(v).__name__}")
    controllers = list(controllers)
    B = len(controllers)
    if B == 0 or not all(isinstance(c, ControllerParams) for c in controllers):
        raise InputError("controllers must be a non-empty sequence of ControllerParams")
    plants = [plant] * B if isinstance(plant, PlantParams) else list(plant)
    if len(plants) != B or not all(isinstance(p, PlantParams) for p in plants):
        raise InputError(
            f"plant must be one PlantParams or one per controller: {len(plants)} plants for {B} controllers"
        )
    _warn_if_grounded(controllers, plants)
    if not isinstance(trajectory, Trajectory):
        raise InputError(f"trajectory must be a Trajectory, got {type(trajectory).__name__}")
    disturbances = list(disturbances)
    if not all(isinstance(d, Disturbance) for d in disturbances):
        raise InputError("disturbances must be Disturbance objects (see sim.disturbances.from_dict)")
    if sensors is not None and not isinstance(sensors, SensorParams):
        raise InputError(f"sensors must be a SensorParams, got {type(sensors).__name__}")
    labels = list(labels) if labels is not None else [c.variant for c in controllers]
    if len(labels) != B or not all(isinstance(x, str) for x in labels):
        raise InputError(f"labels must be {B} strings, one per controller, got {labels!r}")
    vehicles = {id(x.vehicle): x.vehicle for x in (*controllers, *plants)}  # each distinct vehicle once
    counts = {v.n_rotors for v in vehicles.values()}
    if len(counts) > 1:
        raise InputError(f"controllers and plants must have the same number of rotors, got {sorted(counts)}")
    seed_list = [seed] * B if np.ndim(seed) == 0 else list(seed)  # type: ignore[arg-type]
    if all(type(s) is int and 0 <= s < 2**53 for s in seed_list):  # plain ints a float holds: as scalar() passes them
        seeds = seed_list
    else:
        seeds = [scalar("seed", s, lo=0, hi=2**63 - 1, integer=True) for s in seed_list]
    if len(seeds) != B:
        raise InputError(f"{len(seeds)} seeds given for {B} vehicles")
    if window is not None:
        w = as_finite("window", window)
        if w.shape != (2,) or w[1] < w[0]:
            raise InputError(f"window must be (t0, t1) with t0 <= t1, got {window!r}")
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend.startswith("mujoco"):
        from .mjplant import require_mujoco

        require_mujoco()  # before any work: a clear message when the extra is missing
    duration = scalar("duration", duration, lo=0.0, lo_open=True)
    plant_rate = scalar("plant_rate", plant_rate, lo=0.0, lo_open=True)
    sensors = SensorParams() if sensors is None else sensors
    return controllers, plants, disturbances, sensors, labels, seeds, duration, plant_rate


def _prepare(
    controllers: list[ControllerParams], plants: list[PlantParams], trajectory: Trajectory, duration: float,
    disturbances: list[Disturbance], sensors: SensorParams, plant_rate: float, seeds: list[int],
    start_W: Any, backend: str, dec: int, window: tuple[float, float] | None, limits: Limits | None,
) -> tuple[_Setup, np.ndarray]:  # fmt: skip
    """Everything a flight needs, built once: the packed controllers and plants, the timing, the drawn
    disturbances, the reference on the control ticks and the initial state (lifted onto the ground where a
    contact point started under it, by how much returned); the run's size checked against ``limits``."""
    B = len(controllers)
    CA = compile_controllers(controllers)
    Ts, dt = CA.Ts, 1.0 / plant_rate
    n_sub = int(round(Ts / dt))
    if n_sub < 1 or abs(n_sub * dt - Ts) > 1e-9 * Ts:
        raise InputError(f"plant_rate * Ts must be a whole number >= 1, got {plant_rate} Hz * {Ts} s")
    N = int(round(duration / Ts))
    if N < 1:
        raise InputError(f"duration {duration:g} s is shorter than one control period ({Ts:g} s)")
    history = max(latency_steps(sensors, dt)) + 1
    n_rotors = controllers[0].vehicle.n_rotors
    check_limits(
        estimate_run(B, N, n_sub, n_rotors, dec, history, len(disturbances), backend),
        Limits.from_env() if limits is None else limits,
    )
    t_grid = np.arange(N) * Ts
    PA = compile_plants(plants)
    dseeds = [np.random.SeedSequence([seeds[0], 1 + i]) for i in range(len(disturbances))]
    dist = DisturbanceSet(
        [d.prepare(duration + Ts, dt, np.random.default_rng(s)) for d, s in zip(disturbances, dseeds, strict=True)]
    )
    start = trajectory.sample(0.0).p_W if start_W is None else as_finite("start_W", start_W, (3,))
    if start.shape != (3,):
        raise InputError(f"start_W must be one point of shape (3,), got shape {start.shape}")
    for d in disturbances:
        d.check_start(start)
    refs = reference_rows(trajectory, np.append(t_grid, duration), controllers)  # the control ticks and the end
    _check_clearance(refs, plants, Ts, duration)
    x0 = initial_state(PA, np.broadcast_to(start, (B, 3)), np.array([0.0, 0.0, trajectory.yaw0]))
    # A vehicle set down with a contact point (a low-slung payload) under the ground is lifted onto it.
    lift = np.where(PA.ground > 0, np.maximum(lowest_contact_depth(PA, x0), 0.0), 0.0)
    x0[:, 2] -= lift
    setup = _Setup(CA, PA, dist, sensors, NoiseSource(seeds), refs[:-1], x0, Ts, dt, n_sub, N, dec,
                   _window(window, t_grid))  # fmt: skip
    return setup, lift


def reference_rows(trajectory: Trajectory, t: np.ndarray, controllers: list[ControllerParams]) -> np.ndarray:
    """The reference at the control ticks ``t`` as the engines take it, ``(N, 24)``: the row of
    :meth:`Trajectory.sample_many` (what the flight is judged against: metrics, log), then the position
    and velocity the controllers are given, sampled ``reference_delay`` earlier
    (:class:`~vtol_impedance.control.impedance.ControllerParams`; before the start, the start's). The
    batch shares one reference, so its controllers must share that delay."""
    delays = sorted({float(c.reference_delay) for c in controllers})
    if len(delays) > 1:
        raise InputError(
            f"the controllers of one batch align the reference to different delays ({delays} s): fly them in "
            "separate runs, or give them one reference_delay"
        )
    rows = trajectory.sample_many(t)
    aligned = trajectory.sample_many(np.maximum(t - delays[0], 0.0))[:, 0:6] if delays[0] > 0 else rows[:, 0:6]
    return np.concatenate([rows, aligned], axis=1)


def _check_clearance(refs: np.ndarray, plants: list[PlantParams], Ts: float, duration: float) -> None:
    """Refuse a reference under the ground (NED z > 0) and a pendulum longer than the lowest altitude."""
    lowest = float(np.max(refs[:, 2]))  # NED: largest z
    if lowest > 1e-6 and any(p.ground for p in plants):
        k = int(np.argmax(refs[:, 2]))
        raise InputError(
            f"the reference goes {lowest:.3g} m below the ground (NED z > 0) at t = {min(k * Ts, duration):.3g} s: "
            "the vehicle would fly into it; raise the trajectory (or turn plant.ground off)"
        )
    for p in {id(p): p for p in plants}.values():  # each distinct plant once
        if p.pendulum_mass > 0 and lowest + p.pendulum_length >= 0.0:
            raise InputError(
                f"the pendulum ({p.pendulum_length} m) is longer than the flight's lowest altitude ({-lowest:.3g} m): "
                "its bob would hit the ground; shorten it or fly higher (start_on_ground = false)"
            )


def _fly(setup: _Setup, backend: str, plants: list[PlantParams], progress: ProgressFn | None):
    """The flight on ``backend``: per vehicle the log rows (or none), the window metrics and the failure."""
    if backend == "compiled":
        return _run_compiled(setup, progress)
    if backend.startswith("mujoco"):
        from .mjplant import MujocoPlant

        mj_plant = MujocoPlant(plants, setup.PA, setup.dist, setup.x0, setup.dt, compiled=backend == "mujoco")
        run = _run_mujoco if backend == "mujoco" else _run_numpy
        try:
            return run(setup, progress, mj_plant)
        finally:
            mj_plant.close()
    return _run_numpy(setup, progress)


@contextmanager
def _collector_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector (and restore it): a batch's configuration is tens of thousands
    of small acyclic dicts, and the collections their allocation triggers took three quarters of the time
    to build them (10,000 vehicles: 0.8 s -> 0.2 s)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _run_config(
    controllers: Sequence[ControllerParams],
    plants: Sequence[PlantParams],
    disturbances: Sequence[Disturbance],
    sensors: SensorParams,
) -> dict[str, Any]:
    """The flown objects, as plain data for the result's ``config``. A vehicle flown by many of them is one
    dictionary their entries share (4,000 vehicles of a batch: 0.15 s less to build)."""
    memo: dict[int, dict] = {}
    return {
        "controllers": [c.to_dict(memo) for c in controllers],
        "plants": [p.to_dict(memo) for p in plants],
        "sensors": {k: getattr(sensors, k) for k in sensors.__dataclass_fields__},
        "disturbances": [d.to_dict() for d in disturbances],
    }


def _failures(fail_code: np.ndarray, fail_time: np.ndarray) -> list[dict[str, Any] | None]:
    return [
        None if c == 0 else {"time": float(t), "reason": REASONS[int(c)]}
        for c, t in zip(fail_code, fail_time, strict=True)
    ]


def _metrics_from_acc(acc: np.ndarray, failures: list[dict[str, Any] | None]) -> list[dict[str, Any]]:
    """Per-vehicle metrics from the compiled accumulators (same definitions as analysis.metrics): NaN where the
    window held no tick. Computed as columns over the vehicles (a batch's thousands of rows)."""
    n, nt = acc["n"], acc["n_tail"]
    with np.errstate(divide="ignore", invalid="ignore"):  # no tick in the window: NaN, as the rows say
        cols = [
            np.where(n > 0, np.sqrt(acc["e2"] / n), np.nan),
            np.where(n > 0, acc["e_max"], np.nan),
            np.where(nt > 0, acc["e_tail"] / nt, np.nan),
            np.where(n > 0, np.sqrt(acc["ev2"] / n), np.nan),
            np.where(n > 0, np.sqrt(acc["f2"] / n), np.nan),
            np.where(n > 0, np.sqrt(acc["t2"] / n), np.nan),
            np.where(n > 0, acc["sat"] / n, np.nan),
        ]
    rows = zip(*(c.tolist() for c in cols), strict=True)
    return [metrics_row("", *row, failure=f) for row, f in zip(rows, failures, strict=True)]


class _Engine(NamedTuple):
    """What the compiled kernels take for a run, whichever plant flies it: controllers and their shared
    design, plants, controller states and timing histories, the log and the window metrics, the noise
    generators, and which vehicles fly on (with why and when the others stopped)."""

    p: np.ndarray
    d: np.ndarray
    pp: np.ndarray
    S: np.ndarray
    EH: np.ndarray
    logs: np.ndarray
    acc: np.ndarray
    win: np.ndarray
    rng: np.ndarray
    alive: np.ndarray
    fail_code: np.ndarray
    fail_time: np.ndarray


def _engine(s: _Setup) -> _Engine:
    from ..compiled.controller import initial_state as ctrl_initial_state
    from ..compiled.controller import pack_controller
    from ..compiled.layouts import ACCUMULATORS
    from ..compiled.noise import generator_states
    from .plant import pack_plant

    B = s.x0.shape[0]
    if s.CA.batch_shape != (B,):
        raise InputError("the compiled backend needs one controller per vehicle")
    p, d = pack_controller(s.CA)
    S, EH = ctrl_initial_state(p, d)
    n_log = (s.N + s.dec - 1) // s.dec if s.dec else 0
    return _Engine(
        p, d, pack_plant(s.PA), S, EH, empty_log(B, n_log), np.zeros(B, dtype=ACCUMULATORS), np.array(s.window),
        generator_states(s.noise.seeds), np.ones(B, dtype=np.bool_), np.zeros(B, dtype=np.int64), np.zeros(B),
    )  # fmt: skip


def _engine_result(e: _Engine) -> tuple[np.ndarray, list[dict[str, Any]], list[dict[str, Any] | None]]:
    failures = _failures(e.fail_code, e.fail_time)
    return e.logs, _metrics_from_acc(e.acc, failures), failures


#: Smallest batch flown with its plants in SIMD lanes (:func:`vtol_impedance.compiled.engine.run_block_lanes`):
#: one full block. Smaller batches fly a vehicle per thread (:func:`~vtol_impedance.compiled.engine.run_block`).
#: Measured on two cores (case A, 20 s, best of three, lanes / vehicle per thread): 2 vehicles 0.33, 4 and 8
#: vehicles 0.65, 16 vehicles 1.37 (one block on one thread against two threads), 24 1.83, 64 2.06. The engines
#: agree to 1e-11 (the estimators in lanes take their sines from ``compiled.vmath``, ``tests/test_lanes.py``).
LANES_MIN_BATCH = 16


def _run_compiled(s: _Setup, progress: ProgressFn | None):
    from ..compiled.engine import run_block, run_block_lanes
    from ..compiled.lanes import W
    from .disturbances import pack_disturbances
    from .plant import pack_state

    e = _engine(s)
    B = s.x0.shape[0]
    dists, series = pack_disturbances(s.dist.items)
    suite = SensorSuite(s.sensors, s.PA, s.dt)
    X = pack_state(s.x0)
    x_park = X.copy()
    hist = np.empty((B, max(suite.k_mocap, suite.k_imu) + 1), dtype=X.dtype)
    hist[:, 0] = X
    hcount = np.ones(B, dtype=np.int64)
    hhead = np.zeros(B, dtype=np.int64)
    block = int(np.clip(CHUNK_VEHICLE_TICKS // B, 50, 5000))  # ticks between progress reports
    lanes = B >= LANES_MIN_BATCH
    fly = run_block_lanes if lanes else run_block
    with _threads_at_most(-(-B // W) if lanes else B):
        for k0 in range(0, s.N, block):
            k1 = min(k0 + block, s.N)
            fly(k0, k1, s.Ts, s.dt, s.n_sub, X, hist, hcount, hhead, suite.k_mocap, suite.k_imu, suite.sigma,
                      e.rng, e.S, e.EH, e.p, e.d, e.pp, dists, series, s.refs, e.alive, e.fail_time, e.fail_code,
                      x_park, e.logs, s.dec, e.acc, e.win)  # fmt: skip
            if progress is not None:
                progress(k1 / s.N)
    return _engine_result(e)


@contextmanager
def _threads_at_most(n: int) -> Iterator[None]:
    """No more of numba's threads (for this thread's parallel calls) than vehicles: a thread with no vehicle
    still has to wake up and join, and on a busy machine that waited up to a scheduler slice (about 5 ms)
    per block for one vehicle, whose own 0.5 s flight takes 0.2 ms."""
    from numba import get_num_threads, set_num_threads

    was = get_num_threads()
    set_num_threads(max(1, min(n, was)))
    try:
        yield
    finally:
        set_num_threads(was)


def _run_mujoco(s: _Setup, progress: ProgressFn | None, plant: Any):
    """The compiled controller flying MuJoCo (:class:`.mjplant.MujocoPlant`): per control tick MuJoCo gives
    the truth and steps the period (one ``rollout`` call); the sensors, the controller, the lumped wrench,
    the log and the metrics are the compiled engine's tick (:func:`vtol_impedance.compiled.engine.control_ticks`)."""
    from ..compiled.engine import control_ticks, failure_codes
    from .plant import pack_state

    e = _engine(s)
    B = s.x0.shape[0]
    sens = SensorSuite(s.sensors, s.PA, s.dt)
    plant.sensor_ages = (sens.k_mocap, sens.k_imu)
    sens.push(plant.x)
    x_park = s.x0.copy()
    F = np.zeros((B, s.PA.spins.shape[-1]))
    report_every = max(s.N // 100, 1)
    X = pack_state(plant.x)
    code = np.zeros(B, dtype=np.int64)
    for k in range(s.N):
        t = k * s.Ts
        a_o, w_dot, f_env, tau_env = plant.truth(t, F)
        env = np.concatenate([f_env, tau_env], -1)
        xm, xi = sens.delayed()
        control_ticks(k, s.Ts, pack_state(xm), pack_state(xi), X, a_o, w_dot, env, sens.sigma, e.rng, e.S, e.EH,
                      e.p, e.d, e.pp, s.refs, e.alive, e.logs, s.dec, e.acc, e.win, F)  # fmt: skip
        plant.advance(t, F, s.n_sub, s.dt, sens.push)
        X = pack_state(plant.x)
        failure_codes(e.pp, X, e.alive, code)
        if _stop_failed(code, t + s.Ts, e.alive, e.fail_code, e.fail_time, plant, x_park):
            X = pack_state(plant.x)
        if progress is not None and (k % report_every == 0 or k == s.N - 1):
            progress((k + 1) / s.N)
    return _engine_result(e)


def _run_numpy(s: _Setup, progress: ProgressFn | None, plant: Any = None):
    """The NumPy controller flying the built-in plant, or ``plant`` (a :class:`.mjplant.MujocoPlant`). Each
    control tick reads as its stages: sense, estimate and control (:func:`controller_step`), log the truth,
    actuate and integrate (``plant.advance``), check."""
    CA, PA = s.CA, s.PA
    B = s.x0.shape[0]
    sens = SensorSuite(s.sensors, PA, s.dt)
    plant = _BuiltinPlant(PA, s.dist, s.x0) if plant is None else plant
    plant.sensor_ages = (sens.k_mocap, sens.k_imu)  # the states the sensors read
    x_park = s.x0.copy()
    sens.push(plant.x)
    CS = initial_controller_state(CA)
    logs = empty_log(B, s.N)
    alive = np.ones(B, dtype=bool)
    fail_code = np.zeros(B, dtype=np.int64)
    fail_time = np.zeros(B)
    report_every = max(s.N // 100, 1)
    for k in range(s.N):
        if k % BLOCK_TICKS == 0:
            noise = s.noise.block(min(BLOCK_TICKS, s.N - k))
        t = k * s.Ts
        meas = sens.measure(noise[:, k % BLOCK_TICKS])  # sense
        ref, given = _reference(s.refs[k]), _reference(s.refs[k], aligned=True)
        held = (CS.thrust_prev, CS.tau_B_prev)  # the command the plant flew over the period that ends now
        CS, out = controller_step(CA, CS, meas, given)  # estimate, control, allocate
        _log_tick(logs, k, alive, _truth_row(s, plant, t, held, meas, ref, out))  # log (the true reference)
        plant.advance(t, out.f_rotor, s.n_sub, s.dt, sens.push)  # actuate, integrate
        _stop_failed(check_vehicles(PA, plant.x), t + s.Ts, alive, fail_code, fail_time, plant, x_park)  # check
        if progress is not None and (k % report_every == 0 or k == s.N - 1):
            progress((k + 1) / s.N)

    failures = _failures(fail_code, fail_time)
    if s.dec == 1:
        return logs, [], failures
    # metrics-only or decimated: the window metrics at the full control rate, as the compiled engine's
    data = rows_to_data(logs, PA.spins.shape[-1])
    res = Result(np.arange(s.N) * s.Ts, [""] * B, data, {"window": list(s.window[:2])}, failures)
    return logs[:, :: s.dec] if s.dec else logs[:, :0], compute_metrics(res), failures


def _reference(r: np.ndarray, aligned: bool = False) -> Reference:
    """One row of :func:`reference_rows` as a :class:`Reference`: the trajectory's, or (``aligned``) the
    one the controllers are given."""
    p, v = (r[18:21], r[21:24]) if aligned else (r[0:3], r[3:6])
    return Reference(p, v, r[6:9], np.asarray(r[9]), np.asarray(r[10]), np.asarray(r[11]), r[12:18])


def _truth_row(
    s: _Setup, plant: Any, t: float, held: tuple[np.ndarray, np.ndarray], meas: Any, ref: Reference, out: Any
) -> dict[str, Any]:
    """Every logged signal at the tick: the true state and wrench (from the plant, at the start of the
    period), what the sensors gave, the reference, and the controller's output and estimate."""
    x = plant.x
    a_o, w_dot, f_env, tau_env = plant.truth(t, out.f_rotor)
    R = quat_to_rotation(x[..., QUAT])
    eta = euler_from_rotation(R)
    f_lump, tau_lump = _lumped_wrench(s.PA, x, a_o, w_dot, R, eta, *held, s.CA.mass, s.CA.I_B)
    p_o, v_o = origin_kinematics(s.PA, x, R)
    return {
        "p_W": p_o, "v_W": v_o, "eta": eta, "omega_B": x[..., OMEGA],
        "p_ref_W": ref.p_W, "v_ref_W": ref.v_W, "psi_ref": ref.psi,
        "p_meas_W": meas.p_W, "v_meas_W": meas.v_W, "eta_meas": meas.eta,
        "eta_d": out.eta_d, "thrust_request": out.thrust_request, "tau_B_request": out.tau_B_request,
        "thrust": out.thrust, "tau_B": out.tau_B, "f_rotor_cmd": out.f_rotor, "f_rotor": x[..., ROTOR],
        "saturated": out.saturated, "tilt_limited": out.tilt_limited, "rp_scale": out.rp_scale,
        "yaw_scale": out.yaw_scale,
        "f_ext_W": f_env, "tau_ext_B": tau_env, "tau_ext_eta": matvec(transpose(euler_rate_matrix_Q(eta)), tau_env),
        "f_lumped_W": f_lump, "tau_lumped_eta": tau_lump,
        "f_hat_W": out.f_hat_W, "tau_hat_eta": out.tau_hat_eta, "tau_hat_B": out.tau_hat_B,
    }  # fmt: skip


def _log_tick(logs: np.ndarray, k: int, alive: np.ndarray, row: dict[str, Any]) -> None:
    """Write tick ``k`` of the vehicles still flying (a stopped vehicle's rows stay as they were: NaN)."""
    n_rotors = row["f_rotor"].shape[-1]
    for name in SIGNALS:
        field = logs[name][:, k, :n_rotors] if "rotors" in SIGNALS[name][0] else logs[name][:, k]
        field[alive] = np.broadcast_to(np.asarray(row[name], dtype=float), field.shape)[alive]


def _stop_failed(
    code: np.ndarray, t_end: float, alive: np.ndarray, fail_code: np.ndarray, fail_time: np.ndarray, plant: Any,
    x_park: np.ndarray,
) -> bool:  # fmt: skip
    """Record the vehicles whose check ``code`` says they fail at ``t_end`` and park them, so that their NaNs
    cannot reach the others' arithmetic (``alive`` is updated in place); whether any did."""
    newly = alive & (code != 0)
    if not np.any(newly):
        return False
    fail_code[newly] = code[newly]
    fail_time[newly] = t_end
    alive &= ~newly
    plant.park(alive, x_park)
    return True


def check_vehicles(PA: PlantArrays, x: np.ndarray) -> np.ndarray:
    """Failure code per vehicle of the states ``x (B, n)`` (0 when healthy; the reasons are
    :data:`vtol_impedance.records.REASONS`)."""
    code = np.zeros(x.shape[0], dtype=np.int64)
    finite = np.all(np.isfinite(x), axis=-1)
    code[~finite] = FAIL_NAN
    R = quat_to_rotation(np.where(finite[:, None], x[:, 6:10], np.array([1.0, 0, 0, 0])))
    tilt = np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0))
    far = finite & (np.linalg.norm(x[:, 0:3], axis=-1) > MAX_DISTANCE_M)
    code[finite & (tilt > MAX_TILT_RAD)] = FAIL_TILT
    code[far & (code == 0)] = FAIL_FAR
    depth = lowest_contact_depth(PA, np.where(finite[:, None], x, 0.0))
    crash = finite & (np.broadcast_to(PA.ground, code.shape) > 0) & (depth > CRASH_DEPTH_M)
    code[crash & (code == 0)] = FAIL_CRASH
    return code
