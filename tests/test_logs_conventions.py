"""Conventions checked against physics: every wrong convention of a CSV log is refused with the flag that
fixes it, ``--conventions auto`` finds it, a log whose format fixes its conventions is refused when its
data contradict physics, and the other kinds of bad input (a thrust column of zeros, held or frozen, a
negative or percentage thrust, a non-symmetric inertia, a quiet segment outside the log, a nonsense
hover fit, a vehicle that never flies, a thrust that does not carry the weight).

The flight is ``synthflight`` (Newton-Euler with a known wrench); the expected estimate is the continuous
G(s) of eq. (10) applied to the true wrench."""

from __future__ import annotations

import re

import numpy as np
import pytest
import synthflight as S
from logfiles import HOVER, csv_cols, write_csv
from ulog_writer import write_ulog

from vtol_impedance.cli import main
from vtol_impedance.errors import InputError
from vtol_impedance.logs import estimate, estimate_file, read_any, resample
from vtol_impedance.logs.checks import check_thrust_signal
from vtol_impedance.logs.estimate import check_inertia, fit_hover_thrust
from vtol_impedance.logs.timeseries import RawLog, Signal
from vtol_impedance.model.kinematics import quat_from_euler

EVERY = 2  # 125 Hz rows: the checks try every reading of the file, keep it short


@pytest.fixture(scope="module")
def fl():
    return S.flight()


@pytest.fixture(scope="module")
def truth_late(fl):
    """G(s) applied to the true force, late in the flight (after the 1 N step has settled)."""
    t = fl.t[::EVERY]
    g = S.g_response(t, S.f_ext_of)
    late = t > 10.0
    return g[late].mean(0)


# (label, how the file was written, declared flags, the fix the error must name, the auto field: value)
WRONG = [
    ("quaternion x y z w read as w x y z", dict(quat="xyzw"), {}, "--quat-order xyzw", {"quat_order": "xyzw"}),
    ("world-to-body quaternion read as body-to-world", dict(quat="wxyz", qdir="world-to-body"), {},
     "--quat-direction world-to-body", {"quat_direction": "world-to-body"}),
    ("degrees read as radians", dict(angle="deg"), {}, "--angle-unit deg", {"angle_unit": "deg"}),
    ("radians read as degrees", dict(angle="rad"), {"angle_unit": "deg"}, "--angle-unit rad", {"angle_unit": "rad"}),
    ("rates in deg/s read as rad/s", dict(rate="deg"), {}, "--rate-unit deg", {"rate_unit": "deg"}),
    ("ENU velocity read as NED", dict(vworld="enu"), {}, "--velocity-world enu", {"velocity_world": "enu"}),
    ("ENU/FLU log read as NED/FRD", dict(world="enu", body="flu", quat="wxyz"), {}, "--world enu",
     {"world": "enu", "body": "flu", "velocity_world": "enu"}),
    ("FLU body read as FRD", dict(body="flu"), {}, "--body flu", {"body": "flu"}),
    ("milliseconds read as seconds", dict(tunit="ms"), {}, "--time-unit ms", {"time_unit": "ms"}),
    ("microseconds read as seconds", dict(tunit="us"), {}, "--time-unit us", {"time_unit": "us"}),
    ("seconds read as milliseconds", dict(tunit="s"), {"time_unit": "ms"}, "--time-unit s", {"time_unit": "s"}),
]  # fmt: skip


@pytest.mark.parametrize("label, written, declared, fix, auto", WRONG, ids=[w[0] for w in WRONG])
def test_a_wrong_convention_is_refused_and_auto_finds_it(fl, tmp_path, truth_late, label, written, declared, fix,
                                                         auto):  # fmt: skip
    path = write_csv(tmp_path / "f.csv", csv_cols(fl, every=EVERY, **written))
    with pytest.raises(InputError, match="contradicts physics") as err:
        read_any(path, **declared)
    assert fix in str(err.value) and "--conventions auto" in str(err.value)
    raw, rep = read_any(path, conventions="auto", **declared)
    for k, v in auto.items():
        assert getattr(rep.chosen, k) == v, (label, rep.notes)
    assert not rep.warnings  # the flight moves enough to decide every convention
    # and the estimate read that way is the true one
    f = resample(raw, 100.0)
    e = estimate(f, S.MASS, np.diag(S.INERTIA))
    np.testing.assert_allclose(e.f_W[f.t > 10.0].mean(0), truth_late, atol=0.01)


def test_the_declared_right_conventions_pass(fl, tmp_path):
    path = write_csv(tmp_path / "ros.csv", csv_cols(fl, world="enu", body="flu", quat="xyzw", angle="deg", every=EVERY))
    raw, rep = read_any(path, world="enu", body="flu", quat_order="xyzw", angle_unit="deg")
    assert rep.chosen == rep.declared and "fit best" in rep.notes[0]


def test_a_contradicting_ulog_is_refused(fl, tmp_path):
    """PX4 fixes the conventions; a log whose quaternion was stored world-to-body by a converter is refused."""
    us = (fl.t * 1e6).astype(np.uint64) + np.uint64(1_000_000)
    q = quat_from_euler(fl.eta) * np.array([1.0, -1.0, -1.0, -1.0])  # the conjugate: world to body
    u = fl.thrust * HOVER / (S.MASS * S.G)
    topics = {
        "vehicle_local_position": {"timestamp": us[::25], "vx": fl.v_W[::25, 0], "vy": fl.v_W[::25, 1],
                                   "vz": fl.v_W[::25, 2]},
        "vehicle_attitude": {"timestamp": us, "q": q},
        "vehicle_angular_velocity": {"timestamp": us, "xyz": fl.omega_B},
        "vehicle_thrust_setpoint": {"timestamp": us, "xyz": np.stack([0 * u, 0 * u, -u], -1)},
    }  # fmt: skip
    path = write_ulog(tmp_path / "mirror.ulg", topics, {"MPC_THR_HOVER": HOVER})
    with pytest.raises(InputError, match="contradicts physics.*body rates disagree"):
        read_any(path)
    rc = main(["estimate", str(path), "--mass", "1.2", "--out", str(tmp_path / "o")])
    assert rc == 2 and not (tmp_path / "o").exists()
    raw, rep = read_any(path, conventions="unchecked")  # the escape hatch, reported
    assert "not checked" in rep.notes[0]


# ----------------------------------------------------------------------------- thrust columns


def _thrust(values, t=None):
    t = np.arange(len(values)) * 0.01 if t is None else t
    return Signal("thrust", "thrust_n", t, np.asarray(values, float)[:, None], hold=True)


def test_thrust_of_zeros_held_or_frozen():
    with pytest.raises(InputError, match="zero throughout"):
        check_thrust_signal(_thrust(np.zeros(500)), [])
    with pytest.raises(InputError, match="holds the value 11.8 throughout"):
        check_thrust_signal(_thrust(np.full(500, 11.8)), [])
    u = 11.8 + 0.3 * np.sin(np.arange(1000) * 0.05)
    u[300:520] = u[300]  # the logger froze it for 2.2 s
    notes: list[str] = []
    s = check_thrust_signal(_thrust(u), notes)
    assert len(s.t) == 1000 - 219 and "froze" in notes[0]
    assert not np.any((s.t > 3.0) & (s.t < 5.2))  # the frozen stretch became a gap
    # idle on the ground (the column's minimum) and whole-percent steps are honest repeats
    idle = np.concatenate([np.zeros(300), u[300:]])
    assert len(check_thrust_signal(_thrust(idle), []).t) == 1000 - 219  # only the frozen stretch again
    pct = np.round(50 + 5 * np.sin(np.arange(1000) * 0.01)) / 100
    assert len(check_thrust_signal(_thrust(pct), []).t) == 1000
    # a PX4 vehicle idling after landing (armed, a steady idle thrust above zero) is kept, not "frozen";
    # a value held to the end at the flying level is a frozen logger
    flying = 11.8 + 0.3 * np.sin(np.arange(1000) * 0.05)
    landed = np.concatenate([flying[:700], np.full(300, 3.5)])
    notes = []
    assert len(check_thrust_signal(_thrust(landed), notes).t) == 1000 and not notes
    stuck = np.concatenate([flying[:700], np.full(300, flying[700])])  # at the flying level to the end: frozen
    assert len(check_thrust_signal(_thrust(stuck), []).t) == 1000 - 299


def test_a_noise_free_steady_state_is_not_a_frozen_logger():
    """A simulator's log holds its thrust exactly while the vehicle hovers or flies straight: over such a
    stretch the logged motion is as steady as the thrust, so it is kept; with an IMU's noise on the same
    motion, or with the vehicle accelerating unevenly, the repeated thrust is a frozen logger (a dropout)."""
    t = np.arange(1000) * 0.01
    u = 11.8 + 0.3 * np.sin(t * 5.0)
    u[300:520] = u[300]  # 2.2 s repeated
    still = (t >= 3.0) & (t <= 5.19)

    def motion(v_W, omega_B):
        return (Signal("velocity_W", "v", t, v_W), Signal("omega_B", "w", t, omega_B))

    v = np.column_stack([np.sin(t), np.cos(t), 0.1 * t])
    w = np.column_stack([np.sin(2 * t), 0 * t, np.cos(t)])
    v[still] = [0.5, -0.2, 0.0]  # hovering, or straight and level at constant speed
    w[still] = 0.0
    notes: list[str] = []
    assert len(check_thrust_signal(_thrust(u), notes, motion(v, w)).t) == 1000
    assert "steady state" in notes[0] and "froze" not in " ".join(notes)
    ramp = v.copy()  # a constant acceleration at a constant attitude is as steady
    ramp[still, 2] = 0.3 + 0.5 * (t[still] - 3.0)
    assert len(check_thrust_signal(_thrust(u), [], motion(ramp, w)).t) == 1000
    rng = np.random.default_rng(0)
    bob = v.copy()
    bob[still, 2] += 1e-2 * np.sin(40 * t[still])  # moving while the thrust stays put
    row = np.where(still[:, None], v, v + 1e-3 * rng.standard_normal(v.shape))  # a noisy log's whole row frozen
    for bad_v, bad_w in (
        (v + 1e-3 * rng.standard_normal(v.shape), w),  # a real log's noise on the velocity
        (v, w + 2e-3 * rng.standard_normal(w.shape)),  # or on the gyro
        (bob, w),
        (row, w),
    ):
        notes = []
        assert len(check_thrust_signal(_thrust(u), notes, motion(bad_v, bad_w)).t) == 1000 - 219
        assert "froze" in notes[0]
    sparse = (Signal("velocity_W", "v", t[::150], v[::150]), Signal("omega_B", "w", t[::150], w[::150]))
    assert len(check_thrust_signal(_thrust(u), [], sparse).t) == 1000 - 219  # under three samples: not shown still


def test_thrust_columns_of_zeros_and_negated_thrust_from_a_file(fl, tmp_path):
    cols = csv_cols(fl, every=EVERY)
    with pytest.raises(InputError, match="zero throughout"):
        read_any(write_csv(tmp_path / "z.csv", {**cols, "thrust_n": 0 * cols["thrust_n"]}))
    raw, _ = read_any(write_csv(tmp_path / "neg.csv", {**cols, "thrust_n": -cols["thrust_n"]}), conventions="unchecked")
    with pytest.raises(InputError, match="negative.*negate"):
        estimate(resample(raw), S.MASS, None)
    pct = {k: v for k, v in cols.items() if k != "thrust_n"}
    pct["thrust_norm"] = 100 * cols["thrust_n"] * HOVER / (S.MASS * S.G)
    raw, _ = read_any(write_csv(tmp_path / "pct.csv", pct))
    with pytest.raises(InputError, match="percentage"):
        estimate(resample(raw), S.MASS, None, hover_thrust=HOVER)


def test_a_thrust_that_does_not_carry_the_weight(fl, tmp_path):
    path = write_csv(tmp_path / "f.csv", csv_cols(fl, every=EVERY))
    raw, _ = read_any(path)
    f = resample(raw)
    with pytest.raises(InputError, match="does not carry the weight.*Check the mass"):
        estimate(f, 3 * S.MASS, None)
    for scale in (1.4, 0.75):  # plausible but off: a loud warning names the mean force it implies
        e = estimate(f, scale * S.MASS, None)
        (warning,) = [w for w in e.warnings if "times the weight" in w]
        said = float(re.search(r"mean vertical force of about ([-+0-9.e]+) N", warning).group(1))
        # the thrust carries the true weight and the flight's own downward bias: m_true g - m g + bias
        assert said == pytest.approx((1 - scale) * S.MASS * S.G + S.F_BIAS[2], abs=0.1)
        assert np.median(e.f_W[:, 2]) == pytest.approx(said, abs=0.2)
    assert not estimate(f, S.MASS, None).warnings


# ----------------------------------------------------------------------------- vehicle and segments


def test_inertia_must_be_a_rigid_body():
    with pytest.raises(InputError, match=r"symmetric: I\[0,1\] = 0.001 but I\[1,0\] = 0"):
        check_inertia([[0.01, 0.001, 0], [0, 0.01, 0], [0, 0, 0.02]])
    with pytest.raises(InputError, match="triangle inequality.* by 90 % of I3; a typo or mixed units"):
        check_inertia([0.001, 0.001, 0.02])
    with pytest.raises(InputError, match=r"by 1 % of I3; .*give I3 = I1 \+ I2"):  # RotorPy's Crazyflie
        check_inertia([1.43e-5, 1.43e-5, 2.89e-5])
    with pytest.raises(InputError, match="positive definite"):
        check_inertia([0.01, -0.01, 0.02])
    np.testing.assert_array_equal(check_inertia([0.01, 0.01, 0.02]), np.diag([0.01, 0.01, 0.02]))


def test_the_force_alone_needs_no_inertia(fl, tmp_path):
    raw, _ = read_any(write_csv(tmp_path / "f.csv", csv_cols(fl, every=EVERY)))
    f = resample(raw)
    e0 = estimate(f, S.MASS, None)
    e1 = estimate(f, S.MASS, np.diag(S.INERTIA))
    assert e0.tau_B is None and e1.tau_B is not None
    np.testing.assert_allclose(e0.f_W, e1.f_W, atol=1e-12)  # eq. (8)'s force channel does not contain I_B
    assert any("force only" in n for n in e0.notes)


def test_quiet_segment_outside_the_log(fl, tmp_path):
    raw, _ = read_any(write_csv(tmp_path / "f.csv", csv_cols(fl, every=EVERY)))
    f = resample(raw)
    with pytest.raises(InputError, match="quiet segment 10-30 s.*10 % of the segment"):
        estimate(f, S.MASS, None, quiet_segment=(10.0, 30.0))
    e = estimate(f, S.MASS, None, quiet_segment=(8.0, 13.0))  # 80 % inside: used, with a loud warning
    assert any("reaches outside the log" in w for w in e.warnings)


def test_nonsense_hover_fits_are_refused(tmp_path):
    from vtol_impedance.logs import samples

    raw, _ = read_any(samples.path("px4-v1.9"))  # no hover thrust estimate: a fit is what a user would try
    f = resample(raw)
    t0 = f.t[0]
    with pytest.raises(InputError, match="not a hover: the balance changes within it"):
        fit_hover_thrust(f, samples.MASS_KG, (t0 + 0.5, t0 + 5.0))  # the take-off
    h, res = fit_hover_thrust(f, samples.MASS_KG, (t0 + 7.0, t0 + 10.0))
    assert res < 0.05 * samples.MASS_KG * S.G and 0.5 < h < 0.6  # the payload makes it heavier than 0.515
    t = np.arange(0, 20, 0.01)
    still = RawLog(
        Signal("velocity", "v", t, np.zeros((len(t), 3))),
        Signal("attitude", "e", t, np.zeros((len(t), 3))),
        Signal("body rates", "w", t, np.zeros((len(t), 3))),
        Signal("thrust", "u", t, (0.05 + 0.001 * np.sin(t))[:, None], hold=True),
        None,
        thrust_unit="normalized",
    )
    with pytest.raises(InputError, match="never seems to leave the ground"):
        fit_hover_thrust(resample(still), 1.2, (5.0, 10.0))


def test_cli_conventions_errors_exit_2_and_auto_reports(fl, tmp_path, capsys):
    path = write_csv(tmp_path / "ms.csv", csv_cols(fl, tunit="ms", every=EVERY))
    rc = main(["estimate", str(path), "--mass", "1.2", "--out", str(tmp_path / "a")])
    err = capsys.readouterr().err
    assert rc == 2 and "--time-unit ms" in err and "Traceback" not in err
    rc = main(["estimate", str(path), "--mass", "1.2", "--conventions", "auto", "--out", str(tmp_path / "b"),
               "--no-plots"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 0 and "chosen from the data" in err and "--time-unit ms" in err
    import json

    conv = json.loads((tmp_path / "b" / "estimate.json").read_text())["info"]["conventions"]
    assert conv["mode"] == "auto" and conv["chosen"]["time_unit"] == "ms"
    rc = main(["estimate", str(path), "--mass", "1.2", "--time-unit", "ms", "--out", str(tmp_path / "c"), "--no-plots"])
    assert rc == 0
    ulg = estimate_file  # noqa: F841 - the API the CLI calls
    rc = main(["estimate", "--example", "px4", "--world", "enu", "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert rc == 2 and "--world applies to CSV logs" in err and "Traceback" not in err


@pytest.mark.parametrize("rate", [10.0, 15.0])
def test_a_slow_log_is_not_read_as_milliseconds(tmp_path, rate):
    """Read in milliseconds, a 40 s log at 10 Hz lasts 0.04 s: too short to score anything, which scored a
    perfect 0 and beat the true reading ("time looks like milliseconds"). A reading that leaves nothing to
    score is never preferred to one that can be scored; the time unit is then the declared one, decided."""
    fl = S.flight(duration=40.0, rate=rate)
    raw, rep = read_any(write_csv(tmp_path / "slow.csv", csv_cols(fl)))
    assert "time_unit" not in rep.undetermined and "fit best" in rep.notes[0]
    raw, rep = read_any(write_csv(tmp_path / "slow.csv", csv_cols(fl)), conventions="auto")
    assert rep.chosen.time_unit == "s"
    ms = csv_cols(fl, tunit="ms")  # the same log in milliseconds, declared as seconds: still found out
    with pytest.raises(InputError, match="milliseconds"):
        read_any(write_csv(tmp_path / "ms.csv", ms))


def test_an_estimator_slower_than_the_log_says_so(fl, tmp_path):
    """With wn = 0.05 rad/s (5 time constants: 100 s) on a 12 s log the estimate never reaches the force
    and reads a fraction of it, which a reader takes for a small force: a warning says why."""
    from vtol_impedance.estimator import EstimatorParams

    f = resample(read_any(write_csv(tmp_path / "f.csv", csv_cols(fl, every=EVERY)))[0])
    slow = estimate(f, S.MASS, None, params=EstimatorParams(wn=0.05))
    truth = S.F_BIAS + S.F_STEP  # after the step at 5 s
    assert np.linalg.norm(slow.f_W[-1]) < 0.2 * np.linalg.norm(truth)  # the wrong-looking number
    (w,) = [w for w in slow.warnings if "never reaches the force" in w]
    assert "100 s" in w and "raise --wn" in w
    assert not any("never reaches" in w for w in estimate(f, S.MASS, None).warnings)
    # a lightly damped estimator settles on its poles' real part: wn = 1, zeta = 0.1 takes 50 s, not 5 s
    ringing = estimate(f, S.MASS, None, params=EstimatorParams(wn=1.0, zeta=0.1))
    assert any("settles in 50 s" in w for w in ringing.warnings), ringing.warnings


@pytest.mark.parametrize("cell", [1e200, -3e7])  # inf is a missing sample, as NaN (tests/test_logs.py)
def test_one_garbled_cell_is_named_by_line_and_column(fl, tmp_path, cell):
    """One absurd value in one velocity cell made the convention check compare NaN scores and print a
    self-contradicting refusal ("the data agree (score nan against nan)"). It is named by line and column."""
    cols = csv_cols(fl, every=EVERY)
    cols["vx"] = cols["vx"].copy()
    cols["vx"][299] = cell
    with pytest.raises(InputError, match=r"line 301, column 'vx': .* beyond any flight's value"):
        read_any(write_csv(tmp_path / "bad.csv", cols))
    text = (tmp_path / "bad.csv").read_text().split("\n")  # two blank lines before it: the file's own line
    (tmp_path / "blank.csv").write_text("\n".join(text[:5] + ["", ""] + text[5:]))
    with pytest.raises(InputError, match=r"line 303, column 'vx'"):
        read_any(tmp_path / "blank.csv")


def test_a_stretch_on_the_ground_is_named_and_left_out_of_the_statistics(fl, tmp_path):
    """Two flights with a pause on the ground between them: there the thrust carries nothing and the estimate
    is the ground's reaction (about -m g), which the summary's mean counted as external force (-6.2 N in a
    hunt's ArduPilot log). The stretch is named, and the statistics are those of the airborne samples."""
    from vtol_impedance.logs.output import summary

    cols = csv_cols(fl, every=EVERY)
    t = cols["t_s"]
    pause = (t > 6.0) & (t < 8.5)
    cols["thrust_n"] = np.where(pause, 0.0, cols["thrust_n"])
    est = estimate(resample(read_any(write_csv(tmp_path / "two.csv", cols), conventions="unchecked")[0]), S.MASS,
                   None)  # fmt: skip
    ((a, b),) = est.info["ground_s"]
    assert a == pytest.approx(6.0, abs=0.05) and b == pytest.approx(8.5, abs=0.05)
    assert any("the estimate there is the ground's reaction" in n for n in est.notes)
    s = summary(est)
    air = (est.t < a) | (est.t > b)  # the stretch found, checked against the true 6-8.5 s above
    np.testing.assert_allclose(s["stats"]["f_W_N"]["mean"], est.f_W[air].mean(0), atol=1e-9)
    assert s["ground_samples_left_out"] == int((~air).sum()) and est.f_W[~air, 2].mean() < -0.5 * S.MASS * 9.81
