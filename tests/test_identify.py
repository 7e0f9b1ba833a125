"""identify: planted rotor drag, inflow damping and rotor lag recovered from a simulated log (issue 31, item 3)."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import pytest

from vtol_impedance.errors import InputError
from vtol_impedance.estimator import EstimatorParams
from vtol_impedance.logs.identify import identify_file

PLANTED = {"rotor_drag[0]": 0.30, "rotor_drag[1]": 0.20, "inflow_damping": 0.25, "rotor_tau": 0.04}
PRESETS = Path(__file__).resolve().parents[1] / "src" / "vtol_impedance" / "presets"


def _log(tmp: Path, kind: str, move: tuple[float, float, float] = (1.5, -1.5, -1.0), airborne: bool = False) -> Path:
    """A flight of the simulator with the planted terms, written as a CSV log (thrust command in N): the
    case C circle at 1 m/s (take-off 1 m in 4 s, two laps) or a hover (``move``: a step of the set point),
    from the ground or, ``airborne``, from hovering at the altitude."""
    from vtol_impedance.logs.writers import write_csv
    from vtol_impedance.model.kinematics import quat_from_euler
    from vtol_impedance.scenarios import get, simulate

    text = (PRESETS / "hexarotor.toml").read_text().replace('name = "hexarotor"', 'name = "hexa-drag"')
    text += "\nrotor_drag = [0.30, 0.20]\ninflow_damping = 0.25\n"
    (tmp / "v.toml").write_text(text)
    spec = get("case-c-circle")
    traj = replace(spec.trajectory, kind=kind, circle_speed=1.0, move_offset=move, move_duration=1.5,
                   move_hold=2.0, start_on_ground=not airborne)  # fmt: skip
    spec = replace(
        spec, vehicle=str(tmp / "v.toml"), disturbances=(), payload=replace(spec.payload, mass=0.0),
        trajectory=traj, plant=replace(spec.plant, rotor_tau_up=0.04, rotor_tau_down=0.04), duration=25.0,
    )  # fmt: skip
    r = simulate(spec, ["pd"])
    v, q, w = r["v_meas_W"][0], quat_from_euler(r["eta_meas"][0]), r["omega_B"][0]
    cols = {"t_s": r.t}
    cols.update({k: v[:, i] for i, k in enumerate(("vx", "vy", "vz"))})
    cols.update({f"q{i}": q[:, i] for i in range(4)})
    cols.update({k: w[:, i] for i, k in enumerate(("wx", "wy", "wz"))})
    cols["thrust_n"] = r["thrust"][0]
    return write_csv(tmp / f"{kind}.csv", cols)


def _latency() -> EstimatorParams:
    """The estimator told the simulated sensors' latencies (velocity: motion capture; attitude: IMU)."""
    from vtol_impedance.scenarios import get

    s = get("case-c-circle").sensors
    return EstimatorParams(velocity_delay=s.mocap_delay, attitude_delay=s.imu_delay)


@pytest.fixture(scope="module")
def circle_log(tmp_path_factory):
    return _log(tmp_path_factory.mktemp("identify"), "circle")


def test_planted_terms_recovered_within_5_percent(circle_log):
    """Sensor noise and latency on (the scenario's); no payload (a mass offset off the centre of mass is not
    in the model) and no wind. The truth is what the plant flew (the vehicle TOML and plant.rotor_tau_*)."""
    res = identify_file(circle_log, vehicle="hexarotor", params=_latency())
    for c in res.coefficients:
        truth = PLANTED[c.key]
        assert c.identifiable, c.text()
        assert abs(c.value - truth) <= 0.05 * truth, c.text()
        assert c.ci95[0] <= truth <= c.ci95[1], c.text()
    snippet = res.toml_snippet()
    keys = tomllib.loads(snippet)  # the snippet is valid TOML with the vehicle's own key names
    assert keys["rotor_drag"] == pytest.approx([0.30, 0.20], rel=0.05)
    assert keys["inflow_damping"] == pytest.approx(0.25, rel=0.05)
    from vtol_impedance.model.vehicle import vehicle_from_dict

    assert vehicle_from_dict({**tomllib.loads((PRESETS / "hexarotor.toml").read_text()), **keys}).rotor_drag


def test_latency_left_out_reads_as_rotor_lag(circle_log):
    """The velocity's 20 ms latency, not given, adds to the lag: the fit finds about tau + latency."""
    from vtol_impedance.scenarios import get

    res = identify_file(circle_log, vehicle="hexarotor")
    seen = PLANTED["rotor_tau"] + get("case-c-circle").sensors.mocap_delay
    assert res.rotor_tau.value == pytest.approx(seen, rel=0.1)


def test_hover_only_log_is_not_identifiable(tmp_path):
    """A hover that starts in the air: no speed on any body axis."""
    res = identify_file(_log(tmp_path, "hover", (0.0, 0.0, 0.0), airborne=True), vehicle="hexarotor",
                        params=_latency())  # fmt: skip
    for c in (res.rotor_drag_x, res.rotor_drag_y, res.inflow_damping):
        assert not c.identifiable and c.value is None
        assert "not identifiable from this log" in c.text()


def test_bad_inputs(tmp_path):
    with pytest.raises(InputError, match="cannot read log file"):
        identify_file(tmp_path / "missing.csv", vehicle="hexarotor")
    from vtol_impedance.logs import samples

    with pytest.raises(InputError, match="tau_bounds"):
        identify_file(samples.path("csv"), mass=samples.MASS_KG, tau_bounds=(0.1, 0.05))
    with pytest.raises(InputError, match="tau_bounds"):
        identify_file(samples.path("csv"), mass=samples.MASS_KG, tau_bounds=0.1)
    with pytest.raises(InputError, match="mass"):  # 1e-9 kg gave a rotor lag with a zero-width interval
        identify_file(samples.path("csv"), mass=1e-9)
    t0 = samples.CLOCK_OFFSET_S["csv"]
    with pytest.raises(InputError, match="airborne samples"):  # 1.5 s of flight: too short to fit
        identify_file(samples.path("csv"), mass=samples.MASS_KG, t_start=t0 + 5.0, t_end=t0 + 6.5)


def test_cli_prints_fit_and_writes_snippet(tmp_path, capsys):
    from vtol_impedance.cli.main import main

    out = tmp_path / "keys.toml"
    assert main(["identify", "--example", "csv", "--mass", "1.31", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "not identifiable from this log" in text and "Vehicle TOML keys" in text
    assert out.read_text().startswith("# identified from a flight log")
    assert main(["identify", str(tmp_path / "nope.csv")]) == 2
    assert "cannot read log file" in capsys.readouterr().err
