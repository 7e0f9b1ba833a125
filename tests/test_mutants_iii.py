"""Checks written for the bugs a third mutation campaign (eleventh stop) planted and nothing caught: the step
clock's rules, a device as an output, the gyro's glitch rule, the estimator's settling across restarts,
microsecond time stamps, a rotor's two limits, eq. (16)'s lift limit on both backends and the attitude
history's interpolation across the +-pi wrap. Each states the rule it checks; each failed on its bug."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest
import synthflight as S
from logfiles import csv_cols, write_csv

from vtol_impedance import Controller, ControllerWarning, Estimator
from vtol_impedance.control import ControllerParams, Measurement, Reference
from vtol_impedance.errors import InputError
from vtol_impedance.estimator import EstimatorParams
from vtol_impedance.logs import estimate, read_any, resample
from vtol_impedance.logs.checks import evidence
from vtol_impedance.logs.timeseries import RawLog, Signal

MEAS = Measurement(np.array([0.1, 0.0, -1.0]), np.zeros(3), np.zeros(3), omega_B=np.zeros(3))
REF = Reference(np.array([0.0, 0.0, -1.0]))


# --------------------------------------------------------------------------- the step clock


def test_the_same_time_twice_is_not_an_advance():
    ctrl = Controller(ControllerParams.paper("pdc"))
    ctrl.step(MEAS, REF, t=1.0)
    before = ctrl._s.copy()
    with pytest.raises(InputError, match="does not come after"):
        ctrl.step(MEAS, REF, t=1.0)
    assert (ctrl._s == before).all()  # the state unchanged


def test_a_loop_faster_than_ts_is_warned_at_its_second_step():
    """'Another rate' is faster as well as slower: 0.4 Ts is warned at once, not after the mean's 20 steps."""
    ctrl = Controller(ControllerParams.paper("pdc"))
    ctrl.step(MEAS, REF, t=0.0)
    with pytest.warns(ControllerWarning, match="stepped 0.004 s after"):
        ctrl.step(MEAS, REF, t=0.004)


def test_reset_starts_the_estimators_clock_again():
    est = Estimator(1.0, [0.01, 0.01, 0.02], 0.01)
    z = np.zeros(3)
    for k in range(5):
        est.step(z, z, 9.81, z, omega_B=z, t=4.0 + 0.01 * k)
    est.reset()  # a new flight: its clock may start at 0 again
    est.step(z, z, 9.81, z, omega_B=z, t=0.0)


# --------------------------------------------------------------------------- outputs


@pytest.mark.skipif(not os.path.exists("/dev/null"), reason="needs /dev/null")
def test_dev_null_is_a_device_not_an_output_file():
    from vtol_impedance.io import check_output_file

    with pytest.raises(InputError, match="is a device"):
        check_output_file("/dev/null")
    assert os.path.exists("/dev/null") and not os.path.isfile("/dev/null")


# --------------------------------------------------------------------------- the log checks


def _roll_log(rate_hz: float, gyro_extra=None, pulse=None) -> float:
    """The kinematic score of a log rolling gently (and, with ``pulse = (t0, n, rad/s)``, flicking by ``n``
    samples of that rate, in the attitude too); ``gyro_extra(t)`` adds to the logged rate only."""
    t = np.arange(0.0, 10.0, 1.0 / rate_hz)
    p = 0.5 * np.cos(1.1 * t)
    if pulse is not None:
        t0, n, amp = pulse
        i = int(round(t0 * rate_hz))
        p[i : i + n] += amp
    phi = np.concatenate([[0.0], np.cumsum(0.5 * (p[1:] + p[:-1]) * np.diff(t))])  # the attitude integrates it
    w = np.stack([p + (gyro_extra(t) if gyro_extra else 0.0), 0 * t, 0 * t], -1)
    raw = RawLog(Signal("velocity", "v", t, np.zeros((len(t), 3))),
                 Signal("attitude", "eta", t, np.stack([phi, 0 * t, 0 * t], -1)), Signal("rates", "w", t, w),
                 Signal("thrust", "u", t, np.full((len(t), 1), 11.8), hold=True), None)  # fmt: skip
    return evidence(raw).kin


def test_a_garbled_gyro_sample_is_a_glitch_and_a_real_flick_is_not():
    """At 250 Hz, one sample of 30 rad/s the attitude never saw is a garbled sample: the score stays the
    clean log's. A flick of three samples at 10 rad/s that the attitude follows is motion: it is kept."""
    clean = _roll_log(250.0)
    glitch = _roll_log(250.0, gyro_extra=lambda t: np.where(np.arange(len(t)) == 1250, 30.0, 0.0))
    assert glitch < clean + 0.05, (clean, glitch)
    assert _roll_log(250.0, pulse=(5.0, 3, 10.0)) < clean + 0.05


def test_an_estimator_slower_than_every_stretch_between_restarts_says_so(tmp_path):
    """A 40 s log cut by a dropout every 5 s restarts the estimator each time: with wn = 0.5 (settling 10 s) it
    never settles, although the log is longer than that."""
    fl = S.flight(duration=40.0, rate=50.0)
    cols = csv_cols(fl)
    keep = ~np.isin(np.floor(cols["t_s"] / 5.0), [])  # every row, then a 2 s hole every 5 s
    keep &= (cols["t_s"] % 5.0) < 3.0
    raw = read_any(write_csv(tmp_path / "holes.csv", {k: v[keep] for k, v in cols.items()}),
                   conventions="unchecked")[0]  # fmt: skip
    f = resample(raw, max_gap_s=1.0)
    assert f.restart.sum() >= 7
    est = estimate(f, S.MASS, None, params=EstimatorParams(wn=0.5))
    assert any("never reaches the force" in w for w in est.warnings), est.warnings


def test_microsecond_time_stamps_are_time_not_a_garbled_cell(tmp_path):
    """The documented ``timestamp_us`` column runs to 2e7 over 20 s: far beyond a signal cell's limit."""
    fl = S.flight(duration=20.0, rate=50.0)
    cols = csv_cols(fl)
    t = cols.pop("t_s")
    raw, _ = read_any(write_csv(tmp_path / "us.csv", {"timestamp_us": np.round(t * 1e6), **cols}))
    assert raw.velocity_W.t[-1] - raw.velocity_W.t[0] == pytest.approx(t[-1] - t[0])


def test_a_rotor_with_both_limits_is_refused(tmp_path):
    from vtol_impedance.model import load_preset

    f = tmp_path / "both.toml"
    f.write_text("mass = 1.0\ninertia_diag = [1e-3, 1e-3, 2e-3]\nthrust_constant = 1e-5\n" + "".join(
        f"[[rotors]]\nposition_B = [{x}, {y}, 0.0]\nspin = {s}\nf_max = 5.0\nmax_speed = 800.0\n"
        for x, y, s in ((0.15, 0.15, 1), (-0.15, -0.15, 1), (0.15, -0.15, -1), (-0.15, 0.15, -1))))  # fmt: skip
    with pytest.raises(InputError, match=r"rotors\[0\]: give f_max or max_speed, not both"):
        load_preset(str(f))


# --------------------------------------------------------------------------- the controller and estimator


@pytest.mark.parametrize("backend", ["compiled", "numpy"])
def test_a_descent_faster_than_the_lift_limit_is_reported_as_limited(backend):
    """Eq. (16) keeps a fifth of g of lift (``min_lift_accel``): a reference falling at 1.5 g asks for less,
    and the output says the limit took it (as it does for the tilt)."""
    ctrl = Controller(ControllerParams.paper("pdc"), backend=backend)
    ref = Reference(np.array([0.0, 0.0, -1.0]), a_W=np.array([0.0, 0.0, 1.5 * 9.81]))
    at_ref = Measurement(np.array([0.0, 0.0, -1.0]), np.zeros(3), np.zeros(3), omega_B=np.zeros(3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ControllerWarning)
        out = ctrl.step(at_ref, ref)  # no horizontal error: the thrust is the lift limit's alone
    assert out.tilt_limited and out.thrust == pytest.approx(1.2 * 0.2 * 9.81, rel=0.05)


@pytest.mark.parametrize("backend", ["compiled", "numpy"])
def test_a_yaw_through_pi_is_the_same_flight_as_a_yaw_past_it(backend):
    """Yaw is an angle: a vehicle tilted by 0.2 rad and yawing at 3 rad/s through +-pi, its yaw logged wrapped,
    is the same flight as with its yaw logged unwrapped (past pi), so the estimates agree. The attitude
    history is interpolated (a velocity latency 1.5 periods longer than the attitude's puts the attitudes the
    force channel compares with between two samples, and the crossing with them): taken
    straight across, the wrap is a 2 pi jump of the delayed attitude, and the tilted thrust axis with it."""
    m = 1.2
    runs = []
    for wrapped in (False, True):
        est = Estimator(m, [0.0135, 0.0137, 0.0247], 0.01, params=EstimatorParams(velocity_delay=0.015),
                        backend=backend)  # fmt: skip
        z = np.zeros(3)
        out = []
        for k in range(200):
            psi = 2.0 + 3.0 * 0.01 * k
            if wrapped:
                psi = (psi + np.pi) % (2 * np.pi) - np.pi
            o = est.step(z, np.array([0.2, 0.0, psi]), m * 9.81, z, eta_dot=np.array([0.0, 0.0, 3.0]))
            out.append(np.concatenate([o.f_hat_W, o.tau_hat_eta]))
        runs.append(np.array(out))
    assert np.max(np.abs(runs[0][:, :3])) > 0.1  # the tilted thrust: a force the yaw turns
    np.testing.assert_allclose(runs[1], runs[0], atol=1e-9)
