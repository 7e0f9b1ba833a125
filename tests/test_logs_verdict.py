"""The log verdict on a labelled corpus: correct flights (the shipped samples, a gentle Newton-Euler flight,
agile flights of the project's simulator and a prescribed figure-eight, each with an aerodynamic drag force
of 10-25 % of the weight) and corrupted logs made from them (velocity played backwards, rows shuffled, the
thrust replaced by noise, rotor speeds played backwards, degrees declared radians, deg/s declared rad/s,
ENU declared NED, body axes swapped, one column swapped with another), all logged at 50 Hz (the shipped
CSV sample's rate). No corrupted log gets an estimate without ``force``, no correct log is refused; both
rates are counted and printed (docs/guide/logs.md quotes them)."""

from __future__ import annotations

import re
import types
from dataclasses import replace

import numpy as np
import pytest
import synthflight as S
from logfiles import csv_cols, rotor_speeds, write_csv

from vtol_impedance.errors import InputError
from vtol_impedance.logs import estimate_file
from vtol_impedance.logs import samples as sample_logs
from vtol_impedance.logs.verdict import LogRefused
from vtol_impedance.model.kinematics import euler_from_rotation

MASS = 1.2
WEIGHT = MASS * 9.81
RNG_SEED = 35


def _rotation(b3: np.ndarray) -> np.ndarray:
    """Rotation with body z axis ``b3`` (world NED) and zero yaw."""
    b2 = np.cross(b3, np.array([1.0, 0.0, 0.0]))
    b2 /= np.linalg.norm(b2, axis=-1, keepdims=True)
    b1 = np.cross(b2, b3)
    return np.stack([b1, b2, b3], -1)


def figure_eight(drag: float = 0.55, duration: float = 25.0, rate: float = 50.0, quad: float = 0.0
                 ) -> tuple[types.SimpleNamespace, float]:  # fmt: skip
    """A prescribed figure-eight (10 s a lap) at up to ~5 m/s with vertical swings of 1 m/s, under the drag
    ``f = -drag v - quad |v| v`` (N per m/s, N per (m/s)^2): the thrust vector is what Newton's law needs,
    ``u R e3 = m g e3 - m a + f``, the attitude follows it (zero yaw), the body rates are ``R^T dR/dt``. Noise as a real log's. Returns the
    flight and the median drag force over the weight."""
    w = 2 * np.pi / 10.0
    amp = np.array([6.0, 3.0, 0.8])  # m: x at w, y and z at 2 w

    def kin(t):
        s1, c1, s2, c2 = np.sin(w * t), np.cos(w * t), np.sin(2 * w * t), np.cos(2 * w * t)
        v = np.stack([amp[0] * w * c1, 2 * amp[1] * w * c2, 2 * amp[2] * w * c2], -1)
        a = np.stack([-amp[0] * w * w * s1, -4 * amp[1] * w * w * s2, -4 * amp[2] * w * w * s2], -1)
        return None, v, a

    def attitude(t):
        _, v, a = kin(t)
        thrust_W = MASS * (np.array([0.0, 0.0, 9.81]) - a) - drag * v - quad * np.linalg.norm(v, axis=-1)[:, None] * v
        u = np.linalg.norm(thrust_W, axis=-1)
        return _rotation(thrust_W / u[:, None]), u

    t = np.arange(0.0, duration, 1.0 / rate)
    _, v, _ = kin(t)
    R, u = attitude(t)
    h = 1e-5
    Rd = (attitude(t + h)[0] - attitude(t - h)[0]) / (2 * h)
    W = np.swapaxes(R, -1, -2) @ Rd
    omega = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], -1)
    rng = np.random.default_rng(RNG_SEED)
    fl = types.SimpleNamespace(
        t=t, v_W=v + rng.normal(0, 0.02, v.shape), eta=euler_from_rotation(R) + rng.normal(0, 0.002, (len(t), 3)),
        omega_B=omega + rng.normal(0, 0.01, omega.shape), thrust=u * (1 + rng.normal(0, 0.005, len(t))),
        tau_B=np.zeros((len(t), 3)),
    )  # fmt: skip
    speed = np.linalg.norm(v, axis=-1)
    return fl, float(np.median(drag * speed + quad * speed**2) / WEIGHT)


def circle(speed: float, radius: float, drag: float) -> tuple[types.SimpleNamespace, float]:
    """The simulator's Pelican (case C: payload, rotor lag, sensor noise) circling at ``speed`` m/s with the
    plant's linear rotor drag ``drag`` N per m/s (the aerodynamic force), 22 s."""
    from vtol_impedance.scenarios import get, simulate

    base = get("case-c-circle")
    traj = replace(base.trajectory, circle_speed=speed, circle_radius=radius, hover_duration=1.0,
                   takeoff_duration=3.0, land=False)  # fmt: skip
    spec = replace(base, trajectory=traj, sensors=replace(base.sensors, mocap_delay=0.0, imu_delay=0.0),
                   plant=replace(base.plant, rotor_drag=drag), duration=22.0)  # fmt: skip
    r = simulate(spec, ["pd"])
    every = slice(None, None, 2)  # logged at 50 Hz
    fl = types.SimpleNamespace(t=r.t[every], v_W=r["v_meas_W"][0][every], eta=r["eta_meas"][0][every],
                               omega_B=r["omega_B"][0][every], thrust=r["thrust"][0][every],
                               tau_B=r["tau_B"][0][every])  # fmt: skip
    circling = fl.t > 8.0
    return fl, float(np.median(drag * np.linalg.norm(fl.v_W[circling], axis=-1)) / WEIGHT)


def _with_rotors(fl, cols: dict, rotors_only: bool = False) -> dict:
    w = rotor_speeds(fl.thrust, fl.tau_B) * 60 / (2 * np.pi)
    cols = dict(cols, **{f"rpm{i + 1}": w[:, i] for i in range(4)})
    if rotors_only:
        cols.pop("thrust_n")
    return cols


def _corruptions(fl, cols: dict, rng) -> dict[str, tuple[dict, dict]]:
    """name -> (columns, read options): each a wrong log made from the flight ``fl`` written as ``cols``."""
    out: dict[str, tuple[dict, dict]] = {}
    c = dict(cols)
    for k in ("vx", "vy", "vz"):
        c[k] = cols[k][::-1]
    out["velocity reversed in time"] = (c, {})
    perm = rng.permutation(len(cols["t_s"]))
    out["rows shuffled"] = ({k: (v if k == "t_s" else v[perm]) for k, v in cols.items()}, {})
    if "thrust_n" in cols:
        noise = rng.uniform(0.5, 1.5, len(cols["t_s"])) * np.mean(cols["thrust_n"])
        out["thrust replaced by noise"] = (dict(cols, thrust_n=noise), {})
    rpm = {k: v for k, v in cols.items() if k.startswith("rpm")}
    thr = "thrust_n" if "thrust_n" in cols else None
    out["degrees declared radians"] = (dict(csv_cols(fl, angle="deg"), **rpm), {})
    out["deg/s declared rad/s"] = (dict(csv_cols(fl, rate="deg"), **rpm), {})
    out["ENU declared NED"] = (dict(csv_cols(fl, world="enu"), **rpm), {})
    out["body axes x and y swapped (rates)"] = (dict(cols, wx=cols["wy"], wy=cols["wx"]), {})
    out["vx and vy swapped"] = (dict(cols, vx=cols["vy"], vy=cols["vx"]), {})
    out["vy and vz swapped"] = (dict(cols, vy=cols["vz"], vz=cols["vy"]), {})
    if thr is None:
        return out
    for name in list(out):
        if name in ("degrees declared radians", "deg/s declared rad/s", "ENU declared NED") and thr not in out[name][0]:
            out.pop(name)
    return out


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    return build_corpus(tmp_path_factory.mktemp("verdict"))


def build_corpus(d):
    """``([(label, kind, path, read options, _)], {flight: drag force / weight})``, kind ``"correct"`` or
    ``"wrong"``, the logs written into the folder ``d``."""
    rng = np.random.default_rng(RNG_SEED)
    items = []
    for name in sample_logs.names():
        ro = {}
        if name == "ros-csv":
            ro = dict(world="enu", body="flu", quat_order="xyzw", rate_unit="deg", time_unit="ms")
        items.append((f"sample {name}", "correct", sample_logs.path(name), ro, None))
    flights = {"gentle": (S.flight(20.0, 50.0), 0.0)}
    flights["circle 5 m/s"] = circle(5.0, 4.0, 0.45)
    flights["circle 4 m/s"] = circle(4.0, 3.0, 0.6)
    flights["figure-eight"] = figure_eight()
    aero = {}
    for fname, (fl, share) in flights.items():
        aero[fname] = share
        base = csv_cols(fl)
        variants = {fname: base}
        if fname != "gentle":
            variants[f"{fname}, rotor speeds"] = _with_rotors(fl, base)
            variants[f"{fname}, rotor speeds only"] = _with_rotors(fl, base, rotors_only=True)
        for vname, cols in variants.items():
            slug = "".join(ch if ch.isalnum() else "-" for ch in vname)
            items.append((vname, "correct", write_csv(d / f"{slug}.csv", cols), {}, None))
        target = list(variants)[min(1, len(variants) - 1)]  # with the thrust column and rotor speeds
        wrong = _corruptions(fl, variants[target], rng)
        if fname != "gentle":  # rotor speeds only: the thrust comes from them
            only = variants[f"{fname}, rotor speeds only"]
            rpm = [k for k in only if k.startswith("rpm")]
            wrong["rotor speeds only, velocity reversed in time"] = (
                dict(only, **{k: only[k][::-1] for k in ("vx", "vy", "vz")}),
                {},
            )
            wrong["rotor speeds only, rotor speeds played backwards"] = (
                dict(only, **{k: only[k][::-1] for k in rpm}),
                {},
            )
        for cname, (cols, ro) in wrong.items():
            slug = "".join(ch if ch.isalnum() else "-" for ch in f"{fname}-{cname}")
            path = write_csv(d / f"{slug}.csv", cols)
            items.append((f"{fname}: {cname}", "wrong", path, ro, None))
    # the shipped CSV sample's columns, corrupted
    import csv

    rows = list(csv.reader(open(sample_logs.path("csv"))))
    scols = {k: np.array([float(r[i]) for r in rows[1:]]) for i, k in enumerate(rows[0])}
    no_rpm = {k: v for k, v in scols.items() if not k.startswith("rpm")}
    for label, cols in (("sample csv", scols), ("sample csv without rotor speeds", no_rpm)):
        wrong = {"velocity reversed in time": dict(cols, **{k: cols[k][::-1] for k in ("vx", "vy", "vz")}),
                 "thrust replaced by noise": dict(cols, thrust_norm=rng.uniform(0.3, 0.7, len(cols["t_s"]))),
                 "vx and vy swapped": dict(cols, vx=cols["vy"], vy=cols["vx"]),
                 "wx and wy swapped": dict(cols, wx=cols["wy"], wy=cols["wx"])}  # fmt: skip
        perm = rng.permutation(len(cols["t_s"]))
        wrong["rows shuffled"] = {k: (v if k == "t_s" else v[perm]) for k, v in cols.items()}
        for cname, c in wrong.items():
            slug = "".join(ch if ch.isalnum() else "-" for ch in f"{label}-{cname}")
            items.append((f"{label}: {cname}", "wrong", write_csv(d / f"{slug}.csv", c), {}, MASS))
    return items, aero


def _outcome(path, ro, conventions="check", force=False):
    """``("estimated", verdict dict)`` or ``("refused", message)``."""
    try:
        est = estimate_file(path, MASS, read_options=dict(ro, conventions=conventions), force=force)
    except InputError as exc:
        return "refused", str(exc)
    return "estimated", est.info["verdict"]


def test_the_agile_flights_carry_10_to_25_percent_of_the_weight_as_drag(corpus):
    _, aero = corpus
    for name, share in aero.items():
        if name != "gentle":
            assert 0.10 <= share <= 0.25, (name, share)


#: The wrong logs physics cannot tell from a correct one with a push: the shipped sample's one move runs
#: diagonally for 3 s, so vx and vy swapped mirror it within one 4 s window, as a push in that window would
#: (a correct 10 s log with a 1 N step force scores the same; tests/test_logs_fields.py). They are estimated
#: with the verdict "undecided" and a note that the horizontal force test was left out, never accepted.
UNDECIDABLE = {"sample csv: vx and vy swapped", "sample csv without rotor speeds: vx and vy swapped"}
#: Read as ENU (``--conventions auto``), vx and vy swapped are put back in place, and only the sign of vz is
#: then wrong: on a circle at one height vz is noise, so no test can see it (the vertical test is left out
#: for lack of vertical motion). The estimate's horizontal force is right; the verdict is undecided.
REPAIRED = {("circle 5 m/s: vx and vy swapped", "auto"), ("circle 4 m/s: vx and vy swapped", "auto")}


def test_no_wrong_log_accepted_and_no_correct_log_refused(corpus):
    items, _ = corpus
    wrong_estimated, right_refused, n_wrong, n_right = [], [], 0, 0
    for label, kind, path, ro, _ in items:
        modes = ("check", "auto") if kind == "wrong" else ("check",)
        for mode in modes:
            if kind == "wrong" and mode == "auto" and any(w in label for w in ("declared", "ENU")):
                continue  # auto reads these right: the estimate is then correct
            outcome, detail = _outcome(path, ro, mode)
            if kind == "wrong":
                n_wrong += 1
                if outcome == "estimated":
                    wrong_estimated.append((label, mode, detail))
            else:
                n_right += 1
                if outcome == "refused":
                    right_refused.append((label, mode, detail))
    print(f"\nlog verdict corpus: {len(wrong_estimated)} of {n_wrong} wrong logs estimated (all undecided), "
          f"{len(right_refused)} of {n_right} correct logs refused")  # fmt: skip
    assert not right_refused, right_refused
    repaired = [(label, mode) for label, mode, _ in wrong_estimated if (label, mode) in REPAIRED]
    others = {label for label, mode, _ in wrong_estimated if (label, mode) not in REPAIRED}
    assert others <= UNDECIDABLE, wrong_estimated
    for label, mode, verdict in wrong_estimated:  # never accepted: undecided, the test that could tell left out
        assert verdict["outcome"] == "undecided", verdict
        which = "vertical" if (label, mode) in REPAIRED else "horizontal"
        (h,) = [t for t in verdict["tests"] if t["test"] == f"{which} force balance"]
        assert h["status"] == "left out"
    assert len(wrong_estimated) - len(repaired) <= 4 and n_wrong >= 80 and n_right >= 15


def test_an_agile_flight_with_rotor_speeds_only_gets_its_thrust_coefficient(corpus, tmp_path):
    """The figure-eight with rotor speeds only (no thrust column): the coefficient is fitted on the vertical
    balance jointly with a drag term and comes within 3 % of the rotors' own (it was refused: "the fit
    leaves 1.96 N RMS on a 11.8 N vehicle ... (wrong columns?)", the drag and the velocity's noise)."""
    from logfiles import K_T

    fl, _ = figure_eight()
    est = estimate_file(write_csv(tmp_path / "f8.csv", _with_rotors(fl, csv_cols(fl), rotors_only=True)), MASS)
    assert abs(est.info["thrust_coefficient"] / K_T - 1) < 0.03
    assert est.info["verdict"]["outcome"] in ("accepted", "undecided")


def test_cli_refusal_exits_2_names_the_column_and_force_records_the_override(tmp_path, capsys):
    """The issue's sample: the shipped CSV flight with its thrust column replaced by noise, under
    --conventions auto. It was estimated ("the data cannot decide ..."); now refused with exit code 2 (as
    every refused log), naming the thrust column and the residual; --force estimates and records it."""
    import csv
    import json

    from vtol_impedance.cli import main

    rows = list(csv.reader(open(sample_logs.path("csv"))))
    cols = {k: np.array([float(r[i]) for r in rows[1:]]) for i, k in enumerate(rows[0])}
    cols["thrust_norm"] = np.random.default_rng(1).uniform(0.3, 0.7, len(cols["t_s"]))
    path = str(write_csv(tmp_path / "noise.csv", cols))
    args = ["estimate", path, "--mass", "1.2", "--conventions", "auto", "--no-plots", "--out", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "contradict physics" in err and "thrust" in err and "limit" in err and "--force" in err
    assert not (tmp_path / "o").exists()
    assert main([*args, "--force"]) == 0
    out = capsys.readouterr()
    assert "verdict: refused (overridden with --force)" in out.out and "overridden (--force)" in out.err
    info = json.loads((tmp_path / "o" / "estimate.json").read_text())["info"]
    assert info["verdict"]["outcome"] == "refused" and info["verdict"]["forced"] is True
    assert any(t["status"] == "fail" for t in info["verdict"]["tests"])
    with pytest.raises(LogRefused) as exc:
        estimate_file(path, MASS, read_options={"conventions": "auto"})
    assert exc.value.verdict.failed


def test_the_sample_with_its_velocity_played_backwards_names_the_velocity(tmp_path):
    """The issue's other sample: the shipped CSV flight with vx, vy, vz reversed in time, under --conventions
    auto. It was estimated ("the data cannot decide ..."); now both force balances fail, with their
    residuals against the limit, and the refusal points at the velocity they share."""
    import csv

    rows = list(csv.reader(open(sample_logs.path("csv"))))
    cols = {k: np.array([float(r[i]) for r in rows[1:]]) for i, k in enumerate(rows[0])}
    path = write_csv(tmp_path / "rev.csv", dict(cols, **{k: cols[k][::-1] for k in ("vx", "vy", "vz")}))
    with pytest.raises(LogRefused) as exc:
        estimate_file(path, MASS, read_options={"conventions": "auto"})
    failed = {t.name: t for t in exc.value.verdict.failed}
    assert {"horizontal force balance", "vertical force balance"} <= set(failed)
    assert all(t.value > 2 * t.limit for t in failed.values() if "balance" in t.name)
    assert "the velocity, which they share, is the likeliest" in str(exc.value) and "(limit 0.16" in str(exc.value)


def test_euler_rates_logged_as_body_rates_are_refused_on_the_axis_that_shows_it():
    """An attitude rolling and pitching by up to 29 and 23 degrees while yawing at 1 rev/s: the body rates
    are ``Q(eta) eta_dot`` (eq. (1c)), computed here independently of the checks. Logged as such, every axis
    agrees; the Euler-angle rates logged in their place differ on roll and pitch by the yaw rate times the
    tilt, yet the whole score, dominated by the fast yaw, stays under the limit. The axis test refuses it,
    naming the axis."""
    from vtol_impedance.logs.checks import evidence
    from vtol_impedance.logs.timeseries import RawLog, Signal
    from vtol_impedance.logs.verdict import KIN_LIMIT, _kinematics
    from vtol_impedance.model.kinematics import euler_rate_matrix_Q, wrap_angle

    t = np.arange(0.0, 30.0, 0.01)
    eta = np.stack([0.5 * np.sin(1.3 * t), 0.4 * np.sin(0.9 * t + 1.0), wrap_angle(2 * np.pi * t)], -1)
    eta_dot = np.stack([0.65 * np.cos(1.3 * t), 0.36 * np.cos(0.9 * t + 1.0), np.full_like(t, 2 * np.pi)], -1)
    omega_B = np.einsum("nij,nj->ni", euler_rate_matrix_Q(eta), eta_dot)
    still = Signal("velocity", "v", t, np.zeros((len(t), 3)))
    thrust = Signal("thrust", "u", t, np.full((len(t), 1), MASS * 9.81), hold=True)

    def kin(rates):
        raw = RawLog(still, Signal("attitude", "eta", t, eta), Signal("rates", "w", t, rates), thrust, None)
        ev = evidence(raw)
        return ev, _kinematics(ev)

    ev, right = kin(omega_B)
    assert right.status == "pass" and right.value < 0.05
    ev, wrong = kin(eta_dot)
    assert ev.kin < KIN_LIMIT  # the premise: the whole score alone lets it through
    assert wrong.status == "fail" and "relative residual" in wrong.detail and "on body axis" in wrong.detail
    assert wrong.value > KIN_LIMIT


@pytest.mark.parametrize(("rate", "hz"), [(250.0, 100.3), (400.0, 150.2), (250.0, 92.5)])
def test_a_gyro_vibrating_at_a_multiple_of_the_check_grid_is_not_a_wrong_column(tmp_path, rate, hz):
    """Rotors at 6000 rpm shake the gyro at 100 Hz. Sampled at single points of the checks' 50 Hz grid, a
    vibration near 100 or 150 Hz folded to almost 0 Hz and survived every average: a correct log scored
    0.54 on the kinematic test (limit 0.35). The checks average the rates over each grid interval, as the
    attitude's change integrates them: the score stays that of the clean log."""
    from vtol_impedance.logs import read_any
    from vtol_impedance.logs.checks import evidence

    fl = S.flight(duration=12.0, rate=rate)
    clean = csv_cols(fl)
    shaken = dict(clean)
    for j, axis in enumerate(("wx", "wy", "wz")):
        shaken[axis] = clean[axis] + 0.2 * np.sin(2 * np.pi * hz * fl.t + j)
    k0 = evidence(read_any(write_csv(tmp_path / "clean.csv", clean))[0]).kin
    k1 = evidence(read_any(write_csv(tmp_path / "shaken.csv", shaken))[0]).kin
    assert k0 < 0.05 and k1 < k0 + 0.05, (k0, k1)


@pytest.mark.parametrize("scale", [2.0, 0.5, 1.5])
def test_a_gyro_of_the_wrong_scale_is_refused_on_its_gain(tmp_path, scale):
    """Body rates k times too large (a gyro's full-scale range set wrong) score |1 - k| / (1 + k) on the
    kinematic residual, 0.33 for k = 2, under its limit: the log was estimated with a wrong moment. The
    gain on an axis that turns is tested on its own (within 0.35 of 1; a correct log is within 0.01)."""
    fl, _ = figure_eight()
    cols = csv_cols(fl)
    right = estimate_file(write_csv(tmp_path / "right.csv", cols), MASS)
    (kin,) = [t for t in right.info["verdict"]["tests"] if t["test"] == "kinematics"]
    assert kin["status"] == "pass"
    scaled = dict(cols, **{k: scale * cols[k] for k in ("wx", "wy", "wz")})
    with pytest.raises(LogRefused, match=r"body axis [xyz] are [0-9.]+ times the attitude's rate of change") as exc:
        estimate_file(write_csv(tmp_path / "scaled.csv", scaled), MASS)
    said = float(re.search(r"are ([0-9.]+) times", str(exc.value)).group(1))
    assert said == pytest.approx(scale, rel=0.03)


def test_an_agile_flight_with_quadratic_drag_of_a_third_of_its_weight_is_accepted(tmp_path):
    """Aerodynamic drag grows with the square of the speed: a figure-eight whose drag is a third of the weight
    in the median (up to two thirds) left 0.2-0.3 of unexplained force after a linear drag fit, and its thrust
    axis 18 degrees from the specific force (a steady fast flight's thrust tilts against the drag), which the
    convention check took for angles in degrees: a correct agile log was refused. Both fit the drag, linear and
    quadratic in the velocity; the same flight with its velocity reversed in time is still refused."""
    fl, share = figure_eight(drag=0.0, quad=0.35)
    assert 0.3 <= share <= 0.45, share
    cols = csv_cols(fl)
    est = estimate_file(write_csv(tmp_path / "drag.csv", cols), MASS)
    (h,) = [t for t in est.info["verdict"]["tests"] if t["test"] == "horizontal force balance"]
    assert h["status"] == "pass" and h["value"] < 0.1, h
    back = dict(cols, **{k: cols[k][::-1] for k in ("vx", "vy", "vz")})
    with pytest.raises(InputError, match="contradicts physics"):
        estimate_file(write_csv(tmp_path / "back.csv", back), MASS)


def test_a_body_rate_of_the_opposite_sign_is_named_as_such(tmp_path):
    """One gyro axis negated (a body frame mix-up) has a negative gain: it is refused for its residual and
    its sign, not called a scale error."""
    fl, _ = figure_eight()
    cols = csv_cols(fl)
    with pytest.raises(InputError, match="opposite sign|contradicts physics") as exc:
        estimate_file(write_csv(tmp_path / "flip.csv", dict(cols, wy=-cols["wy"])), MASS)
    assert "times the attitude's rate of change" not in str(exc.value)


def test_a_refusal_carries_what_the_estimate_already_doubted(tmp_path):
    """A hover thrust parameter 30 % off made the horizontal balance fail and named the velocity; the cause
    ("the thrust gives 1.46 times the weight ... check the hover thrust") was said only with --force. A
    refusal now carries the estimate's warnings."""
    fl, _ = figure_eight()
    cols = csv_cols(fl)
    cols = dict(cols, thrust_n=1.45 * cols["thrust_n"])  # a thrust map off by 45 %: the weight warning
    with pytest.raises(LogRefused) as exc:
        estimate_file(write_csv(tmp_path / "heavy.csv", cols), MASS)
    text = str(exc.value)
    assert "perhaps the cause" in text and "times the weight" in text, text
