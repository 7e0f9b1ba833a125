"""Checks written for the bugs a fourth mutation campaign planted outside the compiled core (most of which no
other test caught), each failing on its bug:
the metrics of a result (tail window, saturation share, unit factors), sweep grids, resuming and tuning
costs, the scenario registry and ``--set`` rules, Monte-Carlo populations, the sensor latencies, the analytic
disturbances (fan jet, push, wall, gust, Dryden scales, a sinusoid's aliasing bound), an ENU heading and
the loop margins of loops whose answer is known in closed form. Every expected number here is worked out
by hand from the rule a docstring states (quoted in each test), never read off the code's own output."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vtol_impedance.sim.result import Result, compute_metrics, window_mask_of

# --------------------------------------------------------------------------- metrics of a result


def _result(t, ep_x, *, sat=None, tilt=None, tau_err=0.0, window=None) -> Result:
    """One vehicle whose position error is ``ep_x`` (m) along x, everything else exact."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    z3 = np.zeros((1, n, 3))
    p = z3.copy()
    p[0, :, 0] = ep_x
    tau_hat = z3.copy()
    tau_hat[0, :, 2] = tau_err
    data = {"p_W": p, "p_ref_W": z3.copy(), "v_W": z3.copy(), "v_ref_W": z3.copy(), "f_hat_W": z3.copy(),
            "f_lumped_W": z3.copy(), "tau_hat_eta": tau_hat, "tau_lumped_eta": z3.copy(),
            "saturated": np.zeros((1, n)) if sat is None else np.asarray(sat, dtype=float)[None]}  # fmt: skip
    if tilt is not None:
        data["tilt_limited"] = np.asarray(tilt, dtype=float)[None]
    return Result(t, ["pdc"], data, {"window": window} if window else {}, [None])


def test_steady_error_is_the_mean_over_the_last_five_seconds():
    """'ss_ep_cm is the mean |e_p| over the last STEADY_TAIL_S (5) seconds of the window': with |e_p| = t cm
    at t = 0..20 s the last five seconds hold 15..20 cm, whose mean is 17.5 cm (the first five: 2.5 cm)."""
    t = np.arange(21.0)
    row = compute_metrics(_result(t, 0.01 * t))[0]
    assert row["ss_ep_cm"] == pytest.approx(17.5)
    assert row["max_ep_cm"] == pytest.approx(20.0)


def test_the_saturation_share_counts_either_limit():
    """'any limit: the rotor allocation or the tilt/lift bound of eq. (16)': one tick at the rotor limit and
    another at the tilt bound out of four are half the window limited."""
    row = compute_metrics(_result(np.arange(4.0), np.zeros(4), sat=[1, 0, 0, 0], tilt=[0, 1, 0, 0]))[0]
    assert row["sat_pct"] == pytest.approx(50.0)


def test_the_moment_error_is_reported_in_millinewton_metres():
    """``rms_tau_err_mNm`` is 'RMS |tau_hat - tau| [mN m]': a constant 2e-3 N m error is 2 mN m; and the RMS
    of |e_p| alternating 3 and 4 cm is sqrt((9 + 16) / 2) = 3.536 cm, not the mean 3.5."""
    row = compute_metrics(_result(np.arange(4.0), [0.03, 0.04, 0.03, 0.04], tau_err=2e-3))[0]
    assert row["rms_tau_err_mNm"] == pytest.approx(2.0)
    assert row["rms_ep_cm"] == pytest.approx(math.sqrt(12.5))


def test_a_window_of_one_sample_falls_back_to_the_whole_run():
    """'a window holding fewer than two samples ... falls back to the whole run'; one of two is kept."""
    t = np.arange(5.0)
    assert window_mask_of(t, (1.5, 2.2)).all()  # only t = 2 inside
    assert window_mask_of(t, (1.0, 2.0)).tolist() == [False, True, True, False, False]  # both ends inside


# --------------------------------------------------------------------------- sweeps and tuning


def test_a_log_range_is_drawn_log_uniformly():
    """Random mode draws 'uniform over the range (in log with log)': on 1..1e4 in log the median is near
    sqrt(1 * 1e4) = 100 and a quarter of the draws fall below 10; uniform draws would sit near 5000."""
    from vtol_impedance.sweeps.spec import Axis

    a = Axis("control.Kp", lo=1.0, hi=1e4, log=True)
    rng = np.random.default_rng(3)
    x = np.array([a.draw(rng) for _ in range(4000)])
    assert 1.0 <= x.min() and x.max() <= 1e4
    assert 60.0 < np.median(x) < 160.0
    assert np.mean(x < 10.0) == pytest.approx(0.25, abs=0.03)


def test_a_chunks_units_are_the_same_slice_of_all_units():
    """``chunk_units(k)`` is 'the same as units[k * chunk : (k + 1) * chunk]', seeds included."""
    from vtol_impedance.sweeps.spec import from_dict

    sw = from_dict({"name": "s", "base": "case-a-payload", "seeds": 3, "chunk": 4,
                    "axes": {"payload.mass": [0.1, 0.2, 0.3]}}, check_points=False)  # fmt: skip
    units = sw.units
    assert sw.n_chunks == 3  # 9 units in chunks of 4
    for k in range(sw.n_chunks):
        assert sw.chunk_units(k) == units[k * 4 : (k + 1) * 4]


def _tuning(cost: dict, search=None):
    from vtol_impedance.sweeps.tune import tuning_from_dict

    search = search or {"control.Kp": {"min": 8.0, "max": 30.0}}
    return tuning_from_dict({"name": "t", "base": "case-a-payload", "search": search, "cost": cost},
                            check_corners=False)  # fmt: skip


def test_a_member_exactly_at_the_phase_margin_asked_for_is_not_penalised():
    """The margin penalty is 'for every member whose linearised loop is unstable or keeps less than
    min_phase_margin_deg': 20 deg kept of 20 asked is not less."""
    from vtol_impedance.sweeps.tune import trial_cost

    t = _tuning({"min_phase_margin_deg": 20.0, "margin_penalty": 100.0})
    rows = {"rms_ep_cm": [2.0, 4.0], "sat_pct": [0.0, 0.0], "diverged": [False, False],
            "margin_stable": [1.0, 1.0], "pm_min_deg": [20.0, 19.5]}  # fmt: skip
    cost, parts = trial_cost(t, rows)
    assert parts["below_margin"] == 1
    assert cost == pytest.approx((2.0 + 4.0 + 100.0) / 2)


def test_a_best_value_near_the_end_of_a_log_range_is_judged_on_the_log_scale():
    """A note for 'each best value within 1 % of its search range's end (log scale for log ranges)': on
    1..1e4 in log, 2 is log(2)/log(1e4) = 7.5 % of the way (no note; linearly it would be 0.01 %), 1.05 is
    0.5 % (a note)."""
    from vtol_impedance.sweeps.tune import bound_notes

    t = _tuning({}, {"control.Kp": {"min": 1.0, "max": 1e4, "log": True}})
    assert bound_notes(t, {"control.Kp": 2.0}) == []
    assert len(bound_notes(t, {"control.Kp": 1.05})) == 1


def test_a_vector_and_its_entry_overlap_two_entries_do_not():
    """``keys_overlap``: 'the same key, or a vector and one of its entries (payload.offset_B and
    payload.offset_B[0]); two entries of one vector are two values'."""
    from vtol_impedance.scenarios.spec import keys_overlap

    assert keys_overlap("payload.offset_B", "payload.offset_B[0]")
    assert keys_overlap("payload.offset_B[0]", "payload.offset_B")
    assert not keys_overlap("payload.offset_B[0]", "payload.offset_B[1]")
    assert not keys_overlap("payload.mass", "payload.offset_B")


def test_a_chunk_whose_traces_are_lost_is_flown_again(tmp_path):
    """A sweep that keeps traces writes them 'first: a chunk counts as done when its rows exist' (rows written
    after their traces); a chunk whose rows are on disk but whose traces are not is therefore unfinished, and
    resuming computes it again (a dataset must not come back with a chunk's traces missing)."""
    from vtol_impedance.sweeps.run import SweepFolder, chunk_name
    from vtol_impedance.sweeps.spec import from_dict

    sw = from_dict({"name": "tr", "base": "case-a-payload", "controllers": ["pdc"], "seeds": 1, "chunk": 1,
                    "traces": 10, "axes": {"payload.mass": [0.1, 0.2]}}, check_points=False)  # fmt: skip
    folder = SweepFolder(sw, tmp_path / "sweep")
    try:
        for k in range(2):
            (u,) = sw.chunk_units(k)
            rows = {"unit": [u.index], "point": [u.point], "seed": [u.seed], "controller": ["pdc"],
                    "payload.mass": [sw.points[u.point]["payload.mass"]]}  # fmt: skip
            folder.write_chunk(k, rows, {"unit": [u.index], "t_s": [0.0]})
        assert folder.missing() == []
        (folder.traces / chunk_name(1)).unlink()
        assert folder.missing() == [1]
    finally:
        folder.close()


# --------------------------------------------------------------------------- scenarios


def test_a_name_without_a_version_means_the_highest_version():
    """'a name without a version means the latest' and ``names(latest_only=True)`` lists only the latest of
    each: versions compare as numbers (v10 after v2), whatever order they were registered in."""
    from vtol_impedance.scenarios.registry import Registry
    from vtol_impedance.scenarios.spec import ScenarioSpec

    reg = Registry()
    for n in ("hop-v2", "hop-v10", "hop-v1", "other-v3"):
        reg.register(ScenarioSpec(name=n))
    assert reg.resolve("hop") == "hop-v10"
    assert reg.names(latest_only=True) == ["hop-v10", "other-v3"]
    assert reg.resolve("hop-v1") == "hop-v1"


def test_ranges_honour_their_open_low_end_and_closed_high_end():
    """RANGES gives '(low, high, low excluded)': trajectory.altitude's low end 0 is excluded, the high
    ends are included (thrust_shift_max may be 1, a latency the 1 s MAX_DELAY_S)."""
    from vtol_impedance.errors import ScenarioError
    from vtol_impedance.scenarios.spec import ScenarioSpec, set_value

    spec = ScenarioSpec(name="r-v1")
    with pytest.raises(ScenarioError, match="trajectory.altitude"):
        set_value(spec, "trajectory.altitude", 0.0)
    with pytest.raises(ScenarioError, match="trajectory.circle_speed"):
        set_value(spec, "trajectory.circle_speed", 0.0)
    assert set_value(spec, "control.thrust_shift_max", 1.0).control.thrust_shift_max == 1.0
    assert set_value(spec, "sensors.mocap_delay", 1.0).sensors.mocap_delay == 1.0


def test_set_splits_at_the_first_equals_sign():
    """``--set`` takes 'key=value': the key ends at the first '=', the rest is the value."""
    from vtol_impedance.scenarios.spec import ScenarioSpec, apply_overrides

    spec = apply_overrides(ScenarioSpec(name="s-v1"), ["description=a=b"])
    assert spec.description == "a=b"


def _hand_tuned(**control):
    from vtol_impedance.scenarios.spec import ControlSpec, ScenarioSpec

    c = dict(wn_o=8.0, wn_o_yaw=8.0, attitude_filter_wn=30.0, estimator_wn=10.0) | control
    return ScenarioSpec(name="h-v1", control=ControlSpec(**c))


def test_the_assumed_latencies_are_the_sensors_own():
    """``velocity_delay``/``attitude_delay`` left unset are 'the sensor model's': the velocity comes from the
    motion capture (mocap_delay), the attitude from the IMU (imu_delay)."""
    from dataclasses import replace

    from vtol_impedance.scenarios.spec import assumed_timing
    from vtol_impedance.sim.sensors import SensorParams

    spec = replace(_hand_tuned(), sensors=SensorParams(mocap_delay=0.03, imu_delay=0.004))
    t = assumed_timing(spec)
    assert (t.velocity_delay, t.attitude_delay) == (0.03, 0.004)


def test_the_moment_channels_take_their_own_estimator_bandwidth():
    """'estimator_wn: the estimator's bandwidth (rad/s), and of its moment channels too unless
    estimator_wn_moment sets theirs'."""
    from vtol_impedance.scenarios.spec import controller_params

    wn = np.asarray(controller_params(_hand_tuned(estimator_wn_moment=4.0), "pdc").estimator.wn)
    assert wn.tolist() == [10.0, 10.0, 10.0, 4.0, 4.0, 4.0]
    wn = np.asarray(controller_params(_hand_tuned(), "pdc").estimator.wn)
    assert wn.tolist() == [10.0] * 6


def test_a_population_spreads_both_ways_and_moves_both_gains():
    """'Payload mass varies by +-payload_spread (relative) ... and Kp/Dp by +-gain_spread (relative,
    uniform)': over 60 members the payload lies on both sides of the scenario's, within +-50 %, and Dp
    moves (within +-10 %) as Kp does."""
    from vtol_impedance.scenarios.batch import population

    spec = _hand_tuned()
    plants, ctrls, seeds = population(spec, 60, seed=4)
    m0 = spec.payload.mass
    m = np.array([p.payload_mass for p in plants])
    assert m.min() < 0.8 * m0 and m.max() > 1.2 * m0 and np.all(np.abs(m / m0 - 1) <= 0.5 + 1e-12)
    kp = np.array([np.ravel(c.gains.Kp)[0] for c in ctrls]) / spec.control.Kp
    dp = np.array([np.ravel(c.gains.Dp)[0] for c in ctrls]) / spec.control.Dp
    for k in (kp, dp):
        assert k.min() < 0.97 and k.max() > 1.03 and np.all(np.abs(k - 1) <= 0.1 + 1e-12)
    assert len(set(seeds)) == 60


# --------------------------------------------------------------------------- model


def test_the_thrust_given_up_is_what_the_rotors_produce_minus_the_request():
    """Allocation: ``thrust`` is 'what those forces produce' and ``thrust_shift`` 'N, collective moved away
    from the request': for a pure collective beyond four 5 N rotors (30 N asked) they produce 20 N, so the
    shift is 20 - 30 = -10 N (thrust = request + shift)."""
    from vtol_impedance.model import load_preset
    from vtol_impedance.model.mixer import allocate

    g = load_preset().geometry
    n = g.E.shape[1]
    a = allocate(np.array(30.0), np.zeros(3), g.E, g.E_pinv, np.zeros(n), np.full(n, 5.0))
    assert float(a.thrust) == pytest.approx(5.0 * n)
    assert float(a.thrust_shift) == pytest.approx(5.0 * n - 30.0)
    assert bool(a.saturated)


def test_q_dot_is_the_time_derivative_of_q():
    """``euler_rate_matrix_Q_dot`` is the 'time derivative of euler_rate_matrix_Q': a central difference of
    Q along eta(t) = eta0 + eta_dot t agrees to O(h^2)."""
    from vtol_impedance.model.kinematics import euler_rate_matrix_Q, euler_rate_matrix_Q_dot

    eta0, eta_dot, h = np.array([0.4, -0.3, 1.1]), np.array([0.7, -1.3, 0.2]), 1e-6
    num = (euler_rate_matrix_Q(eta0 + h * eta_dot) - euler_rate_matrix_Q(eta0 - h * eta_dot)) / (2 * h)
    np.testing.assert_allclose(euler_rate_matrix_Q_dot(eta0, eta_dot), num, atol=1e-8)


def test_an_enu_heading_is_measured_from_east():
    """'ENU measures counter-clockwise from east, psi_NED = pi/2 - psi_ENU': facing east (ENU yaw 0) is NED
    yaw +pi/2, facing north (ENU yaw pi/2) is NED yaw 0; a NED heading passes unchanged."""
    from vtol_impedance.model.frames import heading_to_ned

    assert float(heading_to_ned(0.0, "enu")) == pytest.approx(np.pi / 2)
    assert float(heading_to_ned(np.pi / 2, "enu")) == pytest.approx(0.0)
    assert float(heading_to_ned(0.3, "ned")) == pytest.approx(0.3)


# --------------------------------------------------------------------------- sensors


def test_latencies_round_to_the_nearest_plant_step():
    """'a latency between two steps flies rounded to the nearest': 3 ms at 1 kHz is 3 steps (3e-3 / 1e-3 is
    2.9999999999999996 in floating point), 2.6 ms is 3, 2.4 ms is 2."""
    from vtol_impedance.sim.sensors import SensorParams, latency_steps

    assert latency_steps(SensorParams(mocap_delay=0.003, imu_delay=0.0026), 1e-3) == (3, 3)
    assert latency_steps(SensorParams(mocap_delay=0.0024, imu_delay=0.0), 1e-3) == (2, 0)


def test_a_delayed_sensor_reads_the_state_exactly_its_latency_ago():
    """'Each sensor reads the true state some time ago (latency, an integer number of plant steps)': with
    the motion capture 2 steps late and the IMU on time, after states 0..5 it reads state 3 and the IMU 5."""
    from vtol_impedance.sim.sensors import SensorParams, SensorSuite

    suite = SensorSuite(SensorParams(mocap_delay=0.002, imu_delay=0.0), None, 1e-3)  # type: ignore[arg-type]
    for i in range(6):
        suite.push(np.array([float(i)]))
    mocap, imu = suite.delayed()
    assert (float(mocap[0]), float(imu[0])) == (3.0, 5.0)


# --------------------------------------------------------------------------- disturbances


def test_the_fan_jet_follows_its_stated_law():
    """'mean_force * ref_distance / max(s, ref_distance/2) * exp(-r^2 / (2 width^2))' along the jet, and the
    moment is the centre of pressure's lever arm crossed with the force (tau = r x f)."""
    from vtol_impedance.sim.disturbances import FanJet

    fan = FanJet(position_W=(0.0, 0.0, 0.0), direction_W=(1.0, 0.0, 0.0), mean_force=1.0, ref_distance=0.2,
                 width=0.2, turbulence=0.0, cop_offset_B=(0.0, 0.0, -0.03))  # fmt: skip
    R = np.eye(3)
    z = np.zeros(3)
    f, tau = fan(1.0, np.array([0.15, 0.0, 0.0]), z, R)  # s = 0.15 > 0.1: 0.2 / 0.15
    np.testing.assert_allclose(f, [0.2 / 0.15, 0.0, 0.0], rtol=1e-12)
    # r x f with r = (0, 0, -0.03), f = (F, 0, 0): (0, -0.03 F, 0)
    np.testing.assert_allclose(tau, [0.0, -0.03 * 0.2 / 0.15, 0.0], rtol=1e-12, atol=1e-15)
    f, _ = fan(1.0, np.array([0.4, 0.1, 0.0]), z, R)  # s = 0.4, r = 0.1
    assert f[0] == pytest.approx(0.2 / 0.4 * math.exp(-0.01 / (2 * 0.04)), rel=1e-12)


def test_a_push_is_a_half_sine():
    """'a half-sine force pulse of peak force_W from t_on lasting duration': a quarter in, sin(pi/4) of it."""
    from vtol_impedance.sim.disturbances import Push

    push = Push(force_W=(2.0, 0.0, 0.0), t_on=1.0, duration=1.0)
    f, _ = push(1.25, np.zeros(3), np.zeros(3), np.eye(3))
    assert f[0] == pytest.approx(2.0 * math.sin(math.pi / 4))
    assert push(1.5, np.zeros(3), np.zeros(3), np.eye(3))[0][0] == pytest.approx(2.0)


def test_a_sinusoid_above_a_quarter_of_the_plant_rate_is_refused():
    """'Refuse a frequency the plant's steps cannot carry: above a quarter of the plant rate the held samples
    alias it; a quarter itself, four samples a period, is the last carried': at 1 kHz, 300 Hz, 400 Hz and
    just above 250 Hz are refused, 250 Hz and 200 Hz are flown."""
    from vtol_impedance.errors import InputError
    from vtol_impedance.sim.disturbances import SinusoidWrench

    rng = np.random.default_rng(0)
    for f in (300.0, 400.0, 250.001):
        with pytest.raises(InputError, match="quarter of the plant rate"):
            SinusoidWrench(force_W=(1.0, 0.0, 0.0), freq_hz=f).prepare(1.0, 1e-3, rng)
    for f in (200.0, 250.0):
        SinusoidWrench(force_W=(1.0, 0.0, 0.0), freq_hz=f).prepare(1.0, 1e-3, rng)


def test_a_wall_pushes_never_pulls_and_its_friction_opposes_sliding():
    """'F_n = max(stiffness (-g) - damping (v . n), 0) along n (a wall pushes, never pulls) and rubs with
    mu F_n against the sliding velocity'."""
    from vtol_impedance.sim.disturbances import Wall

    wall = Wall(position_W=(1.0, 0.0, 0.0), normal_W=(-1.0, 0.0, 0.0), stiffness=2000.0, damping=60.0,
                friction=0.3, slip_speed=0.01)  # fmt: skip
    p = np.array([1.001, 0.0, 0.0])  # 1 mm in
    f, _ = wall(0.0, p, np.array([-1.0, 0.0, 0.0]), np.eye(3))  # leaving fast: 2 N - 60 N < 0
    np.testing.assert_array_equal(f, np.zeros(3))
    f, _ = wall(0.0, p, np.array([0.0, 0.5, 0.0]), np.eye(3))  # sliding along +y
    np.testing.assert_allclose(f, [-2.0, -0.3 * 2.0, 0.0], rtol=1e-12)


def test_a_one_minus_cosine_gust_peaks_at_its_amplitude():
    """'a 1-cosine gust amplitude/2 (1 - cos(2 pi (t - start)/length))': at mid-gust the wind is the amplitude."""
    from vtol_impedance.sim.disturbances import Gust

    g = Gust(direction_W=(1.0, 0.0, 0.0), mean_speed=0.0, amplitude=3.0, start=10.0, length=2.0)
    np.testing.assert_allclose(g.wind_W(np.array([9.0, 10.5, 11.0])), [[0, 0, 0], [1.5, 0, 0], [3.0, 0, 0]],
                               atol=1e-12)  # fmt: skip


def test_dryden_scales_at_ten_metres():
    """MIL-F-8785C low altitude: 'L_w = h, L_u = L_v = h / (0.177 + 0.000823 h)^1.2, sigma_u = sigma_v =
    sigma_w / (0.177 + 0.000823 h)^0.4 with h in feet': at 10 m (32.81 ft), k = 0.2040."""
    from vtol_impedance.sim.disturbances import dryden_filters

    h_ft = 10.0 / 0.3048
    k = 0.177 + 0.000823 * h_ft
    (su, Lu, _), (sv, Lv, _), (sw, Lw, _) = dryden_filters(1.0, 10.0)
    assert Lw == pytest.approx(10.0)
    assert Lu == Lv == pytest.approx(10.0 / k**1.2)
    assert su == sv == pytest.approx(1.0 / k**0.4)
    assert sw == 1.0


# --------------------------------------------------------------------------- loop margins


def _margins(L):
    from vtol_impedance.robust.margins import loop_margins

    return loop_margins("x", L)


def test_margins_of_a_sampled_integrator_in_closed_form():
    """L(z) = K Ts / (z - 1): |L| = 1 where 2 sin(w Ts / 2) = K Ts, with angle(L) = -(90 deg + w Ts / 2), so
    the phase margin is 90 deg - w_c Ts / 2 and the delay margin that phase (rad) over w_c; at Nyquist
    L = -K Ts / 2, a gain margin up of 20 log10(2 / (K Ts)) and none down; the sensitivity peak
    |z - 1| / |z - 1 + K Ts| is largest at z = -1: 2 / (2 - K Ts)."""
    import control as ct

    K, Ts = 20.0, 0.01
    m = _margins(ct.ss([[1.0]], [[1.0]], [[K * Ts]], [[0.0]], Ts))
    th = 2 * math.asin(K * Ts / 2)
    wc = th / Ts
    pm = 90.0 - math.degrees(th) / 2
    assert m.crossover == pytest.approx(wc, rel=1e-5)
    assert m.phase_deg == pytest.approx(pm, rel=1e-5)
    assert m.delay_s == pytest.approx(math.radians(pm) / wc, rel=1e-5)
    assert m.gain_up_db == pytest.approx(20 * math.log10(2 / (K * Ts)), rel=1e-6)
    assert m.gain_down_db == math.inf and m.gain_db == m.gain_up_db
    assert m.sensitivity_peak == pytest.approx(2 / (2 - K * Ts), rel=1e-6)


def test_a_loop_that_fails_when_its_gain_is_lowered_has_a_positive_downward_margin():
    """L(z) = 2 / z never crosses |L| = 1 and is -2 at Nyquist: the gain may fall by 1/2 (6.02 dB) before
    the loop reaches -1; 'the smaller of the upward and downward gain margins' is then 6.02 dB."""
    import control as ct

    m = _margins(ct.ss([[0.0]], [[1.0]], [[2.0]], [[0.0]], 0.01))
    assert m.gain_down_db == pytest.approx(20 * math.log10(2.0), rel=1e-9)
    assert m.gain_up_db == math.inf
    assert m.gain_db == pytest.approx(20 * math.log10(2.0), rel=1e-9)
    assert m.phase_deg == math.inf
