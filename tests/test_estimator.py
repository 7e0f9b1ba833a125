"""The momentum-based estimator, eqs. (6)-(13), against analytic responses and the literal eq. (11)."""

import warnings

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from vtol_impedance.conventions import G
from vtol_impedance.errors import InputError
from vtol_impedance.estimator import (
    EstimatorBandwidthWarning,
    EstimatorParams,
    design,
    estimator_step,
    initial_state,
)

M = 1.2
I_B = np.diag([3.4e-3, 3.4e-3, 4.7e-3])
TS = 0.01


def run_level_vehicle(params, wrench_fn, T, Ts=TS):
    """A level vehicle with hover thrust pushed by an external *force* (the moment channels stay at rest).

    With eta = 0, eta_dot = 0 and thrust m g, eq. (8) gives q_dot = [f_ext; 0], so q(t) is the integral
    of the force, computed here by fine quadrature (independent of the estimator).
    """
    des = design(params, Ts)
    st = initial_state(des)
    zeros = np.zeros(3)
    n = int(round(T / Ts))
    out = np.zeros((n + 1, 6))
    q = np.zeros(6)
    fine = 200
    for k in range(n + 1):
        if k > 0:
            ts = np.linspace((k - 1) * Ts, k * Ts, fine + 1)
            vals = np.array([wrench_fn(t) for t in ts])
            q = q + np.trapezoid(vals, ts, axis=0)
        v_W = q[:3] / M
        st, r = estimator_step(des, st, zeros, zeros, v_W, M * G, zeros, M, I_B)
        out[k] = r
    return np.arange(n + 1) * Ts, out


def test_step_response_is_that_of_G_at_the_samples():
    w = np.array([1.0, -2.0, 0.5, 0.0, 0.0, 0.0])
    t, r = run_level_vehicle(EstimatorParams(wn=10.0, zeta=1.0), lambda t: w, 1.5)
    # analytic step of wn^2/(s+wn)^2 starting at the first sample
    tt = t[1:] - t[1] + TS
    expected = (1 - np.exp(-10 * (tt - 0.0)) * (1 + 10 * tt))[:, None] * w
    np.testing.assert_allclose(r[1:], expected, atol=1e-9 * np.abs(w).max())
    # 95 % at the analytic 0.474 s, to the next sample
    k95 = np.argmax(r[:, 2] >= 0.95 * w[2])
    assert 0.47 <= t[k95] <= 0.49


def test_constant_wrench_recovered_exactly():
    w = np.array([0.3, -0.7, 1.079, 0.0, 0.0, 0.0])
    _, r = run_level_vehicle(EstimatorParams(), lambda t: w, 4.0)
    np.testing.assert_allclose(r[-1], w, rtol=1e-9)


def test_matches_literal_eq11_on_a_sinusoid():
    """Integrate eq. (11) literally in continuous time and compare with the discrete estimator."""
    A, Om = 1.0, 3.0
    wfun = lambda t: np.array([A * np.sin(Om * t), 0, 0, 0, 0, 0])  # noqa: E731
    p = EstimatorParams(wn=10.0, zeta=1.0)
    k1, k2 = p.K1[0], p.K2[0]
    t, r = run_level_vehicle(p, wfun, 4.0)

    # (11): r = K1 int(-r + K2 (q - int(beta + r))); here beta_x = 0 and q_x = int w_x.
    def rhs(tt, s):
        rr, i1 = s
        q = A * (1 - np.cos(Om * tt)) / Om
        return [k1 * (-rr + k2 * (q - i1)), rr]

    sol = solve_ivp(rhs, (0, 4.0), [0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=1e-3)
    # The discrete estimator sees the period average of w: a half-period lag, O(A Om Ts / 2).
    err = np.abs(r[:, 0] - sol.y[0])
    assert err.max() < 0.6 * A * Om * TS
    # and the steady amplitude equals |G(j Om)| (independent of both)
    gain = 100 / np.abs((1j * Om) ** 2 + 20 * 1j * Om + 100)
    tail = t > 2.5
    assert np.ptp(r[tail, 0]) / 2 == pytest.approx(gain * A, rel=0.02)


@pytest.mark.filterwarnings("ignore:Badly conditioned filter coefficients")
@pytest.mark.parametrize("order,proto", [(1, "binomial"), (3, "binomial"), (4, "butterworth"), (5, "butterworth")])
def test_any_order_matches_scipy_step_and_is_exact_in_steady_state(order, proto):
    p = EstimatorParams(wn=12.0, order=order, prototype=proto)
    w = np.array([0.5, 0, -0.2, 0, 0, 0])
    t, r = run_level_vehicle(p, lambda t: w, 5.0)
    poles = p.channel_poles()[0]
    num = [np.real(np.prod(-poles))]
    den = np.real(np.poly(poles))
    sysd = signal.cont2discrete((num, den), TS, method="zoh")
    _, y = signal.dstep(sysd, n=len(t))  # y[0] = 0: the step enters at sample 0, our r[1] is its y[1]
    np.testing.assert_allclose(r[1:, 0], 0.5 * np.ravel(y[0])[1:], atol=1e-9)
    np.testing.assert_allclose(r[-1], w, rtol=1e-6, atol=1e-12)


def test_first_order_is_the_classic_momentum_observer():
    # r_dot = K (w - r): a first-order low-pass with time constant 1/K
    p = EstimatorParams(wn=5.0, order=1, prototype="binomial")
    t, r = run_level_vehicle(p, lambda t: np.array([1.0, 0, 0, 0, 0, 0]), 1.0)
    np.testing.assert_allclose(r[1:, 0], 1 - np.exp(-5.0 * t[1:]), atol=1e-12)


def test_gains_from_eq13():
    p = EstimatorParams.from_gains(K1=20.0, K2=5.0)
    np.testing.assert_allclose(p.wn, 10.0)
    np.testing.assert_allclose(p.zeta, 1.0)
    np.testing.assert_allclose(p.K1, 20.0)
    np.testing.assert_allclose(p.K2, 5.0)


def test_bandwidth_checks():
    with pytest.raises(InputError, match="Ts"):
        design(EstimatorParams(wn=400.0), 0.01)
    with pytest.warns(EstimatorBandwidthWarning, match="Ts"):
        design(EstimatorParams(wn=80.0), 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        design(EstimatorParams(wn=10.0), 0.01)


@pytest.mark.parametrize(
    "kw",
    [
        {"wn": -1.0},
        {"wn": np.nan},
        {"zeta": 0.0},
        {"order": 0},
        {"order": 3},
        {"prototype": "bessel"},
        {"order": 2, "poles": [1.0, -2.0]},
        {"order": 2, "poles": [-1.0]},
    ],
)
def test_bad_parameters_are_refused(kw):
    with pytest.raises(InputError):
        EstimatorParams(**kw)


def test_batched_equals_single(rng):
    des = design(EstimatorParams(), TS)
    B = 4
    eta = rng.uniform(-0.3, 0.3, (6, B, 3))
    eta_dot = rng.uniform(-1, 1, (6, B, 3))
    v = rng.uniform(-1, 1, (6, B, 3))
    u = rng.uniform(10, 14, (6, B))
    tau = rng.uniform(-0.1, 0.1, (6, B, 3))
    sb = initial_state(des, (B,))
    singles = [initial_state(des) for _ in range(B)]
    for k in range(6):
        sb, rb = estimator_step(des, sb, eta[k], eta_dot[k], v[k], u[k], tau[k], M, I_B)
        for b in range(B):
            singles[b], r1 = estimator_step(
                des, singles[b], eta[k, b], eta_dot[k, b], v[k, b], u[k, b], tau[k, b], M, I_B
            )
            np.testing.assert_allclose(rb[b], r1, atol=1e-14)


@pytest.mark.parametrize("backend", ["compiled", "numpy"])
def test_online_estimator_finds_the_force_that_holds_a_still_vehicle(backend):
    """A vehicle at rest, level, with thrust m g + 2 N and a body torque: the world must push 2 N down and
    cancel the torque (Newton, independent of the filter), reached as G's step response."""
    from vtol_impedance import Estimator

    m, Ts = 1.3, 0.01
    est = Estimator(m, [0.01, 0.012, 0.02], Ts, EstimatorParams(wn=10.0, rotor_tau=0.02), backend=backend)
    tau_B = np.array([0.02, -0.01, 0.005])
    z = np.zeros(3)
    outs = [est.step(z, z, m * G + 2.0, tau_B, omega_B=z) for _ in range(300)]
    np.testing.assert_allclose(outs[0].f_hat_W, 0.0)
    np.testing.assert_allclose(outs[-1].f_hat_W, [0.0, 0.0, 2.0], atol=1e-6)
    np.testing.assert_allclose(outs[-1].tau_hat_B, -tau_B, atol=1e-8)
    # second-order, zeta = 1: at t = 2/wn the step response is 1 - 3 e^-2
    k = round(0.2 / Ts)
    assert outs[k].f_hat_W[2] == pytest.approx(2.0 * (1 - 3 * np.exp(-2.0)), rel=0.08)
    # no torque command: the moment is not estimated, and says so
    assert np.all(np.isnan(est.step(z, z, m * G, omega_B=z).tau_hat_B))
    est.reset()
    np.testing.assert_allclose(est.step(z, z, m * G, tau_B, omega_B=z).f_hat_W, 0.0)


def test_online_estimator_backends_agree_with_delays_and_rotor_lag(rng):
    from vtol_impedance import Estimator

    timing = {"velocity_delay": 0.023, "attitude_delay": 0.011, "rotor_tau": 0.03}
    p = EstimatorParams(wn=8.0, order=3, prototype="binomial", **timing)
    a = Estimator(1.2, [0.01, 0.012, 0.02], 0.01, p)
    b = Estimator(1.2, [0.01, 0.012, 0.02], 0.01, p, backend="numpy")
    for _ in range(200):
        v, eta, w = rng.normal(size=3) * 0.1, rng.normal(size=3) * 0.1, rng.normal(size=3)
        tau = rng.normal(size=3) * 0.01
        u = 11.0 + rng.normal()  # a varying thrust: each channel's own delay into the histories shows
        np.testing.assert_allclose(
            np.concatenate(a.step(v, eta, u, tau, omega_B=w)),
            np.concatenate(b.step(v, eta, u, tau, omega_B=w)),
            atol=1e-12,
        )


@pytest.mark.parametrize(
    "kw",
    [
        {"v_W": [0, 0, np.nan]},
        {"v_W": [0, 0]},
        {"eta": [0, np.pi / 2, 0]},
        {"thrust_prev": "9.8"},
        {"thrust_prev": 1e300},
        {"thrust_prev": -5.0},  # rotors push, never pull
        {"thrust_prev": np.array([11.0, 11.0])},  # was a TypeError
        {"omega_B": None},
        {"v_W": np.zeros((1, 3))},  # a batch of one: the compiled kernel's typing error, NumPy's broadcast error
        {"v_W": np.zeros((2, 3))},
        {"eta": np.zeros((1, 3))},
        {"omega_B": np.zeros((1, 3))},
        {"tau_B_prev": np.zeros((1, 3))},
        {"omega_B": None, "eta_dot": np.zeros((1, 3))},
    ],
)
@pytest.mark.parametrize("backend", ["compiled", "numpy"])
def test_online_estimator_refuses_bad_samples(kw, backend):
    from vtol_impedance import Estimator

    est = Estimator(1.0, [0.01, 0.01, 0.02], 0.01, backend=backend)
    args = {"v_W": np.zeros(3), "eta": np.zeros(3), "thrust_prev": 9.8, "omega_B": np.zeros(3)} | kw
    with pytest.raises(ValueError):  # InputError, or SingularityError at theta = 90 deg
        est.step(args.pop("v_W"), args.pop("eta"), args.pop("thrust_prev"), **args)
    with pytest.raises(InputError):
        Estimator(-1.0, [0.01, 0.01, 0.02], 0.01)
    with pytest.raises(InputError):
        Estimator(1.0, [0.01, -0.01, 0.02], 0.01)
    with pytest.raises(InputError, match="triangle inequality"):  # as the CLI and the vehicle files refuse it
        Estimator(1.0, [1.0, 1.0, 100.0], 0.01)
    with pytest.raises(InputError, match="symmetric"):
        Estimator(1.0, [[0.01, 0.001, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.02]], 0.01)


def test_designs_are_kept_per_period_and_cannot_be_changed_by_a_caller():
    """A design is kept for reuse (expm is most of its cost): the same filter at another period must be a
    new design (checked against scipy's own zero-order-hold discretisation), and what a caller does to
    the design it got must not change what the next run gets."""
    p = EstimatorParams(wn=9.0, order=2)
    poles = p.channel_poles()[0]
    for Ts in (0.01, 0.004, 0.01):
        des = design(p, Ts)
        A, B, C, _, _ = signal.cont2discrete(signal.tf2ss([np.real(np.prod(-poles))], np.real(np.poly(poles))), Ts)
        # same transfer function from w to r: compare impulse responses (state coordinates differ)
        h_ref = [float((C @ np.linalg.matrix_power(A, k) @ B)[0, 0]) for k in range(30)]
        h = [float(des.C[0] @ np.linalg.matrix_power(des.Ad[0], k) @ des.Bd[0]) for k in range(30)]
        np.testing.assert_allclose(h, h_ref, rtol=1e-9, atol=1e-12)
        kept = des.Ad[0][0, 0]
        des.Ad[0][0, 0] += 1.0
        des.Bd[:] = 0.0
        again = design(p, Ts)
        assert again.Ad[0][0, 0] == kept and np.all(again.Bd != 0.0)
    a1, a2 = design(p, 0.01), design(p, 0.004)
    assert not np.allclose(a1.Ad, a2.Ad)
    assert a1.Ts == 0.01 and a2.Ts == 0.004


def test_the_attitude_filter_design_is_the_exact_discretisation():
    from vtol_impedance.control.attitude_filter import design_filter

    for wn, zeta, Ts in ((20.0, 1.0, 0.01), (30.0, 0.7, 0.01), (20.0, 1.0, 0.002)):
        f = design_filter(wn, zeta, Ts)
        A = np.array([[0.0, 1.0], [-wn * wn, -2 * zeta * wn]])
        Ad, Bd, *_ = signal.cont2discrete((A, np.array([[0.0], [wn * wn]]), np.eye(2), np.zeros((2, 1))), Ts)
        np.testing.assert_allclose(f.Ad, Ad, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(f.Bd, Bd[:, 0], rtol=1e-12, atol=1e-14)
        with pytest.raises(ValueError):
            f.Bd[0] = 0.0


@pytest.mark.parametrize("tau, Ts", [(0.02, 0.01), (0.05, 0.01), (0.005, 0.02)])
def test_the_rotor_models_period_mean_is_the_lags_mean(tau, Ts):
    """A first-order rotor ``tau y' = c - y`` from ``y0`` over one period: ``y(Ts) = c + (y0 - c) alpha`` and
    its mean ``c + (y0 - c) gamma``; alpha and gamma checked against the exponential, integrated by quad."""
    from scipy.integrate import quad

    d = design(EstimatorParams(rotor_tau=tau), Ts)
    assert d.alpha == pytest.approx(np.exp(-Ts / tau), rel=1e-12)
    assert d.gamma == pytest.approx(quad(lambda t: np.exp(-t / tau), 0.0, Ts)[0] / Ts, rel=1e-9)
    none = design(EstimatorParams(rotor_tau=0.0), Ts)  # no lag: the rotor is at its command at once
    assert none.alpha == 0.0 and none.gamma == 0.0
