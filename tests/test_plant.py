"""The true plant against an independent rigid-body integrator and conservation laws."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from vtol_impedance.conventions import G
from vtol_impedance.model import VehicleParams, load_preset
from vtol_impedance.model.kinematics import quat_to_rotation
from vtol_impedance.sim import PlantParams, compile_plants, rk4_step
from vtol_impedance.sim.plant import OMEGA, P_COM, QUAT, ROTOR, V_COM, initial_state, plant_derivative

VEH = load_preset("pelican")


def hat(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def oracle(params, x0, f_cmd, f_ext_W, tau_ext_B, T):
    """Rotation-matrix Newton-Euler with explicit rotor positions, written independently of the library."""
    v = params.vehicle
    l = v.arm_length * params.arm_length_scale
    cq = v.drag_factor * params.drag_factor_scale
    mb, mp = v.mass, params.payload_mass
    rp = np.array(params.payload_offset_B)
    m = mb + mp
    c = mp * rp / m
    I = np.diag(np.diag(v.inertia) * np.array(params.inertia_scale))
    I = I + mb * (c @ c * np.eye(3) - np.outer(c, c))
    d = rp - c
    I = I + mp * (d @ d * np.eye(3) - np.outer(d, d))
    rotors = np.array([[-l, 0, 0], [0, -l, 0], [l, 0, 0], [0, l, 0]])
    spin = np.array([1, -1, 1, -1])

    def rhs(t, s):
        vel, R, w, f = s[3:6], s[6:15].reshape(3, 3), s[15:18], s[18:22]
        tau_c = np.where(f_cmd > f, params.rotor_tau_up, params.rotor_tau_down)
        f_dot = (f_cmd - f) / tau_c
        v_o = vel - R @ np.cross(w, c)
        F_ext_W = f_ext_W - params.rotor_drag * v_o
        F_B_rot = [np.array([0, 0, -fi]) for fi in f]
        M = sum(np.cross(r - c, Fb) for r, Fb in zip(rotors, F_B_rot, strict=True))
        M = M + np.array([0, 0, cq * spin @ f]) + tau_ext_B + np.cross(-c, R.T @ F_ext_W)
        a = np.array([0, 0, G]) + (R @ sum(F_B_rot) + F_ext_W) / m
        w_dot = np.linalg.solve(I, M - np.cross(w, I @ w))
        R_dot = R @ hat(w)
        return np.concatenate([vel, a, R_dot.ravel(), w_dot, f_dot])

    R0 = quat_to_rotation(x0[QUAT])
    s0 = np.concatenate([x0[P_COM], x0[V_COM], R0.ravel(), x0[OMEGA], x0[ROTOR]])
    sol = solve_ivp(rhs, (0, T), s0, method="DOP853", rtol=1e-11, atol=1e-12)
    s = sol.y[:, -1]
    return s[0:3], s[6:15].reshape(3, 3), s[15:18], s[18:22]


def test_plant_matches_independent_integrator():
    params = PlantParams(
        VEH,
        payload_mass=0.2,
        payload_offset_B=(0.02, -0.01, 0.03),
        inertia_scale=(1.1, 0.9, 1.2),
        arm_length_scale=1.05,
        drag_factor_scale=0.9,
        rotor_drag=0.18,
        ground=False,
    )
    P = compile_plants(params)
    x0 = initial_state(P, np.array([0.0, 0.0, -1.0]), eta=np.array([0.05, -0.03, 0.4]))
    x0[OMEGA] = [0.3, -0.2, 0.5]
    x0[V_COM] = [0.2, 0.1, -0.1]
    x = x0.copy()
    f_cmd = np.array([3.5, 3.0, 3.3, 3.1])
    f_ext, tau_ext = np.array([0.3, -0.2, 0.5]), np.array([0.01, 0.004, -0.002])
    dist = lambda t, p, v, R: (np.broadcast_to(f_ext, p.shape), np.broadcast_to(tau_ext, p.shape))  # noqa: E731
    T, dt = 1.0, 1e-3
    for k in range(int(T / dt)):
        x = rk4_step(P, x, f_cmd, k * dt, dt, dist)
    p_o, R_o, w_o, f_o = oracle(params, x0, f_cmd, f_ext, tau_ext, T)
    np.testing.assert_allclose(x[P_COM], p_o, atol=1e-7)
    np.testing.assert_allclose(quat_to_rotation(x[QUAT]), R_o, atol=1e-7)
    np.testing.assert_allclose(x[OMEGA], w_o, atol=1e-6)
    np.testing.assert_allclose(x[ROTOR], f_o, atol=1e-6)


def _fly_open_loop(backend, P, x, f_cmd, steps, dt):
    """``steps`` RK4 steps with the rotor command held, on the NumPy plant or the compiled one."""
    if backend == "numpy":
        for k in range(steps):
            x = rk4_step(P, x, f_cmd, k * dt, dt)
        return x
    from vtol_impedance.compiled.engine import advance
    from vtol_impedance.sim.disturbances import pack_disturbances
    from vtol_impedance.sim.plant import pack_plant, pack_state, unpack_state

    X = pack_state(x[None])
    dists, series = pack_disturbances([])
    advance(pack_plant(_batch(P)), X, np.ascontiguousarray(f_cmd[None], dtype=float), 0.0, steps, dt, dists, series)
    return unpack_state(X, f_cmd.shape[-1])[0]


def _batch(P):
    """Plant arrays of one vehicle with a batch axis of one."""
    return type(P)(*(np.asarray(v)[None] for v in P))


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_torque_free_rotation_conserves_momentum_and_energy(backend):
    """A tumbling body with unequal inertia and an offset centre of mass, rotors off: the angular momentum in
    the world frame and the rotational energy stay as they were (RK4's error at 1 ms over 2 s is far below
    the tolerance; a wrong gyroscopic term or quaternion rate drifts by percent), and the CoM falls freely."""
    params = PlantParams(
        VEH,
        payload_mass=0.3,
        payload_offset_B=(0.03, 0.02, 0.05),
        inertia_scale=(1.0, 1.4, 0.8),
        rotor_tau_up=0.0,
        rotor_tau_down=0.0,
        ground=False,
    )
    P = compile_plants(params)
    x = initial_state(P, np.zeros(3), hover_rotors=False)
    x[OMEGA] = [2.0, -1.0, 3.0]
    f0 = np.zeros(4)

    def invariants(x):
        R = quat_to_rotation(x[QUAT])
        w = x[OMEGA]
        return R @ (P.I_com @ w), 0.5 * w @ P.I_com @ w

    L0, E0 = invariants(x)
    z0 = x[P_COM][2]
    x = _fly_open_loop(backend, P, x, f0, 2000, 1e-3)
    L1, E1 = invariants(x)
    np.testing.assert_allclose(L1, L0, rtol=1e-8, atol=1e-12)
    assert E1 == pytest.approx(E0, rel=1e-8)
    assert np.linalg.norm(x[QUAT]) == pytest.approx(1.0, abs=1e-12)
    # the centre of mass falls freely
    assert x[P_COM][2] - z0 == pytest.approx(0.5 * G * 2.0**2, rel=1e-9)


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_a_pitch_loop_through_90_degrees_has_no_singularity(backend):
    """Spinning steadily about the body y axis (a principal axis), the attitude after t is a rotation by
    omega t about y, through pitch +-90 deg where Euler angles fail: the quaternion plant does not notice."""
    P = compile_plants(PlantParams(VEH, rotor_tau_up=0.0, rotor_tau_down=0.0, ground=False))
    x = initial_state(P, np.zeros(3), hover_rotors=False)
    w = 2.0
    x[OMEGA] = [0.0, w, 0.0]
    T = 2.0  # 229 deg: through +90 deg and on
    x = _fly_open_loop(backend, P, x, np.zeros(4), 2000, 1e-3)
    c, s_ = np.cos(w * T), np.sin(w * T)
    Ry = np.array([[c, 0, s_], [0, 1, 0], [-s_, 0, c]])
    np.testing.assert_allclose(quat_to_rotation(x[QUAT]), Ry, atol=1e-9)
    np.testing.assert_allclose(x[OMEGA], [0.0, w, 0.0], atol=1e-12)


def test_hover_equilibrium_and_ground_support():
    P = compile_plants(PlantParams(VEH, ground=True))
    x = initial_state(P, np.array([0, 0, -1.0]))
    xd = plant_derivative(P, x, x[ROTOR])
    np.testing.assert_allclose(xd, 0.0, atol=1e-12)
    # on the ground with rotors off: the ground carries the weight at a small compression
    x = initial_state(P, np.zeros(3), hover_rotors=False)
    for k in range(3000):
        x = rk4_step(P, x, np.zeros(4), k * 1e-3, 1e-3)
    assert 0 < x[P_COM][2] < 0.01
    assert abs(x[V_COM][2]) < 1e-4


def test_the_initial_hover_holds_payload_and_pendulum():
    """At rest with an unmodelled payload (offset) and a hanging pendulum, the initial rotor forces carry
    the whole weight: every state's rate is zero (the pendulum's too: it hangs along gravity)."""
    P = compile_plants(PlantParams(VEH, payload_mass=0.11, payload_offset_B=(0.0, 0.0, 0.05), pendulum_mass=0.2,
                                   pendulum_length=0.6, ground=False))  # fmt: skip
    x = initial_state(P, np.array([0, 0, -2.0]))
    np.testing.assert_allclose(x[ROTOR].sum(), (VEH.mass + 0.11 + 0.2) * G, rtol=1e-12)
    np.testing.assert_allclose(plant_derivative(P, x, x[ROTOR]), 0.0, atol=1e-12)


def test_rotor_lag_and_limits():
    P = compile_plants(PlantParams(VEH, rotor_tau_up=0.02, rotor_tau_down=0.04, ground=False))
    x = initial_state(P, np.array([0, 0, -5.0]), hover_rotors=False)
    cmd = np.array([100.0, 2.0, 2.0, 2.0])  # rotor 1 asked past f_max
    for k in range(20):
        x = rk4_step(P, x, cmd, k * 1e-3, 1e-3)
    # after one time constant: 1 - 1/e of the (clipped) target
    np.testing.assert_allclose(x[ROTOR][1:], 2.0 * (1 - np.exp(-1)), rtol=1e-4)
    assert x[ROTOR][0] == pytest.approx(VEH.f_max * (1 - np.exp(-1)), rel=1e-4)


def test_batched_plant_equals_single(rng):
    params = [
        PlantParams(VEH, payload_mass=m, payload_offset_B=(0.01 * i, 0, 0.02)) for i, m in enumerate([0, 0.1, 0.3])
    ]
    Pb = compile_plants(params)
    xb = initial_state(Pb, np.zeros((3, 3)) + [0, 0, -1])
    cmd = rng.uniform(2, 4, (3, 4))
    for k in range(50):
        xb = rk4_step(Pb, xb, cmd, k * 1e-3, 1e-3)
    for i, p in enumerate(params):
        P1 = compile_plants(p)
        x1 = initial_state(P1, np.array([0, 0, -1.0]))
        for k in range(50):
            x1 = rk4_step(P1, x1, cmd[i], k * 1e-3, 1e-3)
        np.testing.assert_allclose(xb[i], x1, rtol=1e-13, atol=1e-14)


def test_a_batch_of_different_vehicles_is_composed_by_the_parallel_axis_theorem():
    """Each row of a batch of different vehicles and payloads, against the composition written out here."""
    heavy_x = VehicleParams(2.0, [0.02, 0.03, 0.04], layout="x", arm_length=0.3, drag_factor=0.02)
    plants = [
        PlantParams(VEH, payload_mass=0.1, payload_offset_B=(0.01, 0.0, 0.05)),
        PlantParams(heavy_x, inertia_scale=(1.1, 0.9, 1.0), arm_length_scale=1.2, drag_factor_scale=1.5),
        PlantParams(VEH, payload_mass=0.3, payload_offset_B=(0.0, 0.02, 0.1), inertia_scale=1.2),
        PlantParams(heavy_x, payload_mass=0.5, payload_offset_B=(-0.03, 0.01, 0.08)),
    ]
    PA = compile_plants(plants)
    for i, P in enumerate(plants):
        v, mp, rp = P.vehicle, P.payload_mass, np.array(P.payload_offset_B)
        m = v.mass + mp
        c = mp * rp / m
        d = rp - c
        I = np.diag(np.diag(v.inertia) * np.array(P.inertia_scale))  # noqa: E741
        I = I + v.mass * (c @ c * np.eye(3) - np.outer(c, c)) + mp * (d @ d * np.eye(3) - np.outer(d, d))  # noqa: E741
        np.testing.assert_allclose(PA.mass[i], m, rtol=1e-15)
        np.testing.assert_allclose(PA.c_B[i], c, rtol=1e-14, atol=1e-16)
        np.testing.assert_allclose(PA.I_com[i], I, rtol=1e-13, atol=1e-16)
        np.testing.assert_allclose(PA.I_com_inv[i] @ I, np.eye(3), atol=1e-12)
        pos = v.geometry.positions_B * P.arm_length_scale
        cq = v.drag_factor * P.drag_factor_scale
        for j, (r, s) in enumerate(zip(pos, v.geometry.spins, strict=True)):
            # thrust along -z_B at r: moment r x (0, 0, -1) = (-r_y, r_x, 0), plus the drag moment s c
            np.testing.assert_allclose(PA.E[i][:, j], [1.0, -r[1], r[0], s * cq], rtol=1e-15)
        np.testing.assert_array_equal(PA.r_contact_B[i], rp if mp > 0 else np.zeros(3))
    assert PA.E.shape == (4, 4, 4) and abs(PA.E[1][1, 0]) != abs(PA.E[0][1, 0])  # premise: the layouts differ


@pytest.mark.parametrize("backend", ["numpy", "compiled", "mujoco"])
def test_a_zero_time_constant_removes_only_its_own_direction(backend):
    """``rotor_tau_down = 0``: a rotor drops at once to a lower command but still spins up with its lag
    (the flown rotor force against the first-order response, by hand), on every plant."""
    from vtol_impedance.control import ControllerParams
    from vtol_impedance.control.reference import Hold, Trajectory
    from vtol_impedance.sim import run_closed_loop
    from vtol_impedance.sim.sensors import SensorParams

    if backend == "mujoco":
        pytest.importorskip("mujoco")
    plant = PlantParams(VEH, rotor_tau_up=0.05, rotor_tau_down=0.0, ground=False)
    traj = Trajectory((Hold((0.0, 0.0, -2.0), 1.0),))
    from vtol_impedance.sim.disturbances import from_dict

    wobble = from_dict({"kind": "sinusoid", "torque_B": [0.05, 0.0, 0.0], "freq_hz": 2.0})
    r = run_closed_loop(plant, [ControllerParams.paper("pd")], traj, 0.6, [wobble], sensors=SensorParams.ideal(),
                        backend=backend, start_W=np.array([0.0, 0.0, -2.0]))  # fmt: skip
    cmd, f = r["f_rotor_cmd"][0], r["f_rotor"][0]  # the command issued at each tick, the force then
    k = np.arange(1, len(r.t))
    down = cmd[k - 1] < f[k - 1] - 1e-6
    up = cmd[k - 1] > f[k - 1] + 1e-6
    assert down.any() and up.any()
    # down: at the command by the next tick; up: one period of the 50 ms lag towards it
    np.testing.assert_allclose(f[k][down], cmd[k - 1][down], atol=1e-6)
    expect = cmd[k - 1] + (f[k - 1] - cmd[k - 1]) * np.exp(-0.01 / 0.05)
    np.testing.assert_allclose(f[k][up], expect[up], atol=2e-3 if backend == "mujoco" else 1e-6)


def test_band_limited_noise_has_its_rms_in_its_band():
    """The noise disturbance's force has the RMS asked for per axis, and its power lies in [f_lo, f_hi]
    (Welch's estimate, SciPy); channels are independent draws."""
    from scipy.signal import welch

    from vtol_impedance.sim.disturbances import BandLimitedNoise

    d = BandLimitedNoise(force_rms_W=(0.3, 0.5, 0.0), torque_rms_B=(0.0, 0.0, 0.02), f_lo=0.5, f_hi=5.0)
    d = d.prepare(120.0, 0.01, np.random.default_rng(7))
    t = np.arange(0.0, 120.0, 0.01)
    f, tau = (np.array(v) for v in zip(*(d(tk, np.zeros(3), np.zeros(3), np.eye(3)) for tk in t), strict=True))
    np.testing.assert_allclose(np.sqrt(np.mean(f**2, axis=0)), [0.3, 0.5, 0.0], rtol=0.02, atol=1e-12)
    assert np.sqrt(np.mean(tau[:, 2] ** 2)) == pytest.approx(0.02, rel=0.02)
    freq, psd = welch(f[:, 0], fs=100.0, nperseg=4096)
    band = (freq >= 0.5) & (freq <= 5.0)
    assert psd[band].sum() / psd.sum() > 0.9
    assert abs(np.corrcoef(f[:, 0], f[:, 1])[0, 1]) < 0.1


def test_noise_bands_are_checked_when_the_disturbance_is_made():
    """A band below MIN_NOISE_F_LO_HZ (its settling padding is drawn at the plant rate: 1e-4 Hz took
    7.6 GB), reversed, or not two numbers is refused at once, for noise and for a fan's turbulence."""
    from vtol_impedance.errors import InputError
    from vtol_impedance.sim.disturbances import MIN_NOISE_F_LO_HZ, from_dict

    assert MIN_NOISE_F_LO_HZ == 0.01
    for bad, match in (({"f_lo": 1e-4}, r"0.01 <= f_lo < f_hi Hz, got 0.0001..5"), ({"f_lo": 3.0, "f_hi": 2.0}, "3..2"),
                       ({"f_lo": float("nan")}, "finite")):  # fmt: skip
        with pytest.raises(InputError, match=match):
            from_dict({"kind": "noise", "force_rms_W": [0.1, 0.0, 0.0], **bad})
    for band in ((1e-3, 5.0), (5.0, 0.5), (1.0,)):
        with pytest.raises(InputError, match="turbulence_band"):
            from_dict({"kind": "fan", "position_W": [2.0, 0.0, -1.0], "direction_W": [-1.0, 0.0, 0.0],
                       "turbulence_band": list(band)})  # fmt: skip
    ok = from_dict({"kind": "noise", "force_rms_W": [0.1, 0.0, 0.0], "f_lo": 0.01, "f_hi": 0.1})
    assert ok.prepare(1.0, 0.001, np.random.default_rng(0))._series.shape == (1002, 6)


@pytest.mark.parametrize("delay, steps", [(0.013, 13), (0.0129, 13), (0.0121, 12), (0.0, 0), (0.0004, 0)])
def test_a_sensor_reads_the_state_of_the_plant_step_nearest_its_latency(delay, steps):
    """Latencies are served at the plant's step (1 ms): the state pushed nearest ``delay`` ago (0.013 s
    is 12.999... steps in floating point, and must not become 12)."""
    import contextlib
    import warnings

    from vtol_impedance.sim.sensors import LatencyWarning, SensorParams, SensorSuite

    P = compile_plants(PlantParams(VEH))
    whole = delay in (0.013, 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a whole number of steps flies as given, without a word
        with contextlib.nullcontext() if whole else pytest.warns(LatencyWarning, match=f"flies as {steps / 1e3:g} s"):
            suite = SensorSuite(SensorParams(mocap_delay=delay, imu_delay=0.0), P, 0.001)
    for k in range(40):
        suite.push(np.full(3, float(k)))
    mocap, imu = suite.delayed()
    assert mocap[0] == 39 - steps and imu[0] == 39


def test_time_profiles_of_the_explicit_wrenches_in_both_backends():
    """By hand: a ramp from 1 to 3 s is 0, 0.5, 1, 1 at 0, 2, 3, 10 s; a sinusoid of 0.5 Hz switched on at
    0.3 s is 0 before and at 0.3 s and peaks 0.5 s later; a step from 1 to 2 s is on inside only. The
    NumPy disturbances and the compiled kernel give these numbers."""
    from vtol_impedance.compiled.plant import add_disturbances
    from vtol_impedance.sim.disturbances import RampWrench, SinusoidWrench, StepWrench, pack_disturbances

    cases = [
        (RampWrench((2.0, 0.0, 0.0), (0.0, 0.0, 0.1), t_start=1.0, t_end=3.0),
         {0.0: 0.0, 1.0: 0.0, 2.0: 0.5, 3.0: 1.0, 10.0: 1.0}),
        (SinusoidWrench((2.0, 0.0, 0.0), (0.0, 0.0, 0.1), freq_hz=0.5, t_on=0.3),
         {0.0: 0.0, 0.3: 0.0, 0.8: 1.0, 1.3: 0.0, 1.8: -1.0}),
        (StepWrench((2.0, 0.0, 0.0), (0.0, 0.0, 0.1), t_on=1.0, t_off=2.0),
         {0.5: 0.0, 1.0: 1.0, 1.5: 1.0, 2.0: 0.0, 3.0: 0.0}),
    ]  # fmt: skip
    R = tuple(np.eye(3).ravel())
    for d, expect in cases:
        d = d.prepare(11.0, 0.001, np.random.default_rng(0))
        dists, series = pack_disturbances([d])
        env = np.empty(6)
        for t, k in expect.items():
            f, tau = d(t, np.zeros(3), np.zeros(3), np.eye(3))
            np.testing.assert_allclose(f, [2.0 * k, 0.0, 0.0], atol=1e-12, err_msg=f"{d.kind} at {t}")
            np.testing.assert_allclose(tau, [0.0, 0.0, 0.1 * k], atol=1e-12)
            add_disturbances(t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, R, dists, series, env)
            np.testing.assert_allclose(env, [2.0 * k, 0, 0, 0, 0, 0.1 * k], atol=1e-12, err_msg=f"{d.kind} at {t}")


def test_each_random_disturbance_draws_its_own_series():
    """Two noise disturbances of one run along x with the same band and RMS 0.3 N add as independent
    draws (RMS 0.3 sqrt(2) N; one shared draw would give 0.6 N), a third along y is uncorrelated with
    them, and a fan's turbulence has the RMS asked for (a fraction of its mean push)."""
    from vtol_impedance.control import ControllerParams
    from vtol_impedance.control.reference import Hold, Trajectory
    from vtol_impedance.sim import SensorParams, run_closed_loop
    from vtol_impedance.sim.disturbances import FanJet, from_dict

    noise = [from_dict({"kind": "noise", "force_rms_W": rms, "f_lo": 0.5, "f_hi": 5.0})
             for rms in ([0.3, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.3, 0.0])]  # fmt: skip
    r = run_closed_loop(PlantParams(VEH, ground=False), [ControllerParams.paper("pd")],
                        Trajectory((Hold((0, 0, -1.0), 20.0),)), 20.0, noise, SensorParams.ideal(), seed=4)  # fmt: skip
    f = r["f_ext_W"][0]
    assert np.std(f[:, 0]) == pytest.approx(0.3 * np.sqrt(2), rel=0.1) and np.std(f[:, 1]) == pytest.approx(
        0.3, rel=0.1
    )
    assert abs(np.corrcoef(f[:, 0], f[:, 1])[0, 1]) < 0.15
    fan = FanJet(position_W=(2.0, 0.0, -1.0), direction_W=(-1.0, 0.0, 0.0), turbulence=0.2)
    gust = fan.prepare(200.0, 0.01, np.random.default_rng(1))._gust
    assert np.std(gust) == pytest.approx(0.2, rel=0.02) and abs(np.mean(gust)) < 0.02


def test_a_sinusoid_faster_than_the_plant_steps_is_refused():
    """At a 1 kHz plant a 1 kHz sinusoid is zero at every step (aliased): refused above 250 Hz, named."""
    from vtol_impedance.errors import InputError
    from vtol_impedance.sim.disturbances import SinusoidWrench

    d = SinusoidWrench((1.0, 0.0, 0.0), (0.0, 0.0, 0.0), freq_hz=1000.0)
    with pytest.raises(InputError, match=r"freq_hz = 1000 Hz is above a quarter of the plant rate \(1000 Hz\)"):
        d.prepare(1.0, 0.001, np.random.default_rng(0))
    assert SinusoidWrench((1.0, 0.0, 0.0), (0.0, 0.0, 0.0), freq_hz=200.0).prepare(1.0, 0.001, None).freq_hz == 200.0


def test_a_latency_between_plant_steps_is_recorded_as_flown():
    """12.6 ms at a 1 kHz plant flies as 13 ms: the run warns and its config says so; a whole number of
    steps adds nothing."""
    from vtol_impedance.scenarios import get, set_value, simulate
    from vtol_impedance.sim.sensors import LatencyWarning

    spec = set_value(get("case-a-payload"), "duration", 0.1)
    assert "sensor_delays_flown_s" not in simulate(spec, ["pd"]).config
    with pytest.warns(LatencyWarning, match="sensors.imu_delay = 0.0126 s flies as 0.013 s"):
        r = simulate(set_value(spec, "sensors.imu_delay", 0.0126), ["pd"])
    assert r.config["sensor_delays_flown_s"] == {"imu_delay": pytest.approx(0.013, abs=1e-15)}


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_a_drop_onto_the_ground_only_loses_energy(backend):
    """Rotors off, level, dropped from rest with its contact points 0.2 m up: the ground is a spring with a
    damper that only pushes, so the vehicle's mechanical energy (kinetic plus potential, NED: -m g z) can
    only fall through the contact, and it settles. Sampled every 10 ms over 3 s: no rebound climbs back to
    the start, the energy never rises above the drop's (beyond the spring's stored share, bounded by the
    final compression), and the vehicle ends at rest (a damper of the wrong sign pumps energy in)."""
    from vtol_impedance.sim.plant import lowest_contact_depth

    P = compile_plants(PlantParams(VEH, ground=True))
    x = initial_state(P, np.zeros(3), hover_rotors=False)
    x[P_COM][2] -= 0.2 + float(lowest_contact_depth(P, x))  # contact points 0.2 m above the ground
    m = float(P.mass)

    def energy(s):
        return 0.5 * m * float(s[V_COM] @ s[V_COM]) - m * G * float(s[P_COM][2])

    z0, e0 = float(x[P_COM][2]), energy(x)
    zs, es = [], []
    for _ in range(300):
        x = _fly_open_loop(backend, P, x, np.zeros(4), 10, 1e-3)
        zs.append(float(x[P_COM][2]))
        es.append(energy(x))
    zs, es = np.array(zs), np.array(es)
    first = int(np.argmax(zs > z0 + 0.19))  # touching down
    assert first > 0 and np.min(zs[first:]) > z0 + 0.1  # no rebound higher than half the drop
    assert np.max(es) <= e0 + 1e-6 * m * G
    assert abs(float(x[V_COM][2])) < 1e-3 and es[-1] < e0 - 0.9 * m * G * 0.2  # settled: the drop's energy gone
