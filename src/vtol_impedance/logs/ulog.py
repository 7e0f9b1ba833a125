"""PX4 flight logs (ULog) through ``pyulog``, across PX4 generations (v1.8 to v1.15 and later).

Every role may be logged by several topics; the reader takes the **highest-rate** one present (topics
within 20 % of the best rate count as equal, and then the earlier in the list wins), and says which:

==============  ==========================================================================================
velocity (NED)  ``vehicle_local_position.vx, vy, vz``; ``vehicle_global_position.vel_n, vel_e, vel_d``
attitude        ``vehicle_attitude.q[0..3]`` (w, x, y, z; body FRD to NED)
body rates FRD  ``vehicle_angular_velocity.xyz`` (>= 1.11); ``vehicle_attitude.rollspeed, pitchspeed,
                yawspeed`` (older); ``sensor_combined.gyro_rad`` (raw gyro)
thrust          ``vehicle_thrust_setpoint.xyz[2]`` (>= 1.14, negated: FRD); ``actuator_controls_0.control[3]``
                (< 1.14); ``vehicle_rates_setpoint.thrust_body[2]`` (>= 1.9, negated) or ``.thrust``
                (<= 1.8); ``vehicle_attitude_setpoint.thrust_body[2]`` / ``.thrust`` (same command, the rate
                controller passes it on)
torque          ``vehicle_torque_setpoint.xyz`` (>= 1.14); ``actuator_controls_0.control[0..2]`` (< 1.14)
hover thrust    ``hover_thrust_estimate.hover_thrust`` (samples flagged valid; >= 1.12), **per sample**;
                else the parameter ``MPC_THR_HOVER``
rotor speeds    ``esc_status.esc[i].esc_rpm`` (ESC telemetry; ``esc_count`` rotors), rpm
mass, inertia   ``SIH_MASS``, ``SIH_IXX/IYY/IZZ/IXY/IXZ/IYZ`` (simulation-in-hardware logs carry the
                vehicle's; a real PX4 firmware has no mass parameter)
==============  ==========================================================================================

Measurement times: where a topic logs ``timestamp_sample`` (the instant the measurement was taken; PX4
>= 1.11 for attitude, rates and local position) it is used instead of ``timestamp`` (when it was
published), so the log's own timestamps align the velocity and attitude with the commands (issue 15:
"in a log, the measurement delay comes from the timestamps"); the estimator's ``--velocity-delay`` and
``--attitude-delay`` then stay 0.

Normalised torque becomes N m through the rotor geometry stored in the log's parameters (control
allocation, PX4 >= 1.13: ``CA_ROTOR_COUNT``, ``CA_ROTOR{i}_PX/PY``, ``CA_ROTOR{i}_KM``, optional
``CA_ROTOR{i}_AX/AY/AZ``): PX4's allocator maps a normalised torque ``c`` to actuator commands with the
pseudo-inverse of the effectiveness matrix whose columns it scales (roll and pitch by the RMS of their
non-zero entries over half the rotor count, yaw by its largest entry), so the physical torque is
``c / scale``. With a rotor's thrust per unit command ``c_T = m g / (n_rotors * hover_thrust)`` (the same
linear map as the thrust) this gives N m. Without these parameters (older logs) the moment estimate is
skipped unless a torque scale is given. The same parameters give the rotor positions and yaw moments for
thrust and torque from rotor speeds.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..io import explain_path
from .frames import ROTOR_SPEED_UNITS
from .timeseries import RawLog, Signal, typical_period

TOPICS = (
    "vehicle_local_position",
    "vehicle_global_position",
    "vehicle_attitude",
    "vehicle_angular_velocity",
    "sensor_combined",
    "vehicle_thrust_setpoint",
    "vehicle_torque_setpoint",
    "actuator_controls_0",
    "vehicle_rates_setpoint",
    "vehicle_attitude_setpoint",
    "hover_thrust_estimate",
    "esc_status",
)
#: Rates within this factor of the best count as equal (the earlier option wins).
RATE_TIE = 1.2
#: A source chosen by its rate must span this share of the longest source's time: a stream requested for
#: seconds (a ground station's probe) loses to one that covers the flight, however fast.
SPAN_SHARE = 0.5

VELOCITY = [
    ("vehicle_local_position", ["vx", "vy", "vz"], 1.0),
    ("vehicle_global_position", ["vel_n", "vel_e", "vel_d"], 1.0),
]
RATES = [
    ("vehicle_angular_velocity", [f"xyz[{i}]" for i in range(3)], 1.0),
    ("vehicle_attitude", ["rollspeed", "pitchspeed", "yawspeed"], 1.0),
    ("sensor_combined", [f"gyro_rad[{i}]" for i in range(3)], 1.0),
]
THRUST = [
    ("vehicle_thrust_setpoint", ["xyz[2]"], -1.0),
    ("actuator_controls_0", ["control[3]"], 1.0),
    ("vehicle_rates_setpoint", ["thrust_body[2]"], -1.0),
    ("vehicle_rates_setpoint", ["thrust"], 1.0),
    ("vehicle_attitude_setpoint", ["thrust_body[2]"], -1.0),
    ("vehicle_attitude_setpoint", ["thrust"], 1.0),
]
TORQUE = [
    ("vehicle_torque_setpoint", [f"xyz[{i}]" for i in range(3)], 1.0),
    ("actuator_controls_0", [f"control[{i}]" for i in range(3)], 1.0),
]


def _pyulog():
    try:
        from pyulog import ULog
    except ImportError:  # pragma: no cover - pyulog is a core dependency
        raise InputError("reading ULog files needs pyulog: pip install pyulog") from None
    return ULog


def _pca_matrix(params: dict[str, float]) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The rotor geometry from PX4's control-allocation parameters; ``None`` when they are absent or not
    finite (a damaged parameter: the force estimate does not need the geometry)."""
    count = params.get("CA_ROTOR_COUNT", 0) or 0
    if not np.isfinite(count) or not 2 <= count <= 64:
        return None
    n = int(count)
    if any(f"CA_ROTOR{i}_PX" not in params or f"CA_ROTOR{i}_PY" not in params for i in range(n)):
        return None
    pos = np.zeros((n, 3))
    axes = np.zeros((n, 3))
    km = np.zeros(n)
    for i in range(n):
        pos[i] = [params[f"CA_ROTOR{i}_PX"], params[f"CA_ROTOR{i}_PY"], params.get(f"CA_ROTOR{i}_PZ", 0.0)]
        a = np.array([params.get(f"CA_ROTOR{i}_A{c}", d) for c, d in (("X", 0.0), ("Y", 0.0), ("Z", -1.0))])
        axes[i] = a / max(np.linalg.norm(a), 1e-9)
        km[i] = params.get(f"CA_ROTOR{i}_KM", 0.05)
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(axes)) and np.all(np.isfinite(km))):
        return None
    return pos, np.column_stack([axes, km]), n


def rotor_geometry(params: dict[str, float]) -> tuple[np.ndarray, np.ndarray] | None:
    """``(positions_B (n, 3), km (n,))`` from PX4's control-allocation parameters (rotors along ``-z_B``:
    a tilted rotor axis is not supported here), ``None`` when absent."""
    got = _pca_matrix(params)
    if got is None:
        return None
    pos, ax_km, _ = got
    if np.any(np.abs(ax_km[:, :3] - [0.0, 0.0, -1.0]) > 1e-3):
        return None
    return pos, ax_km[:, 3]


def torque_per_unit(params: dict[str, float]) -> tuple[np.ndarray, int] | None:
    """``(k (3,), n_rotors)``: N m of body torque per unit normalised torque, per newton of a rotor's thrust
    at full command, from PX4's control-allocation parameters; ``None`` when they are absent."""
    from ..errors import instance

    instance("params", params, dict)
    got = _pca_matrix(params)
    if got is None:
        return None
    pos, ax_km, n = got
    E = np.zeros((4, n))  # rows: roll, pitch, yaw torque, thrust along -z; thrust coefficient 1
    for i in range(n):
        axis, km = ax_km[i, :3], ax_km[i, 3]
        E[:3, i] = np.cross(pos[i], axis) - km * axis
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


def _dev_version(ulog: Any) -> str | None:
    """A development build's version ('v1.15.0 (dev)'; pyulog names only releases), with its git hash."""
    v = ulog.get_version_info()
    if v is None:
        return None
    ver_sw = str(ulog.msg_info_dict.get("ver_sw", ""))[:8]
    return f"v{v[0]}.{v[1]}.{v[2]} (dev{' ' + ver_sw if ver_sw else ''})"


def vehicle_from_params(params: dict[str, float], prefix: str = "SIH_") -> tuple[float | None, np.ndarray | None]:
    """``(mass, inertia 3x3)`` from simulation-in-hardware parameters, ``None`` where absent or not positive."""
    m = params.get(f"{prefix}MASS")
    mass = float(m) if m is not None and m > 0 else None
    names = [f"{prefix}I{a}" for a in ("XX", "YY", "ZZ")]
    if all(n in params and params[n] > 0 for n in names):
        xx, yy, zz = (float(params[n]) for n in names)
        xy, xz, yz = (float(params.get(f"{prefix}I{a}", 0.0)) for a in ("XY", "XZ", "YZ"))
        return mass, np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return mass, None


def pick_fastest(
    role: str,
    options: list[tuple[str, list[str], float]],
    available: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]],
    choices: list[str],
    where: str,
    all_found: list[str],
    required: bool = True,
    skip_zero: bool = False,
) -> tuple[str, np.ndarray, np.ndarray] | None:
    """The highest-rate option ``(topic, fields, sign)`` found in ``available[topic] = (t, data)``: returns
    ``(source, t, values)`` and records the choice; raises (``required``) listing what the log has. With
    ``skip_zero`` a field that is zero throughout (a command field this PX4 version logs but never fills)
    is passed over and reported."""
    found: list[tuple[str, np.ndarray, np.ndarray, float]] = []
    empty: list[str] = []
    for topic, fields, sign in options:
        got = available.get(topic)
        if got is None or not all(f in got[1] for f in fields):
            continue
        t, data = got
        if len(t) < 2:
            continue
        vals = np.stack([np.asarray(data[f], dtype=float) for f in fields], -1) * sign
        if skip_zero and not np.any(np.isfinite(vals) & (vals != 0)):
            empty.append(f"{topic}.{','.join(fields)}")  # a field this PX4 version logs but never fills
            continue
        name = f"{topic}.{','.join(fields)}" + (" (negated)" if sign < 0 else "")
        found.append((name, t, vals, 1.0 / typical_period(t)))
    if not found and empty:
        choices.append(f"{role}: {', '.join(empty)} logged but zero throughout")
        return None
    if not found:
        if not required:
            return None
        wanted = " or ".join(f"{t} ({', '.join(f)})" for t, f, _ in options)
        raise InputError(
            f"{where}: no {role}: needs {wanted}; the log has: {', '.join(all_found) or 'no topics of interest'}"
        )
    return fastest(role, found, choices)


def esc_gap_note(src: str, live: list[int]) -> str:
    """Why rotor speeds are not used: an ESC slot reports zero throughout between slots that report (a
    stopped motor or a renumbered ESC), so which rotor each speed belongs to is not known."""
    dead = sorted(set(range(max(live) + 1)) - set(live))
    return (
        f"rotor speeds: not used: {src} ESC {', '.join(map(str, dead))} reports zero throughout while ESC "
        f"{max(live)} reports (a stopped motor or a missing slot: the rotors' order would be lost)"
    )


def fastest(
    role: str, found: list[tuple[str, np.ndarray, np.ndarray, float]], choices: list[str]
) -> tuple[str, np.ndarray, np.ndarray]:
    """The first of ``found = [(source, t, values, rate_hz)]`` within :data:`RATE_TIE` of the highest rate
    (the order of preference breaks near-ties) among those spanning at least :data:`SPAN_SHARE` of the
    longest one's time, recorded in ``choices`` with the others the log has."""
    spans = [float(np.max(f[1]) - np.min(f[1])) if len(f[1]) > 1 else 0.0 for f in found]
    cover = [f for f, s in zip(found, spans, strict=True) if s >= SPAN_SHARE * max(spans)]
    best_rate = max(f[3] for f in cover)
    pick = next(f for f in cover if f[3] * RATE_TIE >= best_rate)
    others = [
        f"{f[0]} {f[3]:.3g} Hz" + ("" if f in cover else f" over only {s:.3g} of {max(spans):.3g} s")
        for f, s in zip(found, spans, strict=True)
        if f is not pick
    ]
    choices.append(
        f"{role}: {pick[0]} at {pick[3]:.3g} Hz" + (f" (also in the log: {'; '.join(others)})" if others else "")
    )
    return pick[0], pick[1], pick[2]


def read_ulog(path: str | os.PathLike[str]) -> RawLog:
    """Read a PX4 ULog into world NED / body FRD signals (see the module docstring for the topics)."""
    from ..errors import path_like

    path_like("path", path)
    path = Path(path)
    if not path.is_file():
        raise InputError(f"cannot read log file {path}: {explain_path(path) or 'not a regular file'}")
    ULog = _pyulog()
    try:
        with open(path, "rb") as fh:  # ours to close: pyulog leaves a file it opened open when it raises
            ulog = ULog(fh, list(TOPICS))
    except Exception as exc:  # pyulog raises several types on a corrupt or foreign file
        raise InputError(f"{path} is not a readable ULog file ({type(exc).__name__}: {exc})") from None
    try:
        return _from_ulog(path, ulog)
    except InputError:
        raise
    except (KeyError, IndexError, TypeError, AttributeError, ValueError) as exc:  # damaged, and pyulog read it
        raise InputError(
            f"{path}: the ULog's data are damaged or not laid out as PX4 writes them ({type(exc).__name__}: {exc})"
        ) from None


def _in_order(t: np.ndarray) -> np.ndarray:
    """The samples of the time stamps ``t`` that lie between their neighbours where those are in order: a
    garbled sample (0 s, or a time years ahead) is dropped, a true jump back in time (joined logs) is not
    hidden, since both its neighbours stay out of order."""
    keep = np.ones(len(t), bool)
    prev, nxt = t[:-2], t[2:]
    mid = t[1:-1]
    keep[1:-1] = ~((prev <= nxt) & ((mid < prev) | (mid > nxt)))
    if t[0] > t[1] and t[1] <= t[min(2, len(t) - 1)]:
        keep[0] = False
    if t[-1] < t[-2] and t[-3] <= t[-2]:
        keep[-1] = False
    return keep


def _from_ulog(path: Path, ulog: Any) -> RawLog:
    """:func:`read_ulog` of a file pyulog parsed."""
    notes: list[str] = []
    choices: list[str] = []
    if getattr(ulog, "file_corruption", False):
        notes.append("pyulog found corrupted data in the file (a truncated or damaged log) and skipped it")
    found = {d.name: d for d in sorted(ulog.data_list, key=lambda d: d.multi_id, reverse=True)}
    all_found = sorted(found)
    available: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]] = {}
    sample_times = []
    for name, d in list(found.items()):
        if "timestamp" not in d.data:  # a damaged format definition
            notes.append(f"topic {name} has no timestamp (a damaged format definition): not used")
            del found[name]
            continue
        if "timestamp_sample" in d.data and name not in ("vehicle_thrust_setpoint", "vehicle_torque_setpoint"):
            ts = d.data["timestamp_sample"].astype(float)
            ok = np.isfinite(ts) & (ts > 0)
            t = np.where(ok, ts, d.data["timestamp"].astype(float)) * 1e-6
            sample_times.append(name)
        else:
            t = d.data["timestamp"].astype(float) * 1e-6
        data = d.data
        if getattr(ulog, "file_corruption", False) and len(t) >= 3:
            keep = _in_order(t)  # pyulog resynchronised after the damage, with a garbled sample or two
            if not keep.all():
                notes.append(f"topic {name}: {int((~keep).sum())} sample(s) out of time order in the damaged data "
                             "dropped")  # fmt: skip
                t, data = t[keep], {k: np.asarray(v)[keep] for k, v in data.items()}
        available[name] = (t, data)
    params = {}
    for k, v in ulog.initial_parameters.items():
        try:
            params[k] = float(v)
        except (TypeError, ValueError):
            notes.append(f"parameter {k!r} has no numeric value ({v!r}): not used")

    src, t, v = pick_fastest("velocity", VELOCITY, available, choices, str(path), all_found)
    vel = Signal("velocity", src, t, v)
    src, t, q = pick_fastest(
        "attitude", [("vehicle_attitude", [f"q[{i}]" for i in range(4)], 1.0)], available, choices, str(path), all_found
    )
    from .frames import eta_ned_frd, quaternion_rotation

    good = np.all(np.isfinite(q), axis=1) & (np.linalg.norm(q, axis=1) > 0.5)
    eta = np.full((len(t), 3), np.nan)
    eta[good] = eta_ned_frd(quaternion_rotation(q[good], "wxyz", "body-to-world"), "ned", "frd")
    att = Signal("attitude", src, t, eta)
    src, t, w = pick_fastest("body rates", RATES, available, choices, str(path), all_found)
    rates = Signal("body rates", src, t, w)
    meta: dict = {"format": "ulog", "file": str(path)}
    try:
        meta["px4_version"] = ulog.get_version_info_str() or _dev_version(ulog) or "unknown"
    except Exception:  # an absent or malformed version string
        meta["px4_version"] = "unknown"
    meta["px4_generation"] = (
        ">= 1.14 (vehicle_thrust_setpoint, vehicle_torque_setpoint)"
        if "vehicle_thrust_setpoint" in found
        else "< 1.14 (actuator_controls_0)"
    )
    if sample_times:
        meta["measurement_times"] = "timestamp_sample of " + ", ".join(sorted(sample_times))
    thrust = None
    got = pick_fastest("thrust", THRUST, available, choices, str(path), all_found, required=False, skip_zero=True)
    if got is not None:
        thrust = Signal("thrust", got[0], got[1], got[2], hold=True)
    torque = None
    got = pick_fastest("torque", TORQUE, available, choices, str(path), all_found, required=False, skip_zero=True)
    if got is not None:
        torque = Signal("torque", got[0] + " (normalised)", got[1], got[2], hold=True)
    else:
        notes.append("no torque setpoint topic in the log: the moment needs rotor speeds and a rotor geometry")
    kw: dict = {"params": params, "choices": choices}
    geo = torque_per_unit(params)
    if geo is not None:
        kw["torque_per_unit"], kw["n_rotors"] = geo
        meta["rotor_geometry"] = f"CA_ROTOR* parameters, {geo[1]} rotors"
    kw["rotor_geometry"] = rotor_geometry(params)
    d = found.get("hover_thrust_estimate")
    if d is not None and "hover_thrust" in d.data:
        h = d.data["hover_thrust"].astype(float)
        th = available["hover_thrust_estimate"][0]
        ok = np.isfinite(h) & (h > 0.02) & (h < 1.0)
        if "valid" in d.data:
            ok &= d.data["valid"].astype(bool)
        if ok.sum() >= 2:
            kw["hover"] = Signal(
                "hover thrust", "hover_thrust_estimate.hover_thrust (valid samples)", th[ok], h[ok, None]
            )
        elif ok.sum() == 1:
            kw["hover_thrust"] = float(h[ok][0])
            kw["hover_source"] = "hover_thrust_estimate (one valid sample)"
    if "hover" not in kw and "hover_thrust" not in kw and 0.02 < params.get("MPC_THR_HOVER", 0.0) < 1.0:
        kw["hover_thrust"] = params["MPC_THR_HOVER"]
        kw["hover_source"] = "the parameter MPC_THR_HOVER (the log has no hover thrust estimate)"
    d = found.get("esc_status")
    if d is not None:
        n = int(np.max(d.data["esc_count"])) if "esc_count" in d.data else 0
        live = [i for i in range(n) if np.any(d.data.get(f"esc[{i}].esc_rpm", 0) != 0)]  # no motor: zero
        fields = [f"esc[{i}].esc_rpm" for i in live]
        n = len(fields)
        if live != list(range(n)):
            choices.append(esc_gap_note("esc_status", live))
        elif n >= 3:
            rpm = np.stack([d.data[f].astype(float) for f in fields], -1)
            kw["rotor_speed"] = Signal(
                "rotor speeds", f"esc_status.esc[0..{n - 1}].esc_rpm", available["esc_status"][0],
                rpm * ROTOR_SPEED_UNITS["rpm"],
            )  # fmt: skip
            meta["rotor_speed_unit"] = "rpm"
            choices.append(
                f"rotor speeds: esc_status ({n} ESCs) at {1 / typical_period(available['esc_status'][0]):.3g} Hz"
            )
    if thrust is None and "rotor_speed" not in kw:
        zero = [c for c in choices if c.startswith("thrust:") and "zero throughout" in c]
        if zero:
            raise InputError(
                f"{path}: the thrust is zero throughout ({zero[0][len('thrust: ') :]}): the vehicle never flew in "
                "this log (disarmed, on the ground), or the logger did not record it"
            )
        wanted = " or ".join(f"{t} ({', '.join(f)})" for t, f, _ in THRUST)
        raise InputError(
            f"{path}: no thrust: needs {wanted}, or esc_status rotor speeds; the log has: {', '.join(all_found)}"
        )
    mass, inertia = vehicle_from_params(params)
    if mass is not None or inertia is not None:
        kw.update(mass=mass, inertia=inertia, vehicle_source="the SIH_* parameters (simulation in hardware)")
    return RawLog(vel, att, rates, thrust, torque, "normalized", "normalized", notes=notes, meta=meta, **kw)
