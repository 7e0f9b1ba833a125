"""Controller pieces (eqs. 14-20) and their API, against independent references."""

import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from vtol_impedance import Controller
from vtol_impedance.control import (
    ControllerParams,
    ImpedanceGains,
    Measurement,
    Reference,
    thrust_and_attitude,
)
from vtol_impedance.conventions import G
from vtol_impedance.errors import InputError, SingularityError
from vtol_impedance.model import load_preset, mix
from vtol_impedance.runtime import ControllerWarning

VEH = load_preset("pelican")


@pytest.fixture(params=["numpy", "compiled"])
def backend(request):
    """The controller's physics tests run on both backends."""
    return request.param


@given(
    st.floats(2.0, 30.0),
    st.floats(-0.55, 0.55),
    st.floats(-0.55, 0.55),
    st.floats(-np.pi, np.pi),
)
def test_eq16_inversion_round_trip_against_scipy_rotation(u, phi, theta, psi):
    # Build mu_bar = g - (u/m) R e3 with an independent rotation, then invert it (eq. 20 in NED).
    m = 1.2
    R = Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()
    mu_bar = np.array([0, 0, G]) - (u / m) * R[:, 2]
    u2, phi2, theta2, limited = thrust_and_attitude(mu_bar, psi, m, tilt_max=np.radians(80), min_lift_accel=0.1)
    assert not limited
    assert u2 == pytest.approx(u, rel=1e-10)
    assert phi2 == pytest.approx(phi, abs=1e-9)
    assert theta2 == pytest.approx(theta, abs=1e-9)


def test_ned_signs_accelerate_the_right_way():
    # To accelerate north (+x) in NED/FRD the nose pitches down: theta < 0; east (+y): roll right, phi > 0.
    _, phi, theta, _ = thrust_and_attitude(np.array([1.0, 0, 0]), 0.0, 1.2)
    assert theta < 0 and phi == pytest.approx(0)
    _, phi, theta, _ = thrust_and_attitude(np.array([0, 1.0, 0]), 0.0, 1.2)
    assert phi > 0 and theta == pytest.approx(0)
    # climbing (up is -z) needs more than the weight
    u, *_ = thrust_and_attitude(np.array([0, 0, -1.0]), 0.0, 1.2)
    assert u == pytest.approx(1.2 * (G + 1.0))


def test_tilt_and_lift_limits_are_applied_and_reported():
    u, phi, theta, lim = thrust_and_attitude(np.array([30.0, 0, 0]), 0.0, 1.2, tilt_max=np.radians(30))
    assert lim and -theta == pytest.approx(np.radians(30))
    u, phi, theta, lim = thrust_and_attitude(np.array([0, 0, 2 * G]), 0.0, 1.2, min_lift_accel=0.2 * G)
    assert lim and u == pytest.approx(1.2 * 0.2 * G)


def _hover_meas(p=(0, 0, -1.0), v=(0, 0, 0), eta=(0, 0, 0), eta_dot=(0, 0, 0)):
    return Measurement(*(np.array(x, dtype=float) for x in (p, v, eta, eta_dot)))


REF = Reference(np.array([0, 0, -1.0]), np.zeros(3), np.zeros(3), np.array(0.0), np.array(0.0), np.array(0.0))


@pytest.mark.parametrize("variant", ["pd", "pid", "pdc"])
def test_equilibrium_gives_weight_and_no_torque(variant, backend):
    ctrl = Controller(ControllerParams.paper(variant), backend=backend)
    for _ in range(5):
        out = ctrl.step(_hover_meas(), REF)
    assert out.thrust == pytest.approx(VEH.mass * G, rel=1e-12)
    np.testing.assert_allclose(out.tau_B, 0, atol=1e-12)
    np.testing.assert_allclose(out.f_rotor, VEH.mass * G / 4, rtol=1e-12)
    u, tau = mix(out.f_rotor, VEH.geometry.E)
    assert u == pytest.approx(out.thrust)


def test_position_error_gives_the_pd_force(backend):
    # 1 cm low (z + 0.01 in NED): the extra thrust is Kp * 0.01 (eq. 18a), level attitude
    ctrl = Controller(ControllerParams.paper("pd"), backend=backend)
    out = ctrl.step(_hover_meas(p=(0, 0, -0.99)), REF)
    assert out.thrust == pytest.approx(VEH.mass * G + 16 * 0.01, rel=1e-9)


def test_attitude_error_gives_the_impedance_torque(backend):
    # roll error e at rest, eta_d = 0 after filtering: tau_B ~ -Ko e about x (eq. 18b + 14, M(0)=I_B, C=0)
    p = ControllerParams.paper("pd")
    ctrl = Controller(p, backend=backend)
    e = 0.05
    out = ctrl.step(_hover_meas(eta=(e, 0, 0)), REF)
    Ko = p.gains.Ko[0]
    # eta_d is level here; (14) with Q(phi): tau_x = -Ko e exactly at phi only
    assert out.tau_B[0] == pytest.approx(-Ko * e, rel=1e-9)


def test_batch_of_variants_equals_single_controllers(rng):
    ps = [ControllerParams.paper(v) for v in ("pd", "pid", "pdc")]
    batch = Controller(ps)
    singles = [Controller(p) for p in ps]
    for _ in range(20):
        meas = [
            _hover_meas(
                rng.normal(0, 0.05, 3) + [0, 0, -1],
                rng.normal(0, 0.1, 3),
                rng.normal(0, 0.05, 3),
                rng.normal(0, 0.2, 3),
            )
            for _ in ps
        ]
        mb = Measurement(*(np.stack(x) for x in list(zip(*meas, strict=True))[:4]))
        ob = batch.step(mb, REF)
        for b, c in enumerate(singles):
            o = c.step(meas[b], REF)
            np.testing.assert_allclose(ob.f_rotor[b], o.f_rotor, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(ob.f_hat_W[b], o.f_hat_W, rtol=1e-12, atol=1e-12)


def test_bad_measurements_are_refused(backend):
    ctrl = Controller(ControllerParams.paper("pdc"), backend=backend)
    with pytest.raises(InputError, match="non-finite"):
        ctrl.step(_hover_meas(p=(0, np.nan, -1)), REF)
    with pytest.raises(InputError, match="shape"):
        ctrl.step(Measurement(np.zeros(2), np.zeros(3), np.zeros(3), np.zeros(3)), REF)
    with pytest.raises(SingularityError):
        ctrl.step(_hover_meas(eta=(0, np.pi / 2, 0)), REF)
    with pytest.raises(InputError, match=r"shape \(2, 3\); this controller expects \(3,\)"):
        ctrl.step(Measurement(*(np.zeros((2, 3)),) * 4), REF)


@pytest.mark.parametrize(
    "kw",
    [
        {"variant": "lqr"},
        {"Ts": 0.0},
        {"tilt_max": 2.0},
        {"integral_limit": -1.0},
    ],
)
def test_bad_controller_parameters(kw):
    with pytest.raises(InputError):
        ControllerParams(vehicle=VEH, gains=ImpedanceGains.paper(VEH.inertia), **kw)


def test_pid_without_integral_gain_is_refused():
    with pytest.raises(InputError, match="Ki"):
        ControllerParams(vehicle=VEH, gains=ImpedanceGains.paper(VEH.inertia), variant="pid")


@pytest.mark.parametrize("bad", [{"Kp": -16.0}, {"Dp": 0.0}, {"Ko": np.nan}, {"Do": [1.0, 2.0]}])
def test_bad_gains(bad):
    kw = {"Kp": 16.0, "Dp": 12.0, "Ko": 0.2, "Do": 0.05} | bad
    with pytest.raises(InputError):
        ImpedanceGains(**kw)


def test_gains_from_natural_frequency_and_the_paper_mismatch():
    g = ImpedanceGains.from_natural(1.2, VEH.inertia, 4.0, 1.0, 8.0, 1.0)
    np.testing.assert_allclose(g.Kp, 19.2)
    np.testing.assert_allclose(g.Dp, 9.6)
    paper = ImpedanceGains.paper(VEH.inertia)
    np.testing.assert_allclose(paper.Kp, 16.0)
    np.testing.assert_allclose(paper.Dp, 12.0)
    np.testing.assert_allclose(paper.Ko, 64 * np.diag(VEH.inertia))
    nat = paper.natural(1.2)
    assert nat["wn_p"][0] == pytest.approx(np.sqrt(16 / 1.2))


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_pid_integral_term_is_bounded_by_integral_limit(backend):
    """Anti-windup: ``|Ki int e_p|`` per axis never exceeds ``integral_limit`` (newtons), however long the
    error lasts; an error held 6 s that would integrate to twice the limit stops at it."""
    import dataclasses

    base = ControllerParams.paper("pid")
    params = dataclasses.replace(base, gains=dataclasses.replace(base.gains, Ki=20.0), integral_limit=3.0)
    ctrl = Controller(params, backend=backend)
    meas = Measurement(np.array([0.05, -0.05, -1.0]), np.zeros(3), np.zeros(3), np.zeros(3))
    ref = Reference(np.array([0.0, 0.0, -1.0]))
    for _ in range(600):  # 0.05 m for 6 s: Ki int e = 20 x 0.3 = 6 N unbounded
        out = ctrl.step(meas, ref)
        assert not out.saturated and not out.tilt_limited  # nothing else freezes the integral
    integral = ctrl.state.integral if backend == "numpy" else ctrl._s["integral"][0]
    np.testing.assert_allclose(20.0 * np.asarray(integral), [3.0, -3.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_comply_attitude_defaults_to_the_plain_pd(backend):
    """With no attitude impedance given, a complying attitude is the vehicle's own inertia with the
    attitude gains (the README's "a plain PD"): at level attitude, with rates and a yaw error, its torque
    request is the PD controller's (no estimate yet; Coriolis terms are second order in the rates)."""
    meas = Measurement(np.array([0.0, 0.0, -1.0]), np.zeros(3), np.zeros(3), np.array([2e-3, -1e-3, 1.5e-3]))
    ref = Reference(np.array([0.0, 0.0, -1.0]), psi=0.05, comply=np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0]))
    pd = Controller(ControllerParams.paper("pd"), backend=backend).step(meas, ref)
    comply = Controller(ControllerParams.paper("comply"), backend=backend).step(meas, ref)
    np.testing.assert_allclose(comply.tau_B_request, pd.tau_B_request, rtol=1e-4, atol=1e-9)
    assert abs(pd.tau_B_request[2]) > 1e-3  # the yaw stiffness is in it


@given(
    st.tuples(*(st.floats(-3.0, 3.0),) * 3).map(np.array),
    st.tuples(st.floats(-np.pi, np.pi), st.floats(-1.4, 1.4), st.floats(-np.pi, np.pi)).map(np.array),
    st.tuples(*(st.floats(-2.0, 2.0),) * 3).map(np.array),
    st.sampled_from(["xyzw", "wxyz"]),
    st.sampled_from(["body-to-world", "world-to-body"]),
)
def test_measurement_from_another_simulators_frames(p_W, eta, omega_B, order, direction):
    """A NED/FRD state written the way a z-up simulator holds it (world ENU, body FLU, SciPy's quaternion,
    converted here by the frame matrices and SciPy) comes back exactly from ``Measurement.from_frames``."""
    T_W, T_B = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]]), np.diag([1.0, -1.0, -1.0])
    R_NED_FRD = Rotation.from_euler("ZYX", eta[::-1]).as_matrix()
    R = T_W @ R_NED_FRD @ T_B  # ENU <- FLU
    q = Rotation.from_matrix(R if direction == "body-to-world" else R.T).as_quat()  # x, y, z, w
    q = q if order == "xyzw" else q[[3, 0, 1, 2]]
    v_W = 0.5 * omega_B[::-1]
    m = Measurement.from_frames(T_W @ p_W, T_W @ v_W, -q, T_B @ omega_B, world="enu", body="flu",
                                quat_order=order, quat_direction=direction)  # fmt: skip
    np.testing.assert_allclose(m.p_W, p_W, atol=1e-12)
    np.testing.assert_allclose(m.v_W, v_W, atol=1e-12)
    np.testing.assert_allclose(m.omega_B, omega_B, atol=1e-12)
    assert m.eta_dot is None
    err = np.angle(np.exp(1j * (m.eta - eta)))  # the same angles, up to whole turns
    np.testing.assert_allclose(err, 0.0, atol=1e-9)


def test_reference_and_frames_of_another_simulator_fly_the_same_controller():
    """ENU inputs through ``from_frames`` give the controller what NED inputs give it; an ENU heading of 0
    (nose east) is NED's pi/2; the estimate goes back with the same matrix."""
    from vtol_impedance.model.frames import world_vector_from_ned

    T_W = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    ref = Reference.from_frames(np.array([1.0, 2.0, 3.0]), heading=0.2, heading_rate=0.1, world="enu")
    assert ref.psi == pytest.approx(np.pi / 2 - 0.2) and ref.psi_dot == pytest.approx(-0.1)
    np.testing.assert_allclose(ref.p_W, [2.0, 1.0, -3.0])
    ned = Measurement(np.array([2.1, 0.9, -2.9]), np.array([0.1, 0.0, -0.2]), np.array([0.05, -0.03, 1.4]),
                      omega_B=np.array([0.1, 0.2, -0.1]))  # fmt: skip
    R = T_W @ Rotation.from_euler("ZYX", ned.eta[::-1]).as_matrix() @ np.diag([1.0, -1.0, -1.0])
    enu = Measurement.from_frames(T_W @ ned.p_W, T_W @ ned.v_W, Rotation.from_matrix(R).as_quat(),
                                  np.diag([1.0, -1.0, -1.0]) @ ned.omega_B, world="enu", body="flu",
                                  quat_order="xyzw")  # fmt: skip
    a, b = (Controller(ControllerParams.paper("pdc")) for _ in range(2))
    for _ in range(3):
        out_ned = a.step(ned, Reference(np.array([2.0, 1.0, -3.0]), psi=np.pi / 2 - 0.2, psi_dot=-0.1))
        out_enu = b.step(enu, ref)
    np.testing.assert_allclose(out_enu.f_rotor, out_ned.f_rotor, atol=1e-9)
    np.testing.assert_allclose(world_vector_from_ned(out_enu.f_hat_W, "enu"), T_W @ out_ned.f_hat_W, atol=1e-12)
    for bad, match in ((np.array([0.0, 0.0, 0.0, 2.0]), "not a unit quaternion"), (np.zeros(3), r"\(4,\)")):
        with pytest.raises(InputError, match=match):
            Measurement.from_frames(np.zeros(3), np.zeros(3), bad, np.zeros(3), world="ned", body="frd",
                                    quat_order="wxyz")  # fmt: skip
    with pytest.raises(InputError, match="world frame must be one of ned, enu"):
        Reference.from_frames(np.zeros(3), world="nwu")
    # the frames are what this method is for: left out, one is not guessed (a SciPy quaternion taken as
    # scalar-first flew the vehicle over in 0.6 s, with only a saturation warning)
    for missing in ("world", "body", "quat_order"):
        kw = {k: v for k, v in dict(world="enu", body="flu", quat_order="xyzw").items() if k != missing}
        with pytest.raises(TypeError, match=missing):
            Measurement.from_frames(np.zeros(3), np.zeros(3), np.array([0, 0, 0, 1.0]), np.zeros(3), **kw)
    with pytest.raises(TypeError, match="world"):
        Reference.from_frames(np.zeros(3))


def test_comply_fractions_from_another_simulators_frames_follow_its_axes():
    """``comply`` given with ENU axes (yield to the east, reject north and up; nose east) is NED's ``[0, 1, 0]``: the
    comply controller then flies exactly as with the NED reference, and not as one yielding to the north
    (the estimate has both components here, so the two differ)."""
    meas = Measurement(np.array([0.3, -0.2, -0.9]), np.array([0.2, -0.3, 0.1]), np.array([0.05, -0.04, 1.5]),
                       omega_B=np.array([0.1, -0.2, 0.05]))  # fmt: skip
    p_enu = np.array([0.0, 0.0, 1.0])
    for six in (False, True):
        tail = [0.0, 1.0, 0.0] if six else []
        enu = Reference.from_frames(p_enu, comply=np.array([1.0, 0.0, 0.0, *tail]), world="enu")
        np.testing.assert_array_equal(enu.comply, [0.0, 1.0, 0.0, *tail])
        outs = {}
        ned = lambda c, tail=tail: Reference(np.array([0.0, 0.0, -1.0]), psi=np.pi / 2, comply=[*c, *tail])  # noqa: E731
        for name, ref in (("enu", enu), ("east", ned([0.0, 1.0, 0.0])), ("north", ned([1.0, 0.0, 0.0]))):
            ctrl = Controller(ControllerParams.paper("comply"))
            for _ in range(30):
                outs[name] = ctrl.step(meas, ref)
        assert np.all(np.abs(outs["enu"].f_hat_W[:2]) > 0.05)
        np.testing.assert_allclose(outs["enu"].f_rotor, outs["east"].f_rotor, rtol=1e-12)
        assert np.abs(outs["enu"].f_rotor - outs["north"].f_rotor).max() > 1e-3
    assert Reference.from_frames(p_enu, comply=0.5, world="enu").comply == 0.5  # one fraction: every axis
    # a batch is reordered per row, and a NaN stays on its own (east) axis for the step to name
    np.testing.assert_array_equal(
        Reference.from_frames(p_enu, comply=[[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], world="enu").comply,
        [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    )
    np.testing.assert_array_equal(
        Reference.from_frames(p_enu, comply=[np.nan, 0.2, 0.3], world="enu").comply, [0.2, np.nan, 0.3]
    )


def test_inputs_in_a_wrong_frame_are_warned_about_through_the_estimate():
    """ENU inputs read as NED: the controller, told the vehicle is below its reference, runs the rotors at
    full thrust; the vehicle climbs at (4 x 7 N / 1.2 kg - g), which z-up readings report as a fall. The
    estimate reaches about twice the thrust less twice the weight, 2.7 times the weight, which nothing a
    multirotor carries gives, and one warning names the frames to check. A hover and a vehicle resting on
    the ground (the estimate is then the ground's reaction, the weight) do not warn."""
    ctrl = Controller(ControllerParams.paper("pdc"))
    climb = 4 * 7.0 / 1.2 - 9.81  # m/s^2, up
    with pytest.warns(ControllerWarning, match="times the vehicle's weight.*world NED, z down") as record:
        for k in range(100):
            t = 0.01 * k
            enu = Measurement(np.array([0.0, 0.0, 1.0 + 0.5 * climb * t * t]), np.array([0.0, 0.0, climb * t]),
                              np.zeros(3), omega_B=np.zeros(3))  # fmt: skip
            ctrl.step(enu, Reference(np.array([0.0, 0.0, -1.0])))
    assert sum("weight" in str(w.message) for w in record) == 1  # once until reset()
    ok, ground = Controller(ControllerParams.paper("pdc")), Controller(ControllerParams.paper("pdc"))
    with warnings.catch_warnings():
        warnings.filterwarnings("error", ".*times the vehicle's weight", ControllerWarning)
        hover = Measurement(np.array([0.0, 0.0, -1.0]), np.zeros(3), np.zeros(3), omega_B=np.zeros(3))
        for _ in range(100):
            ok.step(hover, Reference(np.array([0.0, 0.0, -1.0])))
        # at rest on the ground, asked to go below it: the estimate is the ground's reaction, most of the weight
        rest = Measurement(np.zeros(3), np.zeros(3), np.zeros(3), omega_B=np.zeros(3))
        for _ in range(200):
            out = ground.step(rest, Reference(np.array([0.0, 0.0, 1.0])))
        assert np.linalg.norm(out.f_hat_W) > 0.7 * 1.2 * 9.81
    with pytest.raises(InputError, match=r"psi_d has shape \(1,\); this controller expects a scalar$"):
        ok.step(hover, Reference(np.array([0.0, 0.0, -1.0]), psi=np.array([0.0])))


@pytest.mark.parametrize("Kp, Dp", [(16.0, 12.0), (19.2, 3.0)])
def test_natural_frequency_and_damping_are_the_position_loops_roots(Kp, Dp):
    """``m s^2 + Dp s + Kp``: the product of its roots is wn^2 and their sum -2 zeta wn (numpy's roots of
    the characteristic polynomial, over- and under-damped); ``from_natural`` inverts ``natural``."""
    m = 1.2
    roots = np.roots([m, Dp, Kp])
    wn, zeta = np.sqrt(np.prod(roots).real), -np.sum(roots).real / (2 * np.sqrt(np.prod(roots).real))
    g = ImpedanceGains(Kp=Kp, Dp=Dp, Ko=0.2, Do=0.05)
    n = g.natural(m)
    np.testing.assert_allclose(n["wn_p"], wn, rtol=1e-12)
    np.testing.assert_allclose(n["zeta_p"], zeta, rtol=1e-12)
    back = ImpedanceGains.from_natural(m, np.diag([3.4e-3, 3.4e-3, 4.7e-3]), wn, zeta, 8.0, 1.0)
    np.testing.assert_allclose(back.Kp, Kp, rtol=1e-12)
    np.testing.assert_allclose(back.Dp, Dp, rtol=1e-12)


def test_the_papers_controller_takes_a_vehicle_by_name():
    from vtol_impedance.model import load_preset

    by_name = ControllerParams.paper("pdc", vehicle="hexarotor")
    given = ControllerParams.paper("pdc", vehicle=load_preset("hexarotor"))
    assert by_name.vehicle.n_rotors == 6 and by_name.vehicle.mass == given.vehicle.mass
    np.testing.assert_array_equal(np.asarray(by_name.gains.Kp), np.asarray(given.gains.Kp))
    for bad, match in ((3, "VehicleParams or a preset name, got int"), ("nope", "unknown vehicle preset 'nope'")):
        with pytest.raises(InputError, match=match):  # an AttributeError once
            ControllerParams.paper("pdc", vehicle=bad)


@pytest.mark.parametrize("backend", ["compiled", "numpy"])
@pytest.mark.filterwarnings("ignore::vtol_impedance.runtime.ControllerWarning")
def test_gyro_rates_are_the_euler_rates_of_eq_1c(backend):
    """``omega_B`` from a gyro enters as ``eta_dot = Q(eta)^-1 omega_B`` (eq. (1c)): the step given the gyro
    equals, to rounding, the step given the Euler rates that a general 3x3 solve of ``Q`` finds (an
    independent inversion), over attitudes up to 80 deg of pitch and both signs of every rate; the single
    vehicle and a batch of one agree, and both given or neither is refused."""
    rng = np.random.default_rng(7)
    for _ in range(12):
        eta = rng.uniform([-1.2, -1.4, -3.0], [1.2, 1.4, 3.0])
        omega_B = rng.uniform(-2.0, 2.0, 3)
        cf, sf, ct, st = np.cos(eta[0]), np.sin(eta[0]), np.cos(eta[1]), np.sin(eta[1])
        Q = np.array([[1.0, 0.0, -st], [0.0, cf, sf * ct], [0.0, -sf, cf * ct]])  # eq. (1c), written out
        eta_dot = np.linalg.solve(Q, omega_B)
        p_W, v_W = rng.normal(size=3), rng.normal(size=3)
        ref = Reference(np.zeros(3), psi=0.3, comply=[0.5, 0.2, 0.7])
        outs = []
        for meas in (Measurement(p_W, v_W, eta, omega_B=omega_B), Measurement(p_W, v_W, eta, eta_dot=eta_dot)):
            ctrl = Controller(ControllerParams.paper("comply"), backend=backend)
            for _ in range(3):
                out = ctrl.step(meas, ref)
            outs.append(out)
        batch = Controller([ControllerParams.paper("comply")], backend=backend)
        for _ in range(3):
            out_b = batch.step(Measurement(p_W[None], v_W[None], eta[None], omega_B=omega_B[None]), ref)
        for name in ("f_rotor", "thrust", "tau_B", "f_hat_W", "tau_hat_eta"):
            np.testing.assert_allclose(getattr(outs[0], name), getattr(outs[1], name), rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(getattr(out_b, name)[0], getattr(outs[0], name), rtol=1e-9, atol=1e-9)
    assert isinstance(outs[0].thrust, float) and isinstance(outs[0].saturated, bool)
    both = Measurement(p_W, v_W, eta, eta_dot=eta_dot, omega_B=omega_B)
    with pytest.raises(InputError, match="exactly one of eta_dot"):
        Controller(ControllerParams.paper("pdc"), backend=backend).step(both, ref)
