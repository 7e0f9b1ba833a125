"""Thrust from measured rotor speeds removes the rotor lag from the estimate: on the simulator's Pelican
(rotor lag 12.5 ms up, 25 ms down) flying a fast move and a fast circle, logged as CSV with the thrust command and each
rotor's speed, the estimate from the rotor speeds follows G(s) of the true wrench (the wrench with the
rotors' actual thrust: what acted on the vehicle) much more closely than the estimate from the commands.
G(s) is applied by SciPy's lsim; the numbers are those quoted in the README."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scipy.signal
from logfiles import write_csv

from vtol_impedance.estimator import EstimatorParams
from vtol_impedance.logs import estimate, read_any, resample
from vtol_impedance.model.kinematics import rotation_zyx

K_T = 8.5e-6  # N per (rad/s)^2


def _spec(flight: str):
    """The fast move: case B's vehicle (payload, fan) moving (2, 1, -0.5) m in 1.2 s; the circle: case C at
    2 m/s. Sensor latency off (a log timestamps its samples), noise on."""
    from vtol_impedance.scenarios import get

    base = get("case-b-fan" if flight == "fast move" else "case-c-circle")
    sens = replace(base.sensors, mocap_delay=0.0, imu_delay=0.0)
    if flight == "fast move":
        traj = replace(base.trajectory, hover_duration=4.0, move_offset=(2.0, 1.0, -0.5), move_duration=1.2,
                       move_hold=4.0)  # fmt: skip
        return replace(base, trajectory=traj, sensors=sens, duration=14.0)
    return replace(base, trajectory=replace(base.trajectory, circle_speed=2.0), sensors=sens, duration=30.0)


@pytest.fixture(scope="module", params=["fast move", "circle"])
def flight_log(request, tmp_path_factory):
    from vtol_impedance.scenarios import simulate

    r = simulate(_spec(request.param), ["pd"])
    t = r.t
    thrust = r["thrust"][0]
    f_rotor = r["f_rotor"][0]
    # what acted: the lumped wrench with the rotors' actual thrust instead of the command held over the period
    b = rotation_zyx(r["eta"][0])[:, :, 2]
    prev = np.concatenate([thrust[:1], thrust[:-1]])
    f_true = r["f_lumped_W"][0] + (f_rotor.sum(-1) - prev)[:, None] * b
    sys_g = scipy.signal.lti([100.0], [1.0, 20.0, 100.0])  # G(s) of eq. (10), wn = 10, zeta = 1
    g = np.stack([scipy.signal.lsim(sys_g, f_true[:, j], t)[1] for j in range(3)], -1)
    rpm = np.sqrt(np.maximum(f_rotor, 0.0) / K_T) * 60 / (2 * np.pi)
    cols = {"t_s": t, **{k: r["v_meas_W"][0][:, i] for i, k in enumerate(("vx", "vy", "vz"))}}
    cols.update({k: r["eta_meas"][0][:, i] for i, k in enumerate(("roll", "pitch", "yaw"))})
    cols.update({k: r["omega_B"][0][:, i] for i, k in enumerate(("wx", "wy", "wz"))})
    cols.update(thrust_n=thrust, **{f"rpm{i + 1}": rpm[:, i] for i in range(rpm.shape[1])})
    path = write_csv(tmp_path_factory.mktemp("lag") / "flight.csv", cols)
    raw, _ = read_any(path)
    return request.param, resample(raw, 100.0), g, t


def _errors(e, g, t):
    err = np.linalg.norm(e.f_W - np.stack([np.interp(e.t, t, g[:, j]) for j in range(3)], -1), axis=-1)
    sel = e.t > 6.0  # the hover before the move, the move and the hold after it
    return float(np.median(err[sel])), float(np.percentile(err[sel], 95))


def test_rotor_speeds_remove_the_rotor_lag(flight_log):
    flight, f, g, t = flight_log
    med_c, p95_c = _errors(estimate(f, 1.2, None, thrust_from="commands"), g, t)
    lagged = estimate(f, 1.2, None, EstimatorParams(rotor_tau=0.019), thrust_from="commands")
    med_m, p95_m = _errors(lagged, g, t)  # the commands through the estimator's own rotor model
    known = estimate(f, 1.2, None, thrust_from="rotors", thrust_coefficient=K_T)
    med_k, p95_k = _errors(known, g, t)
    matched = estimate(f, 1.2, None)  # auto: the rotor speeds, k_T matched to the commands in calm flight
    assert "matched to the commanded thrust" in matched.info["thrust"]
    assert abs(matched.info["thrust_coefficient"] / K_T - 1) < 0.01
    med_a, p95_a = _errors(matched, g, t)
    # measured (README), median / 95th percentile: fast move: commands 0.029 / 0.48 N, with the 19 ms rotor
    # model 0.029 / 0.36 N, rotor speeds with k_T known 0.013 / 0.061 N, with k_T matched 0.027 / 0.080 N;
    # circle: 0.029 / 0.056, 0.029 / 0.051, 0.012 / 0.022, 0.030 / 0.040 N
    assert med_k < 0.6 * med_c and p95_k < 0.5 * p95_c
    assert p95_a < 0.8 * p95_c
    if flight == "fast move":
        assert p95_k < 0.25 * p95_c and p95_a < 0.3 * p95_c and med_a < med_c
        assert p95_m > 2 * p95_a  # a first-order model of the commands does not reach the measured speeds
    print(flight, [round(x, 3) for x in (med_c, p95_c, med_m, p95_m, med_k, p95_k, med_a, p95_a)])


def test_thrust_coefficient_fitted_on_a_tilted_flight():
    """Rotor speeds of a vehicle held at 0.3 rad of roll and 0.2 of pitch by a side force, bobbing 0.3 m/s
    vertically: ``k_T sum w^2 cos(phi) cos(theta) = m (g - a_z)`` gives back k_T (without the tilt it would
    be off by 1/cos, 6 %)."""
    from vtol_impedance.logs.rotors import fit_thrust_coefficient

    t = np.arange(0.0, 20.0, 0.01)
    m, k_T, phi, theta = 1.2, 8e-6, 0.3, 0.2
    v_z = 0.3 * np.sin(t)
    sq_sum = m * (9.81 - 0.3 * np.cos(t)) / (k_T * np.cos(phi) * np.cos(theta))
    eta = np.column_stack([np.full_like(t, phi), np.full_like(t, theta), np.zeros_like(t)])
    v_W = np.column_stack([np.zeros_like(t), np.zeros_like(t), v_z])
    k, res = fit_thrust_coefficient(t, v_W, eta, sq_sum, m, np.ones(len(t), bool))
    assert k == pytest.approx(k_T, rel=1e-4) and res < 1e-3


def test_commands_that_cannot_calibrate_the_rotors_say_what_the_fit_loses(tmp_path):
    """The shipped CSV sample carries a payload (+z in NED) and rotor speeds with normalised thrust and its
    hover thrust. One hover-thrust sample of 0 spoils the commands' calibration: the thrust coefficient is
    then fitted on the vertical balance, which takes the payload's weight into the thrust, and the
    estimate says so in its warnings instead of quietly reporting no load."""
    import csv
    from importlib import resources

    rows = list(csv.reader(open(resources.files("vtol_impedance.logs.samples") / "flight.csv")))
    clean = estimate(resample(read_any(write_csv(tmp_path / "clean.csv", _columns(rows)))[0], 100.0), 1.2, None)
    rows[400][rows[0].index("hover_thrust")] = "0"
    spoilt = estimate(resample(read_any(write_csv(tmp_path / "spoilt.csv", _columns(rows)))[0], 100.0), 1.2, None)
    assert np.mean(clean.f_W[:, 2]) > 0.5 and abs(np.mean(spoilt.f_W[:, 2])) < 0.2  # the load is gone
    assert not any("could not calibrate" in w for w in clean.warnings)
    (w,) = [w for w in spoilt.warnings if "could not calibrate" in w]
    assert "hover thrust 0..0" in w and "payload's weight" in w and "--thrust-coefficient" in w


def _columns(rows: list[list[str]]) -> dict[str, np.ndarray]:
    return {name: np.array([float(r[i]) for r in rows[1:]]) for i, name in enumerate(rows[0])}


def test_a_window_too_short_to_estimate_is_named(tmp_path, capsys):
    """--start/--end keeping 0.3 s of the shipped sample: a clear refusal naming the span (it was an
    IndexError inside the rotor calibration's half-second average)."""
    from importlib import resources

    from vtol_impedance.cli import main

    path = str(resources.files("vtol_impedance.logs.samples") / "flight.csv")
    t0 = float(open(path).readlines()[1].split(",")[0])
    args = ["estimate", path, "--mass", "1.2", "--no-plots", "--quiet", "--out", str(tmp_path / "o")]
    assert main([*args, "--start", str(t0), "--end", str(t0 + 0.3)]) == 2
    err = capsys.readouterr().err
    assert "holds 0.29 s of flight in the window --start/--end" in err and "at least 1 s" in err
    assert "internal error" not in err and not (tmp_path / "o").exists()
    assert main([*args, "--start", str(t0), "--end", str(t0 + 1.5)]) == 0


def test_two_logs_of_one_name_get_two_default_folders(tmp_path, monkeypatch):
    """``results/estimate-flight`` holds the estimate of one ``flight.csv``; another file of that name from
    another folder gets a folder of its own, and re-estimating the first replaces its own."""
    import shutil
    from importlib import resources

    from vtol_impedance.cli import main

    src = resources.files("vtol_impedance.logs.samples") / "flight.csv"
    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        shutil.copy(src, tmp_path / d / "flight.csv")
    monkeypatch.chdir(tmp_path)
    args = ["--mass", "1.2", "--no-plots", "--quiet"]
    for d in ("a", "b", "a"):
        assert main(["estimate", f"{d}/flight.csv", *args]) == 0
    folders = sorted(p.name for p in (tmp_path / "results").iterdir())
    assert len(folders) == 2 and folders[0] == "estimate-flight" and folders[1].startswith("estimate-flight+")
    import json

    files = {json.loads((tmp_path / "results" / f / "estimate.json").read_text())["info"]["file"] for f in folders}
    assert files == {"a/flight.csv", "b/flight.csv"}
