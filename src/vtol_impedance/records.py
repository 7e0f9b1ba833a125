"""What a simulated flight records, shared by both executions: the logged signals (one definition, read
by the NumPy loop, the compiled engine and :class:`vtol_impedance.sim.Result`) and when a vehicle is
stopped as failed."""

from __future__ import annotations

import numpy as np

from .errors import InputError, choice, scalar
from .model.vehicle import MAX_ROTORS

#: Logged signals: name -> (trailing shape, unit, meaning). All are sampled at the control rate. A shape
#: ``("rotors",)`` has one value per rotor.
SIGNALS: dict[str, tuple[tuple[int | str, ...], str, str]] = {
    "p_W": ((3,), "m", "true position of the body origin, world NED"),
    "v_W": ((3,), "m/s", "true velocity of the body origin, world NED"),
    "eta": ((3,), "rad", "true ZYX Euler angles"),
    "omega_B": ((3,), "rad/s", "true body rate"),
    "p_ref_W": ((3,), "m", "reference position"),
    "v_ref_W": ((3,), "m/s", "reference velocity"),
    "psi_ref": ((), "rad", "reference yaw"),
    "p_meas_W": ((3,), "m", "measured position"),
    "v_meas_W": ((3,), "m/s", "measured velocity"),
    "eta_meas": ((3,), "rad", "measured Euler angles"),
    "eta_d": ((3,), "rad", "desired (filtered) attitude"),
    "thrust_request": ((), "N", "thrust asked by eq. (16)"),
    "tau_B_request": ((3,), "N m", "body torque asked by eq. (14)"),
    "thrust": ((), "N", "thrust of the allocated rotor forces"),
    "tau_B": ((3,), "N m", "body torque of the allocated rotor forces"),
    "saturated": ((), "bool", "allocation gave something up"),
    "tilt_limited": ((), "bool", "the tilt or lift limit of eq. (16) clamped the desired attitude"),
    "rp_scale": ((), "1", "share of the requested roll/pitch torque the rotors gave"),
    "yaw_scale": ((), "1", "share of the requested yaw torque the rotors gave"),
    "f_ext_W": ((3,), "N", "applied external force at the origin (disturbances, ground, drag), world"),
    "tau_ext_B": ((3,), "N m", "applied external moment about the origin, body frame"),
    "tau_ext_eta": ((3,), "N m", "applied external moment in Euler coordinates, Q^T tau_ext_B"),
    "f_lumped_W": ((3,), "N", "everything the nominal model misses, as a force: the estimator's target"),
    "tau_lumped_eta": ((3,), "N m", "everything the nominal model misses, Euler coordinates"),
    "f_hat_W": ((3,), "N", "estimated external force, world"),
    "tau_hat_eta": ((3,), "N m", "estimated external moment, Euler coordinates"),
    "tau_hat_B": ((3,), "N m", "estimated external moment, body frame"),
    "f_rotor_cmd": (("rotors",), "N", "allocated rotor force commands"),
    "f_rotor": (("rotors",), "N", "true rotor forces (after lag)"),
}


def signal_shape(name: str, n_rotors: int) -> tuple[int, ...]:
    """Trailing shape of a signal for a vehicle with ``n_rotors`` rotors."""
    choice("name", name, tuple(SIGNALS))
    n_rotors = scalar("n_rotors", n_rotors, lo=1, hi=MAX_ROTORS, integer=True)
    return tuple(n_rotors if d == "rotors" else int(d) for d in SIGNALS[name][0])


#: One logged sample of one vehicle: a field per signal (per-rotor signals padded to ``MAX_ROTORS``).
LOG_ROW = np.dtype([(name, np.float64, signal_shape(name, MAX_ROTORS)) for name in SIGNALS])


def empty_log(batch: int, samples: int) -> np.ndarray:
    """Log rows ``(batch, samples)`` of :data:`LOG_ROW`, all NaN (a row never written stays NaN)."""
    batch = scalar("batch", batch, lo=1, integer=True)
    samples = scalar("samples", samples, lo=0, integer=True)
    rows = np.empty((batch, samples), dtype=LOG_ROW)
    rows.view(np.float64)[...] = np.nan  # every field is float64: one fill of the whole block
    return rows


def rows_to_data(rows: np.ndarray, n_rotors: int) -> dict[str, np.ndarray]:
    """Named signals ``(B, N, *shape)`` from log rows ``(B, N)`` of :data:`LOG_ROW` (views, no copy)."""
    if not isinstance(rows, np.ndarray) or rows.dtype != LOG_ROW:
        raise InputError(f"rows must be log rows of dtype LOG_ROW (from empty_log), got {type(rows).__name__}")
    n_rotors = scalar("n_rotors", n_rotors, lo=1, hi=MAX_ROTORS, integer=True)
    return {name: rows[name][..., :n_rotors] if "rotors" in SIGNALS[name][0] else rows[name] for name in SIGNALS}


#: A vehicle is stopped and flagged when its tilt exceeds this (the Euler parametrisation fails at 90 deg).
MAX_TILT_RAD = float(np.radians(80.0))
#: A vehicle this far from the world origin (m) has flown away and is stopped.
MAX_DISTANCE_M = 1e3
#: A vehicle one of whose ground contact points (the body origin, the payload) goes this far into the
#: ground has crashed: the paper's landings compress the ground model by a few millimetres, an impact
#: at about 2.5 m/s by this much.
CRASH_DEPTH_M = 0.015
#: Failure code: the state is no longer finite (0: flying).
FAIL_NAN = 1
#: Failure code: tilted beyond :data:`MAX_TILT_RAD`.
FAIL_TILT = 2
#: Failure code: farther than :data:`MAX_DISTANCE_M` from the origin.
FAIL_FAR = 3
#: Failure code: a contact point deeper than :data:`CRASH_DEPTH_M` into the ground.
FAIL_CRASH = 4
#: What each failure code means, as results report it.
REASONS = {
    FAIL_NAN: "non-finite state",
    FAIL_TILT: f"tilt above {np.degrees(MAX_TILT_RAD):.0f} deg",
    FAIL_FAR: f"more than {MAX_DISTANCE_M:.0f} m from the origin",
    FAIL_CRASH: f"crashed into the ground (a contact point {100 * CRASH_DEPTH_M:.1f} cm into it)",
}
