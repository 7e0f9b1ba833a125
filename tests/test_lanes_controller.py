"""The control law of a block of vehicles in SIMD lanes (``compiled.lanes_controller``, fourteenth stop): sixteen
controllers of every variant (PD, PD with compensation, PID, comply with its own impedance) on vehicles of their
own masses, inertias and rotor layouts, given sixteen different measurements, estimates and references (comply
fractions, yaw across +-pi, requests beyond the rotors' reach and the tilt limit), command what the
vehicle-by-vehicle law commands and carry the same state; where the allocation does not saturate the rotor
forces give exactly the requested thrust and moments (eq. (4)); the law's loop is vector code."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from vtol_impedance.compiled.controller import control_law, law_lane_of, new_output, pack_controller
from vtol_impedance.compiled.controller import initial_state as ctrl_initial_state
from vtol_impedance.compiled.jit import FLAGS
from vtol_impedance.compiled.lanes import _FC, _N, W, new_buffer
from vtol_impedance.compiled.lanes_controller import (
    allocation_held,
    finish_lanes,
    fix_allocation,
    get_law_state,
    get_output,
    law_lanes,
    new_law_buffer,
    put_law,
    put_law_state,
    put_measurement,
)
from vtol_impedance.compiled.lanes_estimator import _CC, _MM, _QQ, _RD, _WH, _put6, _put9, new_estimator_buffer
from vtol_impedance.control.gains import Impedance, ImpedanceGains
from vtol_impedance.control.impedance import ControllerParams, compile_controllers
from vtol_impedance.model.vehicle import VehicleParams

K = 60  # control ticks
VARIANTS = ("pd", "pdc", "pid", "comply")
_OUT = ("thrust", "tau_B", "thrust_request", "tau_B_request", "f_rotor", "eta_d", "eta_d_dot", "mu_bar",
        "f_hat_W", "tau_hat_eta", "tau_hat_B", "rp_scale", "yaw_scale")  # fmt: skip
_FLAGS = ("saturated", "tilt_limited")
_STATE = ("filt_x", "filt_xd", "integral", "thrust_prev", "tau_B_prev")


def _controllers(rng, layout):
    out = []
    for i in range(W):
        mass = rng.uniform(1.2, 2.0)
        ixx = rng.uniform(0.01, 0.03)
        inertia = np.diag([ixx, rng.uniform(0.8, 1.2) * ixx, rng.uniform(1.5, 1.8) * ixx])  # a rigid body's
        veh = VehicleParams(mass=mass, inertia=inertia, layout=layout, f_max=10.0)
        variant = VARIANTS[i % 4]
        imp = (
            Impedance(M=rng.uniform(0.6, 3.0), D=rng.uniform(2.0, 9.0), K=rng.uniform(3.0, 20.0))
            if i % 8 == 3
            else None
        )
        gains = ImpedanceGains.paper(inertia, Ki=2.0 if variant == "pid" else 0.0, mass=mass)
        out.append(ControllerParams(veh, gains, variant, tilt_max=np.radians(rng.uniform(20, 50)), impedance=imp))
    return out


def _inputs(rng, p):
    """Per tick and lane: the measurement (12), the estimator's sample (Q, M, C, w, rd: 39) and, per tick, the
    reference row (18) with comply fractions. In the second half three lanes ask for far more than their rotors
    give."""
    t = np.arange(K)[:, None] * 0.01
    ph = rng.uniform(0, 2 * np.pi, (1, W))
    Y = np.zeros((K, W, 12))  # noqa: N806
    Y[:, :, 0:3] = 0.3 * np.stack([np.sin(2 * t + ph), np.cos(3 * t + ph), np.sin(t + ph)], -1)
    Y[:, :, 3:6] = 0.2 * np.stack([np.cos(2 * t + ph), np.sin(3 * t + ph), np.cos(t + ph)], -1)
    Y[:, :, 6] = 0.05 * np.sin(5 * t + ph)
    Y[:, :, 7] = 0.05 * np.cos(4 * t + ph)
    Y[:, :, 8] = np.mod(3.1 + 2.0 * t + 0.002 * ph + np.pi, 2 * np.pi) - np.pi  # the yaw winds through +-pi
    Y[:, :, 9:12] = 0.1 * np.sin(3 * t + ph)[..., None] + 0.01 * rng.standard_normal((K, W, 3))
    Y[:, :, 11] += 2.0  # the yaw rate of the reference
    far = (np.arange(K)[:, None] >= K // 2) & (np.arange(W)[None, :] % 5 == 0)
    Y[:, :, 0] += np.where(far, 8.0, 0.0)  # a metres-large error: beyond the tilt limit
    Y[:, :, 6] += np.where(far, 1.0, 0.0)  # a radian of roll error: beyond the rotors' moment
    e0, e1 = Y[:, :, 6], Y[:, :, 7]
    sf, cf, st, ct = np.sin(e0), np.cos(e0), np.sin(e1), np.cos(e1)
    z = np.zeros_like(e0)
    Q = np.stack([z + 1, z, -st, z, cf, sf * ct, z, -sf, cf * ct], -1).reshape(K, W, 3, 3)  # noqa: N806 eq. (1c)
    I = p["I_B"]  # noqa: E741
    M = np.einsum("kiba,ibc,kicd->kiad", Q, I, Q)  # noqa: N806 eq. (3b)
    C = 0.01 * rng.standard_normal((K, W, 3, 3))  # noqa: N806
    w = np.concatenate(
        [np.sin(t + ph)[..., None] * rng.uniform(-2, 2, (1, W, 3)), 0.01 * rng.standard_normal((K, W, 3))], -1
    )
    rd = np.concatenate(
        [np.cos(t + ph)[..., None] * rng.uniform(-2, 2, (1, W, 3)), 0.05 * rng.standard_normal((K, W, 3))], -1
    )
    S = np.concatenate([Q.reshape(K, W, 9), M.reshape(K, W, 9), C.reshape(K, W, 9), w, rd], -1)  # noqa: N806
    R = np.zeros((K, 18))  # noqa: N806
    R[:, 0:3] = 0.1 * np.sin(t)
    R[:, 3:6] = 0.1 * np.cos(t)
    R[:, 6:9] = 0.5 * np.sin(3 * t)
    R[:, 9] = np.mod(3.1 + 2.0 * t[:, 0] + np.pi, 2 * np.pi) - np.pi
    R[:, 10], R[:, 11] = 2.0, 0.0
    R[:, 12:18] = np.clip(0.5 + 0.7 * np.sin(7 * t + np.arange(6)), 0.0, 1.0)  # the comply fractions
    return Y, S, R


@njit(**{**FLAGS, "cache": False})
def _each(p, d, s, Y, S, R, out, o):  # noqa: N803
    """The vehicle-by-vehicle law: ``out[k, i]`` is ``o`` after tick ``k`` of vehicle ``i``."""
    for k in range(Y.shape[0]):
        for i in range(p.shape[0]):
            v = S[k, i]
            Q = (v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8])  # noqa: N806
            M = (v[9], v[10], v[11], v[12], v[13], v[14], v[15], v[16], v[17])  # noqa: N806
            C = (v[18], v[19], v[20], v[21], v[22], v[23], v[24], v[25], v[26])  # noqa: N806
            w = (v[27], v[28], v[29], v[30], v[31], v[32])
            rd = (v[33], v[34], v[35], v[36], v[37], v[38])
            control_law(p[i], d[0], s[i], Y[k, i], R[k], o[0], Q, M, C, w, rd)
            out[k, i] = o[0]


@njit(**{**FLAGS, "cache": False})
def _in_lanes(p, d, s, Y, S, R, out, o, held, plant_rows):  # noqa: N803
    """The same ticks in lanes; ``held[k]``: whether every lane's allocation held its first step at tick ``k``;
    ``plant_rows[k]``: the plant buffer after the tick (the commands it was handed)."""
    cb, eb, buf = new_law_buffer(), new_estimator_buffer(4), new_buffer()
    n = p[0].n_rotors
    for i in range(W):
        put_law(cb, i, law_lane_of(p[i]), p[i])
        put_law_state(cb, i, s[i])
    for k in range(Y.shape[0]):
        for i in range(W):
            put_measurement(cb, i, Y[k, i])
            v = S[k, i]
            _put9(eb, _QQ, i, (v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8]))
            _put9(eb, _MM, i, (v[9], v[10], v[11], v[12], v[13], v[14], v[15], v[16], v[17]))
            _put9(eb, _CC, i, (v[18], v[19], v[20], v[21], v[22], v[23], v[24], v[25], v[26]))
            _put6(eb, _WH, i, (v[27], v[28], v[29], v[30], v[31], v[32]))
            _put6(eb, _RD, i, (v[33], v[34], v[35], v[36], v[37], v[38]))
        held[k] = law_lanes(cb, eb, d[0], R[k], n)
        for i in range(W):
            if not allocation_held(cb, i):
                fix_allocation(cb, i, p[i], o[0].f_rotor)
        finish_lanes(cb, eb, buf, d[0], n)
        for i in range(W):
            get_output(cb, eb, i, R[k], o[0])
            out[k, i] = o[0]
        plant_rows[k] = buf
    for i in range(W):
        get_law_state(cb, i, s[i])


@pytest.mark.parametrize("layout", ["plus", "x", "hex"])
def test_the_laws_in_lanes_command_as_each_vehicle_does(rng, layout):
    ctrls = _controllers(rng, layout)
    arrays = compile_controllers(ctrls)
    p, d = pack_controller(arrays)
    Y, S, R = _inputs(rng, p)  # noqa: N806
    s_each, _ = ctrl_initial_state(p, d)
    # a filter that has not started holds whatever it held: the law must not read it (it starts at its command)
    s_each["filt_x"], s_each["filt_xd"] = rng.uniform(-1, 1, (W, 2)), rng.uniform(-5, 5, (W, 2))
    s_lanes = s_each.copy()
    ref, got = new_output(K * W).reshape(K, W), new_output(K * W).reshape(K, W)
    _each(p, d, s_each, Y, S, R, ref, new_output(1))
    held = np.zeros(K, dtype=np.bool_)
    plant = np.zeros((K, new_buffer().shape[0]))
    _in_lanes(p, d, s_lanes, Y, S, R, got, new_output(1), held, plant)
    # both paths of the allocation were flown: some ticks saturate a lane, some saturate none
    assert held.any() and not held.all()
    assert ref["saturated"].any() and not ref["saturated"].all() and ref["tilt_limited"].any()
    for name in _OUT:
        scale = max(np.abs(ref[name]).max(), 1e-300)
        err = np.abs(got[name] - ref[name]).max()
        assert err <= 1e-11 * scale, (name, err / scale)
    for name in _FLAGS:
        np.testing.assert_array_equal(got[name], ref[name], err_msg=name)
    for name in _STATE:
        scale = max(np.abs(s_each[name]).max(), 1e-300)
        assert np.abs(s_lanes[name] - s_each[name]).max() <= 1e-11 * scale, name
    assert s_lanes["filt_started"].all()
    # independently: the attitude filter starts at rest at its first command ...
    np.testing.assert_array_equal(got["eta_d_dot"][0, :, :2], 0.0)
    # ... and the PID integral sums Ts times the position error, frozen on a tick that saturated or hit the tilt
    # or lift limit (anti-windup), within integral_limit / Ki
    Ts, lim, Ki = ctrls[0].Ts, ctrls[0].integral_limit, p["Ki"]  # noqa: N806
    frozen = ref["saturated"] | ref["tilt_limited"]
    assert frozen[:, Ki[:, 0] > 0].any() and not frozen[:, Ki[:, 0] > 0].all()
    acc = np.zeros((W, 3))
    for k in range(K):
        acc = np.where(frozen[k][:, None], acc, acc + Ts * (Y[k, :, 0:3] - R[k, 0:3]))
        bound = lim / np.maximum(Ki, 1e-12)
        acc = np.clip(acc, -bound, bound)
    pid = Ki[:, 0] > 0
    assert pid.sum() >= 4
    np.testing.assert_allclose(s_lanes["integral"][pid], acc[pid], rtol=1e-12, atol=1e-15)
    # eq. (4): where nothing saturated, the rotor forces give exactly what was asked (an independent check of the
    # allocation: E from the vehicles' own geometry)
    n = ctrls[0].vehicle.n_rotors
    E = np.array([c.vehicle.geometry.E for c in ctrls])  # noqa: N806
    ok = ~got["saturated"]
    wrench = np.einsum("icr,kir->kic", E, got["f_rotor"][:, :, :n])
    asked = np.concatenate([got["thrust_request"][..., None], got["tau_B_request"]], -1)
    np.testing.assert_allclose(wrench[ok], asked[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(wrench[ok][:, 0], got["thrust"][ok], rtol=1e-12)
    # the plant's rows hold each lane's commands and the thrust and moments it was handed
    for r in range(n):
        np.testing.assert_array_equal(plant[:, (_FC + r) * W : (_FC + r + 1) * W], got["f_rotor"][:, :, r])
    np.testing.assert_array_equal(plant[:, (_N + 10) * W : (_N + 11) * W], got["thrust"])


def test_the_law_loop_is_vector_code():
    """The law's arithmetic (eqs. (14)-(20) with its sines, the filter, the allocation's first step) compiles to
    packed FMAs: a call or a branch on a lane's value would leave the loop scalar."""
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if not re.search(r"\bavx2\b", flags):
        pytest.skip("no AVX2 on this machine")
    veh = VehicleParams(mass=1.2, inertia=[0.02, 0.02, 0.04])
    _, d = pack_controller(compile_controllers([ControllerParams(veh, ImpedanceGains.paper(veh.inertia))]))

    @njit(**{**FLAGS, "cache": False})
    def one(cb, eb, d, r):
        return law_lanes(cb, eb, d[0], r, 4)

    one(new_law_buffer(), new_estimator_buffer(4), d, np.zeros(18))
    asm = one.inspect_asm(one.signatures[0])
    packed = len(re.findall(r"vfn?m(?:add|sub)\w*pd\s+%[yz]mm", asm))
    # the loop is vector code with a scalar copy kept for rows that might overlap (never taken: two buffers):
    # 145 packed FMAs measured, none when a load under a branch (the comply fractions) kept it scalar
    assert packed >= 100, packed
    assert not re.search(r"\$(sin|cos|tan|atan2|asin|fmod)\b", asm), "a C-library call in the lanes' law"
