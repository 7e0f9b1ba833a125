"""Single fields of each log format, written in the format's own units and read back through the public
readers: what each field means is taken from the format's specification (PX4's uORB messages and
control-allocation parameters, ArduPilot's DataFlash, MAVLink's common messages), not from the reader.

* ULog: ``timestamp_sample`` is when a measurement was taken (µs); ``hover_thrust_estimate.valid`` flags
  the samples the estimator vouches for; ``CA_ROTOR{i}_KM`` is the yaw moment per newton of thrust, positive
  for a rotor turning counter-clockwise seen from above (its drag yaws the body nose-right: +z in FRD).
* DataFlash: logs of ArduCopter 3.2 and older time every message with ``TimeMS`` (ms since boot).
* tlog: ``GLOBAL_POSITION_INT.vx/vy/vz`` are cm/s (NED); ``ATTITUDE_QUATERNION.q1..q4`` is w, x, y, z of
  the body-to-NED rotation.
* A CSV longer than the convention check takes is checked on its most dynamic block.
* Rotor speeds with a named vehicle's rotor geometry (``--vehicle``) give the body moment.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import synthflight as S
from logfiles import csv_cols, write_csv

from vtol_impedance.errors import InputError
from vtol_impedance.logs import estimate_file, read_any, read_ulog
from vtol_impedance.logs.mavlog import read_dataflash, read_tlog
from vtol_impedance.logs.rotors import rotor_wrench
from vtol_impedance.logs.writers import DFMessage, write_dataflash, write_tlog, write_ulog

HOVER = 0.42  # normalised hover thrust written into the logs


def _ulog_hover_topics(n: int = 200, rate_hz: float = 100.0) -> tuple[np.ndarray, dict]:
    """``(publication times µs, topics)``: a level hover as PX4 >= 1.14 logs it, every field PX4's own
    (uORB names and units), at ``rate_hz`` from t = 1 s."""
    us = (1_000_000 + np.arange(n) * round(1e6 / rate_hz)).astype(np.uint64)
    z = np.zeros(n)
    topics = {
        "vehicle_local_position": {"timestamp": us, "vx": z, "vy": z, "vz": z},
        "vehicle_attitude": {"timestamp": us, "q": np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))},
        "vehicle_angular_velocity": {"timestamp": us, "xyz": np.zeros((n, 3))},
        # thrust along -z_B (FRD): PX4's setpoint z is minus the normalised thrust
        "vehicle_thrust_setpoint": {"timestamp": us, "xyz": np.column_stack([z, z, z - HOVER])},
    }
    return us, topics


# ----------------------------------------------------------------------------- PX4 ULog


def test_ulog_velocity_times_are_its_timestamp_sample_in_seconds(tmp_path):
    """PX4 publishes the local position 3 ms after it measured it: ``timestamp_sample`` (µs) is the
    measurement's instant, and the velocity must be placed there, to the microsecond."""
    us, topics = _ulog_hover_topics()
    sampled_us = us - np.uint64(3000)
    # PX4's field order: timestamp, timestamp_sample, then the data (uint64 µs, as PX4 logs it)
    vel = {k: v for k, v in topics["vehicle_local_position"].items() if k != "timestamp"}
    topics["vehicle_local_position"] = {"timestamp": us, "timestamp_sample": ("uint64_t", sampled_us), **vel}
    raw = read_ulog(write_ulog(tmp_path / "sample.ulg", topics, {"MPC_THR_HOVER": HOVER}))
    t_vel_s = raw.velocity_W.t
    np.testing.assert_allclose(t_vel_s, sampled_us.astype(float) * 1e-6, rtol=0, atol=1e-9)
    assert t_vel_s[0] == pytest.approx(0.997, abs=1e-9)  # 1 s published, 3 ms earlier measured
    # the attitude logged without timestamp_sample keeps its publication times
    np.testing.assert_allclose(raw.attitude.t, us.astype(float) * 1e-6, rtol=0, atol=1e-9)
    assert "vehicle_local_position" in raw.meta["measurement_times"]
    assert "vehicle_attitude" not in raw.meta["measurement_times"]


def test_ulog_hover_thrust_samples_flagged_invalid_are_ignored(tmp_path):
    """``hover_thrust_estimate.valid`` is false while PX4's estimator has not converged: those samples (here
    an absurd 0.9, within 0..1 so that only the flag tells them apart) must not enter the hover thrust."""
    us, topics = _ulog_hover_topics()
    every = slice(None, None, 10)  # the estimate at 10 Hz
    t_us = us[every]
    valid = np.arange(len(t_us)) >= 8  # the first 0.8 s not converged
    hover = np.where(valid, HOVER, 0.9)
    topics["hover_thrust_estimate"] = {"timestamp": t_us, "hover_thrust": hover, "valid": ("bool", valid)}
    raw = read_ulog(write_ulog(tmp_path / "hover.ulg", topics))
    assert raw.hover is not None
    np.testing.assert_allclose(raw.hover.values[:, 0], HOVER, rtol=1e-6)  # float32 in the log
    np.testing.assert_allclose(raw.hover.t, t_us[valid].astype(float) * 1e-6, rtol=0, atol=1e-9)
    # one valid sample only: that sample is the hover thrust
    one = np.arange(len(t_us)) == 12
    topics["hover_thrust_estimate"] = {"timestamp": t_us, "hover_thrust": np.where(one, HOVER, 0.9),
                                       "valid": ("bool", one)}  # fmt: skip
    raw = read_ulog(write_ulog(tmp_path / "one.ulg", topics))
    assert raw.hover is None and raw.hover_thrust == pytest.approx(HOVER, rel=1e-6)


def test_ulog_rotor_km_sign_gives_the_frd_yaw_moment(tmp_path):
    """PX4: ``Torque = KM * Thrust``, KM positive for a rotor turning counter-clockwise seen from above,
    whose drag yaws the body nose-right (+z of FRD). A quad longer than wide with KM of both signs and
    unequal sizes: rotors 0 and 1 (KM +0.05) at 3.6 N, rotors 2 and 3 (KM -0.03) at 2.5 N give a yaw
    moment 2 * 0.05 * 3.6 - 2 * 0.03 * 2.5 = +0.21 N m, and the roll and pitch moments of the positions."""
    _, topics = _ulog_hover_topics()
    px = [0.25, -0.25, 0.25, -0.25]
    py = [0.10, -0.10, -0.10, 0.10]
    km = [0.05, 0.05, -0.03, -0.03]
    params = {"CA_ROTOR_COUNT": 4.0, "MPC_THR_HOVER": HOVER}
    for i in range(4):
        params.update({f"CA_ROTOR{i}_PX": px[i], f"CA_ROTOR{i}_PY": py[i], f"CA_ROTOR{i}_KM": km[i]})
    raw = read_ulog(write_ulog(tmp_path / "km.ulg", topics, params))
    assert raw.rotor_geometry is not None
    pos_B_m, km_read = raw.rotor_geometry
    np.testing.assert_allclose(km_read, km, rtol=1e-6)  # each rotor keeps its spin's sign
    np.testing.assert_allclose(pos_B_m[:, :2], np.column_stack([px, py]), rtol=1e-6)
    k_T = 1e-5  # N per (rad/s)^2
    w_rad_s = np.array([[600.0, 600.0, 500.0, 500.0]])  # thrusts 3.6, 3.6, 2.5, 2.5 N
    thrust_N, tau_B_Nm = rotor_wrench(w_rad_s, k_T, raw.rotor_geometry)
    assert thrust_N[0] == pytest.approx(12.2)
    # roll = sum f (-y): -0.36 + 0.36 + 0.25 - 0.25 = 0; pitch = sum f x: 0.9 - 0.9 + 0.625 - 0.625 = 0
    np.testing.assert_allclose(tau_B_Nm[0], [0.0, 0.0, 0.21], atol=1e-7)
    # rotor 0 alone (front right, CCW): rolls left (-x), pitches nose up (+y), yaws nose right (+z)
    _, tau0 = rotor_wrench(np.array([[600.0, 0.0, 0.0, 0.0]]), k_T, raw.rotor_geometry)
    np.testing.assert_allclose(tau0[0], [-0.10 * 3.6, 0.25 * 3.6, 0.05 * 3.6], rtol=1e-6)


# ----------------------------------------------------------------------------- ArduPilot DataFlash


def test_dataflash_timems_is_milliseconds(tmp_path):
    """ArduCopter 3.2 and older time their messages with ``TimeMS`` (uint32, ms since boot) and no TimeUS:
    rows 10 ms apart from 5 s after boot are a 100 Hz log starting at 5 s."""
    n = 300
    ms = 5000 + 10 * np.arange(n)
    z = np.zeros(n)
    msgs = [
        DFMessage("ATT", "IccccCCCC", {"TimeMS": ms, "DesRoll": z, "Roll": z + 1.5, "DesPitch": z, "Pitch": z - 2.0,
                                       "DesYaw": z, "Yaw": z + 30.0, "ErrRP": z, "ErrYaw": z}),
        DFMessage("RATE", "Iffffff", {"TimeMS": ms, "RDes": z, "R": z, "PDes": z, "P": z, "YDes": z, "Y": z}),
        DFMessage("NKF1", "IBfff", {"TimeMS": ms, "C": z, "VN": z + 1.0, "VE": z, "VD": z}),
        DFMessage("CTUN", "Iff", {"TimeMS": ms, "ThO": z + HOVER, "ThH": z + HOVER}),
    ]  # fmt: skip
    raw = read_dataflash(write_dataflash(tmp_path / "old.bin", msgs))
    for sig in (raw.attitude, raw.omega_B, raw.velocity_W, raw.thrust):
        assert sig.t[0] == pytest.approx(5.0, abs=1e-12), sig.name
        np.testing.assert_allclose(np.diff(sig.t), 0.01, rtol=1e-9, err_msg=sig.name)
    # the centidegree attitude in radians (1.5, -2, 30 deg)
    np.testing.assert_allclose(raw.attitude.values[0], np.radians([1.5, -2.0, 30.0]), atol=1e-9)


# ----------------------------------------------------------------------------- MAVLink tlog


def _quaternion_zyx(roll: float, pitch: float, yaw: float) -> list[float]:
    """w, x, y, z of the body-to-NED rotation Rz(yaw) Ry(pitch) Rx(roll) (the aerospace formula)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]  # fmt: skip


ROLL, PITCH, YAW = 0.2, -0.1, math.radians(30.0)  # rad, body to NED


@pytest.fixture(scope="module")
def quaternion_tlog(tmp_path_factory):
    """A PX4-style stream: ATTITUDE_QUATERNION and ATTITUDE_TARGET at 50 Hz, GLOBAL_POSITION_INT at 25 Hz
    (velocity 150, -75, 20 cm/s), no ATTITUDE and no LOCAL_POSITION_NED."""
    q = _quaternion_zyx(ROLL, PITCH, YAW)
    unix0 = 1.7e9
    msgs = []
    for k in range(200):
        ms = 10_000 + 20 * k
        recv = unix0 + ms * 1e-3 + 0.01
        msgs.append((recv, "ATTITUDE_QUATERNION", {"time_boot_ms": ms, "q1": q[0], "q2": q[1], "q3": q[2],
                                                   "q4": q[3], "rollspeed": 0.0, "pitchspeed": 0.0,
                                                   "yawspeed": 0.0}))  # fmt: skip
        msgs.append((recv + 0.001, "ATTITUDE_TARGET", {"time_boot_ms": ms, "type_mask": 0, "q": [1.0, 0.0, 0.0, 0.0],
                                                       "body_roll_rate": 0.0, "body_pitch_rate": 0.0,
                                                       "body_yaw_rate": 0.0, "thrust": HOVER}))  # fmt: skip
        if k % 2 == 0:
            msgs.append((recv + 0.002, "GLOBAL_POSITION_INT", {"time_boot_ms": ms, "lat": 0, "lon": 0, "alt": 0,
                                                               "relative_alt": 0, "vx": 150, "vy": -75, "vz": 20,
                                                               "hdg": 0}))  # fmt: skip
    return read_tlog(write_tlog(tmp_path_factory.mktemp("tlog") / "quat.tlog", msgs))


def test_tlog_global_position_int_velocity_is_cm_per_s(quaternion_tlog):
    raw = quaternion_tlog
    assert raw.velocity_W.source.startswith("GLOBAL_POSITION_INT")
    np.testing.assert_allclose(raw.velocity_W.values, np.tile([1.5, -0.75, 0.2], (len(raw.velocity_W.t), 1)),
                               rtol=1e-12)  # fmt: skip
    np.testing.assert_allclose(np.diff(raw.velocity_W.t), 0.04, rtol=1e-9)  # 25 Hz on the vehicle's clock


def test_tlog_attitude_quaternion_is_wxyz_body_to_ned(quaternion_tlog):
    """Roll 0.2, pitch -0.1, yaw +30 deg: read as the inverse (world to body) the angles would differ in
    every component (-0.22, -0.015, -0.53 rad), read as x, y, z, w they would be nonsense."""
    raw = quaternion_tlog
    assert raw.attitude.source.startswith("ATTITUDE_QUATERNION")
    eta_rad = raw.attitude.values
    np.testing.assert_allclose(eta_rad, np.tile([ROLL, PITCH, YAW], (len(eta_rad), 1)), atol=1e-6)
    assert eta_rad[0, 2] == pytest.approx(0.5236, abs=1e-4)


# ----------------------------------------------------------------------------- a long CSV: the block checked


def _calm_then_flight(path, calm_rows: int, flight_s: float):
    """A CSV at 1 kHz: ``calm_rows`` of still hover (sensor noise only), then ``flight_s`` of flight
    (``synthflight``, rolling and pitching a few degrees)."""
    dyn = csv_cols(S.flight(flight_s, 1000.0))  # NED, FRD, rad, s
    n = calm_rows
    rng = np.random.default_rng(7)
    calm = {k: np.zeros(n) for k in dyn}
    calm["t_s"] = np.arange(n) / 1000.0
    calm["thrust_n"] = S.MASS * S.G + 0.01 * rng.standard_normal(n)  # the weight, with noise
    for k in ("wx", "wy", "wz"):
        calm[k] = 1e-3 * rng.standard_normal(n)  # gyro noise, rad/s
    dyn["t_s"] = dyn["t_s"] + n / 1000.0
    return write_csv(path, {k: np.concatenate([calm[k], dyn[k]]) for k in dyn})


@pytest.fixture(scope="module")
def long_csv(tmp_path_factory):
    """60,001 rows: 30 s of still hover, then 30 s of flight. The convention check takes 30,000 rows: the
    flight's."""
    return _calm_then_flight(tmp_path_factory.mktemp("long") / "long.csv", 30_000, 30.0)


def test_a_long_csv_is_checked_on_its_flight_not_its_still_hover(long_csv):
    """Only motion tells the conventions apart (a still, level hover reads the same in radians and degrees,
    and with both world and body frames flipped): checked on the flight, the declared conventions are all
    confirmed, and radians declared as degrees are refused with the flag that fixes them."""
    raw, rep = read_any(long_csv)
    assert any("most dynamic part" in n for n in raw.notes)
    assert rep.undetermined == []
    assert "conventions checked against physics: the declared ones fit best" in rep.notes
    with pytest.raises(InputError, match="--angle-unit rad"):
        read_any(long_csv, angle_unit="deg")


def test_a_flight_in_the_last_rows_of_a_long_csv_is_the_part_checked(tmp_path):
    """37,500 rows of still hover, then 6.5 s of flight: the flight is all in the last 30,000 rows, which
    the blocks stepped by a quarter from the start missed (up to 7,499 trailing rows were never looked at,
    and radians declared as degrees passed as "cannot confirm")."""
    path = _calm_then_flight(tmp_path / "tail.csv", 37_500, 6.5)
    with pytest.raises(InputError, match="--angle-unit rad"):
        read_any(path, angle_unit="deg")
    raw, rep = read_any(path)
    assert rep.undetermined == []


# ----------------------------------------------------------------------------- rotor speeds with --vehicle


def test_rotor_speeds_with_a_named_vehicles_geometry_give_the_body_moment(tmp_path):
    """A CSV with only rotor speeds (rpm1..rpm4) of a Pelican in the X layout (``--vehicle pelican-x``): PX4's
    quad-X numbering, rotor 1 front right, 2 rear left, 3 front left, 4 rear right, 0.21 m from the centre at
    45 deg; 1 and 2 turn counter-clockwise seen from above (+z FRD yaw, 0.016 N m per N), 3 and 4 clockwise.
    The speeds are what produces the synthetic flight's thrust and torque with that geometry; the moment
    estimate then follows G(s) of the true external moment, which needs the vehicle's arms and spins."""
    fl = S.flight()
    arm_m, c_Nm_per_N, k_T = 0.21, 0.016, 8.0e-6
    ang = np.radians([45.0, -135.0, -45.0, 135.0])
    x_m, y_m = arm_m * np.cos(ang), arm_m * np.sin(ang)
    spin = np.array([1.0, 1.0, -1.0, -1.0])
    E = np.array([np.ones(4), -y_m, x_m, spin * c_Nm_per_N])  # [u, tau_B] per newton of each rotor
    f_N = np.linalg.solve(E, np.column_stack([fl.thrust, fl.tau_B]).T).T
    assert f_N.min() > 0
    rpm = np.sqrt(f_N / k_T) * 60.0 / (2.0 * math.pi)
    cols = {k: v for k, v in csv_cols(fl, every=2).items() if k not in ("thrust_n", "tx", "ty", "tz")}
    cols.update({f"rpm{i + 1}": rpm[::2, i] for i in range(4)})
    path = write_csv(tmp_path / "rpm.csv", cols)
    e = estimate_file(path, mass=S.MASS, inertia=S.INERTIA, vehicle="pelican-x", thrust_coefficient=k_T)
    assert any(c.startswith("rotor geometry: the vehicle pelican-x") for c in e.info["choices"])
    assert e.info.get("torque", "").startswith("rotor speeds")  # not from commands: the CSV has none
    steady = ((e.t > 3.0) & (e.t < 4.9)) | ((e.t > 10.0) & (e.t < 12.0))  # G settled on the constant moment
    # within 3 deg of level, G applied to the body moment directly is right to 1e-3 N m; a wrong spin sign is
    # off by 0.01 N m in yaw (twice the 5 mN m bias), a 10 % wrong arm by 2-3 mN m in pitch after the step
    np.testing.assert_allclose(e.tau_B[steady], S.g_of_true_wrench(e.t, "tau")[steady], atol=1e-3)


def test_a_dead_esc_between_live_ones_is_not_renumbered(tmp_path):
    """ESC 1 of four reports zero throughout: its neighbours' speeds must not be taken as rotors 0, 1, 2
    (the thrust and moments would come from the wrong arms); the rotor speeds are left out, with the reason.
    With all four alive they are read, in order."""
    from vtol_impedance.logs.mavlog import _combine_escs
    from vtol_impedance.logs.writers import Nested

    us, topics = _ulog_hover_topics()
    n = len(us)
    for dead in (None, 1):
        rpm = np.tile([6000.0, 6100.0, 6200.0, 6300.0], (n, 1))
        if dead is not None:
            rpm[:, dead] = 0.0
        topics["esc_status"] = {
            "timestamp": us, "esc_count": ("uint8_t", np.full(n, 4)),
            "esc": Nested("esc_report", 4, {"esc_rpm": ("int32_t", rpm)}),
        }  # fmt: skip
        raw = read_ulog(write_ulog(tmp_path / f"esc{dead}.ulg", topics, {"MPC_THR_HOVER": HOVER}))
        if dead is None:
            np.testing.assert_allclose(raw.rotor_speed.values[0] * 60 / (2 * math.pi), [6000, 6100, 6200, 6300])
        else:
            assert raw.rotor_speed is None
            assert any("ESC 1 reports zero throughout while ESC 3 reports" in c for c in raw.choices)
    # the MAVLink readers' ESC telemetry: the same rule, the same reason
    t = np.arange(10) * 0.01
    per = {i: (t, np.full(10, 6000.0 + i)) for i in (0, 2, 3)} | {1: (t, np.zeros(10))}
    choices: list[str] = []
    assert _combine_escs(per, "ESC_TELEMETRY_1_TO_4.rpm", choices) is None
    assert any("ESC 1 reports zero throughout" in c for c in choices)


def test_a_time_stamp_jump_is_named_with_its_size_and_place_and_the_advice_works(tmp_path):
    """Two logs joined (the clock jumps by 1e7 s after 10 s at 100 Hz): the refusal says by how much and
    where, not just "implausible" (every signal runs at 100 Hz), and its advice, one part with the
    conventions unchecked, gives an estimate."""
    fl = S.flight(20.0, 100.0)
    cols = csv_cols(fl)
    cols["t_s"] = np.where(np.arange(len(cols["t_s"])) >= 1000, cols["t_s"] + 1e7, cols["t_s"])
    path = write_csv(tmp_path / "joined.csv", cols)
    with pytest.raises(InputError, match=r"jump by 1e\+07 s at t = 9\.99 s .*split the file there"):
        estimate_file(path, mass=S.MASS, inertia=S.INERTIA)
    est = estimate_file(path, mass=S.MASS, inertia=S.INERTIA, t_end=9.9, read_options={"conventions": "unchecked"})
    assert est.t[-1] <= 9.9 and est.t[-1] - est.t[0] > 9.0


def test_damaged_or_absurd_vehicle_parameters_are_named_or_left_out():
    """A log's SIH_MASS of 1e6 kg flew through the estimate (the thrust scales with it, so no balance sees it)
    while --mass 1e6 is refused: checked the same way, naming the parameter. A non-finite CA_ROTOR_COUNT or
    SERVOn_FUNCTION gave internal errors; the geometry and motor channels they name are then unknown, which
    the force estimate does not need."""
    from vtol_impedance.logs import samples
    from vtol_impedance.logs.ardupilot import motor_channels
    from vtol_impedance.logs.pipeline import _vehicle
    from vtol_impedance.logs.ulog import rotor_geometry

    raw, _ = read_any(samples.path("px4"))
    assert _vehicle(raw, None, None, None)[0] == pytest.approx(raw.mass)
    for bad in (1e6, 1e-4):
        raw.mass = bad
        with pytest.raises(InputError, match=r"the log's mass \(the SIH_\* parameters"):
            _vehicle(raw, None, None, None)
    assert _vehicle(raw, 1.2, None, None)[0] == 1.2  # given: the log's is only compared
    quad = {"CA_ROTOR_COUNT": 4.0, **{f"CA_ROTOR{i}_P{c}": v for i, (x, y) in
                                      enumerate(((0.1, 0.1), (-0.1, -0.1), (0.1, -0.1), (-0.1, 0.1)))
                                      for c, v in (("X", x), ("Y", y))}}  # fmt: skip
    assert rotor_geometry(quad) is not None
    for key, value in (("CA_ROTOR_COUNT", math.inf), ("CA_ROTOR_COUNT", math.nan), ("CA_ROTOR1_PX", math.nan),
                       ("CA_ROTOR2_KM", math.inf)):  # fmt: skip
        assert rotor_geometry({**quad, key: value}) is None, key
    motors = {f"SERVO{ch}_FUNCTION": 32.0 + ch for ch in (1, 2, 3, 4)}
    assert motor_channels(motors) == [1, 2, 3, 4]
    assert motor_channels({**motors, "SERVO2_FUNCTION": math.nan, "SERVO3_FUNCTION": math.inf}) == [1, 4]
