"""Sweeps: Monte-Carlo and parameter studies over any scenario value, in this process or on Dask,
resumable, with summary plots; and gain tuning with optuna on the same execution."""

from .cluster import ChunkError, ClusterError
from .report import summarise, write_report
from .run import SweepFolder, read_dataset, run_sweep, run_units
from .spec import Axis, Sweep, Unit, builtin_names, from_dict, load, set_param, unit_seed

__all__ = [
    "Axis",
    "ChunkError",
    "ClusterError",
    "Sweep",
    "SweepFolder",
    "Unit",
    "builtin_names",
    "from_dict",
    "load",
    "read_dataset",
    "run_sweep",
    "run_units",
    "set_param",
    "summarise",
    "unit_seed",
    "write_report",
]
