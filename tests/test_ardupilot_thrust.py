"""ArduCopter's motor thrust curve (logs/ardupilot.py) against hand computation from its documented formula,
and a hover with a known payload read from its motor outputs (DataFlash RCOU, tlog SERVO_OUTPUT_RAW)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vtol_impedance.errors import InputError
from vtol_impedance.logs import estimate, read_any, resample
from vtol_impedance.logs.ardupilot import DEFAULTS, MotorCurve
from vtol_impedance.logs.writers import DFMessage, write_dataflash, write_tlog

G = 9.81
MASS = 1.5  # kg, the nominal vehicle
HOVER = 0.35  # MOT_THST_HOVER: the nominal weight over the four rotors' maximum thrust
PAYLOAD_N = 1.0  # hung below the vehicle: +1.0 N along NED z


# ------------------------------------------------------------------------------------- the curve by hand


def test_curve_matches_the_documented_formula_by_hand():
    c = MotorCurve()  # ArduCopter defaults: expo 0.65, spin 0.15..0.95, PWM 1000..2000
    # PWM 1550: actuator 0.55, throttle (0.55 - 0.15) / 0.8 = 0.5, thrust 0.65 * 0.25 + 0.35 * 0.5 = 0.3375
    assert c.thrust(1550.0) == pytest.approx(0.3375, abs=1e-12)
    # at MOT_SPIN_MIN (1150 us) and below: no thrust; at MOT_SPIN_MAX (1950 us) and above: full thrust
    assert c.thrust([1000.0, 1150.0, 1950.0, 2000.0]).tolist() == pytest.approx([0.0, 0.0, 1.0, 1.0], abs=1e-12)
    # linear (expo 0): thrust = throttle; PWM 1350 -> actuator 0.35 -> throttle 0.25
    assert MotorCurve(expo=0.0).thrust(1350.0) == pytest.approx(0.25, abs=1e-12)
    # second order (expo 1): thrust = throttle^2 = 0.0625
    assert MotorCurve(expo=1.0).thrust(1350.0) == pytest.approx(0.0625, abs=1e-12)
    # expo 0.65 at thrust 0.5: throttle = (-0.35 + sqrt(0.35^2 + 4 * 0.65 * 0.5)) / 1.3
    y = (-0.35 + math.sqrt(0.1225 + 1.3)) / 1.3
    assert c.pwm(0.5) == pytest.approx(1000.0 + 1000.0 * (0.15 + 0.8 * y), abs=1e-9)
    # a PWM range of 1100..1900 and spin 0.1..1.0: PWM 1500 -> actuator 0.5 -> throttle 4/9
    d = MotorCurve(expo=0.5, spin_min=0.1, spin_max=1.0, pwm_min=1100.0, pwm_max=1900.0)
    y = 0.4 / 0.9
    assert d.thrust(1500.0) == pytest.approx(0.5 * y * y + 0.5 * y, abs=1e-12)


def test_round_trip_thrust_pwm_thrust_over_the_range():
    T = np.linspace(0.0, 1.0, 101)
    for expo in (-0.5, 0.0, 0.3, 0.65, 1.0):
        c = MotorCurve(expo=expo, spin_min=0.1, spin_max=0.9, pwm_min=1100.0, pwm_max=1940.0)
        assert np.max(np.abs(c.thrust(c.pwm(T)) - T)) < 1e-12
        pwm = c.pwm(T)
        assert pwm[0] == pytest.approx(1100.0 + 0.1 * 840.0) and pwm[-1] == pytest.approx(1100.0 + 0.9 * 840.0)


def test_battery_compensation_by_hand():
    c = MotorCurve(bat_volt_max=16.8, bat_volt_min=13.2)
    # 14.7 V: v = 14.7 / 16.8 = 0.875; PWM 1550 -> throttle 0.5 -> x = 0.4375 -> 0.65 x^2 + 0.35 x
    x = 0.5 * 14.7 / 16.8
    assert c.thrust(1550.0, 14.7) == pytest.approx(0.65 * x * x + 0.35 * x, abs=1e-12)
    # below MOT_BAT_VOLT_MIN the voltage is held at it; no voltage or none plausible (< 0.25 min): no scaling
    x = 0.5 * 13.2 / 16.8
    assert c.thrust(1550.0, 12.0) == pytest.approx(0.65 * x * x + 0.35 * x, abs=1e-12)
    assert c.thrust(1550.0, 0.0) == pytest.approx(0.3375, abs=1e-12) == c.thrust(1550.0)
    T = np.linspace(0.0, 0.8, 9)
    assert np.max(np.abs(c.thrust(c.pwm(T, 15.0), 15.0) - T)) < 1e-12


def test_parameters_read_and_refused_by_name():
    c = MotorCurve.from_params(DEFAULTS)
    assert (c.expo, c.spin_min, c.spin_max, c.pwm_min, c.pwm_max) == (0.65, 0.15, 0.95, 1000.0, 2000.0)
    p = {**DEFAULTS, "MOT_PWM_MIN": 0.0, "MOT_PWM_MAX": 0.0, "RC3_MIN": 1100.0, "RC3_MAX": 1900.0}
    c = MotorCurve.from_params(p)  # unset MOT_PWM_*: ArduCopter's throttle channel range
    assert (c.pwm_min, c.pwm_max) == (1100.0, 1900.0) and "RC3" in c.pwm_from
    with pytest.raises(InputError, match="RC3_MIN, RC3_MAX"):
        MotorCurve.from_params({**DEFAULTS, "MOT_PWM_MIN": 0.0, "MOT_PWM_MAX": 0.0})
    for name in ("MOT_THST_EXPO", "MOT_SPIN_MIN", "MOT_PWM_MAX", "MOT_BAT_VOLT_MAX"):
        with pytest.raises(InputError, match=name):
            MotorCurve.from_params({k: v for k, v in DEFAULTS.items() if k != name})
    with pytest.raises(InputError, match="MOT_BAT_VOLT_MIN"):
        no_min = {k: v for k, v in DEFAULTS.items() if k != "MOT_BAT_VOLT_MIN"}
        MotorCurve.from_params({**no_min, "MOT_BAT_VOLT_MAX": 16.8})
    with pytest.raises(InputError, match="MOT_SPIN_MIN"):
        MotorCurve(spin_min=0.5, spin_max=0.4)
    with pytest.raises(InputError, match="MOT_THST_EXPO"):
        MotorCurve(expo=1.5)


# ------------------------------------------------------------------- a hover with a payload, from the outputs


#: the vehicle bobs up and down (a logger that holds one value is refused): v_z = V sin(w t), NED
V_BOB, W_BOB = 0.2, 2.0 * math.pi * 0.5


def _vz(t: np.ndarray) -> np.ndarray:
    return V_BOB * np.sin(W_BOB * t)


def _hover_pwm(t: np.ndarray, volt: float | None = None, params=DEFAULTS) -> np.ndarray:
    """The PWM ArduCopter sends each of 4 rotors holding the vehicle and the payload while it bobs, by the
    documented curve: u = m g + f_z - m a_z (NED), as the mean rotor thrust over its maximum."""
    u = MASS * G + PAYLOAD_N - MASS * V_BOB * W_BOB * np.cos(W_BOB * t)
    pwm = MotorCurve.from_params(params).pwm(u / (MASS * G / HOVER), volt)
    return np.round(pwm)  # whole microseconds, as logged


PARAMS = {**DEFAULTS, "MOT_THST_HOVER": HOVER, **{f"SERVO{i}_FUNCTION": 32.0 + i for i in range(1, 5)}}


def _dataflash(path, params, volt=None):
    n = 1000  # 20 s at 50 Hz, level and still
    us = (2.0e6 + np.arange(n) * 20_000).astype(np.int64)
    z = np.zeros(n)
    t = (us - us[0]) * 1e-6
    pwm = _hover_pwm(t, volt, params)
    msgs = [
        DFMessage("ATT", "QccccCCCCB", {"TimeUS": us, "DesRoll": z, "Roll": z, "DesPitch": z, "Pitch": z,
                                        "DesYaw": z, "Yaw": z, "ErrRP": z, "ErrYaw": z, "AEKF": z + 3}),
        DFMessage("RATE", "Qfffffffff", {"TimeUS": us, "RDes": z, "R": z, "ROut": z, "PDes": z, "P": z, "POut": z,
                                         "YDes": z, "Y": z, "YOut": z}),
        DFMessage("XKF1", "QBfff", {"TimeUS": us, "C": z, "VN": z, "VE": z, "VD": _vz(t)}),
        DFMessage("RCOU", "QHHHHHH", {"TimeUS": us, "C1": pwm, "C2": pwm, "C3": pwm, "C4": pwm, "C5": z + 1500,
                                      "C6": z}),
        DFMessage("PARM", "QNf", {"TimeUS": [int(us[0])] * len(params), "Name": list(params),
                                  "Value": list(params.values())}),
    ]  # fmt: skip
    if volt is not None:
        msgs.append(DFMessage("BAT", "QBf", {"TimeUS": us, "Inst": z, "Volt": z + volt}))
    return write_dataflash(path, msgs)


def _tlog(path, params, probe_s: float = 0.0):
    """A 20 s hover at 50 Hz; ``probe_s``: ATTITUDE_TARGET also streamed, fast, for that long at the start (a
    ground station's probe) with a thrust that is not the vehicle's."""
    n = 1000
    boot = 5.0 + np.arange(n) * 0.02
    vz = _vz(boot - boot[0])
    pwm = _hover_pwm(boot - boot[0])
    msgs = [(1.7e9, "HEARTBEAT", {"type": 2, "autopilot": 3, "base_mode": 0, "custom_mode": 0, "system_status": 4,
                                  "mavlink_version": 3})]  # fmt: skip
    for i, (k, v) in enumerate(params.items()):
        msgs.append((1.7e9 + 0.001 * i, "PARAM_VALUE", {"param_id": k.encode(), "param_value": v, "param_type": 9,
                                                         "param_count": len(params), "param_index": i}))  # fmt: skip
    for i in range(n):
        ms, rx = int(round(boot[i] * 1e3)), 1.7e9 + boot[i] + 0.01
        msgs.append((rx, "ATTITUDE", {"time_boot_ms": ms, "roll": 0.0, "pitch": 0.0, "yaw": 0.0, "rollspeed": 0.0,
                                      "pitchspeed": 0.0, "yawspeed": 0.0}))  # fmt: skip
        msgs.append((rx, "LOCAL_POSITION_NED", {"time_boot_ms": ms, "x": 0.0, "y": 0.0, "z": 0.0, "vx": 0.0,
                                                "vy": 0.0, "vz": vz[i]}))  # fmt: skip
        p = int(pwm[i])
        msgs.append((rx, "SERVO_OUTPUT_RAW", {"time_usec": ms * 1000, "port": 0, "servo1_raw": p, "servo2_raw": p,
                                              "servo3_raw": p, "servo4_raw": p, "servo5_raw": 0, "servo6_raw": 0,
                                              "servo7_raw": 0, "servo8_raw": 0}))  # fmt: skip
        if boot[i] - boot[0] < probe_s:
            for k in range(2):  # at 100 Hz
                msgs.append((rx + 0.01 * k, "ATTITUDE_TARGET", {"time_boot_ms": ms + 10 * k, "type_mask": 0,
                                                               "q": [1.0, 0.0, 0.0, 0.0], "body_roll_rate": 0.0,
                                                               "body_pitch_rate": 0.0, "body_yaw_rate": 0.0,
                                                               "thrust": 0.2}))  # fmt: skip
        if i % 10 == 0:  # VFR_HUD throttle: the fallback when the outputs are refused
            msgs.append((rx, "VFR_HUD", {"airspeed": 0.0, "groundspeed": 0.0, "heading": 0, "alt": 0.0, "climb": 0.0,
                                         "throttle": 40 + i % 20}))  # fmt: skip
    return write_tlog(path, msgs)


def _fz(path, mass: float = MASS, settle: float = 5.0) -> tuple[float, object]:
    """Mean estimated NED z force (N) after ``settle`` s, and the log as read; the issue's bar for the spread
    (95 % of the errors within 0.10 N) checked on the way."""
    raw, _ = read_any(path)
    est = estimate(resample(raw, 50.0), mass, None, thrust_from="commands")
    keep = est.t > est.t[0] + settle  # past the estimator's start-up
    assert np.percentile(np.abs(est.f_W[keep, 2] - PAYLOAD_N), 95) < 0.10
    return float(np.mean(est.f_W[keep, 2])), raw


def test_dataflash_rcou_hover_with_a_payload_reads_the_payload(tmp_path):
    fz, raw = _fz(_dataflash(tmp_path / "hover.bin", PARAMS))
    assert "RCOU" in raw.thrust.source and any("MOT_THST_EXPO 0.65" in c for c in raw.choices)
    assert fz == pytest.approx(PAYLOAD_N, abs=0.05)
    # read as linear in PWM (1000..2000 us), the same outputs gave several newtons (what this replaced)
    pwm = _hover_pwm(np.array([0.5]))[0]  # a_z = 0 here
    linear = MASS * G * (pwm - 1000.0) / 1000.0 / HOVER - MASS * G
    assert abs(linear - PAYLOAD_N) > 3.0


def test_dataflash_rcou_with_battery_compensation(tmp_path):
    params = {**PARAMS, "MOT_BAT_VOLT_MAX": 16.8, "MOT_BAT_VOLT_MIN": 13.2}
    fz, raw = _fz(_dataflash(tmp_path / "bat.bin", params, volt=15.1))
    assert any("BAT.Volt" in c for c in raw.choices)
    assert fz == pytest.approx(PAYLOAD_N, abs=0.05)
    # without the voltage the outputs are refused, naming why
    with pytest.raises(InputError, match="RCOU refused as thrust: MOT_BAT_VOLT_MAX"):
        read_any(_dataflash(tmp_path / "nobat.bin", params))


def test_dataflash_rcou_refused_naming_the_missing_parameter(tmp_path):
    params = {k: v for k, v in PARAMS.items() if k != "MOT_SPIN_MAX"}
    with pytest.raises(InputError, match="MOT_SPIN_MAX"):  # no other thrust source in this log
        read_any(_dataflash(tmp_path / "nospin.bin", params))


def test_tlog_servo_output_raw_hover_with_a_payload(tmp_path):
    fz, raw = _fz(_tlog(tmp_path / "hover.tlog", PARAMS))
    assert "SERVO_OUTPUT_RAW" in raw.thrust.source
    assert fz == pytest.approx(PAYLOAD_N, abs=0.05)
    # without MOT_THST_EXPO the outputs are refused by name and VFR_HUD's throttle is used instead
    params = {k: v for k, v in PARAMS.items() if k != "MOT_THST_EXPO"}
    raw, _ = read_any(_tlog(tmp_path / "noexpo.tlog", params))
    assert raw.thrust.source.startswith("VFR_HUD")
    assert any("SERVO_OUTPUT_RAW refused as thrust" in n and "MOT_THST_EXPO" in n for n in raw.notes)


def test_a_fast_stream_of_a_few_seconds_does_not_replace_one_that_covers_the_flight(tmp_path):
    """ATTITUDE_TARGET at 100 Hz for the first 3 s of a 20 s tlog (what a ground station's probe leaves), the
    motor outputs at 50 Hz throughout: the outputs give the thrust (by rate alone the short stream won, and
    its thrust is not the vehicle's)."""
    fz, raw = _fz(_tlog(tmp_path / "probe.tlog", PARAMS, probe_s=3.0))
    assert "SERVO_OUTPUT_RAW" in raw.thrust.source
    assert fz == pytest.approx(PAYLOAD_N, abs=0.05)


# --------------------------------------------------------------------------------------------- live


def test_live_ardupilot_servo_outputs_read_the_payload_through_the_curve(tmp_path):
    """The simulated ArduCopter drives its motors through the documented curve with its default parameters
    (and answers them); ``live`` reads them back: a 1.0 N payload (injected, NED down) is estimated within
    0.05 N, where reading the PWM as linear gave several newtons."""
    from test_live import free_port, quiet_spec, read_csv, sim_thread

    from vtol_impedance.live import LiveSettings, replay, run_live

    port = free_port()
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot",
                    inject_force_W=(0.0, 0.0, PAYLOAD_N), no_streams=("ESC_TELEMETRY_1_TO_4",)):  # fmt: skip
        res = run_live(LiveSettings(f"udpin:127.0.0.1:{port}", duration=8.0, out=str(tmp_path / "r"), display="none"))
    s = res.summary
    assert s["estimator"]["sources"]["outputs"] == "SERVO_OUTPUT_RAW"
    tmap = s["estimator"]["thrust_map"]
    assert tmap["motor_curve"]["expo"] == pytest.approx(0.65) and tmap["motor_channels"] == [1, 2, 3, 4]
    e = read_csv(res.folder / "estimate.csv")
    last = e["t_s"] > e["t_s"][-1] - 1.5
    assert np.mean(e["fz_W_N"][last]) == pytest.approx(PAYLOAD_N, abs=0.05)
    assert np.percentile(np.abs(e["fz_W_N"][last] - PAYLOAD_N), 95) < 0.10
    assert abs(np.mean(e["fx_W_N"][last])) < 0.05 and abs(np.mean(e["fy_W_N"][last])) < 0.05
    # the run folder replays to the same numbers (the curve is in live.json) ...
    ticks, _ = replay(res.folder)
    assert np.allclose([t.f_hat_W[2] for t in ticks], e["fz_W_N"], rtol=0, atol=1e-8)
    # ... and estimate's tlog reader finds in its tlog the parameters live read, and the same force (no ESC
    # telemetry: streamed only while live probes, too few samples for that reader)
    fz, raw = _fz(res.folder / "flight.tlog", mass=tmap["mass"], settle=1.0)
    assert any("SERVO_OUTPUT_RAW: PWM read as thrust" in c and "MOT_THST_EXPO 0.65" in c for c in raw.choices)
    assert fz == pytest.approx(PAYLOAD_N, abs=0.05)


def test_live_ardupilot_outputs_refused_naming_an_unanswered_parameter(tmp_path):
    from test_live import free_port, quiet_spec, sim_thread

    from vtol_impedance.live import LiveSettings, run_live

    port = free_port()
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot") as sim:
        del sim.params["MOT_SPIN_MAX"]  # the vehicle does not answer it
        res = run_live(LiveSettings(f"udpin:127.0.0.1:{port}", duration=6.0, out=str(tmp_path / "r"), display="none"))
    s = res.summary
    assert "outputs" not in s["estimator"]["sources"] and s["estimator"]["sources"]["thrust"] == "ATTITUDE_TARGET"
    assert any("motor outputs refused" in ev["text"] and "MOT_SPIN_MAX" in ev["text"] for ev in s["events"])
    assert res.ticks > 0  # estimated from ATTITUDE_TARGET instead
