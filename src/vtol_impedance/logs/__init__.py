"""Wrench estimation on flight logs: CSV and PX4 ULog readers, frame conversion, resampling onto one
time base, and the estimator (causal or zero-phase) with a bias calibration."""

from .csvlog import read_csv
from .estimate import LogEstimate, commands_in_si, estimate, fit_hover_thrust
from .timeseries import DEFAULT_MAX_GAP_S, DEFAULT_RATE_HZ, FlightLog, RawLog, Signal, resample
from .ulog import read_ulog, torque_per_unit


def read_log(path, **csv_options) -> RawLog:
    """A ``.ulg`` file through :func:`read_ulog`, anything else as CSV through :func:`read_csv`."""
    from pathlib import Path

    if Path(path).suffix.lower() == ".ulg":
        return read_ulog(path)
    return read_csv(path, **csv_options)


__all__ = [
    "DEFAULT_MAX_GAP_S",
    "DEFAULT_RATE_HZ",
    "FlightLog",
    "LogEstimate",
    "RawLog",
    "Signal",
    "commands_in_si",
    "estimate",
    "fit_hover_thrust",
    "read_csv",
    "read_log",
    "read_ulog",
    "resample",
    "torque_per_unit",
]
