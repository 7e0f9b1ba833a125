"""Physics the other tests left unchecked, each against a reference written here (closed forms, SciPy, an
independent rigid-body integrator), never against numbers taken from the code.

Each test was written for a deliberate bug (a mutant) that the rest of the suite let through: a transposed
thrust direction, the eq. (16) limits, the allocator's collective bound and its saturation flag, the
estimator's timing alignment (interpolation across the +-pi wrap, the rotor model, the clamped attitude
lag), its lag and rate outputs, the signs of the compensation, of the PID integral and of the comply laws in
closed loop, the yaw wrap, the attitude filter's acceleration, the reference's accelerations and yaw steps,
the gain scalings, the rigid-body inertia and rotor-limit checks, and the stability margins of loops that
cross over more than once and their damping ratio.
"""

from __future__ import annotations

import control as ct
import numpy as np
import pytest
import scipy.signal
from hypothesis import given
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation
from test_physics import Q_num, R_of, eta_of  # SciPy's rotations and finite differences

from vtol_impedance import Controller
from vtol_impedance.control import (
    ControllerParams,
    Impedance,
    ImpedanceGains,
    Measurement,
    Reference,
    acceleration_from_thrust,
    thrust_and_attitude,
)
from vtol_impedance.control.attitude_filter import FilterState, design_filter, filter_step
from vtol_impedance.control.reference import Circle, Hold, MinJerk, Trajectory
from vtol_impedance.errors import InputError
from vtol_impedance.estimator import EstimatorParams, design, estimator_step, initial_state
from vtol_impedance.estimator.series import causal, momentum_residual
from vtol_impedance.model import Rotor, VehicleParams, allocate, mix
from vtol_impedance.model.dynamics import thrust_direction_W
from vtol_impedance.robust import loop_margins
from vtol_impedance.robust.linear import sampled_plant
from vtol_impedance.robust.margins import MarginReport

G = 9.81
E3 = np.array([0.0, 0.0, 1.0])


# ----------------------------------------------------------------------------- eq. (16) forward and inverse


@given(
    st.floats(0.0, 40.0),
    st.tuples(st.floats(-1.2, 1.2), st.floats(-1.2, 1.2), st.floats(-np.pi, np.pi)).map(np.array),
)
def test_thrust_direction_and_forward_eq16_against_scipy(u, eta):
    """``R(eta) e3`` is the body z axis in the world (third column of SciPy's rotation), and the thrust
    alone accelerates the vehicle by ``g e3 - (u / m) R e3`` (eq. (16) read forward)."""
    R = R_of(eta)
    np.testing.assert_allclose(thrust_direction_W(eta), R[:, 2], atol=1e-12)
    np.testing.assert_allclose(acceleration_from_thrust(u, eta, 1.3), G * E3 - u / 1.3 * R[:, 2], atol=1e-10)


@given(
    st.tuples(st.floats(-30.0, 30.0), st.floats(-30.0, 30.0), st.floats(-25.0, 40.0)).map(np.array),
    st.floats(-np.pi, np.pi),
    st.floats(0.2, 1.2),
    st.floats(0.5, 5.0),
)
def test_eq16_limits_shorten_the_request_but_keep_its_direction(mu_bar, psi, tilt_max, min_lift):
    """Whatever the request, including a dive (``mu_bar_3 > g``, where the rotors would have to pull): the
    thrust found by eq. (16), applied through a SciPy rotation, tilts at most ``tilt_max``, lifts at least
    ``min_lift``, and accelerates horizontally in the requested direction (shortened, never reversed); a
    request within both limits is met exactly."""
    m = 1.2
    u, phi, theta, limited = thrust_and_attitude(mu_bar, psi, m, tilt_max=tilt_max, min_lift_accel=min_lift)
    R = R_of(np.array([phi, theta, psi]))
    a = G * E3 - u / m * R[:, 2]  # the acceleration this thrust gives
    assert np.arccos(np.clip(R[2, 2], -1.0, 1.0)) <= tilt_max + 1e-9
    assert G - a[2] >= min_lift * (1 - 1e-9)
    h, h_req = a[:2], mu_bar[:2]
    assert h @ h_req >= -1e-9 and abs(h[0] * h_req[1] - h[1] * h_req[0]) <= 1e-7 * (1 + np.abs(h_req).sum())
    assert np.linalg.norm(h) <= np.linalg.norm(h_req) + 1e-9
    within = G - mu_bar[2] >= min_lift and np.linalg.norm(h_req) <= (G - mu_bar[2]) * np.tan(tilt_max) * (1 - 1e-9)
    if within:
        assert not limited
        np.testing.assert_allclose(a, mu_bar, atol=1e-8 * (1 + np.abs(mu_bar).max()))


# ----------------------------------------------------------------------------- allocation, eq. (4)


def _plus_with_limits(f_max, f_min=(0.0, 0.0, 0.0, 0.0), arm=0.21):
    pos = [(-arm, 0.0, 0.0), (0.0, -arm, 0.0), (arm, 0.0, 0.0), (0.0, arm, 0.0)]
    spins = (1, -1, 1, -1)
    return VehicleParams(
        1.2,
        [3.4e-3, 3.4e-3, 4.7e-3],
        rotors=tuple(Rotor(p, s, hi, lo) for p, s, hi, lo in zip(pos, spins, f_max, f_min, strict=True)),
    )


def test_pure_thrust_beyond_what_the_rotors_give_is_capped_with_no_torque_and_flagged():
    """Eq. (4) for the '+' layout: zero roll, pitch and yaw torque means ``f1 = f3``, ``f2 = f4`` and
    ``f1 + f3 = f2 + f4``, i.e. four equal forces. So a pure thrust request beyond what the rotors give is
    met by all four at the weakest rotor's limit, with no torque, and reported as saturated (the PID's
    anti-windup relies on the flag)."""
    for f_max, u in (((7.0, 7.0, 7.0, 7.0), 40.0), ((3.0, 7.0, 7.0, 7.0), 20.0)):
        g = _plus_with_limits(f_max).geometry
        a = allocate(u, np.zeros(3), g.E, g.E_pinv, g.f_min, g.f_max)
        np.testing.assert_allclose(a.f, min(f_max), atol=1e-9)
        u_out, tau_out = mix(a.f, g.E)
        assert u_out == pytest.approx(4 * min(f_max))
        np.testing.assert_allclose(tau_out, 0.0, atol=1e-12)
        assert a.saturated


def test_limits_that_leave_no_shared_collective_are_refused():
    """Hovering without torque needs four equal forces (above); with one rotor that cannot go below 5 N and
    another that cannot exceed 4 N there is none, and the vehicle is refused."""
    with pytest.raises(InputError, match="no collective thrust"):
        _plus_with_limits((4.0, 7.0, 7.0, 7.0), f_min=(0.0, 0.0, 5.0, 0.0))
    _plus_with_limits((4.5, 7.0, 7.0, 7.0), f_min=(0.0, 0.0, 4.0, 0.0))  # 4 to 4.5 N each: possible


def test_an_inertia_beyond_the_rigid_body_bound_is_refused():
    """Principal moments of a rigid body obey ``I1 + I2 >= I3`` (``I3 = sum m (x^2 + y^2)``): 5 % beyond it
    is not a rigid body; a flat frame exactly at the bound is."""
    with pytest.raises(InputError, match="triangle inequality"):
        VehicleParams(1.0, [1e-3, 1e-3, 2.1e-3])
    VehicleParams(1.0, [1e-3, 1e-3, 2.0e-3])


# ----------------------------------------------------------------------------- estimator, eqs. (6)-(13)

I_TRUE = np.diag([3.4e-3, 4.1e-3, 4.7e-3])  # all three different


def _coning(t, phi0=0.3, rate=2.0, psi0=np.pi - 4.0):
    """A vehicle at constant roll ``phi0`` turning at a constant yaw rate with the thrust that holds its
    height, ``u = m g / cos(phi0)``: its horizontal acceleration ``g tan(phi0)`` turns with the heading, so
    it flies a circle at ``v = (g tan(phi0) / rate) [cos psi, sin psi, 0]``. Its body rates are constant, so
    the torque it needs is ``omega x I omega`` (Euler's equation). The heading passes +-pi at t = 2 s."""
    psi = psi0 + rate * t
    eta = np.array([phi0, 0.0, (psi + np.pi) % (2 * np.pi) - np.pi])
    eta_dot = np.array([0.0, 0.0, rate])
    v = G * np.tan(phi0) / rate * np.array([np.cos(psi), np.sin(psi), 0.0])
    return eta, eta_dot, v


@pytest.mark.parametrize("dv, da", [(2.5, 1.0), (0.0, 2.5)])
def test_estimator_aligned_to_sensor_delays_sees_no_wrench_on_a_turning_vehicle(dv, da):
    """The velocity ``dv`` periods old, the attitude ``da`` periods old, no external wrench: the estimator
    told the delays compares like with like. Attitude newer than the velocity (2.5 vs 1 period) is
    interpolated in its history, across the +-pi heading wrap: nothing but the trapezoid rule's O(Ts^2) is
    left. Attitude older than the velocity is not extrapolated (module docstring): the force then lags by
    at most the acceleration's change over ``da - dv`` periods, ``m g tan(phi0) rate (da - dv) Ts``."""
    m, Ts, phi0, rate = 1.2, 0.01, 0.3, 2.0
    params = EstimatorParams(wn=10.0, velocity_delay=dv * Ts, attitude_delay=da * Ts)
    des = design(params, Ts)
    st_ = initial_state(des)
    u = m * G / np.cos(phi0)
    n = 300
    t = np.arange(n) * Ts
    rows = {"eta": [], "eta_dot": [], "v": [], "tau": []}
    r = np.zeros((n, 6))
    for k, tk in enumerate(t):
        eta, eta_dot, _ = _coning(tk - da * Ts)
        v = _coning(tk - dv * Ts)[2]
        w = Q_num(eta) @ eta_dot
        tau_B = np.cross(w, I_TRUE @ w)
        st_, r[k] = estimator_step(des, st_, eta, eta_dot, v, u, tau_B, m, I_TRUE)
        for key, val in zip(rows, (eta, eta_dot, v, tau_B), strict=True):
            rows[key].append(val)
    late = t > 1.5  # the history starts filled with the first sample; the heading wraps at t = 2 s
    np.testing.assert_allclose(r[late, 3:], 0.0, atol=1e-9)
    lag = max(da - dv, 0.0) * Ts
    bound = 1e-3 + 1.1 * m * G * np.tan(phi0) * rate * lag
    assert np.abs(r[late, :3]).max() < bound
    if lag == 0.0:  # the series over a whole log does the same alignment
        a = {key: np.array(val) for key, val in rows.items()}
        w_bar = momentum_residual(a["v"], a["eta"], a["eta_dot"], np.full(n, u), a["tau"], m, I_TRUE, Ts, des)
        assert np.abs(causal(des, w_bar)[late]).max() < bound


def test_estimator_rotor_model_is_exact_for_a_first_order_rotor():
    """Level, moving only vertically, the rotors a first-order lag ``tau y' = c - y`` behind a varying
    command held over each period, a constant push ``F`` down: the vertical velocity integrates
    ``g - y / m + F / m`` (the lag's integral over a period in closed form). An estimator told the rotor's
    time constant returns G's step response to ``F``, ``F (1 - (1 + wn t) e^(-wn t))``, at every sample."""
    m, Ts, tau, wn, F = 1.2, 0.01, 0.03, 10.0, 0.7
    des = design(EstimatorParams(wn=wn, rotor_tau=tau), Ts)
    st_ = initial_state(des)
    n = 150
    t = np.arange(n) * Ts
    c = m * G + 1.5 * np.sin(2.3 * t) + 0.8 * ((np.arange(n) // 7) % 2)
    alpha = np.exp(-Ts / tau)
    c_prev, y, v = m * G, m * G, 0.0  # the first call sees the rotor at the command it is given
    z3 = np.zeros(3)
    for k in range(n):
        st_, r = estimator_step(des, st_, z3, z3, np.array([0.0, 0.0, v]), c_prev, z3, m, I_TRUE)
        expected = F * (1.0 - (1.0 + wn * t[k]) * np.exp(-wn * t[k]))
        assert r[2] == pytest.approx(expected, abs=1e-9)
        np.testing.assert_allclose(r[[0, 1, 3, 4, 5]], 0.0, atol=1e-12)
        integral = c[k] * Ts + (y - c[k]) * tau * (1.0 - alpha)
        v += G * Ts - integral / m + F * Ts / m
        y = c[k] + (y - c[k]) * alpha
        c_prev = c[k]


@pytest.mark.parametrize(
    "params, lti",
    [
        (EstimatorParams(wn=10.0, zeta=1.0), scipy.signal.lti([100.0], [1.0, 20.0, 100.0])),
        (EstimatorParams(wn=8.0, zeta=0.6), scipy.signal.lti([64.0], [1.0, 9.6, 64.0])),
        (EstimatorParams(wn=12.0, order=3, prototype="binomial"), scipy.signal.lti([12.0**3], np.poly([-12.0] * 3))),
        (
            EstimatorParams(wn=12.0, order=4, prototype="butterworth"),
            scipy.signal.lti(*scipy.signal.butter(4, 12.0, analog=True)),
        ),
    ],
    ids=["zeta1", "zeta0.6", "binomial3", "butterworth4"],
)
def test_estimator_lag_is_the_area_above_the_step_response(params, lti):
    """The low-frequency delay of a unit-gain filter, ``-G'(0)``, is the area between 1 and its step
    response; the estimate's rate output is the derivative of that step response at the samples. G built
    here from (wn, zeta), the binomial form or SciPy's Butterworth, not from the package's poles."""
    Ts = 0.01
    des = design(params, Ts)
    tt = np.linspace(0.0, 3.0, 30001)
    _, step = lti.step(T=tt)
    area = np.trapezoid(1.0 - step, tt)
    np.testing.assert_allclose(des.lag, area, rtol=1e-5)
    np.testing.assert_allclose(des.lead, area, rtol=1e-5)  # no measurement delay here
    den = np.real(np.poly(params.channel_poles()[0]))  # the package's poles give G's denominator
    np.testing.assert_allclose(den, lti.den / lti.den[0], rtol=1e-9)
    # a constant force on a level vehicle from t = 0: r_k is the step response at t_k, r_dot_k its slope
    m, w = 1.2, np.array([0.0, 0.0, 0.9, 0.0, 0.0, 0.0])
    st_ = initial_state(des)
    z3 = np.zeros(3)
    t = np.arange(60) * Ts
    _, s, _ = scipy.signal.lsim(lti, np.ones_like(t), t)
    slope = lti.impulse(T=t)[1]
    for k in range(len(t)):
        st_, r = estimator_step(des, st_, z3, z3, w[:3] / m * t[k], m * G, z3, m, I_TRUE)
        if k:
            assert r[2] == pytest.approx(0.9 * s[k], abs=1e-7)
            assert st_.r_dot[2] == pytest.approx(0.9 * slope[k], abs=1e-6 * params.wn[0])


def test_first_order_estimate_rate_is_the_low_pass_slope():
    """Order 1 (``r' = wn (w - r)``), a constant force from t = 0: ``r = F (1 - e^(-wn t))`` and its rate
    ``F wn e^(-wn t)``, the input feeding straight into the rate."""
    m, Ts, wn, F = 1.2, 0.01, 5.0, 0.9
    des = design(EstimatorParams(wn=wn, order=1, prototype="binomial"), Ts)
    st_ = initial_state(des)
    z3 = np.zeros(3)
    for k in range(1, 50):
        st_, r = estimator_step(des, st_, z3, z3, np.array([F / m * (k - 1) * Ts, 0.0, 0.0]), m * G, z3, m, I_TRUE)
        if k > 1:
            tk = (k - 1) * Ts
            assert r[0] == pytest.approx(F * (1 - np.exp(-wn * tk)), abs=1e-10)
            assert st_.r_dot[0] == pytest.approx(F * wn * np.exp(-wn * tk), abs=1e-9)


# ----------------------------------------------------------------------------- the controller in closed loop
# A rigid body integrated here (RK4 at 1 ms, rotation matrix and body rates), measured exactly and flown by
# the NumPy controller at 100 Hz; the nominal model is the true one, so the steady states are exact.

MASS = 1.2
VEH = VehicleParams(MASS, np.diag(I_TRUE), arm_length=0.21, drag_factor=0.016, f_max=50.0)
I_INV = np.linalg.inv(I_TRUE)


def _rates(y, u, tau_B, f_ext_W, tau_ext_B):
    v, R, w = y[3:6], y[6:15].reshape(3, 3), y[15:18]
    a = G * E3 - u / MASS * R[:, 2] + f_ext_W / MASS
    w_dot = I_INV @ (tau_B + tau_ext_B - np.cross(w, I_TRUE @ w))
    S = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    return np.concatenate([v, a, (R @ S).ravel(), w_dot])


def fly(params, ref, f_ext_W, tau_ext_B, T, p0=(0.0, 0.0, -1.0)):
    """Fly ``T`` seconds from hover at ``p0`` under a constant external wrench; the last output, the state."""
    ctrl = Controller(params, backend="numpy")
    f_ext_W, tau_ext_B = np.asarray(f_ext_W, float), np.asarray(tau_ext_B, float)
    y = np.concatenate([p0, np.zeros(3), np.eye(3).ravel(), np.zeros(3)])
    h = 0.001
    hist = []
    for _ in range(int(round(T / params.Ts))):
        U, _, Vt = np.linalg.svd(y[6:15].reshape(3, 3))
        y[6:15] = (U @ Vt).ravel()
        eta = eta_of(y[6:15].reshape(3, 3))
        out = ctrl.step(Measurement(y[0:3], y[3:6], eta, np.linalg.solve(Q_num(eta), y[15:18])), ref)
        args = (float(out.thrust), np.asarray(out.tau_B), f_ext_W, tau_ext_B)
        for _ in range(int(round(params.Ts / h))):
            k1 = _rates(y, *args)
            k2 = _rates(y + h / 2 * k1, *args)
            k3 = _rates(y + h / 2 * k2, *args)
            k4 = _rates(y + h * k3, *args)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        hist.append(y[0:3] - ref.p_W)
    return out, y, eta_of(y[6:15].reshape(3, 3)), np.array(hist)


def test_pd_plus_compensation_rejects_a_constant_wrench():
    """PD+C (Sec. VI): a constant external force and body moment are estimated and cancelled, so the vehicle
    returns to its point and heading (PD alone would sag by f / Kp = 19 cm and turn by tau_z / Ko); the
    estimated body moment is the applied one, and the thrust axis balances the weight and the force."""
    f, tau = np.array([3.0, -2.0, 0.8]), np.array([0.01, -0.008, 0.005])
    ref = Reference(np.array([0.0, 0.0, -1.0]))
    out, y, eta, _ = fly(ControllerParams.paper("pdc", vehicle=VEH), ref, f, tau, 6.0)
    np.testing.assert_allclose(y[0:3], ref.p_W, atol=2e-3)
    assert abs(eta[2]) < 1e-3
    np.testing.assert_allclose(out.f_hat_W, f, atol=5e-3)
    np.testing.assert_allclose(out.tau_hat_B, tau, atol=2e-4)
    need = MASS * G * E3 + f  # u R e3 must cancel weight and push
    np.testing.assert_allclose(y[6:15].reshape(3, 3)[:, 2], need / np.linalg.norm(need), atol=2e-3)
    assert np.arccos(y[14]) > 0.25  # premise: tilted, so body and Euler moments differ


def test_pid_integral_removes_the_steady_error_as_the_linear_loop_does():
    """PID (no estimate): along x, ``m e'' + Dp e' + Kp e + Ki int e = f``, solved here; the integral acts
    with the proportional term and the error decays (with the wrong sign it would grow)."""
    Kp, Dp, Ki, f = 16.0, 12.0, 6.0, 1.0
    params = ControllerParams(VEH, ImpedanceGains.paper(VEH.inertia, Ki=Ki), "pid")
    _, _, _, e = fly(params, Reference(np.array([0.0, 0.0, -1.0])), [f, 0.0, 0.0], np.zeros(3), 8.0)
    t = np.arange(1, len(e) + 1) * params.Ts
    lin = solve_ivp(lambda _, s: [s[1], s[2], (f - Dp * s[2] - Kp * s[1] - Ki * s[0]) / MASS], (0, t[-1]),
                    [0.0, 0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12).y[1]  # fmt: skip
    assert np.abs(e[:, 0] - lin).max() < 0.15 * f / Kp  # the attitude loop lags a little
    assert abs(e[-1, 0]) < 0.05 * f / Kp


def test_comply_settles_where_its_stiffness_says_and_the_attitude_rejects():
    """``comply`` on x with ``M_d e'' + D_d e' + K_d e = f``: a constant push settles at ``f / K_d``
    whatever ``M_d`` (here not the vehicle's mass, so the estimate is fed forward). Given three fractions
    the attitude rejects: a roll moment is cancelled, the vehicle stays level in roll and on y and z."""
    f, K = 1.0, 5.0
    params = ControllerParams.paper("comply", vehicle=VEH, impedance=Impedance(M=2.0, D=6.0, K=K))
    ref = Reference(np.array([0.0, 0.0, -1.0]), comply=np.array([1.0, 0.0, 0.0]))
    _, y, eta, _ = fly(params, ref, [f, 0.0, 0.0], [0.01, 0.0, 0.0], 8.0)
    assert y[0] == pytest.approx(f / K, rel=0.02)
    np.testing.assert_allclose(y[1:3], ref.p_W[1:], atol=2e-3)
    need = MASS * G * E3 + [f, 0.0, 0.0]  # at rest the thrust axis balances weight and push: no roll
    np.testing.assert_allclose(y[6:15].reshape(3, 3)[:, 2], need / np.linalg.norm(need), atol=1e-3)
    assert abs(eta[0]) < 1e-3


def test_comply_heading_settles_where_its_stiffness_says():
    """Yaw complying with ``M_o e'' + D_o e' + K_o e = tau_ext_eta``: a constant yaw moment on a level vehicle
    (where ``tau_eta = tau_B``) settles the heading at ``tau / K_o``, turned the way the moment pushes."""
    tau, K_o = 0.005, 0.5
    imp = Impedance(M=2.0, D=6.0, K=5.0, M_o=0.01, D_o=0.12, K_o=K_o)
    params = ControllerParams.paper("comply", vehicle=VEH, impedance=imp)
    ref = Reference(np.array([0.0, 0.0, -1.0]), comply=np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0]))
    _, y, eta, _ = fly(params, ref, np.zeros(3), [0.0, 0.0, tau], 5.0)
    assert eta[2] == pytest.approx(tau / K_o, rel=0.03)
    np.testing.assert_allclose(y[0:3], ref.p_W, atol=2e-3)


def test_yaw_error_takes_the_short_way_across_pi():
    """Heading 179 deg, wanted -179 deg: the error is the 2 deg rotation between them (SciPy's relative
    rotation), not 358 deg, so the yaw torque pushes on through +-pi, as much as the PD torque of 2 deg."""
    p = ControllerParams.paper("pd", vehicle=VEH)
    psi, psi_d = np.radians(179.0), np.radians(-179.0)
    out = Controller(p, backend="numpy").step(
        Measurement(np.array([0.0, 0.0, -1.0]), np.zeros(3), np.array([0.0, 0.0, psi]), np.zeros(3)),
        Reference(np.array([0.0, 0.0, -1.0]), psi=psi_d),
    )
    rel = Rotation.from_euler("Z", psi_d) * Rotation.from_euler("Z", psi).inv()
    e = -rel.as_rotvec()[2]  # psi - psi_d the short way: -2 deg
    assert out.tau_B_request[2] == pytest.approx(-p.gains.Ko[2] * e, rel=1e-6)
    assert out.tau_B_request[2] > 0


def test_attitude_filter_gives_the_step_response_and_its_derivatives():
    """The critically damped filter on the desired attitude, a unit step from rest: value
    ``1 - (1 + wn t) e^(-wn t)``, rate ``wn^2 t e^(-wn t)`` and acceleration ``wn^2 (1 - wn t) e^(-wn t)`` (the
    last feeds eq. (18b)), at every sample (the filter is discretised exactly for a held input)."""
    wn, Ts = 25.0, 0.01
    des = design_filter(wn, 1.0, Ts)
    state = FilterState(np.zeros(2), np.zeros(2), True)
    for k in range(40):
        state, x, xd, xdd = filter_step(des, state, np.ones(2))
        t = k * Ts
        e = np.exp(-wn * t)
        np.testing.assert_allclose(x, 1 - (1 + wn * t) * e, atol=1e-12)
        np.testing.assert_allclose(xd, wn * wn * t * e, atol=1e-9)
        np.testing.assert_allclose(xdd, wn * wn * (1 - wn * t) * e, atol=1e-8)


# ----------------------------------------------------------------------------- reference, gains, vehicle


def test_reference_velocity_and_acceleration_are_the_derivatives_of_its_position():
    """Hold, a minimum-jerk move, a circle with speed ramps, a hold: ``v`` is the derivative of ``p`` and ``a``
    that of ``v`` everywhere (central differences), so eq. (18a)'s feedforward is the path's own."""
    start = (0.0, 0.0, -1.0)
    traj = Trajectory(
        (Hold(start, 0.5), MinJerk(start, (1.0, -0.5, -1.5), 2.0), Circle((1.0, -0.5, -1.5), 0.8, 0.6, 1.0, 1.5))
    )
    h = 1e-4
    t = np.arange(0.01, traj.duration + 0.5, 0.0137)
    s, sp, sm = (traj.sample_many(t + d) for d in (0.0, h, -h))
    np.testing.assert_allclose((sp[:, 0:3] - sm[:, 0:3]) / (2 * h), s[:, 3:6], atol=1e-5)
    np.testing.assert_allclose((sp[:, 3:6] - sm[:, 3:6]) / (2 * h), s[:, 6:9], atol=1e-4)
    assert np.abs(s[:, 6:9]).max() > 0.3  # premise: it accelerates


def test_a_yaw_step_is_in_force_from_its_own_time_as_a_segment_is():
    """A yaw step at t holds from t on, as a segment starting at t does (and a comply switch)."""
    traj = Trajectory((Hold((0.0, 0.0, -1.0), 1.0), Hold((0.0, 0.0, -1.0), 1.0)), yaw_steps=((1.0, 0.5),))
    psi = traj.sample_many(np.array([0.99, 1.0, 1.01]))[:, 9]
    np.testing.assert_array_equal(psi, [0.0, 0.5, 0.5])


@pytest.mark.parametrize("mass", [0.6, 2.5])
def test_papers_gains_for_another_mass_keep_the_papers_closed_loop_poles(mass):
    """``ImpedanceGains.paper(..., mass=m)`` keeps the roots of ``m s^3 + Dp s^2 + Kp s + Ki`` (the PID loop of
    eq. (19a); without Ki the PD's ``m s^2 + Dp s + Kp``) those of the paper's 1.2 kg with 16, 12 and 0.5."""
    g = ImpedanceGains.paper(np.diag([3.4e-3, 3.4e-3, 4.7e-3]), Ki=0.5, mass=mass)
    want = np.sort_complex(np.roots([1.2, 12.0, 16.0, 0.5]))
    np.testing.assert_allclose(np.sort_complex(np.roots([mass, g.Dp[0], g.Kp[0], g.Ki[0]])), want, rtol=1e-9)
    np.testing.assert_allclose(np.sort_complex(np.roots([mass, g.Dp[0], g.Kp[0]])),
                               np.sort_complex(np.roots([1.2, 12.0, 16.0])), rtol=1e-9)  # fmt: skip


@pytest.mark.parametrize("M, D, K", [(2.0, 6.0, 5.0), (0.5, 0.4, 8.0)])
def test_impedance_natural_frequency_and_damping_are_its_roots(M, D, K):
    """``M s^2 + D s + K``: the product of the roots is ``wn^2``, their sum ``-2 zeta wn``."""
    roots = np.roots([M, D, K])
    wn = np.sqrt(np.prod(roots).real)
    nat = Impedance(M=M, D=D, K=K).natural()
    np.testing.assert_allclose(nat["wn"], wn, rtol=1e-12)
    np.testing.assert_allclose(nat["zeta"], -np.sum(roots).real / (2 * wn), rtol=1e-12)


# ----------------------------------------------------------------------------- stability margins


def _sampled_loop(num, den, Ts=0.001, delay=0.0, gain=1.0):
    A, B, C, _ = scipy.signal.tf2ss(gain * np.asarray(num, float), den)
    Ad, Bd, Cd = sampled_plant(A, B, [(C, delay)], Ts)
    return ct.ss(Ad, Bd, Cd, 0.0, Ts)


def _closed_loop_stable(L) -> bool:
    return bool(np.all(np.abs(np.linalg.eigvals(ct.feedback(L, 1).A)) < 1.0))


def test_margins_are_the_distances_to_instability_with_several_crossings():
    """Loops that cross over several times: a PD-like loop with a resonance (three gain crossovers, the
    one of least phase margin not the one of least delay margin), and a conditionally stable loop (three
    phase crossovers above unit gain). The delay margin is the least added latency that destabilises (a
    resonant loop can be stable again at longer delays), the gain margins the least gain change that does,
    whichever crossover sets them: checked on the closed-loop poles over the whole range below them."""
    wr = 30.0  # |L| of k (1 + s/4) / s^2 raised above 1 again by a resonance at 30 rad/s
    num = np.polymul([0.25, 1.0], [1.0, 2 * 0.7 * wr, wr * wr])
    den = np.polymul([1.0, 0.0, 0.0], [1.0, 2 * 0.005 * wr, wr * wr])
    dm = loop_margins("res", _sampled_loop(num, den)).delay_s
    assert all(_closed_loop_stable(_sampled_loop(num, den, delay=d)) for d in np.linspace(0.0, 0.97 * dm, 8))
    assert not _closed_loop_stable(_sampled_loop(num, den, delay=1.03 * dm))
    wr = 4.0  # 10 (1 + s)^2 / s^3 with a lightly damped pair: stable only for some gains below 1
    num = np.polymul(10.0 * np.array([1.0, 2.0, 1.0]), [1.0, 2 * 0.5 * wr, wr * wr])
    den = np.polymul([1.0, 0.0, 0.0, 0.0], [1.0, 2 * 0.02 * wr, wr * wr])
    gm = loop_margins("cond", _sampled_loop(num, den))
    assert np.isfinite(gm.gain_down_db) and np.isfinite(gm.gain_up_db)
    for db, sign in ((gm.gain_down_db, -1.0), (gm.gain_up_db, 1.0)):
        gains = 10 ** (sign * np.linspace(0.0, 0.97 * db, 12) / 20)
        assert all(_closed_loop_stable(_sampled_loop(num, den, gain=g)) for g in gains)
        assert not _closed_loop_stable(_sampled_loop(num, den, gain=10 ** (sign * 1.03 * db / 20)))


def test_damping_ratio_of_the_closed_loop_poles():
    """Roots of ``s^2 + 2 zeta wn s + wn^2`` have damping ``zeta`` whatever ``wn``; a real pole, 1."""
    poles = np.concatenate([np.roots([1.0, 2 * 0.3 * 4.0, 16.0]), np.roots([1.0, 2 * 0.8 * 20.0, 400.0]), [-5.0]])
    rep = MarginReport({}, poles)
    assert rep.damping == pytest.approx(0.3, rel=1e-12)
    assert abs(rep.least_damped) == pytest.approx(4.0, rel=1e-12)
    assert MarginReport({}, np.array([-5.0])).damping == pytest.approx(1.0)


def test_the_circle_is_flown_clockwise_seen_from_above():
    """From its start north of the centre the circle heads east: about NED's +z (down), the positive sense,
    which seen from above is clockwise, as the docstring says."""
    c = Circle((0.0, 0.0, -1.0), 1.0, 0.5, 1.0, 2.0)
    p, v, _ = c.sample(np.linspace(0.5, 12.0, 50))
    r = p - np.array([-1.0, 0.0, -1.0])  # from the centre, 1 m south of the start
    assert np.all(np.cross(r, v)[:, 2] > 0) and v[0, 1] > 0
