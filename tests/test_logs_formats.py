"""Every reader on logs written by the test suite with a known wrench (ArduPilot DataFlash and MAVLink tlog
through pymavlink, PX4 ULog through pyulog), damaged files, missing streams, the defaults taken from the
log (the fastest source of each signal, the hover thrust and the mass from parameters, per-sample hover
thrust, measurement times from timestamp_sample) and the output files, column by column.

Expected values: the continuous G(s) of eq. (10) applied to ``synthflight``'s true wrench, within the
error of what each format does to the signals (velocity interpolation, zero-order hold of the commands,
centidegree attitude)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import synthflight as S
from logfiles import (
    HOVER,
    K_T,
    ROTORS,
    csv_cols,
    synth_tlog_messages,
    write_csv,
    write_synth_dataflash,
    write_synth_tlog,
)
from ulog_writer import write_ulog

from vtol_impedance.cli import main
from vtol_impedance.errors import InputError
from vtol_impedance.logs import estimate, estimate_file, read_any, resample, samples
from vtol_impedance.logs.frames import ROTOR_SPEED_UNITS
from vtol_impedance.logs.timeseries import typical_period
from vtol_impedance.logs.writers import write_tlog
from vtol_impedance.model import load_preset
from vtol_impedance.model.kinematics import quat_from_euler


@pytest.fixture(scope="module")
def fl():
    return S.flight()


def _accel_bound(dt_v: float) -> float:
    """Velocity interpolated linearly between samples dt_v apart: its derivative is off by <= dt_v/2 max|a'|."""
    t = np.linspace(0, 12, 20001)
    jerk = np.gradient(S.accel(t) - S.f_ext_of(t) / S.MASS, t, axis=0)
    return float(S.MASS * dt_v / 2 * np.abs(jerk).max())


def _hold_bound(fl, dt_u: float) -> float:
    """A thrust command held for dt_u: at most max|du/dt| dt_u of thrust error."""
    return float(np.max(np.abs(np.diff(fl.thrust))) / np.diff(fl.t)[0] * dt_u)


STEADY = ((3.0, 4.9), (10.0, 12.0))  # where G has settled on the constant wrench


def _check_force(e, t_true, bound):
    g = S.g_of_true_wrench(t_true)
    sel = np.zeros(len(t_true), bool)
    for a, b in STEADY:
        sel |= (t_true > a) & (t_true < b)
    err = np.abs(e.f_W - g)[sel].max(0)
    assert np.all(err < bound), (err, bound)


# ----------------------------------------------------------------------------- ArduPilot DataFlash


def test_dataflash_written_here_reads_back_through_pymavlink(fl, tmp_path):
    path = write_synth_dataflash(fl, tmp_path / "synth.bin")
    from pymavlink import DFReader

    df = DFReader.DFReader_binary(str(path))  # pymavlink's own reader sees our FMT and scaled fields
    att = df.recv_match(type="ATT")
    assert att.TimeUS == 2_000_000 and att.Roll == pytest.approx(math.degrees(fl.eta[0, 0]), abs=0.006)
    assert df.param("MOT_THST_HOVER") == pytest.approx(HOVER)
    df.close()
    raw, _ = read_any(path)
    assert raw.meta["format"] == "dataflash" and "CTUN.ThH" in raw.hover.source
    f = resample(raw, 100.0)
    bound = _accel_bound(0.04) + _hold_bound(fl, 0.02) + S.MASS * S.G * math.radians(0.01) + 2e-3
    _check_force(estimate(f, S.MASS, None, thrust_from="commands"), f.t - 2.0, bound)
    # the same flight from the ESC rotor speeds with the rotors' coefficient, and the moment through the X
    # geometry (DataFlash logs none: a user gives it with --vehicle)
    geometry = (np.array([[x, y, 0.0] for x, y, _ in ROTORS]), np.array([k for _, _, k in ROTORS]))
    e = estimate(f, S.MASS, S.INERTIA, thrust_from="rotors", thrust_coefficient=K_T, rotor_geometry=geometry)
    assert "ESC.RPM" in e.info["thrust"] and e.info["torque"].startswith("rotor speeds")
    _check_force(e, f.t - 2.0, bound)
    t = f.t - 2.0
    steady = ((t > 3.0) & (t < 4.9)) | ((t > 10.0) & (t < 12.0))
    # G applied to the body moment directly: the attitude stays within 3 deg, so Q^-T G Q^T is G to 1e-3 N m
    np.testing.assert_allclose(e.tau_B[steady], S.g_of_true_wrench(t, "tau")[steady], atol=1e-3)


def test_a_truncated_dataflash_log_is_repaired_and_reported(fl, tmp_path):
    path = write_synth_dataflash(fl, tmp_path / "cut.bin", truncate=11)
    raw, _ = read_any(path)
    assert any("cut short" in n and "dropped" in n for n in raw.notes)
    f = resample(raw)
    assert f.t[-1] - 2.0 > 11.9  # everything before the cut is kept
    (tmp_path / "junk.bin").write_bytes(b"\x00\x01garbage" * 50)
    with pytest.raises(InputError, match="no DataFlash messages|not a readable DataFlash"):
        read_any(tmp_path / "junk.bin")


# ----------------------------------------------------------------------------- MAVLink tlog


def test_tlog_written_here_follows_g_of_the_true_wrench(fl, tmp_path):
    path = write_synth_tlog(fl, tmp_path / "synth.tlog")
    raw, _ = read_any(path)
    assert raw.meta["format"] == "tlog" and raw.hover_thrust == pytest.approx(HOVER)
    assert "ATTITUDE_TARGET" in raw.thrust.source
    f = resample(raw, 100.0)
    bound = _accel_bound(0.04) + _hold_bound(fl, 0.02) + 2e-3
    _check_force(estimate(f, S.MASS, None), f.t - 5.0, bound)


@pytest.mark.parametrize("protocol", [1, 2])
def test_tlog_with_whole_percent_throttle(fl, tmp_path, protocol):
    """ArduPilot streams only VFR_HUD.throttle: whole percent, no time field (placed by receive time); MAVLink
    1 and 2 framing."""
    path = write_synth_tlog(fl, tmp_path / "hud.tlog", thrust_stream="VFR_HUD", protocol=protocol)
    assert path.read_bytes()[8] == (0xFE if protocol == 1 else 0xFD)
    raw, _ = read_any(path)
    assert any("VFR_HUD" in n and "receive time" in n for n in raw.notes)
    f = resample(raw, 100.0)
    quantum = 0.005 * S.MASS * S.G / HOVER  # half a percent of throttle, in newtons
    bound = _accel_bound(0.04) + _hold_bound(fl, 0.02) + quantum + 0.01
    _check_force(estimate(f, S.MASS, None), f.t - 5.0, bound)


def test_a_tlog_received_in_bursts_keeps_its_untimed_thrust_in_place(fl, tmp_path):
    """A link that queues and delivers once a second (a radio that buffers): every message arrives up to 1 s
    late, unevenly. VFR_HUD has no time field; placed by the timed message sent before it, the thrust keeps
    its timing (the same bound as on an even link), and its rate is the stream's, not the burst's."""
    msgs = sorted(synth_tlog_messages(fl, thrust_stream="VFR_HUD"), key=lambda m: m[0])
    t0 = msgs[0][0]
    bursty = [(t0 + math.floor(r - t0) + 1.0 + 1e-6 * k, name, fields) for k, (r, name, fields) in enumerate(msgs)]
    raw, _ = read_any(write_tlog(tmp_path / "bursts.tlog", bursty))
    assert 1.0 / typical_period(raw.thrust.t) == pytest.approx(50.0, rel=0.05)
    f = resample(raw, 100.0)
    assert not [n for n in f.notes if "dropout" in n or "gap in thrust" in n]
    quantum = 0.005 * S.MASS * S.G / HOVER
    bound = _accel_bound(0.04) + _hold_bound(fl, 0.02) + quantum + 0.01
    _check_force(estimate(f, S.MASS, None), f.t - 5.0, bound)


def test_a_truncated_or_damaged_tlog_is_repaired_and_reported(fl, tmp_path):
    path = write_synth_tlog(fl, tmp_path / "cut.tlog", truncate=9)
    raw, _ = read_any(path)
    assert any("cut short" in n for n in raw.notes)
    data = bytearray((tmp_path / "cut.tlog").read_bytes())
    data[5000:5040] = b"\xff" * 40  # damage in the middle: pymavlink skips it, the reader reports it
    (tmp_path / "bad.tlog").write_bytes(bytes(data))
    raw, _ = read_any(tmp_path / "bad.tlog")
    assert any("damaged" in n or "not MAVLink frames" in n for n in raw.notes)
    (tmp_path / "junk.tlog").write_bytes(b"not a tlog" * 3)
    with pytest.raises(InputError, match="no MAVLink frames"):
        read_any(tmp_path / "junk.tlog")


def test_a_tlog_without_the_needed_streams_lists_what_to_request(fl, tmp_path, capsys):
    path = write_synth_tlog(fl, tmp_path / "att_only.tlog", drop=("LOCAL_POSITION_NED", "ATTITUDE_TARGET"))
    with pytest.raises(InputError) as err:
        read_any(path)
    msg = str(err.value)
    assert "velocity needs LOCAL_POSITION_NED or GLOBAL_POSITION_INT" in msg and "thrust needs ATTITUDE_TARGET" in msg
    assert "SR0_POSITION = 10" in msg and "10 Hz or more" in msg and "The tlog has: ATTITUDE 50 Hz" in msg
    rc = main(["estimate", str(path), "--mass", "1.2", "--out", str(tmp_path / "o")])
    err_text = capsys.readouterr().err
    assert rc == 2 and "SR0_POSITION" in err_text and "Traceback" not in err_text


# ----------------------------------------------------------------------------- PX4 ULog: defaults from the log


def test_px4_v19_log_takes_the_fastest_thrust_and_its_hover_parameter():
    raw, _ = read_any(samples.path("px4-v1.9"))
    assert raw.thrust.source.startswith("vehicle_rates_setpoint.thrust_body[2]")
    assert any("actuator_controls_0.control[3] 9.09 Hz" in c for c in raw.choices)
    assert raw.hover_thrust == pytest.approx(0.515) and "MPC_THR_HOVER" in raw.hover_source


def test_mass_and_inertia_from_the_log_and_every_choice_kept(tmp_path):
    e = estimate_file(samples.path("px4"))  # no mass given: SIH_MASS
    assert e.info["mass_kg"] == pytest.approx(samples.MASS_KG)
    assert np.allclose(np.diag(e.info["inertia_kg_m2"]), [3.4e-3, 3.4e-3, 4.7e-3])
    assert any("SIH_*" in c for c in e.info["choices"]) and e.tau_B is not None
    with pytest.raises(InputError, match="needs the vehicle's nominal mass.*--mass"):
        estimate_file(samples.path("px4-v1.9"))
    out = tmp_path / "o"
    assert main(["estimate", "--example", "px4", "--out", str(out), "--no-plots", "--quiet"]) == 0
    summary = json.loads((out / "estimate.json").read_text())
    assert any(c.startswith("mass: 1.2 kg, the SIH_*") for c in summary["info"]["choices"])
    assert "What was chosen from the log" in (out / "report.html").read_text()


def test_measurement_times_come_from_timestamp_sample(fl, tmp_path):
    """The velocity is published 40 ms after it was measured: with timestamp_sample logged, the estimate is
    as if there were no latency; read from the publication times, a rolling vehicle seems pushed sideways."""
    us = (fl.t * 1e6).astype(np.uint64) + np.uint64(1_000_000)
    late = us + np.uint64(40_000)
    u = fl.thrust * HOVER / (S.MASS * S.G)

    def topics(with_sample: bool):
        vel = {"timestamp": late[::10], "vx": fl.v_W[::10, 0], "vy": fl.v_W[::10, 1], "vz": fl.v_W[::10, 2]}
        if with_sample:
            vel = {
                "timestamp": late[::10],
                "timestamp_sample": us[::10],
                **{k: v for k, v in vel.items() if k != "timestamp"},
            }
        return {
            "vehicle_local_position": vel,
            "vehicle_attitude": {"timestamp": us, "q": quat_from_euler(fl.eta)},
            "vehicle_angular_velocity": {"timestamp": us, "xyz": fl.omega_B},
            "vehicle_thrust_setpoint": {"timestamp": us, "xyz": np.stack([0 * u, 0 * u, -u], -1)},
        }

    errs = []
    for with_sample in (True, False):
        path = write_ulog(tmp_path / f"s{with_sample}.ulg", topics(with_sample), {"MPC_THR_HOVER": HOVER})
        raw, _ = read_any(path)
        assert ("measurement_times" in raw.meta) == with_sample
        f = resample(raw, 100.0)
        e = estimate(f, S.MASS, None)
        t = f.t - 1.0
        sel = t > 1.0
        errs.append(float(np.abs(e.f_W - S.g_of_true_wrench(t))[sel].max()))
    assert errs[0] < _accel_bound(0.04) + _hold_bound(fl, 0.01) + 2e-3 < errs[1]


# ----------------------------------------------------------------------------- per sample, full precision


def test_per_sample_hover_thrust_is_used_per_sample(fl, tmp_path):
    """A hover thrust that drifts 6 % (battery sag): per sample the estimate is exact, the median would be
    0.1-0.3 N off at the ends."""
    h = HOVER * (1.0 + 0.06 * fl.t / fl.t[-1])
    cols = {k: v for k, v in csv_cols(fl).items() if k != "thrust_n"}
    cols.update(thrust_norm=fl.thrust * h / (S.MASS * S.G), hover_thrust=h)
    raw, _ = read_any(write_csv(tmp_path / "sag.csv", cols))
    f = resample(raw, 100.0)
    e = estimate(f, S.MASS, None)
    np.testing.assert_allclose(e.hover, np.interp(f.t, fl.t, h), rtol=1e-9)
    _check_force(e, f.t, _hold_bound(fl, 0.01) + 2e-3)
    collapsed = estimate(f, S.MASS, None, hover_thrust=float(np.median(h)))
    g = S.g_of_true_wrench(f.t)
    assert np.abs(collapsed.f_W - g)[f.t > 11].max() > 0.1  # what the median would have cost


def test_every_output_column_round_trips(tmp_path):
    """wrench.csv, wrench.parquet and the estimate in memory hold the same numbers in every column; the time
    of a log on a unix clock (the csv sample, 1.77e9 s) is exact to the last bit."""
    import pyarrow.parquet as pq

    out = tmp_path / "o"
    rc = main(["estimate", "--example", "csv", "--mass", "1.2", "--vehicle", "pelican", "--zero-phase", "--out",
               str(out), "--no-plots", "--quiet", "--thrust-from", "commands"])  # fmt: skip
    assert rc == 0
    est = estimate_file(samples.path("csv"), vehicle=load_preset("pelican"), mass=1.2, zero_phase_too=True,
                        thrust_from="commands")  # fmt: skip
    cols = est.columns()
    table = pq.read_table(out / "wrench.parquet")
    header = (out / "wrench.csv").read_text().splitlines()[0].split(",")
    assert header == list(cols) == table.column_names
    assert {"t_s", "restart", "bridged", "hover_thrust", "thrust_N", "fx_W_N", "taux_B_Nm", "fx_W_N_zp"} <= set(header)
    data = np.genfromtxt(out / "wrench.csv", delimiter=",", skip_header=1)
    assert data[0, 0] > 1.7e9
    for j, name in enumerate(header):
        mem = np.asarray(cols[name], dtype=float)
        np.testing.assert_array_equal(table[name].to_numpy(), mem)
        if name in ("t_s", "segment", "restart", "bridged"):
            np.testing.assert_array_equal(data[:, j], mem)  # exact
        else:
            np.testing.assert_allclose(data[:, j], mem, rtol=1e-11, atol=1e-12 * np.max(np.abs(mem)))
    assert np.all(np.diff(data[:, 0]) > 0.0099)  # a unix clock keeps its 10 ms steps
    summary = json.loads((out / "estimate.json").read_text())
    assert summary["info"]["hover_thrust"]["min"] < summary["info"]["hover_thrust"]["max"]


def test_rotor_speed_units_are_checked(fl, tmp_path):
    """An rpm column that holds rad/s is refused with the flag; a coefficient given for rad/s then works."""
    from logfiles import rotor_speeds

    cols = {k: v for k, v in csv_cols(fl, every=2).items() if k != "thrust_n"}
    w = rotor_speeds(fl.thrust[::2], fl.tau_B[::2])  # rad/s
    cols.update({f"rpm{i + 1}": w[:, i] for i in range(4)})
    path = write_csv(tmp_path / "rads.csv", cols)
    raw, _ = read_any(path)
    with pytest.raises(InputError, match=r"hover at .* rpm.*--rotor-speed-unit rad/s"):
        estimate(resample(raw), S.MASS, None, thrust_coefficient=K_T)
    raw, _ = read_any(path, rotor_speed_unit="rad/s")
    f = resample(raw)
    e = estimate(f, S.MASS, None, thrust_coefficient=K_T)
    _check_force(e, f.t, _hold_bound(fl, 0.01) + 2e-3)
    rpm = {**cols, **{f"rpm{i + 1}": w[:, i] / ROTOR_SPEED_UNITS["rpm"] * 12 for i in range(4)}}  # eRPM, 12 pole pairs
    raw, _ = read_any(write_csv(tmp_path / "erpm.csv", rpm))
    with pytest.raises(InputError, match="above 48000 rpm.*electrical rpm"):
        estimate(resample(raw), S.MASS, None)


def test_a_tlog_across_a_reboot_keeps_the_longest_boot(fl, tmp_path):
    """The vehicle's clock starts again mid-tlog: sorted by it, two boots would interleave; the longest one
    is kept (and said)."""
    from logfiles import synth_tlog_messages

    from vtol_impedance.logs.writers import write_tlog

    first = [m for m in synth_tlog_messages(fl) if m[0] < 1.7e9 + 5.0 + 3.0]  # 3 s before the reboot
    second = [(t + 60.0, name, fields) for t, name, fields in synth_tlog_messages(fl)]  # the same clock again
    raw, _ = read_any(write_tlog(tmp_path / "reboot.tlog", first + second))
    assert any("rebooted 1 time(s)" in n for n in raw.notes)
    f = resample(raw, 100.0)
    assert f.t[-1] - f.t[0] > 11.5 and f.restart.sum() == 1
    bound = _accel_bound(0.04) + _hold_bound(fl, 0.02) + 2e-3
    _check_force(estimate(f, S.MASS, None), f.t - 5.0, bound)


def test_a_foreign_file_named_bin_gives_one_line_not_a_flood(tmp_path, capfd):
    """pymavlink's compiled indexer prints a line per unreadable byte at the descriptor level (177,000 for
    a ULog named .bin): the user sees the one-line error only."""
    from vtol_impedance.logs.samples import path as sample_path

    f = tmp_path / "x.bin"
    f.write_bytes(sample_path("px4").read_bytes())
    assert main(["estimate", str(f), "--out", str(tmp_path / "o")]) == 2
    out, err = capfd.readouterr()
    assert out == "" and len(err.splitlines()) <= 3 and "no DataFlash messages" in err


def test_a_csv_column_is_read_for_one_role_from_one_place(tmp_path):
    """A header naming a used column twice, or one column mapped to two roles, is refused naming it (the
    first was read quietly: a second vz of zeros, or vx read from the vy column)."""
    from vtol_impedance.logs import read_any

    fl = S.flight()
    good = write_csv(tmp_path / "good.csv", csv_cols(fl))
    lines = good.read_text().splitlines()
    twice = tmp_path / "twice.csv"
    twice.write_text("\n".join([lines[0] + ",vz"] + [row + ",0" for row in lines[1:]]) + "\n")
    with pytest.raises(InputError, match="column 'vz' appears 2 times in the header"):
        read_any(twice)
    with pytest.raises(InputError, match=r"column 'vy' is mapped to more than one role \(vx, vy\)"):
        read_any(good, columns={"vx": "vy"})
    read_any(good, columns={"vx": "vx"})  # a mapping to its own column is no conflict


@pytest.mark.parametrize("cut", [1, 5, 10])
def test_a_tlog_cut_inside_a_frame_of_a_new_kind_is_read_up_to_the_cut(tmp_path, cut):
    """A recording stopped by a power loss ends inside a frame. When that frame was the first of its kind (a
    STATUSTEXT at disarming), pymavlink's index of the file failed and the whole log was refused as "not a
    readable tlog". It is read without the cut frame, as the same log ending on a whole frame is."""
    import struct

    from pymavlink.dialects.v20 import ardupilotmega as mav

    src = samples.path("tlog").read_bytes()
    ofs, last_t = 0, 0
    while ofs + 10 <= len(src):  # the receive time of the last frame
        last_t, marker, length = struct.unpack(">Q", src[ofs : ofs + 8])[0], src[ofs + 8], src[ofs + 9]
        ofs += 8 + length + ((12 + (13 if src[ofs + 10] & 1 else 0)) if marker == 0xFD else 8)
    pkt = mav.MAVLink_statustext_message(6, b"Disarming motors").pack(mav.MAVLink(None, srcSystem=1, srcComponent=1))
    full = src + struct.pack(">Q", last_t + 100_000) + pkt
    (tmp_path / "full.tlog").write_bytes(full)
    (tmp_path / "cut.tlog").write_bytes(full[: len(full) - cut])
    whole = estimate_file(tmp_path / "full.tlog", 1.2)
    got = estimate_file(tmp_path / "cut.tlog", 1.2)
    assert any("cut short" in n for n in got.notes)
    np.testing.assert_allclose(got.f_W, whole.f_W)


def test_a_ulog_with_a_lost_block_is_read_around_it(tmp_path):
    """A 4 kB block of an SD card lost (zeros) in the middle of a ULog: pyulog resynchronises and leaves a
    garbled sample whose time stamp jumps back to 0 s, and the whole log was refused as "time goes backwards
    ... several logs were joined". The out-of-order sample is dropped with a note; the estimate matches the
    undamaged log's away from the block."""
    from vtol_impedance.logs.ulog import _in_order

    data = bytearray(samples.path("px4").read_bytes())
    mid = len(data) // 2
    data[mid : mid + 4096] = bytes(4096)
    (tmp_path / "lost.ulg").write_bytes(bytes(data))
    got = estimate_file(tmp_path / "lost.ulg")
    assert any("out of time order in the damaged data dropped" in n for n in got.notes)
    whole = estimate_file(samples.path("px4"))
    assert abs(float(np.mean(got.f_W[:, 2])) - float(np.mean(whole.f_W[:, 2]))) < 0.05
    # the rule itself: a lone sample out of order goes, a jump back that stays (joined logs) does not
    np.testing.assert_array_equal(_in_order(np.array([1.0, 2.0, 0.0, 4.0, 5.0])), [1, 1, 0, 1, 1])
    np.testing.assert_array_equal(_in_order(np.array([1.0, 2.0, 9e9, 4.0, 5.0])), [1, 1, 0, 1, 1])
    assert _in_order(np.array([5.0, 6.0, 7.0, 1.0, 2.0, 3.0])).all()
