"""Documented bounds, checked at both sides with hand-made values: the stop conditions of a flight, the
log's empty rows and rotor columns, the quaternion tolerance, the shortest log and estimate window, and a
CSV's last row."""

from __future__ import annotations

import numpy as np
import pytest
import synthflight as S
from logfiles import csv_cols, write_csv

from vtol_impedance.errors import InputError
from vtol_impedance.model import load_preset
from vtol_impedance.model.frames import quaternion_rotation
from vtol_impedance.records import FAIL_CRASH, FAIL_TILT, REASONS, empty_log, rows_to_data
from vtol_impedance.sim import PlantParams, compile_plants
from vtol_impedance.sim.loop import check_vehicles
from vtol_impedance.sim.plant import initial_state, lowest_contact_depth


def _tilted(deg: float, depth: float = -1.0) -> np.ndarray:
    PA = compile_plants(PlantParams(load_preset("pelican")))
    x = np.atleast_2d(initial_state(PA, np.array([0.0, 0.0, depth]))).copy()
    a = np.radians(deg) / 2
    x[0, 6:10] = [np.cos(a), np.sin(a), 0.0, 0.0]  # rolled by deg
    return PA, x


def test_a_flight_stops_beyond_80_degrees_of_tilt_and_2_cm_under_the_ground():
    PA, x = _tilted(79.0)
    assert check_vehicles(PA, x)[0] == 0
    PA, x = _tilted(82.0)
    assert check_vehicles(PA, x)[0] == FAIL_TILT and "80" in REASONS[FAIL_TILT]
    # level, its lowest contact point 1 cm and then 2 cm under the ground (NED z > 0): 1.5 cm is the bound
    PA, x = _tilted(0.0)
    x[0, 2] += 0.01 - float(lowest_contact_depth(PA, x)[0])
    assert float(lowest_contact_depth(PA, x)[0]) == pytest.approx(0.01)
    assert check_vehicles(PA, x)[0] == 0
    x[0, 2] += 0.01
    assert check_vehicles(PA, x)[0] == FAIL_CRASH


def test_an_unwritten_log_row_is_nan_and_rotor_columns_are_the_first_ones():
    rows = empty_log(2, 3)
    assert np.all(np.isnan(rows.view(np.float64)))
    rows["f_rotor"][..., :4] = [1.0, 2.0, 3.0, 4.0]
    data = rows_to_data(rows, 4)
    np.testing.assert_array_equal(data["f_rotor"][0, 0], [1.0, 2.0, 3.0, 4.0])
    assert data["f_rotor"].shape == (2, 3, 4) and np.isnan(data["p_W"]).all()


def test_a_quaternion_within_5_percent_of_unit_length_is_normalised_beyond_it_refused():
    R = quaternion_rotation(np.array([[1.04, 0.0, 0.0, 0.0]]))
    np.testing.assert_allclose(R[0], np.eye(3), atol=1e-12)
    with pytest.raises(InputError, match="unit"):
        quaternion_rotation(np.array([[0.7, 0.0, 0.0, 0.0]]))


def test_shortest_log_and_window_and_the_csv_last_row(tmp_path):
    """50 samples of each signal are enough, 49 are not; an estimate window of 1.2 s works and 0.8 s is
    refused; a complete last row is read (a cut one is dropped with a note)."""
    from vtol_impedance.logs import estimate_file, read_any
    from vtol_impedance.logs.pipeline import MIN_LOG_SAMPLES, MIN_WINDOW_S

    assert (MIN_LOG_SAMPLES, MIN_WINDOW_S) == (50, 1.0)
    cols = csv_cols(S.flight())
    for n, ok in ((49, False), (50, True)):
        path = write_csv(tmp_path / f"n{n}.csv", {k: v[:n] for k, v in cols.items()})
        if ok:
            raw, _ = read_any(path)
            assert len(raw.velocity_W.t) == 50 and not any("cut short" in m for m in raw.notes)
        else:
            with pytest.raises(InputError, match="49 samples, too few"):
                estimate_file(path, S.MASS)
    whole = write_csv(tmp_path / "whole.csv", cols)
    t0 = float(cols["t_s"][0])
    assert len(estimate_file(whole, S.MASS, t_start=t0, t_end=t0 + 1.2).t) > 100
    with pytest.raises(InputError, match="at least 1 s"):
        estimate_file(whole, S.MASS, t_start=t0, t_end=t0 + 0.8)
    text = whole.read_text().rstrip("\n")
    cut = tmp_path / "cut.csv"
    cut.write_text(text[: text.rfind(",")] + "\n")  # the last row loses its last field
    raw, _ = read_any(cut)
    assert len(raw.velocity_W.t) == len(cols["t_s"]) - 1 and any("cut short" in m for m in raw.notes)
