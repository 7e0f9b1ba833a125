"""The batch engine with its plants and estimators in SIMD lanes (``compiled.lanes``, ``compiled.lanes_estimator``,
``compiled.engine.run_block_lanes``): it flies every shipped scenario as the vehicle-per-thread engine does (to
1e-11: the estimators in lanes use the vector sines, the vehicle engine the C library's) and as the NumPy
definition does (1e-9), for quadrotors and hexarotors, with failures and padding lanes, and its plant loop is
vector code."""

from __future__ import annotations

import functools
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import vtol_impedance.sim.loop as loop
from vtol_impedance.compiled.lanes import W
from vtol_impedance.control import ControllerParams
from vtol_impedance.control.reference import Hold, Trajectory
from vtol_impedance.model.vehicle import load_preset
from vtol_impedance.scenarios import build, get, names
from vtol_impedance.scenarios.batch import population
from vtol_impedance.sim import PlantParams, run_closed_loop

#: Scenarios whose compiled flight (either engine) parts from the NumPy definition by more than 1e-9, and why:
#: in the gust scenario the payload's contact point touches the ground in the first 0.1 s while descending, where
#: the ground's force jumps from 0 to the damper's c v (0.6 N at 4 mm/s), so a last-bit difference moves the
#: touch by a plant step: 3e-4 N of contact force at 0.07 s, 1e-7 m of position and 3e-6 m/s of velocity after a
#: second, 1e-4 of the lumped force (testing guide).
KNOWN_APART = {"gust": 3e-4}


def _fly(monkeypatch, lanes: bool, *args, **kw):
    monkeypatch.setattr(loop, "LANES_MIN_BATCH", 1 if lanes else 10**9)
    return run_closed_loop(*args, **kw)


#: How far the lanes may part from the vehicle engine (largest difference over the signal's scale, :func:`_rel`):
#: the estimators in lanes take their sines from ``compiled.vmath`` (within 3 ulp of the C library's), so
#: their estimates part by about 1e-16 a sample; through the closed loop that stays below 1e-13 over seconds.
ENGINES_APART = 1e-11


def _same_flight(lanes, vehicles, what=""):
    """The two engines' logs, metrics and failures agree: the failures exactly, the rest to :data:`ENGINES_APART`."""
    assert lanes.failures == vehicles.failures
    for k in lanes.data:
        assert _rel(lanes[k], vehicles[k]) <= ENGINES_APART, f"{k} {what}"
    assert (lanes.metrics is None) == (vehicles.metrics is None)
    for ml, mv in zip(lanes.metrics or [], vehicles.metrics or [], strict=True):  # a dict per vehicle (or None)
        assert (ml is None) == (mv is None)
        for k in ml or {}:
            if isinstance(mv[k], float):
                assert ml[k] == pytest.approx(mv[k], rel=1e-9, abs=1e-12, nan_ok=True), f"{k} {what}"
            else:
                assert ml[k] == mv[k], f"{k} {what}"
        assert (ml or {}).keys() == (mv or {}).keys()


def _rel(a, b):
    """Largest difference over the larger of the signal's largest value and one unit (m, m/s, rad, N): over a
    second some signals stay near a millimetre, where the libraries' last-bit differences in exp, sin and atan2
    (libm in the kernels, NumPy's own in the definition) are not yet lost in the signal."""
    a, b = np.asarray(a), np.asarray(b)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    if a.size == 0 or np.isnan(a).all():
        return 0.0
    scale = max(float(np.nanmax(np.abs(a))), 1.0)
    return float(np.nanmax(np.abs(a - b))) / scale


@pytest.mark.parametrize("name", names())
def test_every_scenario_flies_in_lanes_as_vehicle_by_vehicle_and_as_numpy(monkeypatch, name):
    """Three vehicles of the scenario's population (different plants and seeds; the other 13 lanes of the block
    pad), one second: the lanes give the vehicle engine's log to 1e-11, and the NumPy definition's to 1e-9."""
    spec = get(name)
    b = build(spec)
    plants, ctrls, seeds = population(spec, 3, seed=1)
    args = (plants, ctrls, b.trajectory, 1.0, b.disturbances, b.sensors)
    kw = {"seed": seeds, "start_W": b.start_W, "log": "full"}
    lanes = _fly(monkeypatch, True, *args, **kw)
    vehicles = _fly(monkeypatch, False, *args, **kw)
    ref = run_closed_loop(*args, **kw, backend="numpy")
    assert lanes.config["backend"] == "compiled"
    _same_flight(lanes, vehicles)
    for k in ("p_W", "v_W", "eta", "f_hat_W", "tau_hat_eta", "f_rotor", "f_lumped_W"):
        assert _rel(lanes[k], ref[k]) <= KNOWN_APART.get(name.rsplit("-v", 1)[0], 1e-9), k
    assert lanes.failures == vehicles.failures == ref.failures


@pytest.mark.parametrize("preset", ["pelican", "hexarotor"])
def test_more_vehicles_than_a_block_with_a_failure_mid_flight(monkeypatch, preset):
    """More vehicles than a block (two blocks, the second padded), rotor lag on some and not others, and one
    vehicle with a payload it cannot lift: it stops with the vehicle engine's code and time, the others fly on
    unchanged. The hexarotor's six rotors take the general rotor loop, the quadrotor's four the unrolled one."""
    veh = load_preset(preset)
    n = W + 3
    plants, ctrls = [], []
    for i in range(n):
        plants.append(PlantParams(veh, payload_mass=3.0 if i == 5 else 0.04 * (i % 5), rotor_tau_up=0.02 * (i % 2),
                                  rotor_tau_down=0.03 * (i % 3 > 0), rotor_drag=0.1))  # fmt: skip
        c = ControllerParams.paper("pdc", vehicle=veh)
        ctrls.append(replace(c, gains=replace(c.gains, Kp=12.0 + i % 4)))
    traj = Trajectory((Hold((0.0, 0.0, -1.0), 4.0),))
    kw = {"seed": list(range(n)), "log": "full"}
    lanes = _fly(monkeypatch, True, plants, ctrls, traj, 4.0, **kw)
    vehicles = _fly(monkeypatch, False, plants, ctrls, traj, 4.0, **kw)
    _same_flight(lanes, vehicles)
    assert lanes.failures[5] is not None and sum(f is not None for f in lanes.failures) == 1
    # in hover the rotors carry the weight: an independent check that every lane flew its own plant
    m = np.array([p.vehicle.mass + p.payload_mass for p in plants])
    ok = np.array([f is None for f in lanes.failures])
    thrust = np.nansum(lanes["f_rotor"][:, -1], axis=1)
    np.testing.assert_allclose(thrust[ok], m[ok] * 9.81, rtol=0.02)


def test_a_block_with_quadratic_drag_steps_it_and_a_block_without_leaves_it_out(monkeypatch):
    """A block whose plants have neither a pendulum nor quadratic drag takes the plant step without their
    arithmetic (``full`` false); a block where one lane has quadratic drag takes the whole step. Two blocks,
    the second with one vehicle given body drag, fly a 2 m move in a second (3.75 m/s at its middle): the
    lanes give the vehicle engine's log and the NumPy definition's, and the dragged vehicle parts from its
    twin (same plant but for the drag, same seed) by more than a millimetre: the drag acts in lanes."""
    from vtol_impedance.control.reference import MinJerk

    veh = load_preset("pelican")
    n = W + 3
    dragged = W + 1
    plants = [PlantParams(replace(veh, body_drag=(0.2, 0.2, 0.4)) if i == dragged else veh,
                          payload_mass=0.02 * (i % 3), rotor_tau_up=0.02) for i in range(n)]  # fmt: skip
    ctrls = [ControllerParams.paper("pdc", vehicle=veh)] * n
    start = np.array([0.0, 0.0, -1.0])
    traj = Trajectory((Hold(start, 0.2), MinJerk(start, (2.0, 0.0, -1.0), 1.0), Hold((2.0, 0.0, -1.0), 0.3)))
    seeds = [i if i != dragged else dragged - 1 for i in range(n)]  # the dragged vehicle's twin: its neighbour
    plants[dragged - 1] = replace(plants[dragged], vehicle=veh)
    kw = {"seed": seeds, "log": "full", "start_W": start}
    lanes = _fly(monkeypatch, True, plants, ctrls, traj, 1.5, **kw)
    vehicles = _fly(monkeypatch, False, plants, ctrls, traj, 1.5, **kw)
    ref = run_closed_loop(plants, ctrls, traj, 1.5, **kw, backend="numpy")
    _same_flight(lanes, vehicles)
    for k in ("p_W", "v_W", "f_rotor", "f_lumped_W"):
        assert _rel(lanes[k], ref[k]) <= 1e-9, k
    apart = np.abs(lanes["p_W"][dragged] - lanes["p_W"][dragged - 1]).max()
    assert apart > 1e-3, apart


@pytest.mark.parametrize("lagless", [True, False])
def test_the_lanes_keep_their_states_across_chunks_decimated_logs_and_the_metrics_alone(monkeypatch, lagless):
    """The lanes hold the states between ticks and write the records only at a chunk's end, on a failure and
    before a logged tick: with chunks of 50 ticks, a log every third tick, the metrics alone, disturbances that
    read the state (a wall, a push, a sinusoid), two blocks and a vehicle that falls with a payload it cannot
    lift inside the metrics' window, the lanes give the vehicle engine's log, metrics and failures (to
    :data:`ENGINES_APART`). ``lagless``: half the rotors follow their command at once (the tick then visits
    each vehicle); otherwise none does, and without a log the window's sums stay in lanes over a chunk."""
    from vtol_impedance.control.reference import MinJerk
    from vtol_impedance.model.vehicle import HoverWarning
    from vtol_impedance.sim import SensorParams
    from vtol_impedance.sim.disturbances import Push, SinusoidWrench, Wall

    monkeypatch.setattr(loop, "CHUNK_VEHICLE_TICKS", 1)  # chunks of 50 ticks
    veh = load_preset("pelican")
    n = W + 3
    plants = [PlantParams(veh, payload_mass=3.0 if i == 7 else 0.03 * (i % 4),
                          rotor_tau_up=0.02 * (i % 2) if lagless else 0.02 + 0.01 * (i % 2), rotor_drag=0.1)
              for i in range(n)]  # fmt: skip
    ctrls = [ControllerParams.paper("pdc")] * n
    start = np.array([0.0, 0.0, -1.0])
    traj = Trajectory((Hold(start, 0.3), MinJerk(start, (0.45, 0.0, -1.0), 1.0), Hold((0.45, 0.0, -1.0), 0.7)))
    dists = [Wall(position_W=(0.5, 0.0, 0.0), normal_W=(-1.0, 0.0, 0.0), radius=0.1),
             Push(force_W=(0.0, 2.0, 0.0), t_on=1.0, duration=0.3),
             SinusoidWrench(force_W=(0.0, 0.0, 0.5), torque_B=(0.0, 0.0, 0.02), freq_hz=2.0)]  # fmt: skip
    for log in (3, "metrics"):
        kw = {"seed": list(range(n)), "log": log, "window": (0.5, 1.8), "start_W": start}
        with pytest.warns(HoverWarning, match="3 kg of payload"):
            lanes = _fly(monkeypatch, True, plants, ctrls, traj, 2.0, dists, SensorParams(), **kw)
            vehicles = _fly(monkeypatch, False, plants, ctrls, traj, 2.0, dists, SensorParams(), **kw)
        assert lanes.failures[7] is not None and 0.5 < lanes.failures[7]["time"] < 1.8
        assert sum(f is not None for f in lanes.failures) == 1
        _same_flight(lanes, vehicles, f"(log={log})")


@pytest.mark.parametrize("full", [False, True])
def test_the_plant_loop_is_vector_code(full):
    """The lanes' RK4 step compiles to packed double-precision FMAs (a call, a gather or a memory-dependent
    branch in the loop would leave it scalar): counted in the machine code of a block's step, with and
    without the pendulum and the quadratic drag (``full``); without them, no square root or division
    is left but the quaternion's norm on the path of a block with a lane far from unit norm (one of each
    per lane; the common path takes Newton steps, ``plant.inv_norm_near``)."""
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if not re.search(r"\bavx2\b", flags):
        pytest.skip("no AVX2 on this machine")
    from numba import njit

    from vtol_impedance.compiled.jit import FLAGS
    from vtol_impedance.compiled.lanes import new_buffer, step_lanes

    @njit(**{**FLAGS, "cache": False})
    def one_step(buf, dt):
        step_lanes(buf, 4, dt, full)

    one_step(new_buffer(), 1e-3)
    asm = one_step.inspect_asm(one_step.signatures[0])
    packed = len(re.findall(r"vfn?m(?:add|sub)\w*pd\s+%[yz]mm", asm))
    scalar = len(re.findall(r"vfn?m(?:add|sub)\w*sd\s", asm))
    assert packed > 100 and packed > 5 * scalar, (packed, scalar)
    slow = len(re.findall(r"v(?:sqrt|div)pd\s", asm))  # one vector's square roots and divisions
    if full:  # the drag's speed at four stages, the pendulum's length and tension, its projection
        assert slow >= 20, slow
    else:  # the far path's quaternion norm alone (its loop over the lanes perhaps unrolled once)
        assert 0 < slow <= 4, slow


def test_the_truth_and_the_failure_checks_at_a_tick_are_vector_code():
    """What a tick observes of the truth (the plant's derivative, the Euler angles, the lumped wrench, the body
    origin) and the failure checks run over the lanes as packed instructions too (twelfth stop): a scalar FMA
    would say a call or a branch kept the loop scalar."""
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if not re.search(r"\bavx2\b", flags):
        pytest.skip("no AVX2 on this machine")
    from numba import njit

    from vtol_impedance.compiled.jit import FLAGS
    from vtol_impedance.compiled.lanes import failure_lanes, new_buffer, observe_lanes

    @njit(**{**FLAGS, "cache": False})
    def observe(buf):
        observe_lanes(buf, 4, True)

    @njit(**{**FLAGS, "cache": False})
    def observe_plain(buf):
        observe_lanes(buf, 4, False)

    @njit(**{**FLAGS, "cache": False})
    def fail(buf):
        failure_lanes(buf, 4)

    for fn, least in ((observe, 100), (observe_plain, 100), (fail, 10)):
        fn(new_buffer())
        asm = fn.inspect_asm(fn.signatures[0])
        packed = len(re.findall(r"vfn?m(?:add|sub)\w*pd\s+%[yz]mm", asm))
        scalar = len(re.findall(r"vfn?m(?:add|sub)\w*sd\s", asm))
        assert packed >= least and scalar == 0, (fn, packed, scalar)


def test_a_lane_holds_a_state_and_a_plant_as_the_records_do():
    """Writing a state record into a lane and reading it back gives it unchanged; the lane's plant reads back
    as the record's (the rows' order is the one both directions use)."""
    from numba import njit

    from vtol_impedance.compiled.jit import FLAGS
    from vtol_impedance.compiled.lanes import _plant_at, get_state, new_buffer, put_plant, put_state
    from vtol_impedance.compiled.layouts import STATE
    from vtol_impedance.compiled.plant import lane_of
    from vtol_impedance.sim.plant import compile_plants, pack_plant

    plant = PlantParams(load_preset("hexarotor"), payload_mass=0.3, rotor_drag=0.2, pendulum_mass=0.1,
                        pendulum_length=0.5, rotor_tau_up=0.01)  # fmt: skip
    pp = pack_plant(compile_plants([plant]))
    rng = np.random.default_rng(0)
    x = np.zeros(1, dtype=STATE)
    x.view(np.float64)[:] = rng.normal(size=x.view(np.float64).size)
    back = np.zeros(1, dtype=STATE)

    @njit(**{**FLAGS, "cache": False})
    def roundtrip(pp, x, back, i):
        buf = new_buffer()
        put_plant(buf, i, pp[0], lane_of(pp[0]))
        put_state(buf, i, x[0])
        get_state(buf, i, back[0])
        return _plant_at(buf, i), lane_of(pp[0])

    got, want = roundtrip(pp, x, back, W - 1)
    assert got == want
    np.testing.assert_array_equal(back.view(np.float64), x.view(np.float64))


def test_the_newton_steps_give_the_inverse_norm_to_its_last_bit_near_one():
    """``plant.inv_norm_near`` (two Newton steps from the tangent, no square root) against ``1 / sqrt(x)`` in
    40-digit decimal arithmetic, over the whole range it is used in (``|x - 1| <= QUAT_NEAR``) and at its
    ends: within two units in the last place (the last step's own roundings; ``1 / sqrt(x)``, rounded twice,
    is within one), so the quaternion's norm is 1 to rounding either way."""
    from decimal import Decimal, getcontext

    from vtol_impedance.compiled.plant import QUAT_NEAR, inv_norm, inv_norm_near

    getcontext().prec = 40
    rng = np.random.default_rng(3)
    xs = np.concatenate([1.0 + QUAT_NEAR * rng.uniform(-1.0, 1.0, 2000), 1.0 + rng.normal(0.0, 1e-12, 200),
                         [1.0 - QUAT_NEAR, 1.0 + QUAT_NEAR, 1.0, np.nextafter(1.0, 2.0)]])  # fmt: skip
    for x in xs:
        exact = 1 / Decimal(float(x)).sqrt()
        got = inv_norm_near(float(x))
        assert abs(Decimal(got) - exact) <= 2 * Decimal(np.spacing(got)), (x, got)
        assert inv_norm(float(x)) == (got if abs(x - 1.0) <= QUAT_NEAR else 1.0 / np.sqrt(x))
    # beyond the range: the square root (Newton's two steps from the tangent would miss by 1e-7 at x = 1.21)
    assert inv_norm(1.21) == 1.0 / np.sqrt(1.21)
    assert abs(inv_norm_near(1.21) * 1.1 - 1.0) > 1e-8
    assert np.isnan(inv_norm(np.nan))


@functools.cache
def _block_and_vehicles():
    """A block of :data:`W` plants stepped in lanes (``step_lanes``, with or without the whole step as the
    engine picks) and each vehicle alone (``rk4_step``), a command per step held over it: each records the
    states after every step, the block also its contact flag (row ``_C``). Compiled once for the tests."""
    from numba import njit

    from vtol_impedance.compiled.jit import FLAGS
    from vtol_impedance.compiled.lanes import (
        _C,
        block_is_plain,
        get_state,
        new_buffer,
        put_command,
        put_plant,
        put_state,
        step_lanes,
    )
    from vtol_impedance.compiled.plant import lane_of, rk4_step

    @njit(**{**FLAGS, "cache": False})
    def in_lanes(pp, X, f_cmd, out, flag):
        buf = new_buffer()
        for i in range(W):
            put_plant(buf, i, pp[i], lane_of(pp[i]))
            put_state(buf, i, X[i])
        plain = block_is_plain(buf)
        for k in range(f_cmd.shape[0]):
            for i in range(W):
                put_command(buf, i, f_cmd[k, i], 4)
            if plain:  # literals, as the engine's block
                step_lanes(buf, 4, 1e-3, False)
            else:
                step_lanes(buf, 4, 1e-3, True)
            flag[k] = buf[_C * W]
            for i in range(W):
                get_state(buf, i, out[k, i])
        return plain

    @njit(**{**FLAGS, "cache": False})
    def one_by_one(pp, X, f_cmd, out):
        dist = np.zeros(6)
        for i in range(W):
            for k in range(f_cmd.shape[0]):
                rk4_step(pp[i], X[i], f_cmd[k, i], dist, 1e-3)
                out[k, i] = X[i]

    return in_lanes, one_by_one


def _in_lanes_and_alone(plants, x0, f_cmd):
    """The states after each step of a block of the ``plants`` from ``x0`` with the commands ``f_cmd`` (steps,
    :data:`W`, 4), in lanes and vehicle by vehicle, the block's contact flag after each step, and whether the
    block took the plain step (``block_is_plain``)."""
    from vtol_impedance.sim.plant import compile_plants, pack_plant

    in_lanes, one_by_one = _block_and_vehicles()
    pp = pack_plant(compile_plants(plants))
    lanes, alone = np.zeros((len(f_cmd), W), dtype=x0.dtype), np.zeros((len(f_cmd), W), dtype=x0.dtype)
    flag = np.zeros(len(f_cmd))
    plain = in_lanes(pp, x0, f_cmd, lanes, flag)
    one_by_one(pp, x0.copy(), f_cmd, alone)
    return lanes, alone, flag, plain


def test_a_block_renormalises_each_quaternion_as_its_own_vehicle_would():
    """A block's RK4 step brings each quaternion back to unit norm as the vehicle engine's ``rk4_step`` does,
    bit for bit at every step: with the Newton steps where the whole block is near unit norm (flight), and
    lane by lane where one lane is far from it (here a lane whose quaternion starts at norm 1.1: its step
    takes the square root, the other lanes still the Newton steps)."""
    from vtol_impedance.sim.plant import compile_plants, initial_state, pack_state

    plants = [PlantParams(load_preset("pelican"), payload_mass=0.05 * k, rotor_tau_up=0.01) for k in range(W)]
    rng = np.random.default_rng(4)
    x0 = pack_state(initial_state(compile_plants(plants), rng.normal(0.0, 1.0, (W, 3)) - [0, 0, 2.0]))
    q = rng.normal(size=(W, 4))
    x0["q_WB"] = q / np.linalg.norm(q, axis=1, keepdims=True)
    x0["omega_B"] = rng.normal(0.0, 3.0, (W, 3))
    f_cmd = np.repeat(rng.uniform(1.0, 6.0, (1, W, 4)), 3, axis=0)
    for far in (False, True):
        x = x0.copy()
        if far:
            x["q_WB"][5] *= 1.1
        lanes, alone, _, plain = _in_lanes_and_alone(plants, x, f_cmd)
        assert plain
        np.testing.assert_array_equal(lanes.view(np.float64), alone.view(np.float64))
        np.testing.assert_allclose(np.linalg.norm(lanes["q_WB"], axis=-1), 1.0, rtol=0, atol=1e-15)


@pytest.mark.parametrize("full", [False, True])
def test_a_block_takes_the_ground_as_each_vehicle_does_as_it_lands_rests_and_lifts(full):
    """A plain block steps without the ground's arithmetic while no contact point is below the ground, takes it
    again (the same step over) where one would be at any of the step's stages, keeps it while the ground
    acts, and leaves it once every lane is clear: each lane's states bit for bit its own vehicle's
    ``rk4_step``'s at every step. Lanes that touch down during a step, rest on the ground, fly high, and fall
    with the ground off; 90 ms at 0.6 of the hover thrust, then 60 ms at twice it. Independently, the ground
    holds the lanes that have it and not the others, and the block's contact flag (row ``_C``) is up while
    they rest and down once all have lifted off. ``full``: with a pendulum on one lane, the whole step, which
    always takes the ground (the same checks of the states; its flag stays down)."""
    from vtol_impedance.sim.plant import compile_plants, initial_state, pack_state

    kind = np.arange(W) % 4  # 0 touches down within a step or two, 1 rests, 2 flies high, 3 falls (no ground)
    plants = [PlantParams(load_preset("pelican"), payload_mass=0.05 * (k % 5), rotor_tau_up=0.01,
                          ground=bool(kind[k] != 3), pendulum_mass=0.1 if full and k == 2 else 0.0,
                          pendulum_length=0.3) for k in range(W)]  # fmt: skip
    rng = np.random.default_rng(5)
    z0 = np.choose(kind, [-0.002, 0.001, -1.0, -0.002])
    eta = rng.uniform(-0.15, 0.15, (W, 3))
    x0 = np.concatenate([pack_state(initial_state(compile_plants([plants[i]]), [0.3 * i, 0.0, z0[i]], eta[i]))
                         for i in range(W)])  # fmt: skip
    x0["v_com_W"][:, 2] = np.where(kind == 1, 0.0, 0.5)  # falling at 0.5 m/s: the ground within 4 ms
    x0["omega_B"] = rng.normal(0.0, 1.0, (W, 3))
    hover = np.array([(p.vehicle.mass + p.payload_mass + p.pendulum_mass) * 9.81 / 4 for p in plants])
    steps = 150
    f_cmd = np.repeat(hover[None, :, None], 4, axis=2) * np.where(np.arange(steps) < 90, 0.6, 2.0)[:, None, None]
    lanes, alone, flag, plain = _in_lanes_and_alone(plants, x0, f_cmd)
    assert plain is not full
    np.testing.assert_array_equal(lanes.view(np.float64), alone.view(np.float64))
    z = lanes["p_com_W"][:, :, 2] - x0["p_com_W"][:, 2]  # how far each lane's CoM went down
    assert np.all(z[89, kind == 3] > 0.04)  # with the ground off: falling (0.5 m/s, about 0.4 g net down)
    down = (kind == 0) | (kind == 1)
    assert np.all(z[89, down] < 0.02)  # held by the ground
    assert np.all(z[-1, down] < z[89, down] - 0.005)  # and off it again at twice the hover thrust
    if full:  # one form with the ground: the flag never used
        assert not flag.any()
    else:
        assert flag[:90].max() == 1.0 and flag[0] == 1.0  # the ground acts within the first step
        assert flag[-1] == 0.0  # every lane clear of it: the block steps without it again


def test_a_plain_block_leaves_the_pendulum_states_and_a_moving_massless_link_takes_the_whole_step():
    """Without a pendulum (``pend_m = 0``) the link's states have a zero derivative when it does not move, so
    a plain block's step leaves them as they are (``plant.body_rk4``, ``full`` false), bit for bit what each
    vehicle's ``rk4_step`` gives. A lane whose massless link moves (``v_pend_W`` not zero: its end drifts, as
    RK4 integrates it) makes the block take the whole step (``block_is_plain`` false), which moves it as the
    vehicle alone does."""
    from vtol_impedance.sim.plant import compile_plants, initial_state, pack_state

    plants = [PlantParams(load_preset("pelican"), payload_mass=0.05 * (k % 3), rotor_tau_up=0.01) for k in range(W)]
    rng = np.random.default_rng(6)
    x0 = pack_state(initial_state(compile_plants(plants), rng.normal(0.0, 1.0, (W, 3)) - [0, 0, 2.0]))
    x0["r_pend_W"] = rng.normal(0.0, 0.3, (W, 3))
    f_cmd = np.repeat(rng.uniform(1.0, 6.0, (1, W, 4)), 20, axis=0)
    lanes, alone, _, plain = _in_lanes_and_alone(plants, x0, f_cmd)
    assert plain
    np.testing.assert_array_equal(lanes.view(np.float64), alone.view(np.float64))
    np.testing.assert_array_equal(lanes["r_pend_W"][-1], x0["r_pend_W"])  # none moved
    x1 = x0.copy()
    x1["v_pend_W"][3] = (0.2, -0.1, 0.05)
    lanes, alone, _, plain = _in_lanes_and_alone(plants, x1, f_cmd)
    assert not plain
    np.testing.assert_array_equal(lanes.view(np.float64), alone.view(np.float64))
    drift = lanes["r_pend_W"][-1, 3] - x1["r_pend_W"][3]  # 20 steps of 1 ms at a constant rate
    np.testing.assert_allclose(drift, 0.02 * x1["v_pend_W"][3], rtol=1e-12)
    np.testing.assert_array_equal(np.delete(lanes["r_pend_W"][-1], 3, 0), np.delete(x1["r_pend_W"], 3, 0))


def test_the_code_generator_takes_512_bit_vectors_on_avx512_unless_told_not_to():
    """Where the host has AVX-512, importing the package, then ``numba.typed`` (as the engine does before its
    kernels), leaves numba's code generator without LLVM's 256-bit preference; ``VTOL_IMPEDANCE_NARROW_VECTORS=1``
    and a user's own ``NUMBA_CPU_FEATURES`` keep theirs (each in a fresh process: one generator per process)."""
    import os
    import subprocess
    import sys

    if not re.search(r"\bavx512f\b", Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""):
        pytest.skip("no AVX-512 on this machine")
    code = (  # the package first, then what the engine imports before its kernels
        "import vtol_impedance.compiled\n"
        "import numba.typed\n"
        "from numba.core.registry import cpu_target\n"
        "print('prefer-256' in cpu_target.target_context.codegen()._tm_features)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES", "NUMBA_CPU_NAME")}

    def wide(**extra):
        out = subprocess.run([sys.executable, "-c", code], env={**env, **extra}, capture_output=True, text=True,
                             check=True, timeout=120)  # fmt: skip
        return out.stdout.strip() == "True"

    assert wide()
    assert not wide(VTOL_IMPEDANCE_NARROW_VECTORS="1")
    import llvmlite.binding as ll

    assert not wide(NUMBA_CPU_FEATURES=ll.get_host_cpu_features().flatten())
