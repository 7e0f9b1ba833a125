"""Files of a log estimate: the time series as CSV and Parquet, and a JSON summary (atomic writes).

Precision: ``t_s`` is written with 17 significant digits, which gives back the very same double (a log
on a unix clock, ~1.7e9 s, keeps its microseconds); the integer columns (``segment``, ``restart``,
``bridged``) as integers; every other column with 12 significant digits (relative 5e-13, far below any
physical meaning). The Parquet file holds the same columns as doubles and 64-bit integers, exactly.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..io import write_text, write_with
from .estimate import LogEstimate

INTEGER_COLUMNS = ("segment", "restart", "bridged")
TIME_FORMAT = "%.17g"
VALUE_FORMAT = "%.12g"


def summary(est: LogEstimate) -> dict[str, Any]:
    """Per-component mean, RMS and largest magnitude of the causal estimate off the ground (the ground
    stretches of ``info["ground_s"]`` left out), plus how the log was read."""
    from .estimate import airborne

    keep = airborne(est)
    if not keep.any():  # never airborne (a bench test): every sample
        keep[:] = True
    stats: dict[str, Any] = {}
    for name, arr in (("f_W_N", est.f_W), ("tau_B_Nm", est.tau_B)):
        if arr is not None:
            arr = arr[keep]
            stats[name] = {
                "mean": arr.mean(0).tolist(),
                "rms": np.sqrt((arr**2).mean(0)).tolist(),
                "max_abs": np.abs(arr).max(0).tolist(),
            }
    return {"info": est.info, "bias": est.bias, "warnings": est.warnings, "notes": est.notes, "stats": stats,
            "stats_samples": int(keep.sum()), "ground_samples_left_out": int((~keep).sum())}  # fmt: skip


def csv_formats(names: list[str]) -> list[str]:
    """The printf format of each column (module docstring)."""
    return [TIME_FORMAT if n == "t_s" else ("%d" if n in INTEGER_COLUMNS else VALUE_FORMAT) for n in names]


def write_estimate(est: LogEstimate, folder: Path, summ: dict[str, Any] | None = None) -> list[Path]:
    """``wrench.csv``, ``wrench.parquet`` and ``estimate.json`` (``summ``, default :func:`summary`) into
    ``folder``."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = est.columns()
    names = list(cols)
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    fmts = csv_formats(names)
    arrays = [np.asarray(cols[n]) for n in names]
    line = ",".join(fmts) + "\n"
    for k in range(len(arrays[0])):
        buf.write(line % tuple(int(a[k]) if f == "%d" else float(a[k]) for f, a in zip(fmts, arrays, strict=True)))
    table = pa.table({n: np.asarray(cols[n], dtype=np.int64 if n in INTEGER_COLUMNS else float) for n in names})
    summ = summary(est) if summ is None else summ
    meta = {b"vtol_impedance": json.dumps(summ, default=_json_default).encode()}
    table = table.replace_schema_metadata(meta)
    return [
        write_text(folder / "wrench.csv", buf.getvalue()),
        write_with(folder / "wrench.parquet", lambda fh: pq.write_table(table, fh)),
        write_text(folder / "estimate.json", json.dumps(summ, indent=1, default=_json_default)),
    ]


def _json_default(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.floating | np.integer):
        return x.item()
    return str(x)
