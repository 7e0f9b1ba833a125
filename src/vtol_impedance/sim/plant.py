"""The true vehicle: rigid body with payload, rotor dynamics, ground contact and rotor drag.

This is deliberately *not* the controller's model. Its state is the composite centre of mass (CoM)
moving in the world NED frame, a unit quaternion for attitude (no Euler singularity in the plant),
the body rate and the four rotor forces:

    x = [p_com_W (3), v_com_W (3), q_WB (4, [w, x, y, z], body to world), omega_B (3), f_rotor (n)]
                                                                                  (13 + n values)

Forces and moments:

* rotors: the *true* rotor geometry (the vehicle's rotors with positions scaled by ``arm_length_scale``
  and the drag factor by ``drag_factor_scale``): rotor ``i`` pushes ``f_i`` along ``-z_B`` at ``r_i``
  and adds the yaw reaction ``s_i c f_i e3``, summed here from the cross products ``r_i x (-f_i e3)``
  (not from the controller's effectiveness matrix); a payload moves the CoM by ``c_B``, so the
  thrust has a moment ``-c_B x F`` about the true CoM;
* rotor lag: ``f_dot = (clip(f_cmd) - f) / tau`` with a faster time constant up than down;
* environment: explicit disturbances ``f_dist_W`` (at the body origin) and ``tau_dist_B``, the true
  vehicle's aerodynamic force ``R (-D v_B - |v_B| C v_B)`` at the body origin (rotor drag, inflow damping,
  body drag: :mod:`vtol_impedance.model.aero`) and a spring-damper ground (z = 0 in NED, +z is down) acting
  at two contact points: the body origin (the landing gear the controller's position refers to) and the
  payload (which touches first when it hangs below).

Newton-Euler about the CoM: ``m a = m g_W - u R e3 + f_env_W``, ``I w_dot = tau - w x I w``.
All functions broadcast over leading batch dimensions.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import NamedTuple

import numpy as np

from ..conventions import GRAVITY_W, G
from ..errors import InputError, as_finite, batched, instance, positive, scalar
from ..model.aero import aero_force_B
from ..model.dynamics import matvec, transpose
from ..model.kinematics import cross, quat_derivative, quat_from_euler, quat_to_rotation
from ..model.vehicle import MAX_ROTORS, VehicleParams, distinct_vehicles, effectiveness

#: State length without the rotors and the pendulum; the state is ``N_BODY + n_rotors + N_PEND`` long:
#: ``[p_com, v_com, q, omega_B, rotor forces (n), pendulum bob from the joint r_W (3), its rate (3)]``.
N_BODY = 13
N_PEND = 6
P_COM, V_COM, QUAT, OMEGA = slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 13)
ROTOR, PEND_R, PEND_V = slice(13, -N_PEND), slice(-6, -3), slice(-3, None)


def state_size(n_rotors: int) -> int:
    return N_BODY + n_rotors + N_PEND


@dataclass(frozen=True, eq=False)
class PlantParams:
    """The true vehicle and the effects the controller does not model.

    Parameters
    ----------
    vehicle : VehicleParams
        The bare vehicle's true rigid body and rotors (usually the nominal preset).
    payload_mass : float
        Mass (kg) of a point payload rigidly attached at ``payload_offset_B``.
    payload_offset_B : tuple of float
        Where the payload sits, m, body FRD frame, from the body origin.
    inertia_scale : tuple of float
        True bare inertia = ``inertia_scale * I_B`` elementwise on the diagonal (mismatch).
    arm_length_scale, drag_factor_scale : float
        True ``l`` and ``c`` relative to the vehicle's.
    rotor_tau_up, rotor_tau_down : float
        First-order rotor time constants, s, spinning up and down; 0 makes that direction instant (the
        other keeps its lag).
    rotor_drag : float
        Isotropic linear drag, N per m/s of airspeed (0 disables): the shorthand for a vehicle whose
        ``rotor_drag`` and ``inflow_damping`` are all this number (``D = k I``, the same force
        ``-k v`` in any frame). One drag model: a vehicle that describes its own rotor drag or inflow
        damping flies with those, and giving this too is refused.
    ground : bool
        A spring-damper ground at z = 0 (NED) under the body origin.
    ground_stiffness, ground_damping, ground_friction : float
        The ground's spring (N/m), damper (N s/m) and friction (N s/m on the sliding velocity).
    pendulum_mass, pendulum_length : float
        A bob (kg) on a rigid link (m) hung from the centre of mass, simulated as a second body; 0 kg: none.
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
    pendulum_mass: float = 0.0
    pendulum_length: float = 0.5

    def __post_init__(self) -> None:
        if not isinstance(self.vehicle, VehicleParams):
            raise InputError(f"PlantParams.vehicle must be a VehicleParams, got {type(self.vehicle).__name__}")
        object.__setattr__(self, "payload_mass", scalar("payload_mass", self.payload_mass, lo=0.0))
        off = as_finite("payload_offset_B", self.payload_offset_B, (3,))
        if off.shape != (3,) or np.linalg.norm(off) > 10.0:
            raise InputError(f"payload_offset_B must be 3 values within 10 m of the body origin, got {off.tolist()}")
        object.__setattr__(self, "payload_offset_B", tuple(float(v) for v in off))
        scale = positive("inertia_scale", self.inertia_scale)
        if scale.shape not in ((), (3,)):
            raise InputError(f"inertia_scale must be a scalar or 3 values, got {self.inertia_scale!r}")
        object.__setattr__(self, "inertia_scale", tuple(float(v) for v in np.broadcast_to(scale, (3,))))
        for name in ("arm_length_scale", "drag_factor_scale", "ground_stiffness"):
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0, lo_open=True))
        for name in ("rotor_tau_up", "rotor_tau_down"):
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0, hi=10.0))
        for name in ("rotor_drag", "ground_damping", "ground_friction"):
            object.__setattr__(self, name, scalar(name, getattr(self, name), lo=0.0))
        if self.rotor_drag > 0 and any(self.vehicle.linear_drag_B):
            raise InputError(
                f"rotor_drag = {self.rotor_drag:g} N per m/s (isotropic) and vehicle {self.vehicle.name!r}'s own "
                f"rotor_drag {list(self.vehicle.rotor_drag)} / inflow_damping {self.vehicle.inflow_damping:g} are "
                "the same drag: give it once (in a scenario, leave plant.rotor_drag unset to fly the vehicle's)"
            )
        if not isinstance(self.ground, bool | np.bool_):
            raise InputError(f"ground must be true or false, got {self.ground!r}")
        object.__setattr__(self, "pendulum_mass", scalar("pendulum_mass", self.pendulum_mass, lo=0.0, hi=1e3))
        object.__setattr__(
            self, "pendulum_length", scalar("pendulum_length", self.pendulum_length, lo=0.0, hi=100.0, lo_open=True)
        )

    @property
    def total_mass(self) -> float:
        return self.vehicle.mass + float(self.payload_mass)

    def to_dict(self, memo: dict[int, dict] | None = None) -> dict:
        """The plant as plain data (``memo``: as :meth:`VehicleParams.to_dict`)."""
        return {
            "vehicle": self.vehicle.to_dict(memo),
            "payload_mass": float(self.payload_mass),
            "payload_offset_B": list(map(float, self.payload_offset_B)),
            "inertia_scale": list(self.inertia_scale),  # three floats (__post_init__)
            "arm_length_scale": self.arm_length_scale,
            "drag_factor_scale": self.drag_factor_scale,
            "rotor_tau_up": self.rotor_tau_up,
            "rotor_tau_down": self.rotor_tau_down,
            "rotor_drag": self.rotor_drag,
            "ground": self.ground,
            "ground_stiffness": self.ground_stiffness,
            "ground_damping": self.ground_damping,
            "ground_friction": self.ground_friction,
            "pendulum_mass": self.pendulum_mass,
            "pendulum_length": self.pendulum_length,
        }


class PlantArrays(NamedTuple):
    """Derived true quantities, each with a leading batch shape (``()`` for one vehicle)."""

    mass: np.ndarray
    I_com: np.ndarray  # about the composite CoM, body axes
    I_com_inv: np.ndarray
    c_B: np.ndarray  # CoM position from the body origin, FRD
    r_contact_B: np.ndarray  # the second ground contact point (the payload), FRD from the body origin
    rotor_pos_B: np.ndarray  # (..., n, 3) true rotor positions, FRD from the body origin
    spins: np.ndarray  # (..., n)
    drag_factor: np.ndarray
    E: np.ndarray  # (..., 4, n) true effectiveness (for the compiled kernels)
    f_max: np.ndarray  # (..., n)
    f_min: np.ndarray  # (..., n)
    tau_up: np.ndarray
    tau_down: np.ndarray
    lin_drag_B: np.ndarray  # (..., 3) rotor drag d_x, d_y and inflow damping d_z, N s/m, body axes
    quad_drag_B: np.ndarray  # (..., 3) body drag, N s^2/m^2, body axes
    ground: np.ndarray  # 1.0 / 0.0
    k_ground: np.ndarray
    c_ground: np.ndarray
    b_ground: np.ndarray
    pend_m: np.ndarray  # kg, 0: no pendulum
    pend_L: np.ndarray  # m

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.mass.shape


def _point_inertia(m: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Inertia ``m (|r|^2 1 - r r^T)`` of point masses ``m (B,)`` at ``r (B, 3)``: ``(B, 3, 3)``."""
    rr = r[:, 0] * r[:, 0] + r[:, 1] * r[:, 1] + r[:, 2] * r[:, 2]
    return m[:, None, None] * (rr[:, None, None] * np.eye(3) - r[:, :, None] * r[:, None, :])


def compile_plants(params: PlantParams | list[PlantParams]) -> PlantArrays:
    """Arrays for one plant (batch shape ``()``) or a list of plants (batch shape ``(B,)``).

    The true rigid body: mass ``m = m_b + m_p``, CoM ``c = m_p r_p / m`` from the body origin, inertia
    about ``c`` by the parallel-axis theorem, rotors scaled by ``arm_length_scale``. Computed for the whole
    list at once (a 10,000-vehicle population compiles in milliseconds); vehicles shared by several plants
    are read once.
    """
    single = isinstance(params, PlantParams)
    plist = [params] if single else list(params) if hasattr(params, "__iter__") and not isinstance(params, str) else []
    if not plist or not all(isinstance(p, PlantParams) for p in plist):
        raise InputError(f"params must be one PlantParams or a non-empty list of them, got {params!r:.80}")
    vehicles, iv = distinct_vehicles([p.vehicle for p in plist])
    nr = {v.n_rotors for v in vehicles}
    if len(nr) > 1:
        raise InputError(f"plants in one batch must have the same number of rotors, got {sorted(nr)}")
    geo = [v.geometry for v in vehicles]

    def col(name: str) -> np.ndarray:
        return np.array([getattr(p, name) for p in plist], dtype=float)

    m_b = np.array([v.mass for v in vehicles])[iv]
    m_p = col("payload_mass")
    m = m_b + m_p
    r_p = col("payload_offset_B")
    c = m_p[:, None] * r_p / m[:, None]
    scale = col("inertia_scale")
    I_bare = np.array([v.inertia for v in vehicles])[iv] * np.sqrt(scale[:, :, None] * scale[:, None, :])
    I_com = I_bare + _point_inertia(m_b, -c) + _point_inertia(m_p, r_p - c)
    pos = np.array([g.positions_B for g in geo])[iv] * col("arm_length_scale")[:, None, None]
    spins = np.array([g.spins for g in geo], dtype=float)[iv]
    cq = np.array([v.drag_factor for v in vehicles])[iv] * col("drag_factor_scale")
    out = {
        "mass": m,
        "I_com": I_com,
        "I_com_inv": np.linalg.inv(I_com),
        "c_B": c,
        "r_contact_B": np.where((m_p > 0)[:, None], r_p, 0.0),
        "rotor_pos_B": pos,
        "spins": spins,
        "drag_factor": cq,
        "E": effectiveness(pos, spins, cq),
        "f_max": np.array([g.f_max for g in geo], dtype=float)[iv],
        "f_min": np.array([g.f_min for g in geo], dtype=float)[iv],
        "tau_up": col("rotor_tau_up"),
        "tau_down": col("rotor_tau_down"),
        # one linear drag: the vehicle's, or the plant's isotropic shorthand (never both, PlantParams)
        "lin_drag_B": np.array([v.linear_drag_B for v in vehicles])[iv] + col("rotor_drag")[:, None],
        "quad_drag_B": np.array([v.body_drag for v in vehicles], dtype=float)[iv],
        "ground": col("ground"),
        "k_ground": col("ground_stiffness"),
        "c_ground": col("ground_damping"),
        "b_ground": col("ground_friction"),
        "pend_m": col("pendulum_mass"),
        "pend_L": col("pendulum_length"),
    }
    if single:
        out = {k: v[0] for k, v in out.items()}
    return PlantArrays(**out)


def initial_state(
    P: PlantArrays, p_origin_W: np.ndarray, eta: np.ndarray | None = None, hover_rotors: bool = True
) -> np.ndarray:
    """State at rest with the body origin at ``p_origin_W`` and attitude ``eta`` (default level).

    Rotor forces start at the thrust that holds the true weight (``hover_rotors``, shared by the thrust
    shares of the pseudo-inverse) or at zero.
    """
    bs = P.batch_shape
    n = P.spins.shape[-1]
    eta = np.zeros(3) if eta is None else np.asarray(eta, dtype=float)
    x = np.zeros(bs + (state_size(n),))
    q = np.broadcast_to(quat_from_euler(eta), bs + (4,))
    R = quat_to_rotation(q)
    x[..., P_COM] = np.asarray(p_origin_W, dtype=float) + matvec(R, P.c_B)
    x[..., QUAT] = q
    if hover_rotors:
        x[..., ROTOR] = np.clip(((P.mass + P.pend_m) * G)[..., None] / n, P.f_min, P.f_max)
    x[..., PEND_R.start + 2] = P.pend_L  # the bob hangs straight down (NED z), at rest
    return x


def link_force(P: PlantArrays, x: np.ndarray, F_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pendulum: a point mass ``pend_m`` on a rigid massless link of length ``pend_L`` whose spherical
    joint sits at the vehicle's centre of mass (so the link exerts no moment).

    With ``F_W`` every non-gravity force on the vehicle, ``n = r / |r|`` from the joint to the bob and the
    constraint ``n . r'' = -|r'|^2 / L``, the link tension is ``T = (|r'|^2 / L - n . F_W / m) / (1/m_l + 1/m)``
    (``m_l g`` hanging at rest). Returns the force on the vehicle ``T n`` (world) and ``r''``, the bob's
    acceleration relative to the joint. Zero without a pendulum.
    """
    r, rd = x[..., PEND_R], x[..., PEND_V]
    m, ml = P.mass, P.pend_m
    has = ml > 0
    L = np.maximum(np.linalg.norm(r, axis=-1), 1e-9)
    n = r / L[..., None]
    T = (np.sum(rd * rd, -1) / L - np.sum(n * F_W, -1) / m) / (1.0 / np.maximum(ml, 1e-300) + 1.0 / m)
    T = np.where(has, T, 0.0)
    f_link = T[..., None] * n
    r_dd = -(T / np.maximum(ml, 1e-300))[..., None] * n - (F_W + f_link) / m[..., None]
    return f_link, np.where(has[..., None], r_dd, 0.0)


def project_pendulum(P: PlantArrays, x: np.ndarray) -> np.ndarray:
    """Put the bob back on its sphere (``|r| = L``, no radial rate) after an integration step."""
    has = P.pend_m > 0
    if not np.any(has):
        return x
    r, rd = x[..., PEND_R], x[..., PEND_V]
    n = r / np.maximum(np.linalg.norm(r, axis=-1, keepdims=True), 1e-9)
    x = x.copy()
    x[..., PEND_R] = np.where(has[..., None], P.pend_L[..., None] * n, r)
    x[..., PEND_V] = np.where(has[..., None], rd - np.sum(rd * n, -1, keepdims=True) * n, rd)
    return x


def origin_kinematics(P: PlantArrays, x: np.ndarray, R: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Position and velocity of the body origin (where motion capture markers sit)."""
    return point_kinematics(P, x, np.zeros(3), R)


def point_kinematics(
    P: PlantArrays, x: np.ndarray, r_B: np.ndarray, R: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """World position and velocity of the body point ``r_B`` (FRD, from the body origin)."""
    R = quat_to_rotation(x[..., QUAT]) if R is None else R
    w = x[..., OMEGA]
    d = np.asarray(r_B, dtype=float) - P.c_B  # from the CoM
    return x[..., P_COM] + matvec(R, d), x[..., V_COM] + matvec(R, cross(w, d))


def lowest_contact_depth(P: PlantArrays, x: np.ndarray) -> np.ndarray:
    """Depth below the ground plane (m, > 0 underground) of the lower of the two contact points."""
    R = quat_to_rotation(x[..., QUAT])
    z_o = point_kinematics(P, x, np.zeros(3), R)[0][..., 2]
    z_p = point_kinematics(P, x, P.r_contact_B, R)[0][..., 2]
    return np.maximum(z_o, z_p)


DisturbanceFn = Callable[[float, np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _ground_force(P: PlantArrays, p_W: np.ndarray, v_W: np.ndarray) -> np.ndarray:
    """Spring-damper ground with viscous friction at one contact point: pushes, never pulls."""
    pen = p_W[..., 2]  # > 0 means below the ground plane
    in_contact = (pen > 0.0) & (P.ground > 0.0)
    fz = -(P.k_ground * pen + P.c_ground * v_W[..., 2])
    fz = np.where(in_contact, np.minimum(fz, 0.0), 0.0)
    fxy = np.where(in_contact[..., None], -P.b_ground[..., None] * v_W[..., :2], 0.0)
    return np.concatenate([fxy, fz[..., None]], -1)


def aero_force_W(P: PlantArrays, R: np.ndarray, v_o_W: np.ndarray) -> np.ndarray:
    """The true vehicle's aerodynamic force (N, world) at the body origin moving at ``v_o_W`` (still air):
    ``R_WB aero_force_B(R_WBᵀ v_o_W)`` (:func:`vtol_impedance.model.aero.aero_force_B`)."""
    v_B = matvec(transpose(R), v_o_W)
    return matvec(R, aero_force_B(v_B, P.lin_drag_B, P.quad_drag_B))


def environment_wrench(
    P: PlantArrays, t: float, x: np.ndarray, R: np.ndarray, dist: DisturbanceFn | None
) -> tuple[np.ndarray, np.ndarray]:
    """Total external force (world, at the body origin) and moment (body, about the origin).

    Disturbances ``dist(t, p_o_W, v_o_W, R_WB)`` plus the aerodynamic force (:func:`aero_force_W`) plus
    ground contact at the body origin and at the payload: everything except gravity and the rotors.
    """
    p_o, v_o = origin_kinematics(P, x, R)
    if dist is None:
        f_d, tau = np.zeros(p_o.shape), np.zeros(p_o.shape)
    else:
        f_d, tau = dist(t, p_o, v_o, R)
    f = f_d + aero_force_W(P, R, v_o) + _ground_force(P, p_o, v_o)
    p_c, v_c = point_kinematics(P, x, P.r_contact_B, R)
    f_c = _ground_force(P, p_c, v_c)
    tau = tau + cross(P.r_contact_B, matvec(transpose(R), f_c))
    return f + f_c, np.broadcast_to(tau, f.shape)


def rotor_wrench(P: PlantArrays, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total thrust ``u`` and moment about the body origin (body frame) of rotor forces ``f (..., n)``:
    ``sum_i r_i x (-f_i e3) + s_i c f_i e3``."""
    F_B = np.zeros(f.shape + (3,))
    F_B[..., 2] = -f
    yaw = (P.spins * f * P.drag_factor[..., None])[..., None] * np.array([0.0, 0.0, 1.0])
    return f.sum(-1), (cross(P.rotor_pos_B, F_B) + yaw).sum(-2)


def plant_derivative(
    P: PlantArrays, x: np.ndarray, f_cmd: np.ndarray, t: float = 0.0, dist: DisturbanceFn | None = None
) -> np.ndarray:
    """``x_dot`` of the true plant for held rotor commands ``f_cmd (..., n)`` and disturbances ``dist``."""
    x, f_cmd = _step_args(P, x, f_cmd, t)
    q = x[..., QUAT]
    w = x[..., OMEGA]
    f = x[..., ROTOR]
    R = quat_to_rotation(q)  # eq. (1a), from the quaternion
    f_env_W, tau_env_B = environment_wrench(P, t, x, R, dist)
    u, tau_rot_B = rotor_wrench(P, f)  # eq. (4), the true geometry
    z_B = R[..., :, 2]
    F_W = -u[..., None] * z_B + f_env_W  # everything applied at the body origin
    f_link, r_dd = link_force(P, x, F_W)  # the pendulum pulls at the centre of mass: no moment
    a = GRAVITY_W + (F_W + f_link) / P.mass[..., None]  # eqs. (3a), (5a), world frame
    F_B = matvec(transpose(R), F_W)
    tau_com = tau_rot_B + tau_env_B - cross(P.c_B, F_B)
    Iw = matvec(P.I_com, w)
    w_dot = matvec(P.I_com_inv, tau_com - cross(w, Iw))  # eq. (2b)
    target = np.clip(f_cmd, P.f_min, P.f_max)
    tau = np.where(target > f, P.tau_up[..., None], P.tau_down[..., None])
    f_dot = np.where(tau > 0, (target - f) / np.maximum(tau, 1e-12), 0.0)
    return np.concatenate([x[..., V_COM], a, quat_derivative(q, w), w_dot, f_dot, x[..., PEND_V], r_dd], -1)


def apply_instant_rotors(P: PlantArrays, x: np.ndarray, f_cmd: np.ndarray) -> np.ndarray:
    """A rotor follows its new command at once in a direction whose time constant is 0 (``tau_up = 0``: it
    spins up instantly, still lagging down if ``tau_down > 0``, and the reverse)."""
    if not np.any((P.tau_up <= 0) | (P.tau_down <= 0)):
        return x
    target = np.clip(f_cmd, P.f_min, P.f_max)
    f = x[..., ROTOR]
    jump = ((target > f) & (P.tau_up <= 0)[..., None]) | ((target < f) & (P.tau_down <= 0)[..., None])
    x = x.copy()
    x[..., ROTOR] = np.where(jump, target, f)
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


def _step_args(P: PlantArrays, x: np.ndarray, f_cmd: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """The checks of a step's arguments: types and shapes, cheap (NaN passes, as in the batched math)."""
    if type(P) is not PlantArrays:
        instance("P", P, PlantArrays)
    n = P.spins.shape[-1]
    if type(t) is not float:
        scalar("t", t)
    return batched("x", x, (state_size(n),)), batched("f_cmd", f_cmd, (n,))


def rk4_step(
    P: PlantArrays, x: np.ndarray, f_cmd: np.ndarray, t: float, dt: float, dist: DisturbanceFn | None = None
) -> np.ndarray:
    """One classical Runge-Kutta step with the rotor command and the disturbances (evaluated at the
    start, :func:`disturbance_at`) held; renormalises the quaternion."""
    x, f_cmd = _step_args(P, x, f_cmd, t)
    if type(dt) is not float or not dt > 0.0:
        scalar("dt", dt, lo=0.0, lo_open=True)
    held = disturbance_at(P, t, x, dist)
    k1 = plant_derivative(P, x, f_cmd, t, held)
    k2 = plant_derivative(P, x + 0.5 * dt * k1, f_cmd, t + 0.5 * dt, held)
    k3 = plant_derivative(P, x + 0.5 * dt * k2, f_cmd, t + 0.5 * dt, held)
    k4 = plant_derivative(P, x + dt * k3, f_cmd, t + dt, held)
    xn = x + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    q = xn[..., QUAT]
    xn[..., QUAT] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return project_pendulum(P, xn)


def pack_plant(P: PlantArrays) -> np.ndarray:
    """Plant records ``(B,)`` of :data:`vtol_impedance.compiled.layouts.PLANT` from arrays with batch shape
    ``(B,)``; a zero rotor time constant becomes a zero rate (the engine sets that direction at once)."""
    from ..compiled.layouts import PLANT, pack

    def rate(tau: np.ndarray) -> np.ndarray:
        return np.where(tau > 0, 1.0 / np.maximum(tau, 1e-12), 0.0)

    return pack(
        PLANT, P, P.mass.shape[0], inv_mass=1.0 / P.mass, inv_tau_up=rate(P.tau_up), inv_tau_down=rate(P.tau_down),
        n_rotors=P.spins.shape[-1],
    )  # fmt: skip


@cache
def _state_columns(n_rotors: int) -> np.ndarray:
    """Where each entry of a flat state with ``n_rotors`` rotors goes in a
    :data:`~vtol_impedance.compiled.layouts.STATE` record read as float64 (every field is one)."""
    from ..compiled.layouts import STATE

    flat = np.arange(state_size(n_rotors))
    cols = np.empty_like(flat)
    for name, part in (("p_com_W", P_COM), ("v_com_W", V_COM), ("q_WB", QUAT), ("omega_B", OMEGA),
                       ("f_rotor", ROTOR), ("r_pend_W", PEND_R), ("v_pend_W", PEND_V)):  # fmt: skip
        at = flat[part]
        cols[at] = STATE.fields[name][1] // 8 + np.arange(at.size)
    cols.setflags(write=False)
    return cols


def pack_state(x: np.ndarray) -> np.ndarray:
    """States ``(B,)`` of :data:`vtol_impedance.compiled.layouts.STATE` from flat states ``(B, state_size(n))``."""
    from ..compiled.layouts import STATE

    x = np.asarray(x, dtype=float)
    n = x.shape[-1] - state_size(0) if x.ndim == 2 else -1
    if not 0 < n <= MAX_ROTORS:
        raise ValueError(f"flat states of shape (B, state_size(n)) with 1 <= n <= {MAX_ROTORS}, got {x.shape}")
    out = np.zeros(x.shape[0], dtype=STATE)
    out.view(np.float64).reshape(x.shape[0], -1)[:, _state_columns(n)] = x
    return out


def unpack_state(X: np.ndarray, n_rotors: int) -> np.ndarray:
    """Flat states ``(B, state_size(n_rotors))`` from :func:`pack_state`'s records."""
    return np.concatenate(
        [X["p_com_W"], X["v_com_W"], X["q_WB"], X["omega_B"], X["f_rotor"][:, :n_rotors], X["r_pend_W"],
         X["v_pend_W"]], -1,
    )  # fmt: skip
