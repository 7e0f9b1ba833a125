"""PX4 flight logs (ULog) through ``pyulog``, across PX4 generations.

Topics read (first instance), by role, in order of preference:

* velocity (NED): ``vehicle_local_position.vx, vy, vz``;
* attitude: ``vehicle_attitude.q[0..3]`` (w, x, y, z; body FRD to NED);
* body rates (FRD): ``vehicle_angular_velocity.xyz[0..2]`` (PX4 >= 1.11), else
  ``vehicle_attitude.rollspeed, pitchspeed, yawspeed`` (older logs), else ``sensor_combined.gyro_rad[0..2]``;
* thrust and torque commands (normalised): ``vehicle_thrust_setpoint.xyz[2]`` (thrust is ``-xyz[2]``,
  FRD) and ``vehicle_torque_setpoint.xyz[0..2]`` (PX4 >= 1.14), else ``actuator_controls_0.control[0..3]``
  (roll, pitch, yaw, thrust; before 1.14);
* hover thrust: ``hover_thrust_estimate.hover_thrust`` (median over samples flagged valid).

Normalised torque becomes N m through the rotor geometry stored in the log's parameters (control
allocation, PX4 >= 1.13: ``CA_ROTOR_COUNT``, ``CA_ROTOR{i}_PX/PY``, ``CA_ROTOR{i}_KM``, optional
``CA_ROTOR{i}_AX/AY/AZ``): PX4's allocator maps a normalised torque ``c`` to actuator commands with the
pseudo-inverse of the effectiveness matrix whose columns it scales (roll and pitch by the RMS of their
non-zero entries over half the rotor count, yaw by its largest entry), so the physical torque is
``c / scale``. With a rotor's thrust per unit command ``c_T = m g / (n_rotors * hover_thrust)`` (the same
linear map as the thrust) this gives N m. Without these parameters (older logs) the moment estimate is
skipped unless a torque scale is given.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from .timeseries import RawLog, Signal

TOPICS = (
    "vehicle_local_position",
    "vehicle_attitude",
    "vehicle_angular_velocity",
    "sensor_combined",
    "vehicle_thrust_setpoint",
    "vehicle_torque_setpoint",
    "actuator_controls_0",
    "hover_thrust_estimate",
)


def _pyulog():
    try:
        from pyulog import ULog
    except ImportError:  # pragma: no cover - pyulog is a core dependency
        raise InputError("reading ULog files needs pyulog: pip install pyulog") from None
    return ULog


def torque_per_unit(params: dict[str, float]) -> tuple[np.ndarray, int] | None:
    """``(k (3,), n_rotors)``: N m of body torque per unit normalised torque, per newton of a rotor's thrust
    at full command, from PX4's control-allocation parameters; ``None`` when they are absent."""
    n = int(params.get("CA_ROTOR_COUNT", 0) or 0)
    if n < 2 or any(f"CA_ROTOR{i}_PX" not in params or f"CA_ROTOR{i}_PY" not in params for i in range(n)):
        return None
    E = np.zeros((4, n))  # rows: roll, pitch, yaw torque, thrust along -z; thrust coefficient 1
    for i in range(n):
        p = np.array([params[f"CA_ROTOR{i}_PX"], params[f"CA_ROTOR{i}_PY"], params.get(f"CA_ROTOR{i}_PZ", 0.0)])
        axis = np.array([params.get(f"CA_ROTOR{i}_A{c}", d) for c, d in (("X", 0.0), ("Y", 0.0), ("Z", -1.0))])
        axis = axis / max(np.linalg.norm(axis), 1e-9)
        km = params.get(f"CA_ROTOR{i}_KM", 0.05)
        E[:3, i] = np.cross(p, axis) - km * axis
        E[3, i] = -axis[2]
    mix = np.linalg.pinv(E)
    nz_r = np.count_nonzero(np.abs(mix[:, 0]) > 1e-3)
    nz_p = np.count_nonzero(np.abs(mix[:, 1]) > 1e-3)
    s_r = np.sqrt(np.sum(mix[:, 0] ** 2) / (nz_r / 2.0)) if nz_r else 1.0
    s_p = np.sqrt(np.sum(mix[:, 1] ** 2) / (nz_p / 2.0)) if nz_p else 1.0
    s_rp = max(s_r, s_p)
    s_y = float(np.max(mix[:, 2]))
    if not (s_rp > 0 and s_y > 0):
        return None
    return np.array([1.0 / s_rp, 1.0 / s_rp, 1.0 / s_y]), n


def read_ulog(path: str | os.PathLike[str]) -> RawLog:
    """Read a PX4 ULog into world NED / body FRD signals (see the module docstring for the topics)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"log file {path} {'is not a file' if path.exists() else 'does not exist'}")
    ULog = _pyulog()
    try:
        ulog = ULog(str(path), TOPICS)
    except Exception as exc:  # pyulog raises several types on a corrupt or foreign file
        raise InputError(f"{path} is not a readable ULog file ({type(exc).__name__}: {exc})") from None
    notes: list[str] = []
    if getattr(ulog, "file_corruption", False):
        notes.append("pyulog found corrupted data in the file and skipped it")
    found = {d.name: d for d in sorted(ulog.data_list, key=lambda d: d.multi_id, reverse=True)}
    all_found = sorted(found)

    def pick(role: str, options: list[tuple[str, list[str]]]) -> tuple[str, np.ndarray, np.ndarray]:
        for topic, fields in options:
            d = found.get(topic)
            if d is not None and all(f in d.data for f in fields):
                t = d.data["timestamp"].astype(float) * 1e-6
                return f"{topic}.{','.join(fields)}", t, np.stack([d.data[f].astype(float) for f in fields], -1)
        wanted = " or ".join(f"{t} ({', '.join(f)})" for t, f in options)
        raise InputError(
            f"{path}: no {role}: needs {wanted}; the log has: {', '.join(all_found) or 'no topics of interest'}"
        )

    src, t, v = pick("velocity", [("vehicle_local_position", ["vx", "vy", "vz"])])
    vel = Signal("velocity", src, t, v)
    src, t, q = pick("attitude", [("vehicle_attitude", [f"q[{i}]" for i in range(4)])])
    from .frames import eta_ned_frd, quaternion_rotation

    good = np.all(np.isfinite(q), axis=1)
    eta = np.full((len(t), 3), np.nan)
    eta[good] = eta_ned_frd(quaternion_rotation(q[good], "wxyz", "body-to-world"), "ned", "frd")
    att = Signal("attitude", src, t, eta)
    src, t, w = pick(
        "body rates",
        [
            ("vehicle_angular_velocity", [f"xyz[{i}]" for i in range(3)]),
            ("vehicle_attitude", ["rollspeed", "pitchspeed", "yawspeed"]),
            ("sensor_combined", [f"gyro_rad[{i}]" for i in range(3)]),
        ],
    )
    rates = Signal("body rates", src, t, w)
    meta: dict = {"format": "ulog", "file": str(path)}
    try:
        meta["px4_version"] = ulog.get_version_info_str() or "unknown"
    except Exception:  # an absent or malformed version string
        meta["px4_version"] = "unknown"
    if "vehicle_thrust_setpoint" in found:
        src, t, f = pick("thrust command", [("vehicle_thrust_setpoint", ["xyz[2]"])])
        thrust = Signal("thrust", src + " (negated)", t, -f, hold=True)
        torque_opts = [("vehicle_torque_setpoint", [f"xyz[{i}]" for i in range(3)])]
        meta["px4_generation"] = ">= 1.14 (vehicle_thrust_setpoint, vehicle_torque_setpoint)"
    else:
        src, t, c = pick(
            "thrust command",
            [
                ("vehicle_thrust_setpoint", ["xyz[2]"]),
                ("actuator_controls_0", ["control[3]"]),
            ],
        )
        thrust = Signal("thrust", src, t, c, hold=True)
        torque_opts = [("actuator_controls_0", [f"control[{i}]" for i in range(3)])]
        meta["px4_generation"] = "< 1.14 (actuator_controls_0)"
    torque = None
    try:
        src, t, tq = pick("torque command", torque_opts)
        torque = Signal("torque", src + " (normalised)", t, tq, hold=True)
    except InputError:
        notes.append("no torque setpoint topic in the log: the moment estimate is skipped")
    kw: dict = {}
    geo = torque_per_unit({k: float(v) for k, v in ulog.initial_parameters.items()})
    if geo is not None:
        kw["torque_per_unit"], kw["n_rotors"] = geo
        meta["rotor_geometry"] = f"CA_ROTOR* parameters, {geo[1]} rotors"
    d = found.get("hover_thrust_estimate")
    if d is not None and "hover_thrust" in d.data:
        h = d.data["hover_thrust"].astype(float)
        if "valid" in d.data:
            h = h[d.data["valid"].astype(bool)]
        h = h[np.isfinite(h) & (h > 0.02) & (h < 1.0)]
        if len(h):
            kw["hover_thrust"] = float(np.median(h))
            kw["hover_source"] = "hover_thrust_estimate (median of valid samples)"
    return RawLog(vel, att, rates, thrust, torque, "normalized", "normalized", notes=notes, meta=meta, **kw)
