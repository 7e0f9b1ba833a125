"""Any multirotor: rotor geometry, effectiveness, the bounded prioritised allocator, and X / hex vehicles in flight."""

import numpy as np
import pytest
import scipy.optimize
from hypothesis import example, given
from hypothesis import strategies as st

from vtol_impedance.errors import InputError
from vtol_impedance.model import (
    THRUST_SHIFT_MAX,
    Rotor,
    VehicleParams,
    allocate,
    drag_factor_from_constants,
    f_max_from_motor,
    load_preset,
    mix,
    unmix,
)
from vtol_impedance.scenarios import PAPER_CASES, get, set_value, simulate

I_B = [3.4e-3, 3.4e-3, 4.7e-3]
LAYOUT_VEHICLES = {
    "plus": VehicleParams(1.2, I_B, arm_length=0.21, drag_factor=0.016, f_max=7.0, layout="plus"),
    "x": VehicleParams(1.2, I_B, arm_length=0.21, drag_factor=0.016, f_max=7.0, layout="x"),
    "hex": VehicleParams(1.5, [6e-3, 6e-3, 1e-2], arm_length=0.25, drag_factor=0.016, f_max=4.2, layout="hex"),
}


def moment_by_hand(pos, spins, c, f):
    """Thrust and moment about the origin of forces f along -z_B at pos, written from the definitions."""
    tau = np.zeros(3)
    for r, s, fi in zip(pos, spins, f, strict=True):
        tau += np.cross(r, [0.0, 0.0, -fi]) + [0.0, 0.0, s * c * fi]
    return f.sum(), tau


@pytest.mark.parametrize("name", sorted(LAYOUT_VEHICLES))
def test_effectiveness_is_the_sum_of_rotor_moments(name, rng):
    v = LAYOUT_VEHICLES[name]
    g = v.geometry
    for _ in range(5):
        f = rng.uniform(0, 5, g.n)
        u, tau = mix(f, g.E)
        u_ref, tau_ref = moment_by_hand(g.positions_B, g.spins, v.drag_factor, f)
        assert u == pytest.approx(u_ref)
        np.testing.assert_allclose(tau, tau_ref, atol=1e-12)


@pytest.mark.parametrize("name", sorted(LAYOUT_VEHICLES))
def test_pure_yaw_gives_no_roll_or_pitch(name):
    """The sign check DESIGN.md asks for: allocated rotor forces for a pure yaw command, moments by hand."""
    v = LAYOUT_VEHICLES[name]
    g = v.geometry
    hover = v.mass * 9.81
    for yaw in (0.05, -0.05):
        a = allocate(hover, np.array([0.0, 0.0, yaw]), g.E, g.E_pinv, g.f_min, g.f_max)
        u, tau = moment_by_hand(g.positions_B, g.spins, v.drag_factor, a.f)
        assert u == pytest.approx(hover)
        np.testing.assert_allclose(tau[:2], 0.0, atol=1e-12)
        assert tau[2] == pytest.approx(yaw)


def test_hex_layout_numbering():
    """Rotor 1 forward, then every 60 deg towards the right (+y in FRD), spins alternating from +."""
    g = LAYOUT_VEHICLES["hex"].geometry
    a = np.radians(60.0)
    want = 0.25 * np.array([[1, 0], [np.cos(a), np.sin(a)], [-np.cos(a), np.sin(a)], [-1, 0], [-np.cos(a), -np.sin(a)],
                            [np.cos(a), -np.sin(a)]])  # fmt: skip
    np.testing.assert_allclose(g.positions_B[:, :2], want, atol=1e-15)
    assert g.spins.tolist() == [1, -1, 1, -1, 1, -1]
    assert load_preset("hexarotor").geometry.spins.tolist() == [1, -1, 1, -1, 1, -1]


def test_plus_layout_is_eq4_numbering_and_x_layout_numbering():
    g = LAYOUT_VEHICLES["plus"].geometry
    np.testing.assert_allclose(g.positions_B[:, :2], [[-0.21, 0], [0, -0.21], [0.21, 0], [0, 0.21]], atol=1e-15)
    x = LAYOUT_VEHICLES["x"].geometry
    d = 0.21 / np.sqrt(2)
    # 1 front-right, 2 rear-left, 3 front-left, 4 rear-right; diagonal pairs spin alike
    np.testing.assert_allclose(x.positions_B[:, :2], [[d, d], [-d, -d], [d, -d], [-d, d]], atol=1e-15)
    assert x.spins.tolist() == [1, 1, -1, -1]


@st.composite
def requests(draw):
    name = draw(st.sampled_from(sorted(LAYOUT_VEHICLES)))
    v = LAYOUT_VEHICLES[name]
    u = draw(st.floats(0.0, 1.3 * v.geometry.f_max.sum()))
    tau = np.array([draw(st.floats(-2, 2)), draw(st.floats(-2, 2)), draw(st.floats(-0.3, 0.3))])
    shift = draw(st.sampled_from([0.0, 0.1, THRUST_SHIFT_MAX, 0.5]))
    return v, u, tau, shift


def compiled_allocate(v, u, tau, shift):
    """The compiled backend's allocator (``compiled.controller._allocate``) behind NumPy's signature."""
    from types import SimpleNamespace

    from vtol_impedance.compiled import controller as kernels
    from vtol_impedance.control import ControllerParams
    from vtol_impedance.control.impedance import compile_controllers

    p, _ = kernels.pack_controller(compile_controllers([ControllerParams.paper("pd", vehicle=v)]))
    p["thrust_shift_max"] = shift
    o = kernels.new_output(1)
    sat, rp, ys = kernels.allocate_one(p, float(u), float(tau[0]), float(tau[1]), float(tau[2]), o)
    f = o["f_rotor"][0, : v.n_rotors].copy()
    thrust, tau_B = mix(f, v.geometry.E)
    return SimpleNamespace(f=f, thrust=thrust, tau_B=tau_B, saturated=sat, rp_scale=rp, yaw_scale=ys)


ALLOCATORS = {
    "numpy": lambda v, u, tau, shift: allocate(
        u, tau, v.geometry.E, v.geometry.E_pinv, v.geometry.f_min, v.geometry.f_max, shift
    ),  # fmt: skip
    "compiled": compiled_allocate,
}


_YAW_FITS_RP = (  # yaw is what lets the full roll/pitch fit (found by hypothesis in CI)
    VehicleParams(1.2, [0.0034, 0.0034, 0.0047], arm_length=0.21, f_max=7.0, layout="x"),
    0.125,
    np.array([0.015625, 0.015625, -0.25]),
    0.0,
)


@pytest.mark.parametrize("backend", sorted(ALLOCATORS))
@given(req=requests())
@example(req=_YAW_FITS_RP)
def test_allocation_limits_bound_and_priorities(backend, req):
    v, u, tau, shift = req
    g = v.geometry
    a = ALLOCATORS[backend](v, u, tau, shift)
    assert np.all(a.f >= g.f_min - 1e-9) and np.all(a.f <= g.f_max + 1e-9)
    u_out, tau_out = mix(a.f, g.E)
    np.testing.assert_allclose([a.thrust, *a.tau_B], [u_out, *tau_out], atol=1e-9)
    # the thrust never moves by more than the bound beyond what the rotors cannot give at all
    u_feasible = np.clip(u, 0.0, g.f_max.sum())
    assert abs(a.thrust - u_feasible) <= shift * u_feasible + 1e-7
    # a feasible request is met exactly
    f_exact = unmix(u, tau, g.E_pinv)
    if np.all(f_exact >= g.f_min) and np.all(f_exact <= g.f_max):
        np.testing.assert_allclose(a.f, f_exact, atol=1e-9)
        assert not a.saturated
    # roll/pitch keep their direction and are only shortened; yaw is never reversed nor amplified
    assert 0.0 <= a.rp_scale <= 1.0 and 0.0 <= a.yaw_scale <= 1.0
    np.testing.assert_allclose(a.tau_B[:2], a.rp_scale * tau[:2], atol=1e-9)
    assert a.tau_B[2] * tau[2] >= -1e-12 and abs(a.tau_B[2]) <= abs(tau[2]) + 1e-12
    # the roll/pitch scale is the largest any bounded collective shift allows: an LP solved by scipy
    # over (k, delta) with every rotor in range, f = p_u (u_c + delta) + k p_rp, |delta| <= shift u_c
    pu, prp = g.E_pinv[:, 0], g.E_pinv[:, 1:3] @ tau[:2]
    u_c = np.clip(u, (g.f_min / pu).max(), (g.f_max / pu).min())
    lp = scipy.optimize.linprog(
        [-1.0, 0.0], A_ub=np.block([[prp[:, None], pu[:, None]], [-prp[:, None], -pu[:, None]]]),
        b_ub=np.concatenate([g.f_max - pu * u_c, pu * u_c - g.f_min]),
        bounds=[(0.0, 1.0), (-shift * u_c, shift * u_c)], method="highs",
    )  # fmt: skip
    assert lp.status == 0  # compared as torques: with no roll/pitch requested any scale delivers it
    # ... unless yaw is what makes the full roll/pitch fit at the requested collective (a yaw scale in
    # [0, 1] with every rotor in range: another LP), which the allocator uses first
    f_rp0 = unmix(u, np.array([tau[0], tau[1], 0.0]), g.E_pinv)
    y = g.E_pinv[:, 3] * tau[2]
    tol = 1e-12 * np.maximum(np.abs(g.f_max), 1.0)
    room = np.concatenate([g.f_max + tol - f_rp0, f_rp0 - g.f_min + tol])
    with_yaw = scipy.optimize.linprog([0.0], A_ub=np.concatenate([y, -y])[:, None], b_ub=room, bounds=[(0.0, 1.0)])
    best = 1.0 if with_yaw.status == 0 else lp.x[0]
    assert a.rp_scale * np.hypot(*tau[:2]) == pytest.approx(best * np.hypot(*tau[:2]), abs=1e-6)
    # priority: if roll/pitch fit with no yaw at the requested collective, they are delivered in full
    f_rp = unmix(u, np.array([tau[0], tau[1], 0.0]), g.E_pinv)
    if np.all(f_rp >= g.f_min) and np.all(f_rp <= g.f_max):
        assert a.rp_scale == pytest.approx(1.0)
        assert a.thrust == pytest.approx(u, abs=1e-9)


def test_a_light_vehicle_with_strong_rotors_does_not_multiply_thrust():
    """The issue's case: a 5.2 N request with a roll/pitch request that does not fit at that collective."""
    v = VehicleParams(0.5, [2e-3, 2e-3, 3e-3], arm_length=0.15, drag_factor=0.01, f_max=12.0)
    g = v.geometry
    a = allocate(5.2, np.array([1.5, -1.2, 0.0]), g.E, g.E_pinv, g.f_min, g.f_max)
    assert a.saturated and a.rp_scale < 1.0
    assert abs(a.thrust - 5.2) <= THRUST_SHIFT_MAX * 5.2 + 1e-9
    # the direction of the roll/pitch torque is kept
    np.testing.assert_allclose(a.tau_B[:2] / np.linalg.norm(a.tau_B[:2]), np.array([1.5, -1.2]) / np.hypot(1.5, 1.2))


def test_motor_constants_convert_to_limits_and_drag_factor():
    assert f_max_from_motor(1.0e-5, 650.0) == pytest.approx(1.0e-5 * 650.0**2)
    assert drag_factor_from_constants(1.6e-7, 1.0e-5) == pytest.approx(0.016)
    hexa = load_preset("hexarotor")
    assert hexa.n_rotors == 6
    np.testing.assert_allclose(hexa.geometry.f_max, 1.0e-5 * 650.0**2)
    assert hexa.drag_factor == pytest.approx(0.016)
    with pytest.raises(InputError, match="max_speed"):
        f_max_from_motor(1e-5, -3.0)


@pytest.mark.parametrize(
    "kw,msg",
    [
        ({"rotors": (Rotor((0.2, 0, 0), 1), Rotor((-0.2, 0, 0), -1), Rotor((0.3, 0, 0), 1))}, "4 to"),
        ({"rotors": tuple(Rotor((0.2 * i, 0, 0), (-1) ** i) for i in range(4))}, "rank"),
        ({"rotors": (Rotor((0.2, 0, 0), 1),) * 4, "f_max": 3.0}, "not both"),
        ({"layout": "octo"}, "layout"),
    ],
)
def test_bad_geometries_are_refused(kw, msg):
    with pytest.raises(InputError, match=msg):
        VehicleParams(1.0, I_B, **kw)
    with pytest.raises(InputError, match="spin"):
        Rotor((0.1, 0, 0), 2)


def test_plus_and_x_fly_alike_where_physics_says_they_must():
    """Pure climb and pure yaw need no roll/pitch moment: '+' and X give the same closed loop."""
    base = set_value(set_value(get("yaw-step"), "ideal", True), "trajectory.yaw_step_angle", 0.1)
    base = set_value(base, "duration", 4.0)
    runs = {}
    for vehicle in ("pelican", "pelican-x"):
        spec = set_value(base, "vehicle", vehicle)
        runs[vehicle] = simulate(spec, ["pdc"])
    a, b = runs["pelican"], runs["pelican-x"]
    assert a["f_rotor"].shape[-1] == b["f_rotor"].shape[-1] == 4
    np.testing.assert_allclose(a["eta"][0, :, 2], b["eta"][0, :, 2], atol=1e-9)
    assert np.ptp(a["eta"][0, :, 2]) > 0.09  # it did turn
    np.testing.assert_allclose(a["thrust"], b["thrust"], atol=1e-9)
    # and the rotor forces differ, as the layouts do
    assert np.abs(a["f_rotor_cmd"] - b["f_rotor_cmd"]).max() > 1e-3
    climb = set_value(set_value(get("case-a-payload"), "ideal", True), "duration", 8.0)
    ra = simulate(set_value(climb, "vehicle", "pelican"), ["pdc"])
    rb = simulate(set_value(climb, "vehicle", "pelican-x"), ["pdc"])
    np.testing.assert_allclose(ra["p_W"], rb["p_W"], atol=1e-9)


@pytest.mark.parametrize("vehicle", ["pelican-x", "hexarotor"])
def test_x_and_hexarotor_fly_the_case_studies(vehicle):
    for case in PAPER_CASES:
        spec = set_value(get(case), "vehicle", vehicle)
        r = simulate(spec, ["pd", "pdc"], log="metrics")
        assert r.failures == [None, None], (case, r.failures)
        pd, pdc = r.metrics
        assert pdc["rms_ep_cm"] < pd["rms_ep_cm"], (case, pd, pdc)
        assert pdc["rms_ep_cm"] < 3.0, (case, pdc)


def test_numpy_plant_with_hexarotor_matches_compiled():
    spec = set_value(set_value(get("case-c-circle"), "vehicle", "hexarotor"), "duration", 3.0)
    a = simulate(spec, ["pdc"], backend="numpy")
    b = simulate(spec, ["pdc"], backend="compiled")
    assert a["f_rotor"].shape[-1] == 6
    np.testing.assert_allclose(a["p_W"], b["p_W"], atol=1e-10)
    np.testing.assert_allclose(a["f_rotor"], b["f_rotor"], atol=1e-9)


def test_feasible_request_is_identical_to_unmix_even_at_high_thrust():
    v = LAYOUT_VEHICLES["hex"]
    g = v.geometry
    tau = np.array([0.1, -0.05, 0.01])
    u = 20.0
    f = unmix(u, tau, g.E_pinv)
    assert np.all(f <= g.f_max) and np.all(f >= 0)
    np.testing.assert_allclose(allocate(u, tau, g.E, g.E_pinv, g.f_min, g.f_max).f, f, atol=1e-12)
