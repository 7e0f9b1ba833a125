"""Wrench estimation on flight logs: CSV and ULog (both PX4 generations), frames, resampling, zero-phase,
bias, hover fit, and every kind of bad log.

The flights come from ``synthflight`` (Newton-Euler with a known external wrench), the ULog files from an
independent writer; the expected estimate is the continuous G(s) of eq. (10) applied to the true wrench.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import synthflight as S
from ulog_writer import write_ulog

from vtol_impedance.cli import main
from vtol_impedance.errors import InputError
from vtol_impedance.estimator import EstimatorParams, design, estimator_step, initial_state
from vtol_impedance.estimator.series import causal, momentum_residual, zero_phase
from vtol_impedance.logs import estimate, fit_hover_thrust, frames, read_any, read_csv, read_ulog, resample
from vtol_impedance.logs.timeseries import RawLog, Signal
from vtol_impedance.model.kinematics import euler_rate_matrix_Q, rotation_zyx

WN = 10.0
TS = 0.01
STEP_BOUND = WN / math.e * TS  # largest change of the step response of G in one period, per unit step


@pytest.fixture(scope="module")
def fl():
    return S.flight()


def _raw(fl, v_every: int = 1) -> RawLog:
    t = fl.t
    return RawLog(
        Signal("velocity", "v", t[::v_every], fl.v_W[::v_every]),
        Signal("attitude", "eta", t, fl.eta),
        Signal("body rates", "w", t, fl.omega_B),
        Signal("thrust", "u", t, fl.thrust[:, None], hold=True),
        Signal("torque", "tau", t, fl.tau_B, hold=True),
    )


def _thrust_rate_bound(fl) -> float:
    """Zero-order hold of a command that changes: at most max|du/dt| * Ts of thrust error."""
    return float(np.max(np.abs(np.diff(fl.thrust))) / np.diff(fl.t)[0] * TS)


def _write_csv(path, cols: dict[str, np.ndarray]):
    names = list(cols)
    np.savetxt(path, np.column_stack([cols[n] for n in names]), delimiter=",", header=",".join(names), comments="")
    return path


def _csv_cols(fl, world="ned", body="frd", quat=None, deg=False):
    R = frames.rotation_from_ned_frd(rotation_zyx(fl.eta), world, body)
    wm, bm = frames.world_matrix(world), frames.body_matrix(body)
    v, w, tq = fl.v_W @ wm.T, fl.omega_B @ bm.T, fl.tau_B @ bm.T
    k = 180 / np.pi if deg else 1.0
    cols = {"t_s": fl.t, "vx": v[:, 0], "vy": v[:, 1], "vz": v[:, 2]}
    if quat is None:
        from vtol_impedance.model.kinematics import euler_from_rotation

        e = euler_from_rotation(R) * k
        cols.update(roll=e[:, 0], pitch=e[:, 1], yaw=e[:, 2])
    else:
        from scipy.spatial.transform import Rotation

        q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
        q = q if quat == "xyzw" else q[:, [3, 0, 1, 2]]
        cols.update({f"q{i}": q[:, i] for i in range(4)})
    cols.update(
        wx=w[:, 0] * k, wy=w[:, 1] * k, wz=w[:, 2] * k, thrust_n=fl.thrust, tx=tq[:, 0], ty=tq[:, 1], tz=tq[:, 2]
    )
    return cols


# ----------------------------------------------------------------------------- the estimate itself


def test_three_executions_agree(fl):
    """The step-by-step definition (estimator_step), the vectorised series and the compiled loop."""
    f = resample(_raw(fl), 100.0)
    n = 400
    des = design(EstimatorParams(), f.Ts)
    I_B = S.INERTIA
    st = initial_state(des)
    ref = np.zeros((n, 6))
    for k in range(n):
        prev = max(k - 1, 0)
        st, ref[k] = estimator_step(
            des, st, f.eta[k], f.eta_dot[k], f.v_W[k], f.thrust[prev], f.tau_B[prev], np.array(S.MASS), I_B
        )
    w = momentum_residual(f.v_W[:n], f.eta[:n], f.eta_dot[:n], f.thrust[:n], f.tau_B[:n], S.MASS, I_B, f.Ts)
    np.testing.assert_allclose(causal(des, w)[:, :], ref, atol=1e-10)
    for backend in ("compiled", "numpy"):
        e = estimate(f, S.MASS, np.diag(I_B), backend=backend)
        np.testing.assert_allclose(e.f_W[:n], ref[:, :3], atol=1e-9)
        np.testing.assert_allclose(e.tau_eta[:n], ref[:, 3:], atol=1e-10)


def test_estimate_follows_g_of_the_true_wrench(fl):
    """Force and moment against lsim of G(s) on the true wrench, within the bound of the discretisation:
    a step inside a period (STEP_BOUND per unit) plus the zero-order hold of the changing thrust."""
    f = resample(_raw(fl), 100.0)
    e = estimate(f, S.MASS, np.diag(S.INERTIA))
    truth_f = S.g_response(f.t, S.f_ext_of)
    bound_f = STEP_BOUND * np.abs(S.F_STEP) + _thrust_rate_bound(fl) + 1e-4
    assert np.all(np.abs(e.f_W - truth_f).max(0) < bound_f)

    def tau_eta_of(t):  # the estimator's moment target: Q^T tau_ext_B (eq. (5b))
        Q = euler_rate_matrix_Q(S.eta_of(t))
        return np.einsum("nji,nj->ni", Q, S.tau_ext_of(t))

    truth_tau = S.g_response(f.t, tau_eta_of)
    assert np.all(np.abs(e.tau_eta - truth_tau).max(0) < STEP_BOUND * np.abs(S.TAU_STEP) + 1e-4)
    np.testing.assert_allclose(e.tau_B, _tau_B_truth(f.t), atol=STEP_BOUND * np.abs(S.TAU_STEP).max() + 1e-4)


def _tau_B_truth(t):
    """What an ideal estimator reports in the body frame: ``Q^-T`` of G applied to the Euler-coordinate
    target ``Q^T tau_ext_B`` (which moves with the attitude, so G's lag shows even for a constant moment)."""

    def tau_eta_of(tt):
        return np.einsum("nji,nj->ni", euler_rate_matrix_Q(S.eta_of(tt)), S.tau_ext_of(tt))

    QT = np.swapaxes(euler_rate_matrix_Q(S.eta_of(t)), -1, -2)
    return np.linalg.solve(QT, S.g_response(t, tau_eta_of)[..., None])[..., 0]


def test_a_wrong_mass_shows_as_a_constant_force_along_thrust(fl):
    """The documented signature of a mass error: m_nominal - m_true times (g - a) appears as a force."""
    f = resample(_raw(fl), 100.0)
    e_true = estimate(f, S.MASS, np.diag(S.INERTIA))
    e_heavy = estimate(f, S.MASS * 1.1, np.diag(S.INERTIA))
    late = f.t > 11.0
    acc = np.gradient(f.v_W, f.t, axis=0)
    expected = 0.1 * S.MASS * (acc - np.array([0, 0, S.G]))[late]
    np.testing.assert_allclose((e_heavy.f_W - e_true.f_W)[late], expected, atol=0.02)


def test_zero_phase_has_no_lag_on_a_ramp():
    """A residual that ramps: the causal G lags by 2 zeta / wn, the zero-phase variant not at all."""
    des = design(EstimatorParams(), TS)
    t = np.arange(0, 20, TS)
    slope = 0.5
    w = slope * (t - TS / 2)[:, None] * np.ones(6)  # mean over (t_k - Ts, t_k]
    w[0] = 0
    zp = zero_phase(des, w)
    c = causal(des, w)
    mid = (t > 5) & (t < 15)
    np.testing.assert_allclose(zp[mid, 0], slope * t[mid], atol=1e-6)
    lag = 2 * 1.0 / WN
    np.testing.assert_allclose(c[mid, 0], slope * (t[mid] - lag), atol=1e-3)


def test_zero_phase_through_the_pipeline_is_centred_on_the_step(fl):
    f = resample(_raw(fl), 100.0)
    e = estimate(f, S.MASS, np.diag(S.INERTIA), zero_phase_too=True)
    fx = e.f_W_zp[:, 0]
    half = S.F_BIAS[0] + S.F_STEP[0] / 2
    t_half = np.interp(half, fx[(f.t > 4) & (f.t < 6)], f.t[(f.t > 4) & (f.t < 6)])
    assert abs(t_half - S.T_F_STEP) < TS  # symmetric response: half way exactly at the step
    far = (f.t > 1.0) & (np.abs(f.t - S.T_F_STEP) > 1.0)
    np.testing.assert_allclose(fx[far], S.f_ext_of(f.t[far])[:, 0], atol=_thrust_rate_bound(fl) + 1e-3)


def test_bias_calibration_and_removal(fl):
    f = resample(_raw(fl), 100.0)
    e = estimate(f, S.MASS, np.diag(S.INERTIA), quiet_segment=(2.0, 4.9))
    np.testing.assert_allclose(e.bias["f_W_N"], S.F_BIAS, atol=_thrust_rate_bound(fl) + 1e-3)
    np.testing.assert_allclose(e.bias["tau_B_Nm"], S.TAU_BIAS, atol=1e-3)
    r = estimate(f, S.MASS, np.diag(S.INERTIA), quiet_segment=(2.0, 4.9), remove_bias=True, zero_phase_too=True)
    sel = (f.t >= 2.0) & (f.t <= 4.9)
    np.testing.assert_allclose(r.f_W[sel].mean(0), 0, atol=1e-12)
    np.testing.assert_allclose(np.nanmean(r.f_W_zp[sel], 0), 0, atol=1e-12)
    late = f.t > 11
    np.testing.assert_allclose(r.f_W[late].mean(0), S.F_STEP, atol=0.01)  # what stays is the step
    with pytest.raises(InputError, match="quiet segment"):
        estimate(f, S.MASS, np.diag(S.INERTIA), remove_bias=True)
    e2 = estimate(f, S.MASS, np.diag(S.INERTIA), quiet_segment=(0.0, 2.0))
    assert any("transient" in n for n in e2.warnings)


# ----------------------------------------------------------------------------- frames and resampling


@pytest.mark.parametrize("world", ["ned", "enu"])
@pytest.mark.parametrize("body", ["frd", "flu"])
def test_frames_round_trip_and_known_axes(world, body, rng):
    eta = rng.uniform([-1, -1.2, -3], [1, 1.2, 3], (50, 3))
    R = rotation_zyx(eta)
    back = frames.rotation_to_ned_frd(frames.rotation_from_ned_frd(R, world, body), world, body)
    np.testing.assert_allclose(back, R, atol=1e-12)
    np.testing.assert_allclose(
        frames.eta_ned_frd(frames.rotation_from_ned_frd(R, world, body), world, body), eta, atol=1e-9
    )


def test_frame_axes_by_name():
    # east in ENU is east in NED; up is minus down
    np.testing.assert_allclose(frames.world_vector_to_ned([1.0, 0, 0], "enu"), [0, 1.0, 0])
    np.testing.assert_allclose(frames.world_vector_to_ned([0, 0, 1.0], "enu"), [0, 0, -1.0])
    # left in FLU is minus right in FRD
    np.testing.assert_allclose(frames.body_vector_to_frd([0, 1.0, 0], "flu"), [0, -1.0, 0])
    # a vehicle yawed to face north in ENU (ROS convention: yaw = +90 deg from east) has NED yaw 0
    R_enu_flu = rotation_zyx(np.array([0, 0, np.pi / 2]))
    np.testing.assert_allclose(frames.eta_ned_frd(R_enu_flu, "enu", "flu"), [0, 0, 0], atol=1e-12)
    # scalar-last and world-to-body quaternions
    q = np.array([[np.cos(0.3), 0, 0, np.sin(0.3)]])  # wxyz, yaw 0.6 rad
    R1 = frames.quaternion_rotation(q, "wxyz", "body-to-world")
    R2 = frames.quaternion_rotation(q[:, [1, 2, 3, 0]], "xyzw", "body-to-world")
    R3 = frames.quaternion_rotation(q * [1, -1, -1, -1], "wxyz", "world-to-body")
    np.testing.assert_allclose(R1, rotation_zyx(np.array([0, 0, 0.6]))[None], atol=1e-12)
    np.testing.assert_allclose(R2, R1, atol=1e-12)
    np.testing.assert_allclose(R3, R1, atol=1e-12)


def test_resampling_error_within_the_linear_interpolation_bound():
    """A 10 Hz velocity interpolated onto 100 Hz: |error| <= dt^2 / 8 * max|x''|."""
    t10 = np.arange(0, 10, 0.1)
    t1k = np.arange(0, 10, 0.001)
    a, w = 2.0, 3.0
    x = lambda t: a * np.sin(w * t)  # noqa: E731
    raw = RawLog(
        Signal("velocity", "v", t10, np.stack([x(t10)] * 3, -1)),
        Signal("attitude", "e", t1k, np.zeros((len(t1k), 3))),
        Signal("body rates", "w", t1k, np.zeros((len(t1k), 3))),
        Signal("thrust", "u", t1k, np.full((len(t1k), 1), 12.0), hold=True),
        None,
    )
    f = resample(raw, 100.0)
    bound = 0.1**2 / 8 * a * w**2
    err = np.abs(f.v_W[:, 0] - x(f.t))
    assert err.max() <= bound * 1.0001
    assert err.max() > 0.3 * bound  # the bound is the right size, not loose by orders of magnitude


def test_commands_are_held_and_attitude_interpolates_through_the_yaw_wrap():
    t = np.arange(0, 4, 0.1)
    yaw = np.unwrap(np.full(len(t), 0.0) + 2.9 + 0.5 * t)  # crosses +pi at t = 0.48 s
    wrapped = (yaw + np.pi) % (2 * np.pi) - np.pi
    step = (t >= 1.0).astype(float)
    raw = RawLog(
        Signal("velocity", "v", t, np.zeros((len(t), 3))),
        Signal("attitude", "e", t, np.stack([0 * t, 0 * t, wrapped], -1)),
        Signal("body rates", "w", t, np.zeros((len(t), 3))),
        Signal("thrust", "u", t, 10.0 + step[:, None], hold=True),
        None,
    )
    f = resample(raw, 100.0)
    expected = (2.9 + 0.5 * f.t + np.pi) % (2 * np.pi) - np.pi
    err = (f.eta[:, 2] - expected + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(err).max() < 1e-3  # nlerp of a slow rotation: exact to second order
    # a command holds until the next one: 10 before t = 1.0 s, 11 from it on
    np.testing.assert_array_equal(f.thrust, np.where(f.t >= 1.0 - 1e-9, 11.0, 10.0))


def test_enu_flu_quaternion_csv_gives_the_ned_estimate(fl, tmp_path):
    a = read_csv(_write_csv(tmp_path / "ned.csv", _csv_cols(fl)))
    b = read_csv(
        _write_csv(tmp_path / "enu.csv", _csv_cols(fl, "enu", "flu", quat="xyzw", deg=True)),
        world="enu", body="flu", angle_unit="deg", quat_order="xyzw",
    )  # fmt: skip
    ea = estimate(resample(a), S.MASS, np.diag(S.INERTIA))
    eb = estimate(resample(b), S.MASS, np.diag(S.INERTIA))
    np.testing.assert_allclose(eb.f_W, ea.f_W, atol=1e-6)
    np.testing.assert_allclose(eb.tau_B, ea.tau_B, atol=1e-7)
    late = ea.t > 11
    np.testing.assert_allclose(ea.f_W[late].mean(0), S.F_BIAS + S.F_STEP, atol=0.01)


# ----------------------------------------------------------------------------- ULog


A = 0.175  # X quadrotor arm projection, m
KM = 0.05
HOVER = 0.42
ROTORS = [(A, A, KM), (-A, -A, KM), (A, -A, -KM), (-A, A, -KM)]
CA = {"CA_ROTOR_COUNT": 4.0}
for _i, (_x, _y, _k) in enumerate(ROTORS):
    CA.update({f"CA_ROTOR{_i}_PX": _x, f"CA_ROTOR{_i}_PY": _y, f"CA_ROTOR{_i}_KM": _k})


def _ulog(fl, path, generation: str, params=CA, v_every: int = 25, topics_drop=(), **version):
    """The synthetic flight as PX4 would log it: velocity at 10 Hz, commands normalised."""
    us = (fl.t * 1e6).astype(np.uint64) + np.uint64(1_000_000)
    c_t = S.MASS * S.G / (4 * HOVER)  # a rotor's thrust at full command (linear map)
    # hand-derived normalisation of PX4's allocator for this X quad: roll/pitch 2 sqrt(2) a c_T, yaw 4 km c_T
    k = np.array([2 * math.sqrt(2) * A, 2 * math.sqrt(2) * A, 4 * KM]) * c_t
    u = fl.thrust * HOVER / (S.MASS * S.G)
    c = fl.tau_B / k
    from vtol_impedance.model.kinematics import quat_from_euler

    topics = {
        "vehicle_local_position": {"timestamp": us[::v_every], "vx": fl.v_W[::v_every, 0], "vy": fl.v_W[::v_every, 1],
                                   "vz": fl.v_W[::v_every, 2]},
        "vehicle_attitude": {"timestamp": us, "q": quat_from_euler(fl.eta)},
        "hover_thrust_estimate": {"timestamp": us[::50], "hover_thrust": np.full(len(us[::50]), HOVER),
                                  "valid": np.ones(len(us[::50]))},
    }  # fmt: skip
    if generation == "new":
        topics["vehicle_angular_velocity"] = {"timestamp": us, "xyz": fl.omega_B}
        topics["vehicle_thrust_setpoint"] = {"timestamp": us, "xyz": np.stack([0 * u, 0 * u, -u], -1)}
        topics["vehicle_torque_setpoint"] = {"timestamp": us, "xyz": c}
    else:
        topics["vehicle_attitude"].update(
            rollspeed=fl.omega_B[:, 0], pitchspeed=fl.omega_B[:, 1], yawspeed=fl.omega_B[:, 2]
        )
        topics["actuator_controls_0"] = {"timestamp": us, "control": np.column_stack([c, u, np.zeros((len(u), 4))])}
    for name in topics_drop:
        topics.pop(name)
    return write_ulog(path, topics, params, "v1.14.0" if generation == "new" else "v1.12.3", **version)


def _accel_bound(fl, dt_v: float) -> float:
    """Linear interpolation of velocity sampled every dt_v: the derivative is off by <= dt_v / 2 * max|a'|."""
    t = np.linspace(0, 12, 20001)
    smooth = S.accel(t) - S.f_ext_of(t) / S.MASS  # the wrench is constant over the windows checked
    jerk = np.gradient(smooth, t, axis=0)
    return float(S.MASS * dt_v / 2 * np.abs(jerk).max())


@pytest.mark.parametrize(
    "release, git_hash, named",
    [(0x010F00FF, None, "v1.15.0"), (0x010F0000, "cb09dde6e1a2", "v1.15.0 (dev cb09dde6)"), (None, None, "unknown")],
)
def test_a_px4_logs_version_is_named_for_releases_and_development_builds(fl, tmp_path, release, git_hash, named):
    """PX4 encodes its version as major, minor, patch and a type byte (255: release, 0: development);
    pyulog names only releases, so a development build is named here with its git hash."""
    raw = read_ulog(_ulog(fl, tmp_path / "v.ulg", "new", release=release, git_hash=git_hash))
    assert raw.meta["px4_version"] == named


@pytest.mark.parametrize("generation", ["new", "old"])
def test_ulog_both_px4_generations(fl, tmp_path, generation):
    path = _ulog(fl, tmp_path / f"{generation}.ulg", generation)
    raw = read_ulog(path)
    assert raw.meta["px4_generation"].startswith(">=" if generation == "new" else "<")
    f = resample(raw, 100.0)
    e = estimate(f, S.MASS, np.diag(S.INERTIA))
    t_true = f.t - 1.0
    assert "hover_thrust_estimate" in e.info["thrust"]
    steady = ((t_true > 3) & (t_true < 4.9)) | (t_true > 10)
    bound_f = _accel_bound(fl, 0.1) + _thrust_rate_bound(fl) + 1e-3
    np.testing.assert_allclose(e.f_W[steady], S.f_ext_of(t_true[steady]), atol=bound_f)
    # the torque map is exact up to float32: a few per cent of the smallest moment (5 mN m) is a scale error
    np.testing.assert_allclose(e.tau_B[steady], _tau_B_truth(t_true)[steady], atol=5e-5)


def test_ulog_without_rotor_geometry_skips_the_moment(fl, tmp_path, capsys):
    path = _ulog(fl, tmp_path / "old.ulg", "old", params={})
    e = estimate(resample(read_ulog(path)), S.MASS, np.diag(S.INERTIA))
    assert e.tau_B is None and e.f_W is not None
    assert any("moment estimate is skipped" in n for n in e.notes)
    e2 = estimate(resample(read_ulog(path)), S.MASS, np.diag(S.INERTIA), torque_scale=[1.0, 1.0, 1.0])
    assert e2.tau_B is not None


def test_hover_thrust_fitted_on_a_tilted_hover(tmp_path):
    """Held tilted 20 deg by a steady side force (a wind), the vehicle's vertical balance is
    ``u cos(phi) cos(theta) m g / h = m g``: the fit finds h exactly, where a balance without the tilt
    would be off by 1/cos (7 %). Conventions unchecked: the thrust axis is tilted from the specific force
    on purpose (the side force holds it)."""
    t = np.arange(0.0, 10.0, 0.01)
    phi, theta = 0.1, 0.35 + 0.05 * np.sin(1.3 * t)
    theta_dot = 0.05 * 1.3 * np.cos(1.3 * t)
    z = np.zeros_like(t)
    cols = {"t_s": t, "vx": z, "vy": z, "vz": z, "roll": z + phi, "pitch": theta, "yaw": z,
            "wx": z, "wy": np.cos(phi) * theta_dot, "wz": -np.sin(phi) * theta_dot,  # omega_B = Q eta_dot
            "thrust_norm": 0.45 / (np.cos(phi) * np.cos(theta))}  # fmt: skip
    raw, _ = read_any(_write_csv(tmp_path / "tilted.csv", cols), conventions="unchecked")
    h, res = fit_hover_thrust(resample(raw, 100.0), 1.5, (2.0, 8.0))
    assert h == pytest.approx(0.45, rel=1e-4) and res < 1e-3  # the interpolated attitude: 1e-5


def test_hover_thrust_fitted_on_a_segment(fl, tmp_path):
    """The fit absorbs any vertical external force: h_fit = h / (1 - f_z / (m g)) to first order, and the
    estimated vertical force over the segment is then zero on average."""
    path = _ulog(fl, tmp_path / "new.ulg", "new", topics_drop=("hover_thrust_estimate",))
    f = resample(read_ulog(path), 100.0)
    h, _ = fit_hover_thrust(f, S.MASS, (3.0, 5.9))
    expected = HOVER / (1 - S.F_BIAS[2] / (S.MASS * S.G))
    assert abs(h / expected - 1) < 0.005
    auto = estimate(f, S.MASS, np.diag(S.INERTIA))  # no hover thrust anywhere: the hover windows' fit
    assert abs(auto.info["hover_thrust"]["median"] / expected - 1) < 0.005 and "automatic" in auto.info["thrust"]
    e = estimate(f, S.MASS, np.diag(S.INERTIA), hover_segment=(3.0, 5.9))
    sel = (f.t >= 3.0) & (f.t <= 5.9)
    assert abs(e.f_W[sel, 2].mean()) < 0.01
    e = estimate(f, S.MASS, np.diag(S.INERTIA), hover_thrust=HOVER)
    assert e.info["hover_thrust"]["median"] == HOVER


# ----------------------------------------------------------------------------- bad logs


def test_missing_columns_and_topics_are_listed(fl, tmp_path):
    cols = _csv_cols(fl)
    del cols["wy"]
    with pytest.raises(InputError, match=r"body rates needs column\(s\) wy; the file has: t_s, vx"):
        read_csv(_write_csv(tmp_path / "a.csv", cols))
    path = _ulog(fl, tmp_path / "x.ulg", "new", topics_drop=("vehicle_local_position",))
    with pytest.raises(
        InputError, match=r"no velocity: needs vehicle_local_position .*the log has: .*vehicle_attitude"
    ):
        read_ulog(path)


def test_time_faults(fl, tmp_path):
    cols = _csv_cols(fl)
    t = cols["t_s"].copy()
    t[500] = t[498]
    with pytest.raises(InputError, match="time goes backwards at row 500"):
        resample(read_csv(_write_csv(tmp_path / "back.csv", {**cols, "t_s": t})))
    t = cols["t_s"].copy()
    t[501] = t[500]  # a repeated timestamp: kept the last row, reported
    f = resample(read_csv(_write_csv(tmp_path / "dup.csv", {**cols, "t_s": t})))
    assert any("repeated timestamp" in n for n in f.notes)
    # a gap of 1 s in every signal: grid points inside removed, estimator restarted, reported
    keep = (cols["t_s"] < 6.0) | (cols["t_s"] > 7.0)
    f = resample(read_csv(_write_csv(tmp_path / "gap.csv", {k: v[keep] for k, v in cols.items()})))
    assert not np.any((f.t > 6.0 + 1e-9) & (f.t < 7.0 - 1e-9))
    assert f.restart.sum() == 2 and any("gap" in n for n in f.notes)
    e = estimate(f, S.MASS, np.diag(S.INERTIA))
    after = np.flatnonzero(f.restart)[1]
    assert np.all(e.f_W[after] == 0)  # starts afresh after the gap


def test_nan_stretch_becomes_a_reported_gap(fl, tmp_path):
    cols = _csv_cols(fl)
    vx = cols["vx"].copy()
    vx[1000:1200] = np.nan  # 0.8 s of velocity lost
    f = resample(read_csv(_write_csv(tmp_path / "nan.csv", {**cols, "vx": vx})))
    assert any("NaN" in n for n in f.notes) and any("gap in velocity" in n for n in f.notes)
    assert np.all(np.isfinite(f.v_W))


def test_thrust_unit_mistakes(fl, tmp_path):
    cols = _csv_cols(fl)
    normalised = cols["thrust_n"] * HOVER / (S.MASS * S.G)
    f = resample(read_csv(_write_csv(tmp_path / "n.csv", {**cols, "thrust_n": normalised})))
    with pytest.raises(InputError, match="looks normalised"):
        estimate(f, S.MASS, np.diag(S.INERTIA))
    cols2 = {k: v for k, v in cols.items() if k != "thrust_n"}
    cols2["thrust_norm"] = cols["thrust_n"]
    f = resample(read_csv(_write_csv(tmp_path / "m.csv", cols2)))
    with pytest.raises(InputError, match="looks like newtons"):
        estimate(f, S.MASS, np.diag(S.INERTIA), hover_thrust=0.4)
    cols2["thrust_norm"] = normalised
    cols2["hover_thrust"] = np.full(len(normalised), HOVER)
    e = estimate(resample(read_csv(_write_csv(tmp_path / "ok.csv", cols2))), S.MASS, np.diag(S.INERTIA))
    np.testing.assert_allclose(e.thrust_N, resample(read_csv(tmp_path / "n.csv")).thrust * S.MASS * S.G / HOVER)


def test_a_learnt_hover_thrust_that_hides_a_force_is_warned_about(fl, tmp_path):
    """An autopilot's learnt hover thrust follows a steady vertical force (a payload picked up): taken per
    sample it hides that force. Here the log's hover thrust climbs 30 % in 4 s while the true one is HOVER:
    warned, naming the value before; with that value given the true vertical force comes back. A drift as
    slow as a battery's sag (6 % over the flight) is not warned about."""
    cols = {k: v for k, v in _csv_cols(fl).items() if k != "thrust_n"}
    cols["thrust_norm"] = _csv_cols(fl)["thrust_n"] * HOVER / (S.MASS * S.G)
    t = cols["t_s"]
    cols["hover_thrust"] = HOVER * (1.0 + 0.3 * np.clip((t - 4.0) / 4.0, 0.0, 1.0))
    f = resample(read_csv(_write_csv(tmp_path / "learn.csv", cols)))
    e = estimate(f, S.MASS, None)
    (warning,) = [w for w in e.warnings if "learnt by the autopilot" in w]
    assert f"--hover-thrust {HOVER:.4g}" in warning and "+30%" in warning
    late = e.t > 8.5  # the learnt value hides the truth: about 30 % of the weight less, upward
    assert np.median(e.f_W[late, 2]) == pytest.approx(S.F_BIAS[2] - 0.3 / 1.3 * S.MASS * S.G, abs=0.3)
    given = estimate(f, S.MASS, None, hover_thrust=HOVER)
    assert np.median(given.f_W[late, 2]) == pytest.approx(S.F_BIAS[2], abs=0.1)
    assert not any("learnt by the autopilot" in w for w in given.warnings)
    cols["hover_thrust"] = HOVER * (1.0 + 0.06 * t / t[-1])
    e = estimate(resample(read_csv(_write_csv(tmp_path / "sag.csv", cols))), S.MASS, None)
    assert not any("learnt by the autopilot" in w for w in e.warnings)


def test_empty_truncated_and_foreign_files(fl, tmp_path):
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(InputError, match="is empty"):
        read_csv(tmp_path / "empty.csv")
    (tmp_path / "head.csv").write_text("t_s,vx\n")
    with pytest.raises(InputError, match="no data rows"):
        read_csv(tmp_path / "head.csv")
    text = _write_csv(tmp_path / "full.csv", _csv_cols(fl)).read_text()
    (tmp_path / "cut.csv").write_text(text[: len(text) - 40])
    raw = read_csv(tmp_path / "cut.csv")
    assert any("truncated" in n for n in raw.notes)
    (tmp_path / "bad.csv").write_text(text.replace("\n", "\nx,", 1)[:5000])
    with pytest.raises(InputError, match="line 2 has"):
        read_csv(tmp_path / "bad.csv")
    good = _ulog(fl, tmp_path / "g.ulg", "new")
    (tmp_path / "cut.ulg").write_bytes(good.read_bytes()[:300])
    with pytest.raises(InputError):
        resample(read_ulog(tmp_path / "cut.ulg"))
    (tmp_path / "junk.ulg").write_bytes(b"not a ulog at all" * 10)
    with pytest.raises(InputError, match="not a readable ULog"):
        read_ulog(tmp_path / "junk.ulg")
    with pytest.raises(InputError, match="does not exist"):
        read_csv(tmp_path / "nope.csv")
    cols = _csv_cols(fl, quat="wxyz")
    cols["q0"] = cols["q0"] * 2
    with pytest.raises(InputError, match="not a unit quaternion"):
        read_csv(_write_csv(tmp_path / "q.csv", cols))


def test_a_damaged_ulog_is_read_or_refused_never_a_crash(tmp_path):
    """Bytes flipped anywhere in a real log (its definitions included): pyulog may read it, the reader
    then either recovers what it can or refuses it with an InputError; no KeyError from deep inside."""
    from vtol_impedance.logs.samples import path as sample_path

    data = bytearray(Path(sample_path("px4")).read_bytes())
    refused = 0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        bad = bytearray(data)
        at = rng.integers(16, len(bad), 200)
        bad_bytes = rng.integers(0, 256, 200).astype(np.uint8)
        for i, b in zip(at, bad_bytes, strict=True):
            bad[i] = b
        f = tmp_path / f"bad{seed}.ulg"
        f.write_bytes(bytes(bad))
        try:
            resample(read_ulog(f))
        except InputError:
            refused += 1
    assert refused >= 1  # the damage is real: some of these cannot be read


def test_a_truncated_ulog_keeps_what_was_written(fl, tmp_path):
    good = _ulog(fl, tmp_path / "g.ulg", "new")
    data = good.read_bytes()
    (tmp_path / "half.ulg").write_bytes(data[: len(data) // 2])
    f = resample(read_ulog(tmp_path / "half.ulg"))
    assert 2.0 < f.t[-1] - f.t[0] < 10.0


# ----------------------------------------------------------------------------- command line


def test_cli_estimate_writes_series_figures_report(fl, tmp_path, capsys):
    import pyarrow.parquet as pq

    from vtol_impedance.io import verify_run_folder

    log = _ulog(fl, tmp_path / "flight.ulg", "new")
    out = tmp_path / "est"
    rc = main(["estimate", str(log), "--mass", "1.2", "--inertia", "0.0135,0.0137,0.0247", "--zero-phase",
               "--quiet-segment", "4,5.9", "--out", str(out)])  # fmt: skip
    assert rc == 0
    verify_run_folder(out)
    for name in ("wrench.csv", "wrench.parquet", "estimate.json", "wrench.png", "inputs.png", "report.html"):
        assert (out / name).stat().st_size > 0
    table = pq.read_table(out / "wrench.parquet")
    head = (out / "wrench.csv").read_text().splitlines()[0].split(",")
    assert table.column_names == head and "fx_W_N_zp" in head and "taux_B_Nm" in head
    np.testing.assert_allclose(
        np.loadtxt(out / "wrench.csv", delimiter=",", skiprows=1)[:, head.index("fx_W_N")], table["fx_W_N"], rtol=1e-8
    )
    summary = json.loads((out / "estimate.json").read_text())
    np.testing.assert_allclose(summary["bias"]["f_W_N"], S.F_BIAS, atol=0.02)
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html and "src='wrench" not in html


@pytest.mark.parametrize(
    "args, message",
    [
        ([], "nominal mass"),
        (["--mass", "1.2", "--inertia", "1,2"], "--inertia must be 3 or 9"),
        (["--mass", "-1", "--inertia", "0.01,0.01,0.02"], "mass"),
        (["--vehicle", "pelican", "--rate", "0"], "resampling rate"),
        (["--vehicle", "pelican", "--wn", "400"], "estimator bandwidth too high"),
        (["--vehicle", "pelican", "--quiet-segment", "100,200"], "quiet segment"),
        (["--vehicle", "pelican", "--hover-segment", "a,b"], "--hover-segment must be"),
        (["--vehicle", "pelican", "--column", "vx"], "ROLE=NAME"),
        (["--vehicle", "pelican", "--column", "speed=vx"], "unknown column role"),
        (["--vehicle", "no-such-vehicle"], "no-such-vehicle"),
        (["--vehicle", "pelican", "--hover-thrust", "0.5"], "already in newtons"),
        (["--vehicle", "pelican", "--torque-scale", "1"], "already in N m"),
        (["--vehicle", "pelican", "--start", "50"], "window 50.0 to None"),
    ],
)
def test_cli_estimate_bad_input_exits_2(fl, tmp_path, capsys, args, message):
    log = _write_csv(tmp_path / "f.csv", _csv_cols(fl))
    rc = main(["estimate", str(log), "--out", str(tmp_path / "o"), *args])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_a_resampled_log_too_long_to_hold_is_refused():
    t = np.array([0.0, 1e6])  # two samples 11.6 days apart: 1e9 grid points at 1 kHz
    two = lambda k: Signal("s", "s", t, np.zeros((2, k)))  # noqa: E731
    raw = RawLog(two(3), two(3), two(3), Signal("thrust", "u", t, np.full((2, 1), 12.0), hold=True), None)
    with pytest.raises(InputError, match="samples, above 5000000"):
        resample(raw, 1000.0, max_gap_s=2e6)


@pytest.mark.parametrize(
    "flags, message",
    [
        (["--start", "nan"], "start"),
        (["--end", "inf"], "end"),
        (["--start", "5", "--end", "2"], "must end after it starts"),
        (["--mass", "1e30"], "mass"),
        (["--mass", "0"], "mass"),
        (["--hover-thrust", "nan"], "hover thrust"),
        (["--hover-thrust", "1.5"], "hover thrust"),
    ],
)
def test_estimate_values_are_checked_before_the_log_is_read(flags, message, tmp_path, capsys):
    """Each of these was once ignored or used as given (a NaN window, a 1e30 kg vehicle)."""
    assert main(["estimate", "--example", "px4", *flags, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_an_infinite_cell_is_a_missing_sample_without_a_numpy_warning(tmp_path, capsys):
    """A cell of ``inf`` is handled as a gap, as NaN is; NumPy's "invalid value" warning must not leak."""
    import csv

    from vtol_impedance.logs.samples import path as sample_path

    rows = list(csv.reader(sample_path("csv").open()))
    rows[50][rows[0].index("vz")] = "inf"
    f = tmp_path / "inf.csv"
    with f.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    assert main(["estimate", str(f), "--mass", "1.2", "--out", str(tmp_path / "o")]) == 0
    assert "invalid value" not in capsys.readouterr().err


def test_sih_parameters_give_the_inertia_tensor_in_place():
    """PX4's simulation-in-hardware parameters name each inertia entry (SIH_IXY is I_xy, ...): every
    product lands in its two symmetric places, and a vehicle without them has no inertia."""
    from vtol_impedance.logs.ulog import vehicle_from_params

    params = {"SIH_MASS": 1.5, "SIH_IXX": 0.025, "SIH_IYY": 0.026, "SIH_IZZ": 0.03, "SIH_IXY": 0.001,
              "SIH_IXZ": 0.002, "SIH_IYZ": 0.003}  # fmt: skip
    mass, inertia = vehicle_from_params(params)
    assert mass == 1.5
    for (i, j), name in {(0, 0): "XX", (1, 1): "YY", (2, 2): "ZZ", (0, 1): "XY", (0, 2): "XZ", (1, 2): "YZ"}.items():
        assert inertia[i, j] == inertia[j, i] == params[f"SIH_I{name}"]
    assert vehicle_from_params({"SIH_MASS": 1.5, "SIH_IXX": 0.025}) == (1.5, None)
    assert vehicle_from_params({"SIH_MASS": 0.0}) == (None, None)


def test_px4_torque_normalisation_of_a_quad_longer_than_wide():
    """PX4's allocator scales the roll and pitch columns of its mixer by sqrt(sum of squares / (nonzero / 2))
    and uses the larger for both. Rotors at x = +-0.25 m, y = +-0.10 m: the roll column of the pseudo-
    inverse is +-1/(4 * 0.10), so its scale is 1/(2 sqrt(2) 0.10), the larger one: one unit of roll or pitch
    is 2 sqrt(2) 0.10 N m per newton of full-command rotor thrust (a square quad's both scales agree)."""
    from vtol_impedance.logs.ulog import torque_per_unit

    params = {"CA_ROTOR_COUNT": 4}
    for i, ((x, y), km) in enumerate(zip([(0.25, 0.10), (-0.25, -0.10), (0.25, -0.10), (-0.25, 0.10)],
                                         [0.05, 0.05, -0.05, -0.05], strict=True)):  # fmt: skip
        params.update({f"CA_ROTOR{i}_PX": x, f"CA_ROTOR{i}_PY": y, f"CA_ROTOR{i}_KM": km})
    k, n = torque_per_unit(params)
    assert n == 4
    np.testing.assert_allclose(k[:2], 2 * np.sqrt(2) * 0.10, rtol=1e-9)
