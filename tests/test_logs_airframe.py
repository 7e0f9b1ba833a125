"""A log says what vehicle flew it; the estimator's model (eq. (5): a multirotor's thrust along -z_B) is
applied only to multirotors, warned about for VTOL hybrids and refused for the rest, unless overridden."""

from __future__ import annotations

import pytest
import synthflight as S
from logfiles import synth_tlog_messages, write_synth_dataflash
from pymavlink.dialects.v20 import common as mavlink

from vtol_impedance.cli import main
from vtol_impedance.errors import InputError
from vtol_impedance.logs import estimate_file
from vtol_impedance.logs.airframe import MULTIROTOR_TYPES, OTHER_TYPES, VTOL_TYPES, check_airframe, classify
from vtol_impedance.logs.writers import write_tlog


@pytest.fixture(scope="module")
def fl():
    return S.flight()


def test_the_mav_type_tables_follow_the_mavlink_standard():
    """Every MAV_TYPE that MAVLink names as a multirotor, a VTOL or a vehicle of another kind is classified
    so (the names are MAVLink's common.xml, through pymavlink; the tables are this project's)."""
    names = {v: k[len("MAV_TYPE_"):] for k, v in vars(mavlink).items()
             if k.startswith("MAV_TYPE_") and isinstance(v, int) and not k.endswith("ENUM_END")}  # fmt: skip
    for code, name in names.items():
        kind = classify({"mav_type": code}, {})
        if name in ("FIXED_WING", "HELICOPTER", "GROUND_ROVER", "SURFACE_BOAT", "SUBMARINE", "AIRSHIP",
                    "FREE_BALLOON", "ROCKET", "FLAPPING_WING", "KITE", "PARAFOIL"):  # fmt: skip
            assert kind is not None and kind[0] == "other", name
        elif name.startswith("VTOL"):
            assert kind is not None and kind[0] == "vtol", name
        elif "ROTOR" in name or "COPTER" in name or name == "COAXIAL":
            assert kind is not None and kind[0] == "multirotor", name
    for table in (MULTIROTOR_TYPES, VTOL_TYPES, OTHER_TYPES):
        assert set(table) <= set(names)  # no code that MAVLink does not have
    assert not set(MULTIROTOR_TYPES) & set(VTOL_TYPES) and not set(MULTIROTOR_TYPES) & set(OTHER_TYPES)


@pytest.mark.parametrize(
    "meta, params, kind",
    [
        ({"firmware": "ArduCopter V4.5.1 (1a2b3c4d)"}, {}, "multirotor"),
        ({"firmware": "APM:Copter V3.4.4-rc1 (7a1cbb2e)"}, {"FRAME_CLASS": 1.0}, "multirotor"),
        ({"firmware": "ArduCopter V4.5.1"}, {"FRAME_CLASS": 6.0}, "other"),  # a traditional helicopter
        ({"firmware": "ArduPlane V4.5.0"}, {"Q_ENABLE": 1.0}, "vtol"),  # a QuadPlane
        ({"firmware": "ArduPlane V4.5.0"}, {}, "other"),
        ({"firmware": "ArduSub V4.1.1"}, {}, "other"),
        ({"firmware": "ArduRover V4.2.0"}, {}, "other"),
        ({"mav_type": 1}, {"Q_ENABLE": 1.0}, "vtol"),  # an ArduPilot QuadPlane's HEARTBEAT says fixed wing
        ({"mav_type": 2}, {"FRAME_CLASS": 6.0}, "other"),
        ({}, {"MAV_TYPE": 13.0}, "multirotor"),  # PX4's parameter
        ({}, {"MAV_TYPE": 22.0, "VT_TYPE": 2.0}, "vtol"),
        ({}, {"MAV_TYPE": 1.0}, "other"),
        ({"mav_type": 6}, {}, None),  # a ground station names no vehicle
        ({"firmware": "ArduPlane V4.5.0"}, {"Q_ENABLE": float("nan")}, "other"),  # a damaged parameter says nothing
        ({}, {"MAV_TYPE": float("nan")}, None),
        ({}, {}, None),
    ],
)
def test_what_the_log_says_of_its_vehicle(meta, params, kind):
    found = classify(meta, params)
    assert (found[0] if found else None) == kind
    if kind == "other":
        with pytest.raises(InputError, match="models a multirotor.*--airframe multirotor"):
            check_airframe(meta, params)
        said, warning = check_airframe(meta, params, "multirotor")
        assert "taken as a multirotor" in said and "the log says" in said and warning is None
    elif kind == "vtol":
        assert "forward flight" in check_airframe(meta, params)[1]
    else:
        assert check_airframe(meta, params)[1] is None
    for bad in ("plane", "", None, 3, ["auto"]):
        with pytest.raises(InputError, match="airframe must be one of auto, multirotor"):
            check_airframe(meta, params, bad)


def _tlog(fl, path, mav_type: int):
    beat = {"type": mav_type, "autopilot": 12, "base_mode": 0, "custom_mode": 0, "system_status": 4,
            "mavlink_version": 3}  # fmt: skip
    msgs = synth_tlog_messages(fl)
    return write_tlog(path, [(msgs[0][0] - 0.5, "HEARTBEAT", beat), *msgs])


def test_a_submarine_telemetry_log_is_refused_before_the_mass_is_asked_for(fl, tmp_path, capsys):
    path = _tlog(fl, tmp_path / "rov.tlog", 12)
    with pytest.raises(InputError, match="submarine .MAV_TYPE 12"):
        estimate_file(path)  # no mass: the vehicle is what is wrong
    assert main(["estimate", str(path), "--mass", str(S.MASS), "--out", str(tmp_path / "out")]) == 2
    assert "submarine" in capsys.readouterr().err and not (tmp_path / "out").exists()
    # the log's word overridden: the same flight (it is a multirotor's) is estimated
    est = estimate_file(path, S.MASS, airframe="multirotor")
    assert any("taken as a multirotor" in c and "submarine" in c for c in est.info["choices"])
    assert main(["estimate", str(path), "--mass", str(S.MASS), "--airframe", "multirotor",
                 "--out", str(tmp_path / "out")]) == 0  # fmt: skip


def test_a_vtol_is_estimated_with_a_warning_and_a_quadrotor_without(fl, tmp_path):
    vtol = estimate_file(_tlog(fl, tmp_path / "vtol.tlog", 22), S.MASS)
    assert any("VTOL" in w and "forward flight" in w for w in vtol.warnings)
    quad = estimate_file(_tlog(fl, tmp_path / "quad.tlog", 2), S.MASS)
    assert not any("forward flight" in w for w in quad.warnings)
    assert any(c.startswith("vehicle: a quadrotor (MAV_TYPE 2") for c in quad.info["choices"])


def test_a_dataflash_log_names_its_firmware(fl, tmp_path):
    copter = write_synth_dataflash(fl, tmp_path / "copter.bin", firmware="ArduCopter V4.5.1 (1a2b3c4d)")
    assert any("ArduCopter V4.5.1" in c for c in estimate_file(copter, S.MASS).info["choices"])
    heli = write_synth_dataflash(fl, tmp_path / "heli.bin", firmware="ArduCopter V4.5.1", params={"FRAME_CLASS": 6})
    with pytest.raises(InputError, match="a helicopter .ArduCopter V4.5.1, FRAME_CLASS 6"):
        estimate_file(heli, S.MASS)
    plane = write_synth_dataflash(fl, tmp_path / "plane.bin", firmware="ArduPlane V4.5.0")
    with pytest.raises(InputError, match="fixed wing"):
        estimate_file(plane, S.MASS)
    quadplane = write_synth_dataflash(fl, tmp_path / "qp.bin", firmware="ArduPlane V4.5.0", params={"Q_ENABLE": 1})
    assert any("QuadPlane" in w for w in estimate_file(quadplane, S.MASS).warnings)


def test_a_quadplanes_hover_thrust_parameter_is_read(fl, tmp_path):
    """A QuadPlane keeps its hover throttle in Q_M_THST_HOVER (a multicopter in MOT_THST_HOVER)."""
    msgs = synth_tlog_messages(fl)
    t, name, fields = msgs[0]
    assert name == "PARAM_VALUE"
    msgs[0] = (t, name, {**fields, "param_id": b"Q_M_THST_HOVER"})
    est = estimate_file(write_tlog(tmp_path / "qp.tlog", msgs), S.MASS)
    assert "Q_M_THST_HOVER" in est.info["thrust"]
    assert est.info["hover_thrust"]["median"] == pytest.approx(fields["param_value"])
