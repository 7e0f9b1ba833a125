"""Physics checked against references written here, independently of the library, on both backends.

Each test targets a kind of bug that a comparison of the two backends cannot see (the same mistake
written into both): the estimator's C^T eta_dot term on a tumbling body with unequal inertia, the
Q^{-T} C eta_dot term of the torque law (14), the rotor lag and the sensor latency of the closed loop,
PID anti-windup, and sideways payload offsets.
"""

import numpy as np
import pytest
import scipy.signal
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from vtol_impedance import Controller
from vtol_impedance.control import ControllerParams, ImpedanceGains, Measurement, Reference
from vtol_impedance.model import VehicleParams
from vtol_impedance.scenarios import get, set_value, simulate

BACKENDS = ["numpy", "compiled"]
G = 9.81
TS = 0.01
I_TRUE = np.diag([3.4e-3, 4.1e-3, 4.7e-3])  # all three different
MASS = 1.2
VEH = VehicleParams(MASS, np.diag(I_TRUE), arm_length=0.21, drag_factor=0.016, f_max=50.0)


# ----------------------------------------------------------------- independent kinematics (SciPy + finite differences)


def R_of(eta):
    phi, theta, psi = eta
    return Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()


def eta_of(R):
    psi, theta, phi = Rotation.from_matrix(R).as_euler("ZYX")
    return np.array([phi, theta, psi])


def Q_num(eta, h=1e-6):
    """omega_B = Q eta_dot, from S(omega_B) = R^T R_dot by central differences."""
    R = R_of(eta)
    cols = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        S = R.T @ (R_of(eta + e) - R_of(eta - e)) / (2 * h)
        cols.append([S[2, 1], S[0, 2], S[1, 0]])
    return np.array(cols).T


def Qdot_num(eta, eta_dot, h=1e-6):
    return (Q_num(eta + h * eta_dot) - Q_num(eta - h * eta_dot)) / (2 * h)


def rigid_body(t, y, u, tau_B, f_ext_W, tau_ext_B):
    v, R, w = y[3:6], y[6:15].reshape(3, 3), y[15:18]
    a = np.array([0, 0, G]) - u / MASS * R[:, 2] + f_ext_W / MASS
    w_dot = np.linalg.solve(I_TRUE, tau_B + tau_ext_B - np.cross(w, I_TRUE @ w))
    R_dot = R @ np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    return np.concatenate([v, a, R_dot.ravel(), w_dot])


def hold_command(ctrl, u, tau_B):
    """Make the controller's estimator see (u, tau_B) as the command held over the last period."""
    if ctrl.backend == "numpy":
        ctrl.state = ctrl.state._replace(thrust_prev=np.asarray(u, float), tau_B_prev=np.asarray(tau_B, float))
    else:
        ctrl._s["thrust_prev"][0] = u
        ctrl._s["tau_B_prev"][0] = tau_B


def fly_estimator(backend, f_ext_W, tau_ext_B, omega0, T=3.0):
    """Tumbling body integrated by DOP853; the controller's estimator fed at 100 Hz with the applied command."""
    ctrl = Controller(
        ControllerParams(VEH, ImpedanceGains.paper(VEH.inertia), "pdc"),
        backend=backend,
    )
    eta0 = np.array([0.1, -0.2, 0.3])
    y = np.concatenate([np.zeros(3), np.zeros(3), R_of(eta0).ravel(), omega0])
    u = MASS * G
    tau_prev = np.zeros(3)
    out = {"t": [], "tau_hat_eta": [], "f_hat_W": [], "tau_ext_eta": [], "eta": [], "ctd": [], "w": []}
    ref = Reference(np.zeros(3))
    for k in range(int(T / TS)):
        R = y[6:15].reshape(3, 3)
        U, _, Vt = np.linalg.svd(R)
        R = U @ Vt
        eta = eta_of(R)
        w = y[15:18]
        Q = Q_num(eta)
        eta_dot = np.linalg.solve(Q, w)
        hold_command(ctrl, u, tau_prev)
        o = ctrl.step(Measurement(y[0:3], y[3:6], eta, eta_dot), ref)
        out["t"].append(k * TS)
        out["tau_hat_eta"].append(np.array(o.tau_hat_eta))
        out["f_hat_W"].append(np.array(o.f_hat_W))
        out["tau_ext_eta"].append(Q.T @ tau_ext_B)
        out["eta"].append(eta)
        out["w"].append(np.linalg.norm(w))
        # the size of C^T eta_dot, from Euler's equations: Q^T (w x I w) + Q^T I Qdot eta_dot
        out["ctd"].append(np.linalg.norm(Q.T @ (np.cross(w, I_TRUE @ w) + I_TRUE @ Qdot_num(eta, eta_dot) @ eta_dot)))
        tau_B = 0.004 * np.array([np.sin(1.3 * k * TS), np.cos(0.7 * k * TS), -np.sin(0.4 * k * TS)])
        sol = solve_ivp(
            rigid_body, (0, TS), y, args=(u, tau_B, f_ext_W, tau_ext_B), method="DOP853", rtol=1e-11, atol=1e-12
        )
        y = sol.y[:, -1]
        tau_prev = tau_B
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("backend", BACKENDS)
def test_estimator_sees_nothing_on_a_tumbling_body_without_external_wrench(backend):
    r = fly_estimator(backend, np.zeros(3), np.zeros(3), omega0=np.array([1.5, -1.2, 2.5]))
    assert np.max(np.abs(r["eta"][:, 1])) < 1.2  # premise: away from the Euler singularity
    scale = r["ctd"].max()
    assert scale > 2e-3  # premise: the C^T eta_dot term is large here
    # a sign error or C in place of C^T in beta would leave an error of the order of `scale`
    assert np.abs(r["tau_hat_eta"]).max() < 0.05 * scale
    # the force part sees only the trapezoid rule on a thrust direction turning by |w| Ts per period
    assert np.abs(r["f_hat_W"]).max() < MASS * G * (r["w"].max() * TS) ** 2


@pytest.mark.parametrize("backend", BACKENDS)
def test_estimator_recovers_a_known_wrench_while_rotating(backend):
    f_ext = np.array([0.3, -0.2, 0.5])
    tau_ext_B = np.array([0.006, -0.008, 0.004])
    r = fly_estimator(backend, f_ext, tau_ext_B, omega0=np.array([0.6, -0.4, 0.8]), T=1.6)
    # the reference: G(s) of eq. (10) (wn = 10, zeta = 1) applied to the true wrench, by SciPy
    G_s = scipy.signal.lti([100.0], [1.0, 20.0, 100.0])
    t = r["t"]
    for i in range(3):
        expected_f = scipy.signal.lsim(G_s, np.full_like(t, f_ext[i]), t)[1]
        expected_tau = scipy.signal.lsim(G_s, r["tau_ext_eta"][:, i], t)[1]
        late = t > 0.8
        # the trapezoid on the turning thrust (see above); one sample of lag at most for the moment,
        # bounded by the largest change of its input over a period
        tol_f = MASS * G * (r["w"].max() * TS) ** 2
        tol_tau = np.abs(np.diff(r["tau_ext_eta"][:, i])).max() * 1.5 + 2e-4
        np.testing.assert_allclose(r["f_hat_W"][late, i], expected_f[late], atol=tol_f)
        np.testing.assert_allclose(r["tau_hat_eta"][late, i], expected_tau[late], atol=tol_tau)


@pytest.mark.parametrize("backend", BACKENDS)
def test_torque_law_gives_the_commanded_euler_acceleration(backend):
    """Eq. (14) into Euler's equations gives eta_ddot = tau_bar of (18b) (eq. (15) with no residual)."""
    p = ControllerParams(VEH, ImpedanceGains.paper(VEH.inertia), "pd")
    Ko, Do = p.gains.Ko, p.gains.Do
    rng = np.random.default_rng(5)
    for _ in range(5):
        ctrl = Controller(p, backend=backend)
        eta = rng.uniform([-0.5, -0.5, -3], [0.5, 0.5, 3])
        eta_dot = rng.uniform(-2.0, 2.0, 3)
        o = ctrl.step(Measurement(np.zeros(3), np.zeros(3), eta, eta_dot), Reference(np.zeros(3), psi=0.2))
        # first step: eta_d as output, its rates zero (the filter starts at rest)
        e = (eta - np.array(o.eta_d) + np.pi) % (2 * np.pi) - np.pi
        Q = Q_num(eta)
        Qd = Qdot_num(eta, eta_dot)
        w = Q @ eta_dot
        M = Q.T @ I_TRUE @ Q
        C_eta_dot = Q.T @ (np.cross(w, I_TRUE @ w) + I_TRUE @ Qd @ eta_dot)
        # (18b) needs C e_dot with e_dot = eta_dot here, which is C eta_dot
        tau_bar = -np.linalg.solve(M, Do * eta_dot + C_eta_dot + Ko * e)
        w_dot = np.linalg.solve(I_TRUE, np.asarray(o.tau_B_request) - np.cross(w, I_TRUE @ w))
        eta_ddot = np.linalg.solve(Q, w_dot - Qd @ eta_dot)
        np.testing.assert_allclose(eta_ddot, tau_bar, rtol=1e-5, atol=1e-6 * np.abs(tau_bar).max())


@pytest.fixture(scope="module", params=BACKENDS)
def lag_run(request):
    # 5 s: on the ground, then the take-off, where the rotor commands rise and fall fastest (the largest lag
    # of a 12 s flight with the circle is already there); the NumPy backend flies about 2 s of wall per s
    spec = set_value(get("case-c-circle"), "duration", 5.0)
    spec = set_value(spec, "sensors.pos_noise", 0.0)
    spec = set_value(spec, "sensors.vel_noise", 0.0)
    spec = set_value(spec, "sensors.att_noise", 0.0)
    spec = set_value(spec, "sensors.gyro_noise", 0.0)
    spec = set_value(spec, "sensors.mocap_delay", 0.02)
    spec = set_value(spec, "sensors.imu_delay", 0.01)
    return spec, simulate(spec, ["pdc"], backend=request.param)


def test_rotor_forces_follow_the_first_order_lag(lag_run):
    spec, r = lag_run
    f, cmd = r["f_rotor"][0], r["f_rotor_cmd"][0]
    tau_up, tau_dn = spec.plant.rotor_tau_up, spec.plant.rotor_tau_down
    target = np.clip(cmd[:-1], 0.0, 7.0)
    rising = target > f[:-1]
    decay = np.where(rising, np.exp(-TS / tau_up), np.exp(-TS / tau_dn))
    expected = target + (f[:-1] - target) * decay
    np.testing.assert_allclose(f[1:], expected, atol=1e-6)
    # premise: the lag is visible both ways (tau_up and tau_down swapped would be off by > 1e-3 N)
    gap = np.abs(f[1:] - target)
    assert gap.max() > 0.05 and gap[rising].max() > 0.01 and gap[~rising].max() > 0.05


def test_measurements_are_the_true_state_delayed(lag_run):
    _, r = lag_run
    # 20 ms of mocap latency = 2 control periods, 10 ms of IMU latency = 1
    np.testing.assert_allclose(r["p_meas_W"][0, 2:], r["p_W"][0, :-2], atol=1e-12)
    np.testing.assert_allclose(r["v_meas_W"][0, 2:], r["v_W"][0, :-2], atol=1e-12)
    np.testing.assert_allclose(r["eta_meas"][0, 1:], r["eta"][0, :-1], atol=1e-12)
    assert np.abs(np.diff(r["p_W"][0], axis=0)).max() > 1e-3  # premise: it moves


@pytest.mark.parametrize("backend", BACKENDS)
def test_pid_integral_stays_frozen_while_saturated(backend):
    """Anti-windup: while the tilt limit acts, the integral of e_p does not grow."""
    pid = Controller(ControllerParams.paper("pid"), backend=backend)
    pd = Controller(ControllerParams.paper("pd"), backend=backend)
    far = Measurement(np.array([10.0, 0.0, -1.0]), np.zeros(3), np.zeros(3), np.zeros(3))
    for _ in range(200):  # 2 s, 10 m off: the tilt limit acts all along
        o = pid.step(far, Reference(np.array([0.0, 0.0, -1.0])))
        pd.step(far, Reference(np.array([0.0, 0.0, -1.0])))
        assert o.tilt_limited
    at = Measurement(np.array([0.0, 0.0, -1.0]), np.zeros(3), np.zeros(3), np.zeros(3))
    a = pid.step(at, Reference(np.array([0.0, 0.0, -1.0])))
    b = pd.step(at, Reference(np.array([0.0, 0.0, -1.0])))
    # no accumulated integral: PID acts like PD once back at the point (a wound-up one would pull by Ki * 20 m s)
    np.testing.assert_allclose(np.array(a.mu_bar), np.array(b.mu_bar), atol=1e-12)


@pytest.mark.parametrize("offset", [(0.0, 0.03, 0.02), (0.02, -0.03, 0.0), (-0.01, 0.02, -0.02)])
def test_sideways_payload_offsets_agree_between_backends_and_tilt_the_right_way(offset):
    spec = set_value(set_value(get("case-a-payload"), "payload.offset_B", list(offset)), "duration", 10.0)
    spec = set_value(spec, "payload.mass", 0.3)
    # the backends agree over the ground phase, the lift-off and the climb with the payload's moment acting
    # (a different offset law differs at once: 0.1 % more offset moves p_W by 6e-5 m by 2.5 s); the slow NumPy
    # backend flies only those 2.5 s (lift-off at 1.96 s, then 0.5 s of climb with the moment acting)
    short = set_value(spec, "duration", 2.5)
    n, c = simulate(short, ["pd"], backend="numpy"), simulate(short, ["pd"], backend="compiled")
    np.testing.assert_allclose(n["p_W"], c["p_W"], atol=1e-9)
    np.testing.assert_allclose(n["eta"], c["eta"], atol=1e-9)
    assert np.abs(c["tau_B"][0, -1, :2]).max() > 0.5 * 0.3 * G * 0.02  # premise: the moment acts in the window
    a = simulate(spec, ["pd"], backend="compiled")  # the hover after the climb, on the backend shown equal
    # physics: PD has no moment compensation, so in hover the weight of the payload, hanging sideways at
    # offset y, must be balanced by a roll torque of the rotors: tau_x = -m_p g y (sign from r x F with
    # F = m_p g e3 in NED, body level)
    # the rotors cancel r x (m_p g e3) = (y m_p g, -x m_p g, 0)
    tau = a["tau_B"][0, -100:].mean(0)
    assert tau[0] == pytest.approx(-0.3 * G * offset[1], abs=0.1 * 0.3 * G * 0.03)
    assert tau[1] == pytest.approx(0.3 * G * offset[0], abs=0.1 * 0.3 * G * 0.03)
