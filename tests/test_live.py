"""Live over MAVLink: the estimator and the outer loop against the simulated autopilot over UDP loopback.

Each test checks against an independent truth: the wrench the simulated autopilot injects, the step response
of G(s) (eq. (10)), the impedance's static deflection F / K, the watchdog's stated time, the recorded file.
The simulated autopilot runs in a thread (estimation tests) or as a ``vtol-impedance sim-autopilot``
process (the control tests and the two-terminal walk-through, where the timing must not share a GIL).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import vtol_impedance
from vtol_impedance.errors import InputError
from vtol_impedance.live import ControlSettings, LiveError, LiveSettings, parse_address, replay, run_live
from vtol_impedance.live.autopilot import BOOT_S, Impairments, SimAutopilot, SimSettings
from vtol_impedance.live.display import Screen, View, render
from vtol_impedance.live.estimator import RING, LiveEstimator
from vtol_impedance.live.link import mavutil
from vtol_impedance.live.session import LINK_LOST_S
from vtol_impedance.live.streams import ThrustMap
from vtol_impedance.model.vehicle import load_preset
from vtol_impedance.scenarios import apply_overrides, get, set_value

SRC = str(Path(vtol_impedance.__file__).resolve().parents[1])
ENV = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get("PYTHONPATH", ""))
RATE = 50.0  # estimator and stream rate (the defaults)
WN = 10.0  # estimator bandwidth (the default, the paper's)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def quiet_spec(*sets: str):
    """Case A without the payload and the drag (so the lumped wrench is only what is injected), ideal plant."""
    spec = apply_overrides(get("case-a-payload"), ["payload.mass=0", "plant.rotor_drag=0", *sets])
    return set_value(spec, "ideal", True)


@contextlib.contextmanager
def sim_thread(spec, **kw):
    sim = SimAutopilot(spec, SimSettings(**kw))
    ready = threading.Event()
    th = threading.Thread(target=sim.run, kwargs={"ready": ready}, daemon=True)
    th.start()
    ready.wait(5)
    try:
        yield sim
    finally:
        sim.stop()
        th.join(5)
        assert not th.is_alive(), "the simulated autopilot did not stop"


@contextlib.contextmanager
def sim_process(scenario: str, port: int, *args: str):
    cmd = [sys.executable, "-m", "vtol_impedance", "sim-autopilot", scenario, "--connect", f"udpout:127.0.0.1:{port}",
           "--quiet", *args]  # fmt: skip
    p = subprocess.Popen(cmd, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        yield p
    finally:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.fixture(scope="module", autouse=True)
def warm():
    """Load the compiled estimator and the controller design once (the first run may compile)."""
    from vtol_impedance.live.session import Session

    Session(LiveSettings("udpin:127.0.0.1:1", display="none", control=ControlSettings()))


def step_response(t: np.ndarray, wn: float) -> np.ndarray:
    """Unit step response of eq. (10) with zeta = 1: ``1 - (1 + wn t) exp(-wn t)`` (0 before the step)."""
    tau = np.maximum(t, 0.0)
    return np.where(t > 0, 1.0 - (1.0 + wn * tau) * np.exp(-wn * tau), 0.0)


def read_csv(path: Path) -> dict[str, np.ndarray]:
    d = np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding=None)
    return {k: np.asarray(d[k]) for k in d.dtype.names}


@pytest.fixture
def watched(monkeypatch):
    """The sessions ``run_live`` opens, as they run (a test waits on what a session has done, not on the wall
    clock: on a loaded machine the set-up alone once took longer than a whole 6.5 s run)."""
    from vtol_impedance.live.session import Session

    sessions: list = []
    opened = Session.open

    def open_(self) -> None:
        sessions.append(self)
        opened(self)

    monkeypatch.setattr(Session, "open", open_)
    return sessions


def wait_for(cond, timeout: float, what: str, state=lambda: "") -> None:
    """Poll ``cond()`` until it is true; fail naming ``what`` (and ``state()``) after ``timeout`` wall seconds."""
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"{what}: not within {timeout:g} s {state()}"
        time.sleep(0.05)


def run_live_in_thread(settings: LiveSettings) -> tuple[threading.Thread, threading.Event, dict]:
    """``run_live(settings)`` in a thread with a ``stop`` event; the result (or the error) lands in the dict."""
    stop, out = threading.Event(), {}

    def go() -> None:
        try:
            out["res"] = run_live(settings, stop=stop)
        except BaseException as exc:  # the test thread reports it
            out["error"] = exc

    th = threading.Thread(target=go)
    th.start()
    return th, stop, out


# --------------------------------------------------------------------------- bad input, fast


@pytest.mark.parametrize(
    "address, words",
    [
        ("", "needs an address"),
        ("udpin:localhost", "HOST:PORT"),
        ("udpin:127.0.0.1:70000", "not in 1..65535"),
        ("bogus://x", "does not parse"),
        ("/dev/ttyNOPE42", "does not exist"),
        ("COM3,fast", "not a whole number"),
    ],
)
def test_addresses_that_do_not_parse_are_named(address, words):
    with pytest.raises(LiveError, match=words) as exc:
        parse_address(address)
    assert "udpin" in str(exc.value) or words in str(exc.value)
    assert parse_address("udp:127.0.0.1:14550").kind == "udpin"  # pymavlink's legacy spelling listens


def test_an_address_that_does_not_answer_times_out_with_a_message(tmp_path):
    out = tmp_path / "run"
    t0 = time.monotonic()
    with pytest.raises(LiveError, match="no heartbeat from a vehicle .* within 0.5 s"):
        run_live(LiveSettings(f"udpin:127.0.0.1:{free_port()}", connect_timeout_s=0.5, out=str(out), display="none"))
    assert time.monotonic() - t0 < 3.0
    assert not out.exists(), "a failed connection must not leave a run folder"
    from vtol_impedance.cli import main

    port = free_port()
    code = main(["live", "--connect", f"udpin:127.0.0.1:{port}", "--connect-timeout", "0.3", "--out", str(out)])
    assert code == 2


def test_cli_bad_input_is_a_message_not_a_traceback(tmp_path):
    r = subprocess.run([sys.executable, "-m", "vtol_impedance", "live", "--connect", "udpin:nohost"], env=ENV,
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 2 and "error:" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "vtol_impedance", "sim-autopilot", "case-b-fan", "--connect",
                        "udpout:127.0.0.1:9", "--event", "3,explode,now"], env=ENV, capture_output=True, text=True,
                       timeout=60)  # fmt: skip
    assert r.returncode == 2 and "mode|stop|clock" in r.stderr and "Traceback" not in r.stderr


def test_control_options_without_control_are_refused_not_ignored(capsys):
    from vtol_impedance.cli import main

    assert main(["live", "--connect", "udpin:127.0.0.1:9", "--kp", "5", "--comply", "1,1,0"]) == 2
    assert "--comply, --kp apply with --control only" in capsys.readouterr().err


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"inject_force_W": (1e9, 0.0, 0.0)}, "inject force"),
        ({"inject_force_W": (float("nan"), 0.0, 0.0)}, "inject force"),
        ({"inject_torque_B": (0.0, 0.0, 1e5)}, "inject torque"),
        ({"inject_on": 5.0, "inject_off": 1.0}, "must end after it starts"),
        ({"inject_on": -1.0}, "inject on"),
        ({"events": ((0.1, "clock", "nan"),)}, "clock jump"),
        ({"events": ((0.1, "clock", "abc"),)}, "clock jump"),
        ({"events": ((0.1, "stop", "BOGUS"),)}, "not a message this autopilot sends"),
        ({"impairments": {"seed": -1}}, "seed"),
        ({"seed": -1}, "seed"),
        ({"control_rate": 333.0, "plant_rate": 100.0}, r"plant rate \(100 Hz\) must be a whole multiple"),
        ({"control_rate": 50.0, "plant_rate": 120.0}, "whole multiple of the control rate"),
    ],
)
def test_simulated_autopilot_settings_are_checked_before_it_flies(kw, message):
    with pytest.raises(InputError, match=message):
        if "impairments" in kw:
            kw = dict(kw, impairments=Impairments(**kw["impairments"]))
        SimSettings("udpout:127.0.0.1:9", **kw)


def test_an_open_ended_simulated_autopilot_bounds_its_disturbance_series():
    """Without a duration the turbulence is drawn for a horizon whose series fit SERIES_BUDGET_BYTES
    (an hour at 10 kHz took gigabytes); with one, for the whole flight."""
    from vtol_impedance.live.autopilot import OPEN_HORIZON_MAX_S, SERIES_BUDGET_BYTES
    from vtol_impedance.scenarios import get

    spec = get("case-b-fan")
    kw = {"control_rate": 100.0, "plant_rate": 10000.0}
    sim = SimAutopilot(spec, SimSettings("udpout:127.0.0.1:9", **kw))
    n = sum(d.encode()[2].size for d in sim.dist.items if d.encode()[2] is not None)
    assert 0 < 8 * n * 4 <= SERIES_BUDGET_BYTES * 1.1 and sim.series_end_s < 600.0  # + the 5 s margin
    assert SimAutopilot.open_horizon(0.01) == OPEN_HORIZON_MAX_S  # at 100 Hz: the hour
    sized = SimAutopilot(spec, SimSettings("udpout:127.0.0.1:9", duration=12.0, **kw))
    assert sized.series_end_s == pytest.approx(17.0)


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"hover_thrust": float("nan")}, "hover-thrust"),
        ({"hover_thrust": 1.0}, "below 1"),
        ({"max_thrust": -1.0}, "max-thrust"),
        ({"rotor_constant": 0.0}, "rotor-constant"),
        ({"mass": 1e30}, "mass"),
        ({"inertia": (1.0, 1.0, 100.0)}, "triangle inequality"),
        ({"control": {"variant": "comply", "impedance": (0.0, 0.0, 0.0)}}, "impedance"),
        ({"control": {"variant": "pdc", "Kp": 0.0}}, "Kp"),
    ],
)
def test_live_values_are_checked_before_the_link(kw, message):
    """Each of these once passed the up-front checks and ended the session only after it connected."""
    with pytest.raises(InputError, match=message):
        if "control" in kw:
            kw = dict(kw, control=ControlSettings(**kw["control"]))
        LiveSettings("udpin:127.0.0.1:9", **kw)


def test_a_simulated_vehicle_that_diverges_stops_the_run_with_its_reason():
    """A force the rotors cannot hold (1 kN) throws the vehicle away: the run stops at the failure and says
    why, instead of streaming a non-finite state."""
    sim = SimAutopilot(quiet_spec(), SimSettings(f"udpout:127.0.0.1:{free_port()}", speed=100.0, duration=30.0,
                                                 inject_force_W=(1e3, 0.0, 0.0), inject_on=0.5))  # fmt: skip
    s = sim.run()
    assert s["failure"] is not None and s["simulated_s"] < 30.0
    assert "m from the origin" in s["failure"]["reason"] or "tilt" in s["failure"]["reason"]
    assert np.all(np.isfinite(sim.history[-1][1]))


# --------------------------------------------------------------------------- the estimate


@pytest.fixture(scope="module")
def estimated(tmp_path_factory):
    """One session against an autopilot that injects a known wrench at a known time."""
    F_W = np.array([0.8, -0.5, 0.0])
    tau_B = np.array([0.0, 0.0, 0.02])
    t_on = 5.0  # simulated s
    latency = 0.03  # s, each way
    out = tmp_path_factory.mktemp("live") / "run"
    port = free_port()
    with sim_thread(
        quiet_spec(),
        connect=f"udpout:127.0.0.1:{port}",
        inject_force_W=tuple(F_W),
        inject_torque_B=tuple(tau_B),
        inject_on=t_on,
        impairments=Impairments(latency_s=latency),
    ) as sim:
        res = run_live(LiveSettings(f"udpin:127.0.0.1:{port}", duration=8.5, out=str(out), display="none"))
        sim_summary = sim.summary()
    return {"res": res, "F_W": F_W, "tau_B": tau_B, "t_on": t_on + BOOT_S, "latency": latency, "out": res.folder,
            "sim": sim_summary}  # fmt: skip


def test_injected_wrench_is_recovered_within_the_bound_of_G_and_the_sampling(estimated):
    """Bound: the estimate of a step F injected at t_on lies between F s(t - t_on - d) and F s(t - t_on), s the
    step response of eq. (10) (zeta = 1, wn = 10 rad/s), d the longest sampling delay: one period of the
    telemetry, one of the estimator tick and one of the autopilot's control (its held commands and its
    disturbance step), plus an allowance of 5 % of F (the held commands within a period) and the noise floor.
    The link's latency delays when the estimate is shown, not what it is on the vehicle's clock."""
    e = read_csv(estimated["out"] / "estimate.csv")
    t = e["t_s"]
    t_on = estimated["t_on"]
    assert t[0] < t_on - 1.0, "the estimate must be running before the wrench is injected"
    d = 1.0 / RATE + 1.0 / RATE + 1.0 / 50.0
    # the outputs arrive as whole microseconds of PWM over 1000 us: each rotor force is rounded by up to
    # f_max / 2000, so the thrust by n f_max / 2000 and the moment by the mixer's rows times that
    veh = load_preset("pelican")
    half_step = veh.geometry.f_max / 2000.0
    q_force = np.full(3, half_step.sum())
    q_moment = np.abs(veh.geometry.E[1:4]) @ half_step
    for cols, truth, q in ((("fx_W_N", "fy_W_N", "fz_W_N"), estimated["F_W"], q_force),
                           (("taux_B_Nm", "tauy_B_Nm", "tauz_B_Nm"), estimated["tau_B"], q_moment)):  # fmt: skip
        est = np.stack([e[c] for c in cols], -1)
        pre = (t > t_on - 1.0) & (t < t_on)
        noise = est[pre].std(0)
        assert np.all(np.abs(est[pre].mean(0)) < q + 3 * noise + 1e-4)
        win = (t >= t_on) & (t <= t_on + 2.5)
        hi = step_response(t[win] - t_on, WN)[:, None] * truth
        lo = step_response(t[win] - t_on - d, WN)[:, None] * truth
        delta = 0.05 * np.abs(truth) + q + 4 * noise + 1e-4
        upper, lower = np.maximum(hi, lo) + delta, np.minimum(hi, lo) - delta
        bad = (est[win] > upper) | (est[win] < lower)
        assert not bad.any(), f"{cols}: {bad.sum()} samples outside the bound, first at t = {t[win][bad.any(1)][0]:.2f}"
        steady = (t > t_on + 1.5) & (t < t_on + 3.0)
        assert np.all(np.abs(est[steady].mean(0) - truth) < 0.03 * np.abs(truth) + q + 1e-4)


def test_latency_delays_the_estimate_on_the_screen_by_what_the_link_measures(estimated):
    """The sim delays every packet by ``latency`` each way: TIMESYNC must see about that one-way latency, and the
    telemetry's age on arrival must lie between the latency and the latency plus a stream period plus the
    computers' scheduling (50 ms on a loaded machine)."""
    link = estimated["res"].summary["link"]
    lat = estimated["latency"]
    assert lat * 0.8 < link["latency_ms"] * 1e-3 < lat + 0.05
    age = link["telemetry_age_ms"]["median"] * 1e-3
    assert lat * 0.8 < age < lat + 1.0 / RATE + 0.05


def test_the_run_folder_is_complete_and_its_tlog_replays_to_the_live_estimate(estimated):
    out = estimated["out"]
    assert {p.name for p in out.iterdir()} >= {"flight.tlog", "estimate.csv", "live.json", "manifest.json"}
    cfg = json.loads((out / "live.json").read_text())
    streams = {s["message"]: s for s in cfg["streams"]}
    assert streams["ATTITUDE"]["requested_hz"] == RATE and streams["ATTITUDE"]["measured_probe_hz"] > 0.8 * RATE
    assert cfg["estimator"]["sources"]["outputs"] == "SERVO_OUTPUT_RAW"
    # a standard tlog: 8-byte big-endian microseconds, increasing, then MAVLink packets pymavlink reads
    raw = (out / "flight.tlog").read_bytes()
    t_first = struct.unpack(">Q", raw[:8])[0]
    assert abs(t_first * 1e-6 - time.time()) < 3600
    mu = mavutil()
    log = mu.mavlink_connection(str(out / "flight.tlog"))
    types, stamps = set(), []
    while (m := log.recv_msg()) is not None:
        types.add(m.get_type())
        stamps.append(m._timestamp)
    log.close()
    assert np.all(np.diff(stamps) > 0)
    assert {"ATTITUDE", "LOCAL_POSITION_NED", "SERVO_OUTPUT_RAW", "PARAM_VALUE", "HEARTBEAT"} <= types
    assert "BAD_DATA" not in types
    # the same LiveEstimator fed the file in order reproduces every live estimate
    live = read_csv(out / "estimate.csv")
    ticks, _ = replay(out)
    assert len(ticks) == len(live["t_s"])
    f = np.array([t.f_hat_W for t in ticks])
    tau = np.array([t.tau_hat_B for t in ticks])
    assert np.array_equal(np.array([t.t_us for t in ticks]), np.round(live["t_s"] * 1e6).astype(int))
    assert np.allclose(f, np.stack([live["fx_W_N"], live["fy_W_N"], live["fz_W_N"]], -1), rtol=0, atol=1e-8)
    assert np.allclose(tau, np.stack([live["taux_B_Nm"], live["tauy_B_Nm"], live["tauz_B_Nm"]], -1), atol=1e-9)
    # and the NumPy reference gives the same numbers as the compiled kernels
    ticks_np, _ = replay(out, backend="numpy")
    assert np.allclose(np.array([t.f_hat_W for t in ticks_np]), f, atol=1e-9)


def test_ardupilot_messages_and_rotor_speeds(tmp_path):
    """The ArduPilot profile (found from the heartbeat): its hover parameter, its ESC telemetry (no time field)
    turned into rotor forces with the rotor constant, thrust and moment through the mixer; a constant force
    and moment recovered from measured rotor speeds."""
    from vtol_impedance.live.autopilot import ROTOR_CONSTANT

    F_W, tau_B = np.array([-0.5, 0.0, 0.3]), np.array([0.01, 0.0, 0.0])
    port = free_port()
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot",
                    inject_force_W=tuple(F_W), inject_torque_B=tuple(tau_B)):  # fmt: skip
        res = run_live(LiveSettings(f"udpin:127.0.0.1:{port}", duration=6.0, out=str(tmp_path / "r"), display="none",
                                    rotor_constant=ROTOR_CONSTANT))  # fmt: skip
    s = res.summary
    assert s["vehicle"]["autopilot"] == "ArduPilot" and s["estimator"]["sources"]["rpm"] == "ESC_TELEMETRY_1_TO_4"
    e = read_csv(res.folder / "estimate.csv")
    last = e["t_s"] > e["t_s"][-1] - 1.0
    f = np.stack([e["fx_W_N"], e["fy_W_N"], e["fz_W_N"]], -1)[last].mean(0)
    tau = np.stack([e["taux_B_Nm"], e["tauy_B_Nm"], e["tauz_B_Nm"]], -1)[last].mean(0)
    # rotor speeds are whole rpm: f = k_f omega^2 is resolved to 2 k_f omega (2 pi / 60) per rpm, about 1 mN
    assert np.allclose(f, F_W, atol=0.03) and np.allclose(tau, tau_B, atol=2e-3)


def test_an_impaired_link_loses_nothing_but_samples(tmp_path, watched):
    """5 % loss, 5 % repeats, 5 % reordering and 20 ms latency each way: the session runs, counts what happened,
    keeps its buffers bounded, and still recovers a constant force. It runs for 200 estimator ticks (4 s of the
    vehicle's time), however long its set-up takes on a loaded machine."""
    F_W = np.array([0.0, 0.6, 0.0])
    port = free_port()
    imp = Impairments(loss=0.05, duplicate=0.05, reorder=0.05, latency_s=0.02, seed=3)
    settings = LiveSettings(f"udpin:127.0.0.1:{port}", duration=120.0, out=str(tmp_path / "r"), display="none",
                            connect_timeout_s=30.0)  # fmt: skip
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", inject_force_W=tuple(F_W), impairments=imp):
        th, stop, out = run_live_in_thread(settings)
        try:
            wait_for(lambda: bool(watched) and watched[0].ticks >= 200, 90, "200 estimator ticks")
        finally:
            stop.set()
            th.join(30)
    assert "error" not in out, out.get("error")
    res = out["res"]
    s = res.summary
    c = s["estimator"]["counts"]
    assert res.exit_code == 0 and res.ticks >= 200
    assert c["late"] + c["repeated"] > 0 and s["link"]["lost"] > 0 and s["link"]["duplicates"] > 0
    e = read_csv(res.folder / "estimate.csv")
    last = e["t_s"] > e["t_s"][-1] - 1.0
    est = np.stack([e["fx_W_N"], e["fy_W_N"], e["fz_W_N"]], -1)[last].mean(0)
    assert np.allclose(est, F_W, atol=0.05)


def test_memory_stays_bounded_over_many_messages():
    """Twenty thousand messages through the estimator: its rings hold at most RING samples per stream and the
    memory it keeps does not grow with the number of messages."""
    mu = mavutil()
    veh = load_preset("pelican")
    sources = {"attitude": "ATTITUDE", "velocity": "LOCAL_POSITION_NED", "thrust": "ATTITUDE_TARGET"}
    est = LiveEstimator(veh.mass, veh.inertia, ThrustMap.for_vehicle(veh, veh.mass, hover=0.42), sources, 4)

    def feed(k0: int, n: int) -> None:
        for k in range(k0, k0 + n):
            ms = 20 * k
            for m in (mu.mavlink.MAVLink_attitude_message(ms, 0.01, -0.02, 0.1, 0, 0, 0),
                      mu.mavlink.MAVLink_local_position_ned_message(ms, 0, 0, -1, 0, 0, 0),
                      mu.mavlink.MAVLink_attitude_target_message(ms, 0, [1, 0, 0, 0], 0, 0, 0, 0.42)):  # fmt: skip
                est.feed(m)

    feed(0, 2000)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    feed(2000, 3000)
    grown = sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(before, "filename"))
    tracemalloc.stop()
    assert est.counts["ticks"] >= 4900
    assert all(len(b) <= RING for b in est.buffers.values())
    assert grown < 200_000, f"memory grew by {grown} bytes over 9000 messages"


# --------------------------------------------------------------------------- streams, systems, clocks


def test_a_vehicle_without_the_needed_streams_is_refused_with_the_list(tmp_path):
    port = free_port()
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", no_streams=("LOCAL_POSITION_NED",)):
        with pytest.raises(LiveError) as exc:
            run_live(LiveSettings(f"udpin:127.0.0.1:{port}", stream_timeout_s=1.5, out=str(tmp_path / "r"),
                                  display="none"))  # fmt: skip
    text = str(exc.value)
    assert "velocity: needs LOCAL_POSITION_NED or ODOMETRY" in text and "ATTITUDE" in text
    assert not (tmp_path / "r").exists()


def _heartbeats(port: int, system: int, stop: threading.Event) -> None:
    mu = mavutil()
    conn = mu.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=system, source_component=1)
    while not stop.is_set():
        conn.mav.heartbeat_send(mu.mavlink.MAV_TYPE_QUADROTOR, mu.mavlink.MAV_AUTOPILOT_PX4, 0, 0, 0)
        stop.wait(0.2)
    conn.close()


JUMP_US = 1000_000_000  # the vehicle's clock jumps ahead by 1000 s


def n_lost(sess) -> int:
    """How many times the session has said the link was lost."""
    return sum("link lost" in text for _, text in list(sess.events))


def test_second_system_clock_jump_disconnect_and_reconnect(tmp_path, watched):
    """Another vehicle's heartbeats are listed and ignored; a jump of the vehicle's clock restarts the estimator;
    the vehicle goes silent (it rebooted) and comes back with a new clock: the session waits, asks for the
    streams again and goes on estimating. Nothing crashes, the session ends when asked.

    Each step waits for the session to have done the one before (a loaded machine slows the set-up and the
    simulated autopilot's thread by seconds), within generous bounds."""
    port = free_port()
    stop_hb = threading.Event()
    spec = quiet_spec()
    settings = LiveSettings(f"udpin:127.0.0.1:{port}", duration=120.0, out=str(tmp_path / "r"), display="none",
                            connect_timeout_s=30.0)  # fmt: skip
    th_hb = threading.Thread(target=_heartbeats, args=(port, 2, stop_hb))
    with sim_thread(spec, connect=f"udpout:127.0.0.1:{port}") as sim_a:
        th_live, stop, out = run_live_in_thread(settings)
        try:
            wait_for(lambda: watched and watched[0].target is not None, 60, "the vehicle found")
            sess = watched[0]
            th_hb.start()
            wait_for(lambda: sess.ticks >= 50, 60, "50 estimator ticks")
            wait_for(lambda: any("system 2" in o for o in sess.others.values()), 30, "the second system listed")
            n = sess.ticks
            sim_a.jump_clock(JUMP_US * 1e-6)
            wait_for(lambda: sess.est.counts["clock_jumps"] >= 1 and sess.ticks >= n + 25, 60, "the jump, 25 ticks")
            lost_before, found_before = n_lost(sess), sess.reconnects
        except BaseException:
            stop.set()
            stop_hb.set()
            th_live.join(30)
            raise
    stop_hb.set()
    try:
        wait_for(lambda: n_lost(sess) > lost_before, LINK_LOST_S + 30, "the link lost")
        with sim_thread(spec, connect=f"udpout:127.0.0.1:{port}") as sim_b:
            # before the reboot the vehicle's clock read more than the jump; after it, it starts again near 0
            def rebooted() -> bool:
                last = sess.est.last
                return sess.reconnects > found_before and last is not None and last.t_us < JUMP_US

            def state() -> str:
                return f"(reconnects {sess.reconnects}, last tick {sess.est.last and sess.est.last.t_us} us)"

            wait_for(rebooted, 60, "estimating after the reboot", state)
            n = sess.ticks
            wait_for(lambda: sess.ticks >= n + 25, 60, "25 ticks after the reboot")
            stop.set()
            th_live.join(30)
            requested = [name for name, hz in sim_b.stats["requests"]]
    finally:
        stop.set()
        th_live.join(30)
        th_hb.join(5)
    assert not th_live.is_alive() and "error" not in out, out.get("error")
    res = out["res"]
    s = res.summary
    assert res.exit_code == 0 and res.end == "stopped"
    assert any("system 2" in o for o in s["others"])
    assert s["estimator"]["counts"]["clock_jumps"] >= 2  # the jump ahead, then the reboot's jump back
    # the reboot's silence is lost and found once at least; the simulated autopilot's thread, starved on a loaded
    # machine, has fallen silent for 3 s once more: each loss must end in a reconnect
    losses = sum("link lost" in e["text"] for e in s["events"])
    assert s["reconnects"] >= 1 and s["reconnects"] == losses and "ATTITUDE" in requested
    e = read_csv(res.folder / "estimate.csv")
    assert e["segment"].max() >= 2
    assert (e["t_s"][-1] < JUMP_US * 1e-6) and np.any(np.diff(e["t_s"]) < 0), "the estimate goes on after the reboot"


def test_control_is_refused_with_two_vehicles_on_the_link(tmp_path):
    port = free_port()
    stop_hb = threading.Event()
    th = threading.Thread(target=_heartbeats, args=(port, 7, stop_hb))
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}"):
        th.start()
        try:
            with pytest.raises(LiveError, match="more than one vehicle .* --system"):
                run_live(LiveSettings(f"udpin:127.0.0.1:{port}", control=ControlSettings(), out=str(tmp_path / "r"),
                                      display="none"))  # fmt: skip
        finally:
            stop_hb.set()
            th.join(5)


# --------------------------------------------------------------------------- control


def _simulator_steady_error(kp: float, dp: float, force: float, t_on: float) -> float:
    """The simulator's own PD+C (the full controller, 50 Hz, the same position gains) against the same step."""
    from vtol_impedance.scenarios import simulate

    spec = apply_overrides(get("case-a-payload"), [
        "payload.mass=0", "trajectory.start_on_ground=false", "trajectory.hover_duration=8", "control.rate=50",
        f"control.Kp={kp}", f"control.Dp={dp}",
    ])  # fmt: skip
    spec = set_value(spec, "disturbances", [{"kind": "step", "force_W": [force, 0.0, 0.0], "t_on": t_on}])
    r = simulate(spec, ["pdc"])
    t = r.t
    sel = (t > t_on + 2.5) & (t < t_on + 4.0)
    return float(np.mean(r.data["p_W"][0][sel, 0] - r.data["p_ref_W"][0][sel, 0]))


def _control_run(tmp_path, variant: str, event: str | None, duration: float, autopilot: str = "px4"):
    # the push starts 10 s in: the handshake (a heartbeat a second) usually engages within 1 s, and a CI
    # machine under load once took 7 s
    port = free_port()
    force, t_on = 1.0, 10.0
    c = ControlSettings(variant=variant, comply=(1.0, 1.0, 0.0) if variant == "comply" else (0.0, 0.0, 0.0),
                        set_guid_options=autopilot == "ardupilot")  # fmt: skip
    settings = LiveSettings(f"udpin:127.0.0.1:{port}", duration=duration, out=str(tmp_path / variant),
                            display="none", control=c, connect_timeout_s=30)  # fmt: skip
    extra = ["--event", event] if event else []
    args = ("--set", "payload.mass=0", "--inject-force", f"{force},0,0", "--inject-at", f"{t_on}", "--duration", "40",
            "--autopilot", autopilot, *extra)  # fmt: skip
    with sim_process("case-a-payload", port, *args) as sim:
        res = run_live(settings)
        sim.send_signal(signal.SIGINT)
        _, err = sim.communicate(timeout=20)
    assert "Traceback" not in err
    d = read_csv(res.folder / "control.csv")
    return res, d, force, t_on + BOOT_S, c, err


def test_control_holds_against_a_force_like_the_simulators_pdc_and_the_watchdog_hands_back(tmp_path):
    """PD+C offboard: once the estimate has converged the position error under a 1 N push is far below what PD
    leaves (F / Kp) and close to the simulator's PD+C with the same gains. Then the velocity stream stops: the
    watchdog hands control back (hold, confirmed by the heartbeat) within its stated time."""
    res, d, force, t_on, c, err = _control_run(tmp_path, "pdc", "14.5,stop,LOCAL_POSITION_NED", 29.0)
    ctl = res.summary["control"]
    active = d["state"] == "engaged"
    sel = active & (d["t_s"] > t_on + 2.5) & (d["t_s"] < t_on + 4.0)
    assert sel.sum() > 40, "control must be active through the push"
    e_live = float(np.mean(d["x_W_m"][sel] - d["x_ref_W_m"][sel]))
    e_pd = force / c.Kp  # what PD alone leaves
    e_sim = _simulator_steady_error(c.Kp, c.Dp, force, 3.0)
    assert abs(e_live) < 0.15 * e_pd and abs(e_sim) < 0.15 * e_pd
    assert abs(e_live - e_sim) < 0.02
    assert np.allclose(d["fx_hat_W_N"][sel].mean(), force, atol=0.1)
    # the watchdog
    assert ctl["state"] == "handed_back" and "watchdog" in ctl["reason"] and res.exit_code == 3
    hb = ctl["handback"]
    assert hb["outcome"] == "confirmed" and ctl["cause"] == "safety"
    assert c.watchdog_s <= hb["since_last_tick_s"] <= c.watchdog_s + 0.08
    assert hb["mode"] == "AUTO_LOITER" and hb["confirmed_s"] is not None and hb["confirmed_s"] < 1.0
    assert "final mode AUTO_LOITER" in err


def test_control_on_arducopter_sets_guid_options_holds_within_10_cm_and_restores_it(tmp_path):
    """ArduCopter (simulated, GUID_OPTIONS 0 as shipped: thrust read as a climb rate): --set-guid-options sets bit 3,
    reads it back, flies GUIDED_NOGPS with the thrust as thrust, holds within 0.10 m of the hold point under a 1 N
    push (the issue's bound; PD alone would leave F / Kp), hands back to LOITER confirmed by a heartbeat when the
    duration ends, and restores the value read (0) on the way out."""
    # 21 s: the hold is judged from 2.5 s after the push to the end, at least 2 s of 50 Hz samples even when the
    # handshake is slow (a loaded CI machine once left 2.5 s after 18 s); the hand-back at the end of the duration is
    # the same whenever it comes (it flew 29 s before, judged over 15.5 s)
    res, d, force, t_on, c, err = _control_run(tmp_path, "pdc", None, 21.0, autopilot="ardupilot")
    ctl = res.summary["control"]
    engaged = d["state"] == "engaged"
    sel = engaged & (d["t_s"] > t_on + 2.5)
    assert sel.sum() > 100 and d["t_s"][sel][-1] > t_on + 4.5, "control must be active through the push"
    err_m = np.hypot(d["x_W_m"][sel] - d["x_ref_W_m"][sel], d["z_W_m"][sel] - d["z_ref_W_m"][sel])
    assert err_m.max() < 0.10 and force / c.Kp > 0.05
    g = ctl["guid_options"]
    assert g["read"] == 0 and g["set"] == 8 and g["read_back"] == 8 and g["restored"] == 0
    assert ctl["state"] == "handed_back" and ctl["handback"]["outcome"] == "confirmed" and res.exit_code == 0
    assert ctl["handback"]["mode"] == "LOITER"


def test_control_complies_when_asked_and_yields_to_the_pilot_at_once(tmp_path):
    """comply along x, y (M_d 2 kg, D_d 6 N s/m, K_d 5 N/m): a 1 N push moves the vehicle F / K_d = 0.2 m and
    holds it there. Then the pilot switches to POSCTL: no set-point is sent after the heartbeat that says so."""
    res, d, force, t_on, c, err = _control_run(tmp_path, "comply", "14.5,mode,POSCTL", 29.0)
    ctl = res.summary["control"]
    M, D, K = c.impedance
    sel = (d["state"] == "engaged") & (d["t_s"] > t_on + 2.5) & (d["t_s"] < t_on + 4.0)
    assert sel.sum() > 40
    x = float(np.mean(d["x_W_m"][sel] - d["x_ref_W_m"][sel]))
    assert 0.75 * force / K < x < 1.25 * force / K
    assert ctl["state"] == "handed_back" and "POSCTL" in ctl["reason"] and res.exit_code == 0
    assert ctl["handback"]["outcome"] == "pilot" and ctl["cause"] == "pilot"
    # in the recording: the first heartbeat in POSCTL after OFFBOARD, and our last SET_ATTITUDE_TARGET
    mu = mavutil()
    log = mu.mavlink_connection(str(res.folder / "flight.tlog"))
    offboard, t_yield, t_last_sp = False, None, None
    posctl = 3 << 16
    while (m := log.recv_msg()) is not None:
        if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1:
            offboard = offboard or m.custom_mode == 6 << 16
            if offboard and t_yield is None and m.custom_mode == posctl:
                t_yield = m._timestamp
        elif m.get_type() == "SET_ATTITUDE_TARGET":
            t_last_sp = m._timestamp
    log.close()
    assert t_yield is not None and t_last_sp is not None and t_last_sp < t_yield


# --------------------------------------------------------------------------- the two terminals, the display


def test_two_terminals_show_the_fans_force_and_ctrl_c_ends_cleanly(tmp_path):
    """The README's walk-through: sim-autopilot case-b-fan sends to the port where live listens; live shows and
    records the fan's push (+x, about 0.5 N where the position hold leaves the vehicle); Ctrl-C ends it with the
    run folder written and exit code 0."""
    port = free_port()
    out = tmp_path / "fan"
    with sim_process("case-b-fan", port, "--duration", "30"):
        live = subprocess.Popen([sys.executable, "-m", "vtol_impedance", "live", "--connect", f"udpin:127.0.0.1:{port}",
                                 "--out", str(out), "--display", "plain", "--send-back", "--connect-timeout", "30"],
                                env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (out.parent / f".{out.name}.lock").exists():
            time.sleep(0.2)
        time.sleep(8.0)
        live.send_signal(signal.SIGINT)
        stdout, stderr = live.communicate(timeout=20)
    assert live.returncode == 0, stderr
    assert "Traceback" not in stderr and "stopped by Ctrl-C" in stderr
    assert "f_hat_W N:" in stdout  # the plain display's lines
    e = read_csv(out / "estimate.csv")
    last = e["t_s"] > e["t_s"][-1] - 2.0
    fx = e["fx_W_N"][last].mean()
    assert 0.3 < fx < 0.9 and abs(e["fy_W_N"][last].mean()) < 0.1
    cfg = json.loads((out / "live.json").read_text())
    assert cfg["end"] == "stopped by Ctrl-C" and cfg["link"]["sent"] > 50  # heartbeats, TIMESYNC, the send-back


def test_the_display_is_one_steady_screen():
    v = View("udpin:127.0.0.1:14550", vehicle="PX4 system 1", mode="POSCTL armed", f_hat_W=np.array([0.7, 0, 0.01]),
             tau_hat_B=np.array([0, -0.02, 0]))  # fmt: skip
    lines = render(v)
    assert len(lines) == len(render(View("x"))) or len(lines) >= 15
    assert all(len(ln) <= 100 for ln in lines)
    assert any("+0.700" in ln and "#" in ln for ln in lines)
    import io

    buf = io.StringIO()
    scr = Screen("tty", buf)
    scr.draw(v, 0.0)
    scr.draw(v, 1.0)
    text = buf.getvalue()
    assert text.count("\x1b[2J") == 1 and text.count("\x1b[H") == 2  # cleared once, then redrawn in place
    assert "\x1b[K\n" in text
    buf = io.StringIO()
    Screen("plain", buf).draw(v, 0.0)
    assert buf.getvalue().count("\n") == 1 and "\x1b" not in buf.getvalue()


def test_estimate_rereads_the_recorded_tlog_and_finds_the_live_wrench(estimated, tmp_path):
    """``vtol-impedance estimate flight.tlog`` (the flight-log reader, its own resampling at 100 Hz and the
    same estimator) on the recording: the same wrench as live, after the step and before it."""
    from vtol_impedance.cli import main

    out = tmp_path / "est"
    rc = main(["estimate", str(estimated["out"] / "flight.tlog"), "--vehicle", "pelican", "--wn", str(WN),
               "--out", str(out), "--no-plots", "--quiet"])  # fmt: skip
    assert rc == 0
    off = read_csv(out / "wrench.csv")
    live = read_csv(estimated["out"] / "estimate.csv")
    # the two clocks: live ticks on the vehicle's boot clock, the file on its own; align on the step
    cols = ("fx_W_N", "fy_W_N", "fz_W_N")
    for t_a, data in ((off["t_s"], off), (live["t_s"], live)):
        f = np.stack([data[c] for c in cols], -1)
        rise = t_a[np.argmax(np.abs(f[:, 0]) > 0.5 * abs(estimated["F_W"][0]))]
        steady = (t_a > rise + 1.5) & (t_a < rise + 2.5)
        before = t_a < rise - 0.5
        assert steady.sum() > 10 and before.sum() > 10
        np.testing.assert_allclose(f[steady].mean(0), estimated["F_W"], atol=0.04)
        np.testing.assert_allclose(f[before].mean(0), 0.0, atol=0.04)


def test_the_live_estimator_uses_commands_sent_before_a_tick_and_restarts_where_streams_stop():
    """Hand-timed samples (50 Hz ticks, 20 ms apart): a command stamped exactly at a tick is not yet
    in force for it (it acts from then on); a gap in the attitude stream longer than max_gap_s restarts the
    estimator once (the next segment); a command older than command_stale_s gives no tick and restarts."""
    from vtol_impedance.live.estimator import EstimatorSettings
    from vtol_impedance.live.streams import Sample

    veh = load_preset("pelican")
    sources = {"attitude": "ATTITUDE", "velocity": "LOCAL_POSITION_NED", "thrust": "ATTITUDE_TARGET"}
    est = LiveEstimator(veh.mass, veh.inertia, ThrustMap.for_vehicle(veh, veh.mass, hover=0.5), sources, 4,
                        EstimatorSettings(max_gap_s=0.1, command_stale_s=0.5))  # fmt: skip
    assert est.period_us == 20_000
    level, still = (np.zeros(3), np.zeros(3)), (np.array([0.0, 0.0, -1.0]), np.zeros(3))
    ticks = []

    def state(t_us: int) -> None:
        ticks.extend(est.push(Sample("attitude", t_us, level)))
        ticks.extend(est.push(Sample("velocity", t_us, still)))

    est.push(Sample("thrust", 0, (0.5,)))  # hover: u = m g
    est.push(Sample("thrust", 40_000, (0.6,)))  # stamped exactly at the tick of 40 ms
    for t_us in range(0, 100_001, 10_000):
        state(t_us)
    by_t = {k.t_us: k for k in ticks}
    assert by_t[40_000].thrust_N == pytest.approx(veh.mass * 9.81)  # the earlier command still held
    assert by_t[60_000].thrust_N == pytest.approx(0.6 / 0.5 * veh.mass * 9.81)
    assert est.counts["restarts"] == 0 and {k.segment for k in ticks} == {0}
    for t_us in range(300_000, 400_001, 10_000):  # 200 ms without any sample: longer than max_gap_s
        state(t_us)
    assert est.counts["restarts"] == 1 and ticks[-1].segment == 1
    n = len(ticks)
    for t_us in range(400_000 + 10_000, 1_200_001, 10_000):  # the last command (at 40 ms) goes stale
        state(t_us)
    assert all(k.t_us - 40_000 <= 500_000 for k in ticks[n:])  # no tick with a command older than 0.5 s
    assert any("older than 0.5 s" in text for _, text in est.events)
