"""Write the sample logs: one simulated flight in every supported format (``python -m
vtol_impedance.logs.samples.generate [FOLDER]``, default: this package's folder).

The flight: the simulator's case B vehicle (Pelican, unmodelled 0.110 kg payload, fan at 0.15 m) flown
with PD, taking off, hovering 6 s, moving (1.0, 0.6, -0.4) m (NED) away from the fan in 3 s and holding
6 s; rotor lag (12.5 ms up, 25 ms down) and sensor noise on, sensor latency off (every format here
timestamps its samples when they are taken). Its truth is written to ``truth.csv``. Each format logs
what its autopilot would, at its rates, on its clock (:data:`~vtol_impedance.logs.samples.CLOCK_OFFSET_S`):

* the thrust command normalised by a hover thrust that rises from 0.50 to 0.53 over the flight (a battery
  sagging), logged per sample where the autopilot logs it (PX4's hover_thrust_estimate, ArduPilot's
  CTUN.ThH, the CSV's hover_thrust column); the logs that only carry a hover parameter (PX4 v1.9, the
  tlog) come from a vehicle without the sag, normalised by that parameter (0.515);
* the rotor speeds ``w_i = sqrt(f_i / K_T)`` of the rotors' actual forces (after the lag), as ESC rpm;
* the torque command normalised as PX4's allocator does (``torque_per_unit`` of the CA_ROTOR geometry).

Deterministic: the simulator's seed is fixed, the noise of the formats' own (link latency) is seeded.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import CLOCK_OFFSET_S, MASS_KG, SAMPLES, TRUTH_FILE, folder

K_T = 8.5e-6  # N per (rad/s)^2: the Pelican's rotors hover near 5900 rpm
HOVER_START, HOVER_END = 0.50, 0.53
HOVER_PARAM = 0.515
SEED = 2026


def simulate_flight():
    """The flight (module docstring) as a simulator Result (one controller: PD)."""
    from ...scenarios import get, simulate

    spec = get("case-b-fan")
    traj = replace(spec.trajectory, hover_duration=6.0, move_offset=(1.0, 0.6, -0.4), move_duration=3.0, move_hold=6.0)
    sens = replace(spec.sensors, mocap_delay=0.0, imu_delay=0.0)
    spec = replace(spec, trajectory=traj, sensors=sens, duration=20.0, seed=SEED)
    return simulate(spec, ["pd"])


def flight_arrays(r) -> dict[str, np.ndarray]:
    """What the logs are written from, on the simulator's 100 Hz clock."""
    from ...model.kinematics import rotation_zyx

    t = r.t
    thrust = r["thrust"][0]
    f_rotor = r["f_rotor"][0]
    eta_true = r["eta"][0]
    b = rotation_zyx(eta_true)[:, :, 2]
    prev = np.concatenate([thrust[:1], thrust[:-1]])
    f_lumped = r["f_lumped_W"][0]
    f_rot = f_lumped + (f_rotor.sum(-1) - prev)[:, None] * b
    hover = HOVER_START + (HOVER_END - HOVER_START) * (t - t[0]) / (t[-1] - t[0])
    return {
        "t": t,
        "v_W": r["v_meas_W"][0],
        "eta": r["eta_meas"][0],
        "omega_B": r["omega_B"][0] + np.random.default_rng(SEED).normal(0.0, 0.005, (len(t), 3)),
        "thrust": thrust,
        "tau_B": r["tau_B"][0],
        "hover": hover,
        "u_norm": thrust * hover / (MASS_KG * 9.81),
        "u_const": thrust * HOVER_PARAM / (MASS_KG * 9.81),
        "rpm": np.sqrt(np.maximum(f_rotor, 0.0) / K_T) * 60.0 / (2.0 * np.pi),
        "f_cmd": r["f_rotor_cmd"][0],
        "f_lumped_W": f_lumped,
        "f_rotor_W": f_rot,
        "tau_lumped_eta": r["tau_lumped_eta"][0],
    }


def _geometry():
    from ...model import load_preset
    from ..rotors import geometry_from_vehicle

    return geometry_from_vehicle(load_preset("pelican"))


def ca_params() -> dict[str, float]:
    pos, km = _geometry()
    p = {"CA_ROTOR_COUNT": float(len(pos))}
    for i in range(len(pos)):
        p.update({f"CA_ROTOR{i}_PX": pos[i, 0], f"CA_ROTOR{i}_PY": pos[i, 1], f"CA_ROTOR{i}_KM": km[i]})
    return p


def _pwm(f_cmd: np.ndarray, hover: np.ndarray | float) -> np.ndarray:
    """The PWM (whole us) ArduCopter sends for rotor commands ``f_cmd`` (N) with its default thrust curve, the
    rotor's maximum thrust being what makes ``hover`` the hover thrust of the nominal weight."""
    from ..ardupilot import MotorCurve

    T = f_cmd * f_cmd.shape[1] * np.reshape(hover, (-1, 1)) / (MASS_KG * 9.81)
    return np.round(MotorCurve().pwm(T))


def _ardupilot_params() -> dict[str, float]:
    """ArduCopter's motor parameters at their defaults, with outputs 1..4 driving motors 1..4."""
    from ..ardupilot import DEFAULTS

    return {**DEFAULTS, **{f"SERVO{i}_FUNCTION": 32.0 + i for i in range(1, 5)}}


def _every(t: np.ndarray, hz: float, phase: float = 0.0) -> np.ndarray:
    """Indices of the 100 Hz samples closest to a ``hz`` clock (with ``phase`` s of offset)."""
    want = np.arange(t[0] + phase, t[-1], 1.0 / hz)
    return np.unique(np.clip(np.searchsorted(t, want - 1e-9), 0, len(t) - 1))


def _normalised_torque(fa: dict[str, np.ndarray]) -> np.ndarray:
    from ..ulog import torque_per_unit

    k, n = torque_per_unit(ca_params())
    c_t = MASS_KG * 9.81 / (n * fa["hover"])
    return fa["tau_B"] / (k[None, :] * c_t[:, None])


def write_csv_samples(fa: dict[str, np.ndarray], out: Path) -> list[Path]:
    from scipy.spatial.transform import Rotation

    from ...model.kinematics import quat_from_euler, rotation_zyx
    from .. import frames
    from ..writers import write_csv

    t = fa["t"]
    q = quat_from_euler(fa["eta"])
    cols = {"t_s": t + CLOCK_OFFSET_S["csv"]}
    cols.update({k: fa["v_W"][:, i] for i, k in enumerate(("vx", "vy", "vz"))})
    cols.update({f"q{i}": q[:, i] for i in range(4)})
    cols.update({k: fa["omega_B"][:, i] for i, k in enumerate(("wx", "wy", "wz"))})
    cols.update(thrust_norm=fa["u_norm"], hover_thrust=fa["hover"])
    cols.update({k: fa["tau_B"][:, i] for i, k in enumerate(("tx", "ty", "tz"))})
    cols.update({f"rpm{i + 1}": fa["rpm"][:, i] for i in range(fa["rpm"].shape[1])})
    sel = _every(t, 50.0)
    paths = [write_csv(out / SAMPLES["csv"][0], {k: v[sel] for k, v in cols.items()}, {"t_s": "%.6f"}, "%.7g")]
    # the ROS export: ENU / FLU, quaternion x y z w, rates in deg/s, time in milliseconds from zero
    R = frames.rotation_from_ned_frd(rotation_zyx(fa["eta"]), "enu", "flu")
    qx = Rotation.from_matrix(R).as_quat()
    v = frames.world_vector_to_ned(fa["v_W"], "enu")
    w = np.degrees(frames.body_vector_to_frd(fa["omega_B"], "flu"))
    tq = frames.body_vector_to_frd(fa["tau_B"], "flu")
    ros = {"t_s": (t + CLOCK_OFFSET_S["ros-csv"]) * 1e3}
    ros.update({k: v[:, i] for i, k in enumerate(("vx", "vy", "vz"))})
    ros.update({f"q{i}": qx[:, i] for i in range(4)})
    ros.update({k: w[:, i] for i, k in enumerate(("wx", "wy", "wz"))})
    ros.update(thrust_norm=fa["u_norm"], hover_thrust=fa["hover"])
    ros.update({k: tq[:, i] for i, k in enumerate(("tx", "ty", "tz"))})
    paths.append(write_csv(out / SAMPLES["ros-csv"][0], {k: x[sel] for k, x in ros.items()}, {"t_s": "%.3f"}, "%.7g"))
    return paths


def write_px4_samples(fa: dict[str, np.ndarray], out: Path) -> list[Path]:
    from ...model.kinematics import quat_from_euler
    from ..writers import Nested, write_ulog

    t = fa["t"]
    us = np.round((t + CLOCK_OFFSET_S["px4"]) * 1e6).astype(np.uint64)
    q = quat_from_euler(fa["eta"])
    c = _normalised_torque(fa)
    a50, v10, h10, e50 = _every(t, 50.0), _every(t, 10.0, 0.003), _every(t, 10.0, 0.05), _every(t, 50.0, 0.001)
    n = fa["rpm"].shape[1]
    esc = np.zeros((len(e50), 8))
    esc[:, :n] = np.round(fa["rpm"][e50])
    params = {**ca_params(), "MPC_THR_HOVER": HOVER_PARAM, "SIH_MASS": MASS_KG}
    params.update({"SIH_IXX": 3.4e-3, "SIH_IYY": 3.4e-3, "SIH_IZZ": 4.7e-3})
    new = {
        "vehicle_local_position": {"timestamp": us[v10], "timestamp_sample": ("uint64_t", us[v10]),
                                   "vx": fa["v_W"][v10, 0], "vy": fa["v_W"][v10, 1], "vz": fa["v_W"][v10, 2]},
        "vehicle_attitude": {"timestamp": us[a50], "timestamp_sample": ("uint64_t", us[a50]), "q": q[a50]},
        "vehicle_angular_velocity": {"timestamp": us[a50], "timestamp_sample": ("uint64_t", us[a50]),
                                     "xyz": fa["omega_B"][a50]},
        "vehicle_thrust_setpoint": {"timestamp": us[a50], "xyz": np.stack([0 * a50, 0 * a50, -fa["u_norm"][a50]], -1)},
        "vehicle_torque_setpoint": {"timestamp": us[a50], "xyz": c[a50]},
        "hover_thrust_estimate": {"timestamp": us[h10], "hover_thrust": fa["hover"][h10],
                                  "valid": ("bool", np.ones(len(h10), bool))},
        "esc_status": {"timestamp": us[e50], "esc_count": ("uint8_t", np.full(len(e50), n)),
                       "esc": Nested("esc_report", 8, {"esc_rpm": ("int32_t", esc)})},
    }  # fmt: skip
    paths = [write_ulog(out / SAMPLES["px4"][0], new, params, "v1.14.3")]
    # PX4 v1.9: velocity at 8 Hz with dropouts, thrust in actuator_controls_0 (9 Hz) and rates setpoint (30 Hz)
    rng = np.random.default_rng(SEED)
    v8 = _every(t, 8.0, 0.01)
    tv = t[v8]
    drop = np.zeros(len(v8), bool)
    for start in np.arange(2.0, t[-1] - 1.0, 2.3):
        drop |= (tv > start) & (tv < start + rng.uniform(0.3, 0.5))
    v8 = v8[~drop]
    c9, r30 = _every(t, 8.7, 0.004), _every(t, 28.6, 0.007)
    ctrl = np.zeros((len(c9), 8))
    c_const = c * (fa["hover"] / HOVER_PARAM)[:, None]
    ctrl[:, :3], ctrl[:, 3] = c_const[c9], fa["u_const"][c9]
    old = {
        "vehicle_local_position": {"timestamp": us[v8], "vx": fa["v_W"][v8, 0], "vy": fa["v_W"][v8, 1],
                                   "vz": fa["v_W"][v8, 2]},
        "vehicle_attitude": {"timestamp": us[a50], "q": q[a50], "rollspeed": fa["omega_B"][a50, 0],
                             "pitchspeed": fa["omega_B"][a50, 1], "yawspeed": fa["omega_B"][a50, 2]},
        "actuator_controls_0": {"timestamp": us[c9], "control": ctrl},
        "vehicle_rates_setpoint": {"timestamp": us[r30], "roll": 0 * r30, "pitch": 0 * r30, "yaw": 0 * r30,
                                   "thrust_body": np.stack([0 * r30, 0 * r30, -fa["u_const"][r30]], -1)},
    }  # fmt: skip
    paths.append(write_ulog(out / SAMPLES["px4-v1.9"][0], old, {"MPC_THR_HOVER": HOVER_PARAM}, "v1.9.2"))
    return paths


def write_ardupilot_sample(fa: dict[str, np.ndarray], out: Path) -> Path:
    from ..writers import DFMessage, write_dataflash

    t = fa["t"]
    us = np.round((t + CLOCK_OFFSET_S["ardupilot"]) * 1e6).astype(np.int64)
    a25, x25, c10 = _every(t, 25.0), _every(t, 25.0, 0.002), _every(t, 10.0, 0.004)
    deg = np.degrees(fa["eta"][a25])
    deg[:, 2] = np.mod(deg[:, 2], 360.0)
    z = np.zeros(len(a25))
    msgs = [
        DFMessage("MSG", "QZ", {"TimeUS": [int(us[0])], "Message": ["ArduCopter V4.5.7 (vtol-impedance simulation)"]}),
        DFMessage("ATT", "QccccCCCCB", {"TimeUS": us[a25], "DesRoll": deg[:, 0], "Roll": deg[:, 0],
                                        "DesPitch": deg[:, 1], "Pitch": deg[:, 1], "DesYaw": deg[:, 2],
                                        "Yaw": deg[:, 2], "ErrRP": z, "ErrYaw": z, "AEKF": z + 3}),
        DFMessage("RATE", "Qfffffffffffff", {"TimeUS": us[a25], "RDes": z,
                                             "R": np.degrees(fa["omega_B"][a25, 0]), "ROut": z, "PDes": z,
                                             "P": np.degrees(fa["omega_B"][a25, 1]), "POut": z, "YDes": z,
                                             "Y": np.degrees(fa["omega_B"][a25, 2]), "YOut": z, "ADes": z, "A": z,
                                             "AOut": z, "AOutSlew": z}),
        DFMessage("XKF1", "QBccCfffffffccce", {"TimeUS": us[x25], "C": np.zeros(len(x25)), "Roll": z, "Pitch": z,
                                               "Yaw": z, "VN": fa["v_W"][x25, 0], "VE": fa["v_W"][x25, 1],
                                               "VD": fa["v_W"][x25, 2], "dPD": z, "PN": z, "PE": z, "PD": z,
                                               "GX": z, "GY": z, "GZ": z, "OH": z}),
        DFMessage("CTUN", "Qffffffefffhh", {"TimeUS": us[c10], "ThI": fa["u_norm"][c10], "ABst": 0 * c10,
                                            "ThO": fa["u_norm"][c10], "ThH": fa["hover"][c10], "DAlt": 0 * c10,
                                            "Alt": 0 * c10, "BAlt": 0 * c10, "DSAlt": 0 * c10, "SAlt": 0 * c10,
                                            "TAlt": 0 * c10, "DCRt": 0 * c10, "CRt": 0 * c10}),
        DFMessage("PARM", "QNf", {"TimeUS": [int(us[0])] * 3, "Name": ["MOT_THST_HOVER", "FRAME_CLASS", "FRAME_TYPE"],
                                  "Value": [HOVER_PARAM, 1.0, 0.0]}),
    ]  # fmt: skip
    par = _ardupilot_params()
    msgs.append(DFMessage("PARM", "QNf", {"TimeUS": [int(us[0])] * len(par), "Name": list(par),
                                          "Value": list(par.values())}))  # fmt: skip
    pwm = _pwm(fa["f_cmd"][a25], fa["hover"][a25])
    rcou = {"TimeUS": us[a25] + 1000, **{f"C{c}": pwm[:, c - 1] for c in range(1, 5)}}
    msgs.append(DFMessage("RCOU", "QHHHHHHHH", {**rcou, **{f"C{c}": z for c in range(5, 9)}}))
    n = fa["rpm"].shape[1]
    esc_t, esc_i, esc_rpm = [], [], []
    for i in range(n):
        sel = _every(t, 25.0, 0.003 + 0.004 * i)
        esc_t.append(us[sel])
        esc_i.append(np.full(len(sel), i))
        esc_rpm.append(fa["rpm"][sel, i])
    et, ei, er = np.concatenate(esc_t), np.concatenate(esc_i), np.concatenate(esc_rpm)
    z = np.zeros(len(et))
    msgs.append(DFMessage("ESC", "QBffffcfcf", {"TimeUS": et, "Instance": ei, "RPM": er, "RawRPM": er, "Volt": z + 15.8,
                                                "Curr": z + 4.0, "Temp": z + 35.0, "CTot": z, "MotTemp": z + 40.0,
                                                "Err": z}))  # fmt: skip
    return write_dataflash(out / SAMPLES["ardupilot"][0], msgs)


def write_tlog_sample(fa: dict[str, np.ndarray], out: Path) -> Path:
    from ..writers import write_tlog

    t = fa["t"]
    rng = np.random.default_rng(SEED + 1)
    boot = t + CLOCK_OFFSET_S["tlog"]
    unix0 = 1_767_225_600.0
    msgs: list[tuple[float, str, dict]] = []

    def recv(i: int) -> float:
        return unix0 + boot[i] + 0.008 + rng.exponential(0.01)

    param = {"param_id": b"MOT_THST_HOVER", "param_value": HOVER_PARAM, "param_type": 9, "param_count": 1,
             "param_index": 0}  # fmt: skip
    msgs.append((unix0 + boot[0] - 0.5, "PARAM_VALUE", param))
    par = _ardupilot_params()
    for k, (name, value) in enumerate(par.items()):
        msgs.append((unix0 + boot[0] - 0.4 + 0.001 * k, "PARAM_VALUE", {**param, "param_id": name.encode(),
                                                                        "param_value": value}))  # fmt: skip
    beat = {"type": 2, "autopilot": 3, "base_mode": 217, "custom_mode": 5, "system_status": 4, "mavlink_version": 3}
    for i in _every(t, 1.0):
        msgs.append((recv(i), "HEARTBEAT", beat))
    for i in _every(t, 25.0):
        e, w = fa["eta"][i], fa["omega_B"][i]
        att = {"time_boot_ms": int(round(boot[i] * 1e3)), "roll": e[0], "pitch": e[1], "yaw": e[2],
               "rollspeed": w[0], "pitchspeed": w[1], "yawspeed": w[2]}  # fmt: skip
        msgs.append((recv(i), "ATTITUDE", att))
    for i in _every(t, 10.0, 0.02):
        v = fa["v_W"][i]
        pos = {"time_boot_ms": int(round(boot[i] * 1e3)), "x": 0.0, "y": 0.0, "z": 0.0, "vx": v[0], "vy": v[1],
               "vz": v[2]}  # fmt: skip
        msgs.append((recv(i), "LOCAL_POSITION_NED", pos))
    for i in _every(t, 10.0, 0.04):
        hud = {"airspeed": 0.0, "groundspeed": 0.0, "heading": 0, "alt": 1.0, "climb": 0.0,
               "throttle": int(round(100 * fa["u_const"][i]))}  # fmt: skip
        msgs.append((recv(i), "VFR_HUD", hud))
    sel = _every(t, 10.0, 0.08)
    pwm = _pwm(fa["f_cmd"][sel], HOVER_PARAM)
    for k, i in enumerate(sel):
        servo = {"time_usec": int(round(boot[i] * 1e6)), "port": 0, **{f"servo{c}_raw": 0 for c in range(1, 9)}}
        servo.update({f"servo{c}_raw": int(pwm[k, c - 1]) for c in range(1, 5)})
        msgs.append((recv(i), "SERVO_OUTPUT_RAW", servo))
    n = fa["rpm"].shape[1]
    for i in _every(t, 10.0, 0.06):
        rpm = [int(round(x)) for x in fa["rpm"][i, :4]] + [0] * max(0, 4 - n)
        esc = {"temperature": [35] * 4, "voltage": [1580] * 4, "current": [400] * 4, "totalcurrent": [0] * 4,
               "rpm": rpm, "count": [0] * 4}  # fmt: skip
        msgs.append((recv(i), "ESC_TELEMETRY_1_TO_4", esc))
    return write_tlog(out / SAMPLES["tlog"][0], msgs)


def write_truth(fa: dict[str, np.ndarray], out: Path) -> Path:
    from ..writers import write_csv

    sel = _every(fa["t"], 50.0)
    cols = {"t_s": fa["t"][sel]}
    for key in ("f_lumped_W", "f_rotor_W", "tau_lumped_eta"):
        cols.update({f"{key}_{a}": fa[key][sel, i] for i, a in enumerate("xyz")})
    return write_csv(out / TRUTH_FILE, cols, {"t_s": "%.2f"}, "%.5g")


def generate(out: Path | None = None) -> list[Path]:
    """Simulate the flight and write every sample and the truth into ``out`` (default: the package's)."""
    out = Path(out) if out is not None else folder()
    out.mkdir(parents=True, exist_ok=True)
    fa = flight_arrays(simulate_flight())
    paths = write_csv_samples(fa, out) + write_px4_samples(fa, out)
    paths += [write_ardupilot_sample(fa, out), write_tlog_sample(fa, out), write_truth(fa, out)]
    return paths


if __name__ == "__main__":
    for p in generate(Path(sys.argv[1]) if len(sys.argv) > 1 else None):
        print(f"{p} ({p.stat().st_size} bytes)")
