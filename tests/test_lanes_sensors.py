"""The sensors of a block of vehicles in SIMD lanes (``compiled.lanes.measure_lanes``, fourteenth stop): sixteen
vehicles with their own payloads (the CoM off the body origin), each reading two delayed states of its ring
(attitudes across the +-pi yaw wrap and up to 80 degrees of pitch), with noise, report what the NumPy
definition of the sensors reports; the rings go in and out of the lanes unchanged, and a kept state is the
plant's."""

from __future__ import annotations

import numpy as np
from numba import njit

from vtol_impedance.compiled.jit import FLAGS
from vtol_impedance.compiled.lanes import (
    _SN,
    W,
    get_sensors,
    keep_state,
    measure_lanes,
    measurement_at,
    new_buffer,
    new_sensor_buffer,
    put_sensors,
    put_state,
)
from vtol_impedance.model.vehicle import VehicleParams
from vtol_impedance.sim.plant import N_BODY, PlantParams, compile_plants, pack_plant, pack_state, state_size
from vtol_impedance.sim.sensors import measurement

H = 7


@njit(**{**FLAGS, "cache": False})
def _in_lanes(pp, hist, noise, sigma, slot_m, slot_i, out, back, x_now, slot_now):
    sb = new_sensor_buffer(hist.shape[1])
    for i in range(W):
        put_sensors(sb, i, pp[i], hist[i])
        for j in range(12):
            sb[(_SN + j) * W + i] = noise[i, j]
    measure_lanes(sb, slot_m, slot_i, sigma)
    for i in range(W):
        measurement_at(sb, i, out[i])
    buf = new_buffer()  # a plant state kept into a slot, then every ring handed back
    for i in range(W):
        put_state(buf, i, x_now[i])
    keep_state(sb, buf, slot_now)
    for i in range(W):
        get_sensors(sb, i, back[i])


def _states(rng, n):
    """``n`` random plant states (flat, the NumPy layout) for 16 vehicles: any yaw, pitch up to 80 degrees."""
    x = np.zeros((n, W, 13))
    x[..., 0:3] = rng.uniform(-5, 5, (n, W, 3))
    x[..., 3:6] = rng.uniform(-3, 3, (n, W, 3))
    yaw, pitch, roll = rng.uniform(-np.pi, np.pi, (n, W)), rng.uniform(-1.4, 1.4, (n, W)), rng.uniform(-1, 1, (n, W))
    cy, sy, cp, sp, cr, sr = (
        np.cos(yaw / 2),
        np.sin(yaw / 2),
        np.cos(pitch / 2),
        np.sin(pitch / 2),
        np.cos(roll / 2),
        np.sin(roll / 2),
    )
    x[..., 6] = cr * cp * cy + sr * sp * sy  # ZYX Euler angles to [w, x, y, z]
    x[..., 7] = sr * cp * cy - cr * sp * sy
    x[..., 8] = cr * sp * cy + sr * cp * sy
    x[..., 9] = cr * cp * sy - sr * sp * cy
    x[..., 10:13] = rng.uniform(-4, 4, (n, W, 3))
    return x


def _full(x13):
    """Flat states of a quadrotor (the NumPy layout) with these body states, hovering rotors, no pendulum."""
    x = np.zeros((x13.shape[0], state_size(4)))
    x[:, :N_BODY] = x13
    x[:, N_BODY : N_BODY + 4] = 3.0
    return x


def test_the_sensors_in_lanes_report_what_the_numpy_sensors_report(rng):
    plants = [
        PlantParams(VehicleParams(mass=1.2, inertia=[0.02, 0.02, 0.04]), payload_mass=rng.uniform(0.1, 0.6),
                    payload_offset_B=tuple(rng.uniform(-0.05, 0.05, 3)))
        for _ in range(W)
    ]  # fmt: skip
    P = compile_plants(plants)  # noqa: N806
    assert np.abs(P.c_B).max() > 1e-3  # the CoM is off the body origin: the lever arm is exercised
    pp = pack_plant(P)
    X = _states(rng, H)  # noqa: N806
    hist = np.stack([pack_state(_full(X[s])) for s in range(H)], axis=1)  # (W, H) records
    noise, sigma = rng.standard_normal((W, 12)), np.array([0.01, 0.02, 0.005, 0.03])
    slot_m, slot_i = 2, 5
    out, back = np.zeros((W, 12)), np.zeros_like(hist)
    now = _states(rng, 1)[0]
    _in_lanes(pp, hist, noise, sigma, slot_m, slot_i, out, back, pack_state(_full(now)), 4)
    m = measurement(P, _full(X[slot_m]), _full(X[slot_i]), sigma, noise)
    ref = np.concatenate([m.p_W, m.v_W, m.eta, m.eta_dot], -1)
    for cols, what in ((slice(0, 3), "p_W"), (slice(3, 6), "v_W"), (slice(6, 9), "eta"), (slice(9, 12), "eta_dot")):
        np.testing.assert_allclose(out[:, cols], ref[:, cols], rtol=1e-12, atol=1e-12, err_msg=what)
    # the rings are handed back as they were, but for the slot that took the plant's state
    for name, cols in (("p_com_W", slice(0, 3)), ("v_com_W", slice(3, 6)), ("q_WB", slice(6, 10)),
                       ("omega_B", slice(10, 13))):  # fmt: skip
        for s in range(H):
            want = now[:, cols] if s == 4 else X[s][:, cols]
            np.testing.assert_array_equal(back[name][:, s], want, err_msg=(name, s))
