"""MuJoCo as an independent plant: the generated model against MuJoCo's own composition, rotor and yaw
signs in MuJoCo's own z-up frame, state conversion against MuJoCo's kinematics, free-flight parity with
the built-in plant over 10 s, contact and link forces, the model file and the missing-extra message.

The interaction conclusions on MuJoCo (comply, reject, wall, pendulum) are in test_interaction.py,
whose scenario fixtures run on both plants."""

from __future__ import annotations

import sys

import mujoco
import numpy as np
import pytest

from vtol_impedance.cli import main
from vtol_impedance.conventions import T_FRD_FLU, T_NED_ENU
from vtol_impedance.errors import InputError
from vtol_impedance.model import load_preset
from vtol_impedance.scenarios import get, set_value, simulate
from vtol_impedance.scenarios.spec import build
from vtol_impedance.sim.disturbances import ConstantWrench, DisturbanceSet, Push, Wall
from vtol_impedance.sim.mjplant import MujocoPlant, mjcf
from vtol_impedance.sim.plant import (
    OMEGA,
    P_COM,
    PEND_R,
    PEND_V,
    ROTOR,
    PlantParams,
    compile_plants,
    initial_state,
    origin_kinematics,
)

G = 9.81


def _plant(**kw):
    base = dict(ground=False, rotor_tau_up=0.0, rotor_tau_down=0.0)
    base.update(kw)
    return PlantParams(load_preset(kw.pop("preset", "pelican")), **{k: v for k, v in base.items() if k != "preset"})


@pytest.mark.parametrize("preset", ["pelican", "pelican-x", "hexarotor"])
def test_mujoco_composes_the_same_mass_centre_and_inertia(preset):
    """MuJoCo adds the payload body to the vehicle itself; its mass matrix at rest holds the total mass and
    the inertia about the body origin, which must equal ours: I_com + m (|c|^2 I - c c^T)."""
    P = PlantParams(load_preset(preset), payload_mass=0.3, payload_offset_B=(0.05, -0.02, 0.08),
                    inertia_scale=(1.2, 0.9, 1.1), ground=False)  # fmt: skip
    m = mujoco.MjModel.from_xml_string(mjcf(P))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    PA = compile_plants(P)
    c = PA.c_B
    I_origin = PA.I_com + float(PA.mass) * (c @ c * np.eye(3) - np.outer(c, c))
    np.testing.assert_allclose(np.diag(M[:3, :3]), float(PA.mass), rtol=1e-12)
    np.testing.assert_allclose(M[3:6, 3:6], T_FRD_FLU @ I_origin @ T_FRD_FLU, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(d.subtree_com[1], T_FRD_FLU @ c, atol=1e-12)  # level at the origin
    assert m.nu == load_preset(preset).n_rotors + 3


def _rate_after(P, f, seconds=0.2):
    """Angular velocity (MuJoCo's world frame, z up) after holding rotor forces ``f`` from rest."""
    m = mujoco.MjModel.from_xml_string(mjcf(P))
    d = mujoco.MjData(m)
    d.qpos[2] = 5.0
    d.ctrl[: len(f)] = f
    for _ in range(int(seconds / m.opt.timestep)):
        mujoco.mj_step(m, d)
    R = d.xmat[1].reshape(3, 3)
    return R @ d.qvel[3:6], R


def test_yaw_and_tilt_signs_in_mujocos_own_frame():
    """Stated without this package's frames: a propeller turning counter-clockwise seen from above (spin
    +1) turns the body clockwise seen from above (negative rate about MuJoCo's up axis); more thrust on the
    front rotor raises the nose, on the right rotor raises the right side."""
    P = _plant()
    v = P.vehicle
    hover = v.mass * G / 4
    s = v.geometry.spins
    w, _ = _rate_after(P, hover + 0.3 * s)  # spin +1 rotors up, -1 down: no net thrust, no roll or pitch
    assert w[2] < -0.5 and abs(w[0]) < 1e-9 and abs(w[1]) < 1e-9
    w, _ = _rate_after(P, hover - 0.3 * s)
    assert w[2] > 0.5
    front = int(np.argmax(v.geometry.positions_B[:, 0]))  # FRD x forward
    right = int(np.argmax(v.geometry.positions_B[:, 1]))  # FRD y right
    for rotor, axis in ((front, 0), (right, 1)):
        f = np.full(4, hover)
        f[rotor] += 0.2
        _, R = _rate_after(P, f)
        nose_or_right = R @ (np.eye(3)[axis] * (1 if axis == 0 else -1))  # MuJoCo body x forward, -y right
        assert nose_or_right[2] > 0.01


def test_state_round_trip_and_mujocos_own_kinematics():
    P = _plant(payload_mass=0.2, payload_offset_B=(0.03, 0.01, 0.06), pendulum_mass=0.15, pendulum_length=0.7,
               rotor_tau_up=0.01, rotor_tau_down=0.02)  # fmt: skip
    PA = compile_plants([P])
    x = initial_state(PA, np.array([[1.0, -2.0, -3.0]]), np.array([0.2, -0.1, 2.5]))
    x[0, 3:6] = [0.4, -0.3, 0.2]
    x[0, OMEGA] = [0.5, -0.7, 1.1]
    x[0, ROTOR] = [3.0, 3.5, 2.5, 3.2]
    r = np.array([0.2, -0.3, 0.5])
    x[0, PEND_R] = 0.7 * r / np.linalg.norm(r)
    x[0, PEND_V] = np.cross([0.3, 0.8, -0.2], x[0, PEND_R])  # tangential
    mp = MujocoPlant([P], PA, DisturbanceSet([]), x, 0.001)
    np.testing.assert_allclose(mp._read(), x, atol=1e-12)
    d, m = mp.datas[0], mp.models[0]
    # the rollout's states are read by offset: qpos, qvel and act where MuJoCo puts them
    full = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, full, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    oq, ov, oa = mp._offsets
    parts = full[None, oq : oq + m.nq], full[None, ov : ov + m.nv], full[None, oa : oa + m.na]
    for part, own in zip(parts, (d.qpos, d.qvel, d.act), strict=True):
        np.testing.assert_array_equal(part[0], own)
    np.testing.assert_allclose(mp._convert(*parts, np.array([0])), x, atol=1e-12)
    bob = mp.bob[0]
    np.testing.assert_allclose(d.xipos[bob], T_NED_ENU @ (x[0, P_COM] + x[0, PEND_R]), atol=1e-12)
    vel = np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, bob, vel, 0)
    np.testing.assert_allclose(vel[3:6], T_NED_ENU @ (x[0, 3:6] + x[0, PEND_V]), atol=1e-12)
    p_o, v_o = origin_kinematics(PA, x)
    np.testing.assert_allclose(d.xpos[1], T_NED_ENU @ p_o[0], atol=1e-12)


@pytest.mark.parametrize("lag", [True, False])
def test_the_compiled_state_conversion_is_the_numpy_one(lag):
    """MuJoCo's states (ENU/FLU at the body origin) into the plant's, by the compiled kernel the compiled
    loop uses and by the written-out NumPy: both give back the states MuJoCo was set to (by ``set_state``,
    through MuJoCo's own quaternion functions), with and without rotor lag, an offset centre of mass, and
    MuJoCo's quaternion of either sign (the same rotation)."""
    rng = np.random.default_rng(3)
    taus = {"rotor_tau_up": 0.01, "rotor_tau_down": 0.02} if lag else {"rotor_tau_up": 0.0, "rotor_tau_down": 0.0}
    plants = [_plant(payload_mass=0.2, payload_offset_B=(0.03, 0.01, 0.06), **taus),
              _plant(payload_mass=0.1, payload_offset_B=(-0.02, 0.04, 0.05), **taus)]  # fmt: skip
    PA = compile_plants(plants)
    x = initial_state(PA, rng.normal(0, 2, (2, 3)), np.array([[0.3, -0.2, 2.9], [-0.4, 0.5, -3.0]]))
    x[:, 3:6] = rng.normal(0, 1, (2, 3))
    x[:, OMEGA] = rng.normal(0, 2, (2, 3))
    x[:, ROTOR] = rng.uniform(1.0, 5.0, (2, 4))
    x[:, PEND_R] = x[:, PEND_V] = 0.0  # no pendulum: read back at rest
    mp = MujocoPlant(plants, PA, DisturbanceSet([]), x, 0.001, compiled=True)
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    m0 = mp.models[0]
    rows = np.empty((2, mujoco.mj_stateSize(m0, full)))
    for row, m, d in zip(rows, mp.models, mp.datas, strict=True):
        mujoco.mj_getState(m, d, row, full)
    oq, ov, oa = mp._offsets
    rows[1, oq + 3 : oq + 7] *= -1.0  # the same attitude
    parts = rows[:, oq : oq + m0.nq], rows[:, ov : ov + m0.nv], rows[:, oa : oa + m0.na]
    veh = np.array([0, 1])
    compiled = mp._convert(*parts, veh)
    mp.compiled = False
    numpy = mp._convert(*parts, veh)
    np.testing.assert_allclose(compiled, x, atol=1e-12)
    np.testing.assert_allclose(compiled, numpy, rtol=1e-14, atol=1e-14)


def _replay(P_list, cmd, Ts, dist_items, x0):
    """The same rotor commands, held over each control period, on both plants (1 kHz RK4 both; ours is
    the compiled plant, tied to the NumPy one by test_compiled.py)."""
    from vtol_impedance.compiled.engine import advance
    from vtol_impedance.sim.disturbances import pack_disturbances
    from vtol_impedance.sim.plant import pack_plant, pack_state, unpack_state

    PA = compile_plants(P_list)
    dist = DisturbanceSet([d.prepare(cmd.shape[1] * Ts + 1, 0.001, np.random.default_rng(0)) for d in dist_items])
    mp = MujocoPlant(P_list, PA, dist, x0, 0.001)
    pp = pack_plant(PA)
    dists, series = pack_disturbances(dist.items)
    X = pack_state(x0)
    n_sub = int(round(Ts / 0.001))
    err, err_bob = [], []
    for k in range(cmd.shape[1]):
        f = np.ascontiguousarray(cmd[:, k])
        advance(pp, X, f, k * Ts, n_sub, 0.001, dists, series)
        x = unpack_state(X, PA.spins.shape[-1])
        mp.advance(k * Ts, f, n_sub, 0.001, lambda _: None)
        err.append(np.linalg.norm(origin_kinematics(PA, x)[0] - origin_kinematics(PA, mp.x)[0], axis=-1))
        err_bob.append(np.linalg.norm(x[:, PEND_R] - mp.x[:, PEND_R], axis=-1))
    return np.array(err), np.array(err_bob), x


def test_free_flight_parity_with_the_builtin_plant_over_10_s():
    """Commands recorded from a closed-loop flight (a 1 m move with a swinging pendulum), replayed open
    loop on both plants with everything the controller does not know: payload off the centre, inertia
    mismatch, rotor lag up and down, rotor drag, a push with a body moment. Position difference < 1 mm."""
    spec = set_value(get("pendulum"), "duration", 10.0)
    spec = set_value(spec, "trajectory.hover_duration", 2.0)
    rec = simulate(spec, ["pdc"], seed=3)
    cmd = rec["f_rotor_cmd"][0]
    Ts = rec.config["control_period"]
    common = dict(payload_mass=0.11, payload_offset_B=(0.02, -0.01, 0.03), inertia_scale=(1.1, 0.9, 1.2),
                  rotor_drag=0.3, rotor_tau_up=0.0125, rotor_tau_down=0.025)  # fmt: skip
    plants = [_plant(**common), _plant(**common, pendulum_mass=0.1, pendulum_length=0.5)]
    PA = compile_plants(plants)
    x0 = initial_state(PA, np.array([[0.0, 0.0, -1.5]] * 2), np.array([0.0, 0.0, 0.3]))
    push = Push(force_W=(1.0, -0.5, 0.3), torque_B=(0.02, -0.01, 0.03), t_on=3.0, duration=1.0)
    err, err_bob, x = _replay(plants, np.stack([cmd, cmd]), Ts, [push], x0)
    assert err.max() < 1e-3, f"largest position difference {err.max() * 1e3:.3g} mm"
    assert err_bob[:, 1].max() < 2e-3
    assert np.linalg.norm(x[1, PEND_V]) > 0.05  # the bob did swing
    travelled = np.linalg.norm(origin_kinematics(PA, x)[0] - origin_kinematics(PA, x0)[0], axis=-1)
    assert np.all(travelled > 0.5)  # and the flight went somewhere


def test_mujoco_contact_and_link_forces_are_what_statics_says():
    """At rest on the ground with the rotors off, MuJoCo's contact forces carry the whole weight; hovering
    with the pendulum at rest below, the link pulls down with the bob's weight."""
    P = PlantParams(load_preset(), payload_mass=0.1, payload_offset_B=(0.0, 0.0, 0.02), ground=True,
                    rotor_tau_up=0.0, rotor_tau_down=0.0)  # fmt: skip
    PA = compile_plants([P])
    x0 = initial_state(PA, np.zeros((1, 3)), hover_rotors=False)
    mp = MujocoPlant([P], PA, DisturbanceSet([]), x0, 0.001)
    for k in range(3000):  # settle on the ground
        mp.advance(k * 0.001, np.zeros((1, 4)), 1, 0.001, lambda _: None)
    _, _, f_W, _ = mp.truth(3.0, np.zeros((1, 4)))
    np.testing.assert_allclose(f_W[0], [0.0, 0.0, -PA.mass[0] * G], atol=1e-3 * PA.mass[0] * G)

    P = _plant(pendulum_mass=0.2, pendulum_length=0.5)
    PA = compile_plants([P])
    x0 = initial_state(PA, np.array([[0.0, 0.0, -2.0]]))
    mp = MujocoPlant([P], PA, DisturbanceSet([]), x0, 0.001)
    _, _, f_W, _ = mp.truth(0.0, x0[:, ROTOR])
    np.testing.assert_allclose(f_W[0], [0.0, 0.0, 0.2 * G], atol=1e-9)


def test_wall_force_comes_from_mujocos_contact():
    """A vehicle held against a wall by a constant push: MuJoCo's contact force balances it, along the
    wall's normal, and acts at the bumper's surface (its moment about the origin is r x f)."""
    wall = Wall(position_W=(0.5, 0.0, 0.0), normal_W=(-1.0, 0.0, 0.0), stiffness=2000.0, damping=60.0,
                friction=0.3, radius=0.1)  # fmt: skip
    push = ConstantWrench(force_W=(2.0, 0.0, 0.0))
    P = _plant()
    PA = compile_plants([P])
    x0 = initial_state(PA, np.array([[0.35, 0.0, -2.0]]), hover_rotors=False)
    dist = DisturbanceSet([wall.prepare(10, 0.001, np.random.default_rng(0)), push.prepare(10, 0.001, None)])
    mp = MujocoPlant([P], PA, dist, x0, 0.001)
    mp.models[0].opt.gravity[:] = 0.0  # no weight: only the push and the wall
    for k in range(3000):
        mp.advance(k * 0.001, np.zeros((1, 4)), 1, 0.001, lambda _: None)
    _, _, f_W, tau_B = mp.truth(3.0, np.zeros((1, 4)))
    np.testing.assert_allclose(f_W[0], [0.0, 0.0, 0.0], atol=2e-3)  # push + wall cancel
    p_o = origin_kinematics(PA, mp.x)[0][0]
    assert p_o[0] == pytest.approx(0.4, abs=2e-3)  # the bumper touches, with about 1 mm of give
    np.testing.assert_allclose(tau_B[0], 0.0, atol=1e-6)  # along the normal through the origin: no moment


def test_cli_runs_on_mujoco_and_writes_the_model(tmp_path, capsys):
    out = tmp_path / "w"
    code = main(["run", "wall-contact", "--plant", "mujoco", "--duration", "2", "--no-plots", "--quiet",
                 "--out", str(out)])  # fmt: skip
    assert code == 0
    xml = (out / "wall-contact-v2.mjcf.xml").read_text()
    m = mujoco.MjModel.from_xml_string(xml)
    assert m.ngeom >= 4 and "wall0" in xml and "bumper0" in xml
    assert '"backend": "mujoco"' in (out / "wall-contact-v2.config.json").read_text()


def test_cli_flies_the_numpy_controller_on_mujoco_when_asked(tmp_path):
    out = tmp_path / "n"
    code = main(["run", "operator-push", "--plant", "mujoco", "--backend", "numpy", "--duration", "0.3",
                 "--no-plots", "--quiet", "--out", str(out)])  # fmt: skip
    assert code == 0
    assert '"backend": "mujoco-numpy"' in (out / "operator-push-v3.config.json").read_text()
    assert (out / "operator-push-v3.mjcf.xml").exists()


def test_missing_mujoco_is_a_clear_error(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # import fails as if not installed
    b = build(get("operator-push"))
    from vtol_impedance.scenarios.spec import controller_params
    from vtol_impedance.sim.loop import run_closed_loop

    with pytest.raises(InputError, match=r"pip install 'vtol-impedance\[mujoco\]'"):
        run_closed_loop(b.plant, [controller_params(get("operator-push"), "pdc")], b.trajectory, 1.0, backend="mujoco")
    assert main(["run", "operator-push", "--plant", "mujoco", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "vtol-impedance[mujoco]" in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_too_many_walls_for_mujocos_collision_masks():
    walls = [Wall(position_W=(1.0 + i, 0.0, 0.0)) for i in range(31)]
    with pytest.raises(InputError, match="at most 30 walls"):
        mjcf(_plant(), walls)


def test_closed_loop_on_mujoco_logs_the_same_truth_in_free_flight():
    """The pendulum scenario flown in closed loop on both plants: in free flight the physics is the same,
    so the logged motion, the link force (MuJoCo's constraint force against our formula) and the lumped
    wrench the estimator must find (from MuJoCo's accelerations) agree."""
    spec = set_value(get("pendulum"), "duration", 4.0)
    spec = set_value(spec, "trajectory.hover_duration", 1.0)
    a = simulate(spec, ["pdc"], backend="compiled")
    b = simulate(spec, ["pdc"], backend="mujoco")
    assert np.abs(a["f_ext_W"][0, :, 0]).max() > 0.05  # the bob swings during the move
    np.testing.assert_allclose(b["p_W"], a["p_W"], atol=1e-6)
    np.testing.assert_allclose(b["f_ext_W"], a["f_ext_W"], atol=1e-4)
    np.testing.assert_allclose(b["f_lumped_W"], a["f_lumped_W"], atol=1e-4)
    np.testing.assert_allclose(b["tau_lumped_eta"], a["tau_lumped_eta"], atol=1e-5)


def _rel(a, b):
    """Largest difference relative to the signal's size (at least 1e-3 of its unit: a signal that is
    rounding noise about zero, as a nominal vehicle's lumped wrench, has no relative precision)."""
    assert np.array_equal(np.isnan(a), np.isnan(b))
    scale = max(float(np.nanmax(np.abs(a))), 1e-3)
    return float(np.nanmax(np.abs(a - b))) / scale


@pytest.mark.parametrize("name", ["operator-push", "case-b-fan", "pendulum"])
def test_the_compiled_controller_on_mujoco_flies_as_the_numpy_one(name):
    """``backend="mujoco"`` (the compiled engine's tick between MuJoCo's periods) against
    ``"mujoco-numpy"`` (the NumPy controller, sensors and lumped wrench): the same plant, the same noise,
    so the same flight; with a push (forces known in advance: one rollout per period), a fan (a force of
    the state: step by step) and a swinging pendulum."""
    spec = set_value(get(name), "duration", 3.0)
    if name == "operator-push":
        spec = set_value(spec, "disturbances.0.t_on", 1.0)
    a = simulate(spec, ["pd", "pdc"], backend="mujoco-numpy")
    b = simulate(spec, ["pd", "pdc"], backend="mujoco")
    assert a.failures == b.failures == [None, None]
    for k in a.data:
        assert _rel(a[k], b[k]) <= 1e-9, k
    assert np.abs(b["f_ext_W"]).max() > 0.05  # something pushed


def test_a_vehicle_failing_on_mujoco_is_parked_the_same_way_by_both_controllers():
    from dataclasses import replace

    from vtol_impedance.control import ControllerParams
    from vtol_impedance.control.reference import Hold, Trajectory
    from vtol_impedance.sim import SensorParams
    from vtol_impedance.sim.loop import run_closed_loop

    veh = load_preset()
    good = _plant()
    bad = PlantParams(replace(veh, f_max=1e3), inertia_scale=(0.02, 0.02, 0.02), ground=False)
    traj = Trajectory((Hold((0, 0, -1.0), 2.0),))
    kw = dict(sensors=SensorParams(), seed=1, labels=["good", "bad"], log="decimate:2")
    runs = [run_closed_loop([good, bad], [ControllerParams.paper()] * 2, traj, 2.0, backend=b, **kw)
            for b in ("mujoco-numpy", "mujoco")]  # fmt: skip
    assert runs[0].failures == runs[1].failures
    assert runs[1].failures[0] is None and runs[1].failures[1] is not None
    for k in runs[0].data:
        assert _rel(runs[0][k][0], runs[1][k][0]) <= 1e-9, k  # the other vehicle flies on, untouched
