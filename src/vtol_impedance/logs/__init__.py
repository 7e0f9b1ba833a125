"""Wrench estimation on flight logs: CSV, PX4 ULog, ArduPilot DataFlash and MAVLink tlog readers,
conventions checked against physics, frame conversion, resampling onto one time base with gaps bridged,
thrust from commands or rotor speeds, and the estimator (causal or zero-phase) with a bias calibration;
rotor drag, inflow damping and the rotor time constant identified from a log (:mod:`.identify`).
Sample logs with a known wrench ship in :mod:`vtol_impedance.logs.samples`."""

from pathlib import Path

from .ardupilot import MotorCurve
from .checks import ConventionReport, check_conventions, evidence
from .csvlog import read_csv, read_csv_table, table_to_raw
from .estimate import LogEstimate, check_inertia, commands_in_si, estimate, fit_hover_thrust, fit_hover_windows
from .frames import Conventions
from .identify import Coefficient, Identification, identify, identify_file
from .pipeline import estimate_file, log_format, read_any
from .timeseries import DEFAULT_RATE_HZ, FlightLog, RawLog, Signal, default_max_gap, resample
from .ulog import read_ulog, torque_per_unit
from .verdict import LogRefused, Verdict, judge


def read_log(path, **csv_options) -> RawLog:
    """Read a log by its extension (``.ulg``, ``.bin``, ``.tlog``, else CSV through :func:`read_csv`), without
    the convention checks of :func:`read_any`."""
    from ..errors import path_like

    path_like("path", path)
    fmt = log_format(path)
    if fmt == "ulog":
        return read_ulog(path)
    if fmt in ("dataflash", "tlog"):
        from .mavlog import read_dataflash, read_tlog

        return (read_dataflash if fmt == "dataflash" else read_tlog)(Path(path))
    return read_csv(path, **csv_options)


__all__ = [
    "DEFAULT_RATE_HZ",
    "Coefficient",
    "ConventionReport",
    "Conventions",
    "FlightLog",
    "Identification",
    "LogEstimate",
    "LogRefused",
    "MotorCurve",
    "RawLog",
    "Signal",
    "Verdict",
    "check_conventions",
    "check_inertia",
    "commands_in_si",
    "default_max_gap",
    "estimate",
    "estimate_file",
    "evidence",
    "fit_hover_thrust",
    "fit_hover_windows",
    "identify",
    "identify_file",
    "judge",
    "log_format",
    "read_any",
    "read_csv",
    "read_csv_table",
    "read_log",
    "read_ulog",
    "resample",
    "table_to_raw",
    "torque_per_unit",
]
