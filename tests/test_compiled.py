"""The compiled (numba) backend against the NumPy reference backend, the test oracle."""

from dataclasses import replace

import numpy as np
import pytest

from vtol_impedance import Controller
from vtol_impedance.analysis import compute_metrics
from vtol_impedance.control import ControllerParams, Measurement, Reference
from vtol_impedance.control.reference import Hold, Trajectory
from vtol_impedance.errors import InputError, SingularityError
from vtol_impedance.model import load_preset
from vtol_impedance.scenarios import PAPER_CASES, apply_overrides, build, controller_params, get, set_value, simulate
from vtol_impedance.sim import PlantParams, SensorParams, run_closed_loop


def _rel_diff(a, b):
    scale = max(float(np.nanmax(np.abs(a))), 1e-9)
    both_nan = np.isnan(a) & np.isnan(b)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    return float(np.max(np.where(both_nan, 0.0, np.abs(a - b)))) / scale


#: Case C is left out: its first 5 s (ground, take-off; the circle starts at 10 s) are case A's flight bit for
#: bit. The circle is flown by both backends in test_log_modes_agree.
#: twist-v1: comply on the Euler angles (the attitude's blend), which no other case here exercises.
@pytest.mark.parametrize("name", [c for c in PAPER_CASES if c != "case-c-circle"] + ["operator-push", "yaw-step",
                                                                                      "twist-v1"])
def test_compiled_matches_numpy_over_5s_of_closed_loop(name):
    spec = set_value(get(name), "duration", 5.0)
    if name == "operator-push":  # move the push into the window, with comply on x and y from the start
        spec = apply_overrides(spec, ["disturbances.0.t_on=2.0", "interaction.switches=[]",
                                      "interaction.comply=[1.0,1.0,0.0]"])  # fmt: skip
    # the interaction cases fly "comply" too (the position's blend, the attitude's)
    variants = ("pd", "pdc", "comply") if name in ("operator-push", "twist-v1") else ("pd", "pid", "pdc")
    rn = simulate(spec, variants, backend="numpy")
    rc = simulate(spec, variants, backend="compiled")
    assert rn.failures == rc.failures
    for k in rn.data:
        assert _rel_diff(rn[k], rc[k]) <= 1e-9, k


@pytest.mark.parametrize("delays", [(0.013, 0.007), (0.005, 0.013), (0.027, 0.0)])
def test_sensor_delays_off_the_control_grid_read_the_same_states(delays):
    """Latencies that are not whole control periods: the compiled engine keeps only the past states a
    sensor will read, the NumPy reference keeps them all; both must read the same ones."""
    spec = set_value(get("case-a-payload"), "duration", 2.0)
    for name in ("pos_noise", "vel_noise", "att_noise", "gyro_noise"):
        spec = set_value(spec, f"sensors.{name}", 0.0)
    spec = set_value(spec, "sensors.mocap_delay", delays[0])
    spec = set_value(spec, "sensors.imu_delay", delays[1])
    rn = simulate(spec, ["pdc"], backend="numpy")
    rc = simulate(spec, ["pdc"], backend="compiled")
    for k in ("p_meas_W", "v_meas_W", "eta_meas", "p_W", "f_hat_W"):
        assert _rel_diff(rn[k], rc[k]) <= 1e-9, k
    # the measurement is the truth ``mocap_delay`` ago: between two ticks, so close to their interpolation
    # (within the curvature over a period), farther from either tick when the vehicle moves
    d = delays[0]
    lag = int(np.ceil(d / 0.01 - 1e-9))
    if 0 < d < lag * 0.01:
        p, pm = rc["p_W"][0], rc["p_meas_W"][0]
        k = np.arange(lag + 1, p.shape[0])
        w = (lag * 0.01 - d) / 0.01  # of the way from tick k - lag to k - lag + 1
        interp = (1 - w) * p[k - lag] + w * p[k - lag + 1]
        err = np.abs(pm[k] - interp).max()
        assert err < 5e-5
        assert np.abs(pm[k] - p[k - lag]).max() > 20 * err
        assert np.abs(pm[k] - p[k - lag + 1]).max() > 20 * err


def _population(n):
    veh = load_preset()
    plants = [
        PlantParams(veh, payload_mass=0.05 * i, payload_offset_B=(0.01 * i, -0.005 * i, 0.02), rotor_drag=0.18)
        for i in range(n)
    ]
    base = ControllerParams.paper("pdc")
    ctrls = [replace(base, gains=replace(base.gains, Kp=12.0 + 2 * i)) for i in range(n)]
    ctrls[1] = ControllerParams.paper("pid")
    return plants, ctrls


def test_a_batch_equals_single_runs():
    plants, ctrls = _population(4)
    traj = Trajectory((Hold((0, 0, -1.0), 3.0),))
    seeds = [3, 4, 5, 6]
    batch = run_closed_loop(plants, ctrls, traj, 3.0, seed=seeds)
    for i in range(4):
        one = run_closed_loop(plants[i], [ctrls[i]], traj, 3.0, seed=seeds[i])
        for k in one.data:
            np.testing.assert_array_equal(batch[k][i], one[k][0], err_msg=k)


def test_no_more_threads_than_vehicles_and_the_setting_restored(monkeypatch):
    """One vehicle flies on the calling thread (a second thread has nothing to do but must wake and join,
    which on a busy machine cost milliseconds per block); a batch gets every thread; the caller's setting
    comes back, also when the run fails."""
    import numba

    import vtol_impedance.compiled.engine as engine

    seen = []
    real = engine.run_block

    def spy(*args):
        seen.append(numba.get_num_threads())
        return real(*args)

    monkeypatch.setattr(engine, "run_block", spy)
    plants, ctrls = _population(3)
    traj = Trajectory((Hold((0, 0, -1.0), 0.2),))
    before = numba.get_num_threads()
    run_closed_loop(plants[0], ctrls[:1], traj, 0.2)
    run_closed_loop(plants, ctrls, traj, 0.2)
    assert seen == [1, min(3, before)] and numba.get_num_threads() == before

    def fail(*args):
        raise RuntimeError("in the kernel")

    monkeypatch.setattr(engine, "run_block", fail)
    with pytest.raises(RuntimeError):
        run_closed_loop(plants[0], ctrls[:1], traj, 0.2)
    assert numba.get_num_threads() == before


def test_case_c_starts_as_case_a_within_5s():
    """Why case C is not among the 5 s comparisons above: the same flight as case A there, bit for bit."""
    a = simulate(set_value(get("case-a-payload"), "duration", 5.0), ["pdc"])
    c = simulate(set_value(get("case-c-circle"), "duration", 5.0), ["pdc"])
    for k in a.data:
        np.testing.assert_array_equal(a[k], c[k], err_msg=k)


def test_log_modes_agree():
    # 3.15 s (no take-off, a tenth of a lap with a 0.5 s ramp, a short settle): the task window (0.8 s to 2.56 s)
    # still starts and ends inside the flight, so the in-kernel metrics must leave out samples on both sides of
    # it; the NumPy run is the slow one (15 s here, 42 s for the 7 s flight this test flew before)
    spec = apply_overrides(get("case-c-circle"), [
        "trajectory.start_on_ground=false", "trajectory.hover_duration=0.8", "trajectory.circle_laps=0.1",
        "trajectory.circle_ramp=0.5", "trajectory.settle_duration=0.6", "trajectory.land=false",
    ])  # fmt: skip
    full = simulate(spec)
    dec = simulate(spec, log="decimate:5")
    met = simulate(spec, log="metrics")
    dec_np = simulate(spec, backend="numpy", log="decimate:5")  # the NumPy backend's metrics: one code for both
    assert met.data == {} and dec.t.shape[0] == (full.t.shape[0] + 4) // 5
    np.testing.assert_array_equal(dec.t, full.t[::5])
    for k in full.data:
        np.testing.assert_array_equal(dec[k], full[k][:, ::5], err_msg=k)
    window = full.config["window"]
    assert 0.5 < window[0] and window[1] < full.t[-1] - 0.5  # premise: samples outside the window, both sides
    ref = compute_metrics(full)
    # a decimated run's metrics are those of every tick, not a recount on every 5th sample (a sweep's
    # "traces = K" changed its numbers)
    assert dec.metrics is not None and dec_np.metrics is not None and full.metrics is None
    for got in (compute_metrics(met), compute_metrics(dec), compute_metrics(dec_np)):
        for a, b in zip(ref, got, strict=True):
            assert a["controller"] == b["controller"]
            for key in (
                "rms_ep_cm",
                "max_ep_cm",
                "ss_ep_cm",
                "rms_ev_cms",
                "rms_f_err_N",
                "rms_tau_err_mNm",
                "sat_pct",
            ):
                assert b[key] == pytest.approx(a[key], rel=1e-9, abs=1e-12), key


def test_divergence_is_flagged_the_same_way_in_both_backends():
    veh = load_preset()
    good = PlantParams(veh, ground=False)
    bad = PlantParams(replace(veh, f_max=1e3), inertia_scale=(0.02, 0.02, 0.02), ground=False)
    traj = Trajectory((Hold((0, 0, -1.0), 2.0),))
    kw = dict(sensors=SensorParams(), seed=1, labels=["good", "bad"])
    runs = [
        run_closed_loop([good, bad], [ControllerParams.paper()] * 2, traj, 2.0, backend=b, **kw)
        for b in ("numpy", "compiled")
    ]
    assert runs[0].failures == runs[1].failures
    assert runs[1].failures[0] is None and runs[1].failures[1] is not None
    assert np.all(np.isfinite(runs[1]["p_W"][0]))


def test_embeddable_step_matches_the_reference_and_checks_inputs(rng):
    p = ControllerParams.paper("pdc")
    fast = Controller(p)
    ref_ctrl = Controller(p, backend="numpy")
    r = np.array([0.1, 0, -1, 0.2, 0, 0, 0.1, 0.2, 0, 0.3, 0.1, 0.0])
    ref = Reference(r[0:3], r[3:6], r[6:9], np.array(r[9]), np.array(r[10]), np.array(r[11]))
    for _ in range(30):
        y = np.concatenate(
            [rng.normal(0, 0.05, 3) + [0, 0, -1], rng.normal(0, 0.1, 3), rng.normal(0, 0.1, 3), rng.normal(0, 0.3, 3)]
        )
        out = fast.step_arrays(y, r)
        o_ref = ref_ctrl.step(Measurement(y[0:3], y[3:6], y[6:9], y[9:12]), ref)
        np.testing.assert_allclose(out["f_rotor"][:4], o_ref.f_rotor, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out["f_hat_W"], o_ref.f_hat_W, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(out["thrust"], o_ref.thrust, rtol=1e-12)
    bad = y.copy()
    bad[4] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        fast.step_arrays(bad, r)
    sing = y.copy()
    sing[7] = np.pi / 2
    with pytest.raises(SingularityError):
        fast.step_arrays(sing, r)


def test_bad_batch_arguments():
    veh = load_preset()
    traj = Trajectory((Hold((0, 0, -1.0), 1.0),))
    with pytest.raises(InputError, match="seeds"):
        run_closed_loop(PlantParams(veh), [ControllerParams.paper()] * 2, traj, 1.0, seed=[1, 2, 3])
    with pytest.raises(InputError, match="plants"):
        run_closed_loop([PlantParams(veh)] * 3, [ControllerParams.paper()] * 2, traj, 1.0)
    with pytest.raises(InputError, match="log"):
        run_closed_loop(PlantParams(veh), [ControllerParams.paper()], traj, 1.0, log="sometimes")
    with pytest.raises(InputError, match="backend"):
        run_closed_loop(PlantParams(veh), [ControllerParams.paper()], traj, 1.0, backend="gpu")


def test_spec_builders_are_shared_by_both_backends():
    spec = get("case-b-fan")
    b = build(spec)
    assert controller_params(spec, "pdc").variant == "pdc" and b.disturbances[0].kind == "fan"


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_a_crash_into_the_ground_is_flagged(backend):
    veh = load_preset()
    good = PlantParams(veh, ground=True)
    weak = PlantParams(replace(veh, f_max=0.5), ground=True)  # cannot lift itself: falls from 2 m
    traj = Trajectory((Hold((0, 0, -2.0), 2.0),))
    r = run_closed_loop([good, weak], [ControllerParams.paper()] * 2, traj, 2.0, backend=backend, seed=2)
    assert r.failures[0] is None
    assert r.failures[1] is not None and "crashed into the ground" in r.failures[1]["reason"]
    assert 0.5 < r.failures[1]["time"] < 0.9  # free fall from 2 m takes 0.64 s


def test_sensor_noise_drawn_in_the_kernel_is_the_stated_gaussian():
    """The compiled engine draws each vehicle's noise inside the kernel from the vehicle's own generator:
    the measurement minus the truth must be white, zero-mean and of the stated deviation on every channel,
    the same for the same seed and unrelated across seeds (independent of the NumPy backend)."""
    veh = load_preset()
    sens = SensorParams(pos_noise=2e-3, vel_noise=1e-2, mocap_delay=0.0, att_noise=5e-3, gyro_noise=1e-2, imu_delay=0.0)
    traj = Trajectory((Hold((0, 0, -1.0), 20.0),))
    plants = [PlantParams(veh, ground=False)] * 3
    ctrls = [ControllerParams.paper("pdc")] * 3
    r = run_closed_loop(plants, ctrls, traj, 20.0, sensors=sens, seed=[11, 12, 11])
    for meas, true, sigma in (("p_meas_W", "p_W", 2e-3), ("v_meas_W", "v_W", 1e-2), ("eta_meas", "eta", 5e-3)):
        n = (r[meas] - r[true]) / sigma  # (3 vehicles, N, 3 axes): standard normals if all is right
        N = n.shape[1]
        assert np.all(np.abs(n.std(axis=1) - 1.0) < 4.0 / np.sqrt(2 * N)), meas
        assert np.all(np.abs(n.mean(axis=1)) < 4.0 / np.sqrt(N)), meas
        lag1 = np.mean(n[:, 1:] * n[:, :-1], axis=1)
        assert np.all(np.abs(lag1) < 4.0 / np.sqrt(N)), meas
        np.testing.assert_array_equal(n[0], n[2], err_msg=meas)  # same seed, same numbers
        assert abs(np.mean(n[0] * n[1])) < 4.0 / np.sqrt(3 * N), meas  # other seed, other numbers


def test_cached_kernels_are_cleared_when_any_source_they_read_changes(tmp_path, monkeypatch):
    """Numba keys a cached kernel on its own file only; a kernel that inlines another module's code would
    load stale machine code after that module changed. The package stamps its cache with a hash of every
    source the kernels read: a change to any of them clears the cache (once), and nothing else does."""
    import vtol_impedance.compiled as pkg

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    src = [tmp_path / "engine.py", tmp_path / "plant.py"]
    for p in src:
        p.write_text("# kernel source\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    monkeypatch.setattr(pkg, "_HERE", tmp_path)
    monkeypatch.setattr(pkg, "_SOURCES", tuple(src))

    def cached(names=("engine.run_block-1.py311.nbi", "engine.run_block-1.py311.1.nbc")):
        for n in names:
            (cache / n).write_text("machine code")

    pkg._refresh_cache()  # first use: stamped
    cached()
    pkg._refresh_cache()  # nothing changed: the cache stays
    assert len(list(cache.glob("*.nb?"))) == 2
    src[1].write_text("# kernel source, edited: the engine inlines it\n")
    pkg._refresh_cache()
    assert not list(cache.glob("*.nb?")) and (cache / "kernels.stamp").exists()
    cached()
    pkg._refresh_cache()  # the new sources are stamped: compiled once, kept
    assert len(list(cache.glob("*.nb?"))) == 2
