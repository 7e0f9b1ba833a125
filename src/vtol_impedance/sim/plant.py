"""The true vehicle: rigid body with payload, rotor dynamics, ground contact and rotor drag.

This is deliberately *not* the controller's model. Its state is the composite centre of mass (CoM)
moving in the world NED frame, a unit quaternion for attitude (no Euler singularity in the plant),
the body rate and the four rotor forces:

    x = [p_com_W (3), v_com_W (3), q_WB (4, [w, x, y, z]), omega_B (3), f_rotor (4)]   (17 values)

Forces and moments:

* rotors: eq. (4) with the *true* arm length and drag factor, thrust along ``-z_B`` at the body origin
  (the geometric centre the controller believes is the CoM); a payload moves the CoM by ``c_B``, so the
  thrust has a moment ``-c_B x F`` about the true CoM;
* rotor lag: ``f_dot = (clip(f_cmd) - f) / tau`` with a faster time constant up than down;
* environment: explicit disturbances ``f_dist_W`` (at the body origin) and ``tau_dist_B``, linear rotor
  drag ``-k_drag v`` and a spring-damper ground under the body origin (z = 0 in NED, +z is down).

Newton-Euler about the CoM: ``m a = m g_W - u R e3 + f_env_W``, ``I w_dot = tau - w x I w``.
All functions broadcast over leading batch dimensions.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..conventions import GRAVITY_W, G
from ..errors import InputError, as_finite, positive
from ..model.dynamics import matvec, transpose
from ..model.kinematics import cross, quat_derivative, quat_from_euler, quat_to_rotation
from ..model.mixer import mix
from ..model.vehicle import VehicleParams

N_STATE = 17
P_COM, V_COM, QUAT, OMEGA, ROTOR = slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 13), slice(13, 17)


@dataclass(frozen=True, eq=False)
class PlantParams:
    """The true vehicle and the effects the controller does not model.

    Parameters
    ----------
    vehicle : the bare vehicle's true rigid body and rotors (usually the nominal preset).
    payload_mass : kg, a point mass rigidly attached at ``payload_offset_B`` (m, FRD, from the body origin).
    inertia_scale : true bare inertia = ``inertia_scale * I_B`` elementwise on the diagonal (mismatch).
    arm_length_scale, drag_factor_scale : true ``l``, ``c`` relative to the vehicle's.
    rotor_tau_up, rotor_tau_down : first-order rotor time constants (s); 0 disables the lag.
    rotor_drag : linear drag coefficient, N per m/s of airspeed (0 disables).
    ground : spring-damper ground at z = 0 (NED) under the body origin.
    """

    vehicle: VehicleParams
    payload_mass: float = 0.0
    payload_offset_B: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    arm_length_scale: float = 1.0
    drag_factor_scale: float = 1.0
    rotor_tau_up: float = 0.0125
    rotor_tau_down: float = 0.025
    rotor_drag: float = 0.0
    ground: bool = True
    ground_stiffness: float = 3000.0
    ground_damping: float = 150.0
    ground_friction: float = 20.0

    def __post_init__(self) -> None:
        positive("payload_mass", self.payload_mass, allow_zero=True)
        as_finite("payload_offset_B", self.payload_offset_B, (3,))
        positive("inertia_scale", self.inertia_scale)
        positive("arm_length_scale", self.arm_length_scale)
        positive("drag_factor_scale", self.drag_factor_scale)
        positive("rotor_tau_up", self.rotor_tau_up, allow_zero=True)
        positive("rotor_tau_down", self.rotor_tau_down, allow_zero=True)
        positive("rotor_drag", self.rotor_drag, allow_zero=True)
        positive("ground_stiffness", self.ground_stiffness)
        positive("ground_damping", self.ground_damping, allow_zero=True)
        positive("ground_friction", self.ground_friction, allow_zero=True)
        if np.shape(self.inertia_scale) not in ((), (3,)):
            raise InputError(f"inertia_scale must be a scalar or 3 values, got {self.inertia_scale}")

    @property
    def total_mass(self) -> float:
        return self.vehicle.mass + float(self.payload_mass)

    def to_dict(self) -> dict:
        return {
            "vehicle": self.vehicle.to_dict(),
            "payload_mass": float(self.payload_mass),
            "payload_offset_B": list(map(float, self.payload_offset_B)),
            "inertia_scale": list(np.broadcast_to(np.asarray(self.inertia_scale, float), (3,))),
            "arm_length_scale": self.arm_length_scale,
            "drag_factor_scale": self.drag_factor_scale,
            "rotor_tau_up": self.rotor_tau_up,
            "rotor_tau_down": self.rotor_tau_down,
            "rotor_drag": self.rotor_drag,
            "ground": self.ground,
            "ground_stiffness": self.ground_stiffness,
            "ground_damping": self.ground_damping,
            "ground_friction": self.ground_friction,
        }


class PlantArrays(NamedTuple):
    """Derived true quantities, each with a leading batch shape (``()`` for one vehicle)."""

    mass: np.ndarray
    I_com: np.ndarray  # about the composite CoM, body axes
    I_com_inv: np.ndarray
    c_B: np.ndarray  # CoM position from the body origin, FRD
    arm_length: np.ndarray
    drag_factor: np.ndarray
    f_max: np.ndarray
    f_min: np.ndarray
    tau_up: np.ndarray
    tau_down: np.ndarray
    rotor_drag: np.ndarray
    ground: np.ndarray  # 1.0 / 0.0
    k_ground: np.ndarray
    c_ground: np.ndarray
    b_ground: np.ndarray

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.mass.shape


def _point_inertia(m: float, r: np.ndarray) -> np.ndarray:
    return m * (np.dot(r, r) * np.eye(3) - np.outer(r, r))


def compile_plant_one(P: PlantParams) -> dict[str, np.ndarray]:
    v = P.vehicle
    m_b, m_p = v.mass, float(P.payload_mass)
    m = m_b + m_p
    r_p = np.asarray(P.payload_offset_B, dtype=float)
    c = m_p * r_p / m
    scale = np.broadcast_to(np.asarray(P.inertia_scale, dtype=float), (3,))
    I_bare = v.inertia * np.sqrt(np.outer(scale, scale))  # scales the diagonal by `scale`
    I_com = I_bare + _point_inertia(m_b, -c) + _point_inertia(m_p, r_p - c)
    return {
        "mass": m,
        "I_com": I_com,
        "I_com_inv": np.linalg.inv(I_com),
        "c_B": c,
        "arm_length": v.arm_length * P.arm_length_scale,
        "drag_factor": v.drag_factor * P.drag_factor_scale,
        "f_max": v.f_max,
        "f_min": v.f_min,
        "tau_up": P.rotor_tau_up,
        "tau_down": P.rotor_tau_down,
        "rotor_drag": P.rotor_drag,
        "ground": 1.0 if P.ground else 0.0,
        "k_ground": P.ground_stiffness,
        "c_ground": P.ground_damping,
        "b_ground": P.ground_friction,
    }


def compile_plants(params: PlantParams | list[PlantParams]) -> PlantArrays:
    """Arrays for one plant (batch shape ``()``) or a list of plants (batch shape ``(B,)``)."""
    single = isinstance(params, PlantParams)
    dicts = [compile_plant_one(p) for p in ([params] if single else params)]
    if not dicts:
        raise InputError("no plant given")
    out = {k: np.array([d[k] for d in dicts], dtype=float) for k in PlantArrays._fields}
    if single:
        out = {k: v[0] for k, v in out.items()}
    return PlantArrays(**out)


def initial_state(
    P: PlantArrays, p_origin_W: np.ndarray, eta: np.ndarray | None = None, hover_rotors: bool = True
) -> np.ndarray:
    """State at rest with the body origin at ``p_origin_W`` and attitude ``eta`` (default level).

    Rotor forces start at the thrust that holds the true weight (``hover_rotors``) or at zero.
    """
    bs = P.batch_shape
    eta = np.zeros(3) if eta is None else np.asarray(eta, dtype=float)
    x = np.zeros(bs + (N_STATE,))
    q = np.broadcast_to(quat_from_euler(eta), bs + (4,))
    R = quat_to_rotation(q)
    x[..., P_COM] = np.asarray(p_origin_W, dtype=float) + matvec(R, P.c_B)
    x[..., QUAT] = q
    if hover_rotors:
        x[..., ROTOR] = np.clip(P.mass * G / 4.0, P.f_min, P.f_max)[..., None]
    return x


def origin_kinematics(P: PlantArrays, x: np.ndarray, R: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity of the body origin (where motion capture markers sit)."""
    R = quat_to_rotation(x[..., QUAT]) if R is None else R
    w = x[..., OMEGA]
    p_o = x[..., P_COM] - matvec(R, P.c_B)
    v_o = x[..., V_COM] - matvec(R, cross(w, P.c_B))
    return p_o, v_o


DisturbanceFn = Callable[[float, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def environment_wrench(
    P: PlantArrays, t: float, x: np.ndarray, R: np.ndarray, dist: DisturbanceFn | None
) -> tuple[np.ndarray, np.ndarray]:
    """Total external force (world, at the body origin) and moment (body, about the origin).

    Disturbances ``dist(t, p_o_W, v_o_W, R_WB)`` plus rotor drag plus ground contact: everything
    except gravity and the rotors.
    """
    p_o, v_o = origin_kinematics(P, x, R)
    if dist is None:
        f_d, tau = np.zeros(p_o.shape), np.zeros(p_o.shape)
    else:
        f_d, tau = dist(t, p_o, v_o, R)
    f = f_d - P.rotor_drag[..., None] * v_o
    pen = p_o[..., 2]  # > 0 means below the ground plane
    in_contact = (pen > 0.0) & (P.ground > 0.0)
    fz = -(P.k_ground * pen + P.c_ground * v_o[..., 2])
    fz = np.where(in_contact, np.minimum(fz, 0.0), 0.0)  # the ground pushes, never pulls
    fxy = np.where(in_contact[..., None], -P.b_ground[..., None] * v_o[..., :2], 0.0)
    f = f + np.concatenate([fxy, fz[..., None]], -1)
    return f, np.broadcast_to(tau, f.shape)


def plant_derivative(
    P: PlantArrays, x: np.ndarray, f_cmd: np.ndarray, t: float = 0.0, dist: DisturbanceFn | None = None
) -> np.ndarray:
    """``x_dot`` of the true plant for held rotor commands ``f_cmd (..., 4)`` and disturbances ``dist``."""
    q = x[..., QUAT]
    w = x[..., OMEGA]
    f = x[..., ROTOR]
    R = quat_to_rotation(q)
    f_env_W, tau_env_B = environment_wrench(P, t, x, R, dist)
    u, tau_mix_B = mix(f, P.arm_length, P.drag_factor)
    z_B = R[..., :, 2]
    F_W = -u[..., None] * z_B + f_env_W  # everything applied at the body origin
    a = GRAVITY_W + F_W / P.mass[..., None]
    F_B = matvec(transpose(R), F_W)
    tau_com = tau_mix_B + tau_env_B - cross(P.c_B, F_B)
    Iw = matvec(P.I_com, w)
    w_dot = matvec(P.I_com_inv, tau_com - cross(w, Iw))
    target = np.clip(f_cmd, P.f_min[..., None], P.f_max[..., None])
    tau = np.where(target > f, P.tau_up[..., None], P.tau_down[..., None])
    f_dot = np.where(tau > 0, (target - f) / np.maximum(tau, 1e-12), 0.0)
    return np.concatenate([x[..., V_COM], a, quat_derivative(q, w), w_dot, f_dot], -1)


def apply_instant_rotors(P: PlantArrays, x: np.ndarray, f_cmd: np.ndarray) -> np.ndarray:
    """Where a rotor has no lag (time constant 0), its force follows the command at once."""
    lagless = (P.tau_up <= 0) | (P.tau_down <= 0)
    if not np.any(lagless):
        return x
    x = x.copy()
    target = np.clip(f_cmd, P.f_min[..., None], P.f_max[..., None])
    x[..., ROTOR] = np.where(np.asarray(lagless)[..., None], target, x[..., ROTOR])
    return x


def disturbance_at(P: PlantArrays, t: float, x: np.ndarray, dist: DisturbanceFn | None) -> DisturbanceFn | None:
    """The disturbances evaluated once at ``(t, x)``, as a function that returns those values.

    The simulator holds explicit disturbances over each plant step (1 ms by default): they are
    band-limited far below 1 kHz, and one evaluation per step rather than per RK4 stage is what the
    compiled backend does too.
    """
    if dist is None:
        return None
    R = quat_to_rotation(x[..., QUAT])
    p_o, v_o = origin_kinematics(P, x, R)
    f, tau = dist(t, p_o, v_o, R)

    def held(t_, p_, v_, R_):  # noqa: ANN001, ANN202
        return f, tau

    return held


def rk4_step(
    P: PlantArrays, x: np.ndarray, f_cmd: np.ndarray, t: float, dt: float, dist: DisturbanceFn | None = None
) -> np.ndarray:
    """One classical Runge-Kutta step with the rotor command and the disturbances (evaluated at the
    start, :func:`disturbance_at`) held; renormalises the quaternion."""
    held = disturbance_at(P, t, x, dist)
    k1 = plant_derivative(P, x, f_cmd, t, held)
    k2 = plant_derivative(P, x + 0.5 * dt * k1, f_cmd, t + 0.5 * dt, held)
    k3 = plant_derivative(P, x + 0.5 * dt * k2, f_cmd, t + 0.5 * dt, held)
    k4 = plant_derivative(P, x + dt * k3, f_cmd, t + dt, held)
    xn = x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    q = xn[..., QUAT]
    xn[..., QUAT] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return xn
