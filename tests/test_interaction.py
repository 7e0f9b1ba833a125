"""Interaction: the programmable impedance (comply), rejection (PD+C) against PD under a push, bumpless
behaviour switches, wall contact, gusts and Dryden turbulence, and the bad inputs of each."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as sg

from vtol_impedance import Controller
from vtol_impedance.cli import main
from vtol_impedance.control import ControllerParams, Impedance, Measurement, Reference
from vtol_impedance.control.reference import Hold, Trajectory
from vtol_impedance.errors import InputError, ScenarioError
from vtol_impedance.scenarios import get, set_value, simulate
from vtol_impedance.scenarios.spec import resolved_control
from vtol_impedance.sim.disturbances import Gust, Wall, dryden_filters, dryden_series

PUSH_T0, PUSH_LEN, PUSH_F = 10.0, 2.5, 3.0


def _push(t):
    return np.where((t >= PUSH_T0) & (t <= PUSH_T0 + PUSH_LEN), PUSH_F * np.sin(np.pi * (t - PUSH_T0) / PUSH_LEN), 0.0)


#: Every conclusion is checked on this package's plant (compiled) and on MuJoCo's physics.
PLANTS = ["compiled", "mujoco"]


@pytest.fixture(scope="module", params=PLANTS)
def push_run(request):
    return simulate(get("operator-push"), ["pd", "pdc", "comply"], backend=request.param)


def _fit_impedance(r, label: str) -> np.ndarray:
    """Least squares ``f = M e'' + D e' + K e`` along x, from the true motion and the true force the
    nominal model misses (the push, the drag, the payload's share)."""
    b = r.labels.index(label)
    t = r.t
    sel = (t > PUSH_T0 - 0.5) & (t < t[-1] - 0.5)
    e = r["p_W"][b, :, 0] - r["p_ref_W"][b, :, 0]
    ed = r["v_W"][b, :, 0] - r["v_ref_W"][b, :, 0]
    edd = np.gradient(ed, t)
    A = np.stack([edd, ed, e], -1)[sel]
    return np.linalg.lstsq(A, r["f_lumped_W"][b, sel, 0], rcond=None)[0]


def test_comply_shows_the_set_impedance(push_run):
    spec = get("operator-push").interaction
    M, D, K = _fit_impedance(push_run, "comply")
    np.testing.assert_allclose([M, D, K], [spec.M, spec.D, spec.K], rtol=0.10)


def test_comply_yields_and_comes_back(push_run):
    b = push_run.labels.index("comply")
    t, x = push_run.t, push_run["p_W"][b, :, 0]
    assert x[(t > PUSH_T0) & (t < PUSH_T0 + 4)].max() > 0.3  # yields: 3 N on 5 N/m
    assert abs(x[t > t[-1] - 1].mean()) < 0.05  # and returns once the hand lets go


def test_reject_beats_pd_by_what_the_estimator_bandwidth_predicts(push_run):
    """PD: x = L f with L = 1/(m s^2 + Dp s + Kp); PD+C leaves the part the compensation has not caught up
    with: x = L (1 - G e^{-s tau}) f, with G of eq. (10) at the bandwidth flown and tau the time the
    compensating force needs to reach the vehicle: the velocity's latency plus the attitude filter's delay
    2 zeta / wn (the force follows the attitude). The ratio of the peaks, from scipy.signal.lsim."""
    t = np.arange(0, 20, 0.001)
    m, Kp, Dp = 1.2 + 0.110, 16.0, 12.0
    spec = get("operator-push")
    c = resolved_control(spec)
    wn = float(c.estimator_wn)
    tau = spec.sensors.mocap_delay + 2.0 / c.attitude_filter_wn
    _, x_pd, _ = sg.lsim(sg.lti([1.0], [m, Dp, Kp]), _push(t), t)
    _, g, _ = sg.lsim(sg.lti([wn * wn], [1.0, 2.0 * wn, wn * wn]), _push(t), t)
    k = int(round(tau / 0.001))
    _, x_pdc, _ = sg.lsim(sg.lti([1.0], [m, Dp, Kp]), _push(t) - np.concatenate([np.zeros(k), g[: len(g) - k]]), t)
    predicted = np.abs(x_pdc).max() / np.abs(x_pd).max()

    def peak(label):
        b = push_run.labels.index(label)
        tt, x = push_run.t, push_run["p_W"][b, :, 0]
        base = x[(tt > PUSH_T0 - 2) & (tt < PUSH_T0)].mean()
        return np.abs(x[(tt > PUSH_T0) & (tt < PUSH_T0 + 5)] - base).max()

    measured = peak("pdc") / peak("pd")
    assert peak("pd") == pytest.approx(np.abs(x_pd).max(), rel=0.25)
    assert measured == pytest.approx(predicted, rel=0.2)
    assert measured < 0.3


def test_switching_behaviour_has_no_jump_in_the_command():
    """Hold the vehicle 0.3 m off its reference with a known estimate and switch x from comply to reject:
    abruptly the commanded acceleration jumps by the difference of the two laws (computed by hand); ramped
    over 0.5 s no step exceeds the ramp's steepest slope times that difference."""
    params = ControllerParams.paper("comply", impedance=Impedance(M=2.0, D=6.0, K=5.0))
    Ts, m = params.Ts, params.vehicle.mass
    e = 0.3
    lead = 2.0 * 1.0 / params.attitude_filter_wn  # the comply law leads by the attitude filter's delay
    comply_acc = -5.0 * e / 2.0 + lead * 6.0 * 5.0 * e / 2.0**2  # -(K_d e)/M_d + lead D_d K_d e / M_d^2
    reject_acc = -16.0 * e / m  # -(Kp e)/m; level and still, the estimate along x stays zero
    for blend, bound in ((0.0, None), (0.5, 1.875 * Ts / 0.5)):
        traj = Trajectory((Hold((0.0, 0.0, -1.0), 10.0),), comply0=(1.0, 1.0, 1.0), comply_switches=((1.0, 0, 0.0),),
                          blend_s=blend)  # fmt: skip
        ctrl = Controller(params, backend="numpy")
        acc = []
        for k in range(200):
            t = k * Ts
            ref = traj.sample(t)
            out = ctrl.step(Measurement(np.array([e, 0, -1.0]), np.zeros(3), np.zeros(3), np.zeros(3)), ref)
            acc.append(out.mu_bar[0])
        acc = np.array(acc)
        steps = np.abs(np.diff(acc[50:]))  # after the estimator settled on "no force"
        jump = reject_acc - comply_acc
        assert acc[95] == pytest.approx(comply_acc, abs=0.02) and acc[-1] == pytest.approx(reject_acc, abs=0.02)
        if bound is None:
            assert steps.max() == pytest.approx(abs(jump), rel=0.05)
        else:
            assert steps.max() <= bound * abs(jump) * 1.05


def test_comply_backends_agree():
    """Complying in x and y from the start (in the air), pushed at 1 s, x switched to reject at 3 s."""
    spec = set_value(get("operator-push"), "trajectory.start_on_ground", False)
    for key, value in (("duration", 4.5), ("interaction.comply", [1.0, 1.0, 0.0]), ("disturbances.0.t_on", 1.0),
                       ("interaction.switches", [[3.0, "x", "reject"]])):  # fmt: skip
        spec = set_value(spec, key, value)
    a = simulate(spec, ["comply"], backend="compiled")
    b = simulate(spec, ["comply"], backend="numpy")
    assert a["p_W"][0, :, 0].max() > 0.1  # it did yield
    np.testing.assert_allclose(a["p_W"], b["p_W"], atol=1e-8)
    np.testing.assert_allclose(a["f_hat_W"], b["f_hat_W"], atol=1e-7)


# ----------------------------------------------------------------------------- wall


@pytest.fixture(scope="module", params=PLANTS)
def wall_run(request):
    return simulate(get("wall-contact"), ["pdc", "comply"], backend=request.param)


def test_wall_holds_the_commanded_contact_force(wall_run):
    spec = get("wall-contact")
    wall = spec.disturbances[0]
    b = wall_run.labels.index("comply")
    t = wall_run.t
    x = wall_run["p_W"][b, :, 0]
    x_contact = wall["position_W"][0] - wall["radius"]
    x_d = spec.trajectory.move_offset[0]
    commanded = spec.interaction.K * (x_d - x_contact)
    fx = -wall_run["f_ext_W"][b, :, 0]  # the wall pushes back along -x
    last = t > t[-1] - 4
    assert fx[last].mean() == pytest.approx(commanded, rel=0.05)
    in_contact = x >= x_contact
    first = t[np.argmax(in_contact)]
    assert in_contact.any() and np.all(in_contact[t > first + 3.0])  # no bounce, no loss of contact
    # the estimate sees the contact force
    assert wall_run["f_hat_W"][b, last, 0].mean() == pytest.approx(-commanded, rel=0.05)
    # rejecting instead pushes the wall as hard as the rotors allow
    r = wall_run.labels.index("pdc")
    assert -wall_run["f_ext_W"][r, last, 0].mean() > 3 * commanded


def test_wall_force_law_by_hand():
    w = Wall(position_W=(1.0, 0, 0), normal_W=(-1.0, 0, 0), stiffness=1000.0, damping=50.0, friction=0.5, radius=0.1)
    R = np.eye(3)
    f, tau = w(0.0, np.array([0.92, 0.0, -1.0]), np.array([0.1, 0.2, 0.0]), R)
    fn = 1000.0 * 0.02 - 50.0 * (-0.1)  # penetration 2 cm, approaching at 0.1 m/s
    np.testing.assert_allclose(f, [-fn, -0.5 * fn, 0.0], atol=1e-9)  # friction against the 0.2 m/s slide
    np.testing.assert_allclose(tau, np.cross([0.1, 0, 0], f), atol=1e-9)  # acting at the bumper's front
    f, _ = w(0.0, np.array([0.85, 0.0, -1.0]), np.array([0.1, 0.2, 0.0]), R)
    np.testing.assert_allclose(f, 0.0)
    f, _ = w(0.0, np.array([0.905, 0.0, -1.0]), np.array([-2.0, 0.0, 0.0]), R)
    np.testing.assert_allclose(f, 0.0)  # leaving fast: a wall never pulls


# ----------------------------------------------------------------------------- gusts


def test_dryden_series_have_the_model_variance_and_correlation():
    rng = np.random.default_rng(4)
    for order in (1, 2):
        x = dryden_series(rng, 300_000, 0.01, 1.3, 8.0, 2.0, order)
        assert x.std() == pytest.approx(1.3, rel=0.05)
    x = dryden_series(rng, 2_000_000, 0.05, 1.0, 8.0, 2.0, 1)  # 25,000 correlation times: +-0.01
    lag = 40  # 2 s: exp(-V tau / L)
    assert np.mean(x[:-lag] * x[lag:]) == pytest.approx(np.exp(-2.0 * 2.0 / 8.0), abs=0.04)
    (s_u, L_u, _), _, (s_w, L_w, _) = dryden_filters(0.5, 10 * 0.3048)
    assert L_w == pytest.approx(10 * 0.3048) and s_u / s_w == pytest.approx(1 / (0.177 + 0.00823) ** 0.4)


def test_one_minus_cosine_gust_by_hand():
    g = Gust(direction_W=(0.0, 1.0, 0.0), mean_speed=1.0, amplitude=4.0, start=2.0, length=2.0, drag=0.2)
    t = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    np.testing.assert_allclose(g.wind_W(t)[:, 1], [1.0, 1.0, 5.0, 1.0, 1.0], atol=1e-12)
    prepared = g.prepare(6.0, 0.001, np.random.default_rng(0))
    f, _ = prepared(3.0, np.zeros(3), np.zeros(3), np.eye(3))
    np.testing.assert_allclose(f, [0.0, 0.2 * 5.0, 0.0], atol=1e-9)


def test_gust_pushes_pd_more_than_pdc():
    r = simulate(get("gust"), ["pd", "pdc"])
    t = r.t
    w = (t > 12) & (t < 16)
    peak = {lab: np.abs(r["p_W"][i, w, 0] - r["p_ref_W"][i, w, 0]).max() for i, lab in enumerate(r.labels)}
    assert peak["pdc"] < 0.5 * peak["pd"]
    assert r["f_ext_W"][0, w, 0].max() == pytest.approx(0.18 * (1.0 + 5.0), rel=0.3)  # mean + gust, turbulence


# ----------------------------------------------------------------------------- bad input


def test_bad_interaction_inputs():
    with pytest.raises(InputError, match="impedance M must be > 0"):
        Impedance(M=0.0, D=1.0, K=1.0)
    with pytest.raises(InputError, match="impedance K"):
        Impedance(M=1.0, D=1.0, K=[1.0, -2.0, 1.0])
    with pytest.raises(ScenarioError, match="axis 'w' does not exist"):
        set_value(get("operator-push"), "interaction.switches", [[3.0, "w", "reject"]])
    with pytest.raises(ScenarioError, match="behaviour 'soft'"):
        set_value(get("operator-push"), "interaction.switches", [[3.0, "x", "soft"]])
    with pytest.raises(ScenarioError, match="interaction.D"):
        set_value(get("operator-push"), "interaction.D", 0.0)
    spec = set_value(get("wall-contact"), "disturbances.0.position_W", [0.05, 0.0, 0.0])
    with pytest.raises(InputError, match="inside the vehicle's start"):
        simulate(spec, ["comply"])
    with pytest.raises(InputError, match="comply"):
        Controller(ControllerParams.paper("comply")).step(
            Measurement(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)), Reference(np.zeros(3), comply=1.5)
        )
    with pytest.raises(InputError, match="impedance M_o must be > 0"):
        Impedance(M=1.0, D=1.0, K=1.0, M_o=0.0)
    with pytest.raises(ScenarioError, match="interaction.K_o"):
        set_value(get("twist"), "interaction.K_o", -1.0)
    with pytest.raises(ScenarioError, match="axis 'spin' does not exist.*roll, pitch, yaw"):
        set_value(get("twist"), "interaction.switches", [[3.0, "spin", "reject"]])
    with pytest.raises(InputError, match=r"Reference.comply has shape \(4,\)"):
        Controller(ControllerParams.paper("comply")).step(
            Measurement(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)), Reference(np.zeros(3), comply=np.ones(4))
        )
    with pytest.raises(InputError, match="comply0 must be 3"):
        Trajectory((Hold((0.0, 0.0, -1.0), 1.0),), comply0=(1.0, 0.0))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--set", "interaction.M=-2"], "interaction.M"),
        (["--set", 'interaction.switches=[[5.0, "q", "comply"]]'], "axis 'q'"),
        (["--set", "disturbances.0.position_W=[0.0, 0.0, 0.0]"], "inside the vehicle's start"),
    ],
)
def test_cli_interaction_bad_input(args, message, tmp_path, capsys):
    rc = main(["run", "wall-contact", "--controller", "comply", "--out", str(tmp_path / "o"), "--no-plots", *args])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and "Traceback" not in err


# ----------------------------------------------------------------------------- attitude impedance


def _fit_yaw(r, label: str, t0: float = 3.5) -> np.ndarray:
    """Least squares ``tau = M_o e'' + D_o e' + K_o e`` on yaw, from the true motion and the true moment
    the nominal model misses (Euler coordinates); level flight, so the yaw rate is ``omega_z``."""
    b = r.labels.index(label)
    t = r.t
    sel = (t > t0) & (t < t[-1] - 0.5)
    e = r["eta"][b, :, 2] - r["psi_ref"][b]
    ed = r["omega_B"][b, :, 2]
    A = np.stack([np.gradient(ed, t), ed, e], -1)[sel]
    return np.linalg.lstsq(A, r["tau_lumped_eta"][b, sel, 2], rcond=None)[0]


def _twist(M_o: float) -> object:
    """The twist scenario with a yaw impedance of M_o at 2 rad/s, zeta = 1, and a moment scaled to it."""
    spec = get("twist")
    for key, value in (("M_o", M_o), ("D_o", 4 * M_o), ("K_o", 4 * M_o)):
        spec = set_value(spec, f"interaction.{key}", value)
    return set_value(spec, "disturbances.0.torque_B", [0.0, 0.0, 3.0 * M_o])


def test_comply_attitude_shows_the_set_impedance():
    """An apparent yaw inertia near the vehicle's own (0.005 vs 0.0047 kg m^2): all three within 10 %."""
    r = simulate(_twist(0.005), ["comply"])
    np.testing.assert_allclose(_fit_yaw(r, "comply"), [0.005, 0.02, 0.02], rtol=0.10)


@pytest.fixture(scope="module")
def twist_run():
    return simulate(get("twist"), ["pd", "pdc", "comply"])


def test_twist_reject_holds_the_heading_and_comply_yields_with_a_heavier_inertia(twist_run):
    """Twice the vehicle's yaw inertia needs the estimated moment fed forward with weight M_o / I - 1 = 1.1,
    which amplifies the estimate's residual lag: the inertia comes out 25 % low (README), still well above the
    vehicle's own; damping and stiffness within 15 %."""
    M, D, K = _fit_yaw(twist_run, "comply")
    assert M == pytest.approx(0.01, rel=0.30) and M > 1.4 * 0.0047
    assert D == pytest.approx(0.04, rel=0.15) and K == pytest.approx(0.04, rel=0.15)
    peak = {}
    for label in twist_run.labels:
        b = twist_run.labels.index(label)
        e = twist_run["eta"][b, :, 2] - twist_run["psi_ref"][b]
        peak[label] = np.abs(e).max()
        assert np.abs(e[twist_run.t > twist_run.t[-1] - 1]).max() < 0.01  # all come back
    assert peak["comply"] > 0.2  # 0.03 N m on 0.04 N m/rad, for 1 s
    assert peak["pdc"] < 0.15 * peak["comply"] and peak["pdc"] < peak["pd"]


def test_attitude_comply_backends_agree():
    spec = set_value(get("twist"), "duration", 3.5)
    spec = set_value(spec, "disturbances.0.t_on", 0.5)
    spec = set_value(spec, "interaction.switches", [[2.5, "yaw", "reject"]])
    a = simulate(spec, ["comply"], backend="compiled")
    b = simulate(spec, ["comply"], backend="numpy")
    assert np.abs(a["eta"][0, :, 2]).max() > 0.1
    np.testing.assert_allclose(a["eta"], b["eta"], atol=1e-9)
    np.testing.assert_allclose(a["tau_B"], b["tau_B"], atol=1e-9)


def test_animation_is_written_and_embedded(tmp_path):
    from PIL import Image

    out = tmp_path / "o"
    rc = main(["compare", "wall-contact", "--controllers", "pdc,comply", "--duration", "4", "--animate", "--out",
               str(out), "--quiet"])  # fmt: skip
    assert rc == 0
    gif = out / "wall-contact-v2.gif"
    with Image.open(gif) as im:
        assert im.n_frames > 20 and im.format == "GIF"
    assert "data:image/gif;base64," in (out / "report.html").read_text()


# ----------------------------------------------------------------------------- pendulum


def test_pendulum_in_free_fall_conserves_what_it_must():
    """No rotors, no ground, no drag: the centre of mass of vehicle and bob falls with g exactly and the
    bob circles the joint at constant speed (the link's force is internal and does no work there)."""
    from vtol_impedance.model import load_preset
    from vtol_impedance.sim.plant import P_COM, PEND_R, PEND_V, PlantParams, compile_plants, initial_state, rk4_step

    P = compile_plants(PlantParams(load_preset(), pendulum_mass=0.1, pendulum_length=0.5, ground=False,
                                   rotor_tau_up=0.0, rotor_tau_down=0.0))  # fmt: skip
    x = initial_state(P, np.array([0.0, 0.0, -2.0]), hover_rotors=False)
    v0 = np.array([0.8, 0.3, 0.0])
    x[PEND_V] = v0
    m, ml = float(P.mass), float(P.pend_m)
    com0 = x[P_COM] + ml * x[PEND_R] / (m + ml)
    dt, n = 0.001, 1000
    for k in range(n):
        x = rk4_step(P, x, np.zeros(4), k * dt, dt)
        assert np.linalg.norm(x[PEND_V]) == pytest.approx(np.linalg.norm(v0), rel=1e-9)
    T = n * dt
    com = x[P_COM] + ml * x[PEND_R] / (m + ml)
    np.testing.assert_allclose(com, com0 + ml * v0 / (m + ml) * T + 0.5 * np.array([0, 0, 9.81]) * T * T, atol=1e-9)
    assert np.linalg.norm(x[PEND_R]) == pytest.approx(0.5, rel=1e-12)


@pytest.fixture(scope="module")
def pendulum_run():
    # in free flight MuJoCo's pendulum flies the same to 1e-6 m (test_mujoco.py): once is enough here
    return simulate(get("pendulum"), ["pd", "pdc"])


def test_pendulum_pd_sags_by_the_hung_weight_and_pdc_holds(pendulum_run):
    r = pendulum_run
    t = r.t
    hover = (t > 4) & (t < 8)
    pd, pdc = r.labels.index("pd"), r.labels.index("pdc")
    sag = (r["p_W"][pd, hover, 2] - r["p_ref_W"][pd, hover, 2]).mean()
    assert sag == pytest.approx((0.110 + 0.1) * 9.81 / 16.0, rel=0.05)  # payload and bob on Kp = 16
    err = {b: np.linalg.norm(r.e_p[b, t > 3], axis=-1) for b in (pd, pdc)}
    assert np.sqrt(np.mean(err[pdc] ** 2)) < 0.2 * np.sqrt(np.mean(err[pd] ** 2))


def test_pendulum_estimate_follows_the_link_force_within_the_estimator_lag(pendulum_run):
    """Horizontally the force the plant applies is the link's pull (and rotor drag); the estimate is G(s) of
    it, so it can be off by at most the lag 2 zeta / wn times the largest rate of change of that force, plus
    the estimation floor of the hover cases (0.05 N)."""
    r = pendulum_run
    t = r.t
    b = r.labels.index("pdc")
    w = t > 3
    f = r["f_ext_W"][b, :, :2]
    spec = get("pendulum")  # the estimate is late by G's delay and the velocity's latency
    lag = 2 * 1.0 / float(resolved_control(spec).estimator_wn) + spec.sensors.mocap_delay
    bound = lag * np.abs(np.gradient(f, t, axis=0))[w].max(0) + 0.05
    assert np.all(np.abs(r["f_hat_W"][b, :, :2] - f)[w].max(0) < bound)
    assert np.abs(f[w, 0]).max() > 0.1  # the bob did swing and pull


def test_pendulum_backends_agree():
    spec = set_value(set_value(get("pendulum"), "duration", 5.0), "trajectory.hover_duration", 1.0)
    a = simulate(spec, ["pdc"], backend="compiled")
    b = simulate(spec, ["pdc"], backend="numpy")
    np.testing.assert_allclose(a["p_W"], b["p_W"], atol=1e-8)
    np.testing.assert_allclose(a["f_ext_W"], b["f_ext_W"], atol=1e-7)


def test_pendulum_longer_than_the_altitude_is_refused(tmp_path, capsys):
    spec = set_value(get("pendulum"), "plant.pendulum_length", 2.0)
    with pytest.raises(InputError, match="longer than the flight's lowest altitude"):
        simulate(spec, ["pd"])
    rc = main(["run", "pendulum", "--set", "plant.pendulum_length=1.6", "--out", str(tmp_path / "o"), "--no-plots"])
    assert rc == 2 and "pendulum (1.6 m) is longer" in capsys.readouterr().err
    with pytest.raises(InputError, match=r"pendulum \(1.5 m\) is longer"):  # exactly the 1.5 m altitude: on the ground
        simulate(set_value(spec, "plant.pendulum_length", 1.5), ["pd"])


def test_gust_turbulence_correlates_over_the_standard_length_in_metres():
    """MIL-F-8785C low altitude, written here from the standard: at h = 10 ft the longitudinal scale is
    L_u = h / (0.177 + 0.000823 h)^1.2 = 75.6 ft = 23.05 m; the gust's series (through rotor drag) must
    decorrelate to 1/e after L_u / V (in metres and m/s), not after the same number in feet."""
    h_ft, V, drag = 10.0, 2.0, 0.18
    L_u = h_ft / (0.177 + 0.000823 * h_ft) ** 1.2 * 0.3048
    g = Gust(direction_W=(1.0, 0.0, 0.0), mean_speed=V, amplitude=0.0, start=0.0, length=1.0, sigma_w=0.5,
             altitude=h_ft * 0.3048, drag=drag)  # fmt: skip
    dt = 0.05
    p = g.prepare(40_000.0, dt, np.random.default_rng(7))
    u = p._series[:, 0] / drag - V  # the longitudinal turbulence
    u = u - u.mean()
    lag = int(round(L_u / V / dt))
    rho = np.mean(u[:-lag] * u[lag:]) / np.mean(u * u)
    assert rho == pytest.approx(np.exp(-1.0), abs=0.06)


def test_wall_contact_agrees_between_backends():
    """The wall's force law flown by both backends (pressed against it, complying): the same motion."""
    spec = set_value(get("wall-contact"), "trajectory.start_on_ground", False)
    # 4 s: the impact (~1.6 s) and 2 s of steady pressing (1.5 N from 3.5 s); the NumPy backend is the slow one
    for key, value in (("duration", 4.0), ("trajectory.hover_duration", 0.5), ("trajectory.move_duration", 2.0),
                       ("interaction.switches", []), ("interaction.comply", [1.0, 0.0, 0.0])):  # fmt: skip
        spec = set_value(spec, key, value)
    a = simulate(spec, ["comply"], backend="numpy")
    b = simulate(spec, ["comply"], backend="compiled")
    assert -a["f_ext_W"][0, :, 0].min() > 0.5 and -a["f_ext_W"][0, -50:, 0].max() > 0.5  # it touched and presses
    np.testing.assert_allclose(a["p_W"], b["p_W"], atol=1e-8)
    np.testing.assert_allclose(a["f_ext_W"], b["f_ext_W"], atol=1e-6)
