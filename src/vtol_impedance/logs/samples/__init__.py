"""Sample flight logs that ship with the package, written by the project's own simulator with a known
wrench (``tools``: :mod:`vtol_impedance.logs.samples.generate` rewrites them).

One simulated flight (the Pelican of case B: take off, hover in front of the fan with the unmodelled
payload, then a minimum-jerk move away from the fan and a hold; rotor lag on, sensor noise on, sensor
latency off) written the way each autopilot logs it. ``vtol-impedance estimate --example NAME`` runs
the estimate on one (``--example list`` lists them); :func:`path` gives the file, :func:`truth` the
wrench the estimate should find.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from ...errors import InputError

#: name -> (file, what it shows)
SAMPLES: dict[str, tuple[str, str]] = {
    "csv": (
        "flight.csv",
        "CSV, world NED / body FRD, quaternion w x y z, time on a unix clock, normalised thrust with a per-sample "
        "hover_thrust column (a 6 % battery sag), torques in N m, rotor speeds rpm1..rpm4",
    ),
    "ros-csv": (
        "flight-ros.csv",
        "the same flight as a ROS export: world ENU, body FLU, quaternion x y z w, rates in deg/s, time in ms "
        "(try --conventions auto)",
    ),
    "px4": (
        "px4-v1.14.ulg",
        "PX4 >= 1.14 topics (vehicle_thrust_setpoint, vehicle_torque_setpoint), hover_thrust_estimate per sample, "
        "esc_status rotor speeds, CA_ROTOR* geometry, SIH_MASS/SIH_I* (mass and inertia from the log)",
    ),
    "px4-v1.9": (
        "px4-v1.9.ulg",
        "PX4 v1.9 topics: actuator_controls_0 at 9 Hz and vehicle_rates_setpoint at 30 Hz, velocity at 8 Hz with "
        "0.3-0.5 s dropouts, MPC_THR_HOVER, no rotor geometry",
    ),
    "ardupilot": (
        "arducopter.bin",
        "ArduPilot DataFlash (ArduCopter 4.x messages): ATT, RATE, XKF1, CTUN (ThO, ThH), RCOU motor outputs "
        "(PWM by ArduCopter's default thrust curve), ESC rotor speeds, PARM",
    ),
    "tlog": (
        "telemetry.tlog",
        "MAVLink 2 telemetry (ArduPilot streams): ATTITUDE 25 Hz, LOCAL_POSITION_NED 10 Hz, VFR_HUD throttle 10 Hz, "
        "SERVO_OUTPUT_RAW 10 Hz (PWM by ArduCopter's default thrust curve), ESC_TELEMETRY_1_TO_4, PARAM_VALUE "
        "MOT_THST_HOVER and the motor parameters",
    ),
}
TRUTH_FILE = "truth.csv"
#: The simulated vehicle's nominal mass (the Pelican), what ``--mass`` should say.
MASS_KG = 1.2


def names() -> list[str]:
    return list(SAMPLES)


def folder() -> Path:
    return Path(str(resources.files(__name__)))


def path(name: str) -> Path:
    """The file of sample ``name``; an unknown name is an error that lists the samples."""
    if name not in SAMPLES:
        raise InputError(f"no sample log {name!r}; the samples are: {', '.join(SAMPLES)} (--example list)")
    p = folder() / SAMPLES[name][0]
    if not p.is_file():
        raise InputError(f"sample log {name!r} is missing from the installation ({p}); reinstall the package")
    return p


def listing() -> str:
    """One line per sample: its name, file and what it shows."""
    width = max(len(n) for n in SAMPLES)
    return "\n".join(f"{n:<{width}}  {f}: {what}" for n, (f, what) in SAMPLES.items())


def truth() -> dict[str, np.ndarray]:
    """The simulated flight's truth on the simulator's clock (``t_s`` from the start of the flight):
    ``f_lumped_W`` (everything the nominal model misses with the commanded thrust, the estimator's target),
    ``f_rotor_W`` (the same with the rotors' actual thrust: the target of a rotor-speed estimate),
    ``tau_lumped_eta``; and the time offset of each sample's clock, ``clock_offset_s[name]``."""
    data = np.genfromtxt(folder() / TRUTH_FILE, delimiter=",", names=True)
    out = {"t_s": data["t_s"]}
    for key in ("f_lumped_W", "f_rotor_W", "tau_lumped_eta"):
        out[key] = np.stack([data[f"{key}_{a}"] for a in "xyz"], -1)
    return out


#: Each sample's time = simulator time + this offset (s).
CLOCK_OFFSET_S = {
    "csv": 1_767_225_600.0,
    "ros-csv": 0.0,
    "px4": 12.5,
    "px4-v1.9": 12.5,
    "ardupilot": 30.0,
    "tlog": 30.0,
}
