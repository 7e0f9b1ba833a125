"""The simulated autopilot flown by MAVLink software others wrote: MAVSDK (its C++ core through the ``mavsdk``
wheel), MAVProxy as a router, and pymavlink as a plain ground station.

Every check is against what is independently true: Newton's law for the vehicle's response to a thrust
set-point (its mass and its rotors' maximum thrust from the vehicle file), ArduCopter's documented climb-rate
reading of the thrust field (``(t - 0.5) 2 WPNAV_SPEED_UP`` with the documented default 250 cm/s), the
documented parameter defaults, the injected force for the estimate, and the parameter protocol's own rules
(every index once, one count). Ports are free ones; every process is stopped in the teardown.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_live import ENV, free_port, quiet_spec, read_csv, sim_process, sim_thread

from vtol_impedance.conventions import G
from vtol_impedance.live import LiveSettings, run_live
from vtol_impedance.live.link import mavutil
from vtol_impedance.model.vehicle import load_preset

ALTITUDE_M = 1.0  # case A hovers 1 m up


def _mass_and_full_thrust() -> tuple[float, float]:
    """The quiet spec's true vehicle (case A's Pelican, no payload): mass (kg) and all rotors' maximum (N)."""
    veh = load_preset("pelican")
    return float(veh.mass), float(np.sum(veh.geometry.f_max))


def _wait(pred, timeout: float, step: float = 0.05):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(step)
    return pred()


@contextlib.contextmanager
def mavsdk_system(port: int):
    """MAVSDK as a ground station listening on ``port``; yields the first autopilot it discovers."""
    from mavsdk import ComponentType, Configuration, Mavsdk

    m = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        m.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = m.first_autopilot(10.0)
        assert system is not None, "MAVSDK did not discover the simulated autopilot"
        yield system
    finally:
        m.destroy()


def _vz_up(tel) -> float:
    return -float(tel.velocity_ned().down_m_s)


def _true_state(sim) -> tuple[float, float, float]:
    """The plant's (not the telemetry's) simulated time (s), height (m) and climb rate (m/s) now."""
    t, p_W, v_W, _ = sim.history[-1]
    return float(t), -float(p_W[2]), -float(v_W[2])


def _over(sim, seconds: float) -> tuple[float, float]:
    """Mean vertical acceleration (m/s^2, up) and climb rate (m/s) of the plant over the next ``seconds`` of
    simulated time (the vehicle's clock: a loaded machine runs it slower than the wall's)."""
    t0, h0, v0 = _true_state(sim)
    assert _wait(lambda: _true_state(sim)[0] >= t0 + seconds, 10.0 * seconds + 2.0), "the simulation stalled"
    t1, h1, v1 = _true_state(sim)
    return (v1 - v0) / (t1 - t0), (h1 - h0) / (t1 - t0)


def _accel_W(sim, seconds: float) -> np.ndarray:
    """Mean acceleration of the plant (m/s^2, world NED) over the next ``seconds`` of simulated time."""
    t0, v0 = sim.history[-1][0], sim.history[-1][2].copy()
    assert _wait(lambda: sim.history[-1][0] >= t0 + seconds, 10.0 * seconds + 2.0), "the simulation stalled"
    t1, v1 = sim.history[-1][0], sim.history[-1][2]
    return (v1 - v0) / (t1 - t0)


def _common_telemetry(tel, flight_mode) -> None:
    """What MAVSDK reads of a hovering vehicle: health all true, position 1 m above home, armed, in air."""
    assert _wait(tel.health_all_ok, 5.0), f"health not all ok: {tel.health()}"
    pos, home = tel.position(), tel.home()
    assert pos.relative_altitude_m == pytest.approx(ALTITUDE_M, abs=0.05)
    assert pos.absolute_altitude_m - home.absolute_altitude_m == pytest.approx(ALTITUDE_M, abs=0.05)
    assert abs(pos.latitude_deg - home.latitude_deg) < 1e-6 and abs(pos.longitude_deg - home.longitude_deg) < 1e-6
    assert tel.armed() and tel.in_air() and tel.flight_mode() == flight_mode
    att = tel.attitude_euler()
    assert abs(att.roll_deg) < 1.0 and abs(att.pitch_deg) < 1.0


def test_mavsdk_flies_px4_offboard_attitude():
    """MAVSDK discovers the simulated PX4, reads its telemetry and flies attitude set-points in OFFBOARD: 0.1 of
    full thrust above hover accelerates it up at 0.1 U / m (Newton, the vehicle file's numbers), a 5 deg roll
    set-point with the weight's thrust tilts it 5 deg and accelerates it east at g tan(5 deg); stopping offboard
    holds (AUTO_LOITER). The response is measured on the plant, over the vehicle's (simulated) clock."""
    from mavsdk.autopilot import Autopilot
    from mavsdk.plugins.offboard import Attitude, Offboard
    from mavsdk.plugins.telemetry import FlightMode, Telemetry

    mass, full = _mass_and_full_thrust()
    hover = mass * G / full
    port = free_port()
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}") as sim, mavsdk_system(port) as system:
        assert system.autopilot_type() == Autopilot.PX4
        tel, off = Telemetry(system), Offboard(system)
        _common_telemetry(tel, FlightMode.POSCTL)
        off.set_attitude(Attitude(0.0, 0.0, 0.0, hover + 0.1))
        off.start()
        assert _wait(lambda: tel.flight_mode() == FlightMode.OFFBOARD, 2.0)
        h0 = tel.position().relative_altitude_m
        a_up, _ = _over(sim, 0.8)
        assert a_up == pytest.approx(0.1 * full / mass, rel=0.05), a_up
        assert _wait(lambda: tel.position().relative_altitude_m > h0 + 0.3, 2.0)  # and MAVSDK sees it climb
        off.set_attitude(Attitude(5.0, 0.0, 0.0, hover / np.cos(np.radians(5.0))))
        _over(sim, 0.6)  # the attitude loop settles
        a_W = _accel_W(sim, 0.5)
        assert tel.attitude_euler().roll_deg == pytest.approx(5.0, abs=0.5)
        # the tilted thrust (its vertical part the weight) accelerates it east at g tan(5 deg) = 0.86 m/s^2
        assert a_W[1] == pytest.approx(G * np.tan(np.radians(5.0)), rel=0.05) and abs(a_W[0]) < 0.05, a_W
        assert tel.velocity_ned().east_m_s > 0.1  # and MAVSDK sees it
        off.stop()
        assert _wait(lambda: sim.mode == "AUTO_LOITER", 2.0)
        assert _wait(lambda: tel.flight_mode() == FlightMode.HOLD, 2.0)


def test_mavsdk_flies_ardupilot_guided_with_both_readings_of_the_thrust():
    """MAVSDK flies the simulated ArduCopter in GUIDED (its offboard): with GUID_OPTIONS 0 (the documented
    default) the thrust field is a climb rate, 0.75 climbing at (0.75 - 0.5) 2 WPNAV_SPEED_UP = 1.25 m/s and 0.5
    holding the altitude; GUID_OPTIONS 8 set through MAVSDK's param plugin makes it thrust, 0.1 of full thrust
    above hover accelerating it up at 0.1 U / m; stopping offboard brakes or loiters."""
    from mavsdk.autopilot import Autopilot
    from mavsdk.plugins.offboard import Attitude, Offboard
    from mavsdk.plugins.param import Param
    from mavsdk.plugins.telemetry import FlightMode, Telemetry

    mass, full = _mass_and_full_thrust()
    hover = mass * G / full
    port = free_port()
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot") as sim, \
            mavsdk_system(port) as system:  # fmt: skip
        assert system.autopilot_type() == Autopilot.ARDUPILOT
        tel, off, par = Telemetry(system), Offboard(system), Param(system)
        _common_telemetry(tel, FlightMode.HOLD)  # LOITER
        assert par.get_param_int("GUID_OPTIONS") == 0
        off.set_attitude(Attitude(0.0, 0.0, 0.0, 0.75))
        off.start()
        assert _wait(lambda: tel.flight_mode() == FlightMode.OFFBOARD, 2.0) and sim.mode == "GUIDED"
        _over(sim, 1.5)  # the altitude loop settles on the demanded climb rate
        _, climb = _over(sim, 0.5)
        assert climb == pytest.approx(1.25, abs=0.1), climb
        assert _vz_up(tel) == pytest.approx(1.25, abs=0.25)  # MAVSDK reads it too
        off.set_attitude(Attitude(0.0, 0.0, 0.0, 0.5))
        _over(sim, 1.5)
        _, climb = _over(sim, 0.5)
        assert abs(climb) < 0.1, climb
        par.set_param_int("GUID_OPTIONS", 8)
        assert par.get_param_int("GUID_OPTIONS") == 8
        off.set_attitude(Attitude(0.0, 0.0, 0.0, hover + 0.1))
        _over(sim, 0.2)
        a_up, _ = _over(sim, 0.6)
        assert a_up == pytest.approx(0.1 * full / mass, rel=0.05), a_up
        off.stop()
        assert _wait(lambda: sim.mode in ("BRAKE", "LOITER"), 2.0), sim.mode


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_pymavlink_reads_every_parameter_once_and_a_refused_set_is_echoed(autopilot):
    """The parameter protocol as a plain pymavlink ground station sees it: PARAM_REQUEST_LIST streams every
    parameter once, indices 0..count-1 each once, one count; a read by index names the same parameter; the
    documented defaults (PX4 COM_OF_LOSS_T 1 s; ArduCopter GUID_OPTIONS 0, MOT_THST_EXPO 0.65); a set within
    range is echoed with the new value, one outside with the value held."""
    port = free_port()
    name, good, bad = ("COM_OF_LOSS_T", 2.0, 1e3) if autopilot == "px4" else ("GUID_TIMEOUT", 1.5, 50.0)
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", autopilot=autopilot) as sim:
        c = mavutil().mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
        try:
            assert c.wait_heartbeat(timeout=5) is not None
            c.mav.param_request_list_send(1, 1)
            seen: dict[int, tuple[str, float]] = {}
            counts, n = set(), 0
            end = time.monotonic() + 3.0
            while time.monotonic() < end and (not counts or len(seen) < max(counts)):
                m = c.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
                if m is not None:
                    n += 1
                    seen[m.param_index] = (m.param_id, m.param_value)
                    counts.add(m.param_count)
            assert len(counts) == 1 and n == len(seen) == counts.pop() > 0
            assert sorted(seen) == list(range(len(seen)))
            names = {v[0]: v[1] for v in seen.values()}
            assert len(names) == len(seen)
            if autopilot == "px4":
                assert names["COM_OF_LOSS_T"] == pytest.approx(1.0)
            else:
                assert names["GUID_OPTIONS"] == 0.0 and names["MOT_THST_EXPO"] == pytest.approx(0.65)
            idx = next(i for i, v in seen.items() if v[0] == name)
            c.mav.param_request_read_send(1, 1, b"", idx)
            m = c.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
            assert m is not None and m.param_id == name and m.param_index == idx
            for value, held in ((good, good), (bad, good)):
                c.mav.param_set_send(1, 1, name.encode(), value, 9)
                m = c.recv_match(type="PARAM_VALUE", blocking=True, timeout=2)
                assert m is not None and m.param_id == name and m.param_value == pytest.approx(held)
            assert sim.params[name] == good
        finally:
            c.close()


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_land_takeoff_and_refusals_over_pymavlink(autopilot):
    """NAV_LAND lands and disarms (EXTENDED_SYS_STATE on ground); armed again it takes off with NAV_TAKEOFF (PX4:
    to MIS_TAKEOFF_ALT, 2.5 m by default, then AUTO_LOITER; ArduCopter: in GUIDED only, to param 7); a mode this
    simulation does not fly is DENIED, a command it does not implement UNSUPPORTED; the older SET_MODE message
    changes the mode too. At 5x real time."""
    port = free_port()
    ardu = autopilot == "ardupilot"
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", autopilot=autopilot, speed=5.0) as sim:
        c = mavutil().mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
        mav = c.mav
        try:
            assert c.wait_heartbeat(timeout=5) is not None

            def command(cmd, *p):
                p = list(p) + [0.0] * (7 - len(p))
                mav.command_long_send(1, 1, cmd, 0, *p)
                m = c.recv_match(type="COMMAND_ACK", blocking=True, timeout=3,
                                 condition=f"COMMAND_ACK.command=={cmd}")  # fmt: skip
                assert m is not None, f"no ACK for command {cmd}"
                return m.result

            def height():
                return -sim.history[-1][1][2]

            assert command(mavutil().mavlink.MAV_CMD_NAV_LAND) == 0
            assert _wait(lambda: not sim.armed, 5.0) and height() < 0.05
            m = c.recv_match(type="EXTENDED_SYS_STATE", blocking=True, timeout=3,
                             condition="EXTENDED_SYS_STATE.landed_state==1")  # fmt: skip
            assert m is not None  # MAV_LANDED_STATE_ON_GROUND
            assert command(400, 1.0) == 0 and sim.armed
            if ardu:
                assert command(22, 0, 0, 0, 0, 0, 0, 2.0) == 2  # DENIED outside GUIDED
                assert command(176, 1, 4) == 0  # GUIDED
                assert command(22, 0, 0, 0, 0, 0, 0, 2.0) == 0
                target = 2.0
            else:
                assert command(22, *([float("nan")] * 7)) == 0
                target = 2.5
            assert _wait(lambda: abs(height() - target) < 0.1, 8.0), height()
            if not ardu:
                assert _wait(lambda: sim.mode == "AUTO_LOITER", 3.0)
            assert command(176, 1, 2 if ardu else 7) == 2  # ALT_HOLD / STABILIZED: not flown here
            assert command(300) == 3  # MAV_CMD_MISSION_START: no missions here
            hold = 5 if ardu else 3 << 16  # LOITER / POSCTL through the older SET_MODE message
            mav.set_mode_send(1, 1, hold)
            m = c.recv_match(type="COMMAND_ACK", blocking=True, timeout=3, condition="COMMAND_ACK.command==11")
            assert m is not None and m.result == 0 and sim.mode == ("LOITER" if ardu else "POSCTL")
        finally:
            c.close()


@contextlib.contextmanager
def mavproxy_router(master_port: int, out_port: int, tmp_path: Path):
    """MAVProxy as a headless router (no module but the link: it starts in about 3 s), from the vehicle on
    ``master_port`` to a ground station on ``out_port``."""
    cmd = [sys.executable, str(Path(sys.executable).parent / "mavproxy.py"), f"--master=udpin:127.0.0.1:{master_port}",
           f"--out=udpout:127.0.0.1:{out_port}", "--daemon", "--non-interactive", "--streamrate=-1",
           f"--state-basedir={tmp_path}", "--default-modules=link"]  # fmt: skip
    p = subprocess.Popen(cmd, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path)
    try:
        yield p
    finally:
        p.terminate()
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def test_live_through_a_mavproxy_router_gives_the_direct_estimate(tmp_path):
    """``live`` (estimate only) through MAVProxy gives the same estimate of an injected force as over the direct
    link: the means over the last 1.5 s agree within 2 mN, each within 30 mN of the force injected (acting from
    the start: the estimator has converged 1 s after its first tick, 10 / wn). The vehicle is a
    ``sim-autopilot`` process (its timing does not share a GIL with ``live``)."""
    F_W = np.array([0.8, -0.5, 0.0])
    args = ("--set", "payload.mass=0", "--set", "plant.rotor_drag=0", "--ideal", "--inject-force", "0.8,-0.5,0")
    means = []
    for routed in (False, True):
        port, gcs = free_port(), free_port()
        with contextlib.ExitStack() as stack:
            stack.enter_context(sim_process("case-a-payload", port, *args))
            if routed:
                stack.enter_context(mavproxy_router(port, gcs, tmp_path))
            # both start in seconds (more on a loaded machine): live starts once the vehicle is heard
            probe = mavutil().mavlink_connection(f"udpin:127.0.0.1:{gcs if routed else port}", source_system=254)
            try:
                assert probe.wait_heartbeat(timeout=60) is not None, "no heartbeat from the vehicle in 60 s"
            finally:
                probe.close()
            # 7 s (9 s before): the estimate starts 4.2 s in and spans 3.8 s (2.8 s at 6 s), past the 2.5 s checked
            res = run_live(LiveSettings(f"udpin:127.0.0.1:{gcs if routed else port}", duration=7.0,
                                        out=str(tmp_path / f"r{int(routed)}"), display="none"))  # fmt: skip
        e = read_csv(res.folder / "estimate.csv")
        t = e["t_s"]
        assert t.size, f"{'routed' if routed else 'direct'}: {res.end}"
        win = t > t[-1] - 1.5
        assert t[-1] - t[0] > 2.5, f"{routed=}: the estimator must have run 1 s (10 / wn) before the window"
        means.append(np.array([e["fx_W_N"][win].mean(), e["fy_W_N"][win].mean(), e["fz_W_N"][win].mean()]))
    assert np.allclose(means[0], F_W, atol=0.03) and np.allclose(means[1], F_W, atol=0.03), means
    assert np.allclose(means[0], means[1], atol=0.002), means


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (("--inject-at", "x"), "--inject-at is T_ON or T_ON,T_OFF"),
        (("--inject-at", "1,2,3"), "--inject-at is T_ON or T_ON,T_OFF"),
        (("--event", "0.2,mode,STABILIZED"), "not a mode the simulated PX4 flies"),
        (("--autopilot", "ardupilot", "--event", "0.2,mode,ALT_HOLD"), "not a mode the simulated ArduPilot flies"),
        (("--latency", "0.6", "--duration", "0.5"), "no packet would arrive"),
    ],
)
def test_sim_autopilot_options_are_refused_naming_the_value(extra, words, capsys):
    """Options it cannot honour are refused before it flies (exit 2), the message naming the value: a mode it
    does not fly (it would need a pilot), an injection time that is not one or two numbers, a latency as long
    as the run."""
    from vtol_impedance.cli import main

    args = ["sim-autopilot", "case-a-payload", "--connect", "udpout:127.0.0.1:14997", "--quiet", "--duration", "0.5"]
    assert main(args + list(extra)) == 2
    assert words in capsys.readouterr().err


def test_ardupilot_set_points_time_out_to_a_level_hover_in_the_mode():
    """ArduCopter's GUID_TIMEOUT (3 s, documented): attitude targets older than that leave it in GUIDED_NOGPS,
    level and holding its altitude; until then it flies the last one (a 10 deg pitch, with a climb rate of
    0.5: no climb). Targets sent before the mode is entered are not flown (ArduCopter ignores them). At 4x real
    time over pymavlink."""
    port = free_port()
    with sim_thread(quiet_spec(), connect=f"udpout:127.0.0.1:{port}", autopilot="ardupilot", speed=4.0) as sim:
        c = mavutil().mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
        try:
            assert c.wait_heartbeat(timeout=5) is not None
            mav = c.mav
            q = [float(x) for x in np.array([np.cos(np.radians(5.0)), 0.0, np.sin(np.radians(5.0)), 0.0])]
            mav.set_attitude_target_send(0, 1, 1, 7, q, 0, 0, 0, 0.5)  # in LOITER: dropped
            assert _wait(lambda: sim.stats["setpoints_unused"] >= 1, 3.0) and sim.setpoint is None
            mav.command_long_send(1, 1, 176, 0, 1, 20, 0, 0, 0, 0, 0)  # GUIDED_NOGPS
            assert _wait(lambda: sim.mode == "GUIDED_NOGPS", 3.0)
            mav.set_attitude_target_send(0, 1, 1, 7, q, 0, 0, 0, 0.5)
            assert _wait(lambda: sim.setpoint is not None, 3.0)
            t_sp = sim.setpoint["t"]
            assert _wait(lambda: sim.history[-1][0] > t_sp + 1.0, 5.0)
            pitch = float(sim.sensors.measure(np.zeros(12)).eta[1])
            assert pitch == pytest.approx(np.radians(10.0), abs=np.radians(1.0))
            assert _wait(lambda: sim.history[-1][0] > t_sp + 3.0 + 1.5, 10.0)  # GUID_TIMEOUT, then settling
            eta = sim.sensors.measure(np.zeros(12)).eta
            assert sim.mode == "GUIDED_NOGPS" and abs(eta[0]) < np.radians(1.0) and abs(eta[1]) < np.radians(1.0)
            _, climb = _over(sim, 0.5)
            assert abs(climb) < 0.05, climb
        finally:
            c.close()
