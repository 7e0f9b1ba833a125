"""Documented rules that planted bugs (a mutation campaign) got past: each test checks one rule against a value
worked out by hand, an analytic formula or the rule's own words, never against the code's own output.

ArduCopter's battery clamp and PWM fallback, the convention score's tilt term, idle thrust at the ends of a
log, an ArduPlane without Q_ENABLE, resuming a sweep (foreign axis values, a lost traces file), a clock
jump of 23 days, the causal estimator restarted per segment, a mirrored thrust against the rotor speeds,
the NumPy backend's sensor noise, the fan jet's force law, the push's half-sine and the metrics window."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import synthflight as S
from logfiles import csv_cols, rotor_speeds, write_csv

from vtol_impedance.errors import InputError
from vtol_impedance.logs.ardupilot import DEFAULTS, MotorCurve

# ------------------------------------------------------------------------ M03, M04: ArduCopter's curve


def test_battery_voltage_below_the_floor_is_held_at_60_percent_of_max_when_min_is_unset():
    """The documented clamp: ``V`` is held in ``[max(MOT_BAT_VOLT_MIN, 0.6 MOT_BAT_VOLT_MAX), MOT_BAT_VOLT_MAX]``.
    With MOT_BAT_VOLT_MIN = 0 the floor is 0.6 x 16.8 = 10.08 V: at 8 V (and at 5 V) the scale is 10.08 / 16.8
    = 0.6, the same thrust as at the floor itself, computed by hand from the documented curve."""
    c = MotorCurve(bat_volt_max=16.8, bat_volt_min=0.0)
    # PWM 1550 with the defaults: actuator 0.55, throttle y = (0.55 - 0.15) / 0.8 = 0.5; x = y v
    x = 0.5 * 0.6
    by_hand = 0.65 * x * x + 0.35 * x
    for volt in (8.0, 5.0, 10.08):
        assert c.thrust(1550.0, volt) == pytest.approx(by_hand, abs=1e-12), volt
    # above the floor the voltage counts as it is: 14.7 V -> v = 0.875
    x = 0.5 * 14.7 / 16.8
    assert c.thrust(1550.0, 14.7) == pytest.approx(0.65 * x * x + 0.35 * x, abs=1e-12)
    # and the inverse holds the same floor: the PWM for thrust T at 8 V is the one at 10.08 V
    assert c.pwm(0.3, 8.0) == pytest.approx(c.pwm(0.3, 10.08), abs=1e-9)


@pytest.mark.parametrize("which", ["MOT_PWM_MIN", "MOT_PWM_MAX"])
def test_either_pwm_limit_zero_takes_the_throttle_channels_range(which):
    """Module docstring: "when either is 0 or they are not ordered, ArduCopter uses the throttle channel's
    RC3_MIN, RC3_MAX; so does this module". One of the two at 0 (the other set) must give the RC3 range,
    and the RC3 parameters are then required by name."""
    p = {**DEFAULTS, which: 0.0, "RC3_MIN": 1100.0, "RC3_MAX": 1900.0}
    c = MotorCurve.from_params(p)
    assert (c.pwm_min, c.pwm_max) == (1100.0, 1900.0) and "RC3" in c.pwm_from
    # PWM 1500 on 1100..1900: actuator 0.5 -> throttle (0.5 - 0.15) / 0.8 = 0.4375
    y = 0.35 / 0.8
    assert c.thrust(1500.0) == pytest.approx(0.65 * y * y + 0.35 * y, abs=1e-12)
    with pytest.raises(InputError, match="RC3_MIN, RC3_MAX"):
        MotorCurve.from_params({**DEFAULTS, which: 0.0})
    # not ordered (min above max, neither 0): the throttle channel too
    q = {**DEFAULTS, "MOT_PWM_MIN": 2000.0, "MOT_PWM_MAX": 1000.0, "RC3_MIN": 1100.0, "RC3_MAX": 1900.0}
    assert (MotorCurve.from_params(q).pwm_min, MotorCurve.from_params(q).pwm_max) == (1100.0, 1900.0)


# ------------------------------------------------------------------------------ M11: the tilt in the score


def _evidence(tilt: float):
    from vtol_impedance.logs.checks import Evidence

    # every other term neutral: no rotation or acceleration to score, a plausible gyro, a positive thrust gain
    return Evidence(kin=0.0, kin_gain=np.ones(3), kin_motion=0.0, rate_rms=0.1, tilt_rad=tilt, thrust_gain=1.0,
                    dyn=np.zeros(2), dyn_motion=np.zeros(2), rates_hz={"velocity": 50.0}, time_ok=True)  # fmt: skip


def test_the_score_counts_the_thrust_axis_tilt_against_the_specific_force():
    """``Evidence.score``: "about 0.2-0.8 for a consistent log, several units for a contradiction"; the
    gravity check expects the thrust axis within "a few degrees" of the specific force, and tens of degrees
    mean a wrong reading. So with every other term neutral: 3 degrees scores under 0.8, 30 degrees and more
    scores several units (>= 2), the score grows with the tilt, and the tilt adds to the other terms
    (the same tilt on top of a failed thrust gain adds the same amount)."""
    low = _evidence(math.radians(3.0)).score
    high = _evidence(math.radians(30.0)).score
    assert 0.0 < low < 0.8
    assert high >= 2.0
    scores = [_evidence(math.radians(a)).score for a in (0.0, 5.0, 10.0, 20.0, 40.0, 90.0)]
    assert scores[0] == pytest.approx(0.0, abs=1e-12) and all(np.diff(scores) > 0)
    # linear in the tilt (the docstring's sum of terms): twice the tilt, twice the term
    assert _evidence(0.4).score == pytest.approx(2.0 * _evidence(0.2).score, rel=1e-12)
    # additive on top of another term: a negative thrust gain adds its penalty, the tilt term is unchanged
    a, b = _evidence(0.3), _evidence(0.0)
    a.thrust_gain = b.thrust_gain = -1.0
    assert a.score - b.score == pytest.approx(_evidence(0.3).score, rel=1e-12)


# ------------------------------------------------------------------------ M12: idle at either end of a log


def _thrust(values):
    from vtol_impedance.logs.timeseries import Signal

    t = np.arange(len(values)) * 0.01
    return Signal("thrust", "thrust_n", t, np.asarray(values, float)[:, None], hold=True)


def test_idle_before_take_off_and_after_landing_are_kept_and_the_same_value_mid_flight_is_a_frozen_logger():
    """``check_thrust_signal``: a repeated value "at either end of the log, under half the usual level, is the
    vehicle idling before take-off or after landing, kept". Zeros before take-off make the column's minimum 0,
    so a steady 3.5 N after landing sits above the idle floor (a fifth of the usual ~12 N) and below half of
    it: every row is kept, with no "froze" note. The same holds for 3.5 N before take-off with zeros after
    landing. The same 3.5 N held for 3 s in the middle of the flight is not at an end: a frozen logger."""
    from vtol_impedance.logs.checks import check_thrust_signal

    flying = 11.8 + 0.3 * np.sin(np.arange(500) * 0.05)
    landed = np.concatenate([np.zeros(200), flying, np.full(300, 3.5)])
    notes: list[str] = []
    out = check_thrust_signal(_thrust(landed), notes)
    assert len(out.t) == 1000 and not any("froze" in n for n in notes), notes
    taking_off = np.concatenate([np.full(300, 3.5), flying, np.zeros(200)])
    notes = []
    out = check_thrust_signal(_thrust(taking_off), notes)
    assert len(out.t) == 1000 and not any("froze" in n for n in notes), notes
    middle = np.concatenate([np.zeros(100), flying[:250], np.full(300, 3.5), flying[250:], np.zeros(100)])
    notes = []
    out = check_thrust_signal(_thrust(middle), notes)
    assert len(out.t) == 1000 - 299 and any("froze" in n for n in notes), notes


# ------------------------------------------------------------------------------ M18: ArduPlane, Q_ENABLE 0


def test_an_arduplane_with_q_enable_zero_is_a_fixed_wing_and_refused():
    """Module docstring of ``logs.airframe``: ArduPilot's ``Q_ENABLE`` marks a QuadPlane; a fixed wing is
    refused. ``Q_ENABLE = 0`` (the parameter present, the VTOL part off) is a fixed wing, from the firmware
    name and from a HEARTBEAT of type 1 alike, and ``check_airframe`` refuses it; ``Q_ENABLE = 1`` is a VTOL."""
    from vtol_impedance.logs.airframe import check_airframe, classify

    for meta in ({"firmware": "ArduPlane V4.5.0"}, {"mav_type": 1}):
        kind = classify(meta, {"Q_ENABLE": 0.0})
        assert kind is not None and kind[0] == "other", (meta, kind)
        with pytest.raises(InputError, match="fixed wing"):
            check_airframe(meta, {"Q_ENABLE": 0.0})
        assert classify(meta, {"Q_ENABLE": 1.0})[0] == "vtol"


# ------------------------------------------------------------------------------ M46, M47: resuming a sweep

TINY = {"name": "tiny", "base": "case-a-payload", "controllers": ["pd"], "seeds": 1, "seed": 3, "chunk": 1,
        "set": {"trajectory": {"hover_duration": 1.0}}, "axes": {"payload.mass": [0.05, 0.15]}}  # fmt: skip


def _strip_metadata(src, dst):
    """The chunk file ``src`` rewritten at ``dst`` without its metadata (as an older version wrote it)."""
    import pyarrow.parquet as pq

    pq.write_table(pq.read_table(src).replace_schema_metadata(None), dst)


def test_a_chunk_whose_axis_values_are_another_sweeps_is_rejected_on_resume(tmp_path):
    """``SweepFolder.missing``/``_chunk_ok``: a chunk counts as done only if "its rows are this chunk's units,
    seeds, controllers and parameter values"; a foreign one is "moved to rejected/ with a note, and its chunk
    computed again". A chunk from a sweep with the same units and seeds but another payload mass, its
    metadata gone (so only the values can tell), is rejected and recomputed; this sweep's own chunk without
    metadata is kept (the values match)."""
    import pyarrow.parquet as pq

    from vtol_impedance.sweeps import from_dict, read_dataset, run_sweep

    out, other = tmp_path / "s", tmp_path / "o"
    run_sweep(from_dict(TINY), out, show_progress=False)
    reference = read_dataset(out).to_pydict()
    run_sweep(from_dict({**TINY, "axes": {"payload.mass": [0.07, 0.15]}}), other, show_progress=False)
    c0, c1 = out / "chunks" / "chunk-000000.parquet", out / "chunks" / "chunk-000001.parquet"
    foreign = pq.read_table(other / "chunks" / c0.name).to_pydict()
    assert foreign["unit"] == reference["unit"][:1] and foreign["seed"] == reference["seed"][:1]  # same flights
    _strip_metadata(other / "chunks" / c0.name, c0)  # same name, same units, another sweep's mass
    _strip_metadata(c1, c1)  # this sweep's own values, no metadata
    _, computed = run_sweep(from_dict(TINY), out, show_progress=False)
    assert computed == 1
    assert sorted(p.name for p in (out / "rejected").iterdir()) == [c0.name]
    assert read_dataset(out).to_pydict()["payload.mass"] == reference["payload.mass"] == [0.05, 0.15]


def test_a_lost_traces_file_makes_its_chunk_computed_again(tmp_path):
    """Module docstring of ``sweeps.run``: a resumed run "computes only the chunks whose files are missing",
    and a sweep that keeps traces writes ``traces/chunk-*.parquet`` for each chunk. A finished sweep with
    one traces file deleted recomputes that chunk (and only it), and the file is back with the same content
    (every unit's seed depends only on the sweep seed and its indices)."""
    import pyarrow.parquet as pq

    from vtol_impedance.sweeps import from_dict, run_sweep

    spec = {**TINY, "traces": 10}
    out = tmp_path / "s"
    _, computed = run_sweep(from_dict(spec), out, show_progress=False)
    assert computed == 2
    lost = out / "traces" / "chunk-000001.parquet"
    before = pq.read_table(lost).to_pydict()
    lost.unlink()
    _, computed = run_sweep(from_dict(spec), out, show_progress=False)
    assert computed == 1 and lost.exists()
    assert pq.read_table(lost).to_pydict() == before
    _, computed = run_sweep(from_dict(spec), out, show_progress=False)
    assert computed == 0  # nothing missing now


# ---------------------------------------------------------------------------- M57: a clock jump of 23 days


def test_a_clock_jump_of_23_days_is_refused_with_its_size_and_place(tmp_path):
    """``Evidence``: the time stamps must span less than 10 days (no flight lasts that long); a log whose
    clock jumps by 2e6 s (23 days) after 10 s at 100 Hz is refused, and the message says "jump by 2e+06 s at
    t = 9.99 s" (every signal runs at 100 Hz, so it is a jump, not a wrong unit). A jump of 1e5 s (1.2 days)
    keeps the span under 10 days and is not refused for its time base."""
    from vtol_impedance.logs import estimate_file, read_any

    fl = S.flight(20.0, 100.0)
    cols = csv_cols(fl)
    at = np.arange(len(cols["t_s"])) >= 1000
    cols["t_s"] = np.where(at, cols["t_s"] + 2e6, cols["t_s"])
    path = write_csv(tmp_path / "joined.csv", cols)
    with pytest.raises(InputError, match=r"jump by 2e\+06 s at t = 9\.99 s .*split the file there"):
        estimate_file(path, mass=S.MASS, inertia=S.INERTIA)
    short = csv_cols(fl)
    short["t_s"] = np.where(at, short["t_s"] + 1e5, short["t_s"])
    try:
        read_any(write_csv(tmp_path / "short.csv", short))
    except InputError as exc:  # refused for another reason (a gap) is fine; never for the time base
        assert "jump by" not in str(exc) and "time base" not in str(exc), str(exc)


# ------------------------------------------------------------- M58: the causal filter restarts per segment


def test_the_causal_estimate_restarts_from_rest_at_every_segment():
    """``series.causal``: "G(z) applied to the residual from rest at every segment start", the segment's
    first residual taken as 0 (no previous sample). With a constant residual ``c`` from the segment's second
    sample on, the zero-order-hold discretisation of eq. (10) (zeta = 1) gives exactly the continuous step
    response at the samples: ``r_j = c (1 - (1 + wn j Ts) exp(-wn j Ts))``, ``j`` counted from each segment's
    start. So r is 0 at every restart and follows that curve after it, whatever came before."""
    from vtol_impedance.estimator.momentum import EstimatorParams, design
    from vtol_impedance.estimator.series import causal

    wn, Ts, N = 10.0, 0.01, 400
    des = design(EstimatorParams(wn=wn, zeta=1.0), Ts)
    c = np.array([1.0, -2.0, 3.0, 0.1, -0.2, 0.3])
    w = np.tile(c, (N, 1))
    restart = np.zeros(N, bool)
    starts = [0, 150, 230]
    restart[starts] = True
    r = causal(des, w, restart)
    ends = starts[1:] + [N]
    for a, b in zip(starts, ends, strict=True):
        tj = np.arange(b - a) * Ts
        expected = c * (1.0 - (1.0 + wn * tj) * np.exp(-wn * tj))[:, None]
        np.testing.assert_allclose(r[a:b], expected, atol=1e-10, err_msg=f"segment from {a}")
        assert np.all(r[a] == 0.0)
    # a segment that starts on a different history gives the same: a step of another size before it
    w2 = w.copy()
    w2[:150] *= -5.0
    np.testing.assert_allclose(causal(des, w2, restart)[150:], r[150:], atol=1e-12)


# ------------------------------------------------------------ M61: a mirrored thrust against the rotors


def test_a_thrust_mirrored_about_its_mean_fails_the_rotor_speed_test(tmp_path):
    """``verdict._rotors``: the thrust command against the rotors' sum of squared speeds by a least-squares
    scale; "a negative scale fails". A flight logged with its rotor speeds right (thrust and moments through
    the X geometry and k_T) passes; the same flight with the thrust column mirrored about its mean
    (2 mean - u: it falls when the rotors speed up) fits the rotors perfectly but with a negative scale, and
    must fail "thrust against rotor speeds" (the verdict is refused)."""
    from vtol_impedance.logs import read_any, resample
    from vtol_impedance.logs.verdict import judge

    fl = S.flight(20.0, 100.0)
    cols = csv_cols(fl)
    w = rotor_speeds(fl.thrust, fl.tau_B) * 60 / (2 * np.pi)
    cols.update({f"rpm{i + 1}": w[:, i] for i in range(4)})
    raw, _ = read_any(write_csv(tmp_path / "rotors.csv", cols))
    f = resample(raw, 100.0)
    assert f.rotor_speed is not None

    def rotor_test(flight):
        v = judge(flight, f.thrust, S.MASS)
        (t,) = [t for t in v.tests if t.name == "thrust against rotor speeds"]
        return v, t

    v, t = rotor_test(f)
    assert t.status == "pass"
    mirrored = replace(f, thrust=2.0 * np.mean(f.thrust) - f.thrust)
    v, t = rotor_test(mirrored)
    assert t.status == "fail" and v.outcome == "refused", (t, v.outcome)


# --------------------------------------------------------------- M35: the NumPy backend's sensor noise


def test_the_sensor_model_adds_each_groups_own_sigma():
    """``sensors.measurement``: the report is the truth "plus sigma [pos, vel, att, gyro] * noise (..., 12)",
    the noise ordered position, velocity, attitude, gyro. With four different sigmas and a known noise
    vector, each group moves by its own sigma times its own three numbers: the attitude by att_noise, the
    gyro (recovered from the reported Euler rates, omega = Q(eta) eta_dot) by gyro_noise."""
    from vtol_impedance.model import load_preset
    from vtol_impedance.model.kinematics import euler_rate_matrix_Q
    from vtol_impedance.sim import PlantParams
    from vtol_impedance.sim.plant import OMEGA, compile_plants, initial_state
    from vtol_impedance.sim.sensors import measurement

    P = compile_plants(PlantParams(load_preset(), ground=False))
    x = np.asarray(initial_state(P, np.array([0.0, 0.0, -1.0]), np.array([0.1, -0.2, 0.3])), dtype=float)
    x = x.reshape(-1, x.shape[-1])[0].copy()
    x[OMEGA] = [0.1, -0.2, 0.05]
    sigma = np.array([1e-3, 2e-3, 5e-3, 2e-2])
    noise = np.arange(1.0, 13.0) / 10.0 * np.array([1, -1, 1] * 4)
    clean = measurement(P, x, x)
    noisy = measurement(P, x, x, sigma, noise)
    np.testing.assert_allclose(noisy.p_W - clean.p_W, sigma[0] * noise[0:3], atol=1e-15)
    np.testing.assert_allclose(noisy.v_W - clean.v_W, sigma[1] * noise[3:6], atol=1e-15)
    np.testing.assert_allclose(noisy.eta - clean.eta, sigma[2] * noise[6:9], atol=1e-15)
    omega = euler_rate_matrix_Q(noisy.eta) @ noisy.eta_dot
    np.testing.assert_allclose(omega - x[OMEGA], sigma[3] * noise[9:12], atol=1e-12)


def test_numpy_backend_attitude_noise_is_the_stated_gaussian():
    """The NumPy backend's twin of the compiled test: with no latency, the measured minus the true
    position, velocity and attitude divided by their stated sigmas must be standard normals (mean 0,
    deviation 1, white) on every axis; the attitude sigma (5e-3) differs from the gyro's (2e-2) by 4 times,
    so noise drawn with the wrong one shows."""
    from vtol_impedance.control import ControllerParams
    from vtol_impedance.control.reference import Hold, Trajectory
    from vtol_impedance.model import load_preset
    from vtol_impedance.sim import PlantParams, SensorParams, run_closed_loop

    sens = SensorParams(pos_noise=2e-3, vel_noise=1e-2, mocap_delay=0.0, att_noise=5e-3, gyro_noise=2e-2, imu_delay=0.0)
    traj = Trajectory((Hold((0, 0, -1.0), 3.0),))
    r = run_closed_loop([PlantParams(load_preset(), ground=False)], [ControllerParams.paper("pdc")], traj, 3.0,
                        sensors=sens, seed=[7], backend="numpy")  # fmt: skip
    for meas, true, sigma in (("p_meas_W", "p_W", 2e-3), ("v_meas_W", "v_W", 1e-2), ("eta_meas", "eta", 5e-3)):
        n = (r[meas] - r[true])[0] / sigma  # (N, 3): standard normals if all is right
        N = n.shape[0]
        assert np.all(np.abs(n.std(axis=0) - 1.0) < 4.0 / np.sqrt(2 * N)), (meas, n.std(axis=0))
        assert np.all(np.abs(n.mean(axis=0)) < 4.0 / np.sqrt(N)), meas
        lag1 = np.mean(n[1:] * n[:-1], axis=0)
        assert np.all(np.abs(lag1) < 4.0 / np.sqrt(N)), meas


# ----------------------------------------------------------------------------- M37, M40: disturbances


def test_the_fan_jet_follows_its_documented_force_law():
    """``FanJet``: force along the jet ``mean_force * ref_distance / max(s, ref_distance / 2) * exp(-r^2 /
    (2 width^2))`` (no turbulence), ``s`` along the jet and ``r`` off its axis; nothing behind the fan or
    before ``t_on``; the moment is ``cop_offset_B x f_B``. Worked by hand for a fan at (1, 2, -1) blowing
    along +y (given unnormalised)."""
    from vtol_impedance.sim.disturbances import FanJet

    F, d0, wdt = 0.8, 0.2, 0.25
    fan = FanJet(position_W=(1.0, 2.0, -1.0), direction_W=(0.0, 3.0, 0.0), mean_force=F, ref_distance=d0,
                 width=wdt, turbulence=0.0, cop_offset_B=(0.0, 0.0, -0.05), t_on=1.0)  # fmt: skip
    base = np.array([1.0, 2.0, -1.0])
    pts = np.array([
        base + [0.0, 0.05, 0.0],  # on the axis, in the near field (s < d0 / 2): held at 2 F
        base + [0.0, d0, 0.0],  # on the axis at the reference distance: F
        base + [0.0, 0.6, 0.0],  # on the axis at 3 d0: F / 3
        base + [wdt, 0.6, 0.0],  # r = width off the axis at 3 d0: F / 3 exp(-1/2)
        base + [0.0, 0.6, 2 * wdt],  # r = 2 width: F / 3 exp(-2)
        base + [0.0, -0.3, 0.0],  # behind the fan: nothing
    ])  # fmt: skip
    expected = np.array([2 * F, F, F / 3, F / 3 * math.exp(-0.5), F / 3 * math.exp(-2.0), 0.0])
    R = np.broadcast_to(np.eye(3), (len(pts), 3, 3))
    f, tau = fan(2.0, pts, np.zeros_like(pts), R)
    np.testing.assert_allclose(f[:, 1], expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(f[:, [0, 2]], 0.0, atol=1e-15)
    # level body: f_B = f_W; cop (0, 0, -0.05) x (0, fy, 0) = (0.05 fy, 0, 0)
    np.testing.assert_allclose(tau, np.column_stack([0.05 * expected, 0 * expected, 0 * expected]), atol=1e-15)
    f0, tau0 = fan(0.5, pts, np.zeros_like(pts), R)  # before t_on
    assert np.all(f0 == 0.0) and np.all(tau0 == 0.0)


def test_a_push_is_a_half_sine_with_the_documented_impulse():
    """``Push``: "a half-sine force pulse of peak force_W from t_on lasting duration". With duration 2.5 s from
    t_on = 4 s it is 0 before 4 s, peaks at the full force at 4 + 1.25 s, is 0 from 6.5 s on, and its impulse
    (the force integrated over time by quadrature) is 2 F d / pi, the integral of F sin(pi t / d) over d."""
    import scipy.integrate

    from vtol_impedance.sim.disturbances import Push

    F, d, t_on = np.array([3.0, -1.0, 0.5]), 2.5, 4.0
    push = Push(force_W=tuple(F), torque_B=(0.0, 0.0, 0.0), t_on=t_on, duration=d)
    p, z = np.zeros(3), np.zeros(3)

    def force(t):
        return np.asarray(push(t, p, z, np.eye(3))[0])

    np.testing.assert_allclose(force(t_on + d / 2), F, rtol=1e-12)
    for t in (0.0, t_on - 0.01, t_on, t_on + d, t_on + d + 0.01, 20.0):
        np.testing.assert_allclose(force(t), 0.0, atol=1e-12, err_msg=str(t))
    np.testing.assert_allclose(force(t_on + d / 6), 0.5 * F, rtol=1e-9)  # sin(pi / 6)
    # the peak is the largest value: a finer grid around it finds nothing higher
    ts = np.linspace(t_on, t_on + d, 2001)
    mags = np.array([force(t)[0] for t in ts])
    assert ts[np.argmax(mags)] == pytest.approx(t_on + d / 2, abs=d / 2000)
    for i in range(3):
        J, _ = scipy.integrate.quad(lambda t, i=i: force(t)[i], 0.0, 10.0, points=[t_on, t_on + d], limit=200)
        assert J == pytest.approx(2.0 * F[i] * d / math.pi, rel=1e-8)


# ----------------------------------------------------------------------------- M41: the metrics window


def _result(t: np.ndarray, window):
    from vtol_impedance.sim.result import Result

    n = len(t)
    z3 = np.zeros((1, n, 3))
    data = {k: z3.copy() for k in ("p_W", "p_ref_W", "v_W", "v_ref_W", "f_hat_W", "f_lumped_W", "tau_hat_eta",
                                   "tau_lumped_eta")}  # fmt: skip
    data["saturated"] = np.zeros((1, n))
    return Result(t, ["pd"], data, {"window": list(window)}, [None])


def test_a_callers_window_on_two_samples_measures_those_samples_not_the_whole_run():
    """``result._check``: a window the caller gives "must hold two samples of the run (the fallback to the
    whole run is for the stored window of a run cut short, not for a caller's)". A window from one sample time
    to the next is either refused or measures exactly those two samples: it never silently becomes the
    whole run. And ``window_mask_of`` falls back to the whole run only when fewer than two samples are inside."""
    from vtol_impedance.sim.result import compute_metrics, window_mask, window_mask_of

    t = np.arange(41) * 0.25  # exact binary times, 0 .. 10 s
    res = _result(t, (2.0, 6.0))
    res.data["p_W"][0, :, 0] = 0.01  # 1 cm everywhere ...
    res.data["p_W"][0, 9, 0] = 0.05  # ... but 5 cm at t = 2.25 s
    for w in ((2.0, 2.25), (2.25, 2.5)):
        try:
            m = window_mask(res, w)
        except InputError:
            continue
        assert np.count_nonzero(m) == 2 and np.all(m == ((t >= w[0]) & (t <= w[1]))), w
        row = compute_metrics(res, w)[0]
        assert row["max_ep_cm"] == pytest.approx(5.0)  # the 5 cm sample is one of the two
        assert row["rms_ep_cm"] == pytest.approx(math.sqrt((1.0 + 25.0) / 2))
    # fewer than two samples: the whole run (the stored window of a run cut short)
    assert np.all(window_mask_of(t, (20.0, 30.0))) and np.all(window_mask_of(t, (2.1, 2.2)))
    assert np.all(window_mask_of(t, (2.1, 2.3)))  # one sample (2.25 s) inside: still fewer than two
    assert np.count_nonzero(window_mask_of(t, (2.1, 2.6))) == 2
