"""Two rules of the compiled engine checked against their definitions rather than against the NumPy backend
(planted bugs in them were caught only by the parity tests before): a vehicle is stopped as tipped over at
the first period that ends beyond 80 degrees of tilt, and the sensors' position and velocity noise have the
standard deviations asked for, drawn independently. Both engines (a vehicle per thread and the lanes) are checked."""

from __future__ import annotations

import math

import numpy as np
import pytest

import vtol_impedance.sim.loop as loop
from vtol_impedance.control import ControllerParams
from vtol_impedance.control.reference import Hold, Trajectory
from vtol_impedance.model.vehicle import VehicleParams, load_preset
from vtol_impedance.records import FAIL_TILT, MAX_TILT_RAD, REASONS
from vtol_impedance.sim import PlantParams, SensorParams, run_closed_loop
from vtol_impedance.sim.disturbances import ConstantWrench



@pytest.mark.parametrize("lanes", [False, True])
def test_a_vehicle_is_stopped_at_the_first_period_past_eighty_degrees_of_tilt(monkeypatch, lanes):
    """A roll moment of 2 N m, more than the rotors can give (1.47 N m: 7 N on a 0.21 m arm), rolls over a
    vehicle with a large inertia (1 kg m^2: a turn of under a degree a period near the bound) high above the
    ground: it must stop as tipped over, every logged tilt (taken at the start of each period) below the bound,
    and the tilt at the end of the last period flown, extrapolated from the last three logged, past it."""
    monkeypatch.setattr(loop, "LANES_MIN_BATCH", 1 if lanes else 10**9)
    assert MAX_TILT_RAD == pytest.approx(math.radians(80.0))
    veh = VehicleParams(1.2, [1.0, 1.0, 1.8], layout="plus", arm_length=0.21, f_max=7.0, drag_factor=0.016)
    high = np.array([0.0, 0.0, -50.0])
    r = run_closed_loop(PlantParams(veh), [ControllerParams.paper("pd", vehicle=veh)],
                        Trajectory([Hold(high, 5.0)]), 5.0, [ConstantWrench(torque_B=(2.0, 0.0, 0.0))],
                        SensorParams.ideal(), start_W=high, log="full")  # fmt: skip
    assert r.failures[0] is not None and r.failures[0]["reason"] == REASONS[FAIL_TILT]
    eta = np.asarray(r["eta"]).reshape(-1, 3)
    tilt = np.arccos(np.clip(np.cos(eta[:, 0]) * np.cos(eta[:, 1]), -1.0, 1.0))
    flown = tilt[np.isfinite(tilt)]
    assert flown.max() < MAX_TILT_RAD
    turn, before = flown[-1] - flown[-2], flown[-2] - flown[-3]
    end = flown[-1] + turn + (turn - before)  # where the last period flown ended, to a hundredth of a degree
    assert 0.0 < turn < math.radians(3.0)
    assert end >= MAX_TILT_RAD - math.radians(0.2)
    assert r.failures[0]["time"] == pytest.approx(len(flown) * 0.01, abs=1e-9)


@pytest.mark.parametrize("lanes", [False, True])
def test_the_measured_position_and_velocity_carry_their_own_noise(monkeypatch, lanes):
    """Position noise of 1 cm and velocity noise of 5 cm/s (no delay, no attitude noise): over 4 seconds of
    hover on three axes (1,200 samples each), each measured less true has its own standard deviation within
    8 % (the sample's spread is 2 %), no bias, and the two are independent draws (correlation within four
    standard errors of zero); the attitude is read without noise."""
    monkeypatch.setattr(loop, "LANES_MIN_BATCH", 1 if lanes else 10**9)
    sensors = SensorParams(pos_noise=0.01, vel_noise=0.05, att_noise=0.0, gyro_noise=0.0, mocap_delay=0.0,
                           imu_delay=0.0)  # fmt: skip
    start = np.array([0.0, 0.0, -2.0])
    r = run_closed_loop(PlantParams(load_preset("pelican")), [ControllerParams.paper("pd")],
                        Trajectory([Hold(start, 4.0)]), 4.0, (), sensors, start_W=start, log="full", seed=7)  # fmt: skip
    e_p = (np.asarray(r["p_meas_W"]) - np.asarray(r["p_W"])).reshape(-1, 3)[1:]
    e_v = (np.asarray(r["v_meas_W"]) - np.asarray(r["v_W"])).reshape(-1, 3)[1:]
    for err, sigma in ((e_p, 0.01), (e_v, 0.05)):
        assert np.std(err) == pytest.approx(sigma, rel=0.08)
        assert abs(np.mean(err)) < 4 * sigma / math.sqrt(err.size)
    rho = np.corrcoef(e_p.ravel(), e_v.ravel())[0, 1]
    assert abs(rho) < 4 / math.sqrt(e_p.size)
    np.testing.assert_allclose(np.asarray(r["eta_meas"]), np.asarray(r["eta"]), atol=1e-12)
