"""The interaction scenarios' measures (``analysis.measures``, what ``run`` leads its table with), each
on a result built by hand whose answer is known: a response of a known impedance integrated by SciPy,
a wall held with a known force, a pendulum sagging by a known amount."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from vtol_impedance.analysis.measures import pendulum_measures, purpose_tables, push_measures, wall_measures
from vtol_impedance.sim import Result

DT = 0.01


def _result(t: np.ndarray, labels: list[str], scenario: dict, window: list[float], flown: list | None = None,
            **signals: np.ndarray) -> Result:  # fmt: skip
    """A result with zero traces except ``signals`` (``(B, N, 3)`` each); ``flown``: the disturbances as
    flown (``config["disturbances"]``, every field filled in), if given."""
    B, N = len(labels), len(t)
    data = {k: np.zeros((B, N, 3)) for k in ("p_W", "v_W", "p_ref_W", "v_ref_W", "f_ext_W", "f_hat_W", "f_lumped_W",
                                             "eta", "omega_B", "tau_lumped_eta")}  # fmt: skip
    data["psi_ref"] = np.zeros((B, N))
    data.update(signals)
    config = {"scenario": scenario, "window": window}
    if flown is not None:
        config["disturbances"] = flown
    return Result(t, labels, data, config, [None] * B)


def test_a_push_gives_back_the_impedance_that_answered_it():
    """``M e'' + D e' + K e = f`` (M = 2 kg, D = 6 N s/m, K = 5 N/m, the comply defaults) under a 1 s
    half-sine push of 4 N along +y, integrated by SciPy: the fit returns M, D, K; the peak and what is left
    2 s after the push are read off the same curve."""
    t = np.arange(0.0, 12.0, DT)
    t_on, duration = 2.0, 1.0
    s = (t - t_on) / duration
    f = np.where((s >= 0) & (s <= 1), 4.0 * np.sin(np.pi * np.clip(s, 0, 1)), 0.0)
    M, D, K = 2.0, 6.0, 5.0
    _, e, x = scipy.signal.lsim(scipy.signal.StateSpace([[0, 1], [-K / M, -D / M]], [[0], [1 / M]], [[1, 0]], 0), f, t)
    y = np.zeros((1, len(t), 3))
    p, v, fl = y.copy(), y.copy(), y.copy()
    p[0, :, 1], v[0, :, 1], fl[0, :, 1] = e, x[:, 1], f
    scenario = {"disturbances": [{"kind": "push", "force_W": [0.0, 8.0, 0.0], "t_on": t_on, "duration": duration}]}
    r = _result(t, ["comply"], scenario, [0.0, 12.0], p_W=p, v_W=v, f_lumped_W=fl)
    head, rows = push_measures(r)
    assert head[3:] == ["M [kg]", "D [N s/m]", "K [N/m]"]
    (row,) = rows
    during = (t >= t_on) & (t <= t_on + duration + 2.0)
    after = (t >= t_on + duration + 2.0) & (t <= t_on + duration + 2.5)
    assert float(row[1]) == pytest.approx(100 * np.abs(e[during]).max(), abs=0.01)
    assert float(row[2]) == pytest.approx(100 * np.abs(e[after]).mean(), abs=0.01)
    assert [float(v) for v in row[3:]] == pytest.approx([M, D, K], rel=0.03)


def test_the_measures_read_the_disturbances_as_flown_with_their_defaults():
    """A scenario file may leave out a push's ``t_on`` (5 s by default): the push is measured where it was
    flown (from ``config["disturbances"]``), not refused for a missing key; a twist that falls after a
    shortened flight leaves the twist table out instead of failing on an empty selection."""
    from vtol_impedance.analysis.measures import twist_measures
    from vtol_impedance.sim.disturbances import Push

    t = np.arange(0.0, 10.0, DT)
    p = np.zeros((1, len(t), 3))
    p[0, :, 0] = np.where((t >= 5.0) & (t <= 6.0), 0.03, 0.0)  # 3 cm along the push while it acts
    raw = [{"kind": "push", "force_W": [2.0, 0.0, 0.0]}]
    flown = [Push(force_W=(2.0, 0.0, 0.0)).to_dict()]
    assert flown[0]["t_on"] == 5.0
    _, (row,) = push_measures(_result(t, ["PD+C"], {"disturbances": raw}, [0.0, 10.0], flown, p_W=p))
    assert float(row[1]) == pytest.approx(3.0)
    twist = [Push(force_W=(0.0, 0.0, 0.0), torque_B=(0.0, 0.0, 0.5), t_on=4.0).to_dict()]
    short = np.arange(0.0, 2.0, DT)
    assert twist_measures(_result(short, ["comply"], {"disturbances": twist}, [0.0, 2.0], twist)) is None
    assert twist_measures(_result(t, ["PD+C"], {"disturbances": twist}, [0.0, 10.0], twist)) is not None


def test_a_wall_held_with_a_known_force():
    """A wall whose face sits 0.5 m along +x (its point at 0.8 m, a 0.3 m contact radius), a reference
    0.8 m into it, comply's K = 5 N/m: commanded 5 (0.8 - 0.5) = 1.5 N; the wall pushing back 1.4 N over
    the last 4 s is held at 1.400 N, 6.7 % short, estimated at 1.35 N; contact never lost."""
    t = np.arange(0.0, 10.0, DT)
    p = np.zeros((1, len(t), 3))
    p[0, :, 0] = np.where(t > 1.0, 0.52, 0.0)  # touching from 1 s on
    f_ext = np.zeros((1, len(t), 3))
    f_ext[0, :, 0] = -1.4
    f_hat = f_ext.copy()
    f_hat[0, :, 0] = -1.35
    wall = {"kind": "wall", "position_W": [0.8, 0.0, -1.0], "normal_W": [-1.0, 0.0, 0.0], "radius": 0.3}
    scenario = {"disturbances": [wall], "trajectory": {"move_offset": [0.8, 0.0, 0.0]}, "interaction": {"K": 5.0}}
    r = _result(t, ["comply"], scenario, [0.0, 10.0], p_W=p, f_ext_W=f_ext, f_hat_W=f_hat)
    _, (row,) = wall_measures(r)
    assert row == ["comply", "1.400", "1.500", "-6.7", "1.350", "no"]
    p[0, t > 6.0, 0] = 0.3  # it bounces off and stays off
    _, (row,) = wall_measures(_result(t, ["comply"], scenario, [0.0, 10.0], p_W=p, f_ext_W=f_ext, f_hat_W=f_hat))
    assert row[-1] == "yes"


def test_a_pendulum_sag_and_the_estimate_of_its_pull():
    """2 cm below the reference (NED: +z) in the window is a 2.00 cm sag, against (0.1 + 0.2) g / 16;
    the estimate 0.1 N off the link's pull along x at most, 0.05 RMS."""
    t = np.arange(0.0, 6.0, DT)
    p = np.zeros((1, len(t), 3))
    p[0, :, 2] = 0.02
    f_ext = np.zeros((1, len(t), 3))
    f_hat = np.zeros((1, len(t), 3))
    f_hat[0, :, 0] = np.where(np.arange(len(t)) % 2 == 0, 0.1, 0.0)  # |d| alternates 0.1, 0: RMS 0.0707
    scenario = {"plant": {"pendulum_mass": 0.2}, "payload": {"mass": 0.1}, "control": {"Kp": 16.0}}
    r = _result(t, ["pd"], scenario, [1.0, 5.0], p_W=p, f_ext_W=f_ext, f_hat_W=f_hat)
    _, (row,) = pendulum_measures(r)
    assert row[:4] == ["pd", "2.00", f"{100 * 0.3 * 9.81 / 16:.2f}", "2.00"]
    assert row[4] == "0.100 / 0.071"
    assert [title for title, _, _ in purpose_tables(r)] == ["Pendulum"]


def test_the_table_metrics_in_their_displayed_units():
    """Constant errors in a hand-built result: a 3-4-0 cm position error is 5 cm RMS and max, 0.1 m/s of
    velocity error is 10 cm/s, 0.002 N m of moment-estimate error is 2 mN m, 0.5 N of force-estimate error
    is 0.5 N, saturated a quarter of the window is 25 %; an error of 1 m over the first 3 s of the window's
    last 5 s (the documented steady tail) is a 60 cm steady error."""
    from vtol_impedance.analysis import compute_metrics

    t = np.arange(0.0, 20.0, DT)
    n = len(t)
    p = np.zeros((1, n, 3))
    p[0, :, :2] = [0.03, 0.04]
    v = np.zeros((1, n, 3))
    v[0, :, 2] = 0.1
    f_hat = np.zeros((1, n, 3))
    f_hat[0, :, 1] = 0.5
    tau_hat = np.zeros((1, n, 3))
    tau_hat[0, :, 0] = 0.002
    sat = np.zeros((1, n))
    sat[0, t >= 15.0] = 1.0  # the last quarter of the window [0, 20)
    r = _result(t, ["pd"], {}, [0.0, 20.0], p_W=p, v_W=v, f_hat_W=f_hat)
    r.data.update(tau_hat_eta=tau_hat, tau_lumped_eta=np.zeros((1, n, 3)), saturated=sat)
    (row,) = compute_metrics(r)
    assert row["rms_ep_cm"] == pytest.approx(5.0) and row["max_ep_cm"] == pytest.approx(5.0)
    assert row["rms_ev_cms"] == pytest.approx(10.0)
    assert row["rms_tau_err_mNm"] == pytest.approx(2.0) and row["rms_f_err_N"] == pytest.approx(0.5)
    assert row["sat_pct"] == pytest.approx(25.0, abs=0.1)
    p[0] = 0.0
    p[0, (t > 15.0 - DT / 2) & (t < 18.0 - DT / 2), 0] = 1.0  # 3 s of the 5 s tail
    r.data["p_W"] = p
    (row,) = compute_metrics(r)
    assert row["ss_ep_cm"] == pytest.approx(60.0, abs=0.5)
    # a sine of 4 cm (whole periods): RMS 4 / sqrt(2) cm, not its mean magnitude 8 / pi cm
    p[0] = 0.0
    p[0, :, 0] = 0.04 * np.sin(2 * np.pi * 0.5 * t)
    r.data["p_W"] = p
    (row,) = compute_metrics(r)
    assert row["rms_ep_cm"] == pytest.approx(4.0 / np.sqrt(2.0), rel=1e-3)
