"""Aerodynamic forces of a multirotor that the controller does not model: rotor drag, inflow damping, body drag.

Three terms of the vehicle description (:class:`~vtol_impedance.model.VehicleParams`), each 0 unless given,
act on the true plant only (:mod:`vtol_impedance.sim.plant`). With ``v_B = R_WBᵀ v_W`` the body origin's
airspeed in the body frame (FRD; still air: its velocity),

    f_aero_B = -D v_B - |v_B| C v_B,    D = diag(d_x, d_y, d_z),  C = diag(c_x, c_y, c_z)

* **rotor drag** ``d_x, d_y`` (N per m/s): the blade-flapping and induced-drag (H-force) of the rotors,
  linear in the rotor-plane velocity. This is the lumped form ``-R D Rᵀ v`` of Faessler, Franchi and
  Scaramuzza, "Differential flatness of quadrotor dynamics subject to rotor drag for accurate tracking
  of high-speed trajectories", IEEE RA-L 3(2), 2018, eq. (2) (there mass-normalised); per rotor it is
  ``-k_d omega_i v_perp`` (Martin and Salaün, "The true role of accelerometer feedback in quadrotor
  control", ICRA 2010), whose sum near hover is ``d = k_d sum(omega_i)`` (:func:`linear_drag_from_rotor_speed`).
* **inflow damping** ``d_z`` (N per m/s): the thrust a rotor loses when it climbs into its own inflow,
  ``T(v_c) = T_h - d_z v_c`` with the climb speed ``v_c = -v_B,z`` along the thrust axis, linearised
  about hover. Blade-element momentum theory gives the coefficient (:func:`inflow_damping_from_momentum`,
  the hover heave damping ``Z_w`` of Padfield, *Helicopter Flight Dynamics*, 2nd ed., 2007, Sec. 4.3).
* **body drag** ``c_x, c_y, c_z`` (N per (m/s)^2): the frame's parasitic drag, ``1/2 rho C_d A`` per body
  axis, quadratic in airspeed (the form of RotorPy: Folk et al., "RotorPy: a Python-based multirotor
  simulator with aerodynamics for education and research", 2023).

The linear terms are the same drag whichever rotor produced it: a rotor drag proportional to thrust or
rotor speed is constant near hover, which is where this package's vehicles fly; the rotor drag's moment
from the body rate (``omega x r_i``) is left out. All functions broadcast over leading batch dimensions.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError, as_finite, scalar

#: Density of air, kg/m^3 (ISA sea level).
AIR_DENSITY = 1.225


def aero_force_B(v_B: np.ndarray, linear_B: np.ndarray, quadratic_B: np.ndarray) -> np.ndarray:
    """The aerodynamic force ``-D v_B - |v_B| C v_B`` (N, body FRD) at airspeed ``v_B (..., 3)`` (m/s, body).

    Parameters
    ----------
    v_B : ndarray, shape (..., 3)
        Airspeed of the body origin in the body frame, m/s.
    linear_B : ndarray, shape (..., 3)
        ``(d_x, d_y, d_z)``: rotor drag in the rotor plane and inflow damping along the thrust axis, N per m/s.
    quadratic_B : ndarray, shape (..., 3)
        ``(c_x, c_y, c_z)``: body drag per body axis, N per (m/s)^2.
    """
    speed = np.sqrt(np.sum(v_B * v_B, -1, keepdims=True))
    return -(linear_B + speed * quadratic_B) * v_B


def linear_drag_from_rotor_speed(coefficient: float, hover_speed: float, n_rotors: int) -> float:
    """The vehicle's linear drag (N per m/s) from a per-rotor coefficient proportional to rotor speed.

    RotorPy and Martin and Salaün (2010) write a rotor's drag as ``-k omega_i v`` with ``k`` in
    N per (rad/s) per (m/s); near hover every rotor turns at ``hover_speed`` (rad/s), so the vehicle's
    coefficient is ``n_rotors k omega_h``.
    """
    k = scalar("coefficient", coefficient, lo=0.0)
    w = scalar("hover_speed", hover_speed, lo=0.0, lo_open=True)
    n = int(scalar("n_rotors", n_rotors, lo=1, integer=True))
    return n * k * w


def inflow_damping_from_momentum(
    hover_thrust: float,
    rotor_radius: float,
    tip_speed: float,
    solidity: float,
    lift_slope: float = 5.7,
    n_rotors: int = 4,
    air_density: float = AIR_DENSITY,
) -> float:
    """Inflow damping ``-dT/dv_c`` at hover (N per m/s, the whole vehicle) from blade-element momentum theory.

    A rotor of ideal twist at constant speed gives ``C_T = (sigma a / 4)(theta_tip - lambda_c - lambda_i)``
    (blade elements) and ``C_T = 2 lambda_i (lambda_c + lambda_i)`` (momentum), with inflow ratios
    ``lambda = v / (Omega R)``. Differentiated at hover (``lambda_c = 0``, ``lambda_i = lambda_h =
    sqrt(C_T / 2)``): ``dC_T / dlambda_c = -2 sigma a lambda_h / (16 lambda_h + sigma a)``, so per rotor
    ``dT/dv_c = rho A Omega R dC_T/dlambda_c``: the hover heave damping ``Z_w`` of Padfield (2007, Sec. 4.3).
    As ``sigma a`` grows it tends to the momentum-theory bound ``T_h / v_h`` (inflow held at ``v_h``).

    Parameters
    ----------
    hover_thrust : float
        Thrust of one rotor at hover, N.
    rotor_radius : float
        Propeller radius ``R``, m.
    tip_speed : float
        ``Omega R`` at hover, m/s.
    solidity : float
        Blade area over disc area ``sigma`` (small propellers: 0.05-0.15).
    lift_slope : float
        Blade section lift slope ``a``, per rad (about 5.7 for small propellers; 2 pi in thin-airfoil theory).
    n_rotors : int
        Rotors sharing the weight.
    air_density : float
        kg/m^3.
    """
    T = scalar("hover_thrust", hover_thrust, lo=0.0, lo_open=True)
    R = scalar("rotor_radius", rotor_radius, lo=0.0, lo_open=True)
    tip = scalar("tip_speed", tip_speed, lo=0.0, lo_open=True)
    sa = scalar("solidity", solidity, lo=0.0, lo_open=True, hi=1.0) * scalar(
        "lift_slope", lift_slope, lo=0.0, lo_open=True
    )
    n = int(scalar("n_rotors", n_rotors, lo=1, integer=True))
    rho = scalar("air_density", air_density, lo=0.0, lo_open=True)
    A = np.pi * R * R
    lam_h = np.sqrt(T / (2.0 * rho * A)) / tip
    return float(n * rho * A * tip * 2.0 * sa * lam_h / (16.0 * lam_h + sa))


def check_coefficients(name: str, value: Any, size: int) -> tuple[float, ...]:
    """Nonnegative, finite drag coefficients: one number (every axis) or ``size`` numbers, as a tuple."""
    arr = as_finite(name, value)
    if arr.shape not in ((), (size,)):
        raise InputError(f"{name} must be one number or {size} numbers (one per body axis), got {value!r}")
    if np.any(arr < 0):
        raise InputError(f"{name} must be >= 0 (a drag takes energy out), got {value!r}")
    return tuple(float(v) for v in np.broadcast_to(arr, (size,)))


__all__ = [
    "AIR_DENSITY",
    "aero_force_B",
    "inflow_damping_from_momentum",
    "linear_drag_from_rotor_speed",
]
