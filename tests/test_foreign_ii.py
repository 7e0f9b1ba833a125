"""What a second foreign simulator, flying the controller and the estimator through the public API only,
tripped over (twelfth stop): parameters that could be reassigned and were then ignored, copies that shared
the estimate or could not be made, a vehicle that cannot lift itself accepted in silence, a heading step
while holding a side force, an estimated moment no rotor layout can give, and two refusals that did not say
how to mend the input."""

from __future__ import annotations

import copy
import math
import pickle
import warnings

import numpy as np
import pytest

from vtol_impedance import Controller, ControllerWarning, Estimator
from vtol_impedance.control import ControllerParams, Measurement, Reference
from vtol_impedance.errors import InputError
from vtol_impedance.model import HoverWarning, VehicleParams
from vtol_impedance.model.mixer import moment_reach

HOVER = Measurement(np.array([0.1, 0.0, -1.0]), np.zeros(3), np.zeros(3), omega_B=np.zeros(3))
AWAY = Measurement(np.array([0.6, -0.3, -1.2]), np.array([0.2, 0.0, 0.1]), np.zeros(3), omega_B=np.zeros(3))
REF = Reference(np.array([0.0, 0.0, -1.0]))


def _quiet(fn, *a, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*a, **kw)


def test_parameters_cannot_be_reassigned_and_then_ignored():
    ctrl = Controller(ControllerParams.paper("pdc"))
    for name in ("params", "backend", "arrays"):
        with pytest.raises(AttributeError):
            setattr(ctrl, name, None)
    est = Estimator(1.0, [0.01, 0.01, 0.02], 0.01)
    for name in ("mass", "params", "backend", "design"):
        with pytest.raises(AttributeError):
            setattr(est, name, None)
    with pytest.raises(ValueError):  # the inertia the compiled step took at construction
        est.I_B[0, 0] = 5.0


@pytest.mark.parametrize("backend", ["compiled", "numpy"])
@pytest.mark.parametrize("how", ["copy", "deepcopy", "pickle"])
def test_a_copy_is_a_controller_of_its_own_with_what_the_original_learnt(backend, how):
    ctrl = Controller(ControllerParams.paper("pdc"), backend=backend)
    twin = Controller(ControllerParams.paper("pdc"), backend=backend)  # stepped alike: what the original must do
    for _ in range(40):
        _quiet(ctrl.step, AWAY, REF)
        _quiet(twin.step, AWAY, REF)
    dup = {"copy": copy.copy, "deepcopy": copy.deepcopy, "pickle": lambda c: pickle.loads(pickle.dumps(c))}[how](ctrl)
    assert np.linalg.norm(_quiet(dup.step, AWAY, REF).f_hat_W) > 0.0  # it kept the estimate: not a fresh one
    for _ in range(30):  # the copy flies elsewhere ...
        _quiet(dup.step, HOVER, Reference(np.array([2.0, 0.0, -3.0])))
    # ... and the original goes on as if it had not been copied
    np.testing.assert_array_equal(_quiet(ctrl.step, AWAY, REF).f_hat_W, _quiet(twin.step, AWAY, REF).f_hat_W)


@pytest.mark.parametrize("backend", ["compiled", "numpy"])
def test_an_estimator_copy_is_independent_too(backend):
    est = Estimator(1.0, [0.01, 0.01, 0.02], 0.01, backend=backend)
    z = np.zeros(3)
    for _ in range(50):
        est.step(z, z, 9.81 + 1.0, z, omega_B=z)
    dup = pickle.loads(pickle.dumps(est))
    for _ in range(50):
        dup.step(z, z, 9.81 - 3.0, z, omega_B=z)
    a = est.step(z, z, 9.81 + 1.0, z, omega_B=z).f_hat_W
    assert a[2] == pytest.approx(1.0, abs=0.05)  # 1 N more thrust than weight, held still: 1 N down
    assert dup.step(z, z, 9.81 - 3.0, z, omega_B=z).f_hat_W[2] < -1.0


def test_a_vehicle_whose_rotors_cannot_lift_it_is_warned_about_at_the_users_line():
    heavy = VehicleParams(20.0, [0.5, 0.5, 0.9], layout="hex", arm_length=0.5, f_max=7.0)  # 42 N for 196 N
    with pytest.warns(HoverWarning, match="cannot hover") as seen:
        ctrl = Controller(ControllerParams.paper("pd", vehicle=heavy))
    assert seen[0].filename == __file__
    with warnings.catch_warnings():
        warnings.simplefilter("error", HoverWarning)  # its copies do not say it again
        copy.deepcopy(ctrl)
    able = VehicleParams(20.0, [0.5, 0.5, 0.9], layout="hex", arm_length=0.5, f_max=60.0)  # 360 N
    with warnings.catch_warnings():
        warnings.simplefilter("error", HoverWarning)
        Controller(ControllerParams.paper("pd", vehicle=able))


def test_the_simulator_warns_of_it_too():
    from vtol_impedance.control.reference import Hold, Trajectory
    from vtol_impedance.sim import PlantParams, run_closed_loop

    heavy = VehicleParams(20.0, [0.5, 0.5, 0.9], layout="hex", arm_length=0.5, f_max=7.0)
    with pytest.warns(HoverWarning) as seen:
        r = run_closed_loop(PlantParams(heavy), [ControllerParams.paper("pd", vehicle=heavy)],
                            Trajectory([Hold(np.array([0.0, 0.0, -5.0]), 1.0)]), 1.0)  # fmt: skip
    assert seen[0].filename == __file__
    z = np.asarray(r["p_W"]).reshape(-1, 3)[:, 2]  # one vehicle
    assert z[-1] > -4.0 or r.failures[0] is not None  # and it falls, as the warning said


def test_a_heading_step_is_warned_about_and_a_wrapped_one_is_not():
    ctrl = Controller(ControllerParams.paper("pdc"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ControllerWarning)
        ctrl.step(HOVER, Reference(REF.p_W, psi=0.4))  # within the gap
        eta = np.array([0.0, 0.0, -3.1])  # measured just past -pi, asked just before +pi: 0.08 rad apart
        ctrl.step(Measurement(HOVER.p_W, HOVER.v_W, eta, omega_B=np.zeros(3)), Reference(REF.p_W, psi=3.1))
    with pytest.warns(ControllerWarning, match="yaw reference is 0.60 rad") as seen:
        ctrl.step(HOVER, Reference(REF.p_W, psi=-0.6), t=1.0)  # timed: the warning still names this line
    assert seen[0].filename == __file__


def test_a_batch_controller_is_a_snapshot_of_its_list():
    ps = [ControllerParams.paper("pdc"), ControllerParams.paper("pd")]
    ctrl = Controller(ps)
    ps.append(ControllerParams.paper("pid"))  # changed after construction: neither the controller nor a copy sees it
    meas = Measurement(np.tile(HOVER.p_W, (2, 1)), np.zeros((2, 3)), np.zeros((2, 3)), omega_B=np.zeros((2, 3)))
    for c in (ctrl, copy.deepcopy(ctrl)):
        assert len(c.params) == 2
        assert c.step(meas, REF).f_rotor.shape == (2, 4)


def test_the_rotors_moment_reach_by_hand():
    """A plus quadrotor, arm 0.21 m, rotors 0-7 N, drag factor 0.016 m: about x and y one rotor at 7 N on one arm
    against none on the other, 0.21 x 7 = 1.47 N m; about z the two rotors of one spin at 7 N, 2 x 7 x 0.016."""
    veh = VehicleParams(1.2, [0.01, 0.01, 0.02], layout="plus", arm_length=0.21, f_max=7.0, f_min=0.0,
                        drag_factor=0.016)  # fmt: skip
    g = veh.geometry
    np.testing.assert_allclose(moment_reach(g.E, g.f_min, g.f_max), [1.47, 1.47, 0.224], rtol=1e-12)


def test_a_knock_is_not_a_frame_mistake():
    """A yaw rate that jumps by 40 rad/s over three steps and then stays (a knock): the moment estimate peaks far
    beyond the rotors' reach for a moment and decays; held less than MOMENT_PERSIST_S, it is not warned of."""
    ctrl = Controller(ControllerParams.paper("pdc"))
    peak = 0.0
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        psi = 0.0
        for k in range(150):
            rate = min(k, 3) * 40.0 / 3
            psi = math.remainder(psi + 0.01 * rate, 2 * math.pi)
            out = ctrl.step(Measurement(HOVER.p_W, HOVER.v_W, np.array([0.0, 0.0, psi]), omega_B=np.array([0, 0, rate])),
                            Reference(REF.p_W, psi=psi))  # fmt: skip
            peak = max(peak, abs(out.tau_hat_B[2]))
    assert peak > 2 * 1.5 * 0.224  # the knock itself read far beyond the reach, for a moment
    assert not [w for w in seen if "moment" in str(w.message)]


def test_an_estimated_moment_beyond_the_rotors_reach_is_warned_about():
    """Yaw accelerating at 50 rad/s^2 with no yaw command: the estimator reads I_zz x 50 = 1.1 N m about z,
    five times what the Pelican's rotors can give (0.22 N m), for as long as it lasts; a still hover reads
    nothing."""
    params = ControllerParams.paper("pdc")
    quiet = Controller(params)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ControllerWarning)
        for _ in range(100):
            quiet.step(HOVER, REF)
    spun = Controller(params)
    with pytest.warns(ControllerWarning, match="moment about body z"):
        for k in range(100):
            w = np.array([0.0, 0.0, 0.5 * k])  # the yaw rate grows 0.5 rad/s every 10 ms
            eta = np.array([0.0, 0.0, math.remainder(0.0025 * k * k, 2 * math.pi)])
            _quiet_but(spun.step, "moment", Measurement(HOVER.p_W, HOVER.v_W, eta, omega_B=w), Reference(REF.p_W,
                       psi=float(eta[2])))  # fmt: skip


def _quiet_but(fn, keep, *a):
    """``fn(*a)`` with every warning silenced but those whose text holds ``keep``."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        out = fn(*a)
    for w in seen:
        if keep in str(w.message):
            warnings.warn(w.message, w.category, stacklevel=2)
    return out


def test_refusals_say_how_to_mend_the_input():
    ctrl = Controller(ControllerParams.paper("pdc"))
    with pytest.raises(InputError, match=r"wrap it into \[-pi, pi\)"):
        ctrl.step(HOVER, Reference(REF.p_W, psi=1005.0))
    ctrl.step(HOVER, REF, t=np.float32(1.7e6))
    with pytest.raises(InputError, match="float32"):
        ctrl.step(HOVER, REF, t=np.float32(1.7e6) + np.float32(0.01))  # rounds to the same time
