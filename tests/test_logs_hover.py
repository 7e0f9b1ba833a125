"""The hover thrust found, not assumed; a log on the ground; a telemetry log of two vehicles; CSV column
aliases and suggestions (issue 35).

The PX4-like logs here are built by construction: a velocity profile is chosen, the thrust vector that
flies it follows from Newton's law ``T R e3 = m g e3 - m a + f_ext`` (NED), the attitude from the thrust
axis (yaw 0) and the body rates from the attitude's derivative; the thrust command is ``u = T h / (m g)``
with the true hover thrust ``h``. The external force is horizontal, so every hover's vertical balance
gives ``h`` exactly, and the true vertical force is zero everywhere in the air.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import synthflight as S
from logfiles import HOVER, csv_cols, synth_tlog_messages, write_csv
from ulog_writer import write_ulog

from vtol_impedance.cli import main
from vtol_impedance.errors import InputError
from vtol_impedance.logs import estimate_file, read_any
from vtol_impedance.logs.csvlog import ALIASES, COLUMNS
from vtol_impedance.logs.writers import write_tlog
from vtol_impedance.model.kinematics import quat_from_euler

G = 9.81
MASS = 1.2
H_TRUE = 0.36  # the older PX4 flight: the default 0.5 gave 0.72 x the weight
RATE = 100.0  # attitude and commands, Hz; velocity at 20 Hz


def _s2(x):
    return np.sin(np.clip(x, 0.0, np.pi / 2)) ** 2


def _velocity(t, cruise):
    """NED velocity, m/s: on the ground until 2 s, a climb to 4 s, hovers with small motions around a
    1.5 m/s move from 14 to 18 s (or, ``cruise``, always 2 m/s north, airborne from the start)."""
    t = np.asarray(t, float)
    if cruise:
        return np.stack([2.0 + 0.2 * np.sin(0.4 * t), 0.1 * np.sin(0.3 * t), 0.05 * np.sin(1.1 * t)], -1)
    climb = -0.6 * np.sin(np.pi * np.clip(t - 2.0, 0.0, 2.0) / 2.0) ** 2
    move = 1.5 * np.sin(np.pi * np.clip(t - 14.0, 0.0, 4.0) / 4.0) ** 2
    air = (t > 4.0).astype(float)
    vx = move + air * 0.15 * np.sin(0.5 * (t - 4.0))
    vy = air * 0.1 * np.sin(0.3 * (t - 4.0))
    vz = climb + air * 0.05 * np.sin(1.1 * (t - 4.0))
    return np.stack([vx, vy, vz], -1)


PUSH = (22.0, 25.5, 1.0)  # a vertical push (N, NED: down) from 22 to 25.5 s, in one hover window only


def _f_ext(t, push=False, pickup=None, wind=0.0, up_push=False):
    """A horizontal gusty force, N (world NED): no vertical component, unless ``push`` (:data:`PUSH`) or
    ``pickup = (t, N)``, a payload's weight from ``t`` on."""
    t = np.asarray(t, float)
    fz = PUSH[2] * ((t >= PUSH[0]) & (t < PUSH[1])) if push else 0.0 * t
    if pickup is not None:
        fz = fz + pickup[1] * (t >= pickup[0])
    if up_push:  # the mirror of PUSH, upward, in an earlier hover window
        fz = fz - PUSH[2] * ((t >= 7.5) & (t < 11.0))
    return np.stack([wind + 0.3 * np.sin(0.7 * t) + 0.1 * np.sin(2.3 * t), 0.2 * np.sin(0.45 * t), fz], -1)


def _flight(cruise=False, duration=30.0, h_true=H_TRUE, seed=1, push=False, pickup=None, wind=0.0, up_push=False):
    """``(t, v_W, eta, omega_B, u)`` of a flight by construction (module docstring), with noise."""
    t = np.arange(0.0, duration, 1.0 / RATE)
    d = 1e-5

    def thrust_vec(tt):
        a = (_velocity(tt + d, cruise) - _velocity(tt - d, cruise)) / (2 * d)
        return MASS * G * np.array([0, 0, 1.0]) - MASS * a + _f_ext(tt, push, pickup, wind, up_push)

    def eta_of(tt):
        F = thrust_vec(tt)
        n = F / np.linalg.norm(F, axis=-1, keepdims=True)
        return np.stack([-np.arcsin(n[:, 1]), np.arctan2(n[:, 0], n[:, 2]), 0 * n[:, 0]], -1)

    eta = eta_of(t)
    ed = (eta_of(t + d) - eta_of(t - d)) / (2 * d)
    omega = np.stack([ed[:, 0], np.cos(eta[:, 0]) * ed[:, 1], -np.sin(eta[:, 0]) * ed[:, 1]], -1)  # yaw 0
    T = np.linalg.norm(thrust_vec(t), axis=-1)
    if not cruise:  # on the ground until 2 s: the thrust spools up, the ground carries the rest
        ground = t < 2.0
        T[ground] = MASS * G * (0.15 + 0.8 * t[ground] / 2.0)
    rng = np.random.default_rng(seed)
    v = _velocity(t, cruise) + rng.normal(0.0, 0.01, (len(t), 3))
    u = T * h_true / (MASS * G) + rng.normal(0.0, 0.002, len(t))
    return t, v, eta, omega, u


def _px4_old(path, flight, params):
    """The flight as PX4 before 1.12 logs it: no hover_thrust_estimate, actuator_controls_0, velocity at
    20 Hz."""
    t, v, eta, omega, u = flight
    us = (t * 1e6).astype(np.uint64) + np.uint64(1_000_000)
    z = np.zeros((len(t), 4))
    topics = {
        "vehicle_local_position": {"timestamp": us[::5], "vx": v[::5, 0], "vy": v[::5, 1], "vz": v[::5, 2]},
        "vehicle_attitude": {"timestamp": us, "q": quat_from_euler(eta), "rollspeed": omega[:, 0],
                             "pitchspeed": omega[:, 1], "yawspeed": omega[:, 2]},
        "actuator_controls_0": {"timestamp": us, "control": np.column_stack([0 * u, 0 * u, 0 * u, u, z])},
    }  # fmt: skip
    return write_ulog(path, topics, params, "v1.9.2")


@pytest.fixture(scope="module")
def hover_log(tmp_path_factory):
    return _px4_old(tmp_path_factory.mktemp("hover") / "old.ulg", _flight(), {"MPC_THR_HOVER": 0.5})


# ----------------------------------------------------------------------------- hover thrust found


def test_the_hover_windows_recover_the_true_hover_thrust_and_the_z_force(hover_log):
    """PX4's default MPC_THR_HOVER (0.5) is not used: the hover windows give H_TRUE within their stated
    spread; the vertical force is then zero (its truth) in the air, where the default would have put
    ``m g (1 - H_TRUE / 0.5)`` = 3.3 N upward on it."""
    est = estimate_file(hover_log, MASS)
    h = est.info["hover_thrust"]
    assert "automatic hover window" in h["source"] and "firmware default" in h["ignored"]
    kept = [w for w in h["windows"] if w["kept"]]
    assert len(kept) >= 3
    assert 0 < h["sd"] < 0.01 * H_TRUE and abs(h["median"] - H_TRUE) <= 3 * h["sd"]
    # the windows lie in the hovers: none where the move (14-18 s) accelerates by more than 0.5 m/s^2
    # (1.5 pi / 4 sin(pi (t - 14) / 2) > 0.5 from 14.28 to 17.72 s; 0.5 s averages) or the climb's speed
    # and acceleration exceed the limits (from 2.2 s on)
    t0 = est.t[0] - 0.0
    for w in kept:
        a, b = w["t0_s"] - t0, w["t1_s"] - t0
        assert b - a >= 2.0 and (b <= 14.28 + 0.25 or a >= 17.72 - 0.25) and a >= 2.2
    air = (est.t - t0 > 5.0) & (est.t - t0 < 29.5)
    fz = est.f_W[air, 2]
    assert abs(fz.mean()) < 0.03 and np.max(np.abs(fz)) < 0.25
    # the uncertainty column: |T cos(phi) cos(theta)| sd / h, m g sd / h at hover
    cols = est.columns()
    sd_col = cols["fz_W_N_hover_sd"][air]
    assert np.median(sd_col) == pytest.approx(MASS * G * h["sd"] / h["median"], rel=0.02)
    assert h["fz_sd_at_hover_N"] == pytest.approx(MASS * G * h["sd_rel"])
    assert any("hover window" in n and "used" in n for n in est.notes)
    assert any("MPC_THR_HOVER" in n and "not used" in n for n in est.notes)
    default = estimate_file(hover_log, MASS, hover_thrust=0.5)  # what the default would have done
    assert default.f_W[air, 2].mean() == pytest.approx(-MASS * G * (1 - H_TRUE / 0.5), rel=0.02)


def test_the_cli_prints_the_windows_and_writes_the_uncertainty_column(hover_log, tmp_path, capsys):
    rc = main(["estimate", str(hover_log), "--mass", str(MASS), "--out", str(tmp_path / "o"), "--no-plots"])
    err, out = capsys.readouterr()[::-1]
    assert rc == 0 and "hover window" in err and "WARNING" not in err
    assert "vertical force uncertainty" in out
    header = (tmp_path / "o" / "wrench.csv").read_text().splitlines()[0].split(",")
    assert "fz_W_N_hover_sd" in header
    info = json.loads((tmp_path / "o" / "estimate.json").read_text())["info"]
    assert info["hover_thrust"]["windows"] and info["hover_thrust"]["sd"] > 0


def test_a_hover_segment_with_gusts_is_fitted_and_a_take_off_refused(hover_log):
    """The old 3 % residual limit refused gusty hovers; the take-off (the ground carrying part of the
    weight at first) is still refused, by the changing balance within the segment."""
    from vtol_impedance.logs import fit_hover_thrust, resample

    f = resample(read_any(hover_log)[0])
    t0 = f.t[0]
    h, _ = fit_hover_thrust(f, MASS, (t0 + 5.0, t0 + 13.0))
    assert h == pytest.approx(H_TRUE, rel=0.005)
    with pytest.raises(InputError, match="not a hover"):
        fit_hover_thrust(f, MASS, (t0 + 0.5, t0 + 5.0))


def test_a_window_with_a_vertical_force_is_an_outlier_and_the_force_is_seen(tmp_path):
    """A 1 N downward push (8.5 % of the weight) in one hover window: that window's fit is 8.5 % high, named
    as an outlier; the hover thrust stays H_TRUE and the estimate shows the push."""
    path = _px4_old(tmp_path / "push.ulg", _flight(push=True), {})
    est = estimate_file(path, MASS)
    h = est.info["hover_thrust"]
    t0 = est.t[0]
    out = [w for w in h["windows"] if not w["kept"]]
    assert len(out) == 1 and "outlier" in out[0]["why"] and out[0]["hover"] / H_TRUE - 1 > 0.05
    assert out[0]["t0_s"] - t0 < PUSH[1] and out[0]["t1_s"] - t0 > PUSH[0]
    assert abs(h["median"] - H_TRUE) <= 3 * h["sd"] and any("outlier" in n for n in est.notes)
    s = est.t - t0
    assert est.f_W[(s > PUSH[0] + 1.0) & (s < PUSH[1]), 2].mean() == pytest.approx(PUSH[2], abs=0.05)
    assert abs(est.f_W[(s > PUSH[1] + 1.0) & (s < 29.5), 2].mean()) < 0.05


def test_hover_windows_in_two_groups_are_warned_about_not_outvoted(tmp_path):
    """A 2 N payload (17 % of the weight) picked up at 21 s: the windows after it fit a hover thrust 17 %
    higher. Outvoting them in silence would hide the payload or invent one; two windows or more that
    agree on another value are a WARNING naming both values and the force they put in doubt, while one
    odd window (the push above) stays a note."""
    path = _px4_old(tmp_path / "pickup.ulg", _flight(pickup=(21.0, 2.0)), {})
    est = estimate_file(path, MASS)
    h = est.info["hover_thrust"]
    g = h["second_group"]
    assert g["n"] >= 2 and abs(min(g["hover"], h["median"]) - H_TRUE) < 0.01 * H_TRUE
    assert max(g["hover"], h["median"]) / H_TRUE - 1 == pytest.approx(2.0 / (MASS * G), abs=0.01)
    (w,) = [n for n in est.warnings if "hover windows agree" in n]
    assert "payload" in w and "--hover-segment" in w
    single = estimate_file(_px4_old(tmp_path / "push.ulg", _flight(push=True), {}), MASS)
    assert "second_group" not in single.info["hover_thrust"]
    assert not any("hover windows agree" in n for n in single.warnings + single.notes)
    # a push down in one window and up in another: two outliers, on either side, do not agree
    # (two pushes in five windows with vertical motion: the verdict would refuse it, the windows are the point)
    both = estimate_file(_px4_old(tmp_path / "both.ulg", _flight(push=True, up_push=True), {}), MASS, force=True)
    odd = [w for w in both.info["hover_thrust"]["windows"] if "outlier" in w.get("why", "")]
    assert len(odd) == 2 and (odd[0]["hover"] - H_TRUE) * (odd[1]["hover"] - H_TRUE) < 0
    assert "second_group" not in both.info["hover_thrust"]


def test_a_steady_wind_that_tilts_every_hover_still_gives_the_hover_thrust(tmp_path):
    """A steady 3.5 N wind (30 % of the weight) tilts every hover by 17 degrees: no level window. PX4's
    default MPC_THR_HOVER (0.5) would have made the thrust 0.72 x the weight; the hovers tilted up to 25
    degrees give H_TRUE (their vertical balance holds at any tilt), with a warning that translational lift
    in a real wind may bias it, and the wind is estimated."""
    wind = 0.3 * MASS * G
    path = _px4_old(tmp_path / "windy.ulg", _flight(wind=wind), {"MPC_THR_HOVER": 0.5})
    est = estimate_file(path, MASS)
    h = est.info["hover_thrust"]
    assert h.get("windy") and abs(h["median"] - H_TRUE) < 0.01 * H_TRUE
    assert any("no level hover" in w for w in est.warnings)
    air = (est.t - est.t[0] > 5.0) & (est.t - est.t[0] < 29.5)
    assert est.f_W[air, 0].mean() == pytest.approx(wind, abs=0.1) and abs(est.f_W[air, 2].mean()) < 0.1
    calm = estimate_file(_px4_old(tmp_path / "calm.ulg", _flight(), {"MPC_THR_HOVER": 0.5}), MASS)
    assert not calm.info["hover_thrust"].get("windy") and not any("no level hover" in w for w in calm.warnings)


@pytest.mark.parametrize(
    ("params", "h_true", "outcome"),
    [
        ({}, H_TRUE, "refused"),  # nothing to convert the thrust with
        ({"MPC_THR_HOVER": 0.5}, H_TRUE, "refused"),  # the default, 0.72 x the weight: refused, suggests 0.36
        ({"MPC_THR_HOVER": 0.5}, 0.46, "warned"),  # the default, plausible: used with a recorded warning
        ({"MPC_THR_HOVER": 0.37}, H_TRUE, "used"),  # a tuned parameter: used, named as unchecked
    ],
)
def test_a_log_without_a_hover_window(params, h_true, outcome, tmp_path):
    path = _px4_old(tmp_path / "cruise.ulg", _flight(cruise=True, duration=15.0, h_true=h_true), params)
    if outcome == "refused":
        with pytest.raises(InputError, match="no hover window.*--hover-thrust.*--hover-segment") as exc:
            estimate_file(path, MASS)
        if params:
            assert "suggests about 0.36" in str(exc.value)
        return
    est = estimate_file(path, MASS)
    warned = [w for w in est.warnings if "firmware default, not checked on a hover" in w]
    assert bool(warned) == (outcome == "warned")
    if outcome == "used":
        assert "not checked on a hover" in est.info["hover_thrust"]["source"]
    assert est.info["hover_thrust"]["median"] == pytest.approx(params["MPC_THR_HOVER"], rel=1e-6)
    assert est.fz_sd is None and est.info["hover_thrust"]["sd"] is None


# ----------------------------------------------------------------------------- on the ground


def _ground_csv(path):
    """A bench test: still and level, the thrust in newtons stepping through 0.2, 0.4, 0.6 m g."""
    t = np.arange(0.0, 15.0, 0.01)
    T = MASS * G * np.select([t < 5.0, t < 10.0], [0.2, 0.4], 0.6)
    z = np.zeros_like(t)
    cols = {"t_s": t, "vx": z, "vy": z, "vz": z, "roll": z, "pitch": z, "yaw": z, "wx": z, "wy": z, "wz": z,
            "thrust_n": T}  # fmt: skip
    return write_csv(path, cols), t, T


def test_on_ground_gives_the_ground_reaction(tmp_path, capsys):
    """NED: the ground pushes up with ``m g - T``, so the estimate is ``f_z = -(m g - T)``."""
    path, t, T = _ground_csv(tmp_path / "bench.csv")
    for extra in ([], ["--conventions", "unchecked"]):  # unchecked skips the conventions' check only
        rc = main(["estimate", str(path), "--mass", str(MASS), "--out", str(tmp_path / "x"), "--no-plots", *extra])
        err = capsys.readouterr().err
        assert rc == 2 and "not flying on its own thrust" in err and "--on-ground" in err
    rc = main(["estimate", str(path), "--mass", str(MASS), "--on-ground", "--out", str(tmp_path / "g"), "--no-plots"])
    out = capsys.readouterr().out
    assert rc == 0 and "ground reaction" in out
    rows = np.genfromtxt(tmp_path / "g" / "wrench.csv", delimiter=",", names=True)
    for a in (3.0, 8.0, 13.0):  # settled (5 time constants after each step)
        sel = (rows["t_s"] >= a) & (rows["t_s"] <= a + 1.9)
        expected = -(MASS * G - np.interp(a + 1.0, t, T))
        assert rows["fz_W_N"][sel] == pytest.approx(expected, abs=1e-3)
    info = json.loads((tmp_path / "g" / "estimate.json").read_text())["info"]
    assert info["on_ground"] is True and "ground reaction" in info["force_meaning"]


def test_on_ground_with_normalised_thrust_needs_a_hover_thrust(tmp_path):
    path, t, T = _ground_csv(tmp_path / "bench.csv")
    cols = np.genfromtxt(path, delimiter=",", names=True)
    data = {n: cols[n] for n in cols.dtype.names if n != "thrust_n"}
    data["thrust_norm"] = cols["thrust_n"] * 0.4 / (MASS * G)
    norm = write_csv(tmp_path / "norm.csv", data)
    with pytest.raises(InputError, match="on the ground has no hover.*--hover-thrust"):
        estimate_file(norm, MASS, on_ground=True)
    est = estimate_file(norm, MASS, on_ground=True, hover_thrust=0.4)
    sel = (est.t > 13.0) & (est.t < 14.9)
    assert est.f_W[sel, 2] == pytest.approx(-0.4 * MASS * G, abs=1e-3)


def test_on_ground_on_a_log_that_flies_is_warned_about(hover_log):
    """The flight of the hover tests with --on-ground: estimated, but the label is true only on the ground
    (its first 2 s); its hover parameter, PX4's default, is used with a warning (no windows looked for)."""
    est = estimate_file(hover_log, MASS, on_ground=True)
    assert any("moves in this log" in w for w in est.warnings)
    assert any("firmware default" in w for w in est.warnings) and est.info["hover_thrust"]["median"] == 0.5
    est = estimate_file(hover_log, MASS, on_ground=True, hover_thrust=H_TRUE)
    # on the ground, the thrust ramps 0.15..0.95 m g: f_z = -(m g - T), seen through G(s), which follows
    # a ramp 2 zeta / wn = 0.2 s late; noise: the velocity's and the command's (0.1 N)
    s = est.t - est.t[0]
    still = (s > 0.8) & (s < 1.95)
    T_late = MASS * G * (0.15 + 0.8 * (s[still] - 0.2) / 2.0)
    assert est.f_W[still, 2] == pytest.approx(-(MASS * G - T_late), abs=0.15)


# ----------------------------------------------------------------------------- two vehicles in a tlog


@pytest.fixture(scope="module")
def fl():
    return S.flight()


def _two_vehicles(fl, path, second_count=None, second_hover=0.3):
    """System 1: the synthetic flight; system 2: the same flight from another vehicle (its own hover
    parameter), or only its first ``second_count`` messages of each kind."""
    one = synth_tlog_messages(fl)
    two, count = [], {}
    for t, name, fields in one:
        count[name] = count.get(name, 0) + 1
        if name == "PARAM_VALUE":
            two.append((t + 1e-4, name, {**fields, "param_value": second_hover}, (2, 1)))
        elif second_count is None or count[name] <= second_count:
            two.append((t + 1e-4, name, fields, (2, 1)))
    return write_tlog(path, one + two)


def test_a_tlog_of_two_vehicles_is_refused_and_sysid_picks_each(fl, tmp_path):
    path = _two_vehicles(fl, tmp_path / "two.tlog")
    n_att = sum(1 for m in synth_tlog_messages(fl) if m[1] == "ATTITUDE")
    with pytest.raises(InputError, match=rf"2 vehicles \(system 1: {n_att} attitude.*system 2: {n_att}.*--sysid 1"):
        read_any(path)
    for sysid, hover in ((1, HOVER), (2, 0.3)):
        raw, _ = read_any(path, sysid=sysid)
        assert raw.meta["system_component"] == [sysid, 1]
        assert raw.hover_thrust == pytest.approx(hover)  # each vehicle's own parameters
        assert raw.meta["other_systems"] == {str(3 - sysid): n_att}
    est = estimate_file(path, S.MASS, read_options={"sysid": 1})
    assert est.info["system_component"] == [1, 1]
    out = tmp_path / "two"
    # system 2's hover parameter (0.3) does not fit the flight it logged (0.42): the verdict refuses its thrust
    # scale, so the thrust is given as the flight flew it
    argv = ["estimate", str(path), "--mass", str(S.MASS), "--sysid", "2", "--hover-thrust", str(HOVER)]
    assert main([*argv, "--out", str(out), "--no-plots"]) == 0
    assert json.loads((out / "estimate.json").read_text())["info"]["system_component"] == [2, 1]
    with pytest.raises(InputError, match="--sysid 7: no vehicle messages.*system 1"):
        read_any(path, sysid=7)
    with pytest.raises(InputError, match="--compid 5"):
        read_any(path, sysid=1, compid=5)


def test_a_second_system_too_small_to_estimate_is_named_loudly(fl, tmp_path, capsys):
    path = _two_vehicles(fl, tmp_path / "few.tlog", second_count=10)
    raw, _ = read_any(path)
    assert raw.meta["system_component"] == [1, 1] and raw.meta["other_systems"] == {"2": 10}
    assert any(n.startswith("WARNING") and "system 2" in n for n in raw.notes)
    rc = main(["estimate", str(path), "--mass", str(S.MASS), "--out", str(tmp_path / "o"), "--no-plots"])
    err = capsys.readouterr().err
    assert rc == 0 and "WARNING: the tlog also holds messages from other MAVLink systems" in err


def test_sysid_on_a_log_that_is_not_a_tlog_is_refused(fl, tmp_path, capsys):
    path = write_csv(tmp_path / "f.csv", csv_cols(fl, every=2))
    rc = main(["estimate", str(path), "--mass", "1.2", "--sysid", "1", "--out", str(tmp_path / "o")])
    assert rc == 2 and "--sysid chooses a vehicle of a MAVLink telemetry log" in capsys.readouterr().err


# ----------------------------------------------------------------------------- CSV aliases


RENAMED = {"t_s": "time", "vx": "vel_x", "vy": "VEL_Y", "vz": "vD", "roll": "roll_rad", "pitch": "pitch_rad",
           "yaw": "yaw_rad", "wx": "p", "wy": "q", "wz": "r", "tx": "tau_x", "ty": "torque_y", "tz": "Mz"}  # fmt: skip


def test_csv_aliases_read_as_the_roles(fl, tmp_path):
    cols = csv_cols(fl, every=2)
    plain, _ = read_any(write_csv(tmp_path / "plain.csv", cols))
    aliased = write_csv(tmp_path / "alias.csv", {RENAMED.get(k, k): v for k, v in cols.items()})
    raw, _ = read_any(aliased)
    for a, b in zip(plain.signals(), raw.signals(), strict=True):
        assert a.name == b.name and np.array_equal(a.t, b.t) and np.array_equal(a.values, b.values)
    assert any("'vel_x' read as vx" in n for n in raw.notes)


def test_an_ambiguous_alias_is_refused_naming_both(fl, tmp_path):
    cols = {RENAMED.get(k, k): v for k, v in csv_cols(fl, every=2).items()}
    cols["t"] = cols["time"]
    with pytest.raises(InputError, match=r"columns 'time' and 't' both name the role t_s.*--column t_s="):
        read_any(write_csv(tmp_path / "amb.csv", cols))


def test_missing_columns_suggest_the_column_fix(fl, tmp_path, capsys):
    cols = csv_cols(fl, every=2)
    cols = {{"vx": "velN", "vy": "velE", "vz": "velD"}.get(k, k): v for k, v in cols.items()}
    path = write_csv(tmp_path / "ned.csv", cols)
    with pytest.raises(InputError, match=r"needs column\(s\) vx, vy, vz.*--column vx=velN.*--column vy=velE"):
        read_any(path)
    rc = main(["estimate", str(path), "--mass", "1.2", "--column", "rol=velN", "--out", str(tmp_path / "o")])
    assert rc == 2 and "did you mean roll" in capsys.readouterr().err
    with pytest.raises(InputError, match=r"--column vx=velNN: the file has no column 'velNN' \(close: velN"):
        read_any(path, columns={"vx": "velNN"})
    raw, _ = read_any(path, columns={"vx": "velN", "vy": "velE", "vz": "velD"})
    assert raw.velocity_W.values.shape[1] == 3


def test_aliases_are_unambiguous_between_roles():
    """No alias names two roles or another role's own column (a file could not be read one way)."""
    seen: dict[str, str] = {c.lower(): c for c in COLUMNS}
    for role, names in ALIASES.items():
        assert role in COLUMNS
        for n in names:
            assert n.lower() not in seen, (n, role, seen.get(n.lower()))
            seen[n.lower()] = role


def test_rotor_speeds_matched_to_fitted_commands_carry_the_fits_notes_and_uncertainty(tmp_path, capsys):
    """The shipped CSV sample without its hover_thrust column: the thrust comes from the rotor speeds,
    matched to the commands, whose hover thrust is then fitted on hover windows (and so absorbs the
    payload's steady weight). That is said, with the fit's windows and the vertical force's uncertainty
    column, as when the thrust is taken from the commands themselves."""
    from importlib import resources

    src = resources.files("vtol_impedance.logs") / "samples" / "flight.csv"
    lines = src.read_text().splitlines()
    head = lines[0].split(",")
    k = head.index("hover_thrust")
    (tmp_path / "nohover.csv").write_text(
        "\n".join(",".join(c for i, c in enumerate(row.split(",")) if i != k) for row in lines) + "\n"
    )
    rc = main(["estimate", str(tmp_path / "nohover.csv"), "--vehicle", "pelican", "--out", str(tmp_path / "o"),
               "--no-plots"])  # fmt: skip
    err, out = capsys.readouterr()[::-1]
    assert rc == 0 and "rotor speeds" in err
    assert "the commands' calibration: hover window" in err and "vertical force uncertainty" in out
    assert "fz_W_N_hover_sd" in (tmp_path / "o" / "wrench.csv").read_text().splitlines()[0].split(",")
    # the same column present but empty is said to be unused, not dropped in silence
    (tmp_path / "nan.csv").write_text(
        "\n".join(row if j == 0 else ",".join("nan" if i == k else c for i, c in enumerate(row.split(",")))
                  for j, row in enumerate(lines)) + "\n"
    )  # fmt: skip
    rc = main(["estimate", str(tmp_path / "nan.csv"), "--vehicle", "pelican", "--out", str(tmp_path / "n"),
               "--no-plots"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 0 and "hover_thrust column holds no value" in err


def test_a_segment_fit_reads_the_vertical_acceleration_with_its_sign():
    """A level vehicle accelerating upward at 0.8 m/s^2 (NED: a_z = -0.8) for 6 s needs the thrust
    m (g + 0.8); its command is that thrust times the hover thrust over m g. The segment's balance
    ``k u = m (g - a_z)`` gives the hover thrust back exactly; the other sign would give it 15 % low."""
    from vtol_impedance.logs import resample
    from vtol_impedance.logs.estimate import fit_hover_thrust
    from vtol_impedance.logs.timeseries import RawLog, Signal

    t = np.arange(0.0, 8.0, 0.01)
    a_up = 0.8
    vz = -a_up * t
    n = len(t)
    wobble = 0.002 * np.sin(7.0 * t)  # a live command, not one the logger froze
    u = (MASS * (G + a_up) * H_TRUE / (MASS * G)) * (1.0 + wobble)
    raw = RawLog(
        Signal("velocity", "v", t, np.stack([np.zeros(n), np.zeros(n), vz], -1)),
        Signal("attitude", "eta", t, np.zeros((n, 3))),
        Signal("body rates", "w", t, np.zeros((n, 3))),
        Signal("thrust", "u", t, u[:, None], hold=True),
        None,
        thrust_unit="normalized",
    )
    h, _ = fit_hover_thrust(resample(raw, 100.0), MASS, (1.0, 7.0))
    assert h == pytest.approx(H_TRUE, rel=2e-3)
