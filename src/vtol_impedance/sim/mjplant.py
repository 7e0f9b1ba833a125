"""MuJoCo as an independent plant: the same vehicle, payload, pendulum, ground and walls, in another engine.

The model is generated here from :class:`~.plant.PlantParams` (no files are downloaded) in MuJoCo's usual
z-up convention, so that it looks right in MuJoCo's own viewer: world ENU, body FLU. Everything crossing
the boundary is converted with ``T_NED_ENU`` and ``T_FRD_FLU`` (:mod:`vtol_impedance.conventions`);
the rest of the library sees the same state layout as the built-in plant (:mod:`.plant`).

What MuJoCo computes itself, not from this package's equations:

* rigid-body dynamics of the vehicle (a free joint) with the payload as a welded child body, so the
  composite mass, centre of mass and inertia come from MuJoCo's own composition;
* the pendulum: a ball joint at the vehicle's centre of mass and the bob as a body (with a 5 mm sphere's
  inertia about its centre, 4e-5 of ``m L^2`` for the default link), so the link force is a constraint
  force of MuJoCo's solver;
* rotor forces: one site actuator per rotor, force along the site's ``+z`` (FLU up) and the yaw reaction
  ``-s_i c f_i`` about it (a propeller turning counter-clockwise seen from above, ``s_i = +1``, turns the
  body clockwise seen from above), through MuJoCo's first-order activation filter (``filter``,
  integrated by MuJoCo's RK4 with the rest of the state; ``filterexact`` under RK4 was measured 1e-4 N
  off the exact response); its time constant is set per control period to ``rotor_tau_up`` or
  ``rotor_tau_down`` by the direction the command asks for;
* ground and walls: MuJoCo's soft contacts with Coulomb friction: the ground plane touched by 1 cm
  spheres at the two contact points of the built-in plant (the body origin, the payload), each wall by
  its bumper (a sphere of the wall's radius around the body origin, as in :class:`.disturbances.Wall`).
  Their stiffness and damping per unit mass are ``k / m`` and ``c / m`` of the built-in ground and wall
  (``solref < 0`` with a constant impedance of 0.5), which makes the static stiffness about the same
  (measured within 15 %); the force law under motion is MuJoCo's.

Explicit disturbances (pushes, fans, gusts, wind) are the package's own functions of the MuJoCo state,
evaluated at the start of each step like in the built-in plant: the force through ``xfrc_applied`` at
the body origin, the moment through three body-frame motors on the site ``origin`` (held in the body
frame over the step, as the built-in plant holds it). The vehicle's aerodynamic force
(:func:`~.plant.aero_force_W`: rotor drag, inflow damping, body drag) is an isotropic linear drag
``-k v_o`` as the free joint's damping on its three linear velocities (the body origin's, in the world
frame), evaluated by MuJoCo at every stage; any other (body-frame or quadratic) is applied through
``xfrc_applied``, evaluated half a step ahead. MuJoCo's fluid model is off (zero density and viscosity),
so no drag is counted twice.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..conventions import T_FRD_FLU, T_NED_ENU, G
from ..errors import InputError
from ..model.dynamics import matvec
from ..model.kinematics import cross, quat_to_rotation, skew
from .disturbances import DisturbanceSet, Wall
from .plant import (
    OMEGA,
    P_COM,
    PEND_R,
    PEND_V,
    QUAT,
    ROTOR,
    V_COM,
    PlantArrays,
    PlantParams,
    aero_force_W,
    origin_kinematics,
    unpack_state,
)  # fmt: skip

INSTALL_HINT = "pip install 'vtol-impedance[mujoco]'"
#: Radius of the contact spheres; the planes are moved by it so that contact starts at the point itself.
CONTACT_RADIUS_M = 0.01
#: Radius of the sphere whose inertia the pendulum's bob carries (a ball joint needs a body with inertia).
BOB_RADIUS_M = 0.005
#: Collision bits: the ground is bit 0, wall i bit i + 1 (MuJoCo's masks have 32 bits).
MAX_WALLS = 30
#: MuJoCo's constraint impedance, held constant so that ``solref = (-k/m, -c/m)`` scales simply.
IMPEDANCE = 0.5


def require_mujoco() -> Any:
    """The ``mujoco`` module, or a clear error saying how to install it."""
    try:
        import mujoco
    except ImportError:
        raise InputError(
            f"the MuJoCo plant (--plant mujoco, backend='mujoco') needs the mujoco package: {INSTALL_HINT}"
        ) from None
    return mujoco


def _f(x: float) -> str:
    return repr(float(x))  # the shortest text that reads back as the same double


def _v(a: np.ndarray) -> str:
    return " ".join(_f(x) for x in np.ravel(a))


def _flu(v_frd: np.ndarray) -> np.ndarray:
    return T_FRD_FLU @ np.asarray(v_frd, dtype=float)


def _enu(v_ned: np.ndarray) -> np.ndarray:
    return T_NED_ENU @ np.asarray(v_ned, dtype=float)


def _contact_attrs(stiffness: float, damping: float, mass: float) -> str:
    """``solref``/``solimp`` for a contact of ``stiffness`` N/m and ``damping`` N s/m on a body of ``mass``.

    With ``solimp`` fixed at ``d``, MuJoCo scales a negative ``solref`` by ``d^2`` and ``d``; these undo it.
    """
    d = IMPEDANCE
    k, c = stiffness / mass * d * d, damping / mass * d
    return f'solref="{-k:.10g} {-c:.10g}" solimp="{d} {d} 0.001 0.5 2"'


def mjcf(P: PlantParams, walls: Sequence[Wall] = (), timestep: float = 0.001) -> str:
    """The MJCF text of the true vehicle ``P`` with ``walls`` (z-up: world ENU, body FLU).

    Bodies: ``vehicle`` (free joint, the bare vehicle with its centre of mass at the body origin),
    ``payload`` (welded, a point mass at ``payload_offset_B``), ``bob`` (ball joint at the composite
    centre of mass). Sites ``rotor<i>`` carry the actuators ``rotor<i>``.
    """
    if len(walls) > MAX_WALLS:
        raise InputError(f"the MuJoCo plant takes at most {MAX_WALLS} walls, got {len(walls)}")
    m_all = P.vehicle.mass + float(P.payload_mass) + float(P.pendulum_mass)
    out = [
        '<mujoco model="vtol-impedance">',
        '  <compiler angle="radian" autolimits="true"/>',
        f'  <option timestep="{_f(timestep)}" gravity="0 0 {-G}" integrator="RK4" density="0" viscosity="0"/>',
        "  <worldbody>",
    ]
    surfaces, bumpers = _mjcf_surfaces(P, walls, m_all)
    out += surfaces + _mjcf_vehicle(P, bumpers) + ["  </worldbody>", "  <actuator>"] + _mjcf_actuators(P)
    out += ["  </actuator>", "</mujoco>"]
    return "\n".join(out) + "\n"


def _mjcf_surfaces(P: PlantParams, walls: Sequence[Wall], m_all: float) -> tuple[list[str], list[str]]:
    """The ground and the walls (world geoms), and the vehicle's bumper geom for each wall."""
    r0 = CONTACT_RADIUS_M
    out, bumpers = [], []
    if P.ground:
        out.append(
            f'    <geom name="ground" type="plane" size="0 0 1" pos="0 0 {-r0}" contype="0" conaffinity="1" '
            f'friction="1 0.005 0.0001" {_contact_attrs(P.ground_stiffness, P.ground_damping, m_all)}/>'
        )
    for i, w in enumerate(walls):
        # wall i collides only with bumper i: a sphere of the wall's radius around the body origin (as
        # in the built-in wall), or of CONTACT_RADIUS_M with the plane moved to keep the contact point
        n = np.asarray(w.normal_W)
        radius = max(w.radius, r0)
        at = np.asarray(w.position_W) + (w.radius - radius) * n
        bit = 1 << (i + 1)
        out.append(
            f'    <geom name="wall{i}" type="plane" size="0 0 1" pos="{_v(_enu(at))}" zaxis="{_v(_enu(n))}" '
            f'contype="0" conaffinity="{bit}" condim="3" friction="{w.friction:.10g} 0.005 0.0001" '
            f"{_contact_attrs(w.stiffness, w.damping, m_all)}/>"
        )
        bumpers.append(
            f'      <geom name="bumper{i}" type="sphere" size="{_f(radius)}" mass="0" contype="{bit}" '
            'conaffinity="0" rgba="0.9 0.6 0.2 0.3"/>'
        )
    return out, bumpers


def _mjcf_vehicle(P: PlantParams, bumpers: list[str]) -> list[str]:
    """The vehicle body (true mass and inertia, FLU), its rotor sites, the welded payload and the pendulum."""
    v = P.vehicle
    m_b, m_p, m_l = v.mass, float(P.payload_mass), float(P.pendulum_mass)
    r_p = np.asarray(P.payload_offset_B, dtype=float)
    c_B = m_p * r_p / (m_b + m_p)
    scale = np.broadcast_to(np.asarray(P.inertia_scale, dtype=float), (3,))
    I_flu = T_FRD_FLU @ (v.inertia * np.sqrt(np.outer(scale, scale))) @ T_FRD_FLU
    r0 = CONTACT_RADIUS_M
    out = [
        '    <body name="vehicle">',
        '      <freejoint name="vehicle"/>',
        f'      <inertial pos="0 0 0" mass="{_f(m_b)}" fullinertia="{_f(I_flu[0, 0])} {_f(I_flu[1, 1])} '
        f'{_f(I_flu[2, 2])} {_f(I_flu[0, 1])} {_f(I_flu[0, 2])} {_f(I_flu[1, 2])}"/>',
        f'      <geom name="origin" type="sphere" size="{r0}" mass="0" contype="1" conaffinity="0"/>',
        '      <site name="origin" pos="0 0 0" size="0.01"/>',
        *bumpers,
    ]
    for i, r_i in enumerate(v.geometry.positions_B * P.arm_length_scale):
        out.append(f'      <site name="rotor{i}" pos="{_v(_flu(r_i))}" size="0.02"/>')
    if m_p > 0:
        out += [
            f'      <body name="payload" pos="{_v(_flu(r_p))}">',
            f'        <inertial pos="0 0 0" mass="{_f(m_p)}" diaginertia="1e-12 1e-12 1e-12"/>',
            f'        <geom name="payload" type="sphere" size="{r0}" mass="0" contype="1" conaffinity="0"/>',
            "      </body>",
        ]
    if m_l > 0:
        L = P.pendulum_length
        i_bob = 0.4 * m_l * BOB_RADIUS_M**2
        out += [
            f'      <body name="bob" pos="{_v(_flu(c_B))}">',
            '        <joint name="link" type="ball"/>',
            f'        <inertial pos="0 0 {_f(-L)}" mass="{_f(m_l)}" diaginertia="{_v([i_bob] * 3)}"/>',
            f'        <geom type="capsule" fromto="0 0 0 0 0 {_f(-L)}" size="0.004" mass="0" '
            'contype="0" conaffinity="0"/>',
            "      </body>",
        ]
    return out + ["    </body>"]


def _mjcf_actuators(P: PlantParams) -> list[str]:
    """One actuator per rotor (thrust along the site's z, its drag moment, the lag as MuJoCo's filter) and
    three body-frame moment motors for the disturbances."""
    g = P.vehicle.geometry
    cq = P.vehicle.drag_factor * P.drag_factor_scale
    lag = P.rotor_tau_up > 0 or P.rotor_tau_down > 0
    out = []
    for i, s_i in enumerate(g.spins):
        dyn = f'dyntype="filter" dynprm="{_f(max(P.rotor_tau_up, P.rotor_tau_down))}"' if lag else 'dyntype="none"'
        out.append(
            f'    <general name="rotor{i}" site="rotor{i}" gear="0 0 1 0 0 {_f(-s_i * cq)}" {dyn} gaintype="fixed" '
            f'gainprm="1" biastype="none" ctrlrange="{_f(g.f_min[i])} {_f(g.f_max[i])}"/>'
        )
    for axis, gear in zip("xyz", np.eye(3), strict=True):  # disturbance moments, held in the body frame
        out.append(f'    <motor name="moment_{axis}" site="origin" gear="0 0 0 {_v(gear)}" ctrllimited="false"/>')
    return out


def scene_mjcf(P: PlantParams, disturbances: Sequence[Any] = (), timestep: float = 0.001) -> str:
    """:func:`mjcf` with the walls found among ``disturbances`` (the others are forces applied at run time)."""
    return mjcf(P, [d for d in disturbances if isinstance(d, Wall)], timestep)


def _mat2quat(mj: Any, R: np.ndarray) -> np.ndarray:
    q = np.empty(4)
    mj.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).ravel())
    return q


def _quat_z_to(mj: Any, u: np.ndarray) -> np.ndarray:
    q = np.empty(4)
    mj.mju_quatZ2Vec(q, np.ascontiguousarray(u, dtype=float))
    return q


class MujocoPlant:
    """B vehicles, each its own MuJoCo model and data, stepped with held rotor commands.

    ``x`` is the state of every vehicle in the layout of :mod:`.plant` (NED/FRD, composite centre of
    mass, rotor forces, pendulum), converted from MuJoCo's after every step.
    """

    def __init__(
        self,
        plants: Sequence[PlantParams],
        PA: PlantArrays,
        dist: DisturbanceSet,
        x0: np.ndarray,
        dt: float,
        compiled: bool = False,
    ) -> None:
        mj = require_mujoco()
        #: States converted by the compiled kernel (:func:`vtol_impedance.compiled.frames.states_from_enu_flu`)
        #: rather than by the NumPy of :meth:`_convert` (the same equations; the compiled loop's choice).
        self.compiled = compiled
        self.mj = mj
        self.PA = PA
        walls = [d for d in dist.items if isinstance(d, Wall)]
        self.forces = DisturbanceSet([d for d in dist.items if not isinstance(d, Wall)])
        texts: dict[int, str] = {}
        self.models = []
        for p in plants:
            if id(p) not in texts:
                texts[id(p)] = mjcf(p, walls, dt)
            m = mj.MjModel.from_xml_string(texts[id(p)])  # one each: the rotor lag is set per vehicle
            self.models.append(m)
        # The aerodynamic force: an isotropic linear drag -k v_o is MuJoCo's own damping of the free joint's
        # linear velocity (the body origin's, world axes); body-frame or quadratic drag is applied as a force
        # through xfrc_applied (_aero_mid_step).
        lin, quad = PA.lin_drag_B.reshape(-1, 3), PA.quad_drag_B.reshape(-1, 3)
        iso = (lin.min(-1) == lin.max(-1)) & ~quad.any(-1)
        self._damping = np.where(iso, lin[:, 0], 0.0)
        self.aero = ~iso
        for m, k in zip(self.models, self._damping, strict=True):
            m.dof_damping[0:3] = k
        self.datas = [mj.MjData(m) for m in self.models]
        m0 = self.models[0]
        self.vehicle = mj.mj_name2id(m0, mj.mjtObj.mjOBJ_BODY, "vehicle")
        self.bob = [mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, "bob") for m in self.models]
        self.lag = np.array([m.actuator_dyntype[0] != mj.mjtDyn.mjDYN_NONE for m in self.models])
        self.vehicle_geoms = [
            {i for i in range(m.ngeom) if m.geom_bodyid[i] != 0 and m.body_rootid[m.geom_bodyid[i]] == self.vehicle}
            for m in self.models
        ]
        self.n = PA.spins.shape[-1]
        self.x = np.array(x0, dtype=float)
        self.ctrl = np.zeros((len(self.datas), self.n))  # the rotor commands held in each data's ctrl
        self.failed = np.zeros(len(self.datas), dtype=bool)
        self._no_force = np.zeros((len(self.datas), 3))  # the explicit forces when there are none
        self._no_force.setflags(write=False)
        self.frozen = np.zeros(len(self.datas), dtype=bool)
        for b in range(len(self.datas)):
            self.set_state(b, self.x[b])
        #: Ages (plant steps) of the states the sensors read (set by the closed loop): a period is then
        #: stepped in one call and only those states are converted; ``None``: every step's state.
        self.sensor_ages: tuple[int, ...] | None = None
        sizes = {(m.nq, m.nv, m.nu, m.na, m.nbody) for m in self.models}
        self._batched = len(sizes) == 1 and not self.forces.state_dependent and not self.aero.any()
        self._threads = [mj.MjData(m0) for _ in range(min(len(self.models), os.cpu_count() or 1))]
        self._full = mj.mjtState.mjSTATE_FULLPHYSICS
        self._inputs = mj.mjtState.mjSTATE_CTRL | mj.mjtState.mjSTATE_XFRC_APPLIED
        S = mj.mjtState
        #: Where qpos, qvel and act start in a full physics state (MuJoCo orders its parts by their bits).
        self._offsets = tuple(
            mj.mj_stateSize(m0, int(before)) for before in (S.mjSTATE_TIME, S.mjSTATE_TIME | S.mjSTATE_QPOS,
                                                            S.mjSTATE_TIME | S.mjSTATE_QPOS | S.mjSTATE_QVEL)
        )  # fmt: skip
        self._pool: Any = None  # mujoco.rollout.Rollout, made at the first period, ended by close()
        self._read_steps: dict[tuple, list[int]] = {}  # the steps converted, per period length and ages
        self._all_rows: dict[int, np.ndarray] = {}  # each converted row's vehicle, when all step

    def close(self) -> None:
        """End the rollout thread pool (the run does it when it ends; the plant can still be read)."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None

    # -- state conversion -------------------------------------------------------------------------------
    def set_state(self, b: int, x: np.ndarray) -> None:
        """Put vehicle ``b`` in the state ``x`` (layout of :mod:`.plant`)."""
        mj, m, d = self.mj, self.models[b], self.datas[b]
        mj.mj_resetData(m, d)
        R = quat_to_rotation(x[QUAT])
        w_B = x[OMEGA]
        c = np.asarray(self.PA.c_B)[b]
        p_o = x[P_COM] - R @ c
        v_o = x[V_COM] - R @ cross(w_B, c)
        R_enu = T_NED_ENU @ R @ T_FRD_FLU
        d.qpos[0:3] = _enu(p_o)
        d.qpos[3:7] = _mat2quat(mj, R_enu)
        d.qvel[0:3] = _enu(v_o)
        d.qvel[3:6] = _flu(w_B)
        if self.bob[b] >= 0:
            r, rd = T_NED_ENU @ x[PEND_R], T_NED_ENU @ x[PEND_V]
            L = np.linalg.norm(r)
            u_B = R_enu.T @ (r / L)  # the link's direction in the vehicle's frame
            q_rel = _quat_z_to(mj, -u_B)  # the bob hangs along the joint frame's -z
            R_rel = np.empty(9)
            mj.mju_quat2Mat(R_rel, q_rel)
            R_bob = R_enu @ R_rel.reshape(3, 3)
            w_bob_W = np.cross(r, rd) / (L * L)  # the bob's rotation with no spin about the link
            d.qpos[7:11] = q_rel
            d.qvel[6:9] = R_bob.T @ (w_bob_W - R_enu @ _flu(w_B))
        if self.lag[b]:
            d.act[:] = x[ROTOR]
        d.ctrl[: self.n] = self.ctrl[b] = x[ROTOR]
        mj.mj_forward(m, d)

    def _read(self) -> np.ndarray:
        """The state of every vehicle from MuJoCo's ``qpos``, ``qvel``, ``act`` and ``ctrl``."""
        d = self.datas
        return self._convert([e.qpos for e in d], [e.qvel for e in d], [e.act for e in d], np.arange(len(d)))

    def _convert(
        self, qpos: Sequence[np.ndarray], qvel: Sequence[np.ndarray], act: Sequence[np.ndarray], veh: np.ndarray
    ) -> np.ndarray:
        """States in the layout of :mod:`.plant` from MuJoCo's ``qpos``, ``qvel`` (ENU/FLU, the body origin)
        and ``act``, a row each (a 2-D array or a list); row ``i`` is a state of vehicle ``veh[i]``."""
        if self.compiled and isinstance(qpos, np.ndarray) and not any(self.bob[b] >= 0 for b in veh):
            from ..compiled.frames import states_from_enu_flu
            from ..compiled.layouts import STATE

            X = np.zeros(len(veh), dtype=STATE)
            P = self.PA
            states_from_enu_flu(qpos, qvel, act, veh, P.c_B, P.f_min, P.f_max, self.ctrl, self.lag, self.n, X)
            return unpack_state(X, self.n)
        x = np.empty((len(veh),) + self.x.shape[1:])
        q7 = qpos[:, :7] if isinstance(qpos, np.ndarray) else np.array([r[:7] for r in qpos])
        v6 = qvel[:, :6] if isinstance(qvel, np.ndarray) else np.array([r[:6] for r in qvel])
        # q_WB (NED/FRD) = q(T_NED_ENU) q_ENU_FLU q(T_FRD_FLU), half-turns about (1, 1, 0)/sqrt(2) and x,
        # written out; the sign is chosen with w >= 0 (the same rotation)
        w, a, b, c = q7[:, 3], q7[:, 4], q7[:, 5], q7[:, 6]
        q = x[:, QUAT]
        q[:, 0], q[:, 1], q[:, 2], q[:, 3] = w + c, a + b, a - b, w - c
        with np.errstate(divide="ignore", invalid="ignore"):  # a diverged vehicle's NaN stays NaN, quietly
            q *= np.copysign(1.0 / np.sqrt(np.einsum("ij,ij->i", q, q)), q[:, 0])[:, None]
        R = quat_to_rotation(q)
        c_B = self.PA.c_B[veh]
        x[:, OMEGA] = v6[:, 3:6] * [1.0, -1.0, -1.0]  # T_FRD_FLU
        x[:, P_COM] = q7[:, [1, 0, 2]] * [1.0, 1.0, -1.0] + matvec(R, c_B)  # T_NED_ENU: a swap and a sign
        x[:, V_COM] = v6[:, [1, 0, 2]] * [1.0, 1.0, -1.0] + matvec(R, cross(x[:, OMEGA], c_B))
        x[:, ROTOR] = np.clip(self.ctrl[veh], self.PA.f_min[veh], self.PA.f_max[veh])
        x[:, PEND_R] = x[:, PEND_V] = 0.0
        for i, b in enumerate(veh):
            if self.lag[b]:
                x[i, ROTOR] = act[i][: self.n]
            if self.bob[b] >= 0:
                R_enu, R_rel = np.empty(9), np.empty(9)
                self.mj.mju_quat2Mat(R_enu, qpos[i][3:7])
                self.mj.mju_quat2Mat(R_rel, qpos[i][7:11])
                R_enu = R_enu.reshape(3, 3)
                R_bob = R_enu @ R_rel.reshape(3, 3)
                r = R_bob @ np.array([0.0, 0.0, -float(self.PA.pend_L[b])])
                w_bob = R_enu @ qvel[i][3:6] + R_bob @ qvel[i][6:9]
                x[i, PEND_R] = T_NED_ENU @ r
                x[i, PEND_V] = T_NED_ENU @ np.cross(w_bob, r)
        return x

    # -- the loop's interface ---------------------------------------------------------------------------
    def _forces(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Explicit disturbances and the applied aerodynamic force (world force at the origin, body moment)
        and the origin's velocity."""
        if not (self.forces.items or self.aero.any()):  # nothing to evaluate; the free joint's velocity
            v_o = np.array([d.qvel[0:3] for d in self.datas]) @ T_NED_ENU.T
            return self._no_force, self._no_force, v_o
        R = quat_to_rotation(self.x[:, QUAT])
        p_o, v_o = origin_kinematics(self.PA, self.x, R)
        if self.forces.items:
            f_W, tau_B = self.forces(t, p_o, v_o, R)
        else:
            f_W, tau_B = self._no_force, self._no_force
        if self.aero.any():
            f_W = f_W + np.where(self.aero[:, None], self._aero_mid_step(R, v_o), 0.0)
        return f_W, np.broadcast_to(tau_B, f_W.shape), v_o

    def _aero_mid_step(self, R: np.ndarray, v_o: np.ndarray) -> np.ndarray:
        """The aerodynamic force (world, at the origin) held over the next step, evaluated half a step ahead
        (velocity from MuJoCo's last acceleration, attitude from the body rate): second order in the step, as
        the built-in plant's evaluation at every RK4 stage is (held at the start it was first order: 0.8 mm/s
        per second apart at 3 m/s with 1 ms steps)."""
        h = 0.5 * np.array([m.opt.timestep for m in self.models])[:, None]
        a_o = np.array([d.qacc[0:3] for d in self.datas]) @ T_NED_ENU.T
        R_mid = R + h[..., None] * R @ skew(self.x[:, OMEGA])
        return aero_force_W(self.PA, R_mid, v_o + h * a_o)

    def _apply(self, t: float, f_cmd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rotor commands, and the explicit disturbances held over the next step: the force (world) through
        ``xfrc_applied``, the moment through the body-frame actuators ``moment_*`` (held in the body
        frame, as the built-in plant holds it)."""
        f_W, tau_B, v_o = self._forces(t)
        n, P = self.n, self.PA
        forces = bool(self.forces.items) or bool(self.aero.any())  # else the zeros MuJoCo's reset left
        if forces:
            tau_flu, f_enu = tau_B @ T_FRD_FLU.T, f_W @ T_NED_ENU.T  # every vehicle at once
        if self.lag.any():
            act = np.zeros(f_cmd.shape)
            for b in np.flatnonzero(self.lag):  # a vehicle without lag has no activation state
                act[b] = self.datas[b].act[:n]
            target = np.clip(f_cmd, P.f_min, P.f_max)
            tau = np.where(target > act, P.tau_up[:, None], P.tau_down[:, None])
            now = tau <= 0  # a direction without lag: the rotor is at its command at once
            act, rate = np.where(now, target, act), np.where(now, 1.0, tau)
        for b, (m, d) in enumerate(zip(self.models, self.datas, strict=True)):
            d.ctrl[:n] = self.ctrl[b] = f_cmd[b]
            if forces:
                d.ctrl[n:] = tau_flu[b]
                d.xfrc_applied[self.vehicle, 0:3] = f_enu[b]
            if self.lag[b]:
                d.act[:n] = act[b]
                m.actuator_dynprm[:n, 0] = rate[b]
        return f_W, tau_B, v_o

    def truth(self, t: float, f_cmd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What acts at the start of the period: the body origin's acceleration ``a_o_W`` and ``w_dot_B``
        from MuJoCo's ``qacc``, and the external force (world, at the origin) and moment (body, about the
        origin): the explicit ones applied, MuJoCo's contact forces and the pendulum link's pull."""
        mj = self.mj
        # the rotors as they are at this instant (the new command acts from the next step on, as in the
        # built-in plant; it matters for rotors without lag, whose force is the command itself)
        f_W, tau_B, v_o = self._apply(t, self.x[:, ROTOR])
        f_W, tau_B = f_W - self._damping[:, None] * v_o, tau_B.copy()  # MuJoCo's damping: the isotropic drag
        B = len(self.datas)
        a_o, w_dot = np.zeros((B, 3)), np.zeros((B, 3))
        f6 = np.zeros(6)
        acc = np.zeros(6)
        for b, (m, d) in enumerate(zip(self.models, self.datas, strict=True)):
            mj.mj_forward(m, d)
            if self.bob[b] >= 0:  # the bob's acceleration below needs it; qacc and contacts do not
                mj.mj_rnePostConstraint(m, d)
            a_o[b] = T_NED_ENU @ d.qacc[0:3]
            w_dot[b] = T_FRD_FLU @ d.qacc[3:6]
            R_enu = d.xmat[self.vehicle].reshape(3, 3)
            p_o = d.xpos[self.vehicle]
            f_c = np.zeros(3)
            tau_c = np.zeros(3)
            for k in range(d.ncon):
                con = d.contact[k]
                if con.geom1 in self.vehicle_geoms[b]:
                    sign = -1.0
                elif con.geom2 in self.vehicle_geoms[b]:
                    sign = 1.0
                else:
                    continue
                mj.mj_contactForce(m, d, k, f6)
                f_world = sign * (f6[:3] @ con.frame.reshape(3, 3))  # on the vehicle
                f_c += f_world
                tau_c += np.cross(con.pos - p_o, f_world)
            if self.bob[b] >= 0:
                # MuJoCo's accelerations include gravity as an upward acceleration of the world (what an
                # accelerometer reads), so the bob's is its proper acceleration: the link pulls the vehicle
                # by minus the bob's mass times it.
                mj.mj_objectAcceleration(m, d, mj.mjtObj.mjOBJ_BODY, self.bob[b], acc, 0)
                f_link = -m.body_mass[self.bob[b]] * acc[3:6]
                f_c += f_link
            f_W[b] += T_NED_ENU @ f_c
            tau_B[b] += T_FRD_FLU @ (R_enu.T @ tau_c)
        return a_o, w_dot, f_W, tau_B

    def advance(self, t: float, f_cmd: np.ndarray, n_sub: int, dt: float, push: Any) -> None:
        """``n_sub`` MuJoCo steps with the rotor commands held; the explicit forces are evaluated at the
        start of each step (as the built-in plant does); ``push(x)`` after each.

        When the explicit forces depend on time alone (no fan) and the vehicles' models have one size, the
        period is one call of ``mujoco.rollout`` over every vehicle (threads across vehicles), with the
        forces of each step given in advance, and only the states the sensors will read are converted."""
        if self._batched and n_sub > 1:
            self._advance_rollout(t, f_cmd, n_sub, dt, push)
            return
        mj = self.mj
        for j in range(n_sub):
            self._apply(t + j * dt, f_cmd)
            for b, (m, d) in enumerate(zip(self.models, self.datas, strict=True)):
                if not (self.failed[b] or self.frozen[b]):
                    mj.mj_step(m, d)
                    if d.warning[mj.mjtWarning.mjWARN_BADQACC].number > 0:
                        self.failed[b] = True
            self.x = self._read()
            self.x[self.failed] = np.nan
            push(self.x)

    def _advance_rollout(self, t: float, f_cmd: np.ndarray, n_sub: int, dt: float, push: Any) -> None:
        mj = self.mj
        active = [b for b in range(len(self.datas)) if not (self.failed[b] or self.frozen[b])]
        inputs, state0 = self._rollout_inputs(active, t, f_cmd, n_sub, dt)
        states = np.empty((len(active), n_sub, state0.shape[1]))
        if active:
            from mujoco import rollout

            if self._pool is None:  # one thread pool for the whole run (a pool per call costs its threads)
                self._pool = rollout.Rollout(nthread=len(self._threads) if len(self._threads) > 1 else 0)
            # the arrays are made here with the sizes MuJoCo asks for: its argument checks are skipped
            self._pool.rollout([self.models[b] for b in active], self._threads, state0, inputs,
                               control_spec=int(self._inputs), nstep=n_sub, state=states, skip_checks=True)  # fmt: skip
        converted = self._rollout_states(active, states, n_sub)
        for i, b in enumerate(active):  # the vehicles' data end at the period's final state
            mj.mj_setState(self.models[b], self.datas[b], states[i, n_sub - 1], self._full)
        self.x = converted[n_sub - 1]
        # every step is pushed, in order; a state no sensor reads stands in as the period's last
        for j in range(n_sub):
            push(converted.get(j, self.x))

    def _rollout_inputs(
        self, active: list[int], t: float, f_cmd: np.ndarray, n_sub: int, dt: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rollout's per-step inputs (rotor commands, disturbance moments and forces) and initial states
        of the ``active`` vehicles."""
        mj = self.mj
        # the rotor commands, lags and the first step's forces; then each step's forces (time alone)
        f_W, tau_B, _ = self._apply(t, f_cmd)
        if self.forces.items:
            R = quat_to_rotation(self.x[:, QUAT])
            p_o, v_o = origin_kinematics(self.PA, self.x, R)
        m0 = self.models[0]
        inputs = np.empty((len(active), n_sub, mj.mj_stateSize(m0, self._inputs)))
        state0 = np.empty((len(active), mj.mj_stateSize(m0, self._full)))
        for j in range(n_sub if self.forces.items else 1):  # without forces the first step's inputs hold
            if j:
                f_W, tau_B = self.forces(t + j * dt, p_o, v_o, R)
                tau_B = np.broadcast_to(tau_B, f_W.shape)
            for i, b in enumerate(active):
                m, d = self.models[b], self.datas[b]
                if j:  # the first step's were applied with the commands
                    d.ctrl[self.n :] = _flu(tau_B[b])
                    d.xfrc_applied[self.vehicle, 0:3] = _enu(f_W[b])
                mj.mj_getState(m, d, inputs[i, j], self._inputs)
        if not self.forces.items:
            inputs[:, 1:] = inputs[:, :1]
        for i, b in enumerate(active):
            mj.mj_getState(self.models[b], self.datas[b], state0[i], self._full)
        return inputs, state0

    def _rollout_states(self, active: list[int], states: np.ndarray, n_sub: int) -> dict[int, np.ndarray]:
        """The plant states (this package's layout, NED/FRD) of the steps a sensor reads, every vehicle; a
        vehicle that no longer steps keeps its state, a diverged one is NaN."""
        js = self._steps_read(n_sub)
        oq, ov, oa = self._offsets
        m0 = self.models[0]
        nq, nv, na = m0.nq, m0.nv, m0.na
        every = len(active) == len(self.datas)  # every vehicle stepped: no state to keep
        if active:
            rows = states[:, js].reshape(len(active) * len(js), -1)  # vehicle-major
            veh = self._all_rows.get(len(js)) if every else np.repeat(np.asarray(active, dtype=int), len(js))
            if veh is None:
                veh = self._all_rows[len(js)] = np.repeat(np.arange(len(active)), len(js))
            finite = np.isfinite(rows).all(1).reshape(len(active), len(js)).all(1)
            if not finite.all():
                self.failed[np.asarray(active, dtype=int)[~finite]] = True
            conv = self._convert(rows[:, oq : oq + nq], rows[:, ov : ov + nv], rows[:, oa : oa + na], veh)
            conv = conv.reshape(len(active), len(js), -1).swapaxes(0, 1)
        if every:
            xs = conv
        else:
            xs = np.repeat(self.x[None], len(js), 0)  # a vehicle that no longer steps keeps its state
            if active:
                xs[:, active] = conv
        if self.failed.any():
            xs = xs.copy()
            xs[:, self.failed] = np.nan
        return dict(zip(js, xs, strict=True))

    def _steps_read(self, n_sub: int) -> list[int]:
        """The steps of a period whose states are converted: those a sensor reads (:attr:`sensor_ages`) and
        the last."""
        key = (n_sub, self.sensor_ages)
        js = self._read_steps.get(key)
        if js is None:
            ages = self.sensor_ages
            wanted = set(range(n_sub)) if ages is None else {n_sub - 1 - k % n_sub for k in ages} | {n_sub - 1}
            js = self._read_steps[key] = sorted(wanted)
        return js

    def park(self, alive: np.ndarray, x_park: np.ndarray) -> None:
        """Failed vehicles go back to ``x_park`` and stay there (no more steps, no solver warnings)."""
        for b in np.flatnonzero(~alive & ~self.frozen):
            self.set_state(int(b), x_park[b])
            self.failed[b] = False
            self.frozen[b] = True
        self.x = self._read()
