"""The compiled kernels' data, named: one NumPy structured dtype per layout.

Numba compiles a field of a structured dtype to a fixed offset, so kernel code reads ``p.Kp[i]``,
``x.q_WB[0]``, ``out.f_hat_W[2]`` at the cost of an indexed load. Each layout is defined once, here;
both the packing (from the NumPy backend's arrays, whose field names these repeat) and the kernels use
it. Sizes that vary between vehicles are padded to a maximum (:data:`MAX_ROTORS` rotors,
:data:`MAX_ORDER` estimator order) so that one compiled kernel serves every vehicle; the valid length is
a field (``n_rotors``, ``order``).

Layouts (per vehicle unless noted):

* :data:`CONTROLLER`: nominal model, gains and limits of eqs. (14)-(20), the rotor mixer (4) and its
  prioritised inverse;
* :data:`DESIGN` (one per run, shared): control period, attitude filter and estimator matrices of
  eqs. (10)-(11) with their timing;
* :data:`CONTROLLER_STATE`: what the controller and the estimator carry from one period to the next;
  :data:`HISTORY` one row of the estimator's timing history (``(H,)`` rows per vehicle, most recent first);
* :data:`OUTPUT`: one control step's result (the fields of :class:`vtol_impedance.control.ControlOutput`);
* :data:`PLANT`: the true vehicle (:class:`vtol_impedance.sim.plant.PlantArrays`);
* :data:`STATE`: the true plant's state (the NumPy backend's flat state, named);
* :data:`DISTURBANCE`: one prepared disturbance (the union of every kind's parameters; ``kind`` says
  which apply, see :data:`KIND`);
* :data:`ACCUMULATORS`: the running sums of the window metrics.
"""

from __future__ import annotations

import numpy as np

from ..model.vehicle import MAX_ROTORS

#: Largest estimator order the compiled kernels hold (the NumPy backend takes any): far above any use
#: (the paper's is 2; the estimate's delay grows with the order).
MAX_ORDER = 8

_F = np.float64
_R = MAX_ROTORS

CONTROLLER = np.dtype(
    [
        ("mass", _F),  # nominal, kg
        ("I_B", _F, (3, 3)),  # nominal inertia, body FRD, kg m^2
        ("Kp", _F, 3),
        ("Dp", _F, 3),
        ("Ki", _F, 3),
        ("Ko", _F, 3),
        ("Do", _F, 3),
        ("compensate", _F),  # 1: feed the estimate forward (PD+C)
        ("tilt_max", _F),  # rad
        ("min_lift_accel", _F),  # m/s^2
        ("integral_limit", _F),  # N
        ("thrust_shift_max", _F),
        ("Md", _F, 3),  # comply: apparent mass per world axis, kg
        ("Dd", _F, 3),
        ("Kd", _F, 3),
        ("comply_enable", _F),
        ("Mo_d", _F, 3),  # comply: apparent inertia per Euler angle
        ("Do_d", _F, 3),
        ("Ko_d", _F, 3),
        ("n_rotors", np.int64),
        ("E", _F, (4, _R)),  # nominal effectiveness, eq. (4): [u; tau_B] = E f
        ("E_pinv", _F, (_R, 4)),
        ("f_min", _F, _R),
        ("f_max", _F, _R),
    ]
)

DESIGN = np.dtype(
    [
        ("Ts", _F),  # control period, s
        ("filt_wn", _F),  # attitude filter on (phi_d, theta_d)
        ("filt_zeta", _F),
        ("filt_Ad", _F, (2, 2)),
        ("filt_Bd", _F, 2),
        ("order", np.int64),  # estimator order n
        ("Ad", _F, (6, MAX_ORDER, MAX_ORDER)),  # x_k = Ad x_{k-1} + Bd w_bar_k, r_k = C x_k per channel
        ("Bd", _F, (6, MAX_ORDER)),
        ("C", _F, (6, MAX_ORDER)),
        ("CA", _F, (6, MAX_ORDER)),  # r_dot_k = CA x_k + CB w_bar_k
        ("CB", _F, 6),
        ("lag", _F, 6),  # G's delay at low frequency, s
        ("dv", _F),  # velocity delay, periods
        ("da", _F),  # attitude delay, periods
        ("d_att", _F),
        ("alpha", _F),  # rotor model
        ("gamma", _F),
        ("H", np.int64),  # history rows
    ]
)

CONTROLLER_STATE = np.dtype(
    [
        ("x", _F, (6, MAX_ORDER)),  # estimator filter state per channel
        ("x_new", _F, MAX_ORDER),  # scratch of the filter update
        ("q_prev", _F, 6),  # generalised momentum at the previous sample, eq. (6)
        ("Q_prev", _F, 9),  # Q(eta) and C(eta, eta_dot) at the previous sample, row-major (eq. (8) there)
        ("C_prev", _F, 9),
        ("eta_dot_prev", _F, 3),
        ("started", np.bool_),
        ("w_hat", _F, 6),  # [f_hat_W; tau_hat_eta]
        ("r_dot", _F, 6),  # its rate of change
        ("act", _F, 4),  # rotor model output now: thrust, tau_B
        ("filt_x", _F, 2),  # attitude filter value (phi_d, theta_d) and rate
        ("filt_xd", _F, 2),
        ("filt_started", np.bool_),
        ("integral", _F, 3),  # PID integral of e_p, m s
        ("thrust_prev", _F),  # command held over the last period, N
        ("tau_B_prev", _F, 3),  # N m
    ]
)

HISTORY = np.dtype([("act", _F, 4), ("eta", _F, 3)])

OUTPUT = np.dtype(
    [
        ("thrust", _F),
        ("tau_B", _F, 3),
        ("f_rotor", _F, _R),
        ("saturated", np.bool_),
        ("thrust_request", _F),
        ("tau_B_request", _F, 3),
        ("f_hat_W", _F, 3),
        ("tau_hat_eta", _F, 3),
        ("tau_hat_B", _F, 3),
        ("eta_d", _F, 3),
        ("eta_d_dot", _F, 3),
        ("mu_bar", _F, 3),
        ("tilt_limited", np.bool_),
        ("rp_scale", _F),
        ("yaw_scale", _F),
    ]
)

PLANT = np.dtype(
    [
        ("mass", _F),
        ("inv_mass", _F),
        ("I_com", _F, (3, 3)),  # about the composite CoM, body axes
        ("I_com_inv", _F, (3, 3)),
        ("c_B", _F, 3),  # CoM from the body origin, FRD
        ("r_contact_B", _F, 3),  # second ground contact (the payload)
        ("tau_up", _F),  # rotor time constants, s (0: no lag in that direction)
        ("tau_down", _F),
        ("inv_tau_up", _F),
        ("inv_tau_down", _F),
        ("lin_drag_B", _F, 3),  # rotor drag d_x, d_y and inflow damping d_z, N s/m, body axes
        ("quad_drag_B", _F, 3),  # body drag, N s^2/m^2, body axes
        ("ground", _F),  # 1: a ground at z = 0
        ("k_ground", _F),
        ("c_ground", _F),
        ("b_ground", _F),
        ("pend_m", _F),  # kg, 0: no pendulum
        ("pend_L", _F),  # m
        ("n_rotors", np.int64),
        ("E", _F, (4, _R)),  # true effectiveness
        ("f_min", _F, _R),
        ("f_max", _F, _R),
    ]
)

STATE = np.dtype(
    [
        ("p_com_W", _F, 3),
        ("v_com_W", _F, 3),
        ("q_WB", _F, 4),  # unit quaternion [w, x, y, z], body to world
        ("omega_B", _F, 3),
        ("f_rotor", _F, _R),
        ("r_pend_W", _F, 3),  # pendulum bob from its joint at the CoM
        ("v_pend_W", _F, 3),
    ]
)

#: Disturbance kinds of :data:`DISTURBANCE` (``kind <= PUSH``: a wrench times a profile of time).
KIND = {"constant": 0, "step": 1, "ramp": 2, "sinusoid": 3, "push": 4, "series": 5, "fan": 6, "wall": 7}
PUSH = KIND["push"]

DISTURBANCE = np.dtype(
    [
        ("kind", np.int64),
        ("force_W", _F, 3),  # profile kinds: wrench at full strength
        ("torque_B", _F, 3),
        ("t_on", _F),  # s: step on, ramp start, sinusoid start, push start, fan on
        ("t_off", _F),  # s: step off, ramp end
        ("duration", _F),  # s: push
        ("freq_hz", _F),  # sinusoid
        ("phase", _F),  # rad
        ("point_W", _F, 3),  # wall: a point of its plane; fan: the nozzle
        ("normal_W", _F, 3),  # wall: unit normal towards the free side; fan: unit jet direction
        ("stiffness", _F),  # wall, N/m
        ("damping", _F),  # wall, N s/m
        ("friction", _F),  # wall, Coulomb coefficient
        ("radius", _F),  # wall: the vehicle's contact radius, m
        ("slip_speed", _F),  # wall: friction regularisation, m/s
        ("mean_force", _F),  # fan: force at ref_distance on the axis, N
        ("ref_distance", _F),  # m
        ("width", _F),  # fan: jet radius (Gaussian sigma), m
        ("cop_offset_B", _F, 3),  # fan: centre of pressure from the body origin, FRD
        ("sample_dt", _F),  # series and fan gusts: sample period, s
        ("n_samples", np.int64),
    ]
)

ACCUMULATORS = np.dtype(
    [
        ("n", _F),  # samples in the window
        ("e2", _F),  # sum of |e_p|^2
        ("e_max", _F),
        ("ev2", _F),  # sum of |e_v|^2
        ("f2", _F),  # sum of |f_hat - f_lumped|^2
        ("t2", _F),  # sum of |tau_hat_eta - tau_lumped_eta|^2
        ("sat", _F),  # samples saturated or tilt-limited
        ("n_tail", _F),  # samples in the tail of the window
        ("e_tail", _F),  # sum of |e_p| there
    ]
)


def pack(dtype: np.dtype, source: object, batch: int, **extra: object) -> np.ndarray:
    """A ``(batch,)`` array of ``dtype`` with every field taken from ``extra`` or the attribute of ``source``
    of the same name; arrays smaller than a padded field fill its leading part (the rest stays zero)."""
    out = np.zeros(batch, dtype=dtype)
    for name in dtype.names:
        value = extra[name] if name in extra else getattr(source, name)
        fill(out, name, value)
    return out


def fill(out: np.ndarray, name: str, value: object) -> None:
    """``out[name] = value`` for a ``(B,)`` array ``out``; ``value`` is one vehicle's (broadcast) or has the
    leading ``B``, and fills the leading part of a padded field (``E (4, n)`` into ``E (4, MAX_ROTORS)``)."""
    field = out[name]
    fshape = field.shape[1:]
    v = np.asarray(value, dtype=field.dtype)
    if v.ndim < len(fshape) or any(a > b for a, b in zip(v.shape[v.ndim - len(fshape) :], fshape, strict=True)):
        raise ValueError(f"{name}: a value of shape {v.shape} does not fit the field's {fshape}")
    vshape = v.shape[v.ndim - len(fshape) :]
    field[(slice(None), *(slice(0, s) for s in vshape))] = v
