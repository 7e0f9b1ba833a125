"""ArduPilot DataFlash logs (``.bin``) and MAVLink telemetry logs (``.tlog``) through ``pymavlink``.

Both are read with ``pymavlink.mavutil.mavlink_connection``; fields are read **by name**, so any message
layout of a supported version works (DataFlash carries its own ``FMT`` definitions; MAVLink 1 and 2
tlogs, common and ardupilotmega messages). Where several messages carry a role, the highest-rate one
present wins (within 20 %, the earlier in the list), and the choice is reported.

**DataFlash** (ArduCopter 3.6 to 4.6; time from ``TimeUS``, older ``TimeMS``):

==============  ==========================================================================================
attitude        ``ATT.Roll, Pitch, Yaw`` or ``ANG.Roll, Pitch, Yaw`` (deg, ZYX, body to NED)
body rates      ``RATE.R, P, Y`` (deg/s, AHRS-corrected gyro) or ``IMU.GyrX/Y/Z`` (rad/s, first IMU)
velocity (NED)  ``XKF1.VN, VE, VD`` (EKF3, core 0) or ``NKF1.VN, VE, VD`` (EKF2, core 0), m/s
thrust          ``CTUN.ThO`` (throttle out, 0..1, in ArduPilot's linearised thrust space), or the motor
                outputs ``RCOU.Cn`` (PWM, us; the channels ``SERVOn_FUNCTION`` 33..40) read through ArduCopter's
                thrust curve (:mod:`.ardupilot`, with ``BAT.Volt`` when ``MOT_BAT_VOLT_MAX`` is set): the
                faster, ``CTUN`` on a tie; refused, naming the parameter, when one the curve needs is not logged
hover thrust    ``CTUN.ThH`` (learned hover throttle, per sample), else the parameter ``MOT_THST_HOVER``
                (a QuadPlane's ``Q_M_THST_HOVER``)
torque          ``RATE.ROut, POut, YOut`` (normalised; N m only with ``--torque-scale``: ArduPilot logs no
                arm length)
rotor speeds    ``ESC.RPM`` per ``Instance`` (4.1+; ESC ``i`` taken as motor ``i + 1``), or ``ESC1..ESC8.RPM``
parameters      ``PARM.Name, Value``
==============  ==========================================================================================

**tlog** (the vehicle's clock: ``time_boot_ms``/``time_usec``; messages without one, ``VFR_HUD`` and
``ESC_TELEMETRY_1_TO_4``, are placed on it at the time of the timed message sent just before them, at most
their receive time minus the link's smallest delay):

==============  ==========================================================================================
attitude        ``ATTITUDE.roll, pitch, yaw`` or ``ATTITUDE_QUATERNION.q1..q4`` (rad, body to NED)
body rates      ``ATTITUDE.rollspeed, pitchspeed, yawspeed`` (or the quaternion message's), or
                ``HIGHRES_IMU.xgyro..`` (rad/s)
velocity (NED)  ``LOCAL_POSITION_NED.vx, vy, vz`` (m/s) or ``GLOBAL_POSITION_INT.vx, vy, vz`` (cm/s)
thrust          ``ATTITUDE_TARGET.thrust`` (0..1; PX4 streams it), ``ACTUATOR_CONTROL_TARGET.controls[3]``
                (PX4 < 1.14), else ``VFR_HUD.throttle`` (percent, whole numbers: coarse); from ArduPilot
                also ``SERVO_OUTPUT_RAW.servoN_raw`` (PWM) through its thrust curve as for ``RCOU`` (with
                ``SYS_STATUS.voltage_battery``), when the tlog holds the parameters (``PARAM_VALUE``)
torque          ``ACTUATOR_CONTROL_TARGET.controls[0..2]`` (normalised, PX4 < 1.14)
rotor speeds    ``ESC_STATUS.rpm`` (by ``index``) or ``ESC_TELEMETRY_1_TO_4.rpm`` (ArduPilot)
parameters      ``PARAM_VALUE`` (when the ground station downloaded them): ``MPC_THR_HOVER``,
                ``MOT_THST_HOVER``, PX4's ``CA_ROTOR*`` and ``SIH_*``
==============  ==========================================================================================

A tlog of several vehicles (MAVLink system ids) is read for one: ``sysid`` (:func:`read_tlog`); without it
a tlog of two that could each be estimated is refused, naming them and their attitude message counts.
A tlog without the streams the estimate needs is refused with the streams to request and their rates
(:data:`STREAM_ADVICE`). A file cut short inside a message (a truncated download) loses that message,
and the repair is reported; damaged bytes that ``pymavlink`` skips are counted and reported.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import tempfile
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..io import explain_path
from .airframe import classify
from .ardupilot import MotorCurve, motor_channels
from .frames import ROTOR_SPEED_UNITS, eta_ned_frd, euler_rotation, quaternion_rotation
from .timeseries import RawLog, Signal, typical_period
from .ulog import RATE_TIE, esc_gap_note, fastest, rotor_geometry, torque_per_unit, vehicle_from_params

#: What to request from the vehicle when a tlog lacks a stream: role -> (messages, advice).
STREAM_ADVICE = {
    "attitude": (
        "ATTITUDE or ATTITUDE_QUATERNION",
        "ATTITUDE at 25 Hz or more (ArduPilot: SR0_EXTRA1 = 25; PX4: mavlink stream -s ATTITUDE -r 50)",
    ),
    "body rates": ("ATTITUDE (rollspeed..) or HIGHRES_IMU", "ATTITUDE at 25 Hz or more (as above)"),
    "velocity": (
        "LOCAL_POSITION_NED or GLOBAL_POSITION_INT",
        "LOCAL_POSITION_NED at 10 Hz or more (ArduPilot: SR0_POSITION = 10; PX4: mavlink stream -s "
        "LOCAL_POSITION_NED -r 30)",
    ),
    "thrust": (
        "ATTITUDE_TARGET, ACTUATOR_CONTROL_TARGET or VFR_HUD",
        "ATTITUDE_TARGET at 25 Hz or more (PX4: mavlink stream -s ATTITUDE_TARGET -r 50), or VFR_HUD at 10 Hz "
        "or more (ArduPilot: SR0_EXTRA2 = 10), or ESC telemetry with rotor speeds (ArduPilot: SR0_EXTRA3)",
    ),
}
MIN_STREAM_HZ = 5.0


def _connect(path: Path, out: io.StringIO, err: io.StringIO):
    try:
        from pymavlink import mavutil
    except ImportError:  # pragma: no cover - a core dependency
        raise InputError("reading DataFlash and tlog files needs pymavlink: pip install pymavlink") from None
    with _descriptors_into(err), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        return mavutil.mavlink_connection(str(path))


#: The most of pymavlink's own messages kept (a foreign file gives a "bad header" line per byte).
MAX_READER_MESSAGES_BYTES = 1 << 20


@contextlib.contextmanager
def _descriptors_into(err: io.StringIO) -> Any:
    """Standard output and error at the descriptor level into ``err``: pymavlink's compiled DataFlash
    indexer prints there itself, a line per unreadable byte of a foreign file."""
    import sys
    import tempfile

    with tempfile.TemporaryFile() as tmp:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        saved = [os.dup(1), os.dup(2)]
        try:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            tmp.seek(0)
            err.write(tmp.read(MAX_READER_MESSAGES_BYTES).decode("utf-8", "replace"))


def _close(reader: Any) -> None:
    """Close a pymavlink reader (its file, and a DataFlash log's memory map); what it raises is moot."""
    try:
        reader.close()
    except Exception:  # noqa: BLE001 - an already-closed or half-made reader
        pass


class _Table:
    """Messages of one type as arrays by field."""

    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []

    def arrays(self) -> dict[str, np.ndarray]:
        if not self.rows:
            return {}
        keys = self.rows[0].keys()
        out = {}
        for k in keys:
            try:
                out[k] = np.array([r.get(k, np.nan) for r in self.rows], dtype=float)
            except (TypeError, ValueError):
                continue
        return out


def _pick(
    role: str,
    options: list[tuple[str, list[str], float, dict[str, Any]]],
    tables: dict[str, dict[str, np.ndarray]],
    choices: list[str],
) -> tuple[str, np.ndarray, np.ndarray] | None:
    """The highest-rate option ``(message, fields, scale, {instance_field: value})``; ``None`` when absent."""
    found = []
    for msg, fields, scale, where in options:
        d = tables.get(msg)
        if not d or not all(f in d for f in fields) or "_t" not in d:
            continue
        sel = np.ones(len(d["_t"]), bool)
        for k, v in where.items():
            if k in d:
                sel &= d[k] == v
        if sel.sum() < 2:
            continue
        t = d["_t"][sel]
        vals = np.stack([d[f][sel] for f in fields], -1) * scale
        order = np.argsort(t, kind="stable")
        found.append((f"{msg}.{','.join(fields)}", t[order], vals[order], 1.0 / typical_period(t)))
    if not found:
        return None
    return fastest(role, found, choices)


def _with_motor_outputs(
    thrust: tuple[str, np.ndarray, np.ndarray] | None,
    table: dict[str, np.ndarray],
    msg: str,
    field: str,
    params: dict[str, float],
    volt: tuple[np.ndarray, np.ndarray, str] | None,
    choices: list[str],
    notes: list[str],
) -> tuple[str, np.ndarray, np.ndarray] | None:
    """The thrust source: ``thrust`` (a :func:`_pick` result or ``None``) or ArduCopter's motor outputs ``table``
    (message ``msg``, PWM fields ``field.format(channel)``) read through its thrust curve (:mod:`.ardupilot`),
    as their mean rotor thrust (0..1, the space of ``CTUN.ThO``); the faster, ``thrust`` on a tie unless it is
    ``VFR_HUD``'s whole percent, recorded in ``choices``. ``volt``: ``(t, V, source)`` of the battery voltage.
    Outputs the curve cannot read (a parameter not in the log) are refused with a note naming it."""
    found = []
    if thrust is not None:
        found.append((*thrust, 1.0 / typical_period(thrust[1])))
    if "_t" in table and len(table["_t"]) >= 2:
        try:
            curve = MotorCurve.from_params(params)
            chans = motor_channels(params)
            if chans is None:
                raise InputError("ArduCopter motor outputs need SERVOn_FUNCTION (33..40: Motor1..8) to find the motors")
            cols = [field.format(c) for c in chans]
            if any(c not in table for c in cols):
                raise InputError(f"{msg} has no {next(c for c in cols if c not in table)} (a motor's channel)")
            order = np.argsort(table["_t"], kind="stable")
            t, pwm = table["_t"][order], np.column_stack([table[c][order] for c in cols])
            v = None
            if curve.compensates:
                ok = np.isfinite(volt[1]) if volt is not None else np.zeros(0, bool)
                if volt is None or ok.sum() < 1:
                    raise InputError(
                        f"MOT_BAT_VOLT_MAX is {curve.bat_volt_max:g} V (battery compensation on) and the log has no "
                        f"battery voltage ({'BAT.Volt' if msg == 'RCOU' else 'SYS_STATUS.voltage_battery'})"
                    )
                v = np.interp(t, volt[0][ok], volt[1][ok])[:, None]
            T = curve.thrust(pwm, v).mean(axis=1, keepdims=True)
            mine = (f"{msg}.{','.join(cols)} (ArduCopter thrust curve)", t, T, 1.0 / typical_period(t))
            coarse = thrust is not None and thrust[0].startswith("VFR_HUD")
            found.insert(0, mine) if coarse else found.append(mine)
            choices.append(
                f"motor outputs {msg}: PWM read as thrust through ArduCopter's curve ({curve.describe()}"
                + (f", voltage from {volt[2]}" if v is not None else "")  # type: ignore[index]
                + ")"
            )
        except InputError as exc:
            other = f"thrust from {thrust[0]}" if thrust is not None else "no other thrust source"
            notes.append(f"motor outputs {msg} refused as thrust: {exc}; {other}")
    if not found:
        return None
    return fastest("thrust", found, choices)


def _attitude_signal(src: str, t: np.ndarray, vals: np.ndarray, kind: str) -> Signal:
    if kind == "euler_deg":
        R = euler_rotation(*np.radians(vals).T)
    elif kind == "euler_rad":
        R = euler_rotation(*vals.T)
    else:
        good = np.linalg.norm(vals, axis=-1) > 0.5
        vals, t = vals[good], t[good]
        R = quaternion_rotation(vals, "wxyz", "body-to-world")
    return Signal("attitude", src, t, eta_ned_frd(R, "ned", "frd"))


def _esc_dataflash(tables: dict[str, dict[str, np.ndarray]], choices: list[str]) -> Signal | None:
    """Rotor speeds (rad/s) from ESC messages, every instance onto the clock of the first."""
    per: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    d = tables.get("ESC")
    if d and "Instance" in d and "RPM" in d:
        for i in np.unique(d["Instance"]).astype(int):
            sel = d["Instance"] == i
            per[i] = (d["_t"][sel], d["RPM"][sel])
        src = "ESC.RPM by Instance"
    else:
        for i in range(8):
            d = tables.get(f"ESC{i + 1}")
            if d and "RPM" in d:
                per[i] = (d["_t"], d["RPM"])
        src = "ESC1..ESC8.RPM"
    return _combine_escs(per, src, choices)


def _combine_escs(per: dict[int, tuple[np.ndarray, np.ndarray]], src: str, choices: list[str]) -> Signal | None:
    per = {k: v for k, v in per.items() if np.any(v[1] != 0)}  # ESC slots without a motor report zero
    if len(per) < 3:
        return None
    n = max(per) + 1
    if sorted(per) != list(range(n)):
        choices.append(esc_gap_note(src, sorted(per)))
        return None
    t0 = per[0][0]
    lo = max(p[0][0] for p in per.values())
    hi = min(p[0][-1] for p in per.values())
    t = t0[(t0 >= lo) & (t0 <= hi)]
    if len(t) < 2:
        return None
    rpm = np.stack([np.interp(t, per[i][0], per[i][1]) for i in range(n)], -1)
    choices.append(f"rotor speeds: {src} ({n} ESCs) at {1 / typical_period(t):.3g} Hz")
    return Signal("rotor speeds", f"{src} [rpm]", t, rpm * ROTOR_SPEED_UNITS["rpm"])


def _truncation_dataflash(path: Path, reader: Any) -> str | None:
    data_len = int(getattr(reader, "data_len", 0))
    offsets, formats = getattr(reader, "offsets", None), getattr(reader, "formats", {})
    if not data_len or offsets is None:
        return None
    end, last = 0, None
    for mtype in range(256):
        offs = offsets[mtype]
        if len(offs) and mtype in formats:
            e = int(offs[-1]) + int(formats[mtype].len)
            if e > end:
                end, last = e, mtype
    if end > data_len and last is not None:
        have = data_len - int(offsets[last][-1])
        return (
            f"{path.name} ends inside its last message ({formats[last].name}, {have} of {formats[last].len} bytes): "
            "the file was cut short; the incomplete message was dropped"
        )
    if data_len > end:
        return f"{path.name} has {data_len - end} unreadable byte(s) after its last complete message: dropped"
    return None


def read_dataflash(path: str | os.PathLike[str]) -> RawLog:
    """Read an ArduPilot DataFlash ``.bin`` log (module docstring) into NED/FRD signals."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"cannot read log file {path}: {explain_path(path) or 'not a regular file'}")
    out, err = io.StringIO(), io.StringIO()
    try:
        reader = _connect(path, out, err)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"{path} is not a readable DataFlash log ({type(exc).__name__}: {exc})") from None
    wanted = ["ATT", "ANG", "RATE", "IMU", "XKF1", "NKF1", "CTUN", "ESC", "PARM", "MSG", "VER", "RCOU", "BAT"]
    wanted += [f"ESC{i}" for i in range(1, 9)]
    tabs: dict[str, _Table] = defaultdict(_Table)
    params: dict[str, float] = {}
    version = ""
    n_msgs = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        while True:
            try:
                m = reader.recv_match(type=wanted)
            except Exception as exc:  # a malformed message deep in a damaged file
                err.write(f"pymavlink stopped: {type(exc).__name__}: {exc}\n")
                break
            if m is None:
                break
            n_msgs += 1
            typ = m.get_type()
            if typ == "PARM":
                params[str(m.Name)] = float(m.Value)
                continue
            if typ == "MSG":
                text = str(getattr(m, "Message", ""))
                if not version and any(k in text for k in ("Copter", "Plane", "Rover", "Sub", "Blimp", "ArduPilot")):
                    version = text
                continue
            if typ == "VER":  # newer firmware names itself here too (FWS: "ArduCopter V4.5.1 (...)")
                fws = getattr(m, "FWS", "")
                fws = fws.decode(errors="replace") if isinstance(fws, bytes) else str(fws)
                if fws.strip() and not version:
                    version = fws.strip()
                continue
            row = {k: getattr(m, k) for k in m.get_fieldnames() if not isinstance(getattr(m, k), str | bytes)}
            if "TimeUS" in row:
                row["_t"] = row["TimeUS"] * 1e-6
            elif "TimeMS" in row:
                row["_t"] = row["TimeMS"] * 1e-3
            tabs[typ].rows.append(row)
    cut = _truncation_dataflash(path, reader) if n_msgs else None
    _close(reader)
    if n_msgs == 0:
        raise InputError(f"{path} holds no DataFlash messages (not an ArduPilot .bin log, or empty)")
    notes: list[str] = []
    if cut:
        notes.append(cut)
    skipped = err.getvalue().count("bad header") + err.getvalue().count("Skipped")
    if skipped:
        notes.append(f"pymavlink skipped damaged data in {path.name} ({skipped} place(s))")
    tables = {k: v.arrays() for k, v in tabs.items()}
    choices: list[str] = []
    att = _pick(
        "attitude",
        [("ATT", ["Roll", "Pitch", "Yaw"], 1.0, {}), ("ANG", ["Roll", "Pitch", "Yaw"], 1.0, {})],
        tables,
        choices,
    )
    rates = _pick(
        "body rates",
        [("RATE", ["R", "P", "Y"], np.pi / 180.0, {}), ("IMU", ["GyrX", "GyrY", "GyrZ"], 1.0, {"I": 0})],
        tables,
        choices,
    )
    vel = _pick(
        "velocity",
        [("XKF1", ["VN", "VE", "VD"], 1.0, {"C": 0}), ("NKF1", ["VN", "VE", "VD"], 1.0, {"C": 0})],
        tables,
        choices,
    )
    thrust = _pick("thrust", [("CTUN", ["ThO"], 1.0, {})], tables, [])
    bat = tables.get("BAT", {})
    inst = bat.get("Inst", bat.get("Instance"))
    sel = inst == params.get("MOT_BAT_IDX", 0.0) if inst is not None else slice(None)
    volt = (bat["_t"][sel], bat["Volt"][sel], "BAT.Volt") if "Volt" in bat and "_t" in bat else None
    thrust = _with_motor_outputs(thrust, tables.get("RCOU", {}), "RCOU", "C{}", params, volt, choices, notes)
    torque = _pick("torque", [("RATE", ["ROut", "POut", "YOut"], 1.0, {})], tables, choices)
    rotor = _esc_dataflash(tables, choices)
    missing = [
        (role, need)
        for role, got, need in (
            ("attitude", att, "ATT or ANG"),
            ("body rates", rates, "RATE or IMU"),
            ("velocity", vel, "XKF1 or NKF1 (EKF velocity)"),
        )
        if got is None
    ]
    if thrust is None and rotor is None:
        ctun = "; this log's CTUN has no ThO field" if "CTUN" in tables else ""
        refused = "".join(f" ({n})" for n in notes if "refused as thrust" in n)
        need = f"CTUN.ThO (throttle out{ctun}), RCOU (motor outputs{refused}) or ESC (rotor speeds)"
        missing.append(("thrust", need))
    if missing:
        have = ", ".join(f"{k} ({len(v['_t'])})" for k, v in sorted(tables.items()) if "_t" in v) or "none of interest"
        kind = classify({"firmware": version}, params)
        other = f" The log is of {kind[1]}, not a multirotor." if kind is not None and kind[0] != "multirotor" else ""
        raise InputError(
            f"{path}: " + "; ".join(f"no {r}: needs {n}" for r, n in missing) + f". The log has: {have}.{other} "
            "Check LOG_BITMASK (ATTITUDE_MED/FAST, CTUN, NTUN/EKF, ESC) on the vehicle"
        )
    kw: dict[str, Any] = {"params": params, "choices": choices}
    d = tables.get("CTUN", {})
    if "ThH" in d and "_t" in d:
        ok = np.isfinite(d["ThH"]) & (d["ThH"] > 0.02) & (d["ThH"] < 1.0)
        if ok.sum() >= 2:
            kw["hover"] = Signal("hover thrust", "CTUN.ThH (learned hover throttle)", d["_t"][ok], d["ThH"][ok, None])
    for name in ("MOT_THST_HOVER", "Q_M_THST_HOVER"):  # a multicopter's, a QuadPlane's
        if "hover" not in kw and "hover_thrust" not in kw and 0.02 < params.get(name, 0.0) < 1.0:
            kw["hover_thrust"] = params[name]
            kw["hover_source"] = f"the parameter {name} (no CTUN.ThH in the log)"
    if rotor is not None:
        kw["rotor_speed"] = rotor
    meta = {"format": "dataflash", "file": str(path), "firmware": version or "unknown"}
    if rotor is not None:
        meta["rotor_speed_unit"] = "rpm"
    return RawLog(
        Signal("velocity", vel[0], vel[1], vel[2]),
        _attitude_signal(att[0] + " [deg]", att[1], att[2], "euler_deg"),
        Signal("body rates", rates[0], rates[1], rates[2]),
        None if thrust is None else Signal("thrust", thrust[0], thrust[1], thrust[2], hold=True),
        None if torque is None else Signal("torque", torque[0] + " (normalised)", torque[1], torque[2], hold=True),
        "normalized",
        "normalized",
        notes=notes,
        meta=meta,
        **kw,
    )


def _tlog_frames(path: Path) -> tuple[int, int, str | None, int]:
    """Walk the tlog's frames (8-byte big-endian time, then a MAVLink 1 or 2 packet): ``(complete frames,
    damaged bytes skipped, note about a cut or damaged file, bytes cut off the end)``. After damage the walk
    resynchronises on the next frame whose time is within a day of the last good one."""
    data = path.read_bytes()
    ofs, n, skipped, last_t = 0, 0, 0, None
    cut = None
    while ofs + 8 + 2 <= len(data):
        marker = data[ofs + 8]
        t = struct.unpack(">Q", data[ofs : ofs + 8])[0]
        plausible = last_t is None or abs(int(t) - last_t) < 86_400_000_000
        size = None
        if marker == 0xFE and plausible:
            size = 8 + data[ofs + 9] + 8
        elif marker == 0xFD and plausible and ofs + 8 + 3 <= len(data):
            size = 8 + data[ofs + 9] + 12 + (13 if data[ofs + 10] & 1 else 0)
        if size is None:
            ofs += 1
            skipped += 1
            continue
        if ofs + size > len(data):
            cut = len(data) - ofs
            break
        last_t = int(t)
        ofs += size
        n += 1
    if cut is None and ofs < len(data):
        cut = len(data) - ofs
    notes = []
    if skipped:
        notes.append(f"{skipped} damaged byte(s) skipped")
    if cut:
        notes.append(
            f"the file ends inside a MAVLink frame ({cut} byte(s)): it was cut short; the incomplete message was "
            "dropped"
        )
    return n, skipped, (f"{path.name}: " + "; ".join(notes)) if notes else None, int(cut or 0)


TLOG_TYPES = [
    "ATTITUDE", "ATTITUDE_QUATERNION", "HIGHRES_IMU", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT",
    "ATTITUDE_TARGET", "ACTUATOR_CONTROL_TARGET", "VFR_HUD", "ESC_STATUS", "ESC_TELEMETRY_1_TO_4",
    "PARAM_VALUE", "HEARTBEAT", "AUTOPILOT_VERSION", "SERVO_OUTPUT_RAW", "SYS_STATUS",
]  # fmt: skip


#: A second vehicle in a tlog that sent at least this many attitude messages could be estimated on its
#: own (pipeline.MIN_LOG_SAMPLES): without ``sysid`` the log is then refused rather than one of them taken.
MIN_VEHICLE_MESSAGES = 50


def read_tlog(path: str | os.PathLike[str], sysid: int | None = None, compid: int | None = None) -> RawLog:
    """Read a MAVLink telemetry log ``.tlog`` (module docstring) into NED/FRD signals.

    A tlog may hold several vehicles (MAVLink system ids), each perhaps from several components. The
    vehicle is ``sysid`` (and its component ``compid``; default: the component that sent the most
    attitude messages). Without ``sysid``, a tlog whose systems include two that each sent at least
    :data:`MIN_VEHICLE_MESSAGES` attitude messages is refused, naming them and their counts; one with a
    single such system takes it, and names any other system heard (with its count) in a warning and in
    ``meta["other_systems"]``.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"cannot read log file {path}: {explain_path(path) or 'not a regular file'}")
    n_frames, _, tail, cut = _tlog_frames(path)
    if n_frames == 0:
        raise InputError(f"{path} holds no MAVLink frames (not a .tlog, or empty)")
    if cut:  # pymavlink's index of a tlog fails on a cut frame that is the first of its kind: read it without
        with tempfile.TemporaryDirectory() as tmp:
            trimmed = Path(tmp) / path.name
            with open(path, "rb") as src:
                trimmed.write_bytes(src.read(path.stat().st_size - cut))
            return _read_tlog(path, trimmed, sysid, compid, tail, n_frames)
    return _read_tlog(path, path, sysid, compid, tail, n_frames)


def _read_tlog(
    path: Path, source: Path, sysid: int | None, compid: int | None, tail: str | None, n_frames: int
) -> RawLog:
    """:func:`read_tlog` of the file ``source`` (``path`` itself, or its copy without a cut last frame),
    named by ``path``."""
    out, err = io.StringIO(), io.StringIO()
    try:
        conn = _connect(source, out, err)
    except Exception as exc:
        raise InputError(f"{path} is not a readable tlog ({type(exc).__name__}: {exc})") from None
    raw_rows: dict[tuple[int, int], dict[str, list]] = defaultdict(lambda: defaultdict(list))
    params_of: dict[int, dict[str, float]] = defaultdict(dict)  # per system id
    autopilots: dict[int, int] = {}
    bad = 0
    mav_types: dict[tuple[int, int], int] = {}  # each source's HEARTBEAT.type (MAV_TYPE)
    order = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            while True:
                try:
                    m = conn.recv_match()
                except Exception as exc:
                    err.write(f"pymavlink stopped: {type(exc).__name__}: {exc}\n")
                    break
                if m is None:
                    break
                typ = m.get_type()
                if typ == "BAD_DATA":
                    bad += 1
                    continue
                if typ not in TLOG_TYPES:
                    continue
                src = (m.get_srcSystem(), m.get_srcComponent())
                if typ == "PARAM_VALUE":
                    pid = m.param_id.decode() if isinstance(m.param_id, bytes) else str(m.param_id)
                    params_of[src[0]][pid.rstrip("\x00")] = float(m.param_value)
                    continue
                if typ == "HEARTBEAT":
                    if getattr(m, "autopilot", 8) != 8:  # 8: MAV_AUTOPILOT_INVALID (a GCS)
                        autopilots.setdefault(src[0], int(m.autopilot))
                        mav_types.setdefault(src, int(getattr(m, "type", 0)))
                    continue
                m._order = order = order + 1  # its place in the file: the order the vehicle sent it in
                raw_rows[src][typ].append(m)
        finally:
            _close(conn)
    if not raw_rows:
        raise InputError(f"{path}: no vehicle messages of interest (it has {n_frames} MAVLink frames)")
    src, notes, others = _choose_source(path, raw_rows, sysid, compid)
    msgs = raw_rows[src]
    params = params_of.get(src[0], {})
    autopilot = autopilots.get(src[0])
    if tail:
        notes.append(tail)
    if bad:
        notes.append(f"{bad} damaged MAVLink packet(s) skipped")
    tables, clock_note = _tlog_tables(msgs)
    if clock_note:
        notes.append(clock_note)
    choices: list[str] = []
    att_q = _pick("attitude", [("ATTITUDE_QUATERNION", ["q1", "q2", "q3", "q4"], 1.0, {})], tables, [])
    att_e = _pick("attitude", [("ATTITUDE", ["roll", "pitch", "yaw"], 1.0, {})], tables, [])
    att = None
    if att_q is not None and (att_e is None or 1 / typical_period(att_q[1]) > RATE_TIE / typical_period(att_e[1])):
        att = _attitude_signal(att_q[0], att_q[1], att_q[2], "quat")
    elif att_e is not None:
        att = _attitude_signal(att_e[0], att_e[1], att_e[2], "euler_rad")
    if att is not None:
        choices.append(f"attitude: {att.source} at {1 / typical_period(att.t):.3g} Hz")
    rates = _pick(
        "body rates",
        [
            ("ATTITUDE", ["rollspeed", "pitchspeed", "yawspeed"], 1.0, {}),
            ("ATTITUDE_QUATERNION", ["rollspeed", "pitchspeed", "yawspeed"], 1.0, {}),
            ("HIGHRES_IMU", ["xgyro", "ygyro", "zgyro"], 1.0, {}),
        ],
        tables,
        choices,
    )
    vel = _pick(
        "velocity",
        [("LOCAL_POSITION_NED", ["vx", "vy", "vz"], 1.0, {}), ("GLOBAL_POSITION_INT", ["vx", "vy", "vz"], 0.01, {})],
        tables,
        choices,
    )
    thrust = _pick(
        "thrust",
        [
            ("ATTITUDE_TARGET", ["thrust"], 1.0, {}),
            ("ACTUATOR_CONTROL_TARGET", ["controls[3]"], 1.0, {"group_mlx": 0}),
            ("VFR_HUD", ["throttle"], 0.01, {}),
        ],
        tables,
        [] if autopilot == 3 else choices,
    )
    if autopilot == 3:  # ArduPilot: its motor outputs through its thrust curve (PX4's are not read)
        sys_status = tables.get("SYS_STATUS", {})
        volt = None
        if "voltage_battery" in sys_status:
            mv = np.where(sys_status["voltage_battery"] >= 65535, np.nan, sys_status["voltage_battery"])  # unknown
            volt = (sys_status["_t"], mv * 1e-3, "SYS_STATUS.voltage_battery")
        out = tables.get("SERVO_OUTPUT_RAW", {})
        if "port" in out:  # the first eight outputs (port 0) only
            keep = out["port"] == 0
            out = {k: v[keep] for k, v in out.items()}
        thrust = _with_motor_outputs(thrust, out, "SERVO_OUTPUT_RAW", "servo{}_raw", params, volt, choices, notes)
    torque = _pick(
        "torque",
        [("ACTUATOR_CONTROL_TARGET", [f"controls[{i}]" for i in range(3)], 1.0, {"group_mlx": 0})],
        tables,
        choices,
    )
    rotor = _esc_tlog(tables, choices)
    missing = [r for r, got in (("attitude", att), ("body rates", rates), ("velocity", vel)) if got is None]
    if thrust is None and rotor is None:
        missing.append("thrust")
    have = ", ".join(
        f"{k} {1 / typical_period(v['_t']):.3g} Hz" for k, v in sorted(tables.items()) if len(v.get("_t", [])) > 1
    )
    if missing:
        raise InputError(
            f"{path} lacks the streams the estimate needs: "
            + "; ".join(f"{r} needs {STREAM_ADVICE[r][0]}" for r in missing)
            + ". Request "
            + "; ".join(dict.fromkeys(STREAM_ADVICE[r][1] for r in missing))
            + f". The tlog has: {have or 'none of these messages'}"
            + "".join(f". {n}" for n in notes if "refused as thrust" in n)
        )
    for role, sig_t in (("attitude", att.t), ("body rates", rates[1]), ("velocity", vel[1])):
        hz = 1.0 / typical_period(sig_t)
        if hz < MIN_STREAM_HZ:
            notes.append(
                f"WARNING: {role} streamed at only {hz:.2g} Hz: the estimate resolves little above {hz / 3:.2g} Hz; "
                f"request {STREAM_ADVICE.get(role, ('', ''))[1] or 'a faster stream'}"
            )
    if thrust is not None and thrust[0].startswith("VFR_HUD"):
        notes.append(
            "thrust from VFR_HUD.throttle: whole percent steps (about 2.5 % of the weight each); stream "
            "ATTITUDE_TARGET or ESC telemetry for a finer one"
        )
    kw: dict[str, Any] = {"params": params, "choices": choices}
    for name in ("MPC_THR_HOVER", "MOT_THST_HOVER", "Q_M_THST_HOVER"):
        if 0.02 < params.get(name, 0.0) < 1.0:
            kw["hover_thrust"] = params[name]
            kw["hover_source"] = f"the parameter {name} (from the tlog's PARAM_VALUE messages)"
            break
    geo = torque_per_unit(params)
    if geo is not None:
        kw["torque_per_unit"], kw["n_rotors"] = geo
    kw["rotor_geometry"] = rotor_geometry(params)
    mass, inertia = vehicle_from_params(params)
    if mass is not None or inertia is not None:
        kw.update(mass=mass, inertia=inertia, vehicle_source="the SIH_* parameters in the tlog")
    if rotor is not None:
        kw["rotor_speed"] = rotor
    meta = {
        "format": "tlog",
        "file": str(path),
        "autopilot": {3: "ArduPilot", 12: "PX4"}.get(autopilot, f"MAV_AUTOPILOT {autopilot}"),
        "system_component": list(src),
    }
    if others:
        meta["other_systems"] = others
    if src in mav_types:
        meta["mav_type"] = mav_types[src]
    if rotor is not None:
        meta["rotor_speed_unit"] = "rpm"
    return RawLog(
        Signal("velocity", vel[0], vel[1], vel[2]),
        att,
        Signal("body rates", rates[0], rates[1], rates[2]),
        None if thrust is None else Signal("thrust", thrust[0], thrust[1], thrust[2], hold=True),
        None if torque is None else Signal("torque", torque[0] + " (normalised)", torque[1], torque[2], hold=True),
        "normalized",
        "normalized",
        notes=notes,
        meta=meta,
        **kw,
    )


def _attitude_count(rows: dict[str, list]) -> int:
    return len(rows.get("ATTITUDE", [])) + len(rows.get("ATTITUDE_QUATERNION", []))


def _choose_source(
    path: Path, raw_rows: dict[tuple[int, int], dict[str, list]], sysid: int | None, compid: int | None
) -> tuple[tuple[int, int], list[str], dict[str, int]]:
    """``((system, component), notes, other systems' attitude counts)``: the vehicle of :func:`read_tlog`."""
    per_sys: dict[int, int] = defaultdict(int)
    for (sy, _), rows in raw_rows.items():
        per_sys[sy] += _attitude_count(rows)
    listing = ", ".join(f"system {sy}: {n} attitude message(s)" for sy, n in sorted(per_sys.items()))
    notes: list[str] = []
    if sysid is not None:
        if sysid not in per_sys:
            raise InputError(f"{path}: --sysid {sysid}: no vehicle messages from that system; the tlog has {listing}")
        chosen = sysid
    else:
        vehicles = sorted((sy for sy, n in per_sys.items() if n >= MIN_VEHICLE_MESSAGES), key=lambda sy: -per_sys[sy])
        if len(vehicles) > 1:
            raise InputError(
                f"{path} holds {len(vehicles)} vehicles ({listing}): choose one with --sysid "
                + " or --sysid ".join(str(sy) for sy in vehicles)
            )
        chosen = vehicles[0] if vehicles else max(per_sys, key=lambda sy: per_sys[sy])
    others = {str(sy): n for sy, n in sorted(per_sys.items()) if sy != chosen}
    if any(others.values()) and sysid is None:
        notes.append(
            f"WARNING: the tlog also holds messages from other MAVLink systems ({listing}): system {chosen} is "
            "estimated, the others (too few attitude messages to estimate) ignored; --sysid chooses"
        )
    elif others:
        notes.append(f"system {chosen} estimated{' (--sysid)' if sysid is not None else ''}; in the tlog: {listing}")
    comps = {c: _attitude_count(rows) for (sy, c), rows in raw_rows.items() if sy == chosen}
    if compid is not None:
        if compid not in comps:
            raise InputError(
                f"{path}: --compid {compid}: system {chosen} sent nothing from that component; its components: "
                + ", ".join(f"{c} ({n} attitude message(s))" for c, n in sorted(comps.items()))
            )
        comp = compid
    else:
        comp = max(comps, key=lambda c: comps[c])
        if sum(1 for n in comps.values() if n > 0) > 1:
            notes.append(
                f"system {chosen}: component {comp} taken (the most attitude messages; "
                + ", ".join(f"component {c}: {n}" for c, n in sorted(comps.items()))
                + "); --compid chooses"
            )
    return (chosen, comp), notes, others


def _fields(m: Any) -> dict[str, float]:
    out = {}
    for k in m.get_fieldnames():
        v = getattr(m, k)
        if isinstance(v, list | tuple):
            for i, x in enumerate(v):
                out[f"{k}[{i}]"] = float(x)
        elif isinstance(v, int | float):
            out[k] = float(v)
    return out


def _tlog_tables(msgs: dict[str, list]) -> tuple[dict[str, dict[str, np.ndarray]], str | None]:
    """Arrays by field, with ``_t`` on the vehicle's clock (see the module docstring)."""
    tables: dict[str, dict[str, np.ndarray]] = {}
    offsets = []  # receive time minus vehicle time, of messages that carry both
    for typ, ms in msgs.items():
        rows = [_fields(m) for m in ms]
        d = {k: np.array([r.get(k, np.nan) for r in rows]) for k in rows[0]}
        d["_recv"] = np.array([m._timestamp for m in ms], dtype=float)
        d["_order"] = np.array([getattr(m, "_order", 0) for m in ms], dtype=float)
        if "time_boot_ms" in d:
            d["_t"] = d["time_boot_ms"] * 1e-3
        elif "time_usec" in d and np.median(d["time_usec"]) < 1e14:  # since boot, not a unix time
            d["_t"] = d["time_usec"] * 1e-6
        tables[typ] = d
    note = _one_boot(tables)
    for d in tables.values():
        if "_t" in d:
            offsets.append(d["_recv"] - d["_t"])
    if offsets:
        off = np.concatenate(offsets)
        delay = float(np.percentile(off, 2))
        timed = [d for d in tables.values() if "_t" in d]
        seq = np.concatenate([d["_order"] for d in timed])
        by_seq = np.argsort(seq, kind="stable")
        seq, t_seq = seq[by_seq], np.maximum.accumulate(np.concatenate([d["_t"] for d in timed])[by_seq])
        placed = []
        for typ, d in tables.items():
            if "_t" not in d:
                d["_t"] = _place_untimed(d["_order"], d["_recv"] - delay, seq, t_seq)
                placed.append(typ)
        if placed:
            note = "; ".join(filter(None, [note, (
                f"{', '.join(sorted(placed))}: no time field; placed on the vehicle clock after the timed message "
                "sent before it (a link that delivers in bursts delays them unevenly), at most by receive time "
                "minus the link's smallest delay"
            )]))  # fmt: skip
    else:
        for d in tables.values():
            d["_t"] = d["_recv"]
        note = "no message carries the vehicle's clock: receive times used"
    for d in tables.values():
        order = np.argsort(d["_t"], kind="stable")
        for k in list(d):
            d[k] = d[k][order]
    return tables, note


#: An untimed message is placed at the vehicle time of the timed message sent just before it when that
#: one's receive-time bound is within this of its own (else the link paused: receive time is the better).
PLACE_WITHIN_S = 2.0


def _place_untimed(order: np.ndarray, upper: np.ndarray, seq: np.ndarray, t_seq: np.ndarray) -> np.ndarray:
    """Vehicle times of messages without a time field, from their places in the file ``order`` and their
    receive times less the link's smallest delay ``upper`` (a bound: a message cannot be received before it
    was sent): the vehicle time ``t_seq`` of the timed message just before (places ``seq``, sorted). A link
    that queues and delivers in bursts holds the messages of a second back by up to that second; the
    order they were sent in keeps their times."""
    i = np.searchsorted(seq, order, side="left") - 1
    before = np.where(i >= 0, t_seq[np.maximum(i, 0)], -np.inf)
    return np.where((before <= upper) & (upper - before <= PLACE_WITHIN_S), before, upper)


def _one_boot(tables: dict[str, dict[str, np.ndarray]]) -> str | None:
    """A tlog may span a reboot of the vehicle (its clock starts again): keep the boot with the longest
    stretch of attitude messages (by receive time), drop the rest, and say so."""
    ref = tables.get("ATTITUDE") or tables.get("ATTITUDE_QUATERNION")
    if not ref or "_t" not in ref:
        return None
    order = np.argsort(ref["_recv"], kind="stable")
    t, recv = ref["_t"][order], ref["_recv"][order]
    resets = np.flatnonzero(np.diff(t) < -1.0)
    if not len(resets):
        return None
    edges = np.concatenate([[0], resets + 1, [len(t)]])
    spans = [(recv[a], recv[b - 1]) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    lo, hi = max(spans, key=lambda ab: ab[1] - ab[0])
    for d in tables.values():
        keep = (d["_recv"] >= lo - 0.5) & (d["_recv"] <= hi + 0.5)
        for k in list(d):
            d[k] = d[k][keep]
    return (
        f"the vehicle rebooted {len(resets)} time(s) during the tlog (its clock starts again): the longest boot "
        f"({hi - lo:.0f} s) is used"
    )


def _esc_tlog(tables: dict[str, dict[str, np.ndarray]], choices: list[str]) -> Signal | None:
    d = tables.get("ESC_STATUS")
    per: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    if d and "index" in d:
        for idx in np.unique(d["index"]).astype(int):
            sel = d["index"] == idx
            for j in range(4):
                if f"rpm[{j}]" in d:
                    per[idx + j] = (d["_t"][sel], d[f"rpm[{j}]"][sel])
        src = "ESC_STATUS.rpm"
    else:
        d = tables.get("ESC_TELEMETRY_1_TO_4")
        if d:
            for j in range(4):
                if f"rpm[{j}]" in d:
                    per[j] = (d["_t"], d[f"rpm[{j}]"])
        src = "ESC_TELEMETRY_1_TO_4.rpm"
    return _combine_escs(per, src, choices)


def pack_tlog_frame(t_us: int, packet: bytes) -> bytes:
    """One tlog frame: the receive time in microseconds, big-endian, then the MAVLink packet."""
    return struct.pack(">Q", int(t_us)) + packet


__all__ = ["STREAM_ADVICE", "pack_tlog_frame", "read_dataflash", "read_tlog"]
