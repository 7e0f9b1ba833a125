"""Kinematics, dynamics (eqs. 1-8) and the mixer (4), checked against independent references."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from vtol_impedance.errors import SingularityError
from vtol_impedance.model import (
    VehicleParams,
    allocate,
    coriolis_matrix_C,
    euler_rate_matrix_Q,
    euler_rate_matrix_Q_dot,
    euler_rate_matrix_T,
    inertia_matrix_M,
    mix,
    rotation_zyx,
    unmix,
)
from vtol_impedance.model.kinematics import (
    check_euler_regular,
    euler_from_rotation,
    quat_from_euler,
    quat_to_rotation,
)

angle = st.floats(-np.pi, np.pi)
pitch = st.floats(-1.4, 1.4)  # away from +-pi/2
rate = st.floats(-5.0, 5.0)
eta_st = st.tuples(angle, pitch, angle).map(np.array)
rate_st = st.tuples(rate, rate, rate).map(np.array)
inertia_st = st.tuples(*(st.floats(1e-3, 1e-2),) * 3).map(np.diag)


def _oracle_R(eta):
    # scipy's intrinsic 'ZYX' with angles (psi, theta, phi) is Rz(psi) Ry(theta) Rx(phi)
    return Rotation.from_euler("ZYX", [eta[2], eta[1], eta[0]]).as_matrix()


@given(eta_st)
def test_rotation_matches_scipy_and_is_proper(eta):
    R = rotation_zyx(eta)
    np.testing.assert_allclose(R, _oracle_R(eta), atol=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


@given(eta_st)
def test_quaternion_and_euler_round_trip(eta):
    R = rotation_zyx(eta)
    np.testing.assert_allclose(quat_to_rotation(quat_from_euler(eta)), R, atol=1e-12)
    np.testing.assert_allclose(rotation_zyx(euler_from_rotation(R)), R, atol=1e-9)


@given(eta_st, rate_st)
def test_T_and_Q_map_euler_rates_to_angular_velocity(eta, eta_dot):
    # S(omega_W) = R_dot R^T and S(omega_B) = R^T R_dot, R_dot by central differences
    h = 1e-6
    R_dot = (rotation_zyx(eta + h * eta_dot) - rotation_zyx(eta - h * eta_dot)) / (2 * h)
    R = rotation_zyx(eta)
    Sw = R_dot @ R.T
    Sb = R.T @ R_dot
    w_W = np.array([Sw[2, 1], Sw[0, 2], Sw[1, 0]])
    w_B = np.array([Sb[2, 1], Sb[0, 2], Sb[1, 0]])
    np.testing.assert_allclose(euler_rate_matrix_T(eta) @ eta_dot, w_W, atol=1e-6)
    np.testing.assert_allclose(euler_rate_matrix_Q(eta) @ eta_dot, w_B, atol=1e-6)
    np.testing.assert_allclose(euler_rate_matrix_Q(eta), R.T @ euler_rate_matrix_T(eta), atol=1e-12)


@given(eta_st, rate_st)
def test_Q_dot_is_the_time_derivative_of_Q(eta, eta_dot):
    h = 1e-6
    fd = (euler_rate_matrix_Q(eta + h * eta_dot) - euler_rate_matrix_Q(eta - h * eta_dot)) / (2 * h)
    np.testing.assert_allclose(euler_rate_matrix_Q_dot(eta, eta_dot), fd, atol=1e-6)


@given(eta_st, inertia_st)
def test_M_symmetric_positive_definite(eta, I_B):
    M = inertia_matrix_M(eta, I_B)
    np.testing.assert_allclose(M, M.T, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(M) > 0)


@given(eta_st, rate_st, inertia_st)
def test_M_dot_equals_C_plus_C_transpose_eq7(eta, eta_dot, I_B):
    h = 1e-6
    M_dot = (inertia_matrix_M(eta + h * eta_dot, I_B) - inertia_matrix_M(eta - h * eta_dot, I_B)) / (2 * h)
    C = coriolis_matrix_C(eta, eta_dot, I_B)
    np.testing.assert_allclose(M_dot, C + C.T, atol=1e-7 * max(1.0, np.abs(M_dot).max()))


@given(eta_st, rate_st, inertia_st, st.tuples(*(st.floats(-0.5, 0.5),) * 3).map(np.array))
def test_euler_dynamics_3b_agree_with_newton_euler_2b(eta, eta_dot, I_B, tau_B):
    # Solve (3b) for eta_ddot, map to omega_dot, and check Euler's equation I w_dot + w x I w = tau.
    M = inertia_matrix_M(eta, I_B)
    C = coriolis_matrix_C(eta, eta_dot, I_B)
    Q = euler_rate_matrix_Q(eta)
    eta_ddot = np.linalg.solve(M, Q.T @ tau_B - C @ eta_dot)
    w = Q @ eta_dot
    w_dot = Q @ eta_ddot + euler_rate_matrix_Q_dot(eta, eta_dot) @ eta_dot
    np.testing.assert_allclose(I_B @ w_dot + np.cross(w, I_B @ w), tau_B, atol=1e-9)


def test_batched_matches_single(rng):
    eta = rng.uniform(-1, 1, (5, 4, 3))
    eta_dot = rng.uniform(-2, 2, (5, 4, 3))
    I_B = np.diag([3.4e-3, 3.4e-3, 4.7e-3])
    Mb = inertia_matrix_M(eta, I_B)
    Cb = coriolis_matrix_C(eta, eta_dot, I_B)
    for i in range(5):
        for j in range(4):
            np.testing.assert_allclose(Mb[i, j], inertia_matrix_M(eta[i, j], I_B), atol=1e-15)
            np.testing.assert_allclose(Cb[i, j], coriolis_matrix_C(eta[i, j], eta_dot[i, j], I_B), atol=1e-15)


def test_singularity_is_reported():
    with pytest.raises(SingularityError, match="90"):
        check_euler_regular(np.array([0.0, np.pi / 2, 0.0]))
    check_euler_regular(np.array([0.0, 1.5, 0.0]))


force = st.floats(0.0, 7.0)
PLUS = VehicleParams(1.2, [3.4e-3, 3.4e-3, 4.7e-3], arm_length=0.21, drag_factor=0.016, f_max=7.0)


@given(st.tuples(force, force, force, force).map(np.array))
def test_mixer_is_eq4_for_the_plus_layout(f):
    """Eq. (4) written out by hand against the effectiveness matrix built from rotor positions."""
    l, c = 0.21, 0.016
    g = PLUS.geometry
    u, tau = mix(f, g.E)
    assert u == pytest.approx(f.sum())
    assert tau[0] == pytest.approx(l * (f[1] - f[3]))
    assert tau[1] == pytest.approx(l * (f[2] - f[0]))
    assert tau[2] == pytest.approx(c * (f[0] - f[1] + f[2] - f[3]))
    np.testing.assert_allclose(unmix(u, tau, g.E_pinv), f, atol=1e-12)
    alloc = allocate(u, tau, g.E, g.E_pinv, g.f_min, g.f_max)
    np.testing.assert_allclose(alloc.f, f, atol=1e-9)
    assert not alloc.saturated


def test_huge_yaw_request_keeps_thrust_and_roll_pitch():
    g = PLUS.geometry
    a = allocate(12.0, np.array([0.05, -0.03, 15.0]), g.E, g.E_pinv, g.f_min, g.f_max)
    assert a.saturated
    assert a.thrust == pytest.approx(12.0)
    np.testing.assert_allclose(a.tau_B[:2], [0.05, -0.03], atol=1e-12)
    assert 0 < a.tau_B[2] < 15.0 and a.yaw_scale < 0.05


@pytest.mark.parametrize(
    "kw",
    [
        {"mass": 0.0},
        {"mass": -1.2},
        {"mass": float("nan")},
        {"inertia": [1e-3, -1e-3, 1e-3]},
        {"inertia": np.ones((3, 3))},
        {"inertia": [1e-3, 1e-3]},
        {"f_max": 0.0},
        {"f_min": 8.0},
        {"arm_length": float("inf")},
        {"layout": "tri"},
        {"mass": "1.2"},
        {"drag_factor": [0.01, 0.02]},
    ],
)
def test_bad_vehicle_parameters(kw):
    from vtol_impedance.errors import InputError
    from vtol_impedance.model import VehicleParams

    base = {"mass": 1.2, "inertia": [3.4e-3, 3.4e-3, 4.7e-3]} | kw
    with pytest.raises(InputError):
        VehicleParams(**base)


def test_pelican_preset_matches_the_paper():
    from vtol_impedance.model import load_preset

    v = load_preset("pelican")
    assert v.mass == 1.2
    np.testing.assert_allclose(np.diag(v.inertia), [3.4e-3, 3.4e-3, 4.7e-3])
    assert 2.3 < v.thrust_to_weight < 2.5
    with pytest.raises(ValueError, match="available: hexarotor, pelican, pelican-x"):
        load_preset("mavic")


@given(eta_st, rate_st, rate_st)
def test_euler_and_body_moments_do_the_same_work(eta, eta_dot, tau):
    """``tau_eta`` is the generalized force of the Euler coordinates: the power it delivers, ``tau_eta .
    eta_dot``, is that of the body moment, ``tau_B . omega_B`` with ``omega_B = Q eta_dot`` (virtual work),
    whichever way the moment is converted."""
    from vtol_impedance.model.dynamics import body_moment_from_euler, euler_moment_from_body

    omega_B = euler_rate_matrix_Q(eta) @ eta_dot
    tau_B = body_moment_from_euler(tau, eta)
    assert tau_B @ omega_B == pytest.approx(tau @ eta_dot, rel=1e-9, abs=1e-9)
    assert euler_moment_from_body(tau, eta) @ eta_dot == pytest.approx(tau @ omega_B, rel=1e-9, abs=1e-9)
