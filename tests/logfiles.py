"""Flight logs with a known wrench for the log tests: the synthetic flight of ``synthflight`` written as
CSV in any convention, as ArduPilot DataFlash and as a MAVLink tlog (the writers of
``vtol_impedance.logs.writers``; pymavlink reads them back)."""

from __future__ import annotations

import math

import numpy as np
import synthflight as S
from scipy.spatial.transform import Rotation

from vtol_impedance.logs import frames
from vtol_impedance.logs.writers import DFMessage, write_dataflash, write_tlog
from vtol_impedance.model.kinematics import euler_from_rotation, rotation_zyx

HOVER = 0.42  # normalised hover thrust of the synthetic vehicle's thrust map
A = 0.175  # X quadrotor arm projection, m
KM = 0.05
ROTORS = [(A, A, KM), (-A, -A, KM), (A, -A, -KM), (-A, A, -KM)]
K_T = 8.0e-6  # N per (rad/s)^2 of the synthetic rotors


def csv_cols(fl, world="ned", body="frd", quat=None, angle="rad", rate=None, vworld=None, qdir="body-to-world",
             tunit="s", every=1):  # fmt: skip
    """The flight's columns as a CSV written in the given conventions (what a logger would write)."""
    rate = rate or angle
    vworld = vworld or world
    sl = slice(None, None, every)
    R = frames.rotation_from_ned_frd(rotation_zyx(fl.eta[sl]), world, body)
    bm = frames.body_matrix(body)
    v, w, tq = fl.v_W[sl] @ frames.world_matrix(vworld).T, fl.omega_B[sl] @ bm.T, fl.tau_B[sl] @ bm.T
    ka = 180 / np.pi if angle == "deg" else 1.0
    kr = 180 / np.pi if rate == "deg" else 1.0
    cols = {"t_s": fl.t[sl] / frames.TIME_UNITS[tunit], "vx": v[:, 0], "vy": v[:, 1], "vz": v[:, 2]}
    if quat is None:
        e = euler_from_rotation(R) * ka
        cols.update(roll=e[:, 0], pitch=e[:, 1], yaw=e[:, 2])
    else:
        if qdir == "world-to-body":
            R = np.swapaxes(R, -1, -2)
        q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
        q = q if quat == "xyzw" else q[:, [3, 0, 1, 2]]
        cols.update({f"q{i}": q[:, i] for i in range(4)})
    cols.update(wx=w[:, 0] * kr, wy=w[:, 1] * kr, wz=w[:, 2] * kr, thrust_n=fl.thrust[sl])
    cols.update(tx=tq[:, 0], ty=tq[:, 1], tz=tq[:, 2])
    return cols


def write_csv(path, cols: dict[str, np.ndarray]):
    names = list(cols)
    np.savetxt(path, np.column_stack([cols[n] for n in names]), delimiter=",", header=",".join(names), comments="",
               fmt="%.12g")  # fmt: skip
    return path


def rotor_speeds(thrust: np.ndarray, tau_B: np.ndarray) -> np.ndarray:
    """Rotor speeds (rad/s) that produce ``thrust`` and ``tau_B`` with the X geometry and ``K_T``."""
    E = np.array([[1.0] * 4, [-y for _, y, _ in ROTORS], [x for x, _, _ in ROTORS], [k for _, _, k in ROTORS]])
    f = np.linalg.solve(E, np.column_stack([thrust, tau_B]).T).T
    return np.sqrt(f / K_T)


def write_synth_dataflash(fl, path, truncate: int | None = None, firmware: str | None = None, params=None):
    """The flight as ArduCopter logs it: ATT (centidegrees) and RATE (deg/s) at 50 Hz, XKF1 at 25 Hz, CTUN
    (normalised throttle and hover throttle) at 50 Hz, ESC rpm at 50 Hz, PARM; TimeUS from boot + 2 s.
    ``firmware``: the MSG naming it (e.g. "ArduCopter V4.5.1"); ``params``: more PARM rows."""
    us = np.round((fl.t + 2.0) * 1e6).astype(np.int64)
    a = np.arange(0, len(fl.t), 5)  # 50 Hz
    x = np.arange(2, len(fl.t), 10)  # 25 Hz
    deg = np.degrees(fl.eta[a])
    deg[:, 2] = np.mod(deg[:, 2], 360.0)
    z = np.zeros(len(a))
    u = fl.thrust * HOVER / (S.MASS * S.G)
    w = rotor_speeds(fl.thrust, fl.tau_B) * 60 / (2 * math.pi)
    msgs = [
        DFMessage("ATT", "QccccCCCCB", {"TimeUS": us[a], "DesRoll": z, "Roll": deg[:, 0], "DesPitch": z,
                                        "Pitch": deg[:, 1], "DesYaw": z, "Yaw": deg[:, 2], "ErrRP": z, "ErrYaw": z,
                                        "AEKF": z + 3}),
        DFMessage("RATE", "Qfffffffffffff", {"TimeUS": us[a], "RDes": z, "R": np.degrees(fl.omega_B[a, 0]), "ROut": z,
                                             "PDes": z, "P": np.degrees(fl.omega_B[a, 1]), "POut": z, "YDes": z,
                                             "Y": np.degrees(fl.omega_B[a, 2]), "YOut": z, "ADes": z, "A": z,
                                             "AOut": z, "AOutSlew": z}),
        DFMessage("XKF1", "QBccCfffffffccce", {"TimeUS": us[x], "C": 0 * x, "Roll": 0 * x, "Pitch": 0 * x,
                                               "Yaw": 0 * x, "VN": fl.v_W[x, 0], "VE": fl.v_W[x, 1], "VD": fl.v_W[x, 2],
                                               "dPD": 0 * x, "PN": 0 * x, "PE": 0 * x, "PD": 0 * x, "GX": 0 * x,
                                               "GY": 0 * x, "GZ": 0 * x, "OH": 0 * x}),
        DFMessage("CTUN", "Qffffffefffhh", {"TimeUS": us[a], "ThI": u[a], "ABst": z, "ThO": u[a], "ThH": z + HOVER,
                                            "DAlt": z, "Alt": z, "BAlt": z, "DSAlt": z, "SAlt": z, "TAlt": z,
                                            "DCRt": z, "CRt": z}),
        DFMessage("PARM", "QNf", {"TimeUS": [int(us[0])] * (1 + len(params or {})),
                                  "Name": ["MOT_THST_HOVER", *(params or {})],
                                  "Value": [HOVER, *(params or {}).values()]}),
    ]  # fmt: skip
    if firmware is not None:
        msgs.append(DFMessage("MSG", "QZ", {"TimeUS": [int(us[0])], "Message": [firmware]}))
    ei = np.repeat(np.arange(4)[None, :], len(a), 0).ravel()
    et = np.repeat(us[a][:, None], 4, 1).ravel() + ei * 100
    er = w[a].ravel()
    ze = np.zeros(len(et))
    esc = {"TimeUS": et, "Instance": ei, "RPM": er, "RawRPM": er, "Volt": ze, "Curr": ze, "Temp": ze, "CTot": ze,
           "MotTemp": ze, "Err": ze}  # fmt: skip
    msgs.append(DFMessage("ESC", "QBffffcfcf", esc))
    write_dataflash(path, msgs)
    if truncate is not None:
        data = path.read_bytes()
        path.write_bytes(data[: len(data) - truncate])
    return path


def synth_tlog_messages(fl, drop=(), thrust_stream="ATTITUDE_TARGET"):
    """The flight as a telemetry stream: ATTITUDE 50 Hz, LOCAL_POSITION_NED 25 Hz, a thrust stream at 50 Hz
    (ATTITUDE_TARGET, PX4 style, or VFR_HUD), PARAM_VALUE MPC_THR_HOVER; receive times 10 ms late."""
    boot = fl.t + 5.0
    unix0 = 1.7e9
    u = fl.thrust * HOVER / (S.MASS * S.G)
    msgs = [(unix0 + boot[0] - 1.0, "PARAM_VALUE", {"param_id": b"MPC_THR_HOVER", "param_value": HOVER,
                                                   "param_type": 9, "param_count": 1, "param_index": 0})]  # fmt: skip
    for i in range(0, len(fl.t), 5):
        ms = int(round(boot[i] * 1e3))
        e, w = fl.eta[i], fl.omega_B[i]
        msgs.append((unix0 + boot[i] + 0.01, "ATTITUDE", {"time_boot_ms": ms, "roll": e[0], "pitch": e[1],
                                                          "yaw": e[2], "rollspeed": w[0], "pitchspeed": w[1],
                                                          "yawspeed": w[2]}))  # fmt: skip
        if thrust_stream == "ATTITUDE_TARGET":
            msgs.append((unix0 + boot[i] + 0.012, "ATTITUDE_TARGET", {"time_boot_ms": ms, "type_mask": 0,
                                                                      "q": [1.0, 0.0, 0.0, 0.0], "body_roll_rate": 0.0,
                                                                      "body_pitch_rate": 0.0, "body_yaw_rate": 0.0,
                                                                      "thrust": u[i]}))  # fmt: skip
        else:
            msgs.append((unix0 + boot[i] + 0.012, "VFR_HUD", {"airspeed": 0.0, "groundspeed": 0.0, "heading": 0,
                                                              "throttle": int(round(100 * u[i])), "alt": 0.0,
                                                              "climb": 0.0}))  # fmt: skip
    for i in range(1, len(fl.t), 10):
        v = fl.v_W[i]
        msgs.append((unix0 + boot[i] + 0.011, "LOCAL_POSITION_NED", {"time_boot_ms": int(round(boot[i] * 1e3)),
                                                                     "x": 0.0, "y": 0.0, "z": 0.0, "vx": v[0],
                                                                     "vy": v[1], "vz": v[2]}))  # fmt: skip
    return [m for m in msgs if m[1] not in drop]


def write_synth_tlog(fl, path, drop=(), truncate: int | None = None, thrust_stream="ATTITUDE_TARGET", protocol=2):
    write_tlog(path, synth_tlog_messages(fl, drop, thrust_stream), protocol=protocol)
    if truncate is not None:
        data = path.read_bytes()
        path.write_bytes(data[: len(data) - truncate])
    return path
