"""Robust by design: the linear model of the sampled loop against closed forms, python-control and the
simulator; the estimator's timing; the design rule and the defaults it gives; bad input."""

from __future__ import annotations

import dataclasses
import json

import control as ct
import numpy as np
import pytest

from vtol_impedance.cli import main
from vtol_impedance.errors import InputError, ScenarioError
from vtol_impedance.estimator.momentum import EstimatorParams, design, estimator_step, initial_state
from vtol_impedance.robust import (
    Thresholds,
    TrimError,
    equivalent_rotor_tau,
    linearize,
    loop_margins,
    margins,
    operating_point,
    rotor_lag_describing_function,
)
from vtol_impedance.robust.linear import jacobian, sampled_plant
from vtol_impedance.robust.margins import FrequencyResponse
from vtol_impedance.scenarios import get, set_value, simulate
from vtol_impedance.scenarios.margins import scenario_margins
from vtol_impedance.scenarios.spec import PAPER_CONTROL, apply_overrides, build, controller_params
from vtol_impedance.sim import run_closed_loop
from vtol_impedance.sim.disturbances import from_dict


def _paper(spec):
    for k, v in PAPER_CONTROL.items():
        spec = set_value(spec, k, v)
    return spec


# ----------------------------------------------------------------------------- the margin machinery


def _pd_on_a_mass(m, Kp, Dp, delay, Ts):
    """``m x'' = u``, ``u = -(Kp x + Dp x')`` read ``delay`` late, held over ``Ts``: the loop ``L(z)``."""
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0 / m]])
    Ad, Bd, Cd = sampled_plant(A, B, [(np.eye(2), delay)], Ts)
    return ct.ss(Ad, Bd, np.array([[Kp, Dp]]) @ Cd, 0.0, Ts)


@pytest.mark.parametrize("delay", [0.02, 0.0213])  # a whole number of periods, and a fraction
def test_pd_on_a_double_integrator_with_delay_matches_the_closed_form(delay):
    """Continuous closed form: |Dp jw + Kp| = m w^2 at the crossover, PM = atan(Dp w / Kp) - w tau with
    tau the delay plus half a period (the hold); at Ts = 0.5 ms the sampled loop is within 0.3 deg."""
    m, Kp, Dp, Ts = 1.2, 16.0, 12.0, 0.0005
    L = _pd_on_a_mass(m, Kp, Dp, delay, Ts)
    wc = np.sqrt((Dp**2 + np.sqrt(Dp**4 + 4 * m**2 * Kp**2)) / (2 * m**2))
    pm = np.degrees(np.arctan(Dp * wc / Kp) - wc * (delay + Ts / 2))
    got = loop_margins("x", L)
    assert got.crossover == pytest.approx(wc, rel=2e-3)
    assert got.phase_deg == pytest.approx(pm, abs=0.3)
    assert got.delay_s == pytest.approx(np.radians(pm) / wc, rel=0.01)


def test_sampled_double_integrator_is_the_exact_zoh_transfer():
    """``x = Ts^2 (z + 1) / (2 m (z - 1)^2) u``, ``x' = Ts / (m (z - 1)) u`` (zero-order hold), read ``n``
    periods late; a fractional delay ``n Ts + delta`` reads ``Ts - delta`` into the older period."""
    m, Kp, Dp, Ts = 1.2, 16.0, 12.0, 0.01
    w = np.array([0.3, 2.0, 9.0, 40.0, 200.0])
    z = np.exp(1j * w * Ts)
    exact = (Kp * Ts**2 * (z + 1) / (2 * m * (z - 1) ** 2) + Dp * Ts / (m * (z - 1))) * z**-2
    assert np.allclose(FrequencyResponse(_pd_on_a_mass(m, Kp, Dp, 0.02, Ts))(w), exact, rtol=1e-9)
    # 25 ms = 2 Ts + 5 ms: the state 5 ms into period k - 3 (Ts - 5 ms after its start), with its input
    s = Ts - 0.005
    x, v = Ts**2 * (z + 1) / (2 * m * (z - 1) ** 2), Ts / (m * (z - 1))  # x_k / u, v_k / u
    exact_frac = (Kp * (x + s * v + s * s / (2 * m)) + Dp * (v + s / m)) * z**-3
    got = FrequencyResponse(_pd_on_a_mass(m, Kp, Dp, 0.025, Ts))(w)
    assert np.allclose(got, exact_frac, rtol=1e-9)


def test_delay_margin_is_the_delay_that_destabilises():
    """Adding just under the delay margin keeps the closed loop stable; just over it does not."""
    m, Kp, Dp, Ts = 1.2, 16.0, 12.0, 0.001
    dm = loop_margins("x", _pd_on_a_mass(m, Kp, Dp, 0.02, Ts)).delay_s

    def stable(delay):
        L = _pd_on_a_mass(m, Kp, Dp, delay, Ts)
        return np.all(np.abs(np.linalg.eigvals(ct.feedback(L, 1).A)) < 1.0)

    assert stable(0.02 + 0.97 * dm) and not stable(0.02 + 1.03 * dm)


def test_first_order_lag_matches_the_closed_form():
    """``L(s) = K / (s (tau s + 1))``: crossover from ``K = w sqrt(1 + w^2 tau^2)``, PM = 90 - atan(w tau)
    (less half a period for the hold)."""
    K, tau, Ts = 20.0, 0.05, 0.0005
    A = np.array([[0.0, 1.0], [0.0, -1.0 / tau]])
    B = np.array([[0.0], [1.0 / tau]])
    Ad, Bd, Cd = sampled_plant(A, B, [(np.array([[K, 0.0]]), 0.0)], Ts)
    got = loop_margins("lag", ct.ss(Ad, Bd, Cd, 0.0, Ts))
    wc = np.sqrt((-1 + np.sqrt(1 + 4 * K**2 * tau**2)) / (2 * tau**2))
    assert got.crossover == pytest.approx(wc, rel=2e-3)
    assert got.phase_deg == pytest.approx(90 - np.degrees(np.arctan(wc * tau) + wc * Ts / 2), abs=0.2)
    assert got.gain_up_db > 30.0  # continuous, never -180 deg; held, only near the Nyquist frequency


def test_a_slow_loop_is_found_on_the_default_grid():
    """The default grid starts at OMEGA_MIN = 1e-3 rad/s: a sampled integrator ``k Ts / (z - 1)`` crossing
    over at 2e-3 rad/s (an integral loop of minutes) has its crossover and its 90 deg of phase found."""
    Ts, k = 0.01, 2e-3
    got = loop_margins("slow", ct.ss([[1.0]], [[Ts]], [[k]], 0.0, Ts))
    assert got.crossover == pytest.approx(k, rel=1e-3)
    assert got.phase_deg == pytest.approx(90.0 - np.degrees(k * Ts / 2), abs=1e-3)


def test_margins_agree_with_python_control():
    L = _pd_on_a_mass(1.2, 16.0, 12.0, 0.03, 0.01)
    gm, pm, sm, _wpc, wgc, _wms = ct.stability_margins(L)
    got = loop_margins("x", L)
    assert got.sensitivity_peak == pytest.approx(1.0 / sm, rel=1e-3)  # the nearest approach to -1
    assert got.phase_deg == pytest.approx(pm, abs=1e-3)
    assert got.crossover == pytest.approx(wgc, rel=1e-5)
    assert got.gain_up_db == pytest.approx(20 * np.log10(gm), abs=1e-3)


def test_the_linearised_estimator_is_g_held_over_each_period():
    """A free mass pushed by a force held over each period; the estimator (eqs. (6)-(11), differentiated
    numerically as the linear model does) returns it through G(s) discretised with a zero-order hold."""
    m, I_B, Ts = 1.2, np.diag([3.4e-3, 3.4e-3, 4.7e-3]), 0.01
    des = design(EstimatorParams(wn=10.0, zeta=1.0), Ts)
    S0 = initial_state(des)
    z3 = np.zeros(3)
    S0, _ = estimator_step(des, S0, z3, z3, z3, 0.0, z3, m, I_B)  # started, at rest
    from vtol_impedance.robust.linear import flatten_state, unflatten_state

    s0 = flatten_state(S0)

    def step(X):  # state and the measured velocity (x) -> next state and f_hat_x
        S = unflatten_state(S0, X[:, :-1])
        v = np.zeros((len(X), 3))
        v[:, 0] = X[:, -1]
        S2, r = estimator_step(des, S, np.zeros((len(X), 3)), np.zeros((len(X), 3)), v, 0.0, z3, m, I_B)
        return np.concatenate([flatten_state(S2, S0), r[:, :1]], -1)

    J = jacobian(step, np.append(s0, 0.0), 1e-6)
    n = s0.size
    AK, BK, CK, DK = J[:n, :n], J[:n, n:], J[n:, :n], J[n:, n:]
    est = ct.ss(AK, BK, CK, DK, Ts)
    Ad, Bd, Cd = sampled_plant(np.zeros((1, 1)), np.array([[1.0 / m]]), [(np.eye(1), 0.0)], Ts)
    chain = ct.series(ct.ss(Ad, Bd, Cd, 0.0, Ts), est)  # force -> velocity -> f_hat
    G = ct.c2d(ct.tf([100.0], [1.0, 20.0, 100.0]), Ts, "zoh")
    w = np.array([0.5, 3.0, 10.0, 50.0])
    # the force held over a period is recovered exactly at its end, then filtered: exactly G_zoh(z)
    assert np.allclose(FrequencyResponse(chain)(w), G(np.exp(1j * w * Ts)), rtol=1e-6)


def test_rotor_lag_equivalent_is_the_mean_and_the_describing_function_agrees():
    assert equivalent_rotor_tau(0.0125, 0.025) == pytest.approx(0.01875)
    for w in (3.0, 13.0):
        N = rotor_lag_describing_function(0.0125, 0.025, w)
        tau_phase = -np.tan(np.angle(N)) / w
        assert tau_phase == pytest.approx(0.01875, rel=0.03)
        lag = 1.0 / (1.0 + 1j * w * 0.01875)
        assert abs(N - lag) < 0.02
    # homogeneous: the same with a symmetric lag is exactly a first-order lag
    N = rotor_lag_describing_function(0.02, 0.02, 10.0)
    assert N == pytest.approx(1.0 / (1.0 + 0.2j), abs=2e-3)


# ----------------------------------------------------------------------------- against the simulator


def _growth(t, x, base, lo=1e-7, hi=2e-3):
    """Growth rate (1/s) of an oscillation about ``base`` from its peaks between ``lo`` and ``hi``, up to the
    first that exceeds ``hi`` (beyond it the rotors' limits make it a limit cycle)."""
    a = np.abs(x - base)
    big = np.flatnonzero(~(a < hi))
    a = a[: big[0]] if big.size else a
    peaks = np.array([i for i in range(1, len(a) - 1) if a[i] >= a[i - 1] and a[i] > a[i + 1]], dtype=int)
    keep = peaks[(a[peaks] > lo) & (a[peaks] < hi)]
    assert len(keep) >= 6, "too few peaks to fit a growth rate"
    return np.polyfit(t[keep], np.log(a[keep]), 1)[0]


def _kicked_hover(spec, variant, duration=50.0):
    """Noise-free hover in the air (sensor latencies kept, no ground), kicked by 10 mN for 50 ms at 15 s: the
    simulated growth rate of roll and pitch, and the model's rightmost pole."""
    spec = apply_overrides(spec, ["trajectory.start_on_ground=false", "plant.ground=false"])
    quiet = ("pos_noise", "vel_noise", "att_noise", "gyro_noise")
    spec = dataclasses.replace(spec, sensors=dataclasses.replace(spec.sensors, **{k: 0.0 for k in quiet}))
    b = build(spec)
    ctrl = controller_params(spec, variant)
    kick = from_dict({"kind": "push", "force_W": [1e-2, 1e-2, 0.0], "t_on": 15.0, "duration": 0.05})
    r = run_closed_loop(b.plant, [ctrl], b.trajectory, duration, [kick], b.sensors, start_W=b.start_W)
    after, before = r.t > 16.0, (r.t > 14.0) & (r.t < 15.0)
    sim = max(_growth(r.t[after], r["eta"][0, after, i], r["eta"][0, before, i].mean()) for i in (0, 1))
    model = margins(linearize(ctrl, b.plant, b.sensors, p_W=b.start_W)).rightmost.real
    return sim, model


@pytest.mark.parametrize(
    "sets, variant",
    [
        (["payload.mass=0"], "pdc"),  # the paper's loop without payload: grows (the limit cycle)
        (["payload.mass=0"], "pd"),
        ([], "pdc"),  # the payload damps it
        (["payload.mass=0", "control.estimator_wn=6"], "pdc"),
        (["payload.mass=0", "control.estimator_wn=15"], "pdc"),
        (["payload.mass=0", "plant.rotor_tau_down=0.05", "sensors.mocap_delay=0.03"], "pd"),  # PD too
    ],
)
def test_rightmost_pole_is_the_simulated_growth_rate(sets, variant):
    sim, model = _kicked_hover(apply_overrides(_paper(get("case-a-payload")), sets), variant)
    assert model == pytest.approx(sim, abs=max(0.05, 0.2 * abs(sim)))


# ----------------------------------------------------------------------------- the estimator's timing


@pytest.mark.parametrize("backend", ["compiled", "numpy"])
def test_aligned_estimator_sees_no_false_force_when_the_vehicle_tilts(backend):
    """Ideal vehicle (no payload, no drag, exact inertia), 20 ms position latency, real rotor lag, PD (the
    estimate does not feed back), a 1 m move: nothing external acts, so the estimate should stay near 0.
    Read at face value (the paper) the delayed velocity against the present tilt shows a false force;
    aligned to the latencies and through the rotor model the false force shrinks by more than half."""
    spec = apply_overrides(get("case-a-payload"), [
        "payload.mass=0", "plant.rotor_drag=0", "plant.inertia_scale=1", "plant.drag_factor_scale=1",
        "trajectory.start_on_ground=false", "trajectory.hover_duration=0.5", "trajectory.move_offset=[1, 0, 0]",
        "trajectory.move_duration=1.5", "trajectory.move_hold=1", "sensors.pos_noise=0", "sensors.vel_noise=0",
        "sensors.att_noise=0", "sensors.gyro_noise=0", "plant.rotor_tau_up=0.019", "plant.rotor_tau_down=0.019",
    ])  # fmt: skip
    rms = {}
    for timing in (False, True):
        r = simulate(set_value(spec, "control.estimator_timing", timing), ["pd"], backend=backend)
        rms[timing] = float(np.sqrt(np.mean(np.sum(r["f_hat_W"][0] ** 2, -1))))
    assert rms[True] < 0.5 * rms[False]
    # the effect is there to remove: the threshold of the former 5.5 s flight (0.05 N), scaled to this 3 s one
    # (the estimate is ~0 outside the move, so the sum of squares is the same)
    assert rms[False] > 0.05 * np.sqrt(5.5 / 3.0)


# ----------------------------------------------------------------------------- the design and the defaults


def test_paper_setup_is_thin_and_the_check_says_so():
    """The paper's gains without payload: PD keeps under 10 deg, PD+C is unstable; the designed defaults
    keep every controller above the thresholds."""
    spec = set_value(get("case-a-payload"), "payload.mass", 0.0)
    paper = scenario_margins(_paper(spec), ["pd", "pdc"])
    assert paper["pd"].stable and paper["pd"].summary()["pm_min_deg"] < 10.0
    assert not paper["pdc"].stable
    assert paper["pdc"].violations()[0].startswith("unstable")
    assert all(np.isnan(m.phase_deg) for m in paper["pdc"].loops.values())  # never a positive margin
    designed = scenario_margins(spec, ["pd", "pid", "pdc"])
    assert all(not r.violations() for r in designed.values())


@pytest.mark.parametrize("vehicle", ["pelican", "pelican-x", "hexarotor"])
def test_defaults_never_make_the_hover_worse_than_pd(vehicle):
    """With and without payload, on the nominal timing and on slower rotors with longer latency: PD+C is
    no worse than PD, or the margin check said before the flight that it might be."""
    base = apply_overrides(get("case-a-payload"), [f"vehicle={vehicle}", "trajectory.hover_duration=12"])
    for sets in (["payload.mass=0"], [], ["payload.mass=0", "plant.rotor_tau_down=0.05", "sensors.mocap_delay=0.03"]):
        spec = apply_overrides(base, sets)
        warned = bool(scenario_margins(spec, ["pdc"])["pdc"].violations())
        r = simulate(spec, ["pd", "pdc"])
        from vtol_impedance.analysis.metrics import compute_metrics

        pd, pdc = (m["rms_ep_cm"] for m in compute_metrics(r))
        assert warned or pdc <= pd * 1.05 + 0.02, (vehicle, sets, pd, pdc)


def test_design_is_reproducible_and_its_rule_holds():
    from vtol_impedance.model import load_preset
    from vtol_impedance.robust.design import COMPENSATION_COST_DEG, design

    v = load_preset("pelican")
    d = design(v, 16.0, 12.0)
    assert d.wn_o > 12.0 / 1.2  # the attitude loop above the position loop's Dp/m
    assert d.wn_o_yaw <= d.wn_o and d.attitude_filter_wn >= d.wn_o
    assert d.estimator_wn in (4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 15.0)
    assert d.worst_pdc["stable"] == 1.0
    assert d.worst_pdc["pm_min_deg"] >= Thresholds().phase_deg
    assert d.worst_pd["pm_min_deg"] - d.worst_pdc["pm_min_deg"] <= COMPENSATION_COST_DEG + 1e-9
    assert design(v, 16.0, 12.0) == d  # cached, the same answer


def test_designed_controller_follows_its_own_advice_and_warns_where_thin():
    """The DesignError's advice is gains the design accepts (numbers read off the message, not computed
    here): their PD loop is stable on every plant of the design set, where the refused gains' is not on
    the nominal one; the thin result's notes reach the caller as a DesignWarning, while the paper's
    setup at 100 Hz gives none."""
    import re
    import warnings

    from vtol_impedance.model import load_preset
    from vtol_impedance.robust import DesignError, DesignWarning, designed_controller
    from vtol_impedance.robust.design import PLANT_SET, Timing, _plant, _sensors

    v = load_preset("pelican")
    with pytest.raises(DesignError, match="Dp must come down to") as exc:
        designed_controller(v, "pdc", Kp=16.0, Dp=12.0, rate=10.0)
    dp, kp = (float(x) for x in re.search(r"to ([\d.]+) N s/m or less \(Kp to ([\d.]+) N/m", str(exc.value)).groups())
    assert dp < 12.0 and kp < 16.0
    with pytest.warns(DesignWarning, match="PD\\+C may be worse than PD"):
        ctrl = designed_controller(v, "pdc", Kp=kp, Dp=dp, rate=10.0)
    assert ctrl.Ts == pytest.approx(0.1) and ctrl.gains.Dp[0] == pytest.approx(dp)
    t = Timing()
    pd = dataclasses.replace(ctrl, variant="pd")
    for inertia, payload in PLANT_SET:
        assert margins(linearize(pd, _plant(v, inertia, payload, t.rotor_tau), _sensors(t))).stable
    refused = dataclasses.replace(pd, gains=dataclasses.replace(pd.gains, Kp=np.full(3, 16.0), Dp=np.full(3, 12.0)))
    assert not margins(linearize(refused, _plant(v, 1.0, 0.0, t.rotor_tau), _sensors(t))).stable
    with warnings.catch_warnings():
        warnings.simplefilter("error", DesignWarning)
        designed_controller(v, "pdc", Kp=16.0, Dp=12.0)


# ----------------------------------------------------------------------------- bad input


def test_operating_point_beyond_the_rotors_is_refused():
    spec = set_value(get("case-a-payload"), "payload.mass", 5.0)
    with pytest.raises(TrimError, match="cannot hover here: it needs 60.8 N"):
        scenario_margins(spec, ["pd"])


def test_no_bandwidth_can_fly_it_names_the_limit(capsys, tmp_path):
    rc = main(["margins", "case-a-payload", "--set", "control.rate=10", "--out", str(tmp_path / "m"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "10 Hz control rate" in err and "Dp must come down" in err and "by hand" in err
    assert "Traceback" not in err and not (tmp_path / "m").exists()


def test_a_loop_too_large_to_analyse_is_refused_before_any_work(capsys, tmp_path, monkeypatch):
    """Latencies of many control periods become delay lines of six states each: a 1 s latency at 100 Hz
    (622 states) or the default 20 ms at 100 kHz is refused at once, naming the count and the latency, by
    the design (the run stops with the hand-set alternative) and by the pre-flight check (the flight goes
    on without margins when the bandwidths are set by hand). The count is the plant model's own size."""
    from vtol_impedance.robust import MAX_LOOP_STATES, LoopSizeError
    from vtol_impedance.sim import SensorParams

    ctrl = controller_params(get("case-a-payload"), "pd")
    plant = build(get("case-a-payload")).plant
    import vtol_impedance.robust.linear as lin

    def no_trim(*args, **kw):
        raise AssertionError("the trim ran: the size is checked after the work")

    with monkeypatch.context() as m:
        m.setattr(lin, "_trim", no_trim)  # refused before the trim, which took minutes at 100 kHz
        with pytest.raises(LoopSizeError, match=r"622 states, more than MAX_LOOP_STATES = 250: a 1000 ms position"):
            linearize(ctrl, plant, SensorParams(mocap_delay=1.0))
        fast = dataclasses.replace(ctrl, Ts=1e-5)
        with pytest.raises(LoopSizeError, match="2200 control periods at 100000 Hz"):
            linearize(fast, plant, SensorParams(), plant_rate=1e5)
    assert MAX_LOOP_STATES >= 34 + 6 * 18  # the default loop, and 1 kHz with its 20 ms latency, fit
    for sensors in (SensorParams(), SensorParams(mocap_delay=0.025), SensorParams(mocap_delay=0.02, imu_delay=0.0)):
        n = linearize(ctrl, plant, sensors).plant.nstates  # what sampled_plant built
        with monkeypatch.context() as m:
            m.setattr(lin, "MAX_LOOP_STATES", n)
            linearize(ctrl, plant, sensors)  # exactly at the bound: analysed
            m.setattr(lin, "MAX_LOOP_STATES", n - 1)
            with pytest.raises(LoopSizeError, match=f"have {n} states"):
                linearize(ctrl, plant, sensors)
    by_hand = ["--set", "control.wn_o=17", "--set", "control.wn_o_yaw=7", "--set", "control.attitude_filter_wn=25",
               "--set", "control.estimator_wn=8"]  # fmt: skip
    base = ["run", "case-a-payload", "--set", "sensors.mocap_delay=1.0", "--duration", "0.3", "--no-plots", "--quiet"]
    assert main([*base, "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "MAX_LOOP_STATES" in err and "by hand" in err and "Traceback" not in err
    assert main([*base, *by_hand, "--out", str(tmp_path / "b")]) == 0
    assert "no margins, the linearised loop would have" in capsys.readouterr().err


def test_bad_arguments_are_named():
    ctrl = controller_params(get("case-a-payload"), "pdc")
    plant = build(get("case-a-payload")).plant
    with pytest.raises(InputError, match="unknown loop"):
        linearize(ctrl, plant).loop("elevator")
    with pytest.raises(InputError, match="controller must be a ControllerParams"):
        linearize("pdc", plant)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="comply"):
        operating_point(ctrl, plant, comply=[2.0, 0.0, 0.0])
    with pytest.raises(InputError, match="phase_deg"):
        Thresholds(phase_deg=-5.0)
    with pytest.raises(InputError, match="rotors"):
        linearize(ctrl, dataclasses.replace(plant, vehicle=build(set_value(get("case-a-payload"), "vehicle",
                                                                         "hexarotor")).plant.vehicle))  # fmt: skip
    with pytest.raises(ScenarioError, match="control.wn_o"):
        set_value(get("case-a-payload"), "control.wn_o", "fast")


def test_margins_command_writes_its_report(tmp_path, capsys):
    out = tmp_path / "m"
    assert main(["margins", "case-a-payload", "--controllers", "pd,pdc", "--set", "payload.mass=0", "--out",
                 str(out), "--quiet"]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert "roll torque" in text and "every controller meets the thresholds" in text
    data = json.loads((out / "case-a-payload-v1.margins.json").read_text())
    assert set(data) == {"pd", "pdc"} and data["pdc"]["summary"]["stable"] == 1.0
    for f in ("report.html", "manifest.json", "case-a-payload-v1_margins_bode.png",
              "case-a-payload-v1_margins_nyquist.png", "case-a-payload-v1_margins_poles.png"):  # fmt: skip
        assert (out / f).is_file(), f


def test_run_warns_before_flying_a_thin_loop(tmp_path, capsys):
    args = ["run", "case-a-payload", "--set", "payload.mass=0", "--duration", "1", "--no-plots", "--out",
            str(tmp_path / "r"), *(f"--set={k}={json.dumps(v)}" for k, v in PAPER_CONTROL.items())]  # fmt: skip
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "warning: stability margins below the thresholds" in err and "unstable" in err
    assert err.index("warning: stability margins") < err.index("results written")
    assert (tmp_path / "r" / "case-a-payload-v1.margins.json").is_file()


# ----------------------------------------------------------------------------- the robustness study


def test_the_check_predicts_which_cells_oscillate(tmp_path):
    """A corner of the built-in robustness study, straddling the edge: the model's verdict (closed loop
    unstable) against the flights (PD+C above 0.5 cm RMS or failed) in at least 95 % of the cells, and
    wherever the check passes PD+C is no worse than PD."""
    from vtol_impedance.sweeps import from_dict, run_sweep, summarise
    from vtol_impedance.sweeps.report import margin_agreement

    study = {
        "name": "robust-corner", "base": "case-a-payload", "controllers": ["pd", "pdc"], "seeds": 1, "seed": 7,
        "chunk": 8, "set": {"trajectory": {"hover_duration": 30.0}},
        "axes": {
            "payload.mass": [0.0, 0.12],
            "plant.inertia_scale": [[1.0, 1.0, 1.0], [1.3, 1.3, 1.3]],
            "plant.rotor_tau_up,plant.rotor_tau_down": [[0.01333, 0.02667], [0.03333, 0.06667]],
            "sensors.mocap_delay": [0.01, 0.02, 0.03, 0.04],
        },
    }  # fmt: skip
    run_sweep(from_dict(study), tmp_path / "s", show_progress=False)
    s = summarise(tmp_path / "s")
    a = margin_agreement(s)["pdc"]
    assert a["oscillating"] >= 5 and a["cells"] - a["oscillating"] >= 15  # both kinds are there to predict
    assert a["agreement"] >= 0.95
    c = s["cols"]
    pdc, pd = c["controller"] == "pdc", c["controller"] == "pd"
    ok = c["margin_ok"][pdc].astype(float) > 0.5
    ratio = c["rms_ep_cm"][pdc].astype(float) / c["rms_ep_cm"][pd].astype(float)
    assert ok.sum() >= 10 and np.all(ratio[ok] <= 1.0)
