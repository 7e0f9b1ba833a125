"""Closed loop: true plant at the plant rate (fixed-step RK4), controller and estimator at the control rate.

Timing per control period ``Ts`` (ZOH): sensors are read, the controller computes rotor forces from the
estimate of the period that just ended, and the forces are held while the plant takes ``Ts / dt`` RK4
steps. Logged signals are sampled at the control instants.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..control.impedance import (
    ControllerParams,
    compile_controllers,
    controller_step,
    initial_controller_state,
)
from ..control.reference import Trajectory
from ..conventions import E3, GRAVITY_W
from ..errors import InputError, positive
from ..model.dynamics import coriolis_matrix_C, inertia_matrix_M, matvec, transpose
from ..model.kinematics import (
    cross,
    euler_from_rotation,
    euler_rate_matrix_Q,
    euler_rate_matrix_Q_dot,
    quat_to_rotation,
)
from .disturbances import Disturbance, DisturbanceSet
from .plant import (
    OMEGA,
    QUAT,
    V_COM,
    PlantArrays,
    PlantParams,
    apply_instant_rotors,
    compile_plants,
    environment_wrench,
    initial_state,
    origin_kinematics,
    plant_derivative,
    rk4_step,
)
from .result import SIGNALS, Result
from .sensors import SensorParams, SensorSuite

#: A vehicle is stopped and flagged when its tilt exceeds this (the Euler parametrisation fails at 90 deg).
MAX_TILT_RAD = np.radians(80.0)
MAX_DISTANCE_M = 1e3

ProgressFn = Callable[[float], None]


def _lumped_wrench(
    PA: PlantArrays,
    x: np.ndarray,
    x_dot: np.ndarray,
    R: np.ndarray,
    eta: np.ndarray,
    thrust_prev: np.ndarray,
    tau_B_prev: np.ndarray,
    mass_nom: np.ndarray,
    I_nom: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """What the nominal model (5) misses, given the true motion: the estimator's target.

    ``f = m (a_o - g_W) + u R e3`` and ``tau_eta = M eta_ddot + C eta_dot - Q^T tau_B`` with nominal
    ``m``, ``I_B``, the true acceleration ``a_o`` of the body origin and the command held over the period.
    """
    w = x[..., OMEGA]
    w_dot = x_dot[..., OMEGA]
    c = PA.c_B
    a_o = x_dot[..., V_COM] - matvec(R, cross(w_dot, c) + cross(w, cross(w, c)))
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


def run_closed_loop(
    plant: PlantParams | Sequence[PlantParams],
    controllers: Sequence[ControllerParams],
    trajectory: Trajectory,
    duration: float,
    disturbances: Sequence[Disturbance] = (),
    sensors: SensorParams | None = None,
    plant_rate: float = 1000.0,
    seed: int = 0,
    labels: Sequence[str] | None = None,
    start_W: np.ndarray | None = None,
    progress: ProgressFn | None = None,
    config: dict[str, Any] | None = None,
) -> Result:
    """Fly ``B = len(controllers)`` vehicles through the same trajectory and disturbance realisation.

    Parameters
    ----------
    plant : one true plant for all vehicles, or one per vehicle.
    controllers : nominal controllers, one per vehicle (they must share the control period).
    trajectory : reference; the run starts at ``start_W`` (default: the trajectory's first point).
    disturbances : explicit external disturbances, prepared once from ``seed``.
    sensors : noise and latency (default :class:`SensorParams`); use ``SensorParams.ideal()`` for none.
    plant_rate : RK4 rate in Hz; ``plant_rate * Ts`` must be an integer.
    progress : called with the fraction done.
    """
    controllers = list(controllers)
    B = len(controllers)
    if B == 0:
        raise InputError("no controller given")
    plants = [plant] * B if isinstance(plant, PlantParams) else list(plant)
    if len(plants) != B:
        raise InputError(f"{len(plants)} plants given for {B} controllers")
    labels = list(labels) if labels is not None else [c.variant for c in controllers]
    if len(labels) != B:
        raise InputError(f"{len(labels)} labels given for {B} controllers")
    duration = float(positive("duration", duration))
    plant_rate = float(positive("plant_rate", plant_rate))
    sensors = SensorParams() if sensors is None else sensors

    CA = compile_controllers(controllers)
    Ts = CA.Ts
    dt = 1.0 / plant_rate
    n_sub = int(round(Ts / dt))
    if n_sub < 1 or abs(n_sub * dt - Ts) > 1e-9 * Ts:
        raise InputError(f"plant_rate * Ts must be a whole number >= 1, got {plant_rate} Hz * {Ts} s")
    N = int(round(duration / Ts))

    PA = compile_plants(plants)
    seeds = np.random.SeedSequence(seed).spawn(1 + len(disturbances))
    sens = SensorSuite(sensors, PA, dt, np.random.default_rng(seeds[0]))
    dist = DisturbanceSet(
        [d.prepare(duration + Ts, dt, np.random.default_rng(s)) for d, s in zip(disturbances, seeds[1:], strict=True)]
    )

    start = trajectory.sample(0.0).p_W if start_W is None else np.asarray(start_W, dtype=float)
    x = initial_state(PA, np.broadcast_to(start, (B, 3)))
    x_park = x.copy()
    sens.push(x)
    CS = initial_controller_state(CA)

    logs = {k: np.full((B, N) + shape, np.nan) for k, (shape, _, _) in SIGNALS.items()}
    alive = np.ones(B, dtype=bool)
    failures: list[dict[str, Any] | None] = [None] * B
    t_grid = np.arange(N) * Ts
    report_every = max(N // 100, 1)

    for k in range(N):
        t = t_grid[k]
        meas = sens.measure()
        ref = trajectory.sample(t)
        thrust_prev, tau_prev = CS.thrust_prev, CS.tau_B_prev
        CS, out = controller_step(CA, CS, meas, ref)

        # True and lumped wrenches at t_k, for logging.
        x_dot = plant_derivative(PA, x, out.f_rotor, t, dist)
        R = quat_to_rotation(x[..., QUAT])
        eta = euler_from_rotation(R)
        f_env, tau_env = environment_wrench(PA, t, x, R, dist)
        f_lump, tau_lump = _lumped_wrench(PA, x, x_dot, R, eta, thrust_prev, tau_prev, CA.mass, CA.I_B)
        p_o, v_o = origin_kinematics(PA, x, R)
        row = {
            "p_W": p_o,
            "v_W": v_o,
            "eta": eta,
            "omega_B": x[..., OMEGA],
            "p_ref_W": ref.p_W,
            "v_ref_W": ref.v_W,
            "psi_ref": ref.psi,
            "p_meas_W": meas.p_W,
            "v_meas_W": meas.v_W,
            "eta_meas": meas.eta,
            "eta_d": out.eta_d,
            "thrust_request": out.thrust_request,
            "tau_B_request": out.tau_B_request,
            "thrust": out.thrust,
            "tau_B": out.tau_B,
            "f_rotor_cmd": out.f_rotor,
            "f_rotor": x[..., 13:17],
            "saturated": out.saturated,
            "f_ext_W": f_env,
            "tau_ext_B": tau_env,
            "tau_ext_eta": matvec(transpose(euler_rate_matrix_Q(eta)), tau_env),
            "f_lumped_W": f_lump,
            "tau_lumped_eta": tau_lump,
            "f_hat_W": out.f_hat_W,
            "tau_hat_eta": out.tau_hat_eta,
            "tau_hat_B": out.tau_hat_B,
        }
        for name, val in row.items():
            logs[name][alive, k] = np.broadcast_to(val, (B,) + SIGNALS[name][0])[alive]

        x = apply_instant_rotors(PA, x, out.f_rotor)
        for j in range(n_sub):
            x = rk4_step(PA, x, out.f_rotor, t + j * dt, dt, dist)
            sens.push(x)

        reason = _check_vehicles(x)
        newly = alive & (reason != "")
        if np.any(newly):
            for b in np.flatnonzero(newly):
                failures[b] = {"time": float(t + Ts), "reason": str(reason[b])}
            alive &= ~newly
            # Park failed vehicles so that their NaNs cannot reach the others' arithmetic.
            x = np.where(alive[:, None], x, x_park)
        if progress is not None and (k % report_every == 0 or k == N - 1):
            progress((k + 1) / N)

    cfg = dict(config or {})
    cfg.update(
        {
            "seed": int(seed),
            "duration": duration,
            "plant_rate": plant_rate,
            "control_period": Ts,
            "labels": labels,
            "controllers": [c.to_dict() for c in controllers],
            "plants": [p.to_dict() for p in plants],
            "sensors": {k: getattr(sensors, k) for k in sensors.__dataclass_fields__},
            "disturbances": [d.to_dict() for d in disturbances],
        }
    )
    return Result(t_grid, labels, logs, cfg, failures)


def _check_vehicles(x: np.ndarray) -> np.ndarray:
    """Reason string per vehicle ('' when healthy): non-finite state, excessive tilt or flyaway."""
    reason = np.full(x.shape[0], "", dtype=object)
    finite = np.all(np.isfinite(x), axis=-1)
    reason[~finite] = "non-finite state"
    R = quat_to_rotation(np.where(finite[:, None], x[:, 6:10], np.array([1.0, 0, 0, 0])))
    tilt = np.arccos(np.clip(R[:, 2, 2], -1.0, 1.0))
    reason[finite & (tilt > MAX_TILT_RAD)] = f"tilt above {np.degrees(MAX_TILT_RAD):.0f} deg"
    far = finite & (np.linalg.norm(x[:, 0:3], axis=-1) > MAX_DISTANCE_M)
    reason[far] = f"more than {MAX_DISTANCE_M:.0f} m from the origin"
    return reason
