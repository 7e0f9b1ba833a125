"""Scenario registry, overrides and TOML files: valid input works, bad input gets a clear error."""

import numpy as np
import pytest

from vtol_impedance.errors import InputError, ScenarioError
from vtol_impedance.scenarios import (
    PAPER_CASES,
    Registry,
    ScenarioSpec,
    apply_overrides,
    build,
    get,
    load_toml,
    names,
    set_value,
)


def test_paper_cases_are_registered_with_versions():
    for n in PAPER_CASES:
        assert get(n).name == f"{n}-v1"
        assert get(f"{n}-v1") is get(n)
    assert set(f"{n}-v1" for n in PAPER_CASES) <= set(names(latest_only=False))


def test_latest_version_wins():
    reg = Registry()
    reg.register(ScenarioSpec(name="x-v1"))
    reg.register(ScenarioSpec(name="x-v2", description="new"))
    assert reg.get("x").description == "new"
    with pytest.raises(ScenarioError, match="version"):
        reg.register(ScenarioSpec(name="unversioned"))
    with pytest.raises(ScenarioError, match="already"):
        reg.register(ScenarioSpec(name="x-v1"))


def test_unknown_scenario_lists_valid_names():
    with pytest.raises(ScenarioError) as e:
        get("case-z")
    for n in PAPER_CASES:
        assert n in str(e.value)


def test_overrides_are_typed():
    s = apply_overrides(
        get("case-a-payload"),
        [
            "payload.mass=0.2",
            "plant.inertia_scale=[1, 1.2, 1]",
            "seed=3",
            "trajectory.land=true",
            "control.Kp=[10, 10, 20]",
        ],
    )
    assert s.payload.mass == 0.2 and isinstance(s.payload.mass, float)
    assert s.plant.inertia_scale == (1.0, 1.2, 1.0)
    assert s.seed == 3 and s.trajectory.land is True
    assert s.control.Kp == (10.0, 10.0, 20.0)
    b = build(s)
    assert b.plant.total_mass == pytest.approx(1.4)


@pytest.mark.parametrize(
    "assignment,match",
    [
        ("payload.mas=0.2", "mass"),  # the valid keys are listed
        ("nosuch=1", "trajectory"),
        ("payload.mass=abc", "number"),
        ("trajectory.land=1", "true/false"),
        ("plant.inertia_scale=[1, 2]", "3 values"),
        ("payload", "key=value"),
        ("payload=1", "section"),
        ("seed=1.5", "integer"),
        ("disturbances.0.mean_force=1", "0..-1|disturbances"),
    ],
)
def test_bad_overrides(assignment, match):
    with pytest.raises(ScenarioError, match=match):
        apply_overrides(get("case-a-payload"), [assignment])


def test_disturbance_overrides_and_validation():
    s = apply_overrides(get("case-b-fan"), ["disturbances.0.mean_force=1.0"])
    assert s.disturbances[0]["mean_force"] == 1.0
    with pytest.raises(InputError, match="valid keys"):
        apply_overrides(get("case-b-fan"), ["disturbances.0.speed=1.0"])
    for index in ("-1", "+0", "1", "0x0"):  # a negative index once added a second fan, changed
        with pytest.raises(ScenarioError, match="use an index 0..0"):
            apply_overrides(get("case-b-fan"), [f"disturbances.{index}.mean_force=2.0"])
    with pytest.raises(InputError, match="valid kinds"):
        ScenarioSpec(name="x-v1", disturbances=({"kind": "tornado"},))


@pytest.mark.parametrize(
    "bad",
    [
        "payload.mass=-0.1",
        "plant.rotor_tau_up=-1",
        "trajectory.kind='spiral'",
        "sensors.pos_noise=-1",
        "control.Kp=0",
    ],
)
def test_bad_values_fail_before_flying(bad):
    from vtol_impedance.scenarios import controller_params

    with pytest.raises(InputError):
        s = apply_overrides(get("case-a-payload"), [bad])
        build(s)
        controller_params(s, "pdc")


def test_toml_file(tmp_path):
    f = tmp_path / "windy.toml"
    f.write_text(
        'base = "case-a-payload"\nname = "windy-v1"\n[payload]\nmass = 0.05\n'
        '[[disturbances]]\nkind = "wind"\nvelocity_W = [2.0, 0.0, 0.0]\n'
    )
    s = load_toml(f)
    assert s.name == "windy-v1" and s.payload.mass == 0.05
    assert s.disturbances[0]["kind"] == "wind"
    b = build(s)
    f_w, _ = b.disturbances[0](0.0, np.zeros(3), np.zeros(3), np.eye(3))
    np.testing.assert_allclose(f_w, [0.36, 0, 0])

    bad = tmp_path / "bad.toml"
    bad.write_text('base = "case-a-payload"\n[payload]\nweight = 1\n')
    with pytest.raises(ScenarioError, match="weight"):
        load_toml(bad)
    broken = tmp_path / "broken.toml"
    broken.write_text("[payload\n")
    with pytest.raises(ScenarioError, match="cannot read"):
        load_toml(broken)


def test_trajectories_are_smooth_and_join():
    for n in PAPER_CASES:
        b = build(get(n))
        ts = np.arange(0, b.duration, 0.005)
        p = np.array([b.trajectory.sample(t).p_W for t in ts])
        v = np.array([b.trajectory.sample(t).v_W for t in ts])
        # velocity is the derivative of position (checks every segment and the joins)
        np.testing.assert_allclose(np.gradient(p, ts, axis=0)[1:-1], v[1:-1], atol=2e-3)
    c = build(get("case-c-circle"))
    t0, t1 = c.window
    mid = np.arange(t0 + 3, t1 - 3, 0.1)
    speed = [np.linalg.norm(c.trajectory.sample(t).v_W) for t in mid]
    np.testing.assert_allclose(speed, 0.5, rtol=1e-9)
    # two laps: the path length is twice the circumference (the speed is smooth and 0 at both ends of the
    # window, so a 10 ms sum is exact to ~1e-13; a 1 ms one was 10 times the work for no more accuracy)
    ts = np.arange(t0, t1, 0.01)
    length = np.sum([np.linalg.norm(c.trajectory.sample(t).v_W) for t in ts]) * 0.01
    assert length == pytest.approx(2 * 2 * np.pi * 1.0, rel=1e-6)


def test_numpy_values_are_taken_and_a_key_must_be_a_name():
    """A sweep or a user hands NumPy scalars and arrays: taken as the Python numbers they are."""
    s = get("case-a-payload")
    assert set_value(s, "payload.mass", np.float32(0.25)).payload.mass == pytest.approx(0.25)
    assert set_value(s, "seed", np.int64(3)).seed == 3 and type(set_value(s, "seed", np.int64(3)).seed) is int
    assert set_value(s, "plant.inertia_scale", np.array([1.0, 1.1, 1.2])).plant.inertia_scale == (1.0, 1.1, 1.2)
    assert set_value(s, "trajectory.land", np.bool_(True)).trajectory.land is True
    with pytest.raises(ScenarioError, match="integer"):
        set_value(s, "seed", np.float64(1.5))
    for key in (None, "", 3):
        with pytest.raises(ScenarioError, match="dotted name"):
            set_value(s, key, 1.0)


def test_one_component_of_a_vector_is_set_as_in_a_sweep():
    """``--set payload.offset_B[0]=0.02`` takes the keys a sweep axis takes (docs: the same keys)."""
    s = apply_overrides(get("case-a-payload"), ["payload.offset_B[0]=0.02", "control.Kp[2]=20"])
    assert s.payload.offset_B == (0.02, 0.0, 0.03)
    assert s.control.Kp == (16.0, 16.0, 20.0)
    for bad in ("payload.offset_B[3]=1", "payload.mass[0]=1", "trajectory.land[0]=1"):
        with pytest.raises(ScenarioError, match="not a vector"):
            apply_overrides(get("case-a-payload"), [bad])


def test_the_paper_cases_carry_the_documented_numbers():
    """The numbers of the paper (Sec. VI) and of the attachment, written here rather than read back from
    the registry: hover at 1 m, 0.110 kg payload, the fan 0.15 m from the vehicle pushing 0.7 N along +x
    with 20 % turbulence in 0.5-5 Hz, the circle 1 m at 0.5 m/s twice, 100 Hz with Kp 16, Dp 12, Ki 0.5;
    the gust scenario a 1 m/s breeze with a 5 m/s gust at 12 s over 2 s."""
    from vtol_impedance.scenarios import build

    a, b, c = (get(n) for n in ("case-a-payload", "case-b-fan", "case-c-circle"))
    for s in (a, b, c):
        assert s.payload.mass == 0.110 and s.trajectory.altitude == 1.0
        assert (s.control.rate, s.control.Kp, s.control.Dp, s.control.Ki) == (100.0, 16.0, 12.0, 0.5)
    (fan,) = b.disturbances
    start = build(b).start_W
    hover = np.array([0.0, 0.0, -1.0])
    assert np.linalg.norm(np.asarray(fan["position_W"]) - hover) == pytest.approx(0.15) and start[2] == 0.0
    assert tuple(fan["direction_W"]) == (1.0, 0.0, 0.0) and fan["mean_force"] == 0.7
    assert fan["turbulence"] == 0.2 and tuple(fan["turbulence_band"]) == (0.5, 5.0)
    t = c.trajectory
    assert (t.kind, t.circle_radius, t.circle_speed, t.circle_laps) == ("circle", 1.0, 0.5, 2.0)
    (gust,) = get("gust").disturbances
    assert (gust["mean_speed"], gust["amplitude"], gust["start"], gust["length"]) == (1.0, 5.0, 12.0, 2.0)


def test_scenario_controller_and_plant_values_reach_what_flies():
    """``control.zeta_o`` sets the attitude damping ``Do = 2 zeta_o wn_o I`` (eq. (14) with the nominal
    inertia), and ``plant.rotor_limits = false`` lifts the true rotors' limits (to 1e6 N) while the
    controller keeps its own."""
    from vtol_impedance.model import load_preset
    from vtol_impedance.scenarios import build, controller_params

    spec = apply_overrides(get("case-a-payload"), ["control.zeta_o=0.5", "control.wn_o=12", "control.wn_o_yaw=6"])
    g = controller_params(spec, "pd").gains
    I = np.diag(load_preset("pelican").inertia)  # noqa: E741
    np.testing.assert_allclose(np.asarray(g.Do), 2 * 0.5 * np.array([12.0, 12.0, 6.0]) * I)  # per axis
    np.testing.assert_allclose(np.asarray(g.Ko), np.array([12.0, 12.0, 6.0]) ** 2 * I)
    free = build(apply_overrides(get("case-a-payload"), ["plant.rotor_limits=false"]))
    assert np.all(free.plant.vehicle.geometry.f_max >= 1e6)
    assert np.all(controller_params(spec, "pd").vehicle.geometry.f_max == 7.0)
    assert np.all(build(get("case-a-payload")).plant.vehicle.geometry.f_max == 7.0)
